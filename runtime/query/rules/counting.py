"""Counts, is-there questions, more-or-fewer and lists: the handlers that read which objects and where."""
from __future__ import annotations

import re
from typing import Any

from ...infra.numbers import field_max, read_number
from ..ir import EVERYTHING, Count, CountCompare, CountCondition, Exists, List, Node, Relation, SeenSide, ViewerSide
from .lexicon import COUNT_OPS, COUNT_RX, NUMBERS, SCENE, TESTED, VIEW_WORDS, WHAT_AT_RX
from .intent import my_side
from .locations import attached_near, conditions, location, single
from .state import R, State
from .tokens import before, has

# "how many legs does the chair have?": parts of an object, which the map does not hold
_PARTS_RX = re.compile(r"^how many ([a-z' -]+?) (?:does|do|did) (?:the|this|that|a|an|each|every|your|my|our) "
                       r"([a-z' -]+?) (?:have|has|got)\b")


def count(st: State, toks: list[str], joined: str, nps: list[dict[str, Any]], extra: dict[str, Any]) -> Node | None:
    if has(joined, r"^how many (?:steps|paces|strides) (?:to|until|till|away|from|is it)\b"):
        return st.fail("a walking distance in steps", "steps: the map measures in metres; ask 'how far am I from the "
                                                      "...?'")
    m = _PARTS_RX.search(joined)
    if m and not set(m.group(2).split()) & SCENE:  # "how many chairs does the kitchen have?" is a count
        return st.fail(f"a count of the {m.group(1)} of the {m.group(2)}", "parts of an object: the map holds whole "
                                                                          "objects, not their parts")
    every = has(joined, r"\b(?:objects|things|items|pieces of furniture)\b")
    if not nps and every:
        return Count((EVERYTHING,))  # every object in the map
    objs, conds = conditions(toks, nps, every)
    where = location(st, toks, objs, conds) if conds else attached_near(st, joined, objs)
    if where is not None:  # "how many cups are on the table?", "how many things are near the door?"
        target = st.refs(objs)[0] if objs else "*"
        return Count((R(target),), where)
    if len(objs) > 1 and conds:  # "how many chairs are on the desk and the couch?": never drop the location
        return st.fail("a count of " + " and ".join(f"'{' '.join(p['words'])}'" for p in objs),
                       "several objects with a location; ask about one object at a time")
    if len(objs) > 1:  # "how many chairs and (how many) cups are there?": one count per object
        names = list(dict.fromkeys(st.refs(objs)))
        return Count(tuple(R(n) for n in names))
    n = single(st, objs + conds, "count")
    return Count((R(n),)) if n is not None else None


def count_compare(st: State, toks: list[str], joined: str, nps: list[dict[str, Any]], extra: dict[str, Any]
                  ) -> Node | None:
    """"Are there more chairs than cups?" (yes or no), "which are there fewer of, cups or chairs?" (a name), "how
    many more chairs than cups are there?" (the difference)."""
    names = st.option_names() or st.refs(nps)
    if len(names) != 2:
        return st.fail("a more-or-fewer question", "exactly two objects to count against each other, without a "
                                                   "location (e.g. 'are there more chairs than tables?')")
    form = "difference" if has(joined, r"\bhow many (?:more|fewer|less)\b") else \
        "yesno" if "than" in toks and not has(joined, r"^(?:which|what|whichever)\b") else "which"
    more = has(joined, r"\bmore\b|\b(?:greater|larger|bigger|higher)\b")
    return CountCompare(R(names[0]), R(names[1]), "more" if more else "fewer", form)


COUNT_MAX = 1000  # CountCondition.n's bound (ir.py)


def _count_condition(joined: str) -> CountCondition | None:
    """"are there two chairs?" -> (==, 2); "is there more than one cup?" -> (>, 1); else None."""
    m = COUNT_RX.search(joined)
    if m is None:
        return None
    n = read_number(m.group(2), "question: the count", lo=0, hi=field_max(CountCondition, "n"), integer=True,
                    fix="ask about a count in that range") if m.group(2).isdigit() else NUMBERS[m.group(2)]
    return CountCondition(COUNT_OPS.get(m.group(1) or "exactly"), n)


