"""Floor-standing extents (`semantic_map.extend_to_floor`): hidden space under a box is unknown, not empty; only
open space actually seen under it blocks the extension. And the whole-image attach of the alignment policy
retries pairs that failed with matches inside the boxes (`alignment.attach_frames`)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from mosaicthinker.runtime.geometry import OrientedBox
from mosaicthinker.runtime.map import ObjectInstance, band_visibility, extend_to_floor

H, W = 96, 128
K = np.array([[100.0, 0, W / 2], [0, 100.0, H / 2], [0, 0, 1]])


def _look_at(eye, target) -> np.ndarray:
    """Camera-to-world pose (OpenCV camera: x right, y down, z forward) at `eye` looking at `target`, z up."""
    eye, target = np.asarray(eye, float), np.asarray(target, float)
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    T = np.eye(4)
    T[:3, :3] = np.stack([x, y, z], 1)
    T[:3, 3] = eye
    return T


def _render(T_wc: np.ndarray, boxes: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    """z-depth [H, W] of a room: the floor z = 0, a wall at y = 2 and axis-aligned solid boxes (lo, hi)."""
    v, u = np.mgrid[0:H, 0:W]
    d = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u, float)], -1).reshape(-1, 3)
    R, o = T_wc[:3, :3], T_wc[:3, 3]
    dw = d @ R.T  # world ray per pixel; the parameter along it is the camera z-depth (d has z = 1)
    best = np.full(len(dw), np.inf)
    with np.errstate(divide="ignore", invalid="ignore"):
        for axis, value in ((2, 0.0), (1, 2.0)):
            t = (value - o[axis]) / dw[:, axis]
            best = np.where((t > 0) & (t < best), t, best)
        for lo, hi in boxes:
            t0, t1 = (lo - o) / dw, (hi - o) / dw
            tn, tf = np.nanmax(np.minimum(t0, t1), 1), np.nanmin(np.maximum(t0, t1), 1)
            hit = (tn <= tf) & (tn > 0)
            best = np.where(hit & (tn < best), tn, best)
    return np.where(np.isfinite(best), best, 0.0).reshape(H, W).astype(np.float32)


def _scene(occluders: list[tuple[np.ndarray, np.ndarray]]):
    """A chair's back seen as a slab at z 0.65-0.77 (all the fused box holds), cameras in front of it."""
    back = (np.array([-0.2, 0.0, 0.65]), np.array([0.2, 0.08, 0.77]))
    poses = {i: _look_at([x, -2.2, 1.5], [0.0, 0.0, 0.5]) for i, x in enumerate((-0.6, 0.0, 0.6))}
    frames = [SimpleNamespace(index=i, K=K, depth=_render(T, [back, *occluders])) for i, T in poses.items()]
    box = OrientedBox(np.array([0.0, 0.04, 0.71]), np.array([0.4, 0.08, 0.12]), np.eye(3))
    return [ObjectInstance(0, "chair", box)], frames, poses


def test_hidden_under_an_occluder_is_extended_to_the_floor():
    # a counter between the cameras and the chair hides everything below its top (0.75 m): unknown, not empty
    counter = (np.array([-1.0, -1.0, 0.0]), np.array([1.0, -0.1, 0.75]))
    inst, frames, poses = _scene([counter])
    vis = band_visibility(inst[0].box, [(f.depth, f.K, poses[f.index]) for f in frames])
    assert vis[:, 0].max() < 0.1 and vis[:, 2].min() > 0.9  # nothing seen empty, every band unknown
    assert extend_to_floor(inst, frames, poses, ("chair",), 0.6) == [0]
    b = inst[0].box
    assert abs(b.centroid[2] - 0.385) < 1e-6 and abs(b.axes_lengths[2] - 0.77) < 1e-6


