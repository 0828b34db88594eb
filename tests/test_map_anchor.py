"""Objects on RGB (`runtime/map/anchor.py`): a detection lifted with the frame's depth factor is re-placed by the
triangulated map points inside its footprint (synthetic camera, known truth)."""
from __future__ import annotations

import numpy as np

from mosaicthinker.runtime.map.anchor import anchor_factor, anchor_observations, summary
from mosaicthinker.runtime.types import Observation

K = np.array([[500.0, 0, 160], [0, 500.0, 120], [0, 0, 1]])
H, W = 240, 320


def _backproject(u: np.ndarray, v: np.ndarray, z: np.ndarray) -> np.ndarray:
    return np.c_[(u - K[0, 2]) * z / K[0, 0], (v - K[1, 2]) * z / K[1, 1], z]


def _scene(g: np.random.Generator, true_z: float = 3.0, rel_factor: float = 0.6, occluders: int = 3):
    """A box object at depth true_z filling pixels [100, 200) x [60, 160); the frame's relative depth holds it at
    rel_factor x its true depth (the frame-wide factor is wrong there). Returns (observation lifted with that
    depth, map points [M, 3] in the camera: the object's surface at the true depth, a few occluders in front,
    background points outside the footprint), the depth map."""
    depth = np.full((H, W), 5.0, np.float32)
    depth[60:160, 100:200] = true_z * rel_factor
    vv, uu = np.mgrid[60:160:2, 100:200:2]
    obs_pts = _backproject(uu.ravel() + 0.5, vv.ravel() + 0.5, depth[vv.ravel(), uu.ravel()].astype(float))
    ob = Observation("chair", 0.9, 0, 0.0, obs_pts.astype(np.float32), np.array([100, 60, 200, 160], np.float32))
    n = 30
    u, v = g.uniform(102, 198, n), g.uniform(62, 158, n)
    on = _backproject(u, v, true_z + g.normal(0, 0.02, n))
    u2, v2 = g.uniform(102, 198, occluders), g.uniform(62, 158, occluders)
    front = _backproject(u2, v2, np.full(occluders, 1.0))
    u3, v3 = g.uniform(0, 90, 40), g.uniform(0, 230, 40)
    bg = _backproject(u3, v3, np.full(40, 5.0))
    return ob, np.concatenate([on, front, bg]), depth


def test_anchor_recovers_the_objects_depth_and_size():
    g = np.random.default_rng(0)
    ob, pts, depth = _scene(g)
    out, a = anchor_observations([ob], pts, depth, K, 0)
    f = a.rows[0][2]
    assert f is not None and abs(f - 1 / 0.6) < 0.03, f  # the occluders in front are left out
    z = np.median(out[0].points[:, 2])
    assert abs(z - 3.0) < 0.05, z
    width = np.ptp(out[0].points[:, 0])  # 100 px at 3 m with f = 500: 0.6 m (the pixel footprint is kept)
    assert abs(width - 0.6) < 0.03, width
    assert np.isclose(np.ptp(ob.points[:, 0]) * f, width, rtol=1e-4)


def test_too_few_points_keep_the_frame_factor():
    g = np.random.default_rng(1)
    ob, pts, depth = _scene(g)
    few = pts[:3]  # three object points only
    out, a = anchor_observations([ob], few, depth, K, 0, min_points=5)
    assert a.rows[0][2] is None and a.rows[0][1] == 3
    assert out[0] is ob
    s = summary([a])
    assert s["anchored"] == 0 and s["frame_factor"] == 1


def test_points_outside_the_footprint_do_not_count():
    g = np.random.default_rng(2)
    ob, pts, depth = _scene(g)
    f, k = anchor_factor(ob.points.astype(float), pts[33:], depth, K, 4, 5, 0.15)  # background points only
    assert f is None and k == 0


def test_implausible_factor_is_not_trusted():
    g = np.random.default_rng(3)
    ob, pts, depth = _scene(g, rel_factor=0.2)  # the points say x5: beyond max_factor 3
    _, a = anchor_observations([ob], pts, depth, K, 0, max_factor=3.0)
    assert a.rows[0][2] is None
    _, a = anchor_observations([ob], pts, depth, K, 0, max_factor=6.0)
    assert abs(a.rows[0][2] - 5.0) < 0.1
