"""The sparse global semantic map: object instances with oriented 3D boxes in a gravity-aligned world.

World frame (see ARCHITECTURE.md): z up, metres. Boxes follow the VSI-Bench meta_info format
(`geometry.OrientedBox`, `normalizedAxes` rows are the box axes).

This file holds the map *data structures* first (`ObjectInstance`, `Room`, `SemanticMap`, JSON save/load,
`SemanticMap.from_meta_info`); the fusion functions that build a map from perception (per-frame points ->
instances, occlusion refinement) follow further down.

Room extent of a map built from boxes only (`room_from_boxes`): the floor polygon is the 2D convex hull of the
floor-projected corners of every object box (the area the furnished space spans at least); floor z is the lowest
box bottom, ceiling z the highest box top. A map built from video (`pipeline._room`) uses the floor-projected
hull of everything the aligned key frames' depth saw (walls included), the object footprints and the camera track
(source "observed_depth_hull"). The benchmark's own `room_size`/`room_center` fields are never copied into the map
(`meta` keeps only the scene name and dataset), so room-size answers come from the map's extent.
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass, field, replace
from typing import Any, ClassVar, Iterable, Sequence

import numpy as np

from .config import StageConf
from .errors import InputError, path_kind
from .file_schemas import check_map
from .geometry import OrientedBox, convex_hull_2d, polygon_area

MAP_SCHEMA = "mosaicthinker.semantic_map/1"
# Largest saved map the runtime reads: a room holds hundreds of objects; 100 k leaves room for dense maps and keeps
# every question (validation + answer) around a second. Larger maps are refused, not answered slowly.
MAX_MAP_OBJECTS = 100_000
MAX_MAP_BYTES = 256 << 20


# ----------------------------------------------------------------------------- data structures


def _no_json_constant(name: str) -> Any:
    raise ValueError(f"{name} is not a number a map may hold")


def validate_map_dict(d: Any, where: str = "semantic map") -> None:
    """Check a saved map before use against its schema (`file_schemas.map_spec`: types, ranges, orthonormal
    axes, rigid cameras, unique ids, a room whose ceiling is above its floor). Raises InputError naming the field.
    Column-wise over instances (a 100 k-object map validates in well under a second)."""
    check_map(d, where, MAP_SCHEMA, MAX_MAP_OBJECTS)


@dataclass
class ObjectInstance:
    """One object in the map.

    id: unique within the map; name: canonical vocabulary name (`grounding.canonical_name`);
    box: oriented box in the z-up metric world; first_seen: video time (s) of the first frame showing it, or None
    when unknown (e.g. a map built from benchmark boxes); score: detection confidence (1.0 for ground truth);
    n_points: 3D points fused into it (0 for ground truth); frames: indices of the frames it was seen in;
    views: the per-view estimates it was fused from, one per fused detection (`view_estimates`: frame, score,
    n_points, centre [3] and size [3] along the box axes of that view's points alone), [] for ground truth. The
    reasoner's evidence (the spread of an answer's quantity over the views) reads them.
    """

    id: int
    name: str
    box: OrientedBox
    first_seen: float | None = None
    score: float = 1.0
    n_points: int = 0
    frames: list[int] = field(default_factory=list)
    views: list[dict[str, Any]] = field(default_factory=list)

    @property
    def center(self) -> np.ndarray:
        """Box centre `[3]` (m)."""
        return np.asarray(self.box.centroid, dtype=np.float64)

    def to_dict(self) -> dict[str, Any]:
        d = {"id": int(self.id), "name": self.name, "box": self.box.to_meta(),
             "first_seen": None if self.first_seen is None else float(self.first_seen),
             "score": float(self.score), "n_points": int(self.n_points), "frames": [int(f) for f in self.frames]}
        if self.views:
            d["views"] = [_plain(v) for v in self.views]
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "ObjectInstance":
        views = [v for v in d.get("views", []) if isinstance(v, dict)]
        return cls(int(d["id"]), str(d["name"]), OrientedBox.from_meta(d["box"]),
                   None if d.get("first_seen") is None else float(d["first_seen"]),
                   float(d.get("score", 1.0)), int(d.get("n_points", 0)), [int(f) for f in d.get("frames", [])],
                   views)


@dataclass
class Room:
    """Room extent. polygon: [P, 2] floor outline (x, y metres, counter-clockwise); floor_z/ceiling_z: heights (m);
    source: how it was obtained (e.g. "object_boxes_hull", "camera_track", "floor_fit")."""

    polygon: np.ndarray
    floor_z: float
    ceiling_z: float
    source: str = "unknown"

    def area(self) -> float:
        """Floor area (m^2) of the polygon."""
        return polygon_area(self.polygon)

    def to_dict(self) -> dict[str, Any]:
        return {"polygon": np.asarray(self.polygon, dtype=np.float64).tolist(), "floor_z": float(self.floor_z),
                "ceiling_z": float(self.ceiling_z), "source": self.source, "area_m2": self.area()}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "Room":
        return cls(np.asarray(d["polygon"], dtype=np.float64).reshape(-1, 2), float(d["floor_z"]),
                   float(d["ceiling_z"]), str(d.get("source", "unknown")))


@dataclass
class SemanticMap:
    """Object instances, optional room extent, optional camera track `[(t seconds, T_wc [4, 4])]` in the same
    z-up world, and free-form `meta` (scene name, how the map was built, ...)."""

    instances: list[ObjectInstance] = field(default_factory=list)
    room: Room | None = None
    cameras: list[tuple[float, np.ndarray]] = field(default_factory=list)
    meta: dict[str, Any] = field(default_factory=dict)

    # -- queries
    def by_name(self, name: str) -> list[ObjectInstance]:
        """Instances whose canonical name equals the canonical form of `name` (synonyms resolved)."""
        from .grounding import canonical_name  # grounding is pure text; imported here to keep this module light

        key = canonical_name(name) or name.strip().lower()
        return list(self._category_index().get(key, ()))

    def _category_index(self) -> dict[str, list[ObjectInstance]]:
        """canonical name -> instances, rebuilt only when the instance list changed (a question on a 10 k-object
        map asks for names many times; canonicalising every instance name per call took seconds)."""
        from .grounding import canonical_name

        key = tuple(map(id, self.instances))
        cached = self.__dict__.get("_index")
        if cached is not None and cached[0] == key:
            return cached[1]
        names: dict[str, str] = {}
        index: dict[str, list[ObjectInstance]] = {}
        for o in self.instances:
            if o.name not in names:
                names[o.name] = canonical_name(o.name) or o.name.lower()
            index.setdefault(names[o.name], []).append(o)
        self.__dict__["_index"] = (key, index)
        return index

    def names(self) -> list[str]:
        """Distinct instance names, sorted."""
        return sorted({o.name for o in self.instances})

    def counts(self) -> dict[str, int]:
        out: dict[str, int] = {}
        for o in self.instances:
            out[o.name] = out.get(o.name, 0) + 1
        return out

    def get(self, instance_id: int) -> ObjectInstance:
        for o in self.instances:
            if o.id == instance_id:
                return o
        raise KeyError(instance_id)

    def box_arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Every instance's box as stacked arrays: centroids [N, 3], axis lengths [N, 3], axes [N, 3, 3] (rows),
        kept until an instance or a box is replaced (a big map's image, text, checks and file read them once)."""
        key = tuple(id(o.box) for o in self.instances)
        cached = self.__dict__.get("_boxes")
        if cached is None or cached[0] != key:
            n = len(self.instances)
            b = [o.box for o in self.instances]
            arrays = (np.array([x.centroid for x in b], np.float64).reshape(n, 3),
                      np.array([x.axes_lengths for x in b], np.float64).reshape(n, 3),
                      np.array([x.axes for x in b], np.float64).reshape(n, 3, 3))
            cached = self.__dict__["_boxes"] = (key, arrays)
        return cached[1]

    def extent(self) -> Room | None:
        """The map's room extent: its room, else the one its object boxes span (`room_from_boxes`); None when the
        map has neither."""
        return self.room if self.room is not None else room_from_boxes([o.box for o in self.instances])

    def floor_z(self) -> tuple[float, str]:
        """(floor height in metres, where it comes from): the room's floor, else the lowest object bottom."""
        room = self.extent()
        if room is None:
            raise ValueError("floor_z: the map has neither a room nor objects")
        return float(room.floor_z), (f"the room's floor, {room.source}" if self.room is not None else
                                     "the lowest object bottom")

    def room_area(self) -> float | None:
        """Floor area (m^2) of the map's room extent; None when the map has neither a room nor objects."""
        room = self.extent()
        return None if room is None else room.area()

    # -- serialisation
    def to_dict(self, instances: bool = True) -> dict[str, Any]:
        return {"schema": MAP_SCHEMA,
                **({"instances": _instance_dicts(self.instances)} if instances else {}),
                "room": None if self.room is None else self.room.to_dict(),
                "cameras": [{"t": float(t), "T_wc": np.asarray(T, dtype=np.float64).tolist()} for t, T in self.cameras],
                "meta": _plain(self.meta)}

    @classmethod
    def from_dict(cls, d: dict[str, Any], where: str = "semantic map") -> "SemanticMap":
        """A map from its JSON form, validated first (`validate_map_dict`): a bad field raises InputError naming
        it instead of crashing a renderer or answering from NaN / negative sizes."""
        validate_map_dict(d, where)
        instances, arrays = _instances_from_dicts(d["instances"])
        smap = cls(instances,
                   None if d.get("room") is None else Room.from_dict(d["room"]),
                   [(float(c["t"]), np.asarray(c["T_wc"], dtype=np.float64).reshape(4, 4))
                    for c in d.get("cameras", [])],
                   dict(d.get("meta", {})))
        smap.__dict__["_boxes"] = (tuple(id(o.box) for o in instances), arrays)  # the boxes are views of them
        return smap

    def json_text(self, **extra: Any) -> str:
        """The JSON of `to_dict()` (plus `extra` top-level fields, e.g. a run id), one line per object, written
        from the stacked box numbers without building a dict per object (`_instance_lines`): a 100 k-object map
        in about a second."""
        d = self.to_dict(instances=False)
        d.update(extra)
        head = ",\n".join(f" {json.dumps(k)}: {json.dumps(v)}" for k, v in d.items())
        lines = _instance_lines(self.instances, self.box_arrays())
        return "{\n" + head + ',\n "instances": [\n  ' + ",\n  ".join(lines) + "\n ]\n}\n"

    def save(self, path: str | os.PathLike) -> None:
        with open(path, "w") as f:
            f.write(self.json_text())

    @classmethod
    def load(cls, path: str | os.PathLike) -> "SemanticMap":
        """Read and validate a saved map; maps over MAX_MAP_BYTES / MAX_MAP_OBJECTS are refused."""
        kind = path_kind(path)  # a FIFO would block the read; a loop or a folder is said as such
        if kind != "a file":
            raise InputError(f"{path}: cannot read the semantic map (no such file); build one with `mosaic map`"
                             if kind == "missing" else f"{path}: the map is {kind}; give a map.json file")
        try:
            size = os.path.getsize(path)
            if size > MAX_MAP_BYTES:
                raise InputError(f"{path}: the map file is {size / 2**20:.0f} MB; at most {MAX_MAP_BYTES >> 20} MB "
                                 f"({MAX_MAP_OBJECTS} objects) is supported; split the scene or map fewer objects")
            with open(path, "rb") as f:
                raw = f.read()
            d = json.loads(raw.decode("utf-8"), parse_constant=_no_json_constant)
        except InputError:
            raise
        except (OSError, ValueError, RecursionError) as e:
            raise InputError(f"{path}: cannot read the semantic map ({e}); build one with `mosaic map`") from e
        return cls.from_dict(d, str(path))

    # -- construction from benchmark ground truth
    @classmethod
    def from_meta_info(cls, scene_meta: dict[str, Any], scene_name: str | None = None) -> "SemanticMap":
        """Map from one VSI-Bench meta_info scene (`object_bbox`: category -> list of boxes).

        Names are canonicalised through the grounding vocabulary; instances are numbered in file order.
        The room is derived from the boxes (`room_from_boxes`); `room_size`/`room_center` are not copied.
        """
        if "object_bbox" not in scene_meta:
            raise InputError(f"meta_info scene {scene_name or ''}: field `object_bbox` is missing")
        from .grounding import canonical_name

        inst: list[ObjectInstance] = []
        for cat, boxes in scene_meta["object_bbox"].items():
            name = canonical_name(cat) or cat.strip().lower()
            for b in boxes:
                inst.append(ObjectInstance(len(inst), name, OrientedBox.from_meta(b)))
        meta = {"source": "meta_info", "scene_name": scene_name, "dataset": scene_meta.get("dataset")}
        return cls(inst, room_from_boxes([o.box for o in inst]), [], meta)


