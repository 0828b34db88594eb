"""Nearest boxes in O(log n): a KD-tree over box centres, culled by axis-aligned bounds, exact distances only for the
few pairs that can still win.

`BoxSet(instances)` indexes the boxes of a list of instances (a KD-tree over the centres of the small ones, the few
large ones — half-diagonal over `LARGE` times the median — kept aside and always checked). A box's distance to any
indexed box is at least the gap of their axis-aligned bounding boxes (`boxes.aabb_gaps`), and a box whose centre is
farther than `best + r_query + r_max` cannot be nearer than `best`; so a query costs a ball search, one vectorised
bound over its result and exact `geometry.box_distance` calls only where the bound does not rule a box out.
Answers are those of the exhaustive search, ties included (the first pair in list order).
"""
from __future__ import annotations

from typing import Any, Iterable

import numpy as np

from ..geometry import box_distance
from .boxes import aabb_gaps, half_extents
from .result import Unsupported

LARGE = 4.0  # a box whose half-diagonal exceeds this many times the median is checked by every query
SMALL = 32  # a set of at most this many boxes is searched whole (bounds, then exact where they allow)


class BoxSet:
    """The boxes of `instances` (list order kept: index i is instances[i])."""

    def __init__(self, instances: Iterable[Any]):
        self.inst = list(instances)
        self.c, self.e = half_extents(self.inst)
        self.r = np.linalg.norm(self.e, axis=1)
        self.pos = {id(o): i for i, o in enumerate(self.inst)}
        big = self.r > LARGE * float(np.median(self.r)) if len(self.inst) else np.zeros(0, bool)
        self.large = np.flatnonzero(big)
        self.small = np.flatnonzero(~big)
        self.tree = None  # small sets are searched whole: no tree (and no scipy import on a small map's question)
        if len(self) > SMALL and len(self.small):
            from scipy.spatial import cKDTree

            self.tree = cKDTree(self.c[self.small])
        self.rmax = float(self.r[self.small].max()) if len(self.small) else 0.0

    def __len__(self) -> int:
        return len(self.inst)

    def near(self, cx: np.ndarray, rx: float, within: float) -> np.ndarray:
        """Indices of the boxes that can be within `within` of a box centred at cx with half-diagonal rx (sorted)."""
        if self.tree is None:  # a few boxes (or only large ones): all of them, their bounds decide
            return np.arange(len(self))
        idx = list(self.large)
        if self.tree is not None and np.isfinite(within):
            idx += [int(self.small[k]) for k in self.tree.query_ball_point(cx, within + rx + self.rmax)]
        elif self.tree is not None:
            idx += list(self.small)
        return np.array(sorted(idx), dtype=int)

    def upper(self, cx: np.ndarray, skip: int) -> float:
        """A distance some box of the set is within of a box centred at cx: the distance between their centres
        (both centres lie inside their boxes), to the nearest other centre; inf when there is none."""
        if self.tree is None:
            d = np.linalg.norm(self.c - cx, axis=1)
            if skip >= 0:
                d[skip] = np.inf
            return float(d.min()) if len(d) else np.inf
        best = np.inf
        if self.tree is not None:
            dd, kk = self.tree.query(cx, k=min(2, len(self.small)))
            for d, k_ in zip(np.atleast_1d(dd), np.atleast_1d(kk)):
                if int(self.small[int(k_)]) != skip:
                    best = float(d)
                    break
        for j in self.large:
            if int(j) != skip:
                best = min(best, float(np.linalg.norm(self.c[j] - cx)))
        return best

    def nearest(self, o: Any, best: float = np.inf, bounds: tuple[np.ndarray, np.ndarray] | None = None
                ) -> tuple[float, int]:
        """(distance, index) of the box nearest to instance `o` among those nearer than `best` (+1e-9), ties the
        lowest index; (inf, -1) when none is. `o` itself (same object) is never its own partner. bounds: o's AABB
        centre and half extent [3], [3] when known."""
        if bounds is None:
            cx, ex = half_extents([o])
            cx, ex = cx[0], ex[0]
        else:
            cx, ex = bounds
        skip = self.pos.get(id(o), -1)
        if not np.isfinite(best):
            best = self.upper(cx, skip)
        cand = self.near(cx, float(np.linalg.norm(ex)), best)
        if skip >= 0:
            cand = cand[cand != skip]
        if not len(cand):
            return np.inf, -1
        lb = aabb_gaps(cx, ex, self.c[cand], self.e[cand])
        keep = lb <= best + 1e-9
        out_d, out_j = np.inf, -1
        for g, j in sorted(zip(lb[keep], cand[keep])):
            if g > out_d + 1e-9 or g > best + 1e-9:
                break
            d = box_distance(o.box, self.inst[int(j)].box)
            if d < out_d or (d == out_d and j < out_j):
                out_d, out_j = d, int(j)
        return out_d, out_j


def closest_pair(a: list[Any], b: list[Any] | BoxSet) -> tuple[float, Any, Any]:
    """(distance, x of a, y of b) of the closest pair of distinct instances (closest points of the solid boxes);
    ties: the first minimal pair in a x b order. Stops at the first touching pair. `b`: a list or its BoxSet.
    Unsupported when a and b are one single instance. When a is much larger than b the search runs from b's
    side (each y's nearest x), with the same answer."""
    bs = b if isinstance(b, BoxSet) else BoxSet(b)
    if len(a) > 4 * max(len(bs), 1) and len(a) > 64:
        return _closest_from_b(a, bs)
    ca, ea = half_extents(a)
    best, pair = np.inf, None
    for i, x in enumerate(a):
        d, j = bs.nearest(x, best, (ca[i], ea[i]))
        if j >= 0 and (d < best or pair is None):
            best, pair = d, (x, bs.inst[j])
        if pair is not None and best <= 0.0:  # touching: nothing later can be smaller
            break
    if pair is None:
        raise Unsupported("the two objects are the same single instance")
    return best, pair[0], pair[1]


