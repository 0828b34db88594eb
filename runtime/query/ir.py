"""The question as a typed program: one frozen dataclass per node of the query language.

A question is a `Program`: one node saying what is asked (`Count`, `Size`, `Distance`, `Nearest`, `Direction`,
`Route` ...) and the options of a multiple-choice question. Nodes name objects through `Ref`s (a name, the question's
own words, and selectors that pick one instance: `Superlative`, `NearestTo`, `InstanceId`, `Described`); locations
(`Relation`) and sides (`ViewerSide`, `SeenSide`, `StanceSide`) are small nodes of their own. The rule parser
(`query.rules`, `query.templates`) and the VLM (`query.vlm`, constrained by `query.schema.json_schema`) emit the same
program; `answer.execute` runs it on a map.

Conventions: lengths the question compares against are integers in millimetres, areas in square centimetres
(exact for any decimal a person types, and bounded for constrained decoding); the viewer (where the video ended)
is `None` where a node takes an optional object; `EVERYTHING` (name "*") stands for every object of the map.
Each node knows its VSI-Bench-style type name (`qtype`), its targets and cues (the objects key-frame search looks
for first and second), and whether it needs the whole map (`whole_map`). Pure data: imports nothing but typing.
"""
from __future__ import annotations

from dataclasses import dataclass, field, fields, is_dataclass, replace
from typing import Any, Callable, ClassVar, Iterator, Literal, Union

SCHEMA_VERSION = "mosaicthinker.query/1"

# the VSI-Bench question types (the templates' names; `Node.qtype` adds the types people ask beyond them)
QTYPES = ("object_counting", "object_size_estimation", "room_size_estimation", "object_abs_distance",
          "object_rel_distance", "object_rel_direction_easy", "object_rel_direction_medium",
          "object_rel_direction_hard", "route_planning", "obj_appearance_order")

# length units of the questions, in metres
UNIT_M = {"m": 1.0, "cm": 0.01, "mm": 0.001, "ft": 0.3048, "in": 0.0254}
# size word -> (box measure, pick): one table for selectors ("the biggest table") and size comparisons
SUPERLATIVES = {"biggest": ("volume", max), "largest": ("volume", max), "smallest": ("volume", min),
                "tallest": ("height", max), "shortest": ("height", min), "highest": ("top", max),
                "lowest": ("top", min), "longest": ("length", max), "widest": ("width", max),
                "narrowest": ("width", min)}
COMPARATIVES = {"bigger": "biggest", "larger": "largest", "smaller": "smallest", "taller": "tallest",
                "shorter": "shortest", "higher": "highest", "lower": "lowest", "longer": "longest",
                "wider": "widest", "narrower": "narrowest"}
SupWord = Literal["biggest", "largest", "smallest", "tallest", "shortest", "highest", "lowest", "longest", "widest",
                  "narrowest"]
LengthUnit = Literal["cm", "m", "mm", "ft", "in"]
Side = Literal["left", "right", "front", "back"]
DirWord = Literal["left", "right", "front", "back", "front-left", "front-right", "back-left", "back-right"]
CmpOp = Literal["<", "<=", ">", ">="]
Extreme = Literal["closest", "farthest"]

NAME = {"min_length": 1, "max_length": 80}  # object names and phrases: bounded for constrained decoding
TEXT = {"max_length": 80}


def _many(lo: int = 0, hi: int = 12) -> dict[str, int]:
    return {"min_items": lo, "max_items": hi}


# ----------------------------------------------------------------------------- selectors and references


@dataclass(frozen=True)
class Superlative:
    """"the biggest table": the instance with the extreme box measure (`SUPERLATIVES[word]`)."""

    KIND: ClassVar[str] = "superlative"
    word: SupWord


@dataclass(frozen=True)
class NearestTo:
    """"the chair nearest the door": the instance closest (closest points) to any instance of `name`."""

    KIND: ClassVar[str] = "nearest_to"
    name: str = field(metadata=NAME)
    phrase: str = field(default="", metadata=TEXT)

    @property
    def words(self) -> str:
        return self.phrase or self.name


