"""Real-room failure modes, on synthetic inputs: the box-prompted mask's depth layer, one detection named twice,
and the floor fit when the key frames see mostly a table top and little floor."""
from __future__ import annotations

import numpy as np
import pytest

from mosaicthinker.runtime.map import box_depth_mask, box_layer, duplicate_names, fit_floor_plane


def test_box_mask_takes_the_layer_that_stands_out_not_the_wall_or_the_table_edge():
    d = np.full((120, 160), 3.0, np.float32)      # the wall / counter behind: everywhere
    d[80:, :] = 1.0                               # a table edge in front: across the whole image
    d[20:80, 60:100:3] = 1.6                      # a chair back (slats) over the table edge: only in the box
    d[20:30, 60:100] = 1.6                        # its top rail
    box = np.array([50, 15, 110, 110])
    m = box_depth_mask(d, box)
    chair = (d == 1.6)
    assert m[chair].all() and not m[d == 3.0].any() and not m[d == 1.0].any()
    # the box's central half is mostly wall and table: its median is not the chair's depth
    c = d[15 + 24:110 - 24, 50 + 15:110 - 15]
    assert abs(float(np.median(c)) - 1.6) > 0.5
    assert box_layer(d[15:110, 50:110].ravel(), np.array([3.0] * 50 + [1.0] * 50)) == pytest.approx(1.6, rel=0.05)


def test_box_mask_of_an_object_on_a_plain_background_is_the_object():
    d = np.full((100, 100), 3.0, np.float32)
    d[30:70, 30:70] = 1.0
    m = box_depth_mask(d, np.array([20, 20, 80, 80]))
    assert m.sum() == 40 * 40 and m[50, 50]


def test_one_box_named_twice_is_one_detection_two_objects_side_by_side_stay():
    boxes = np.array([[10, 10, 100, 80], [12, 11, 101, 79], [110, 10, 200, 80]], np.float32)
    keep = duplicate_names(boxes, ["tv", "laptop", "tv"], np.array([0.6, 0.7, 0.9]))
    assert keep.tolist() == [False, True, True]   # the laptop/tv pair: the higher score stays; the other tv stays
    keep = duplicate_names(boxes[:2], ["chair", "chair"], np.array([0.6, 0.7]))
    assert keep.all()                             # same name: the detector's own NMS decides, not this


def _plane(rng, n, z, half):
    xy = rng.uniform(-half, half, (n, 2))
    return np.c_[xy, np.full(n, z) + rng.normal(0, 0.004, n)]


def test_floor_fit_with_a_large_table_and_little_floor_keeps_the_level_normal_and_finds_the_floor():
    rng = np.random.default_rng(0)
    table = _plane(rng, 20000, 0.75, 0.8)
    floor = _plane(rng, 300, 0.0, 2.0)             # the floor only seen past the furniture: ~1 % of the points
    floor = floor[np.abs(floor[:, :2]).max(1) > 1.0]
    wall = np.c_[rng.uniform(-2, 2, 8000), np.full(8000, 2.0), rng.uniform(0, 2.2, 8000)]
    counter = _plane(rng, 6000, 0.9, 0.5) + [0, 1.4, 0]
    P = np.concatenate([table, floor, wall, counter])
    fit = fit_floor_plane(P, np.array([0.05, 0.0, -1.0]))
    assert fit is not None
    n, d, _ = fit
    assert np.degrees(np.arccos(-n[2])) < 0.5
    assert -d == pytest.approx(0.0, abs=0.03)      # down . p = d: the floor z = -d
    assert np.mean(P @ n > d + 0.05) <= 0.005      # nothing lies below it


def test_eval_scene_maps_one_name_per_detector_label_set():
    from mosaicthinker.runtime.models.detector import one_name_per_label
    from mosaicthinker.runtime.models.detector import map_names

    labels = ["person", "chair", "dining table", "tv", "cup"]
    mapping, _ = map_names(["chair", "stool", "desk", "table", "monitor", "tv", "mug", "cup"], labels)
    keep = one_name_per_label(mapping, labels, ["table"])
    assert keep == {"chair", "table", "tv", "cup"}   # annotated name first, else the label's own name
    # no preference: the label's head noun ("table" for "dining table"), not the first alias alphabetically
    # ("desk": "what's the closest object to the cup?" on the kitchen answered "desk")
    assert one_name_per_label(mapping, labels, []) == {"chair", "table", "tv", "cup"}
    assert one_name_per_label({"desk": [0], "counter": [0]}, ["worktop"], []) == {"counter"}  # else alphabetical
