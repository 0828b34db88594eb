"""Geometry: back-projection, projection, pose algebra, Umeyama + RANSAC, oriented boxes.

The only home for these. Conventions (see ARCHITECTURE.md):
- camera axes as OpenCV: x right, y down, z forward; depth is z-depth in metres, 0 = invalid;
- poses are `[4, 4] float64` camera-to-world (`T_wc`); `invert(T_wc)` gives world-to-camera;
- intrinsics `K` are `[3, 3]`; points are `[N, 3] float64`;
- oriented boxes follow VSI-Bench meta_info: `normalizedAxes` rows are the box axes.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import os

from .infra.errors import InputError

# ----------------------------------------------------------------------------- pose algebra


def make_pose(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """R: [3, 3], t: [3] -> T: [4, 4] float64."""
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = np.asarray(t, dtype=np.float64).reshape(3)
    return T


def invert(T: np.ndarray) -> np.ndarray:
    """Inverse of a rigid or similarity transform `[4, 4]` (rotation block may carry a uniform scale)."""
    A = T[:3, :3]
    s2 = float(np.mean(np.sum(A * A, axis=0)))  # squared scale
    Ti = np.eye(4)
    Ti[:3, :3] = A.T / s2
    Ti[:3, 3] = -Ti[:3, :3] @ T[:3, 3]
    return Ti


def transform(T: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Apply `[4, 4]` T to points `[N, 3]` -> `[N, 3]`."""
    pts = np.asarray(pts, dtype=np.float64)
    return pts @ T[:3, :3].T + T[:3, 3]


