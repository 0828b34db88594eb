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
from typing import Any, Callable, ClassVar, Mapping, Sequence

import numpy as np

from .config import StageConf
from .errors import InputError, MosaicError
from .frames import Frame, FrameSource
from .perception import Detections
from .progress import phase, start, ticking
from .semantic_map import (FusionConfig, ObjectInstance, Observation, Room, SemanticMap, expected_visible,
                           fit_floor_plane, fuse_observations, gravity_world_transform, lift_observations)
from .trace import Trace

DetectFn = Callable[[Frame, list[str]], Detections]
SegmentFn = Callable[[Frame, Detections], np.ndarray]          # -> masks [N, H, W] bool
PromptSegmentFn = Callable[[Frame, np.ndarray, str], np.ndarray | None]  # points [P, 2] -> mask [H, W] or None
DepthFn = Callable[[Frame], np.ndarray]                          # -> metric depth [H, W] float32


@dataclass
class PipelineConfig(StageConf):
    """One config for a run; stage configs are dicts merged into each stage's defaults
    (`PipelineConfig.merged(mapping_or_conf, **overrides)`, unknown keys are an error)."""

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
    cover_min_area: float = 0.02         # top-up coverage: an object counts as seen from this box area share on
    coverage_min_names: int = 4          # a map of this many object names or more (e.g. "everything") ...
    coverage_share: float = 0.5          # ... reserves this share of K for temporal coverage (`spread_keyframes`):
                                         # the search alone clusters on the frames with the most detections
    topup: bool = True                   # fewer than K passing: the search's `min_keyframes = K` top-up (recorded)
    whole_image_fallback: bool = True    # key frames unaligned with matches inside boxes: retry on whole images
    bridge_frames: int = 48              # at most this many extra frames to connect unaligned key frames (0 = off)
    bridge_gap_s: float = 0.25           # bridge frames are placed at most this far apart in time
    bridge_rounds: int = 2               # bridge, check, bridge again around edges the check rejected
    bridge_max_gap_s: float = 10.0       # ... and only across gaps up to this long (long chains drift)
    # floor-standing furniture seen from above (a table top, a chair back) reaches down to the floor when the key
    # frames saw its support: points under the footprint in >= `floor_band_share` of the 10 cm height bands
    # between the floor and the box, the lowest band included (`extend_to_floor`); () = off
    floor_standing: tuple[str, ...] = ("table", "chair", "sofa", "couch", "bed", "bench", "desk", "stool",
                                       "refrigerator", "toilet", "cabinet", "shelf", "bookshelf")
    floor_band_share: float = 0.6
    verify_depth: bool = True            # reject tree edges whose depth maps contradict each other (metric depth)
    max_free_space_violation: float = 0.02  # share of a frame's points seen in front of the other's surfaces
    camera_height_m: float = 1.5         # prior when no floor is found
    dedup: dict[str, Any] = field(default_factory=dict)
    keyframe: dict[str, Any] = field(default_factory=dict)
    # fewer inliers than alignment's default 20 are accepted because every tree edge is then checked against
    # the two depth maps (`verify_depth`), which catches the wrong ones a low inlier count lets through
    alignment: dict[str, Any] = field(default_factory=lambda: {"min_inliers": 12, "iterations": 1000})
    match: dict[str, Any] = field(default_factory=lambda: {"sift_contrast_threshold": 0.02})  # OpenCV matchers
    fusion: dict[str, Any] = field(default_factory=dict)

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
        if not 0 <= self.cover_min_area <= 1 or not 0 <= self.max_free_space_violation <= 1:
            raise InputError("pipeline config: cover_min_area and max_free_space_violation must be in [0, 1]")


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


def _stage(budget: Any, trace: Trace, name: str) -> Any:
    """A stage of the plan: timed in the trace and, under a budget, measured against its share when it ends (an
    overrun re-plans the stages after it: budget.BudgetController.end_stage)."""
    return budget.stage(name) if budget is not None else trace.stage(name)


def _candidates(source: FrameSource, conf: PipelineConfig, trace: Trace, budget: Any = None) -> list[int]:
    from .dedup import remove_redundant

    with _stage(budget, trace, "dedup"), phase("dedup", len(source), "frame") as bar:
        res = remove_redundant(ticking(source, bar), conf.dedup or None)
        bar.to(len(source))
        bar.note(candidates=len(res.kept))
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
        self.on_call: Callable[[], None] | None = None  # progress of the key-frame search

    def __call__(self, index: int, names: list[str]) -> Detections:
        key = (int(index), tuple(names))
        if key not in self.cache:
            with self.trace.stage("detect"):
                self.cache[key] = self.fn(self.source[int(index)], list(names))
            if self.on_call is not None:
                self.on_call()
        return self.cache[key]


