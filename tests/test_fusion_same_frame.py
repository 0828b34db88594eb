"""One frame's detections of one name: a union box over two side-by-side objects and a box NMS left inside another
box of the same object are left out (`same_frame_redundant`); objects side by side or one in front of another stay
two instances; the trace says what was left out."""
from __future__ import annotations

import numpy as np

from mosaicthinker.runtime.map import FusionConfig, fuse_observations, same_frame_redundant
from mosaicthinker.runtime.types import Observation
from mosaicthinker.runtime.infra.trace import Trace


def _slab(rng, x0, x1, y, n=600):
    """Points of a screen-like vertical slab spanning x0..x1 at depth y."""
    return np.c_[rng.uniform(x0, x1, n), np.full(n, y) + rng.normal(0, 0.005, n), rng.uniform(1.2, 1.8, n)]


def _ob(pts, frame, score, name="tv"):
    return Observation(name, score, frame, float(frame), pts, np.zeros(4))


def test_union_box_of_two_side_by_side_screens_is_left_out_and_they_stay_two():
    rng = np.random.default_rng(0)
    left, right = _slab(rng, 0.0, 1.0, 3.0), _slab(rng, 1.05, 1.9, 3.0)
    obs = [_ob(left, 0, 0.7), _ob(right, 0, 0.6), _ob(np.concatenate([left, right]), 0, 0.8),
           _ob(_slab(rng, 0.1, 0.9, 3.0), 1, 0.7), _ob(_slab(rng, 1.1, 1.8, 3.0), 1, 0.6)]
    assert same_frame_redundant(obs, 0.12) == {2: "group"}
    tr = Trace()
    inst, _ = fuse_observations(obs, FusionConfig(), tr)
    assert sorted(round(float(o.center[0]), 1) for o in inst) == [0.5, 1.5]
    ev = [e for e in tr.events if e["kind"] == "fusion"]
    assert ev and "group" in ev[0]["message"]


def test_a_box_inside_a_box_of_the_same_screen_is_a_duplicate_the_higher_score_stays():
    rng = np.random.default_rng(1)
    whole, part = _slab(rng, 0.0, 1.0, 3.0), _slab(rng, 0.1, 0.7, 3.0)
    obs = [_ob(part, 0, 0.5), _ob(whole, 0, 0.7)]
    assert same_frame_redundant(obs, 0.12) == {0: "duplicate"}
    inst, _ = fuse_observations(obs)
    assert len(inst) == 1 and inst[0].score == 0.7


def test_one_object_in_front_of_another_and_objects_side_by_side_stay():
    rng = np.random.default_rng(2)
    near, far = _slab(rng, 0.0, 1.0, 2.0), _slab(rng, 0.2, 0.8, 3.0)  # overlapping boxes, other depths
    side = _slab(rng, 1.3, 2.0, 3.0)
    obs = [_ob(near, 0, 0.5, "chair"), _ob(far, 0, 0.7, "chair"), _ob(side, 0, 0.6, "chair")]
    assert same_frame_redundant(obs, 0.12) == {}
    assert len(fuse_observations(obs)[0]) == 3
    # two mugs 2 cm apart: the voxel-size radius fusion uses does not take one for a copy of the other
    mug = lambda x0: np.c_[rng.uniform(x0, x0 + 0.08, 200), rng.uniform(1.0, 1.08, 200), rng.uniform(0.75, 0.85, 200)]
    mugs = [_ob(mug(0.0), 0, 0.6, "cup"), _ob(mug(0.10), 0, 0.5, "cup")]
    assert same_frame_redundant(mugs, FusionConfig().voxel_m) == {}


def test_refinement_views_are_not_detector_repeats():
    rng = np.random.default_rng(3)
    whole = _slab(rng, 0.0, 1.0, 3.0)
    part = _ob(_slab(rng, 0.1, 0.7, 3.0), 0, 0.5)
    part.recovered = True  # re-prompted by occlusion refinement, not a detection
    assert same_frame_redundant([part, _ob(whole, 0, 0.7)], 0.12) == {}
