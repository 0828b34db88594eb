"""The geometric core's fast paths give the answers of the straightforward implementations they replaced
(kept here only, as references): connected components of a point cloud (every point pair within link_m listed
by a KD-tree, then scipy's connected components), lifting masks over the whole image, the density test by a
ball count, fusion on top of them; and the tree's lazy verification / deferred refinement (fewer pairs, same
kind of tree)."""
from __future__ import annotations

import numpy as np
import pytest

from mosaicthinker.runtime import geometry as G
from mosaicthinker.runtime import map as sm
from mosaicthinker.runtime.map import cluster
from mosaicthinker.runtime.align import AlignConf, align_frames
from mosaicthinker.runtime.frames import open_source
from test_alignment import _emb, _OracleMatcher, _synthetic
from test_fusion import box, lift_all, views


def ref_components(points, link_m):
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    pairs = cKDTree(points).query_pairs(link_m, output_type="ndarray")
    g = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(points),) * 2)
    return connected_components(g, directed=False)[1]


def ref_lift(depth, K, T_wc, boxes, names, scores, masks, frame, t, conf):
    """lift_observations as it was: erosion and back-projection over the whole image, reference components."""
    import cv2

    rng = np.random.default_rng(conf.subsample_seed + frame)
    out = []
    d = np.where(depth < conf.max_depth_m, depth, 0).astype(np.float32)
    kernel = np.ones((2 * conf.erode_px + 1,) * 2, np.uint8) if conf.erode_px > 0 else None
    keep = sm.duplicate_names(boxes, names, scores, conf.duplicate_iou) if conf.duplicate_iou > 0 else None
    for j, (bx, name) in enumerate(zip(boxes, names)):
        if keep is not None and not keep[j]:
            continue
        if masks is not None:
            m = masks[j].astype(np.uint8)
            if kernel is not None:
                eroded = cv2.erode(m, kernel)
                m = eroded if eroded.sum() >= conf.min_points else m
        else:
            m = sm.box_depth_mask(d, bx).astype(np.uint8)
        pts, _ = G.backproject(d, K, m.astype(bool), conf.pixel_stride)
        if len(pts) < conf.min_points:
            continue
        if len(pts) > conf.max_points:
            pts = pts[rng.choice(len(pts), conf.max_points, replace=False)]
        if conf.component_link_m > 0:
            lab = ref_components(pts, conf.component_link_m)
            cnt = np.bincount(lab)
            pts = pts[cnt[lab] >= conf.component_share * cnt.max()]
            if len(pts) < conf.min_points:
                continue
        out.append((name, G.transform(T_wc, pts)))
    return out


