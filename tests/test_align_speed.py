"""Issue 31 (speed): the backbone's walks never extract a frame's features twice, whatever the matcher's default
cache bound (`LRU.hold`, `align_backbone`); real 7-Scenes frames with sensor depth and ORB, nothing mocked."""
from __future__ import annotations

from collections import Counter

import numpy as np

from mosaicthinker.runtime.infra.lru import LRU


def test_hold_grows_a_cache_and_never_shrinks_or_enables_one():
    c = LRU(2)
    c.hold(5)
    for k in range(5):
        c.put(k, k)
    assert len(c) == 5 and c.get(0) == 0
    c.hold(3)
    assert c.size == 5
    off = LRU(0)
    off.hold(10)
    off.put(1, 1)
    assert len(off) == 0


def _run(src, cache_size):
    from mosaicthinker.runtime.align import AlignConf, BackboneConf, align_keyframes
    from mosaicthinker.runtime.align.matching import FeatureMatcher
    from mosaicthinker.runtime.infra.trace import Trace

    class Counting(FeatureMatcher):
        def _remember(self, key, f):  # called once per extraction of a keyed frame
            self.seen[key] += 1
            super()._remember(key, f)

    m = Counting("orb", cache_size=cache_size)
    m.seen = Counter()
    idx = [0, 40, 80]  # far enough apart that walks load frames between them
    frames = [src[i] for i in idx]
    al, used = align_keyframes(frames, m, {i: None for i in idx}, None, src, lambda f: f, False, AlignConf(),
                               Trace(), backbone=BackboneConf(walk_matcher="pipeline", max_frames=30, closures=0))
    return al, used, m.seen


def test_walks_extract_each_frame_once_with_a_tiny_cache(redkitchen):
    from mosaicthinker.runtime.frames import open_source

    src = open_source(redkitchen)
    al, used, seen = _run(src, cache_size=2)
    assert len(used) >= 3, "the walks loaded no frames: the test would prove nothing"
    assert max(seen.values()) == 1, {k: n for k, n in seen.items() if n > 1}
    al_big, used_big, _ = _run(src, cache_size=10_000)  # the cache changes the cost, never the result
    assert sorted(al.poses) == sorted(al_big.poses) and [f.index for f in used] == [f.index for f in used_big]
    for k in al.poses:
        assert np.allclose(al.poses[k], al_big.poses[k], atol=1e-9)
