"""Redundant-frame removal: SSIM against scikit-image, and the down-sample -> ORB -> SSIM cascade."""
from __future__ import annotations

import numpy as np
import pytest
from skimage.metrics import structural_similarity

from mosaicthinker.runtime.scan import DedupConf, orb_track, remove_redundant, ssim
from mosaicthinker.runtime.infra.errors import InputError
from mosaicthinker.runtime.types import Frame
from mosaicthinker.runtime.frames import FrameList, open_source


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
                          "near_duplicates": 3, "kept": 5, "inserted_for_overlap": 0}
    assert res.scores[101]["ssim"] > 0.8 and res.scores[101]["tracked"] > 0.35
    assert res.scores[105]["ssim"] < 0.8 and "tracked" not in res.scores[105]  # ORB only on SSIM's candidates


def _tracking_first(grays: list[np.ndarray], conf: DedupConf) -> list[int]:
    """The rule in the paper's order, written out: ORB tracking against the last kept frame, then SSIM."""
    kept = [0]
    for k in range(1, len(grays)):
        g0, g = grays[kept[-1]], grays[k]
        tracked, motion = orb_track(g0, g, conf.orb_features, n_levels=conf.orb_levels)
        dup = (tracked >= conf.min_tracked and motion <= conf.max_motion * g.shape[1]
               and ssim(g0, g) >= conf.ssim_threshold)
        if not dup:
            kept.append(k)
    return kept


@pytest.mark.parametrize("stride", [1, 4])
def test_ssim_first_keeps_the_frames_tracking_first_keeps(redkitchen, stride):
    """The scan tests SSIM before ORB (cheaper; ORB only on SSIM's candidates): the same frames are kept as by
    the rule in the paper's order, on the real kitchen at 15 fps (many near-duplicates) and every 4th frame."""
    from mosaicthinker.runtime.scan import small_gray

    src = open_source(redkitchen)
    conf = DedupConf(sample_fps=None)
    pos = list(range(0, 160, stride))
    grays = [small_gray(src.colour(p).rgb, conf.work_width) for p in pos]
    frames = [Frame(src.colour(p).rgb, float(k), k, src.K) for k, p in enumerate(pos)]
    res = remove_redundant(FrameList(frames), conf)
    expected = _tracking_first(grays, conf)
    assert res.kept == expected and len(expected) < len(pos)
    assert res.counts["near_duplicates"] == len(pos) - len(expected)


def test_remove_redundant_downsampling_by_time(redkitchen):
    src = open_source(redkitchen)  # 15 fps
    frames = [src[i] for i in range(0, 30)]
    res = remove_redundant(FrameList(frames), DedupConf(sample_fps=3.0, min_sampled=1))
    assert res.counts["after_downsampling"] == 6
    assert sum("downsampled" in r for r in res.dropped.values()) == 24
    assert res.kept[0] == 0 and all(k % 5 == 0 for k in res.kept)


def test_a_short_input_is_sampled_densely_enough_to_compare(redkitchen):
    """Ten photos in a folder (a nominal 30 fps) or a 1 s clip kept one frame at 3 fps, and the map then failed
    with "only 1 key frame"; below `min_sampled` frames the input is sampled by stride instead."""

    src = open_source(redkitchen)  # 15 fps: 2 s -> 6 frames at 3 fps
    frames = [src[i] for i in range(0, 30)]
    res = remove_redundant(FrameList(frames), DedupConf(sample_fps=3.0, min_sampled=16))
    assert res.counts["after_downsampling"] == 30 and res.decisions["dedup.short_input"]["at_sample_fps"] == 6
    assert len(res.kept) > 6  # the comparisons, not the clock, decide what is redundant
    long = remove_redundant(src, DedupConf(sample_fps=3.0, min_sampled=16))
    assert long.counts["after_downsampling"] == 50  # 250 frames: the clock's 50 are enough


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
    from mosaicthinker.runtime.frames import small_gray
    from mosaicthinker.runtime.scan import BackgroundDedup, OnlineDedup

    src = open_source(redkitchen)
    serial, background = OnlineDedup(hist=(8, 64)), BackgroundDedup(OnlineDedup(hist=(8, 64)))
    for p, t in enumerate(src.timestamps[:120]):
        want = serial.wants(float(t))
        assert background.wants(float(t)) == want
        if want:  # the scan hands the worker the colour frame only: its gray copy is made there
            bgr = np.ascontiguousarray(src.colour(p).rgb[:, :, ::-1])
            serial.push(p, small_gray(bgr, serial.conf.work_width, bgr=True), bgr)
            background.push(p, None, bgr)
    a, b = serial.result(120, int), background.finish().result(120, int)
    b_conf_w = DedupConf().thumb_width
    assert a.kept == b.kept and a.dropped == b.dropped and a.scores == b.scores and len(a.kept) > 5
    assert set(a.histograms) == set(a.kept) and all(np.array_equal(a.histograms[i], b.histograms[i]) for i in a.kept)
    assert all(np.array_equal(a.thumbs[i], b.thumbs[i]) for i in a.kept)
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
    from mosaicthinker.runtime.types import Detections
    from mosaicthinker.runtime.pipeline import Perception, PipelineConfig, select
    from mosaicthinker.runtime.infra.trace import Trace

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