_CORNER_SIGNS = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], np.float64)


def _instance_dicts(instances: list[ObjectInstance]) -> list[dict[str, Any]]:
    """`[o.to_dict() for o in instances]` with the boxes' numbers computed for all instances at once (a
    100 k-object map: one pass, not 100 k small numpy calls)."""
    n = len(instances)
    if not n:
        return []
    C, L, A = SemanticMap(instances).box_arrays()
    corners = C[:, None, :] + (_CORNER_SIGNS[None] * (L[:, None, :] / 2.0)) @ A
    out = []
    for o, c, ln, a, lo, hi in zip(instances, C.tolist(), L.tolist(), A.reshape(n, 9).tolist(),
                                   corners.min(1).tolist(), corners.max(1).tolist()):
        d = {"id": int(o.id), "name": o.name,
             "box": {"centroid": c, "axesLengths": ln, "normalizedAxes": a, "min": lo, "max": hi},
             "first_seen": None if o.first_seen is None else float(o.first_seen),
             "score": float(o.score), "n_points": int(o.n_points), "frames": [int(f) for f in o.frames]}
        if o.views:
            d["views"] = [_plain(v) for v in o.views]
        out.append(d)
    return out


_LINE = ('{"id": %d, "name": %s, "box": {"centroid": [%r, %r, %r], "axesLengths": [%r, %r, %r], '
         '"normalizedAxes": [%r, %r, %r, %r, %r, %r, %r, %r, %r], "min": [%r, %r, %r], "max": [%r, %r, %r]}, '
         '"first_seen": %s, "score": %r, "n_points": %d, "frames": %s%s}')


