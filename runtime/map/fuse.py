"""Fusion (paper: iterative construction): observations of one name that overlap in 3D (or share a centre)
become one instance; outliers removed; gravity-aligned oriented boxes fitted (yaw from the floor-projected points).
One frame's group and duplicate boxes of one object are left out first."""
from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from ..geometry import OrientedBox, box_footprint, fit_gravity_box, local_f32, polygon_area, worker_threads
from ..infra.progress import phase
from ..infra.trace import StageLog, as_trace
from ..types import Detections, Frame, Observation
from .cluster import remove_outliers, voxel_downsample
from .conf import FusionConfig, default_fusion_conf
from .lift import lift_detections, place
from .model import ObjectInstance


@dataclass
class _Acc:
    name: str
    points: np.ndarray
    score: float
    first_seen: float
    frames: list[int]
    hints: list[int]
    views: list[tuple[int, float, np.ndarray]] = field(default_factory=list)  # (frame, score, points) per detection
    boxes2d: dict[int, np.ndarray] = field(default_factory=dict)  # frame -> its detection's image box [4]

    _memo: tuple[np.ndarray, dict[str, Any]] | None = field(default=None, repr=False, compare=False)

    def _cached(self) -> dict[str, Any]:
        """Per-points memo (KD-tree, centre, radius), rebuilt only when `points` is replaced (after a merge)."""
        if self._memo is None or self._memo[0] is not self.points:
            self._memo = (self.points, {})
        return self._memo[1]

    def tree(self) -> Any:
        m = self._cached()
        if "tree" not in m:
            from scipy.spatial import cKDTree

            m["tree"] = cKDTree(self.points)
        return m["tree"]

    def centre(self) -> np.ndarray:
        m = self._cached()
        if "centre" not in m:
            m["centre"] = np.median(self.points, 0)
        return m["centre"]

    def radius(self) -> float:
        m = self._cached()
        if "radius" not in m:
            m["radius"] = float(np.percentile(np.linalg.norm(self.points - self.centre(), axis=1), 90))
        return m["radius"]


def same_frame_redundant(observations: list[Observation], radius_m: float, share: float = 0.5
                         ) -> dict[int, str]:
    """Observations (by index) that one frame holds twice, among that frame's detections of the same name (not
    refinement's `recovered` views), with
    why: a `group` box — its points cover (>= `share` within `radius_m`) two or more of the frame's other
    detections that do not cover each other (the detector's union box of two side-by-side objects) — or a
    `duplicate` — its points lie (>= `share`) on a higher-scored detection's (a box NMS left inside another box of
    the same object). Objects in front of one another have points at other depths: both kept. Pure."""
    from scipy.spatial import cKDTree

    groups: dict[tuple[int, str], list[int]] = {}
    for i, ob in enumerate(observations):
        if not ob.recovered:  # the detector's repeats; refinement's prompted views are not detections
            groups.setdefault((ob.frame, ob.name), []).append(i)
    out: dict[int, str] = {}
    for idx in groups.values():
        if len(idx) < 2:
            continue
        pts = [voxel_downsample(observations[i].points, radius_m / 2) for i in idx]
        trees = [cKDTree(p) for p in pts]
        cov = np.array([[1.0 if a == b else float(np.mean(np.isfinite(
            trees[a].query(pts[b], distance_upper_bound=radius_m)[0]))) for b in range(len(idx))]
            for a in range(len(idx))])  # cov[a, b]: share of b's points near a's
        for a in range(len(idx)):
            inner = [b for b in range(len(idx)) if b != a and cov[a, b] >= share]
            if any(cov[x, y] < share and cov[y, x] < share for x in inner for y in inner if x < y):
                out[idx[a]] = "group"
        for a in range(len(idx)):
            if idx[a] in out:
                continue
            for b in sorted(range(len(idx)), key=lambda b: -observations[idx[b]].score):
                if b != a and idx[b] not in out and cov[b, a] >= share and \
                        (observations[idx[b]].score, -b) > (observations[idx[a]].score, -a):
                    out[idx[a]] = "duplicate"
                    break
    return out


