"""The kind of question from its cue words (`intent`), and what refuses a whole text: a place in the room as a
location, several questions of different kinds in one text, a negation the parse did not use."""
from __future__ import annotations

import re
from typing import Any

from .lexicon import (CLOSE, FAR, WHICH, CMP, CMP_RX, DIST_CMP_RX, DIST_OPS, FACING_AHEAD_RX, LOCATED, NUMBERS, ROOM_REGION_RX,
                      SUP_DIM_RX, SUP_RX, UNIT_M, UNIT_WORDS, VIEW_RX, WHAT_AT_RX)
from ...infra.numbers import field_max, read_number
from ..ir import DistanceCondition
from ..text import split_options
from .state import State
from .tokens import has, noun_phrases, unit_in

PREAMBLE = [  # phrases that would be misread as the question's own words
    re.compile(r"(?:measuring|measured|measure|as measured)?\s*(?:from|between)?\s*(?:the\s+)?(?:closest|nearest)"
               r"\s+points?(?:\s+(?:of|on)\s+(?:each|the|both|two)(?:\s+(?:two|the))?\s+objects?)?"),
    re.compile(r"(?:closest|nearest)[- ]point[- ]to[- ](?:closest|nearest)[- ]point"),
    re.compile(r"(?:an object is (?:to )?my back|(?:it|something) counts as (?:behind|back)|count (?:it|that|"
               r"something) as (?:behind|back)) if .{0,120}?(?:face it|degrees(?: or more)?)\b"),
    re.compile(r"(?:the )?directions? (?:refer|refers|are) .{0,160}?(?:y-axis|y axis|quadrants?)\b\)?"),
]


# the viewer addressed as "you" ("picture yourself by the sofa, facing the tv: is the lamp to your left?") is the
# asker: read as "I am ... my left"
IMAGINED_VIEWER = [(re.compile(rx), to) for rx, to in (
    (r"\b(?:picture|imagine|visuali[sz]e|suppose|pretend) (?:that )?(?:yourself|you're|you are|you)\b", "i am"),
    (r"\b(to|on|at) your (left|right|back|front)\b", r"\1 my \2"), (r"\bbehind you\b", "behind me"),
    (r"\b(in front of|ahead of) you\b", r"\1 me"), (r"\b(left|right) of you\b", r"\1 of me"))]


def strip_preamble(joined: str) -> tuple[str, dict[str, Any]]:
    extra: dict[str, Any] = {}
    m = re.search(r"\b(?:turn|turning|turned|rotate|rotating|rotation)(?: of| by| through)?(?: at least| more than| over|"
                  r" about)? (\d+)\s+degrees", joined)
    if m:
        extra["back_deg"] = read_number(m.group(1), "question: the turn", lo=1, hi=180, unit="degrees",
                                        fix="give a turn of at most 180 degrees (left or right)")
    for rx in PREAMBLE:
        joined = rx.sub(" ", joined)
    for rx, to in IMAGINED_VIEWER:  # "picture yourself by the sofa ... to your left": the asker's own place
        joined = rx.sub(to, joined)
    return " ".join(joined.split()), extra


ROOMS = (r"(?:room|space|kitchen|bedroom|bathroom|apartment|flat|office|house|living room|area|whole space|place|"
         r"home|studio|suite|lounge|hallway|scene)")
