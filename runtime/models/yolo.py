"""YOLO-family closed-set detectors over onnxruntime (numpy + OpenCV only).

- `YoloxDetector` (arch `yolox`): a YOLOX graph without decoding or NMS: input NCHW, output [1, A, 5 + C] per
  anchor (4 raw box values, objectness, C class probabilities, sigmoids applied), anchors on the stride 8 / 16 / 32
  grids in row-major order. Decoded here: cx = (o0 + gx) s, cy = (o1 + gy) s, w = exp(o2) s, h = exp(o3) s;
  score = objectness x best class probability; per-class NMS at `conf.nms_iou`.
- `UltralyticsDetector` (arch `ultralytics_e2e`): an Ultralytics export with NMS inside the graph (`nms=True`):
  detections [1, N, 6 + M] (x1, y1, x2, y2, score, class, M mask coefficients; empty rows score 0) and, for a
  `-seg` model, prototypes [1, h, w, M] or [1, M, h, w]. Boxes are fractions of the input (`config.box_units`
  "normalised", a TFLite conversion) or input pixels ("pixels", a PyTorch ONNX export). Instance masks:
  sigmoid(coef . prototypes) > 0.5 inside the box, sampled straight into the frame (`instance_masks`). It serves
  the `detector` role (boxes) and the `instance_segmenter` role (boxes + one mask per detection).

Both read a letterboxed input (`letterbox`): the frame resized by r = min(H / h, W / w), pasted at the top-left
(YOLOX) or centred (Ultralytics) on an H x W canvas of `pad_value`; boxes are mapped back by the same transform.
"""
from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from ..geometry import box_iou
from ..types import Detections
from . import preprocess_image
from .detector import LabelDetector, map_names


def letterbox(rgb: np.ndarray, pp: dict[str, Any]) -> tuple[np.ndarray, float, tuple[float, float]]:
    """rgb [H, W, 3] uint8 -> (model input [1, h, w, 3] or [1, 3, h, w] as `preprocess_image` makes it, scale r,
    (pad_x, pad_y) in input pixels): frame pixel (u, v) lies at (u r + pad_x, v r + pad_y) on the input.
    pp: the manifest's preprocessing with `size` [h, w], `letterbox` "top-left" | "centre", `pad_value`."""
    import cv2

    H, W = rgb.shape[:2]
    h, w = (int(v) for v in pp["size"])
    r = min(h / H, w / W)
    nh, nw = int(round(H * r)), int(round(W * r))
    img = rgb if (nh, nw) == (H, W) else cv2.resize(rgb, (nw, nh), interpolation=cv2.INTER_LINEAR)
    if str(pp.get("letterbox", "top-left")).lower() in ("centre", "center"):
        # Ultralytics LetterBox: the odd pixel goes to the bottom / right
        top, left = int(round((h - nh) / 2 - 0.1)), int(round((w - nw) / 2 - 0.1))
    else:
        top, left = 0, 0
    canvas = np.full((h, w, 3), int(pp.get("pad_value", 114)), np.uint8)
    canvas[top:top + nh, left:left + nw] = img
    return preprocess_image(canvas, {k: v for k, v in pp.items() if k != "size"}), r, (float(left), float(top))


def nms(boxes: np.ndarray, scores: np.ndarray, iou: float) -> np.ndarray:
    """Greedy non-maximum suppression: boxes [N, 4] x0 y0 x1 y1, scores [N] -> kept indices, best first (ties by
    index: deterministic)."""
    order = np.lexsort((np.arange(len(scores)), -scores))
    area = np.maximum(boxes[:, 2] - boxes[:, 0], 0) * np.maximum(boxes[:, 3] - boxes[:, 1], 0)
    keep: list[int] = []
    while len(order):
        i = order[0]
        keep.append(int(i))
        rest = order[1:]
        xx0 = np.maximum(boxes[i, 0], boxes[rest, 0])
        yy0 = np.maximum(boxes[i, 1], boxes[rest, 1])
        xx1 = np.minimum(boxes[i, 2], boxes[rest, 2])
        yy1 = np.minimum(boxes[i, 3], boxes[rest, 3])
        inter = np.maximum(xx1 - xx0, 0) * np.maximum(yy1 - yy0, 0)
        union = area[i] + area[rest] - inter
        order = rest[inter <= iou * np.maximum(union, 1e-9)]
    return np.asarray(keep, np.int64)


