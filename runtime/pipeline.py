"""The pipeline: from a frame source and a question (or a list of object names) to a semantic map and an answer.

The paper's stages, in order, each the function of its own module (imported below in that order); this file
only wires them, asks the budget for the plan and records everything in a `Trace`:

    ground the question (grounding) ─▶ drop redundant frames (dedup) ─▶ key-frame search (keyframes)
    ─▶ perception per key frame (Perception: bundle models or the oracle) ─▶ alignment (alignment: box matches,
    whole image, bridges, depth verification) ─▶ semantic map: gravity, fusion, occlusion refinement, extent,
    first-seen times (semantic_map) ─▶ visual prompt (prompt) ─▶ answer (answer)

Perception is injected (`Perception`): bundle models, or the synthetic oracle (evaluation only — this module
never imports `host.synth`). Bundle loading and the budget planner are imported where they are used (they
pull in onnxruntime and the profile machinery, which a saved-map question never needs).
"""
from __future__ import annotations

import dataclasses
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any, Callable, ClassVar, Collection, Mapping, Sequence

import numpy as np

from . import health
from .config import StageConf
from .errors import InputError, MosaicError
from .frames import Frame, FrameSource
from .perception import Detections
from .progress import phase, start, ticking
from .trace import Trace, as_trace
# the stages, in the paper's order
from .grounding import ParsedQuestion, ground
from .dedup import DedupConf, DedupResult, remove_redundant
from .keyframes import KeyFrameConf, scored_budget, select_keyframes, uniform_keyframes
from .matching import MatchConf, make_matcher
from .alignment import AlignConf, align_keyframes, worker_threads
from .semantic_map import (FusionConfig, ObjectInstance, Observation, SemanticMap, box_depth_mask,
                           extend_to_floor, first_seen_from_detections, fuse_observations, gravity_from_frames,
                           lift_camera, place, refine, room_extent)
from . import prompt as vprompt
from .answer import MapReasoner, answer_question, answer_with_vlm, cannot_detect
# moved to their stage modules; importable from here as before
from .alignment import attach_frames, bridge_attach, depth_consistency, verify_tree  # noqa: F401
from .semantic_map import floor_support, hull_candidates as _hull_candidates  # noqa: F401

DetectFn = Callable[[Frame, list[str]], Detections]
SegmentFn = Callable[[Frame, Detections], np.ndarray]          # -> masks [N, H, W] bool
PromptSegmentFn = Callable[[Frame, np.ndarray, str], np.ndarray | None]  # points [P, 2] -> mask [H, W] or None
DepthFn = Callable[[Frame], np.ndarray]                          # -> metric depth [H, W] float32


def _pipeline_alignment() -> AlignConf:
    # fewer inliers than alignment's default 20 are accepted because every tree edge is then checked against
    # the two depth maps (`verify_depth`), which catches the wrong ones a low inlier count lets through
    return AlignConf(min_inliers=12)


# typed stage configs of a run: field -> its class (a mapping given for one is merged over the field's default)
_SUB_CONFS: dict[str, type] = {"dedup": DedupConf, "alignment": AlignConf, "match": MatchConf, "fusion": FusionConfig}


