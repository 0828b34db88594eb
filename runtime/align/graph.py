"""A pose graph over every verified edge: spanning-tree initialisation and robust least-squares refinement.

Nodes are frames (key frames and the odometry backbone's frames), edges are verified relative poses
(`Edge.T`: pose of b in a's camera, so P_b = P_a T). The maximum spanning tree of the paper composes poses
along one path per frame; a walk-through that comes back to a place gives more than one path, and the tree then
carries the drift of whichever path it took. `refine` spreads it: Gauss-Newton (scipy's trust-region least
squares on the sparse Jacobian) over the residuals r = [log(R_e) / sigma_r, t_e / sigma_t] of
E = T^-1 P_a^-1 P_b for every edge, with a Huber loss so a wrong edge that got through verification is
down-weighted instead of bending the map; the root is fixed. Pure numpy / scipy.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np


@dataclass
class Edge:
    """A verified relative pose between frames a and b: T [4, 4] = pose of b in a's camera; sigma_t (m) and
    sigma_r (rad): its expected error; kind: where it came from (e.g. "tree", "loop", "odometry")."""

    a: int
    b: int
    T: np.ndarray
    kind: str = ""
    sigma_t: float = 0.02
    sigma_r: float = 0.0175
    weight: float = 1.0   # spanning-tree preference (larger first), e.g. the inlier count


def so3_exp(w: np.ndarray) -> np.ndarray:
    """Rotation vectors [N, 3] -> rotation matrices [N, 3, 3] (Rodrigues)."""
    w = np.asarray(w, np.float64).reshape(-1, 3)
    th = np.linalg.norm(w, axis=1)
    k = w / np.where(th > 1e-12, th, 1.0)[:, None]
    Kx = np.zeros((len(w), 3, 3))
    Kx[:, 0, 1], Kx[:, 0, 2], Kx[:, 1, 2] = -k[:, 2], k[:, 1], -k[:, 0]
    Kx -= Kx.transpose(0, 2, 1)
    s, c = np.sin(th)[:, None, None], (1 - np.cos(th))[:, None, None]
    return np.eye(3) + s * Kx + c * (Kx @ Kx)


def so3_log(R: np.ndarray) -> np.ndarray:
    """Rotation matrices [N, 3, 3] -> rotation vectors [N, 3] (angle < pi; near pi the axis from the diagonal)."""
    R = np.asarray(R, np.float64).reshape(-1, 3, 3)
    cos = np.clip((np.trace(R, axis1=1, axis2=2) - 1) / 2, -1.0, 1.0)
    th = np.arccos(cos)
    v = np.stack([R[:, 2, 1] - R[:, 1, 2], R[:, 0, 2] - R[:, 2, 0], R[:, 1, 0] - R[:, 0, 1]], 1)
    s = np.sin(th)
    small = s < 1e-6
    out = v * np.where(small, 0.5, th / (2 * np.where(small, 1.0, s)))[:, None]
    near_pi = small & (cos < 0)
    for i in np.flatnonzero(near_pi):  # th ~ pi: axis from the largest diagonal entry of (R + I) / 2
        B = (R[i] + np.eye(3)) / 2
        j = int(np.argmax(np.diag(B)))
        ax = B[:, j] / np.sqrt(max(B[j, j], 1e-12))
        out[i] = ax * th[i]
    return out


def spanning_poses(root: int, edges: Sequence[Edge]) -> tuple[dict[int, np.ndarray], list[Edge]]:
    """Poses {node: [4, 4] in the root's camera} of the root's connected part, composed along a maximum spanning
    tree of `weight` (Kruskal; ties keep the edges' order), and the tree's edges."""
    parent: dict[int, int] = {}

    def find(x: int) -> int:
        parent.setdefault(x, x)
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    tree = []
    for e in sorted(edges, key=lambda e: -e.weight):
        ra, rb = find(e.a), find(e.b)
        if ra != rb:
            parent[rb] = ra
            tree.append(e)
    adj: dict[int, list[tuple[int, np.ndarray]]] = {}
    for e in tree:
        adj.setdefault(e.a, []).append((e.b, e.T))
        adj.setdefault(e.b, []).append((e.a, _inv(e.T)))
    poses = {root: np.eye(4)}
    todo = [root]
    while todo:
        p = todo.pop()
        for c, T in adj.get(p, []):
            if c not in poses:
                poses[c] = poses[p] @ T
                todo.append(c)
    return poses, tree


def _inv(T: np.ndarray) -> np.ndarray:
    out = np.eye(4)
    out[:3, :3] = T[:3, :3].T
    out[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return out


@dataclass
class GraphReport:
    """What `refine` did: nodes and edges used, the robust cost before and after, the edges whose residual stayed
    above the Huber scale after the fit (down-weighted: (a, b, kind, residual in sigmas))."""

    nodes: int
    edges: int
    cost_before: float
    cost_after: float
    outliers: list[tuple[int, int, str, float]]
    seconds: float = 0.0

    def to_dict(self) -> dict:
        return {"nodes": self.nodes, "edges": self.edges, "cost_before": round(self.cost_before, 3),
                "cost_after": round(self.cost_after, 3), "outliers": [list(o) for o in self.outliers],
                "seconds": round(self.seconds, 3)}


def _edge_residuals(Pa: np.ndarray, Pb: np.ndarray, Tinv: np.ndarray, st: np.ndarray, sr: np.ndarray
                    ) -> np.ndarray:
    """Residuals [E, 6] of edges with end poses Pa, Pb [E, 4, 4] and inverted measurements Tinv [E, 4, 4]."""
    Ra_t = Pa[:, :3, :3].transpose(0, 2, 1)
    Rrel = Ra_t @ Pb[:, :3, :3]
    trel = np.einsum("nij,nj->ni", Ra_t, Pb[:, :3, 3] - Pa[:, :3, 3])
    Re = Tinv[:, :3, :3] @ Rrel
    te = np.einsum("nij,nj->ni", Tinv[:, :3, :3], trel) + Tinv[:, :3, 3]
    return np.concatenate([so3_log(Re) / sr[:, None], te / st[:, None]], 1)


def _perturbed(P: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Poses P [N, 4, 4] with right perturbations d [N, 6] (rotation vector, translation)."""
    out = P.copy()
    out[:, :3, :3] = P[:, :3, :3] @ so3_exp(d[:, :3])
    out[:, :3, 3] = P[:, :3, 3] + d[:, 3:]
    return out


def refine(poses: Mapping[int, np.ndarray], edges: Sequence[Edge], root: int, huber: float = 3.0,
           iterations: int = 20) -> tuple[dict[int, np.ndarray], GraphReport]:
    """Robust pose-graph refinement (module docstring) of the poses [4, 4] of the nodes in `poses` over the edges
    between them (others ignored), the root's pose fixed; `huber`: the loss scale in sigmas. Levenberg-Marquardt
    with Huber weights re-computed per iteration (IRLS), each edge's 6 x 12 Jacobian by finite differences (all
    edges in one batch per parameter), normal equations solved sparse. Returns the refined poses (rigid) and a
    report. With no edge beyond a tree the poses come back unchanged (zero residuals)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.linalg import spsolve

    t0 = time.perf_counter()
    nodes = sorted(poses)
    pos = {n: k for k, n in enumerate(nodes)}
    use = [e for e in edges if e.a in pos and e.b in pos and e.a != e.b]
    if not use or len(nodes) < 2:
        return {n: np.array(poses[n]) for n in nodes}, GraphReport(len(nodes), len(use), 0.0, 0.0, [])
    P = np.stack([_rigid(poses[n]) for n in nodes])
    ia = np.array([pos[e.a] for e in use])
    ib = np.array([pos[e.b] for e in use])
    Tinv = np.stack([_inv(_rigid(e.T)) for e in use])
    st = np.array([e.sigma_t for e in use], np.float64)
    sr = np.array([e.sigma_r for e in use], np.float64)
    E, N, eps = len(use), len(nodes), 1e-6
    free = np.ones(N, bool)
    free[pos[root]] = False
    fidx = -np.ones(N, int)
    fidx[free] = np.arange(int(free.sum()))
    rows_a = np.repeat(fidx[ia], 6)
    rows_b = np.repeat(fidx[ib], 6)

    def cost_of(r: np.ndarray) -> float:
        return _cauchy(np.linalg.norm(r, axis=1) / np.sqrt(6), huber)

    r = _edge_residuals(P[ia], P[ib], Tinv, st, sr)
    cost0 = cost = cost_of(r)
    lam = 1e-3
    for _ in range(iterations):
        Ja = np.empty((E, 6, 6))
        Jb = np.empty((E, 6, 6))
        for j in range(6):
            dj = np.zeros((E, 6))
            dj[:, j] = eps
            Ja[:, :, j] = (_edge_residuals(_perturbed(P[ia], dj), P[ib], Tinv, st, sr) - r) / eps
            Jb[:, :, j] = (_edge_residuals(P[ia], _perturbed(P[ib], dj), Tinv, st, sr) - r) / eps
        nr = np.linalg.norm(r, axis=1) / np.sqrt(6)
        w = 1.0 / (1.0 + (nr / huber) ** 2)  # Cauchy IRLS weight per edge: a gross outlier loses its pull
        H, g = _normal_equations(Ja, Jb, r, w, ia, ib, fidx, int(free.sum()))
        improved = False
        for _ in range(6):
            A = H + lam * coo_matrix((np.asarray(H.diagonal()) + 1e-9, (np.arange(H.shape[0]),) * 2),
                                     shape=H.shape).tocsr()
            step = spsolve(A.tocsc(), -g)
            d = np.zeros((N, 6))
            d[free] = step.reshape(-1, 6)
            P2 = _perturbed(P, d)
            r2 = _edge_residuals(P2[ia], P2[ib], Tinv, st, sr)
            c2 = cost_of(r2)
            if c2 < cost:
                gain = cost - c2
                P, r, cost, lam, improved = P2, r2, c2, max(lam / 3, 1e-9), True
                break
            lam *= 4
        if not improved or gain < 1e-6 * max(cost, 1e-12):
            break
    out = {n: P[k] for k, n in enumerate(nodes)}
    norm = np.linalg.norm(r, axis=1) / np.sqrt(6)
    outl = [(int(use[k].a), int(use[k].b), use[k].kind, round(float(norm[k]), 2)) for k in np.flatnonzero(norm > huber)]
    return out, GraphReport(N, E, cost0, cost, outl, time.perf_counter() - t0)


def _normal_equations(Ja: np.ndarray, Jb: np.ndarray, r: np.ndarray, w: np.ndarray, ia: np.ndarray, ib: np.ndarray,
                      fidx: np.ndarray, nfree: int) -> tuple[object, np.ndarray]:
    """H = J^T W J (sparse, [6F, 6F]) and g = J^T W r over the free nodes (fidx: node -> free index or -1)."""
    from scipy.sparse import coo_matrix

    rows, cols, vals = [], [], []
    g = np.zeros(6 * nfree)
    blocks = ((ia, Ja), (ib, Jb))
    for n1, J1 in blocks:
        f1 = fidx[n1]
        ok1 = f1 >= 0
        g_e = np.einsum("eki,ek->ei", J1, r * w[:, None])
        np.add.at(g, (6 * f1[ok1, None] + np.arange(6)).ravel(), g_e[ok1].ravel())
        for n2, J2 in blocks:
            f2 = fidx[n2]
            ok = ok1 & (f2 >= 0)
            B = np.einsum("eki,ekj->eij", J1[ok], J2[ok] * w[ok, None, None])
            ri = (6 * f1[ok, None, None] + np.arange(6)[None, :, None]).repeat(6, 2)
            ci = (6 * f2[ok, None, None] + np.arange(6)[None, None, :]).repeat(6, 1)
            rows.append(ri.ravel())
            cols.append(ci.ravel())
            vals.append(B.ravel())
    H = coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                   shape=(6 * nfree, 6 * nfree)).tocsr()
    return H, g


def _cauchy(nr: np.ndarray, c: float) -> float:
    return float(np.sum(0.5 * c * c * np.log1p((nr / c) ** 2)))


def _huber(r: np.ndarray, k: float) -> float:
    a = np.abs(r)
    return float(np.sum(np.where(a <= k, 0.5 * a * a, k * a - 0.5 * k * k)))


def rigid_part(T: np.ndarray) -> np.ndarray:
    """The nearest rigid transform [4, 4] of T [4, 4] (a similarity's scale removed, the rotation
    re-orthonormalised; the translation kept)."""
    return _rigid(T)


def _rigid(T: np.ndarray) -> np.ndarray:
    """See `rigid_part`."""
    T = np.asarray(T, np.float64)
    U, _, Vt = np.linalg.svd(T[:3, :3])
    R = U @ np.diag([1, 1, np.sign(np.linalg.det(U @ Vt))]) @ Vt
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = R, T[:3, 3]
    return out