def rotation_angle_deg(R: np.ndarray) -> float:
    """Angle of a rotation matrix `[3, 3]` in degrees."""
    c = (np.trace(R[:3, :3]) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def rotation_about(axis: np.ndarray, angle_rad: float) -> np.ndarray:
    """Rodrigues rotation `[3, 3]` about a unit `axis [3]`."""
    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(angle_rad) * K + (1 - np.cos(angle_rad)) * (K @ K)


def rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Smallest rotation `[3, 3]` taking direction `a [3]` onto direction `b [3]`."""
    a = np.asarray(a, float) / np.linalg.norm(a)
    b = np.asarray(b, float) / np.linalg.norm(b)
    v = np.cross(a, b)
    s, c = np.linalg.norm(v), float(np.dot(a, b))
    if s < 1e-12:
        if c > 0:
            return np.eye(3)
        perp = np.cross(a, [1.0, 0, 0]) if abs(a[0]) < 0.9 else np.cross(a, [0, 1.0, 0])
        return rotation_about(perp, np.pi)
    return rotation_about(v / s, np.arctan2(s, c))


# ----------------------------------------------------------------------------- camera models


def backproject(depth: np.ndarray, K: np.ndarray, mask: np.ndarray | None = None,
                stride: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Lift valid depth pixels to camera-frame 3D points.

    depth: [H, W] float32 metres (0 = invalid); K: [3, 3]; mask: [H, W] bool or None.
    Returns points [N, 3] float64 (camera frame) and pixels [N, 2] float64 (u, v).
    """
    H, W = depth.shape
    v, u = np.mgrid[0:H:stride, 0:W:stride]
    d = depth[::stride, ::stride]
    ok = np.isfinite(d) & (d > 0)
    if mask is not None:
        ok &= mask[::stride, ::stride].astype(bool)
    u, v, z = u[ok].astype(np.float64), v[ok].astype(np.float64), d[ok].astype(np.float64)
    uv = np.stack([u, v], 1)
    return backproject_pixels(uv, z, K), uv


def backproject_pixels(uv: np.ndarray, z: np.ndarray, K: np.ndarray) -> np.ndarray:
    """uv: [N, 2] pixels, z: [N] z-depth (m), K: [3, 3] -> points [N, 3] in the camera frame."""
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    z = np.asarray(z, dtype=np.float64).reshape(-1)
    x = (uv[:, 0] - K[0, 2]) / K[0, 0] * z
    y = (uv[:, 1] - K[1, 2]) / K[1, 1] * z
    return np.stack([x, y, z], 1)


def sample_depth(depth: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Nearest-pixel depth at `uv [N, 2]` -> `[N]` (0 outside the image or invalid)."""
    H, W = depth.shape
    ui = np.round(uv[:, 0]).astype(int)
    vi = np.round(uv[:, 1]).astype(int)
    ok = (ui >= 0) & (ui < W) & (vi >= 0) & (vi < H)
    z = np.zeros(len(uv), dtype=np.float64)
    z[ok] = depth[vi[ok], ui[ok]]
    z[~np.isfinite(z)] = 0
    return z


def project(points_world: np.ndarray, K: np.ndarray, T_wc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Project world points `[N, 3]` into a camera with pose `T_wc [4, 4]` -> uv `[N, 2]`, z `[N]`."""
    pc = transform(invert(T_wc), points_world)
    z = pc[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = K[0, 0] * pc[:, 0] / z + K[0, 2]
        v = K[1, 1] * pc[:, 1] / z + K[1, 2]
    return np.stack([u, v], 1), z


def intrinsics_from_fov(width: int, height: int, hfov_deg: float = 60.0) -> np.ndarray:
    """Pinhole `K [3, 3]` from a horizontal field of view (principal point at the centre)."""
    f = 0.5 * width / np.tan(np.radians(hfov_deg) / 2)
    return np.array([[f, 0, (width - 1) / 2], [0, f, (height - 1) / 2], [0, 0, 1.0]])


# ----------------------------------------------------------------------------- rigid/similarity estimation


def umeyama(src: np.ndarray, dst: np.ndarray, with_scale: bool = False) -> np.ndarray:
    """Least-squares T `[4, 4]` with dst ≈ s·R·src + t (Umeyama 1991). src, dst: `[N, 3]`, N >= 3."""
    src = np.asarray(src, dtype=np.float64)
    dst = np.asarray(dst, dtype=np.float64)
    mu_s, mu_d = src.mean(0), dst.mean(0)
    xs, xd = src - mu_s, dst - mu_d
    cov = xd.T @ xs / len(src)
    U, D, Vt = np.linalg.svd(cov)
    S = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        S[2, 2] = -1
    R = U @ S @ Vt
    s = 1.0
    if with_scale:
        var_s = (xs**2).sum() / len(src)
        s = float(np.trace(np.diag(D) @ S) / var_s) if var_s > 0 else 1.0
    T = np.eye(4)
    T[:3, :3] = s * R
    T[:3, 3] = mu_d - s * R @ mu_s
    return T


@dataclass
class RansacResult:
    """Outcome of `ransac_transform`. T: [4, 4] (src -> dst); inliers: [N] bool."""

    T: np.ndarray
    inliers: np.ndarray
    n_inliers: int
    residual: float  # RMS distance (m) of inliers after the final refit
    ok: bool
    iterations: int = 0
    extra: dict[str, Any] = field(default_factory=dict)


def worker_threads(n: int = 0) -> int:
    """Threads for independent per-pair / per-frame work (numpy and OpenCV release the GIL): n when > 0, else
    $MOSAIC_THREADS when set, else the CPU count capped at 4 (1 = the caller's thread only). The results do not
    depend on it."""
    env = os.environ.get("MOSAIC_THREADS", "")
    if n <= 0 and env:
        if not env.isdigit() or int(env) < 1:
            raise ValueError(f"MOSAIC_THREADS must be a positive integer, got {env!r}")
        return int(env)
    return n if n > 0 else min(4, os.cpu_count() or 1)


def ransac_transform(src: np.ndarray, dst: np.ndarray, threshold: float = 0.05, iterations: int = 1000,
                     with_scale: bool = False, *, min_inliers: int, confidence: float = 0.999,
                     rng: np.random.Generator | int | None = 0) -> RansacResult:
    """Robust SE(3) (or Sim(3)) from 3D-3D correspondences: Umeyama inside RANSAC, then an inlier refit.

    src, dst: [N, 3] metres; threshold: inlier distance (m). Stops early by the usual confidence bound.
    `ok` is False when fewer than `min_inliers` agree (the caller's setting, e.g. `AlignConf.min_inliers`; the
    caller must not trust `T` then).
    """
    src = np.asarray(src, dtype=np.float64)
    dst = np.asarray(dst, dtype=np.float64)
    n = len(src)
    rng = np.random.default_rng(rng)
    if n < 3:
        return RansacResult(np.eye(4), np.zeros(n, bool), 0, float("inf"), False)
    best = np.zeros(n, bool)
    best_count, it, max_it = 0, 0, iterations
    thr2 = threshold * threshold
    pairs = ((0, 1), (0, 2), (1, 2))
    bsize = 32  # batches grow 32, 64, 128, 256: easy pairs stop after one small batch by the confidence bound
    while it < max_it:  # hypotheses are drawn and scored in vectorised batches (same estimator, ~50x faster)
        b = min(bsize, max_it - it)
        bsize = min(256, 2 * bsize)
        it += b
        idx = rng.integers(0, n, size=(b, 3))
        a, c = src[idx], dst[idx]  # [b, 3, 3]
        good = (idx[:, 0] != idx[:, 1]) & (idx[:, 0] != idx[:, 2]) & (idx[:, 1] != idx[:, 2])
        # distance pre-test (lossless): if all three points are inliers of some T, every pairwise distance is
        # preserved to within 2 * threshold (times the scale for Sim(3)). Most samples holding an outlier fail
        # here, before any SVD or scoring -- this is what makes failed pairs cheap.
        da = np.stack([np.linalg.norm(a[:, i] - a[:, j], axis=1) for i, j in pairs], 1)  # [b, 3]
        dc = np.stack([np.linalg.norm(c[:, i] - c[:, j], axis=1) for i, j in pairs], 1)
        if with_scale:  # a common scale s with |s * da - dc| < 2 thr on all three pairs must exist
            with np.errstate(divide="ignore", invalid="ignore"):
                lo = ((dc - 2 * threshold) / da).max(1)
                hi = ((dc + 2 * threshold) / da).min(1)
            good &= (lo <= hi) & (hi > 0)
        else:
            good &= (np.abs(da - dc) < 2 * threshold).all(1)
        if not good.any():
            continue
        a, c = a[good], c[good]
        area = np.linalg.norm(np.cross(a[:, 1] - a[:, 0], a[:, 2] - a[:, 0]), axis=1)
        ok_area = area >= 1e-9
        if not ok_area.any():
            continue
        Tb = umeyama_batch(a[ok_area], c[ok_area], with_scale)  # [g, 4, 4]
        g = len(Tb)
        pred = (src @ Tb[:, :3, :3].reshape(3 * g, 3).T).reshape(n, g, 3)  # one GEMM for all hypotheses
        pred += Tb[None, :, :3, 3]
        pred -= dst[:, None, :]
        inl_all = (np.einsum("ngk,ngk->gn", pred, pred) < thr2)  # [g, n]
        counts = inl_all.sum(1)
        k = int(np.argmax(counts))
        cnt = int(counts[k])
        if cnt > best_count:
            best, best_count = inl_all[k], cnt
            w = cnt / n
            denom = np.log(max(1e-12, 1 - w**3))
            if denom < 0:
                max_it = min(iterations, int(np.ceil(np.log(1 - confidence) / denom)) + 1)
    if best_count < 3:
        return RansacResult(np.eye(4), best, best_count, float("inf"), False, it)
    # refit on inliers twice (inlier set may grow once the model is refined)
    for _ in range(2):
        T = umeyama(src[best], dst[best], with_scale)
        err = np.linalg.norm(transform(T, src) - dst, axis=1)
        new = err < threshold
        if new.sum() < 3:
            break
        best = new
    T = umeyama(src[best], dst[best], with_scale)
    err = np.linalg.norm(transform(T, src[best]) - dst[best], axis=1)
    nin = int(best.sum())
    return RansacResult(T, best, nin, float(np.sqrt(np.mean(err**2))), nin >= min_inliers, it)


# ----------------------------------------------------------------------------- oriented boxes


@dataclass
class OrientedBox:
    """Oriented 3D box. centroid: [3]; axes_lengths: [3] full lengths (m); axes: [3, 3], rows = unit axes."""

    centroid: np.ndarray
    axes_lengths: np.ndarray
    axes: np.ndarray

    def corners(self) -> np.ndarray:
        """The 8 corners `[8, 3]`."""
        signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=np.float64)
        half = signs * (np.asarray(self.axes_lengths) / 2.0)
        return np.asarray(self.centroid) + half @ np.asarray(self.axes)

    def aabb(self) -> tuple[np.ndarray, np.ndarray]:
        """Axis-aligned min/max `[3]`, `[3]` of the corners."""
        c = self.corners()
        return c.min(0), c.max(0)

    def contains(self, pts: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """Which of `pts [N, 3]` are inside (with margin, m) -> `[N]` bool."""
        local = (np.asarray(pts) - self.centroid) @ np.asarray(self.axes).T
        return np.all(np.abs(local) <= np.asarray(self.axes_lengths) / 2 + margin, axis=1)

    @classmethod
    def from_meta(cls, m: dict[str, Any]) -> "OrientedBox":
        """From a VSI-Bench meta_info box dict (`centroid`, `axesLengths`, `normalizedAxes` row-major 3x3)."""
        return cls(np.asarray(m["centroid"], dtype=np.float64).reshape(3),
                   np.asarray(m["axesLengths"], dtype=np.float64).reshape(3),
                   np.asarray(m["normalizedAxes"], dtype=np.float64).reshape(3, 3))

    def to_meta(self) -> dict[str, Any]:
        lo, hi = self.aabb()
        return {"centroid": np.asarray(self.centroid).tolist(), "axesLengths": np.asarray(self.axes_lengths).tolist(),
                "normalizedAxes": np.asarray(self.axes).reshape(-1).tolist(), "min": lo.tolist(), "max": hi.tolist()}


def local_f32(*point_sets: np.ndarray) -> tuple[np.ndarray, list[np.ndarray]]:
    """(origin [D] float64, each set [N_i, D] minus it as float32): world coordinates for OpenCV's float32-only
    geometry (minAreaRect, convexHull, intersectConvexConvex) taken relative to a local origin in float64 (the
    first set's first point), so a map 10^6 m from its world origin measures as it does at 0 (float32 keeps ~7
    digits: absolute coordinates of 10^6 m lose the centimetres)."""
    sets = [np.asarray(p, dtype=np.float64) for p in point_sets]
    first = next((s.reshape(-1, s.shape[-1]) for s in sets if s.size), None)
    origin = first[0].copy() if first is not None else np.zeros(sets[0].shape[-1] if sets else 2)
    return origin, [(s - origin).astype(np.float32) for s in sets]


def min_area_rect(xy: np.ndarray) -> tuple[tuple[float, float], tuple[float, float], float]:
    """`cv2.minAreaRect` of points `[N, 2]` (N >= 1) in world coordinates, computed about a local origin in float64
    (`local_f32`): ((cx, cy), (w, h), angle in degrees)."""
    import cv2

    origin, (local,) = local_f32(np.asarray(xy, dtype=np.float64).reshape(-1, 2))
    (cx, cy), (w, h), ang = cv2.minAreaRect(local)
    return (float(cx + origin[0]), float(cy + origin[1])), (float(w), float(h)), float(ang)


def fit_gravity_box(points: np.ndarray, up: np.ndarray | None = None) -> OrientedBox:
    """Gravity-aligned oriented box around `points [N, 3]` in a z-up world: yaw from the floor-projected
    points (minimum-area rectangle of their 2D convex hull), z extent from min/max height."""
    pts = np.asarray(points, dtype=np.float64)
    xy = pts[:, :2]
    if len(pts) >= 3:
        (cx, cy), (w, h), ang = min_area_rect(xy)
    else:
        lo, hi = xy.min(0), xy.max(0)
        (cx, cy), (w, h), ang = tuple((lo + hi) / 2), tuple(hi - lo), 0.0
    a = np.radians(ang)
    ax0 = np.array([np.cos(a), np.sin(a), 0.0])
    ax1 = np.array([-np.sin(a), np.cos(a), 0.0])
    z0, z1 = pts[:, 2].min(), pts[:, 2].max()
    return OrientedBox(np.array([cx, cy, (z0 + z1) / 2]), np.array([w, h, z1 - z0]),
                       np.stack([ax0, ax1, np.array([0, 0, 1.0])]))


# ----------------------------------------------------------------------------- planar polygons, box distances


def convex_hull_2d(points: np.ndarray) -> np.ndarray:
    """Convex hull of `points [N, 2]` -> polygon `[P, 2]` counter-clockwise (Andrew's monotone chain).
    Degenerate inputs (fewer than 3 distinct points, collinear) return the distinct extreme points."""
    pts = np.unique(np.asarray(points, dtype=np.float64).reshape(-1, 2), axis=0)
    if len(pts) < 3:
        return pts
    if len(pts) > 64:
        pts = pts[~_inside_extremes(pts)]  # same hull, far fewer points for the Python loop below

    def half(seq: np.ndarray) -> list[np.ndarray]:
        h: list[np.ndarray] = []
        for p in seq:
            while len(h) >= 2 and ((h[-1][0] - h[-2][0]) * (p[1] - h[-2][1])
                                   - (h[-1][1] - h[-2][1]) * (p[0] - h[-2][0])) <= 0:
                h.pop()
            h.append(p)
        return h

    lower, upper = half(pts), half(pts[::-1])
    return np.array(lower[:-1] + upper[:-1])


def _inside_extremes(pts: np.ndarray) -> np.ndarray:
    """Mask of points strictly inside the polygon of the extreme points along x, y, x+y and x-y
    (Akl-Toussaint): they cannot be hull vertices. Vectorised; boundary points are kept."""
    keys = (pts[:, 0], pts[:, 1], pts[:, 0] + pts[:, 1], pts[:, 0] - pts[:, 1])
    idx = {int(np.argmin(k)) for k in keys} | {int(np.argmax(k)) for k in keys}
    poly = pts[sorted(idx)]
    if len(poly) < 3:
        return np.zeros(len(pts), bool)
    c = poly.mean(0)
    poly = poly[np.argsort(np.arctan2(poly[:, 1] - c[1], poly[:, 0] - c[0]))]  # counter-clockwise
    inside = np.ones(len(pts), bool)
    for a, b in zip(poly, np.roll(poly, -1, axis=0)):
        cross = (b[0] - a[0]) * (pts[:, 1] - a[1]) - (b[1] - a[1]) * (pts[:, 0] - a[0])
        inside &= cross > 1e-12 * max(1.0, float(np.abs(pts).max()))
    return inside


def polygon_area(polygon: np.ndarray) -> float:
    """Unsigned area (shoelace) of a simple polygon `[P, 2]`; 0 for fewer than 3 vertices."""
    p = np.asarray(polygon, dtype=np.float64).reshape(-1, 2)
    if len(p) < 3:
        return 0.0
    p = p - p[0]  # about a local origin: products of coordinates 10^6 m away would cancel the area's digits
    x, y = p[:, 0], p[:, 1]
    return float(abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))) / 2.0)