def class_nms(boxes: np.ndarray, scores: np.ndarray, classes: np.ndarray, iou: float) -> np.ndarray:
    """Per-class NMS (boxes of different classes never suppress each other) -> kept indices, best first."""
    keep = [np.flatnonzero(classes == c)[nms(boxes[classes == c], scores[classes == c], iou)]
            for c in np.unique(classes)]
    k = np.concatenate(keep) if keep else np.zeros(0, np.int64)
    return k[np.lexsort((k, -scores[k]))]


def _to_frame(xyxy: np.ndarray, r: float, pad: tuple[float, float], shape: tuple[int, int]) -> np.ndarray:
    """Input-pixel boxes [N, 4] -> frame pixels (undo the letterbox), clipped to the frame [H, W]."""
    H, W = shape
    out = (xyxy - np.array([pad[0], pad[1], pad[0], pad[1]], np.float32)) / np.float32(r)
    return out.clip(0, [W, H, W, H]).astype(np.float32)


_GRIDS: dict[tuple[int, int, tuple[int, ...]], tuple[np.ndarray, np.ndarray]] = {}


def yolox_grid(h: int, w: int, strides: Sequence[int] = (8, 16, 32)) -> tuple[np.ndarray, np.ndarray]:
    """Anchor cells of an h x w YOLOX input: (grid [A, 2] float32 gx, gy; stride [A, 1] float32), strides in order,
    cells row-major within each."""
    key = (h, w, tuple(strides))
    if key not in _GRIDS:
        g, s = [], []
        for st in strides:
            yv, xv = np.meshgrid(np.arange(h // st), np.arange(w // st), indexing="ij")
            g.append(np.stack([xv, yv], -1).reshape(-1, 2))
            s.append(np.full((g[-1].shape[0], 1), st))
        _GRIDS[key] = (np.concatenate(g).astype(np.float32), np.concatenate(s).astype(np.float32))
    return _GRIDS[key]


class YoloxDetector(LabelDetector):
    """YOLOX (e.g. YOLOX-Nano, COCO 80): the graph's raw anchors decoded and NMS'd here (module docstring)."""

    def _run(self, rgb: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        pp = self.spec.preprocessing
        x, r, pad = letterbox(rgb, pp)
        with self._stage(self.role):
            out = self.session().run({self._input: x})[0][0]
        h, w = (int(v) for v in pp["size"])
        grid, stride = yolox_grid(h, w, self.spec.config.get("strides", (8, 16, 32)))
        if len(out) != len(grid):
            raise ValueError(f"{self.name}: the graph gave {len(out)} anchors for a {h}x{w} input; strides "
                             f"{list(self.spec.config.get('strides', (8, 16, 32)))} make {len(grid)}")
        cls_p = out[:, 5:]
        cls = cls_p.argmax(1)
        score = out[:, 4] * cls_p[np.arange(len(cls)), cls]
        keep = np.flatnonzero(score >= self.conf.floor)
        o = out[keep]
        c = (o[:, :2] + grid[keep]) * stride[keep]
        half = np.exp(np.minimum(o[:, 2:4], 20.0)) * stride[keep] / 2  # exp of a wild value stays finite
        boxes = _to_frame(np.concatenate([c - half, c + half], 1), r, pad, rgb.shape[:2])
        s, k = score[keep].astype(np.float32), cls[keep].astype(np.int64)
        ok = (boxes[:, 2] > boxes[:, 0]) & (boxes[:, 3] > boxes[:, 1])
        boxes, s, k = boxes[ok], s[ok], k[ok]
        sel = class_nms(boxes, s, k, self.conf.nms_iou)[: self.conf.max_detections]
        return boxes[sel], k[sel], s[sel]


class UltralyticsDetector(LabelDetector):
    """Ultralytics end-to-end export (NMS in the graph); with prototypes also an instance segmenter: `detect(...,
    masks=True)` gives one mask per detection, `segment` masks for given boxes, `class_mask` for refinement."""

    roles = ("detector", "instance_segmenter")  # the roles a manifest may give this arch (`models.check_archs`)

    def __init__(self, spec, sessions, trace, conf=None):
        super().__init__(spec, sessions, trace, conf)
        outs = self.session().get_outputs()
        self._dets, self._protos = _ultralytics_outputs(outs)
        self.kind = "instance" if self._protos is not None else "boxes"
        self.units = str(spec.config.get("box_units", "normalised"))
        if self.units not in ("normalised", "pixels"):
            raise ValueError(f"{self.name}: config.box_units must be normalised or pixels, got {self.units!r}")
        self.undetectable: list[str] = []

    def _run(self, rgb: np.ndarray) -> tuple[np.ndarray, ...]:
        pp = self.spec.preprocessing
        x, r, pad = letterbox(rgb, pp)
        with self._stage(self.role):
            res = self.session().run({self._input: x})
        d = res[self._dets][0]
        d = d[d[:, 4] >= max(self.conf.floor, 1e-6)]
        d = d[np.lexsort((np.arange(len(d)), -d[:, 4]))][: self.conf.max_detections]
        h, w = (float(v) for v in pp["size"])
        # fractions of the input canvas' width and height, or its pixels
        xyxy = d[:, :4] * (np.array([w, h, w, h], np.float32) if self.units == "normalised" else np.float32(1))
        boxes = _to_frame(xyxy.astype(np.float32), r, pad, rgb.shape[:2])
        cls, sc = d[:, 5].round().astype(np.int64), d[:, 4].astype(np.float32)
        ok = (boxes[:, 2] > boxes[:, 0]) & (boxes[:, 3] > boxes[:, 1]) & (cls >= 0) & (cls < len(self.labels))
        coef = d[ok, 6:].astype(np.float32)
        protos = np.zeros((coef.shape[1], 1, 1), np.float32)
        if self._protos is not None:
            p = res[self._protos][0]
            protos = p if p.shape[0] == coef.shape[1] else p.transpose(2, 0, 1)  # -> [M, h, w]
        xform = np.array([r, pad[0], pad[1], pp["size"][0], pp["size"][1]], np.float64)
        return boxes[ok], cls[ok], sc[ok], coef, np.ascontiguousarray(protos, np.float32), xform

    def instance_masks(self, rgb: np.ndarray, idx: np.ndarray) -> np.ndarray:
        """Masks [len(idx), H, W] bool of the detections `idx` of `raw(rgb)`: the prototype logits
        (coef . prototypes) bilinearly sampled at each frame pixel inside the detection's box, > 0."""
        import cv2

        boxes, _, _, coef, protos, xf = self.raw(rgb)
        H, W = rgb.shape[:2]
        out = np.zeros((len(idx), H, W), bool)
        if self._protos is None or not len(idx):
            return out
        M, ph, pw = protos.shape
        r, padx, pady, ih, iw = xf
        flat = protos.reshape(M, -1)
        for j, i in enumerate(np.asarray(idx, np.int64)):
            x0, y0 = int(np.floor(boxes[i, 0])), int(np.floor(boxes[i, 1]))
            x1, y1 = int(min(W, np.ceil(boxes[i, 2]))), int(min(H, np.ceil(boxes[i, 3])))
            if x1 <= x0 or y1 <= y0:
                continue
            logit = (coef[i] @ flat).reshape(ph, pw)
            mx = ((np.arange(x0, x1, dtype=np.float32) + 0.5) * r + padx) * (pw / iw) - 0.5
            my = ((np.arange(y0, y1, dtype=np.float32) + 0.5) * r + pady) * (ph / ih) - 0.5
            gx, gy = np.meshgrid(mx.astype(np.float32), my.astype(np.float32))
            win = cv2.remap(logit, gx, gy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
            out[j, y0:y1, x0:x1] = win > 0
        return out

    def detect(self, rgb: np.ndarray, names: Sequence[str], min_score: float | None = None,
               masks: bool = False) -> Detections:
        """As `LabelDetector.detect`; masks=True (an instance model) adds one mask [H, W] per detection."""
        with self._overhead(self.role):
            d = self._detect(rgb, names, min_score)
            if masks and self.kind == "instance" and len(d):
                idx, _, _ = self._select(rgb, names, min_score)
                d.masks = self.instance_masks(rgb, idx)
                d.mask_from = [self.spec.role] * len(d)
            return d

    def segment(self, rgb: np.ndarray, boxes: np.ndarray | None, names: Sequence[str],
                points: np.ndarray | None = None, min_iou: float = 0.5) -> np.ndarray:
        """The segmenter interface: for each box [N, 4] (None = the whole image) and name, the mask of this
        model's own detection of that name that overlaps it best (box IoU >= min_iou; the whole image: every
        detection of the name), cut to the box; empty when it has none. Point prompts are not supported
        (ignored, said once in the trace). -> masks [N, H, W] bool."""
        with self._overhead(self.role):
            if points is not None and not getattr(self, "_points_noted", False):
                self._points_noted = True
                self.trace.event("degraded", f"{self.name}: instance segmenter ignores point prompts",
                                 stage=self.role)
            H, W = rgb.shape[:2]
            mapping, self.undetectable = map_names(list(dict.fromkeys(names)), self.labels)
            out = np.zeros((len(names), H, W), bool)
            raw = self.raw(rgb)
            for j, nm in enumerate(names):
                cand = np.flatnonzero(np.isin(raw[1], mapping.get(nm, [])))
                if not len(cand):
                    continue
                if boxes is None:
                    out[j] = self.instance_masks(rgb, cand).any(0)
                    continue
                b = np.asarray(boxes, np.float32).reshape(-1, 4)[j]
                ious = box_iou(b[None], raw[0][cand])[0]
                if ious.max() >= min_iou:
                    m = self.instance_masks(rgb, cand[[int(ious.argmax())]])[0]
                    x0, y0 = int(max(0, np.floor(b[0]))), int(max(0, np.floor(b[1])))
                    x1, y1 = int(min(W, np.ceil(b[2]))), int(min(H, np.ceil(b[3])))
                    out[j, y0:y1, x0:x1] = m[y0:y1, x0:x1]
            return out

    def class_mask(self, rgb: np.ndarray, name: str) -> np.ndarray | None:
        """[H, W] bool: the union of this model's masks of `name` (every detection down to `conf.floor`; for
        occlusion refinement); None when the label list has no such class."""
        mapping, missing = map_names([name], self.labels)
        if missing or self.kind != "instance":
            return None
        return self.segment(rgb, None, [name])[0]


def _ultralytics_outputs(outs: Sequence[Any]) -> tuple[int, int | None]:
    """(index of the detections output [1, N, 6 + M], index of the prototypes [1, h, w, M] / [1, M, h, w] or
    None) among a graph's outputs; ValueError when they are not the Ultralytics end-to-end format."""
    dets = [i for i, o in enumerate(outs) if len(o.shape or []) == 3]
    protos = [i for i, o in enumerate(outs) if len(o.shape or []) == 4]
    if len(dets) != 1 or len(protos) > 1:
        raise ValueError(f"not an Ultralytics end-to-end graph: outputs {[(o.name, o.shape) for o in outs]}; "
                         f"expected detections [1, N, 6 + M] and optionally prototypes [1, h, w, M]")
    return dets[0], (protos[0] if protos else None)
