"""Perception per key frame (paper: segmentation + depth per key frame): the models a run uses (`Perception`,
from a bundle's roles or injected, e.g. the synthetic oracle), detections cached between the key-frame search and
the map, a key frame's candidate detections (`keyframe_detector`: the detector's down to its low score, merged with
an instance segmenter's, `merge_detections`), depth (sensor or model), one mask per detection (the instance
segmenter's, else the segmenter's, else box-prompted: `keyframe_masks`), and each detection lifted to camera-frame
points as the key frame is perceived."""
from __future__ import annotations

import dataclasses
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping

import numpy as np

from .conf import PipelineConfig
from .frames import FrameSource
from .infra.bundle import load_bundle
from .infra.errors import InputError, MosaicError
from .infra.progress import start
from .geometry import box_iou
from .infra.trace import StageLog, Trace, as_trace
from .map import FusionConfig, box_depth_mask, lift_detections
from .models import load_role
from .models.detector import DetectorConf
from .types import Budget, Detections, Frame, Observation

DetectFn = Callable[[Frame, list[str]], Detections]
SegmentFn = Callable[[Frame, Detections], np.ndarray]          # -> masks [N, H, W] bool
PromptSegmentFn = Callable[[Frame, np.ndarray, str], np.ndarray | None]  # points [P, 2] -> mask [H, W] or None
DepthFn = Callable[[Frame], np.ndarray]                          # -> metric depth [H, W] float32


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
    # key-frame perception: candidate detections down to the detector's low score, with instance masks where an
    # instance segmenter gives them (the map verifies candidates across views); None = `detect`'s detections
    detect_keyframe: DetectFn | None = None
    # the detector's confidence threshold (the bundle manifest's `score_threshold`, one per role): a lone view at
    # or above it may stand in the map (`map.verify`, unless `VerifyConf.confident` is set); default: DetectorConf's
    confident_score: float = DetectorConf.score_threshold


def colour_frame(source: FrameSource, i: int) -> Frame:
    """Frame i as a colour-only reader needs it (`FrameSource.colour`; a plain sequence of frames: the frame)."""
    return source.colour(i) if hasattr(source, "colour") else source[i]


class CachedDetector:
    """Detections per (frame, names): the search and the map reuse the same detector calls (timed as "detect" in
    `log`, which the pipeline records)."""

    def __init__(self, source: FrameSource, detect: DetectFn, log: StageLog | None = None):
        self.source, self.fn, self.log = source, detect, log if log is not None else StageLog()
        self.cache: dict[tuple[int, tuple[str, ...]], Detections] = {}
        self.on_call: Callable[[], None] | None = None  # progress of the key-frame search

    def __call__(self, index: int, names: list[str]) -> Detections:
        key = (int(index), tuple(names))
        if key not in self.cache:
            with self.log.stage("detect"):  # detection reads colour only: no depth decoded for it
                self.cache[key] = self.fn(colour_frame(self.source, int(index)), list(names))
            if self.on_call is not None:
                self.on_call()
        return self.cache[key]

    def scored(self) -> dict[int, set[str]]:
        """Every frame the detector ran on -> the names it detected there (of those it was asked for)."""
        out: dict[int, set[str]] = {}
        for (i, _names), d in self.cache.items():
            out.setdefault(i, set()).update(d.names)
        return out

    def undetectable(self) -> list[str]:
        """The names the detector said it cannot detect at all, in any call (`Detections.undetectable`)."""
        return sorted({n for d in self.cache.values() for n in d.undetectable})


def depth_for(frame: Frame, depth: str, perception: Perception, log: StageLog) -> np.ndarray:
    """The depth [H, W] the run uses for a frame: `depth` "sensor", "model" or "auto" (sensor when it has it)."""
    use = depth
    if use == "auto":
        use = "sensor" if frame.depth is not None else "model"
    if use == "sensor":
        if frame.depth is None:
            raise InputError(f"frame {frame.index} has no sensor depth; use depth=model with a bundle depth model")
        return frame.depth
    if perception.depth is None:
        raise InputError("depth=model needs a depth model (bundle role `depth`) or choose depth=sensor")
    with log.stage("depth"):
        return perception.depth(frame)


def with_depth(depth: str, perception: Perception, log: StageLog) -> Callable[[Frame], Frame]:
    """A source frame -> the same frame with the depth the run uses (sensor or the depth model)."""
    return lambda f: dataclasses.replace(f, depth=depth_for(f, depth, perception, log))