# The 12 edges of a box as corner-index pairs (corners in `OrientedBox.corners` order: index bits = x, y, z signs).
_BOX_EDGES = np.array([(i, i | bit) for i in range(8) for bit in (4, 2, 1) if not i & bit])


def _clamp_into_box(pts: np.ndarray, c: np.ndarray, axes: np.ndarray, half: np.ndarray) -> np.ndarray:
    """The point of a solid box closest to each point [N, 3] -> [N, 3] (clamped in the box's frame)."""
    return c + np.clip((pts - c) @ axes.T, -half, half) @ axes


def _edge_inside(p0: np.ndarray, p1: np.ndarray, c: np.ndarray, axes: np.ndarray, half: np.ndarray
                 ) -> np.ndarray | None:
    """A point of some segment p0[i] -> p1[i] inside the solid box (slab clipping), or None."""
    a, d = (p0 - c) @ axes.T, (p1 - p0) @ axes.T  # [E, 3] in the box's frame
    with np.errstate(divide="ignore", invalid="ignore"):
        t0, t1 = (-half - a) / d, (half - a) / d
    lo, hi = np.where(d != 0, np.minimum(t0, t1), -np.inf), np.where(d != 0, np.maximum(t0, t1), np.inf)
    outside = (d == 0) & (np.abs(a) > half + 1e-12)  # parallel to a slab and outside it
    lo, hi = np.maximum(lo.max(1), 0.0), np.minimum(hi.min(1), 1.0)
    ok = np.flatnonzero((lo <= hi + 1e-12) & ~outside.any(1))
    return None if not len(ok) else p0[ok[0]] + 0.5 * (lo[ok[0]] + hi[ok[0]]) * (p1[ok[0]] - p0[ok[0]])


