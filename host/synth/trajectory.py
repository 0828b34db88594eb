"""Handheld camera walk-through of a synthetic room: camera-to-world poses at a fixed frame rate.

The walker loops through the free space of the room (a grid path through waypoints spread by farthest-point
sampling, ordered around the room centre, joined by shortest paths that avoid tall objects and prefer to avoid low
ones, then smoothed) at a walking speed in [0.2, 0.5] m/s. The eye (~1.5 m) looks half along the walk, half towards
the room centre, with slow yaw sweeps (+-40 deg), a downward pitch (10-18 deg), step bob and small hand jitter
(angles ~1 deg, position ~1 cm). Poses use OpenCV camera axes (x right, y down, z forward) in the z-up world.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.ndimage import gaussian_filter1d
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra

from mosaicthinker.runtime.geometry import make_pose
from mosaicthinker.host.synth.scene import Scene

CELL = 0.1  # planning grid (m)


def camera_rotation(yaw: float, pitch: float, roll: float = 0.0) -> np.ndarray:
    """Camera-to-world rotation [3, 3] (OpenCV axes) looking along yaw (about world z, from +x) and pitch
    (positive up), rolled about the optical axis."""
    fwd = np.array([math.cos(pitch) * math.cos(yaw), math.cos(pitch) * math.sin(yaw), math.sin(pitch)])
    right = np.array([math.sin(yaw), -math.cos(yaw), 0.0])
    down = np.cross(fwd, right)
    cr, sr = math.cos(roll), math.sin(roll)
    x = cr * right + sr * down
    y = -sr * right + cr * down
    return np.stack([x, y, fwd], 1)


def _grid_costs(scene: Scene) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    room = scene.room
    xs = np.arange(-room.Lx / 2 + CELL / 2, room.Lx / 2, CELL)
    ys = np.arange(-room.Ly / 2 + CELL / 2, room.Ly / 2, CELL)
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    P = np.stack([X.ravel(), Y.ravel()], 1)
    cost = np.ones(len(P))
    wall = np.minimum(room.Lx / 2 - np.abs(P[:, 0]), room.Ly / 2 - np.abs(P[:, 1]))
    cost[wall < 0.45] = np.inf
    cost[(wall >= 0.45) & (wall < 0.7)] = 3.0
    for o in scene.objects:
        local = (P - o.pos[:2]) @ o.R[:2, :2]
        top = o.pos[2] + o.size[2]
        dx = np.abs(local[:, 0]) - o.size[0] / 2
        dy = np.abs(local[:, 1]) - o.size[1] / 2
        dist = np.hypot(np.maximum(dx, 0), np.maximum(dy, 0))
        if top > 1.3 and o.pos[2] < 1.7:  # the camera cannot pass: keep 0.35 m away
            cost[dist < 0.35] = np.inf
        else:
            cost[(dist < 0.25) & np.isfinite(cost)] = np.maximum(cost[(dist < 0.25) & np.isfinite(cost)], 25.0)
    return P, cost.reshape(X.shape), X.shape


def _graph(cost: np.ndarray) -> csr_matrix:
    nx, ny = cost.shape
    idx = np.arange(nx * ny).reshape(nx, ny)
    rows, cols, w = [], [], []
    for dx, dy in ((1, 0), (0, 1), (1, 1), (1, -1)):
        a = idx[max(0, -dx):nx - max(0, dx), max(0, -dy):ny - max(0, dy)]
        b = idx[max(0, dx):, max(0, dy):][:a.shape[0], :a.shape[1]] if dy >= 0 else \
            idx[dx:, :ny + dy][:a.shape[0], :a.shape[1]]
        ca, cb = cost.ravel()[a.ravel()], cost.ravel()[b.ravel()]
        ok = np.isfinite(ca) & np.isfinite(cb)
        length = math.hypot(dx, dy)
        ww = length * (ca + cb) / 2
        rows += [a.ravel()[ok], b.ravel()[ok]]
        cols += [b.ravel()[ok], a.ravel()[ok]]
        w += [ww[ok], ww[ok]]
    n = nx * ny
    return csr_matrix((np.concatenate(w), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n))


def walk_path(scene: Scene, rng: np.random.Generator, n_waypoints: int = 6) -> np.ndarray:
    """Closed loop through the room's free space -> [M, 2] points about 5 cm apart."""
    P, cost, shape = _grid_costs(scene)
    free = np.flatnonzero(np.isfinite(cost.ravel()) & (cost.ravel() <= 3.0))
    if len(free) < 4:
        free = np.flatnonzero(np.isfinite(cost.ravel()))
    if len(free) < 2:  # a crowded closet: walk a small circle around the centre
        a = np.linspace(0, 2 * np.pi, 100, endpoint=False)
        r = 0.25 * min(scene.room.Lx, scene.room.Ly)
        return np.stack([r * np.cos(a), r * np.sin(a)], 1)
    # farthest-point sampling for coverage
    pick = [int(free[rng.integers(len(free))])]
    dmin = np.linalg.norm(P[free] - P[pick[0]], axis=1)
    for _ in range(n_waypoints - 1):
        j = int(free[np.argmax(dmin)])
        pick.append(j)
        dmin = np.minimum(dmin, np.linalg.norm(P[free] - P[j], axis=1))
    pick = list(dict.fromkeys(pick))
    ang = np.arctan2(P[pick, 1], P[pick, 0])
    pick = [pick[k] for k in np.argsort(ang)]
    G = _graph(cost)
    dist, pred = dijkstra(G, indices=pick, return_predecessors=True)
    pts: list[np.ndarray] = []
    for k in range(len(pick)):
        a, b = k, (k + 1) % len(pick)
        if not np.isfinite(dist[a, pick[b]]):
            continue
        seq = []
        j = pick[b]
        while j != pick[a] and j >= 0:
            seq.append(j)
            j = pred[a, j]
        seq.append(pick[a])
        pts.append(P[seq[::-1]])
    if not pts:
        pts = [P[pick]]
    poly = np.concatenate(pts)
    # resample every 5 cm and smooth (closed loop)
    seg = np.linalg.norm(np.diff(np.vstack([poly, poly[:1]]), axis=0), axis=1)
    s = np.concatenate([[0], np.cumsum(seg)])
    total = s[-1]
    if total < 0.5:
        a = np.linspace(0, 2 * np.pi, 100, endpoint=False)
        return poly.mean(0) + 0.4 * np.stack([np.cos(a), np.sin(a)], 1)
    closed = np.vstack([poly, poly[:1]])
    q = np.arange(0, total, 0.05)
    path = np.stack([np.interp(q, s, closed[:, 0]), np.interp(q, s, closed[:, 1])], 1)
    return gaussian_filter1d(path, sigma=8, axis=0, mode="wrap")