UNITS_RX = r"(?:cm|centimet\w+|mm|millimet\w+|m|meters?|metres?|feet|foot|ft|inch(?:es)?)"
SIMPLE_INTENTS = [(name, re.compile(rx)) for name, rx in (  # tried in this order, after the choice questions
    ("room_size", rf"\bhow (?:big|large|long|wide) is (?:the |this |our )?{ROOMS}\b|\b(?:length|width|dimensions?|"
                  rf"measurements?) of (?:the |this |our )?{ROOMS}\b|^(?:is|are) (?:the |this |our )?{ROOMS} "
                  rf"(?:bigger|larger|smaller) than [\d.]+|floor (?:area|space|size)|square "
                  rf"(?:meters?|metres?|feet)|\bsq\b|(?:size|area|footprint) of (?:the |this )?{ROOMS}\b|"
                  rf"\b{ROOMS} 's (?:floor )?(?:size|area|footprint)\b|^(?:the |this )?{ROOMS} (?:floor )?(?:size|area|"
                  rf"footprint)\b"),
    ("size", rf"\bhow (?:big|large|long|tall|wide|high|deep)\b|\b(?:size|dimensions?|length|height|width|depth|volume|"
             rf"measure|measures|measurements?)\b|\b(?:longest|biggest|largest|greatest|widest|max|maximum) (?:side|"
             rf"edge|dimension|extent|length|measurement)\b|how many {UNITS_RX}\b"),
    ("count", r"\bhow many\b|\bcount\b|\bnumber of\b|\bquantity of\b|\btotal of\b|^(?:the )?total\b|"
              r"\b(?:give|tell) (?:me )?(?:the |a )?(?:number|count|total)\b"),
    ("existence", r"^(?:is|are|isn't|aren't|was|were) there\b|\bis there (?:one|any)\b|\b(?:is|are) (?:a |an |any )?"
                  r"[^?]{1,60}? (?:present|around|visible)\b|^(?:have|has|did) (?:you|we|i) (?:seen|see|spotted|spot|"
                  r"noticed|notice|found|find)\b|\b(?:do|can|did|could) (?:you|i|we) (?:see|spot|find|notice)\b|"
                  r"\b(?:does|do) (?:the|this|our|your) \w+(?: \w+)? (?:have|contain|include|hold)\b|\bexists?\b|"
                  r"^(?:do|does) (?:we|you|i|they|it) (?:have|got)\b|"
                  r"^(?:any|got any)\b|\bis (?:a|an) [^?]{1,80}? (?:in|here)\b"))]


# "the number of chairs greater than (the number of) cups": a count comparison in other words
COUNT_CMP_RX = (r"\b(?:number|count|amount|quantity) of \w+(?: \w+)? (?:is |are )?(?:greater|larger|bigger|higher|"
                 r"smaller|lower)\b")


# "how high above the floor is the lamp?", "how far off the ground is the shelf?": the bottom's height over the floor
ELEVATION_RX = (r"\bhow (?:high|far)\b[^?]{0,60}? (?:above|off|from|over) the (?:floor|ground)\b|\b(?:height|elevation)"
                 r"\b[^?]{0,40}? (?:above|off|from) the (?:floor|ground)\b|\bhow high up\b|\bat what height\b|\belevation\b|"
                 r"\bhow high (?:is|are) [^?]{1,60}? (?:mounted|hung|hanging|placed|fixed|installed)\b")



def distance_condition(text: str) -> dict[str, Any] | None:
    """{"op", "threshold_m", "text"} of "within 2 m of" / "more than half a metre from" in the raw question text
    (decimals intact), else None."""
    m = re.search(DIST_CMP_RX, text.lower())
    if m is None:
        return None
    n = m.group(2)
    unit = UNIT_WORDS.get(m.group(3)) or unit_in(m.group(3), "m")
    v = read_number(n, f"question: the distance '{m.group(1)} ...'", lo=0, unit=unit, fix="ask with a distance in "
                    "that range", hi=field_max(DistanceCondition, "threshold_mm") / 1000 / UNIT_M[unit]) \
        if n[0].isdigit() else 0.5 if n.startswith("half") else 1.0 if n in ("a", "an") else float(NUMBERS[n])
    return {"op": DIST_OPS[m.group(1)], "threshold_m": v * UNIT_M[unit], "text": f"{m.group(1)} {n} {m.group(3)}"}


# "which came first in the video", "what showed up earliest": an order in time and something seen (not a count)
ORDER_RX = (r"^(?!how many\b)(?=.*\b(?:first|earliest|earlier|sooner|soonest|order|sequence|before)\b)"
            r"(?=.*\b(?:came|come|comes|show|shows|showed|shown|seen|see|saw|spotted|noticed|visible|video|recording|"
            r"footage|camera|view|filmed|recorded)\b)")