def _closest_from_b(a: list[Any], bs: BoxSet) -> tuple[float, Any, Any]:
    aset = BoxSet(a)
    best: tuple[float, int, int] | None = None
    for j, y in enumerate(bs.inst):
        d, i = aset.nearest(y, best[0] if best is not None else np.inf, (bs.c[j], bs.e[j]))
        if i >= 0 and (best is None or (d, i, j) < best):
            best = (d, i, j)
    if best is None:
        raise Unsupported("the two objects are the same single instance")
    return best[0], a[best[1]], bs.inst[best[2]]


def nearest_values(a: list[Any], b: list[Any] | BoxSet, k: int, largest: bool = False) -> dict[int, float]:
    """{position in a: distance to its nearest box of b} for the k members of `a` whose nearest box is nearest
    (largest: farthest); members with no partner but themselves are left out. Members are visited in the order
    of a bound on that distance (its nearest centre) and the visit stops once no later one can enter the k."""
    bs = b if isinstance(b, BoxSet) else BoxSet(b)
    if not a or not len(bs):
        return {}
    ca, ea = half_extents(a)
    ra = np.linalg.norm(ea, axis=1)
    own = np.array([bs.pos.get(id(x), -1) for x in a])
    rows = np.arange(len(a))
    if bs.tree is None:  # a small set: the bounds of every pair (an instance is not its own partner)
        gaps = np.linalg.norm(np.maximum(np.abs(ca[:, None] - bs.c[None]) - ea[:, None] - bs.e[None], 0.0), axis=2)
        cd = np.linalg.norm(ca[:, None] - bs.c[None], axis=2)
        mine = own >= 0
        gaps[rows[mine], own[mine]] = np.inf
        cd[rows[mine], own[mine]] = np.inf
        lower, centre_d = gaps.min(1), cd.min(1)  # a lower and an upper bound of each one's nearest distance
    else:
        kk = min(2, len(bs.small))
        dd, jj = bs.tree.query(ca, k=kk)
        dd, jj = dd.reshape(len(a), kk), bs.small[jj.reshape(len(a), kk)]
        first_other = (jj[:, 0] == own).astype(int) if kk > 1 else np.zeros(len(a), int)
        centre_d = np.where((jj[:, 0] == own) & (kk == 1), np.inf, dd[rows, first_other])
        lower = np.maximum(centre_d - ra - bs.rmax, 0.0)
        for j in bs.large:  # the large boxes: their exact bounds
            gap = aabb_gaps(bs.c[j], bs.e[j], ca, ea)
            cdj = np.linalg.norm(ca - bs.c[j], axis=1)
            gap[own == j], cdj[own == j] = np.inf, np.inf
            lower, centre_d = np.minimum(lower, gap), np.minimum(centre_d, cdj)
    key = -centre_d if largest else lower
    order = sorted(range(len(a)), key=lambda i: (key[i], i))
    got: dict[int, float] = {}
    for i in order:
        if len(got) >= k:
            kth = sorted(got.values(), reverse=largest)[k - 1]
            if (largest and centre_d[i] < kth - 1e-9) or (not largest and (lower[i] > kth + 1e-9 or kth <= 0.0)):
                break  # (a later one at distance 0 would come after these in list order too)
        d, j = bs.nearest(a[i], np.inf, (ca[i], ea[i]))
        if j >= 0:
            got[i] = d
    ranked = sorted(got, key=lambda i: (-got[i] if largest else got[i], i))[:k]
    return {i: got[i] for i in ranked}


def k_nearest(o: Any, bs: BoxSet, k: int, allow: np.ndarray | None = None) -> list[tuple[float, int]]:
    """The k boxes of the set nearest to `o` as (distance, index), ties the lowest index; `allow` [len] bool:
    only those may be returned. Candidates in the order of their bound; exact distances until the k-th is no
    farther than the next bound (the search radius grows from the k nearest centres)."""
    cx, ex = half_extents([o])
    cx, ex, rx = cx[0], ex[0], float(np.linalg.norm(ex[0]))
    skip = bs.pos.get(id(o), -1)
    ok = np.ones(len(bs), bool) if allow is None else np.asarray(allow, bool).copy()
    if skip >= 0:
        ok[skip] = False
    if not ok.any():
        return []
    radius = 0.5
    if bs.tree is not None:
        dd, _ = bs.tree.query(cx, k=min(len(bs.small), k + 1))
        radius = max(float(np.max(dd)), 1e-3)
    span = float(np.linalg.norm(bs.c.max(0) - bs.c.min(0))) + 2 * rx + 2 * bs.rmax + 1.0
    exact: dict[int, float] = {}
    while True:  # grow the search until k exact distances are no farther than any bound left
        cand = bs.near(cx, rx, radius)
        cand = cand[ok[cand]] if len(cand) else cand
        lb = aabb_gaps(cx, ex, bs.c[cand], bs.e[cand]) if len(cand) else np.zeros(0)
        done = False
        for g, j in sorted(zip(lb, cand)):
            got = sorted((d, i) for i, d in exact.items())
            if len(got) >= k and got[k - 1][0] < g - 1e-9:
                done = True
                break
            if g > radius:
                break  # beyond the radius the ball may miss boxes: widen it first
            if int(j) not in exact:
                exact[int(j)] = box_distance(o.box, bs.inst[int(j)].box)
        got = sorted((d, i) for i, d in exact.items())
        if done or radius >= span or (len(got) >= k and got[k - 1][0] <= radius):
            return got[:k]
        radius *= 2.0
