"""Semantic map data structures: meta_info boxes, corners vs min/max, room extent, save/load, geometry helpers."""
from __future__ import annotations

import json

import numpy as np
import pytest

from mosaicthinker.runtime.infra.errors import InputError
from mosaicthinker.runtime.geometry import (OrientedBox, box_closest_points, box_distance, convex_hull_2d,
                                            polygon_area, rotation_about)
from mosaicthinker.runtime.map import MAP_SCHEMA, ObjectInstance, Room, SemanticMap, room_from_boxes


@pytest.fixture(scope="module")
def meta(vsibench_dir):
    with open(vsibench_dir / "meta_info.json") as f:
        return json.load(f)


def test_corners_reproduce_meta_min_max(meta):
    """normalizedAxes rows are the box axes: the corners' axis-aligned extent is the file's min/max."""
    n = 0
    for scene in meta.values():
        for boxes in scene["object_bbox"].values():
            for b in boxes:
                lo, hi = OrientedBox.from_meta(b).aabb()
                np.testing.assert_allclose(lo, b["min"], atol=1e-6)
                np.testing.assert_allclose(hi, b["max"], atol=1e-6)
                n += 1
    assert n > 800


def test_columns_as_axes_would_not_reproduce_min_max(meta):
    """The opposite reading (columns = axes) fails on rotated boxes, so the test above can tell them apart."""
    bad = 0
    for scene in meta.values():
        for boxes in scene["object_bbox"].values():
            for b in boxes:
                ob = OrientedBox.from_meta(b)
                lo, hi = OrientedBox(ob.centroid, ob.axes_lengths, ob.axes.T).aabb()
                bad += not (np.allclose(lo, b["min"], atol=1e-6) and np.allclose(hi, b["max"], atol=1e-6))
    assert bad > 50


def test_from_meta_info_instances_names_and_counts(meta):
    scene = meta["41069025"]
    m = SemanticMap.from_meta_info(scene, "41069025")
    assert m.counts() == {k: v for k, v in scene["object_counts"].items()}
    assert len(m.by_name("table")) == 4 and len(m.by_name("dining table")) == 4
    assert len(m.by_name("couch")) == 1 and m.by_name("television")[0].name == "tv"
    assert m.by_name("piano") == []
    assert sorted({o.id for o in m.instances}) == list(range(len(m.instances)))
    # the benchmark's room fields are not copied: the area comes from the boxes' extent
    assert "room_size" not in json.dumps(m.to_dict()) and "room_center" not in json.dumps(m.to_dict())
    corners = np.concatenate([o.box.corners() for o in m.instances])
    assert m.room is not None and m.room.source == "object_boxes_hull"
    assert m.room.floor_z == pytest.approx(corners[:, 2].min())
    assert m.room_area() == pytest.approx(polygon_area(convex_hull_2d(corners[:, :2])))
    assert m.room_area() != pytest.approx(scene["room_size"], rel=0.05)


def test_meta_without_boxes_is_a_clear_error():
    with pytest.raises(InputError, match="object_bbox"):
        SemanticMap.from_meta_info({"room_size": 3.0}, "x")


def _tiny_map() -> SemanticMap:
    R = rotation_about([0, 0, 1], np.radians(30))
    inst = [ObjectInstance(0, "chair", OrientedBox(np.array([1.0, 2.0, 0.4]), np.array([0.5, 0.6, 0.8]), R.T),
                           first_seen=1.5, score=0.9, n_points=120, frames=[3, 4, 9]),
            ObjectInstance(1, "sofa", OrientedBox(np.array([-1.0, 0.0, 0.4]), np.array([2.0, 0.9, 0.8]), np.eye(3)))]
    T = np.eye(4)
    T[:3, 3] = [0.5, -1, 1.5]
    return SemanticMap(inst, Room(np.array([[-3, -3], [3, -3], [3, 4], [-3, 4.0]]), 0.0, 2.6, "camera_track"),
                       [(0.0, np.eye(4)), (0.5, T)], {"scene_name": "tiny", "built_by": "test"})


def test_save_load_round_trip(tmp_path):
    m = _tiny_map()
    p = tmp_path / "map.json"
    m.save(p)
    assert json.loads(p.read_text())["schema"] == MAP_SCHEMA
    m2 = SemanticMap.load(p)
    assert len(m2.instances) == 2
    for a, b in zip(m.instances, m2.instances):
        assert (a.id, a.name, a.first_seen, a.score, a.n_points, a.frames) == \
               (b.id, b.name, b.first_seen, b.score, b.n_points, b.frames)
        np.testing.assert_allclose(a.box.corners(), b.box.corners())
    np.testing.assert_allclose(m2.room.polygon, m.room.polygon)
    assert m2.room.source == "camera_track" and m2.room_area() == pytest.approx(42.0)
    assert [t for t, _ in m2.cameras] == [0.0, 0.5]
    np.testing.assert_allclose(m2.cameras[1][1], m.cameras[1][1])
    assert m2.meta == m.meta
    assert m2.to_dict() == m.to_dict()


def test_load_rejects_other_schema(tmp_path):
    p = tmp_path / "bad.json"
    p.write_text(json.dumps({"schema": "something/9", "instances": []}))
    with pytest.raises(InputError, match="schema"):
        SemanticMap.load(p)
    with pytest.raises(InputError, match="cannot read"):
        SemanticMap.load(tmp_path / "missing.json")


