"""Multi-frame alignment: Kruskal vs brute force, failed edges, pose composition, the sequential baseline,
Sim(3) for relative depth, box-restricted matching, and one real-data accuracy check on 7-Scenes."""
from __future__ import annotations

import itertools

import numpy as np
import pytest

from mosaicthinker.runtime import geometry as G
from mosaicthinker.runtime.align import (align_frames, choose_root, compose_tree, maximum_spanning_tree, similarity_matrix)
from mosaicthinker.runtime.infra.errors import AlignmentError
from mosaicthinker.host.evaluation.pose import ate_rmse, evaluate_pose, pick_frames, rpe
from mosaicthinker.runtime.types import Frame
from mosaicthinker.runtime.frames import open_source
from mosaicthinker.runtime.align.matching import Matches, match_features

# ----------------------------------------------------------------------------- spanning tree


def _spans(edges, K):
    p = list(range(K))

    def f(x):
        while p[x] != x:
            x = p[x]
        return x

    for i, j in edges:
        a, b = f(i), f(j)
        if a == b:
            return False
        p[a] = b
    return True


def _brute_best(W, allowed, K):
    best = -np.inf
    for combo in itertools.combinations(allowed, K - 1):
        if _spans(combo, K):
            best = max(best, sum(W[i, j] for i, j in combo))
    return best


@pytest.mark.parametrize("seed", range(12))
def test_mst_matches_brute_force(seed):
    rng = np.random.default_rng(seed)
    K = int(rng.integers(3, 7))
    W = rng.uniform(-1, 1, size=(K, K))
    W = (W + W.T) / 2
    tree, failed = maximum_spanning_tree(W)
    assert failed == [] and len(tree) == K - 1 and _spans(tree, K)
    allowed = list(itertools.combinations(range(K), 2))
    assert sum(W[i, j] for i, j in tree) == pytest.approx(_brute_best(W, allowed, K))


@pytest.mark.parametrize("seed", range(12))
def test_failed_edges_use_next_best(seed):
    rng = np.random.default_rng(100 + seed)
    K = int(rng.integers(4, 7))
    W = rng.uniform(0, 1, size=(K, K))
    W = (W + W.T) / 2
    all_edges = list(itertools.combinations(range(K), 2))
    bad = {e for e in all_edges if rng.random() < 0.35}
    allowed = [e for e in all_edges if e not in bad]
    called = []

    def verify(i, j):
        called.append((i, j))
        return (i, j) not in bad

    tree, failed = maximum_spanning_tree(W, verify)
    assert not set(tree) & bad and set(failed) <= bad
    weights = [W[i, j] for i, j in called]
    assert weights == sorted(weights, reverse=True)  # edges verified lazily, best first
    if any(_spans(c, K) for c in itertools.combinations(allowed, K - 1)):  # still connected
        assert len(tree) == K - 1
        assert sum(W[i, j] for i, j in tree) == pytest.approx(_brute_best(W, allowed, K))
    else:
        assert len(tree) < K - 1  # a forest: some frames cannot be connected


def test_compose_tree_and_root():
    rng = np.random.default_rng(7)
    poses = [G.make_pose(G.rotation_about(rng.normal(size=3), rng.uniform(0, 1)), rng.normal(size=3))
             for _ in range(6)]
    edges = [(0, 1), (1, 2), (1, 3), (4, 3)]  # frame 5 not connected
    T = {(i, j): G.relative_pose(poses[i], poses[j]) for i, j in edges}
    T[(4, 3)] = G.relative_pose(poses[4], poses[3])
    out, parent = compose_tree(3, edges, T)
    assert set(out) == {0, 1, 2, 3, 4} and parent[3] == -1
    for k, P in out.items():
        assert np.allclose(P, G.relative_pose(poses[3], poses[k]), atol=1e-9)
    S = np.array([[0, 1, 0.2], [1, 0, 0.9], [0.2, 0.9, 0]])
    assert choose_root(S) == 1


# ----------------------------------------------------------------------------- synthetic frames


