"""The pipeline: from a frame source and a question (or a list of object names) to a semantic map and an answer.

    source ─▶ dedup ─▶ grounding ─▶ key frames ─▶ perception per key frame ─▶ alignment (MST)
           ─▶ gravity ─▶ fusion ─▶ occlusion refinement ─▶ visual prompt ─▶ answer

Every stage is a function of its own module; this file only wires them, asks the budget for the plan and
records everything in a `Trace`. Perception is injected (`Perception`): bundle models, or the synthetic oracle
(evaluation only — this module never imports `runtime.synth`).
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np

from .errors import InputError, MosaicError
from .frames import Frame, FrameSource
from .perception import Detections
from .semantic_map import (FusionConfig, ObjectInstance, Observation, Room, SemanticMap, expected_visible,
                           fit_floor_plane, fuse_observations, gravity_world_transform, lift_observations)
from .trace import Trace

DetectFn = Callable[[Frame, list[str]], Detections]
SegmentFn = Callable[[Frame, Detections], np.ndarray]          # -> masks [N, H, W] bool
PromptSegmentFn = Callable[[Frame, np.ndarray, str], np.ndarray | None]  # points [P, 2] -> mask [H, W] or None
DepthFn = Callable[[Frame], np.ndarray]                          # -> metric depth [H, W] float32


@dataclass
class PipelineConfig:
    """One config for a run; stage configs are dicts merged into each stage's defaults."""

    keyframe_method: str = "iterative"   # iterative | uniform | exhaustive
    keyframes: int = 16                  # K, the key-frame budget (the budget planner may lower it)
    depth: str = "auto"                  # auto (sensor when the source has it) | sensor | model
    matcher: str = "sift"                # orb | sift | model
    gravity: str = "auto"                # auto (source if it knows gravity, else floor fit) | source | floor
    refine: bool = True                  # occlusion refinement
    min_keyframes: int = 3               # fewer passing frames are topped up uniformly (recorded)
    camera_height_m: float = 1.5         # prior when no floor is found
    dedup: dict[str, Any] = field(default_factory=dict)
    keyframe: dict[str, Any] = field(default_factory=dict)
    alignment: dict[str, Any] = field(default_factory=dict)
    fusion: dict[str, Any] = field(default_factory=dict)

    @classmethod
    def merged(cls, overrides: dict[str, Any] | None = None) -> "PipelineConfig":
        over = dict(overrides or {})
        known = {f.name for f in dataclasses.fields(cls)}
        bad = sorted(set(over) - known)
        if bad:
            raise InputError(f"pipeline config: unknown key(s) {bad}; known: {sorted(known)}")
        return cls(**over)


default_conf = PipelineConfig()


@dataclass
class Perception:
    """The perception a run uses. detect/segment/depth are callables over frames; `matcher` is 'orb' | 'sift' |
    an object with `.match(rgb0, rgb1, boxes0, boxes1)`; segment_points re-prompts a promptable segmenter (SAM
    or the oracle) for occlusion refinement; segment_class gives a semantic segmenter's class mask (refinement
    with a segmenter that takes no prompts); embed gives frame embeddings for the tree's similarity."""

    detect: DetectFn
    segment: SegmentFn | None = None
    depth: DepthFn | None = None
    matcher: Any = "sift"
    segment_points: PromptSegmentFn | None = None
    segment_class: Callable[[Frame, str], np.ndarray | None] | None = None
    embed: Callable[[np.ndarray], np.ndarray] | None = None
    depth_relative: bool = False
    describe: dict[str, Any] = field(default_factory=dict)


@dataclass
class MapBuild:
    """A built map and how it was built. observations are kept for refinement/rendering; clouds: per instance
    fused points [M, 3] in the map world."""

    map: SemanticMap
    keyframes: list[int]
    clouds: list[np.ndarray]
    poses_world: dict[int, np.ndarray]
    world_from_root: np.ndarray
    unaligned: list[int]
    recovered: int = 0
    reduced_plan: bool = False
    info: dict[str, Any] = field(default_factory=dict)


# ----------------------------------------------------------------------------- stages


def _candidates(source: FrameSource, conf: PipelineConfig, trace: Trace) -> list[int]:
    from .dedup import remove_redundant

    with trace.stage("dedup"):
        res = remove_redundant(source, conf.dedup or None)
    kept = [int(i) for i in res.kept]
    trace.decide("dedup", {"frames": len(source), "kept": len(kept), "dropped": len(source) - len(kept),
                           "reasons": _count_reasons(res.dropped)})
    return kept


