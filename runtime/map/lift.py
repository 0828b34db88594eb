"""Lifting (paper: iterative construction): per key frame, each detection's mask (or, without a segmenter, its
box's depth layer) and depth -> camera-frame points; `place` moves them into the world through the frame's pose."""
from __future__ import annotations

from dataclasses import replace
from typing import Any, Iterable

import numpy as np

from ..geometry import backproject, backproject_pixels, transform
from ..types import Detections, Frame, Observation
from .cluster import largest_components
from .conf import FusionConfig, default_fusion_conf


def lift_observations(rgb_shape: tuple[int, int], depth: np.ndarray, K: np.ndarray, T_wc: np.ndarray,
                      boxes: np.ndarray, names: list[str], scores: np.ndarray, masks: np.ndarray | None,
                      frame: int, t: float, conf: FusionConfig = default_fusion_conf,
                      instance_ids: np.ndarray | None = None) -> list[Observation]:
    """Masked depth -> world points for each detection of one frame: `place(lift_camera(...), T_wc)`.

    depth: [H, W] float32 metres (0 invalid); K: [3, 3]; T_wc: [4, 4] camera-to-world (gravity-aligned world);
    boxes: [N, 4] pixels; masks: [N, H, W] bool or None (then the box interior is used, with a tighter depth
    filter: the median-depth band, since boxes also cover background).
    """
    return place(lift_camera(rgb_shape, depth, K, boxes, names, scores, masks, frame, t, conf, instance_ids), T_wc)


def place(observations: list[Observation], T_wc: np.ndarray) -> list[Observation]:
    """Camera-frame observations (`lift_camera`) -> the same in the world: points [N, 3] through T_wc [4, 4]."""
    return [replace(o, points=transform(T_wc, o.points)) for o in observations]


def lift_camera(rgb_shape: tuple[int, int], depth: np.ndarray, K: np.ndarray, boxes: np.ndarray, names: list[str],
                scores: np.ndarray, masks: np.ndarray | None, frame: int, t: float,
                conf: FusionConfig = default_fusion_conf, instance_ids: np.ndarray | None = None
                ) -> list[Observation]:
    """Masked depth -> camera-frame points for each detection of one frame (arguments as `lift_observations`).
    Needs no pose (a rigid move keeps the component split's distances), so a key frame is lifted when it is
    perceived (paper: per key frame, segmentation + depth -> object point clouds) and fusion only places it."""
    import cv2

    rng = None  # the frame's subsampling stream, made on first use (most masks need none: ~50 us a frame)
    out: list[Observation] = []
    # with segmenter masks only the masks' windows are read: the depth cut-off is applied there
    # (`_backproject_window`), not to the whole image; box-prompted masks need the cut depth image itself
    d = _depth_upto(depth, conf.max_depth_m) if masks is None else depth
    kernel = np.ones((2 * conf.erode_px + 1,) * 2, np.uint8) if conf.erode_px > 0 else None
    keep = duplicate_names(boxes, names, scores, conf.duplicate_iou) if conf.duplicate_iou > 0 else None
    for j, (box, name) in enumerate(zip(boxes, names)):
        if keep is not None and not keep[j]:
            continue
        full = masks[j] if masks is not None else box_depth_mask(d, box)
        win = _mask_window(full, conf.erode_px if masks is not None else 0, conf.pixel_stride)
        if win is None:
            continue
        m = full[win].astype(np.uint8)
        if masks is not None and kernel is not None:
            eroded = cv2.erode(m, kernel)
            m = eroded if eroded.sum() >= conf.min_points else m
        pts = _backproject_window(d, K, m.astype(bool), win, conf.pixel_stride, conf.max_depth_m)
        if len(pts) < conf.min_points:
            continue
        if len(pts) > conf.max_points:
            rng = rng or np.random.default_rng(conf.subsample_seed + frame)
            pts = pts[rng.choice(len(pts), conf.max_points, replace=False)]
        if conf.component_link_m > 0:  # a mask that bled across a depth edge (onto the table, the next chair)
            pts = largest_components(pts, conf.component_link_m, conf.component_share)
            if len(pts) < conf.min_points:
                continue
        out.append(Observation(name, float(scores[j]), frame, t, pts, np.asarray(box, np.float32),
                               None if instance_ids is None else int(instance_ids[j])))
    return out


