"""Cross-frame and multi-frame alignment (paper: "Cross-frame alignment", "Multi-frame alignment").

Pairwise (`AlignConf.edge`):
- "rgbd" (metric depth): feature matches lifted to 3D with each frame's depth, then `geometry.ransac_transform`
  (SE(3); Sim(3) per edge when forced on relative depth). The best `max_matches` matches by score are used;
  RANSAC rejects most outlier samples by a lossless distance pre-test before any SVD.
- "essential" (relative, non-metric depth; chosen by "auto" when `with_scale=True`): `align_pair_essential` -
  5-point essential matrix (OpenCV USAC_MAGSAC) for rotation + translation direction; the depth only sets the
  translation length (median of predicted / unit-baseline triangulated depth over inliers with parallax). The
  per-frame depth scales are then solved over all verified edges (`essential_frame_scales`, scale_mode "graph")
  so the tree composes in one global scale (the root frame's depth unit). Measured on 7-Scenes (PyDNet++ +
  XFeat, K=32 evenly spaced): ATE 0.08 m against 0.53 m for rgbd Sim(3) edges on the same frames.

Multi-frame (strategy "mst"):
1. frame-similarity matrix S [K, K]: cosine similarity of per-frame embeddings when given, otherwise the
   correlation of colour histograms (HSV, 16 hue x 8 saturation x 4 value bins, OpenCV's HISTCMP_CORREL);
2. root = frame with the largest total similarity;
3. geometric refinement of S (`verify_top`, default 4): each frame's 4 most similar frames are aligned
   pairwise (plus time neighbours for essential edges); a verified pair weighs 1 + its RANSAC inlier count, a
   failed pair is removed, untried pairs keep their similarity (< 1, so they rank after every verified pair).
   Measured on 7-Scenes: colour histograms alone pick wide-baseline pairs whose few inliers give 10-25 cm
   errors (ATE 0.11 m at K=32 instead of 0.05);
4. maximum spanning tree by Kruskal over these weights. An edge that would join two components and has not
   been aligned yet is aligned then; when an alignment fails (too few inliers or too low an inlier ratio) the
   edge is dropped and Kruskal moves on to the next-best edge (failed-edge handling);
5. the pose of every frame = composition of the pairwise transforms along its unique tree path to the root,
   expressed in the root camera's frame. Frames outside the root's component are reported as unaligned and
   get no pose.

Strategy "sequential" is the paper's naive baseline: frames in time order, chained t -> t+1; a failed link
keeps the previous pose (those frames are listed in `guessed`).
"""
from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass, field, replace
from typing import Any, ClassVar, Mapping, Sequence

import numpy as np

from .config import StageConf
from .errors import AlignmentError, InputError
from .geometry import (backproject_pixels, icp_point_to_plane, ransac_transform, rotation_angle_deg, sample_depth,
                       transform, transform_scale, umeyama)
from .matching import FeatureMatcher, Matches


