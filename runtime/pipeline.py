"""The pipeline: from a frame source and a question (or a list of object names) to a semantic map and an answer.

The paper's stages, in order, each in its own module or package (imported below in that order); this file only
wires them, asks the budget for the plan and alone writes the `Trace`, from what the stages return (their results
and `StageLog`s):

    open + scan (frames, scan) ─▶ ground the question (grounding) ─▶ key frames (keyframes) ─▶ perception per key
    frame (perceive; models/) ─▶ alignment (align/) ─▶ the map: gravity, fusion, occlusion refinement, extents
    (map/) ─▶ visual prompt (prompt) ─▶ answer (answer)

Perception is injected (`Perception`): bundle models, or the synthetic oracle (evaluation only — this module never
imports `host`). The budget controller is made where a profile is given.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Collection, Mapping, Sequence

import numpy as np

from .budget import controller_for
from . import health
from .conf import PipelineConfig
from .frames import FrameSource
from .infra.errors import InputError
from .infra.progress import phase, start, ticking
from .infra.trace import StageLog, Trace, as_trace
from .detectable import detectable_names, undetectable_names
from .types import Budget, Detections, Frame, Observation
# the stages, in the paper's order
from .scan import DedupConf, ScanResult, open_scanned, remove_redundant
from .grounding import ParsedQuestion, bundle_reader, ground
from .keyframes import (KeyFrameConf, KeyFrameResult, finish_keyframes, plan_keyframes, requested_keyframes,
                        select_keyframes)
from .perceive import (CachedDetector, Perceived, Perception, colour_frame, load_vlm, match_boxes, perceive_keyframes,
                       perception_from_bundle, with_depth)
from .align import AlignmentResult, align_keyframes, make_matcher, rigid_part
from .map import (FusionConfig, ObjectInstance, Room, SemanticMap, annotate_views, extend_to_floor,
                  first_seen_from_detections, fuse_frames, gravity_from_frames, refine, room_extent,
                  verify_observations, world_points)
from .map.scale import box_dims, estimate_scale, rescale_map, sensor_scale
from .map.anchor import anchor_observations, summary as anchor_summary
from . import prompt as vprompt
from .answer import MapReasoner, answer_question, answer_with_vlm, cannot_detect

default_conf = PipelineConfig()


@dataclass
class MapBuild:
    """A built map and how it was built. clouds: per instance fused points [M, 3] in the map world; undetectable:
    the names the detector said it cannot detect at all (the answer says so)."""

    map: SemanticMap
    keyframes: list[int]
    clouds: list[np.ndarray]
    poses_world: dict[int, np.ndarray]
    world_from_root: np.ndarray
    unaligned: list[int]
    recovered: int = 0
    reduced_plan: bool = False
    info: dict[str, Any] = field(default_factory=dict)
    undetectable: list[str] = field(default_factory=list)


# ----------------------------------------------------------------------------- stages


def _stage(budget: Budget | None, trace: Trace, name: str) -> Any:
    """A stage of the plan: timed in the trace and, under a budget, measured against its share when it ends (an
    overrun re-plans the stages after it: budget.BudgetController.end_stage)."""
    return budget.stage(name) if budget is not None else trace.stage(name)


def scan(source: FrameSource, conf: PipelineConfig, trace: Trace, budget: Budget | None = None) -> ScanResult:
    """The scan stage (`scan.remove_redundant`), timed as "dedup", its decisions recorded."""
    with _stage(budget, trace, "dedup"), phase("dedup", len(source), "frame") as bar:
        res = remove_redundant(ticking(source, bar), conf.dedup)
        bar.to(len(source))
        bar.note(candidates=len(res.kept))
    for key, value in res.decisions.items():
        trace.decide(key, value)
    kept = [int(i) for i in res.kept]
    trace.decide("dedup", {"frames": len(source), "kept": len(kept), "dropped": len(source) - len(kept),
                           "reasons": _count_reasons(res.dropped)})
    return res


def _count_reasons(dropped: Any) -> dict[str, int]:
    out: dict[str, int] = {}
    for r in (dropped.values() if isinstance(dropped, dict) else []):
        key = str(r).split(":")[0].split(" (")[0]
        out[key] = out.get(key, 0) + 1
    return out


def select(source: FrameSource, targets: Sequence[str], cues: Sequence[str], perception: Perception,
           conf: PipelineConfig, trace: Trace, detector: CachedDetector | None = None,
           keyframes: int | None = None, budget: Budget | None = None, dedup: ScanResult | None = None
           ) -> tuple[list[int], CachedDetector, KeyFrameResult, list[int]]:
    """Dedup (unless its result is given) + key-frame search. Returns (key frame indices in time order, the cached
    detector, the search result, the candidate frames kept by dedup). Under a budget the search spends the plan's
    scored frames as they stand after dedup (its candidate count, or a re-plan after a slow dedup)."""
    dedup = dedup if dedup is not None else scan(source, conf, trace, budget)
    cands = [int(i) for i in dedup.kept]
    det = detector or CachedDetector(source, perception.detect)
    if budget is not None:  # the plan as it stands after dedup (its candidate count, or a re-plan)
        budget.update_candidates(len(cands))
    names = set(targets) | set(cues)
    plan = plan_keyframes(conf.keyframe, budget, len(cands), len(source), len(names), keyframes)
    if plan.capped:
        trace.decide("keyframes.budget_capped", plan.capped)
    kconf = plan.search
    log = StageLog()
    with _stage(budget, trace, "keyframes"), phase("keyframes", kconf.budget or kconf.keyframes, "frame") as bar:
        det.on_call = bar.update  # one tick per frame scored
        res = select_keyframes(kconf.keyframe_method, cands, list(targets), list(cues), det,
                               lambda i: colour_frame(source, int(i)).rgb, kconf, log,
                               prefetch=getattr(source, "prefetch", None), image_size=tuple(source.size),
                               thumbs=dict(dedup.thumbs),  # small gray copies: no candidate read again
                               histograms=(dict(dedup.histograms)  # the scan's: no neighbour decoded again
                                           if dedup.hist_params == (kconf.hist_bins, kconf.hist_size) else None))
        det.on_call = None
        bar.note(keyframes=len(res.chosen))
    trace.record(log)
    log = StageLog()
    chosen = finish_keyframes(res, plan, cands, len(names), budget, log)  # floor, coverage, a re-planned budget
    trace.record(log)
    trace.decide("keyframes", {**res.to_dict(), "chosen": chosen, "scores": None, "order": None,
                               "coverage_reserve": plan.reserve})
    bar.note(keyframes=len(chosen))  # the summary line: the key frames perception gets (top-up and reserve in)
    return sorted(chosen), det, res, cands


# ----------------------------------------------------------------------------- build_map: the stages wired


def _over_budget(budget: Budget | None, unaligned: Sequence[int]) -> str | None:
    """Past the latency budget: why bridge rounds are skipped (a reduced plan), else None."""
    if budget is None or budget.remaining_ms() >= 0:
        return None
    return (f"reduced plan: bridge rounds skipped ({len(unaligned)} key frame(s) stay unaligned), because the run "
            f"is {-budget.remaining_ms():.0f} ms over its budget")


def _align(p: Perceived, source: FrameSource, perception: Perception, conf: PipelineConfig, trace: Trace,
           budget: Budget | None, matcher: Any, thumbs: Mapping[int, np.ndarray] | None = None) -> AlignmentResult:
    """Alignment of the key frames (`align.align_keyframes`; `thumbs`: the scan's, for bridges found by
    appearance), with `matcher` (its feature cache serves refinement too)."""
    if hasattr(matcher, "prefetch"):  # every key frame is matched: extract on worker threads while embedding
        matcher.prefetch([(f.index, f.rgb) for f in p.frames])
    emb = None
    if perception.embed is not None:
        with trace.stage("embed"):
            emb = np.stack([perception.embed(f.rgb) for f in p.frames])
    log = StageLog()
    boxes = {f.index: match_boxes(f, p.dets[f.index], perception, log) for f in p.frames}
    if budget is not None:  # one plan stage from matching to refinement (fusion is an alias of alignment)
        budget.start_stage("alignment")
    bar = start("alignment", unit="round")
    al, _used = align_keyframes(p.frames, matcher, boxes, emb, source, with_depth(conf.depth, perception, log),
                                perception.depth_relative, conf.alignment, log,
                                lambda unaligned: _over_budget(budget, unaligned), thumbs, conf.backbone,
                                perception.embed, conf.sfm)
    trace.record(log)
    bar.done(aligned=f"{sum(f.index in al.poses for f in p.frames)}/{len(p.frames)} key frames")
    return al


def _gravity(frames: list[Frame], poses_root: dict[int, np.ndarray], source: FrameSource, root: int,
             conf: PipelineConfig, log: StageLog) -> np.ndarray:
    """World-from-root transform [4, 4] (`map.gravity_from_frames`) with the source's gravity when `conf.gravity`
    allows it and the source knows it."""
    down = None
    if conf.gravity in ("auto", "source"):
        down = source.gravity_camera(root) if hasattr(source, "gravity_camera") else None
        if down is None and conf.gravity == "source":
            raise InputError("gravity=source but the source gives no gravity direction")
    return gravity_from_frames(frames, poses_root, down, conf.camera_height_m, conf.floor_fit_max_depth_m, log)


@dataclass
class _Verifier:
    """Fusion's cross-view verification of the candidate detections (`map.verify_observations`), called by
    `map.fuse_frames`: what it found goes into `log` (timed as "verify"; the report as a decision, what it left
    out as an event) and is kept (`obs`: every observation, `ver`: the `Verification`) so the views each instance
    rests on are annotated after refinement."""

    p: Perceived
    poses: dict[int, np.ndarray]
    conf: PipelineConfig
    metric: bool
    confident_score: float  # the detector's threshold (`Perception.confident_score`)
    log: StageLog
    obs: list[Observation] | None = None
    ver: Any = None

    def __call__(self, obs: list[Observation]) -> list[Observation]:
        with self.log.stage("verify"):
            kept, ver = verify_observations(obs, self.p.frames, self.poses, self.p.dets, self.conf.verify,
                                            self.metric, self.confident_score)
        self.obs, self.ver = obs, ver
        self.log.decide("verify", ver.report(obs))
        if msg := ver.message(obs):
            self.log.event("verify", msg, stage="fusion", dropped=len(obs) - len(kept))
        return kept


@dataclass
class _Mapped:
    """What the alignment plan stage makes of the perceived key frames: poses in the map world (gravity applied),
    the fused and refined instances with their points, and the matcher (its feature counters are booked)."""

    alignment: AlignmentResult
    world_from_root: np.ndarray
    poses: dict[int, np.ndarray]
    instances: list[ObjectInstance]
    clouds: list[np.ndarray]
    recovered: int
    matcher: Any


def _map_stage(p: Perceived, source: FrameSource, perception: Perception, conf: PipelineConfig,
               fconf: FusionConfig, trace: Trace, budget: Budget | None,
               thumbs: Mapping[int, np.ndarray] | None) -> _Mapped:
    """The budget's "alignment" plan stage, opened and closed here: alignment, gravity, fusion with cross-view
    verification, occlusion refinement and the views each instance rests on."""
    matcher = make_matcher(perception.matcher, conf.match)  # one matcher: features cached across the rounds
    al = _align(p, source, perception, conf, trace, budget, matcher, thumbs)  # opens the plan stage
    log = StageLog()
    with trace.stage("gravity"):
        W = _gravity(p.frames, al.poses, source, al.root, conf, log)
    trace.record(log)
    poses = {i: W @ T for i, T in al.poses.items()}
    log = StageLog()
    verifier = _Verifier(p, poses, conf, not perception.depth_relative, perception.confident_score, log)
    lifted = _anchor(p, al, fconf, perception, trace)
    with trace.stage("fusion"):
        obs, instances, clouds = fuse_frames(p.frames, p.dets, poses, fconf, log, lifted, verifier)
    trace.record(log)
    instances, clouds, recovered = _refine(instances, clouds, obs, p.frames, poses, p.dets, perception, fconf,
                                           matcher, conf, trace, budget)
    if verifier.ver is not None:
        annotate_views(instances, verifier.obs, verifier.ver)
    if budget is not None:
        budget.end_stage("alignment")
    return _Mapped(al, W, poses, instances, clouds, recovered, matcher)


def _anchor(p: Perceived, al: AlignmentResult, fconf: FusionConfig, perception: Perception,
            trace: Trace) -> dict[int, list[Observation]]:
    """Relative depth posed by structure from motion: each key frame's detections scaled to the triangulated
    points inside them (`map.anchor`), said in the trace; otherwise perception's lifted observations as they are."""
    if not (fconf.anchor and perception.depth_relative and al.points is not None and len(al.points)):
        return p.lifted
    out, done = dict(p.lifted), []
    with trace.stage("anchor"):
        for f in p.frames:
            if f.index not in al.poses or f.index not in p.lifted or f.depth is None:
                continue
            T = np.linalg.inv(al.poses[f.index])  # root -> this camera, in this frame's depth units
            out[f.index], a = anchor_observations(p.lifted[f.index], al.points @ T[:3, :3].T + T[:3, 3], f.depth,
                                                  f.K, f.index, fconf.anchor_cell_px, fconf.anchor_min_points,
                                                  fconf.anchor_inlier_log)
            done.append(a)
    s = anchor_summary(done)
    trace.decide("anchor", s)
    if s["frame_factor"]:
        trace.event("anchor", f"objects on RGB: {s['anchored']} of {s['observations']} detections placed by the "
                    f"triangulated points inside them, {s['frame_factor']} by their frame's depth factor (too few "
                    f"points on them)", stage="fusion", **{k: s[k] for k in ("anchored", "frame_factor")})
    return out