def select(source: FrameSource, targets: Sequence[str], cues: Sequence[str], perception: Perception,
           conf: PipelineConfig, trace: Trace, detector: _CachedDetector | None = None,
           keyframes: int | None = None, budget: Any = None) -> tuple[list[int], _CachedDetector, Any, list[int]]:
    """Dedup + key-frame search. Returns (key frame indices in time order, the cached detector, the search
    result, the candidate frames kept by dedup). Under a budget the search spends the plan's scored frames as
    they stand after dedup (its candidate count, or a re-plan after a slow dedup)."""
    from .keyframes import KeyFrameConf, select_keyframes, uniform_keyframes

    cands = _candidates(source, conf, trace, budget)
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
        # not capped at the candidates: the search says when they run out before the budget
        kc["budget"] = int(max(np.ceil(frac * len(cands)), conf.min_scored_per_keyframe * K))
    K = K - reserve
    if conf.topup and conf.keyframe_method == "iterative":
        # fewer than K passing: the search tops up from the frames it scored (coverage first, then by score),
        # at least len/(4K) frames apart; recorded by the search
        kc.setdefault("min_keyframes", K)
        kc.setdefault("topup_gap", max(1, len(source) // (4 * K)))
        kc.setdefault("topup_relax", False)
        kc.setdefault("cover_min_area", conf.cover_min_area)
    kconf = KeyFrameConf.merged(kc)
    with _stage(budget, trace, "keyframes"), phase("keyframes", kc.get("budget", K), "frame") as bar:
        det.on_call = bar.update  # one tick per frame scored
        res = select_keyframes(conf.keyframe_method, cands, list(targets), list(cues), det,
                               lambda i: source[int(i)].rgb, kconf, trace,
                               prefetch=getattr(source, "prefetch", None), image_size=tuple(source.size))
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
        trace.event("keyframes", f"{len(set(targets) | set(cues))} object names: {reserve} of {K + reserve} key "
                    f"frames reserved for temporal coverage (largest gaps between the search's frames): {spread}",
                    stage="keyframes", coverage=spread)
        chosen = sorted(chosen + spread)
    if budget is not None and len(chosen) > budget.keyframes:  # the search overran and the plan was reduced
        chosen = _reduce_keyframes(sorted(chosen), int(budget.keyframes), budget, trace)
    trace.decide("keyframes", {**res.to_dict(), "chosen": chosen, "scores": None, "order": None,
                               "coverage_reserve": reserve})
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


def depth_consistency(fa: Frame, fb: Frame, T_ab: np.ndarray, stride: int = 8) -> tuple[float, float, float]:
    """How well frame b's depth agrees with frame a's under T_ab (b camera -> a camera).

    Returns (overlap: share of b's points that land on valid depth in a, consistent: share of those within
    5 cm + 3% of a's depth, violation: share of those lying clearly in FRONT of a's observed surface, i.e. in
    space a sees as empty). A wrong transform puts points in free space; a right one only at occlusion edges."""
    from .geometry import backproject, sample_depth, transform

    p, _ = backproject(fb.depth, fb.K, stride=stride)
    if len(p) == 0:
        return 0.0, 0.0, 0.0
    q = transform(T_ab, p)
    z = q[:, 2]
    zs = np.maximum(z, 1e-6)
    uv = np.stack([fa.K[0, 0] * q[:, 0] / zs + fa.K[0, 2], fa.K[1, 1] * q[:, 1] / zs + fa.K[1, 2]], 1)
    zo = sample_depth(fa.depth, uv)
    ins = (z > 0.1) & (zo > 0)
    n = max(int(ins.sum()), 1)
    cons = ins & (np.abs(z - zo) < 0.05 + 0.03 * zo)
    viol = ins & (z < zo - (0.10 + 0.05 * zo))
    return float(ins.mean()), float(cons.sum() / n), float(viol.sum() / n)


def verify_tree(al: Any, frames: dict[int, Frame], conf: PipelineConfig, trace: Trace) -> Any:
    """Check every tree edge with `depth_consistency` in both directions; a frame whose edge to its parent puts
    more than `max_free_space_violation` of the points into observed free space is detached with its subtree
    and re-attached through another verified pair (from the pairs alignment already tried) that passes the same
    check, if any; the rest become unaligned. Recorded in the trace; the rejected edges are kept in
    `al.rejected_edges` so that a later round does not use them again."""
    from collections import deque

    from .geometry import invert

    def ok(a: int, b: int, T_ab: np.ndarray) -> bool:
        if a not in frames or b not in frames:
            return True  # frames without kept depth are not checked
        v1 = depth_consistency(frames[a], frames[b], T_ab)[2]
        v2 = depth_consistency(frames[b], frames[a], invert(T_ab))[2]
        return max(v1, v2) <= conf.max_free_space_violation

    adj: dict[int, list[int]] = {}
    for a, b in al.edges:
        adj.setdefault(a, []).append(b)
        adj.setdefault(b, []).append(a)
    poses = dict(al.poses)
    parent = {al.root: None}
    order = deque([al.root])
    bad: list[tuple[int, int]] = list(getattr(al, "rejected_edges", []))
    while order:  # breadth-first from the root: a failing edge drops its whole subtree
        p = order.popleft()
        for c in adj.get(p, []):
            if c in parent or c not in poses:
                continue
            if ok(p, c, invert(poses[p]) @ poses[c]):
                parent[c] = p
                order.append(c)
            else:
                bad.append((p, c))
    kept = set(parent)
    dropped = [i for i in poses if i not in kept]
    al.rejected_edges = bad  # type: ignore[attr-defined]
    if not dropped:
        return al
    for i in dropped:
        poses.pop(i)
    reattached = []
    changed = True
    while changed:  # re-attach through other pairs alignment verified
        changed = False
        for (a, b), r in al.edge_stats.items():
            if not r.ok:
                continue
            for x, y, T in ((a, b, r.T_ab), (b, a, invert(r.T_ab))):  # T: pose of y in x's camera
                if x in poses and y not in poses and y in dropped and ok(x, y, T):
                    poses[y] = poses[x] @ T
                    reattached.append(y)
                    changed = True
    lost = [i for i in dropped if i not in poses]
    trace.event("degraded" if lost else "alignment",
                f"depth check rejected tree edge(s) {bad}: {len(dropped)} frame(s) detached, {len(reattached)} "
                f"re-attached through other verified pairs, {len(lost)} left unaligned", stage="alignment",
                rejected=[list(e) for e in bad], unaligned=lost)
    al.poses = poses
    al.unaligned = sorted(set(al.unaligned) | set(lost))
    return al


def attach_frames(al: Any, frames: dict[int, Frame], todo: Sequence[int], matcher: Any, conf: PipelineConfig,
                  tries: int = 4) -> list[int]:
    """Attach frames without a pose to the tree one edge at a time, metric depth only: each frame in `todo` is
    matched (whole image, cached features) to its `tries` nearest aligned frames in time, the first edge that
    passes RANSAC and the depth check (`max_free_space_violation` both ways) gives its pose; repeated while
    frames get attached (a new one can host the next). Costs <= tries pairs per frame, against a full
    re-alignment's all-pairs search. Mutates al (poses, edges, unaligned, edge_stats); returns the attached."""
    from .alignment import AlignConf, align_pair
    from .geometry import invert

    aconf = AlignConf.merged(conf.alignment or None)
    rng = np.random.default_rng(aconf.seed)
    tried = set(frozenset(e) for e in al.edge_stats) | set(frozenset(e) for e in getattr(al, "rejected_edges", []))
    attached: list[int] = []
    changed = True
    while changed:
        changed = False
        for u in [int(i) for i in todo if int(i) not in al.poses and int(i) in frames]:
            fu = frames[u]
            near = sorted((a for a in al.poses if a in frames and frozenset((a, u)) not in tried),
                          key=lambda a: (abs(float(frames[a].t) - float(fu.t)), a))[:tries]
            for a in near:
                tried.add(frozenset((a, u)))
                fa = frames[a]
                mt = matcher.match_keys(a, fa.rgb, u, fu.rgb, None, None)
                r = align_pair(mt, fa.depth, fa.K, fu.depth, fu.K, aconf, False, rng, getattr(fa, "dist", None),
                               getattr(fu, "dist", None))
                al.edge_stats[(a, u)] = r
                if not r.ok or max(depth_consistency(fa, fu, r.T_ab)[2],
                                   depth_consistency(fu, fa, invert(r.T_ab))[2]) > conf.max_free_space_violation:
                    continue
                al.poses[u] = al.poses[a] @ r.T_ab
                al.edges.append((a, u))
                attached.append(u)
                changed = True
                break
    al.unaligned = [i for i in al.unaligned if i not in al.poses]
    return attached


class _BlockPairs:
    """Matcher wrapper that returns no matches for the given frame pairs (edges the depth check rejected), so a
    new alignment round cannot choose them again; everything else goes to the wrapped matcher."""

    def __init__(self, matcher: Any, pairs: Sequence[tuple[int, int]]):
        self.m = matcher
        self.pairs = {frozenset(p) for p in pairs}

    def match_keys(self, k0: Any, rgb0: np.ndarray, k1: Any, rgb1: np.ndarray, boxes0: Any = None,
                   boxes1: Any = None) -> Any:
        from .matching import Matches

        if frozenset((k0, k1)) in self.pairs:
            return Matches.empty()
        if hasattr(self.m, "match_keys"):
            return self.m.match_keys(k0, rgb0, k1, rgb1, boxes0, boxes1)
        return self.m.match(rgb0, rgb1, boxes0, boxes1)

    def match(self, rgb0: np.ndarray, rgb1: np.ndarray, boxes0: Any = None, boxes1: Any = None) -> Any:
        return self.m.match(rgb0, rgb1, boxes0, boxes1)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.m, name)


def _bridge(al: Any, frames: list[Frame], boxes: dict[int, Any], cands: list[int], source: FrameSource,
            matcher: Any, perception: Perception, conf: PipelineConfig, trace: Trace,
            previous: Sequence[Frame] = ()) -> tuple[Any, list[Frame]]:
    """Key frames far apart in time often share no view, so the tree falls apart into components. Connect each
    unaligned key frame to its nearest aligned key frame in time through intermediate candidate frames (at
    most `bridge_gap_s` apart, `bridge_frames` in all, only across gaps up to `bridge_max_gap_s`; used for
    poses only, never detected) and align again. Key frames still unaligned afterwards stay unaligned
    (recorded). Returns (alignment, the bridge frames used)."""
    from .alignment import align_frames

    have = {f.index for f in frames}
    prev = {f.index: f for f in previous}  # bridges of an earlier round are kept (their depth is loaded)
    times = {i: float(source.timestamps[i]) for i in cands}
    extra: list[int] = []
    for u in sorted(al.unaligned, key=lambda u: min(abs(u - a) for a in al.poses)):
        a = min(al.poses, key=lambda j: abs(j - u))
        lo, hi = sorted((u, a))
        if abs(float(source.timestamps[hi]) - float(source.timestamps[lo])) > conf.bridge_max_gap_s:
            continue  # a long chain of bridges drifts: better unaligned (reported) than misplaced
        between = [c for c in cands if lo < c < hi and c not in have and c not in extra and c not in prev]
        last = float(source.timestamps[lo])
        for c in between:
            if times[c] - last >= conf.bridge_gap_s:
                extra.append(c)
                last = times[c]
        if len(extra) >= conf.bridge_frames:
            break
    extra = sorted(set(extra[:conf.bridge_frames]) | set(prev))
    if not set(extra) - set(prev):
        return al, []
    bf = []
    for i in extra:
        if i in prev:
            bf.append(prev[i])
            continue
        f = source[i]
        bf.append(dataclasses.replace(f, depth=_depth_for(f, conf, perception, trace)))
    with trace.stage("alignment"):
        al2 = align_frames(frames + bf, matcher, "mst", conf.alignment or None, None,
                           {**boxes, **{i: None for i in extra}}, with_scale=perception.depth_relative, trace=None)
    before = len(al.unaligned)
    al2.unaligned = [i for i in al2.unaligned if i in have]
    al2.rejected_edges = list(getattr(al, "rejected_edges", []))  # type: ignore[attr-defined]
    trace.event("degraded" if al2.unaligned else "alignment",
                f"{before} key frame(s) had no verified edge to the tree; {len(extra)} bridge frames between them "
                f"and their neighbours in time left {len(al2.unaligned)} unaligned", stage="alignment",
                bridges=extra, unaligned=al2.unaligned)
    if len(al2.poses) and sum(i in have for i in al2.poses) >= sum(i in have for i in al.poses):
        return al2, bf
    return al, []


def _over_budget(budget: Any, trace: Trace, unaligned: Sequence[int]) -> bool:
    """Past the latency budget: bridge rounds are skipped (said as a reduced plan)."""
    if budget is None or budget.remaining_ms() >= 0:
        return False
    trace.event("reduced_plan", f"reduced plan: bridge rounds skipped ({len(unaligned)} key frame(s) stay "
                f"unaligned), because the run is {-budget.remaining_ms():.0f} ms over its budget", stage="alignment")
    return True


def _align_rest(al: Any, frames: list[Frame], boxes: dict[int, Any], emb: Any, matcher: Any, source: FrameSource,
                perception: Perception, conf: PipelineConfig, trace: Trace,
                budget: Any = None) -> tuple[Any, list[Frame]]:
    """Relative depth (no depth check): the box-matched tree's unaligned frames get a whole-image re-alignment,
    then bridge rounds (`_bridge`) while they buy aligned key frames. Returns (alignment, bridge frames used)."""
    from .alignment import align_frames

    if al.unaligned and conf.whole_image_fallback:
        # too few matches inside the task objects' boxes (small or few objects): match whole images instead
        with trace.stage("alignment"):
            al2 = align_frames(frames, matcher, "mst", conf.alignment or None, emb, None,
                               with_scale=perception.depth_relative, trace=None)
        trace.event("fallback", f"alignment inside object boxes left {len(al.unaligned)} of {len(frames)} key frames "
                    f"unaligned; whole-image matching left {len(al2.unaligned)}", stage="alignment",
                    boxes_unaligned=list(al.unaligned), whole_unaligned=list(al2.unaligned))
        if len(al2.unaligned) < len(al.unaligned):
            al, boxes = al2, {i: None for i in boxes}
    used: list[Frame] = []
    keys = {f.index for f in frames}
    al.unaligned = [i for i in al.unaligned if i in keys]
    for _ in range(conf.bridge_rounds):
        if not al.unaligned or conf.bridge_frames <= 0 or _over_budget(budget, trace, al.unaligned):
            break
        blocked = _BlockPairs(matcher, getattr(al, "rejected_edges", []))  # never re-use a rejected edge
        # bridge frames come from the whole video (consecutive frames match best), not only dedup's candidates
        al_b, bridges = _bridge(al, frames, boxes, list(range(len(source))), source, blocked, perception, conf,
                                trace, used)
        if not bridges:
            break
        al_b.unaligned = [i for i in al_b.unaligned if i in keys]  # bridges are not counted: only key frames
        if len(al_b.unaligned) >= len(al.unaligned):
            # another round only pays where it buys aligned key frames: keep the better tree and stop
            trace.event("alignment", f"bridge round left {len(al_b.unaligned)} key frame(s) unaligned (before: "
                        f"{len(al.unaligned)}): kept the tree without it, no further rounds", stage="alignment")
            break
        al, used = al_b, bridges
    return al, used


def _align_rest_metric(al: Any, frames: list[Frame], matcher: Any, source: FrameSource, perception: Perception,
                       conf: PipelineConfig, trace: Trace, budget: Any = None) -> list[Frame]:
    """Metric depth after the box-matched tree: depth-check its edges, attach what it left out by whole-image
    edges, then bridge what is still out. Returns the bridge frames used."""
    with trace.stage("alignment.verify"):
        al = verify_tree(al, {f.index: f for f in frames}, conf, trace)
    keys = {f.index for f in frames}
    al.unaligned = [i for i in al.unaligned if i in keys]
    if al.unaligned and conf.whole_image_fallback:
        before = list(al.unaligned)
        with trace.stage("alignment"):
            got = attach_frames(al, {f.index: f for f in frames}, before, matcher, conf)
        trace.event("fallback", f"box-matched tree left {len(before)} of {len(frames)} key frames unaligned; "
                    f"whole-image edges attached {len(got)}, {len(al.unaligned)} left", stage="alignment",
                    boxes_unaligned=before, attached=got)
    if not al.unaligned or conf.bridge_frames <= 0 or conf.bridge_rounds <= 0 \
            or _over_budget(budget, trace, al.unaligned):
        return []
    with trace.stage("alignment"):
        return bridge_attach(al, frames, source, matcher, perception, conf, trace)


def bridge_attach(al: Any, frames: list[Frame], source: FrameSource, matcher: Any, perception: Perception,
                  conf: PipelineConfig, trace: Trace) -> list[Frame]:
    """Metric depth: connect each unaligned key frame through a chain of video frames (at least `bridge_gap_s`
    apart, `bridge_frames` in all) walked from its nearest aligned key frame in time towards it (`_bridge_chain`),
    one `attach_frames` edge per step, loading a frame only when the chain reaches it and stopping as soon as the
    key frame itself attaches: no re-alignment of the whole set, so a round that cannot buy an aligned frame costs
    only its failed steps. Gaps over `bridge_max_gap_s` are not bridged (long chains drift). Returns the bridge
    frames used (poses only, never detected); recorded."""
    pool = {f.index: f for f in frames}
    keys = set(pool)
    used: list[Frame] = []
    budget = conf.bridge_frames
    for u in sorted(al.unaligned, key=lambda u: min((abs(u - a) for a in al.poses if a in keys), default=0)):
        if budget <= 0 or u in al.poses:
            continue
        anchors = [a for a in al.poses if a in keys]
        if not anchors:
            break
        # the nearest aligned key frame on each side in time, the nearer first (a chain can fail on one side)
        sides = [max((j for j in anchors if j < u), default=None), min((j for j in anchors if j > u), default=None)]
        for a in sorted((j for j in sides if j is not None), key=lambda j: abs(j - u)):
            if u in al.poses or abs(float(source.timestamps[u]) - float(source.timestamps[a])) > conf.bridge_max_gap_s:
                continue
            budget, chain = _bridge_chain(al, pool, a, u, source, matcher, perception, conf, trace, budget)
            used += chain
    al.unaligned = [i for i in al.unaligned if i not in al.poses]
    trace.event("degraded" if al.unaligned else "alignment",
                f"bridging: {conf.bridge_frames - budget} video frame(s) tried, {len(used)} attached; "
                f"{len(al.unaligned)} key frame(s) left unaligned", stage="alignment",
                bridges=[f.index for f in used], unaligned=list(al.unaligned))
    return used


def _bridge_chain(al: Any, pool: dict[int, Frame], a: int, u: int, source: FrameSource, matcher: Any,
                  perception: Perception, conf: PipelineConfig, trace: Trace, budget: int) -> tuple[int, list[Frame]]:
    """Walk from aligned frame a towards unaligned key frame u: each step first tries u itself, then jumps
    to the frame halfway between the chain's end and u, halving the jump on a failed attach down to
    `bridge_gap_s`, then walking on at that spacing (slow camera motion costs few bridge frames, fast motion the
    dense chain). Returns (budget left, the bridge frames attached)."""
    ts = source.timestamps
    end, used = a, []
    while budget > 0 and u not in al.poses:
        if attach_frames(al, pool, [u], matcher, conf, tries=1):
            break
        gap = abs(float(ts[u]) - float(ts[end]))
        if gap < 2 * conf.bridge_gap_s:
            break  # no room for a bridge frame
        step, moved = (1 if u > end else -1), False
        # halve down to the shortest jump, then walk on at that spacing (a blurred frame is skipped)
        halving = [gap / 2 ** k for k in range(1, 32) if gap / 2 ** k >= conf.bridge_gap_s]
        walking = [conf.bridge_gap_s * k for k in range(2, int(gap / conf.bridge_gap_s))]
        for jump in halving + walking:
            if budget <= 0 or moved:
                break
            c = min(range(end + step, u, step), key=lambda i: abs(abs(float(ts[i]) - float(ts[end])) - jump))
            if c in pool:
                continue
            f = source[c]
            pool[c] = dataclasses.replace(f, depth=_depth_for(f, conf, perception, trace))
            budget -= 1
            if attach_frames(al, pool, [c], matcher, conf, tries=1):
                end, moved = c, True
                used.append(pool[c])
        if not moved:
            break  # no bridge frame attached at any jump: give up on u (reported by the caller)
    return budget, used


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
                  min_share: float = 0.02) -> np.ndarray:
    """Masks [N, H, W]: a detection the segmenter left (nearly) empty — a category it cannot segment (DeepLab has
    no cup) or a miss — gets a box-prompted mask (the depth-consistent pixels inside its box) instead of being
    dropped; recorded as degraded (once per name)."""
    from .semantic_map import box_depth_mask

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
    if offset is not None and len(P):
        # nothing lies below the floor: when a share of the seen points does, the plane found is a table or
        # counter top (the key frames did not see the floor); the floor is then at least as low as those points
        q = P @ down
        if np.mean(q > offset + 0.05) > 0.005:
            low = float(np.percentile(q, 99.8))
            trace.event("degraded", f"floor fit found a plane {low - offset:.2f} m above points the key frames saw "
                        f"(a table or counter top; the floor itself was not seen): floor put at the lowest seen "
                        f"points instead (objects cannot be below it; the floor height is a lower bound)",
                        stage="gravity", plane_m=offset, floor_m=low)
            offset = low
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
    chosen, det, _, cands_all = select(source, targets, cues, perception, conf, trace, keyframes=K, budget=budget)

    # perception per key frame
    frames: list[Frame] = []
    dets: dict[int, Detections] = {}
    bar = start("perception", len(chosen), "key frame")
    with _stage(budget, trace, "perception"):
        for i in chosen:
            if budget is not None and not budget.check_headroom(50.0):
                trace.event("reduced_plan", f"memory guard: stopped adding key frames at {len(frames)}",
                            stage="perception")
                break
            f = source[i]
            f = dataclasses.replace(f, depth=_depth_for(f, conf, perception, trace))
            d = det(i, names)
            if d.masks is None and perception.segment is not None and len(d):
                with trace.stage("segment"):
                    d = dataclasses.replace(d, masks=_box_prompted(perception.segment(f, d), f.depth, d, trace))
            dets[i] = d
            frames.append(f)
            bar.update()
    bar.done()
    if len(frames) < 2:
        raise MosaicError(f"only {len(frames)} key frame(s) available: need at least 2 to build a map")

    # alignment: matches restricted to object boxes (the paper's trick), MST over frame similarity
    from .alignment import _make_matcher, align_frames
    from .matching import FeatureMatcher

    emb = None
    if perception.embed is not None:
        with trace.stage("embed"):
            emb = np.stack([perception.embed(f.rgb) for f in frames])
    boxes = {f.index: (dets[f.index].boxes if len(dets[f.index]) else None) for f in frames}
    # one matcher: features are cached across the rounds below
    matcher = (FeatureMatcher(perception.matcher, conf.match or None) if isinstance(perception.matcher, str)
               else _make_matcher(perception.matcher))
    if budget is not None:  # one plan stage from matching to refinement (fusion is an alias of alignment)
        budget.start_stage("alignment")
    bar = start("alignment", unit="round")
    with trace.stage("alignment"):
        al = align_frames(frames, matcher, "mst", conf.alignment or None, emb, boxes,
                          with_scale=perception.depth_relative, trace=trace)
    check = conf.verify_depth and not perception.depth_relative
    keys = {f.index for f in frames}
    if check:  # metric depth: one edge at a time onto the verified tree (cheap; see attach_frames)
        used = _align_rest_metric(al, frames, matcher, source, perception, conf, trace, budget)
    else:
        al, used = _align_rest(al, frames, boxes, emb, matcher, source, perception, conf, trace, budget)
    al.unaligned = [i for i in al.unaligned if i in keys]
    if al.unaligned:
        trace.event("degraded", f"{len(al.unaligned)} of {len(frames)} key frames unaligned after alignment "
                    f"(left out of the map): {sorted(al.unaligned)}", stage="alignment", unaligned=sorted(al.unaligned))
    bar.done(aligned=f"{sum(f.index in al.poses for f in frames)}/{len(frames)} key frames")
    root = al.root
    with trace.stage("gravity"):
        W = _gravity(frames, al.poses, source, root, conf, trace)
    poses = {i: W @ T for i, T in al.poses.items()}

    # lift and fuse
    fconf = FusionConfig.merged(conf.fusion or None)
    obs: list[Observation] = []
    with trace.stage("fusion"), phase("fusion", len(frames), "key frame") as bar:
        for f in frames:
            if f.index not in poses:
                continue
            d = dets[f.index]
            obs += lift_observations(f.rgb.shape[:2], f.depth, f.K, poses[f.index], d.boxes, d.names, d.scores,
                                     d.masks, f.index, f.t, fconf, d.instance_ids)
            bar.update()
        instances, clouds = fuse_observations(obs, fconf)
        bar.note(instances=len(instances))
    recovered = 0
    if conf.refine and budget is not None and budget.reduced and budget.remaining_ms() < 0:
        trace.event("reduced_plan", f"reduced plan: occlusion refinement skipped, because the run is "
                    f"{-budget.remaining_ms():.0f} ms over its {budget.budget_ms:.0f} ms budget", stage="refine")
    elif conf.refine and (perception.segment_points is not None or perception.segment_class is not None):
        with trace.stage("refine"):
            instances, clouds, recovered = refine(instances, obs, frames, poses, dets, perception, fconf, trace,
                                                  matcher=matcher)
    if budget is not None:
        budget.end_stage("alignment")
    trace.decide("instances", {"count": len(instances), "recovered_by_refinement": recovered,
                               "by_name": {n: sum(o.name == n for o in instances) for n in names},
                               "list": [{"id": o.id, "name": o.name, "centre": np.round(o.center, 3).tolist(),
                                         "size": np.round(np.asarray(o.box.axes_lengths), 3).tolist(),
                                         "frames": o.frames, "score": round(float(o.score), 3)}
                                        for o in instances]})
    missing = [n for n in names if not any(o.name == n for o in instances)]
    if missing:
        trace.event("not_in_map", f"not found in the key frames: {', '.join(missing)}", names=missing)

    cams = [(float(f.t), poses[f.index]) for f in frames if f.index in poses]
    if conf.first_seen_from_search:
        _first_seen_from_search(instances, det, names, source, trace)
    if conf.floor_standing and not perception.depth_relative:
        with trace.stage("extent"):
            extend_to_floor(instances, frames, poses, conf, trace)
    with trace.stage("room"):
        room = _room(instances, cams, frames, poses)
    smap = SemanticMap(instances, room, cams,
                       {"source": getattr(source, "name", "frames"), "built_from": "video", "keyframes": chosen,
                        "root": root, "unaligned": al.unaligned, "objects": names, "recovered": recovered})
    return MapBuild(smap, chosen, clouds, poses, W, list(al.unaligned), recovered,
                    bool(budget is not None and getattr(budget, "reduced", False)),
                    {"alignment": al.to_dict(), "dedup_kept": None})


