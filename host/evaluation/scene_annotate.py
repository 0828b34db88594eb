"""Annotate a real RGB-D room with oriented 3D boxes from a few 2D marks per instance (evaluation only).

    python -m mosaicthinker.host.evaluation.scene_annotate --data DIR --marks MARKS.json --out ANNOT.json
           [--render DIR]

How a box is made (reproducible from the committed marks file, no hand-edited 3D numbers):
1. the sensor depth of every frame is lifted with the ground-truth poses into the pose frame and fused into one
   voxel cloud (`fuse_room`);
2. the pose frame is rotated into a z-up frame by the sequence's gravity direction (`gravity-direction.txt`, or a
   floor fit when absent); the floor (the lowest large horizontal layer of the fused cloud) is put at z = 0; the
   4x4 transform pose frame -> annotation frame is stored beside the boxes (`T_annot_from_pose`);
3. each instance is marked by 2D boxes in a few frames (seen from different sides): the fused points that project
   inside every mark and are not carved away by any mark's depth (a point in front of the surface a mark saw is
   free space) form its visual hull; optional `above`: drop points below the top of another instance (a cup on
   the table); the largest connected component (plus large neighbours) is kept;
4. a gravity-aligned box is fitted to the 1st..99th height percentiles and the minimum-area rectangle of the
   floor-projected points (`geometry.fit_gravity_box`), in the VSI-Bench meta_info format.

Marks file: {"scene": str, "licence": str, "instances": [{"category": str, "id": str, "above": id?,
"grow": bool?, "on_floor": bool?,
"marks": [{"frame": "frame-000246" (file stem), "box": [x0, y0, x1, y1]}]}], "not_annotated": {category: reason}}.
"""
from __future__ import annotations

import argparse
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from mosaicthinker.runtime.infra import jsonio
from mosaicthinker.runtime.infra.errors import InputError
from mosaicthinker.runtime.geometry import OrientedBox, backproject, fit_gravity_box, project, transform
from mosaicthinker.runtime.map import components as _components
from mosaicthinker.runtime.map import largest_components

ANNOT_SCHEMA = "mosaicthinker.scene_annotation/1"


@dataclass
class FusedRoom:
    """points: [N, 3] voxel cloud in the annotation frame (z up, floor z = 0); T: [4, 4] pose frame -> annotation
    frame; poses: [F, 4, 4] camera-to-annotation; depths: [F, H, W]; K: [3, 3]."""

    points: np.ndarray
    T: np.ndarray
    poses: np.ndarray
    depths: np.ndarray
    K: np.ndarray
    stems: list[str]

    def index(self, frame: str | int) -> int:
        """Frame index of a mark's `frame` (a file stem such as "frame-000246", or an index)."""
        if isinstance(frame, str):
            if frame not in self.stems:
                raise InputError(f"marks: frame {frame!r} is not in the data folder")
            return self.stems.index(frame)
        if not 0 <= int(frame) < len(self.poses):
            raise InputError(f"marks: frame {frame} is outside 0..{len(self.poses) - 1}")
        return int(frame)


def up_transform(down: np.ndarray, x_hint: np.ndarray) -> np.ndarray:
    """Rotation [4, 4] taking `down [3]` to -z, keeping the horizontal part of `x_hint [3]` as +x."""
    z = -np.asarray(down, float) / np.linalg.norm(down)
    x = np.asarray(x_hint, float) - z * (z @ x_hint)
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3] = np.stack([x, np.cross(z, x), z])
    return T


def floor_height(z: np.ndarray, bin_m: float = 0.02, rel_peak: float = 0.25) -> float:
    """Height of the lowest dense layer (the floor): the lowest `bin_m` band holding >= `rel_peak` of the densest
    band's points (table and counter tops are dense too, but above the floor)."""
    lo, hi = np.percentile(z, [0.1, 99.9])
    hist, edges = np.histogram(z, bins=max(1, int((hi - lo) / bin_m)), range=(lo, hi))
    big = np.nonzero(hist >= max(rel_peak * hist.max(), 0.002 * len(z)))[0]
    if not len(big):
        raise InputError("annotation: no floor layer found in the fused depth")
    i = big[0]
    while i + 1 < len(hist) and hist[i + 1] > hist[i]:  # climb to the layer's peak
        i += 1
    return float(0.5 * (edges[i] + edges[i + 1]))


