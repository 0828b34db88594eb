"""Multi-frame alignment (paper: maximum spanning tree over frame similarity).

1. frame similarity S [K, K]: cosine of per-frame embeddings, else the correlation of HSV colour histograms;
2. root = the frame with the largest total similarity;
3. geometric refinement of S: each frame's most similar frames (plus its time neighbour) are aligned pairwise
   (`verify_top_first`, widened up to `verify_top` while a frame stays unconnected); a verified pair weighs
   1 + its inliers, a failed one is removed, untried pairs keep their similarity (< 1);
4. Kruskal's maximum spanning tree over these weights; an edge that fails when aligned is dropped and the next
   best tried;
5. every frame's pose = the composition of the pairwise transforms along its tree path to the root; frames
   outside the root's component are unaligned.
Strategy "sequential" is the paper's naive baseline (t -> t+1; a failed link keeps the previous pose).
"""
from __future__ import annotations

import time
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from typing import Any, Mapping, Sequence

import numpy as np

from ..geometry import invert, worker_threads
from ..infra.errors import AlignmentError, InputError
from ..infra.trace import StageLog, as_trace
from ..types import Frame
from .conf import AlignConf
from .essential import EssentialPose, essential_edge, essential_pose, rescale_essential
from .matching import KeyedMatcher, Matches, make_matcher
from .pairwise import PairResult, align_pair, depth_valid


def color_histograms(rgbs: Sequence[np.ndarray], bins: tuple[int, int, int] = (16, 8, 4),
                     threads: int = 1) -> np.ndarray:
    """HSV histograms of images [H, W, 3] uint8 RGB -> [K, prod(bins)] float64 (each sums to 1); the images on
    `threads` threads (OpenCV releases the GIL; the same histograms in the same order)."""
    import cv2

    def one(rgb: np.ndarray) -> np.ndarray:
        small = cv2.resize(rgb, (160, max(1, round(160 * rgb.shape[0] / rgb.shape[1]))),
                           interpolation=cv2.INTER_AREA)
        hsv = cv2.cvtColor(small, cv2.COLOR_RGB2HSV)
        h = cv2.calcHist([hsv], [0, 1, 2], None, list(bins), [0, 180, 0, 256, 0, 256]).ravel()
        return h / max(h.sum(), 1e-12)

    if threads <= 1 or len(rgbs) < 2:
        return np.array([one(rgb) for rgb in rgbs], dtype=np.float64)
    with ThreadPoolExecutor(min(threads, len(rgbs))) as ex:
        return np.array(list(ex.map(one, rgbs)), dtype=np.float64)


def similarity_matrix(rgbs: Sequence[np.ndarray] | None = None, embeddings: np.ndarray | None = None,
                      bins: tuple[int, int, int] = (16, 8, 4), threads: int = 1) -> tuple[np.ndarray, str]:
    """Frame similarity S [K, K] (diagonal 0) and what it is: 'embedding_cosine' for embeddings [K, D],
    else 'color_hist_correlation' (Pearson correlation of HSV histograms, as cv2.HISTCMP_CORREL; histograms on
    `threads` threads)."""
    if embeddings is not None:
        E = np.asarray(embeddings, dtype=np.float64)
        E = E / np.maximum(np.linalg.norm(E, axis=1, keepdims=True), 1e-12)
        S, kind = E @ E.T, "embedding_cosine"
    else:
        if rgbs is None:
            raise AlignmentError("similarity_matrix needs images or embeddings")
        H = color_histograms(rgbs, bins, threads)
        H = H - H.mean(1, keepdims=True)
        H = H / np.maximum(np.linalg.norm(H, axis=1, keepdims=True), 1e-12)
        S, kind = H @ H.T, "color_hist_correlation"
    S = S.copy()
    np.fill_diagonal(S, 0.0)
    return S, kind


def choose_root(S: np.ndarray) -> int:
    """Row with the largest total similarity (ties -> the earliest frame)."""
    return int(np.argmax(S.sum(1)))