def _count_reasons(dropped: Any) -> dict[str, int]:
    out: dict[str, int] = {}
    for r in (dropped.values() if isinstance(dropped, dict) else []):
        key = str(r).split(":")[0].split(" (")[0]
        out[key] = out.get(key, 0) + 1
    return out


class _CachedDetector:
    """Detections per (frame, names): the search and the map reuse the same detector calls."""

    def __init__(self, source: FrameSource, detect: DetectFn, trace: Trace):
        self.source, self.fn, self.trace = source, detect, trace
        self.cache: dict[tuple[int, tuple[str, ...]], Detections] = {}

    def __call__(self, index: int, names: list[str]) -> Detections:
        key = (int(index), tuple(names))
        if key not in self.cache:
            with self.trace.stage("detect"):
                self.cache[key] = self.fn(self.source[int(index)], list(names))
        return self.cache[key]


def select(source: FrameSource, targets: Sequence[str], cues: Sequence[str], perception: Perception,
           conf: PipelineConfig, trace: Trace, detector: _CachedDetector | None = None,
           keyframes: int | None = None) -> tuple[list[int], _CachedDetector, Any]:
    """Dedup + key-frame search. Returns (key frame indices in time order, the cached detector, the result)."""
    from .keyframes import KeyFrameConf, select_keyframes, uniform_keyframes

    cands = _candidates(source, conf, trace)
    det = detector or _CachedDetector(source, perception.detect, trace)
    K = int(keyframes or conf.keyframes)
    kconf = KeyFrameConf.merged({**conf.keyframe, "keyframes": K})
    with trace.stage("keyframes"):
        res = select_keyframes(conf.keyframe_method, cands, list(targets), list(cues), det,
                               lambda i: source[int(i)].rgb, kconf, trace)
    chosen = [int(i) for i in res.chosen]
    if len(chosen) < min(conf.min_keyframes, len(cands)):
        extra = [int(i) for i in uniform_keyframes(cands, KeyFrameConf.merged({"keyframes": conf.min_keyframes})).chosen
                 if int(i) not in chosen]
        need = conf.min_keyframes - len(chosen)
        chosen = sorted(chosen + extra[:need])
        trace.event("degraded", f"only {len(res.chosen)} frames passed the key-frame threshold; topped up with "
                    f"{min(need, len(extra))} evenly spaced frames", stage="keyframes")
    trace.decide("keyframes", {**res.to_dict(), "chosen": chosen, "scores": None, "order": None})
    return sorted(chosen), det, res


def _depth_for(frame: Frame, conf: PipelineConfig, perception: Perception, trace: Trace) -> np.ndarray:
    use = conf.depth
    if use == "auto":
        use = "sensor" if frame.depth is not None else "model"
    if use == "sensor":
        if frame.depth is None:
            raise InputError(f"frame {frame.index} has no sensor depth; use depth=model with a bundle depth model")
        return frame.depth
    if perception.depth is None:
        raise InputError("depth=model needs a depth model (bundle role `depth`) or choose depth=sensor")
    with trace.stage("depth"):
        return perception.depth(frame)


def _gravity(frames: list[Frame], poses_root: dict[int, np.ndarray], source: FrameSource, root: int,
             conf: PipelineConfig, trace: Trace) -> np.ndarray:
    """World-from-root transform [4, 4] (z up, origin on the floor below the root camera)."""
    from .geometry import backproject, transform

    down, offset, how = None, None, ""
    if conf.gravity in ("auto", "source"):
        g = source.gravity_camera(root) if hasattr(source, "gravity_camera") else None
        if g is not None:
            down, how = np.asarray(g, float) / np.linalg.norm(g), "source"
        elif conf.gravity == "source":
            raise InputError("gravity=source but the source gives no gravity direction")
    # floor fit on depth points of the key frames, in the root camera frame
    pts = []
    for f in frames:
        if f.index in poses_root and f.depth is not None:
            p, _ = backproject(f.depth, f.K, stride=8)
            pts.append(transform(poses_root[f.index], p[p[:, 2] < 6.0]))
    P = np.concatenate(pts) if pts else np.zeros((0, 3))
    hint = down if down is not None else np.array([0.0, 1.0, 0.0])
    fit = fit_floor_plane(P, hint, max_tilt_deg=15.0 if down is not None else 35.0)
    if down is None and fit is not None:
        down, how = fit[0], "floor_fit"
    if fit is not None:
        offset = float(down @ (fit[0] * fit[1]))  # floor distance below the root camera along `down`
        if offset <= 0.3:
            offset = None
    if down is None:
        down, how = np.array([0.0, 1.0, 0.0]), "camera_axes"
        trace.event("degraded", "no gravity from the source and no floor found: assuming the root camera is level",
                    stage="gravity")
    if offset is None:
        trace.event("degraded", f"floor height unknown: assuming the root camera is {conf.camera_height_m} m above "
                    f"the floor", stage="gravity")
    trace.decide("gravity", {"method": how, "down_root": down.tolist(), "floor_below_root_m": offset})
    return gravity_world_transform(down, offset, conf.camera_height_m)