def fuse_room(data: str | Path, stride: int = 4, voxel_m: float = 0.02) -> FusedRoom:
    """Fuse the sensor depth of all frames of an RGB-D source with its ground-truth poses (see module doc)."""
    from mosaicthinker.runtime.frames import open_source
    from mosaicthinker.runtime.map import voxel_downsample

    src = open_source(data)
    frames = [src[i] for i in range(len(src))]
    if any(f.depth is None or f.pose_gt is None for f in frames):
        raise InputError(f"{data}: annotation needs sensor depth and ground-truth poses in every frame")
    K = np.asarray(frames[0].K, float)
    pts = [transform(f.pose_gt, backproject(f.depth, K, None, stride)[0]) for f in frames]
    cloud = voxel_downsample(np.concatenate(pts), voxel_m)
    down = src.gravity if src.gravity is not None else _floor_fit_down(cloud, frames)
    T = up_transform(down, frames[0].pose_gt[:3, 0])
    up = transform(T, cloud)
    T[2, 3] = -floor_height(up[:, 2])
    return FusedRoom(transform(T, cloud), T, np.stack([T @ f.pose_gt for f in frames]),
                     np.stack([f.depth for f in frames]), K,
                     list(getattr(src, "stems", [str(i) for i in range(len(src))])))