def root_in_largest(S: np.ndarray, tree: Sequence[tuple[int, int]], root: int) -> int:
    """`root` if its tree component is the largest (ties keep it), else the `choose_root` row of the largest
    component of the verified forest: a split tree keeps the most key frames aligned, not the most similar
    frame's few (the map is built from the root's component only)."""
    dsu = _DSU(len(S))
    for i, j in tree:
        dsu.union(i, j)
    comp = np.array([dsu.find(i) for i in range(len(S))])
    sizes = np.bincount(comp, minlength=len(S))
    if sizes[comp[root]] >= sizes.max():
        return root
    members = np.flatnonzero(comp == int(np.argmax(sizes)))
    return int(members[np.argmax(S[np.ix_(members, members)].sum(1))])


class _DSU:
    def __init__(self, n: int):
        self.p = list(range(n))

    def find(self, x: int) -> int:
        while self.p[x] != x:
            self.p[x] = self.p[self.p[x]]
            x = self.p[x]
        return x

    def union(self, a: int, b: int) -> bool:
        ra, rb = self.find(a), self.find(b)
        if ra == rb:
            return False
        self.p[rb] = ra
        return True


def maximum_spanning_tree(S: np.ndarray, verify=None, max_attempts: int | None = None
                          ) -> tuple[list[tuple[int, int]], list[tuple[int, int]]]:
    """Kruskal on weights S [K, K] (symmetric; only i < j used), heaviest first.

    verify(i, j) -> bool is called for every edge that would join two components; a False edge is skipped and
    the next-best edge tried (failed-edge handling). Returns (tree edges, failed edges), each as (i, j), i < j.
    The result is a maximum spanning forest when the verified graph is disconnected."""
    K = len(S)
    iu, ju = np.triu_indices(K, 1)
    order = np.argsort(-S[iu, ju], kind="stable")
    dsu = _DSU(K)
    tree: list[tuple[int, int]] = []
    failed: list[tuple[int, int]] = []
    for e in order:
        i, j = int(iu[e]), int(ju[e])
        if dsu.find(i) == dsu.find(j):
            continue
        if max_attempts is not None and len(tree) + len(failed) >= max_attempts:
            break
        if verify is not None and not verify(i, j):
            failed.append((i, j))
            continue
        dsu.union(i, j)
        tree.append((i, j))
        if len(tree) == K - 1:
            break
    return tree, failed


def candidate_pairs(S: np.ndarray, top: int, extra: Sequence[tuple[int, int]] = ()) -> list[tuple[int, int]]:
    """The pairs `refine_with_inliers` verifies, as sorted (i, j), i < j: every frame's `top` most similar
    frames (by S [K, K]) plus the `extra` pairs."""
    K = len(S)
    cand = {(min(i, j), max(i, j)) for i, j in extra if i != j}
    for i in range(K):
        for j in np.argsort(-S[i])[:min(top, K - 1)]:
            if int(j) != i:
                cand.add((min(i, int(j)), max(i, int(j))))
    return sorted(cand)


def refine_with_inliers(S: np.ndarray, verify, inliers, top: int,
                        extra: Sequence[tuple[int, int]] = ()) -> np.ndarray:
    """Edge weights refined by geometric verification: every frame's `top` most similar frames (by S [K, K])
    are aligned, plus the `extra` pairs (e.g. time neighbours); a verified pair weighs 1 + its inlier count, a
    failed one -1 (never used), an untried one keeps its similarity (in [-1, 1], so verified edges come first and
    untried ones are the next-best fallbacks). verify(i, j) -> bool, inliers(i, j) -> int (after verify).
    Returns W [K, K]."""
    W = np.array(S, dtype=np.float64)
    for i, j in candidate_pairs(S, top, extra):
        W[i, j] = W[j, i] = (1.0 + inliers(i, j)) if verify(i, j) else -1.0
    return W


def compose_tree(root: int, edges: Sequence[tuple[int, int]], T: Mapping[tuple[int, int], np.ndarray]
                 ) -> tuple[dict[int, np.ndarray], dict[int, int]]:
    """Global poses along tree paths. T[(i, j)] = pose of j in i's camera frame (the reverse direction is
    derived). Returns ({node: pose [4, 4] in root's camera frame}, {node: parent}) for the root's component."""
    adj: dict[int, list[int]] = {}
    for i, j in edges:
        adj.setdefault(i, []).append(j)
        adj.setdefault(j, []).append(i)
    poses = {root: np.eye(4)}
    parent = {root: -1}
    q = deque([root])
    while q:
        p = q.popleft()
        for c in adj.get(p, []):
            if c in poses:
                continue
            T_pc = T[(p, c)] if (p, c) in T else invert(T[(c, p)])
            poses[c] = poses[p] @ T_pc
            parent[c] = p
            q.append(c)
    return poses, parent


