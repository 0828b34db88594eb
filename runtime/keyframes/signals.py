"""Cheap per-candidate signals of the key-frame search (no detector call): edge density and view change (the
content axis the search measures distances along), colour-histogram similarity (the kernels' widths)."""
from __future__ import annotations

from typing import Callable, MutableMapping, Sequence

import cv2
import numpy as np

from ..scan import colour_histogram
from .conf import KeyFrameConf

ImageFn = Callable[[int], np.ndarray]


def edge_density(rgb: np.ndarray, size: int = 64) -> float:
    """Share of edge pixels (Canny 50/150) in a `size`-wide grey copy of `rgb` [H, W, 3] uint8: how much a view
    could show. A blank wall, floor or ceiling has almost none; any object adds outlines."""
    h, w = rgb.shape[:2]
    g = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2GRAY) if rgb.ndim == 3 else rgb
    if w > size:
        g = cv2.resize(g, (size, max(1, round(h * size / w))), interpolation=cv2.INTER_AREA)
    return float((cv2.Canny(g, 50, 150) > 0).mean())


def grey_thumbnail(rgb: np.ndarray, size: int = 32) -> np.ndarray:
    """A `size`-wide grey float32 copy of `rgb` [H, W, 3] uint8 (or of a grey [H, W] image) minus its mean (an
    exposure change is not a view change): what `view_change` compares."""
    h, w = rgb.shape[:2]
    g = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2GRAY) if rgb.ndim == 3 else np.asarray(rgb)
    g = cv2.resize(g, (size, max(1, round(h * size / w))), interpolation=cv2.INTER_AREA).astype(np.float32)
    return g - g.mean()


def view_change(thumbs: Sequence[np.ndarray]) -> np.ndarray:
    """[M] how fast the view changes at each candidate: the mean absolute difference of its `grey_thumbnail`
    to the previous and to the next candidate's, averaged (an end: its one neighbour). Where the camera pans
    every frame shows something new and an object stays in view for a few frames only; where it lingers one
    frame stands for its neighbours. Thumbnails of different shapes are resized to the first one's."""
    m = len(thumbs)
    if m < 2:
        return np.zeros(m)
    shape = thumbs[0].shape
    t = np.stack([g if g.shape == shape else cv2.resize(g, (shape[1], shape[0]), interpolation=cv2.INTER_AREA)
                  for g in thumbs]).astype(np.float32)
    step = np.abs(t[1:] - t[:-1]).reshape(m - 1, -1).mean(1).astype(np.float64)  # [M-1] between neighbours
    out = np.empty(m)
    out[0], out[-1] = step[0], step[-1]
    out[1:-1] = 0.5 * (step[1:] + step[:-1])
    return out


def content_axis(density: np.ndarray, floor: float = 0.1, change: np.ndarray | None = None,
                 power: float = 1.0) -> np.ndarray:
    """Candidate coordinates [M] for the search: cumulative content, each candidate's step = its edge density
    (times (`change` / its mean) ** `power` when a `view_change` is given: how much *new* content the view
    brings) / the mean of that + `floor` (so an empty view still takes a little room), rescaled to a mean step
    of 1 (x[0] = 0, x[-1] = M - 1; all equal steps give the candidate index). Exploration that is even along
    this axis spends the detector where the views show something new, instead of evenly in time."""
    d = np.asarray(density, np.float64)
    m = d.size
    if m < 2:
        return np.zeros(m)
    if change is not None and power > 0:
        c = np.asarray(change, np.float64)
        d = d * (c / c.mean()) ** power if c.mean() > 0 else d
    mean = d.mean()
    step = (d / mean if mean > 0 else np.ones(m)) + floor
    mid = 0.5 * (step[1:] + step[:-1])  # the distance between neighbours: half of each one's share
    x = np.concatenate([[0.0], np.cumsum(mid)])
    return x * (m - 1) / x[-1]


def histogram_similarity(h1: np.ndarray, h2: np.ndarray) -> float:
    """Histogram intersection of two L1-normalised histograms: 1 = same colour distribution, 0 = disjoint."""
    return float(cv2.compareHist(h1, h2, cv2.HISTCMP_INTERSECT))


class _HistogramCache:
    """Colour histograms of candidates, computed on first use only (`store`: frame index -> histogram, may be
    shared between searches over the same video)."""

    def __init__(self, candidates: np.ndarray, image: ImageFn, conf: KeyFrameConf,
                 store: MutableMapping[int, np.ndarray] | None = None) -> None:
        self.candidates, self.image, self.conf = candidates, image, conf
        self.store: MutableMapping[int, np.ndarray] = {} if store is None else store

    def __call__(self, pos: int) -> np.ndarray:
        f = int(self.candidates[pos])
        if f not in self.store:
            self.store[f] = colour_histogram(self.image(f), self.conf.hist_bins, self.conf.hist_size)
        return self.store[f]

    def neighbour_similarity(self, pos: int) -> float:
        """Mean similarity of candidate `pos` to the candidates within +-r (0 when it has none)."""
        r, m = self.conf.r, len(self.candidates)
        nb = [j for j in range(pos - r, pos + r + 1) if j != pos and 0 <= j < m]
        if not nb:
            return 0.0
        h = self(pos)
        return float(np.mean([histogram_similarity(h, self(j)) for j in nb]))