@dataclass
class AlignConf(StageConf):
    """Defaults of the alignment stage (`AlignConf.merged(overrides)`, see config.StageConf)."""

    conf_name: ClassVar[str] = "alignment config"

    threshold_m: float = 0.05          # RANSAC inlier distance for metric depth (m)
    threshold_rel: float = 0.025       # ... for relative depth (with_scale): fraction of the median depth
    refine_m: float = 0.02             # final least-squares refit on matches within this distance (m; for
                                       # relative depth scaled like threshold_rel); 0 = off
    iterations: int = 1000
    max_matches: int = 400             # matches with valid depth kept per pair, best scores first (0 = all)
    min_inliers: int = 20              # fewer inliers = failed edge
    min_inlier_ratio: float = 0.15     # inliers / matches with depth, below = failed edge (random matches)
    max_depth_m: float = 10.0          # ignore depth beyond this (sensor noise)
    edge_radius: int = 3               # a match's depth must be smooth in a (2r+1)^2 window (0 = off) ...
    edge_rel: float = 0.05             # ... i.e. max - min depth there below this fraction of its depth
    hist_bins: tuple[int, int, int] = (16, 8, 4)
    icp: bool = False                  # refine metric edges by point-to-plane ICP on the two depth maps (off:
                                       # on 7-Scenes it did not lower ATE and costs ~0.1 s per edge; ICP
                                       # started AT the ground truth moves 1-5 cm, i.e. GT noise dominates)
    icp_iterations: int = 10
    icp_stride: int = 4
    icp_max_change: tuple[float, float] = (0.10, 5.0)  # (m, deg) larger ICP corrections are rejected
    icp_min_overlap: float = 0.2       # fraction of b's points paired in a, below = ICP rejected
    verify_top: int = 4                # geometric refinement: each frame's top-k similar frames are aligned first
                                       # and the tree prefers edges with more inliers (0 = order by S only).
                                       # Measured: 3 keeps SIFT's accuracy with 63 instead of 80 pairs at K=32,
                                       # but ORB's tree then takes wrong edges (uniform K=64 ATE 0.16 vs 0.05 m),
                                       # and essential edges get worse (0.13 vs 0.08 m)
    verify_neighbours: int | None = None  # ... plus each frame's n time neighbours; None = 1 for essential edges
                                       # (their inlier counts favour short, ill-conditioned baselines: measured
                                       # ATE 0.12 -> 0.08 m at K=32) and 0 for rgbd edges (the paper's
                                       # similarity alone; SIFT + sensor depth meets its targets without)
    max_attempts: int | None = None    # cap on pairwise alignments tried by Kruskal (None = as many as needed)
    seed: int = 0
    # edge type: "rgbd" = 3D-3D RANSAC on depth-lifted matches (SE(3) metric / Sim(3) relative); "essential" =
    # 5-point essential matrix for rotation + translation direction, the depth only sets the translation
    # length (`align_pair_essential`); "auto" = essential when depth is relative (with_scale), else rgbd
    edge: str = "auto"
    essential_px: float | None = None  # essential-matrix RANSAC threshold (pixels, Sampson distance); None =
                                       # the matcher's `keypoint_px` (keypoint localisation noise) or 1.0.
                                       # Measured on 7-Scenes: SIFT best at 1 px (ATE 0.03 vs 0.11 m at 2 px),
                                       # XFeat at 2 px (0.09 vs 0.14 m at 1 px)
    essential_method: str = "magsac"   # OpenCV robust estimator: "magsac" (USAC_MAGSAC, local optimisation),
                                       # "accurate" (USAC_ACCURATE) or "ransac" (classic RANSAC; measured worse)
    essential_matches: int = 800       # matches kept for the essential matrix, best scores first (0 = all)
    essential_refine: bool = True      # Sampson-error least squares (Huber) on the inliers after RANSAC
                                       # (measured on 7-Scenes + XFeat: ATE lower in 4 of 5 subsets, ~20 ms/edge)
    min_parallax_deg: float = 1.0      # triangulated points with a smaller ray angle do not vote on the scale
    min_scale_points: int = 8          # fewer voting points = failed edge
    scale_mode: str = "graph"          # "chain": each frame's relative depth has its own scale, the edge carries
                                       # the ratio (Sim(3) edge; scale composes along the tree); "graph": the same,
                                       # but the per-frame scales are solved over ALL verified edges
                                       # (`essential_frame_scales`) before composing; "shared": one scale for
                                       # every frame's depth (rigid edge, baseline = geometric mean)



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
    lim = conf.max_depth_m if not with_scale else np.inf
    ok = (za > 0) & (zb > 0) & (za < lim) & (zb < lim)
    if conf.edge_radius > 0:  # keypoints sit on corners, often on depth edges: their depth is unreliable
        q = np.flatnonzero(ok)
        ok[q] = depth_smooth(depth_a, m.uv0[q], conf.edge_radius, conf.edge_rel) & \
            depth_smooth(depth_b, m.uv1[q], conf.edge_radius, conf.edge_rel)
    if conf.max_matches and ok.sum() > conf.max_matches:  # keep the most distinctive matches (RANSAC cost ~ N)
        q = np.flatnonzero(ok)
        ok[:] = False
        ok[q[np.argsort(-m.scores[q], kind="stable")[:conf.max_matches]]] = True
    nv = int(ok.sum())
    if nv < max(3, conf.min_inliers):
        return PairResult(np.eye(4), False, len(m), nv, 0, float("inf"), time.perf_counter() - t0,
                          f"only {nv} matches with valid depth (need {conf.min_inliers})")
    pa = backproject_pixels(_undistort(m.uv0[ok], K_a, dist_a), za[ok], K_a)
    pb = backproject_pixels(_undistort(m.uv1[ok], K_b, dist_b), zb[ok], K_b)
    thr = conf.threshold_m if not with_scale else conf.threshold_rel * float(np.median(za[ok]))
    # only a model with >= w_min inliers could be accepted: enough iterations to find one with 99.9%
    # confidence (fewer than `iterations` for small match sets; failed pairs are the common, costly case)
    w_min = min(1.0, max(conf.min_inliers / nv, conf.min_inlier_ratio))
    its = conf.iterations if w_min >= 1.0 else \
        min(conf.iterations, int(np.ceil(np.log(1e-3) / np.log(max(1e-12, 1.0 - w_min**3)))) + 1)
    r = ransac_transform(pb, pa, threshold=thr, iterations=its, with_scale=with_scale,
                         min_inliers=conf.min_inliers, rng=rng)
    reason = ""
    good = r.ok
    if good and conf.refine_m > 0:  # accept with the loose threshold, estimate from the tight inliers
        thr2 = conf.refine_m * (1.0 if not with_scale else thr / conf.threshold_m)
        T = r.T
        for _ in range(2):
            sel = np.linalg.norm(transform(T, pb) - pa, axis=1) < thr2
            if sel.sum() < max(6, conf.min_inliers // 2):
                break
            T = umeyama(pb[sel], pa[sel], with_scale)
        r.T = T
    if not r.ok:
        reason = f"{r.n_inliers} inliers (need {conf.min_inliers})"
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


def align_pair_essential(m: Matches, depth_a: np.ndarray, K_a: np.ndarray, depth_b: np.ndarray, K_b: np.ndarray,
                         conf: AlignConf | None = None, dist_a: np.ndarray | None = None,
                         dist_b: np.ndarray | None = None) -> PairResult:
    """Pairwise alignment for relative (non-metric) depth: the 5-point essential matrix (OpenCV, RANSAC) gives
    the rotation and the translation direction; the depth maps ([H, W], any consistent-per-frame unit, 0 =
    invalid) only set the translation length.

    Scale: the essential inliers are triangulated with a unit baseline; for points whose two rays meet at more
    than `min_parallax_deg`, the predicted depth over the triangulated depth is the baseline length in that
    frame's depth units; the median over the points gives s_a (frame a) and s_b (frame b). Returned T_ab (b camera
    -> a camera) is the similarity [(s_a / s_b) R_ba, s_a t_ba] in a's depth units (`scale_mode` "chain"), so
    composing edges along the tree keeps one global scale (the root's); "shared" assumes every frame's depth has
    the same unit and returns the rigid [R_ba, sqrt(s_a s_b) t_ba].
    Failed edges: too few matches or essential inliers, a degenerate essential matrix, or too few points with
    parallax and depth to fix the scale (pure rotation / tiny baseline)."""
    import cv2

    conf = conf or AlignConf()
    t0 = time.perf_counter()
    n = len(m)

    def fail(why: str, nv: int = 0, ninl: int = 0) -> PairResult:
        return PairResult(np.eye(4), False, n, nv, ninl, float("inf"), time.perf_counter() - t0, why)

    if n < max(8, conf.min_inliers):
        return fail(f"only {n} matches (need {max(8, conf.min_inliers)})")
    sel = np.arange(n)
    if conf.essential_matches and n > conf.essential_matches:
        sel = np.argsort(-m.scores, kind="stable")[:conf.essential_matches]
    elif conf.essential_method == "magsac-prosac":  # PROSAC samples the best scores first
        sel = np.argsort(-m.scores, kind="stable")
    uva, uvb = m.uv0[sel].astype(np.float64), m.uv1[sel].astype(np.float64)
    xa = cv2.undistortPoints(uva.reshape(-1, 1, 2), K_a, None if dist_a is None else np.asarray(dist_a, float))
    xb = cv2.undistortPoints(uvb.reshape(-1, 1, 2), K_b, None if dist_b is None else np.asarray(dist_b, float))
    xa, xb = xa.reshape(-1, 2), xb.reshape(-1, 2)
    f = 0.25 * (K_a[0, 0] + K_a[1, 1] + K_b[0, 0] + K_b[1, 1])
    px = conf.essential_px if conf.essential_px is not None else 1.0
    E, mask = _find_essential(xa, xb, px / f, conf.essential_method)
    if E is None or E.shape[0] < 3:
        return fail("no essential matrix", len(sel))
    q0 = np.flatnonzero(mask.ravel())  # cheirality test on the RANSAC inliers only (same result, less work)
    _n, R, t, m2 = cv2.recoverPose(E[:3], xa[q0], xb[q0], np.eye(3))
    mask2 = np.zeros(len(sel), np.uint8)
    mask2[q0[m2.ravel() > 0]] = 1
    inl = mask2.ravel() > 0
    ninl = int(inl.sum())
    if ninl < conf.min_inliers:
        return fail(f"{ninl} essential inliers (need {conf.min_inliers})", len(sel), ninl)
    if ninl < conf.min_inlier_ratio * len(sel):
        return fail(f"essential inlier ratio {ninl / len(sel):.2f} below {conf.min_inlier_ratio}", len(sel), ninl)
    t = t.reshape(3) / max(np.linalg.norm(t), 1e-12)  # x_b = R x_a + t, |t| = 1
    if conf.essential_refine:  # on at most 200 inliers, evenly picked (cost ~ points x iterations)
        q = np.flatnonzero(inl)
        q = q[np.linspace(0, len(q) - 1, min(len(q), 200)).astype(int)]
        R, t = refine_essential(R, t, xa[q], xb[q], px / f)
    Xh = cv2.triangulatePoints(np.eye(3, 4), np.hstack([R, t[:, None]]), xa[inl].T, xb[inl].T)
    with np.errstate(divide="ignore", invalid="ignore"):
        X = (Xh[:3] / Xh[3]).T  # [M, 3] in camera a, unit baseline
    Xb = X @ R.T + t
    cb = -R.T @ t  # centre of b in a
    ra, rb = X, X - cb
    cosang = np.sum(ra * rb, 1) / np.maximum(np.linalg.norm(ra, axis=1) * np.linalg.norm(rb, axis=1), 1e-12)
    par = np.degrees(np.arccos(np.clip(cosang, -1, 1)))
    da = sample_depth(depth_a, uva[inl])
    db = sample_depth(depth_b, uvb[inl])
    ok = np.isfinite(X).all(1) & (X[:, 2] > 0) & (Xb[:, 2] > 0) & (par >= conf.min_parallax_deg) & (da > 0) & (db > 0)
    nv = int(ok.sum())
    if nv < conf.min_scale_points:
        return fail(f"{nv} inliers with parallax >= {conf.min_parallax_deg} deg and depth (need "
                    f"{conf.min_scale_points}): baseline too small to fix the scale", nv, ninl)
    la = np.log(da[ok] / X[ok, 2])  # log baseline length in a's / b's depth units, per point
    lb = np.log(db[ok] / Xb[ok, 2])
    s_a, s_b = float(np.exp(np.median(la))), float(np.exp(np.median(lb)))
    spread = float(np.median(np.abs(la - np.log(s_a))))  # robust log-scale spread (residual)
    T = np.eye(4)
    if conf.scale_mode == "shared":
        T[:3, :3] = R.T
        T[:3, 3] = -np.sqrt(s_a * s_b) * (R.T @ t)
    else:
        T[:3, :3] = (s_a / s_b) * R.T
        T[:3, 3] = -s_a * (R.T @ t)
    return PairResult(T, True, n, nv, ninl, spread, time.perf_counter() - t0, scale_a=s_a, scale_b=s_b)


def _find_essential(xa: np.ndarray, xb: np.ndarray, thr: float, method: str) -> tuple[Any, Any]:
    """Robust essential matrix of normalised correspondences xa, xb [N, 2] -> (E, mask). "magsac":
    cv2.USAC_MAGSAC; "accurate": cv2.USAC_ACCURATE; "ransac": cv2.RANSAC; "magsac-prosac": MAGSAC++ scoring and
    sigma consensus with PROSAC sampling over the score order (xa, xb best first) - measured on 7-Scenes + XFeat
    K=32: 22% less CPU for the edges but ATE 0.089 m against 0.065-0.085 m for "magsac" over 5 match orders, so
    not the default."""
    import cv2

    if method == "magsac-prosac":
        p = cv2.UsacParams()
        p.confidence, p.maxIterations, p.threshold = 0.999, 1000, thr
        p.sampler, p.score, p.loMethod = cv2.SAMPLING_PROSAC, cv2.SCORE_METHOD_MAGSAC, cv2.LOCAL_OPTIM_SIGMA
        I3, z = np.eye(3), np.zeros(5)
        return cv2.findEssentialMat(xa, xb, I3, I3, z, z, params=p)
    flag = {"magsac": cv2.USAC_MAGSAC, "accurate": cv2.USAC_ACCURATE, "ransac": cv2.RANSAC}.get(method)
    if flag is None:
        raise InputError(f"alignment config: essential_method must be 'magsac', 'accurate', 'ransac' or "
                         f"'magsac-prosac', got {method!r}")
    return cv2.findEssentialMat(xa, xb, np.eye(3), method=flag, prob=0.999, threshold=thr)


def refine_essential(R: np.ndarray, t: np.ndarray, xa: np.ndarray, xb: np.ndarray, scale: float,
                     iterations: int = 20) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares refinement of a relative pose (x_b = R x_a + t, |t| = 1) on inlier correspondences in
    normalised coordinates xa, xb [N, 2]: Sampson error, Huber loss at `scale`, rotation as a rotation vector
    update and t on the unit sphere (2 tangent directions). Returns (R [3, 3], t [3]).

    Levenberg-Marquardt with Huber IRLS weights (the minimum of scipy's least_squares(loss="huber") on the same
    residuals); the Jacobian by forward differences, all 6 residual vectors in one batched evaluation (was
    scipy's trf with one Python call per difference: ~50 ms a pair, now ~1 ms)."""
    ha = np.hstack([xa, np.ones((len(xa), 1))])
    hb = np.hstack([xb, np.ones((len(xb), 1))])
    u = np.cross(t, [1.0, 0, 0] if abs(t[0]) < 0.9 else [0, 1.0, 0])
    u /= np.linalg.norm(u)
    v = np.cross(t, u)
    p = np.zeros(5)
    r = _sampson_batch(R, t, u, v, p[None], ha, hb)[0]
    cost = _huber_cost(r, scale)
    lam, eps = 1e-3, 1e-7
    for _ in range(iterations):
        P = np.vstack([p, p + eps * np.eye(5)])
        rr = _sampson_batch(R, t, u, v, P, ha, hb)          # [6, N]
        J = (rr[1:] - rr[0]).T / eps                        # [N, 5]
        a = np.abs(rr[0])
        w = np.where(a <= scale, 1.0, scale / np.maximum(a, 1e-300))  # Huber IRLS weights
        A = J.T @ (J * w[:, None])
        g = J.T @ (w * rr[0])
        improved = False
        for _ in range(6):
            step = np.linalg.solve(A + lam * np.diag(np.diag(A) + 1e-12), -g)
            r_new = _sampson_batch(R, t, u, v, (p + step)[None], ha, hb)[0]
            c_new = _huber_cost(r_new, scale)
            if c_new < cost:
                gain = cost - c_new
                p, cost, lam, improved = p + step, c_new, max(lam / 3, 1e-9), True
                break
            lam *= 4
        if not improved or gain < 1e-8 * cost:  # converged (scipy's ftol default)
            break
    return _pose_update(R, t, u, v, p[None])


def _huber_cost(r: np.ndarray, scale: float) -> float:
    a = np.abs(r)
    return float(np.sum(np.where(a <= scale, 0.5 * r * r, scale * a - 0.5 * scale * scale)))


def _pose_update(R: np.ndarray, t: np.ndarray, u: np.ndarray, v: np.ndarray, P: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Parameter rows P [B, 5] (rotation vector, two tangent steps of t) -> R [B, 3, 3], t [B, 3] (one row: unbatched)."""
    w = P[:, :3]
    ang = np.linalg.norm(w, axis=1)
    k = w / np.where(ang > 1e-12, ang, 1.0)[:, None]
    Kx = np.zeros((len(P), 3, 3))
    Kx[:, 0, 1], Kx[:, 0, 2], Kx[:, 1, 2] = -k[:, 2], k[:, 1], -k[:, 0]
    Kx -= Kx.transpose(0, 2, 1)
    s, c = np.sin(ang)[:, None, None], (1 - np.cos(ang))[:, None, None]
    Rn = (np.eye(3) + s * Kx + c * (Kx @ Kx)) @ R
    tn = t + P[:, 3:4] * u + P[:, 4:5] * v
    tn /= np.linalg.norm(tn, axis=1, keepdims=True)
    if len(P) == 1:
        return Rn[0], tn[0]
    return Rn, tn


def _sampson_batch(R: np.ndarray, t: np.ndarray, u: np.ndarray, v: np.ndarray, P: np.ndarray, ha: np.ndarray,
                   hb: np.ndarray) -> np.ndarray:
    """Signed Sampson errors [B, N] of homogeneous correspondences ha, hb [N, 3] for the poses of P [B, 5]."""
    B = len(P)
    Rn, tn = _pose_update(R, t, u, v, P)
    Rn, tn = Rn.reshape(B, 3, 3), tn.reshape(B, 3)
    tx = np.zeros((B, 3, 3))
    tx[:, 0, 1], tx[:, 0, 2], tx[:, 1, 2] = -tn[:, 2], tn[:, 1], -tn[:, 0]
    tx -= tx.transpose(0, 2, 1)
    E = tx @ Rn                                                   # [B, 3, 3]
    Ea = (ha @ E.reshape(3 * B, 3).T).reshape(len(ha), B, 3)      # E x_a, one GEMM for the batch
    Eb = (hb @ E.transpose(1, 0, 2).reshape(3, 3 * B)).reshape(len(hb), B, 3)  # E^T x_b
    num = np.einsum("nj,nbj->bn", hb, Ea)
    den = np.sqrt(Ea[..., 0]**2 + Ea[..., 1]**2 + Eb[..., 0]**2 + Eb[..., 1]**2).T + 1e-12
    return num / den


def essential_frame_scales(n: int, root: int, edges: Mapping[tuple[int, int], PairResult],
                           rounds: int = 3) -> np.ndarray:
    """Per-frame depth scales sigma [n] (global units per unit of frame k's relative depth, sigma[root] = 1) from
    every verified essential edge (a, b) -> PairResult with scale_a/scale_b (the pair's baseline in a's and b's
    depth units): the baseline is one length, so sigma_a * scale_a = sigma_b * scale_b. Solved in log space by
    least squares over all verified edges (a graph, not only the tree: each frame's scale is averaged over its
    edges instead of inheriting the errors of one path), re-weighted (Huber, 0.1 in log units) `rounds` times.
    Frames without a verified edge keep 1."""
    rows = [(a, b, np.log(r.scale_b) - np.log(r.scale_a), float(r.n_inliers))
            for (a, b), r in edges.items() if r.ok and r.scale_a > 0 and r.scale_b > 0]
    ls = np.zeros(n)
    if not rows:
        return np.ones(n)
    A = np.zeros((len(rows) + 1, n))
    y = np.zeros(len(rows) + 1)
    w0 = np.ones(len(rows) + 1)
    for k, (a, b, d, ninl) in enumerate(rows):  # log sigma_a - log sigma_b = log scale_b - log scale_a
        A[k, a], A[k, b], y[k] = 1.0, -1.0, d
        w0[k] = np.sqrt(ninl)
    A[-1, root], w0[-1] = 1.0, 1e3  # gauge: sigma_root = 1
    w = w0.copy()
    for _ in range(max(1, rounds)):
        ls = np.linalg.lstsq(A * w[:, None], y * w, rcond=None)[0]
        r = np.abs(A @ ls - y)
        w = w0 * np.where(r > 0.1, 0.1 / np.maximum(r, 1e-12), 1.0) ** 0.5
        w[-1] = w0[-1]
    return np.exp(ls)


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


# ----------------------------------------------------------------------------- similarity, root, spanning tree


def color_histograms(rgbs: Sequence[np.ndarray], bins: tuple[int, int, int] = (16, 8, 4)) -> np.ndarray:
    """HSV histograms of images [H, W, 3] uint8 RGB -> [K, prod(bins)] float64 (each sums to 1)."""
    import cv2

    out = []
    for rgb in rgbs:
        small = cv2.resize(rgb, (160, max(1, round(160 * rgb.shape[0] / rgb.shape[1]))),
                           interpolation=cv2.INTER_AREA)
        hsv = cv2.cvtColor(small, cv2.COLOR_RGB2HSV)
        h = cv2.calcHist([hsv], [0, 1, 2], None, list(bins), [0, 180, 0, 256, 0, 256]).ravel()
        out.append(h / max(h.sum(), 1e-12))
    return np.array(out, dtype=np.float64)


def similarity_matrix(rgbs: Sequence[np.ndarray] | None = None, embeddings: np.ndarray | None = None,
                      bins: tuple[int, int, int] = (16, 8, 4)) -> tuple[np.ndarray, str]:
    """Frame similarity S [K, K] (diagonal 0) and what it is: 'embedding_cosine' for embeddings [K, D],
    else 'color_hist_correlation' (Pearson correlation of HSV histograms, as cv2.HISTCMP_CORREL)."""
    if embeddings is not None:
        E = np.asarray(embeddings, dtype=np.float64)
        E = E / np.maximum(np.linalg.norm(E, axis=1, keepdims=True), 1e-12)
        S, kind = E @ E.T, "embedding_cosine"
    else:
        if rgbs is None:
            raise AlignmentError("similarity_matrix needs images or embeddings")
        H = color_histograms(rgbs, bins)
        H = H - H.mean(1, keepdims=True)
        H = H / np.maximum(np.linalg.norm(H, axis=1, keepdims=True), 1e-12)
        S, kind = H @ H.T, "color_hist_correlation"
    S = S.copy()
    np.fill_diagonal(S, 0.0)
    return S, kind


def choose_root(S: np.ndarray) -> int:
    """Row with the largest total similarity (ties -> the earliest frame)."""
    return int(np.argmax(S.sum(1)))


class _DSU:
    def __init__(self, n: int):
        self.p = list(range(n))

    def find(self, x: int) -> int:
        while self.p[x] != x:
            self.p[x] = self.p[self.p[x]]
            x = self.p[x]
        return x

    def union(self, a: int, b: int) -> bool:
        ra, rb = self.find(a), self.find(b)
        if ra == rb:
            return False
        self.p[rb] = ra
        return True


def maximum_spanning_tree(S: np.ndarray, verify=None, max_attempts: int | None = None
                          ) -> tuple[list[tuple[int, int]], list[tuple[int, int]]]:
    """Kruskal on weights S [K, K] (symmetric; only i < j used), heaviest first.

    verify(i, j) -> bool is called for every edge that would join two components; a False edge is skipped and
    the next-best edge tried (failed-edge handling). Returns (tree edges, failed edges), each as (i, j), i < j.
    The result is a maximum spanning forest when the verified graph is disconnected."""
    K = len(S)
    iu, ju = np.triu_indices(K, 1)
    order = np.argsort(-S[iu, ju], kind="stable")
    dsu = _DSU(K)
    tree: list[tuple[int, int]] = []
    failed: list[tuple[int, int]] = []
    for e in order:
        i, j = int(iu[e]), int(ju[e])
        if dsu.find(i) == dsu.find(j):
            continue
        if max_attempts is not None and len(tree) + len(failed) >= max_attempts:
            break
        if verify is not None and not verify(i, j):
            failed.append((i, j))
            continue
        dsu.union(i, j)
        tree.append((i, j))
        if len(tree) == K - 1:
            break
    return tree, failed


def refine_with_inliers(S: np.ndarray, verify, inliers, top: int,
                        extra: Sequence[tuple[int, int]] = ()) -> np.ndarray:
    """Edge weights refined by geometric verification: every frame's `top` most similar frames (by S [K, K])
    are aligned, plus the `extra` pairs (e.g. time neighbours); a verified pair weighs 1 + its inlier count, a
    failed one -1 (never used), an untried one keeps its similarity (in [-1, 1], so verified edges come first and
    untried ones are the next-best fallbacks). verify(i, j) -> bool, inliers(i, j) -> int (after verify).
    Returns W [K, K]."""
    K = len(S)
    W = np.array(S, dtype=np.float64)
    cand = {(min(i, j), max(i, j)) for i, j in extra if i != j}
    for i in range(K):
        for j in np.argsort(-S[i])[:min(top, K - 1)]:
            if int(j) != i:
                cand.add((min(i, int(j)), max(i, int(j))))
    for i, j in sorted(cand):
        W[i, j] = W[j, i] = (1.0 + inliers(i, j)) if verify(i, j) else -1.0
    return W


def compose_tree(root: int, edges: Sequence[tuple[int, int]], T: Mapping[tuple[int, int], np.ndarray]
                 ) -> tuple[dict[int, np.ndarray], dict[int, int]]:
    """Global poses along tree paths. T[(i, j)] = pose of j in i's camera frame (the reverse direction is
    derived). Returns ({node: pose [4, 4] in root's camera frame}, {node: parent}) for the root's component."""
    from .geometry import invert

    adj: dict[int, list[int]] = {}
    for i, j in edges:
        adj.setdefault(i, []).append(j)
        adj.setdefault(j, []).append(i)
    poses = {root: np.eye(4)}
    parent = {root: -1}
    q = deque([root])
    while q:
        p = q.popleft()
        for c in adj.get(p, []):
            if c in poses:
                continue
            T_pc = T[(p, c)] if (p, c) in T else invert(T[(c, p)])
            poses[c] = poses[p] @ T_pc
            parent[c] = p
            q.append(c)
    return poses, parent


# ----------------------------------------------------------------------------- multi-frame


@dataclass
class AlignmentResult:
    """poses: {frame index: T [4, 4] camera -> root camera frame}; root: frame index; edges: tree edges (or
    sequential links) as (frame index, frame index); unaligned: frame indices with no pose; guessed: frame
    indices whose pose was guessed (sequential baseline: a failed link keeps the previous pose);
    edge_stats: {(a, b): PairResult} for every pair tried."""

    poses: dict[int, np.ndarray]
    root: int
    edges: list[tuple[int, int]]
    unaligned: list[int]
    strategy: str
    guessed: list[int] = field(default_factory=list)
    edge_stats: dict[tuple[int, int], PairResult] = field(default_factory=dict)
    similarity: np.ndarray | None = None
    similarity_kind: str = ""
    with_scale: bool = False
    seconds: dict[str, float] = field(default_factory=dict)
    edge: str = "rgbd"    # pairwise edge type used: "rgbd" (3D-3D RANSAC) or "essential" (see AlignConf.edge)

    @property
    def aligned(self) -> list[int]:
        return [i for i in self.poses if i not in set(self.guessed)]

    def to_dict(self) -> dict[str, Any]:
        return {"strategy": self.strategy, "root": self.root, "edges": [list(e) for e in self.edges],
                "aligned": len(self.aligned), "unaligned": list(self.unaligned), "guessed": list(self.guessed),
                "similarity": self.similarity_kind, "with_scale": self.with_scale, "edge": self.edge,
                "pairs_tried": len(self.edge_stats), "pairs_failed": sum(not r.ok for r in self.edge_stats.values()),
                "edge_stats": {f"{a}-{b}": r.to_dict() for (a, b), r in self.edge_stats.items()},
                "seconds": {k: round(v, 4) for k, v in self.seconds.items()}}


def _make_matcher(matcher: Any) -> Any:
    if isinstance(matcher, str):
        return FeatureMatcher(matcher)
    if not hasattr(matcher, "match"):
        raise InputError(f"matcher must be 'orb', 'sift' or an object with .match(rgb0, rgb1, boxes0, boxes1), "
                         f"got {type(matcher).__name__}")
    return matcher


def _as_list(x: Any, frames: Sequence[Any], what: str) -> list[Any]:
    if x is None:
        return [None] * len(frames)
    if isinstance(x, Mapping):
        return [x.get(f.index) for f in frames]
    x = list(x)
    if len(x) != len(frames):
        raise InputError(f"{what}: {len(x)} entries for {len(frames)} frames")
    return x


def align_frames(frames: Sequence[Any], matcher: Any = "sift", strategy: str = "mst",
                 conf: AlignConf | Mapping[str, Any] | None = None, embeddings: np.ndarray | None = None,
                 boxes: Sequence[np.ndarray | None] | Mapping[int, np.ndarray] | None = None,
                 with_scale: bool = False, trace: Any = None) -> AlignmentResult:
    """Align frames (objects with .rgb [H, W, 3], .depth [H, W] metres (or relative depth with with_scale),
    .K [3, 3], .index) into the root camera's frame.

    matcher: 'sift' | 'orb' | an object with .match(rgb0, rgb1, boxes0, boxes1) -> Matches (features are cached
    per frame when it also has .match_keys); strategy: 'mst' | 'sequential'; embeddings: [K, D] for the
    similarity matrix (else colour histograms); boxes: per-frame [N, 4] boxes to restrict matching (list in frame
    order or {frame index: boxes}); with_scale: estimate Sim(3) per edge (relative, non-metric depth).
    """
    conf = AlignConf.merged(conf)
    if strategy not in ("mst", "sequential"):
        raise InputError(f"strategy must be 'mst' or 'sequential', got {strategy!r}")
    frames = list(frames)
    if len(frames) < 2:
        raise AlignmentError(f"need at least 2 frames to align, got {len(frames)}")
    for f in frames:
        if f.depth is None:
            raise AlignmentError(f"frame {f.index} has no depth: alignment needs sensor or model depth per frame")
    idx = [int(f.index) for f in frames]
    if len(set(idx)) != len(idx):
        raise InputError("align_frames: frame indices must be unique")
    if conf.edge not in ("auto", "rgbd", "essential"):
        raise InputError(f"alignment config: edge must be 'auto', 'rgbd' or 'essential', got {conf.edge!r}")
    if conf.scale_mode not in ("chain", "graph", "shared"):
        raise InputError(f"alignment config: scale_mode must be 'chain', 'graph' or 'shared', got "
                         f"{conf.scale_mode!r}")
    edge = conf.edge if conf.edge != "auto" else ("essential" if with_scale else "rgbd")
    m = _make_matcher(matcher)
    if edge == "essential" and conf.essential_px is None:
        conf = replace(conf, essential_px=float(getattr(m, "keypoint_px", 1.0)))
    box_list = _as_list(boxes, frames, "boxes")
    stats: dict[tuple[int, int], PairResult] = {}
    Tpair: dict[tuple[int, int], np.ndarray] = {}
    secs = {"match": 0.0, "ransac": 0.0}
    extract0 = getattr(m, "extract_seconds", 0.0)
    rng = np.random.default_rng(conf.seed)

    def verify(a: int, b: int) -> bool:
        fa, fb = frames[a], frames[b]
        t0 = time.perf_counter()
        if hasattr(m, "match_keys"):
            mt = m.match_keys(fa.index, fa.rgb, fb.index, fb.rgb, box_list[a], box_list[b])
        else:
            mt = m.match(fa.rgb, fb.rgb, box_list[a], box_list[b])
        secs["match"] += time.perf_counter() - t0
        if edge == "essential":
            r = align_pair_essential(mt, fa.depth, fa.K, fb.depth, fb.K, conf, getattr(fa, "dist", None),
                                     getattr(fb, "dist", None))
        else:
            r = align_pair(mt, fa.depth, fa.K, fb.depth, fb.K, conf, with_scale, rng, getattr(fa, "dist", None),
                           getattr(fb, "dist", None))
        secs["ransac"] += r.seconds
        stats[(fa.index, fb.index)] = r
        if r.ok:
            Tpair[(a, b)] = r.T_ab
        return r.ok

    ok_cache: dict[tuple[int, int], bool] = {}
    n_inl: dict[tuple[int, int], int] = {}

    def verify_cached(a: int, b: int) -> bool:
        a, b = min(a, b), max(a, b)
        if (a, b) not in ok_cache:
            ok_cache[(a, b)] = verify(a, b)
            n_inl[(a, b)] = stats[(frames[a].index, frames[b].index)].n_inliers if ok_cache[(a, b)] else 0
        return ok_cache[(a, b)]

    def stats_inliers(a: int, b: int) -> int:
        verify_cached(a, b)
        return n_inl[(min(a, b), max(a, b))]

    t_all = time.perf_counter()
    S, kind = None, ""
    guessed: list[int] = []
    if strategy == "mst":
        t0 = time.perf_counter()
        S, kind = similarity_matrix([f.rgb for f in frames] if embeddings is None else None, embeddings,
                                    conf.hist_bins)
        secs["similarity"] = time.perf_counter() - t0
        root = choose_root(S)
        t0 = time.perf_counter()
        W = S
        if conf.verify_top > 0:
            order = sorted(range(len(frames)), key=lambda k: (frames[k].t, idx[k]))
            n_nb = conf.verify_neighbours if conf.verify_neighbours is not None else int(edge == "essential")
            nb = [(order[p], order[p + d]) for d in range(1, n_nb + 1)
                  for p in range(len(order) - d)]
            W = refine_with_inliers(S, verify_cached, stats_inliers, conf.verify_top, nb)
        tree, _failed = maximum_spanning_tree(W, verify_cached, conf.max_attempts)
        secs["tree"] = time.perf_counter() - t0
        if edge == "essential" and conf.scale_mode == "graph":
            _rescale_essential(Tpair, tree, stats, idx, root)
        local, _parent = compose_tree(root, tree, Tpair)
        poses = {idx[k]: T for k, T in local.items()}
        edges = [(idx[i], idx[j]) for i, j in tree]
    else:
        order = sorted(range(len(frames)), key=lambda k: (frames[k].t, idx[k]))
        root = order[0]
        poses = {idx[root]: np.eye(4)}
        edges = []
        prev = root
        for k in order[1:]:
            if verify(prev, k):
                poses[idx[k]] = poses[idx[prev]] @ Tpair[(prev, k)]
                edges.append((idx[prev], idx[k]))
            else:  # naive baseline: keep the previous pose
                poses[idx[k]] = poses[idx[prev]].copy()
                guessed.append(idx[k])
            prev = k
    secs["total"] = time.perf_counter() - t_all
    secs["extract"] = getattr(m, "extract_seconds", 0.0) - extract0
    secs["match"] -= secs["extract"]  # match time excluding feature extraction
    unaligned = [i for i in idx if i not in poses]
    res = AlignmentResult(poses, idx[root], edges, unaligned, strategy, guessed, stats, S, kind, with_scale, secs,
                          edge)
    if trace is not None:
        trace.decide("alignment.strategy", strategy)
        trace.decide("alignment.edge", edge)
        trace.decide("alignment.similarity", kind or "time_order")
        trace.decide("alignment.root", idx[root])
        if unaligned:
            trace.event("degraded", f"{len(unaligned)} of {len(idx)} frames could not be aligned "
                        f"(no verified edge to the root's tree)", frames=unaligned)
        if guessed:
            trace.event("degraded", f"sequential chaining: {len(guessed)} failed links kept the previous pose",
                        frames=guessed)
    return res


def _rescale_essential(Tpair: dict[tuple[int, int], np.ndarray], tree: Sequence[tuple[int, int]],
                       stats: Mapping[tuple[int, int], PairResult], idx: Sequence[int], root: int) -> None:
    """Rewrite the tree's essential edges with per-frame scales solved over all verified edges: T_ab =
    [(sigma_b / sigma_a) R_ab, (L_ab / sigma_a) d_ab], L_ab = geometric mean of sigma_a scale_a and sigma_b scale_b
    (the baseline in global units), d_ab the unit translation direction; composing gives pose_k = [sigma_k R_k,
    c_k], which maps frame k's depth points into the root frame (in the root's depth units)."""
    pos = {int(f): k for k, f in enumerate(idx)}
    by_pos = {(pos[a], pos[b]): r for (a, b), r in stats.items()}
    sig = essential_frame_scales(len(idx), root, by_pos)
    for a, b in tree:
        r = by_pos[(a, b)]
        T = Tpair[(a, b)]
        R = T[:3, :3] / transform_scale(T)
        d = T[:3, 3] / max(np.linalg.norm(T[:3, 3]), 1e-12)
        L = np.sqrt(sig[a] * r.scale_a * sig[b] * r.scale_b)
        Tn = np.eye(4)
        Tn[:3, :3] = (sig[b] / sig[a]) * R
        Tn[:3, 3] = (L / sig[a]) * d
        Tpair[(a, b)] = Tn


def pose_change(T_a: np.ndarray, T_b: np.ndarray) -> tuple[float, float]:
    """(translation m, rotation deg) between two poses [4, 4] (camera centres, relative rotation)."""
    d = np.linalg.norm(T_a[:3, 3] - T_b[:3, 3])
    Ra = T_a[:3, :3] / transform_scale(T_a)
    Rb = T_b[:3, :3] / transform_scale(T_b)
    return float(d), rotation_angle_deg(Ra.T @ Rb)
