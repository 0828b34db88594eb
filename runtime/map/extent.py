"""The built map's extents: floor-standing objects seen from above reach down to the floor unless open space was
seen under them; the room is the hull of what the key frames' depth saw; first-seen times from every frame the
key-frame search scored."""
from __future__ import annotations

from typing import Iterable, Sequence

import numpy as np

from ..geometry import OrientedBox, convex_hull_2d
from ..infra.trace import StageLog, as_trace
from ..types import Frame
from .lift import world_points
from .model import ObjectInstance, Room


def band_visibility(box: OrientedBox, views: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray]], band_m: float = 0.10,
                    grid: int = 5, tol_m: float = 0.04, tol_rel: float = 0.02) -> np.ndarray:
    """What the key cameras saw of each `band_m` height band between the floor (z = 0) and a gravity-aligned box's
    bottom, inside its footprint (shrunk to 80 %: the edges touch neighbours): [n_bands, 3] shares of sample
    points (a `grid` x `grid` x 2 lattice per band) that are seen EMPTY (some camera's depth along the ray lies
    beyond the point and none has a surface at it), seen a SURFACE (some depth within tolerance of it), or
    UNKNOWN (every camera that has it in view sees something nearer — the table in front of a chair's seat —
    or none has it in view). views: (depth [H, W] z-depth m, K [3, 3], T_wc [4, 4]). Pure."""
    ax = np.asarray(box.axes, np.float64)
    up = int(np.argmax(np.abs(ax[:, 2])))
    L, c = np.asarray(box.axes_lengths, np.float64), np.asarray(box.centroid, np.float64)
    bottom = c[2] - L[up] / 2
    n = max(1, int(np.ceil(bottom / band_m - 1e-9)))
    side = [k for k in range(3) if k != up]
    g = (np.arange(grid) + 0.5) / grid - 0.5
    uu, vv = np.meshgrid(g * 0.8 * L[side[0]], g * 0.8 * L[side[1]])
    foot = c[None, :2] + uu.reshape(-1, 1) * ax[side[0], :2] + vv.reshape(-1, 1) * ax[side[1], :2]
    edges = np.linspace(0.0, bottom, n + 1)
    zs = np.stack([edges[:-1] + f * (edges[1:] - edges[:-1]) for f in (0.25, 0.75)], 1)  # [n, 2]
    pts = np.array([[x, y, z] for b in range(n) for z in zs[b] for x, y in foot])
    band = np.repeat(np.arange(n), 2 * len(foot))
    through, hit = np.zeros(len(pts), bool), np.zeros(len(pts), bool)
    for depth, K, T_wc in views:
        Tcw = np.linalg.inv(np.asarray(T_wc, np.float64))
        pc = pts @ Tcw[:3, :3].T + Tcw[:3, 3]
        z = pc[:, 2]
        ok = z > 0.1
        u = np.full(len(pts), -1, np.int64)
        v = np.full(len(pts), -1, np.int64)
        u[ok] = np.round(K[0, 0] * pc[ok, 0] / z[ok] + K[0, 2]).astype(np.int64)
        v[ok] = np.round(K[1, 1] * pc[ok, 1] / z[ok] + K[1, 2]).astype(np.int64)
        H, W = depth.shape
        ok &= (u >= 0) & (u < W) & (v >= 0) & (v < H)
        d = np.zeros(len(pts))
        d[ok] = depth[v[ok], u[ok]]
        ok &= np.isfinite(d) & (d > 0)
        tol = tol_m + tol_rel * z
        through |= ok & (d > z + tol)
        hit |= ok & (np.abs(d - z) <= tol)
    empty = through & ~hit
    out = np.zeros((n, 3))
    for b in range(n):
        sel = band == b
        out[b] = [empty[sel].mean(), hit[sel].mean(), (~empty[sel] & ~hit[sel]).mean()]
    return out


def floor_decision(share: float, lowest: bool, vis: np.ndarray, support: np.ndarray, band_share: float,
                   empty_share: float) -> tuple[bool, str]:
    """Extend a floor-standing box to the floor? Yes when support is seen under it (points in >= `band_share`
    of the bands, the lowest included), or when no band is seen empty: a band without support points whose
    sample points are seen empty in >= `empty_share` blocks it; a band hidden by something nearer (unknown) does
    not. support: [n_bands] bool (points in the band). Returns (extend, why). Pure."""
    if share >= band_share and lowest:
        return True, "support"
    empty = [b for b in range(len(vis)) if not support[b] and vis[b, 0] >= empty_share]
    if empty:
        return False, f"seen empty: bands {empty}"
    return True, f"hidden: {int(np.sum(vis[:, 2] > 0.5))} of {len(vis)} band(s) unknown, none seen empty"


