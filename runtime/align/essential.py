"""Essential-matrix edges for relative (non-metric) depth: the 5-point essential matrix (OpenCV USAC_MAGSAC) gives
rotation + translation direction, Sampson refinement sharpens it, the depth only sets the translation length; the
per-frame depth scales are then solved over every verified edge (`essential_frame_scales`) so the tree composes in
one global scale (the root frame's depth unit). Measurements: docs/foundation.md."""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np

from ..geometry import sample_depth, transform_scale
from ..infra.errors import InputError
from .conf import SOLVER_MIN_POINTS, AlignConf
from .matching import Matches
from .pairwise import PairResult


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
    parallax and depth to fix the scale (pure rotation / tiny baseline).
    = `essential_edge(essential_pose(...), ..., refine=conf.essential_refine)`."""
    conf = conf or AlignConf()
    pose = essential_pose(m, K_a, K_b, conf, dist_a, dist_b)
    if isinstance(pose, PairResult):
        return pose
    return essential_edge(pose, depth_a, depth_b, conf, conf.essential_refine)


@dataclass
class EssentialPose:
    """The RANSAC part of an essential edge: normalised (xa, xb [M, 2]) and pixel (uva, uvb [M, 2]) coordinates
    of the matches used, the cheirality inliers inl [M] bool, the relative pose x_b = R x_a + t (|t| = 1), the
    Sampson threshold in normalised units, the pair's match count, seconds spent."""

    xa: np.ndarray
    xb: np.ndarray
    uva: np.ndarray
    uvb: np.ndarray
    inl: np.ndarray
    R: np.ndarray
    t: np.ndarray
    thr: float
    n_matches: int
    seconds: float


def essential_pose(m: Matches, K_a: np.ndarray, K_b: np.ndarray, conf: AlignConf,
                   dist_a: np.ndarray | None = None, dist_b: np.ndarray | None = None) -> EssentialPose | PairResult:
    """Essential matrix (`_find_essential`) + cheirality (cv2.recoverPose on its inliers) of one pair; a failed
    PairResult when there are too few matches or inliers (see `align_pair_essential`)."""
    import cv2

    t0 = time.perf_counter()
    n = len(m)

    def fail(why: str, nv: int = 0, ninl: int = 0) -> PairResult:
        return PairResult(np.eye(4), False, n, nv, ninl, float("inf"), time.perf_counter() - t0, why)

    need = conf.edge_min_inliers
    if n < max(SOLVER_MIN_POINTS["essential"], need):
        return fail(f"only {n} matches (need {max(SOLVER_MIN_POINTS['essential'], need)})")
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
    inl = np.zeros(len(sel), bool)
    inl[q0[m2.ravel() > 0]] = True
    ninl = int(inl.sum())
    if ninl < need:
        return fail(f"{ninl} essential inliers (need {need})", len(sel), ninl)
    if ninl < conf.min_inlier_ratio * len(sel):
        return fail(f"essential inlier ratio {ninl / len(sel):.2f} below {conf.min_inlier_ratio}", len(sel), ninl)
    t = t.reshape(3) / max(np.linalg.norm(t), 1e-12)  # x_b = R x_a + t, |t| = 1
    return EssentialPose(xa, xb, uva, uvb, inl, R, t, px / f, n, time.perf_counter() - t0)


def essential_edge(pose: EssentialPose, depth_a: np.ndarray, depth_b: np.ndarray, conf: AlignConf,
                   refine: bool) -> PairResult:
    """The rest of an essential edge from its RANSAC pose: the Sampson refinement (when `refine`), then the
    translation length from the depth maps (see `align_pair_essential`). Same inliers either way."""
    import cv2

    t0 = time.perf_counter()
    R, t, inl, xa, xb = pose.R, pose.t, pose.inl, pose.xa, pose.xb
    ninl = int(inl.sum())

    def fail(why: str, nv: int = 0) -> PairResult:
        return PairResult(np.eye(4), False, pose.n_matches, nv, ninl, float("inf"),
                          pose.seconds + time.perf_counter() - t0, why)

    if refine:  # on at most 200 inliers, evenly picked (cost ~ points x iterations)
        q = np.flatnonzero(inl)
        q = q[np.linspace(0, len(q) - 1, min(len(q), 200)).astype(int)]
        R, t = refine_essential(R, t, xa[q], xb[q], pose.thr)
    Xh = cv2.triangulatePoints(np.eye(3, 4), np.hstack([R, t[:, None]]), xa[inl].T, xb[inl].T)
    with np.errstate(divide="ignore", invalid="ignore"):
        X = (Xh[:3] / Xh[3]).T  # [M, 3] in camera a, unit baseline
    Xb = X @ R.T + t
    cb = -R.T @ t  # centre of b in a
    ra, rb = X, X - cb
    cosang = np.sum(ra * rb, 1) / np.maximum(np.linalg.norm(ra, axis=1) * np.linalg.norm(rb, axis=1), 1e-12)
    par = np.degrees(np.arccos(np.clip(cosang, -1, 1)))
    da = sample_depth(depth_a, pose.uva[inl])
    db = sample_depth(depth_b, pose.uvb[inl])
    ok = np.isfinite(X).all(1) & (X[:, 2] > 0) & (Xb[:, 2] > 0) & (par >= conf.min_parallax_deg) & (da > 0) & (db > 0)
    nv = int(ok.sum())
    if nv < conf.min_scale_points:
        return fail(f"{nv} inliers with parallax >= {conf.min_parallax_deg} deg and depth (need "
                    f"{conf.min_scale_points}): baseline too small to fix the scale", nv)
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
    return PairResult(T, True, pose.n_matches, nv, ninl, spread, pose.seconds + time.perf_counter() - t0,
                      scale_a=s_a, scale_b=s_b)


def _find_essential(xa: np.ndarray, xb: np.ndarray, thr: float, method: str) -> tuple[Any, Any]:
    """Robust essential matrix of normalised correspondences xa, xb [N, 2] -> (E, mask). "magsac":
    cv2.USAC_MAGSAC; "accurate": cv2.USAC_ACCURATE; "ransac": cv2.RANSAC; "magsac-prosac": MAGSAC++ scoring and
    sigma consensus with PROSAC sampling over the score order (xa, xb best first; cheaper, less accurate:
    docs/settings.md)."""
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
    residuals); the Jacobian by forward differences, all 6 residual vectors in one batched evaluation."""
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


def rescale_essential(Tpair: dict[tuple[int, int], np.ndarray], tree: Sequence[tuple[int, int]],
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
