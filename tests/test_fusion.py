"""Object fusion, outlier removal, floor/gravity, visibility and occlusion refinement on synthetic frames
(an exact ray caster of boxes on a floor, written here), plus gravity alignment on the real 7-Scenes frames."""
from __future__ import annotations

import numpy as np
import pytest

from mosaicthinker.runtime.types import Frame
from mosaicthinker.runtime.geometry import OrientedBox, intrinsics_from_fov, rotation_about, transform
from mosaicthinker.runtime.align.matching import Matches
from mosaicthinker.runtime.types import Detections
from mosaicthinker.runtime.pipeline import Perception, refine
from mosaicthinker.runtime.map import (FusionConfig, expected_visible, fit_floor_plane, fuse_observations, gravity_world_transform, lift_observations, remove_outliers)
from mosaicthinker.runtime.infra.trace import Trace

W, H = 320, 240
K = intrinsics_from_fov(W, H, 60.0)


def box(c, size, yaw_deg=0.0) -> OrientedBox:
    return OrientedBox(np.asarray(c, float), np.asarray(size, float), rotation_about([0, 0, 1], np.radians(yaw_deg)).T)


def look_at(pos, target) -> np.ndarray:
    """Camera-to-world pose (OpenCV axes: x right, y down, z forward) at `pos` looking at `target`, z up."""
    z = np.asarray(target, float) - pos
    z /= np.linalg.norm(z)
    x = np.cross(z, [0, 0, 1.0])
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3] = np.stack([x, np.cross(z, x), z], 1)
    T[:3, 3] = pos
    return T


def raycast(T_wc: np.ndarray, boxes: list[OrientedBox]) -> tuple[np.ndarray, np.ndarray]:
    """Exact z-depth [H, W] and instance ids [H, W] (0 = floor / nothing, k + 1 = boxes[k]) of boxes on the
    floor z = 0 seen by a pinhole camera."""
    v, u = np.mgrid[0:H, 0:W].astype(float)
    d_c = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], -1).reshape(-1, 3)
    o, d = T_wc[:3, 3], d_c @ T_wc[:3, :3].T  # t along d is the z-depth because d_c has z = 1
    best = np.full(len(d), np.inf)
    ids = np.zeros(len(d), np.int32)
    with np.errstate(divide="ignore", invalid="ignore"):
        t_floor = np.where(d[:, 2] < -1e-9, -o[2] / d[:, 2], np.inf)
    best = np.minimum(best, t_floor)
    for k, b in enumerate(boxes):
        A = np.asarray(b.axes)
        lo_c, dl = A @ (o - b.centroid), d @ A.T
        half = np.asarray(b.axes_lengths) / 2
        with np.errstate(divide="ignore", invalid="ignore"):
            t1, t2 = (-half - lo_c) / dl, (half - lo_c) / dl
        tn = np.nanmax(np.minimum(t1, t2), 1)
        tf = np.nanmin(np.maximum(t1, t2), 1)
        hit = (tn <= tf) & (tn > 0.05) & (tn < best)
        best[hit], ids[hit] = tn[hit], k + 1
    depth = np.where(np.isfinite(best), best, 0).astype(np.float32).reshape(H, W)
    return depth, ids.reshape(H, W)


def views(boxes, target, n=4, radius=3.0, start_deg=-60.0, span_deg=120.0):
    out = []
    for i, a in enumerate(np.radians(np.linspace(start_deg, start_deg + span_deg, n))):
        pos = np.array([target[0] + radius * np.sin(a), target[1] - radius * np.cos(a), 1.5])
        T = look_at(pos, target)
        depth, ids = raycast(T, boxes)
        rgb = np.zeros((H, W, 3), np.uint8)
        out.append((Frame(rgb, float(i), i, K, depth, T), ids))
    return out


def detections(ids: np.ndarray, names: list[str], drop: tuple[int, ...] = ()) -> Detections:
    B, S, N, M = [], [], [], []
    for k, name in enumerate(names):
        m = ids == k + 1
        if m.sum() < 30 or k in drop:
            continue
        vv, uu = np.nonzero(m)
        B.append([uu.min(), vv.min(), uu.max() + 1, vv.max() + 1])
        S.append(0.9)
        N.append(name)
        M.append(m)
    if not B:
        return Detections.empty()
    return Detections(np.array(B), np.array(S), N, np.stack(M))


def lift_all(frames, names, drop=None, conf=FusionConfig()):
    obs = []
    for f, ids in frames:
        d = detections(ids, names, drop.get(f.index, ()) if drop else ())
        obs += lift_observations((H, W), f.depth, K, f.pose_gt, d.boxes, d.names, d.scores, d.masks, f.index, f.t,
                                 conf)
    return obs