def _instance_lines(instances: list[ObjectInstance], arrays: tuple[np.ndarray, ...] | None = None) -> list[str]:
    """One JSON object per instance, equal to `json.dumps(o.to_dict())` once parsed (floats written by repr, as
    the JSON encoder does), formatted from the stacked numbers."""
    n = len(instances)
    if not n:
        return []
    C, L, A = SemanticMap(instances).box_arrays() if arrays is None else arrays
    corners = C[:, None, :] + (_CORNER_SIGNS[None] * (L[:, None, :] / 2.0)) @ A
    rows = np.concatenate([C, L, A.reshape(n, 9), corners.min(1), corners.max(1)], 1).tolist()
    names: dict[str, str] = {}
    out = []
    for o, r in zip(instances, rows):
        name = names.get(o.name) or names.setdefault(o.name, json.dumps(o.name))
        fs = "null" if o.first_seen is None else repr(float(o.first_seen))
        frames = json.dumps([int(f) for f in o.frames]) if o.frames else "[]"
        views = f', "views": {json.dumps([_plain(v) for v in o.views])}' if o.views else ""
        out.append(_LINE % (int(o.id), name, *r, fs, float(o.score), int(o.n_points), frames, views))
    return out


def _instances_from_dicts(items: list[dict[str, Any]]
                          ) -> tuple[list[ObjectInstance], tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """`[ObjectInstance.from_dict(o) for o in items]` (validated dicts) with the box arrays built at once;
    returns (instances, (centroids [N, 3], lengths [N, 3], axes [N, 3, 3])), the boxes being views of them."""
    n = len(items)
    if not n:
        return [], (np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3, 3)))
    boxes = [o["box"] for o in items]
    C = np.array([b["centroid"] for b in boxes], np.float64).reshape(n, 3)
    L = np.array([b["axesLengths"] for b in boxes], np.float64).reshape(n, 3)
    A = np.array([b["normalizedAxes"] for b in boxes], np.float64).reshape(n, 3, 3)
    return [ObjectInstance(int(d["id"]), str(d["name"]), OrientedBox(C[i], L[i], A[i]),
                           None if d.get("first_seen") is None else float(d["first_seen"]),
                           float(d.get("score", 1.0)), int(d.get("n_points", 0)), [int(f) for f in d.get("frames", [])],
                           list(d.get("views", []))) for i, d in enumerate(items)], (C, L, A)


def room_from_boxes(boxes: Iterable[OrientedBox], extra_xy: np.ndarray | None = None) -> Room | None:
    """Room extent spanned by object boxes: convex hull of the floor-projected corners (plus `extra_xy [M, 2]`,
    e.g. camera positions of a walk-through, which also lie inside the room), floor = lowest box bottom,
    ceiling = highest box top. None without boxes. A lower bound of the true floor area: the space between the
    furniture and the walls is not seen by boxes alone."""
    boxes = list(boxes)
    if not boxes:
        return None
    # every box's 8 corners at once (OrientedBox.corners, vectorised: a 10 k-object map in milliseconds)
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=np.float64)
    half = signs[None] * (np.array([b.axes_lengths for b in boxes], np.float64)[:, None, :] / 2.0)
    c = (np.array([b.centroid for b in boxes], np.float64)[:, None, :]
         + half @ np.array([b.axes for b in boxes], np.float64)).reshape(-1, 3)
    xy = c[:, :2] if extra_xy is None else np.concatenate([c[:, :2], np.asarray(extra_xy, np.float64).reshape(-1, 2)])
    src = "object_boxes_hull" if extra_xy is None else "object_boxes_and_cameras_hull"
    return Room(convex_hull_2d(xy), float(c[:, 2].min()), float(c[:, 2].max()), src)


def _plain(x: Any) -> Any:
    from .trace import jsonable

    return jsonable(x)