@dataclass
class AlignmentResult:
    """poses: {frame index: T [4, 4] camera -> root camera frame}; root: frame index; edges: tree edges (or
    sequential links) as (frame index, frame index); unaligned: frame indices with no pose; guessed: frame
    indices whose pose was guessed (sequential baseline: a failed link keeps the previous pose);
    edge_stats: {(a, b): PairResult} for every pair tried."""

    poses: dict[int, np.ndarray]
    root: int
    edges: list[tuple[int, int]]
    unaligned: list[int]
    strategy: str
    guessed: list[int] = field(default_factory=list)
    edge_stats: dict[tuple[int, int], PairResult] = field(default_factory=dict)
    similarity: np.ndarray | None = None
    similarity_kind: str = ""
    with_scale: bool = False
    seconds: dict[str, float] = field(default_factory=dict)
    edge: str = "rgbd"    # pairwise edge type used: "rgbd" (3D-3D RANSAC) or "essential" (see AlignConf.edge)
    # tree edges the depth check rejected (`verify_tree`): later rounds never use them again
    rejected_edges: list[tuple[int, int]] = field(default_factory=list)
    # pairs already tried with whole-image matches (`attach_frames`): a pair that failed inside object boxes
    # is not one of them (few boxes give few matches; the whole image may still align it)
    whole_tried: set[frozenset] = field(default_factory=set)
    # structure from motion: its triangulated points [N, 3] in the root camera frame and the map's units
    points: np.ndarray | None = None
    # what became of each key frame in the end (`align_keyframes`): the step that gave its final pose, or
    # "unaligned"; the steps' own trace events are the history, this is the state
    fates: dict[int, str] = field(default_factory=dict)
    # frames whose pose the last `verify_tree` only re-expressed in a new root's frame (their fate stays)
    rebased: list[int] = field(default_factory=list)

    @property
    def aligned(self) -> list[int]:
        return [i for i in self.poses if i not in set(self.guessed)]

    def to_dict(self) -> dict[str, Any]:
        return {"strategy": self.strategy, "root": self.root, "edges": [list(e) for e in self.edges],
                "aligned": len(self.aligned), "unaligned": list(self.unaligned), "guessed": list(self.guessed),
                "similarity": self.similarity_kind, "with_scale": self.with_scale, "edge": self.edge,
                "pairs_tried": len(self.edge_stats), "pairs_failed": sum(not r.ok for r in self.edge_stats.values()),
                "fates": {str(i): f for i, f in self.fates.items()},
                "edge_stats": {f"{a}-{b}": r.to_dict() for (a, b), r in self.edge_stats.items()},
                "seconds": {k: round(v, 4) for k, v in self.seconds.items()}}


def _as_list(x: Any, frames: Sequence[Frame], what: str) -> list[Any]:
    if x is None:
        return [None] * len(frames)
    if isinstance(x, Mapping):
        return [x.get(f.index) for f in frames]
    x = list(x)
    if len(x) != len(frames):
        raise InputError(f"{what}: {len(x)} entries for {len(frames)} frames")
    return x


