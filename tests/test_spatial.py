"""The spatial index answers what the exhaustive search answers (ties included), and big maps stay fast: a count
and a distance between two large categories touch O(n log n) work, not every pair."""
from __future__ import annotations

import time

import numpy as np
import pytest

from mosaicthinker.runtime.answer.spatial import BoxSet, closest_pair, k_nearest, nearest_values
from mosaicthinker.runtime.geometry import OrientedBox, box_distance, rotation_about
from mosaicthinker.runtime.map import ObjectInstance


def _boxes(rng, n, spread, big=0):
    out = []
    for i in range(n):
        size = rng.uniform(0.2, 1.2, 3) * (6.0 if i < big else 1.0)
        R = rotation_about([0, 0, 1], rng.uniform(0, 6.3)) if i % 3 else rotation_about(rng.normal(size=3),
                                                                                       rng.uniform(0, 3))
        out.append(ObjectInstance(i, "x", OrientedBox(rng.uniform(0, spread, 3) * [1, 1, 0.2], size, R.T)))
    return out


def _brute_pair(a, b):
    best = None
    for i, x in enumerate(a):
        for j, y in enumerate(b):
            if x is y:
                continue
            d = box_distance(x.box, y.box)
            if best is None or d < best[0]:
                best = (d, i, j)
    return best


@pytest.mark.parametrize("spread, big, n", [(6.0, 0, 24),  # 40 > SMALL: the KD-tree's path (slow: brute force)
                                            pytest.param(60.0, 3, 40, marks=pytest.mark.slow)])
def test_closest_pair_and_nearest_values_equal_the_exhaustive_search(spread, big, n):
    rng = np.random.default_rng(int(spread) + big)
    a, b = _boxes(rng, n + 6, spread, big), _boxes(rng, n, spread, big)
    d, x, y = closest_pair(a, b)
    want = _brute_pair(a, b)
    assert d == want[0] and x is a[want[1]] and y is b[want[2]]
    shared = a[:n // 2] + b[:n // 2]  # a list with itself: an instance is never its own partner
    d, x, y = closest_pair(shared, shared)
    want = _brute_pair(shared, shared)
    assert d == want[0] and x is shared[want[1]] and y is shared[want[2]]
    per = {i: min(box_distance(x.box, y.box) for y in b) for i, x in enumerate(a)}
    for largest in (False, True):
        got = nearest_values(a, b, 7, largest)
        want = sorted(per, key=lambda i: (-per[i] if largest else per[i], i))[:7]
        assert list(got) == want and all(got[i] == per[i] for i in got)
    bs = BoxSet(b)
    allow = np.arange(len(b)) % 2 == 0
    for o in a[:10]:
        near = sorted((box_distance(o.box, y.box), j) for j, y in enumerate(b) if allow[j])[:3]
        assert k_nearest(o, bs, 3, allow) == near


def _big_map(n, seed=0):
    from mosaicthinker.runtime.map import SemanticMap

    rng = np.random.default_rng(seed)
    side = np.sqrt(n * 4.0)  # one object per 4 square metres
    names = ("chair", "table", "sofa", "lamp", "cabinet")
    inst = [ObjectInstance(i, names[i % len(names)] if i >= 2 else ("refrigerator", "door")[i],
                           OrientedBox(np.array([*rng.uniform(0, side, 2), 0.5]), rng.uniform(0.3, 1.2, 3),
                                       rotation_about([0, 0, 1], rng.uniform(0, 6.3)).T)) for i in range(n)]
    return SemanticMap(inst, None, [(0.0, np.eye(4))])


@pytest.mark.slow
def test_big_maps_grow_near_linearly_for_counts_distances_and_selectors():
    """2,000 and 20,000 objects (400 and 4,000 chairs and tables): the time of each question grows by far less
    than the square of the map (x100); checked as a ratio measured in one run."""
    from mosaicthinker.runtime.answer import MapReasoner

    qs = ["How many chairs are there?", "How far is the chair from the table?",
          "What is the nearest object to the refrigerator?", "How far is the chair nearest the door from the sofa?",
          "Where is the refrigerator?", "How many chairs are near the tables?"]
    times = {}
    for n in (2000, 20000):
        r = MapReasoner(_big_map(n))
        t0 = time.process_time()
        for q in qs:
            assert r.answer(q).ok, q
        times[n] = time.process_time() - t0
    assert times[20000] < 30 * times[2000], times


def test_located_counts_with_culling_equal_every_pair_tested():
    """"How many chairs are near / on / under the tables?" over a map of 120 objects: the culled count equals the
    relation tested on every chair x table pair."""  # 120 objects: the exhaustive side is the slow one
    from mosaicthinker.runtime.answer import MapReasoner, ReasonerConfig, relation_holds
    from mosaicthinker.runtime.map import SemanticMap

    rng = np.random.default_rng(5)
    inst = []
    for i in range(120):
        name = "chair" if i % 2 else "table"
        z = rng.uniform(0.1, 1.5)
        inst.append(ObjectInstance(i, name, OrientedBox(np.array([*rng.uniform(0, 7, 2), z]),
                                                        rng.uniform(0.2, 1.4, 3),
                                                        rotation_about([0, 0, 1], rng.uniform(0, 6.3)).T)))
    r, conf = MapReasoner(SemanticMap(inst, None, [])), ReasonerConfig()
    chairs, tables = [o for o in inst if o.name == "chair"], [o for o in inst if o.name == "table"]
    for rel, q in (("near", "How many chairs are near the tables?"), ("on", "How many chairs are on the tables?"),
                   ("under", "How many chairs are under the tables?")):
        want = sum(any(relation_holds(c, t, rel, conf) for t in tables) for c in chairs)
        assert r.answer(q).value == want, (q, want)
