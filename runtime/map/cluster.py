"""Point-cloud clean-up shared by lifting and fusion: exact connected components on a grid, voxel
down-sampling, outlier removal. Pure functions over [N, 3] arrays."""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np


# cell offsets d > 0 (lexicographically) of a 5x5x5 block: cells of side link_m / sqrt(3) this far apart can hold
# points within link_m of each other (d < 0 are the same pairs seen from the other cell); 13 touch, 49 do not
_OFFSETS = np.array([d for d in np.ndindex(5, 5, 5) if tuple(np.subtract(d, 2)) > (0, 0, 0)], np.int64) - 2


_TOUCHING = _OFFSETS[np.abs(_OFFSETS).max(1) == 1]


_FARTHER = _OFFSETS[np.abs(_OFFSETS).max(1) == 2]


def components(points: np.ndarray, link_m: float) -> np.ndarray:
    """Connected-component label [N] per point of `points [N, 3]` (points closer than `link_m` are linked);
    labels numbered by first point, as a connected-components pass over the point graph numbers them.

    Exact, without listing the point pairs (a 4000-point mask at 5 cm has ~150 k): on a grid of cells of side
    link_m / sqrt(3) every cell is one clique, so only cell pairs up to 2 cells apart can link. Touching cells
    are tested first; cells 2 apart only near another component's bounding box. A cell pair links for sure when
    its points' boxes are within link_m at their farthest corners or one point of each is, never when the boxes
    are farther apart; the rest (cells along a gap) are decided point by point, where they join two components.
    (A pair exactly link_m apart may round either way, as in any floating-point distance test.)"""
    n = len(points)
    if n == 0:
        return np.zeros(0, np.int64)
    keys = np.floor(points / (link_m / np.sqrt(3) * (1 - 1e-9))).astype(np.int64)
    keys -= keys.min(0) - 2  # a margin of 2 cells: neighbour keys never wrap into another row
    span = keys.max(0) + 3
    if float(span[0]) * float(span[1]) * float(span[2]) >= 2.0 ** 62:  # absurd extents: list the point pairs
        from scipy.spatial import cKDTree

        pr = cKDTree(points).query_pairs(link_m, output_type="ndarray")
        return _graph_labels(n, pr[:, 0], pr[:, 1])
    flat = (keys[:, 0] * span[1] + keys[:, 1]) * span[2] + keys[:, 2]
    order = np.argsort(flat, kind="stable")
    fs = flat[order]
    first = np.flatnonzero(np.r_[True, fs[1:] != fs[:-1]])
    nc = len(first)
    cell_of = np.empty(n, np.int64)
    cell_of[order] = np.repeat(np.arange(nc), np.diff(np.r_[first, n]))
    ps = points[order]
    grid = _Cells(fs[first], span, np.hstack([np.minimum.reduceat(ps, first, 0), np.maximum.reduceat(ps, first, 0)]),
                  ps[first], link_m * link_m)
    grid.index(n)
    a, b, sure = grid.pairs(np.arange(nc), _TOUCHING)
    lab = _graph_labels(nc, a[sure], b[sure])
    if lab.max() > 0:
        a2, b2, s2 = grid.pairs(grid.near_other(lab), _FARTHER)
        a, b, sure = np.r_[a, a2], np.r_[b, b2], np.r_[sure, s2]
        lab = _graph_labels(nc, a[sure], b[sure])
    open_ = ~sure & (lab[a] != lab[b])
    if open_.any():  # point pairs of the undecided cells only
        from scipy.spatial import cKDTree

        sel = np.flatnonzero(np.isin(cell_of, np.r_[a[open_], b[open_]]))
        pr = cKDTree(points[sel]).query_pairs(link_m, output_type="ndarray")
        ca, cb = cell_of[sel[pr[:, 0]]], cell_of[sel[pr[:, 1]]]
        x = lab[ca] != lab[cb]
        lab = _graph_labels(nc, np.r_[a[sure], ca[x]], np.r_[b[sure], cb[x]])
    pl = lab[cell_of]
    _, first_pt = np.unique(pl, return_index=True)
    return np.argsort(np.argsort(first_pt))[pl]


