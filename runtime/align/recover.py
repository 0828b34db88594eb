"""Recovery of key frames the tree left out: whole-image edges, bridge frames walked from an aligned key frame in
time (metric depth) or re-aligned with the tree (relative depth), and bridges found by appearance where the
video revisits a place. `Fates` records which step placed each key frame."""
from __future__ import annotations

from typing import Any, Callable, Mapping, Sequence

import numpy as np

from ..frames import FrameSource
from ..infra.trace import StageLog, as_trace
from ..types import Frame
from .conf import AlignConf
from .matching import KeyedMatcher, Matches
from .pairwise import align_pair
from .tree import AlignmentResult, align_frames
from .verify import edge_ok, reattach


WithDepth = Callable[[Frame], Frame]   # a source frame -> the same frame with the depth the run uses (sensor or model)


def attach_frames(al: AlignmentResult, frames: dict[int, Frame], todo: Sequence[int], matcher: KeyedMatcher,
                  conf: AlignConf, tries: int | None = None) -> list[int]:
    """Attach frames without a pose to the tree one edge at a time, metric depth only: each frame in `todo` is
    matched (whole image, cached features) to its `tries` (default `conf.attach_tries`) nearest aligned frames
    in time, the first edge that passes RANSAC and the depth check (`max_free_space_violation` both ways) gives
    its pose; repeated while frames get attached (a new one can host the next). Costs <= tries pairs per frame,
    against a full re-alignment's all-pairs search. Mutates al (poses, edges, unaligned, edge_stats); returns
    the attached."""
    tries = conf.attach_tries if tries is None else tries
    rng = np.random.default_rng(conf.ransac_seed)
    # not al.edge_stats: those pairs failed with matches inside the boxes only (the trial's 0-of-13 attached)
    tried = al.whole_tried | set(frozenset(e) for e in al.rejected_edges)
    attached: list[int] = []
    changed = True
    while changed:
        changed = False
        for u in [int(i) for i in todo if int(i) not in al.poses and int(i) in frames]:
            fu = frames[u]
            near = sorted((a for a in al.poses if a in frames and frozenset((a, u)) not in tried),
                          key=lambda a: (abs(float(frames[a].t) - float(fu.t)), a))[:tries]
            for a in near:
                tried.add(frozenset((a, u)))
                if _try_edge(al, frames, a, u, matcher, conf, rng):
                    attached.append(u)
                    changed = True
                    break
    al.unaligned = [i for i in al.unaligned if i not in al.poses]
    return attached


def _try_edge(al: AlignmentResult, frames: Mapping[int, Frame], a: int, u: int, matcher: KeyedMatcher,
              conf: AlignConf, rng: np.random.Generator) -> bool:
    """One whole-image edge from aligned frame a to frame u: RANSAC, then the depth check both ways; on success
    u gets its pose through a. Recorded in al (whole_tried, edge_stats, and poses + edges on success)."""
    al.whole_tried.add(frozenset((a, u)))
    fa, fu = frames[a], frames[u]
    mt = matcher.match_keys(a, fa.rgb, u, fu.rgb, None, None)
    r = align_pair(mt, fa.depth, fa.K, fu.depth, fu.K, conf, False, rng, getattr(fa, "dist", None),
                   getattr(fu, "dist", None))
    al.edge_stats[(a, u)] = r
    if not r.ok or not edge_ok(fa, fu, r.T_ab, conf.max_free_space_violation):
        return False
    al.poses[u] = al.poses[a] @ r.T_ab
    al.edges.append((a, u))
    return True


class BlockPairs:
    """Matcher wrapper that returns no matches for the given frame pairs (edges the depth check rejected), so a
    new alignment round cannot choose them again; everything else goes to the wrapped matcher."""

    def __init__(self, matcher: KeyedMatcher, pairs: Sequence[tuple[int, int]]):
        self.m = matcher
        self.pairs = {frozenset(p) for p in pairs}

    def match_keys(self, k0: Any, rgb0: np.ndarray, k1: Any, rgb1: np.ndarray, boxes0: Any = None,
                   boxes1: Any = None) -> Matches:
        if frozenset((k0, k1)) in self.pairs:
            return Matches.empty()
        return self.m.match_keys(k0, rgb0, k1, rgb1, boxes0, boxes1)

    def match(self, rgb0: np.ndarray, rgb1: np.ndarray, boxes0: Any = None, boxes1: Any = None) -> Matches:
        return self.m.match(rgb0, rgb1, boxes0, boxes1)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.m, name)