def build_map(source: FrameSource, targets: Sequence[str], cues: Sequence[str] = (),
              perception: Perception | None = None, conf: PipelineConfig | dict | None = None,
              trace: Trace | None = None, keyframes: int | None = None,
              budget: Any | None = None) -> MapBuild:
    """Build the semantic map of the task objects (targets weigh 1, cues 0.5 in the search).

    source: frames (`frames.open_source`); perception: injected models; keyframes: K (default `conf.keyframes`);
    budget: an optional `budget.BudgetController` (deadlines + memory guard may lower K; recorded).
    """
    if perception is None:
        raise InputError("build_map needs a Perception (bundle models or the synthetic oracle)")
    conf = conf if isinstance(conf, PipelineConfig) else PipelineConfig.merged(conf)
    trace = trace if trace is not None else Trace()
    names = list(dict.fromkeys(list(targets) + list(cues)))
    if not names:
        raise InputError("build_map: no object names to look for")
    K = int(keyframes or conf.keyframes)
    if budget is not None:
        K = int(budget.allow_keyframes(K))
    chosen, det, _ = select(source, targets, cues, perception, conf, trace, keyframes=K)

    # perception per key frame
    frames: list[Frame] = []
    dets: dict[int, Detections] = {}
    for i in chosen:
        if budget is not None and not budget.check_headroom(50.0):
            trace.event("reduced_plan", f"memory guard: stopped adding key frames at {len(frames)}",
                        stage="perception")
            break
        f = source[i]
        d = det(i, names)
        if d.masks is None and perception.segment is not None and len(d):
            with trace.stage("segment"):
                d = dataclasses.replace(d, masks=perception.segment(f, d))
        dets[i] = d
        frames.append(dataclasses.replace(f, depth=_depth_for(f, conf, perception, trace)))
    if len(frames) < 2:
        raise MosaicError(f"only {len(frames)} key frame(s) available: need at least 2 to build a map")

    # alignment: matches restricted to object boxes (the paper's trick), MST over frame similarity
    from .alignment import align_frames

    emb = None
    if perception.embed is not None:
        with trace.stage("embed"):
            emb = np.stack([perception.embed(f.rgb) for f in frames])
    boxes = {f.index: (dets[f.index].boxes if len(dets[f.index]) else None) for f in frames}
    with trace.stage("alignment"):
        al = align_frames(frames, perception.matcher, "mst", conf.alignment or None, emb, boxes,
                          with_scale=perception.depth_relative, trace=trace)
    root = al.root
    with trace.stage("gravity"):
        W = _gravity(frames, al.poses, source, root, conf, trace)
    poses = {i: W @ T for i, T in al.poses.items()}

    # lift and fuse
    fconf = dataclasses.replace(FusionConfig(), **conf.fusion) if conf.fusion else FusionConfig()
    obs: list[Observation] = []
    with trace.stage("fusion"):
        for f in frames:
            if f.index not in poses:
                continue
            d = dets[f.index]
            obs += lift_observations(f.rgb.shape[:2], f.depth, f.K, poses[f.index], d.boxes, d.names, d.scores,
                                     d.masks, f.index, f.t, fconf, d.instance_ids)
        instances, clouds = fuse_observations(obs, fconf)
    recovered = 0
    if conf.refine and (perception.segment_points is not None or perception.segment_class is not None):
        with trace.stage("refine"):
            instances, clouds, recovered = refine(instances, obs, frames, poses, dets, perception, fconf, trace)
    trace.decide("instances", {"count": len(instances), "recovered_by_refinement": recovered,
                               "by_name": {n: sum(o.name == n for o in instances) for n in names}})
    missing = [n for n in names if not any(o.name == n for o in instances)]
    if missing:
        trace.event("not_in_map", f"not found in the key frames: {', '.join(missing)}", names=missing)

    cams = [(float(f.t), poses[f.index]) for f in frames if f.index in poses]
    smap = SemanticMap(instances, _room(instances, cams), cams,
                       {"source": getattr(source, "name", "frames"), "built_from": "video", "keyframes": chosen,
                        "root": root, "unaligned": al.unaligned, "objects": names, "recovered": recovered})
    return MapBuild(smap, chosen, clouds, poses, W, list(al.unaligned), recovered,
                    bool(budget is not None and getattr(budget, "reduced", False)),
                    {"alignment": al.to_dict(), "dedup_kept": None})


