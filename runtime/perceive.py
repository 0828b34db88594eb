"""Perception per key frame (paper: segmentation + depth per key frame): the models a run uses (`Perception`,
from a bundle's roles or injected, e.g. the synthetic oracle), detections cached between the key-frame search and
the map, depth (sensor or model), masks (box-prompted where the segmenter has none), and each detection lifted to
camera-frame points as the key frame is perceived."""
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
from .infra.trace import StageLog, Trace, as_trace
from .map import FusionConfig, box_depth_mask, lift_detections
from .models import load_role
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


def box_prompted(masks: np.ndarray, depth: np.ndarray, d: Detections, min_share: float
                 ) -> tuple[np.ndarray, list[str]]:
    """Masks [N, H, W]: a detection the segmenter left (nearly) empty — a category it cannot segment (DeepLab has
    no cup) or a miss — gets a box-prompted mask (the depth-consistent pixels inside its box) instead of being
    dropped. Returns (masks, the names of the detections that got one)."""
    masks = np.array(masks, dtype=bool)
    prompted = []
    for j, (b, nm) in enumerate(zip(d.boxes, d.names)):
        area = max(1.0, float((b[2] - b[0]) * (b[3] - b[1])))
        if masks[j].sum() >= min_share * area:
            continue
        masks[j] = box_depth_mask(depth, b)
        prompted.append(nm)
    return masks, prompted


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
    """Perception per key frame: depth, detections (cached from the search), masks, and the detections' point
    clouds in the camera frame (`map.lift_detections`, on a worker thread while the next key frame's models run).
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
            d = det(i, names)
            if d.masks is None and perception.segment is not None and len(d):
                with log.stage("segment"):
                    masks, got = box_prompted(perception.segment(f, d), f.depth, d, conf.box_prompt_min_share)
                    d = dataclasses.replace(d, masks=masks)
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


PERCEPTION_ROLES = ("detector", "segmenter", "depth", "matcher", "embedder")


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
    if bundle is None:
        return None
    b = load_bundle(bundle)
    if not b.has_role("vlm"):
        return None
    vlm = load_role(b, "vlm", trace=trace, **role_kwargs(profile, "vlm", b, trace))
    as_trace(trace).decide("vlm", vlm.describe() if hasattr(vlm, "describe") else "vlm")
    return vlm