def _bridge_frames(al: AlignmentResult, have: set[int], prev: Mapping[int, Frame], cands: list[int], source: FrameSource,
                   conf: AlignConf) -> list[int]:
    """Candidate frames (at most `bridge_gap_s` apart, `bridge_frames` in all) between each unaligned key frame
    and its nearest aligned key frame in time, across gaps up to `bridge_max_gap_s`; earlier rounds' kept."""
    times = {i: float(source.timestamps[i]) for i in cands}
    extra: list[int] = []
    for u in sorted(al.unaligned, key=lambda u: min(abs(u - a) for a in al.poses)):
        a = min(al.poses, key=lambda j: abs(j - u))
        lo, hi = sorted((u, a))
        if abs(float(source.timestamps[hi]) - float(source.timestamps[lo])) > conf.bridge_max_gap_s:
            continue  # a long chain of bridges drifts: better unaligned (reported) than misplaced
        between = [c for c in cands if lo < c < hi and c not in have and c not in extra and c not in prev]
        last = float(source.timestamps[lo])
        for c in between:
            if times[c] - last >= conf.bridge_gap_s:
                extra.append(c)
                last = times[c]
        if len(extra) >= conf.bridge_frames:
            break
    return sorted(set(extra[:conf.bridge_frames]) | set(prev))


def bridge_realign(al: AlignmentResult, frames: list[Frame], boxes: dict[int, np.ndarray | None], cands: list[int], source: FrameSource,
                   matcher: KeyedMatcher, with_depth: WithDepth, with_scale: bool, conf: AlignConf, log: StageLog | None,
                   previous: Sequence[Frame] = ()) -> tuple[AlignmentResult, list[Frame]]:
    """Relative depth: key frames far apart in time often share no view, so the tree falls apart into
    components. Connect each unaligned key frame to its nearest aligned key frame in time through intermediate
    candidate frames (`_bridge_frames`; used for poses only, never detected) and align again. Key frames still
    unaligned afterwards stay unaligned (recorded). Returns (alignment, the bridge frames used)."""
    log = as_trace(log)
    have = {f.index for f in frames}
    prev = {f.index: f for f in previous}  # bridges of an earlier round are kept (their depth is loaded)
    extra = _bridge_frames(al, have, prev, cands, source, conf)
    if not set(extra) - set(prev):
        return al, []
    bf = [prev[i] if i in prev else with_depth(source[i]) for i in extra]
    with log.stage("alignment"):
        al2 = align_frames(frames + bf, matcher, "mst", conf, None,
                           {**boxes, **{i: None for i in extra}}, with_scale=with_scale, log=None)
    before = len(al.unaligned)
    al2.unaligned = [i for i in al2.unaligned if i in have]
    al2.rejected_edges = list(al.rejected_edges)
    log.event("alignment", f"{before} key frame(s) had no verified edge to the tree; {len(extra)} bridge "
                f"frames between them "
                f"and their neighbours in time left {len(al2.unaligned)} unaligned", stage="alignment",
                bridges=extra, unaligned=al2.unaligned)
    if len(al2.poses) and sum(i in have for i in al2.poses) >= sum(i in have for i in al.poses):
        return al2, bf
    return al, []


def whole_image_realign(al: AlignmentResult, frames: list[Frame], boxes: dict[int, np.ndarray | None], emb: np.ndarray | None,
                         matcher: KeyedMatcher, with_scale: bool, conf: AlignConf, log: StageLog | None
                         ) -> tuple[AlignmentResult, dict[int, Any]]:
    """Too few matches inside the task objects' boxes (small or few objects): match whole images instead;
    the better tree is kept. Returns (alignment, the boxes it used)."""
    with log.stage("alignment"):
        al2 = align_frames(frames, matcher, "mst", conf, emb, None, with_scale=with_scale, log=None)
    log.event("alignment", f"alignment inside object boxes left {len(al.unaligned)} of {len(frames)} key "
                f"frames "
                f"unaligned; whole-image matching left {len(al2.unaligned)}", stage="alignment",
                boxes_unaligned=list(al.unaligned), whole_unaligned=list(al2.unaligned))
    if len(al2.unaligned) < len(al.unaligned):
        return al2, {i: None for i in boxes}
    return al, boxes