def box_prompted(masks: np.ndarray, depth: np.ndarray, d: Detections, min_share: float,
                 src: list[str] | None = None) -> tuple[np.ndarray, list[str]]:
    """Masks [N, H, W]: a detection the segmenter left (nearly) empty — a category it cannot segment (DeepLab has
    no cup) or a miss — gets a box-prompted mask (the depth-consistent pixels inside its box) instead of being
    dropped (`src`, when given, says "box" for it). Returns (masks, the names of the detections that got one)."""
    masks = np.array(masks, dtype=bool)
    prompted = []
    for j, (b, nm) in enumerate(zip(d.boxes, d.names)):
        area = max(1.0, float((b[2] - b[0]) * (b[3] - b[1])))
        if masks[j].sum() >= min_share * area:
            continue
        masks[j] = box_depth_mask(depth, b)
        if src is not None:
            src[j] = "box"
        prompted.append(nm)
    return masks, prompted


def keyframe_masks(f: Frame, d: Detections, perception: Perception, min_share: float, log: StageLog
                   ) -> tuple[Detections, list[str]]:
    """A key frame's detections with one mask each: the instance segmenter's where it gave one, else the
    segmenter's (a semantic one: class pixels in the box), else the box-prompted depth mask (`box_prompted`);
    `mask_from` says which, per detection. Without any segmenter and without instance masks: unchanged (fusion
    lifts the box's depth band). Returns (detections, the names of those that got a box-prompted mask)."""
    if not len(d) or (d.masks is None and perception.segment is None):
        return d, []
    have = np.zeros(len(d), bool) if d.masks is None else np.array(
        [m.any() and src not in ("none", "box") for m, src in zip(d.masks, d.mask_from or ["?"] * len(d))])
    masks = np.zeros((len(d),) + f.rgb.shape[:2], bool) if d.masks is None else np.array(d.masks, bool)
    src = list(d.mask_from or ["instance_segmenter" if d.masks is not None else "none"] * len(d))
    if perception.segment is not None and not have.all():
        rest = np.flatnonzero(~have)
        with log.stage("segment"):
            masks[rest] = perception.segment(f, d.select(rest))
        for j in rest:
            src[j] = "segmenter"
    with log.stage("segment"):
        masks, prompted = box_prompted(masks, f.depth, d, min_share, src)
    return dataclasses.replace(d, masks=masks, mask_from=src), prompted


@dataclass
class Perceived:
    """What perception gave the key frames: the frames with the run's depth, their detections (with masks), the
    detections lifted to camera-frame points per key frame, and the log of the stage."""

    frames: list[Frame]
    dets: dict[int, Detections]
    lifted: dict[int, list[Observation]]
    log: StageLog


def perceive_keyframes(source: FrameSource, chosen: list[int], det: CachedDetector, names: list[str],
                       perception: Perception, conf: PipelineConfig, fconf: FusionConfig,
                       budget: Budget | None = None, scan_counts: Mapping[str, int] | None = None) -> Perceived:
    """Perception per key frame: depth, detections (`Perception.detect_keyframe`'s candidates, else cached from the
    search), masks (`keyframe_masks`), and the detections' point clouds in the camera frame (`map.lift_detections`, on a worker thread while the next key frame's models run).
    The memory guard may stop adding key frames (logged). Needs 2 frames at least (`scan_counts`, the scan's, say
    why when the input shows one view)."""
    log = StageLog()
    frames: list[Frame] = []
    dets: dict[int, Detections] = {}
    lifting: dict[int, Any] = {}
    prompted: dict[str, int] = {}
    bar = start("perception", len(chosen), "key frame")
    with ThreadPoolExecutor(1) as lifter:
        for i in chosen:
            if budget is not None and not budget.check_headroom(conf.memory_headroom_mb):
                log.event("reduced_plan", f"memory guard: stopped adding key frames at {len(frames)}",
                          stage="perception")
                break
            f = with_depth(conf.depth, perception, log)(source[i])
            if perception.detect_keyframe is not None:
                with log.stage("detect"):
                    d = perception.detect_keyframe(colour_frame(source, i), list(names))
            else:
                d = det(i, names)
            d, got = keyframe_masks(f, d, perception, conf.box_prompt_min_share, log)
            for nm in got:
                if nm not in prompted:
                    log.event("degraded", f"segmenter gave no mask for {nm!r}: box-prompted mask "
                              f"(depth-consistent pixels inside the box) used instead", stage="segment", name=nm)
                prompted[nm] = prompted.get(nm, 0) + 1
            dets[i] = d
            frames.append(f)
            lifting[i] = lifter.submit(lift_detections, f, d, fconf)
            bar.update()
        lifted = {i: fut.result() for i, fut in lifting.items()}
    bar.done()
    if prompted:
        log.decide("segment.box_prompted", prompted)
    if len(frames) < 2:
        c = scan_counts or {}
        why = (f" (the input has {c['input']} frame(s); give a video or images that move around the room)"
               if c.get("input", 2) < 2 else
               f" (redundant-frame removal kept {c['kept']} of the {c['input']} frames: the input shows one view; "
               f"give a video or images that move around the room)" if c.get("kept", 2) < 2 else "")
        name = getattr(source, "name", None)
        raise MosaicError(f"{name + ': ' if name else ''}only {len(frames)} key frame(s) available: need at least 2 "
                          f"to build a map{why}")
    return Perceived(frames, dets, lifted, log)


