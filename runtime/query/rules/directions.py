"""Directions and places: where I stand, what I face and what is asked about (in any order of the sentence), left
of / behind as the viewer sees it, where an object is, and the order of first appearance."""
from __future__ import annotations

import re
from typing import Any

from ..ir import AppearanceOrder, Direction, List, Node, StanceSide, ViewDirection, Where
from ..text import split_options
from .intent import my_side
from .lexicon import AHEAD_OF_ME, FACE1, FACE2, IS_AHEAD, PLACED_VERBS, QUADRANTS, VIEW_WORDS
from .locations import single
from .state import R, State
from .tokens import before, direction_words, has, noun_phrases, tokens


_FACING_IT = r"\b(?:facing|face|faces|looking at|look at|looking toward|looking towards|turned to|turned toward|" \
             r"turned towards) (?:it|that one|that)\b"
_CLOSENESS = {"closest", "nearest", "farthest", "furthest"}
_OPENS = {"with", ",", ":", ";", ".", "-", "and", "", "one"}
_AT_MY_BACK = r"(?:is )?(?:behind me|at my back|to my back)\b"


def stance(toks: list[str], nps: list[dict[str, Any]]) -> tuple[int | None, int | None, int | None]:
    """Indices of the phrases for where I stand, what I face, and the object a side is relative to."""
    pos = face = rel = None
    for k, p in enumerate(nps):
        b = [w for w in before(toks, p, 4) if w not in _CLOSENESS][-3:]  # "facing the closest sofa": facing
        last = b[-1] if b else ""
        two = " ".join(b[-2:])
        b4 = before(toks, p, 4)
        if pos is None and b4[-3:] == ["in", "front", "of"] and len(b4) == 4 and b4[0] in PLACED_VERBS:
            pos = k  # "I am in front of the desk, facing ...": where I stand, not a side of the desk
            continue
        after = " ".join(toks[p["end"]:p["end"] + 5])
        ahead = re.match(AHEAD_OF_ME, after) is not None
        ahead_is = re.match(IS_AHEAD, after) is not None
        opens = last in _OPENS  # the phrase opens a clause ("..., the stove in front of me")
        if face is None and (last in FACE1 or two in FACE2 or ((last == "with" or opens) and ahead) or ahead_is):
            face = k
            continue
        if pos is None and (two in ("back to", "back against") or (opens and re.match(_AT_MY_BACK, after))):
            pos = k  # "with my back to the sofa", "the stool behind me": where I stand (the benchmark's "by")
            continue
        if rel is None and last == "of" and len(b) >= 2 and b[-2] in ("left", "right", "front", "behind", "back",
                                                                     "side"):
            rel = k
            continue
        seated = last in ("on", "in") and len(b) >= 2 and b[-2] in ("sitting", "sit", "sat", "lying", "standing",
                                                                    "seated")  # "sitting on the couch"
        if pos is None and (last in ("by", "at", "beside", "near", "from") or seated or
                            two in ("next to", "close to", "front of", "from where", "position is", "location is",
                                    "place is", "spot is", "position were", "position was", "location were")):
            pos = k
    return pos, face, rel