@dataclass
class PipelineConfig(StageConf):
    """One config for a run (`PipelineConfig.merged(mapping_or_conf, **overrides)`, unknown keys are an error).
    Stage configs are typed (`dedup`, `alignment`, `match`, `fusion`; a mapping given for one is merged over its
    default here, unknown keys an error); `keyframe` stays a mapping of overrides, because the pipeline derives
    the search's budget and top-up per clip and a key set here must win over the derived value."""

    conf_name: ClassVar[str] = "pipeline config"

    keyframe_method: str = "iterative"   # iterative | uniform | exhaustive
    keyframes: int = 16                  # K, the key-frame budget (the budget planner may lower it)
    depth: str = "auto"                  # auto (sensor when the source has it) | sensor | model
    matcher: str = "sift"                # orb | sift | model
    gravity: str = "auto"                # auto (source if it knows gravity, else floor fit) | source | floor
    refine: bool = True                  # occlusion refinement
    first_seen_from_search: bool = True  # first-seen times also from the frames the search scored
    min_keyframes: int = 3               # fallback: fewer key frames even after the top-up -> evenly spaced ones
    min_scored_per_keyframe: int = 3     # search budget >= this x K (capped at the candidates), recorded
    # ... and <= this x K without a plan, whatever the candidates (`keyframes.scored_budget`): 25% of a 600 s
    # video's candidates was 449 scored frames, 26 s of detector here. 3 (= the floor: the same budget at every
    # duration) is what the 600 s maps were measured good at; 6 (the planner's cap, `PlanConf`) scored 96 frames
    # at 600 s and its maps lost recall 1.00 -> 0.82, answers 0.93 -> 0.60 (docs/performance.md, "round 4")
    max_scored_per_keyframe: float | None = 3.0
    cover_min_area: float = 0.02         # top-up coverage: an object counts as seen from this box area share on
    coverage_min_names: int = 4          # a map of this many object names or more (e.g. "everything") ...
    coverage_share: float = 0.5          # ... reserves this share of K for temporal coverage (`spread_keyframes`):
                                         # the search alone clusters on the frames with the most detections
    topup: bool = True                   # fewer than K passing: the search's `min_keyframes = K` top-up (recorded)
    topup_spacing: int = 4               # ... its frames at least len(video) / (this x K) frames apart
    box_prompt_min_share: float = 0.02   # a mask under this share of its box is replaced by a box-prompted one
    grounding_frames: int = 4            # frames (evenly spaced) shown to a VLM that grounds the question
    whole_image_fallback: bool = True    # key frames unaligned with matches inside boxes: retry on whole images
    # relative depth (essential edges): match inside the boxes in the first tree too. Off: an essential matrix
    # from matches on a few objects is ill-conditioned; on the kitchen (PyDNet++ + XFeat) the box-matched tree
    # (+ whole-image edges for the frames it left out) had ATE 0.41-0.50 m against 0.06-0.16 m for the
    # whole-image tree, which is what the runs then used anyway (docs/performance.md, "round 4")
    relative_box_matching: bool = False
    attach_tries: int = 4                # ... metric depth: each tries its this many nearest aligned frames in time
    bridge_frames: int = 48              # at most this many extra frames to connect unaligned key frames (0 = off)
    bridge_gap_s: float = 0.25           # bridge frames are placed at most this far apart in time
    bridge_rounds: int = 2               # bridge, check, bridge again around edges the check rejected
    bridge_max_gap_s: float = 10.0       # ... and only across gaps up to this long (long chains drift)
    revisit_tries: int = 4               # metric depth, unaligned key frames beyond that gap from every aligned
                                         # one: this many (frame near it in time, aligned frame far away) pairs
                                         # most alike by dedup's thumbnails tried each, a place the video shows
                                         # twice (0 = off; the frames loaded count in `bridge_frames`)
    # floor-standing furniture seen from above (a table top, a chair back) reaches down to the floor when the key
    # frames saw its support (points under the footprint in >= `floor_band_share` of the 10 cm height bands, the
    # lowest included) or saw no open space under it (hidden bands are unknown) (`extend_to_floor`); () = off
    floor_standing: tuple[str, ...] = ("table", "chair", "sofa", "couch", "bed", "bench", "desk", "stool",
                                       "refrigerator", "toilet", "cabinet", "shelf", "bookshelf")
    floor_band_share: float = 0.6
    verify_depth: bool = True            # reject tree edges whose depth maps contradict each other (metric depth)
    max_free_space_violation: float = 0.02  # share of a frame's points seen in front of the other's surfaces
    camera_height_m: float = 1.5         # prior when no floor is found
    floor_fit_max_depth_m: float = 6.0   # the floor plane is fitted on key-frame depth nearer than this (the far
                                         # floor is noisy and often a wall's foot); the room extent uses fusion's
                                         # `max_depth_m`, alignment its own (`AlignConf.max_depth_m`)
    room_trim_percent: float = 0.5       # room extent: depth points beyond this percentile in any direction dropped
    memory_headroom_mb: float = 50.0     # budget's memory guard: no more key frames below this free memory
    dedup: DedupConf = field(default_factory=DedupConf)
    keyframe: dict[str, Any] = field(default_factory=dict)
    alignment: AlignConf = field(default_factory=_pipeline_alignment)
    match: MatchConf = field(default_factory=MatchConf)  # OpenCV matchers (ratio per method when unset)
    fusion: FusionConfig = field(default_factory=FusionConfig)

    def __post_init__(self) -> None:
        for name, cls in _SUB_CONFS.items():
            v = getattr(self, name)
            if isinstance(v, Mapping):
                setattr(self, name, _merge_sub(cls, getattr(type(self)(), name), v))
            elif v is None:
                setattr(self, name, getattr(type(self)(), name))

    def validate(self) -> None:
        if self.keyframe_method not in ("iterative", "uniform", "exhaustive"):
            raise InputError(f"pipeline config: keyframe_method must be iterative, uniform or exhaustive "
                             f"(got {self.keyframe_method!r})")
        if self.keyframes < 1:
            raise InputError(f"pipeline config: keyframes must be >= 1 (got {self.keyframes})")
        for name, allowed in (("depth", ("auto", "sensor", "model")), ("gravity", ("auto", "source", "floor"))):
            if getattr(self, name) not in allowed:
                raise InputError(f"pipeline config: {name} must be one of {', '.join(allowed)} "
                                 f"(got {getattr(self, name)!r})")
        if self.min_keyframes < 0 or self.min_scored_per_keyframe < 0 or self.bridge_frames < 0:
            raise InputError("pipeline config: min_keyframes, min_scored_per_keyframe and bridge_frames must be >= 0")
        if self.max_scored_per_keyframe is not None and not self.max_scored_per_keyframe >= self.min_scored_per_keyframe:
            raise InputError(f"pipeline config: max_scored_per_keyframe must be >= min_scored_per_keyframe "
                             f"({self.min_scored_per_keyframe}; got {self.max_scored_per_keyframe}) or null")
        if not 0 <= self.cover_min_area <= 1 or not 0 <= self.max_free_space_violation <= 1:
            raise InputError("pipeline config: cover_min_area and max_free_space_violation must be in [0, 1]")
        if self.revisit_tries < 0:
            raise InputError("pipeline config: revisit_tries must be >= 0")
        if self.attach_tries < 1 or self.topup_spacing < 1 or self.grounding_frames < 1:
            raise InputError("pipeline config: attach_tries, topup_spacing and grounding_frames must be >= 1")


def _merge_sub(cls: type, base: Any, upd: Mapping[str, Any]) -> Any:
    """A stage config from the pipeline's default for it and a mapping of overrides (unknown keys named). Not
    `cls.merged`: MatchConf.merged fills the per-method ratio, which must stay unset until the method is known."""
    known = {f.name for f in dataclasses.fields(cls)}
    bad = sorted(set(upd) - known)
    if bad:
        raise InputError(f"{cls.conf_name}: unknown key(s) {bad}; known: {sorted(known)}")
    out = dataclasses.replace(base, **dict(upd))
    out.validate()
    return out


default_conf = PipelineConfig()


