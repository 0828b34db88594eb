"""The odometry backbone: what joins the key frames the paper's tree leaves apart (metric depth).

After the box-matched maximum spanning tree and its depth check (the paper's path, kept where it works), the key
frames form parts: the root's aligned part and parts (often single frames) the tree could not reach. For every two
key frames next to each other in time (`walk_all`; else only those in different parts), `odometry.walk` follows
the camera from one to the other through the frames between them (forwards, then backwards from the other end where it got stuck), with
edges that need depth at one end only (`pnp.rgbd_edge`: 3D-3D, PnP, essential matrix). Every verified edge -
the tree's, the other verified key-frame pairs (loop closures), the walks' - goes into one pose graph; the root's
connected part is composed along its maximum spanning tree and refined (`graph.refine`, Cauchy loss: a wrong edge
that passed verification loses its pull). The key frames of the root's part are aligned; each says by which path
(the tree, or the backbone), and the trace has every walk (frames loaded, edges by method, why it stopped).
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from ..frames import FrameSource
from ..geometry import icp_point_to_plane, invert
from ..infra.trace import StageLog, as_trace
from ..types import Frame
from .conf import EDGE_SIGMA, ICP_SIGMA, AlignConf, BackboneConf
from .graph import Edge, refine, spanning_poses
from .matching import KeyedMatcher
from .odometry import OrbWalker, walk
from .pairwise import pose_change
from .pnp import EdgeResult, rgbd_edge
from .recover import Fates, WithDepth
from .tree import AlignmentResult
from .verify import depth_consistency, edge_ok, verify_tree

def sigma_of(r: EdgeResult | Any) -> tuple[float, float]:
    """(metres, radians) expected error of an edge by its method (`EDGE_SIGMA`; 3d-3d when it has none; `ICP_SIGMA`
    once ICP refined it)."""
    if getattr(r, "icp", "") == "applied":
        m, d = ICP_SIGMA
    else:
        m, d = EDGE_SIGMA.get(getattr(r, "method", "") or "3d-3d", EDGE_SIGMA["3d-3d"])
    return m, np.radians(d)


class _Parts:
    """Union-find over frame indices."""

    def __init__(self) -> None:
        self.p: dict[int, int] = {}

    def find(self, x: int) -> int:
        self.p.setdefault(x, x)
        while self.p[x] != x:
            self.p[x] = self.p[self.p[x]]
            x = self.p[x]
        return x

    def union(self, a: int, b: int) -> None:
        self.p[self.find(b)] = self.find(a)


def _join_ends(fw: Any, bw: Any, estimate: Callable[[int, int, bool], EdgeResult]) -> list[Edge]:
    """Two walks that stopped facing each other: their last two frames are tried pairwise (loaded already), the
    nearest pairs first; the first edge that verifies joins them."""
    def tail(w: Any) -> list[int]:
        seen = [w.start] + [e.b for e in w.edges]
        return list(dict.fromkeys(reversed(seen)))[:2]

    for a, b in sorted(((x, y) for x in tail(fw) for y in tail(bw) if x != y), key=lambda p: abs(p[0] - p[1])):
        r = estimate(a, b, False)
        if r.ok:
            st, sr = sigma_of(r)
            return [Edge(a, b, r.T_ab, f"odometry/{r.method}", st, sr, 1e3 + r.n_inliers)]
    return []


def key_edges(al: AlignmentResult, pool: Mapping[int, Any], max_violation: float, loops: bool) -> list[Edge]:
    """The key frames' verified edges: the tree's (those the depth check kept) and, with `loops`, every other pair
    alignment verified that passes the same depth check."""
    rejected = {frozenset(e) for e in al.rejected_edges}
    tree = {frozenset(e) for e in al.edges}
    out = []
    for (a, b), r in al.edge_stats.items():
        if not r.ok or frozenset((a, b)) in rejected or a not in pool or b not in pool:
            continue
        kind = "tree" if frozenset((a, b)) in tree else "loop"
        if kind == "loop" and not loops:
            continue
        if kind == "loop" or not (a in al.poses and b in al.poses):  # the tree's root part was checked already
            if not edge_ok(pool[a], pool[b], r.T_ab, max_violation):
                continue
        st, sr = sigma_of(r)
        out.append(Edge(a, b, r.T_ab, kind, st, sr, 1e6 + r.n_inliers if kind == "tree" else float(r.n_inliers)))
    return out


def icp_refined(r: EdgeResult, fa: Frame, fb: Frame, conf: AlignConf) -> EdgeResult:
    """A verified edge refined by point-to-plane ICP on the two frames' depth (`geometry.icp_point_to_plane`, the
    alignment's `icp_*` settings): features place the frames, the dense depth of everything both see fixes the
    last centimetres. Rejected (the edge as it was, `r.icp` says why) when the depth overlaps too little or ICP
    moves the edge more than `icp_max_change`."""
    T2, rms, _n, overlap = icp_point_to_plane(fa.depth, fa.K, fb.depth, fb.K, r.T_ab, conf.icp_iterations,
                                              conf.icp_stride)
    dt, dr = pose_change(r.T_ab, T2)
    if overlap < conf.icp_min_overlap:
        r.icp = f"rejected: overlap {overlap:.2f} < {conf.icp_min_overlap}"
    elif dt > conf.icp_max_change[0] or dr > conf.icp_max_change[1]:
        r.icp = f"rejected: moved {dt:.3f} m / {dr:.1f} deg from the feature pose"
    else:
        r.T_ab, r.icp, r.icp_rms_m = T2, "applied", rms
    return r


def tiny_descriptor(rgb: np.ndarray) -> np.ndarray:
    """A place descriptor without a model: the 32 x 24 gray thumbnail, zero-mean and unit-norm [768] (its dot
    product is a normalised cross-correlation). Weaker than an embedder (`revisit_edges`)."""
    import cv2

    g = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2GRAY) if rgb.ndim == 3 else rgb
    g = cv2.resize(g, (32, 24), interpolation=cv2.INTER_AREA).astype(np.float64).ravel()
    g -= g.mean()
    return g / max(float(np.linalg.norm(g)), 1e-12)


def _spread(items: Sequence[int], n: int) -> list[int]:
    """At most n of the sorted items, evenly spread."""
    items = sorted(items)
    if len(items) <= n:
        return items
    return [items[int(round(k))] for k in np.linspace(0, len(items) - 1, n)]


def revisit_edges(parts: _Parts, nodes: Sequence[int], keys: Sequence[int], root: int, pool: Mapping[int, Any],
                  estimate: Callable[[int, int, bool], EdgeResult], describe: Callable[[np.ndarray], np.ndarray],
                  tries: int, per_part: int = 24) -> tuple[list[Edge], int]:
    """Places the walk-through comes back to: a part the walks could not join to the root's (a jump in the
    recording: ScanNet's subsample has steps of 1.4 m / 46 deg) is looked for among the root part's frames by
    appearance - `describe(rgb)` (the bundle's embedder, else `tiny_descriptor`) of at most `per_part` frames of
    each part, every pair ranked by cosine - and the `tries` most alike pairs per part are tried with whole-image
    edges (depth at one end at least, depth-checked). Returns (the edges found, kind "revisit"; frames described)."""
    if tries <= 0:
        return [], 0
    desc: dict[int, np.ndarray] = {}

    def d(i: int) -> np.ndarray:
        if i not in desc:
            v = np.asarray(describe(pool[i].rgb), np.float64).ravel()
            desc[i] = v / max(float(np.linalg.norm(v)), 1e-12)
        return desc[i]

    out: list[Edge] = []
    groups: dict[int, list[int]] = {}
    for n in nodes:
        groups.setdefault(parts.find(n), []).append(n)
    for head in sorted(groups, key=lambda h: min(groups[h])):
        members = groups[head]
        if parts.find(head) == parts.find(root) or not any(k in members for k in keys):
            continue
        home = [n for n in nodes if parts.find(n) == parts.find(root)]
        mine, theirs = _spread(members, per_part), _spread(home, per_part)
        sims = sorted(((-float(d(u) @ d(v)), u, v) for u in mine for v in theirs))
        for _s, u, v in sims[:tries]:
            r = estimate(v, u, False)
            if r.ok:
                st, sr = sigma_of(r)
                out.append(Edge(v, u, r.T_ab, f"revisit/{r.method}", st, sr, 1e3 + r.n_inliers))
                parts.union(v, u)
                break
    return out, len(desc)


def closure_edges(poses: Mapping[int, np.ndarray], tree: Sequence[Edge], pool: Mapping[int, Any],
                  estimate: Callable[[int, int], EdgeResult], n: int, hops: int) -> list[Edge]:
    """Loop closures: pairs of posed frames (poses in one frame, from the spanning tree) that are more than `hops`
    tree edges apart but whose poses say they see the same surfaces (`alignment.depth_consistency`'s overlap of
    one frame's depth in the other, under the composed relative pose: drift a walk-through gathers between two
    visits of a place is a few centimetres, a view's overlap changes little with it); the `n` pairs of largest
    predicted overlap (at most 2 per frame) are tried as edges. Returns the verified ones (kind "closure")."""
    if n <= 0:
        return []
    adj: dict[int, list[int]] = {}
    for e in tree:
        adj.setdefault(e.a, []).append(e.b)
        adj.setdefault(e.b, []).append(e.a)
    ids = sorted(i for i in poses if i in pool and pool[i].depth is not None)
    C = np.array([poses[i][:3, 3] for i in ids])
    Z = np.array([poses[i][:3, 2] for i in ids])
    cand = []
    for x in range(len(ids)):
        near = np.flatnonzero((np.linalg.norm(C - C[x], axis=1) < 1.5) & (Z @ Z[x] > np.cos(np.radians(45))))
        far = _beyond_hops(ids[x], adj, hops)
        for y in near[near > x]:
            if ids[y] in far:
                cand.append((ids[x], int(ids[y])))
    scored = []
    for a, b in cand:
        ov = depth_consistency(pool[a], pool[b], invert(poses[a]) @ poses[b], stride=16)[0]
        if ov > 0.3:
            scored.append((-ov, a, b))
    out, per = [], {}
    for _ov, a, b in sorted(scored):
        if len(out) >= n or per.get(a, 0) >= 2 or per.get(b, 0) >= 2:
            continue
        r = estimate(a, b)
        per[a], per[b] = per.get(a, 0) + 1, per.get(b, 0) + 1
        if r.ok:
            st, sr = sigma_of(r)
            out.append(Edge(a, b, r.T_ab, f"closure/{r.method}", st, sr, float(r.n_inliers)))
    return out


def _beyond_hops(start: int, adj: Mapping[int, list[int]], hops: int) -> set[int]:
    """Nodes more than `hops` edges from `start` in the graph `adj` (unreached nodes count as beyond)."""
    seen, frontier = {start}, [start]
    for _ in range(hops):
        frontier = [c for p in frontier for c in adj.get(p, []) if c not in seen]
        seen.update(frontier)
    return {n for n in adj if n not in seen}


def path_kinds(root: int, tree: Sequence[Edge]) -> dict[int, str]:
    """Per frame of the root's spanning tree: by which path it is joined to the root - "box-matched tree" when
    every edge on the way is the tree's, else "place revisit" when a revisit edge is on it, else "odometry
    backbone"."""
    adj: dict[int, list[tuple[int, str]]] = {}
    for e in tree:
        adj.setdefault(e.a, []).append((e.b, e.kind))
        adj.setdefault(e.b, []).append((e.a, e.kind))
    out, todo = {root: "box-matched tree"}, [root]
    rank = {"box-matched tree": 0, "odometry backbone": 1, "place revisit": 2}
    while todo:
        p = todo.pop()
        for c, kind in adj.get(p, []):
            if c in out:
                continue
            k = ("place revisit" if kind.startswith("revisit") else "odometry backbone"
                 if kind.startswith("odometry") else "box-matched tree")
            out[c] = max(out[p], k, key=rank.__getitem__)
            todo.append(c)
    return out


def align_backbone(al: AlignmentResult, frames: list[Frame], matcher: KeyedMatcher, source: FrameSource,
                   with_depth: WithDepth, grid: Sequence[int], conf: AlignConf, bconf: BackboneConf,
                   log: StageLog | None = None, fates: Fates | None = None,
                   describe: Callable[[np.ndarray], np.ndarray] | None = None) -> list[Frame]:
    """Join the key frames' parts by odometry walks and refine every pose in one graph (module docstring).
    al: the key frames' alignment after the tree's depth check (mutated: poses, unaligned, edges, edge_stats);
    grid: frames the walks step over (the scan's kept frames); conf: the alignment settings (edges, depth check);
    describe: rgb -> a place descriptor for revisits (the bundle's embedder). Returns the frames the walks loaded
    and used (poses only, never detected)."""
    log = as_trace(log)
    t0 = time.perf_counter()
    px = bconf.pnp_px if bconf.pnp_px is not None else 1.5 * float(getattr(matcher, "keypoint_px", 1.0))
    pool = {f.index: f for f in frames}
    keys = sorted(pool)
    viol = conf.max_free_space_violation
    rng = np.random.default_rng(conf.ransac_seed)
    stats: dict[tuple[int, int], EdgeResult] = {}

    walker = matcher if bconf.walk_matcher == 'pipeline' else OrbWalker(bconf.walk_keypoints)
    for m in (matcher, walker):  # every frame the walks may load stays cached: none is extracted twice
        hold = getattr(m, "hold", None)
        if callable(hold):
            hold(len(frames) + bconf.max_frames)
    wpx = bconf.pnp_px if bconf.pnp_px is not None else 1.5 * float(getattr(walker, "keypoint_px", 1.0))

    def estimate(a: int, b: int, adjacent: bool, wide: bool = False, icp: bool = True) -> EdgeResult:
        for i in (a, b):
            if i not in pool:
                pool[i] = with_depth(source[i])
        fa, fb = pool[a], pool[b]
        m = (matcher if wide else walker).match_keys(a, fa.rgb, b, fb.rgb, None, None)
        methods = tuple(x for x in bconf.methods if adjacent or x != "essential")
        if adjacent and bconf.adjacent_essential and "essential" not in methods:
            methods += ("essential",)
        r = rgbd_edge(m, fa, fb, conf, px if wide else wpx, rng, methods)
        if r.ok and not edge_ok(fa, fb, r.T_ab, viol):
            r = EdgeResult(r.T_ab, False, r.n_matches, r.n_valid, r.n_inliers, r.residual_m, r.seconds,
                           f"{r.method} edge failed the depth check", method="")
        if r.ok and bconf.edge_icp and icp:  # after the check: ICP refines an edge, never admits one
            r = icp_refined(r, fa, fb, conf)
        stats[(a, b)] = r
        return r

    edges = key_edges(al, pool, viol, bconf.loops)
    parts = _Parts()
    for k in keys:
        parts.find(k)
    for e in edges:
        parts.union(e.a, e.b)
    budget = bconf.max_frames
    walks = []
    for a, b in zip(keys, keys[1:]):
        if (parts.find(a) == parts.find(b) and not bconf.walk_all) or budget <= 0:
            continue
        fw, budget = walk(a, b, grid, estimate, budget, lambda i: i in pool, bconf.first_jump, sigma_of,
                          bconf.max_jump)
        gap = [fw]
        if not fw.reached and budget > 0:  # from the other end back to where the first walk stopped
            bw, budget = walk(b, fw.end, grid, estimate, budget, lambda i: i in pool, bconf.first_jump,
                              sigma_of, bconf.max_jump)
            gap.append(bw)
            if not bw.reached:  # the two ends across the frames neither could step over
                gap[-1].edges += _join_ends(fw, bw, estimate)
        for w in gap:
            walks.append(w)
            edges += w.edges
            for e in w.edges:
                parts.union(e.a, e.b)
    root = al.root if al.root in pool else keys[0]
    nodes = sorted({i for e in edges for i in (e.a, e.b)} | set(keys))
    found, described = revisit_edges(parts, nodes, keys, root, pool,
                                     lambda a, b, adj: estimate(a, b, adj, True, False), describe or tiny_descriptor, bconf.part_revisits)
    edges += found
    poses, tree = spanning_poses(root, edges)
    closed = closure_edges(poses, tree, pool, lambda a, b: estimate(a, b, False, icp=False), bconf.closures,
                           bconf.closure_hops)
    edges += closed
    report = None
    if bconf.graph and len(poses) > 2:
        poses, report = refine(poses, edges, root, bconf.robust)
    before = {i for i in keys if i in al.poses}
    new_keys = [k for k in keys if k in poses]
    al.poses = {k: poses[k] for k in new_keys}
    al.root = root
    al.unaligned = [k for k in keys if k not in poses]
    for (a, b), r in stats.items():
        al.edge_stats.setdefault((a, b), r)
    al.rebased = [k for k in new_keys if k in before]  # their path stays the tree's; the graph only refines them
    if fates is not None:
        paths = path_kinds(root, tree)
        for k in new_keys:
            if k not in before:
                fates.how[k] = paths.get(k, "odometry backbone")
        fates.after(al, "odometry backbone")
    used_ids = sorted({i for e in edges for i in (e.a, e.b) if i in poses and i not in set(keys)})
    methods: dict[str, int] = {}
    for w in walks:
        for e in w.edges:
            m = e.kind.split("/")[-1]
            methods[m] = methods.get(m, 0) + 1
    log.event("alignment", f"odometry backbone: {len(walks)} walk(s) between key frames next in time"
                f"{'' if bconf.walk_all else ' in different parts'}, "
                f"{bconf.max_frames - budget} frame(s) loaded, {sum(len(w.edges) for w in walks)} edge(s) "
                f"({', '.join(f'{n} {k}' for k, n in sorted(methods.items())) or 'none'}); "
                f"{len(new_keys) - len(before & set(new_keys))} key frame(s) aligned through it, "
                f"{len(found)} revisit edge(s) ({described} frame(s) described); {len(al.unaligned)} left "
                f"unaligned", stage="alignment",
                walks=[{"from": w.start, "to": w.goal, "end": w.end, "edges": len(w.edges), "loaded": w.loaded,
                        "tried": w.tried, "why": w.why if not w.reached else ""} for w in walks],
                unaligned=list(al.unaligned), seconds=round(time.perf_counter() - t0, 3))
    if report is not None:
        log.event("alignment", f"pose graph: {report.nodes} frames, {report.edges} edges "
                    f"({sum(e.kind == 'loop' for e in edges)} verified key-frame pairs beyond the tree, {len(closed)} "
                    f"loop closure(s)), cost {report.cost_before:.1f} -> "
                    f"{report.cost_after:.1f}, {len(report.outliers)} edge(s) down-weighted",
                    stage="alignment", graph=report.to_dict())
    return [pool[i] for i in used_ids]


def align_rest_backbone(al: AlignmentResult, frames: list[Frame], matcher: KeyedMatcher, source: FrameSource,
                        with_depth: WithDepth, conf: AlignConf, bconf: BackboneConf, log: StageLog | None,
                        over_budget: Callable[[list[int]], "str | None"], fates: Fates | None = None,
                        thumbs: Mapping[int, np.ndarray] | None = None,
                        describe: Callable[[np.ndarray], np.ndarray] | None = None) -> list[Frame]:
    """Metric depth after the box-matched tree (`stage.align_keyframes` with a backbone config): the tree's depth
    check (`verify.verify_tree`), then the backbone over the frames the scan kept (the keys of `thumbs`; every
    frame when none are given). Returns the frames the walks used."""
    log = as_trace(log)
    with log.stage("alignment.verify"):
        al = verify_tree(al, {f.index: f for f in frames}, conf, log)
    if fates is not None:
        fates.after(al, "re-attached after the depth check")
    keys = {f.index for f in frames}
    al.unaligned = [i for i in al.unaligned if i in keys]
    why = over_budget(al.unaligned) if al.unaligned else None
    if why:  # past the budget: the walks are skipped (a reduced plan)
        log.event("reduced_plan", why, stage="alignment")
        return []
    grid = sorted(int(i) for i in thumbs) if thumbs else list(range(len(source)))
    with log.stage("alignment.backbone"):
        return align_backbone(al, frames, matcher, source, with_depth, grid, conf, bconf, log, fates, describe)