class _OracleMatcher:
    """Matcher with the common interface that returns the exact correspondences of known 3D points (frame id is
    encoded in pixel (0, 0)); frame `isolated` gets random correspondences, as a frame with no overlap would."""

    def __init__(self, scene, isolated=None):
        self.scene, self.isolated = scene, isolated
        self.rng = np.random.default_rng(0)

    def match(self, rgb0, rgb1, boxes0=None, boxes1=None):
        a, b = int(rgb0[0, 0, 0]), int(rgb1[0, 0, 0])
        (uva, va), (uvb, vb) = self.scene[a], self.scene[b]
        if self.isolated in (a, b):
            n = 80
            return Matches(self.rng.uniform(5, 300, (n, 2)), self.rng.uniform(5, 230, (n, 2)), np.ones(n))
        both = va & vb
        return Matches(uva[both], uvb[both], np.ones(int(both.sum())))


def _synthetic(n=6, seed=0, depth_scale=None):
    rng = np.random.default_rng(seed)
    W, H = 320, 240
    K = G.intrinsics_from_fov(W, H, 70.0)
    pts = rng.uniform([-2.5, -1.8, 3.0], [2.5, 1.8, 5.0], size=(160, 3))
    frames, scene, poses = [], {}, []
    for i in range(n):
        T = G.make_pose(G.rotation_about([0.1, 1, 0], 0.04 * i), [0.12 * i, 0.03 * i, 0.05 * i])
        uv, z = G.project(pts, K, T)
        vis = (z > 0) & (uv[:, 0] > 6) & (uv[:, 0] < W - 7) & (uv[:, 1] > 6) & (uv[:, 1] < H - 7)
        depth = np.zeros((H, W), np.float32)
        for k in np.argsort(-z):  # nearest point wins; 9x9 patches so the depth-edge check passes
            if vis[k]:
                u, v = int(round(uv[k, 0])), int(round(uv[k, 1]))
                depth[v - 4:v + 5, u - 4:u + 5] = z[k] * (1.0 if depth_scale is None else depth_scale[i])
        # keep only points whose own patch centre survived (others are occluded by a nearer patch)
        zz = G.sample_depth(depth, uv) / (1.0 if depth_scale is None else depth_scale[i])
        vis &= np.abs(zz - z) < 1e-5
        rgb = np.zeros((H, W, 3), np.uint8)
        rgb[0, 0, 0] = i
        frames.append(Frame(rgb, 0.1 * i, 10 + i, K, depth, T))
        scene[i] = (uv.astype(np.float32), vis)
        poses.append(T)
    return frames, scene, poses


def _emb(n):
    # similarity decreasing with the time gap: frame i's nearest neighbours are i-1, i+1
    return np.array([[np.cos(0.3 * i), np.sin(0.3 * i)] for i in range(n)])


def test_align_frames_exact_and_unaligned_frame():
    frames, scene, poses = _synthetic(6)
    res = align_frames(frames, _OracleMatcher(scene, isolated=4), "mst", embeddings=_emb(6))
    assert res.unaligned == [14] and 14 not in res.poses  # never placed at a guessed pose
    root = res.root
    for f in frames:
        if f.index in res.poses:
            assert np.abs(res.poses[f.index] - G.relative_pose(poses[root - 10], f.pose_gt)).max() < 1e-6
    assert res.similarity_kind == "embedding_cosine"
    assert any(not r.ok for r in res.edge_stats.values())


def test_each_pair_matched_and_verified_once():
    frames, scene, _ = _synthetic(6)
    om = _OracleMatcher(scene, isolated=4)
    calls = []
    inner = om.match
    om.match = lambda a, b, b0=None, b1=None: calls.append((int(a[0, 0, 0]), int(b[0, 0, 0]))) or inner(a, b, b0, b1)
    for rank in ("inliers", "matches"):
        calls.clear()
        res = align_frames(frames, om, "mst", embeddings=_emb(6), conf={"verify_rank": rank})
        pairs = [(min(c) + 10, max(c) + 10) for c in calls]  # frame index = 10 + the position in the pixel
        assert len(pairs) == len(set(pairs))  # ranking + Kruskal share one match and one verification per pair
        assert set(res.edge_stats) <= set(pairs) and (rank == "matches" or len(pairs) == len(res.edge_stats))