def _refine(instances: list[ObjectInstance], clouds: list[np.ndarray], obs: list[Observation],
            frames: list[Frame], poses: dict[int, np.ndarray], dets: dict[int, Detections], perception: Perception,
            fconf: FusionConfig, matcher: Any, conf: PipelineConfig, trace: Trace, budget: Budget | None
            ) -> tuple[list[ObjectInstance], list[np.ndarray], int]:
    """Occlusion refinement (`map.refine`) unless off, impossible (no re-promptable segmenter) or the run is
    over its budget (said as a reduced plan)."""
    if conf.refine and budget is not None and budget.reduced and budget.remaining_ms() < 0:
        trace.event("reduced_plan", f"reduced plan: occlusion refinement skipped, because the run is "
                    f"{-budget.remaining_ms():.0f} ms over its {budget.budget_ms:.0f} ms budget", stage="refine")
    elif conf.refine and (perception.segment_points is not None or perception.segment_class is not None):
        log = StageLog()
        with trace.stage("refine"):
            out = refine(instances, obs, frames, poses, dets, perception, fconf, log, matcher=matcher)
        trace.record(log)
        return out
    return instances, clouds, 0


def _record_instances(instances: list[ObjectInstance], names: list[str], recovered: int, trace: Trace,
                      dets: dict[int, Detections], unaligned: Sequence[int],
                      scored: Mapping[int, Collection[str]] | None = None) -> None:
    trace.decide("instances", {"count": len(instances), "recovered_by_refinement": recovered,
                               "by_name": {n: sum(o.name == n for o in instances) for n in names},
                               "list": [{"id": o.id, "name": o.name, "centre": np.round(o.center, 3).tolist(),
                                         "size": np.round(np.asarray(o.box.axes_lengths), 3).tolist(),
                                         "frames": o.frames, "score": round(float(o.score), 3)}
                                        for o in instances]})
    missing = [n for n in names if not any(o.name == n for o in instances)]
    if missing:
        trace.event("not_in_map", "not in the map: " + missing_reasons(missing, dets, unaligned, scored),
                    names=missing)


