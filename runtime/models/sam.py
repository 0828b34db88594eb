"""SAM / SlimSAM promptable segmenter adapter over the encoder + prompt-decoder graphs of export/hf_sam.py.

`segment(rgb, boxes, names, points=None) -> masks [N, H, W] bool`: the image encoder runs once per frame
(the embedding of the last frame is cached), the decoder once per call for all N prompts. A prompt is a box
(two labelled corners), optionally refined with points; with no boxes each name gets the whole image as its
box. Of SAM's three candidate masks the one with the highest predicted IoU is returned.
"""
from __future__ import annotations

import hashlib
from typing import Any, Sequence

import numpy as np

from ..infra.errors import InputError
from . import RoleModel


def sam_preprocess(rgb: np.ndarray, size: int, pp: dict[str, Any] | None = None) -> tuple[np.ndarray, float]:
    """rgb [H, W, 3] uint8 -> ([1, 3, S, S] float32, scale): longest side resized to S, normalised with SAM's
    pixel mean/std (0..255 units), zero-padded bottom/right (as SamProcessor)."""
    import cv2

    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
        raise InputError(f"expected an RGB image [H, W, 3] uint8, got {rgb.shape} {rgb.dtype}")
    pp = pp or {}
    mean = np.asarray(pp.get("mean", [123.675, 116.28, 103.53]), np.float32)
    std = np.asarray(pp.get("std", [58.395, 57.12, 57.375]), np.float32)
    h, w = rgb.shape[:2]
    scale = size / max(h, w)
    nh, nw = max(1, int(round(h * scale))), max(1, int(round(w * scale)))
    img = cv2.resize(rgb, (nw, nh), interpolation=cv2.INTER_LINEAR).astype(np.float32)
    x = np.zeros((size, size, 3), np.float32)
    x[:nh, :nw] = (img * float(pp.get("scale", 1.0)) - mean) / std
    return np.ascontiguousarray(x.transpose(2, 0, 1)[None]), scale


class SamSegmenter(RoleModel):
    """Promptable segmenter: boxes and/or points -> one mask per prompt."""

    role = "segmenter"

    def __init__(self, spec, sessions, trace):
        super().__init__(spec, sessions, trace)
        self.size = int(spec.config.get("input_size") or spec.preprocessing["size"][0])
        self.mask_threshold = float(spec.config.get("mask_threshold", 0.0))
        self._cache: tuple[str, np.ndarray, float] | None = None
        self.undetectable: list[str] = []

    def _key(self, rgb: np.ndarray) -> str:
        return hashlib.sha1(np.ascontiguousarray(rgb[::7, ::7]).tobytes() + str(rgb.shape).encode()).hexdigest()

    def embed(self, rgb: np.ndarray) -> tuple[np.ndarray, float]:
        """Image embedding [1, C, h, w] of a frame (cached for the last frame) and the resize scale."""
        key = self._key(rgb)
        if self._cache is None or self._cache[0] != key:
            x, scale = sam_preprocess(rgb, self.size, self.spec.preprocessing)
            with self.trace.stage("segmenter.encoder"):
                emb = self.session("encoder").run({"pixel_values": x})[0]
            self._cache = (key, np.asarray(emb, np.float32), scale)
        return self._cache[1], self._cache[2]

    def predict(self, rgb: np.ndarray, coords: np.ndarray, labels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """coords [P, N, 2] original-image pixels, labels [P, N] (1 fg, 0 bg, 2/3 box corners, -1 pad) ->
        (mask logits [P, H, W] float32 of the best candidate, predicted IoU [P])."""
        import cv2

        emb, scale = self.embed(rgb)
        feeds = {"image_embeddings": emb, "point_coords": (coords * scale).astype(np.float32),
                 "point_labels": labels.astype(np.float32)}
        with self.trace.stage("segmenter.decoder"):
            masks, iou = self.session("decoder").run(feeds)
        best = np.argmax(iou, axis=1)
        low = masks[np.arange(len(best)), best]                                  # [P, 4h, 4w]
        h, w = rgb.shape[:2]
        nh, nw = int(round(h * scale)), int(round(w * scale))
        out = np.empty((len(low), h, w), np.float32)
        for i, m in enumerate(low):
            up = cv2.resize(m, (self.size, self.size), interpolation=cv2.INTER_LINEAR)[:nh, :nw]
            out[i] = cv2.resize(up, (w, h), interpolation=cv2.INTER_LINEAR)
        return out, iou[np.arange(len(best)), best]

    def segment(self, rgb: np.ndarray, boxes: np.ndarray | None, names: Sequence[str],
                points: np.ndarray | None = None) -> np.ndarray:
        """boxes [N, 4] x0 y0 x1 y1 pixels (None = whole image per name); points: None, [N, 2] (one foreground
        point per prompt) or [N, M, 3] (x, y, label 1/0) -> masks [N, H, W] bool."""
        h, w = rgb.shape[:2]
        n = len(names) if boxes is None else len(boxes)
        if n == 0:
            return np.zeros((0, h, w), bool)
        parts_c, parts_l = [], []
        if boxes is not None or points is None:
            b = np.tile([[0, 0, w - 1, h - 1]], (n, 1)) if boxes is None else np.asarray(boxes, np.float32)
            parts_c.append(b.reshape(n, 2, 2))
            parts_l.append(np.tile([[2.0, 3.0]], (n, 1)))
        if points is not None:
            p = np.asarray(points, np.float32)
            if p.ndim == 2:
                p = np.concatenate([p[:, None, :], np.ones((len(p), 1, 1), np.float32)], axis=2)
            if p.ndim != 3 or p.shape[0] != n or p.shape[2] != 3:
                raise InputError(f"segmenter points: expected [N, 2] or [N, M, 3] with N={n}, got {p.shape}")
            parts_c.append(p[:, :, :2])
            parts_l.append(p[:, :, 2])
        coords = np.concatenate(parts_c, axis=1).astype(np.float32)
        labels = np.concatenate(parts_l, axis=1).astype(np.float32)
        logits, _ = self.predict(rgb, coords, labels)
        return logits > self.mask_threshold
