"""Pairwise RGB-D edges (paper: cross-frame alignment): feature matches lifted to 3D with each frame's depth,
then `geometry.ransac_transform` (SE(3); Sim(3) per edge on relative depth). The best `max_matches` matches by score
are used; RANSAC rejects most outlier samples by a lossless distance pre-test before any SVD."""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..geometry import (backproject_pixels, icp_point_to_plane, ransac_transform, rotation_angle_deg, sample_depth,
                        transform, transform_scale, umeyama)
from .conf import SOLVER_MIN_POINTS, AlignConf
from .matching import Matches


@dataclass
class PairResult:
    """Pairwise alignment of frames a, b. T_ab [4, 4]: pose of camera b in camera a's frame (maps b-camera points
    to a-camera points; a similarity when estimated with scale)."""

    T_ab: np.ndarray
    ok: bool
    n_matches: int
    n_valid: int          # matches with valid depth in both frames
    n_inliers: int
    residual_m: float
    seconds: float
    reason: str = ""
    icp: str = ""         # "" (not tried), "applied", or why it was rejected
    icp_rms_m: float = float("nan")
    scale_a: float = float("nan")  # essential edges: baseline length in frame a's / b's depth units
    scale_b: float = float("nan")

    def to_dict(self) -> dict[str, Any]:
        return {"ok": self.ok, "matches": self.n_matches, "valid": self.n_valid, "inliers": self.n_inliers,
                "residual": round(float(self.residual_m), 5) if np.isfinite(self.residual_m) else None,
                "scale": round(transform_scale(self.T_ab), 5), "seconds": round(self.seconds, 5),
                "reason": self.reason, "icp": self.icp,
                "icp_rms": None if not np.isfinite(self.icp_rms_m) else round(float(self.icp_rms_m), 5)}