def missing_reasons(missing: list[str], dets: dict[int, Detections], unaligned: Sequence[int],
                    scored: Mapping[int, Collection[str]] | None = None) -> str:
    """Why each name is not in the map: never detected in a key frame, detected only in key frames that stayed
    unaligned (so out of the map), or detected in aligned ones whose points fusion did not keep. `scored`: the
    detections of every frame the key-frame search scored: a name no key frame shows is then said to be seen in
    none of them (how far a "no" was looked for) or only in frames the search did not choose."""
    seen = {n: sorted(i for i, d in dets.items() if n in d.names) for n in missing}
    never = [n for n in missing if not seen[n]]
    parts = [f"not detected in any key frame: {', '.join(never)}"] if never and scored is None else []
    if never and scored is not None:
        elsewhere = {n: sorted(i for i, seen_there in scored.items() if n in seen_there) for n in never}
        if none := [n for n in never if not elsewhere[n]]:
            parts.append(f"not detected in any of the {len(scored)} frames the detector ran on: {', '.join(none)}")
        parts += [f"{n}: detected only in scored frame(s) the search did not choose as key frames: {elsewhere[n]}"
                  for n in never if elsewhere[n]]
    for n in (n for n in missing if seen[n]):
        out = [i for i in seen[n] if i in set(unaligned)]
        kept = [i for i in seen[n] if i not in set(unaligned)]
        parts.append(f"{n}: detected in key frame(s) {seen[n]}" + (f"; {out} stayed unaligned, out of the map"
                                                                    if out else "")
                     + (f"; in {kept} too few consistent 3D points for an instance" if kept else ""))
    return "; ".join(parts)