def match_boxes(f: Frame, d: Detections, perception: Perception, log: StageLog) -> np.ndarray | None:
    """The boxes a key frame's matches are restricted to: every object the detector names in it, not only the
    question's (a few small targets give too few matches); the question's alone without `detect_all`."""
    boxes = [d.boxes] if len(d) else []
    if perception.detect_all is not None:
        with log.stage("detect"):
            a = perception.detect_all(f)
        if len(a):
            boxes.append(a.boxes)
    return np.concatenate(boxes).astype(np.float32) if boxes else None


PERCEPTION_ROLES = ("detector", "instance_segmenter", "segmenter", "depth", "matcher", "embedder")


def role_kwargs(profile: Any, role: str, bundle: Any = None, trace: Trace | None = None) -> dict[str, Any]:
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
    """Build the pipeline's `Perception` from a bundle's roles (adapters of `runtime.models`).

    - detector (required unless `detector` is not "model"): `.detect(rgb, names)`;
    - instance_segmenter (optional, unless `conf.keyframe_detections` is "detector"): detections with one mask
      each, merged with the detector's at key frames (`keyframe_detector`); its masks first in refinement;
    - segmenter (optional): a semantic segmenter (`kind == "semantic"`, e.g. DeepLab) gives masks as class pixels
      inside each box and, for refinement, the class mask inside the projected box; a promptable one (SAM-style)
      gives box masks and point-prompt masks. Without one: the box + dominant depth band is lifted (recorded);
    - depth (used when `conf.depth` is "model", or "auto" on a source without sensor depth): metric models as is,
      relative ones scaled by the adapter's documented prior, with Sim(3) alignment per edge (`depth_relative`);
    - matcher: `conf.matcher` "orb" | "sift" (OpenCV, no weights) or "model" (the bundle's matcher role);
    - embedder (optional): frame embeddings for the alignment tree's similarity (else colour histograms).
    Every choice is recorded in `trace.decisions["perception"]`.
    """
    conf = conf if isinstance(conf, PipelineConfig) else PipelineConfig.merged(conf)
    trace = trace if trace is not None else Trace()
    b = load_bundle(bundle) if bundle is not None else None
    has = (lambda r: b is not None and b.has_role(r))
    desc: dict[str, Any] = {}

    def load(role: str) -> Any:
        m = load_role(b, role, trace=trace, **role_kwargs(profile, role, b, trace))
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
    p = Perception(detect=lambda frame, names: det.detect(frame.rgb, names), confident_score=det.score_threshold)
    if getattr(det, "labels", None):
        labels = [x for x in dict.fromkeys(det.labels) if x and x.strip("?") and x.lower() != "n/a"]
        p.detect_all = lambda frame: det.detect(frame.rgb, labels)
    inst = load("instance_segmenter") if has("instance_segmenter") and conf.keyframe_detections != "detector" \
        else None
    p.detect_keyframe = keyframe_detector(det, inst, desc, conf.keyframe_detections)
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
    elif inst is None:
        trace.event("degraded", "bundle has no segmenter: objects are lifted from their boxes (dominant depth "
                    "band), occlusion refinement is off", stage="perception")
        desc["segmenter"] = "none (box + depth band)"
    if inst is not None and getattr(inst, "kind", "") == "instance":  # refinement asks its masks first
        p.segment_class = instance_class_mask(inst, p.segment_class, desc)
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


