"""The sparse global semantic map: object instances with oriented 3D boxes in a gravity-aligned world.

World frame (see ARCHITECTURE.md): z up, metres. Boxes follow the VSI-Bench meta_info format
(`geometry.OrientedBox`, `normalizedAxes` rows are the box axes).

This file holds the map *data structures* first (`ObjectInstance`, `Room`, `SemanticMap`, JSON save/load,
`SemanticMap.from_meta_info`); the fusion functions that build a map from perception (per-frame points ->
instances, occlusion refinement) follow further down.

Room extent of a map built from boxes only (`room_from_boxes`): the floor polygon is the 2D convex hull of the
floor-projected corners of every object box (the area the furnished space spans at least); floor z is the lowest
box bottom, ceiling z the highest box top. A map built from video may instead set the room from the camera
track and the floor fit. The benchmark's own `room_size`/`room_center` fields are never copied into the map
(`meta` keeps only the scene name and dataset), so room-size answers come from the map's extent.
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from typing import Any, Iterable

import numpy as np

from .errors import InputError
from .geometry import OrientedBox, convex_hull_2d, polygon_area

MAP_SCHEMA = "mosaicthinker.semantic_map/1"


# ----------------------------------------------------------------------------- data structures


@dataclass
class ObjectInstance:
    """One object in the map.

    id: unique within the map; name: canonical vocabulary name (`grounding.canonical_name`);
    box: oriented box in the z-up metric world; first_seen: video time (s) of the first frame showing it, or None
    when unknown (e.g. a map built from benchmark boxes); score: detection confidence (1.0 for ground truth);
    n_points: 3D points fused into it (0 for ground truth); frames: indices of the frames it was seen in.
    """

    id: int
    name: str
    box: OrientedBox
    first_seen: float | None = None
    score: float = 1.0
    n_points: int = 0
    frames: list[int] = field(default_factory=list)

    @property
    def center(self) -> np.ndarray:
        """Box centre `[3]` (m)."""
        return np.asarray(self.box.centroid, dtype=np.float64)

    def to_dict(self) -> dict[str, Any]:
        return {"id": int(self.id), "name": self.name, "box": self.box.to_meta(),
                "first_seen": None if self.first_seen is None else float(self.first_seen),
                "score": float(self.score), "n_points": int(self.n_points), "frames": [int(f) for f in self.frames]}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "ObjectInstance":
        return cls(int(d["id"]), str(d["name"]), OrientedBox.from_meta(d["box"]),
                   None if d.get("first_seen") is None else float(d["first_seen"]),
                   float(d.get("score", 1.0)), int(d.get("n_points", 0)), [int(f) for f in d.get("frames", [])])


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
        return [o for o in self.instances if (canonical_name(o.name) or o.name.lower()) == key]

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

    def room_area(self) -> float | None:
        """Floor area (m^2) of the map's room extent; None when the map has neither a room nor objects."""
        room = self.room if self.room is not None else room_from_boxes([o.box for o in self.instances])
        return None if room is None else room.area()

    # -- serialisation
    def to_dict(self) -> dict[str, Any]:
        return {"schema": MAP_SCHEMA,
                "instances": [o.to_dict() for o in self.instances],
                "room": None if self.room is None else self.room.to_dict(),
                "cameras": [{"t": float(t), "T_wc": np.asarray(T, dtype=np.float64).tolist()} for t, T in self.cameras],
                "meta": _plain(self.meta)}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "SemanticMap":
        schema = d.get("schema")
        if schema != MAP_SCHEMA:
            raise InputError(f"semantic map: field `schema` is {schema!r}, expected {MAP_SCHEMA!r} "
                             f"(rebuild the map with `mosaic map`)")
        return cls([ObjectInstance.from_dict(o) for o in d.get("instances", [])],
                   None if d.get("room") is None else Room.from_dict(d["room"]),
                   [(float(c["t"]), np.asarray(c["T_wc"], dtype=np.float64).reshape(4, 4))
                    for c in d.get("cameras", [])],
                   dict(d.get("meta", {})))

    def save(self, path: str | os.PathLike) -> None:
        with open(path, "w") as f:
            json.dump(self.to_dict(), f, indent=1)

    @classmethod
    def load(cls, path: str | os.PathLike) -> "SemanticMap":
        try:
            with open(path) as f:
                d = json.load(f)
        except (OSError, json.JSONDecodeError) as e:
            raise InputError(f"{path}: cannot read the semantic map ({e}); build one with `mosaic map`") from e
        return cls.from_dict(d)

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


def room_from_boxes(boxes: Iterable[OrientedBox], extra_xy: np.ndarray | None = None) -> Room | None:
    """Room extent spanned by object boxes: convex hull of the floor-projected corners (plus `extra_xy [M, 2]`,
    e.g. camera positions of a walk-through, which also lie inside the room), floor = lowest box bottom,
    ceiling = highest box top. None without boxes. A lower bound of the true floor area: the space between the
    furniture and the walls is not seen by boxes alone."""
    corners = [b.corners() for b in boxes]
    if not corners:
        return None
    c = np.concatenate(corners, 0)
    xy = c[:, :2] if extra_xy is None else np.concatenate([c[:, :2], np.asarray(extra_xy, np.float64).reshape(-1, 2)])
    src = "object_boxes_hull" if extra_xy is None else "object_boxes_and_cameras_hull"
    return Room(convex_hull_2d(xy), float(c[:, 2].min()), float(c[:, 2].max()), src)


def _plain(x: Any) -> Any:
    from .trace import jsonable

    return jsonable(x)