def _map_extras(instances: list[ObjectInstance], frames: list[Frame], poses: dict[int, np.ndarray],
                det: CachedDetector, names: list[str], source: FrameSource, perception: Perception,
                conf: PipelineConfig, fconf: FusionConfig, trace: Trace, anchored: bool = False
                ) -> tuple[Room | None, list[Any]]:
    """First-seen times from the search's detections, floor-standing extents (metric depth, or relative depth
    whose objects were placed by triangulated points: `anchored`), the room. Returns (room, cams)."""
    # a camera is a position and an orientation: with relative depth a pose carries its frame's depth scale (Sim(3))
    cams = [(float(f.t), rigid_part(poses[f.index])) for f in frames if f.index in poses]
    log = StageLog()
    if conf.first_seen_from_search:
        key = tuple(names)
        first_seen_from_detections(instances, [(float(source.timestamps[i]), d.names)
                                               for (i, nm), d in det.cache.items() if nm == key], log)
    if conf.floor_standing and (anchored or not perception.depth_relative):
        with log.stage("extent"):
            extend_to_floor(instances, frames, poses, conf.floor_standing, conf.floor_band_share, log)
    with log.stage("room"):
        room = room_extent(instances, cams, frames, poses, conf.room_trim_percent, fconf.max_depth_m)
    trace.record(log)
    return room, cams


def _metric_scale(smap: SemanticMap, clouds: list[np.ndarray], poses: dict[int, np.ndarray], frames: list[Frame],
                  source: FrameSource, perception: Perception, conf: PipelineConfig, trace: Trace,
                  sparse: np.ndarray | None = None, seen: list[tuple[str, Any, bool]] | None = None
                  ) -> tuple[SemanticMap, list[np.ndarray], dict[int, np.ndarray]]:
    """The map's metric scale (`map.scale`): sensor depth is metric (said in the trace); a map from model depth
    takes it from the camera height, the objects' sizes and a metric model's own scale, applied once (map,
    clouds, poses) and said with the answer ("scale" event); no usable cue: the depth prior stays, said loudly.
    `sparse` [N, 3]: triangulated world points (structure from motion), where the floor is fitted when there
    are enough of them (a depth model's dense points smear the floor). `seen`: (name, box) as fused, before the
    floor-standing extension, whose height comes from a floor an RGB map only estimates, and whether it was extended
    (then seen only in part: its height does not vote): the size votes use these."""
    if not (conf.depth == "model" or (conf.depth == "auto" and not getattr(source, "has_depth", False))):
        trace.decide("scale", sensor_scale().to_dict())
        return smap, clouds, poses
    with trace.stage("scale"):
        posed = [f for f in frames if f.index in poses]
        if sparse is not None and len(sparse) >= conf.scale.min_sparse_points:
            cloud = sparse
        else:
            pts = world_points(posed, poses, 8, lambda q: q[:, 2] < conf.floor_fit_max_depth_m)
            cloud = np.concatenate(pts) if pts else None
        ms = estimate_scale(np.array([rigid_part(poses[f.index]) for f in posed]).reshape(-1, 4, 4),
                            cloud, seen if seen is not None else smap.instances, np.array([0.0, 0.0, 1.0]),
                            None if perception.depth_relative else [1.0] * len(posed), conf.scale)
    trace.decide("scale", ms.to_dict())
    if ms.source == "guess":
        trace.event("degraded", ms.message(), stage="scale")
        return smap, clouds, poses
    trace.event("scale", ms.message(), stage="scale", scale=ms.scale, percent=round(ms.percent, 1))
    if not conf.scale.apply:
        return smap, clouds, poses
    S = np.diag([ms.scale] * 3 + [1.0])
    return rescale_map(smap, ms), [c * ms.scale for c in clouds], {i: S @ T for i, T in poses.items()}