def test_room_from_boxes_hand_case():
    boxes = [OrientedBox(np.array([0.5, 0.5, 0.5]), np.ones(3), np.eye(3)),
             OrientedBox(np.array([3.5, 0.5, 1.0]), np.array([1.0, 1.0, 2.0]), np.eye(3))]
    room = room_from_boxes(boxes)
    assert room.area() == pytest.approx(4.0)  # hull of [0,4] x [0,1]
    assert (room.floor_z, room.ceiling_z) == (pytest.approx(0.0), pytest.approx(2.0))
    assert room_from_boxes([]) is None
    cams = np.array([[2.0, 3.0]])  # a camera position widens the hull by a triangle of area 0.5 * 4 * 2
    r2 = room_from_boxes(boxes, cams)
    assert r2.area() == pytest.approx(8.0) and r2.source == "object_boxes_and_cameras_hull"
    assert SemanticMap().room_area() is None


def test_polygon_area_and_hull():
    sq = np.array([[0, 0], [2, 0], [2, 3], [0, 3.0]])
    assert polygon_area(sq) == pytest.approx(6.0)
    assert polygon_area(sq[::-1]) == pytest.approx(6.0)
    pts = np.concatenate([sq, np.random.default_rng(0).uniform([0, 0], [2, 3], (50, 2))])
    hull = convex_hull_2d(pts)
    assert len(hull) == 4 and polygon_area(hull) == pytest.approx(6.0)
    assert polygon_area(sq[:2]) == 0.0


def test_box_distance_hand_cases():
    a = OrientedBox(np.zeros(3), np.ones(3), np.eye(3))
    assert box_distance(a, OrientedBox(np.array([3.0, 0, 0]), np.ones(3), np.eye(3))) == pytest.approx(2.0)
    # corner to corner: offset (2, 2, 0) between unit cubes -> gap (1, 1, 0)
    assert box_distance(a, OrientedBox(np.array([2.0, 2.0, 0]), np.ones(3), np.eye(3))) == pytest.approx(np.sqrt(2))
    # overlapping boxes touch: 0
    assert box_distance(a, OrientedBox(np.array([0.5, 0, 0]), np.ones(3), np.eye(3))) == pytest.approx(0.0, abs=1e-9)
    # a cube rotated 45 deg about z: its edge reaches 0.5*sqrt(2) from its centre along x
    R = rotation_about([0, 0, 1], np.pi / 4)
    b = OrientedBox(np.array([3.0, 0, 0]), np.ones(3), R.T)
    d, p, q = box_closest_points(a, b)
    assert d == pytest.approx(3.0 - 0.5 - 0.5 * np.sqrt(2), abs=1e-6)
    assert a.contains(p[None], 1e-6)[0] and b.contains(q[None], 1e-6)[0]
    # flat boxes (zero height) still work
    f = OrientedBox(np.array([0, 0, 2.0]), np.array([1.0, 1.0, 0.0]), np.eye(3))
    assert box_distance(a, f) == pytest.approx(1.5)


def _small_map() -> SemanticMap:
    inst = [ObjectInstance(i, ("chair", "table")[i % 2], OrientedBox(np.array([i, 0.5, 0.4]), np.array([0.5, 0.4, 0.8]),
                                                                  np.eye(3)), float(i), 0.9, 10, [i]) for i in range(4)]
    return SemanticMap(inst, None, [(0.0, np.eye(4))], {"scene": "t", "note": "x"})


@pytest.mark.parametrize("previous_run_id", [None, "20261203T000000Z-aaaa"])
def test_an_unchanged_loaded_map_is_written_as_its_own_file_with_the_run_id(tmp_path, previous_run_id):
    """A map read by `load` and unchanged writes its file's text with `run_id` set (inserted, or replaced where the
    file has one): what a reader gets equals the file plus the new run id. Any change to the map, and a file whose
    text names `"run_id":` twice, take the encoder instead: never a stale copy."""
    p = tmp_path / "map.json"
    d = _small_map().to_dict()
    if previous_run_id:
        d["run_id"] = previous_run_id
    p.write_text(json.dumps(d, indent=2))
    m = SemanticMap.load(p)
    out = m.json_bytes(run_id="NEW")
    assert json.loads(out) == {**d, "run_id": "NEW"}
    text = p.read_bytes()  # the file's own text: the field replaced in place, or inserted after the `{`
    assert out.count(b'"run_id"') == 1
    assert (out.replace(b'"NEW"', json.dumps(previous_run_id).encode()) == text if previous_run_id else
            out.endswith(text[1:]))
    for change in (lambda m: setattr(m.instances[1], "name", "sofa"), lambda m: m.instances[2].frames.append(7),
                   lambda m: m.instances[0].box.centroid.__setitem__(0, 9.0), lambda m: m.meta.update(scene="u"),
                   lambda m: m.instances.pop()):
        m = SemanticMap.load(p)
        change(m)
        got = json.loads(m.json_bytes(run_id="NEW"))
        assert got == {**m.to_dict(), "run_id": "NEW"} and got != {**d, "run_id": "NEW"}
    d["meta"]["x\\\"run_id"] = "trap"  # a key whose text ends like a run_id field: a second match
    p.write_text(json.dumps(d))
    got = json.loads(SemanticMap.load(p).json_bytes(run_id="NEW"))
    assert got["run_id"] == "NEW" and got["meta"]["x\\\"run_id"] == "trap"
