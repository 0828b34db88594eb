"""RGB-only structure from motion (`align.sfm`, `align.bundle_adjust`, `align.rgb_stage`) and the pose scores of
`mosaic eval pose` (SE(3) / Sim(3) ATE, the Sim(3)'s scale)."""
from __future__ import annotations

import numpy as np
import pytest

from mosaicthinker.host.evaluation.pose import ate_fields, ate_rmse
from mosaicthinker.runtime.align.bundle_adjust import bundle_adjust, project
from mosaicthinker.runtime.align.conf import SfmConf
from mosaicthinker.runtime.align.rgb_stage import stream_positions
from mosaicthinker.runtime.align.sfm import build_tracks, match_stream, reconstruct, triangulate

K = np.array([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]])


def _look(c: np.ndarray, yaw: float) -> np.ndarray:
    z = np.array([np.cos(yaw), 0.1, np.sin(yaw)])
    z /= np.linalg.norm(z)
    x = np.cross([0, -1, 0], z)
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = np.stack([x, np.cross(z, x), z], 1), c
    return T


def _scene(n: int = 24, noise: float = 0.5, outliers: float = 0.1, jump_at: int | None = None, seed: int = 0):
    """Points on the walls of an 8 x 3 x 8 m room, a camera walking an arc and turning (camera-to-world [n, 4, 4]);
    `match(a, b)` gives the true correspondences with pixel noise and a share of random matches; `jump_at`: that
    frame is seen from a camera rolled 40 degrees from its neighbours (a jump)."""
    rng = np.random.default_rng(seed)
    X = rng.uniform([-4, -1.5, -4], [4, 1.5, 4], (6000, 3))
    X = X[np.abs(X).max(1) > 3.0]
    poses = []
    for i in range(n):
        a = 0.8 * np.pi * i / n
        T = _look(np.array([1.2 * np.cos(a), 0, 1.2 * np.sin(a)]), a + 1.2)
        if i == jump_at:  # the same view, rolled 40 degrees about the optical axis
            c, s_ = np.cos(np.radians(40)), np.sin(np.radians(40))
            T[:3, :3] = T[:3, :3] @ np.array([[c, -s_, 0], [s_, c, 0], [0, 0, 1]])
        poses.append(T)
    obs = []
    for T in poses:
        R, t = T[:3, :3].T, -T[:3, :3].T @ T[:3, 3]
        x = X @ R.T + t
        ok = x[:, 2] > 0.2
        uv = x[:, :2] / np.where(ok, x[:, 2], 1)[:, None] * 500 + [320, 240]
        ok &= (uv[:, 0] > 0) & (uv[:, 0] < 640) & (uv[:, 1] > 0) & (uv[:, 1] < 480)
        obs.append((uv + rng.normal(0, noise, uv.shape), ok))

    def match(a: int, b: int) -> tuple[np.ndarray, np.ndarray]:
        ok = np.flatnonzero(obs[a][1] & obs[b][1])
        ua, ub = obs[a][0][ok].copy(), obs[b][0][ok].copy()
        k = int(outliers * len(ok))
        ub[:k] = rng.uniform([0, 0], [640, 480], (k, 2))
        return ua, ub

    return np.array(poses), match