@dataclass
class Perception:
    """The perception a run uses. detect/segment/depth are callables over frames; `matcher` is 'orb' | 'sift' |
    a `matching.Matcher` (`.match(rgb0, rgb1, boxes0, boxes1)`); segment_points re-prompts a promptable segmenter
    (SAM or the oracle) for occlusion refinement; segment_class gives a semantic segmenter's class mask
    (refinement with a segmenter that takes no prompts); embed gives frame embeddings for the tree's similarity."""

    detect: DetectFn
    segment: SegmentFn | None = None
    depth: DepthFn | None = None
    matcher: Any = "sift"
    segment_points: PromptSegmentFn | None = None
    segment_class: Callable[[Frame, str], np.ndarray | None] | None = None
    embed: Callable[[np.ndarray], np.ndarray] | None = None
    depth_relative: bool = False
    describe: dict[str, Any] = field(default_factory=dict)
    # every object the detector names in a frame (not only the question's): the boxes alignment matches inside
    detect_all: Callable[[Frame], Detections] | None = None


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


def _stage(budget: Any, trace: Trace, name: str) -> Any:
    """A stage of the plan: timed in the trace and, under a budget, measured against its share when it ends (an
    overrun re-plans the stages after it: budget.BudgetController.end_stage)."""
    return budget.stage(name) if budget is not None else trace.stage(name)


def _candidates(source: FrameSource, conf: PipelineConfig, trace: Trace, budget: Any = None) -> DedupResult:
    with _stage(budget, trace, "dedup"), phase("dedup", len(source), "frame") as bar:
        res = remove_redundant(ticking(source, bar), conf.dedup, trace)
        bar.to(len(source))
        bar.note(candidates=len(res.kept))
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


def _colour(source: FrameSource, i: int) -> Frame:
    """Frame i as a colour-only reader needs it (`FrameSource.colour`; a plain sequence of frames: the frame)."""
    return source.colour(i) if hasattr(source, "colour") else source[i]


class _CachedDetector:
    """Detections per (frame, names): the search and the map reuse the same detector calls."""

    def __init__(self, source: FrameSource, detect: DetectFn, trace: Trace):
        self.source, self.fn, self.trace = source, detect, trace
        self.cache: dict[tuple[int, tuple[str, ...]], Detections] = {}
        self.on_call: Callable[[], None] | None = None  # progress of the key-frame search

    def __call__(self, index: int, names: list[str]) -> Detections:
        key = (int(index), tuple(names))
        if key not in self.cache:
            with self.trace.stage("detect"):  # detection reads colour only: no depth decoded for it
                self.cache[key] = self.fn(_colour(self.source, int(index)), list(names))
            if self.on_call is not None:
                self.on_call()
        return self.cache[key]

    def scored(self) -> dict[int, set[str]]:
        """Every frame the detector ran on -> the names it detected there (of those it was asked for)."""
        out: dict[int, set[str]] = {}
        for (i, _names), d in self.cache.items():
            out.setdefault(i, set()).update(d.names)
        return out