def test_fusion_one_instance_per_object_with_accurate_gravity_box():
    table = box([0.0, 0.0, 0.375], [1.2, 0.6, 0.75], 30.0)
    chair = box([1.6, 0.6, 0.45], [0.5, 0.5, 0.9], -10.0)
    frames = views([table, chair], [0.5, 0.2, 0.4], n=5, start_deg=-80, span_deg=160)
    obs = lift_all(frames, ["table", "chair"])
    inst, clouds = fuse_observations(obs)
    assert sorted(o.name for o in inst) == ["chair", "table"]
    for o, truth in zip(sorted(inst, key=lambda o: o.name), (chair, table)):
        assert np.linalg.norm(o.center[:2] - truth.centroid[:2]) < 0.06
        assert abs(o.center[2] - truth.centroid[2]) < 0.08
        # yaw from the floor-projected points: sizes match in some order of the two horizontal axes
        assert sorted(o.box.axes_lengths[:2]) == pytest.approx(sorted(truth.axes_lengths[:2]), abs=0.1)
        assert o.box.axes_lengths[2] == pytest.approx(truth.axes_lengths[2], abs=0.1)
        assert np.allclose(o.box.axes[2], [0, 0, 1])  # gravity-aligned
        assert o.first_seen == min(o_.t for o_ in obs if o_.name == o.name)
        assert len(o.frames) >= 3
    assert all(len(c) > 50 for c in clouds)


def test_same_name_objects_stay_separate_and_partial_views_merge():
    a, b = box([-1.0, 0.0, 0.4], [0.5, 0.5, 0.8]), box([1.2, 0.3, 0.4], [0.5, 0.5, 0.8])
    frames = views([a, b], [0.1, 0.1, 0.4], n=4)
    inst, _ = fuse_observations(lift_all(frames, ["chair", "chair"]))
    assert len(inst) == 2
    centres = sorted(o.center[0] for o in inst)
    assert centres[0] == pytest.approx(-1.0, abs=0.08) and centres[1] == pytest.approx(1.2, abs=0.08)
    # a long sofa seen from its two ends only (little overlap between the views): still one instance
    sofa = box([0.0, 0.0, 0.4], [2.6, 0.9, 0.8], 0.0)
    ends = [views([sofa], [-1.1, 0.0, 0.4], n=1, radius=1.6, start_deg=-40, span_deg=0)[0],
            views([sofa], [1.1, 0.0, 0.4], n=1, radius=1.6, start_deg=40, span_deg=0)[0]]
    ends[1][0].index = 1
    inst, _ = fuse_observations(lift_all(ends, ["sofa"]))
    assert len(inst) == 1 and max(inst[0].box.axes_lengths[:2]) > 2.0


def test_outlier_removal_keeps_thin_parts_and_drops_flying_pixels():
    rng = np.random.default_rng(0)
    top = np.c_[rng.uniform(-0.6, 0.6, 2000), rng.uniform(-0.3, 0.3, 2000), np.full(2000, 0.75)]
    legs = np.concatenate([np.c_[np.full(20, x), np.full(20, y), np.linspace(0, 0.74, 20)]
                           for x in (-0.55, 0.55) for y in (-0.25, 0.25)])
    flying = np.array([[2.0, 2.0, 1.5], [-1.5, 1.0, 0.2], [0.0, -2.0, 2.0]])
    from mosaicthinker.runtime.map import voxel_downsample

    pts = voxel_downsample(np.concatenate([top, legs, flying]), 0.04)
    kept = remove_outliers(pts, 6.0, 0.1, 2)
    assert kept[:, 2].min() < 0.05  # legs reach the floor
    assert not any(np.any(np.all(np.isclose(kept, f, atol=1e-6), 1)) for f in flying)


def test_floor_plane_below_a_larger_table_top_and_world_transform():
    rng = np.random.default_rng(1)
    # camera frame (y down): floor 1.5 m below the camera, a bigger table top 0.75 m below, a wall ahead
    tilt = rotation_about([1, 0, 0], np.radians(12.0))  # camera pitched
    floor = np.c_[rng.uniform(-2, 2, 1500), np.full(1500, 1.5), rng.uniform(1, 5, 1500)]
    tabletop = np.c_[rng.uniform(-1, 1, 3000), np.full(3000, 0.75), rng.uniform(1.5, 3, 3000)]
    wall = np.c_[rng.uniform(-2, 2, 2000), rng.uniform(-1, 1.5, 2000), np.full(2000, 5.0)]
    pts = np.concatenate([floor, tabletop, wall]) + rng.normal(0, 0.005, (6500, 3))
    pts = pts @ tilt.T
    down_true = tilt @ np.array([0, 1.0, 0])
    n, d, cnt = fit_floor_plane(pts, np.array([0, 1.0, 0]))
    assert np.degrees(np.arccos(n @ down_true)) < 1.0 and d == pytest.approx(1.5, abs=0.02)
    Tw = gravity_world_transform(n, d)
    fw = transform(Tw, floor @ tilt.T)
    assert np.abs(fw[:, 2]).max() < 0.05  # the floor is z = 0
    assert Tw[:3, 3] == pytest.approx([0, 0, 1.5], abs=0.02)  # the root camera is 1.5 m above it
    assert fit_floor_plane(pts[:20], np.array([0, 1.0, 0])) is None


