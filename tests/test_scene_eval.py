"""Real-scene benchmark pieces: annotation geometry, matching/registration of the scorer, and the fusion rules the
benchmark asked for (two detections of one frame stay two instances; box-prompted masks)."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from mosaicthinker.host.evaluation.scene import (SceneEvalConfig, iou_3d, load_annotation, match_instances,
                                                    register_box, score_instances)
from mosaicthinker.host.evaluation.scene_annotate import floor_height, largest_components, up_transform
from mosaicthinker.runtime.geometry import OrientedBox, rotation_about
from mosaicthinker.runtime.map import box_depth_mask, fuse_observations
from mosaicthinker.runtime.types import Observation

REPO = Path(__file__).resolve().parents[1]
ANNOT = REPO / "benchmarks" / "data" / "redkitchen_annotation.json"


def _box(c, size, yaw=0.0):
    a = np.array([[np.cos(yaw), np.sin(yaw), 0], [-np.sin(yaw), np.cos(yaw), 0], [0, 0, 1.0]])
    return OrientedBox(np.asarray(c, float), np.asarray(size, float), a)


def test_iou_3d_identical_disjoint_and_half():
    a = _box([0, 0, 0.5], [1, 1, 1])
    assert abs(iou_3d(a, a) - 1) < 1e-6
    assert iou_3d(a, _box([3, 0, 0.5], [1, 1, 1])) == 0.0
    assert abs(iou_3d(a, _box([0.5, 0, 0.5], [1, 1, 1])) - 1 / 3) < 1e-3  # overlap 0.5 of 1.5 union
    assert abs(iou_3d(a, _box([0, 0, 0.5], [1, 1, 1], np.pi / 2)) - 1) < 1e-4  # yaw by 90 deg: same box


def test_match_is_one_to_one_and_thresholded():
    conf = SceneEvalConfig()
    truth = [_box([0, 0, 0.4], [0.5, 0.5, 0.8]), _box([1, 0, 0.4], [0.5, 0.5, 0.8])]
    built = [_box([0.05, 0, 0.4], [0.5, 0.5, 0.8])] * 2 + [_box([5, 5, 0.4], [0.5, 0.5, 0.8])]
    pairs = match_instances(built, truth, conf)
    assert len(pairs) == 1 and pairs[0][1] == 0  # one built box cannot count for two true ones, far one no match
    s = score_instances({"chair": built}, {"chair": truth}, conf)["per_category"]["chair"]
    assert s["tp"] == 1 and s["count_error"] == 1 and abs(s["precision"] - 1 / 3) < 1e-9 and s["recall"] == 0.5


def test_register_box_similarity():
    S = np.eye(4)
    S[:3, :3] = 2.0 * rotation_about(np.array([0, 0, 1.0]), np.pi / 2)
    S[:3, 3] = [1, 2, 3]
    b = register_box(_box([1, 0, 0], [1, 2, 3]), S)
    assert np.allclose(b.centroid, [1, 4, 3]) and np.allclose(b.axes_lengths, [2, 4, 6])
    assert np.allclose(np.abs(b.axes @ b.axes.T), np.eye(3), atol=1e-9)


def test_up_transform_and_floor_height():
    down = np.array([0.1, 0.9, 0.4])
    T = up_transform(down, np.array([1.0, 0, 0]))
    assert np.allclose(T[:3, :3] @ (down / np.linalg.norm(down)), [0, 0, -1])
    rng = np.random.default_rng(0)
    z = np.concatenate([rng.normal(-1.2, 0.005, 3000), rng.normal(-0.45, 0.005, 8000), rng.uniform(-1.2, 1, 5000)])
    assert abs(floor_height(z) + 1.2) < 0.02  # the lowest dense layer, not the denser table top


def test_largest_components_drops_strays():
    rng = np.random.default_rng(1)
    blob = rng.uniform(0, 0.3, (500, 3))
    stray = rng.uniform(0, 0.02, (5, 3)) + 2.0
    kept = largest_components(np.concatenate([blob, stray]))
    assert len(kept) >= 480 and kept.max() < 1.0


def test_box_depth_mask_keeps_the_object_not_the_wall():
    d = np.full((100, 100), 3.0, np.float32)
    d[30:70, 30:70] = 1.0
    m = box_depth_mask(d, np.array([20, 20, 80, 80]))
    assert m[50, 50] and not m[22, 22] and m.sum() == 40 * 40


def test_two_detections_of_one_frame_stay_two_instances():
    rng = np.random.default_rng(2)
    a = rng.uniform(0, 0.4, (300, 3))
    b = a + [0.45, 0, 0]  # side by side, touching: a merged chair pair in the old fusion
    obs = [Observation("chair", 0.9, 0, 0.0, a, np.zeros(4)), Observation("chair", 0.9, 0, 0.0, b, np.zeros(4))]
    inst, _ = fuse_observations(obs)
    assert len(inst) == 2
    obs.append(Observation("chair", 0.9, 1, 0.1, a + 0.01, np.zeros(4)))  # a later view of the first joins it
    inst, _ = fuse_observations(obs)
    assert len(inst) == 2 and sorted(len(o.frames) for o in inst) == [1, 2]


def test_committed_annotation_loads_and_matches_its_marks():
    name, scene, T = load_annotation(ANNOT)
    marks = json.loads((REPO / "benchmarks" / "data" / "redkitchen_marks.json").read_text())
    n = {}
    for i in marks["instances"]:
        n[i["category"]] = n.get(i["category"], 0) + 1
    assert scene["object_counts"] == n and np.allclose(T[3], [0, 0, 0, 1])
    for lst in scene["object_bbox"].values():
        for m in lst:
            assert OrientedBox.from_meta(m).centroid[2] - m["axesLengths"][2] / 2 >= -0.05  # nothing under the floor


def test_register_cameras_recovers_a_similarity_from_a_straight_track():
    from mosaicthinker.host.evaluation.scene import register_cameras

    rng = np.random.default_rng(3)
    S = np.eye(4)
    S[:3, :3] = 1.7 * rotation_about(np.array([0.3, 0.2, 1.0]) / np.linalg.norm([0.3, 0.2, 1.0]), 0.8)
    S[:3, 3] = [0.5, -1, 2]
    est = []
    for k in range(8):  # cameras on a straight line: centres alone cannot fix the roll about it
        T = np.eye(4)
        T[:3, :3] = rotation_about(rng.normal(size=3) / np.linalg.norm(rng.normal(size=3)), rng.uniform(0, 1))
        T[:3, 3] = [0.2 * k, 0, 0]
        est.append(T)
    est = np.stack(est)
    gt = np.stack([S @ T for T in est])
    gt[:, :3, :3] /= 1.7  # ground-truth poses are rigid
    assert np.allclose(register_cameras(est, gt, with_scale=True), S, atol=1e-6)


@pytest.mark.slow
def test_the_kitchen_as_a_video_holds_the_same_frames_and_a_wrong_video_is_refused(redkitchen, tmp_path):
    import shutil

    from mosaicthinker.host.evaluation.scene import evaluate_scene, video_of_frames
    from mosaicthinker.runtime.infra.errors import InputError
    from mosaicthinker.runtime.frames import open_source

    folder = tmp_path / "k"
    folder.mkdir()
    for f in sorted(redkitchen.glob("frame-0000[0-3]*")) + [redkitchen / "camera-intrinsics.txt"]:
        shutil.copy(f, folder / f.name)
    src = open_source(folder)
    vid = open_source(video_of_frames(folder, tmp_path / "k.mp4"), K=src.K)
    assert len(vid) == len(src) > 10 and vid.size == src.size
    assert np.allclose(np.diff(vid.timestamps), np.diff(src.timestamps), atol=1e-3)  # the folder's 15 fps
    for i in (0, len(src) // 2, len(src) - 1):  # the same frame at the same index (lossy codec: a few levels)
        assert np.abs(vid[i].rgb.astype(int) - src[i].rgb.astype(int)).mean() < 6
    short = video_of_frames(folder, tmp_path / "short.mp4")
    with pytest.raises(InputError, match="frames in order"):
        evaluate_scene(redkitchen, ANNOT, "unused-bundle", depth="model", video=short)