def fuse_observations(observations: list[Observation], conf: FusionConfig = default_fusion_conf,
                      log: StageLog | None = None) -> tuple[list[ObjectInstance], list[np.ndarray]]:
    """Fuse observations into instances (same name + 3D overlap or close centres), remove outliers and fit
    gravity-aligned oriented boxes (yaw from floor-projected points).

    Returns the instances and their fused point clouds ([M, 3] each, same order).
    Two observations of one name merge when >= `merge_overlap` of the new points lie within `merge_radius_m`
    of the instance's points, or when the centres are closer than `merge_centre_m` and than the larger of the
    two radii (an object seen from two sides overlaps little but shares its centre). One frame's group boxes and
    duplicate boxes of one object (`same_frame_redundant`) are left out first (the trace's `fusion` event); every
    other pair of one frame's detections stays two instances.
    """
    if conf.same_frame_share > 0:
        # one frame, one depth image: a box repeating another holds the very same surface points, so the radius is
        # the voxel size (two small objects a few cm apart do not cover each other)
        drop = same_frame_redundant(observations, conf.voxel_m, conf.same_frame_share)
        if drop:
            as_trace(log).event("fusion", f"fusion: left out {len(drop)} detection(s) that repeat others of their "
                                  f"frame: " + ", ".join(f"{observations[i].name} in frame {observations[i].frame} "
                                                         f"({why})" for i, why in sorted(drop.items())),
                                  stage="fusion", dropped=[{"frame": observations[i].frame, "name": observations[i].name,
                                                            "why": why} for i, why in sorted(drop.items())])
            observations = [o for i, o in enumerate(observations) if i not in drop]
    accs: list[_Acc] = []
    for ob in sorted(observations, key=lambda o: (o.t, o.frame, -o.score)):
        pts = voxel_downsample(ob.points, conf.voxel_m)
        best, best_ov = None, 0.0
        c_new = np.median(pts, 0)
        r_new = float(np.percentile(np.linalg.norm(pts - c_new, axis=1), 90))
        for a in accs:
            if a.name != ob.name or ob.frame in a.frames:  # two detections in one frame are two objects
                continue
            # each instance's KD-tree, centre and radius are kept until its points change (not rebuilt per query)
            dist, _ = a.tree().query(pts, distance_upper_bound=conf.merge_radius_m)
            ov = float(np.mean(np.isfinite(dist)))
            cdist = float(np.linalg.norm(c_new - a.centre()))
            close = cdist < min(conf.merge_centre_m, max(a.radius(), r_new))
            if (ov >= conf.merge_overlap or close) and ov + (1.0 if close else 0.0) > best_ov:
                best, best_ov = a, ov + (1.0 if close else 0.0)
        if best is None:
            accs.append(_Acc(ob.name, pts, ob.score, ob.t, [ob.frame],
                             [] if ob.instance_hint is None else [ob.instance_hint], [(ob.frame, ob.score, pts)],
                             {ob.frame: np.asarray(ob.box2d, float)}))
        else:
            best.views.append((ob.frame, ob.score, pts))
            best.boxes2d.setdefault(ob.frame, np.asarray(ob.box2d, float))
            best.points = voxel_downsample(np.concatenate([best.points, pts]), conf.voxel_m)
            best.score = max(best.score, ob.score)
            best.first_seen = min(best.first_seen, ob.t)
            if ob.frame not in best.frames:
                best.frames.append(ob.frame)
            if ob.instance_hint is not None:
                best.hints.append(ob.instance_hint)
    cleaned: list[tuple[_Acc, np.ndarray]] = []
    for a in accs:
        pts = remove_outliers(a.points, conf.outlier_mad, conf.outlier_radius_m, conf.outlier_neighbors)
        if len(pts) >= max(4, conf.min_instance_points // max(1, int(round(conf.voxel_m / 0.04)))):
            cleaned.append((a, pts))
    if conf.merge_footprint:
        cleaned = _merge_overlapping(cleaned, conf)
    if conf.named_twice_inside > 0:
        cleaned = _drop_named_twice(cleaned, conf, log)
    instances, clouds = [], []
    for a, pts in cleaned:
        box = fit_gravity_box(pts)
        inst = ObjectInstance(len(instances), a.name, box, a.first_seen, a.score, len(pts), sorted(a.frames),
                              view_estimates(box, a.views))
        instances.append(inst)
        clouds.append(pts)
    return instances, clouds


def view_estimates(box: OrientedBox, views: list[tuple[int, float, np.ndarray]], margin_m: float = 0.05,
                   lo: float = 2.0, hi: float = 98.0) -> list[dict[str, Any]]:
    """Per-view estimates of one fused instance: for each fused detection (frame, score, points [N, 3]), the
    box its own points give along the fused box's axes (the points inside the fused box grown by `margin_m`,
    i.e. without what outlier removal dropped; `lo`..`hi` percentiles per axis): centre [3] and size [3]. A view
    with fewer than 4 such points keeps its frame and score with centre/size None. Sorted by frame. Pure."""
    ax = np.asarray(box.axes, np.float64)
    c0 = np.asarray(box.centroid, np.float64)
    out = []
    for frame, score, pts in sorted(views, key=lambda v: (v[0], -v[1])):
        p = np.asarray(pts, np.float64)
        p = p[box.contains(p, margin_m)] if len(p) else p
        v: dict[str, Any] = {"frame": int(frame), "score": round(float(score), 3), "n_points": int(len(p)),
                             "centre": None, "size": None}
        if len(p) >= 4:
            local = (p - c0) @ ax.T
            a, b = np.percentile(local, [lo, hi], axis=0)  # one partition for both (same values)
            v["centre"] = np.round(c0 + ((a + b) / 2) @ ax, 4).tolist()
            v["size"] = np.round(np.maximum(b - a, 0.0), 4).tolist()
        out.append(v)
    return out


def footprint_overlap(a: OrientedBox, b: OrientedBox) -> float:
    """Intersection area of two gravity-aligned boxes' floor footprints over the smaller footprint, in [0, 1]."""
    import cv2

    _, (fa, fb) = local_f32(box_footprint(a), box_footprint(b))
    area, _ = cv2.intersectConvexConvex(fa, fb)
    small = min(polygon_area(fa), polygon_area(fb))
    return float(area / small) if small > 1e-9 else 0.0


def _merge_overlapping(items: list[tuple["_Acc", np.ndarray]], conf: FusionConfig
                       ) -> list[tuple["_Acc", np.ndarray]]:
    """Merge same-name instances whose floor footprints overlap (>= 30% of the smaller one): two views of one
    object that shared too few points to fuse (a table seen from either end). Same-category objects do not
    interpenetrate, so overlapping footprints mean one object (objects stacked on each other have other names)."""
    items = list(items)
    merged = True
    while merged:
        merged = False
        boxes = [fit_gravity_box(p) for _, p in items]
        for i in range(len(items)):
            for j in range(i + 1, len(items)):
                if (items[i][0].name != items[j][0].name or set(items[i][0].frames) & set(items[j][0].frames)
                        or footprint_overlap(boxes[i], boxes[j]) < 0.3):
                    continue  # instances seen side by side in one frame are two objects
                a, pa = items[i]
                b, pb = items[j]
                a.points = voxel_downsample(np.concatenate([pa, pb]), conf.voxel_m)
                a.score = max(a.score, b.score)
                a.first_seen = min(a.first_seen, b.first_seen)
                a.frames = sorted(set(a.frames) | set(b.frames))
                a.hints += b.hints
                a.views += b.views
                a.boxes2d = {**b.boxes2d, **a.boxes2d}
                items[i] = (a, a.points)
                del items[j]
                merged = True
                break
            if merged:
                break
    return items


def box_inside_share(a: np.ndarray, b: np.ndarray) -> float:
    """Share of image box a [4] (x0, y0, x1, y1) inside image box b [4], in [0, 1]."""
    w = max(0.0, min(a[2], b[2]) - max(a[0], b[0]))
    h = max(0.0, min(a[3], b[3]) - max(a[1], b[1]))
    area = max((a[2] - a[0]) * (a[3] - a[1]), 1e-9)
    return float(w * h / area)


def _footprint_area(box: OrientedBox) -> float:
    """Floor area of a gravity box (z up): the product of its two sides nearest the horizontal."""
    L = np.asarray(box.axes_lengths, float)
    k = int(np.argmax(np.abs(np.asarray(box.axes, float)[:, 2])))
    return float(np.prod(np.delete(L, k)))


def named_twice(small: tuple[str, np.ndarray, dict[int, np.ndarray]], big: tuple[str, np.ndarray, dict[int, np.ndarray]],
                inside: float, box_inside: float = 0.8, grow: float = 0.1, floor_share: float = 0.25,
                min_footprint: float = 0.25) -> str | None:
    """Why `small` is the same piece of furniture as `big` under another name, or None. Each is (name, points
    [N, 3] in a z-up world, {frame: image box [4]}). All of these (unit-free, relative to big's box): both are
    detected in at least two frames (all of small's, if fewer; elsewhere the detector may name it only one way),
    and in most of those small's image box lies inside big's (>= `box_inside` of its area); >= `inside` of small's
    points lie in big's gravity box grown by `grow` of its sides; small stands where big stands (its bottom within
    `floor_share` x big's height of big's bottom: a cushion on a seat or a cup on a table is another object) and
    does not rise above it (its 95th-percentile height under big's top + `grow` x height: a chair pushed under a
    table shows its back above the top), and covers >= `min_footprint` of big's floor footprint (one seat of a
    three-seat sofa does; an oven built into a run of kitchen cabinets does not)."""
    (na, pa, fa), (nb, pb, fb) = small, big
    shared = sorted(set(fa) & set(fb))
    if na == nb or not fa or len(shared) < min(2, len(fa)):
        return None
    within = sum(box_inside_share(fa[f], fb[f]) >= box_inside for f in shared)
    if within < max(1, len(shared) / 2):
        return None
    box = fit_gravity_box(pb)
    L = np.asarray(box.axes_lengths, float)
    local = (pa - box.centroid) @ np.asarray(box.axes, float).T
    share = float(np.mean(np.all(np.abs(local) <= L / 2 * (1 + grow), axis=1)))
    k = int(np.argmax(np.abs(np.asarray(box.axes, float)[:, 2])))
    h = L[k]
    bottom, top = float(box.centroid[2]) - h / 2, float(box.centroid[2]) + h / 2
    za = pa[:, 2]
    if (share < inside or _footprint_area(fit_gravity_box(pa)) < min_footprint * _footprint_area(box)
            or abs(float(np.percentile(za, 2)) - bottom) > floor_share * h
            or float(np.percentile(za, 95)) > top + grow * h):
        return None
    return (f"{na} (frames {sorted(fa)}) lies inside {nb}'s box ({100 * share:.0f} % of its points), stands on the "
            f"same floor and is detected inside {nb}'s image box in {within} of the {len(shared)} frames both are "
            f"seen in: one object named twice, kept as {nb}")


def _drop_named_twice(items: list[tuple["_Acc", np.ndarray]], conf: FusionConfig, log: StageLog | None
                      ) -> list[tuple["_Acc", np.ndarray]]:
    """Instances of another name that are one piece of furniture with a bigger one (`named_twice`): the smaller
    is left out, the reason in the trace's `fusion` event."""
    order = sorted(range(len(items)), key=lambda i: len(items[i][1]))
    drop: dict[int, str] = {}
    for i in order:
        a, pa = items[i]
        for j in reversed(order):
            b, pb = items[j]
            if j == i or j in drop or len(pb) <= len(pa):
                continue
            why = named_twice((a.name, pa, a.boxes2d), (b.name, pb, b.boxes2d), conf.named_twice_inside)
            if why:
                drop[i] = why
                b.frames = sorted(set(b.frames) | set(a.frames))
                break
    if drop:
        as_trace(log).event("fusion", "fusion: left out as named twice: " + "; ".join(drop[i] for i in sorted(drop)),
                            stage="fusion",
                            named_twice=[{"name": items[i][0].name, "why": drop[i]} for i in sorted(drop)])
    return [it for i, it in enumerate(items) if i not in drop]


def fuse_frames(frames: list[Frame], dets: dict[int, Detections], poses: dict[int, np.ndarray], fconf: FusionConfig,
                log: StageLog | None = None, lifted: dict[int, list[Observation]] | None = None,
                verify: Callable[[list[Observation]], list[Observation]] | None = None
                ) -> tuple[list[Observation], list[ObjectInstance], list[np.ndarray]]:
    """Place every posed key frame's camera-frame observations in the world (`lifted`: perception's; a frame
    without them is lifted here), keep those `verify` keeps (cross-view verification, `map.verify`) and fuse them
    into instances. Returns (the fused observations, instances, clouds)."""
    obs: list[Observation] = []
    lifted = lifted or {}

    def lift(f: Frame) -> list[Observation]:
        return place(lifted[f.index] if f.index in lifted else lift_detections(f, dets[f.index], fconf), poses[f.index])

    posed = [f for f in frames if f.index in poses]
    threads = 1 if all(f.index in lifted for f in posed) else worker_threads()  # placing is a matrix product
    with phase("fusion", len(frames), "key frame") as bar, ThreadPoolExecutor(threads) as ex:
        for got in ex.map(lift, posed):  # frames lift independently; in order
            obs += got
            bar.update()
        if verify is not None:
            obs = verify(obs)
        instances, clouds = fuse_observations(obs, fconf, log)
        bar.note(instances=len(instances))
    return obs, instances, clouds