def direction(st: State, toks: list[str], joined: str, nps: list[dict[str, Any]], extra: dict[str, Any]
              ) -> Node | None:
    pos, face, rel = stance(toks, nps)
    names = st.refs(nps)
    if face is None and rel is not None and re.search(_FACING_IT, " ".join(toks)):
        face = rel  # "is the lamp left or right of the tv when I'm by the bed facing it?": it is the tv
        st.notes.append(f"'it' (what I face) read as the {st.phrase(names[rel])}")
    rest = [k for k in range(len(nps)) if k not in (pos, face, rel)]
    by_order = pos is None and face is not None and len(rest) >= 2 and nps[rest[0]]["start"] < nps[face]["start"]
    if by_order:  # "my spot is the stove and I look at the tv, is the sofa ...": the object named before what I face
        pos, rest = rest[0], rest[1:]
    side = my_side(joined)
    if pos is not None and face is not None and not rest and side and has(joined, r"\b(?:what|what's|which)\b"):
        return List((), StanceSide(R(names[pos]), R(names[face]), side))  # "..., what is on my left?": every object
    if pos is None or face is None or not rest:
        have = {"where I stand": pos, "what I face": face, "the object asked about": rest[0] if rest else None}
        got = [f"{k} = '{st.phrase(names[v])}'" for k, v in have.items() if v is not None]
        miss = [k for k, v in have.items() if v is None]
        return st.fail("a direction question" + (f" ({', '.join(got)})" if got else ""), ", ".join(miss) +
                       " (say e.g. 'standing by the sofa facing the tv, is the lamp to my left?')")
    cands = tuple(R(names[k]) for k in rest) if len(rest) > 1 else ()  # "what's on my right: the radiator or ...?"
    opts = split_options(st.options)
    asked = [d for _, t in opts for d in direction_words(t)[:1]] if opts else direction_words(
        " ".join(t for i, t in enumerate(toks) if not any(p["start"] <= i < p["end"] for p in nps)))
    if any(d in QUADRANTS for d in asked) or "quadrant" in toks:  # "which quadrant is the lamp in?"
        level = "hard"
    elif "back" in asked:
        level = "medium"
    elif opts or len(set(asked)) > 1:
        level = "easy"
    else:
        level = "free"
    if not opts and len(set(asked)) <= 1 and "quadrant" not in toks:  # "is the lamp on my left?": yes/no or words
        level = "free"
    if cands and not opts:
        level = "free"
    back = extra.get("back_deg")
    return Direction(R(names[pos]), R(names[face]), R(names[rest[0]]), level,
                     R(names[rel]) if rel is not None else None, cands,
                     tuple(dict.fromkeys(asked)) if level == "free" else (),
                     int(back) if back is not None else None, by_order)


def view_direction(st: State, toks: list[str], joined: str, nps: list[dict[str, Any]], extra: dict[str, Any]
                   ) -> Node | None:
    """"Is the chair to the left of the table?", "is the cup behind the tv?": no stance named, so as the viewer
    sees them (from the last camera, looking at the second object)."""
    names = st.refs(nps)
    if len(names) != 2:
        return st.fail("a left-of / in-front-of question", "exactly two objects (e.g. 'is the chair to the left "
                                                           "of the table?')")
    word = re.search(r"\b(left|right|front|behind)\b", joined).group(1)
    return ViewDirection(R(names[0]), R(names[1]), VIEW_WORDS[word])


def where(st: State, toks: list[str], joined: str, nps: list[dict[str, Any]], extra: dict[str, Any]) -> Node | None:
    """"Where is the printer?"; "where is the printer relative to / in relation to the desk?" (that object first
    among the landmarks)."""
    if len(nps) == 2 and before(toks, nps[1], 2) in (["relative", "to"], ["relation", "to"], ["respect", "to"],
                                                     ["regard", "to"], ["compared", "to"]):
        names = st.refs(nps)
        return Where(R(names[0]), R(names[1]))
    n = single(st, nps, "where-is question")
    return Where(R(n)) if n is not None else None


def appearance_order(st: State, toks: list[str], joined: str, nps: list[dict[str, Any]], extra: dict[str, Any]
                     ) -> Node | None:
    names = st.refs(nps)
    opts = split_options(st.options)
    if len(names) < 2 and opts:  # "in which order did these appear?" with the orders as options
        names = list(dict.fromkeys(n for _, t in opts for n in st.refs([p for p in noun_phrases(tokens(t))
                                                                         if not p["scene"]])))
    if len(names) < 2:
        return st.fail("an appearance-order question", "at least two objects to order")
    return AppearanceOrder(tuple(R(n) for n in names))