@dataclass(frozen=True)
class InstanceId:
    """"chair #3": the map instance with this id."""

    KIND: ClassVar[str] = "instance"
    id: int = field(metadata={"minimum": 0, "maximum": 10_000_000})


@dataclass(frozen=True)
class Described:
    """"the red chair", "the second cup": words a map does not hold (colours, materials, ordinals); they resolve
    only when the map has a category named by the whole phrase, else the question is unsupported, saying so."""

    KIND: ClassVar[str] = "described"
    words: tuple[str, ...] = field(metadata={**_many(1, 6), "item": NAME})
    phrase: str = field(metadata=NAME)


@dataclass(frozen=True)
class At:
    """"the laptop on the desk", "the chair by the window": the instances that are `relation` an instance of
    `name` (tested on the boxes, as a count's location)."""

    KIND: ClassVar[str] = "at"
    relation: Literal["on", "near", "in", "under", "above"]
    name: str = field(metadata=NAME)
    phrase: str = field(default="", metadata=TEXT)

    @property
    def words(self) -> str:
        return self.phrase or self.name


@dataclass(frozen=True)
class Closest:
    """"the closest sofa", "the farthest chair" with no object to measure from: from the viewer (in a route, the
    walker's position; else the last camera)."""

    KIND: ClassVar[str] = "closest"
    extreme: Extreme = "closest"


Selector = Union[Superlative, NearestTo, InstanceId, Described, At, Closest]


@dataclass(frozen=True)
class Ref:
    """An object the question names. name: the vocabulary name ("sofa" for "couch"), an open-vocabulary name as
    written ("computer tower"), or "*" (every object); phrase: the question's own words ("" = the name); known:
    the name is in the vocabulary; select: how one instance is picked (applied in order, `Described` first)."""

    name: str = field(metadata=NAME)
    phrase: str = field(default="", metadata=TEXT)
    known: bool = True
    select: tuple[Selector, ...] = field(default=(), metadata=_many(0, 4))

    @property
    def words(self) -> str:
        return self.phrase or self.name


EVERYTHING = Ref("*", "everything")


def everything(r: Ref) -> bool:
    return r.name == "*"


@dataclass(frozen=True)
class Relation:
    """A location the map can test on boxes: A `relation` B (or between B and `object2`); negate: the others
    ("cups not on the table")."""

    KIND: ClassVar[str] = "relation"
    relation: Literal["on", "near", "in", "under", "above", "between"]
    object: Ref
    object2: Ref | None = None
    negate: bool = False


@dataclass(frozen=True)
class ViewerSide:
    """Every object on that side of the viewer (the last camera, where the video ended)."""

    KIND: ClassVar[str] = "viewer_side"
    side: Side


@dataclass(frozen=True)
class SeenSide:
    """Every other object on that side of `reference`, as seen from the last camera."""

    KIND: ClassVar[str] = "seen_side"
    reference: Ref
    side: Side


@dataclass(frozen=True)
class StanceSide:
    """Every other object on that side of someone standing at `stand` facing `face`."""

    KIND: ClassVar[str] = "stance_side"
    stand: Ref
    face: Ref
    side: Side


Region = Union[Relation, ViewerSide, SeenSide, StanceSide]


@dataclass(frozen=True)
class CountCondition:
    """"are there two chairs?" (== 2), "more than one" (> 1)."""

    op: Literal["==", "<", "<=", ">", ">="]
    n: int = field(metadata={"minimum": 0, "maximum": 1000})


@dataclass(frozen=True)
class DistanceCondition:
    """"within 2 m of", "more than half a metre from": the distance against a length (mm); text: as asked."""

    op: CmpOp
    threshold_mm: int = field(metadata={"minimum": 0, "maximum": 1_000_000})
    text: str = field(default="", metadata=TEXT)