def _segments_closest(p1: np.ndarray, q1: np.ndarray, p2: np.ndarray, q2: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray]:
    """Closest points of segment pairs p1[i]q1[i] and p2[i]q2[i] (Ericson, Real-Time Collision Detection 5.1.9,
    vectorised; degenerate segments are points). Returns the points on the first and second segments [N, 3]."""
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a, e = (d1 * d1).sum(1), (d2 * d2).sum(1)
    b, c, f = (d1 * d2).sum(1), (d1 * r).sum(1), (d2 * r).sum(1)
    eps = 1e-18
    sa, se = np.where(a > eps, a, 1.0), np.where(e > eps, e, 1.0)
    den = a * e - b * b
    s = np.where(den > eps, np.clip((b * f - c * e) / np.where(den > eps, den, 1.0), 0, 1), 0.0)
    t = (b * s + f) / se
    s = np.where(t < 0, np.clip(-c / sa, 0, 1), np.where(t > 1, np.clip((b - c) / sa, 0, 1), s))
    t = np.clip(t, 0, 1)
    s = np.where(a > eps, np.where(e > eps, s, np.clip(-c / sa, 0, 1)), 0.0)
    t = np.where(e > eps, np.where(a > eps, t, np.clip(f / se, 0, 1)), 0.0)
    return p1 + d1 * s[:, None], p2 + d2 * t[:, None]


