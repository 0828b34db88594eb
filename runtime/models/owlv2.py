"""OWLv2 open-vocabulary detector adapter over the image + text graphs of export/hf_owlv2.py.

`detect(rgb, names) -> Detections`: one image pass per frame; one text pass per NEW name (text embeddings are
cached per name for the adapter's lifetime). Scores are the class head's sigmoid((c . t + shift) * scale) per
patch; per name, patches above `score_threshold` go through NMS (`nms_iou`) and the best `max_per_name` are
kept. Boxes come back in the original image's pixels (the model saw the image padded to a square).
Names are never "undetectable" for an open vocabulary; an empty name is an InputError.
"""
from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from ..infra.errors import BundleError, InputError
from ..types import Detections
from . import RoleModel


def owl_preprocess(rgb: np.ndarray, pp: dict[str, Any]) -> tuple[np.ndarray, float]:
    """rgb [H, W, 3] uint8 -> ([1, 3, S, S] float32, side of the padded square in original pixels).
    OWLv2's processor pads bottom/right to a square with grey (0.5 after scaling), then resizes."""
    import cv2

    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
        raise InputError(f"expected an RGB image [H, W, 3] uint8, got {rgb.shape} {rgb.dtype}")
    h, w = rgb.shape[:2]
    side = max(h, w)
    x = np.full((side, side, 3), float(pp.get("pad_value", 0.5)), np.float32)
    x[:h, :w] = rgb.astype(np.float32) * float(pp.get("scale", 1 / 255))
    S = int(pp["size"][0])
    x = cv2.resize(x, (S, S), interpolation=cv2.INTER_AREA if side > S else cv2.INTER_LINEAR)
    x = (x - np.asarray(pp["mean"], np.float32)) / np.asarray(pp["std"], np.float32)
    return np.ascontiguousarray(x.transpose(2, 0, 1)[None]), float(side)


def nms(boxes: np.ndarray, scores: np.ndarray, iou: float) -> np.ndarray:
    """Greedy NMS. boxes [N, 4] x0 y0 x1 y1, scores [N] -> kept indices (descending score)."""
    order = np.argsort(-scores)
    keep = []
    while order.size:
        i = order[0]
        keep.append(i)
        if order.size == 1:
            break
        rest = order[1:]
        x0 = np.maximum(boxes[i, 0], boxes[rest, 0])
        y0 = np.maximum(boxes[i, 1], boxes[rest, 1])
        x1 = np.minimum(boxes[i, 2], boxes[rest, 2])
        y1 = np.minimum(boxes[i, 3], boxes[rest, 3])
        inter = np.clip(x1 - x0, 0, None) * np.clip(y1 - y0, 0, None)
        area = lambda b: (b[..., 2] - b[..., 0]) * (b[..., 3] - b[..., 1])  # noqa: E731
        ious = inter / np.maximum(area(boxes[i]) + area(boxes[rest]) - inter, 1e-9)
        order = rest[ious <= iou]
    return np.asarray(keep, np.int64)


class OwlV2Detector(RoleModel):
    """Open-vocabulary detector: `.detect(rgb [H, W, 3] uint8, names) -> perception.Detections`."""

    role = "detector"

    def __init__(self, spec, sessions, trace):
        super().__init__(spec, sessions, trace)
        from tokenizers import Tokenizer

        cfg = spec.config
        tok_ref = spec.meta.get("tokenizer") or {}
        path = spec.bundle.file(tok_ref, "roles.detector.tokenizer")
        self.tokenizer = Tokenizer.from_file(str(path))
        self.text_length = int(cfg.get("text_length", 16))
        self.start_id = self.tokenizer.token_to_id(cfg.get("start_token", "<|startoftext|>"))
        self.end_id = self.tokenizer.token_to_id(cfg.get("end_token", "<|endoftext|>"))
        if self.start_id is None or self.end_id is None:
            raise BundleError(f"{path}: start/end tokens of roles.detector.config are not in the tokenizer")
        self.pad_id = int(cfg.get("pad_id", 0))
        self.template = str(cfg.get("query_template", "{}"))
        self.score_threshold = float(cfg.get("score_threshold", 0.1))  # the bundle's; a lone view stands from it
        self.nms_iou = float(cfg.get("nms_iou", 0.3))
        self.max_per_name = int(cfg.get("max_per_name", 10))
        self._text_cache: dict[str, np.ndarray] = {}

    def tokenize(self, names: Sequence[str]) -> tuple[np.ndarray, np.ndarray]:
        """names -> input_ids, attention_mask [Q, L] int64 (start, tokens, end, pad; truncated to L)."""
        L = self.text_length
        ids = np.full((len(names), L), self.pad_id, np.int64)
        mask = np.zeros((len(names), L), np.int64)
        for i, n in enumerate(names):
            toks = self.tokenizer.encode(self.template.format(n), add_special_tokens=False).ids[:L - 2]
            row = [self.start_id, *toks, self.end_id]
            ids[i, :len(row)] = row
            mask[i, :len(row)] = 1
        return ids, mask

    def text_embeddings(self, names: Sequence[str]) -> np.ndarray:
        """[Q, D] unit-norm text embeddings; only names not seen before run the text graph."""
        new = [n for n in dict.fromkeys(names) if n not in self._text_cache]
        if new:
            ids, mask = self.tokenize(new)
            with self.trace.stage("detector.text"):
                emb = np.asarray(self.session("text").run({"input_ids": ids, "attention_mask": mask})[0], np.float32)
            self._text_cache.update(zip(new, emb))
        return np.stack([self._text_cache[n] for n in names]) if names else np.zeros((0, 1), np.float32)

    def scores(self, rgb: np.ndarray, names: Sequence[str]) -> tuple[np.ndarray, np.ndarray]:
        """-> (scores [P, Q] in [0, 1], boxes [P, 4] x0 y0 x1 y1 in original pixels)."""
        x, side = owl_preprocess(rgb, self.spec.preprocessing)
        with self.trace.stage("detector.image"):
            cls, shift, scale, boxes, _ = self.session("image").run({"pixel_values": x})
        t = self.text_embeddings(names)
        logits = (cls[0] @ t.T + shift[0]) * scale[0]
        sc = 1.0 / (1.0 + np.exp(-logits))
        cx, cy, bw, bh = (boxes[0][:, i] * side for i in range(4))
        xyxy = np.stack([cx - bw / 2, cy - bh / 2, cx + bw / 2, cy + bh / 2], axis=1)
        h, w = rgb.shape[:2]
        xyxy = np.clip(xyxy, 0, [w, h, w, h]).astype(np.float32)
        return sc.astype(np.float32), xyxy

    def detect(self, rgb: np.ndarray, names: Sequence[str]) -> Detections:
        """rgb [H, W, 3] uint8, names: object names -> Detections (boxes in pixels, scores, names)."""
        names = [str(n).strip() for n in names]
        if any(not n for n in names):
            raise InputError("detector: empty object name")
        if not names:
            return Detections.empty()
        sc, boxes = self.scores(rgb, names)
        out_b, out_s, out_n = [], [], []
        for q, name in enumerate(names):
            cand = np.flatnonzero(sc[:, q] >= self.score_threshold)
            if cand.size == 0:
                continue
            keep = cand[nms(boxes[cand], sc[cand, q], self.nms_iou)][: self.max_per_name]
            out_b.append(boxes[keep])
            out_s.append(sc[keep, q])
            out_n += [name] * len(keep)
        if not out_n:
            return Detections.empty()
        return Detections(np.concatenate(out_b), np.concatenate(out_s), out_n)
