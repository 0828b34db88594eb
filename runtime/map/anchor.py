"""Objects on RGB: each lifted detection's relative-depth shape anchored to the triangulated points inside it.

Structure from motion gives each key frame ONE depth scale (the median ratio of its triangulated points' depth to
the relative depth there, `align.sfm.keyframe_scale`). A relative depth model's error is not one factor per image
(an inverse depth with an unknown shift bends near and far apart), so an object lifted with the frame's factor can
sit too near or too far, and comes out too small or too big in proportion. `anchor_observations` re-scales each
observation about the camera centre (its pixel footprint unchanged: the depth model gives the shape, the
triangulated features inside the object's mask give where it is) by the robust median ratio of the map points
that project inside its footprint and agree with each other; too few points: the frame's factor stays (counted).
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from ..types import Observation


@dataclass
class Anchored:
    """What anchoring did to one frame's observations: per observation (name, points used, factor or None)."""

    frame: int
    rows: list[tuple[str, int, float | None]]

    def to_dict(self) -> dict[str, Any]:
        return {"frame": self.frame, "objects": [{"name": n, "points": k, "factor": None if f is None else round(f, 3)}
                                                 for n, k, f in self.rows]}


def footprint_cells(P: np.ndarray, K: np.ndarray, cell_px: int) -> np.ndarray:
    """Pixel cells (row-major keys, `cell_px` pixels a side) that camera-frame points P [N, 3] cover."""
    z = P[:, 2]
    ok = z > 1e-9
    u = K[0, 0] * P[ok, 0] / z[ok] + K[0, 2]
    v = K[1, 1] * P[ok, 1] / z[ok] + K[1, 2]
    return np.unique(_keys(u, v, cell_px))


def _keys(u: np.ndarray, v: np.ndarray, cell_px: int) -> np.ndarray:
    return (np.floor(v / cell_px).astype(np.int64) << 20) + np.floor(u / cell_px).astype(np.int64)


def anchor_factor(obs_points: np.ndarray, map_cam: np.ndarray, depth: np.ndarray, K: np.ndarray, cell_px: int,
                  min_points: int, inlier_log: float) -> tuple[float | None, int]:
    """(factor, points used) for one observation: obs_points [N, 3] camera-frame (lifted with `depth`), map_cam
    [M, 3] the map's points in the same camera and units, depth [H, W] the frame's depth. The map points whose
    pixels fall in the observation's footprint cells give log(z / depth there); those within `inlier_log` of
    their median (occluders and what lies behind the object differ) give the factor, exp(median); under
    `min_points` of them: (None, count)."""
    H, W = depth.shape
    z = map_cam[:, 2]
    q = map_cam[z > 1e-9]
    if not len(q) or not len(obs_points):
        return None, 0
    u = K[0, 0] * q[:, 0] / q[:, 2] + K[0, 2]
    v = K[1, 1] * q[:, 1] / q[:, 2] + K[1, 2]
    inside = (u >= 0) & (u < W) & (v >= 0) & (v < H)
    u, v, q = u[inside], v[inside], q[inside]
    hit = np.isin(_keys(u, v, cell_px), footprint_cells(obs_points, K, cell_px))
    if hit.sum() < min_points:
        return None, int(hit.sum())
    d = depth[v[hit].astype(int), u[hit].astype(int)].astype(np.float64)
    ok = np.isfinite(d) & (d > 0)
    r = np.log(q[hit, 2][ok] / d[ok])
    if len(r) < min_points:
        return None, len(r)
    keep = np.abs(r - np.median(r)) <= inlier_log
    if keep.sum() < min_points:
        return None, int(keep.sum())
    return float(np.exp(np.median(r[keep]))), int(keep.sum())


def anchor_observations(obs: list[Observation], map_cam: np.ndarray, depth: np.ndarray, K: np.ndarray,
                        frame: int, cell_px: int = 4, min_points: int = 5, inlier_log: float = 0.15,
                        max_factor: float = 3.0) -> tuple[list[Observation], Anchored]:
    """One key frame's camera-frame observations, each scaled about the camera centre by its `anchor_factor`
    (module doc); a factor beyond `max_factor` either way is not trusted (the points are then not on the
    object: kept at the frame's factor). Pure: new observations."""
    out, rows = [], []
    for o in obs:
        f, k = anchor_factor(np.asarray(o.points, np.float64), map_cam, depth, np.asarray(K, np.float64), cell_px,
                             min_points, inlier_log)
        if f is not None and not (1.0 / max_factor <= f <= max_factor):
            f = None
        rows.append((o.name, k, f))
        out.append(o if f is None else replace(o, points=(np.asarray(o.points) * f).astype(o.points.dtype)))
    return out, Anchored(frame, rows)


def summary(done: list[Anchored]) -> dict[str, Any]:
    """The trace's account: observations anchored / kept at their frame's factor, and the factors' spread."""
    rows = [r for a in done for r in a.rows]
    f = np.array([r[2] for r in rows if r[2] is not None], float)
    return {"observations": len(rows), "anchored": int(len(f)), "frame_factor": len(rows) - int(len(f)),
            "factor_quartiles": np.round(np.percentile(f, [25, 50, 75]), 3).tolist() if len(f) else None,
            "frames": [a.to_dict() for a in done]}


__all__ = ["Anchored", "anchor_factor", "anchor_observations", "footprint_cells", "summary"]