def _mask_window(mask: np.ndarray, margin: int, stride: int) -> tuple[slice, slice] | None:
    """Rows/cols window of `mask [H, W]` around its pixels, `margin` wider (what an erosion reads), starting on
    the stride grid: the per-detection work (erosion, lifting) runs on the window, not the whole image, with
    the same result. None for an empty mask."""
    rows, cols = np.flatnonzero(mask.any(1)), np.flatnonzero(mask.any(0))
    if not len(rows):
        return None
    H, W = mask.shape
    y0, x0 = max(0, rows[0] - margin) // stride * stride, max(0, cols[0] - margin) // stride * stride
    return slice(y0, min(H, rows[-1] + 1 + margin)), slice(x0, min(W, cols[-1] + 1 + margin))


def _depth_upto(depth: np.ndarray, max_depth_m: float) -> np.ndarray:
    """float32 depth with everything at or beyond `max_depth_m` (and NaN) set to 0 (invalid)."""
    return np.where(depth < max_depth_m, depth, 0).astype(np.float32)


def _backproject_window(depth: np.ndarray, K: np.ndarray, mask: np.ndarray, win: tuple[slice, slice],
                        stride: int, max_depth_m: float = np.inf) -> np.ndarray:
    """`geometry.backproject(_depth_upto(depth, max_depth_m), K, full_mask, stride)` points for a mask given on
    `win` (its window, starting on the stride grid): the same points in the same order. -> [N, 3]"""
    d = _depth_upto(depth[win][::stride, ::stride], max_depth_m)
    ok = np.isfinite(d) & (d > 0) & mask[::stride, ::stride]
    v, u = np.nonzero(ok)
    uv = np.stack([u * stride + win[1].start, v * stride + win[0].start], 1).astype(np.float64)
    return backproject_pixels(uv, d[ok].astype(np.float64), K)


def box_depth_mask(depth: np.ndarray, box: np.ndarray, band_m: float = 0.15, band_rel: float = 0.15,
                   ring: float = 0.25, min_share: float = 0.1) -> np.ndarray:
    """Box-prompted mask [H, W] bool: the valid depth pixels inside `box [4]` of the depth layer the box was
    drawn around (|d - layer| < max(band_m, band_rel * layer)).

    The layer is the one that stands out of its surroundings (`box_layer`): of the depth modes holding
    >= `min_share` of the box's pixels, the one whose share inside the box most exceeds its share in a ring
    around it (`ring` x the box size each side). A wall or counter behind, or a table edge in front, goes on
    past the box's edges; the object ends there. Used when there is no segmenter, or the segmenter cannot
    segment the box's category (recorded as degraded by the caller)."""
    H, W = depth.shape
    x0, y0, x1, y1 = np.round(np.asarray(box, float)).astype(int)
    x0, y0, x1, y1 = max(0, x0), max(0, y0), min(W, x1), min(H, y1)
    m = np.zeros((H, W), bool)
    if x1 <= x0 or y1 <= y0:
        return m
    patch = depth[y0:y1, x0:x1]
    inside = patch[patch > 0]
    if not len(inside):
        return m
    gx, gy = int(round(ring * (x1 - x0))), int(round(ring * (y1 - y0)))
    outer = depth[max(0, y0 - gy):min(H, y1 + gy), max(0, x0 - gx):min(W, x1 + gx)].copy()
    outer[y0 - max(0, y0 - gy):y1 - max(0, y0 - gy), x0 - max(0, x0 - gx):x1 - max(0, x0 - gx)] = 0
    layer = box_layer(inside, outer[outer > 0], band_m, band_rel, min_share)
    m[y0:y1, x0:x1] = (patch > 0) & (np.abs(patch - layer) < max(band_m, band_rel * layer))
    return m