def _check_frames(frames: list[Frame], strategy: str, conf: AlignConf) -> None:
    """Input errors of `align_frames`, named."""
    if strategy not in ("mst", "sequential"):
        raise InputError(f"strategy must be 'mst' or 'sequential', got {strategy!r}")
    if len(frames) < 2:
        raise AlignmentError(f"need at least 2 frames to align, got {len(frames)}")
    for f in frames:
        if f.depth is None:
            raise AlignmentError(f"frame {f.index} has no depth: alignment needs sensor or model depth per frame")
    idx = [int(f.index) for f in frames]
    if len(set(idx)) != len(idx):
        raise InputError("align_frames: frame indices must be unique")
    if conf.edge not in ("auto", "rgbd", "essential"):
        raise InputError(f"alignment config: edge must be 'auto', 'rgbd' or 'essential', got {conf.edge!r}")
    if conf.verify_rank not in ("inliers", "matches"):
        raise InputError(f"alignment config: verify_rank must be 'inliers' or 'matches', got "
                         f"{conf.verify_rank!r}")
    if not isinstance(conf.threads, int) or conf.threads < 0:
        raise InputError(f"alignment config: threads must be an integer >= 0 (0 = the CPU count), got "
                         f"{conf.threads!r}")
    if conf.scale_mode not in ("chain", "graph", "shared"):
        raise InputError(f"alignment config: scale_mode must be 'chain', 'graph' or 'shared', got "
                         f"{conf.scale_mode!r}")