# ----------------------------------------------------------------------------- building a map from perception
#
# Paper, "Iterative construction": per key frame, detector boxes -> segmenter masks -> masked depth -> 3D points
# -> world frame through the frame's global pose; then gravity alignment to a z-up world, fusion of same-name
# observations into instances, outlier removal and gravity-aligned oriented boxes.


@dataclass
class FusionConfig(StageConf):
    """Defaults chosen for metric indoor depth; all overridable (`FusionConfig.merged(mapping_or_conf,
    **overrides)`: unknown keys are an error)."""

    conf_name: ClassVar[str] = "fusion config"

    stride: int = 2               # pixel stride when lifting masks (speed; masks are dense)
    erode_px: int = 2             # shrink masks so depth edges (object/background) do not bleed in
    max_depth_m: float = 8.0      # ignore far, noisy depth
    min_points: int = 25          # an observation with fewer 3D points is dropped
    max_points: int = 4000        # per observation, random subsample (memory bound)
    voxel_m: float = 0.04         # instance point clouds are voxel-downsampled at this size
    merge_radius_m: float = 0.12  # a point "overlaps" an instance if an instance point is this close
    merge_overlap: float = 0.2    # ... and this share of the observation's points overlaps
    merge_centre_m: float = 0.6   # or the centres are this close relative to the instance's size (see below)
    outlier_mad: float = 6.0      # radial outlier removal: keep points within median + k * MAD of the centre
    outlier_radius_m: float = 0.1  # density outlier removal: >= outlier_neighbors other points within this
    outlier_neighbors: int = 2
    component_link_m: float = 0.05  # per observation: keep its largest connected part (0 = off) ...
    component_share: float = 0.5    # ... and parts with at least this share of its points
    merge_footprint: bool = True  # after fusion, merge same-name instances whose floor footprints overlap
    min_instance_points: int = 40
    duplicate_iou: float = 0.7    # one frame's boxes of two names this alike are one object named twice (0 = off)
    same_frame_share: float = 0.5  # one frame's same-name box whose points lie on another's: group/duplicate (0 = off)
    seed: int = 0

    def validate(self) -> None:
        if self.stride < 1 or self.erode_px < 0 or self.min_points < 1 or self.max_points < self.min_points:
            raise InputError(f"fusion config: need stride >= 1, erode_px >= 0, 1 <= min_points <= max_points "
                             f"(got {self.stride}, {self.erode_px}, {self.min_points}, {self.max_points})")
        for name in ("max_depth_m", "voxel_m", "merge_radius_m", "merge_centre_m", "outlier_mad", "outlier_radius_m"):
            if getattr(self, name) <= 0:
                raise InputError(f"fusion config: {name} must be > 0 (got {getattr(self, name)})")
        if not 0 <= self.merge_overlap <= 1:
            raise InputError(f"fusion config: merge_overlap must be in [0, 1] (got {self.merge_overlap})")


default_fusion_conf = FusionConfig()


@dataclass
class Observation:
    """One detection lifted to 3D. points: [N, 3] world (m); frame: key-frame index; t: seconds;
    instance_hint: id from an oracle (evaluation only) or None."""

    name: str
    score: float
    frame: int
    t: float
    points: np.ndarray
    box2d: np.ndarray
    instance_hint: int | None = None
    recovered: bool = False  # a view occlusion refinement re-prompted for one instance (not a detection)


def lift_observations(rgb_shape: tuple[int, int], depth: np.ndarray, K: np.ndarray, T_wc: np.ndarray,
                      boxes: np.ndarray, names: list[str], scores: np.ndarray, masks: np.ndarray | None,
                      frame: int, t: float, conf: FusionConfig = default_fusion_conf,
                      instance_ids: np.ndarray | None = None) -> list[Observation]:
    """Masked depth -> world points for each detection of one frame: `place(lift_camera(...), T_wc)`.

    depth: [H, W] float32 metres (0 invalid); K: [3, 3]; T_wc: [4, 4] camera-to-world (gravity-aligned world);
    boxes: [N, 4] pixels; masks: [N, H, W] bool or None (then the box interior is used, with a tighter depth
    filter: the median-depth band, since boxes also cover background).
    """
    return place(lift_camera(rgb_shape, depth, K, boxes, names, scores, masks, frame, t, conf, instance_ids), T_wc)


def place(observations: list[Observation], T_wc: np.ndarray) -> list[Observation]:
    """Camera-frame observations (`lift_camera`) -> the same in the world: points [N, 3] through T_wc [4, 4]."""
    from .geometry import transform

    return [replace(o, points=transform(T_wc, o.points)) for o in observations]


def lift_camera(rgb_shape: tuple[int, int], depth: np.ndarray, K: np.ndarray, boxes: np.ndarray, names: list[str],
                scores: np.ndarray, masks: np.ndarray | None, frame: int, t: float,
                conf: FusionConfig = default_fusion_conf, instance_ids: np.ndarray | None = None
                ) -> list[Observation]:
    """Masked depth -> camera-frame points for each detection of one frame (arguments as `lift_observations`).
    Needs no pose (a rigid move keeps the component split's distances), so a key frame is lifted when it is
    perceived (paper: per key frame, segmentation + depth -> object point clouds) and fusion only places it."""
    import cv2

    rng = None  # the frame's subsampling stream, made on first use (most masks need none: ~50 us a frame)
    out: list[Observation] = []
    # with segmenter masks only the masks' windows are read: the depth cut-off is applied there
    # (`_backproject_window`), not to the whole image; box-prompted masks need the cut depth image itself
    d = _depth_upto(depth, conf.max_depth_m) if masks is None else depth
    kernel = np.ones((2 * conf.erode_px + 1,) * 2, np.uint8) if conf.erode_px > 0 else None
    keep = duplicate_names(boxes, names, scores, conf.duplicate_iou) if conf.duplicate_iou > 0 else None
    for j, (box, name) in enumerate(zip(boxes, names)):
        if keep is not None and not keep[j]:
            continue
        full = masks[j] if masks is not None else box_depth_mask(d, box)
        win = _mask_window(full, conf.erode_px if masks is not None else 0, conf.stride)
        if win is None:
            continue
        m = full[win].astype(np.uint8)
        if masks is not None and kernel is not None:
            eroded = cv2.erode(m, kernel)
            m = eroded if eroded.sum() >= conf.min_points else m
        pts = _backproject_window(d, K, m.astype(bool), win, conf.stride, conf.max_depth_m)
        if len(pts) < conf.min_points:
            continue
        if len(pts) > conf.max_points:
            rng = rng or np.random.default_rng(conf.seed + frame)
            pts = pts[rng.choice(len(pts), conf.max_points, replace=False)]
        if conf.component_link_m > 0:  # a mask that bled across a depth edge (onto the table, the next chair)
            pts = largest_components(pts, conf.component_link_m, conf.component_share)
            if len(pts) < conf.min_points:
                continue
        out.append(Observation(name, float(scores[j]), frame, t, pts, np.asarray(box, np.float32),
                               None if instance_ids is None else int(instance_ids[j])))
    return out