def floor_support(box: Any, P: np.ndarray, band_m: float = 0.10, min_points: int = 3) -> tuple[float, bool]:
    """Support under a gravity-aligned box: of the `band_m` height bands between the floor (z = 0) and the box
    bottom, the share holding >= min_points of P [N, 3] inside the box's footprint, and whether the lowest band
    does. Pure."""
    ax = np.asarray(box.axes, np.float64)
    up = int(np.argmax(np.abs(ax[:, 2])))
    L, c = np.asarray(box.axes_lengths, np.float64), np.asarray(box.centroid, np.float64)
    bottom = c[2] - L[up] / 2
    if bottom <= 0 or len(P) == 0:
        return 0.0, False
    side = [k for k in range(3) if k != up]
    local = (np.asarray(P, np.float64) - c) @ ax.T
    z = P[np.all(np.abs(local[:, side]) <= L[side] / 2, axis=1), 2]
    n = max(1, int(np.ceil(bottom / band_m - 1e-9)))
    hist = np.histogram(z[(z >= 0) & (z < bottom)], bins=np.linspace(0.0, bottom, n + 1))[0]
    return float(np.mean(hist >= min_points)), bool(hist[0] >= min_points)


def extend_to_floor(instances: list[ObjectInstance], frames: Sequence[Frame], poses: dict[int, np.ndarray],
                    conf: PipelineConfig, trace: Trace, band_m: float = 0.10, stride: int = 8) -> list[int]:
    """A floor-standing object (`conf.floor_standing`) whose fused box stops above the floor (z = 0) — the top
    of a table seen from above, a chair's back over the table edge — gets its box extended down to the floor
    when the key frames' depth shows its support: points inside its footprint in at least `floor_band_share`
    of the `band_m` height bands between the floor and the box bottom, the lowest band included. Open space
    seen under it (no points) leaves the box as fused. Mutates the boxes; recorded (extended and kept, with
    the band share). Returns the ids extended."""
    from .geometry import OrientedBox, backproject, transform

    todo = [o for o in instances if o.name in conf.floor_standing]
    if not todo:
        return []
    pts = [transform(poses[f.index], backproject(f.depth, f.K, stride=stride)[0]) for f in frames
           if f.index in poses and f.depth is not None]
    P = np.concatenate(pts) if pts else np.zeros((0, 3))
    P = P[P[:, 2] > 0.5 * band_m / 2]  # the floor's own points do not count as support
    done, kept = [], {}
    for o in todo:
        ax = np.asarray(o.box.axes, np.float64)
        up = int(np.argmax(np.abs(ax[:, 2])))
        if abs(ax[up, 2]) < 0.99:
            continue  # not a gravity-aligned box
        L = np.asarray(o.box.axes_lengths, np.float64)
        c = np.asarray(o.box.centroid, np.float64)
        if c[2] - L[up] / 2 < band_m:
            continue
        share, lowest = floor_support(o.box, P, band_m)
        if share >= conf.floor_band_share and lowest:
            top = c[2] + L[up] / 2
            L2, c2 = L.copy(), c.copy()
            L2[up], c2[2] = top, top / 2
            o.box = OrientedBox(c2, L2, ax)
            done.append(o.id)
        else:
            kept[o.id] = round(share, 2)
    trace.event("extent", f"{len(done)} floor-standing object(s) extended to the floor (support seen under "
                f"them): {done}; {len(kept)} kept as fused (support share per id): {kept}", stage="extent",
                extended=done, kept=kept)
    return done