def _c2w(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R.T, -R.T @ t
    return T


def test_ate_fields_separate_shape_and_scale():
    rng = np.random.default_rng(0)
    gt = np.tile(np.eye(4), (10, 1, 1))
    gt[:, :3, 3] = rng.normal(0, 1, (10, 3))
    est = gt.copy()
    est[:, :3, 3] *= 0.5                                       # the right shape at half the size
    r = ate_fields(est, gt, with_scale=True)
    assert r["ate_sim3_m"] < 1e-9 and abs(r["sim3_scale"] - 2.0) < 1e-9 and r["ate_m"] == r["ate_sim3_m"]
    assert r["ate_rmse_m"] > 0.2                               # SE(3) keeps the scale error: what a user gets
    assert ate_fields(gt, gt, with_scale=False)["ate_m"] < 1e-12
    few = ate_fields(est[:1], gt[:1], with_scale=True)
    assert few["ate_sim3_m"] is None and few["sim3_scale"] is None  # never NaN in the new fields


def test_triangulate_and_bundle_adjust_recover_the_scene():
    T0, T1 = _look(np.zeros(3), 0.0), _look(np.array([0.5, 0, 0.1]), 0.1)
    rng = np.random.default_rng(1)
    X = rng.uniform([1, -1, 2], [3, 1, 5], (300, 3)) @ T0[:3, :3].T
    cams = [(T[:3, :3].T, -T[:3, :3].T @ T[:3, 3]) for T in (T0, T1)]
    uv = [project(np.zeros_like(X), np.zeros_like(X), X @ R.T + t, K) for R, t in cams]
    Xt, ang = triangulate(K, *cams[0], *cams[1], uv[0], uv[1])
    r0, r1 = X - T0[:3, 3], X - T1[:3, 3]
    ref = np.degrees(np.arccos(np.sum(r0 * r1, 1) / np.linalg.norm(r0, axis=1) / np.linalg.norm(r1, axis=1)))
    assert np.abs(Xt - X).max() < 1e-6 and np.allclose(ang, ref, atol=1e-6)
    # three cameras, noisy start: the adjustment brings the error down to the pixel noise
    T2 = _look(np.array([0.9, 0.1, 0.3]), 0.2)
    cams.append((T2[:3, :3].T, -T2[:3, :3].T @ T2[:3, 3]))
    import cv2

    rv = np.array([cv2.Rodrigues(R)[0].ravel() for R, _ in cams])
    tv = np.array([t for _, t in cams])
    cam = np.repeat(np.arange(3), len(X))
    pt = np.tile(np.arange(len(X)), 3)
    obs = np.concatenate([project(np.repeat(rv[c:c + 1], len(X), 0), np.repeat(tv[c:c + 1], len(X), 0), X, K)
                          for c in range(3)]) + rng.normal(0, 0.5, (3 * len(X), 2))
    obs[:15] += 80.0                                           # a few gross outliers: the robust loss ignores them
    free = np.array([False, False, True])                      # two fixed cameras: no gauge freedom left
    rv0, tv0 = rv.copy(), tv.copy()
    rv0[2] += rng.normal(0, 0.01, 3)
    tv0[2] += rng.normal(0, 0.03, 3)
    X0 = X + rng.normal(0, 0.05, X.shape)
    res = bundle_adjust(rv0, tv0, X0, cam, pt, obs, K, free, scale_px=2.0, max_nfev=30)
    e = np.linalg.norm(project(res.rvecs[cam], res.tvecs[cam], res.X[pt], K) - obs, axis=1)
    assert np.median(e[15:]) < 1.0 and np.allclose(res.rvecs[0], rv[0]) and np.allclose(res.tvecs[0], tv[0])
    assert np.linalg.norm(res.tvecs[2] - tv[2]) < 0.01 and np.linalg.norm(tv0[2] - tv[2]) > 0.02


def test_tracks_never_see_a_frame_twice():
    a = np.array([[10.0, 10], [20, 20]])
    b = np.array([[30.0, 30], [40, 40]])
    c = np.array([[50.0, 50], [60, 60]])
    # 0-1 and 1-2 chain two tracks; a wrong 0-2 match would join keypoint 0 of frame 0 to the second track
    tr = build_tracks(3, {(0, 1): (a, b), (1, 2): (b, c), (0, 2): (a[:1], c[1:])})
    assert tr.n == 2
    for p in range(3):
        assert len(set(tr.tid[p].tolist())) == len(tr.tid[p])


def test_sfm_registers_a_noisy_walk_with_outlier_matches():
    poses, match = _scene()
    conf = SfmConf()
    res = reconstruct(match_stream(len(poses), match, K, conf), K, conf)
    assert len(res.models) == 1 and len(res.models[0].poses) == len(poses) and res.why == {}
    m = res.models[0]
    est = np.array([_c2w(*m.poses[p]) for p in range(len(poses))])
    assert ate_rmse(est, poses, True)[0] < 0.01                # measured 0.002 m over a 3 m arc


def test_sfm_rejects_a_jump_and_says_why():
    poses, match = _scene(jump_at=12)
    conf = SfmConf()
    res = reconstruct(match_stream(len(poses), match, K, conf), K, conf)
    assert 12 not in res.model_of
    assert any(p == 12 and w.startswith("jump") for p, w in res.rejected), res.rejected
    # the frames around it are still registered, and placed right
    m = res.models[0]
    keep = [p for p in range(len(poses)) if p in m.poses]
    assert len(keep) >= len(poses) - 3
    est = np.array([_c2w(*m.poses[p]) for p in keep])
    assert ate_rmse(est, poses[keep], True)[0] < 0.02


def test_a_broken_chain_is_relocalized_against_the_whole_map():
    """A walk cut in two (frames 12-15 match nothing: blur, a fast turn), one pair far in time (a loop pair) linking
    frame 9 with frame 17: the first chain ends at the cut; its whole map then re-localizes frame 17 by PnP on the
    loop's tracks and, from it, the frames after the cut, placed right; the dead frames stay out with reasons."""
    from mosaicthinker.runtime.align.sfm import _Mapper

    poses, match = _scene(n=24)
    dead = {12, 13, 14, 15}

    def cut(a: int, b: int) -> tuple[np.ndarray, np.ndarray]:
        if a in dead or b in dead or (a < 12 < b and (a, b) != (9, 17)):
            return np.zeros((0, 2)), np.zeros((0, 2))
        return match(a, b)

    conf = SfmConf(min_tri_parallax_deg=0.5)  # what 9 and 17 share are far walls (0.1-1.2 deg from 8 to 11)
    tracks = match_stream(len(poses), cut, K, conf, extra_pairs=[(9, 17)])
    mp = _Mapper(tracks, K, conf)
    m, end = mp.chain(0)
    assert sorted(m.poses) == list(range(12)) and end == 12
    got = mp.relocalize(m)
    assert sorted(got) == list(range(16, 24)), (got, mp.why)
    assert not dead & set(m.poses) and {12, 13, 14} <= set(mp.why)
    keep = sorted(m.poses)
    est = np.array([_c2w(*m.poses[p]) for p in keep])
    assert ate_rmse(est, poses[keep], True)[0] < 0.02


def test_pnp_on_degenerate_points_is_a_reason_not_a_crash():
    """SQPnP asserts on collapsed 3-D points (seen on a real walk): the registration fails with its reason."""
    from mosaicthinker.runtime.align.sfm import Reconstruction, Tracks, _Mapper

    uv = np.random.default_rng(0).uniform(0, 400, (40, 2))
    tracks = Tracks([np.arange(40), np.arange(40)], [uv, uv + 1], 40)
    m = Reconstruction(poses={0: (np.eye(3), np.zeros(3))}, X=np.tile([[0.0, 0.0, 2.0]], (40, 1)))
    why = _Mapper(tracks, K, SfmConf()).register(m, 1, 0)
    assert why is not None and 1 not in m.poses


def test_stream_keeps_every_key_frame_and_thins_the_rest():
    s = stream_positions([0, 50, 100], list(range(0, 101, 2)), 20)
    assert {0, 50, 100} <= set(s) and len(s) <= 20 and s == sorted(s)
    assert stream_positions([10, 20], list(range(100)), 160) == list(range(10, 21))


@pytest.mark.slow
def test_real_kitchen_keyframes_posed_from_the_stream(redkitchen):
    """8 key frames over 8 s of the kitchen, RGB only (their depth: the sensor's with an unknown scale each, a
    stand-in for relative depth); SfM over the frames between them (SIFT) places them up to one Sim(3)."""
    from dataclasses import replace

    from mosaicthinker.runtime.align import align_keyframes, make_matcher
    from mosaicthinker.runtime.align.conf import AlignConf
    from mosaicthinker.runtime.frames import open_source

    src = open_source(redkitchen)
    keys = list(range(0, 121, 17))
    rng = np.random.default_rng(0)
    factor = dict(zip(keys, rng.uniform(0.3, 3.0, len(keys))))
    frames = [replace(src[i], depth=src[i].depth * factor[i]) for i in keys]
    al, used = align_keyframes(frames, make_matcher("sift"), {i: None for i in keys}, None, src, lambda f: f, True,
                               AlignConf(), None, thumbs={i: None for i in range(0, 121, 4)},
                               sfm=SfmConf(stream_frames=40))
    assert len(al.poses) >= 7 and al.edge == "sfm" and len(used) > 10
    ev = sorted(al.poses)
    ate = ate_rmse(np.array([al.poses[i] for i in ev]), np.array([src[i].pose_gt for i in ev]), True)[0]
    assert ate < 0.06, ate
    # each pose carries its frame's depth scale, undoing the unknown factor: scale x factor is one constant
    units = np.array([np.cbrt(np.linalg.det(al.poses[i][:3, :3])) * factor[i] for i in ev])
    assert units.max() / units.min() < 1.1, units



def test_loop_pairs_join_far_apart_look_alikes_only():
    from mosaicthinker.runtime.align.rgb_stage import loop_pairs

    d = np.eye(4)[[0, 1, 2, 0]]          # key frames 0 and 3 show the same place; 1 and 2 are unlike anything
    d = d + 0.01 * np.arange(16).reshape(4, 4)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    got = loop_pairs(d, [0, 10, 20, 30], 1, 6)
    assert (0, 30) in got and all(b - a > 6 for a, b in got)
    assert loop_pairs(d, [0, 10, 20, 30], 0, 6) == [] and loop_pairs(d, [0, 3, 5, 8], 1, 100) == []


def test_loop_candidates_are_the_key_frames_and_every_nth_stream_frame():
    from mosaicthinker.runtime.align.rgb_stage import loop_candidates

    stream = list(range(0, 40, 2))
    assert loop_candidates([6, 30], stream, 0) == [6, 30]
    assert loop_candidates([6, 30], stream, 4) == [0, 6, 8, 16, 24, 30, 32]


def test_bundle_adjustment_refines_a_focal_length_10_percent_off():
    """Six cameras see 300 points with a 550 px focal length; adjusted from a 500 px prior: fixed, the
    reprojection error stays high; refined, the focal length comes back within 1 % and the error to the noise."""
    rng = np.random.default_rng(0)
    X = rng.uniform([-3, -2, 4], [3, 2, 8], (300, 3))
    rv = rng.normal(0, 0.1, (6, 3))
    tv = np.c_[np.linspace(-1, 1, 6), rng.normal(0, 0.1, (6, 2))]
    true_K = K @ np.diag([1.1, 1.1, 1.0])
    cam, pt = np.repeat(np.arange(6), len(X)), np.tile(np.arange(len(X)), 6)
    uv = project(rv[cam], tv[cam], X[pt], true_K) + rng.normal(0, 0.5, (len(cam), 2))
    free = np.arange(6) > 0
    start = (rv + rng.normal(0, 0.01, rv.shape), tv + 0.02, X + rng.normal(0, 0.05, X.shape))
    fixed = bundle_adjust(*start, cam, pt, uv, K, free, max_nfev=50)
    got = bundle_adjust(*start, cam, pt, uv, K, free, max_nfev=50, refine_focal=True)
    assert fixed.focal == 1.0 and fixed.rms_px > 1.0
    assert abs(got.focal * K[0, 0] - 550) < 5.5 and got.rms_px < 0.8, (got.focal, got.rms_px)


def test_a_refined_focal_length_is_kept_within_bounds_and_said():
    from mosaicthinker.runtime.align.rgb_stage import hfov_deg, refined_focal

    assert abs(hfov_deg(K) - 65.2) < 0.1
    keep, words = refined_focal(K, K @ np.diag([1.1, 1.1, 1]), (0.67, 1.5))
    assert keep and "refined" in words and f"{hfov_deg(K):.1f} deg" in words
    keep, words = refined_focal(K, K @ np.diag([3.0, 3.0, 1]), (0.67, 1.5))
    assert not keep and "not refined" in words and "may bend" in words