# a route: a walk with turns to choose ("[please fill in]"), or turns and a walk from a start
WALK_RX = (r"\b(?:navigate|route|path|robot|walk|walks|walking|head|heads|heading|drive|travel|proceed|forward|"
           r"destination|go|goes|going|move|moves|moving)\b")
ROUTE_RX = (rf"\bplease fill in\b|^(?=.*\bturn(?:s|ing)?\b)(?=.*{WALK_RX})(?=.*\b(?:begin|begins|beginning|start|"
            rf"starts|starting)\b)")


def route_options(options: list[str] | None) -> bool:
    """Options that are turns ("A. Turn Left, Turn Right", "B. left then back"): a route's answers."""
    texts = [t.lower() for _, t in split_options(options)]
    turn = r"(?<![-\w])(?:left|right|back)(?![-\w])"  # "back-left" is a quadrant, not two turns
    return bool(texts) and all(re.search(turn, t) for t in texts) and any(
        re.search(r"\bturn", t) or len(re.findall(turn, t)) > 1 for t in texts)


def intent(j: str, n_obj: int, has_opts: bool) -> str | None:
    """The intent from cue words (order matters: the more specific first)."""
    if has(j, ROUTE_RX):
        return "route"
    if has(j, ELEVATION_RX):
        return "size"
    if n_obj == 0 and has(j, rf"\b{ROOMS}\b") and has(j, r"\b(?:area|size|big|large|square|footprint|floor space|"
                                                         r"how much space|dimensions?|length|width|long|wide)\b"):
        return "room_size"  # "what's the area covered by the room?": the room is the only thing named
    if has(j, rf"^(?:is|are) (?:the |this |our )?{ROOMS} (?:bigger|larger|smaller) than (?:about |around )?\d"):
        return "room_size"  # "is the room bigger than 20 square meters?": its floor area against a number
    if has(j, r"^(?:is|are|was|were)\b") and has(j.replace(" . ", "."), DIST_CMP_RX):
        return "abs_distance"  # "is the sofa within 2 m of the tv?": yes or no, with the distance
    stance = has(j, r"\b(?:facing|face|faces|faced|looking at|look at|looking towards?|look towards?|turned towards?|"
                     r"looking in the direction of|eyes on|gaze on|pointed at|pointing at|oriented towards?|"
                     r"turn(?:s|ing)? (?:to|towards?)|gazing at|gaze at|watching|staring at|my face to)\b|" +
                  FACING_AHEAD_RX)
    sided = stance and has(j, r"\b(?:left|right|behind)\b")  # "facing X, does Y appear left or right of X?"
    if not sided and (not has(j, r"\bhow many\b") and has(j, r"\b(?:appear|appears|appeared|appearance|show up|"
                                                            r"showed up|came into view)\b|"
               r"\b(?:see|saw|seen|spot|spotted|notice|noticed)\b.*\bfirst\b|\bfirst\b.*\b(?:see|saw|seen)\b|"
               r"\bin (?:what|which) order\b") or has(j, ORDER_RX) and not stance):
        return "obj_appearance_order"
    where_i = re.sub(r"\b(?:looking|look|looked|staring) at\b", " ", j)  # "looking at A, B or C, which ...": no place
    if stance and has(where_i, r"\b(?:standing|stand|stood|sitting|sit|i am|i'm|im|i was|you are|from|at|by|next "
                                r"to|beside|near|positioned|located|my (?:position|location|spot|place)|back (?:to|"
                                r"against)|behind me|at my back)\b"):
        return "direction"
    if has(j, r"\b(?:distance|how far|far apart|far away|far from|how close|how near|gap (?:between|from)|separat\w*|"
               r"(?:gap|space) (?:is there |are there |do you see |would there be )?(?:between|from)|"
               r"spacing|"
               r"how much (?:space|room|gap)|\b(?:from|between)\b.*\bhow many (?:meters?|metres?|feet|foot|ft|"
               r"cm|centimet\w+|inch(?:es)?|mm)\b|how many (?:m|meters?|"
               r"metres?|cm|centimet\w+|feet|foot|ft|inch(?:es)?|mm)\b.*\b(?:between|from|apart|away|to)\b)"):
        if has(j, CLOSE + "|" + FAR) and has(j, r"\b(?:which|whichever|or|than)\b"):
            return "rel_distance"
        return "abs_distance"  # "what is the distance from the laptop to the nearest chair": instances' minimum  # "how far is the chair nearest the door from the tv": a selector, not the question
    if has(j, CLOSE + "|" + FAR) and has(j, WHICH):
        return "rel_distance"
    if has(j, r"\b(?:what|what's|which)\b(?: \w+){0,3} (?:next to|beside|near|by)\b") and \
            not has(j, r"\b(?:objects|things|items)\b"):
        return "rel_distance"  # "what's next to the desk?": the nearest other object
    if has(j, r"\b(?:more|fewer|less)\b") and has(j, r"\b(?:than|or)\b") and not has(j, r"\d|\bmore or less\b") \
            and n_obj >= 2:
        return "count_compare"  # "are there more chairs than cups?", "which are there fewer of, cups or chairs?"
    if has(j, COUNT_CMP_RX) and has(j, r"\b(?:than|or)\b") and n_obj >= 2:
        return "count_compare"  # "is the number of chairs greater than the number of cups?"
    if has(j, rf"\bhow much {CMP} (?:is|are|was|were)\b|\bby how much (?:is|are|was|were)\b.*{CMP_RX}|"
               rf"\bhow much (?:is|are|was|were)\b.*{CMP_RX}") and has(j, r"\bthan\b"):
        return "size_compare"  # "how much taller is the fridge than the table?": the difference
    if not has(j, r"\bhow\b") and (has(j, CMP_RX) and has(j, r"\b(?:which|whichever|what|or|than)\b")
                                     or has(j, SUP_RX) and has(j, r"^(?:which|what|what's)\b")
                                     and not has(j, SUP_DIM_RX)
                                     and not has(j, r"\b(?:height|length|width|size|depth|dimensions?) of\b|"
                                                     r"\bat (?:its|their) (?:longest|biggest|largest|widest|"
                                                     r"tallest|highest)\b")):  # "what would X measure at its longest"
        return "size_compare"  # "which is bigger, the table or the sofa?", "what's the tallest thing here?"
    if has(j, r"^(?:is|are|was|were) (?!there\b)") and has(j, VIEW_RX) and n_obj >= 2:
        return "view_direction"  # "is the chair to the left of the table?": as seen from the camera
    if has(j, r"^(?:is|are|was|were) (?!there\b)") and has(j, rf"\b{LOCATED}\b") and n_obj >= 2:
        return "relation"  # "is the cup on the table?": an is-there question with a location
    if has(j, r"^(?:what|what's|which (?:objects|things|items))(?: is| are|'s)? (?:to the |on the )?(?:left|right)"
               r"(?: hand side| side)? of\b|^(?:what|what's|which (?:objects|things|items))(?: is| are|'s)? "
               r"(?:behind|in front of)\b(?! me\b)"):
        return "view_list"  # as the viewer (the last camera) sees them
    if has(j, WHAT_AT_RX) or has(j, r"^(?:what|which \w+) (?:do|can|did|could) (?:you|i|we) (?:see|spot|notice)\b"):
        return "list"  # "what's on the table?", "what is near the door?", "what do you see?"
    for intent, rx in SIMPLE_INTENTS:
        if rx.search(j) and not (intent == "existence" and has(j, r"^(?:where|where's)\b")):
            return intent  # "where can I find the bin?" asks where, not whether
    if has(j, r"\b(?:where|whereabouts|locate|location of|position of)\b|^(?:show me|find|point (?:me )?to)\b|"
               r"\bwhich way (?:is|to)\b|\bhow (?:do|can|could) (?:i|we) (?:get|go|walk) to\b|\bhow to get to\b|"
               r"\b(?:guide|take|lead) me to\b|\bdirections? to\b"):
        return "direction" if has(j, r"\b(?:if i|standing|when i)\b") and stance else "where"
    if has(j, r"\b(?:list|enumerate|inventory)\b|\b(?:what|which) (?:objects|things|items|furniture)\b|"
               r"\bwhat (?:are|is) the (?:objects|things|items|furniture)\b|"
               r"\bwhat(?:'s| is| are) (?:in|there)\b|\bwhat do you see\b|\bwhat can you see\b"):
        return "list"
    if has(j, MY_SIDE_RX):
        if has(j, r"^(?:what|what's|which (?:objects|things|items))\b") and n_obj == 0:
            return "list"  # "what is to my left?": every object on that side of the viewer (the last camera)
        return "direction"
    return None


