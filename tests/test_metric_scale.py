"""Metric scale without a depth sensor (`runtime/map/scale.py`): synthetic maps of a known scale."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from mosaicthinker.runtime.geometry import OrientedBox
from mosaicthinker.runtime.map.model import ObjectInstance, Room, SemanticMap
from mosaicthinker.runtime.map.scale import (estimate_scale, fit_depth_to_points, load_size_priors, rescale_map,
                                             sensor_scale)

# OpenCV camera looking along world +y, its image down (+y) along world -z: camera-to-world rotation
R_LEVEL = np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]])


def _cameras(height: float, n: int = 12, rng: np.random.Generator | None = None) -> np.ndarray:
    g = rng or np.random.default_rng(0)
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, :3] = R_LEVEL
    T[:, :3, 3] = np.c_[g.uniform(-2, 2, n), g.uniform(-2, 2, n), height + g.normal(0, 0.03, n)]
    return T


def _layer(n: int, z: float, half: float, g: np.random.Generator, noise: float = 0.01) -> np.ndarray:
    return np.c_[g.uniform(-half, half, (n, 2)), z + g.normal(0, noise, n)]


def _room_points(g: np.random.Generator, floor_n: int = 3000, counter_n: int = 0, floor: bool = True) -> np.ndarray:
    """A 6 x 6 m room: floor at z = 0 (optional), walls to 2.6 m, a counter top at 0.9 m (counter_n points)."""
    walls = np.c_[g.choice([-3.0, 3.0], 6000), g.uniform(-3, 3, 6000), g.uniform(0, 2.6, 6000)]
    walls[::2, :2] = walls[::2, 1::-1]
    parts = [walls]
    if floor:
        parts.append(_layer(floor_n, 0.0, 3.0, g))
    if counter_n:
        parts.append(np.c_[g.uniform(-3, -2.4, counter_n), g.uniform(-3, 3, counter_n), 0.9 + g.normal(0, 0.01, counter_n)])
    return np.concatenate(parts)


def _objects(names: list[str], g: np.random.Generator, factor: dict[int, float] | None = None) -> list[ObjectInstance]:
    """Objects of their category's prior median size (x factor[i] for the i-th), standing on the floor."""
    pri = load_size_priors()
    out = []
    for i, n in enumerate(names):
        L = np.asarray(pri[n]["median_m"]) * (factor or {}).get(i, 1.0) * np.exp(g.normal(0, 0.05, 3))
        box = OrientedBox(np.array([g.uniform(-2, 2), g.uniform(-2, 2), L[2] / 2]), L, np.eye(3))
        out.append(ObjectInstance(i, n, box))
    return out


def _in_map_units(T: np.ndarray, P: np.ndarray, objs: list[ObjectInstance], unit: float):
    """The metric scene in map units (1 map unit = `unit` m): what an RGB-only map holds."""
    T = T.copy()
    T[:, :3, 3] /= unit
    objs = [ObjectInstance(o.id, o.name, OrientedBox(o.box.centroid / unit, o.box.axes_lengths / unit, o.box.axes))
            for o in objs]
    return T, P / unit, objs


@pytest.mark.parametrize("unit", [0.23, 1.0, 4.1])
def test_camera_height_and_objects_recover_a_known_scale(unit):
    g = np.random.default_rng(1)
    T, P, objs = _in_map_units(_cameras(1.40, rng=g), _room_points(g), _objects(["chair", "chair", "bed", "tv"], g),
                               unit)
    ms = estimate_scale(T, P, objs)
    assert ms.source == "cues" and set(ms.cues) == {"camera_height", "objects"}
    assert ms.scale == pytest.approx(unit, rel=0.05)
    assert 5 < ms.percent < 35
    assert ms.message().startswith("scale from camera height and 4 objects (chair x2, bed, tv), +-")