@dataclass(frozen=True)
class AreaCondition:
    """"is the room bigger than 20 square meters?": the area against a number (cm^2); text: as asked."""

    op: Literal["<", ">"]
    threshold_cm2: int = field(metadata={"minimum": 0, "maximum": 10_000_000_000})
    text: str = field(default="", metadata=TEXT)


# ----------------------------------------------------------------------------- nodes


class _Node:
    """Shared behaviour of the question nodes (each a frozen dataclass with a `KIND`)."""

    KIND: ClassVar[str]

    @property
    def qtype(self) -> str:
        return _QTYPE[self.KIND]

    def roles(self) -> tuple[list[str], list[str]]:
        """(targets, cues): names of the objects asked about and of the reference objects (ranked)."""
        return [r.name for r in iter_refs(self)], []

    @property
    def whole_map(self) -> bool:
        """About everything in the map: the map is built for every category the detector names."""
        return any(everything(r) for r in iter_refs(self))


@dataclass(frozen=True)
class Count(_Node):
    """How many: one count per object ("how many chairs and cups?"); objects[0] "*": every object; where: only
    those at a location."""

    KIND: ClassVar[str] = "count"
    objects: tuple[Ref, ...] = field(metadata=_many(1, 12))
    where: Relation | None = None

    def roles(self) -> tuple[list[str], list[str]]:
        if self.where is not None:
            return [r.name for r in self.objects if not everything(r)], _where_names(self.where)
        if everything(self.objects[0]):
            return [], []
        return [r.name for r in self.objects], []


@dataclass(frozen=True)
class Exists(_Node):
    """Is there ...: any (all: every) of the objects, at a location, or a number of them (`count`)."""

    KIND: ClassVar[str] = "exists"
    objects: tuple[Ref, ...] = field(metadata=_many(1, 12))
    all: bool = False
    where: Relation | None = None
    count: CountCondition | None = None

    def roles(self) -> tuple[list[str], list[str]]:
        return [r.name for r in self.objects], _where_names(self.where) if self.where else []


@dataclass(frozen=True)
class CountCompare(_Node):
    """More (fewer) of a than of b: yes / no, which, or the difference."""

    KIND: ClassVar[str] = "count_compare"
    a: Ref
    b: Ref
    compare: Literal["more", "fewer"] = "more"
    form: Literal["yesno", "which", "difference"] = "yesno"


@dataclass(frozen=True)
class Size(_Node):
    """A box measure of one object: longest side, height, width, length, depth, volume (m^3), every side (all),
    or its height above the floor (elevation)."""

    KIND: ClassVar[str] = "size"
    object: Ref
    dimension: Literal["longest", "height", "width", "length", "depth", "volume", "all", "elevation"] = "longest"
    unit: Literal["cm", "m", "mm", "ft", "in", "m3"] = "cm"


@dataclass(frozen=True)
class SizeCompare(_Node):
    """Which candidate has the extreme box measure of `measure` (a superlative word); (EVERYTHING,): every object;
    one candidate: which of its instances. form: which | yesno (the first wins?) | difference (first minus second,
    in `unit`) | threshold (the measure against `threshold_mm`); with_value: say the measure too."""

    KIND: ClassVar[str] = "size_compare"
    measure: SupWord
    candidates: tuple[Ref, ...] = field(metadata=_many(1, 12))
    form: Literal["which", "yesno", "difference", "threshold"] = "which"
    threshold_mm: int | None = field(default=None, metadata={"minimum": 0, "maximum": 1_000_000})
    threshold_text: str = field(default="", metadata=TEXT)
    with_value: bool = False
    unit: LengthUnit | None = None


@dataclass(frozen=True)
class RoomSize(_Node):
    """The room's floor area (m2 / ft2), or the sides of its smallest enclosing rectangle (length, width, all);
    than: yes / no against an area."""

    KIND: ClassVar[str] = "room_size"
    measure: Literal["area", "length", "width", "all"] = "area"
    unit: Literal["m2", "ft2", "cm", "m", "mm", "ft", "in"] = "m2"
    than: AreaCondition | None = None

    def roles(self) -> tuple[list[str], list[str]]:
        return [], []

    @property
    def whole_map(self) -> bool:
        return True