def _room(instances: list[ObjectInstance], cams: list[tuple[float, np.ndarray]], frames: Sequence[Frame] = (),
          poses: dict[int, np.ndarray] | None = None, trim: float = 0.5) -> Room | None:
    """Room extent of a built map: the floor-projected hull of everything the aligned key frames' depth saw
    (walls, floor, furniture), plus the object footprints and the camera track. Points beyond the `trim`
    percentile along any of 36 directions are dropped first (stray depth through doorways and windows). A
    convex hull: an L-shaped room is over-estimated, a room whose walls were never seen under-estimated."""
    from .geometry import backproject, convex_hull_2d, transform

    pts = [o.box.corners()[:, :2] for o in instances] + [T[None, :2, 3] for _, T in cams]
    seen = []
    for f in frames:
        if poses is not None and f.index in poses and f.depth is not None:
            p, _ = backproject(f.depth, f.K, stride=12)
            seen.append(transform(poses[f.index], p[(p[:, 2] > 0.1) & (p[:, 2] < 8.0)])[:, :2])
    source = "objects_and_camera_hull"
    if seen:
        S = np.concatenate(seen)
        if len(S) > 100:
            ang = np.linspace(0, np.pi, 36, endpoint=False)
            D = np.stack([np.cos(ang), np.sin(ang)], 1)
            proj = S @ D.T
            lo, hi = np.percentile(proj, trim, 0), np.percentile(proj, 100 - trim, 0)
            S = S[np.all((proj >= lo) & (proj <= hi), 1)]
            pts.append(S)
            source = "observed_depth_hull"
    if not pts:
        return None
    P = np.concatenate(pts)
    top = max([float(o.box.aabb()[1][2]) for o in instances] + [2.4])
    return Room(convex_hull_2d(_hull_candidates(P)), 0.0, top, source)