def _book_counters(trace: Trace, source: FrameSource, loaded0: tuple[float, int], matcher: Any) -> None:
    """Work that happens inside other stages, booked as stages of its own (seconds and calls, overlapping the
    stages it ran in): frame decoding ("frames.load", cache misses), OpenCV feature extraction and descriptor
    matching ("features.extract", "features.match"; a bundle matcher books "matcher.*" itself)."""
    trace.add_time("frames.load", getattr(source, "load_seconds", 0.0) - loaded0[0],
                   getattr(source, "loads", 0) - loaded0[1])
    if hasattr(matcher, "extracts"):
        trace.add_time("features.extract", matcher.extract_seconds, matcher.extracts)
        trace.add_time("features.match", matcher.match_seconds, matcher.matches_done)


def _start_build(source: FrameSource, targets: Sequence[str], cues: Sequence[str], perception: Perception,
                 conf: PipelineConfig, trace: Trace, keyframes: int | None, budget: Budget | None
                 ) -> tuple[list[str], Perception, int]:
    """Input notes, the object names, the depth kind actually used, K. Returns (names, perception, K)."""
    for note in getattr(source, "notes", []):  # partial decode, mixed depth, greyscale, downscale: in the answer
        trace.event("degraded", note, stage="input")
    names = list(dict.fromkeys(list(targets) + list(cues)))
    if not names:  # e.g. a room-size question: key frames are spread uniformly, the map holds the room only
        trace.event("degraded", "no object names to look for: uniform key frames; the map holds the room extent "
                    "and the camera track only", stage="keyframes")
    uses_model_depth = conf.depth == "model" or (conf.depth == "auto" and not getattr(source, "has_depth", False))
    if perception.depth_relative and not uses_model_depth:  # sensor depth is metric whatever the bundle holds
        perception = dataclasses.replace(perception, depth_relative=False)
    log = StageLog()
    K = requested_keyframes(keyframes, conf.keyframe, budget, log)  # flag, budget, config; the memory guard
    trace.record(log)
    return names, perception, K


def build_map(source: FrameSource, targets: Sequence[str], cues: Sequence[str] = (),
              perception: Perception | None = None, conf: PipelineConfig | dict | None = None,
              trace: Trace | None = None, keyframes: int | None = None,
              budget: Budget | None = None, chosen: Sequence[int] | None = None) -> MapBuild:
    """Build the semantic map of the task objects (targets weigh 1, cues 0.5 in the search).

    source: frames (`frames.open_source`); perception: injected models; keyframes: K (default
    `conf.keyframe.keyframes`); budget: an optional `budget.BudgetController` (deadlines + memory guard may lower
    K; recorded); chosen: key frame indices given instead of the search (`mosaic eval pose`: the frames it
    scores go through the very map stages `ask` runs, metric scale included).
    """
    if perception is None:
        raise InputError("build_map needs a Perception (bundle models or the synthetic oracle)")
    conf = conf if isinstance(conf, PipelineConfig) else PipelineConfig.merged(conf)
    trace = trace if trace is not None else Trace()
    _say(trace, health.sample_frames(source))
    loaded0 = (getattr(source, "load_seconds", 0.0), getattr(source, "loads", 0))
    names, perception, K = _start_build(source, targets, cues, perception, conf, trace, keyframes, budget)
    scanned = scan(source, conf, trace, budget)  # its thumbnails serve the search and the bridges
    if chosen is None:
        chosen, det, _, _cands = select(source, targets, cues, perception, conf, trace, keyframes=K, budget=budget,
                                        dedup=scanned)
    else:
        chosen, det = sorted(int(i) for i in chosen), CachedDetector(source, perception.detect)
        trace.decide("keyframes", {"method": "given", "chosen": chosen})
    fconf = FusionConfig.merged(conf.fusion)
    with _stage(budget, trace, "perception"):
        p = perceive_keyframes(source, chosen, det, names, perception, conf, fconf, budget, scanned.counts)
    trace.record(p.log)
    _say(trace, health.frame_notes([health.frame_health(f.rgb, f.depth) for f in p.frames]))
    m = _map_stage(p, source, perception, conf, fconf, trace, budget, scanned.thumbs)
    al, instances = m.alignment, m.instances
    _record_instances(instances, names, m.recovered, trace, p.dets, al.unaligned, det.scored())
    seen = [(o.name, o.box) for o in instances]  # the boxes as fused: what the size votes measure (below)
    room, cams = _map_extras(instances, p.frames, m.poses, det, names, source, perception, conf, fconf, trace,
                             bool(trace.decisions.get("anchor", {}).get("anchored")))
    trace.record(det.log)  # the detector's time over the search and perception
    _book_counters(trace, source, loaded0, m.matcher)
    smap = SemanticMap(instances, room, cams,
                       {"source": getattr(source, "name", "frames"), "built_from": "video", "keyframes": chosen,
                        "root": al.root, "unaligned": al.unaligned, "objects": names, "recovered": m.recovered})
    sparse = al.points @ m.world_from_root[:3, :3].T + m.world_from_root[:3, 3] if al.points is not None else None
    # a box the floor-standing extension reached down for was seen only in part: its height does not vote
    z = np.array([0.0, 0.0, 1.0])
    seen = [(n, b, float(box_dims(o.box, z)[2]) > 1.05 * float(box_dims(b, z)[2])) for (n, b), o in zip(seen, instances)]
    smap, clouds, poses = _metric_scale(smap, m.clouds, m.poses, p.frames, source, perception, conf, trace, sparse,
                                        seen)
    return MapBuild(smap, chosen, clouds, poses, m.world_from_root, list(al.unaligned), m.recovered,
                    bool(budget is not None and getattr(budget, "reduced", False)),
                    {"alignment": al.to_dict(), "dedup_kept": None}, det.undetectable())