class Fates:
    """What became of each key frame: the step that gave it its current pose, or "unaligned" (`after` is called
    once per step; a step that leaves a frame's pose object as it was leaves its fate too)."""

    def __init__(self, keys: Sequence[int]):
        self.keys = sorted(int(i) for i in keys)
        self.how: dict[int, str] = {}
        self.steps: list[str] = []   # in the order they ran (the summary's order)
        self._poses: dict[int, Any] = {}

    def after(self, al: AlignmentResult, step: str) -> None:
        if step not in self.steps:
            self.steps.append(step)
        for i in self.keys:
            T = al.poses.get(i)
            if T is None:
                self.how[i] = "unaligned"
            elif self._poses.get(i) is not T and i not in al.rebased:
                self.how[i] = step
            self._poses[i] = T
        al.rebased = []

    def summary(self) -> str:
        """"12 of 16 key frames aligned (9 box-matched tree, 3 through bridge frames)"."""
        n = len(self.keys)
        got_by = [self.how.get(i, "unaligned") for i in self.keys]
        counts = {k: got_by.count(k) for k in self.steps if k != "unaligned" and k in got_by}
        got = sum(counts.values())
        return f"{got} of {n} key frames aligned" + (f" ({', '.join(f'{c} {k}' for k, c in counts.items())})"
                                                    if counts else "")


def bridge_attach(al: AlignmentResult, frames: list[Frame], source: FrameSource, matcher: KeyedMatcher, with_depth: WithDepth,
                  conf: AlignConf, log: StageLog | None = None, thumbs: Mapping[int, np.ndarray] | None = None,
                  fates: Fates | None = None) -> list[Frame]:
    """Metric depth: connect each unaligned key frame through a chain of video frames (at least `bridge_gap_s`
    apart, `bridge_frames` in all) walked from its nearest aligned key frame in time towards it (`bridge_chain`),
    one `attach_frames` edge per step, loading a frame only when the chain reaches it and stopping as soon as the
    key frame itself attaches: no re-alignment of the whole set, so a round that cannot buy an aligned frame costs
    only its failed steps. Gaps over `bridge_max_gap_s` are not bridged (long chains drift): key frames that far
    from every aligned one then get bridges found by appearance (`revisit_attach`, with `thumbs`: small gray
    images of the video's frames, e.g. dedup's) from what is left of the same `bridge_frames` budget. Returns
    the bridge frames used (poses only, never detected); recorded."""
    pool = {f.index: f for f in frames}
    keys = set(pool)
    used: list[Frame] = []
    budget = conf.bridge_frames
    n0 = len(al.unaligned)
    failed: dict[tuple[int, int], int] = {}  # (anchor, direction) -> the key frame its chain got stuck before
    skipped: list[int] = []
    for u in sorted(al.unaligned, key=lambda u: min((abs(u - a) for a in al.poses if a in keys), default=0)):
        if budget <= 0 or u in al.poses:
            continue
        anchors = [a for a in al.poses if a in keys]
        if not anchors:
            break
        # the nearest aligned key frame on each side in time, the nearer first (a chain can fail on one side)
        sides = [max((j for j in anchors if j < u), default=None), min((j for j in anchors if j > u), default=None)]
        for a in sorted((j for j in sides if j is not None), key=lambda j: abs(j - u)):
            if u in al.poses or abs(float(source.timestamps[u]) - float(source.timestamps[a])) > conf.bridge_max_gap_s:
                continue
            d = int(np.sign(u - a))
            if (a, d) in failed and d * (u - failed[(a, d)]) > 0:
                # a nearer key frame across the same gap from the same anchor was not reached: a chain to this
                # one, beyond it, must cross the same frames, so it would spend the budget without buying one
                skipped.append(u)
                continue
            budget, chain = bridge_chain(al, pool, a, u, source, matcher, with_depth, conf, budget)
            used += chain
            end = chain[-1].index if chain else a
            if u not in al.poses and abs(float(source.timestamps[u]) - float(source.timestamps[end])) \
                    >= 2 * conf.bridge_gap_s:  # stuck inside the gap (not merely u itself failing at its end)
                failed.setdefault((a, d), u)  # the nearest such key frame (they come nearest first)
    al.unaligned = [i for i in al.unaligned if i not in al.poses]
    as_trace(log).event("alignment", f"bridging: {conf.bridge_frames - budget} video frame(s) tried, "
                          f"{len(used)} attached as "
                          f"bridges, {n0 - len(al.unaligned)} of {n0} key frame(s) aligned through them; "
                          f"{len(al.unaligned)} key frame(s) left unaligned"
                          + (f" ({len(set(skipped))} not tried: behind a gap a chain did not cross)" if skipped
                             else ""), stage="alignment", bridges=[f.index for f in used],
                          unaligned=list(al.unaligned), skipped=sorted(set(skipped)))
    if thumbs and conf.revisit_tries > 0 and al.unaligned and budget > 0:
        if fates is not None:
            fates.after(al, "through bridge frames")
        budget, more = revisit_attach(al, pool, keys, source, matcher, with_depth, conf, thumbs, budget, log)
        used += more
        if fates is not None:
            fates.after(al, "through bridges found by appearance")
    return used


