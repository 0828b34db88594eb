"""Kind + role spans (a `reader.Reading`) -> the program node of `ir.py`, or a refusal saying what was not read.

Deterministic and small: each kind takes the spans of its roles; the options of a multiple-choice question fix a
direction's granularity and supply candidates the question does not list. Confidence decides: a kind below
`ComposeConfig.kind_min`, a span used below `span_min`, a role the kind needs missing or doubled, or a confident
span of a role the kind does not use ("how many chairs are on the table": a place the count is restricted to) is a
refusal naming it; a confident wrong program is the failure to avoid.
"""
from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Callable

from .ir import (AppearanceOrder, Count, Direction, Distance, Forward, Nearest, Node, Ref, RoomSize, Route, Size,
                 Turn)
from .reader import Reading, Span


@dataclass(frozen=True)
class ComposeConfig:
    kind_min: float = 0.85  # the kind's probability needed to compose a program
    span_min: float = 0.6  # each used span's least word-piece tag probability
    stray_min: float = 0.8  # a span of a role the kind does not use, this sure, refuses


# the roles each kind uses (others, when confident, refuse the question)
USES = {"count": {"OBJ"}, "size": {"OBJ", "UNIT", "NUM"}, "room_size": {"UNIT", "NUM"},
        "distance": {"OBJ", "UNIT", "NUM", "REF"}, "closest": {"REF", "CAND"}, "farthest": {"REF", "CAND"},
        "direction": {"OBJ", "STAND", "FACE"}, "route": {"START", "FACE", "GOAL", "WAY", "TURN"},
        "appearance": {"CAND"}, "other": set()}
ROLE_WORDS = {"OBJ": "the object asked about", "STAND": "where you stand", "FACE": "what you face",
              "CAND": "the objects compared", "REF": "the object measured from", "UNIT": "the unit",
              "NUM": "a number", "START": "where the walk starts", "GOAL": "the goal", "WAY": "a waypoint",
              "TURN": "a turn", "LOC": "a place the objects are at"}
_UNITS = [("mm", r"^mil+i|^mm"), ("cm", r"^cent|^cm"), ("in", r"^inch|^in\b|^\"$"), ("ft", r"^f(ee|oo)?t|^'$"),
          ("m", r"^met|^mtr|^m\b|^m$")]
_MOST = r"\b(long|larg|bigg|great|max|most)\w*|\b(length|dimension|size|measure)\w*"
_DIM = [("height", r"\b(tall|height|high)\b"), ("width", r"\b(wide|width)\b")]
_ARTICLE = re.compile(r"^(?:(?:the|a|an|this|that|these|those|my|your|our|some)\s+)+", re.I)

Resolve = Callable[[str, bool], tuple[Ref, list[str]]]  # (phrase, plural allowed) -> (Ref, notes)


class Refusal(Exception):
    """What the reader did not understand (its message is said in the answer)."""


def clean_phrase(text: str) -> str:
    """A span's words as a name: articles and a possessive dropped, punctuation at the ends removed."""
    t = _ARTICLE.sub("", text.strip().strip(".,;:!?()[]\"'")).strip()
    return re.sub(r"'s$|\u2019s$", "", t).strip()


def unit_of(spans: list[Span], default: str) -> str:
    """The length unit a UNIT span names ("metres", "cms", "ft"); the default when none."""
    for s in spans:
        w = s.text.lower().strip(" .()")
        if "sq" in w or "squar" in w:
            continue
        for unit, rx in _UNITS:
            if re.search(rx, w):
                return unit
    return default


def compose(r: Reading, question: str, options: list[str] | None, resolve: Resolve,
            conf: ComposeConfig = ComposeConfig()) -> tuple[Node | None, list[str]]:
    """(node, notes) or (None, notes saying what was not understood)."""
    notes: list[str] = []
    if r.truncated:
        return None, ["not understood: the question is longer than the reader reads; please shorten it"]
    if r.kind_confidence < conf.kind_min:
        return None, [f"not understood: what is asked (reader: {r.kind} {r.kind_confidence:.2f}, "
                      f"{r.runner_up[0]} {r.runner_up[1]:.2f})"]
    if r.kind == "other":
        return None, ["not understood: this asks something no program of the map answers (reader: other "
                      f"{r.kind_confidence:.2f})"]
    used = USES[r.kind]
    best: dict[tuple[str, str], float] = {}  # a name said again in the same role: its surest mention counts
    for s in r.spans:
        key = (s.role, clean_phrase(s.text).lower())
        best[key] = max(best.get(key, 0.0), s.confidence)
    for s in r.spans:
        if s.role not in used and s.confidence >= conf.stray_min:
            return None, [f"not understood: '{s.text}' read as {ROLE_WORDS[s.role]}, which a {r.kind} question "
                          f"does not take"]
        if s.role in used and best[(s.role, clean_phrase(s.text).lower())] < conf.span_min:
            return None, [f"not understood: whether '{s.text}' is {ROLE_WORDS[s.role]} (reader {s.confidence:.2f})"]
    try:
        node = _BUILD[r.kind](r, question, options, resolve, notes)
    except Refusal as e:
        return None, notes + [f"not understood: {e}"]
    return node, notes


def _one(r: Reading, role: str) -> Span:
    """The one span of a role; the same name said twice ("closest to the tv ... from the tv") is one span."""
    spans = r.of(role)
    if len({clean_phrase(s.text).lower() for s in spans}) == 1:
        spans = [max(spans, key=lambda s: s.confidence)]
    if len(spans) != 1:
        raise Refusal(f"{ROLE_WORDS[role]} ({'none found' if not spans else ', '.join(s.text for s in spans)})")
    return spans[0]