@pytest.fixture(scope="module")
def kitchen_masks(redkitchen):
    """Real-size inputs: 7-Scenes frames with mask-like regions (depth-edge bands of boxes, so parts bleed across
    depth discontinuities as segmenter masks do) -> [(frame, boxes [N, 4], masks [N, H, W])]."""
    src = open_source(redkitchen)
    rng = np.random.default_rng(0)
    out = []
    for i in range(0, len(src), len(src) // 8):
        f = src[i]
        H, W = f.depth.shape
        boxes, masks = [], []
        for _ in range(5):
            x0, y0 = int(rng.integers(0, W - 220)), int(rng.integers(0, H - 200))
            w, h = int(rng.integers(40, 220)), int(rng.integers(40, 200))
            m = np.zeros((H, W), bool)
            yy, xx = np.mgrid[0:h, 0:w]
            m[y0:y0 + h, x0:x0 + w] = ((xx - w / 2) / (w / 2)) ** 2 + ((yy - h / 2) / (h / 2)) ** 2 <= 1  # an ellipse
            boxes.append([x0, y0, x0 + w, y0 + h])
            masks.append(m)
        out.append((f, np.array(boxes, float), np.stack(masks)))
    return out


def test_components_equal_reference_on_real_masks(kitchen_masks):
    n, multi = 0, 0
    for f, _boxes, masks in kitchen_masks:
        for m in masks:
            pts, _ = G.backproject(np.where(f.depth < 8, f.depth, 0).astype(np.float32), f.K, m, 2)
            if len(pts) < 25:
                continue
            pts = pts[np.random.default_rng(n).permutation(len(pts))[:4000]]
            ref = ref_components(pts, 0.05)
            assert np.array_equal(sm.components(pts, 0.05), ref)  # same labels, same numbering
            n, multi = n + 1, multi + (ref.max() > 0)
    assert n >= 30 and multi >= 5  # real-size clouds, several with more than one part


@pytest.mark.parametrize("seed", range(4))
def test_components_equal_reference_on_hard_layouts(seed):
    rng = np.random.default_rng(seed)
    for _ in range(60):
        n = int(rng.integers(1, 500))
        link = float(rng.choice([0.02, 0.05, 0.1]))
        pts = rng.random((n, 3)) * float(rng.choice([0.05, 0.3, 1.0, 3.0]))
        if rng.random() < 0.4:  # a lattice (many equal distances; none exactly link_m, where rounding decides)
            pts = np.round(pts / (0.3 * link)) * (0.3 * link)
        assert np.array_equal(sm.components(pts, link), ref_components(pts, link))
    # absurd extents (stray points far away) take the pair-listing route, same labels
    far = np.r_[rng.random((50, 3)), [[1e9, 0, 0], [1e9, 1e9, 1e9]]]
    assert np.array_equal(sm.components(far, 0.05), ref_components(far, 0.05))
    assert len(sm.components(np.zeros((0, 3)), 0.05)) == 0


@pytest.mark.parametrize("seed", range(3))
def test_components_cell_lookup_paths_agree(seed, monkeypatch):
    """The dense key -> cell table and the binary search (a sparse grid: stray points metres away) give the same
    cells, so the same labels; both equal the reference, with a few stray points and without."""
    rng = np.random.default_rng(seed)
    pts = rng.random((800, 3)) * 0.6
    pts[rng.random(800) < 0.3] += [0.5, 0, 0]  # two blobs
    stray = np.r_[pts, [[40.0, 3.0, 1.0]]]
    built = []
    orig = cluster._Cells.index
    monkeypatch.setattr(cluster._Cells, "index", lambda self, n: (orig(self, n), built.append(self.lut is not None)))
    for cloud in (pts, stray):
        dense = sm.components(cloud, 0.05)
        monkeypatch.setattr(cluster._Cells, "LUT_PER_POINT", 0)  # every grid searched
        searched = sm.components(cloud, 0.05)
        monkeypatch.setattr(cluster._Cells, "LUT_PER_POINT", 64)
        assert np.array_equal(dense, searched) and np.array_equal(dense, ref_components(cloud, 0.05))
    assert built == [True, False, False, False]  # the compact cloud used the table, the stray one searched
    monkeypatch.setattr(cluster._Cells, "LUT_MAX", 1000)  # a table never exceeds LUT_MAX entries (room-sized clouds)
    assert np.array_equal(sm.components(pts, 0.05), ref_components(pts, 0.05)) and built[-1] is False


def test_remove_outliers_equals_ball_count(kitchen_masks):
    from scipy.spatial import cKDTree

    f, _b, masks = kitchen_masks[0]
    pts = sm.voxel_downsample(G.backproject(f.depth, f.K, masks.any(0), 2)[0], 0.04)
    for radius, k in ((0.1, 2), (0.06, 3), (0.1, 0)):
        cnt = np.asarray(cKDTree(pts).query_ball_point(pts, radius, return_length=True)) - 1
        dense = pts[cnt >= k]
        c = np.median(dense, 0)
        r = np.linalg.norm(dense - c, axis=1)
        med = np.median(r)
        ref = dense[r <= med + 6.0 * 1.4826 * (np.median(np.abs(r - med)) + 1e-9)]
        assert np.array_equal(sm.remove_outliers(pts, 6.0, radius, k), ref)


@pytest.mark.parametrize("conf", [sm.FusionConfig(), sm.FusionConfig(pixel_stride=3, erode_px=3, max_points=1500),
                                  sm.FusionConfig(pixel_stride=1, erode_px=0), sm.FusionConfig(max_depth_m=2.2)])
def test_lift_observations_equal_reference(kitchen_masks, conf):
    T = G.make_pose(G.rotation_about([0, 0, 1], 0.3), [0.5, -1.0, 1.2])
    n = 0
    for f, boxes, masks in kitchen_masks:
        names, scores = [f"o{k}" for k in range(len(boxes))], np.linspace(0.9, 0.5, len(boxes))
        for mk in (masks, None):  # segmenter masks, and box-prompted depth masks
            got = sm.lift_observations(f.depth.shape, f.depth, f.K, T, boxes, names, scores, mk, f.index, f.t, conf)
            ref = ref_lift(f.depth, f.K, T, boxes, names, scores, mk, f.index, f.t, conf)
            assert [o.name for o in got] == [nm for nm, _ in ref]
            assert all(np.array_equal(o.points, p) for o, (_, p) in zip(got, ref))
            n += len(got)
    assert n >= 40


def test_lift_observations_depth_cut_inside_windows(kitchen_masks):
    """The depth cut-off applied inside each mask's window equals the whole-image cut of the reference, with
    invalid values (NaN, inf, negative, beyond the cut) inside the masks."""
    conf = sm.FusionConfig(max_depth_m=2.5)
    rng = np.random.default_rng(3)
    for f, boxes, masks in kitchen_masks[:4]:
        depth = f.depth.astype(np.float32).copy()
        bad = rng.random(depth.shape) < 0.05
        depth[bad] = rng.choice(np.array([np.nan, np.inf, -1.0, 9.0], np.float32), int(bad.sum()))
        names, scores = [f"o{k}" for k in range(len(boxes))], np.linspace(0.9, 0.5, len(boxes))
        got = sm.lift_observations(depth.shape, depth, f.K, np.eye(4), boxes, names, scores, masks, f.index, f.t, conf)
        ref = ref_lift(depth, f.K, np.eye(4), boxes, names, scores, masks, f.index, f.t, conf)
        assert len(got) == len(ref) > 0 and all(np.array_equal(o.points, p) for o, (_, p) in zip(got, ref))
        assert all(np.isfinite(o.points).all() and (o.points[:, 2] < 2.5).all() for o in got)


def test_fusion_instances_equal_reference(monkeypatch):
    """Synthetic scene fused with the fast paths and with the references swapped in: the same instances."""
    table = box([0.0, 0.0, 0.375], [1.2, 0.6, 0.75], 30.0)
    chair = box([1.6, 0.6, 0.45], [0.5, 0.5, 0.9], -10.0)
    frames = views([table, chair], [0.5, 0.2, 0.4], n=5, start_deg=-80, span_deg=160)
    got, _ = sm.fuse_observations(lift_all(frames, ["table", "chair"]))
    monkeypatch.setattr(sm, "components", ref_components)
    ref, _ = sm.fuse_observations(lift_all(frames, ["table", "chair"]))
    assert len(got) == len(ref) == 2
    for a, b in zip(got, ref):
        assert a.name == b.name and np.allclose(a.center, b.center, atol=1e-9)
        assert np.allclose(a.box.axes_lengths, b.box.axes_lengths, atol=1e-9)


def test_lazy_verification_fewer_pairs_same_poses():
    frames, scene, poses = _synthetic(8)
    om = _OracleMatcher(scene, isolated=6)
    eager = align_frames(frames, om, "mst", embeddings=_emb(8), conf={"verify_rank": "inliers"})
    lazy = align_frames(frames, om, "mst", embeddings=_emb(8), conf={"verify_rank": "matches"})
    assert len(lazy.edge_stats) < len(eager.edge_stats)
    assert lazy.unaligned == eager.unaligned == [16] and sorted(lazy.edges) == sorted(eager.edges)
    root = lazy.root
    for f in frames:
        if f.index in lazy.poses:
            assert np.abs(lazy.poses[f.index] - G.relative_pose(poses[root - 10], f.pose_gt)).max() < 1e-6
    with pytest.raises(Exception, match="verify_rank"):
        align_frames(frames, om, "mst", conf={"verify_rank": "nope"})


def test_essential_tree_edges_refined_others_not(monkeypatch):
    """Essential edges: every candidate is verified (ranking, scale graph), only the tree's edges are refined."""
    from mosaicthinker.runtime.align import essential as al

    frames, scene, _ = _synthetic(6)
    refined = []
    inner = al.refine_essential
    monkeypatch.setattr(al, "refine_essential", lambda *a, **k: refined.append(1) or inner(*a, **k))
    res = align_frames(frames, _OracleMatcher(scene), "mst", embeddings=_emb(6), conf=AlignConf(edge="essential"),
                       with_scale=True)
    assert len(res.aligned) == 6 and len(refined) == len(res.edges) == 5 < len(res.edge_stats)


def _same_alignment(a, b):
    """Two AlignmentResults exactly equal: tree, root, poses, every pair's inliers / transform / scales."""
    assert a.root == b.root and a.edges == b.edges and a.unaligned == b.unaligned and a.guessed == b.guessed
    assert sorted(a.poses) == sorted(b.poses)
    assert all(np.array_equal(a.poses[k], b.poses[k]) for k in a.poses)
    assert list(a.edge_stats) == list(b.edge_stats)  # same pairs, recorded in the same order
    for k, r in a.edge_stats.items():
        s = b.edge_stats[k]
        assert (r.ok, r.n_matches, r.n_valid, r.n_inliers, r.reason) == (s.ok, s.n_matches, s.n_valid, s.n_inliers,
                                                                          s.reason)
        assert np.array_equal(r.T_ab, s.T_ab) and np.array_equal([r.scale_a, r.scale_b], [s.scale_a, s.scale_b],
                                                                 equal_nan=True)


@pytest.mark.parametrize("edge", ["rgbd", "essential"])
def test_threads_give_identical_alignment_synthetic(edge):
    frames, scene, _ = _synthetic(8)
    runs = [align_frames(frames, _OracleMatcher(scene, isolated=6), s, embeddings=_emb(8),
                         conf=AlignConf(edge=edge, threads=t), with_scale=edge == "essential")
            for s in ("mst", "sequential") for t in (1, 4, 4)]
    for a, b in ((0, 1), (0, 2), (3, 4), (3, 5)):  # 1 vs 4 threads, and a repeat run
        _same_alignment(runs[a], runs[b])
    assert len(runs[0].edge_stats) > len(runs[0].edges) and runs[0].unaligned == [16]


@pytest.mark.slow
@pytest.mark.parametrize("with_scale", [False, True])
def test_threads_give_identical_alignment_and_map_7scenes(redkitchen, with_scale, monkeypatch):
    """Real frames (SIFT, K = 12): 1 thread vs 2 and 3 threads vs a repeat run, rgbd edges on sensor depth and
    essential edges (depth as relative): the same pairs, inliers, transforms, poses; fusion on them the same."""
    from mosaicthinker.host.evaluation.pose import pick_frames
    from mosaicthinker.runtime.align.matching import FeatureMatcher

    src = open_source(redkitchen)
    frames = [src[i] for i in pick_frames(len(src), 12, "uniform")]
    fm = FeatureMatcher("sift", cache_size=64)
    runs = [align_frames(frames, fm, "mst", conf=AlignConf(threads=t), with_scale=with_scale) for t in (1, 2, 3, 3)]
    assert len(runs[0].aligned) >= 10 and len(runs[0].edge_stats) >= 15  # rgbd: 18 pairs (narrow candidates)
    for r in runs[1:]:
        _same_alignment(runs[0], r)
    maps = [_fused(frames, r.poses, t, monkeypatch) for r, t in ((runs[0], 1), (runs[1], 3), (runs[2], 3))]
    maps.append(_fused(frames, runs[0].poses, 1, monkeypatch, prelift=True))  # lifted at perception, then placed
    for m in maps[1:]:  # the map on 1 thread vs 3 (alignment and the pipeline's per-frame lifting), repeated
        assert len(m) == len(maps[0]) > 0
        assert all(x.name == y.name and np.array_equal(x.center, y.center)
                   and np.array_equal(x.box.axes_lengths, y.box.axes_lengths) for x, y in zip(maps[0], m))


def _fused(frames, poses, threads, monkeypatch, prelift=False):
    """The pipeline's fusion step (lifting per frame on `threads` threads) with two box detections per frame;
    prelift: the key frames lifted in the camera frame first, as perception does, and only placed by fusion."""
    from mosaicthinker.runtime.map import fuse
    from mosaicthinker.runtime.types import Detections

    monkeypatch.setattr(fuse, "worker_threads", lambda n=0: threads)
    H, W = frames[0].depth.shape
    boxes = np.array([[0, 0, W // 2, H // 2], [W // 3, H // 3, W, H]], np.float32)
    dets = {f.index: Detections(boxes, np.array([0.9, 0.8], np.float32), ["a", "b"]) for f in frames}
    fconf = sm.FusionConfig()
    lifted = {f.index: sm.lift_detections(f, dets[f.index], fconf) for f in frames} if prelift else None
    if prelift:
        for f in frames:  # the same points as lifting with the pose
            want = sm.lift_observations(f.depth.shape, f.depth, f.K, poses.get(f.index, np.eye(4)), boxes,
                                        ["a", "b"], np.array([0.9, 0.8]), None, f.index, f.t, fconf)
            got = sm.place(lifted[f.index], poses.get(f.index, np.eye(4)))
            assert [o.name for o in got] == [o.name for o in want]
            assert all(np.allclose(a.points, b.points, atol=1e-9) for a, b in zip(got, want))
    return fuse.fuse_frames(frames, dets, poses, fconf, None, lifted)[1]


def test_threads_config_checked():
    frames, scene, _ = _synthetic(3)
    with pytest.raises(Exception, match="threads"):
        align_frames(frames, _OracleMatcher(scene), "mst", conf={"threads": -1})