@dataclass(frozen=True)
class Distance(_Node):
    """Closest-point distance between a and b (the nearest instance pair; a and b of one name: the two nearest
    instances); b None: from the viewer. within: yes / no against a length; pick (with b None): which instance
    of a is closest / farthest from the viewer."""

    KIND: ClassVar[str] = "distance"
    a: Ref
    b: Ref | None = None
    unit: LengthUnit = "m"
    within: DistanceCondition | None = None
    pick: Extreme | None = None


@dataclass(frozen=True)
class Nearest(_Node):
    """Which candidate is closest (farthest) to origin (None: the viewer); (EVERYTHING,): among every other object
    of the map; one candidate without options: which of its instances; yesno: does the first candidate win?"""

    KIND: ClassVar[str] = "nearest"
    origin: Ref | None
    candidates: tuple[Ref, ...] = field(metadata=_many(1, 12))
    extreme: Extreme = "closest"
    exclude: tuple[Ref, ...] = field(default=(), metadata=_many(0, 12))
    yesno: bool = False

    @property
    def qtype(self) -> str:
        return "object_nearest" if self.among_everything else "object_rel_distance"

    @property
    def among_everything(self) -> bool:
        return any(everything(c) for c in self.candidates)

    def roles(self) -> tuple[list[str], list[str]]:
        origin = [self.origin.name] if self.origin is not None else []
        if self.among_everything:
            return [], origin
        return [c.name for c in self.candidates], origin


@dataclass(frozen=True)
class Direction(_Node):
    """Standing at `stand` facing `face`, where is `target`: granularity easy (left / right), medium (+ back),
    hard (quadrants) or free (every reading; `asked`: the direction words the question asks about); candidates:
    "which of these is on my left"; back_deg: the question's own turn for "back"."""

    KIND: ClassVar[str] = "direction"
    stand: Ref
    face: Ref
    target: Ref
    granularity: Literal["easy", "medium", "hard", "free"] = "free"
    relative_to: Ref | None = None
    candidates: tuple[Ref, ...] = field(default=(), metadata=_many(0, 12))
    asked: tuple[DirWord, ...] = field(default=(), metadata=_many(0, 12))
    back_deg: int | None = field(default=None, metadata={"minimum": 1, "maximum": 180})
    stand_by_order: bool = False

    @property
    def qtype(self) -> str:
        return "object_direction" if self.granularity == "free" else f"object_rel_direction_{self.granularity}"

    def roles(self) -> tuple[list[str], list[str]]:
        asked = [c.name for c in self.candidates] or [self.target.name]
        return asked, [self.stand.name, self.face.name]


@dataclass(frozen=True)
class ViewDirection(_Node):
    """"Is A to the left of / behind B?" as the viewer (the last camera) sees them."""

    KIND: ClassVar[str] = "view_direction"
    object: Ref
    reference: Ref
    asked: Side


@dataclass(frozen=True)
class Where(_Node):
    """Where an object is: its nearest landmarks and its side from the viewer; relative_to: that one first."""

    KIND: ClassVar[str] = "where"
    object: Ref
    relative_to: Ref | None = None

    def roles(self) -> tuple[list[str], list[str]]:
        return [self.object.name], [self.relative_to.name] if self.relative_to is not None else []


@dataclass(frozen=True)
class List(_Node):
    """Every object of these names (none: every object), or every object in a region."""

    KIND: ClassVar[str] = "list"
    objects: tuple[Ref, ...] = field(default=(), metadata=_many(0, 12))
    region: Region | None = None

    def roles(self) -> tuple[list[str], list[str]]:
        r = self.region
        cues = (_where_names(r) if isinstance(r, Relation) else [r.reference.name] if isinstance(r, SeenSide)
                else [r.stand.name, r.face.name] if isinstance(r, StanceSide) else [])
        return [o.name for o in self.objects], cues

    @property
    def whole_map(self) -> bool:
        return not self.objects


