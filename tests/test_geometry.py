"""Geometry on exact synthetic cases: pose algebra, back-projection, Umeyama, RANSAC (50% outliers), Sim(3), ICP."""
from __future__ import annotations

import numpy as np
import pytest

from mosaicthinker.runtime import geometry as G


def _random_pose(rng: np.random.Generator, scale: float = 1.0) -> np.ndarray:
    R = G.rotation_about(rng.normal(size=3), rng.uniform(0.1, 3.0))
    return G.make_pose(scale * R, rng.normal(size=3))


def test_pose_algebra_inverse_and_relative():
    rng = np.random.default_rng(0)
    for s in (1.0, 0.37, 2.5):
        T = _random_pose(rng, s)
        assert np.allclose(G.invert(T) @ T, np.eye(4), atol=1e-12)
        assert G.transform_scale(T) == pytest.approx(s, abs=1e-12)
    A, B = _random_pose(rng), _random_pose(rng)
    assert np.allclose(A @ G.relative_pose(A, B), B, atol=1e-12)
    R = G.rotation_about([0, 0, 1], np.radians(30))
    assert G.rotation_angle_deg(R) == pytest.approx(30.0, abs=1e-9)
    assert np.allclose(G.rotation_between([1, 0, 0], [0, 1, 0]) @ [1, 0, 0], [0, 1, 0], atol=1e-12)


def test_backproject_project_roundtrip():
    rng = np.random.default_rng(1)
    K = G.intrinsics_from_fov(64, 48, 70.0)
    depth = rng.uniform(0.5, 4.0, size=(48, 64)).astype(np.float32)
    depth[::7, ::5] = 0  # invalid pixels are skipped
    pts, uv = G.backproject(depth, K)
    assert len(pts) == int((depth > 0).sum())
    T = _random_pose(rng)
    uv2, z = G.project(G.transform(T, pts), K, T)
    assert np.allclose(uv2, uv, atol=1e-9)
    assert np.allclose(z, depth[uv[:, 1].astype(int), uv[:, 0].astype(int)], atol=1e-6)


@pytest.mark.parametrize("with_scale", [False, True])
def test_umeyama_exact(with_scale):
    rng = np.random.default_rng(2)
    for _ in range(5):
        T = _random_pose(rng, rng.uniform(0.2, 3.0) if with_scale else 1.0)
        src = rng.normal(size=(20, 3))
        est = G.umeyama(src, G.transform(T, src), with_scale)
        assert np.abs(est - T).max() < 1e-6
        batch = G.umeyama_batch(np.stack([src[:3], src[5:8]]), np.stack([G.transform(T, src[:3]),
                                                                          G.transform(T, src[5:8])]), with_scale)
        assert np.abs(batch - T).max() < 1e-6


def test_umeyama_handles_reflection_case():
    # a planar, mirrored configuration must still give a proper rotation (det +1)
    rng = np.random.default_rng(3)
    src = np.c_[rng.normal(size=(10, 2)), np.zeros(10)]
    T = G.umeyama(src, src * [1, 1, -1])
    assert np.linalg.det(T[:3, :3]) == pytest.approx(1.0, abs=1e-9)


@pytest.mark.parametrize("with_scale", [False, True])
def test_ransac_recovers_transform_with_half_outliers(with_scale):
    rng = np.random.default_rng(4)
    T = _random_pose(rng, 1.7 if with_scale else 1.0)
    src = rng.uniform(-2, 2, size=(300, 3))
    dst = G.transform(T, src)
    out = np.zeros(300, bool)
    out[rng.choice(300, 150, replace=False)] = True
    dst[out] += rng.uniform(0.3, 2.0, size=(150, 3)) * rng.choice([-1, 1], size=(150, 3))
    r = G.ransac_transform(src, dst, threshold=0.01, with_scale=with_scale, min_inliers=12, rng=0)
    assert r.ok
    assert np.array_equal(r.inliers, ~out)
    assert np.abs(r.T - T).max() < 1e-6
    assert r.residual < 1e-6


def test_ransac_fails_on_noise():
    rng = np.random.default_rng(5)
    r = G.ransac_transform(rng.normal(size=(60, 3)), rng.normal(size=(60, 3)) * 3, threshold=0.01,
                           min_inliers=12)
    assert not r.ok


def _room_depth(T_wc: np.ndarray, K: np.ndarray, W: int = 160, H: int = 120) -> np.ndarray:
    """Ray-cast z-depth of the inside of an axis-aligned room [-2, 2] x [-1.5, 1.5] x [-3, 3] plus a box."""
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    d_cam = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], -1).reshape(-1, 3)
    d = d_cam @ T_wc[:3, :3].T
    o = T_wc[:3, 3]
    lo, hi = np.array([-2, -1.5, -3.0]), np.array([2, 1.5, 3.0])
    with np.errstate(divide="ignore", invalid="ignore"):
        t_far = np.where(d > 0, (hi - o) / d, (lo - o) / d)
    t = np.nanmin(np.where(t_far > 0, t_far, np.inf), axis=1)
    blo, bhi = np.array([-0.5, 0.5, 1.0]), np.array([0.3, 1.5, 1.8])  # a box standing in the room
    with np.errstate(divide="ignore", invalid="ignore"):
        t1, t2 = (blo - o) / d, (bhi - o) / d
    tn, tf = np.nanmax(np.minimum(t1, t2), 1), np.nanmin(np.maximum(t1, t2), 1)
    hit = (tn <= tf) & (tn > 0)
    t = np.where(hit & (tn < t), tn, t)
    return (t * d_cam[:, 2]).reshape(H, W).astype(np.float32)


def test_icp_point_to_plane_refines_small_error():
    K = G.intrinsics_from_fov(160, 120, 75.0)
    Ta = G.make_pose(G.rotation_about([0, 1, 0], 0.1), [0.1, 0.0, -1.0])
    Tb = G.make_pose(G.rotation_about([0.2, 1, 0], 0.25), [0.3, 0.1, -0.8])
    da, db = _room_depth(Ta, K), _room_depth(Tb, K)
    T_true = G.relative_pose(Ta, Tb)
    init = G.make_pose(G.rotation_about([1, 0, 0], 0.02), [0.02, -0.01, 0.015]) @ T_true
    T, rms, n, overlap = G.icp_point_to_plane(da, K, db, K, init, iterations=30, stride=1)
    assert overlap > 0.5
    dt = np.linalg.norm(T[:3, 3] - T_true[:3, 3])
    assert dt < 1e-3 and G.rotation_angle_deg(T[:3, :3].T @ T_true[:3, :3]) < 0.02  # started 2.6 cm, 1.1 deg off