class _FailingPairs(_OracleMatcher):
    """Oracle matches, except random ones (a failed edge) for the listed frame pairs."""

    def __init__(self, scene, bad=()):
        super().__init__(scene)
        self.bad = {frozenset(p) for p in bad}

    def match(self, rgb0, rgb1, boxes0=None, boxes1=None):
        if frozenset((int(rgb0[0, 0, 0]), int(rgb1[0, 0, 0]))) in self.bad:
            n = 80
            return Matches(self.rng.uniform(5, 300, (n, 2)), self.rng.uniform(5, 230, (n, 2)), np.ones(n))
        return super().match(rgb0, rgb1, boxes0, boxes1)


def _tried(res):
    return {(a - 10, b - 10) for a, b in res.edge_stats}  # frame index = 10 + position


def test_rgbd_candidates_start_narrow():
    """rgbd edges verify each frame's 2 most similar frames + its time neighbour first (here: the chain i, i+1
    and the end frames' second neighbours), not the 4 most similar: 9 pairs for 8 frames, all aligned."""
    frames, scene, poses = _synthetic(8)
    res = align_frames(frames, _FailingPairs(scene), "mst", embeddings=_emb(8))
    assert _tried(res) == {(i, i + 1) for i in range(7)} | {(0, 2), (5, 7)} and not res.unaligned
    wide = align_frames(frames, _FailingPairs(scene), "mst", embeddings=_emb(8), conf={"verify_top_first": 4})
    assert len(wide.edge_stats) > 7 and not wide.unaligned  # the old candidate set: every frame's top 4


def test_rgbd_candidates_widen_only_while_disconnected():
    """A failed chain link (3, 4) splits the verified graph: the candidates widen to each frame's top 3, whose
    2-apart pairs reconnect it with verified edges (not an unverified similarity fallback); the tree is exact."""
    frames, scene, poses = _synthetic(8)
    res = align_frames(frames, _FailingPairs(scene, bad=[(3, 4)]), "mst", embeddings=_emb(8))
    tried = _tried(res)
    assert {(i, i + 1) for i in range(7)} <= tried and {(2, 4), (3, 5)} & tried
    assert not res.edge_stats[(13, 14)].ok and not res.unaligned and (13, 14) not in res.edges
    root = res.root - 10
    for f in frames:
        assert np.abs(res.poses[f.index] - G.relative_pose(poses[root], f.pose_gt)).max() < 1e-6
    assert max(b - a for a, b in tried) <= 3  # widened by one frame (top 3), not to every frame's top 4
    narrow = align_frames(frames, _FailingPairs(scene, bad=[(3, 4)]), "mst", embeddings=_emb(8),
                          conf={"verify_top": 2})  # no room to widen: the tree falls back to an unverified edge
    assert len(narrow.edge_stats) < len(res.edge_stats)


def test_candidate_widths_per_edge_type():
    from mosaicthinker.runtime.align import AlignConf
    from mosaicthinker.runtime.align.tree import _candidate_widths

    assert _candidate_widths(AlignConf(), "rgbd") == (2, 1)  # narrow start + time neighbour
    assert _candidate_widths(AlignConf(), "essential") == (4, 1)  # every candidate (the scale graph needs them)
    assert _candidate_widths(AlignConf(verify_top_first=4), "rgbd") == (4, 0)  # the former candidate set
    assert _candidate_widths(AlignConf(verify_rank="matches"), "rgbd") == (4, 0)  # lazy ranking: unchanged
    assert _candidate_widths(AlignConf(verify_top=1), "rgbd") == (1, 0)
    assert _candidate_widths(AlignConf(verify_neighbours=0), "rgbd") == (2, 0)


def test_sequential_baseline_keeps_previous_pose():
    frames, scene, poses = _synthetic(6)
    res = align_frames(frames, _OracleMatcher(scene, isolated=2), "sequential")
    assert res.root == 10 and res.guessed == [12, 13]  # links 1->2 and 2->3 fail
    assert np.allclose(res.poses[12], res.poses[11]) and np.allclose(res.poses[13], res.poses[12])
    assert res.unaligned == []
    # the chain resumes from the guessed pose: frame 4 is offset like frame 3
    assert np.abs(res.poses[14] - res.poses[13] @ G.relative_pose(poses[3], poses[4])).max() < 1e-6