class _PairVerifier:
    """Pairwise alignment of frames by position (a, b), each pair aligned once: the PairResult per frame-index
    pair (`stats`), the transforms of the verified pairs by position (`Tpair`), match and RANSAC seconds."""

    def __init__(self, frames: list[Frame], m: KeyedMatcher, edge: str, conf: AlignConf, with_scale: bool,
                 boxes: list[Any]):
        self.frames, self.m, self.edge, self.conf, self.with_scale, self.boxes = frames, m, edge, conf, with_scale, boxes
        self.stats: dict[tuple[int, int], PairResult] = {}
        self.Tpair: dict[tuple[int, int], np.ndarray] = {}
        self.secs = {"match": 0.0, "ransac": 0.0}
        self.threads = worker_threads(conf.threads)
        self._ready: dict[tuple[int, int], tuple[PairResult, EssentialPose | None]] = {}  # `prefetch`ed results
        self._ready_refine: dict[tuple[int, int], PairResult] = {}
        self.ok_cache: dict[tuple[int, int], bool] = {}
        self.n_inl: dict[tuple[int, int], int] = {}
        self._matches: dict[tuple[int, int], Matches] = {}
        # essential edges: refinement deferred to the edges the tree takes (`refine_edge`); the RANSAC poses kept
        self.defer_refine = False
        self._poses: dict[tuple[int, int], EssentialPose] = {}
        self.refined: set[tuple[int, int]] = set()

    def match(self, a: int, b: int) -> Matches:
        """The pair's matches, computed once (ranking by match count and verifying read the same ones)."""
        if (a, b) not in self._matches:
            fa, fb = self.frames[a], self.frames[b]
            t0 = time.perf_counter()
            self._matches[(a, b)] = self.m.match_keys(fa.index, fa.rgb, fb.index, fb.rgb, self.boxes[a], self.boxes[b])
            self.secs["match"] += time.perf_counter() - t0
        return self._matches[(a, b)]

    def n_depth_matches(self, a: int, b: int) -> int:
        """Matches with valid depth in both frames: what RANSAC could use, an upper bound of its inliers."""
        a, b = min(a, b), max(a, b)
        m = self.match(a, b)
        return int(depth_valid(m, self.frames[a].depth, self.frames[b].depth, self.conf, self.with_scale).sum())

    def verify(self, a: int, b: int) -> bool:
        """Align frames at positions a, b (a result `prefetch` computed is taken, not recomputed) and record it."""
        ready = self._ready.pop((a, b), None)
        r, pose = ready if ready is not None else self._solve(a, b, self.match(a, b))
        self.secs["ransac"] += r.seconds
        self.stats[(self.frames[a].index, self.frames[b].index)] = r
        if pose is not None:
            self._poses[(a, b)] = pose
            if self.conf.essential_refine and not self.defer_refine:
                self.refined.add((a, b))
        if r.ok:
            self.Tpair[(a, b)] = r.T_ab
        return r.ok

    def _solve(self, a: int, b: int, mt: Matches) -> tuple[PairResult, EssentialPose | None]:
        """One pair's alignment from its matches; touches no shared state (runs in worker threads). rgbd RANSAC
        draws from the pair's own stream (seed, frame a, frame b); OpenCV's USAC seeds each call itself."""
        fa, fb = self.frames[a], self.frames[b]
        da, db = getattr(fa, "dist", None), getattr(fb, "dist", None)
        if self.edge == "essential":
            pose = essential_pose(mt, fa.K, fb.K, self.conf, da, db)
            if isinstance(pose, PairResult):
                return pose, None
            refine = self.conf.essential_refine and not self.defer_refine
            return essential_edge(pose, fa.depth, fb.depth, self.conf, refine), pose
        rng = np.random.default_rng((self.conf.ransac_seed, int(fa.index), int(fb.index)))
        return align_pair(mt, fa.depth, fa.K, fb.depth, fb.K, self.conf, self.with_scale, rng, da, db), None

    def prefetch(self, pairs: Sequence[tuple[int, int]]) -> None:
        """Align the given (a, b) pairs not aligned yet concurrently on `threads` threads; `verify` then records
        them in whatever order it is called, so the state is exactly that of aligning them one by one. Matches
        are computed here first, in order, in this thread (a matcher need not be thread-safe)."""
        todo = list(dict.fromkeys(p for p in pairs if p not in self._ready and p not in self._done()))
        if self.threads <= 1 or len(todo) < 2:
            return
        jobs = [(a, b, self.match(a, b)) for a, b in todo]
        with ThreadPoolExecutor(min(self.threads, len(jobs))) as ex:
            for (a, b, _m), res in zip(jobs, ex.map(lambda j: self._solve(*j), jobs)):
                self._ready[(a, b)] = res

    def _done(self) -> set[tuple[int, int]]:
        pos = {int(f.index): k for k, f in enumerate(self.frames)}
        return {(pos[i], pos[j]) for i, j in self.stats}

    def verify_cached(self, a: int, b: int) -> bool:
        a, b = min(a, b), max(a, b)
        if (a, b) not in self.ok_cache:
            self.ok_cache[(a, b)] = self.verify(a, b)
            self.n_inl[(a, b)] = (self.stats[(self.frames[a].index, self.frames[b].index)].n_inliers
                                  if self.ok_cache[(a, b)] else 0)
        return self.ok_cache[(a, b)]

    def prefetch_refine(self, edges: Sequence[tuple[int, int]]) -> None:
        """The deferred refinements of verified essential edges (a < b), computed concurrently (see `prefetch`);
        `refine_edge` takes them."""
        todo = [e for e in edges if e not in self.refined and e in self._poses and e not in self._ready_refine]
        if self.threads <= 1 or len(todo) < 2 or not self.conf.essential_refine:
            return
        def run(e: tuple[int, int]) -> PairResult:
            fa, fb = self.frames[e[0]], self.frames[e[1]]
            return essential_edge(self._poses[e], fa.depth, fb.depth, self.conf, True)
        with ThreadPoolExecutor(min(self.threads, len(todo))) as ex:
            self._ready_refine.update(zip(todo, ex.map(run, todo)))

    def refine_edge(self, a: int, b: int) -> bool:
        """A verified essential edge (a < b) with the refinement deferred: refine it now (same inliers; the pose
        and its baseline scales change). False when the refined pose no longer fixes the scale."""
        if (a, b) in self.refined or not self.conf.essential_refine:
            return self.ok_cache.get((a, b), False)
        fa, fb = self.frames[a], self.frames[b]
        r = self._ready_refine.pop((a, b), None) or essential_edge(self._poses[(a, b)], fa.depth, fb.depth,
                                                                    self.conf, True)
        self.secs["ransac"] += r.seconds - self._poses[(a, b)].seconds
        self.stats[(fa.index, fb.index)] = r
        self.refined.add((a, b))
        if r.ok:
            self.Tpair[(a, b)] = r.T_ab
        else:
            self.Tpair.pop((a, b), None)
        self.ok_cache[(a, b)] = r.ok
        return r.ok

    def inliers(self, a: int, b: int) -> int:
        self.verify_cached(a, b)
        return self.n_inl[(min(a, b), max(a, b))]


def _time_order(frames: list[Frame]) -> list[int]:
    return sorted(range(len(frames)), key=lambda k: (frames[k].t, int(frames[k].index)))