# ----------------------------------------------------------------------------- the question API


@dataclass
class AskResult:
    """answer: `answer.Answer`; map: the semantic map used; trace: what happened; prompt: the rendered
    `prompt.VisualPrompt` (None when not rendered); build: the `MapBuild` (None when a saved map was given);
    question: the grounded `grounding.ParsedQuestion`."""

    answer: Any
    map: SemanticMap | None
    trace: Trace
    prompt: Any = None
    build: MapBuild | None = None
    question: Any = None
    method: str = "mosaic"

    def to_dict(self, rows: bool = True) -> dict[str, Any]:
        """The result as JSON values; rows=False leaves out the per-object rows (`instances`; `objects` counts
        them): a printed answer shows only the count, and 100 k rows cost about a second."""
        return {"answer": self.answer.text, "status": self.answer.status, "value": self.answer.value,
                "unit": self.answer.unit,
                "explanation": self.answer.explanation, "qtype": self.answer.qtype, "missing": self.answer.missing,
                "method": self.method,
                "grounding": None if self.question is None else self.question.to_dict(),
                "objects": None if self.map is None else len(self.map.instances),
                "instances": None if self.map is None or not rows else _instance_rows(self.map),
                "keyframes": None if self.build is None else self.build.keyframes,
                # key frames left out of the map (no verified pose): stated with the answer, not only in the trace
                "unaligned": None if self.build is None else sorted(self.build.unaligned)}


def _say(trace: Trace, notes: list[str]) -> None:
    """Input health notes (`health`) as "input" events: the printed answer and the JSON result repeat them."""
    for n in notes:
        trace.event("input", n, stage="health")


def _instance_rows(smap: SemanticMap) -> list[dict[str, Any]]:
    """id, name, centre and size (3 decimals), first_seen of every instance (rounded for all at once)."""
    instances = smap.instances
    if not instances:
        return []
    C, L, _ = smap.box_arrays()
    c, s = np.round(C, 3).tolist(), np.round(L, 3).tolist()
    return [{"id": o.id, "name": o.name, "centre": ci, "size": si, "first_seen": o.first_seen}
            for o, ci, si in zip(instances, c, s)]


def _open(source: Any, trace: Trace | None = None) -> FrameSource | SemanticMap:
    if isinstance(source, (FrameSource, SemanticMap)):
        return source
    p = Path(source)
    if p.suffix.lower() == ".json":  # a map file: a folder, FIFO or loop of that name is said as such
        return SemanticMap.load(p)
    if p.is_dir() and (p / "map.json").is_file() and not any(p.glob("frame-*")) and not any(
            q.suffix.lower() in (".jpg", ".png", ".mp4") and q.name != "map.png" for q in p.iterdir()):
        return SemanticMap.load(p / "map.json")  # a `--out` folder: map.json beside the map's own map.png
    return open_frames(p, trace)


def open_frames(path: Any, trace: Trace | None = None, **opts: Any) -> FrameSource:
    """`frames.open_source` as a stage ("open": trace and progress summary) with the scan stage running while a
    video decodes (`scan.open_scanned`: default `DedupConf`, the search's histograms), seconds the "dedup" stage
    then does not spend. `opts` go to `open_source` (e.g. `hfov_deg`, `fps`, `K`)."""
    with as_trace(trace).stage("open"), phase("open", None, "frame") as bar:
        # a video's scan moves the bar as it decodes
        src = open_scanned(path, DedupConf(), (KeyFrameConf.hist_bins, KeyFrameConf.hist_size), progress=bar.to,
                           **opts)
        bar.to(len(src))
        if getattr(src, "observed", None) is not None:
            bar.note(redundant_frames="removed while decoding")
    return src


