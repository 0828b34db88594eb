"""Segmenter adapters: boxes (and, for promptable models, points) -> masks.

`SemanticSegmenter` wraps a per-pixel classifier (DeepLabv3 on PASCAL VOC here). It runs once per frame
(class maps of the last 64 images cached at the model's resolution: refinement asks one class mask per object and
key frame after perception segmented every key frame, so the cache must outlast K) and answers
`segment(rgb, boxes, names)` with, for each box, the pixels inside the box whose class is the name's class (through the same synonym table as the detector). It IGNORES point prompts
(a `points` argument is accepted for interface compatibility and recorded once in the trace as "degraded"):
refinement with it can only intersect boxes with class pixels; it cannot split two touching instances of one
class nor segment classes outside its label list (those boxes get an empty mask and the name is reported).
Promptable SAM-style models (`sam.py`, H6) implement the same `segment` with an image encoder run once per frame
and a prompt decoder per box/point.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from . import ImageLRU, RoleModel, preprocess_image
from .detector import map_names


class SemanticSegmenter(RoleModel):
    """Per-pixel logits [1, h, w, C] (NHWC) or [1, C, h, w] (config.logits_layout) over semantics.labels."""

    role = "segmenter"

    def __init__(self, spec, sessions, trace):
        super().__init__(spec, sessions, trace)
        self.labels: list[str] = list(spec.semantics["labels"])
        self.kind = "semantic"
        self.logits_layout = spec.config.get("logits_layout", "NHWC")
        self._input = self.session().input_names[0]
        # refinement revisits every key frame after perception: with 16 maps a K = 32 run segmented 27 key
        # frames twice. The maps are kept at the model's output size (257 x 257 uint8: 66 kB, 4 MB for 64)
        self._cache = ImageLRU(64)
        self.undetectable: list[str] = []

    def classes(self, rgb: np.ndarray) -> np.ndarray:
        """rgb [H, W, 3] uint8 -> class id per pixel [H, W] (the model's argmax, nearest-resized to the image)."""
        import cv2

        lab = self._cache.cached(rgb, self._run)
        return cv2.resize(lab, (rgb.shape[1], rgb.shape[0]), interpolation=cv2.INTER_NEAREST)

    def _run(self, rgb: np.ndarray) -> np.ndarray:
        """The class map at the model's output size [h, w] (uint8 below 256 labels, else int32)."""
        x = preprocess_image(rgb, self.spec.preprocessing)
        with self._stage("segmenter"):
            logits = self.session().run({self._input: x})[0][0]
        if self.logits_layout == "NCHW":
            logits = logits.transpose(1, 2, 0)
        return logits.argmax(-1).astype(np.uint8 if logits.shape[-1] <= 256 else np.int32)

    def class_mask(self, rgb: np.ndarray, name: str) -> np.ndarray | None:
        """[H, W] bool pixels of `name`'s class (None when the label list has no such class)."""
        with self._overhead("segmenter"):
            mapping, missing = map_names([name], self.labels)
            if missing:
                return None
            return np.isin(self.classes(rgb), mapping[name])

    def segment(self, rgb: np.ndarray, boxes: np.ndarray | None, names: Sequence[str],
                points: np.ndarray | None = None) -> np.ndarray:
        """boxes [N, 4] x0 y0 x1 y1 (None = whole image per name), names: N names -> masks [N, H, W] bool.
        `points` are ignored (semantic model). Names outside the label list get empty masks and are listed in
        `.undetectable` after the call."""
        with self._overhead("segmenter"):
            return self._segment(rgb, boxes, names, points)

    def _segment(self, rgb: np.ndarray, boxes: np.ndarray | None, names: Sequence[str],
                 points: np.ndarray | None) -> np.ndarray:
        H, W = rgb.shape[:2]
        if points is not None and not getattr(self, "_points_noted", False):
            self._points_noted = True
            self.trace.event("degraded", f"{self.name}: semantic segmenter ignores point prompts", stage="segmenter")
        n = len(names)
        bxs = np.tile(np.array([0, 0, W, H], np.float32), (n, 1)) if boxes is None else \
            np.asarray(boxes, np.float32).reshape(-1, 4)
        masks = np.zeros((n, H, W), bool)
        mapping, missing = map_names(list(dict.fromkeys(names)), self.labels)
        self.undetectable = missing
        if not mapping:
            return masks
        lab = self.classes(rgb)
        for i, (nm, b) in enumerate(zip(names, bxs)):
            if nm not in mapping:
                continue
            x0, y0 = int(max(0, np.floor(b[0]))), int(max(0, np.floor(b[1])))
            x1, y1 = int(min(W, np.ceil(b[2]))), int(min(H, np.ceil(b[3])))
            if x1 > x0 and y1 > y0:
                masks[i, y0:y1, x0:x1] = np.isin(lab[y0:y1, x0:x1], mapping[nm])
        return masks
