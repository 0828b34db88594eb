"""The alignment mechanisms for real walk-throughs (`runtime/align/`): edges that need depth at one end only,
the walks' jump schedule, the pose graph, thinning by measured overlap - on exact synthetic geometry and on the
shared rooms' real frames (`docs/real-rooms.md`)."""
from __future__ import annotations

import numpy as np
import pytest

from mosaicthinker.runtime.align.graph import Edge, refine, so3_exp, so3_log, spanning_poses
from mosaicthinker.runtime.align.odometry import Walk, _jumps, walk
from mosaicthinker.runtime.align.pnp import EdgeResult, pnp_pair, rgbd_edge
from mosaicthinker.runtime.align import AlignConf, Matches, pose_change
from mosaicthinker.runtime.geometry import invert, make_pose
from mosaicthinker.runtime.scan import overlap_sampled
from mosaicthinker.runtime.types import Frame

K = np.array([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]])


def _frame(depth: np.ndarray, index: int) -> Frame:
    return Frame(np.zeros((480, 640, 3), np.uint8), index / 30, index, K, depth.astype(np.float32))


def _scene(T_ab: np.ndarray, n: int = 300, seed: int = 0) -> tuple[Matches, np.ndarray, np.ndarray]:
    """n points 2-4 m in front of camera a, seen by camera b (pose T_ab: b camera -> a camera); matches and the two
    depth images (constant patches around each pixel, so the depth is smooth there)."""
    rng = np.random.default_rng(seed)
    Xa = np.c_[rng.uniform(-1.2, 1.2, n), rng.uniform(-0.9, 0.9, n), rng.uniform(2, 4, n)]
    Xb = (invert(T_ab) @ np.c_[Xa, np.ones(n)].T).T[:, :3]
    ua = (K @ Xa.T).T
    ub = (K @ Xb.T).T
    uva, uvb = ua[:, :2] / ua[:, 2:], ub[:, :2] / ub[:, 2:]
    ok = (uvb[:, 0] > 8) & (uvb[:, 0] < 632) & (uvb[:, 1] > 8) & (uvb[:, 1] < 472)
    da, db = np.zeros((480, 640)), np.zeros((480, 640))
    for uv, z, d in ((uva[ok], Xa[ok, 2], da), (uvb[ok], Xb[ok, 2], db)):
        for (u, v), zz in zip(np.round(uv).astype(int), z):
            d[v - 4:v + 5, u - 4:u + 5] = zz
    # depth is sampled at the rounded pixel: put the points exactly there
    m = Matches(np.round(uva[ok]), np.round(uvb[ok]), np.ones(int(ok.sum())))
    return m, da, db


def test_pnp_needs_depth_in_one_frame_only():
    """With frame b's depth gone (a sensor hole), the 3D-3D edge fails for want of depth at both ends; PnP from
    frame a's depth recovers the pose; the chain of methods says which one made the edge."""
    T = make_pose(so3_exp(np.array([[0.02, -0.1, 0.03]]))[0], np.array([0.3, -0.05, 0.1]))
    m, da, db = _scene(T)
    fa, fb = _frame(da, 0), _frame(np.zeros_like(db), 1)
    conf = AlignConf(min_inliers=12)
    assert not rgbd_edge(m, fa, fb, conf, 2.0, methods=("3d-3d",)).ok
    r = rgbd_edge(m, fa, fb, conf, 2.0)
    assert r.ok and r.method == "pnp"
    dt, dr = pose_change(r.T_ab, T)
    assert dt < 0.01 and dr < 0.3
    # and the other way round (depth in b only): the inverse is solved and returned as T_ab
    r2 = pnp_pair(m, _frame(np.zeros_like(da), 0), _frame(db, 1), conf)
    assert r2.ok and max(pose_change(r2.T_ab, T)[0], 0) < 0.01


def test_edges_report_every_method_that_failed():
    m, da, db = _scene(np.eye(4), n=6)
    r = rgbd_edge(m, _frame(da, 0), _frame(db, 1), AlignConf(min_inliers=12))
    assert not r.ok and r.method == "" and all(k in r.reason for k in ("3d-3d:", "pnp:", "essential:"))


def test_jump_schedule_and_walk_over_a_grid():
    assert _jumps(5, 2, max_jump=4) == [4, 2, 1]          # goal (6 grid steps) beyond the largest jump: not tried
    assert _jumps(5, 2) == [6, 4, 2, 1]                   # no limit: the goal first
    assert _jumps(1, 4, max_jump=4) == [2, 1]             # the goal is within a jump: tried first
    assert _jumps(3, 2, max_jump=2) == [2, 1]

    def estimate(a: int, b: int, adjacent: bool) -> EdgeResult:  # only frames <= 2 apart align
        ok = abs(b - a) <= 2
        return EdgeResult(make_pose(np.eye(3), np.array([b - a, 0.0, 0])), ok, 100, 100, 50 if ok else 0, 0.0, 0.0,
                          "" if ok else "too far", method="3d-3d" if ok else "")

    loaded: set[int] = {0, 10}
    w, budget = walk(0, 10, list(range(0, 11)), estimate, 20, loaded.__contains__, first_jump=4, max_jump=4)
    assert w.reached and budget == 20 - w.loaded and [e.b for e in w.edges][-1] == 10
    assert all(abs(e.b - e.a) <= 2 for e in w.edges)
    # backwards in time, and stuck: a gap no step crosses
    w2, _ = walk(10, 0, [0, 5, 10], estimate, 20, loaded.__contains__)
    assert isinstance(w2, Walk) and not w2.reached and w2.end == 10 and "too far" in w2.why