def align_pair(m: Matches, depth_a: np.ndarray, K_a: np.ndarray, depth_b: np.ndarray, K_b: np.ndarray,
               conf: AlignConf | None = None, with_scale: bool = False,
               rng: np.random.Generator | int | None = 0, dist_a: np.ndarray | None = None,
               dist_b: np.ndarray | None = None) -> PairResult:
    """Matches (uv0 in a, uv1 in b) -> 3D points via each frame's depth ([H, W] float32, 0 = invalid) and
    intrinsics K [3, 3] -> RANSAC transform T_ab (b camera -> a camera). dist_a/dist_b: OpenCV distortion
    coefficients; when given, the pixels are undistorted before back-projection (depth is read at the raw pixel)."""
    conf = conf or AlignConf()
    t0 = time.perf_counter()
    za = sample_depth(depth_a, m.uv0)
    zb = sample_depth(depth_b, m.uv1)
    ok = depth_valid(m, depth_a, depth_b, conf, with_scale, za, zb)
    if conf.edge_radius > 0:  # keypoints sit on corners, often on depth edges: their depth is unreliable
        q = np.flatnonzero(ok)
        ok[q] = depth_smooth(depth_a, m.uv0[q], conf.edge_radius, conf.edge_rel) & \
            depth_smooth(depth_b, m.uv1[q], conf.edge_radius, conf.edge_rel)
    if conf.max_matches and ok.sum() > conf.max_matches:  # keep the most distinctive matches (RANSAC cost ~ N)
        q = np.flatnonzero(ok)
        ok[:] = False
        ok[q[np.argsort(-m.scores[q], kind="stable")[:conf.max_matches]]] = True
    nv = int(ok.sum())
    need = conf.edge_min_inliers
    if nv < max(SOLVER_MIN_POINTS["3d-3d"], need):
        return PairResult(np.eye(4), False, len(m), nv, 0, float("inf"), time.perf_counter() - t0,
                          f"only {nv} matches with valid depth (need {need})")
    pa = backproject_pixels(_undistort(m.uv0[ok], K_a, dist_a), za[ok], K_a)
    pb = backproject_pixels(_undistort(m.uv1[ok], K_b, dist_b), zb[ok], K_b)
    thr = conf.threshold_m if not with_scale else conf.threshold_rel * float(np.median(za[ok]))
    # only a model with >= w_min inliers could be accepted: enough iterations to find one with 99.9%
    # confidence (fewer than `iterations` for small match sets; failed pairs are the common, costly case)
    w_min = min(1.0, max(need / nv, conf.min_inlier_ratio))
    its = conf.ransac_iterations if w_min >= 1.0 else \
        min(conf.ransac_iterations, int(np.ceil(np.log(1e-3) / np.log(max(1e-12, 1.0 - w_min**3)))) + 1)
    r = ransac_transform(pb, pa, threshold=thr, iterations=its, with_scale=with_scale,
                         min_inliers=need, rng=rng)
    reason = ""
    good = r.ok
    if good and conf.refine_m > 0:  # accept with the loose threshold, estimate from the tight inliers
        thr2 = conf.refine_m * (1.0 if not with_scale else thr / conf.threshold_m)
        T = r.T
        for _ in range(2):
            sel = np.linalg.norm(transform(T, pb) - pa, axis=1) < thr2
            if sel.sum() < max(SOLVER_MIN_POINTS["refit"], need // 2):
                break
            T = umeyama(pb[sel], pa[sel], with_scale)
        r.T = T
    if not r.ok:
        reason = f"{r.n_inliers} inliers (need {need})"
    elif r.n_inliers < conf.min_inlier_ratio * nv:
        good, reason = False, f"inlier ratio {r.n_inliers / nv:.2f} below {conf.min_inlier_ratio}"
    T, icp, icp_rms = r.T, "", float("nan")
    if good and conf.icp and not with_scale:
        T2, icp_rms, _n, overlap = icp_point_to_plane(depth_a, K_a, depth_b, K_b, r.T, conf.icp_iterations,
                                                      conf.icp_stride)
        dt, dr = pose_change(r.T, T2)
        if overlap < conf.icp_min_overlap:
            icp = f"rejected: overlap {overlap:.2f} < {conf.icp_min_overlap}"
        elif dt > conf.icp_max_change[0] or dr > conf.icp_max_change[1]:
            icp = f"rejected: moved {dt:.3f} m / {dr:.1f} deg from the RANSAC pose"
        else:
            T, icp = T2, "applied"
    return PairResult(T, good, len(m), nv, r.n_inliers, r.residual, time.perf_counter() - t0, reason, icp, icp_rms)


def depth_valid(m: Matches, depth_a: np.ndarray, depth_b: np.ndarray, conf: AlignConf, with_scale: bool,
                za: np.ndarray | None = None, zb: np.ndarray | None = None) -> np.ndarray:
    """[M] bool: matches with depth > 0 at both ends (and below `max_match_depth_m` for metric depth); za, zb: the
    sampled depths when already known."""
    za = sample_depth(depth_a, m.uv0) if za is None else za
    zb = sample_depth(depth_b, m.uv1) if zb is None else zb
    lim = conf.max_match_depth_m if not with_scale else np.inf
    return (za > 0) & (zb > 0) & (za < lim) & (zb < lim)


def _undistort(uv: np.ndarray, K: np.ndarray, dist: np.ndarray | None) -> np.ndarray:
    if dist is None or not np.any(dist):
        return uv
    import cv2

    pts = np.asarray(uv, np.float64).reshape(-1, 1, 2)
    return cv2.undistortPoints(pts, K, np.asarray(dist, np.float64), P=K).reshape(-1, 2)


def depth_smooth(depth: np.ndarray, uv: np.ndarray, radius: int = 3, rel: float = 0.05) -> np.ndarray:
    """For pixels uv [N, 2]: True where every depth in the (2r+1)^2 window is valid and max - min < rel * depth
    (not on a depth discontinuity, where a slightly misplaced sample jumps to the background) -> [N] bool."""
    H, W = depth.shape
    if len(uv) == 0:
        return np.zeros(0, bool)
    u = np.round(uv[:, 0]).astype(int)
    v = np.round(uv[:, 1]).astype(int)
    o = np.arange(-radius, radius + 1)
    uu = np.clip(u[:, None, None] + o[None, None, :], 0, W - 1)
    vv = np.clip(v[:, None, None] + o[None, :, None], 0, H - 1)
    win = depth[vv, uu].reshape(len(uv), -1)
    lo, hi = win.min(1), win.max(1)
    return (lo > 0) & np.isfinite(hi) & (hi - lo < rel * hi)


def pose_change(T_a: np.ndarray, T_b: np.ndarray) -> tuple[float, float]:
    """(translation m, rotation deg) between two poses [4, 4] (camera centres, relative rotation)."""
    d = np.linalg.norm(T_a[:3, 3] - T_b[:3, 3])
    Ra = T_a[:3, :3] / transform_scale(T_a)
    Rb = T_b[:3, :3] / transform_scale(T_b)
    return float(d), rotation_angle_deg(Ra.T @ Rb)
