"""The sparse global semantic map: object instances with oriented 3D boxes in a gravity-aligned world (z up,
metres; boxes in the VSI-Bench meta_info format, `geometry.OrientedBox`), the room extent and the camera track,
with JSON save/load checked field by field.

A map built from boxes alone (`SemanticMap.from_meta_info`) takes its room from the boxes (`room_from_boxes`: the
hull of their floor-projected corners, floor = lowest bottom, ceiling = highest top); a map built from video takes
the hull of what the key frames' depth saw (`extent.room_extent`). The benchmark's own room size is never copied.
"""
from __future__ import annotations

import gc
import json
import os
import re
from contextlib import contextmanager
from dataclasses import dataclass, field
from operator import attrgetter
from typing import Any, Iterable, Iterator

import numpy as np

from ..geometry import OrientedBox, convex_hull_2d, polygon_area
from ..grounding import canonical_name
from ..infra import jsonio
from ..infra.errors import InputError, path_kind
from ..infra.file_schemas import check_map
from ..infra.trace import jsonable


MAP_SCHEMA = "mosaicthinker.semantic_map/1"


# Largest saved map the runtime reads: a room holds hundreds of objects; 100 k leaves room for dense maps and keeps
# every question (validation + answer) around a second. Larger maps are refused, not answered slowly.
MAX_MAP_OBJECTS = 100_000


MAX_MAP_BYTES = 256 << 20


def _no_json_constant(name: str) -> Any:
    raise ValueError(f"{name} is not a number a map may hold")


def validate_map_dict(d: Any, where: str = "semantic map") -> None:
    """Check a saved map before use against its schema (`infra.file_schemas.map_spec`: types, ranges, orthonormal
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

    def box_arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Every instance's box as stacked arrays: centroids [N, 3], axis lengths [N, 3], axes [N, 3, 3] (rows),
        kept until an instance or a box is replaced (a big map's image, text, checks and file read them once)."""
        key = _box_key(self.instances)
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
        smap.__dict__["_boxes"] = (_box_key(instances), arrays)  # the boxes are views of them
        return smap

    def json_text(self, **extra: Any) -> str:
        """The JSON of `to_dict()` (plus `extra` top-level fields, e.g. a run id), one line per object, written
        from the stacked box numbers without building a dict per object (`_instance_lines`): a 100 k-object map
        in about a second."""
        d = self.to_dict(instances=False)
        d.update(extra)
        head = ",\n".join(f" {jsonio.dumps(k)}: {jsonio.dumps(v)}" for k, v in d.items())
        lines = _instance_lines(self.instances, self.box_arrays())
        return "{\n" + head + ',\n "instances": [\n  ' + ",\n  ".join(lines) + "\n ]\n}\n"

    def json_bytes(self, **extra: Any) -> bytes:
        """`json_text(**extra)` as UTF-8; a map read by `load` and unchanged since is its file's own text with the
        `extra` fields set (`_with_fields`): a 100 k-object map's map.json is a copy, not a re-encoding."""
        src = self.__dict__.get("_source")
        if src is not None and src[2] == self._state():
            out = _with_fields(src[0], src[1], extra)
            if out is not None:
                return out
        return self.json_text(**extra).encode()

    def _state(self) -> tuple[Any, ...]:
        """Everything the map holds, to tell whether it changed since it was read (`json_bytes`)."""
        C, L, A = self.box_arrays()
        rows = [(o.id, o.name, o.first_seen, o.score, o.n_points, tuple(o.frames), repr(o.views) if o.views else "")
                for o in self.instances]
        return rows, C.tobytes(), L.tobytes(), A.tobytes(), jsonio.dumps(self.to_dict(instances=False), default=str)

    def save(self, path: str | os.PathLike) -> None:
        with open(path, "wb") as f:
            f.write(self.json_bytes())

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
        except OSError as e:
            raise InputError(f"{path}: cannot read the semantic map ({e}); build one with `mosaic map`") from e
        with _gc_paused():  # millions of parsed values: the cyclic collector would walk them all again and again
            try:
                d = json.loads(raw.decode("utf-8"), parse_constant=_no_json_constant)
            except (ValueError, RecursionError) as e:
                raise InputError(f"{path}: cannot read the semantic map ({e}); build one with `mosaic map`") from e
            smap = cls.from_dict(d, str(path))
            smap.__dict__["_source"] = (raw, frozenset(d), smap._state())  # what `json_bytes` may copy
            del d  # freed before the collector is back: it would walk every parsed value once more
        return smap

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
    rows = np.concatenate([C, L, A.reshape(n, 9), corners.min(1), corners.max(1)], 1)
    scores = np.fromiter((float(o.score) for o in instances), np.float64, n)
    bad = np.flatnonzero(~(np.isfinite(rows).all(1) & np.isfinite(scores)))
    if len(bad):  # repr would write `nan`: not JSON, and no reader (this one included) takes it back
        who = ", ".join(f"{instances[int(i)].name} #{instances[int(i)].id}" for i in bad[:3])
        raise ValueError(f"cannot write the map: {who} hold NaN or infinity in their box or score")
    rows = rows.tolist()
    names: dict[str, str] = {}
    out = []
    for o, r in zip(instances, rows):
        name = names.get(o.name) or names.setdefault(o.name, jsonio.dumps(o.name))
        fs = "null" if o.first_seen is None else repr(float(o.first_seen))
        frames = jsonio.dumps([int(f) for f in o.frames]) if o.frames else "[]"
        views = f', "views": {jsonio.dumps([_plain(v) for v in o.views])}' if o.views else ""
        out.append(_LINE % (int(o.id), name, *r, fs, float(o.score), int(o.n_points), frames, views))
    return out