def test_open_space_seen_under_the_box_is_not_extended():
    # nothing in front: the cameras see the floor and the wall through the space under the slab
    inst, frames, poses = _scene([])
    vis = band_visibility(inst[0].box, [(f.depth, f.K, poses[f.index]) for f in frames])
    assert vis[1:-1, 0].min() > 0.9 and vis[-1, 0] > 0.5  # seen empty above the floor (the top band: partly
    # behind the slab itself)
    assert extend_to_floor(inst, frames, poses, ("chair",), 0.6) == []
    assert abs(inst[0].box.centroid[2] - 0.71) < 1e-6
    # the counter hides it from the front cameras, but a camera from the side sees the open space: not extended
    counter = (np.array([-1.0, -1.0, 0.0]), np.array([1.0, -0.1, 0.75]))
    inst, frames, poses = _scene([counter])
    side = _look_at([2.2, 0.04, 1.2], [0.0, 0.04, 0.4])
    frames.append(SimpleNamespace(index=9, K=K, depth=_render(side, [counter, (np.array([-0.2, 0.0, 0.65]),
                                                                               np.array([0.2, 0.08, 0.77]))])))
    poses[9] = side
    assert extend_to_floor(inst, frames, poses, ("chair",), 0.6) == []


def test_legs_seen_under_the_box_extend_it():
    # the space between the legs is seen empty, but the legs themselves are support in every band
    legs = [(np.array([x - 0.03, 0.0, 0.0]), np.array([x + 0.03, 0.06, 0.65])) for x in (-0.15, 0.15)]
    inst, frames, poses = _scene(legs)
    assert extend_to_floor(inst, frames, poses, ("chair",), 0.6, stride=2) == [0]
    inst, frames, poses = _scene(legs)
    assert extend_to_floor(inst, frames, poses, ("table",), 0.6, stride=2) == []  # not a floor-standing name


def test_attach_retries_pairs_that_failed_inside_boxes(redkitchen):
    from mosaicthinker.runtime.align import AlignmentResult, PairResult, attach_frames
    from mosaicthinker.runtime.frames import open_source
    from mosaicthinker.runtime.align import AlignConf
    from mosaicthinker.runtime.align.matching import make_matcher

    conf = AlignConf.merged(min_inliers=AlignConf.keyframe_min_inliers)  # as inside `align_keyframes`
    src = open_source(redkitchen)
    frames = {i: src[i] for i in (50, 55)}
    failed = PairResult(np.eye(4), False, 3, 0, 0, float("nan"), 0.0, "only 0 matches with valid depth (need 12)")
    al = AlignmentResult({50: np.eye(4)}, 50, [], [55], "mst", edge_stats={(50, 55): failed})
    assert attach_frames(al, frames, [55], make_matcher("sift"), conf) == [55]
    assert al.unaligned == [] and (50, 55) in al.edges and al.edge_stats[(50, 55)].ok
    # a pair already tried with whole images is not tried again
    al2 = AlignmentResult({50: np.eye(4)}, 50, [], [55], "mst", whole_tried={frozenset((50, 55))})
    assert attach_frames(al2, frames, [55], make_matcher("sift"), conf) == []


def test_bridging_skips_key_frames_behind_a_gap_a_chain_did_not_cross(redkitchen):
    """`bridge_attach`: the chain from frame 0 towards key frame 48 gets stuck in the gap (no edge passes), so the
    key frame 60 behind it on the same side is not chained to (it would cross the same frames): the budget
    goes only to the first chain, and the skip is recorded."""
    from mosaicthinker.runtime.align import AlignmentResult, bridge_attach
    from mosaicthinker.runtime.frames import open_source
    from mosaicthinker.runtime.align import AlignConf
    from mosaicthinker.runtime.align.matching import make_matcher
    from mosaicthinker.runtime.infra.trace import Trace

    class NoMatches:
        def match(self, rgb0, rgb1, boxes0=None, boxes1=None):
            from mosaicthinker.runtime.align.matching import Matches

            return Matches.empty()

    src = open_source(redkitchen)
    al = AlignmentResult({0: np.eye(4)}, 0, [], [48, 60], "mst")
    loaded: list[int] = []

    def with_depth(f):
        loaded.append(f.index)
        return f

    trace = Trace()
    conf = AlignConf.merged(bridge_gap_s=0.4, min_inliers=AlignConf.keyframe_min_inliers)
    used = bridge_attach(al, [src[0], src[48], src[60]], src, make_matcher(NoMatches()), with_depth, conf, trace)
    assert used == [] and al.unaligned == [48, 60]
    assert loaded == [24, 12, 6, 18, 30, 36, 42]  # the chain to 48 only (test_layout's schedule)
    ev = [e for e in trace.events if "bridging" in e["message"]][-1]
    assert ev["skipped"] == [60] and "0 of 2 key frame(s) aligned" in ev["message"]