def box_layer(inside: np.ndarray, around: np.ndarray, band_m: float = 0.15, band_rel: float = 0.15,
              min_share: float = 0.1, bins: int = 48) -> float:
    """Depth (m) of the layer a box was drawn around, from its valid depths `inside [N]` and those of a ring
    `around [M]` it: each depth mode (a histogram peak in log depth) holding >= `min_share` of `inside` within
    its band scores its inside share minus its share of `around`; the best wins (ties: the nearer). Without a
    ring (a box filling the image) the score is the inside share. Pure."""
    d = np.asarray(inside, np.float64)
    lo, hi = np.log(max(float(d.min()), 1e-3)), np.log(max(float(d.max()), 1e-3))
    if hi - lo < 1e-6:
        return float(d[0])
    hist, edges = np.histogram(np.log(d), bins=bins, range=(lo, hi))
    sm = np.convolve(hist, [1, 2, 1], "same")
    peaks = [k for k in range(bins) if sm[k] > 0 and sm[k] >= sm[max(0, k - 1)] and sm[k] >= sm[min(bins - 1, k + 1)]]
    best, best_score = float(np.median(d)), -np.inf
    a = np.asarray(around, np.float64)
    for k in peaks:
        c = float(np.exp((edges[k] + edges[k + 1]) / 2))
        band = max(band_m, band_rel * c)
        share = float(np.mean(np.abs(d - c) < band))
        if share < min_share:
            continue
        score = share - (float(np.mean(np.abs(a - c) < band)) if len(a) else 0.0)
        if score > best_score + 1e-9:
            best, best_score = c, score
    return best


def duplicate_names(boxes: np.ndarray, names: list[str], scores: np.ndarray, iou: float = 0.7) -> np.ndarray:
    """Keep mask [N] over one frame's detections: a detection whose box overlaps (IoU >= `iou`) a
    higher-scored detection of another name is the same object named twice (a closed-set detector's per-class
    NMS gives "laptop" and "tv" for one screen); one detection is one object. Pure."""
    b = np.asarray(boxes, np.float64).reshape(-1, 4)
    keep = np.ones(len(b), bool)
    area = np.maximum(b[:, 2] - b[:, 0], 0) * np.maximum(b[:, 3] - b[:, 1], 0)
    for i in np.argsort(-np.asarray(scores, np.float64), kind="stable"):
        if not keep[i]:
            continue
        w = np.maximum(0, np.minimum(b[i, 2], b[:, 2]) - np.maximum(b[i, 0], b[:, 0]))
        h = np.maximum(0, np.minimum(b[i, 3], b[:, 3]) - np.maximum(b[i, 1], b[:, 1]))
        ov = w * h / np.maximum(area[i] + area - w * h, 1e-9)
        dup = (ov >= iou) & np.array([n != names[i] for n in names]) & keep
        dup[i] = False
        keep &= ~dup
    return keep


def world_points(frames: Iterable[Frame], poses: dict[int, np.ndarray], stride: int,
                  keep: Any = None) -> list[np.ndarray]:
    """Depth points of the posed frames in the poses' frame; `keep(p) -> mask` selects camera-frame points."""
    out = []
    for f in frames:
        if f.index in poses and f.depth is not None:
            p, _ = backproject(f.depth, f.K, stride=stride)
            out.append(transform(poses[f.index], p if keep is None else p[keep(p)]))
    return out


def lift_detections(f: Frame, d: Detections, fconf: FusionConfig) -> list[Observation]:
    """A key frame's detections [N] as camera-frame point clouds (`lift_camera` on the frame's depth, K, t)."""
    return lift_camera(f.rgb.shape[:2], f.depth, f.K, d.boxes, d.names, d.scores, d.masks, f.index, f.t, fconf,
                       d.instance_ids)