# "on my left", "to my right", "behind me", "in front of me" -> the side asked (`_my_side`)
MY_SIDE_RX = r"\b(?:on|to) my (left|right|back|front)\b|\b(behind) me\b|\b(in front of|ahead of) me\b"


def my_side(joined: str) -> str | None:
    """The side of the viewer a question asks about: left | right | back | front (None: none named)."""
    m = re.search(MY_SIDE_RX, joined)
    if m is None:
        return None
    w = next(g for g in m.groups() if g)
    return {"behind": "back", "in front of": "front", "ahead of": "front"}.get(w, w)



def refuse_whole_text(st: State, joined: str, has_opts: bool) -> None:
    """Refuse a place in the room as a location, and several questions in one text."""
    region = re.search(ROOM_REGION_RX, joined)
    if region:  # "is the table in the middle of the room?": not an object called "middle"; never guessed
        st.refuse("a position in the room", f"'{region.group(0)}' (the map reasoner places objects relative to "
                                              f"other objects or to you, not to parts of the room)")
    several = several_questions(joined, has_opts)
    if several:  # "how many chairs and how far is the sofa?": never one answer for two questions
        st.refuse(f"several questions in one ({several})", "which one to answer: ask them one at a time")


EXCEPT_RX = r"\b(?:apart from|aside from|except(?: for)?|other than|besides|excluding|not counting|but not)\b"