def exists(st: State, toks: list[str], joined: str, nps: list[dict[str, Any]], extra: dict[str, Any]) -> Node | None:
    """"Is there a fridge?", "is there a cup on the table?", "is the cup on the table?" (the same question),
    "is there anything on the chair?" (every object)."""
    if not nps:
        return st.fail("an is-there question", "which object it is about")
    every = has(joined, r"\b(?:anything|something|any ?things?|objects|things|items|stuff)\b")
    objs, conds = conditions(toks, nps, every)
    rel = location(st, toks, objs, conds) if conds and (objs or every) else None
    rel = rel or attached_near(st, joined, objs)  # "is there a chair near the table?" (read as a selector)
    n = _count_condition(joined)  # "are there two chairs?": a count, not "is there a chair?"
    if n is not None and n.n > COUNT_MAX:  # a number no program holds: refused, never a program the schema rejects
        return st.fail("an are-there-N question", f"a count of at most {COUNT_MAX} (read {str(n.n)[:12]}...)")
    if n is not None and len(objs) > 1:
        return st.fail("an are-there-N question", "one object to count (e.g. 'are there two chairs?')")
    if n is not None and objs and len(objs[0]["words"]) > 1 and objs[0]["words"][0] in NUMBERS:
        objs[0] = {**objs[0], "words": objs[0]["words"][1:]}  # "two chairs": the object is "chairs"
    if rel is not None:  # "is there a cup on the table?"
        names = st.refs(objs) if objs else ["*"]
        return Exists(tuple(R(x) for x in names), False, rel, n)
    if conds:
        where = ", ".join(" ".join(before(toks, p, 1) + p["words"]) for p in conds)
        about = ", ".join(f"'{' '.join(p['words'])}'" for p in objs) or "anything"
        ask = (f"'is there a {' '.join(objs[0]['words'])} on the ...?' or 'where is the "
               f"{' '.join(objs[0]['words'])}?'") if objs else f"'what is on / near the {' '.join(conds[0]['words'])}?'"
        return st.fail(f"an is-there question about {about}", f"the location ('{where}'): the map tests {TESTED}; "
                                                              f"ask {ask}")
    names = st.refs(objs)
    return Exists(tuple(R(x) for x in names), " and " in f" {joined} ", None, n)


def view_list(st: State, toks: list[str], joined: str, nps: list[dict[str, Any]], extra: dict[str, Any]
              ) -> Node | None:
    """"What is to the left of the couch?", "what's behind the desk?": every object there as the viewer (the last
    camera) sees them."""
    n = single(st, nps, "what-is-there question")
    if n is None:
        return None
    word = re.search(r"\b(left|right|front|behind)\b", joined).group(1)
    return List((), SeenSide(R(n), VIEW_WORDS[word]))


def list_objects(st: State, toks: list[str], joined: str, nps: list[dict[str, Any]], extra: dict[str, Any]
                 ) -> Node | None:
    """"What objects are in the room?", "list the chairs", "what's on the table?" (every object on it), "what
    is to my left?" (every object on that side of the viewer)."""
    side = my_side(joined)
    if side is not None and not nps:
        return List((), ViewerSide(side))
    if nps and has(joined, r"^(?:what|what's|which)\b"):
        objs, conds = conditions(toks, nps, every=True)
        if conds and (not objs or has(joined, WHAT_AT_RX)):  # what is there at one place: nothing else named
            where = location(st, toks, objs, conds) if not objs else None
            if where is None:  # "under the desk", "between the desk and the couch"
                words = " ".join(before(toks, conds[0], 1) + conds[0]["words"])
                return st.fail("a what-is-there question", f"the location '{words}' (the map tests {TESTED})")
            return List((), where)
    return List(tuple(R(n) for n in st.refs(nps)))


def where_of(node: Node) -> Relation | None:
    """The location a count, is-there or list question tests (None: none)."""
    w = getattr(node, "where", None) or getattr(node, "region", None)
    return w if isinstance(w, Relation) else None