def _candidate_widths(conf: AlignConf, edge: str) -> tuple[int, int]:
    """(first round's top-k, time neighbours) of the candidate pairs for this edge type (AlignConf defaults)."""
    narrow = edge == "rgbd" and conf.verify_rank == "inliers"  # (the lazy ranking verifies ~K pairs anyway)
    top = conf.verify_top_first if conf.verify_top_first is not None else (
        min(2, conf.verify_top) if narrow else conf.verify_top)
    top = max(1, min(top, conf.verify_top))
    n_nb = conf.verify_neighbours if conf.verify_neighbours is not None else int(
        edge == "essential" or top < conf.verify_top)
    return top, n_nb


def _widening_weights(S: np.ndarray, pv: _PairVerifier, top: int, max_top: int,
                      extra: Sequence[tuple[int, int]]) -> np.ndarray:
    """`refine_with_inliers` over each frame's `top` most similar frames (+ `extra`), widened by one frame per
    round up to `max_top` while the verified pairs do not connect every frame: a frame whose first candidates
    all failed gets more before the tree falls back to unverified similarity edges."""
    while True:
        pv.prefetch(candidate_pairs(S, top, extra))
        W = refine_with_inliers(S, pv.verify_cached, pv.inliers, top, extra)
        if top >= max_top or _connected(len(S), [e for e, ok in pv.ok_cache.items() if ok]):
            return W
        top += 1


def _connected(n: int, edges: Sequence[tuple[int, int]]) -> bool:
    """Whether the undirected graph on n nodes with these edges is connected."""
    dsu, parts = _DSU(n), n
    for a, b in edges:
        parts -= dsu.union(a, b)
    return parts <= 1


def _align_mst(frames: list[Frame], pv: _PairVerifier, embeddings: np.ndarray | None
               ) -> tuple[int, dict[int, np.ndarray], list[tuple[int, int]], np.ndarray, str]:
    """Similarity matrix, root, geometric refinement, Kruskal, composition (module docstring, steps 1-5).
    Returns (root position, poses by frame index, tree edges by frame index, S, similarity kind)."""
    conf, idx = pv.conf, [int(f.index) for f in frames]
    t0 = time.perf_counter()
    S, kind = similarity_matrix([f.rgb for f in frames] if embeddings is None else None, embeddings, conf.hsv_bins,
                                pv.threads)
    pv.secs["similarity"] = time.perf_counter() - t0
    root = choose_root(S)
    t0 = time.perf_counter()
    W = S
    if conf.verify_top > 0:
        top, n_nb = _candidate_widths(conf, pv.edge)
        order = _time_order(frames)
        nb = [(order[p], order[p + d]) for d in range(1, n_nb + 1) for p in range(len(order) - d)]
        if conf.verify_rank == "inliers":
            # ranking and the scale graph need every candidate's inliers and scales, not its refined pose
            pv.defer_refine = pv.edge == "essential"
            W = _widening_weights(S, pv, top, conf.verify_top, nb)
        else:  # lazy: ranked by match count, verified by Kruskal only when it takes the edge
            W = refine_with_inliers(S, lambda i, j: True, pv.n_depth_matches, conf.verify_top, nb)
    tree, _failed = maximum_spanning_tree(W, pv.verify_cached, conf.max_attempts)
    while pv.defer_refine:  # the tree's edges refined; one that fails then is dropped and the tree re-grown
        pv.prefetch_refine(tree)
        bad = [e for e in tree if not pv.refine_edge(*e)]
        if not bad:
            break
        for i, j in bad:
            W[i, j] = W[j, i] = -1.0
        tree, _failed = maximum_spanning_tree(W, pv.verify_cached, conf.max_attempts)
    pv.secs["tree"] = time.perf_counter() - t0
    root = root_in_largest(S, tree, root)
    if pv.edge == "essential" and conf.scale_mode == "graph":
        rescale_essential(pv.Tpair, tree, pv.stats, idx, root)
    local, _parent = compose_tree(root, tree, pv.Tpair)
    return root, {idx[k]: T for k, T in local.items()}, [(idx[i], idx[j]) for i, j in tree], S, kind