def _hull_candidates(P: np.ndarray, directions: int = 16) -> np.ndarray:
    """Points [N, 2] that may be convex-hull vertices (Akl-Toussaint): the extreme points in `directions`
    directions span a convex polygon; points clearly inside it (by more than 1e-9 of the extent) are dropped.
    The hull is unchanged, the Python monotone chain just sees far fewer points."""
    if len(P) < 64:
        return P
    ang = np.linspace(0, 2 * np.pi, directions, endpoint=False)
    D = np.stack([np.cos(ang), np.sin(ang)], 1)
    idx = np.unique(np.argmax(P @ D.T, 0))              # extreme points, ordered by direction below
    V = P[idx]
    c = V.mean(0)
    V = V[np.argsort(np.arctan2(V[:, 1] - c[1], V[:, 0] - c[0]))]
    if len(V) < 3:
        return P
    eps = 1e-9 * float(np.ptp(P, 0).max() + 1.0)
    inside = np.ones(len(P), bool)
    for a, b in zip(V, np.roll(V, -1, 0)):              # counter-clockwise: inside = left of every edge
        e = b - a
        nrm = float(np.hypot(*e))
        if nrm == 0:
            continue
        inside &= (e[0] * (P[:, 1] - a[1]) - e[1] * (P[:, 0] - a[0])) / nrm > eps
    return P[~inside]