def _mask_window(mask: np.ndarray, margin: int, stride: int) -> tuple[slice, slice] | None:
    """Rows/cols window of `mask [H, W]` around its pixels, `margin` wider (what an erosion reads), starting on
    the stride grid: the per-detection work (erosion, lifting) runs on the window, not the whole image, with
    the same result. None for an empty mask."""
    rows, cols = np.flatnonzero(mask.any(1)), np.flatnonzero(mask.any(0))
    if not len(rows):
        return None
    H, W = mask.shape
    y0, x0 = max(0, rows[0] - margin) // stride * stride, max(0, cols[0] - margin) // stride * stride
    return slice(y0, min(H, rows[-1] + 1 + margin)), slice(x0, min(W, cols[-1] + 1 + margin))


def _depth_upto(depth: np.ndarray, max_depth_m: float) -> np.ndarray:
    """float32 depth with everything at or beyond `max_depth_m` (and NaN) set to 0 (invalid)."""
    return np.where(depth < max_depth_m, depth, 0).astype(np.float32)


def _backproject_window(depth: np.ndarray, K: np.ndarray, mask: np.ndarray, win: tuple[slice, slice],
                        stride: int, max_depth_m: float = np.inf) -> np.ndarray:
    """`geometry.backproject(_depth_upto(depth, max_depth_m), K, full_mask, stride)` points for a mask given on
    `win` (its window, starting on the stride grid): the same points in the same order. -> [N, 3]"""
    from .geometry import backproject_pixels

    d = _depth_upto(depth[win][::stride, ::stride], max_depth_m)
    ok = np.isfinite(d) & (d > 0) & mask[::stride, ::stride]
    v, u = np.nonzero(ok)
    uv = np.stack([u * stride + win[1].start, v * stride + win[0].start], 1).astype(np.float64)
    return backproject_pixels(uv, d[ok].astype(np.float64), K)


def box_depth_mask(depth: np.ndarray, box: np.ndarray, band_m: float = 0.15, band_rel: float = 0.15,
                   ring: float = 0.25, min_share: float = 0.1) -> np.ndarray:
    """Box-prompted mask [H, W] bool: the valid depth pixels inside `box [4]` of the depth layer the box was
    drawn around (|d - layer| < max(band_m, band_rel * layer)).

    The layer is the one that stands out of its surroundings (`box_layer`): of the depth modes holding
    >= `min_share` of the box's pixels, the one whose share inside the box most exceeds its share in a ring
    around it (`ring` x the box size each side). A wall or counter behind, or a table edge in front, goes on
    past the box's edges; the object ends there. Used when there is no segmenter, or the segmenter cannot
    segment the box's category (recorded as degraded by the caller)."""
    H, W = depth.shape
    x0, y0, x1, y1 = np.round(np.asarray(box, float)).astype(int)
    x0, y0, x1, y1 = max(0, x0), max(0, y0), min(W, x1), min(H, y1)
    m = np.zeros((H, W), bool)
    if x1 <= x0 or y1 <= y0:
        return m
    patch = depth[y0:y1, x0:x1]
    inside = patch[patch > 0]
    if not len(inside):
        return m
    gx, gy = int(round(ring * (x1 - x0))), int(round(ring * (y1 - y0)))
    outer = depth[max(0, y0 - gy):min(H, y1 + gy), max(0, x0 - gx):min(W, x1 + gx)].copy()
    outer[y0 - max(0, y0 - gy):y1 - max(0, y0 - gy), x0 - max(0, x0 - gx):x1 - max(0, x0 - gx)] = 0
    layer = box_layer(inside, outer[outer > 0], band_m, band_rel, min_share)
    m[y0:y1, x0:x1] = (patch > 0) & (np.abs(patch - layer) < max(band_m, band_rel * layer))
    return m


def box_layer(inside: np.ndarray, around: np.ndarray, band_m: float = 0.15, band_rel: float = 0.15,
              min_share: float = 0.1, bins: int = 48) -> float:
    """Depth (m) of the layer a box was drawn around, from its valid depths `inside [N]` and those of a ring
    `around [M]` it: each depth mode (a histogram peak in log depth) holding >= `min_share` of `inside` within
    its band scores its inside share minus its share of `around`; the best wins (ties: the nearer). Without a
    ring (a box filling the image) the score is the inside share. Pure."""
    d = np.asarray(inside, np.float64)
    lo, hi = np.log(max(float(d.min()), 1e-3)), np.log(max(float(d.max()), 1e-3))
    if hi - lo < 1e-6:
        return float(d[0])
    hist, edges = np.histogram(np.log(d), bins=bins, range=(lo, hi))
    sm = np.convolve(hist, [1, 2, 1], "same")
    peaks = [k for k in range(bins) if sm[k] > 0 and sm[k] >= sm[max(0, k - 1)] and sm[k] >= sm[min(bins - 1, k + 1)]]
    best, best_score = float(np.median(d)), -np.inf
    a = np.asarray(around, np.float64)
    for k in peaks:
        c = float(np.exp((edges[k] + edges[k + 1]) / 2))
        band = max(band_m, band_rel * c)
        share = float(np.mean(np.abs(d - c) < band))
        if share < min_share:
            continue
        score = share - (float(np.mean(np.abs(a - c) < band)) if len(a) else 0.0)
        if score > best_score + 1e-9:
            best, best_score = c, score
    return best


