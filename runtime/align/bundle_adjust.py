"""Bundle adjustment of cameras and points: Levenberg-Marquardt with analytic Jacobians, a Huber loss by
iterative reweighting and the points eliminated by the Schur complement (numpy only: runs on ARM CPUs). The
refinement step of the RGB-only structure from motion (`sfm`). scipy's `least_squares` (trf, sparse Jacobian)
was tried first and stopped far from the minimum within any affordable budget (docs/rgb-geometry.md).

Conventions: camera j maps a world point X to its frame by x = R_j X + t_j with R_j = Rodrigues(r_j); a pixel is
K (x / z) with one K [3, 3] shared by every camera; with `refine_focal` its fx, fy by one factor refined too
(intrinsics from a field-of-view prior).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def rotate(rvec: np.ndarray, X: np.ndarray) -> np.ndarray:
    """Rodrigues rotation of points. rvec: [M, 3] axis-angle, X: [M, 3] -> [M, 3] (row m rotated by rvec m)."""
    th = np.linalg.norm(rvec, axis=1, keepdims=True)
    small = th < 1e-12
    k = np.where(small, 0.0, rvec / np.where(small, 1.0, th))
    c, s = np.cos(th), np.sin(th)
    kx = np.cross(k, X)
    out = X * c + kx * s + k * np.sum(k * X, axis=1, keepdims=True) * (1 - c)
    return np.where(small, X + np.cross(rvec, X), out)


def project(rvec: np.ndarray, tvec: np.ndarray, X: np.ndarray, K: np.ndarray, focal: float = 1.0) -> np.ndarray:
    """Pixels of points X [M, 3] seen by cameras (rvec, tvec) [M, 3] each (one per point) -> [M, 2]; points
    behind a camera get a large finite pixel so a robust loss treats them as outliers."""
    x = rotate(rvec, X) + tvec
    z = np.where(x[:, 2] > 1e-9, x[:, 2], 1e-9)
    return np.stack([focal * K[0, 0] * x[:, 0] / z + K[0, 2], focal * K[1, 1] * x[:, 1] / z + K[1, 2]], 1)


@dataclass
class BAResult:
    """rvecs, tvecs: [C, 3] refined cameras; X: [P, 3] refined points; rms_px: RMS reprojection error of the observations after (px); nfev: residual evaluations."""

    rvecs: np.ndarray
    tvecs: np.ndarray
    X: np.ndarray
    rms_px: float
    nfev: int
    focal: float = 1.0  # the focal length's factor found (1.0 unless `refine_focal`)


def _jacobians(R: np.ndarray, t: np.ndarray, X: np.ndarray, K: np.ndarray, focal: float
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per observation (camera R [M, 3, 3], t [M, 3], point X [M, 3]): predicted pixels [M, 2], d uv / d (omega,
    t) [M, 2, 6] for the update R <- exp(omega) R, d uv / d X [M, 2, 3], valid (in front) [M]."""
    RX = (R @ X[:, :, None])[:, :, 0]
    x = RX + t
    ok = x[:, 2] > 1e-6
    z = np.where(ok, x[:, 2], 1e-6)
    fx, fy = focal * K[0, 0], focal * K[1, 1]
    uv = np.stack([fx * x[:, 0] / z + K[0, 2], fy * x[:, 1] / z + K[1, 2]], 1)
    dp = np.zeros((len(X), 2, 3))
    dp[:, 0, 0], dp[:, 0, 2] = fx / z, -fx * x[:, 0] / z**2
    dp[:, 1, 1], dp[:, 1, 2] = fy / z, -fy * x[:, 1] / z**2
    skew = np.zeros((len(X), 3, 3))  # d x / d omega = -[R X]_x
    skew[:, 0, 1], skew[:, 0, 2], skew[:, 1, 2] = RX[:, 2], -RX[:, 1], RX[:, 0]
    skew[:, 1, 0], skew[:, 2, 0], skew[:, 2, 1] = -RX[:, 2], RX[:, 1], -RX[:, 0]
    Jc = np.concatenate([dp @ skew, dp], 2)
    Jp = dp @ R
    return uv, Jc, Jp, ok


def _scatter(idx: np.ndarray, vals: np.ndarray, n: int) -> np.ndarray:
    """Sum rows vals [m, ...] into out [n, ...] by row index idx [m] (np.add.at, by bincount: much faster)."""
    flat = vals.reshape(len(vals), -1)
    k = flat.shape[1]
    out = np.bincount((idx[:, None] * k + np.arange(k)).ravel(), weights=flat.ravel(), minlength=n * k)
    return out.reshape((n,) + vals.shape[1:])