def _first_seen_from_search(instances: list[ObjectInstance], det: "_CachedDetector", names: list[str],
                            source: FrameSource, trace: Trace) -> None:
    """The key-frame search ran the detector on many more frames than the key frames: a category detected
    earlier than any of its instances' key frames was first seen then. The earliest instance of the category
    takes that time (appearance-order questions are about categories)."""
    key = tuple(names)
    first: dict[str, float] = {}
    for (i, nm), d in det.cache.items():
        if nm != key:
            continue
        t = float(source.timestamps[i])
        for n in set(d.names):
            first[n] = min(first.get(n, np.inf), t)
    changed = 0
    for n, t in first.items():
        inst = [o for o in instances if o.name == n and o.first_seen is not None]
        if inst:
            o = min(inst, key=lambda o: o.first_seen)
            if t < o.first_seen:
                o.first_seen, changed = t, changed + 1
    if changed:
        trace.decide("first_seen_from_search", changed)


# ----------------------------------------------------------------------------- occlusion refinement


def refine(instances: list[ObjectInstance], obs: list[Observation], frames: list[Frame],
           poses: dict[int, np.ndarray], dets: dict[int, Detections], perception: Perception,
           conf: FusionConfig, trace: Trace, conf_views: int = 2, matcher: Any = None
           ) -> tuple[list[ObjectInstance], list[np.ndarray], int]:
    """Paper, occlusion refinement: project every instance into each key frame; where it should be visible but
    was not segmented, re-prompt the segmenter — with point prompts from cross-frame matches inside its other
    views (promptable segmenter), or the class mask inside the projected box (semantic segmenter) — and add what
    it recovers. Returns the re-fused instances, their clouds and how many instances gained a view."""
    from .alignment import _make_matcher

    matcher = matcher if matcher is not None else _make_matcher(perception.matcher)
    by_index = {f.index: f for f in frames}
    n_pts = {}  # (instance name, frame) -> points of its observation there: prompts come from the best views
    for o in obs:
        n_pts[(o.name, o.frame)] = max(n_pts.get((o.name, o.frame), 0), len(o.points))
    found: dict[tuple[int, int], list[Observation]] = {}  # (instance position, frame position) -> recovered
    # frame-major: a semantic segmenter caches its class map for the last image, so all instances of one frame
    # share one segmenter run; the result is put back in instance-major order below (same fusion input)
    for fi, f in enumerate(frames):
        if f.index not in poses:
            continue
        for ii, inst in enumerate(instances):
            if f.index in set(inst.frames):
                continue
            box = expected_visible(inst, f.K, poses[f.index], (f.rgb.shape[1], f.rgb.shape[0]), f.depth)
            if box is None:
                continue
            mask = None
            if perception.segment_points is not None:
                pts = []
                views = sorted(inst.frames, key=lambda g: -n_pts.get((inst.name, g), 0))[:conf_views]
                for g_idx in views:  # matches between a view that has it and this frame, inside both boxes
                    g = by_index.get(g_idx)
                    if g is None:
                        continue
                    gb = [o.box2d for o in obs if o.frame == g_idx and o.name == inst.name]
                    if not gb:
                        continue
                    if hasattr(matcher, "match_keys"):  # cached features per frame
                        m = matcher.match_keys(g.index, g.rgb, f.index, f.rgb, np.stack(gb), box[None])
                    else:
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
                    found.setdefault((ii, fi), []).append(ob)
    new_obs = [ob for key in sorted(found) for ob in found[key]]
    gained = {instances[ii].id for ii, _ in found}
    if not new_obs:
        return instances, [np.zeros((0, 3))] * len(instances), 0
    trace.event("refinement", f"occlusion refinement recovered {len(new_obs)} view(s) of {len(gained)} "
                f"instance(s)", views=len(new_obs), instances=len(gained))
    inst2, clouds = fuse_observations(obs + new_obs, conf)
    return inst2, clouds, len(gained)


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
    if trace is not None:
        trace.decide("vlm", vlm.describe() if hasattr(vlm, "describe") else "vlm")
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
                "explanation": self.answer.explanation, "qtype": self.answer.qtype, "missing": self.answer.missing,
                "method": self.method,
                "grounding": None if self.question is None else self.question.to_dict(),
                "instances": None if self.map is None else [
                    {"id": o.id, "name": o.name, "centre": np.round(o.center, 3).tolist(),
                     "size": np.round(np.asarray(o.box.axes_lengths), 3).tolist(), "first_seen": o.first_seen}
                    for o in self.map.instances],
                "keyframes": None if self.build is None else self.build.keyframes}