def _floor_fit_down(cloud: np.ndarray, frames: list) -> np.ndarray:
    from mosaicthinker.runtime.map import fit_floor_plane

    hint = frames[0].pose_gt[:3, 1]  # the first camera's image-down axis
    fit = fit_floor_plane(cloud[:: max(1, len(cloud) // 50000)], hint)
    if fit is None:
        raise InputError("annotation: no gravity-direction.txt and no floor plane found")
    return fit[0]


def _mark_box(m: dict[str, Any], pad_px: float) -> np.ndarray:
    return np.asarray(m["box"], float) + [-pad_px, -pad_px, pad_px, pad_px]


def mark_points(room: FusedRoom, mark: dict[str, Any], floor_tol_m: float = 0.03, support_z: float | None = None,
                pad_px: float = 6.0, link_m: float = 0.04, stride: int = 2) -> np.ndarray:
    """The marked object's surface as one view saw it: the depth pixels inside the mark `[M, 3]` (annotation
    frame), without the floor (and without the support below `support_z`), split into connected components;
    the component with most pixels in the box's central half is the object (the box is drawn around it; the
    background fills its margins). Marks are grown by `pad_px` (a 7-Scenes depth pixel is not exactly under the
    same colour pixel: the two cameras differ)."""
    f = room.index(mark["frame"])
    H, W = room.depths.shape[1:]
    x0, y0, x1, y1 = np.clip(_mark_box(mark, pad_px), 0, [W, H, W, H]).astype(int)
    m = np.zeros((H, W), bool)
    m[y0:y1, x0:x1] = True
    pc, uv = backproject(room.depths[f], room.K, m, stride)
    pts = transform(room.poses[f], pc)
    ok = pts[:, 2] > (floor_tol_m if support_z is None else support_z)
    pts, uv = pts[ok], uv[ok]
    if len(pts) < 3:
        return pts
    lab = _components(pts, link_m)
    cx, cy, hw, hh = (x0 + x1) / 2, (y0 + y1) / 2, (x1 - x0) / 4, (y1 - y0) / 4
    central = (np.abs(uv[:, 0] - cx) <= hw) & (np.abs(uv[:, 1] - cy) <= hh)
    votes = np.bincount(lab[central], minlength=lab.max() + 1) if central.any() else np.bincount(lab)
    return pts[lab == int(np.argmax(votes))]


def carve(room: FusedRoom, points: np.ndarray, marks: list[dict[str, Any]], tol_m: float = 0.05,
          pad_px: float = 6.0) -> np.ndarray:
    """Drop points [N, 3] that some mark's camera saw through (inside its box, in front of its depth by > tol)."""
    keep = np.ones(len(points), bool)
    H, W = room.depths.shape[1:]
    for m in marks:
        f = room.index(m["frame"])
        x0, y0, x1, y1 = _mark_box(m, pad_px)
        uv, z = project(points, room.K, room.poses[f])
        inside = (z > 0.1) & (uv[:, 0] >= x0) & (uv[:, 0] <= x1) & (uv[:, 1] >= y0) & (uv[:, 1] <= y1)
        ui = np.clip(np.round(uv[:, 0]).astype(int), 0, W - 1)
        vi = np.clip(np.round(uv[:, 1]).astype(int), 0, H - 1)
        d = np.where(inside, room.depths[f][vi, ui], 0)
        keep &= ~((d > 0) & (z < d - tol_m))
    return points[keep]


def instance_points(room: FusedRoom, marks: list[dict[str, Any]], floor_tol_m: float = 0.03,
                    support_z: float | None = None) -> np.ndarray:
    """One instance's points [M, 3]: the union of its marks' object surfaces (`mark_points`), minus what another
    mark saw through (`carve`), largest connected parts kept (`largest_components`)."""
    parts = [mark_points(room, m, floor_tol_m, support_z) for m in marks]
    pts = np.concatenate([p for p in parts if len(p)] or [np.zeros((0, 3))])
    return largest_components(carve(room, pts, marks)) if len(pts) else pts


def grow(room: FusedRoom, seed: np.ndarray, taken: np.ndarray, floor_tol_m: float = 0.03, link_m: float = 0.045,
         reach_m: float = 0.4, rounds: int = 30) -> np.ndarray:
    """Grow `seed [M, 3]` through the fused cloud (points within `link_m`, above the floor, not within `link_m` of
    `taken [T, 3]` (other instances' points), within `reach_m` of the seed's floor-projected extent): the parts
    no mark saw directly (a chair's seat below the table edge its back shows over)."""
    from scipy.spatial import cKDTree

    lo, hi = seed[:, :2].min(0) - reach_m, seed[:, :2].max(0) + reach_m
    cand = room.points[(room.points[:, 2] > floor_tol_m) & np.all((room.points[:, :2] >= lo)
                                                                  & (room.points[:, :2] <= hi), 1)]
    if len(taken):
        cand = cand[~np.isfinite(cKDTree(taken).query(cand, distance_upper_bound=link_m)[0])]
    if not len(cand):
        return seed
    tree = cKDTree(cand)
    inside = np.zeros(len(cand), bool)
    front = seed
    for _ in range(rounds):  # breadth-first flood fill, `link_m` per round
        hits = tree.query_ball_point(front, link_m)
        new = np.unique(np.concatenate([np.asarray(h, int) for h in hits] or [np.zeros(0, int)]))
        new = new[~inside[new]]
        if not len(new):
            break
        inside[new] = True
        front = cand[new]
    return np.concatenate([seed, cand[inside]])


def robust_box(points: np.ndarray, q: float = 1.0, floor_tol_m: float = 0.03, on_floor: bool = False) -> OrientedBox:
    """Gravity-aligned box of the points between the q-th and (100-q)-th height percentiles; a box whose bottom
    is within 3 * `floor_tol_m` of the floor, or marked `on_floor` (furniture whose legs no view separates from
    what is around them), is extended down to z = 0."""
    lo, hi = np.percentile(points[:, 2], [q, 100 - q])
    core = points[(points[:, 2] >= lo) & (points[:, 2] <= hi)]
    b = fit_gravity_box(core if len(core) >= 3 else points)
    bottom = b.centroid[2] - b.axes_lengths[2] / 2
    if 0 < bottom and (on_floor or bottom <= 3 * floor_tol_m):
        top = bottom + b.axes_lengths[2]
        b = OrientedBox(np.array([*b.centroid[:2], top / 2]), np.array([*b.axes_lengths[:2], top]), b.axes)
    return b


def annotate(data: str | Path, marks_doc: dict[str, Any], floor_tol_m: float = 0.03
             ) -> tuple[dict[str, Any], FusedRoom, dict]:
    """Annotation document (meta_info-style scene + transform + provenance), the fused room, and per-instance
    fused points (for rendering)."""
    room = fuse_room(data)
    boxes: dict[str, OrientedBox] = {}
    clouds: dict[str, np.ndarray] = {}
    bbox: dict[str, list] = {}
    ids: dict[str, list] = {}
    for inst in marks_doc["instances"]:
        support = None
        if inst.get("above"):  # the support's surface: its densest height layer (chair backs may reach above)
            support = floor_height(clouds[inst["above"]][:, 2], rel_peak=0.9) + 0.025
        pts = instance_points(room, inst["marks"], floor_tol_m, support)
        if len(pts) and inst.get("grow"):
            taken = np.concatenate(list(clouds.values())) if clouds else np.zeros((0, 3))
            pts = grow(room, pts, taken, floor_tol_m)
        if len(pts) < 5:
            raise InputError(f"marks: instance {inst['id']} has only {len(pts)} fused points in its marks")
        boxes[inst["id"]] = b = robust_box(pts, floor_tol_m=floor_tol_m, on_floor=bool(inst.get("on_floor")))
        clouds[inst["id"]] = pts
        bbox.setdefault(inst["category"], []).append(b.to_meta())
        ids.setdefault(inst["category"], []).append(inst["id"])
    scene = {"object_counts": {c: len(v) for c, v in bbox.items()}, "object_bbox": bbox,
             "instance_ids": ids, "dataset": "7scenes"}
    doc = {"schema": ANNOT_SCHEMA, "scene": marks_doc.get("scene"), "licence": marks_doc.get("licence"),
           "frame": "z up from gravity-direction.txt, floor at z = 0, metres",
           "T_annot_from_pose": room.T.tolist(), "n_frames": int(len(room.poses)),
           "not_annotated": marks_doc.get("not_annotated", {}), "meta_info": {marks_doc.get("scene", "scene"): scene}}
    return doc, room, clouds


def render_topdown(points: np.ndarray, boxes: dict[str, list[dict]], path: str | Path, title: str,
                   extra: dict[str, list[dict]] | None = None, px_per_m: int = 150,
                   tracks: list[tuple[np.ndarray, tuple[int, int, int], bool]] | None = None) -> None:
    """Top-down PNG: a cloud `[N, 3]` (z up) coloured by height (blue low .. red high), annotation boxes (white,
    labelled), optional `extra` boxes (yellow, e.g. a built map registered into the annotation frame) and
    `tracks`: (camera centres [M, 3], BGR colour, as a line (else dots)), e.g. the ground-truth camera path and the
    registered key-frame cameras."""
    import cv2

    tracks = [(np.asarray(c, float).reshape(-1, 3), col, line) for c, col, line in (tracks or []) if len(c)]
    corners = [OrientedBox.from_meta(m).corners() for d in (boxes, extra or {}) for lst in d.values() for m in lst]
    p = np.concatenate([np.asarray(points, float).reshape(-1, 3)] + corners + [c for c, _, _ in tracks])
    p = p[p[:, 2] < 2.2]  # the ceiling would hide everything
    lo, hi = p[:, :2].min(0) - 0.3, p[:, :2].max(0) + 0.3
    W, H = (np.ceil((hi - lo) * px_per_m)).astype(int) + 1
    img = np.zeros((H + 40, W, 3), np.uint8)
    order = np.argsort(p[:, 2])
    u = ((p[order, 0] - lo[0]) * px_per_m).astype(int)
    v = (H - 1 - (p[order, 1] - lo[1]) * px_per_m).astype(int) + 40
    col = cv2.applyColorMap(np.clip(p[order, 2] / 2.0 * 255, 0, 255).astype(np.uint8)[:, None], cv2.COLORMAP_JET)
    img[v, u] = col[:, 0]

    def draw(sets: dict[str, list[dict]], colour: tuple[int, int, int]) -> None:
        for cat, lst in sets.items():
            for k, m in enumerate(lst):
                c = OrientedBox.from_meta(m).corners()[:, :2]
                hull = cv2.convexHull(np.stack([(c[:, 0] - lo[0]) * px_per_m,
                                                H - 1 - (c[:, 1] - lo[1]) * px_per_m + 40], 1).astype(np.int32))
                cv2.polylines(img, [hull], True, colour, 2)
                x, y = hull[:, 0].min(0)
                cv2.putText(img, f"{cat}{k}", (int(x), int(y) - 3), cv2.FONT_HERSHEY_SIMPLEX, 0.4, colour, 1)

    draw(boxes, (255, 255, 255))
    if extra:
        draw(extra, (0, 255, 255))
    for c, colour, line in tracks:
        q = np.stack([(c[:, 0] - lo[0]) * px_per_m, H - 1 - (c[:, 1] - lo[1]) * px_per_m + 40], 1).astype(np.int32)
        if line:
            cv2.polylines(img, [q], False, colour, 1)
        else:
            for x, y in q:
                cv2.circle(img, (int(x), int(y)), 3, colour, -1)
    cv2.putText(img, title, (5, 25), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1)
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), img)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", required=True, help="RGB-D frame folder with ground-truth poses (7-Scenes layout)")
    ap.add_argument("--marks", required=True, help="marks JSON (2D boxes per instance)")
    ap.add_argument("--out", required=True, help="annotation JSON to write")
    ap.add_argument("--render", help="folder for the top-down check picture (not committed: made from the data)")
    a = ap.parse_args(argv)
    marks = json.loads(Path(a.marks).read_text())
    doc, room, _ = annotate(a.data, marks)
    Path(a.out).write_text(jsonio.dumps(doc, indent=1))
    scene = next(iter(doc["meta_info"].values()))
    print(f"wrote {a.out}: {scene['object_counts']}")
    for cat, lst in scene["object_bbox"].items():
        for i, m in enumerate(lst):
            print(f"  {cat}{i}: centre {np.round(m['centroid'], 2).tolist()} size {np.round(m['axesLengths'], 2).tolist()}")
    if a.render:
        render_topdown(room.points, scene["object_bbox"], Path(a.render) / "annotation_topdown.png",
                       f"{doc['scene']}: fused sensor depth (height colour) + annotation")
        print(f"wrote {Path(a.render) / 'annotation_topdown.png'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
