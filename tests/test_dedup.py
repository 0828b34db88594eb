"""Redundant-frame removal: SSIM against scikit-image, and the down-sample -> ORB -> SSIM cascade."""
from __future__ import annotations

import numpy as np
import pytest
from skimage.metrics import structural_similarity

from mosaicthinker.runtime.dedup import DedupConf, orb_track, remove_redundant, ssim
from mosaicthinker.runtime.errors import InputError
from mosaicthinker.runtime.frames import Frame, FrameList, open_source


def _ref(a, b, **kw):
    return structural_similarity(a, b, gaussian_weights=True, sigma=1.5, use_sample_covariance=False, **kw)


def test_ssim_matches_skimage_synthetic():
    rng = np.random.default_rng(0)
    for shape in [(11, 11), (40, 57), (64, 48)]:
        a = rng.integers(0, 256, shape, dtype=np.uint8)
        for noise in (5, 40, 120):
            b = np.clip(a.astype(int) + rng.integers(-noise, noise + 1, shape), 0, 255).astype(np.uint8)
            assert abs(ssim(a, b) - _ref(a, b)) < 1e-12
    x = rng.random((30, 40))
    y = x + 0.1 * rng.random((30, 40))
    assert abs(ssim(x, y, data_range=1.0) - _ref(x, y, data_range=1.0)) < 1e-12
    with pytest.raises(ValueError):
        ssim(x, y)  # float images need data_range


def test_ssim_matches_skimage_real(redkitchen):
    src = open_source(redkitchen)
    a, b, c = src[0].rgb[::2, ::2], src[3].rgb[::2, ::2], src[120].rgb[::2, ::2]
    for x, y in ((a, b), (a, c), (a, a)):
        assert abs(ssim(x, y) - _ref(x, y, channel_axis=2)) < 1e-12
        gx, gy = x[..., 1], y[..., 1]
        assert abs(ssim(gx, gy) - _ref(gx, gy)) < 1e-12
    assert ssim(a, a) == pytest.approx(1.0)


def test_remove_redundant_drops_static_copies(redkitchen):
    src = open_source(redkitchen)
    K = src.K
    # 0-3: the camera rests (copies with sensor noise); then four views from across the sequence
    base = src[0].rgb
    rng = np.random.default_rng(0)
    rgbs = [np.clip(base.astype(int) + rng.integers(-3, 4, base.shape), 0, 255).astype(np.uint8)
            for _ in range(4)] + [src[i].rgb for i in (60, 120, 180, 240)]
    frames = [Frame(rgb, 0.5 * k, 100 + k, K) for k, rgb in enumerate(rgbs)]
    res = remove_redundant(FrameList(frames), {"sample_fps": None})
    assert res.kept == [100, 104, 105, 106, 107]
    assert set(res.dropped) == {101, 102, 103} and all("near-duplicate" in r for r in res.dropped.values())
    assert res.counts == {"input": 8, "after_downsampling": 8, "downsampled_away": 0, "candidates": 3,
                          "near_duplicates": 3, "kept": 5}
    assert res.scores[101]["ssim"] > 0.8 and "ssim" not in res.scores.get(105, {})  # SSIM only on candidates


def test_remove_redundant_downsampling_by_time(redkitchen):
    src = open_source(redkitchen)  # 15 fps
    frames = [src[i] for i in range(0, 30)]
    res = remove_redundant(FrameList(frames), DedupConf(sample_fps=3.0))
    assert res.counts["after_downsampling"] == 6
    assert sum("downsampled" in r for r in res.dropped.values()) == 24
    assert res.kept[0] == 0 and all(k % 5 == 0 for k in res.kept)


def test_orb_track_identity_and_unrelated(redkitchen):
    src = open_source(redkitchen)
    g0 = src[0].rgb[::2, ::2, 1].copy()
    tracked, motion = orb_track(g0, g0)
    assert tracked > 0.9 and motion == 0
    t2, _ = orb_track(g0, np.zeros_like(g0))
    assert t2 == 0


def test_remove_redundant_errors():
    with pytest.raises(InputError):
        remove_redundant([])
    with pytest.raises(InputError, match="unknown"):
        DedupConf.merged({"ssim_treshold": 0.5})


def test_background_scan_gives_the_serial_result_and_raises_the_workers_error(redkitchen):
    from mosaicthinker.runtime.dedup import BackgroundDedup, OnlineDedup, small_gray

    src = open_source(redkitchen)
    serial, background = OnlineDedup(), BackgroundDedup(OnlineDedup())
    for p, t in enumerate(src.timestamps[:120]):
        want = serial.wants(float(t))
        assert background.wants(float(t)) == want
        if want:
            g = small_gray(src.colour(p).rgb, serial.conf.work_width)
            serial.push(p, g)
            background.push(p, g)
    a, b = serial.result(120, int), background.finish().result(120, int)
    b_conf_w = DedupConf().thumb_width
    assert a.kept == b.kept and a.dropped == b.dropped and a.scores == b.scores and len(a.kept) > 5
    assert set(b.thumbs) == set(b.kept) and all(g.shape[1] == b_conf_w for g in b.thumbs.values())
    bad = BackgroundDedup(OnlineDedup())
    bad.wants(0.0)
    bad.push(0, np.zeros((48, 64), np.uint8))
    bad.wants(1.0)
    bad.push(1, np.zeros((40, 64), np.uint8))  # a frame of another size: the worker's InputError reaches us
    with pytest.raises(InputError, match="differs"):
        bad.finish()


def test_the_key_frame_search_reads_candidates_thumbnails_not_the_video(redkitchen):
    """The content prior's densities come from dedup's thumbnails: the search decodes only the frames it
    scores (and their histogram neighbours), not every candidate a second time."""
    from mosaicthinker.runtime.perception import Detections
    from mosaicthinker.runtime.pipeline import Perception, PipelineConfig, select
    from mosaicthinker.runtime.trace import Trace

    class Counting:
        def __init__(self, src):
            self.src, self.read = src, set()

        def __getattr__(self, name):
            return getattr(self.src, name)

        def __len__(self):
            return len(self.src)

        def colour(self, i):
            self.read.add(int(i))
            return self.src.colour(i)

    src = Counting(open_source(redkitchen))
    nothing = lambda frame, names: Detections.empty()  # noqa: E731 - no object anywhere: scores are all 0
    conf = PipelineConfig.merged({"keyframe": {"budget": 6}})
    chosen, _, res, cands = select(src, ["chair"], [], Perception(detect=nothing), conf, Trace(), keyframes=4)
    assert len(cands) > 30 and res.frames_scored <= 6
    assert len(src.read & set(cands)) < len(cands) // 2, sorted(src.read)
