"""The fast paths of issue 14 against the paths they replace: online redundant-frame removal while a video is
scanned, the batched essential-matrix refinement, ORB features reused across comparisons."""
from __future__ import annotations

import numpy as np
import pytest

from mosaicthinker.runtime.align import AlignConf, align_pair_essential, refine_essential
from mosaicthinker.runtime.frames import small_gray
from mosaicthinker.runtime.scan import (DedupConf, OnlineDedup, online_result, orb_features, orb_track, remove_redundant,
                                        scanner)
from mosaicthinker.runtime.infra.errors import InputError
from mosaicthinker.runtime.frames import VideoSource, open_source
from mosaicthinker.runtime.geometry import rotation_about


def _write_video(path, frames, fps=15):
    import cv2

    h, w = frames[0].shape[:2]
    wr = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (w, h))
    for f in frames:
        wr.write(np.ascontiguousarray(f[:, :, ::-1]))
    wr.release()


@pytest.fixture(scope="module")
def kitchen_video(tmp_path_factory, redkitchen):
    """60 real frames forwards then backwards, with two static runs (near-duplicates to drop)."""
    src = open_source(redkitchen)
    rgb = [src[i].rgb for i in range(0, 60)]
    rgb = rgb[:20] + [rgb[20]] * 12 + rgb[20:] + rgb[::-1] + [rgb[0]] * 10
    p = tmp_path_factory.mktemp("video") / "kitchen.mp4"
    _write_video(p, rgb)
    return p


def test_online_dedup_during_scan_equals_decode_pass(kitchen_video):
    offline = remove_redundant(VideoSource(kitchen_video))  # decodes the sampled frames again
    src = VideoSource(kitchen_video, observer=scanner())
    assert online_result(src, DedupConf()) is not None
    online = remove_redundant(src)
    assert online.kept == offline.kept and online.dropped == offline.dropped and online.scores == offline.scores
    assert online.counts == offline.counts and online.counts["near_duplicates"] > 0  # the static runs
    # another config: the scan's result does not apply, the removal decodes (and still agrees with a plain run)
    other = {"ssim_threshold": 0.9}
    assert online_result(src, DedupConf.merged(other)) is None
    assert remove_redundant(src, other).kept == remove_redundant(VideoSource(kitchen_video), other).kept


def test_video_gray_equals_rgb_gray(kitchen_video):
    src = VideoSource(kitchen_video)
    for i in (0, 5, 40):
        g = src.gray(i, 320)
        assert np.array_equal(g, small_gray(src[i].rgb, 320))


def test_online_dedup_on_frames_matches_remove_redundant(redkitchen):
    src = open_source(redkitchen)
    od = OnlineDedup({"sample_fps": None, "stride": 3})
    for p, t in enumerate(src.timestamps[:90]):
        if od.wants(float(t)):
            od.push(p, small_gray(src[p].rgb, 320))
    res = od.result(90, int)
    ref = remove_redundant([src[i] for i in range(90)], {"sample_fps": None, "stride": 3})
    assert res.kept == ref.kept and res.counts == ref.counts


def test_orb_track_with_precomputed_features(redkitchen):
    src = open_source(redkitchen)
    g0, g1 = small_gray(src[0].rgb, 320), small_gray(src[4].rgb, 320)
    a = orb_track(g0, g1)
    b = orb_track(g0, g1, 500, orb_features(g0), orb_features(g1))
    assert a == b and 0.2 < a[0] <= 1.0


def _scipy_refine(R, t, xa, xb, scale):
    """The former implementation (scipy least_squares, Huber), as the reference."""
    from scipy.optimize import least_squares

    ha, hb = np.hstack([xa, np.ones((len(xa), 1))]), np.hstack([xb, np.ones((len(xb), 1))])
    u = np.cross(t, [1.0, 0, 0] if abs(t[0]) < 0.9 else [0, 1.0, 0])
    u /= np.linalg.norm(u)
    v = np.cross(t, u)

    def pose(p):
        a = float(np.linalg.norm(p[:3]))
        Rn = (rotation_about(p[:3] / a, a) if a > 1e-12 else np.eye(3)) @ R
        tn = t + p[3] * u + p[4] * v
        return Rn, tn / np.linalg.norm(tn)

    def res(p):
        Rn, tn = pose(p)
        E = np.array([[0, -tn[2], tn[1]], [tn[2], 0, -tn[0]], [-tn[1], tn[0], 0]]) @ Rn
        Ea, Eb = ha @ E.T, hb @ E
        return np.sum(hb * Ea, 1) / (np.sqrt(Ea[:, 0]**2 + Ea[:, 1]**2 + Eb[:, 0]**2 + Eb[:, 1]**2) + 1e-12)

    return pose(least_squares(res, np.zeros(5), loss="huber", f_scale=scale, method="trf", max_nfev=50).x)


def _angle(A, B):
    return np.degrees(np.arccos(np.clip((np.trace(A.T @ B) - 1) / 2, -1, 1)))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_refine_essential_reaches_the_scipy_minimum(seed):
    rng = np.random.default_rng(seed)
    R = rotation_about(rng.normal(size=3), 0.2)
    t = rng.normal(size=3)
    t /= np.linalg.norm(t)
    X = rng.uniform([-1, -1, 2], [1, 1, 5], size=(200, 3))
    xa = X[:, :2] / X[:, 2:]
    Xb = X @ R.T + t
    xb = Xb[:, :2] / Xb[:, 2:] + rng.normal(scale=1e-3, size=(200, 2))
    xb[:20] += rng.normal(scale=0.05, size=(20, 2))  # outliers: the Huber loss
    R0 = rotation_about(rng.normal(size=3), 0.02) @ R
    t0 = t + rng.normal(scale=0.05, size=3)
    t0 /= np.linalg.norm(t0)
    Rn, tn = refine_essential(R0, t0, xa, xb, 2e-3)
    Rs, ts = _scipy_refine(R0, t0, xa, xb, 2e-3)
    assert _angle(Rn, Rs) < 1e-3 and np.degrees(np.arccos(np.clip(tn @ ts, -1, 1))) < 1e-2
    assert _angle(Rn, R) < _angle(R0, R) and abs(np.linalg.norm(tn) - 1) < 1e-12


@pytest.mark.slow  # SIFT on 24 real frames: 15.6 s at load 10 on 2 cores
def test_essential_method_names(redkitchen):
    from mosaicthinker.runtime.align.matching import FeatureMatcher

    src = open_source(redkitchen)
    fm = FeatureMatcher("sift")
    pairs = [(i, i + d) for i in (0, 60, 120) for d in (8, 16)]
    for method in ("magsac", "magsac-prosac"):
        conf = AlignConf(essential_method=method, essential_px=1.0)
        ok = [align_pair_essential(fm.match(src[i].rgb, src[j].rgb), src[i].depth, src[i].K, src[j].depth,
                                   src[j].K, conf).ok for i, j in pairs]
        assert sum(ok) >= len(pairs) // 2, (method, ok)
    a, b = src[0], src[8]
    with pytest.raises(InputError):
        align_pair_essential(fm.match(a.rgb, b.rgb), a.depth, a.K, b.depth, b.K, AlignConf(essential_method="lmeds"))