def _wiggle(rng: np.random.Generator, t: np.ndarray, amp: float, fmin: float = 0.3, fmax: float = 2.0,
            n: int = 4) -> np.ndarray:
    out = np.zeros_like(t)
    for _ in range(n):
        out += np.sin(2 * np.pi * rng.uniform(fmin, fmax) * t + rng.uniform(0, 2 * np.pi))
    return amp * out / math.sqrt(n / 2)


def camera_track(scene: Scene, n_frames: int, fps: float) -> tuple[np.ndarray, np.ndarray]:
    """-> times [N] seconds and camera-to-world poses [N, 4, 4]."""
    conf = scene.config
    rng = np.random.default_rng([int(conf.seed), 1009])
    t = np.arange(n_frames) / float(fps)
    duration = max(t[-1], 1e-3) if n_frames > 1 else 1.0
    path = walk_path(scene, rng, n_waypoints=int(np.clip(round(duration / 8), 4, 10)))
    seg = np.linalg.norm(np.diff(np.vstack([path, path[:1]]), axis=0), axis=1)
    s = np.concatenate([[0], np.cumsum(seg)])
    L = s[-1]
    speed = float(np.clip(L / duration, 0.2, 0.5))
    dist = (rng.uniform(0, L) + speed * t) % L
    closed = np.vstack([path, path[:1]])
    pos = np.stack([np.interp(dist, s, closed[:, 0]), np.interp(dist, s, closed[:, 1])], 1)
    ahead = np.stack([np.interp((dist + 0.3) % L, s, closed[:, 0]), np.interp((dist + 0.3) % L, s, closed[:, 1])], 1)
    tang = ahead - pos
    tang /= np.maximum(np.linalg.norm(tang, axis=1, keepdims=True), 1e-9)
    inward = -pos / np.maximum(np.linalg.norm(pos, axis=1, keepdims=True), 1e-9)
    look = 0.5 * tang + 0.5 * inward
    yaw0 = np.unwrap(np.arctan2(look[:, 1], look[:, 0]))
    yaw0 = gaussian_filter1d(yaw0, sigma=max(1.0, 1.5 * fps), mode="nearest")
    sweep_T = rng.uniform(7, 11)
    yaw = yaw0 + math.radians(40) * np.sin(2 * np.pi * t / sweep_T + rng.uniform(0, 2 * np.pi)) \
        + _wiggle(rng, t, math.radians(1.0))
    pitch = -np.radians(14 + 4 * np.sin(2 * np.pi * t / rng.uniform(11, 15) + rng.uniform(0, 2 * np.pi))) \
        + _wiggle(rng, t, math.radians(0.8))
    roll = _wiggle(rng, t, math.radians(1.0), 0.2, 1.0)
    eye = conf.eye_height + rng.uniform(-0.05, 0.05)
    step_f = rng.uniform(1.6, 2.0)
    z = eye + 0.012 * np.sin(2 * np.pi * step_f * t) + _wiggle(rng, t, 0.005)
    pos = pos + np.stack([_wiggle(rng, t, 0.008), _wiggle(rng, t, 0.008)], 1)
    poses = np.stack([make_pose(camera_rotation(yaw[i], pitch[i], roll[i]), [pos[i, 0], pos[i, 1], z[i]])
                      for i in range(n_frames)])
    return t, poses