def test_pose_graph_spreads_drift_and_ignores_a_wrong_loop():
    rng = np.random.default_rng(1)
    n = 24
    true = [make_pose(so3_exp(np.array([[0, 0, 2 * np.pi * k / n]]))[0],
                      np.array([3 * np.cos(2 * np.pi * k / n), 3 * np.sin(2 * np.pi * k / n), 0])) for k in range(n)]
    edges = []
    for k in range(n):
        j = (k + 1) % n
        noise = make_pose(so3_exp(rng.normal(0, 0.01, (1, 3)))[0], rng.normal(0, 0.02, 3))
        edges.append(Edge(k, j, invert(true[k]) @ true[j] @ noise, "odometry", weight=1.0 if j else 0.0))
    rel = [invert(true[0]) @ t for t in true]

    def ate(p: dict) -> float:
        return float(np.sqrt(np.mean([np.sum((p[k][:3, 3] - rel[k][:3, 3]) ** 2) for k in range(n)])))

    p0, tree = spanning_poses(0, edges)
    assert len(tree) == n - 1 and set(p0) == set(range(n))
    p1, rep = refine(p0, edges, 0)
    assert ate(p1) < 0.5 * ate(p0)  # the closing edge spreads the drift
    wrong = make_pose(np.eye(3), np.array([1.0, 0, 0]))  # a loop that verified but is wrong (repeated furniture)
    p2, rep2 = refine(p0, edges + [Edge(0, n // 2, wrong, "loop", weight=0.0)], 0)
    assert ate(p2) < 0.5 * ate(p0) and any(o[2] == "loop" for o in rep2.outliers)
    w = np.random.default_rng(2).normal(size=(50, 3))
    assert np.abs(so3_log(so3_exp(w)) - np.where(np.linalg.norm(w, axis=1, keepdims=True) < np.pi, w, so3_log(
        so3_exp(w)))).max() < 1e-9


def test_overlap_sampling_inserts_only_where_samples_do_not_overlap():
    # items are positions; consecutive samples "overlap" when at most 2 frames apart
    got = list(overlap_sampled([0, 10, 12, 20], lambda p: p, lambda a, b: 1.0 if b - a <= 2 else 0.0, 0.5))
    pos = [p for p, _, _ in got]
    assert pos == sorted(pos) and {0, 10, 12, 20} <= set(pos)
    assert all(b - a <= 2 for a, b in zip(pos, pos[1:]))
    assert [p for p, _, ins in got if not ins] == [0, 10, 12, 20]
    assert [p for p, _, _ in overlap_sampled([0, 10], lambda p: p, lambda a, b: 0.0, 0.0)] == [0, 10]  # off


def _corner_depth(T_wc: np.ndarray) -> np.ndarray:
    """Depth [480, 640] of a room corner (floor y = 0.8, walls z = 3 and x = -0.8 in the world, camera looking down
    +z) seen by a camera with pose T_wc: ray-plane intersections, the nearest in front."""
    v, u = np.mgrid[0:480, 0:640].astype(np.float64)
    rays = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], -1)  # camera, z = 1
    d_w = rays @ T_wc[:3, :3].T
    o = T_wc[:3, 3]
    best = np.full(u.shape, np.inf)
    for axis, value in ((1, 0.8), (2, 3.0), (0, -0.8)):
        with np.errstate(divide="ignore", invalid="ignore"):
            s = (value - o[axis]) / d_w[..., axis]
        best = np.where((s > 0) & (s < best), s, best)
    return np.where(np.isfinite(best), best, 0.0).astype(np.float32)  # s is the depth: rays have z = 1


def test_icp_refines_a_verified_edge_and_refuses_a_large_move():
    """`backbone.icp_refined`: a feature edge 2 cm / 1 deg off is pulled back onto the depth (two views of a room
    corner); the pose graph then trusts it with `ICP_SIGMA`; a correction beyond `icp_max_change` is refused."""
    from mosaicthinker.runtime.align.backbone import icp_refined, sigma_of
    from mosaicthinker.runtime.align.conf import ICP_SIGMA

    Ta = make_pose(so3_exp(np.array([[0.05, -0.2, 0.0]]))[0], np.array([0.2, 0.0, 0.0]))
    Tb = make_pose(so3_exp(np.array([[0.08, -0.3, 0.02]]))[0], np.array([0.35, 0.05, 0.1]))
    fa, fb = _frame(_corner_depth(Ta), 0), _frame(_corner_depth(Tb), 1)
    T_true = invert(Ta) @ Tb
    off = make_pose(so3_exp(np.array([[0.0, np.radians(1.0), 0.0]]))[0], np.array([0.02, 0.0, -0.01])) @ T_true
    conf = AlignConf()
    r = icp_refined(EdgeResult(off.copy(), True, 100, 100, 80, 0.01, 0.0, method="3d-3d"), fa, fb, conf)
    assert r.icp == "applied"
    dt, dr = pose_change(r.T_ab, T_true)
    assert dt < 0.003 and dr < 0.1, (dt, dr)
    assert np.allclose(sigma_of(r), (ICP_SIGMA[0], np.radians(ICP_SIGMA[1])))
    tight = AlignConf(icp_max_change=(0.005, 0.2))
    r2 = icp_refined(EdgeResult(off.copy(), True, 100, 100, 80, 0.01, 0.0, method="3d-3d"), fa, fb, tight)
    assert r2.icp.startswith("rejected: moved") and np.allclose(r2.T_ab, off)
    assert sigma_of(r2) == sigma_of(EdgeResult(off, True, 100, 100, 80, 0.01, 0.0, method="3d-3d"))