def _T(A: np.ndarray) -> np.ndarray:
    return np.swapaxes(A, -1, -2)


def _so3(w: np.ndarray) -> np.ndarray:
    """exp of axis-angle rows w [C, 3] -> [C, 3, 3]."""
    import cv2

    return np.array([cv2.Rodrigues(v.reshape(3, 1))[0] for v in w])


def bundle_adjust(rvecs: np.ndarray, tvecs: np.ndarray, X: np.ndarray, cam: np.ndarray, pt: np.ndarray,
                  uv: np.ndarray, K: np.ndarray, free_cams: np.ndarray,
                  loss: str = "huber", scale_px: float = 2.0, max_nfev: int = 30, refine_focal: bool = False
                  ) -> BAResult:
    """Levenberg-Marquardt on the robust (Huber, iteratively reweighted) reprojection error over the free cameras
    and every observed point, the points eliminated by the Schur complement (the reduced camera system is
    6 x free cameras square). rvecs, tvecs: [C, 3]; X: [P, 3]; observations cam [M] (camera row), pt [M] (point
    row), uv [M, 2] pixels; free_cams: [C] bool (the rest stay fixed: the gauge, or a local window's border);
    `max_nfev`: iterations at most; `refine_focal`: the focal length (one factor on K's fx, fy, shared by every
    camera) is one more column of the reduced camera system. Returns a `BAResult` (fixed cameras unchanged)."""
    C, P, M = len(rvecs), len(X), len(cam)
    Rs = _so3(np.asarray(rvecs, np.float64))
    t = np.asarray(tvecs, np.float64).copy()
    X = np.asarray(X, np.float64).copy()
    free_idx = np.flatnonzero(free_cams)
    slot = -np.ones(C, int)
    slot[free_idx] = np.arange(len(free_idx))
    nf = len(free_idx)
    focal, lam, it = 1.0, 1e-3, 0
    fc = slot[cam] >= 0

    def cost(Rs_: np.ndarray, t_: np.ndarray, X_: np.ndarray, f_: float) -> tuple[float, np.ndarray]:
        x = (Rs_[cam] @ X_[pt][:, :, None])[:, :, 0] + t_[cam]
        z = np.where(x[:, 2] > 1e-6, x[:, 2], 1e-6)
        u = np.stack([f_ * K[0, 0] * x[:, 0] / z + K[0, 2], f_ * K[1, 1] * x[:, 1] / z + K[1, 2]], 1)
        e = np.linalg.norm(u - uv, axis=1)
        rho = np.where(e <= scale_px, e**2, 2 * scale_px * e - scale_px**2) if loss != "linear" else e**2
        return float(rho.sum()), e

    cur, _ = cost(Rs, t, X, focal)
    for it in range(1, max_nfev + 1):
        u, Jc, Jp, ok = _jacobians(Rs[cam], t[cam], X[pt], K, focal)
        r = u - uv
        e = np.linalg.norm(r, axis=1)
        w = np.where(e <= scale_px, 1.0, scale_px / np.maximum(e, 1e-12)) if loss != "linear" else np.ones(M)
        w = w * ok
        # normal equations blocks
        V = _scatter(pt, w[:, None, None] * (_T(Jp) @ Jp), P)
        bp = _scatter(pt, w[:, None] * (_T(Jp) @ r[:, :, None])[:, :, 0], P)
        U = _scatter(slot[cam[fc]], w[fc, None, None] * (_T(Jc[fc]) @ Jc[fc]), nf)
        bc = _scatter(slot[cam[fc]], w[fc, None] * (_T(Jc[fc]) @ r[fc][:, :, None])[:, :, 0], nf)
        W = w[fc, None, None] * (_T(Jc[fc]) @ Jp[fc])  # [Mf, 6, 3] per free observation
        if refine_focal:  # d uv / d focal factor [M, 2]: the normalised point times fx, fy
            Jf = (u - K[:2, 2]) / focal
            Uff, bf = float(np.sum(w * np.sum(Jf**2, 1))), float(np.sum(w * np.sum(Jf * r, 1)))
            Ucf = _scatter(slot[cam[fc]], w[fc, None] * (_T(Jc[fc]) @ Jf[fc][:, :, None])[:, :, 0], nf)
            Wf = _scatter(pt, w[:, None] * (_T(Jp) @ Jf[:, :, None])[:, :, 0], P)  # [P, 3]
        new, rel = np.inf, 1.0
        while True:
            Vd = V + lam * (np.eye(3) * (np.einsum("pii->pi", V)[:, :, None] + 1e-9))
            Vi = np.linalg.inv(Vd)
            S = np.zeros((nf * 6, nf * 6))
            Ud = U + lam * (np.eye(6) * (np.einsum("cii->ci", U)[:, :, None] + 1e-9))
            for c in range(nf):
                S[6 * c:6 * c + 6, 6 * c:6 * c + 6] += Ud[c]
            # S -= sum over points of W_cp Vi_p W_dp^T for every two free observations (c, d) of the point p
            fo = np.flatnonzero(fc)
            order = np.argsort(pt[fo], kind="stable")
            fo_s, W_s = fo[order], W[order]
            p_s = pt[fo_s]
            starts = np.flatnonzero(np.r_[True, p_s[1:] != p_s[:-1]])
            counts = np.diff(np.r_[starts, len(p_s)])
            WVi = (W_s @ Vi[p_s])
            rhs = -bc + _scatter(slot[cam[fo_s]], (WVi @ bp[p_s][:, :, None])[:, :, 0], nf)
            for n in np.unique(counts):  # points seen by n free cameras at once: one [6n, 6n] block each
                st = starts[counts == n]
                idx = st[:, None] + np.arange(n)[None, :]        # [Q, n]
                A = WVi[idx].reshape(len(st), 6 * n, 3)
                B = W_s[idx].reshape(len(st), 6 * n, 3)
                blk = A @ _T(B)                                  # [Q, 6n, 6n]
                rows = (6 * slot[cam[fo_s[idx]]][:, :, None] + np.arange(6)).reshape(len(st), 6 * n)
                flat = (rows[:, :, None] * (6 * nf) + rows[:, None, :]).ravel()
                S -= np.bincount(flat, weights=blk.ravel(), minlength=S.size).reshape(S.shape)
            df = 0.0
            try:
                if refine_focal:  # one more row and column: the focal factor, its point coupling eliminated too
                    ViWf = (Vi @ Wf[:, :, None])[:, :, 0]
                    Scf = Ucf - _scatter(slot[cam[fo]], (W @ ViWf[pt[fo]][:, :, None])[:, :, 0], nf)
                    Sff = Uff * (1 + lam) - float(np.sum(Wf * ViWf))
                    A = np.block([[S, Scf.reshape(-1, 1)], [Scf.reshape(1, -1), np.array([[Sff]])]])
                    sol = np.linalg.solve(A, np.r_[rhs.ravel(), -bf + float(np.sum(ViWf * bp))])
                    dc, df = sol[:-1].reshape(nf, 6), float(sol[-1])
                else:
                    dc = np.linalg.solve(S, rhs.ravel()).reshape(nf, 6) if nf else np.zeros((0, 6))
            except np.linalg.LinAlgError:
                lam *= 10
                if lam > 1e8:
                    break
                continue
            g = bp + _scatter(pt[fo], (_T(W) @ dc[slot[cam[fo]]][:, :, None])[:, :, 0], P)
            if refine_focal:
                g = g + Wf * df
            dX = -(Vi @ g[:, :, None])[:, :, 0]
            Rn, tn = Rs.copy(), t.copy()
            Rn[free_idx] = _so3(dc[:, :3]) @ Rs[free_idx]
            tn[free_idx] = t[free_idx] + dc[:, 3:]
            Xn = X + dX
            fn = focal + df
            new, _ = cost(Rn, tn, Xn, fn)
            if new < cur:
                rel = (cur - new) / max(cur, 1e-12)
                Rs, t, X, cur, focal = Rn, tn, Xn, new, fn
                lam = max(lam / 3, 1e-7)
                break
            lam *= 10
            if lam > 1e8:
                break
        if lam > 1e8 or (new < cur + 1e-12 and rel < 1e-6):
            break
    _, e = cost(Rs, t, X, focal)
    import cv2

    rv = np.array([cv2.Rodrigues(R)[0].ravel() for R in Rs])
    out = BAResult(rv, t, X, float(np.sqrt(np.mean(e**2))) if M else 0.0, it, focal)
    return out