def duplicate_names(boxes: np.ndarray, names: list[str], scores: np.ndarray, iou: float = 0.7) -> np.ndarray:
    """Keep mask [N] over one frame's detections: a detection whose box overlaps (IoU >= `iou`) a
    higher-scored detection of another name is the same object named twice (a closed-set detector's per-class
    NMS gives "laptop" and "tv" for one screen); one detection is one object. Pure."""
    b = np.asarray(boxes, np.float64).reshape(-1, 4)
    keep = np.ones(len(b), bool)
    area = np.maximum(b[:, 2] - b[:, 0], 0) * np.maximum(b[:, 3] - b[:, 1], 0)
    for i in np.argsort(-np.asarray(scores, np.float64), kind="stable"):
        if not keep[i]:
            continue
        w = np.maximum(0, np.minimum(b[i, 2], b[:, 2]) - np.maximum(b[i, 0], b[:, 0]))
        h = np.maximum(0, np.minimum(b[i, 3], b[:, 3]) - np.maximum(b[i, 1], b[:, 1]))
        ov = w * h / np.maximum(area[i] + area - w * h, 1e-9)
        dup = (ov >= iou) & np.array([n != names[i] for n in names]) & keep
        dup[i] = False
        keep &= ~dup
    return keep


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


@dataclass
class _Acc:
    name: str
    points: np.ndarray
    score: float
    first_seen: float
    frames: list[int]
    hints: list[int]
    views: list[tuple[int, float, np.ndarray]] = field(default_factory=list)  # (frame, score, points) per detection

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
                      trace: Any = None) -> tuple[list[ObjectInstance], list[np.ndarray]]:
    """Fuse observations into instances (same name + 3D overlap or close centres), remove outliers and fit
    gravity-aligned oriented boxes (yaw from floor-projected points).

    Returns the instances and their fused point clouds ([M, 3] each, same order).
    Two observations of one name merge when >= `merge_overlap` of the new points lie within `merge_radius_m`
    of the instance's points, or when the centres are closer than `merge_centre_m` and than the larger of the
    two radii (an object seen from two sides overlaps little but shares its centre). One frame's group boxes and
    duplicate boxes of one object (`same_frame_redundant`) are left out first (the trace's `fusion` event); every
    other pair of one frame's detections stays two instances.
    """
    from .geometry import fit_gravity_box

    if conf.same_frame_share > 0:
        # one frame, one depth image: a box repeating another holds the very same surface points, so the radius is
        # the voxel size (two small objects a few cm apart do not cover each other)
        drop = same_frame_redundant(observations, conf.voxel_m, conf.same_frame_share)
        if drop:
            from .trace import as_trace

            as_trace(trace).event("fusion", f"fusion: left out {len(drop)} detection(s) that repeat others of their "
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
                             [] if ob.instance_hint is None else [ob.instance_hint], [(ob.frame, ob.score, pts)]))
        else:
            best.views.append((ob.frame, ob.score, pts))
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

    from .geometry import box_footprint as _footprint

    fa, fb = _footprint(a).astype(np.float32), _footprint(b).astype(np.float32)
    area, _ = cv2.intersectConvexConvex(fa, fb)
    small = min(polygon_area(fa), polygon_area(fb))
    return float(area / small) if small > 1e-9 else 0.0


def _merge_overlapping(items: list[tuple["_Acc", np.ndarray]], conf: FusionConfig
                       ) -> list[tuple["_Acc", np.ndarray]]:
    """Merge same-name instances whose floor footprints overlap (>= 30% of the smaller one): two views of one
    object that shared too few points to fuse (a table seen from either end). Same-category objects do not
    interpenetrate, so overlapping footprints mean one object (objects stacked on each other have other names)."""
    from .geometry import fit_gravity_box

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
                items[i] = (a, a.points)
                del items[j]
                merged = True
                break
            if merged:
                break
    return items


# ----------------------------------------------------------------------------- gravity


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


def gravity_world_transform(down_root: np.ndarray, floor_offset: float | None = None,
                            camera_height_m: float = 1.5) -> np.ndarray:
    """T [4, 4] from the root camera frame to the gravity-aligned world: z up, y = the root camera's viewing
    direction projected on the floor, x right, origin on the floor below the root camera.

    down_root: [3] gravity (down) in the root camera frame; floor_offset: d with down·p = d on the floor plane
    (distance of the floor below the root camera); when unknown, `camera_height_m` is used (a documented prior).
    """
    z = -np.asarray(down_root, float) / np.linalg.norm(down_root)
    fwd = np.array([0.0, 0.0, 1.0]) - z * z[2]  # camera z axis, horizontal part
    if np.linalg.norm(fwd) < 1e-6:  # looking straight down/up: use the camera's y axis instead
        fwd = np.array([0.0, -1.0, 0.0]) - z * (-z[1])
    y = fwd / np.linalg.norm(fwd)
    x = np.cross(y, z)
    R = np.stack([x, y, z])  # rows: world axes in root-camera coordinates -> R maps root cam to world
    h = camera_height_m if floor_offset is None else float(floor_offset)
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = np.array([0.0, 0.0, h])
    return T


# ----------------------------------------------------------------------------- occlusion refinement


def expected_visible(inst: ObjectInstance, K: np.ndarray, T_wc: np.ndarray, size: tuple[int, int],
                     depth: np.ndarray | None = None, min_px: int = 400, occlusion_tol_m: float = 0.25
                     ) -> np.ndarray | None:
    """Projected 2D box [4] of `inst` in a camera, or None when it should not be visible there (behind the
    camera, off-image, too small, or hidden: the observed depth in its projected box is mostly in front of it)."""
    from .geometry import project

    W, H = size
    uv, z = project(inst.box.corners(), K, T_wc)
    if np.any(z <= 0.1):
        return None
    x0, y0 = np.clip(uv.min(0), 0, [W - 1, H - 1])
    x1, y1 = np.clip(uv.max(0), 0, [W - 1, H - 1])
    if (x1 - x0) * (y1 - y0) < min_px:
        return None
    if depth is not None:
        from .geometry import invert, transform

        zc = transform(invert(T_wc), inst.center[None])[0, 2]
        patch = depth[int(y0):int(y1) + 1, int(x0):int(x1) + 1]
        valid = patch[patch > 0]
        if len(valid) and np.mean(valid < zc - occlusion_tol_m - 0.5 * max(inst.box.axes_lengths)) > 0.7:
            return None  # something is in front of it
    return np.array([x0, y0, x1, y1], np.float32)


