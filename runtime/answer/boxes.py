"""What the executors read off oriented boxes: measures (longest side, height, width, volume ...), the relations
on / near / in / under / above / between, and the closest pair of two instance lists.

Nearest boxes and closest pairs over many instances: `spatial` (a KD-tree, culled by the bounds here).
"""
from __future__ import annotations

from typing import Any

import numpy as np

from ..geometry import box_distance, local_f32, point_box_distance
from .angles import signed_angle_deg
from .result import ReasonerConfig, Unsupported  # noqa: F401 (Unsupported: view_relation)


def measure(o: Any, what: str) -> float:
    """A box measure in metres: longest side, height (vertical extent), length and width (the longer horizontal
    side, as furniture is sold: W x D x H), depth (the shorter horizontal side), volume (m^3), top (highest z) or
    bottom (lowest z)."""
    b = o.box
    lengths = np.asarray(b.axes_lengths, float)
    if what == "longest":
        return float(np.max(lengths))
    if what == "volume":
        return float(np.prod(lengths))
    z = b.corners()[:, 2]
    if what == "height":
        return float(z.max() - z.min())
    if what == "top":
        return float(z.max())
    if what == "bottom":
        return float(z.min())
    up = int(np.argmax(np.abs(np.asarray(b.axes, float)[:, 2])))
    horiz = sorted((float(lengths[i]) for i in range(3) if i != up), reverse=True)
    return horiz[1] if what == "depth" else horiz[0]  # length / width: the longer horizontal side (W x D x H)


MEASURE_WORDS = {"volume": "box volume", "height": "height", "top": "top height", "length": "length",
                 "width": "width"}


def relation_holds(a: Any, b: Any, relation: str, conf: ReasonerConfig, c: Any = None) -> bool:
    """Whether instance a is `relation` ("on", "near", "in", "under", "above"; "between" b and c) instance b,
    from their boxes (z up)."""
    if relation == "near":  # a centre within near_m of the other box: near already (an upper bound), no solve
        return (point_box_distance(a.center, b.box) <= conf.near_m or point_box_distance(b.center, a.box) <= conf.near_m
                or box_distance(a.box, b.box) <= conf.near_m)
    if relation == "in":
        return bool(b.box.contains(a.center[None])[0])
    if relation == "between":
        return c is not None and _between(a, b, c)
    bottom = measure(a, "bottom")
    over = b.box.contains(np.array([[a.center[0], a.center[1], b.center[2]]]))[0]  # within b's footprint
    if relation == "under":  # centre within b's footprint and below b's top ("the bin under the desk")
        return bool(over) and float(a.center[2]) < measure(b, "top") - conf.on_gap_m
    if relation == "above":  # over b's footprint, bottom at or above b's top ("the lamp above the table")
        return bool(over) and bottom >= measure(b, "top") - conf.on_gap_m
    return bool(over) and abs(bottom - measure(b, "top")) <= conf.on_gap_m


def _between(a: Any, b: Any, c: Any) -> bool:
    """a's centre inside the top-view convex hull of b's and c's footprints, and in neither footprint."""
    import cv2

    origin, (pts,) = local_f32(np.concatenate([b.box.corners()[:, :2], c.box.corners()[:, :2]]))
    hull = cv2.convexHull(pts)
    p = (float(a.center[0]), float(a.center[1]))
    inside = cv2.pointPolygonTest(hull, (p[0] - float(origin[0]), p[1] - float(origin[1])), False) >= 0
    own = any(o.box.contains(np.array([[p[0], p[1], o.center[2]]]))[0] for o in (b, c))
    return bool(inside) and not own


def half_extents(boxes: list[Any]) -> tuple[np.ndarray, np.ndarray]:
    """Centroids [M, 3] and axis-aligned half extents [M, 3] of oriented boxes (their AABBs contain them)."""
    c = np.array([o.box.centroid for o in boxes], np.float64).reshape(-1, 3)
    ax = np.abs(np.array([o.box.axes for o in boxes], np.float64).reshape(-1, 3, 3))
    h = np.array([o.box.axes_lengths for o in boxes], np.float64).reshape(-1, 1, 3) / 2
    return c, (h @ ax).reshape(-1, 3)


def aabb_gaps(cx: np.ndarray, ex: np.ndarray, cb: np.ndarray, eb: np.ndarray) -> np.ndarray:
    """Lower bounds [M] of the distance from one box (centroid cx [3], AABB half extent ex [3]) to each box of b:
    the distance of their AABBs (exact for axis-aligned boxes)."""
    gap = np.maximum(np.abs(cb - cx) - ex - eb, 0.0)
    return np.linalg.norm(gap, axis=1)


def view_relation(A: Any, B: Any, T: np.ndarray) -> tuple[str, str, float, float]:
    """(left | right, front | back, angle deg, metres beyond B) of A against B as seen from the camera T_wc,
    looking at B: A's bearing left or right of B's, and in front of / behind B along that line."""
    cam = T[:2, 3]
    vb, va = B.center[:2] - cam, A.center[:2] - cam
    if np.linalg.norm(vb) < 1e-6:
        raise Unsupported(f"the last camera stands at the {B.name}")
    th = signed_angle_deg(vb, va)  # counter-clockwise: left of B as seen from the camera
    along = float(va @ vb / np.linalg.norm(vb) - np.linalg.norm(vb))  # > 0: beyond B (behind it)
    return ("left" if th > 0 else "right"), ("back" if along > 0 else "front"), th, along
