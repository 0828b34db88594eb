"""The floor plane: a RANSAC fit of the lowest large level surface in a point cloud (pure numpy, below every
stage: the map's gravity (`map.floor`) and the depth adapter's scale from a camera height (`models.depth`) share
this one fit)."""
from __future__ import annotations

import numpy as np


def fit_floor_plane(points: np.ndarray, down_hint: np.ndarray, max_tilt_deg: float = 35.0,
                    threshold: float = 0.03, iterations: int = 300, min_share: float = 0.05,
                    rng: int = 0, parallel_deg: float = 5.0, low_share: float = 0.01
                    ) -> tuple[np.ndarray, float, int] | None:
    """Find the floor: the lowest large level surface, its normal within `max_tilt_deg` of `down_hint`.

    points: [N, 3] in the root camera frame (or any frame); down_hint: [3] rough gravity (e.g. the camera's +y).
    Returns (down [3] unit normal pointing down, offset d with down·p = d on the plane, inliers) or None.
    1. RANSAC over 3-point planes (`_ransac_planes`); 2. the orientation: of the largest candidates that are
    real surfaces, the sharpest, then sharpened (`_reference_plane`): every level surface (floor, table and
    counter tops) shares the normal, the largest fixes it best; 3. the floor: the lowest layer along that
    normal (`_lowest_layer`): a dense height layer (a floor mostly hidden by furniture still fills one), or a
    lower RANSAC surface parallel to it (within `parallel_deg`, >= `min_share` of the points) measured along
    the reference normal — a lower plane's own tilt is not taken (a plane tilted through two levels collects
    inliers without being level); 4. a floor layer at least half the reference's size refines the normal on its
    own points (`_floor_normal`).
    """
    pts = np.asarray(points, dtype=np.float64)
    if len(pts) < 50:
        return None
    hint = np.asarray(down_hint, float) / np.linalg.norm(down_hint)
    cos_max = np.cos(np.radians(max_tilt_deg))
    cands = _ransac_planes(pts, hint, cos_max, threshold, iterations, np.random.default_rng(rng))
    ref = _reference_plane(pts, cands, hint, cos_max, threshold) if cands else None
    if ref is None:
        return None
    low = _lowest_layer(pts, ref, cands, hint, cos_max, threshold, min_share, parallel_deg, low_share)
    return _floor_normal(pts, ref, low, threshold)


def _ransac_planes(pts: np.ndarray, hint: np.ndarray, cos_max: float, threshold: float, iterations: int,
                   g: np.random.Generator) -> list[tuple[int, np.ndarray, float]]:
    """(inliers, normal [3] towards `hint`, offset) of random 3-point planes within the tilt limit, largest
    first."""
    cands: list[tuple[int, np.ndarray, float]] = []
    for _ in range(iterations):
        a, b, c = pts[g.choice(len(pts), 3, replace=False)]
        n = np.cross(b - a, c - a)
        nn = np.linalg.norm(n)
        if nn < 1e-9:
            continue
        n /= nn
        if n @ hint < 0:
            n = -n
        if n @ hint < cos_max:
            continue
        d = float(n @ a)
        cands.append((int(np.sum(np.abs(pts @ n - d) < threshold)), n, d))
    cands.sort(key=lambda c: -c[0])
    return cands


def _refit_plane(pts: np.ndarray, n: np.ndarray, d: float, hint: np.ndarray, cos_max: float, threshold: float
                 ) -> tuple[np.ndarray, float, int, bool]:
    """Least squares on the inliers, inliers of the refit, ... (a few rounds converge) -> (normal, offset,
    inliers, is a surface): the inliers' own normal agrees and they spread in two directions (a slanted plane
    cutting through vertical cabinet fronts collects a thin band, not a surface)."""
    n2, d2 = n, d
    for _ in range(3):
        inl = np.abs(pts @ n2 - d2) < threshold
        q = pts[inl]
        if len(q) < 3:
            return n, d, 0, False
        cq = q.mean(0)
        _, sv, vt = np.linalg.svd(q - cq, full_matrices=False)
        n2 = vt[2] if vt[2] @ hint > 0 else -vt[2]
        d2 = float(n2 @ cq)
    surface = bool(n2 @ n > np.cos(np.radians(8.0)) and sv[1] > 0.25 * sv[0] and n2 @ hint >= cos_max)
    return n2, d2, int(inl.sum()), surface


def _reference_plane(pts: np.ndarray, cands: list[tuple[int, np.ndarray, float]], hint: np.ndarray,
                     cos_max: float, threshold: float) -> tuple[np.ndarray, float, int] | None:
    """The orientation reference: of the 10 largest candidates that are surfaces, the sharpest (a slightly
    tilted plane through two levels, a table top near and a counter top far, collects as many inliers as the
    level one, but its points do not share one height), its normal sharpened (no least-squares refit after it:
    that is what tilts). (normal, height of its fullest layer, inliers)."""
    ref, best = None, -1
    for cnt, n, d in cands[:10]:
        r = _refit_plane(pts, n, d, hint, cos_max, threshold)
        if not r[3]:
            continue
        sharp = int(np.sum(np.abs(pts @ r[0] - r[1]) < threshold / 3))
        if sharp > best:
            ref, best = r, sharp
    if ref is None:
        return None
    n_sharp = sharpen_normal(pts, ref[0])
    h_ref = float(_peak_height(pts @ n_sharp)[0])
    return n_sharp, h_ref, int(np.sum(np.abs(pts @ n_sharp - h_ref) < threshold))