def test_sim3_edges_for_relative_depth():
    scales = [1.0, 0.5, 2.0, 1.3, 0.8]
    frames, scene, poses = _synthetic(5, seed=1, depth_scale=scales)
    res = align_frames(frames, _OracleMatcher(scene), "mst", embeddings=_emb(5), with_scale=True,
                       conf={"edge": "rgbd"})
    assert len(res.poses) == 5 and res.edge == "rgbd"
    est = np.array([res.poses[f.index] for f in frames])
    gt = np.array([f.pose_gt for f in frames])
    ate, S = ate_rmse(est, gt, with_scale=True)
    assert ate < 1e-6
    assert ate_rmse(est, gt, with_scale=False)[0] > 1e-3  # rigid alignment cannot undo the scale
    rt, rr = rpe(est, gt, S)
    assert rt < 1e-6 and rr < 1e-4


@pytest.mark.parametrize("scale_mode", ["graph", "chain"])
def test_essential_edges_for_relative_depth(scale_mode):
    """Relative depth (a different unknown scale per frame) -> essential-matrix edges chosen automatically;
    rotation and translation direction from the 5-point solver, lengths from the depth: exact up to one Sim(3)."""
    scales = [1.0, 0.5, 2.0, 1.3, 0.8, 1.7]
    frames, scene, poses = _synthetic(6, seed=2, depth_scale=scales)
    res = align_frames(frames, _OracleMatcher(scene), "mst", embeddings=_emb(6), with_scale=True,
                       conf={"scale_mode": scale_mode})
    assert res.edge == "essential" and len(res.poses) == 6 and not res.unaligned
    est = np.array([res.poses[f.index] for f in frames])
    gt = np.array([f.pose_gt for f in frames])
    ate, S = ate_rmse(est, gt, with_scale=True)
    assert ate < 1e-4
    rt, rr = rpe(est, gt, S)
    assert rt < 1e-4 and rr < 0.01
    # each pose maps its frame's (scaled) depth into the root frame: pose scale = frame scale / root scale
    root = res.root - 10
    for k, f in enumerate(frames):
        assert G.transform_scale(res.poses[f.index]) == pytest.approx(scales[root] / scales[k], rel=1e-4)


def test_essential_pair_and_frame_scales():
    from mosaicthinker.runtime.align import AlignConf, PairResult, align_pair_essential, essential_frame_scales

    frames, scene, poses = _synthetic(3, seed=3, depth_scale=[2.5, 1.0, 0.7])
    (uva, va), (uvb, vb) = scene[0], scene[2]
    both = va & vb
    m = Matches(uva[both], uvb[both], np.ones(int(both.sum())))
    r = align_pair_essential(m, frames[0].depth, frames[0].K, frames[2].depth, frames[2].K,
                             AlignConf(scale_mode="chain"))
    T_gt = G.relative_pose(poses[0], poses[2])
    assert r.ok and r.n_inliers == int(both.sum())
    s = G.transform_scale(r.T_ab)
    assert s == pytest.approx(2.5 / 0.7, rel=1e-4)  # a's depth units per b's
    assert G.rotation_angle_deg((r.T_ab[:3, :3] / s).T @ T_gt[:3, :3]) < 0.01
    assert np.allclose(r.T_ab[:3, 3], 2.5 * T_gt[:3, 3], atol=1e-4)  # baseline in a's depth units
    assert r.scale_a == pytest.approx(2.5 * np.linalg.norm(T_gt[:3, 3]), rel=1e-4)
    # too few matches / pure noise -> a failed edge with a reason, never a pose
    bad = align_pair_essential(Matches(uva[both][:5], uvb[both][:5], np.ones(5)), frames[0].depth, frames[0].K,
                               frames[2].depth, frames[2].K)
    assert not bad.ok and "matches" in bad.reason
    # frame scales from a loop of consistent edges: sigma_a * scale_a = sigma_b * scale_b
    sig = np.array([1.0, 2.0, 0.5, 4.0])
    base = {(0, 1): 1.0, (1, 2): 0.3, (0, 2): 0.7, (2, 3): 0.2}
    edges = {e: PairResult(np.eye(4), True, 50, 50, 50, 0.0, 0.0, scale_a=L / sig[e[0]], scale_b=L / sig[e[1]])
             for e, L in base.items()}
    assert np.allclose(essential_frame_scales(4, 0, edges), sig, rtol=1e-6)


