"""Routes as people word them: where the walk begins, what it faces, the waypoints in the order walked, and the
turns to choose ("[please fill in]", "turn", or as many as the options hold, one before each further waypoint)."""
from __future__ import annotations

import re
from typing import Any

from ..ir import Forward, Node, Route, Turn
from ..text import split_options
from .directions import stance
from .lexicon import DET
from .state import R, State
from ..vocabulary import canonical_name
from .tokens import before

# a waypoint follows a word of walking ("go forward until the tv", "walk to the door", "then the sofa")
_WALK = {"until", "till", "reach", "reaching", "reached", "past", "toward", "towards", "then", "arrive", "arriving",
         "forward", "to", "stop", "stops", "stopping", "end", "ends", "arrives"}
# the destination follows one of these ("navigate to the toilet", "to get to the bed", "my destination is the desk")
_DEST = re.compile(r"\b(?:navigate|get|want to go|destination(?: is)?|goal(?: is)?|end up|target(?: is)?|heading for|"
                   r"(?:need|needs|want|wants|have|trying|going) to (?:reach|arrive at|go to|walk to|head to))"
                   r"(?: to| at| by)?$")
# a turn to choose: "[please fill in]", or "turn" that is neither answered ("turn left") nor asked ("which turn")
_TURN = re.compile(r"\bplease fill in\b|(?<!which )(?<!what )(?<!which way to )\bturn(?:s|ing)?\b"
                   r"(?! (?:left|right|back|around|do|does|should|must|will|would|is|are)\b)")


def _turns_in_options(options: list[str] | None) -> int | None:
    """How many turns each option lists ("A. Turn Left, Turn Right": 2); None without options or when they
    differ."""
    counts = {len(re.findall(r"\b(?:left|right|back)\b", t, re.I)) for _, t in split_options(options)}
    return counts.pop() if len(counts) == 1 and 0 not in counts else None


def route(st: State, toks: list[str], joined: str, nps: list[dict[str, Any]], extra: dict[str, Any]) -> Node | None:
    """"Starting at the bed facing the tv, I walk to the tv, turn, walk to the shower, turn and walk to the toilet:
    which turns?" -> Route(bed, tv, [forward tv, turn, forward shower, turn, forward toilet])."""
    pos, face, _ = stance(toks, nps)
    if pos is None:  # "start = the sofa", "the walk begins: sofa": the phrase right after a word of starting
        pos = next((k for k, p in enumerate(nps) if k != face and set(before(toks, p, 2)) & _START), None)
    if pos is None or face is None:
        have = {"where the walk begins": pos, "what it faces": face}
        return st.fail("a route question", ", ".join(k for k, v in have.items() if v is None) +
                       " (say e.g. 'beginning at the bed facing the tv, go forward until the tv, turn, go forward "
                       "until the toilet: which turn?')")
    names = st.refs(nps)
    dest = None
    events: list[tuple[int, Any]] = [(m.start(), "turn") for m in _TURN.finditer(" ".join(toks))]
    char = [len(" ".join(toks[:p["start"]])) + (1 if p["start"] else 0) for p in nps]  # phrase -> character offset
    # a waypoint is an object: a name, or a phrase with a determiner ("the zither"); not "head", "makes", "once"
    objects = [k for k, p in enumerate(nps) if canonical_name(" ".join(p["words"])) is not None or
               (p["start"] > 0 and toks[p["start"] - 1] in DET)]
    last_end = 0
    for k, p in enumerate(nps):
        gap, last_end = [t for t in toks[last_end:p["start"]] if t not in DET][-3:], p["end"] if k in objects \
            else last_end  # the words since the object before it ("until you reach the tv")
        if k in (pos, face) or k not in objects or _moves(toks, p):
            continue
        if _DEST.search(" ".join(before(toks, p, 4))) and dest is None:
            dest = k
        if set(gap) & _WALK and not (k == dest and not _later_walk(toks, p)):
            events.append((char[k], k))
    events.sort(key=lambda e: e[0])
    forwards = [e[1] for e in events if e[1] != "turn"]
    n_turns = sum(e[1] == "turn" for e in events)
    want = _turns_in_options(st.options)
    if not forwards and dest is not None:
        forwards = [dest]
    if want is not None and want != n_turns:  # the options say how many: one before each further waypoint
        if len(forwards) == want + 1:
            events = [(0, forwards[0])] + [(0, x) for f in forwards[1:] for x in ("turn", f)]
        elif len(forwards) == want:
            events = [(0, x) for f in forwards for x in ("turn", f)]
        else:
            return st.fail(f"a route question with {len(forwards)} waypoint(s)",
                           f"where its {want} turn(s) are (say 'turn' or '[please fill in]' where each one is)")
    if not forwards or not any(e[1] == "turn" for e in events):
        return st.fail("a route question", "the waypoints and the turns to choose")
    steps = tuple(Turn() if e[1] == "turn" else Forward(R(names[e[1]])) for e in events)
    return Route(R(names[pos]), R(names[face]), steps, R(names[dest]) if dest is not None else None)


_START = {"start", "starts", "starting", "begin", "begins", "beginning", "origin"}
# a word followed by one of these moves ("head forward", "walk to", "turn around"): a verb, not a place
_PARTICLES = {"forward", "forwards", "to", "toward", "towards", "until", "till", "straight", "ahead", "up", "down",
              "along", "past", "over", "around", "back", "on", "onward", "onwards"}


def _moves(toks: list[str], p: dict[str, Any]) -> bool:
    """A one-word phrase that is a verb of walking ("head forward until ...", "move to ...")."""
    nxt = toks[p["end"]] if p["end"] < len(toks) else ""
    return len(p["words"]) == 1 and not p["sel"] and nxt in _PARTICLES and canonical_name(p["words"][0]) is None


def _later_walk(toks: list[str], p: dict[str, Any]) -> bool:
    """Whether the destination phrase is also walked to (a walking word right before it)."""
    b = before(toks, p, 2)
    wish = set(before(toks, p, 4)) & {"need", "needs", "want", "wants", "have", "trying", "going"}
    return bool(b) and b[-1] in ("until", "till", "reach", "reaching") and not wish  # "need to reach X": the goal
