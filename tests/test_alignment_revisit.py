"""Bridges found by appearance (`alignment.revisit_attach`): a long video comes back to places, so a key frame
with no aligned key frame near it in time is connected through a frame near it in time that looks like an aligned
frame far away in time, then a time chain. Pure parts on toy data; the whole step on a ping-pong of 7-Scenes."""
from __future__ import annotations

import dataclasses

import cv2
import numpy as np

from mosaicthinker.runtime.align import (AlignConf, AlignmentResult, BlockPairs, bridge_attach, revisit_attach,
                                         revisit_pairs, thumb_histograms)
from mosaicthinker.runtime.geometry import invert
from mosaicthinker.runtime.align.matching import make_matcher
from mosaicthinker.runtime.infra.trace import Trace


def test_thumb_histograms_are_correlations():
    rng = np.random.default_rng(0)
    a = rng.integers(0, 256, (48, 64), dtype=np.uint8)
    h = thumb_histograms({1: a, 2: a.copy(), 3: 255 - a, 4: np.full((48, 64), 7, np.uint8)})
    assert np.isclose(h[1] @ h[2], 1.0) and np.isclose(np.linalg.norm(h[3]), 1.0)
    dark, bright = np.full((48, 64), 20, np.uint8), np.full((48, 64), 230, np.uint8)
    g = thumb_histograms({1: dark, 2: dark + rng.integers(0, 3, dark.shape, dtype=np.uint8), 3: bright})
    assert g[1] @ g[2] > g[1] @ g[3]


def test_revisit_pairs_pick_near_frames_alike_far_aligned_ones():
    times = np.arange(100, dtype=float)       # 1 s apart
    look = {0: 10, 1: 200, 2: 100}            # three places: dark, bright, middle
    # frame i shows place look[i // 10 % 3]; frames 0-9 aligned; u = 95 (place look[9 % 3 = 0])
    thumbs = {i: np.full((6, 8), look[i // 10 % 3], np.uint8) for i in range(100)}
    hist = thumb_histograms(thumbs)
    aligned = [0, 5, 30, 60, 61]
    pairs = revisit_pairs(95, aligned, hist, times, 8.0, set(), 3)
    assert len(pairs) == 3
    for c, a in pairs:
        assert abs(c - 95) <= 8 and c not in aligned          # near u in time, not aligned yet
        assert abs(a - 95) > 8 and a in aligned               # aligned and far from u
        assert thumbs[c][0, 0] == thumbs[a][0, 0]             # the same place (identical histograms)
    # a tried pair is not proposed again; aligned frames near u in time are the time chains' work
    c, a = pairs[0]
    assert (c, a) not in revisit_pairs(95, aligned, hist, times, 8.0, {frozenset((a, c))}, 3)
    assert revisit_pairs(95, [90], hist, times, 8.0, set(), 3) == []
    assert revisit_pairs(95, aligned, hist, times, 8.0, set(), 0) == []


class _PingPong:
    """Frames 0..n-1 of a source forwards, then backwards (a walk back): index, time re-numbered."""

    def __init__(self, src, n):
        self.src, self.n = src, n
        self.timestamps = np.arange(2 * n) / 15.0
        self.loaded: list[int] = []

    def __len__(self):
        return 2 * self.n

    def real(self, i):
        return i if i < self.n else 2 * self.n - 1 - i

    def __getitem__(self, i):
        self.loaded.append(int(i))
        return dataclasses.replace(self.src[self.real(i)], index=int(i), t=float(self.timestamps[i]))


def test_revisit_bridges_align_a_key_frame_far_in_time_from_every_aligned_one(redkitchen):
    """Key frame 192 (7-Scenes frame 7, 12.8 s) is over `bridge_max_gap_s` from the only aligned key frame 20
    (frame 20, 1.3 s), and their direct pair is blocked: time bridging cannot reach it. The walk back shows
    frame 20's place again at 179 (0.9 s before 192): found by its thumbnail, attached to 20, then chained to
    192 in time. The pose agrees with the ground truth and the loads stay within the budget."""
    from mosaicthinker.runtime.frames import open_source

    pp = _PingPong(open_source(redkitchen), 100)
    thumbs = {i: cv2.resize(cv2.cvtColor(pp.src[pp.real(i)].rgb, cv2.COLOR_RGB2GRAY), (64, 48),
                            interpolation=cv2.INTER_AREA) for i in range(0, 200, 3)}
    thumbs[20] = cv2.resize(cv2.cvtColor(pp.src[20].rgb, cv2.COLOR_RGB2GRAY), (64, 48), interpolation=cv2.INTER_AREA)
    k20, k192 = pp[20], pp[192]
    pp.loaded.clear()

    def run(conf, blocked):
        al = AlignmentResult({20: np.eye(4)}, 20, [], [192], "mst")
        trace = Trace()
        used = bridge_attach(al, [k20, k192], pp, BlockPairs(make_matcher("sift"), blocked), lambda f: f, conf,
                             trace, thumbs)
        return al, used, trace

    conf = AlignConf.merged(bridge_max_gap_s=3.0, bridge_frames=12, min_inliers=AlignConf.keyframe_min_inliers)
    al, used, trace = run(conf, [(20, 192)])
    assert al.unaligned == [] and 192 in al.poses
    assert any(abs(f.index - 179) <= 3 for f in used)                    # the revisit of frame 20's place
    assert len(set(pp.loaded)) <= conf.bridge_frames and all(i >= 147 for i in pp.loaded)  # near 192 only
    T_gt = invert(k20.pose_gt) @ k192.pose_gt
    T = al.poses[192]
    assert np.linalg.norm(T[:3, 3] - T_gt[:3, 3]) < 0.05
    ev = [e for e in trace.events if "found by appearance" in e["message"]][-1]
    assert ev["aligned"] == [192] and ev["unaligned"] == []

    # off: the key frame stays unaligned, nothing is loaded
    pp.loaded.clear()
    al, used, _ = run(conf.merged(conf, revisit_tries=0), [(20, 192)])
    assert al.unaligned == [192] and used == [] and pp.loaded == []

    # a key frame with an aligned key frame within `bridge_max_gap_s` is the time chains' (which failed here):
    # no revisit is tried for it, nothing is loaded
    pp.loaded.clear()
    al = AlignmentResult({20: np.eye(4), 185: np.eye(4)}, 20, [], [192], "mst")
    pool = {20: k20, 185: pp[185], 192: k192}
    pp.loaded.clear()
    left, used = revisit_attach(al, pool, {20, 185, 192}, pp, BlockPairs(make_matcher("sift"), [(20, 192)]),
                                lambda f: f, conf, thumbs, 12)
    assert (left, used, pp.loaded, al.unaligned) == (12, [], [], [192])