# ----------------------------------------------------------------------------- the built map: gravity, extent, times
# (moved from pipeline.py: the map's own geometry; the pipeline passes its settings, this module owns the maths)


def _world_points(frames: Iterable[Any], poses: dict[int, np.ndarray], stride: int,
                  keep: Any = None) -> list[np.ndarray]:
    """Depth points of the posed frames in the poses' frame; `keep(p) -> mask` selects camera-frame points."""
    from .geometry import backproject, transform

    out = []
    for f in frames:
        if f.index in poses and f.depth is not None:
            p, _ = backproject(f.depth, f.K, stride=stride)
            out.append(transform(poses[f.index], p if keep is None else p[keep(p)]))
    return out


def _floor_below_seen(P: np.ndarray, down: np.ndarray, offset: float, trace: Any) -> float:
    """Nothing lies below the floor: when a share of the seen points does, the plane found is a table or counter
    top (the key frames did not see the floor); the floor is then at least as low as those points."""
    q = P @ down
    if np.mean(q > offset + 0.05) > 0.005:
        low = float(np.percentile(q, 99.8))
        trace.event("degraded", f"floor fit found a plane {low - offset:.2f} m above points the key frames saw "
                    f"(a table or counter top; the floor itself was not seen): floor put at the lowest seen "
                    f"points instead (objects cannot be below it; the floor height is a lower bound)",
                    stage="gravity", plane_m=offset, floor_m=low)
        return low
    return offset


def gravity_from_frames(frames: Sequence[Any], poses_root: dict[int, np.ndarray], source_down: np.ndarray | None,
                        camera_height_m: float, floor_fit_max_depth_m: float, trace: Any) -> np.ndarray:
    """World-from-root transform [4, 4] (z up, origin on the floor below the root camera). `source_down`: the
    source's gravity in the root camera (None: the floor fit on the key frames' depth points nearer than
    `floor_fit_max_depth_m` gives it); the floor height from the same fit, else `camera_height_m` (recorded)."""
    from .trace import as_trace

    trace = as_trace(trace)
    down, offset, how = None, None, ""
    if source_down is not None:
        down, how = np.asarray(source_down, float) / np.linalg.norm(source_down), "source"
    pts = _world_points(frames, poses_root, 8, lambda p: p[:, 2] < floor_fit_max_depth_m)
    P = np.concatenate(pts) if pts else np.zeros((0, 3))
    hint = down if down is not None else np.array([0.0, 1.0, 0.0])
    fit = fit_floor_plane(P, hint, max_tilt_deg=15.0 if down is not None else 35.0)
    if down is None and fit is not None:
        down, how = fit[0], "floor_fit"
    if fit is not None:
        offset = float(down @ (fit[0] * fit[1]))  # floor distance below the root camera along `down`
        if offset <= 0.3:
            offset = None
    if offset is not None and len(P):
        offset = _floor_below_seen(P, down, offset, trace)
    if down is None:
        down, how = np.array([0.0, 1.0, 0.0]), "camera_axes"
        trace.event("degraded", "no gravity from the source and no floor found: assuming the root camera is level",
                    stage="gravity")
    if offset is None:
        trace.event("degraded", f"floor height unknown: assuming the root camera is {camera_height_m} m above "
                    f"the floor", stage="gravity")
    trace.decide("gravity", {"method": how, "down_root": down.tolist(), "floor_below_root_m": offset})
    return gravity_world_transform(down, offset, camera_height_m)


def band_visibility(box: Any, views: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray]], band_m: float = 0.10,
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


def floor_support(box: Any, P: np.ndarray, band_m: float = 0.10, min_points: int = 3) -> tuple[float, bool]:
    """Support under a gravity-aligned box: of the `band_m` height bands between the floor (z = 0) and the box
    bottom, the share holding >= min_points of P [N, 3] inside the box's footprint, and whether the lowest band
    does. Pure."""
    hist = _band_counts(box, P, band_m)
    if hist is None:
        return 0.0, False
    return float(np.mean(hist >= min_points)), bool(hist[0] >= min_points)


def _band_counts(box: Any, P: np.ndarray, band_m: float) -> np.ndarray | None:
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


def extend_to_floor(instances: list[ObjectInstance], frames: Sequence[Any], poses: dict[int, np.ndarray],
                    floor_standing: Sequence[str], band_share: float, trace: Any = None, band_m: float = 0.10,
                    stride: int = 8, empty_share: float = 0.5, min_points: int = 3) -> list[int]:
    """A floor-standing object (a name in `floor_standing`) whose fused box stops above the floor (z = 0) — the
    top of a table seen from above, a chair's back over the table edge — gets its box extended down to the
    floor unless the key frames SAW open space under it (`floor_decision` on `band_visibility`): support seen
    (points in its footprint in >= `band_share` of the `band_m` bands, the lowest included) extends it; a band
    hidden from every camera by something nearer counts as unknown, not as empty; a band without points seen
    empty (depth beyond it along the rays) keeps the box as fused. Mutates the boxes; recorded (extended and
    kept, with why). Returns the ids extended."""
    from .trace import as_trace

    todo = [o for o in instances if o.name in floor_standing]
    if not todo:
        return []
    pts = _world_points(frames, poses, stride)
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
    as_trace(trace).event("extent", f"{len(done)} floor-standing object(s) extended to the floor (support seen "
                          f"or hidden under them, no open space seen): {done}; {len(kept)} kept as fused (open "
                          f"space seen under them; support share per id): {kept}", stage="extent", extended=done,
                          kept=kept, why=why)
    return done