def _ask_direct(src: Any, question: str, options: list[str] | None, vlm: Any, trace: Trace,
                direct_frames: int) -> AskResult:
    """The Direct Input baseline: frames sampled uniformly straight to the VLM, no map."""
    if isinstance(src, SemanticMap):
        raise InputError("`method=direct` needs a video or frame folder, not a saved map", fields=("method",))
    if vlm is None:
        raise InputError("`method=direct` (the Direct Input baseline) needs a bundle with a `vlm` role",
                         fields=("method",))
    n = min(direct_frames, len(src))
    idx = np.unique(np.floor((np.arange(n) + 0.5) * len(src) / n).astype(int))
    with trace.stage("decode"):
        imgs = [src[int(i)].rgb for i in idx]
    trace.decide("direct.frames", idx.tolist())
    pq = ground(question, options, None, None, trace)
    text = vprompt.vlm_prompt(question, options if options is not None else pq.options, "", "video")
    ans = answer_with_vlm(vlm, question, options, text, imgs, trace=trace, parsed=pq)
    trace.decide("answer", ans.to_dict())
    return AskResult(ans, None, trace, None, None, pq, "direct")


def _render_prompt(smap: SemanticMap, build: MapBuild | None, mode: str, render: bool) -> Any:
    """The visual prompt of the map (the fused points too in the ``points`` mode); None when not rendered."""
    pts = ids = None
    if mode == "points" and build is not None and build.clouds:
        pts = np.concatenate([c for c in build.clouds if len(c)] or [np.zeros((0, 3))])
        ids = np.concatenate([np.full(len(c), o.id) for o, c in zip(smap.instances, build.clouds)
                              if len(c)] or [np.zeros(0, int)])
    return vprompt.render(smap, {"mode": mode}, pts, ids) if render else None


def _whole_map_targets(pq: ParsedQuestion, bundle: Any, trace: Trace) -> list[str]:
    """The question's targets; for a question about everything ("what's in the room?", "the biggest object",
    "how many things are on the desk?") every name the bundle's closed-set detector knows as well, so the map
    holds what the video shows."""
    if not pq.whole_map or pq.qtype == "room_size_estimation" or bundle is None:
        return pq.targets
    try:
        names = detectable_names(bundle, pq.objects)  # the question's own names for what the detector sees
    except InputError as e:  # an open-vocabulary detector finds only what it is asked for
        trace.event("degraded", f"a question about every object, but {e}", stage="grounding")
        return pq.targets
    trace.decide("targets", {"whole_map": True, "names": names})
    return list(dict.fromkeys(pq.targets + [n for n in names if n not in pq.cues]))


def _cannot_detect_first(pq: ParsedQuestion, options: list[str] | None, bundle: Any, trace: Trace) -> Any:
    """The "cannot recognise" answer (`answer.cannot_detect`) before any frame is read, when an object the
    question names is outside the bundle's closed-set detector ("where's the kettle?" with the COCO SSD):
    searching the video could only end in a misleading "not found". None otherwise, and for multiple choice
    (an option the detector cannot see may still lose to one it can)."""
    if bundle is None or options:
        return None
    cannot, n_labels, close = undetectable_names(bundle, pq.objects)
    if not cannot:
        return None
    ans = cannot_detect(pq, cannot, n_labels, close)
    trace.event("undetectable", ans.explanation, names=cannot, stage="grounding")
    trace.decide("answer", {k: v for k, v in ans.to_dict().items() if k != "parsed"})
    return ans


@dataclass
class AskRequest:
    """How one question is answered: every choice `ask` makes beside the source, the question and the models.

    answerer: "map" | "vlm" | "auto"; method: "mosaic" (map + visual prompt) or "direct" (the baseline: frames
    sampled uniformly straight to the VLM, `direct_frames` of them); prompt_mode: "grid" | "points" | "text" |
    "json"; grounding: "rules" | "model" | "vlm" | "auto" (who reads the question into its program, `grounding.ground`);
    keyframes: K (None: the budget's, else the config's: `keyframes.requested_keyframes`); render_image=False skips
    the map image when nothing will show it (no VLM, no file written: on a 10 k-object map it dominates); conf: the
    `PipelineConfig` or overrides of it; profile: a device profile (a budget controller is made from it for a
    video) or budget: a controller already made."""

    answerer: str = "auto"
    method: str = "mosaic"
    prompt_mode: str = "grid"
    grounding: str = "auto"
    keyframes: int | None = None
    direct_frames: int = 8
    render_image: bool = True
    conf: PipelineConfig | dict | None = None
    profile: Any = None
    budget: Budget | None = None