def select(source: FrameSource, targets: Sequence[str], cues: Sequence[str], perception: Perception,
           conf: PipelineConfig, trace: Trace, detector: _CachedDetector | None = None,
           keyframes: int | None = None, budget: Any = None, dedup: DedupResult | None = None
           ) -> tuple[list[int], _CachedDetector, Any, list[int]]:
    """Dedup (unless its result is given) + key-frame search. Returns (key frame indices in time order, the cached
    detector, the search result, the candidate frames kept by dedup). Under a budget the search spends the plan's
    scored frames as they stand after dedup (its candidate count, or a re-plan after a slow dedup)."""
    dedup = dedup if dedup is not None else _candidates(source, conf, trace, budget)
    cands = [int(i) for i in dedup.kept]
    det = detector or _CachedDetector(source, perception.detect, trace)
    K = int(keyframes or conf.keyframes)
    if budget is not None:  # the plan as it stands after dedup (its candidate count, or a re-plan)
        budget.update_candidates(len(cands))
        K = min(K, int(budget.keyframes))
    reserve = coverage_reserve(K, len(set(targets) | set(cues)), conf)
    kc = {**conf.keyframe, "keyframes": K - reserve}  # the search picks the rest; `spread_keyframes` the reserve
    if budget is not None:
        kc["budget"] = int(budget.scored_frames)
    if "budget" not in kc and conf.min_scored_per_keyframe > 0:
        # the paper's 25% of the candidates, but at least a few frames per key frame (short videos; the full K:
        # the reserve's frames are chosen by the same scores)
        frac = float(kc.get("budget_fraction", KeyFrameConf.budget_fraction))
        kc["budget"] = scored_budget(len(cands), K, frac, conf.min_scored_per_keyframe, conf.max_scored_per_keyframe)
        uncapped = scored_budget(len(cands), K, frac, conf.min_scored_per_keyframe)
        if kc["budget"] < uncapped:
            trace.decide("keyframes.budget_capped", {"scored": kc["budget"], "fraction_would_score": uncapped,
                                                     "max_per_keyframe": conf.max_scored_per_keyframe})
    K = K - reserve
    if conf.topup and conf.keyframe_method == "iterative":
        # fewer than K passing: the search tops up from the frames it scored (coverage first, then by score),
        # at least len/(topup_spacing x K) frames apart; recorded by the search
        kc.setdefault("min_keyframes", K)
        kc.setdefault("topup_gap", max(1, len(source) // (conf.topup_spacing * K)))
        kc.setdefault("topup_relax", False)
        kc.setdefault("cover_min_area", conf.cover_min_area)
    kconf = KeyFrameConf.merged(kc)
    with _stage(budget, trace, "keyframes"), phase("keyframes", kc.get("budget", K), "frame") as bar:
        det.on_call = bar.update  # one tick per frame scored
        res = select_keyframes(conf.keyframe_method, cands, list(targets), list(cues), det,
                               lambda i: _colour(source, int(i)).rgb, kconf, trace,
                               prefetch=getattr(source, "prefetch", None), image_size=tuple(source.size),
                               thumbs=dict(dedup.thumbs),  # small gray copies: no candidate read again
                               histograms=(dict(dedup.histograms)  # the scan's: no neighbour decoded again
                                           if dedup.hist_params == (kconf.hist_bins, kconf.hist_size) else None))
        det.on_call = None
        bar.note(keyframes=len(res.chosen))
    chosen = [int(i) for i in res.chosen]
    if len(chosen) < min(conf.min_keyframes, len(cands)):
        extra = [int(i) for i in uniform_keyframes(cands, KeyFrameConf.merged({"keyframes": conf.min_keyframes})).chosen
                 if int(i) not in chosen]
        need = conf.min_keyframes - len(chosen)
        chosen = sorted(chosen + extra[:need])
        trace.event("degraded", f"only {len(res.chosen)} frames passed the key-frame threshold; topped up with "
                    f"{min(need, len(extra))} evenly spaced frames", stage="keyframes")
    if reserve:
        spread = spread_keyframes(chosen, cands, res.scores, reserve)
        trace.event("keyframes", f"{len(set(targets) | set(cues))} object names: {reserve} of {K} key "
                    f"frames reserved for temporal coverage (largest gaps between the search's frames): {spread}",
                    stage="keyframes", coverage=spread)
        chosen = sorted(chosen + spread)
    if budget is not None and len(chosen) > budget.keyframes:  # the search overran and the plan was reduced
        chosen = _reduce_keyframes(sorted(chosen), int(budget.keyframes), budget, trace)
    trace.decide("keyframes", {**res.to_dict(), "chosen": chosen, "scores": None, "order": None,
                               "coverage_reserve": reserve})
    bar.note(keyframes=len(chosen))  # the summary line: the key frames perception gets (top-up and reserve in)
    return sorted(chosen), det, res, cands


def coverage_reserve(K: int, n_names: int, conf: PipelineConfig) -> int:
    """Key frames kept back from the search for temporal coverage: a map of many categories (an "everything"
    question, `mosaic map`) needs every part of the video, not only the frames dense in detections."""
    if conf.coverage_share <= 0 or n_names < max(conf.coverage_min_names, 1) or K < 4:
        return 0
    return int(min(K - 2, round(conf.coverage_share * K)))


def spread_keyframes(chosen: Sequence[int], cands: Sequence[int], scores: Mapping[int, float], n: int) -> list[int]:
    """n more frames, each in the largest remaining gap (in frame order, the clip's ends included) between the
    frames chosen so far: among the candidates in the middle half of that gap, the one the search scored highest
    (unscored count 0), ties to the gap's middle. Pure; returns the new frames in time order."""
    pool = sorted(int(c) for c in cands)
    if not pool:
        return []
    lo, hi = pool[0], pool[-1]
    have = sorted(set(int(c) for c in chosen))
    out: list[int] = []
    for _ in range(n):
        marks = sorted(have + out)
        if not marks:
            gaps = [(hi - lo, lo, hi)]
        else:  # an uncovered end is as open as an inner gap twice its length (a virtual mark beyond the end)
            gaps = [(2 * (marks[0] - lo), 2 * lo - marks[0], marks[0]), (2 * (hi - marks[-1]), marks[-1], 2 * hi - marks[-1])]
            gaps += [(b - a, a, b) for a, b in zip(marks, marks[1:])]
        free = [c for c in pool if c not in marks]
        best = None
        for _, a, b in sorted(gaps, reverse=True):
            mid, q = (a + b) / 2.0, (b - a) / 4.0
            inside = [c for c in free if abs(c - mid) <= q]
            if inside:
                best = max(inside, key=lambda c: (float(scores.get(c, 0.0)), -abs(c - mid)))
                break
        if best is None:
            break
        out.append(best)
    return sorted(out)


def _reduce_keyframes(chosen: list[int], k: int, budget: Any, trace: Trace) -> list[int]:
    """Keep `k` of the chosen key frames, evenly spread in time (the map still covers the clip), and say why."""
    keep = sorted({chosen[int(j)] for j in np.linspace(0, len(chosen) - 1, max(k, 2)).round()})
    why = budget.reasons[-1].removeprefix("reduced plan: ") if getattr(budget, "reasons", None) else \
        "the budget was re-planned"
    trace.event("reduced_plan", f"reduced plan: {len(chosen)} -> {len(keep)} key frames, because {why}",
                stage="keyframes", keyframes=len(keep))
    return keep


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


def _box_prompted(masks: np.ndarray, depth: np.ndarray, d: Detections, trace: Trace,
                  min_share: float) -> np.ndarray:
    """Masks [N, H, W]: a detection the segmenter left (nearly) empty — a category it cannot segment (DeepLab has
    no cup) or a miss — gets a box-prompted mask (the depth-consistent pixels inside its box) instead of being
    dropped; recorded as degraded (once per name)."""
    masks = np.array(masks, dtype=bool)
    for j, (b, nm) in enumerate(zip(d.boxes, d.names)):
        area = max(1.0, float((b[2] - b[0]) * (b[3] - b[1])))
        if masks[j].sum() >= min_share * area:
            continue
        masks[j] = box_depth_mask(depth, b)
        noted = trace.decisions.setdefault("segment.box_prompted", {})
        if nm not in noted:
            trace.event("degraded", f"segmenter gave no mask for {nm!r}: box-prompted mask (depth-consistent "
                        f"pixels inside the box) used instead", stage="segment", name=nm)
        noted[nm] = noted.get(nm, 0) + 1
    return masks


# ----------------------------------------------------------------------------- build_map: the stages wired


def _with_depth(conf: PipelineConfig, perception: Perception, trace: Trace) -> Callable[[Frame], Frame]:
    """A source frame -> the same frame with the depth the run uses (sensor or the depth model)."""
    return lambda f: dataclasses.replace(f, depth=_depth_for(f, conf, perception, trace))


def _lift(f: Frame, d: Detections, fconf: FusionConfig) -> list[Observation]:
    """A key frame's detections as camera-frame point clouds (`semantic_map.lift_camera`)."""
    return lift_camera(f.rgb.shape[:2], f.depth, f.K, d.boxes, d.names, d.scores, d.masks, f.index, f.t, fconf,
                       d.instance_ids)


def _perceive(source: FrameSource, chosen: list[int], det: _CachedDetector, names: list[str],
              perception: Perception, conf: PipelineConfig, fconf: FusionConfig, trace: Trace, budget: Any
              ) -> tuple[list[Frame], dict[int, Detections], dict[int, list[Observation]]]:
    """Perception per key frame: depth, detections (cached from the search), masks, and the detections' point
    clouds in the camera frame (`lift_camera`, on a worker thread while the next key frame's models run). The
    memory guard may stop adding key frames (recorded). Needs 2 frames at least. -> (frames, detections,
    camera-frame observations per key frame)"""
    frames: list[Frame] = []
    dets: dict[int, Detections] = {}
    lifting: dict[int, Any] = {}
    bar = start("perception", len(chosen), "key frame")
    with _stage(budget, trace, "perception"), ThreadPoolExecutor(1) as lifter:
        for i in chosen:
            if budget is not None and not budget.check_headroom(conf.memory_headroom_mb):
                trace.event("reduced_plan", f"memory guard: stopped adding key frames at {len(frames)}",
                            stage="perception")
                break
            f = _with_depth(conf, perception, trace)(source[i])
            d = det(i, names)
            if d.masks is None and perception.segment is not None and len(d):
                with trace.stage("segment"):
                    d = dataclasses.replace(d, masks=_box_prompted(perception.segment(f, d), f.depth, d, trace,
                                                                conf.box_prompt_min_share))
            dets[i] = d
            frames.append(f)
            lifting[i] = lifter.submit(_lift, f, d, fconf)
            bar.update()
        lifted = {i: fut.result() for i, fut in lifting.items()}
    bar.done()
    if len(frames) < 2:
        c = trace.decisions.get("dedup.counts") or {}
        why = (f" (the input has {c['input']} frame(s); give a video or images that move around the room)"
               if c.get("input", 2) < 2 else
               f" (redundant-frame removal kept {c['kept']} of the {c['input']} frames: the input shows one view; "
               f"give a video or images that move around the room)" if c.get("kept", 2) < 2 else "")
        name = getattr(source, "name", None)
        raise MosaicError(f"{name + ': ' if name else ''}only {len(frames)} key frame(s) available: need at least 2 "
                          f"to build a map{why}")
    return frames, dets, lifted


def _over_budget(budget: Any, trace: Trace, unaligned: Sequence[int]) -> bool:
    """Past the latency budget: bridge rounds are skipped (said as a reduced plan)."""
    if budget is None or budget.remaining_ms() >= 0:
        return False
    trace.event("reduced_plan", f"reduced plan: bridge rounds skipped ({len(unaligned)} key frame(s) stay "
                f"unaligned), because the run is {-budget.remaining_ms():.0f} ms over its budget", stage="alignment")
    return True


def _align(frames: list[Frame], dets: dict[int, Detections], source: FrameSource, perception: Perception,
           conf: PipelineConfig, trace: Trace, budget: Any, thumbs: Mapping[int, np.ndarray] | None = None
           ) -> tuple[Any, Any]:
    """Alignment of the key frames (`alignment.align_keyframes`; `thumbs`: dedup's, for bridges found by
    appearance). Returns (alignment, the matcher: its feature cache serves refinement too)."""
    matcher = make_matcher(perception.matcher, conf.match)  # one matcher: features cached across the rounds
    if hasattr(matcher, "prefetch"):  # every key frame is matched: extract on worker threads while embedding
        matcher.prefetch([(f.index, f.rgb) for f in frames])
    emb = None
    if perception.embed is not None:
        with trace.stage("embed"):
            emb = np.stack([perception.embed(f.rgb) for f in frames])
    boxes = {f.index: _align_boxes(f, dets[f.index], perception, trace) for f in frames}
    if budget is not None:  # one plan stage from matching to refinement (fusion is an alias of alignment)
        budget.start_stage("alignment")
    bar = start("alignment", unit="round")
    al, _used = align_keyframes(frames, matcher, boxes, emb, source, _with_depth(conf, perception, trace),
                                perception.depth_relative, conf, trace,
                                lambda unaligned: _over_budget(budget, trace, unaligned), thumbs)
    bar.done(aligned=f"{sum(f.index in al.poses for f in frames)}/{len(frames)} key frames")
    return al, matcher


def _align_boxes(f: Frame, d: Detections, perception: Perception, trace: Trace) -> np.ndarray | None:
    """The boxes a key frame's matches are restricted to: every object the detector names in it, not only the
    question's (a few small targets give too few matches); the question's alone without `detect_all`."""
    boxes = [d.boxes] if len(d) else []
    if perception.detect_all is not None:
        with trace.stage("detect"):
            a = perception.detect_all(f)
        if len(a):
            boxes.append(a.boxes)
    return np.concatenate(boxes).astype(np.float32) if boxes else None


def _gravity(frames: list[Frame], poses_root: dict[int, np.ndarray], source: FrameSource, root: int,
             conf: PipelineConfig, trace: Trace) -> np.ndarray:
    """World-from-root transform [4, 4] (`semantic_map.gravity_from_frames`) with the source's gravity when
    `conf.gravity` allows it and the source knows it."""
    down = None
    if conf.gravity in ("auto", "source"):
        down = source.gravity_camera(root) if hasattr(source, "gravity_camera") else None
        if down is None and conf.gravity == "source":
            raise InputError("gravity=source but the source gives no gravity direction")
    return gravity_from_frames(frames, poses_root, down, conf.camera_height_m, conf.floor_fit_max_depth_m, trace)


def fuse_frames(frames: list[Frame], dets: dict[int, Detections], poses: dict[int, np.ndarray], fconf: FusionConfig,
                trace: Trace | None = None, lifted: dict[int, list[Observation]] | None = None
                ) -> tuple[list[Observation], list[ObjectInstance], list[np.ndarray]]:
    """Place every posed key frame's camera-frame observations in the world (`lifted`: perception's; a frame
    without them is lifted here) and fuse them into instances."""
    obs: list[Observation] = []
    lifted = lifted or {}

    def lift(f: Frame) -> list[Observation]:
        return place(lifted[f.index] if f.index in lifted else _lift(f, dets[f.index], fconf), poses[f.index])

    posed = [f for f in frames if f.index in poses]
    threads = 1 if all(f.index in lifted for f in posed) else worker_threads()  # placing is a matrix product
    with phase("fusion", len(frames), "key frame") as bar, ThreadPoolExecutor(threads) as ex:
        for got in ex.map(lift, posed):  # frames lift independently; in order
            obs += got
            bar.update()
        instances, clouds = fuse_observations(obs, fconf, trace)
        bar.note(instances=len(instances))
    return obs, instances, clouds


def _refine(instances: list[ObjectInstance], clouds: list[np.ndarray], obs: list[Observation],
            frames: list[Frame], poses: dict[int, np.ndarray], dets: dict[int, Detections], perception: Perception,
            fconf: FusionConfig, matcher: Any, conf: PipelineConfig, trace: Trace, budget: Any
            ) -> tuple[list[ObjectInstance], list[np.ndarray], int]:
    """Occlusion refinement (`semantic_map.refine`) unless off, impossible (no re-promptable segmenter) or the
    run is over its budget (said as a reduced plan)."""
    if conf.refine and budget is not None and budget.reduced and budget.remaining_ms() < 0:
        trace.event("reduced_plan", f"reduced plan: occlusion refinement skipped, because the run is "
                    f"{-budget.remaining_ms():.0f} ms over its {budget.budget_ms:.0f} ms budget", stage="refine")
    elif conf.refine and (perception.segment_points is not None or perception.segment_class is not None):
        with trace.stage("refine"):
            return refine(instances, obs, frames, poses, dets, perception, fconf, trace, matcher=matcher)
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
                det: _CachedDetector, names: list[str], source: FrameSource, perception: Perception,
                conf: PipelineConfig, fconf: FusionConfig, trace: Trace) -> tuple[Any, list[Any]]:
    """First-seen times from the search's detections, floor-standing extents, the room. Returns (room, cams)."""
    cams = [(float(f.t), poses[f.index]) for f in frames if f.index in poses]
    if conf.first_seen_from_search:
        key = tuple(names)
        first_seen_from_detections(instances, [(float(source.timestamps[i]), d.names)
                                               for (i, nm), d in det.cache.items() if nm == key], trace)
    if conf.floor_standing and not perception.depth_relative:
        with trace.stage("extent"):
            extend_to_floor(instances, frames, poses, conf.floor_standing, conf.floor_band_share, trace)
    with trace.stage("room"):
        room = room_extent(instances, cams, frames, poses, conf.room_trim_percent, fconf.max_depth_m)
    return room, cams


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
                 conf: PipelineConfig, trace: Trace, keyframes: int | None, budget: Any
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
    K = int(keyframes or getattr(budget, "keyframes", None) or conf.keyframes)
    if budget is not None:
        K = int(budget.allow_keyframes(K))
        trace.decide("budget.keyframes", K)
    return names, perception, K


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
    _say(trace, health.sample_frames(source))
    loaded0 = (getattr(source, "load_seconds", 0.0), getattr(source, "loads", 0))
    names, perception, K = _start_build(source, targets, cues, perception, conf, trace, keyframes, budget)
    dedup = _candidates(source, conf, trace, budget)  # its thumbnails serve the search and the bridges
    chosen, det, _, _cands = select(source, targets, cues, perception, conf, trace, keyframes=K, budget=budget,
                                    dedup=dedup)
    fconf = FusionConfig.merged(conf.fusion)
    frames, dets, lifted = _perceive(source, chosen, det, names, perception, conf, fconf, trace, budget)
    _say(trace, health.frame_notes([health.frame_health(f.rgb, f.depth) for f in frames]))
    al, matcher = _align(frames, dets, source, perception, conf, trace, budget, dedup.thumbs)
    with trace.stage("gravity"):
        W = _gravity(frames, al.poses, source, al.root, conf, trace)
    poses = {i: W @ T for i, T in al.poses.items()}
    with trace.stage("fusion"):
        obs, instances, clouds = fuse_frames(frames, dets, poses, fconf, trace, lifted)
    instances, clouds, recovered = _refine(instances, clouds, obs, frames, poses, dets, perception, fconf, matcher,
                                           conf, trace, budget)
    if budget is not None:
        budget.end_stage("alignment")
    _record_instances(instances, names, recovered, trace, dets, al.unaligned, det.scored())
    room, cams = _map_extras(instances, frames, poses, det, names, source, perception, conf, fconf, trace)
    _book_counters(trace, source, loaded0, matcher)
    smap = SemanticMap(instances, room, cams,
                       {"source": getattr(source, "name", "frames"), "built_from": "video", "keyframes": chosen,
                        "root": al.root, "unaligned": al.unaligned, "objects": names, "recovered": recovered})
    return MapBuild(smap, chosen, clouds, poses, W, list(al.unaligned), recovered,
                    bool(budget is not None and getattr(budget, "reduced", False)),
                    {"alignment": al.to_dict(), "dedup_kept": None})


# ----------------------------------------------------------------------------- perception from a bundle

PERCEPTION_ROLES = ("detector", "segmenter", "depth", "matcher", "embedder")


def _role_kwargs(profile: Any, role: str, bundle: Any = None, trace: Trace | None = None) -> dict[str, Any]:
    if profile is None:
        return {}
    out: dict[str, Any] = {"providers": profile.providers_for(role)}
    if getattr(profile, "intra_op_threads", None):
        out["threads"] = profile.intra_op_threads
    # the profile's precision, or the nearest the bundle has (said in the trace and the printed answer)
    variant = profile.variant_in(role, bundle, trace) if bundle is not None and profile.uses(role) else None
    if variant:
        out["variant"] = variant
    return out


def perception_from_bundle(bundle: Any, conf: PipelineConfig | dict | None = None, trace: Trace | None = None,
                           profile: Any = None, detector: str = "model") -> Perception:
    """Build the pipeline's `Perception` from a bundle's roles (adapters of `runtime.stages`).

    - detector (required unless `detector` is not "model"): `.detect(rgb, names)`;
    - segmenter (optional): a semantic segmenter (`kind == "semantic"`, e.g. DeepLab) gives masks as class pixels
      inside each box and, for refinement, the class mask inside the projected box; a promptable one (SAM-style)
      gives box masks and point-prompt masks. Without one: the box + dominant depth band is lifted (recorded);
    - depth (used when `conf.depth` is "model", or "auto" on a source without sensor depth): metric models as is,
      relative ones scaled by the adapter's documented prior, with Sim(3) alignment per edge (`depth_relative`);
    - matcher: `conf.matcher` "orb" | "sift" (OpenCV, no weights) or "model" (the bundle's matcher role);
    - embedder (optional): frame embeddings for the alignment tree's similarity (else colour histograms).
    Every choice is recorded in `trace.decisions["perception"]`.
    """
    from .bundle import load_bundle
    from .stages import load_role

    conf = conf if isinstance(conf, PipelineConfig) else PipelineConfig.merged(conf)
    trace = trace if trace is not None else Trace()
    b = load_bundle(bundle) if bundle is not None else None
    has = (lambda r: b is not None and b.has_role(r))
    desc: dict[str, Any] = {}

    def load(role: str) -> Any:
        m = load_role(b, role, trace=trace, **_role_kwargs(profile, role, b, trace))
        desc[role] = m.describe() if hasattr(m, "describe") else role
        return m

    if detector != "model":
        raise InputError(f"perception_from_bundle: `detector={detector}`; the oracle detector is evaluation-only "
                         f"(`mosaic ask --detector oracle` on a synthetic scene)", fields=("detector",))
    if not has("detector"):
        raise InputError(f"{'no `bundle` given' if b is None else str(b.manifest_path) + ': no `detector` role'}: "
                         f"the map needs a detector (export one with `mosaic export detector`), or use "
                         f"`detector=oracle` on a synthetic scene", fields=("bundle", "detector"))
    det = load("detector")
    p = Perception(detect=lambda frame, names: det.detect(frame.rgb, names))
    if getattr(det, "labels", None):
        labels = [x for x in dict.fromkeys(det.labels) if x and x.strip("?") and x.lower() != "n/a"]
        p.detect_all = lambda frame: det.detect(frame.rgb, labels)
    if has("segmenter"):
        seg = load("segmenter")
        if getattr(seg, "kind", "") == "semantic":
            p.segment = lambda frame, d: seg.segment(frame.rgb, d.boxes, d.names)
            p.segment_class = lambda frame, name: seg.class_mask(frame.rgb, name)
            desc["refinement"] = "semantic segmenter: class mask inside the projected box (takes no prompts)"
        else:
            p.segment = lambda frame, d: seg.segment(frame.rgb, d.boxes, d.names)
            p.segment_points = lambda frame, pts, name: _first_mask(seg.segment(
                frame.rgb, None, [name], points=np.concatenate([np.asarray(pts, np.float32).reshape(-1, 2),
                                                               np.ones((len(pts), 1), np.float32)], 1)[None]))
            desc["refinement"] = "promptable segmenter: point prompts from cross-frame matches"
    else:
        trace.event("degraded", "bundle has no segmenter: objects are lifted from their boxes (dominant depth "
                    "band), occlusion refinement is off", stage="perception")
        desc["segmenter"] = "none (box + depth band)"
    if conf.depth == "model":
        if not has("depth"):
            raise InputError("`depth=model` needs a bundle with a depth role (or use `depth=sensor`)", fields=("depth",))
        dm = load("depth")
        p.depth = lambda frame: dm.predict_metric(frame.rgb)[0]
        p.depth_relative = getattr(dm, "semantics", "metric_m") != "metric_m"
    elif conf.depth == "auto" and has("depth"):
        dm = load("depth")
        p.depth = lambda frame: dm.predict_metric(frame.rgb)[0]
        p.depth_relative = getattr(dm, "semantics", "metric_m") != "metric_m"
    if conf.matcher == "model":
        if not has("matcher"):
            raise InputError("`matcher=model` needs a bundle with a matcher role (or use `matcher=sift|orb`)",
                             fields=("matcher",))
        p.matcher = load("matcher")
    else:
        p.matcher = conf.matcher
        desc["matcher"] = f"opencv {conf.matcher}"
    if has("embedder"):
        emb = load("embedder")
        p.embed = emb.embed
    p.describe = desc
    trace.decide("perception", desc)
    return p


def _first_mask(masks: Any) -> np.ndarray | None:
    m = np.asarray(masks)
    if m.ndim == 3 and len(m):
        m = m[0]
    return m.astype(bool) if m.ndim == 2 and m.any() else None


def load_vlm(bundle: Any, trace: Trace | None = None, profile: Any = None) -> Any | None:
    """The bundle's VLM adapter (`.generate(images, prompt, max_new_tokens=...) -> str`) or None without one."""
    from .bundle import load_bundle

    if bundle is None:
        return None
    b = load_bundle(bundle)
    if not b.has_role("vlm"):
        return None
    from .stages import load_role

    vlm = load_role(b, "vlm", trace=trace, **_role_kwargs(profile, "vlm", b, trace))
    as_trace(trace).decide("vlm", vlm.describe() if hasattr(vlm, "describe") else "vlm")
    return vlm


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

    def to_dict(self) -> dict[str, Any]:
        return {"answer": self.answer.text, "status": self.answer.status, "value": self.answer.value,
                "unit": self.answer.unit,
                "explanation": self.answer.explanation, "qtype": self.answer.qtype, "missing": self.answer.missing,
                "method": self.method,
                "grounding": None if self.question is None else self.question.to_dict(),
                "instances": None if self.map is None else _instance_rows(self.map),
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
    from pathlib import Path

    if isinstance(source, (FrameSource, SemanticMap)):
        return source
    p = Path(source)
    if p.suffix.lower() == ".json":  # a map file: a folder, FIFO or loop of that name is said as such
        return SemanticMap.load(p)
    if p.is_dir() and (p / "map.json").is_file() and not any(p.glob("frame-*")) and not any(
            q.suffix.lower() in (".jpg", ".png", ".mp4") for q in p.iterdir()):
        return SemanticMap.load(p / "map.json")
    return open_frames(p, trace)


def open_frames(path: Any, trace: Trace | None = None) -> FrameSource:
    """`frames.open_source` as a stage ("open": trace and progress summary): a video's opening scan decodes
    every frame and removes redundant ones on the way, seconds the "dedup" stage then does not spend."""
    from .frames import open_source

    with as_trace(trace).stage("open"), phase("open", None, "frame") as bar:
        src = open_source(path, progress=bar.to)  # a video's scan moves the bar as it decodes
        bar.to(len(src))
        if getattr(src, "deduped_while_decoding", False):
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
    from .stages.detector import detectable_names

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
    from .stages.detector import undetectable_names

    cannot, n_labels, close = undetectable_names(bundle, pq.objects)
    if not cannot:
        return None
    ans = cannot_detect(pq, cannot, n_labels, close)
    trace.event("undetectable", ans.explanation, names=cannot, stage="grounding")
    trace.decide("answer", {k: v for k, v in ans.to_dict().items() if k != "parsed"})
    return ans


def ask(source: Any, question: str, options: list[str] | None = None, *, perception: Perception | None = None,
        bundle: Any = None, profile: Any = None, conf: PipelineConfig | dict | None = None,
        answerer: str = "auto", method: str = "mosaic", prompt_mode: str = "grid", vlm: Any = None,
        trace: Trace | None = None, keyframes: int | None = None, budget: Any = None,
        direct_frames: int = 8, render_image: bool = True) -> AskResult:
    """Answer a spatial question about a video, frame folder or saved map.

    source: a path (video, image/RGB-D folder, `map.json`), a `FrameSource` or a `SemanticMap`; options:
    multiple-choice options ("A. ...") or None. perception: injected models (default: built from `bundle`);
    answerer: "map" | "vlm" | "auto"; method: "mosaic" (map + visual prompt) or "direct" (the baseline: frames
    sampled uniformly straight to the VLM); prompt_mode: "grid" | "points" | "text"; render_image=False skips
    the map image when nothing will show it (no VLM, no file written: on a 10 k-object map it dominates).
    """
    trace = trace if trace is not None else Trace()
    conf = conf if isinstance(conf, PipelineConfig) else PipelineConfig.merged(conf)
    if method not in ("mosaic", "direct"):
        raise InputError(f"`method` must be mosaic or direct, got {method!r}", fields=("method",))
    if vlm is None and bundle is not None and answerer != "map":  # the map answerer neither grounds nor answers
        vlm = load_vlm(bundle, trace, profile)                     # with a VLM: not loaded, not run
    src = _open(source, trace)
    if method == "direct":
        return _ask_direct(src, question, options, vlm, trace, direct_frames)
    frames_for_grounding = None
    if vlm is not None and not isinstance(src, SemanticMap):
        n = min(conf.grounding_frames, len(src))
        frames_for_grounding = [src[int(i)].rgb for i in np.linspace(0, len(src) - 1, n).round().astype(int)]
    with trace.stage("grounding"):
        pq = ground(question, options, vlm, frames_for_grounding, trace)
    build = None
    if budget is None and profile is not None and not isinstance(src, SemanticMap):
        from .budget import controller_for

        budget = controller_for(profile, src, trace, bundle)  # the planner's own clip length and frame rate
    if isinstance(src, SemanticMap):
        smap = src
        trace.decide("map", {"source": "saved map", "instances": len(smap.instances)})
    else:
        if not pq.objects and not pq.whole_map:
            # nothing to look for: the reasoner's "not understood" reply (status unsupported, exit 0, trace kept)
            ans = MapReasoner(SemanticMap()).answer(question, options, parsed=pq)
            why = "the question was not understood" if pq.qtype is None else "the question names no object to look for"
            trace.event("degraded", f"{why}: {ans.explanation}", stage="grounding")
            trace.decide("answer", {k: v for k, v in ans.to_dict().items() if k != "parsed"})
            return AskResult(ans, None, trace, None, None, pq, "mosaic")
        cannot = _cannot_detect_first(pq, options, bundle if perception is None else None, trace)
        if cannot is not None:
            return AskResult(cannot, None, trace, None, None, pq, "mosaic")
        if perception is None:
            perception = perception_from_bundle(bundle, conf, trace, profile)
        build = build_map(src, _whole_map_targets(pq, bundle, trace), pq.cues, perception, conf, trace, keyframes,
                          budget)
        smap = build.map
    _say(trace, health.map_notes(smap))
    with trace.stage("prompt"):
        vp = _render_prompt(smap, build, prompt_mode, render_image or vlm is not None)
    with trace.stage("answer"):
        ans = answer_question(smap, question, options, answerer, vlm, vp, trace, pq)
        if ans.status == "not_found":  # missing because the detector could not look for them: say so
            und = {n for e in trace.events if e["kind"] == "undetectable" for n in e.get("names", [])}
            if cannot_see := [n for n in ans.missing if n in und]:
                ans = cannot_detect(pq, cannot_see)
    trace.decide("answer", {k: v for k, v in ans.to_dict().items() if k != "parsed"})
    return AskResult(ans, smap, trace, vp, build, pq, "mosaic")
