"""Pairwise edges for sensor (metric) depth that do not need depth at both ends of a match.

The paper's edge lifts every match to 3D with each frame's depth (`pairwise.align_pair`, 3D-3D). Real RGB-D
sensors leave holes exactly where the features are (far walls, windows, glass; a HoloLens covers ~60 % of the
pixels) and the 3D-3D edge then fails for want of matches with depth in BOTH frames. What RGB-D trackers do
instead, in order of preference (`rgbd_edge`):

1. "3d-3d": the paper's edge, where enough matches have depth at both ends;
2. "pnp": 3D-2D: the matches with depth in one frame are lifted there and the other frame's pose is solved from
   their pixels (`cv2.solvePnPRansac` + Levenberg-Marquardt on the inliers); the side with more lifted matches
   is used;
3. "essential": 2D-2D: the essential matrix gives the rotation and the translation direction, the length comes
   from whatever depth the triangulated inliers have in either frame (metres, so one pooled median).

Each returns an `EdgeResult` (an `pairwise.PairResult` that says which method made it). Pure functions over
arrays (frames: objects with .rgb, .depth [H, W] metres, 0 = invalid, .K [3, 3], .dist).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from ..geometry import backproject_pixels, invert, sample_depth
from .conf import SOLVER_MIN_POINTS, AlignConf
from .essential import essential_pose
from .matching import Matches
from .pairwise import PairResult, _undistort, align_pair, depth_smooth


@dataclass
class EdgeResult(PairResult):
    """A `PairResult` with the method that made it ("3d-3d", "pnp", "essential"; "" when every method failed)
    and, for a failure, each method's reason."""

    method: str = ""

    def to_dict(self) -> dict[str, Any]:
        return {**super().to_dict(), "method": self.method}


def _as_edge(r: PairResult, method: str) -> EdgeResult:
    return EdgeResult(r.T_ab, r.ok, r.n_matches, r.n_valid, r.n_inliers, r.residual_m, r.seconds, r.reason, r.icp,
                      r.icp_rms_m, r.scale_a, r.scale_b, method=method if r.ok else "")