def test_counter_top_above_the_floor_is_not_the_floor():
    """A counter top holding 10 x the floor's points: the floor is the lowest supported layer, not the biggest."""
    g = np.random.default_rng(2)
    T, P, _ = _in_map_units(_cameras(1.40, rng=g), _room_points(g, floor_n=600, counter_n=6000), [], 2.5)
    ms = estimate_scale(T, P, [], up=np.array([0.0, 0, 1]))
    assert list(ms.cues) == ["camera_height"]
    assert ms.scale == pytest.approx(2.5, rel=0.05)  # the counter top would give 1.40 / 0.5 m: x2.8
    # gravity found from the map itself (no up given) gives the same floor
    assert estimate_scale(T, P, []).scale == pytest.approx(2.5, rel=0.05)


def test_objects_outvote_a_wrong_floor_and_outlier_objects_are_left_out():
    """No floor seen (only the counter top below the cameras): the camera-height vote is off by about x2.8 and
    is left out against four objects; a chair three times its size is left out too."""
    g = np.random.default_rng(3)
    objs = _objects(["chair", "chair", "chair", "refrigerator", "toilet", "chair"], g, {5: 3.0})
    T, P, objs = _in_map_units(_cameras(1.40, rng=g), _room_points(g, counter_n=6000, floor=False), objs, 0.5)
    ms = estimate_scale(T, P, objs, up=np.array([0.0, 0, 1]))
    dropped = [v for v in ms.votes if not v.kept]
    assert {v.cue for v in dropped} == {"camera_height", "objects"} and len(dropped) == 2
    assert ms.scale == pytest.approx(0.5, rel=0.06)
    assert "left out as off the others" in ms.message()


def test_a_cue_that_could_not_vote_is_said_with_why():
    """Objects alone give the scale when the map shows no floor: the statement names the cues used and says why
    the camera height could not vote (it was dropped from the statement before)."""
    g = np.random.default_rng(4)
    objs = _objects(["chair", "chair", "refrigerator", "toilet"], g, {})
    T, _, objs = _in_map_units(_cameras(1.40, rng=g), _room_points(g), objs, 0.5)
    ms = estimate_scale(T, None, objs, up=np.array([0.0, 0, 1]))
    assert list(ms.cues) == ["objects"] and ms.scale == pytest.approx(0.5, rel=0.1)
    assert ms.message().startswith("scale from 4 objects")
    assert ms.message().endswith("no camera height (no map points to find the floor in)")


def test_metric_depth_ratios_are_a_cue():
    g = np.random.default_rng(4)
    ms = estimate_scale(_cameras(1.4, rng=g), None, [], depth_ratios=list(3.0 * np.exp(g.normal(0, 0.05, 16))))
    assert list(ms.cues) == ["depth_model"] and ms.scale == pytest.approx(3.0, rel=0.05)
    assert ms.message().startswith("scale from a metric depth model, +-18 % (90 % range)")


def test_no_cue_is_said_loudly_as_a_guess():
    ms = estimate_scale(_cameras(1.4), None, [ObjectInstance(0, "cup", OrientedBox(np.zeros(3), np.ones(3) * .1,
                                                                                    np.eye(3)))])
    assert ms.source == "guess" and ms.scale == 1.0
    msg = ms.message()
    assert msg.startswith("metric scale is a GUESS") and "no camera height" in msg and "no object of a known size" in msg
    assert sensor_scale().message() == "scale from sensor depth (metric)"


def test_fit_depth_to_points_puts_relative_depth_in_map_units():
    g = np.random.default_rng(5)
    z = g.uniform(1.0, 4.0, (48, 64))
    pred = ((z - 0.5) / 2.0).astype(np.float32)  # relative: z = 2 pred + 0.5
    uv = np.c_[g.integers(0, 64, 40), g.integers(0, 48, 40)].astype(float)
    zz = z[uv[:, 1].astype(int), uv[:, 0].astype(int)] * 0.3  # map units: 0.3 per metre
    zz[:4] *= 3.0  # mismatched features
    ss = fit_depth_to_points(pred, uv, zz)
    assert ss.s == pytest.approx(0.6, rel=0.02) and ss.t == pytest.approx(0.15, abs=0.01)
    few = fit_depth_to_points(pred, uv[4:7], zz[4:7])  # 3 points: scale only
    assert few.t == 0.0