def test_align_frames_input_errors():
    frames, scene, _ = _synthetic(2)
    with pytest.raises(AlignmentError):
        align_frames(frames[:1], _OracleMatcher(scene))
    frames[1].depth = None
    with pytest.raises(AlignmentError, match="no depth"):
        align_frames(frames, _OracleMatcher(scene))


def test_similarity_matrix_histograms():
    rng = np.random.default_rng(0)
    a = rng.integers(0, 256, (48, 64, 3), dtype=np.uint8)
    b = np.clip(a.astype(int) + 3, 0, 255).astype(np.uint8)
    c = np.zeros_like(a)
    c[..., 2] = 200
    S, kind = similarity_matrix([a, b, c])
    assert kind == "color_hist_correlation" and S[0, 0] == 0 and S[0, 1] > S[0, 2] and np.allclose(S, S.T)
    imgs = [np.roll(a, k, axis=k % 2) for k in range(7)] + [b, c]  # on threads: the same matrix, same order
    assert np.array_equal(similarity_matrix(imgs, threads=3)[0], similarity_matrix(imgs)[0])


# ----------------------------------------------------------------------------- real data


def test_box_restricted_matching_real(redkitchen):
    src = open_source(redkitchen)
    a, b = src[0].rgb, src[4].rgb
    box = np.array([[200, 120, 440, 360]], np.float32)
    m = match_features(a, b, box, box, method="orb")
    assert len(m) > 20
    assert np.all((m.uv0[:, 0] >= 196) & (m.uv0[:, 0] <= 444) & (m.uv1[:, 1] >= 116) & (m.uv1[:, 1] <= 364))
    assert len(match_features(a, b, np.zeros((0, 4)), None, method="orb")) == 0


@pytest.mark.slow
def test_real_redkitchen_accuracy(redkitchen):
    """8 frames, 1 s apart, with sensor depth and SIFT: sub-5 cm ATE, every frame aligned."""
    src = open_source(redkitchen)
    idx = list(range(0, 120, 15))
    from mosaicthinker.runtime.align.matching import FeatureMatcher

    fm = FeatureMatcher("sift")
    for strategy in ("mst", "sequential"):
        r = evaluate_pose(src, idx, fm, strategy)
        assert r["aligned_frames"] == 8 and r["unaligned_frames"] == []
        assert r["ate_rmse_m"] < 0.05, (strategy, r["ate_rmse_m"])  # measured 0.023 (mst), 0.026 (sequential)
        assert r["rpe_rot_deg"] < 3.0
    assert pick_frames(250, 16, "random", 3) == sorted(pick_frames(250, 16, "random", 3))


@pytest.mark.slow
def test_real_essential_edges_with_relative_depth(redkitchen):
    """Relative depth on real frames: the sensor depth with an unknown scale per frame (x0.3 .. x3), SIFT
    matches -> essential-matrix edges chosen automatically; the trajectory is right up to one Sim(3)."""
    from dataclasses import replace

    from mosaicthinker.runtime.align.matching import FeatureMatcher

    src = open_source(redkitchen)
    idx = list(range(0, 120, 15))
    rng = np.random.default_rng(0)
    frames = [replace(src[i], depth=(src[i].depth * rng.uniform(0.3, 3.0)).astype(np.float32)) for i in idx]
    fm = FeatureMatcher("sift")
    for strategy in ("mst", "sequential"):
        res = align_frames(frames, fm, strategy, with_scale=True)
        assert res.edge == "essential" and len(res.aligned) == 8
        est = np.array([res.poses[f.index] for f in frames])
        gt = np.array([f.pose_gt for f in frames])
        ate = ate_rmse(est, gt, with_scale=True)[0]
        assert ate < 0.05, (strategy, ate)