def box_closest_points(a: "OrientedBox", b: "OrientedBox") -> tuple[float, np.ndarray, np.ndarray]:
    """Closest points of two solid oriented boxes: (distance m, point on a [3], point on b [3]).

    Exact, numpy only (no solver import on the question path): overlapping boxes (a corner or edge of one
    inside the other) give 0 and a common point; otherwise the closest pair of two disjoint convex polytopes
    is corner-to-solid or edge-to-edge, so the minimum over the 16 corners and the 144 edge pairs is exact.
    """
    Aa, Ab = np.asarray(a.axes, np.float64), np.asarray(b.axes, np.float64)
    ha, hb = np.asarray(a.axes_lengths, np.float64) / 2, np.asarray(b.axes_lengths, np.float64) / 2
    ca, cb = np.asarray(a.centroid, np.float64), np.asarray(b.centroid, np.float64)
    va, vb = a.corners().astype(np.float64), b.corners().astype(np.float64)
    for p0, p1, c, ax, h in ((va[_BOX_EDGES[:, 0]], va[_BOX_EDGES[:, 1]], cb, Ab, hb),
                             (vb[_BOX_EDGES[:, 0]], vb[_BOX_EDGES[:, 1]], ca, Aa, ha)):
        inside = _edge_inside(p0, p1, c, ax, h)  # corners are edge end points: covered here too
        if inside is not None:
            return 0.0, inside, inside.copy()
    on_b, on_a = _clamp_into_box(va, cb, Ab, hb), _clamp_into_box(vb, ca, Aa, ha)
    ia, ib = np.repeat(_BOX_EDGES, 12, axis=0), np.tile(_BOX_EDGES, (12, 1))
    ea, eb = _segments_closest(va[ia[:, 0]], va[ia[:, 1]], vb[ib[:, 0]], vb[ib[:, 1]])
    P = np.concatenate([va, on_a, ea])  # points on a
    Q = np.concatenate([on_b, vb, eb])  # their partners on b
    d = np.linalg.norm(P - Q, axis=1)
    k = int(np.argmin(d))
    return float(d[k]), P[k], Q[k]