def room_extent(instances: list[ObjectInstance], cams: list[tuple[float, np.ndarray]], frames: Sequence[Any] = (),
                poses: dict[int, np.ndarray] | None = None, trim: float = 0.5, max_depth_m: float = 8.0
                ) -> Room | None:
    """Room extent of a built map: the floor-projected hull of everything the aligned key frames' depth saw
    (walls, floor, furniture; depth in (0.1, `max_depth_m`) m, fusion's own limit), plus the object footprints
    and the camera track. Points beyond the `trim` percentile along any of 36 directions are dropped first
    (stray depth through doorways and windows). A convex hull: an L-shaped room is over-estimated, a room whose
    walls were never seen under-estimated."""
    pts = [o.box.corners()[:, :2] for o in instances] + [T[None, :2, 3] for _, T in cams]
    seen = [p[:, :2] for p in _world_points(frames, poses or {}, 12,
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
                               trace: Any = None) -> int:
    """The key-frame search ran the detector on many more frames than the key frames: a category detected
    (`detections`: (time s, names detected) per scored frame) earlier than any of its instances' key frames was
    first seen then. The earliest instance of the category takes that time (appearance-order questions are
    about categories). Mutates first_seen; returns how many changed (recorded when any)."""
    from .trace import as_trace

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
        as_trace(trace).decide("first_seen_from_search", changed)
    return changed


# ----------------------------------------------------------------------------- occlusion refinement (the stage)


def _prompt_points(inst: ObjectInstance, f: Any, box: np.ndarray, obs: list[Observation], by_index: dict[int, Any],
                   n_pts: dict[tuple[str, int], int], matcher: Any, conf_views: int) -> np.ndarray | None:
    """Point prompts for `inst` in frame f: cross-frame matches between its best views (most points) and f,
    inside both boxes; None with fewer than 3."""
    pts = []
    views = sorted(inst.frames, key=lambda g: -n_pts.get((inst.name, g), 0))[:conf_views]
    for g_idx in views:  # matches between a view that has it and this frame, inside both boxes
        g = by_index.get(g_idx)
        if g is None:
            continue
        gb = [o.box2d for o in obs if o.frame == g_idx and o.name == inst.name]
        if not gb:
            continue
        m = matcher.match_keys(g.index, g.rgb, f.index, f.rgb, np.stack(gb), box[None])  # cached features
        if len(m.uv1):
            pts.append(m.uv1)
    if not pts:
        return None
    P = np.concatenate(pts)
    P = P[(P[:, 0] >= box[0]) & (P[:, 0] <= box[2]) & (P[:, 1] >= box[1]) & (P[:, 1] <= box[3])]
    return P if len(P) >= 3 else None


def _recover_mask(inst: ObjectInstance, f: Any, box: np.ndarray, perception: Any, prompts: Any
                  ) -> np.ndarray | None:
    """The re-prompted mask: a promptable segmenter on the point prompts (`prompts()`), else a semantic
    segmenter's class mask inside the projected box."""
    mask = None
    if perception.segment_points is not None:
        P = prompts()
        if P is not None:
            mask = perception.segment_points(f, P[:16], inst.name)
    if mask is None and perception.segment_class is not None:
        cls = perception.segment_class(f, inst.name)
        if cls is not None:
            x0, y0, x1, y1 = np.round(box).astype(int)
            mask = np.zeros(cls.shape, bool)
            mask[y0:y1 + 1, x0:x1 + 1] = cls[y0:y1 + 1, x0:x1 + 1]
    return mask


def refine(instances: list[ObjectInstance], obs: list[Observation], frames: list[Any],
           poses: dict[int, np.ndarray], dets: dict[int, Any], perception: Any,
           conf: FusionConfig, trace: Any, conf_views: int = 2, matcher: Any = None
           ) -> tuple[list[ObjectInstance], list[np.ndarray], int]:
    """Paper, occlusion refinement: project every instance into each key frame; where it should be visible but
    was not segmented, re-prompt the segmenter — with point prompts from cross-frame matches inside its other
    views (promptable segmenter), or the class mask inside the projected box (semantic segmenter) — and add what
    it recovers. `perception`: the pipeline's `Perception` (segment_points, segment_class, matcher). Returns the
    re-fused instances, their clouds and how many instances gained a view."""
    from .matching import make_matcher
    from .trace import as_trace

    matcher = make_matcher(matcher if matcher is not None else perception.matcher)
    by_index = {f.index: f for f in frames}
    n_pts: dict[tuple[str, int], int] = {}  # (instance name, frame) -> points of its observation there
    for o in obs:
        n_pts[(o.name, o.frame)] = max(n_pts.get((o.name, o.frame), 0), len(o.points))
    found: dict[tuple[int, int], list[Observation]] = {}  # (instance position, frame position) -> recovered
    # frame-major: a semantic segmenter caches its class map for the last image, so all instances of one frame
    # share one segmenter run; the result is put back in instance-major order below (same fusion input)
    for fi, f in enumerate(frames):
        if f.index not in poses:
            continue
        for ii, inst in enumerate(instances):
            if f.index in set(inst.frames):
                continue
            box = expected_visible(inst, f.K, poses[f.index], (f.rgb.shape[1], f.rgb.shape[0]), f.depth)
            if box is None:
                continue
            mask = _recover_mask(inst, f, box, perception, lambda: _prompt_points(
                inst, f, box, obs, by_index, n_pts, matcher, conf_views))
            if mask is None or mask.sum() < conf.min_points:
                continue
            lifted = lift_observations(f.rgb.shape[:2], f.depth, f.K, poses[f.index], box[None], [inst.name],
                                       np.array([inst.score * 0.9]), mask[None], f.index, f.t, conf)
            for ob in lifted:  # keep only what agrees with the instance (the prompt may have hit an occluder)
                inside = inst.box.contains(ob.points, margin=0.15)
                if inside.mean() >= 0.5:
                    ob.points = ob.points[inside]
                    ob.recovered = True
                    found.setdefault((ii, fi), []).append(ob)
    new_obs = [ob for key in sorted(found) for ob in found[key]]
    gained = {instances[ii].id for ii, _ in found}
    if not new_obs:
        return instances, [np.zeros((0, 3))] * len(instances), 0
    as_trace(trace).event("refinement", f"occlusion refinement recovered {len(new_obs)} view(s) of {len(gained)} "
                          f"instance(s)", views=len(new_obs), instances=len(gained))
    inst2, clouds = fuse_observations(obs + new_obs, conf, trace)
    return inst2, clouds, len(gained)