def _lowest_layer(pts: np.ndarray, ref: tuple[np.ndarray, float, int], cands: list[tuple[int, np.ndarray, float]],
                  hint: np.ndarray, cos_max: float, threshold: float, min_share: float, parallel_deg: float,
                  low_share: float) -> tuple[float, int]:
    """(height along the reference normal, points) of the floor: the lowest dense layer along the reference
    normal (a floor seen past the furniture holds few points, random 3-point samples rarely land on it, but
    nothing lies below it), or a lower RANSAC surface parallel to the reference, measured along the reference
    normal and kept only where its points form a layer there (>= `min_share` of all)."""
    n = ref[0]
    h = pts @ n
    lowest = (ref[1], ref[2])
    bins = np.arange(ref[1] + threshold, h.max() + 2 * threshold, 2 * threshold)
    if len(bins) > 1:
        cnt, edges = np.histogram(h, bins=bins)
        dense = np.nonzero(cnt >= max(low_share * len(pts), 0.1 * ref[2], 50))[0]
        if len(dense):
            k = dense[-1]  # farthest along `down`
            hk = h[(h >= edges[k]) & (h < edges[k + 1])]
            lowest = (float(np.median(hk)), int(len(hk)))
    cos_par = np.cos(np.radians(parallel_deg))
    for cnt, m, d in cands:
        if cnt < max(min_share * len(pts), 0.2 * ref[2]) or m @ n < cos_par or d <= lowest[0] + threshold:
            continue
        r = _refit_plane(pts, m, d, hint, cos_max, threshold)
        if not (r[3] and r[0] @ n >= cos_par):
            continue
        inl = np.abs(pts @ r[0] - r[1]) < threshold
        hc, _ = _peak_height(h[inl])
        k = int(np.sum(np.abs(h - hc) < threshold))
        if k >= min_share * len(pts) and hc > lowest[0] + threshold:
            lowest = (hc, k)
    return _nothing_below(h, lowest, threshold)


def _nothing_below(h: np.ndarray, lowest: tuple[float, int], threshold: float, max_below: float = 0.005,
                   layer_share: float = 0.002) -> tuple[float, int]:
    """Nothing lies below the floor: when more than `max_below` of the heights h [N] lie beyond the layer
    found (it is a table or counter top; the floor was seen only past the furniture), the floor is the
    farthest 2 x `threshold` height layer holding >= `layer_share` of the points (a surface, not scattered
    flying pixels); unchanged when there is none."""
    if np.mean(h > lowest[0] + 2 * threshold) <= max_below:
        return lowest
    bins = np.arange(lowest[0] + threshold, h.max() + 2 * threshold, 2 * threshold)
    if len(bins) < 2:
        return lowest
    cnt, edges = np.histogram(h, bins=bins)
    full = np.nonzero(cnt >= max(layer_share * len(h), 30))[0]
    if not len(full):
        return lowest
    k = full[-1]
    hk = h[(h >= edges[k]) & (h < edges[k + 1])]
    return float(np.median(hk)), int(len(hk))


def _floor_normal(pts: np.ndarray, ref: tuple[np.ndarray, float, int], low: tuple[float, int], threshold: float
                  ) -> tuple[np.ndarray, float, int]:
    """(down, offset, inliers): the reference normal at the floor's height; a floor layer at least half the
    reference's size sharpens the normal on its own points (the floor itself is then the best level surface)."""
    n, (h, cnt) = ref[0], low
    if low[0] > ref[1] + threshold and cnt >= 0.5 * ref[2]:
        layer = pts[np.abs(pts @ n - h) < 3 * threshold]
        if len(layer) >= 50:
            n = sharpen_normal(layer, n, span_deg=3.0)
            h = float(_peak_height(layer @ n)[0])
            cnt = int(np.sum(np.abs(pts @ n - h) < threshold))
    return n, h, cnt


def _peak_height(h: np.ndarray, bin_m: float = 0.01) -> tuple[float, int]:
    """(height, count) of the fullest `bin_m` layer of heights h [N]."""
    lo = float(h.min())
    k = np.floor((h - lo) / bin_m).astype(np.int64)
    cnt = np.bincount(k)
    j = int(np.argmax(cnt))
    return lo + (j + 0.5) * bin_m, int(cnt[j])


def sharpen_normal(points: np.ndarray, n0: np.ndarray, span_deg: float = 8.0, step_deg: float = 0.5,
                   max_points: int = 20000) -> np.ndarray | None:
    """The normal [3] within `span_deg` of n0 whose height histogram has the fullest 1 cm layer: a level
    surface puts all its points at one height, a plane tilted to pass through two levels (table near, counter
    far) does not. Coarse-to-fine grid over two tilt angles."""
    pts = points[:: max(1, len(points) // max_points)]
    n0 = np.asarray(n0, float) / np.linalg.norm(n0)
    a = np.cross(n0, [1.0, 0, 0] if abs(n0[0]) < 0.9 else [0, 1.0, 0])
    a /= np.linalg.norm(a)
    b = np.cross(n0, a)
    best, best_n = _peak_height(pts @ n0)[1], n0
    centre, span = (0.0, 0.0), span_deg
    while span >= step_deg:
        g = np.radians(np.linspace(-span, span, 9))
        for u in g + np.radians(centre[0]):
            for v in g + np.radians(centre[1]):
                n = n0 + np.tan(u) * a + np.tan(v) * b
                n /= np.linalg.norm(n)
                c = _peak_height(pts @ n)[1]
                if c > best:
                    best, best_n, cu, cv = c, n, np.degrees(u), np.degrees(v)
                    centre = (cu, cv)
        span /= 4
    return best_n