def _room(instances: list[ObjectInstance], cams: list[tuple[float, np.ndarray]]) -> Room | None:
    """Room extent of a built map: hull of the object footprints and the camera track (a lower bound)."""
    from .geometry import convex_hull_2d

    pts = [o.box.corners()[:, :2] for o in instances] + [T[None, :2, 3] for _, T in cams]
    if not pts:
        return None
    P = np.concatenate(pts)
    top = max([float(o.box.aabb()[1][2]) for o in instances] + [2.4])
    return Room(convex_hull_2d(P), 0.0, top, "objects_and_camera_hull")


# ----------------------------------------------------------------------------- occlusion refinement


def refine(instances: list[ObjectInstance], obs: list[Observation], frames: list[Frame],
           poses: dict[int, np.ndarray], dets: dict[int, Detections], perception: Perception,
           conf: FusionConfig, trace: Trace) -> tuple[list[ObjectInstance], list[np.ndarray], int]:
    """Paper, occlusion refinement: project every instance into each key frame; where it should be visible but
    was not segmented, re-prompt the segmenter — with point prompts from cross-frame matches inside its other
    views (promptable segmenter), or the class mask inside the projected box (semantic segmenter) — and add what
    it recovers. Returns the re-fused instances, their clouds and how many instances gained a view."""
    from .alignment import _make_matcher

    matcher = _make_matcher(perception.matcher)
    by_index = {f.index: f for f in frames}
    new_obs: list[Observation] = []
    gained: set[int] = set()
    for inst in instances:
        seen = set(inst.frames)
        for f in frames:
            if f.index in seen or f.index not in poses:
                continue
            box = expected_visible(inst, f.K, poses[f.index], (f.rgb.shape[1], f.rgb.shape[0]), f.depth)
            if box is None:
                continue
            mask = None
            if perception.segment_points is not None:
                pts = []
                for g_idx in inst.frames:  # matches between a view that has it and this frame, inside both boxes
                    g = by_index.get(g_idx)
                    if g is None:
                        continue
                    gb = [o.box2d for o in obs if o.frame == g_idx and o.name == inst.name]
                    if not gb:
                        continue
                    m = matcher.match(g.rgb, f.rgb, np.stack(gb), box[None])
                    if len(m.uv1):
                        pts.append(m.uv1)
                if pts:
                    P = np.concatenate(pts)
                    inside = ((P[:, 0] >= box[0]) & (P[:, 0] <= box[2]) & (P[:, 1] >= box[1]) & (P[:, 1] <= box[3]))
                    P = P[inside]
                    if len(P) >= 3:
                        mask = perception.segment_points(f, P[:16], inst.name)
            if mask is None and perception.segment_class is not None:
                cls = perception.segment_class(f, inst.name)
                if cls is not None:
                    x0, y0, x1, y1 = np.round(box).astype(int)
                    mask = np.zeros(cls.shape, bool)
                    mask[y0:y1 + 1, x0:x1 + 1] = cls[y0:y1 + 1, x0:x1 + 1]
            if mask is None or mask.sum() < conf.min_points:
                continue
            lifted = lift_observations(f.rgb.shape[:2], f.depth, f.K, poses[f.index], box[None], [inst.name],
                                       np.array([inst.score * 0.9]), mask[None], f.index, f.t, conf)
            # keep only what agrees with the instance (the prompt may have hit an occluder)
            for ob in lifted:
                inside = inst.box.contains(ob.points, margin=0.15)
                if inside.mean() >= 0.5:
                    ob.points = ob.points[inside]
                    new_obs.append(ob)
                    gained.add(inst.id)
    if not new_obs:
        return instances, [np.zeros((0, 3))] * len(instances), 0
    trace.event("refinement", f"occlusion refinement recovered {len(new_obs)} view(s) of {len(gained)} "
                f"instance(s)", views=len(new_obs), instances=len(gained))
    inst2, clouds = fuse_observations(obs + new_obs, conf)
    return inst2, clouds, len(gained)