def floor_support(box: OrientedBox, P: np.ndarray, band_m: float = 0.10, min_points: int = 3) -> tuple[float, bool]:
    """Support under a gravity-aligned box: of the `band_m` height bands between the floor (z = 0) and the box
    bottom, the share holding >= min_points of P [N, 3] inside the box's footprint, and whether the lowest band
    does. Pure."""
    hist = _band_counts(box, P, band_m)
    if hist is None:
        return 0.0, False
    return float(np.mean(hist >= min_points)), bool(hist[0] >= min_points)


def _band_counts(box: OrientedBox, P: np.ndarray, band_m: float) -> np.ndarray | None:
    """Points of P [N, 3] inside the box's footprint per `band_m` band below it (None: no room below)."""
    ax = np.asarray(box.axes, np.float64)
    up = int(np.argmax(np.abs(ax[:, 2])))
    L, c = np.asarray(box.axes_lengths, np.float64), np.asarray(box.centroid, np.float64)
    bottom = c[2] - L[up] / 2
    if bottom <= 0 or len(P) == 0:
        return None
    side = [k for k in range(3) if k != up]
    local = (np.asarray(P, np.float64) - c) @ ax.T
    z = P[np.all(np.abs(local[:, side]) <= L[side] / 2, axis=1), 2]
    n = max(1, int(np.ceil(bottom / band_m - 1e-9)))
    return np.histogram(z[(z >= 0) & (z < bottom)], bins=np.linspace(0.0, bottom, n + 1))[0]


def extend_to_floor(instances: list[ObjectInstance], frames: Sequence[Frame], poses: dict[int, np.ndarray],
                    floor_standing: Sequence[str], band_share: float, log: StageLog | None = None, band_m: float = 0.10,
                    stride: int = 8, empty_share: float = 0.5, min_points: int = 3) -> list[int]:
    """A floor-standing object (a name in `floor_standing`) whose fused box stops above the floor (z = 0) — the
    top of a table seen from above, a chair's back over the table edge — gets its box extended down to the
    floor unless the key frames SAW open space under it (`floor_decision` on `band_visibility`): support seen
    (points in its footprint in >= `band_share` of the `band_m` bands, the lowest included) extends it; a band
    hidden from every camera by something nearer counts as unknown, not as empty; a band without points seen
    empty (depth beyond it along the rays) keeps the box as fused. Mutates the boxes; recorded (extended and
    kept, with why). Returns the ids extended."""
    todo = [o for o in instances if o.name in floor_standing]
    if not todo:
        return []
    pts = world_points(frames, poses, stride)
    P = np.concatenate(pts) if pts else np.zeros((0, 3))
    P = P[P[:, 2] > 0.5 * band_m / 2]  # the floor's own points do not count as support
    views = [(f.depth, np.asarray(f.K, np.float64), poses[f.index]) for f in frames
             if f.index in poses and f.depth is not None]
    done, kept, why = [], {}, {}
    for o in todo:
        ax = np.asarray(o.box.axes, np.float64)
        up = int(np.argmax(np.abs(ax[:, 2])))
        if abs(ax[up, 2]) < 0.99:
            continue  # not a gravity-aligned box
        L = np.asarray(o.box.axes_lengths, np.float64)
        c = np.asarray(o.box.centroid, np.float64)
        if c[2] - L[up] / 2 < band_m:
            continue
        hist = _band_counts(o.box, P, band_m)
        hist = np.zeros(1, int) if hist is None else hist
        share, lowest = float(np.mean(hist >= min_points)), bool(hist[0] >= min_points)
        vis = band_visibility(o.box, views, band_m)
        ok, why[o.id] = floor_decision(share, lowest, vis, hist >= min_points, band_share, empty_share)
        if ok:
            top = c[2] + L[up] / 2
            L2, c2 = L.copy(), c.copy()
            L2[up], c2[2] = top, top / 2
            o.box = OrientedBox(c2, L2, ax)
            done.append(o.id)
        else:
            kept[o.id] = round(share, 2)
    as_trace(log).event("extent", f"{len(done)} floor-standing object(s) extended to the floor (support seen "
                          f"or hidden under them, no open space seen): {done}; {len(kept)} kept as fused (open "
                          f"space seen under them; support share per id): {kept}", stage="extent", extended=done,
                          kept=kept, why=why)
    return done