def test_rescale_map_scales_every_length_once():
    o = ObjectInstance(0, "chair", OrientedBox(np.array([1.0, 2, 0.5]), np.array([0.5, 0.4, 1.0]), np.eye(3)),
                       views=[{"frame": 3, "centre": [1.0, 2.0, 0.5], "size": [0.5, 0.4, 1.0]}])
    T = np.eye(4)
    T[:3, 3] = [1, 1, 1.5]
    smap = SemanticMap([o], Room(np.array([[0, 0], [4, 0], [4, 3.0]]), 0.0, 2.5), [(0.0, T)])
    ms = estimate_scale(np.array([T]), None, [], depth_ratios=[2.0])
    out = rescale_map(smap, ms)
    assert np.allclose(out.instances[0].box.axes_lengths, [1.0, 0.8, 2.0])
    assert np.allclose(out.instances[0].views[0]["centre"], [2.0, 4.0, 1.0])
    assert np.allclose(out.cameras[0][1][:3, 3], [2, 2, 3]) and out.room.ceiling_z == pytest.approx(5.0)
    assert out.meta["scale"]["source"] == "cues" and smap.instances[0].box.axes_lengths[0] == 0.5


@pytest.mark.slow
def test_kitchen_rgb_map_recovers_an_unknown_scale(redkitchen, shared_bundle):
    """The 7-Scenes kitchen built as the RGB-only pipeline would (16 uniform key frames, the shared detector,
    instance segmenter and relative depth fitted to triangulated points), its ground-truth trajectory x 0.37 as
    the unknown: the recovered metres per map unit within the issue's 30 % bound, said with its sources."""
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    from metric_scale import room_rows

    run = room_rows(redkitchen, shared_bundle, 16, [0.37])["runs"][0]
    assert run["source"] == "cues" and abs(run["error"]) <= 0.30, run["message"]
    assert run["message"].startswith("scale from ") and " +-" in run["message"]


@pytest.mark.slow
def test_pipeline_rescales_a_model_depth_map_and_says_so(tmp_path_factory):
    """A generated room (objects drawn from the VSI-Bench statistics, a hand-held camera track) built with a
    "relative" depth model that is the sensor depth x 0.5: the pipeline's scale stage says where the scale came
    from and brings the map's boxes back to metres; with sensor depth it says "sensor depth" and changes nothing."""
    import dataclasses
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from test_pipeline import synthetic_scene

    from mosaicthinker.host.evaluation.oracle_perception import oracle_perception
    from mosaicthinker.host.synth.generate import load_scene
    from mosaicthinker.runtime import Trace, build_map, open_source

    scene = synthetic_scene(tmp_path_factory)
    names = sorted(load_scene(scene)["object_counts"])
    base = oracle_perception(scene)
    half = dataclasses.replace(base, depth=lambda f: f.depth * 0.5, depth_relative=True)
    trace = Trace()
    mb = build_map(open_source(scene), names, [], half, {"keyframe": {"keyframes": 10}, "depth": "model"}, trace)
    said = [e for e in trace.events if e["kind"] == "scale"]
    assert len(said) == 1 and said[0]["message"].startswith("scale from "), trace.events
    assert said[0]["scale"] == pytest.approx(2.0, rel=0.25)  # measured 1.67: camera at 1.5 m against the 1.40 prior
    assert mb.map.meta["scale"]["source"] == "cues"
    ref = Trace()
    build_map(open_source(scene), names, [], base, {"keyframe": {"keyframes": 10}}, ref)
    assert ref.decisions["scale"]["source"] == "sensor depth" and not [e for e in ref.events if e["kind"] == "scale"]


def test_size_priors_table_is_what_its_command_derives(vsibench_dir):
    """The checked-in priors are the generator's output on VSI-Bench's meta_info (regenerate, never hand-edit)."""
    import json

    from mosaicthinker.host.synth.size_priors import size_priors
    from mosaicthinker.host.synth.stats import load_meta_info
    from mosaicthinker.runtime.map.scale import PRIORS_PATH

    assert json.loads(PRIORS_PATH.read_text()) == size_priors(load_meta_info(vsibench_dir / "meta_info.json"))