def point_box_distance(p: np.ndarray, box: "OrientedBox") -> float:
    """Distance (m) from a point [3] to a solid oriented box (0 inside)."""
    c, ax = np.asarray(box.centroid, np.float64), np.asarray(box.axes, np.float64)
    p = np.asarray(p, np.float64).reshape(1, 3)
    return float(np.linalg.norm(p - _clamp_into_box(p, c, ax, np.asarray(box.axes_lengths, np.float64) / 2)))


def box_distance(a: "OrientedBox", b: "OrientedBox") -> float:
    """Shortest distance (m) between two solid oriented boxes (0 when they overlap)."""
    return box_closest_points(a, b)[0]


# ----------------------------------------------------------------------------- batched estimation, Sim(3) helpers


def umeyama_batch(src: np.ndarray, dst: np.ndarray, with_scale: bool = False) -> np.ndarray:
    """`umeyama` over a batch: src, dst [B, n, 3] (n >= 3) -> T [B, 4, 4] with dst ≈ s·R·src + t."""
    src = np.asarray(src, dtype=np.float64)
    dst = np.asarray(dst, dtype=np.float64)
    mu_s, mu_d = src.mean(1), dst.mean(1)  # [B, 3]
    xs, xd = src - mu_s[:, None], dst - mu_d[:, None]
    cov = np.einsum("bni,bnj->bij", xd, xs) / src.shape[1]
    U, D, Vt = np.linalg.svd(cov)
    sign = np.sign(np.linalg.det(U) * np.linalg.det(Vt))
    sign[sign == 0] = 1.0
    S = np.ones((len(src), 3))
    S[:, 2] = sign
    R = np.einsum("bij,bj,bjk->bik", U, S, Vt)
    s = np.ones(len(src))
    if with_scale:
        var_s = (xs**2).sum((1, 2)) / src.shape[1]
        s = np.where(var_s > 0, (D * S).sum(1) / np.where(var_s > 0, var_s, 1.0), 1.0)
    T = np.tile(np.eye(4), (len(src), 1, 1))
    T[:, :3, :3] = s[:, None, None] * R
    T[:, :3, 3] = mu_d - np.einsum("bij,bj->bi", T[:, :3, :3], mu_s)
    return T


def transform_scale(T: np.ndarray) -> float:
    """Uniform scale s of a similarity transform `[4, 4]` (1 for a rigid one)."""
    return float(np.cbrt(abs(np.linalg.det(np.asarray(T)[:3, :3]))))


def relative_pose(T_wa: np.ndarray, T_wb: np.ndarray) -> np.ndarray:
    """Pose of camera b in camera a's frame: inv(T_wa) @ T_wb, both `[4, 4]` camera-to-world."""
    return invert(T_wa) @ T_wb


