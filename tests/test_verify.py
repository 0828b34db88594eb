"""Cross-view verification of candidate detections (runtime/map/verify.py) on rendered geometry: two cameras, one
real object, false boxes, occlusion; and the pipeline keeping low-score detections only where views agree."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from conftest import REPO
from mosaicthinker.runtime.map.verify import VerifyConf, annotate_views, rests_on, verify_observations
from mosaicthinker.runtime.map import fuse_observations
from mosaicthinker.runtime.types import Detections, Observation

K = np.array([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]])
H, W = 480, 640


def _pose(x: float) -> np.ndarray:
    """Camera at (x, 0, 0) looking down +z (OpenCV axes), camera-to-world."""
    T = np.eye(4)
    T[0, 3] = x
    return T


def _cube(c, s=0.3, n=400, seed=0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.asarray(c, float) + (rng.random((n, 3)) - 0.5) * s


def _box_of(P: np.ndarray, T: np.ndarray) -> list[float]:
    pc = P - T[:3, 3]
    u = K[0, 0] * pc[:, 0] / pc[:, 2] + K[0, 2]
    v = K[1, 1] * pc[:, 1] / pc[:, 2] + K[1, 2]
    return [u.min(), v.min(), u.max(), v.max()]


def _frame(i: int, depth_m: float = 3.0) -> SimpleNamespace:
    return SimpleNamespace(index=i, K=K, depth=np.full((H, W), depth_m, np.float32), rgb=np.zeros((H, W, 3), np.uint8))


def _obs(name, score, frame, P) -> Observation:
    return Observation(name, score, frame, float(frame), P, np.zeros(4, np.float32))


def test_a_low_score_view_is_kept_when_another_frame_agrees_and_dropped_when_it_sees_nothing_there():
    poses = {0: _pose(0.0), 1: _pose(0.3)}
    frames = [_frame(0), _frame(1)]
    cup = _cube([0.1, 0.0, 2.0], 0.2)
    ghost = _cube([-0.4, 0.1, 2.0], 0.2, seed=1)
    # frame 1 detects the cup (too few points to lift: only its box) but nothing at the ghost's place
    dets = {0: Detections([_box_of(cup, poses[0]), _box_of(ghost, poses[0])], [0.3, 0.3], ["cup", "cup"]),
            1: Detections([_box_of(cup, poses[1])], [0.35], ["cup"])}
    obs = [_obs("cup", 0.3, 0, cup), _obs("cup", 0.3, 0, ghost)]
    kept, ver = verify_observations(obs, frames, poses, dets, VerifyConf())
    assert [o is obs[0] for o in kept] == [True]
    assert ver.support == [[1], []] and ver.against == [[], [1]] and ver.why == ["views", "unverified"]
    rep = ver.report(obs)
    assert rep["kept"] == 1 and rep["dropped"][0]["seen_without_it_in"] == [1]
    # relative depth (no occlusion test, scales per frame): agreement is no test for a low-score candidate
    _, rel = verify_observations(obs, frames, poses, dets, VerifyConf(), use_depth=False)
    assert rel.support[0] == [1] and rel.kept == [False, False]
    # the depth of frame 1 shows a wall in front of both: it cannot see them, so it neither agrees nor disagrees
    _, hidden = verify_observations(obs, [_frame(0), _frame(1, depth_m=1.0)], poses, dets, VerifyConf())
    assert hidden.support == [[], []] and hidden.against == [[], []] and hidden.kept == [False, False]


def test_two_lifted_views_of_one_place_agree_in_3d_and_the_instance_says_it():
    poses = {0: _pose(0.0), 1: _pose(0.3), 2: _pose(-0.3)}
    frames = [_frame(0), _frame(1), _frame(2)]
    sink = _cube([0.0, 0.2, 2.5], 0.4)
    # views 0 and 1 lift the sink (points 2 cm apart: different pixels of one surface); frame 2's box misses it
    obs = [_obs("sink", 0.28, 0, sink), _obs("sink", 0.31, 1, sink + 0.02)]
    dets = {0: Detections([[0, 0, 10, 10]], [0.28], ["sink"]), 1: Detections([[0, 0, 10, 10]], [0.31], ["sink"]),
            2: Detections.empty()}
    kept, ver = verify_observations(obs, frames, poses, dets, VerifyConf())
    assert len(kept) == 2 and ver.support == [[1], [0]] and ver.against == [[2], [2]]
    inst, _ = fuse_observations(kept)
    annotate_views(inst, obs, ver)
    assert len(inst) == 1 and rests_on(inst[0]) == 2 and [v["agreed_by"] for v in inst[0].views] == [[1], [0]]


def test_one_confident_view_adds_an_object_only_to_a_category_seen_twice():
    poses = {0: _pose(0.0), 1: _pose(0.3)}
    frames = [_frame(0), _frame(1)]
    chair_a, chair_b = _cube([0.5, 0.0, 2.0]), _cube([-0.5, 0.0, 2.0], seed=2)
    lamp = _cube([0.0, -0.5, 2.0], 0.2, seed=3)
    # chair a is seen by both frames; chair b and the lamp only by frame 0 (frame 1's depth: a wall in front)
    dets = {0: Detections([_box_of(chair_a, poses[0])] * 3, [0.9, 0.8, 0.9], ["chair", "chair", "lamp"]),
            1: Detections([_box_of(chair_a, poses[1])], [0.9], ["chair"])}
    obs = [_obs("chair", 0.9, 0, chair_a), _obs("chair", 0.8, 0, chair_b), _obs("lamp", 0.9, 0, lamp),
           _obs("chair", 0.9, 1, chair_a)]
    depth1 = np.full((H, W), 3.0, np.float32)
    depth1[:, :200] = 1.0  # chair b projects to the left of frame 1 behind this near surface
    depth1[:140, :] = 1.0  # ... and the lamp above
    frames[1].depth = depth1
    kept, ver = verify_observations(obs, frames, poses, dets, VerifyConf())
    assert ver.why == ["views", "confident", "unseen category", "views"]
    assert [o.name for o in kept] == ["chair", "chair", "chair"]
    _, loose = verify_observations(obs, frames, poses, dets, VerifyConf(confident_needs_seen=False))
    assert loose.why[2] == "confident"
    off, _ = verify_observations(obs, frames, poses, {}, VerifyConf(enabled=False))
    assert len(off) == 4
    # the lone view's threshold is the detector's own (the bundle's score_threshold) unless verification sets one
    strict = verify_observations(obs, frames, poses, dets, VerifyConf(), detector_threshold=0.85)[1]
    assert strict.why[1] == "unverified" and strict.confident == 0.85 and "from score 0.85" in strict.message(obs)
    assert verify_observations(obs, frames, poses, dets, VerifyConf(confident=0.5), detector_threshold=0.85)[1].why \
        == ver.why and ver.confident == 0.5


def test_the_detector_threshold_has_one_owner_per_role():
    """Verification reads the detector's confidence threshold (the manifest's; DetectorConf's default), never a
    copy of its own."""
    from mosaicthinker.runtime.models.detector import DetectorConf
    from mosaicthinker.runtime.perceive import Perception

    assert VerifyConf().confident is None
    assert Perception(detect=lambda f, n: None).confident_score == DetectorConf.score_threshold == 0.5
    src = (REPO / "runtime" / "models" / "owlv2.py").read_text()
    assert 'self.score_threshold = float(cfg.get("score_threshold", 0.1))' in src