SURE_UNKNOWN = 0.9  # a span naming nothing known (vocabulary, map, by meaning) is kept only this sure


def _ref(span: Span | str, resolve: Resolve, notes: list[str], plural: bool = False) -> Ref:
    phrase = clean_phrase(span.text if isinstance(span, Span) else span)
    if not phrase:
        raise Refusal(f"which object '{span.text if isinstance(span, Span) else span}' names")
    ref, more = resolve(phrase, plural)
    if isinstance(span, Span) and not ref.known and ref.name == phrase and span.confidence < SURE_UNKNOWN:
        raise Refusal(f"whether '{phrase}' is an object ({'; '.join(more) or 'no known name'})")
    notes.extend(more)
    return ref


def _count(r, q, options, resolve, notes) -> Node:
    objs = r.of("OBJ")
    if not objs:
        raise Refusal("which objects to count")
    return Count(tuple(_ref(s, resolve, notes, True) for s in objs))


def _size(r, q, options, resolve, notes) -> Node:
    low = q.lower()  # the longest unless one dimension is asked alone ("how tall", not "length, width or height")
    dim = "longest" if re.search(_MOST, low) else next((d for d, rx in _DIM if re.search(rx, low)), "longest")
    return Size(_ref(_one(r, "OBJ"), resolve, notes), dim, unit_of(r.of("UNIT"), "cm"))


def _room(r, q, options, resolve, notes) -> Node:
    u = " ".join(s.text.lower() for s in r.of("UNIT"))
    return RoomSize("area", "ft2" if re.search(r"f(ee|oo)?t|sq ?ft", u) else "m2")


def _distance(r, q, options, resolve, notes) -> Node:
    objs = r.of("OBJ") + r.of("REF")
    objs.sort(key=lambda s: s.start)
    if len(objs) != 2:
        raise Refusal(f"the two objects ({', '.join(s.text for s in objs) or 'none found'})")
    return Distance(_ref(objs[0], resolve, notes), _ref(objs[1], resolve, notes), unit_of(r.of("UNIT"), "m"))


def _option_texts(options: list[str] | None) -> list[str]:
    return [re.sub(r"^\s*[A-Za-z][.)]\s*", "", o).strip() for o in options or []]


def _nearest(extreme: str):
    def build(r, q, options, resolve, notes) -> Node:
        # the options are the choices (names as the question's author wrote them); else the listed objects
        cands = [_ref(t, resolve, notes) for t in _option_texts(options) if t] or \
            [_ref(s, resolve, notes) for s in r.of("CAND")]
        if not cands:
            raise Refusal("the objects compared (none listed, no options)")
        origin = _ref(_one(r, "REF"), resolve, notes)
        if origin.name in {c.name for c in cands}:  # measured from one of the candidates: roles misread
            raise Refusal(f"which object distances are measured from ('{origin.words}' is also a candidate)")
        return Nearest(origin, tuple(cands), extreme)
    return build


def _granularity(options: list[str] | None, q: str) -> str:
    """The choices asked: the options', else those the question lists ("left, right or behind?")."""
    text = " ".join(_option_texts(options)).lower() if options else q.lower()
    if re.search(r"(front|back)[- ]?(left|right)|quadrant|diagonal", text):
        return "hard"
    if re.search(r"\bleft\b.{0,30}\bright\b.{0,20}\b(back|behind)\b", text):  # a choice, not "my back is to"
        return "medium"
    return "easy" if re.search(r"\bleft\b.*\bright\b|\bright\b.*\bleft\b", text) else "free"


def _direction(r, q, options, resolve, notes) -> Node:
    faces = r.of("FACE")
    if not faces or len({clean_phrase(s.text).lower() for s in faces}) != 1:
        raise Refusal(f"{ROLE_WORDS['FACE']} ({', '.join(s.text for s in faces) or 'none found'})")
    face = max(faces, key=lambda s: s.confidence)
    return Direction(_ref(_one(r, "STAND"), resolve, notes), _ref(face, resolve, notes),
                     _ref(_one(r, "OBJ"), resolve, notes), _granularity(options, q))


def _route(r, q, options, resolve, notes) -> Node:
    start, face = _one(r, "START"), _one(r, "FACE")
    goals = r.of("GOAL")
    if not goals:
        raise Refusal("where the walk goes (no goal found)")
    steps: list[Forward | Turn] = []
    later = [s for s in r.spans if s.role in ("WAY", "TURN") or (s.role == "GOAL" and s is not goals[0])]
    for s in later:
        steps.append(Turn() if s.role == "TURN" else Forward(_ref(s, resolve, notes)))
    if not any(isinstance(s, Turn) for s in steps):
        fw = [s for s in steps if isinstance(s, Forward)]
        steps = [fw[0]] + [x for f in fw[1:] for x in (Turn(), f)] if fw else []
    if not any(isinstance(s, Forward) for s in steps):
        steps = [Turn(), Forward(_ref(goals[-1], resolve, notes))]
    return Route(_ref(start, resolve, notes), _ref(face, resolve, notes), tuple(steps),
                 _ref(goals[-1], resolve, notes))


def _appearance(r, q, options, resolve, notes) -> Node:
    cands = [_ref(s, resolve, notes) for s in r.of("CAND")]
    if len(cands) < 2 and options:
        cands = [_ref(t, resolve, notes) for t in re.split(r",\s*", _option_texts(options)[0]) if t.strip()]
    if len(cands) < 2:
        raise Refusal("the categories to order (fewer than two found)")
    return AppearanceOrder(tuple(cands))


_BUILD = {"count": _count, "size": _size, "room_size": _room, "distance": _distance, "closest": _nearest("closest"),
          "farthest": _nearest("farthest"), "direction": _direction, "route": _route, "appearance": _appearance}
