"""Rectangular input for a fixed-size Ultralytics end-to-end graph converted from TFLite (`--set size=HxW`).

A 640x480 frame fills 75 % of a 640x640 letterbox: the other quarter of the convolutions runs on grey padding.
Ultralytics itself infers on rectangles (`rect=True`); its TFLite export bakes the square size into the graph as
constants: the reshapes of the three detection levels (stride 8 / 16 / 32: S/s x S/s cells each, A in all), the
attention block's token count at stride 32, the anchor centres [1, 2, A] and the per-anchor stride scale [1, 4, A]
(both as fractions of the input's width and height), and a batch offset A. `rect_graph` rewrites exactly those for
an H x W input (multiples of 32) and refuses a graph where any of them is not found. The result is not the square
graph on fewer pixels (the padding is context the square graph saw), so the export checks it as a task: its
detections against the square graph's on real frames (`agreement`).
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from mosaicthinker.runtime.infra.errors import ExportError

STRIDES = (8, 16, 32)


def _levels(h: int, w: int) -> list[tuple[int, int, int]]:
    return [(s, h // s, w // s) for s in STRIDES]


def rect_graph(src: str | os.PathLike, dst: str | os.PathLike, size: Sequence[int]) -> dict[str, Any]:
    """Write `dst`: the square-input graph `src` ([1, S, S, 3] NHWC) for an input of `size` [H, W]. Returns
    {"square": S, "size": [H, W], "patched": {what: count}}; ExportError when the graph is not the expected
    Ultralytics TFLite conversion (a constant not found) or the size is not a multiple of 32."""
    import onnx
    from onnx import numpy_helper

    H, W = (int(v) for v in size)
    if H % 32 or W % 32 or H <= 0 or W <= 0:
        raise ExportError(f"--set size={H}x{W}: height and width must be positive multiples of 32")
    m = onnx.load(str(src))
    g = m.graph
    dims = [d.dim_value for d in g.input[0].type.tensor_type.shape.dim]
    if len(dims) != 4 or dims[1] != dims[2] or dims[3] != 3 or dims[1] <= 0:
        raise ExportError(f"{src}: expected a square NHWC input [1, S, S, 3], got {dims}")
    S = dims[1]
    old, new = _levels(S, S), _levels(H, W)
    cells = {h * w: nh * nw for (_, h, w), (_, nh, nw) in zip(old, new)}
    A, nA = sum(h * w for _, h, w in old), sum(h * w for _, h, w in new)
    users: dict[str, set[str]] = {}
    for n in g.node:
        for i in n.input:
            users.setdefault(i, set()).add(n.op_type)
    patched = {"reshape": 0, "offset": 0, "anchors": 0, "strides": 0}
    for init in g.initializer:
        a = numpy_helper.to_array(init)
        ops = users.get(init.name, set())
        if "Reshape" in ops and a.ndim == 1 and a.dtype.kind == "i":
            v = _reshape_target(a.tolist(), S, H, W, cells, A, nA)
            if v is not None:
                init.CopyFrom(numpy_helper.from_array(np.asarray(v, a.dtype), init.name))
                patched["reshape"] += 1
        elif "Mul" in ops and a.dtype.kind == "i" and a.size == 1 and int(a.ravel()[0]) == A:
            init.CopyFrom(numpy_helper.from_array(np.full(a.shape, nA, a.dtype), init.name))
            patched["offset"] += 1
        elif a.dtype.kind == "f" and a.shape == (1, 2, A) and np.allclose(a, _anchors(old, S, S), atol=1e-6):
            init.CopyFrom(numpy_helper.from_array(_anchors(new, H, W).astype(a.dtype), init.name))
            patched["anchors"] += 1
        elif a.dtype.kind == "f" and a.shape == (1, 4, A) and np.allclose(a, _scales(old, S, S), atol=1e-7):
            init.CopyFrom(numpy_helper.from_array(_scales(new, H, W).astype(a.dtype), init.name))
            patched["strides"] += 1
    missing = [k for k, v in patched.items() if not v]
    if missing:
        raise ExportError(f"{src}: not an Ultralytics TFLite end-to-end graph whose size can be changed ({missing} "
                          f"not found); export it at {H}x{W} with Ultralytics instead (imgsz=[{H}, {W}])")
    g.input[0].type.tensor_type.shape.dim[1].dim_value = H
    g.input[0].type.tensor_type.shape.dim[2].dim_value = W
    for o in g.output:
        d = o.type.tensor_type.shape.dim
        if len(d) == 4 and d[1].dim_value == d[2].dim_value == S // 4:  # prototypes at stride 4
            d[1].dim_value, d[2].dim_value = H // 4, W // 4
    del g.value_info[:]  # shapes inferred for the square input
    Path(dst).parent.mkdir(parents=True, exist_ok=True)
    onnx.save(m, str(dst))
    return {"square": S, "size": [H, W], "patched": patched}


def _reshape_target(v: list[int], S: int, H: int, W: int, cells: dict[int, int], A: int, nA: int
                    ) -> list[int] | None:
    """A Reshape shape for the new size, or None when `v` does not depend on the input size."""
    if len(v) >= 3 and v[-2:] == [S // 32, S // 32]:
        return v[:-2] + [H // 32, W // 32]
    if len(v) >= 3 and v[-1] == A:
        return v[:-1] + [nA]
    if len(v) >= 3 and v[-1] in cells and v[-1] != v[-2]:
        return v[:-1] + [cells[v[-1]]]
    return None


def _anchors(levels: list[tuple[int, int, int]], H: int, W: int) -> np.ndarray:
    """[1, 2, A]: anchor centres x / W, y / H, levels in stride order, cells row-major (Ultralytics' TFLite
    normalisation)."""
    xs, ys = [], []
    for s, h, w in levels:
        gy, gx = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
        xs.append((gx.ravel() + 0.5) * s / W)
        ys.append((gy.ravel() + 0.5) * s / H)
    return np.stack([np.concatenate(xs), np.concatenate(ys)])[None]


def _scales(levels: list[tuple[int, int, int]], H: int, W: int) -> np.ndarray:
    """[1, 4, A]: each anchor's stride over the input's W, H, W, H."""
    return np.stack([np.concatenate([np.full(h * w, s / div) for s, h, w in levels])
                     for div in (W, H, W, H)])[None]


def agreement(square: str | os.PathLike, rect: str | os.PathLike, frames: Sequence[np.ndarray],
              min_score: float = 0.5, min_iou: float = 0.5) -> dict[str, Any]:
    """Task check: the square graph's detections (score >= min_score, letterboxed frames) found by the rect graph
    (same class, box IoU >= min_iou, any score >= 0.25): the share found, their mean IoU and score change."""
    import onnxruntime as ort

    from mosaicthinker.runtime.geometry import box_iou
    from mosaicthinker.runtime.models.yolo import letterbox

    def sess(p):
        so = ort.SessionOptions()
        so.log_severity_level = 3
        return ort.InferenceSession(str(p), so, providers=["CPUExecutionProvider"])

    a, b = sess(square), sess(rect)
    sa, sb = [int(v) for v in a.get_inputs()[0].shape[1:3]], [int(v) for v in b.get_inputs()[0].shape[1:3]]
    pp = {"layout": "NHWC", "channel_order": "RGB", "dtype": "float32", "scale": 1 / 255, "letterbox": "centre"}
    found, total, ious, dscore = 0, 0, [], []
    for f in frames:
        out = []
        for s, size in ((a, sa), (b, sb)):
            x, r, (px, py) = letterbox(f, {**pp, "size": size})
            d = s.run(None, {s.get_inputs()[0].name: x})[0][0]
            d = d[d[:, 4] >= 0.25]
            box = (d[:, :4] * [size[1], size[0], size[1], size[0]] - [px, py, px, py]) / r
            out.append((box, d[:, 4], d[:, 5]))
        (ba, sca, ca), (bb, scb, cb) = out
        for k in np.flatnonzero(sca >= min_score):
            total += 1
            same = np.flatnonzero(cb == ca[k])
            io = box_iou(ba[k:k + 1], bb[same])[0] if len(same) else np.zeros(0)
            if len(io) and io.max() >= min_iou:
                found += 1
                ious.append(float(io.max()))
                dscore.append(abs(float(scb[same[io.argmax()]] - sca[k])))
    return {"frames": len(frames), "detections": total, "found": round(found / max(total, 1), 3),
            "mean_iou": round(float(np.mean(ious)), 3) if ious else None,
            "median_score_change": round(float(np.median(dscore)), 3) if dscore else None,
            "rule": f"square-input detections >= {min_score} found by the rect graph (same class, IoU >= {min_iou})"}