def test_gravity_from_floor_fit_on_7scenes_frames(redkitchen):
    """Floor fit on single 7-Scenes frames that see the floor vs the shared gravity-direction.txt."""
    from mosaicthinker.runtime.frames import open_source
    from mosaicthinker.runtime.geometry import backproject

    src = open_source(redkitchen)
    angles = []
    for i in (0, 30, 60):
        f = src[i]
        p, _ = backproject(f.depth, f.K, stride=8)
        n, d, _ = fit_floor_plane(p[p[:, 2] < 6.0], np.array([0, 1.0, 0]))
        g = src.gravity_camera(i)
        angles.append(float(np.degrees(np.arccos(np.clip(n @ g, -1, 1)))))
        assert 1.0 < d < 1.8  # the floor is about 1.3-1.4 m below this handheld camera
    assert max(angles) < 5.0, angles


def test_expected_visible_projection_behind_and_occluded():
    obj = box([0.0, 0.0, 0.4], [0.6, 0.6, 0.8])
    T = look_at(np.array([0.0, -3.0, 1.2]), [0, 0, 0.4])
    from mosaicthinker.runtime.map import ObjectInstance

    inst = ObjectInstance(0, "chair", obj)
    depth, _ = raycast(T, [obj])
    bb = expected_visible(inst, K, T, (W, H), depth)
    assert bb is not None and bb[0] < W / 2 < bb[2] and bb[1] < H / 2 < bb[3]
    behind = look_at(np.array([0.0, -3.0, 1.2]), [0, -6, 1.2])
    assert expected_visible(inst, K, behind, (W, H)) is None
    wall = box([0.0, -1.5, 1.0], [3.0, 0.1, 2.0])  # between the camera and the object
    depth2, _ = raycast(T, [obj, wall])
    assert expected_visible(inst, K, T, (W, H), depth2) is None


class GroundTruthMatcher:
    """Correspondences from the exact geometry of the test scene (the matcher is injected into refinement)."""

    def __init__(self, frames):
        self.f = {fr.index: (fr, ids) for fr, ids in frames}
        self.by_rgb = {id(fr.rgb): fr.index for fr, _ in frames}

    def match(self, rgb0, rgb1, boxes0=None, boxes1=None):
        from mosaicthinker.runtime.geometry import backproject, project

        (f0, ids0), (f1, _) = self.f[self.by_rgb[id(rgb0)]], self.f[self.by_rgb[id(rgb1)]]
        m = ids0 > 0
        if boxes0 is not None:
            bm = np.zeros_like(m)
            for x0, y0, x1, y1 in np.asarray(boxes0).astype(int):
                bm[y0:y1, x0:x1] = True
            m &= bm
        p, uv0 = backproject(f0.depth, K, m, stride=6)
        uv1, z = project(transform(f0.pose_gt, p), K, f1.pose_gt)
        zz = f1.depth[np.clip(uv1[:, 1].round().astype(int), 0, H - 1), np.clip(uv1[:, 0].round().astype(int), 0, W - 1)]
        ok = (uv1[:, 0] >= 0) & (uv1[:, 0] < W) & (uv1[:, 1] >= 0) & (uv1[:, 1] < H) & (np.abs(zz - z) < 0.03)
        return Matches(uv0[ok], uv1[ok], np.ones(int(ok.sum())))


def test_refinement_recovers_a_dropped_mask():
    table = box([0.0, 0.0, 0.375], [1.2, 0.6, 0.75], 20.0)
    frames = views([table], [0.0, 0.0, 0.4], n=3)
    for k, (f, _) in enumerate(frames):  # distinct images so the matcher can tell the frames apart
        f.rgb = np.full((H, W, 3), k, np.uint8)
    conf = FusionConfig()
    dets = {f.index: detections(ids, ["table"], (0,) if f.index == 1 else ()) for f, ids in frames}
    obs = lift_all(frames, ["table"], drop={1: (0,)})
    inst, _ = fuse_observations(obs, conf)
    assert len(inst) == 1 and 1 not in inst[0].frames  # the detector missed the table in frame 1
    ids_of = {f.index: ids for f, ids in frames}

    def segment_points(frame, pts, name):  # the instance under the prompts (what SAM would return)
        ids = ids_of[frame.index]
        hit = ids[pts[:, 1].round().astype(int).clip(0, H - 1), pts[:, 0].round().astype(int).clip(0, W - 1)]
        top = np.bincount(hit[hit > 0]).argmax() if (hit > 0).any() else 0
        return (ids == top) if top else None

    perc = Perception(detect=None, matcher=GroundTruthMatcher(frames), segment_points=segment_points)
    trace = Trace()
    poses = {f.index: f.pose_gt for f, _ in frames}
    inst2, clouds, recovered = refine(inst, obs, [f for f, _ in frames], poses, dets, perc, conf, trace)
    assert recovered == 1 and 1 in inst2[0].frames
    assert any(e["kind"] == "refinement" for e in trace.events)
    assert np.linalg.norm(inst2[0].center[:2] - table.centroid[:2]) < 0.06
    # with nothing to recover (no prompts hit it), refinement changes nothing and says so
    perc.segment_points = lambda frame, pts, name: None
    _, _, rec = refine(inst, obs, [f for f, _ in frames], poses, dets, perc, conf, Trace())
    assert rec == 0
