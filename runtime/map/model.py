"""The sparse global semantic map: object instances with oriented 3D boxes in a gravity-aligned world (z up,
metres; boxes in the VSI-Bench meta_info format, `geometry.OrientedBox`), the room extent and the camera track,
with JSON save/load checked field by field.

A map built from boxes alone (`SemanticMap.from_meta_info`) takes its room from the boxes (`room_from_boxes`: the
hull of their floor-projected corners, floor = lowest bottom, ceiling = highest top); a map built from video takes
the hull of what the key frames' depth saw (`extent.room_extent`). The benchmark's own room size is never copied.
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from typing import Any, Iterable

import numpy as np

from ..geometry import OrientedBox, convex_hull_2d, polygon_area
from ..grounding import canonical_name
from ..infra.errors import InputError
from ..infra.trace import jsonable


MAP_SCHEMA = "mosaicthinker.semantic_map/1"


# Largest saved map the runtime reads: a room holds hundreds of objects; 100 k leaves room for dense maps and keeps
# every question (validation + answer) around a second. Larger maps are refused, not answered slowly.
MAX_MAP_OBJECTS = 100_000


MAX_MAP_BYTES = 256 << 20


def _no_json_constant(name: str) -> Any:
    raise ValueError(f"{name} is not a number a map may hold")


def _map_error(where: str, field_: str, what: str) -> InputError:
    return InputError(f"{where}: {field_} {what}; rebuild the map with `mosaic map` or fix that field")


def _finite_array(v: Any, shape: tuple[int, ...], where: str, field_: str) -> np.ndarray:
    try:
        a = np.asarray(v, dtype=np.float64)
    except (TypeError, ValueError):
        raise _map_error(where, field_, f"must be numbers of shape {list(shape)}") from None
    if a.size == 0 and shape and shape[0] == 0:  # an empty map's stacked fields: [] is shape (0,), not (0, 3)
        a = a.reshape(shape)
    if a.shape != shape:
        raise _map_error(where, field_, f"has shape {list(a.shape)}, expected {list(shape)}")
    if not np.isfinite(a).all():
        raise _map_error(where, field_, "holds NaN or infinity")
    return a


def validate_map_dict(d: Any, where: str = "semantic map") -> None:
    """Check a saved map before use: schema, `instances` present (a missing list is not an empty map), every
    instance's id/name/box, finite box numbers, positive sizes, orthonormal axes (zero axes would give wrong
    distances), unique ids, finite cameras and room. Raises InputError naming the field. Vectorised over
    instances (a 100 k-object map validates in well under a second)."""
    if not isinstance(d, dict):
        raise _map_error(where, "the top level", "must be a JSON object")
    if d.get("schema") != MAP_SCHEMA:
        raise InputError(f"{where}: field `schema` is {d.get('schema')!r}, expected {MAP_SCHEMA!r} "
                         f"(rebuild the map with `mosaic map`)")
    inst = d.get("instances")
    if not isinstance(inst, list):
        raise _map_error(where, "`instances`", "is missing or not a list (an empty map is `\"instances\": []`)")
    if len(inst) > MAX_MAP_OBJECTS:
        raise InputError(f"{where}: {len(inst)} objects; at most {MAX_MAP_OBJECTS} are supported; split the scene "
                         f"or map fewer object kinds")
    cents, lens, axes, ids = [], [], [], []
    for i, o in enumerate(inst):
        f = f"instances[{i}]"
        if not isinstance(o, dict) or not isinstance(o.get("box"), dict):
            raise _map_error(where, f"{f}.box", "is missing (each instance needs id, name and box)")
        if not isinstance(o.get("id"), int) or isinstance(o.get("id"), bool):
            raise _map_error(where, f"{f}.id", "is missing or not an integer")
        if not isinstance(o.get("name"), str) or not o["name"].strip():
            raise _map_error(where, f"{f}.name", "is missing or empty")
        b = o["box"]
        for k in ("centroid", "axesLengths", "normalizedAxes"):
            if k not in b:
                raise _map_error(where, f"{f}.box.{k}", "is missing")
        if o.get("first_seen") is not None and not (isinstance(o["first_seen"], (int, float))
                                                    and np.isfinite(o["first_seen"])):
            raise _map_error(where, f"{f}.first_seen", "must be a finite number or null")
        ids.append(o["id"])
        cents.append(b["centroid"])
        lens.append(b["axesLengths"])
        axes.append(b["normalizedAxes"])
    n = len(inst)
    c = _finite_array(cents, (n, 3), where, "instances[*].box.centroid")
    ln = _finite_array(lens, (n, 3), where, "instances[*].box.axesLengths")
    ax = _finite_array(axes, (n, 9), where, "instances[*].box.normalizedAxes").reshape(n, 3, 3)
    del c
    bad = np.flatnonzero((ln <= 0).any(1))
    if len(bad):
        raise _map_error(where, f"instances[{bad[0]}].box.axesLengths", f"is {ln[bad[0]].tolist()}: sizes must be > 0")
    ortho = np.abs(ax @ ax.transpose(0, 2, 1) - np.eye(3)).max(axis=(1, 2)) if n else np.zeros(0)
    bad = np.flatnonzero(ortho > 1e-2)
    if len(bad):
        raise _map_error(where, f"instances[{bad[0]}].box.normalizedAxes", "must be three orthonormal rows "
                         "(unit length, perpendicular)")
    if len(set(ids)) != n:
        raise _map_error(where, "instances[*].id", "has duplicates; ids must be unique")
    _validate_cameras_room(d, where)


def _validate_cameras_room(d: dict[str, Any], where: str) -> None:
    cams = d.get("cameras", [])
    if not isinstance(cams, list):
        raise _map_error(where, "`cameras`", "must be a list")
    for i, cam in enumerate(cams):
        if not isinstance(cam, dict) or "T_wc" not in cam or "t" not in cam:
            raise _map_error(where, f"cameras[{i}]", "needs `t` and `T_wc`")
        _finite_array(cam["t"], (), where, f"cameras[{i}].t")
        T = _finite_array(cam["T_wc"], (4, 4), where, f"cameras[{i}].T_wc")
        if not np.allclose(T[3], [0, 0, 0, 1]) or abs(np.linalg.det(T[:3, :3]) - 1) > 1e-2:
            raise _map_error(where, f"cameras[{i}].T_wc", "is not a rigid pose (rotation + translation)")
    room = d.get("room")
    if room is not None:
        if not isinstance(room, dict) or "polygon" not in room:
            raise _map_error(where, "`room`", "needs `polygon`, `floor_z` and `ceiling_z`")
        poly = np.asarray(room["polygon"], dtype=object)
        _finite_array(room["polygon"], (len(poly), 2), where, "room.polygon")
        fz = _finite_array(room.get("floor_z"), (), where, "room.floor_z")
        cz = _finite_array(room.get("ceiling_z"), (), where, "room.ceiling_z")
        if cz <= fz:
            raise _map_error(where, "room.ceiling_z", "must be above room.floor_z")


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
        key = canonical_name(name) or name.strip().lower()
        return list(self._category_index().get(key, ()))

    def _category_index(self) -> dict[str, list[ObjectInstance]]:
        """canonical name -> instances, rebuilt only when the instance list changed (a question on a 10 k-object
        map asks for names many times; canonicalising every instance name per call took seconds)."""
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
    def to_dict(self) -> dict[str, Any]:
        return {"schema": MAP_SCHEMA,
                "instances": [o.to_dict() for o in self.instances],
                "room": None if self.room is None else self.room.to_dict(),
                "cameras": [{"t": float(t), "T_wc": np.asarray(T, dtype=np.float64).tolist()} for t, T in self.cameras],
                "meta": _plain(self.meta)}

    @classmethod
    def from_dict(cls, d: dict[str, Any], where: str = "semantic map") -> "SemanticMap":
        """A map from its JSON form, validated first (`validate_map_dict`): a bad field raises InputError naming
        it instead of crashing a renderer or answering from NaN / negative sizes."""
        validate_map_dict(d, where)
        return cls([ObjectInstance.from_dict(o) for o in d["instances"]],
                   None if d.get("room") is None else Room.from_dict(d["room"]),
                   [(float(c["t"]), np.asarray(c["T_wc"], dtype=np.float64).reshape(4, 4))
                    for c in d.get("cameras", [])],
                   dict(d.get("meta", {})))

    def save(self, path: str | os.PathLike) -> None:
        with open(path, "w") as f:
            json.dump(self.to_dict(), f, indent=1)

    @classmethod
    def load(cls, path: str | os.PathLike) -> "SemanticMap":
        """Read and validate a saved map; maps over MAX_MAP_BYTES / MAX_MAP_OBJECTS are refused."""
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
        inst: list[ObjectInstance] = []
        for cat, boxes in scene_meta["object_bbox"].items():
            name = canonical_name(cat) or cat.strip().lower()
            for b in boxes:
                inst.append(ObjectInstance(len(inst), name, OrientedBox.from_meta(b)))
        meta = {"source": "meta_info", "scene_name": scene_name, "dataset": scene_meta.get("dataset")}
        return cls(inst, room_from_boxes([o.box for o in inst]), [], meta)


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
    return jsonable(x)
