"""Per-frame perception results shared by every detector/segmenter backend (models, oracle, tests), and how a key
frame's detections are made from the bundle's adapters (`keyframe_detector`, `merge_detections`,
`instance_class_mask`).

Kept separate from the adapters so that the pipeline, the key-frame search and the synthetic oracle exchange one
type without importing each other.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np


@dataclass
class Detections:
    """Objects found in one frame.

    boxes: [N, 4] float32 x0, y0, x1, y1 pixels; scores: [N] float32 in [0, 1]; names: N object names (the
    question's vocabulary, not the model's label); masks: [N, H, W] bool or None; instance_ids: [N] int64 or None
    (only the synthetic oracle knows them); undetectable: names the backend cannot detect at all (reported, never
    silently treated as "absent"); mask_from: N words saying where each mask came from (the role that made it,
    e.g. "instance_segmenter", "segmenter", "box" for the box-prompted depth mask) or None.
    """

    boxes: np.ndarray
    scores: np.ndarray
    names: list[str]
    masks: np.ndarray | None = None
    instance_ids: np.ndarray | None = None
    undetectable: list[str] = field(default_factory=list)
    mask_from: list[str] | None = None

    def __post_init__(self) -> None:
        self.boxes = np.asarray(self.boxes, dtype=np.float32).reshape(-1, 4)
        self.scores = np.asarray(self.scores, dtype=np.float32).reshape(-1)
        if not (len(self.boxes) == len(self.scores) == len(self.names)):
            raise ValueError("Detections: boxes, scores and names must have the same length")

    def __len__(self) -> int:
        return len(self.names)

    @classmethod
    def empty(cls, undetectable: list[str] | None = None) -> "Detections":
        return cls(np.zeros((0, 4), np.float32), np.zeros(0, np.float32), [], undetectable=list(undetectable or []))

    def best_score(self, name: str) -> float:
        """Highest confidence for `name` in this frame (0 if not seen)."""
        s = [float(sc) for n, sc in zip(self.names, self.scores) if n == name]
        return max(s) if s else 0.0

    def select(self, keep: np.ndarray) -> "Detections":
        keep = np.asarray(keep)
        idx = np.flatnonzero(keep) if keep.dtype == bool else keep
        return Detections(self.boxes[idx], self.scores[idx], [self.names[i] for i in idx],
                          None if self.masks is None else self.masks[idx],
                          None if self.instance_ids is None else self.instance_ids[idx], list(self.undetectable),
                          None if self.mask_from is None else [self.mask_from[i] for i in idx])


def box_iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Pairwise IoU of boxes a [N, 4] and b [M, 4] (x0 y0 x1 y1 pixels) -> [N, M]."""
    a, b = np.asarray(a, np.float64).reshape(-1, 4), np.asarray(b, np.float64).reshape(-1, 4)
    x0 = np.maximum(a[:, None, 0], b[None, :, 0])
    y0 = np.maximum(a[:, None, 1], b[None, :, 1])
    x1 = np.minimum(a[:, None, 2], b[None, :, 2])
    y1 = np.minimum(a[:, None, 3], b[None, :, 3])
    inter = np.clip(x1 - x0, 0, None) * np.clip(y1 - y0, 0, None)
    area_a = np.clip(a[:, 2] - a[:, 0], 0, None) * np.clip(a[:, 3] - a[:, 1], 0, None)
    area_b = np.clip(b[:, 2] - b[:, 0], 0, None) * np.clip(b[:, 3] - b[:, 1], 0, None)
    return inter / np.maximum(area_a[:, None] + area_b[None, :] - inter, 1e-9)


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