def room_extent(instances: list[ObjectInstance], cams: list[tuple[float, np.ndarray]], frames: Sequence[Frame] = (),
                poses: dict[int, np.ndarray] | None = None, trim: float = 0.5, max_depth_m: float = 8.0
                ) -> Room | None:
    """Room extent of a built map: the floor-projected hull of everything the aligned key frames' depth saw
    (walls, floor, furniture; depth in (0.1, `max_depth_m`) m, fusion's own limit), plus the object footprints
    and the camera track. Points beyond the `trim` percentile along any of 36 directions are dropped first
    (stray depth through doorways and windows). A convex hull: an L-shaped room is over-estimated, a room whose
    walls were never seen under-estimated."""
    pts = [o.box.corners()[:, :2] for o in instances] + [T[None, :2, 3] for _, T in cams]
    seen = [p[:, :2] for p in world_points(frames, poses or {}, 12,
                                            lambda p: (p[:, 2] > 0.1) & (p[:, 2] < max_depth_m))]
    source = "objects_and_camera_hull"
    if seen:
        S = np.concatenate(seen)
        if len(S) > 100:
            ang = np.linspace(0, np.pi, 36, endpoint=False)
            D = np.stack([np.cos(ang), np.sin(ang)], 1)
            proj = S @ D.T
            lo, hi = np.percentile(proj, trim, 0), np.percentile(proj, 100 - trim, 0)
            S = S[np.all((proj >= lo) & (proj <= hi), 1)]
            pts.append(S)
            source = "observed_depth_hull"
    if not pts:
        return None
    P = np.concatenate(pts)
    top = max([float(o.box.aabb()[1][2]) for o in instances] + [2.4])
    return Room(convex_hull_2d(hull_candidates(P)), 0.0, top, source)


def hull_candidates(P: np.ndarray, directions: int = 16) -> np.ndarray:
    """Points [N, 2] that may be convex-hull vertices (Akl-Toussaint): the extreme points in `directions`
    directions span a convex polygon; points clearly inside it (by more than 1e-9 of the extent) are dropped.
    The hull is unchanged, the Python monotone chain just sees far fewer points."""
    if len(P) < 64:
        return P
    ang = np.linspace(0, 2 * np.pi, directions, endpoint=False)
    D = np.stack([np.cos(ang), np.sin(ang)], 1)
    idx = np.unique(np.argmax(P @ D.T, 0))              # extreme points, ordered by direction below
    V = P[idx]
    c = V.mean(0)
    V = V[np.argsort(np.arctan2(V[:, 1] - c[1], V[:, 0] - c[0]))]
    if len(V) < 3:
        return P
    eps = 1e-9 * float(np.ptp(P, 0).max() + 1.0)
    inside = np.ones(len(P), bool)
    for a, b in zip(V, np.roll(V, -1, 0)):              # counter-clockwise: inside = left of every edge
        e = b - a
        nrm = float(np.hypot(*e))
        if nrm == 0:
            continue
        inside &= (e[0] * (P[:, 1] - a[1]) - e[1] * (P[:, 0] - a[0])) / nrm > eps
    return P[~inside]


def first_seen_from_detections(instances: list[ObjectInstance], detections: Iterable[tuple[float, Iterable[str]]],
                               log: StageLog | None = None) -> int:
    """The key-frame search ran the detector on many more frames than the key frames: a category detected
    (`detections`: (time s, names detected) per scored frame) earlier than any of its instances' key frames was
    first seen then. The earliest instance of the category takes that time (appearance-order questions are
    about categories). Mutates first_seen; returns how many changed (recorded when any)."""
    first: dict[str, float] = {}
    for t, seen in detections:
        for n in set(seen):
            first[n] = min(first.get(n, np.inf), float(t))
    changed = 0
    for n, t in first.items():
        inst = [o for o in instances if o.name == n and o.first_seen is not None]
        if inst:
            o = min(inst, key=lambda o: o.first_seen)
            if t < o.first_seen:
                o.first_seen, changed = t, changed + 1
    if changed:
        as_trace(log).decide("first_seen_from_search", changed)
    return changed