def depth_normals(depth: np.ndarray, K: np.ndarray, stride: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Vertex and normal maps of a depth image (camera frame). depth: [H, W] metres (0 = invalid), K: [3, 3].
    Returns V [h, w, 3] and N [h, w, 3] (unit normals facing the camera; zeros where undefined), h = H // stride.
    Normals from central differences; undefined next to invalid pixels or depth jumps."""
    d = np.asarray(depth, dtype=np.float64)[::stride, ::stride]
    h, w = d.shape
    v, u = np.mgrid[0:h, 0:w].astype(np.float64) * stride
    V = np.stack([(u - K[0, 2]) / K[0, 0] * d, (v - K[1, 2]) / K[1, 1] * d, d], -1)
    N = np.zeros_like(V)
    dx = V[1:-1, 2:] - V[1:-1, :-2]
    dy = V[2:, 1:-1] - V[:-2, 1:-1]
    n = np.cross(dx, dy)
    ln = np.linalg.norm(n, axis=-1, keepdims=True)
    c = d[1:-1, 1:-1]
    nb = [d[1:-1, 2:], d[1:-1, :-2], d[2:, 1:-1], d[:-2, 1:-1]]
    ok = (c > 0) & (ln[..., 0] > 0)
    for q in nb:
        ok &= (q > 0) & (np.abs(q - c) < 0.05 * c + 0.01 * stride)
    n = np.where(ok[..., None], n / np.maximum(ln, 1e-12), 0.0)
    n *= np.where(np.sum(n * V[1:-1, 1:-1], -1, keepdims=True) > 0, -1.0, 1.0)  # face the camera
    N[1:-1, 1:-1] = n
    return V, N


def _se3_exp(xi: np.ndarray) -> np.ndarray:
    """Small-motion update [6] (rotation vector, translation) -> [4, 4] (rotation via Rodrigues)."""
    w, t = xi[:3], xi[3:]
    a = float(np.linalg.norm(w))
    R = np.eye(3) if a < 1e-12 else rotation_about(w / a, a)
    return make_pose(R, t)


def icp_point_to_plane(depth_a: np.ndarray, K_a: np.ndarray, depth_b: np.ndarray, K_b: np.ndarray,
                       T_ab: np.ndarray, iterations: int = 10, stride: int = 4,
                       max_dist: tuple[float, float] = (0.10, 0.02)) -> tuple[np.ndarray, float, int, float]:
    """Refine a rigid T_ab [4, 4] (b camera -> a camera) by projective point-to-plane ICP on two depth maps
    ([H, W] metres). Points of b (every `stride` pixels) are projected into a, paired with a's vertex there,
    and the linearised point-to-plane error minimised; the pairing distance shrinks from max_dist[0] to
    max_dist[1]. Returns (T_ab, RMS point-to-plane residual m, pairs used, overlap = pairs / valid b points)."""
    Va, Na = depth_normals(depth_a, K_a, 1)
    H, W = depth_a.shape
    pb, _ = backproject(depth_b, K_b, stride=stride)
    if len(pb) < 6:
        return T_ab, float("inf"), 0, 0.0
    T = np.array(T_ab, dtype=np.float64)
    rms, n_used = float("inf"), 0
    for it in range(iterations):
        md = max_dist[0] + (max_dist[1] - max_dist[0]) * min(1.0, it / max(1, iterations - 3))
        p = transform(T, pb)
        z = p[:, 2]
        ok = z > 1e-6
        u = np.full(len(p), -1)
        v = np.full(len(p), -1)
        u[ok] = np.round(K_a[0, 0] * p[ok, 0] / z[ok] + K_a[0, 2]).astype(int)
        v[ok] = np.round(K_a[1, 1] * p[ok, 1] / z[ok] + K_a[1, 2]).astype(int)
        ok &= (u >= 0) & (u < W) & (v >= 0) & (v < H)
        q = np.zeros_like(p)
        n = np.zeros_like(p)
        q[ok], n[ok] = Va[v[ok], u[ok]], Na[v[ok], u[ok]]
        ok &= (q[:, 2] > 0) & (np.abs(n).sum(1) > 0) & (np.linalg.norm(q - p, axis=1) < md)
        n_used = int(ok.sum())
        if n_used < 6:
            break
        P, Q, Nn = p[ok], q[ok], n[ok]
        r = np.sum(Nn * (Q - P), 1)
        A = np.concatenate([np.cross(P, Nn), Nn], 1)
        rms = float(np.sqrt(np.mean(r**2)))
        try:
            xi = np.linalg.solve(A.T @ A + 1e-9 * np.eye(6), A.T @ r)
        except np.linalg.LinAlgError:
            break
        T = _se3_exp(xi) @ T
        if np.linalg.norm(xi) < 1e-6:
            break
    return T, rms, n_used, n_used / len(pb)


def box_footprint(box: Any) -> np.ndarray:
    """Floor footprint `[4, 2]` of an oriented box (corners of the bottom face, in order): the two axes closest to
    horizontal span it. Pure; shared by the visual prompt and fusion's footprint merge."""
    c = np.asarray(box.centroid)[:2]
    ax = np.asarray(box.axes)
    L = np.asarray(box.axes_lengths) / 2
    horiz = np.argsort(np.abs(ax[:, 2]))[:2]
    a, b = ax[horiz[0], :2] * L[horiz[0]], ax[horiz[1], :2] * L[horiz[1]]
    return np.stack([c - a - b, c + a - b, c + a + b, c - a + b])


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


# ----------------------------------------------------------------------------- image regions


def in_boxes(uv: np.ndarray, boxes: np.ndarray | None, margin: float = 0.0) -> np.ndarray:
    """Which pixels uv [N, 2] lie inside any of boxes [B, 4] (x0, y0, x1, y1) -> [N] bool (all True if None)."""
    if boxes is None:
        return np.ones(len(uv), bool)
    b = np.asarray(boxes, dtype=np.float32).reshape(-1, 4)
    if len(b) == 0:
        return np.zeros(len(uv), bool)
    x, y = uv[:, :1], uv[:, 1:2]
    inside = (x >= b[:, 0] - margin) & (x <= b[:, 2] + margin) & (y >= b[:, 1] - margin) & (y <= b[:, 3] + margin)
    return inside.any(1)


# ----------------------------------------------------------------------------- depth scale/shift fits


@dataclass
class ScaleShift:
    """z_metric = s * pred + t (relative) or 1 / (s * pred + t) (relative_inverse); n: points used;
    residual: median absolute residual of the fit (in the fitted space)."""

    s: float
    t: float
    n: int
    residual: float
    semantics: str = "relative"
    method: str = ""

    def apply(self, pred: np.ndarray, min_depth: float = 0.05, max_depth: float = 20.0) -> np.ndarray:
        """pred [H, W] -> metric depth [H, W] float32, 0 where the result is not a plausible depth."""
        v = self.s * pred.astype(np.float64) + self.t
        if self.semantics == "relative_inverse":
            with np.errstate(divide="ignore"):
                v = np.where(v > 1e-6, 1.0 / np.maximum(v, 1e-6), 0.0)
        out = np.where((v >= min_depth) & (v <= max_depth), v, 0.0)
        return out.astype(np.float32)

    def to_dict(self) -> dict[str, Any]:
        return {"s": self.s, "t": self.t, "n": self.n, "residual": self.residual, "semantics": self.semantics,
                "method": self.method}


def robust_line_fit(x: np.ndarray, y: np.ndarray, shift: bool, trim_rounds: int = 2
                    ) -> tuple[float, float, int, float]:
    """Least squares y ~ s x + t (t = 0 unless `shift`) over x, y [N], `trim_rounds` rounds dropping residuals
    above 2.5 x MAD. Returns (s, t, points kept, median absolute residual of the kept)."""
    keep = np.ones(len(x), bool)
    s, t = 1.0, 0.0
    for r in range(trim_rounds + 1):
        xs, ys = x[keep], y[keep]
        if len(xs) < (2 if shift else 1):
            break
        if shift:
            A = np.stack([xs, np.ones_like(xs)], 1)
            (s, t), *_ = np.linalg.lstsq(A, ys, rcond=None)
        else:
            s, t = float(xs @ ys / max(xs @ xs, 1e-12)), 0.0
        res = np.abs(s * x + t - y)
        if r < trim_rounds:
            mad = np.median(res[keep]) + 1e-12
            keep = res <= 2.5 * 1.4826 * mad
    res = np.abs(s * x[keep] + t - y[keep])
    return float(s), float(t), int(keep.sum()), float(np.median(res)) if len(res) else float("inf")


def fit_scale_shift(d: np.ndarray, z: np.ndarray, semantics: str, shift: bool, method: str) -> ScaleShift:
    """(s, t) mapping depth-model values d [N] to metric (or map-unit) depths z [N] > 0 in `semantics`
    (relative: z ~ s d + t; relative_inverse: 1/z ~ s d + t; metric_m: scale only)."""
    if len(d) < 3:
        raise InputError(f"depth scale recovery ({method}): only {len(d)} valid correspondences (need >= 3)")
    if semantics == "metric_m":
        shift = False
    y = 1.0 / z if semantics == "relative_inverse" else z
    s, t, n, res = robust_line_fit(d, y, shift)
    return ScaleShift(s, t, n, res, semantics if semantics != "metric_m" else "relative", method)
