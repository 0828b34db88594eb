"""The VSI-Bench question templates (exact wording) -> program nodes.

Targets are the objects the question asks about, cues the reference objects that fix the frame or the route
(key-frame scoring weighs targets 1 and cues 0.5): see each node's `roles`. A phrase resolves to its vocabulary
name (`vocabulary.canonical_name`); one that is not in the vocabulary keeps its words as its name (`Ref.known`
False: reported, never dropped silently).
"""
from __future__ import annotations

import re
from dataclasses import replace

from .ir import (AppearanceOrder, Count, Direction, Distance, Forward, Nearest, Node, Ref, RoomSize, Route, Size,
                 Turn, iter_refs, map_refs)
from .rules.locations import ref_of_phrase
from .vocabulary import canonical_name

# an object phrase (leading articles dropped, lazily up to the template's next words); bounded and without
# commas / question marks so that a template with three phrases cannot backtrack cubically on long input
_O = r"(?:the\s+)*([^,?]{1,80}?)"

_TEMPLATES: list[tuple[str, re.Pattern[str]]] = [
    ("object_counting", re.compile(rf"^how many {_O}\s*(?:\(s\))? (?:are|is) (?:there )?in (?:this|the) room", re.I)),
    ("object_size_estimation", re.compile(
        rf"longest dimension \(length, width, or height\) of {_O}, measured in centimeters", re.I)),
    ("room_size_estimation", re.compile(r"size of (?:this|the) room \(in square meters\)", re.I)),
    ("object_abs_distance", re.compile(rf"distance between {_O} and {_O} \(in meters\)", re.I)),
    ("object_rel_distance", re.compile(
        rf"which of these objects \((.+?)\) is (?:the )?(closest|nearest|farthest|furthest) to {_O}\s*\?", re.I)),
    ("object_rel_direction_hard", re.compile(
        rf"standing by {_O} and facing {_O}, is {_O} to my front-left, front-right, back-left, or back-right",
        re.I)),
    ("object_rel_direction_medium", re.compile(
        rf"standing by {_O} and facing {_O}, is {_O} to my left, right, or back", re.I)),
    ("object_rel_direction_easy", re.compile(
        rf"standing by {_O} and facing {_O}, is {_O} to the left or (?:to )?the right of {_O}\s*\?", re.I)),
    ("obj_appearance_order", re.compile(
        r"first-time appearance order of the following categories in the video:\s*(.+?)\s*\?", re.I)),
    ("route_planning", re.compile(r"you are a robot beginning (?:at|by|near) ", re.I)),
]


_TEMPLATE_WINDOW = 1200  # the benchmark's questions are < 600 characters


def _ref(phrase: str) -> Ref:
    phrase = re.sub(r"^(?:the\s+)+", "", phrase.strip().rstrip(".?,"), flags=re.I).strip()
    canon = canonical_name(phrase)
    name = canon if canon is not None else phrase
    return Ref(name, "" if phrase == name else phrase, canon is not None)


def _one_phrase(node: Node, refs: list[Ref] | None = None) -> Node:
    """Every reference of a name with the same words: the last the question used for it (`refs`: the
    references in the question's order, when the node's field order differs)."""
    last = {r.name: r.phrase for r in (refs if refs is not None else iter_refs(node))}
    return map_refs(node, lambda r: replace(r, phrase=last[r.name]))


def parse_template(q: str) -> tuple[Node | None, list[str], bool]:
    """(node, notes, matched): the first template the cleaned question `q` follows; matched False when none does
    (the rule parser reads it then); node None with a note when a template matched but could not be read."""
    for qtype, rx in _TEMPLATES:
        m = rx.search(q[:_TEMPLATE_WINDOW])
        if not m:
            continue
        if qtype in ("object_counting", "object_size_estimation") and re.search(r",| and | or ", m.group(1)):
            continue  # "how many chairs and tables are in the room?": several objects, not one named "tables"
        node, notes = _node(qtype, m, q)
        return (_one_phrase(node) if node is not None and qtype != "route_planning" else node), notes, True
    return None, [], False


def _node(qtype: str, m: re.Match[str], q: str) -> tuple[Node | None, list[str]]:
    if qtype == "object_counting":
        return Count((_ref(m.group(1)),)), []
    if qtype == "object_size_estimation":
        return Size(_ref(m.group(1))), []
    if qtype == "room_size_estimation":
        return RoomSize(), []
    if qtype == "object_abs_distance":
        return Distance(_ref(m.group(1)), _ref(m.group(2))), []
    if qtype == "object_rel_distance":
        cands = tuple(_ref(c) for c in m.group(1).split(","))
        extreme = "closest" if m.group(2).lower() in ("closest", "nearest") else "farthest"
        return Nearest(_ref(m.group(3)), cands, extreme), []
    if qtype.startswith("object_rel_direction"):
        level = qtype.rsplit("_", 1)[1]
        rel = _ref(m.group(4)) if level == "easy" else None
        return Direction(_ref(m.group(1)), _ref(m.group(2)), _ref(m.group(3)), level, rel), []
    if qtype == "obj_appearance_order":
        cats = tuple(_ref(c) for c in re.split(r",\s*(?:and\s+)?|\s+and\s+", m.group(1)) if c.strip())
        return AppearanceOrder(cats), []
    return _parse_route(q)


_ROUTE_START = re.compile(
    r"beginning (?:at|by|near) (.+?)(?:,)? (?:and )?facing (?:into |toward |towards |to |out )?(.+?)\s*\. "
    r"you want to navigate to (.+?)\s*\. ", re.I)
# "go forward until past the bed": the bed is the waypoint ("past" is how it is reached, not an object)
_STEP = re.compile(r"\d+\.\s*(\[please fill in\]\.?|go forward (?:until|to)\s+(?:(?:you )?(?:are |have |get )?(?:past|passed|"
                   r"passing|beyond)\s+)?(.+?))\s*(?=\d+\.\s|you have reached|$)", re.I)




def _waypoint(phrase: str) -> Ref:
    """A route's waypoint with what picks its instance ("the chair beside the screen", "the closest sofa")."""
    text = re.sub(r"^(?:the\s+)+", "", phrase.strip().rstrip(".?,"), flags=re.I).strip()
    return ref_of_phrase(text) or _ref(text)


def _parse_route(q: str) -> tuple[Node | None, list[str]]:
    """Route questions are written by people: start, facing, destination, then numbered steps, each
    "[please fill in]" (a turn to choose) or "Go forward until X"."""
    m = _ROUTE_START.search(q)
    if not m:
        return None, ["understood: a route question; not understood: its start, facing object and destination"]
    start, facing, dest = _waypoint(m.group(1)), _waypoint(m.group(2)), _waypoint(m.group(3))
    steps: list[Forward | Turn] = []
    for sm in _STEP.finditer(q[m.end():]):
        if sm.group(2) is None:
            steps.append(Turn())
        else:
            steps.append(Forward(_waypoint(re.sub(r"\s*(?:is on your (?:left|right)|on your (?:left|right))\s*\.?$",
                                                  "", sm.group(2)))))
    if not steps:
        return None, ["understood: a route question; not understood: its numbered steps"]
    order = [start, facing, dest] + [s.to for s in steps if isinstance(s, Forward)]  # the question's order
    return _one_phrase(Route(start, facing, tuple(steps), dest), order), []