def _align_sequential(frames: list[Frame], pv: _PairVerifier
                      ) -> tuple[int, dict[int, np.ndarray], list[tuple[int, int]], list[int]]:
    """The naive baseline: t -> t+1 links; a failed link keeps the previous pose (listed as guessed)."""
    idx = [int(f.index) for f in frames]
    order = _time_order(frames)
    root = order[0]
    poses = {idx[root]: np.eye(4)}
    edges, guessed = [], []
    pv.prefetch(list(zip(order[:-1], order[1:])))
    prev = root
    for k in order[1:]:
        if pv.verify(prev, k):
            poses[idx[k]] = poses[idx[prev]] @ pv.Tpair[(prev, k)]
            edges.append((idx[prev], idx[k]))
        else:  # naive baseline: keep the previous pose
            poses[idx[k]] = poses[idx[prev]].copy()
            guessed.append(idx[k])
        prev = k
    return root, poses, edges, guessed


def _record_alignment(log: StageLog | None, res: AlignmentResult, n: int, step: bool = False) -> None:
    """Decisions and the unaligned frames of one `align_frames` call: a final state ("degraded") for a caller
    that stops there, history (kind "alignment") for a first round that later steps continue (`step`)."""
    t = as_trace(log)
    t.decide("alignment.strategy", res.strategy)
    t.decide("alignment.edge", res.edge)
    t.decide("alignment.similarity", res.similarity_kind or "time_order")
    t.decide("alignment.root", res.root)
    if res.unaligned:
        t.event("alignment" if step else "degraded",
                f"{'first round: ' if step else ''}{len(res.unaligned)} of {n} frames could not be aligned "
                f"(no verified edge to the root's tree)", frames=res.unaligned, stage="alignment")
    if res.guessed:
        t.event("degraded", f"sequential chaining: {len(res.guessed)} failed links kept the previous pose",
                frames=res.guessed)


def align_frames(frames: Sequence[Frame], matcher: Any = "sift", strategy: str = "mst",
                 conf: AlignConf | Mapping[str, Any] | None = None, embeddings: np.ndarray | None = None,
                 boxes: Sequence[np.ndarray | None] | Mapping[int, np.ndarray] | None = None,
                 with_scale: bool = False, log: StageLog | None = None, step: bool = False) -> AlignmentResult:
    """Align frames (objects with .rgb [H, W, 3], .depth [H, W] metres (or relative depth with with_scale),
    .K [3, 3], .index) into the root camera's frame.

    matcher: 'sift' | 'orb' | a `matching.Matcher` (features are cached per frame when it is a `KeyedMatcher`);
    strategy: 'mst' | 'sequential'; embeddings: [K, D] for the similarity matrix (else colour histograms);
    boxes: per-frame [N, 4] boxes to restrict matching (list in frame order or {frame index: boxes});
    with_scale: estimate Sim(3) per edge (relative, non-metric depth); step: a first round that later steps
    continue (its unaligned frames are recorded as history, not as the final state).
    """
    conf = AlignConf.merged(conf)
    frames = list(frames)
    _check_frames(frames, strategy, conf)
    idx = [int(f.index) for f in frames]
    edge = conf.edge if conf.edge != "auto" else ("essential" if with_scale else "rgbd")
    m = make_matcher(matcher)
    if edge == "essential" and conf.essential_px is None:
        conf = replace(conf, essential_px=float(getattr(m, "keypoint_px", 1.0)))
    pv = _PairVerifier(frames, m, edge, conf, with_scale, _as_list(boxes, frames, "boxes"))
    extract0 = getattr(m, "extract_seconds", 0.0)
    t_all = time.perf_counter()
    S, kind, guessed = None, "", []
    if strategy == "mst":
        root, poses, edges, S, kind = _align_mst(frames, pv, embeddings)
    else:
        root, poses, edges, guessed = _align_sequential(frames, pv)
    secs = pv.secs
    secs["total"] = time.perf_counter() - t_all
    secs["extract"] = getattr(m, "extract_seconds", 0.0) - extract0
    secs["match"] -= secs["extract"]  # match time excluding feature extraction
    unaligned = [i for i in idx if i not in poses]
    res = AlignmentResult(poses, idx[root], edges, unaligned, strategy, guessed, pv.stats, S, kind, with_scale, secs,
                          edge)
    _record_alignment(log, res, len(idx), step)
    return res