def thumb_histograms(thumbs: Mapping[int, np.ndarray], bins: int = 32) -> dict[int, np.ndarray]:
    """Gray-level histograms of small gray images, zero-mean and unit-norm, so that a dot product is their
    Pearson correlation (like `similarity_matrix`'s colour histograms; dedup's thumbnails are gray). Pure.
    Chosen over zero-mean NCC of blurred thumbnails and gradient-orientation grids by how often the most alike
    frame far away in time overlaps (synthetic seeds 7 and 8, docs/performance.md)."""
    out = {}
    for i, g in thumbs.items():
        h = np.histogram(np.asarray(g), bins, (0, 256))[0].astype(np.float64)
        h -= h.mean()
        out[int(i)] = h / max(float(np.linalg.norm(h)), 1e-12)
    return out


def revisit_pairs(u: int, aligned: Sequence[int], hist: Mapping[int, np.ndarray], times: Any, max_gap_s: float,
                  skip: set[frozenset[int]], n: int) -> list[tuple[int, int]]:
    """Up to n (c, a) pairs to connect unaligned frame u through a place the video shows twice: c a frame
    with a histogram (u itself included) within `max_gap_s` of u in time and not in `aligned`, a an aligned
    frame more than `max_gap_s` away from u (nearer ones are the time chains' work); each c with the a it is
    most alike, the most alike pairs first, pairs in `skip` (tried) left out. Pure."""
    tu = float(times[u])
    far = [a for a in aligned if a in hist and abs(float(times[a]) - tu) > max_gap_s]
    near = [c for c in hist if c not in aligned and abs(float(times[c]) - tu) <= max_gap_s]
    if not far or not near:
        return []
    sim = np.array([hist[c] for c in near]) @ np.array([hist[a] for a in far]).T
    best = []
    for i, c in enumerate(near):
        order = [j for j in np.argsort(-sim[i], kind="stable") if frozenset((far[j], c)) not in skip]
        if order:
            best.append((-float(sim[i, order[0]]), abs(float(times[c]) - tu), c, far[order[0]]))
    return [(c, a) for _, _, c, a in sorted(best)[:n]]