@dataclass(frozen=True)
class Forward:
    """"Go forward until the X": walk to X's centre (its instance nearest the previous waypoint)."""

    KIND: ClassVar[str] = "forward"
    to: Ref


@dataclass(frozen=True)
class Turn:
    """"[please fill in]": the turn (left / right / back) towards the next waypoint."""

    KIND: ClassVar[str] = "turn"


Step = Union[Forward, Turn]


@dataclass(frozen=True)
class Route(_Node):
    """Start at `start` facing `face`; each `Turn` is answered as left / right / back towards the next `Forward`."""

    KIND: ClassVar[str] = "route"
    start: Ref
    face: Ref
    steps: tuple[Step, ...] = field(metadata={**_many(1, 24), "steps": True})
    destination: Ref | None = None

    def roles(self) -> tuple[list[str], list[str]]:
        dest = [self.destination.name] if self.destination is not None else []
        return dest, [self.start.name, self.face.name] + [s.to.name for s in self.steps if isinstance(s, Forward)]


@dataclass(frozen=True)
class AppearanceOrder(_Node):
    """The categories in the order the video first showed them."""

    KIND: ClassVar[str] = "appearance_order"
    categories: tuple[Ref, ...] = field(metadata=_many(2, 12))


Node = Union[Count, Exists, CountCompare, Size, SizeCompare, RoomSize, Distance, Nearest, Direction,
             ViewDirection, Where, List, Route, AppearanceOrder]
NODES: tuple[type, ...] = Node.__args__  # type: ignore[attr-defined]

_QTYPE = {"count": "object_counting", "exists": "object_existence", "count_compare": "object_count_compare",
          "size": "object_size_estimation", "size_compare": "object_size_compare",
          "room_size": "room_size_estimation", "distance": "object_abs_distance", "view_direction":
          "object_view_direction", "where": "object_where", "list": "object_list", "route": "route_planning",
          "appearance_order": "obj_appearance_order"}


@dataclass(frozen=True)
class Option:
    """One option of a multiple-choice question."""

    letter: str = field(metadata={"min_length": 1, "max_length": 1})
    text: str = field(metadata={"max_length": 400})


@dataclass(frozen=True)
class Program:
    """A question as a program: what is asked (`ask`) and, for multiple choice, the options."""

    ask: Node
    options: tuple[Option, ...] = field(default=(), metadata=_many(0, 26))

    @property
    def qtype(self) -> str:
        return self.ask.qtype


# ----------------------------------------------------------------------------- walking a program


def _where_names(w: Relation) -> list[str]:
    return [r.name for r in (w.object, w.object2) if r is not None]


def iter_refs(x: Any) -> Iterator[Ref]:
    """Every `Ref` of a node, depth first in field order (selectors' names are not Refs)."""
    if isinstance(x, Ref):
        yield x
    elif is_dataclass(x):
        for f in fields(x):
            yield from iter_refs(getattr(x, f.name))
    elif isinstance(x, tuple):
        for v in x:
            yield from iter_refs(v)


def phrases(node: Any) -> dict[str, str]:
    """name -> the question's words for it (the first reference of each name)."""
    out: dict[str, str] = {}
    for r in iter_refs(node):
        out.setdefault(r.name, r.words)
    return out


def map_refs(x: Any, f: Callable[[Ref], Ref]) -> Any:
    """`x` with every `Ref` replaced by `f(ref)` (selectors' names are not Refs)."""
    if isinstance(x, Ref):
        return f(x)
    if is_dataclass(x):
        return replace(x, **{fd.name: map_refs(getattr(x, fd.name), f) for fd in fields(x)})
    if isinstance(x, tuple):
        return tuple(map_refs(v, f) for v in x)
    return x