@pytest.mark.slow
def test_eval_pose_scores_the_map_in_the_units_ask_gives(tmp_path_factory):
    """`mosaic eval pose --path ask --depth model` scores the poses of the map `ask` builds from the given frames,
    after its metric scale: a generated room with a "relative" depth that is the sensor's x 0.5 gives a Sim(3)
    scale near 1 (the estimate undid the 0.5) where the same frames without the scale applied need about 2."""
    import dataclasses
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from test_pipeline import synthetic_scene

    from mosaicthinker.host.evaluation.oracle_perception import oracle_perception
    from mosaicthinker.host.evaluation.pose import evaluate_pose_map, pick_frames
    from mosaicthinker.host.synth.generate import load_scene
    from mosaicthinker.runtime import open_source

    scene = synthetic_scene(tmp_path_factory)
    names = sorted(load_scene(scene)["object_counts"])
    half = dataclasses.replace(oracle_perception(scene), depth=lambda f: f.depth * 0.5, depth_relative=True)
    src = open_source(scene)
    idx = pick_frames(len(src), 10, "uniform")
    r = evaluate_pose_map(src, idx, None, None, perception=half, names=names)
    assert r["frames"] == idx and r["evaluated_frames"] >= 8 and r["sim3"]
    assert r["scale"]["source"] == "cues" and r["scale"]["message"].startswith("scale from ")
    assert abs(r["sim3_scale"] - 1.0) < 0.3 and abs(r["scale_error"]) < 0.3, r["scale"]
    assert isinstance(r["scale_covered"], bool)
    off = evaluate_pose_map(src, idx, None, {"scale": {"apply": False}}, perception=half, names=names)
    assert off["sim3_scale"] == pytest.approx(2.0, rel=0.3) and off["scale"]["source"] == "cues"
    assert r["ate_rmse_m"] < off["ate_rmse_m"]  # SE(3) after the scale: what the user gets, in metres


def test_step_scale_holds_where_the_trajectory_is_folded():
    """A walk whose second half is folded back (a misplaced chain) at the right scale: the Sim(3) fit shrinks it,
    the median step ratio still says 1; at half the size it says 2."""
    from mosaicthinker.host.evaluation.pose import ate_fields, step_scale

    gt = np.tile(np.eye(4), (12, 1, 1))
    gt[:, 0, 3] = np.arange(12) * 0.5
    est = gt.copy()
    est[6:, 0, 3] = est[5, 0, 3] - (np.arange(6) + 1) * 0.5  # the same steps, walked back
    assert abs(np.log(ate_fields(est, gt, True)["sim3_scale"])) > 0.4  # the Sim(3) would call it a scale error
    assert step_scale(est, gt) == pytest.approx(1.0)
    half = est.copy()
    half[:, :3, 3] *= 0.5
    assert step_scale(half, gt) == pytest.approx(2.0)
    assert step_scale(gt[:2], gt[:2]) is None


def test_a_partly_seen_height_does_not_vote():
    """A chair whose box the floor-standing extension had to reach down for (its back seen over a table: 0.3 m of
    its 0.9 m): flagged partial, only its footprint votes; unflagged, its height pulls the vote up ~x2."""
    from mosaicthinker.runtime.map.conf import ScaleConf
    from mosaicthinker.runtime.map.scale import object_votes

    pri = load_size_priors()
    L = np.asarray(pri["chair"]["median_m"], float)
    top = OrientedBox(np.array([0.0, 0.0, 0.75]), np.array([L[0], L[1], 0.3]), np.eye(3))
    up = np.array([0.0, 0, 1])
    (full,) = object_votes([("chair", top)], up, pri, ScaleConf())
    (part,) = object_votes([("chair", top, True)], up, pri, ScaleConf())
    assert abs(part.log_s) < 1e-6 and full.log_s > 0.3