@dataclass
class _Cells:
    """Occupied grid cells of `components`: sorted flat keys [C], grid span [3], each cell's point box as
    lo|hi [C, 6], one point rep [C, 3] per cell, link distance squared."""

    keys: np.ndarray
    span: np.ndarray
    box: np.ndarray
    rep: np.ndarray
    r2: float
    lut: np.ndarray | None = None  # cell number by flat key (-1 = empty), when the grid is small enough

    # a dense key -> cell table replaces the binary search when it has at most this many entries per point (an
    # object's grid of 2.9 cm cells holds ~10-50 entries per point; a stray point metres away makes it sparse),
    # and never more than LUT_MAX entries (16 MB: a room-sized cloud searches)
    LUT_PER_POINT: ClassVar[int] = 64
    LUT_MAX: ClassVar[int] = 1 << 22

    def index(self, n_points: int) -> None:
        """Build the dense table (`lut`) when the grid span is small next to the point count."""
        size = int(np.prod(self.span.astype(np.float64)))
        if size <= min(self.LUT_PER_POINT * max(n_points, 1024), self.LUT_MAX):
            self.lut = np.full(size, -1, np.int32)  # (fewer cells than entries: int32 holds them)
            self.lut[self.keys] = np.arange(len(self.keys))

    def find(self, nb: np.ndarray) -> np.ndarray:
        """Cell number of each flat key in `nb` (any shape; keys inside the grid span), -1 where no cell."""
        if self.lut is not None:
            return self.lut[nb]
        j = np.searchsorted(self.keys, nb).clip(0, len(self.keys) - 1)
        return np.where(self.keys[j] == nb, j, -1)

    def pairs(self, src: np.ndarray, offsets: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Cell pairs (a from `src`, b = a + offset) whose boxes are within link distance, and which of them
        link for sure -> (a [P], b [P], sure [P])."""
        step = (offsets[:, 0] * self.span[1] + offsets[:, 1]) * self.span[2] + offsets[:, 2]
        j = self.find(self.keys[src][None, :] + step[:, None])
        hit = j >= 0
        a, b = np.broadcast_to(src, j.shape)[hit], j[hit]
        ba, bb = self.box[a], self.box[b]
        gap = np.maximum(0, np.maximum(bb[:, :3] - ba[:, 3:], ba[:, :3] - bb[:, 3:]))
        near = np.einsum("ij,ij->i", gap, gap) <= self.r2
        a, b, ba, bb = a[near], b[near], ba[near], bb[near]
        far, d = np.maximum(bb[:, 3:] - ba[:, :3], ba[:, 3:] - bb[:, :3]), self.rep[a] - self.rep[b]
        return a, b, (np.einsum("ij,ij->i", far, far) <= self.r2) | (np.einsum("ij,ij->i", d, d) <= self.r2)

    def near_other(self, lab: np.ndarray) -> np.ndarray:
        """Cells within link distance of the bounding box of a component (label `lab [C]`) other than their own:
        only these can link two components (all cells when there are very many components)."""
        L = int(lab.max()) + 1
        if L * len(lab) > 1_000_000:
            return np.arange(len(lab))
        order = np.argsort(lab, kind="stable")
        starts = np.flatnonzero(np.r_[True, np.diff(lab[order]) != 0])
        clo = np.minimum.reduceat(self.box[order, :3], starts, 0)
        chi = np.maximum.reduceat(self.box[order, 3:], starts, 0)
        gap = np.maximum(0, np.maximum(clo[None] - self.box[:, None, 3:], self.box[:, None, :3] - chi[None]))
        close = np.einsum("ckj,ckj->ck", gap, gap) <= self.r2  # [C, L]
        close[np.arange(len(lab)), lab] = False
        return np.flatnonzero(close.any(1))


def _graph_labels(n: int, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Connected-component label [n] (0 .. count - 1) of the undirected graph with edges (a[k], b[k]): min-label
    hooking of the roots, then pointer jumping, until every edge joins one root (no sparse matrix: ~4x faster
    than scipy's connected_components on the few-thousand-edge graphs of `components`)."""
    lab = np.arange(n)
    while True:
        la, lb = lab[a], lab[b]
        if np.array_equal(la, lb):
            break
        m = np.minimum(la, lb)
        np.minimum.at(lab, la, m)
        np.minimum.at(lab, lb, m)
        while True:
            nxt = lab[lab]
            if np.array_equal(nxt, lab):
                break
            lab = nxt
    # every label is now a root (lab[r] == r, the smallest node of its component): number the roots in order,
    # as np.unique(lab, return_inverse=True) would, without its sort
    root = lab == np.arange(n)
    return (np.cumsum(root) - 1)[lab]


def largest_components(points: np.ndarray, link_m: float = 0.05, min_share: float = 0.2) -> np.ndarray:
    """The largest connected part of `points [N, 3]` and the parts with >= `min_share` of its points."""
    if len(points) < 3:
        return points
    lab = components(points, link_m)
    cnt = np.bincount(lab)
    return points[cnt[lab] >= min_share * cnt.max()]


def voxel_downsample(points: np.ndarray, voxel: float) -> np.ndarray:
    """One point (the mean) per occupied voxel. points: [N, 3] -> [M, 3]."""
    if len(points) == 0:
        return points
    keys = np.floor(points / voxel).astype(np.int64)
    keys -= keys.min(0)
    span = keys.max(0) + 1
    if float(span[0]) * float(span[1]) * float(span[2]) < 2.0 ** 62:
        # one int64 per voxel, in the same (lexicographic) order as the rows: a 1-D unique is ~10x faster
        flat = (keys[:, 0] * span[1] + keys[:, 1]) * span[2] + keys[:, 2]
        _, inv = np.unique(flat, return_inverse=True)
    else:  # absurd extents (stray points kilometres away): rows
        _, inv = np.unique(keys, axis=0, return_inverse=True)
    inv = inv.reshape(-1)
    n = int(inv.max()) + 1
    sums = np.stack([np.bincount(inv, points[:, j], n) for j in range(3)], 1)
    cnt = np.bincount(inv, minlength=n).astype(np.float64)
    return sums / cnt[:, None]


def remove_outliers(points: np.ndarray, k: float, radius: float | None = None, min_neighbors: int = 3
                    ) -> np.ndarray:
    """Outlier removal for one instance's points [N, 3] -> [M, 3].

    1. density (when `radius` is given): drop points with fewer than `min_neighbors` other points within
       `radius` (isolated flying pixels at depth edges); thin parts such as table legs are lines of neighbouring
       voxels and survive;
    2. radial: keep points within median + k * 1.4826 * MAD of the distance to the median point (far-flung
       clusters, e.g. a mask that bled onto the wall behind).
    """
    if len(points) < 8:
        return points
    if radius is not None:
        from scipy.spatial import cKDTree

        # the min_neighbors-th other point within radius (<= radius, as a ball count): a k-NN query stops at k
        # points where counting the ball visits all ~20 neighbours of a voxel cloud
        kth = cKDTree(points).query(points, k=min_neighbors + 1, distance_upper_bound=np.nextafter(radius, np.inf))[0]
        dense = np.isfinite(kth.reshape(len(points), -1)[:, -1])
        if dense.sum() >= 8:
            points = points[dense]
    c = np.median(points, 0)
    r = np.linalg.norm(points - c, axis=1)
    med = np.median(r)
    mad = np.median(np.abs(r - med)) + 1e-9
    return points[r <= med + k * 1.4826 * mad]