def _instances_from_dicts(items: list[dict[str, Any]]
                          ) -> tuple[list[ObjectInstance], tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """`[ObjectInstance.from_dict(o) for o in items]` (dicts the map schema accepted: ids and n_points are ints,
    names strings) with the box arrays built at once; returns (instances, (centroids [N, 3], lengths [N, 3], axes
    [N, 3, 3])), the boxes being views of them."""
    n = len(items)
    if not n:
        return [], (np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3, 3)))
    boxes = [o["box"] for o in items]
    C = np.array([b["centroid"] for b in boxes], np.float64).reshape(n, 3)
    L = np.array([b["axesLengths"] for b in boxes], np.float64).reshape(n, 3)
    A = np.array([b["normalizedAxes"] for b in boxes], np.float64).reshape(n, 3, 3)
    out = []
    for d, box in zip(items, map(OrientedBox, C, L, A)):
        fs = d.get("first_seen")
        out.append(ObjectInstance(d["id"], d["name"], box, None if fs is None else float(fs),
                                  float(d.get("score", 1.0)), d.get("n_points", 0), list(d.get("frames", ())),
                                  list(d.get("views", ()))))
    return out, (C, L, A)


@contextmanager
def _gc_paused() -> Iterator[None]:
    """The cyclic garbage collector off for a block that builds many objects and no cycles (reading a map: a
    100 k-object file parsed in about 2/3 of the time); back as it was after."""
    was = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was:
            gc.enable()


def _box_key(instances: list[ObjectInstance]) -> tuple[int, ...]:
    """Identity of every instance's box: the stacked box arrays are kept while it is unchanged (a box is a value:
    new numbers are a new `OrientedBox`; the boxes of a loaded map are views of the arrays, so edits show)."""
    return tuple(map(id, map(_BOX, instances)))


_BOX = attrgetter("box")
_STRING = re.compile(rb'"(?:[^"\\]|\\.)*"')


def _with_fields(raw: bytes, keys: frozenset[str], extra: dict[str, Any]) -> bytes | None:
    """The JSON text `raw` of an object (top-level `keys`) with the string fields `extra` set: a field it lacks is
    inserted after its `{`; one it has is replaced where the text holds it, found as the only `"key":` in the
    text (a second one, e.g. in `meta`, and None is returned: the caller re-encodes)."""
    body = raw.lstrip()
    if not body.startswith(b"{"):
        return None
    start, head = len(raw) - len(body) + 1, []
    for k, v in extra.items():
        key, val = jsonio.dumps(k).encode(), jsonio.dumps(v).encode()
        if not isinstance(v, str):
            return None
        if k not in keys:
            head.append(key + b": " + val)
            continue
        hits = list(re.finditer(re.escape(key) + rb"\s*:\s*", raw))
        old = _STRING.match(raw, hits[0].end()) if len(hits) == 1 else None
        if old is None:
            return None
        raw = raw[:old.start()] + val + raw[old.end():]
    return raw[:start] + b"".join(h + b", " for h in head) + raw[start:] if head else raw


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