def _orb_track_two_matchers(k0, d0, k1, d1):
    """The former orb_track body (two cv2.BFMatcher passes over DMatch lists), as the reference."""
    import cv2

    bf = cv2.BFMatcher(cv2.NORM_HAMMING)
    best_back = np.full(len(k1), -1)
    for m in bf.match(d1, d0):
        best_back[m.queryIdx] = m.trainIdx
    rows = [(m.queryIdx, m.trainIdx, m.distance, n.distance) for m, n in bf.knnMatch(d0, d1, k=2)]
    q, t, dm, dn = (np.array(c) for c in zip(*rows))
    q, t = q.astype(int), t.astype(int)
    good = (dm < 0.8 * dn) & (best_back[t] == q)
    if not good.any():
        return 0.0, float("inf")
    p0, p1 = cv2.KeyPoint_convert(k0), cv2.KeyPoint_convert(k1)
    disp = np.hypot(*(p1[t[good]] - p0[q[good]]).T.astype(np.float64))
    return int(good.sum()) / len(k0), float(np.median(disp))


def test_orb_track_equals_two_brute_force_matchers(redkitchen):
    """One forward pass as arrays plus a backward pass over the ratio test's targets only: the same tracked
    fraction and motion as matching both ways in full, for near and far pairs, at both feature settings."""
    from mosaicthinker.runtime.scan import orb_features, small_gray

    src = open_source(redkitchen)
    gs = [small_gray(src.colour(i).rgb, 320) for i in range(0, 240, 12)]
    for n, levels in ((300, 4), (500, 8)):
        fs = [orb_features(g, n, levels) for g in gs]
        checked = 0
        for i in range(len(gs)):
            for j in (i + 1, i + 4, len(gs) - 1 - i):
                if j < len(gs) and j != i:
                    got = orb_track(gs[i], gs[j], f0=fs[i], f1=fs[j])
                    assert got == _orb_track_two_matchers(*fs[i], *fs[j]), (n, i, j)
                    checked += got[0] > 0
        assert checked > 20  # most pairs track something: the comparison is not of empty results


def test_ssim_float32_within_1e5_of_skimage(redkitchen):
    src = open_source(redkitchen)
    rng = np.random.default_rng(3)
    g = [src[i].rgb[::2, ::2, 1].copy() for i in (0, 2, 30, 120)]
    noisy = np.clip(g[0].astype(int) + rng.integers(-20, 21, g[0].shape), 0, 255).astype(np.uint8)
    for x, y in ((g[0], g[1]), (g[0], g[2]), (g[0], g[3]), (g[0], noisy), (g[0], np.zeros_like(g[0]))):
        f32 = ssim(x, y, dtype=np.float32)
        assert abs(f32 - _ref(x, y)) < 1e-5 and abs(f32 - ssim(x, y)) < 1e-5


def test_fewer_orb_features_and_levels_keep_the_kitchens_decisions(redkitchen):
    """`orb_features` / `orb_levels` reach ORB (the tracked fractions change) and 300 over 4 levels, the cheaper
    setting docs/performance.md weighs, keeps exactly the frames the defaults keep on every frame of the real
    kitchen (15 fps, no down-sampling: ~all are candidates)."""
    from mosaicthinker.runtime.scan import OnlineDedup, small_gray

    src = open_source(redkitchen)
    default, fewer = OnlineDedup({"sample_fps": None}), OnlineDedup({"sample_fps": None, "orb_features": 300,
                                                                     "orb_levels": 4})
    for p, t in enumerate(src.timestamps):
        assert default.wants(float(t)) and fewer.wants(float(t))
        g = small_gray(src.colour(p).rgb, default.conf.work_width)
        default.push(p, g)
        fewer.push(p, g)
    tracked = [(default.scores[i]["tracked"], fewer.scores[i]["tracked"]) for i in default.scores
               if "tracked" in default.scores[i]]  # (ORB runs on SSIM's candidates only)
    assert sum(a != b for a, b in tracked) > len(tracked) // 2  # the settings were used
    assert default.n_dup > 5 and fewer.kept == default.kept and fewer.dropped.keys() == default.dropped.keys()


def test_without_a_plan_the_search_budget_is_capped_per_key_frame(redkitchen):
    """Issue 14: without a device plan the search scored 25% of the candidates, 449 frames (26 s of detector) on
    a 600 s clip; it is now capped at `max_scored_per_keyframe` x K (the rule the planner's target uses too,
    `keyframes.scored_budget`), and the trace says so."""
    from mosaicthinker.runtime.keyframes import scored_budget
    from mosaicthinker.runtime.types import Detections
    from mosaicthinker.runtime.pipeline import Perception, PipelineConfig, select
    from mosaicthinker.runtime.infra.trace import Trace

    assert scored_budget(1795, 16, 0.25, 3, 6.0) == 96 and scored_budget(1795, 16, 0.25, 3, None) == 449
    assert scored_budget(180, 16, 0.25, 3, 6.0) == 48 and scored_budget(10, 4, 0.25, 0, 6.0) == 3
    kc = PipelineConfig().keyframe
    assert kc.max_scored_per_keyframe == kc.min_scored_per_keyframe  # no growth
    src = open_source(redkitchen)
    nothing = lambda frame, names: Detections.empty()  # noqa: E731
    runs = {}
    for cap in (1.5, None):
        t = Trace()
        conf = PipelineConfig.merged({"keyframe": {"max_scored_per_keyframe": cap, "min_scored_per_keyframe": 1}})
        _, _, res, cands = select(src, ["chair"], [], Perception(detect=nothing), conf, t, keyframes=4)
        runs[cap] = (res.frames_scored, t.decisions.get("keyframes.budget_capped"), len(cands))
    n = runs[None][2]
    assert runs[1.5][0] <= 6 < runs[None][0] <= int(np.ceil(0.25 * n))
    assert runs[1.5][1] == {"scored": 6, "fraction_would_score": int(np.ceil(0.25 * n)), "max_per_keyframe": 1.5}
    assert runs[None][1] is None
    with pytest.raises(InputError, match="max_scored_per_keyframe"):
        PipelineConfig.merged({"keyframe": {"max_scored_per_keyframe": 2, "min_scored_per_keyframe": 3}})