def ask(source: Any, question: str, options: list[str] | None = None, request: AskRequest | None = None, *,
        perception: Perception | None = None, bundle: Any = None, vlm: Any = None,
        trace: Trace | None = None) -> AskResult:
    """Answer a spatial question about a video, frame folder or saved map.

    source: a path (video, image/RGB-D folder, `map.json`), a `FrameSource` or a `SemanticMap`; options:
    multiple-choice options ("A. ...") or None; request: how to answer (`AskRequest`; default: its defaults).
    perception: injected models (default: built from `bundle`); vlm: an injected VLM (default: the bundle's,
    loaded only when it grounds or answers).
    """
    req = request if request is not None else AskRequest()
    trace = trace if trace is not None else Trace()
    conf = req.conf if isinstance(req.conf, PipelineConfig) else PipelineConfig.merged(req.conf)
    if req.method not in ("mosaic", "direct"):
        raise InputError(f"`method` must be mosaic or direct, got {req.method!r}", fields=("method",))
    if vlm is None and bundle is not None and (req.answerer != "map" or req.grounding == "vlm"):  # the map answerer
        vlm = load_vlm(bundle, trace, req.profile)  # with rule grounding neither grounds nor answers with a VLM
    src = _open(source, trace)
    if req.method == "direct":
        return _ask_direct(src, question, options, vlm, trace, req.direct_frames)
    pq = _ground(src, question, options, vlm, conf, trace, req.grounding, bundle)
    build = None
    if isinstance(src, SemanticMap):
        smap = src
        trace.decide("map", {"source": "saved map", "instances": len(smap.instances)})
    else:
        budget = req.budget
        if budget is None and req.profile is not None:
            budget = controller_for(req.profile, src, trace, bundle)  # the planner's own clip length and frame rate
        early = _refused_before_frames(question, options, pq, bundle if perception is None else None, trace)
        if early is not None:
            return AskResult(early, None, trace, None, None, pq, "mosaic")
        if perception is None:
            perception = perception_from_bundle(bundle, conf, trace, req.profile)
        build = build_map(src, _whole_map_targets(pq, bundle, trace), pq.cues, perception, conf, trace,
                          req.keyframes, budget)
        smap = build.map
    return _answer(smap, build, question, options, pq, vlm, req, trace)


def _ground(src: FrameSource | SemanticMap, question: str, options: list[str] | None, vlm: Any,
            conf: PipelineConfig, trace: Trace, grounding: str, bundle: Any) -> ParsedQuestion:
    """The grounding stage: the question's program (`grounding.ground`); a video's frames are decoded only if
    the VLM grounds it, a saved map's names help read it, the bundle's trained reader reads what the rules
    refuse."""
    frames_for_grounding = None
    if vlm is not None and not isinstance(src, SemanticMap):  # decoded only if the VLM grounds the question
        n = min(conf.grounding_frames, len(src))
        frames_for_grounding = lambda: [src[int(i)].rgb for i in np.linspace(0, len(src) - 1, n).round().astype(int)]  # noqa: E731
    with trace.stage("grounding"):
        names = sorted({o.name for o in src.instances}) if isinstance(src, SemanticMap) else ()
        reader = bundle_reader(bundle, trace) if grounding in ("model", "auto") else None
        return ground(question, options, vlm, frames_for_grounding, trace, grounding, names, reader=reader)


def _refused_before_frames(question: str, options: list[str] | None, pq: ParsedQuestion, bundle: Any,
                           trace: Trace) -> Any:
    """The answer given before any frame is read, else None: nothing to look for (the reasoner's "not understood"
    reply: status unsupported, exit 0, trace kept) or a name the bundle's detector cannot see
    (`_cannot_detect_first`)."""
    if not pq.objects and not pq.whole_map:
        ans = MapReasoner(SemanticMap()).answer(question, options, parsed=pq)
        why = "the question was not understood" if pq.qtype is None else "the question names no object to look for"
        trace.event("degraded", f"{why}: {ans.explanation}", stage="grounding")
        trace.decide("answer", {k: v for k, v in ans.to_dict().items() if k != "parsed"})
        return ans
    return _cannot_detect_first(pq, options, bundle, trace)


def _answer(smap: SemanticMap, build: MapBuild | None, question: str, options: list[str] | None,
            pq: ParsedQuestion, vlm: Any, req: AskRequest, trace: Trace) -> AskResult:
    """The map's notes, the visual prompt and the answer (`answer.answer_question`); a name missing because the
    detector could not look for it is said as such."""
    _say(trace, health.map_notes(smap))
    with trace.stage("prompt"):
        vp = _render_prompt(smap, build, req.prompt_mode, req.render_image or vlm is not None)
    with trace.stage("answer"):
        ans = answer_question(smap, question, options, req.answerer, vlm, vp, trace, pq)
        if ans.status == "not_found":  # missing because the detector could not look for them: say so
            und = set(build.undetectable) if build is not None else set()
            if cannot_see := [n for n in ans.missing if n in und]:
                ans = cannot_detect(pq, cannot_see)
    trace.decide("answer", {k: v for k, v in ans.to_dict().items() if k != "parsed"})
    return AskResult(ans, smap, trace, vp, build, pq, "mosaic")