def several_questions(joined: str, has_opts: bool) -> str | None:
    """The kinds of question asked when a text asks several of different kinds ("how many chairs? where is the
    sofa?", "how many chairs and how far is the sofa?"), else None (one question, or several counts)."""
    parts = [c for c in re.split(r"\?|\band (?=(?:how|what|what's|where|where's|which)\b)", joined) if c.strip()]
    if len(parts) < 2:  # one clause: one question (its intent is found once, by the caller)
        return None
    kinds = []
    for c in parts:
        n = len([p for p in noun_phrases(c.split()) if not p["scene"]])
        k = intent(c.strip(), n, has_opts) if n else None  # "..., how many exactly?" names nothing: a follow-up
        kinds += [k] if k else []
    return " and ".join(dict.fromkeys(k.replace("_", " ") for k in kinds)) if len(set(kinds)) > 1 else None


NEGATIONS = {"not", "no", "none", "never", "without", "nothing", "nobody", "neither", "nor"}
# a negative question asks the same as the positive one ("isn't there a chair?" = "is there a chair?")
NEGATIVE_QUESTION = {"isn't", "aren't", "doesn't", "don't", "didn't", "wasn't", "weren't", "can't", "won't"}


def unread_negation(toks: list[str], negated_location: bool) -> str | None:
    """A negation the parse did not use ("is there no laptop?", "which chair is not near the desk?"), or None.
    Read: "not" before a location the parse negated ("cups not on the table": `negated_location`); "yes or no";
    "whether or not"; a negative question form at the start ("isn't there a chair?")."""
    words = re.sub(r"\byes or no\b|\bor not\b|\bnot only\b|\bno more than\b|\bnot more than\b", " ",
                   " ".join(toks)).split()
    found = [t for t in words if t in NEGATIONS or (t.endswith("n't") and t not in NEGATIVE_QUESTION)]
    found += [t for t in words[1:] if t in NEGATIVE_QUESTION]  # "how many aren't ...": not a question form
    if "not" in found and negated_location:
        found.remove("not")
    return found[0] if found else None