def lifted(m: Matches, fa: Any, fb: Any, conf: AlignConf) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per match [M]: sampled depth in a and b (metres), and whether each end's depth is usable for lifting
    (valid, below `max_depth_m`, and smooth around the pixel: `pairwise.depth_smooth`)."""
    za = sample_depth(fa.depth, m.uv0)
    zb = sample_depth(fb.depth, m.uv1)
    ua = (za > 0) & (za < conf.max_match_depth_m)
    ub = (zb > 0) & (zb < conf.max_match_depth_m)
    if conf.edge_radius > 0:
        q = np.flatnonzero(ua)
        ua[q] = depth_smooth(fa.depth, m.uv0[q], conf.edge_radius, conf.edge_rel)
        q = np.flatnonzero(ub)
        ub[q] = depth_smooth(fb.depth, m.uv1[q], conf.edge_radius, conf.edge_rel)
    return za, zb, ua, ub


def pnp_pair(m: Matches, fa: Any, fb: Any, conf: AlignConf, px: float = 2.0, iterations: int = 500,
             rng: np.random.Generator | int | None = 0) -> EdgeResult:
    """3D-2D edge: T_ab [4, 4] (b camera -> a camera) from the matches with usable depth in ONE frame (the side
    with more of them): those are lifted there and the other frame's pose is solved from their pixels (EPnP in
    RANSAC at `px` pixels of reprojection error, then Levenberg-Marquardt on the inliers, inliers re-counted).
    Fails with fewer than `edge_min_inliers` inliers or an inlier ratio below `min_inlier_ratio`."""
    import cv2

    t0 = time.perf_counter()
    za, zb, ua, ub = lifted(m, fa, fb, conf)
    use_a = ua.sum() >= ub.sum()
    sel = ua if use_a else ub
    n = int(sel.sum())

    def fail(why: str, ninl: int = 0) -> EdgeResult:
        return EdgeResult(np.eye(4), False, len(m), n, ninl, float("inf"), time.perf_counter() - t0, why)

    need = conf.edge_min_inliers
    if n < max(SOLVER_MIN_POINTS["pnp"], need):
        return fail(f"only {n} matches with depth in one frame (need {need})")
    src, dst = (fa, fb) if use_a else (fb, fa)
    uv_src = (m.uv0 if use_a else m.uv1)[sel]
    uv_dst = (m.uv1 if use_a else m.uv0)[sel].astype(np.float64)
    X = backproject_pixels(_undistort(uv_src, src.K, getattr(src, "dist", None)), (za if use_a else zb)[sel], src.K)
    dist = getattr(dst, "dist", None)
    dist = None if dist is None else np.asarray(dist, np.float64)
    seed = int(np.random.default_rng(rng).integers(1 << 30)) if not isinstance(rng, int) else rng
    cv2.setRNGSeed(seed)
    ok, rvec, tvec, inl = cv2.solvePnPRansac(X.astype(np.float64), uv_dst, dst.K, dist, iterationsCount=iterations,
                                             reprojectionError=px, confidence=0.999, flags=cv2.SOLVEPNP_EPNP)
    if not ok or inl is None or len(inl) < 6:
        return fail("no PnP solution")
    inl = inl.ravel()
    rvec, tvec = cv2.solvePnPRefineLM(X[inl], uv_dst[inl], dst.K, dist, rvec, tvec)
    proj, _ = cv2.projectPoints(X, rvec, tvec, dst.K, dist)
    R = cv2.Rodrigues(rvec)[0]
    zc = X @ R[2] + float(tvec.ravel()[2])
    err = np.linalg.norm(proj.reshape(-1, 2) - uv_dst, axis=1)
    good = (err < px) & (zc > 0)
    ninl = int(good.sum())
    if ninl < need:
        return fail(f"{ninl} PnP inliers (need {need})", ninl)
    if ninl < conf.min_inlier_ratio * n:
        return fail(f"PnP inlier ratio {ninl / n:.2f} below {conf.min_inlier_ratio}", ninl)
    T = np.eye(4)  # src camera -> dst camera
    T[:3, :3], T[:3, 3] = R, tvec.ravel()
    T_ab = invert(T) if use_a else T
    return EdgeResult(T_ab, True, len(m), n, ninl, float(np.median(err[good])), time.perf_counter() - t0,
                      method="pnp")


def essential_metric_pair(m: Matches, fa: Any, fb: Any, conf: AlignConf, px: float = 2.0) -> EdgeResult:
    """2D-2D edge with metric scale: the essential matrix (`essential.essential_pose`: RANSAC + cheirality) gives
    R and the translation direction; its inliers are triangulated with a unit baseline and every one with a ray
    angle >= `min_parallax_deg` and sensor depth in EITHER frame votes for the baseline length (sensor depth /
    triangulated depth, in metres); the median of the pooled votes is the length. Fails with fewer than
    `min_scale_points` votes."""
    import cv2


    t0 = time.perf_counter()
    c = conf if conf.essential_px is not None else replace(conf, essential_px=px)
    pose = essential_pose(m, fa.K, fb.K, c, getattr(fa, "dist", None), getattr(fb, "dist", None))
    if isinstance(pose, PairResult):
        return _as_edge(pose, "essential")
    R, t, inl, xa, xb = pose.R, pose.t, pose.inl, pose.xa, pose.xb
    Xh = cv2.triangulatePoints(np.eye(3, 4), np.hstack([R, t[:, None]]), xa[inl].T, xb[inl].T)
    with np.errstate(divide="ignore", invalid="ignore"):
        X = (Xh[:3] / Xh[3]).T
    Xb = X @ R.T + t
    cb = -R.T @ t
    cosang = np.sum(X * (X - cb), 1) / np.maximum(np.linalg.norm(X, axis=1) * np.linalg.norm(X - cb, axis=1), 1e-12)
    par = np.degrees(np.arccos(np.clip(cosang, -1, 1)))
    da = sample_depth(fa.depth, pose.uva[inl])
    db = sample_depth(fb.depth, pose.uvb[inl])
    geo = np.isfinite(X).all(1) & (X[:, 2] > 0) & (Xb[:, 2] > 0) & (par >= conf.min_parallax_deg)
    va = geo & (da > 0) & (da < conf.max_match_depth_m)
    vb = geo & (db > 0) & (db < conf.max_match_depth_m)
    votes = np.concatenate([np.log(da[va] / X[va, 2]), np.log(db[vb] / Xb[vb, 2])])
    ninl = int(inl.sum())
    if len(votes) < conf.min_scale_points:
        return EdgeResult(np.eye(4), False, pose.n_matches, len(votes), ninl, float("inf"),
                          pose.seconds + time.perf_counter() - t0,
                          f"{len(votes)} essential inliers with parallax and depth (need {conf.min_scale_points})")
    s = float(np.exp(np.median(votes)))
    spread = float(np.median(np.abs(votes - np.log(s))))
    T = np.eye(4)  # x_b = R x_a + s t  ->  b camera -> a camera
    T[:3, :3] = R.T
    T[:3, 3] = -s * (R.T @ t)
    return EdgeResult(T, True, pose.n_matches, len(votes), ninl, spread, pose.seconds + time.perf_counter() - t0,
                      method="essential")


def rgbd_edge(m: Matches, fa: Any, fb: Any, conf: AlignConf, px: float = 2.0,
              rng: np.random.Generator | int | None = 0, methods: tuple[str, ...] = ("3d-3d", "pnp", "essential")
              ) -> EdgeResult:
    """The first of `methods` that verifies (module docstring); a failure carries every method's reason."""
    why = []
    t0 = time.perf_counter()
    for meth in methods:
        if meth == "3d-3d":
            r = _as_edge(align_pair(m, fa.depth, fa.K, fb.depth, fb.K, conf, False, rng, getattr(fa, "dist", None),
                                    getattr(fb, "dist", None)), "3d-3d")
        elif meth == "pnp":
            r = pnp_pair(m, fa, fb, conf, px, rng=rng)
        elif meth == "essential":
            r = essential_metric_pair(m, fa, fb, conf, px)
        else:
            raise ValueError(f"rgbd_edge: unknown method {meth!r}")
        if r.ok:
            r.seconds = time.perf_counter() - t0
            return r
        why.append(f"{meth}: {r.reason}")
    return EdgeResult(np.eye(4), False, len(m), 0, 0, float("inf"), time.perf_counter() - t0, "; ".join(why))