def merge_detections(instances: Detections, boxes: Detections, iou: float = 0.5) -> Detections:
    """One frame's detections from an instance segmenter (`instances`, with masks) and a box detector (`boxes`,
    without) as one set: a pair of the same name whose boxes overlap (IoU >= `iou`, greedy from the highest IoU)
    is one object -- the segmenter's box and mask, the higher score; every other detection of both is kept (the
    detector's with an empty mask, `mask_from` "none", for the pipeline's fallbacks). Instances first, then the
    detector's unmatched ones in their order. Pure."""
    H, W = (instances.masks.shape[1:] if instances.masks is not None and instances.masks.ndim == 3 else (0, 0))
    n, m = len(instances), len(boxes)
    if m == 0:
        return instances
    scores = instances.scores.copy()
    matched = np.zeros(m, bool)
    if n:
        ov = box_iou(instances.boxes, boxes.boxes)
        same = np.array([[a == b for b in boxes.names] for a in instances.names])
        ov = np.where(same, ov, 0.0)
        used = np.zeros(n, bool)
        for flat in np.argsort(-ov, axis=None, kind="stable"):
            i, j = divmod(int(flat), m)
            if ov[i, j] < iou:
                break
            if used[i] or matched[j]:
                continue
            used[i] = matched[j] = True
            scores[i] = max(scores[i], boxes.scores[j])
    rest = np.flatnonzero(~matched)
    masks = None
    if instances.masks is not None:
        masks = np.concatenate([instances.masks, np.zeros((len(rest), H, W), bool)])
    mask_from = list(instances.mask_from or ["instance_segmenter"] * n) + ["none"] * len(rest)
    return Detections(np.concatenate([instances.boxes, boxes.boxes[rest]]),
                      np.concatenate([scores, boxes.scores[rest]]),
                      list(instances.names) + [boxes.names[j] for j in rest], masks, None,
                      sorted(set(instances.undetectable) & set(boxes.undetectable)), mask_from)


def keyframe_detector(det: Any, inst: Any, desc: dict[str, Any], mode: str = "merged"
                      ) -> Callable[[Any, list[str]], Detections] | None:
    """Key-frame detections (frames: anything with `.rgb`). Without an instance segmenter: the detector's candidates
    down to its `candidate_threshold` (None when it keeps none: the key frames reuse the search's detections). With
    one, by `mode`: "merged" -- its detections with one mask each, candidates down to its `candidate_threshold`,
    plus the detector's confident boxes (>= `score_threshold`) it missed (`merge_detections`: a same-name pair that
    overlaps is one object with the segmenter's mask); "merged_candidates" -- the detector's candidates too (boxes
    without masks at low scores: weaker evidence); "instance_segmenter" -- its own alone (one model, one pass)."""
    cand = getattr(getattr(det, "conf", None), "candidate_threshold", None)
    if inst is None:
        if cand is None:
            return None
        desc["keyframe_detections"] = f"detector candidates down to score {cand}, verified across views"
        return lambda frame, names: det.detect(frame.rgb, names, min_score=det.conf.floor)
    masks = f"instance segmenter (a mask per detection) candidates down to score {inst.conf.floor}"
    if mode == "instance_segmenter":
        desc["keyframe_detections"] = f"{masks}, alone; verified across views"
        return lambda frame, names: inst.detect(frame.rgb, names, min_score=inst.conf.floor, masks=True)
    floor = det.conf.floor if mode == "merged_candidates" else det.conf.score_threshold
    desc["keyframe_detections"] = f"{masks}, with the detector's boxes >= {floor}; verified across views"

    def detect(frame: Any, names: list[str]) -> Detections:
        seg = inst.detect(frame.rgb, names, min_score=inst.conf.floor, masks=True)
        return merge_detections(seg, det.detect(frame.rgb, names, min_score=floor))

    return detect


def instance_class_mask(inst: Any, semantic: Callable[[Any, str], np.ndarray | None] | None, desc: dict[str, Any]
                        ) -> Callable[[Any, str], np.ndarray | None]:
    """Occlusion refinement's class mask: the instance segmenter's masks of the name (every candidate) first, then
    the semantic segmenter's (`semantic`, may be None) where it has none. frame: anything with `.rgb`."""
    def class_mask(frame: Any, name: str) -> np.ndarray | None:
        m = inst.class_mask(frame.rgb, name)
        if (m is None or not m.any()) and semantic is not None:
            return semantic(frame, name)
        return m

    desc["refinement"] = ("instance segmenter: its masks of the name inside the projected box"
                          + (", else the semantic segmenter's class mask" if semantic is not None else ""))
    return class_mask


def _first_mask(masks: Any) -> np.ndarray | None:
    m = np.asarray(masks)
    if m.ndim == 3 and len(m):
        m = m[0]
    return m.astype(bool) if m.ndim == 2 and m.any() else None


def load_vlm(bundle: Any, trace: Trace | None = None, profile: Any = None) -> Any | None:
    """The bundle's VLM adapter (`.generate(images, prompt, max_new_tokens=...) -> str`) or None without one."""
    if bundle is None:
        return None
    b = load_bundle(bundle)
    if not b.has_role("vlm"):
        return None
    vlm = load_role(b, "vlm", trace=trace, **role_kwargs(profile, "vlm", b, trace))
    as_trace(trace).decide("vlm", vlm.describe() if hasattr(vlm, "describe") else "vlm")
    return vlm