def _open(source: Any) -> FrameSource | SemanticMap:
    from pathlib import Path

    if isinstance(source, (FrameSource, SemanticMap)):
        return source
    p = Path(source)
    if p.is_file() and p.suffix.lower() == ".json":
        return SemanticMap.load(p)
    if p.is_dir() and (p / "map.json").is_file() and not any(p.glob("frame-*")) and not any(
            q.suffix.lower() in (".jpg", ".png", ".mp4") for q in p.iterdir()):
        return SemanticMap.load(p / "map.json")
    from .frames import open_source

    return open_source(p)


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
    from . import prompt as vprompt
    from .answer import answer_question, answer_with_vlm
    from .grounding import ground

    trace = trace if trace is not None else Trace()
    conf = conf if isinstance(conf, PipelineConfig) else PipelineConfig.merged(conf)
    if method not in ("mosaic", "direct"):
        raise InputError(f"`method` must be mosaic or direct, got {method!r}", fields=("method",))
    if vlm is None and bundle is not None:
        vlm = load_vlm(bundle, trace, profile)
    src = _open(source)
    if method == "direct":
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

    frames_for_grounding = None
    if vlm is not None and not isinstance(src, SemanticMap):
        n = min(4, len(src))
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
        if not pq.objects and pq.qtype not in ("room_size_estimation", "object_list"):
            from .answer import MapReasoner

            # nothing to look for: the reasoner's "not understood" reply (status unsupported, exit 0, trace kept)
            ans = MapReasoner(SemanticMap()).answer(question, options, parsed=pq)
            trace.event("degraded", f"the question names no object to look for: {ans.explanation}", stage="grounding")
            trace.decide("answer", {k: v for k, v in ans.to_dict().items() if k != "parsed"})
            return AskResult(ans, None, trace, None, None, pq, "mosaic")
        if perception is None:
            perception = perception_from_bundle(bundle, conf, trace, profile)
        build = build_map(src, pq.targets, pq.cues, perception, conf, trace, keyframes, budget)
        smap = build.map
    vp = None
    with trace.stage("prompt"):
        pts = ids = None
        if prompt_mode == "points" and build is not None and build.clouds:
            pts = np.concatenate([c for c in build.clouds if len(c)] or [np.zeros((0, 3))])
            ids = np.concatenate([np.full(len(c), o.id) for o, c in zip(smap.instances, build.clouds)
                                  if len(c)] or [np.zeros(0, int)])
        if render_image or vlm is not None:
            vp = vprompt.render(smap, {"mode": prompt_mode}, pts, ids)
    with trace.stage("answer"):
        ans = answer_question(smap, question, options, answerer, vlm, vp, trace, pq)
    trace.decide("answer", {k: v for k, v in ans.to_dict().items() if k != "parsed"})
    return AskResult(ans, smap, trace, vp, build, pq, "mosaic")