def revisit_attach(al: AlignmentResult, pool: dict[int, Frame], keys: set[int], source: FrameSource, matcher: KeyedMatcher,
                   with_depth: WithDepth, conf: AlignConf, thumbs: Mapping[int, np.ndarray], budget: int,
                   log: StageLog | None = None) -> tuple[int, list[Frame]]:
    """Bridges found by appearance, metric depth: a long video comes back to places (people walk back), so a
    key frame with no aligned key frame within `bridge_max_gap_s` in time (out of the time chains' reach) may
    still be near (in time) a view of an aligned frame's place. Key frames with an aligned key frame that near
    are left to the time chains (where those failed, a chain from a revisit must cross the same frames near the
    key frame). For each unaligned key frame u out of reach, its `revisit_tries` (c, a) pairs
    (`revisit_pairs`: c near u in time, a aligned far from it, alike by thumbnail histogram) are tried as
    whole-image edges a -> c (RANSAC + the depth check both ways); an attached c is chained to u in time
    (`bridge_chain`). Once u is aligned, the unaligned key frames it has verified pairs with come along
    (`_reattach`, depth-checked), e.g. the rest of a part the depth check cut off. Loads at most `budget`
    frames. Mutates al and pool; returns (budget left, the bridge frames used); recorded."""
    rng = np.random.default_rng(conf.ransac_seed)
    ts, gap = source.timestamps, conf.bridge_max_gap_s
    todo = [u for u in sorted(al.unaligned) if u not in al.poses and not any(
        a in al.poses and abs(float(ts[a]) - float(ts[u])) <= gap for a in keys)]
    if not todo:
        return budget, []
    hist = thumb_histograms(thumbs)
    n0, tried, used, gained = len(al.unaligned), 0, [], []

    def ok(a: int, b: int, T_ab: np.ndarray) -> bool:
        return a in pool and b in pool and edge_ok(pool[a], pool[b], T_ab, conf.max_free_space_violation)

    for u in todo:
        if budget <= 0:
            break
        if u in al.poses:
            continue
        for c, a in revisit_pairs(u, list(al.poses), hist, ts, gap, al.whole_tried, conf.revisit_tries):
            if u in al.poses:
                break
            if c in al.poses:
                continue  # attached by an earlier chain of this loop
            if c not in pool:
                if budget <= 0:
                    break
                pool[c] = with_depth(source[c])
                budget -= 1
            tried += 1
            if not _try_edge(al, pool, a, c, matcher, conf, rng):
                continue
            if c != u:
                used.append(pool[c])
                budget, chain = bridge_chain(al, pool, c, u, source, matcher, with_depth, conf, budget)
                used += chain
        if u in al.poses:
            gained.append(u)
            gained += reattach(al, al.poses, [i for i in al.unaligned if i in keys and i not in al.poses], ok)
    al.unaligned = [i for i in al.unaligned if i not in al.poses]
    as_trace(log).event("alignment", f"bridges found by appearance: {len(todo)} key frame(s) more than {gap:g} s "
                          f"from every aligned one, {tried} pair(s) tried, {len(used)} frame(s) attached as "
                          f"bridges, {n0 - len(al.unaligned)} of {n0} key frame(s) aligned through them; "
                          f"{len(al.unaligned)} left unaligned", stage="alignment", out_of_reach=todo,
                          bridges=[f.index for f in used], aligned=gained, unaligned=list(al.unaligned))
    return budget, used


def chain_jumps(gap: float, min_gap: float) -> list[float]:
    """The jump schedule of one `bridge_chain` step over a `gap` (s) to the key frame: halve the gap down to
    `min_gap` (`bridge_gap_s`), then walk at 2, 3, ... x `min_gap` (slow camera motion costs few bridge frames,
    fast motion the dense chain). Pure; a fixed schedule, so a step always ends."""
    halving = [gap / 2 ** k for k in range(1, 32) if gap / 2 ** k >= min_gap]
    walking = [min_gap * k for k in range(2, int(gap / min_gap))]
    return halving + walking


def bridge_chain(al: AlignmentResult, pool: dict[int, Frame], a: int, u: int, source: FrameSource, matcher: KeyedMatcher,
                 with_depth: WithDepth, conf: AlignConf, budget: int) -> tuple[int, list[Frame]]:
    """Walk from aligned frame a towards unaligned key frame u: each step first tries u itself, then jumps
    (`chain_jumps`) to the frame halfway between the chain's end and u, halving the jump on a failed attach
    down to `bridge_gap_s`, then walking on at that spacing. Returns (budget left, the bridge frames
    attached)."""
    ts = source.timestamps
    end, used = a, []
    while budget > 0 and u not in al.poses:
        if attach_frames(al, pool, [u], matcher, conf, tries=1):
            break
        gap = abs(float(ts[u]) - float(ts[end]))
        if gap < 2 * conf.bridge_gap_s or abs(u - end) < 2:
            break  # no room for a bridge frame (in time, or no frame at all between: sparse frames far apart)
        step, moved = (1 if u > end else -1), False
        for jump in chain_jumps(gap, conf.bridge_gap_s):  # a blurred frame is skipped
            if budget <= 0 or moved:
                break
            c = min(range(end + step, u, step), key=lambda i: abs(abs(float(ts[i]) - float(ts[end])) - jump))
            if c in pool:
                continue
            pool[c] = with_depth(source[c])
            budget -= 1
            if attach_frames(al, pool, [c], matcher, conf, tries=1):
                end, moved = c, True
                used.append(pool[c])
        if not moved:
            break  # no bridge frame attached at any jump: give up on u (reported by the caller)
    return budget, used
