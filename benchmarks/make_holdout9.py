"""Write benchmarks/data/vsibench_paraphrases_holdout9.jsonl: held-out wording set 9 for VSI-Bench.

Written without reading or running the question parser (nothing under runtime/, host/ or tests/, no query docs, no
golden files, no `mosaic` command). The earlier wording sets (benchmarks/data/vsibench_paraphrases*.jsonl) were read
only for their row format and to keep away from their wordings; `--check-overlap` measures that (below).

Every row re-asks one real benchmark question (`source_id`) about the same scene, the same objects in the same roles
(where I stand, what I face, what is asked about, the reference of a distance) and, for multiple choice, the
benchmark's own `options` list and answer letter, unchanged:

- 8 types x 10 wording patterns x 4 questions (object_counting, object_size_estimation, room_size_estimation,
  object_abs_distance, object_rel_distance, object_rel_direction_easy/medium/hard). Rows of one type are in pattern
  order: rows 4k..4k+3 of a type use pattern k (the lists below, in order). The questions are drawn at random
  (seed 9) from the benchmark questions of that type that set 8 did not use.
- route_planning: every route question of the benchmark, twice (pattern 0, then pattern 1), options kept.

Written the way people type to a phone: polite lead-ins, "um"/"like", the object first and the question after,
British and American spellings, units in words and in symbols, some numbers in words, everyday object names (telly,
couch, fridge, cooker, loo, washing machine, bath ...), and about one question in five (exactly 8 of the 40 rows of
each type, 42 of the 208 route rows) with one single-letter slip: in a non-object word, or in an object name of five
letters or more. The slips are a fixed list of misspellings (TYPO_WORDS, TYPO_OBJECTS) chosen so that none is
another English word; direction words (left, right, front, back, behind, turn) and units are never misspelt.

Numbers asked in another unit carry the ground truth converted exactly (as set 8 does: rounded to 4 places):
object sizes (benchmark: cm) in cm, mm, m, inches or feet; distances (benchmark: m) in m, cm, mm, inches or feet;
room areas (benchmark: m^2) in m^2 or square feet. 1 in = 2.54 cm, 1 ft = 30.48 cm.

    python benchmarks/make_holdout9.py [--questions Q.jsonl] [--set8 SET8.jsonl] [--seed 9] [--out OUT.jsonl]
    python benchmarks/make_holdout9.py --check-overlap   # longest runs of words shared with an earlier set

`--check-overlap` masks the benchmark's own content (object names -> OBJ, a list of objects -> LIST, a run of
direction option words -> OPTS, a route's waypoint phrases -> OBJ) and prints every run of 5+ words a new question
shares with a question of an earlier set. As committed, the longest is 7 words ("turn left, turn right or turn
back", the benchmark's route options); every other shared run is a stock phrase of 7 words or fewer ("at the OBJ
and facing the OBJ", "from the OBJ to the OBJ"); no pattern of an earlier set is reused.
"""
from __future__ import annotations

import argparse
import glob
import json
import random
import re
from pathlib import Path

from holdout_common import (AREA_FROM_M2, FILL_RE, FORWARD_RE, NUMBER, N_PATTERNS, PER_PATTERN, ROUTE_RE, Seg,
                            TEMPLATES, TYPES, TYPO_PER_TYPE, UNIT_FROM_CM, UNIT_FROM_M, _segments, _split_objects,
                            _tidy)

HERE = Path(__file__).resolve().parent
VSI = HERE.parent.parent / "shared" / "data" / "vsibench"
SET8 = HERE / "data" / "vsibench_paraphrases_holdout8.jsonl"
ID_BASE = 1000000

# everyday names a native speaker reads without context; the benchmark's own name is kept about 40 % of the time
SYN = {"tv": ["telly", "TV", "television", "telly"], "sofa": ["couch", "couch", "sofa"],
       "refrigerator": ["fridge", "fridge"], "washer": ["washing machine", "washing machine"],
       "bathtub": ["bath", "bathtub", "bath tub"], "stove": ["cooker", "stove"], "toilet": ["loo", "toilet"]}
PLURAL = {"couch": "couches", "telly": "tellies", "TV": "TVs", "washing machine": "washing machines",
          "bath": "baths", "loo": "loos"}
# one single-letter slip per word (a letter dropped, doubled, swapped with its neighbour or hit next to it on the
# keyboard); none of these is itself an English word
TYPO_OBJECTS = {"table": ["tabke", "tabel"], "chair": ["chiar", "chaor"], "couch": ["coutch", "cuoch"],
                "fridge": ["frige", "fridhe"], "telly": ["tellt", "tely"], "stove": ["stvoe", "stoce"],
                "toilet": ["toliet", "toilett"], "bathtub": ["bathub", "bathtib"], "dishwasher": ["dishwaher"],
                "fireplace": ["firepalce", "fireplave"], "washing": ["washign", "wasing"],
                "machine": ["machien", "mashine"], "refrigerator": ["refigerator", "refrigerater"],
                "television": ["televsion", "televison"], "cooker": ["cooekr", "cookr"], "stool": ["stoool"],
                "washer": ["wahser", "washr"], "sofa": [], "bed": []}
TYPO_WORDS = {"would": ["woudl", "whould"], "which": ["whcih", "wich"], "where": ["wehre", "whre"],
              "there": ["tehre", "ther"], "please": ["pleae", "plese"], "could": ["coudl", "cuold"],
              "the": ["teh", "hte"], "standing": ["standign", "stnading"], "facing": ["facign", "faceing"],
              "looking": ["lookign", "loking"], "nearest": ["nearets", "neaest"], "closest": ["cloest", "clsoest"],
              "distance": ["distnace", "distane"], "between": ["betwen", "bewteen"], "measure": ["meausre"],
              "longest": ["longets", "logest"], "sorry": ["sory", "sorrry"], "many": ["mnay", "mant"],
              "room": ["rooom", "roon"], "together": ["togehter", "togther"], "combined": ["combnied", "comined"],
              "roughly": ["rougly", "roughy"], "picture": ["pciture", "picure"], "forward": ["foward", "forwrad"],
              "until": ["untill", "utnil"], "towards": ["towrads", "twards"], "beside": ["besdie", "bside"],
              "number": ["nubmer", "numebr"], "floor": ["flor", "floro"], "video": ["vidoe", "vdeo"],
              "dimension": ["dimesion", "dimention"], "biggest": ["bigest", "biggets"], "just": ["jsut"],
              "like": ["liek"], "size": ["szie"], "what's": ["waht's", "whats'"], "how": ["hwo"],
              "tell": ["tel", "tlel"], "exactly": ["exacly", "exatly"], "area": ["aera"], "help": ["hlep"],
              "these": ["theese", "thes"], "those": ["thsoe"], "steps": ["setps", "stpes"], "route": ["rotue"],
              "with": ["wiht"], "next": ["nxet"], "side": ["sdie"], "edge": ["egde"], "space": ["sapce"],
              "altogether": ["altogehter"], "want": ["wnat"], "know": ["konw"], "thing": ["thign"],
              "whereabouts": ["wherabouts"], "measured": ["mesured"], "actually": ["acutally"],
              "directions": ["direcitons", "diretions"], "heading": ["headign"], "total": ["totla"],
              "quadrants": ["quadrnats"], "stood": ["stod"], "work": ["wrok"], "mind": ["mnid"],
              "rooms": ["roooms"], "each": ["eahc"], "other": ["otehr"], "blank": ["blnak"], "blanks": ["blnaks"],
              "first": ["frist"], "then": ["thne"], "after": ["afetr"], "where's": ["wher's"]}

# --- the wording patterns (10 per type) ---------------------------------------------------------------------------
# counting: {P} one object, {Ps} its plural (every benchmark count is 2 or more)
COUNT = [
    "sorry to bother you, could you do a count of the {Ps} in this room for me?",
    "{Ps}... like, how many of them are in this room altogether?",
    "um so what number of {Ps} does this room have",
    "Please could you tell me how many {Ps} you can see in this room?",
    "in this room, {Ps} — how many all told?",
    "need a headcount of the {Ps} in this room pls",
    "how many {Ps} have we got in this room? exact number if you can",
    "Hi! Do me a favour and add up the {Ps} in this room, how many?",
    "ok the {Ps} in this room — how many is that?",
    "hey, just wondering how many {Ps} are in this room",
]
# object size (benchmark: the longest of length, width, height, in cm): (wording, unit)
SIZE = [
    ("could you tell me roughly what length the {X} comes to at its longest? in centimetres please", "cm"),
    ("the {X}, um, what's its longest dimension in inches?", "in"),
    ("Sorry, how big is the {X}? I mean its biggest dimension, whether that's length, width or height, in ft", "ft"),
    ("longest side of the {X} in metres, like approximately?", "m"),
    ("so the {X} — how many cm is it along whichever side is longest?", "cm"),
    ("Hi! Would you be able to measure the {X} for me? Just the longest of its three dimensions, in millimetres.",
     "mm"),
    ("what does the {X} measure end to end along its longest axis, in feet", "ft"),
    ("how tall or wide or long is the {X}, whichever of the three is biggest? answer in centimeters", "cm"),
    ("um, approx size of the {X} in inches? the longest measurement I mean", "in"),
    ("I need the {X}'s greatest dimension, in meters", "m"),
]
# room size (benchmark: m^2, every room shown counted together): (wording, unit)
ROOM = [
    ("could you estimate the floor area of this room for me in square metres? if there's more than one room, the "
     "whole lot together", "m2"),
    ("how big is this place in sq ft — all the rooms in the video combined, if there are several", "ft2"),
    ("um, what's the area here, like in square feet? count every room that's shown as one space", "ft2"),
    ("the space in this video, how many sq m is it altogether, including any other rooms you saw?", "m2"),
    ("Sorry, how many square meters does this room cover? (combined, if it's more than one room)", "m2"),
    ("what size is the room in m², counting all the rooms together if the video shows more than one", "m2"),
    ("Hi, could I get the total floor space of this room in square feet? if it's a few rooms just add them up",
     "ft2"),
    ("how many sq ft of floor is there in total? one room or several, the whole space", "ft2"),
    ("in square metres, how large is this room? combine them if more than one room is shown", "m2"),
    ("area of the room plz, metres squared. the whole space if it spans two or more rooms", "m2"),
]
# absolute distance (benchmark: between the closest points, in m): (wording, unit); {A} and {B} are the
# benchmark's first and second object
ABS = [
    ("the {A} — how far is it from the {B}? edge to edge, in metres", "m"),
    ("could you tell me the gap between the {A} and the {B} in centimetres, measured from their closest points?",
     "cm"),
    ("um how big a gap is there between the {A} and the {B} at the closest bit, in ft?", "ft"),
    ("{B} and {A}: shortest distance between them in inches?", "in"),
    ("Sorry, the {A} and the {B}, at their nearest, how many meters between them?", "m"),
    ("how close do the {A} and the {B} get to each other, like at their nearest points, in cm", "cm"),
    ("if I measured straight across from the {A} to the {B} at the closest spot, how many feet would that be?",
     "ft"),
    ("Would you mind working out how far apart the {A} and the {B} are at their closest? in millimetres please",
     "mm"),
    ("distance {A} to {B}, closest edges, in metres pls", "m"),
    ("the {B} is how far from the {A}? shortest gap, in inches", "in"),
]
# relative distance (every benchmark question asks which candidate is closest to {R}); {L} the four candidates in
# the benchmark's order, listed in the given style; options kept
REL = [
    ("could you tell me which one of these four is closest to the {R}: {L}?", "comma"),
    ("the {R} — out of {L}, which is nearest to it?", "comma_and"),
    ("um, like, what's nearest the {R} of these: {L}", "slash"),
    ("Sorry to ask, but which thing sits nearest the {R}, would it be {L}", "the_or"),
    ("if I'm measuring from the {R}, which of these four comes out closest: {L}", "comma_or"),
    ("{L} — out of those, which one's nearest to the {R}, edge to edge?", "the_and"),
    ("hey, {L}: what's the nearest thing to the {R}?", "the_comma_or"),
    ("between {L}, which would you say is the closest one to the {R}", "the_and"),
    ("what's closest to the {R}, {L}? just pick one", "or_or"),
    ("um the {R}... like which of these is closest to it? {L}", "comma"),
]
# directions: {A} where I stand, {B} what I face, {C} the object asked about
EASY = [
    "Sorry, if I'm over by the {A} looking towards the {B}, does the {C} appear left or right of the {B}?",
    "the {C} — left or right of the {B}? I'm stood by the {A}, facing the {B}",
    "um so I'm next to the {A}, my face pointed at the {B}... is the {C}, like, to its left or its right?",
    "Could you help me out: I've got the {A} right beside me and I'm facing the {B}. The {C}, which side of the {B} "
    "is that on, left or right?",
    "picture me at the {A}, eyes on the {B}: {C} on the left or the right of it?",
    "when I stand near the {A} and face the {B}, which way is the {C} from the {B}, left or right",
    "{A} next to me, {B} in front of me — so is the {C} to the left of the {B} or the right of it?",
    "hi, I'm by the {A}, turned to face the {B}. the {C} is to the left or right? of the {B} I mean",
    "looking at the {B} while standing beside the {A}, is the {C} going to be on the left or on the right of the "
    "{B}",
    "from beside the {A}, facing the {B}: left or right of the {B} for the {C}?",
]
MEDIUM = [
    "ok I'm stood by the {A}, facing the {B}. the {C}: is it to my left, to my right, or at my back?",
    "the {C} — is that off to my left, off to my right, or round the back of me, if I'm next to the {A} looking "
    "towards the {B}?",
    "um where's the {C} if I'm at the {A} and facing the {B}? like left, right or back behind me",
    "Could you tell me if the {C} is to my left, to my right, or behind me when I'm at the {A} with my face towards "
    "the {B}? (behind meaning I'd have to turn a hundred and thirty-five degrees or more)",
    "picture me near the {A} with my eyes on the {B}. {C}: left, right, or behind?",
    "if I'm facing the {B} from right beside the {A}, which is it for the {C} — left, right, or back?",
    "{A} at my side, {B} straight in front — is the {C} over to my left, my right or behind me?",
    "hi, standing next to the {A}, facing towards the {B}, would I have to look left, look right or turn round "
    "behind me to see the {C}?",
    "when I'm by the {A} and I've turned to the {B}, would you put the {C} on my left side, my right side, or behind?",
    "from the {A} looking at the {B}, the {C} is left/right/behind?",
]
HARD = [
    "Sorry to ask, I'm next to the {A} and have the {B} right in front of me. Which of the four quadrants is the {C} "
    "in: front-left, front-right, back-left, back-right?",
    "the {C}, where is it from me if I'm stood by the {A} with my face to the {B}? front-left / front-right / "
    "back-left / back-right",
    "um so if I'm at the {A} and looking towards the {B}, is the {C} like in front of me or behind me, and to the "
    "left or the right? (front-left, front-right, back-left or back-right)",
    "Could you tell me where the {C} falls, front left, front right, back left or back right, when I stand beside the "
    "{A} facing the {B}?",
    "picture me at the {A} with the {B} in front. {C}: front-left, front-right, back-left or back-right?",
    "facing the {B}, with the {A} right next to me — the {C} would be in which direction, front-left, front-right, "
    "back-left or back-right?",
    "{A} by my side, eyes on the {B}... does the {C} sit ahead of me on the left or the right, or behind me on the "
    "left or the right?",
    "hi! standing near the {A}, turned towards the {B}, whereabouts is the {C}: front-left, front-right, back-left, "
    "or back-right?",
    "when I'm over at the {A} with the {B} ahead, where's the {C} from me? front-left, front-right, back-left or "
    "back-right",
    "from beside the {A}, looking at the {B}, the {C} is where: front or back, and left or right?",
]
ORDINAL = ["first", "second", "third", "fourth", "fifth", "sixth", "seventh", "eighth"]


def convert(value: str, factor: float) -> str:
    return str(round(float(value) * factor, 4))


def say(name: str, rng: random.Random) -> str:
    """An everyday name for a benchmark category (its own name about 40 % of the time)."""
    return rng.choice(SYN[name]) if name in SYN and rng.random() < 0.6 else name


def plural(word: str) -> str:
    return PLURAL.get(word, word + ("es" if word.endswith(("sh", "ch", "x", "s")) else "s"))


def listing(words: list[str], style: str) -> str:
    """The four candidates as a person lists them."""
    the = ["the " + w for w in words]
    if style == "comma":
        return ", ".join(words)
    if style == "slash":
        return " / ".join(words)
    if style in ("comma_or", "comma_and"):
        return ", ".join(words[:-1]) + (" or " if style == "comma_or" else " and ") + words[-1]
    if style == "or_or":
        return " or ".join(the)
    if style == "the_comma_or":
        return ", ".join(the[:-1]) + ", or " + the[-1]
    return ", ".join(the[:-1]) + (" or " if style == "the_or" else " and ") + the[-1]


# --- one single-letter slip -----------------------------------------------------------------------------------------


def _slips(segs: list[Seg]) -> list[tuple[int, int, int, str]]:
    """Every place a slip may go: (segment, start, end, misspelling choices key)."""
    found = []
    for i, (text, is_obj) in enumerate(segs):
        table = TYPO_OBJECTS if is_obj else TYPO_WORDS
        for m in re.finditer(r"[A-Za-z']+", text):
            w = m.group(0).lower()
            if table.get(w):
                found.append((i, m.start(), m.end(), w))
    return found


def _pick(spots: list[tuple[int, int, int, str]], rng: random.Random) -> tuple[int, int, int, str]:
    """One place for the slip: a word drawn evenly from the distinct words that may carry one (so that 'the', said
    many times, is not misspelt most of the time), then one of its occurrences."""
    word = rng.choice(sorted({w for *_, w in spots}))
    return rng.choice([s for s in spots if s[3] == word])


def join(segs: list[Seg], rng: random.Random | None) -> str:
    """The question text; with `rng`, one word (a template word, or an object name listed in TYPO_OBJECTS) is
    misspelt once."""
    segs = list(segs)
    if rng is not None:
        spots = _slips(segs)
        if not spots:
            raise ValueError("no word to misspell in: " + "".join(t for t, _ in segs))
        i, a, b, w = _pick(spots, rng)
        table = TYPO_OBJECTS if segs[i][1] else TYPO_WORDS
        slip = rng.choice(table[w])
        orig = segs[i][0][a:b]
        if orig[:1].isupper():
            slip = slip[:1].upper() + slip[1:]
        segs[i] = (segs[i][0][:a] + slip + segs[i][0][b:], segs[i][1])
    return "".join(t for t, _ in segs)


# --- the eight types ------------------------------------------------------------------------------------------------
def rewrite(q: dict, k: int, rng: random.Random, typo: bool) -> dict:
    """Question `q` re-asked with pattern `k` of its type (options and answer letter kept)."""
    qt, text, gt = q["question_type"], q["question"], q["ground_truth"]
    key = "object_rel_direction" if qt.startswith("object_rel_direction") else qt
    m = re.search(TEMPLATES[key], text)
    if m is None:
        raise ValueError(f"question {q['id']} is not in the benchmark's {qt} wording")
    out = {**q, "source_id": q["id"]}
    if qt == "object_counting":
        one = say(m.group(1).strip(), rng)
        segs = _segments(COUNT[k], {"P": one, "Ps": plural(one)})
    elif qt == "object_size_estimation":
        tpl, unit = SIZE[k]
        segs = _segments(tpl, {"X": say(m.group(1), rng)})
        out["ground_truth"] = convert(gt, UNIT_FROM_CM[unit])
    elif qt == "room_size_estimation":
        tpl, unit = ROOM[k]
        segs = _segments(tpl, {})
        out["ground_truth"] = convert(gt, AREA_FROM_M2[unit])
    elif qt == "object_abs_distance":
        tpl, unit = ABS[k]
        segs = _segments(tpl, {"A": say(m.group(1), rng), "B": say(m.group(2), rng)})
        out["ground_truth"] = convert(gt, UNIT_FROM_M[unit])
    elif qt == "object_rel_distance":
        tpl, style = REL[k]
        cands = [c.strip() for c in m.group(1).split(",")]
        if len(cands) != 4:
            raise ValueError(f"question {q['id']}: {len(cands)} candidates, the patterns say four")
        said = [say(c, rng) for c in cands]
        # the list is written into the template, then each candidate's name marked as an object (for the slip)
        segs = _split_objects(_segments(tpl.replace("{L}", listing(said, style)), {"R": say(m.group(2), rng)}), said)
    else:
        tpl = {"object_rel_direction_easy": EASY, "object_rel_direction_medium": MEDIUM,
               "object_rel_direction_hard": HARD}[qt][k]
        segs = _segments(tpl, {"A": say(m.group(1), rng), "B": say(m.group(2), rng), "C": say(m.group(3), rng)})
    out["question"] = join(segs, rng if typo else None)
    return out


# --- route planning -------------------------------------------------------------------------------------------------


def route_parts(text: str) -> tuple[str, str, str, list[str | None]]:
    """(start, facing, goal, steps) of a benchmark route question (set 8's reading of the benchmark's template): a
    step is None for a turn to fill in, else where to walk to (or the rest of a step that is not 'until ...')."""
    m = ROUTE_RE.search(text)
    if m is None:
        raise ValueError(f"route question not in the benchmark's wording: {text[:80]}")
    start, face, goal, body = (_tidy(g) for g in m.groups())
    steps: list[str | None] = []
    for raw in re.split(r"\s*\b\d+\.\s+", " " + body):
        raw = raw.strip()
        if not raw:
            continue
        if FILL_RE.match(raw):
            steps.append(None)
            continue
        f = FORWARD_RE.match(raw)
        if f is None:
            raise ValueError(f"route step not understood: {raw!r}")
        steps.append(_tidy(f.group(1)))
    return start, face, goal, steps


def _move(rest: str, until: str, plain: str) -> tuple[str, str]:
    """(verb words, place) of a forward step: 'until the TV' keeps the place after `until`; a step that is not
    'until ...' ('about one foot', 'through the doorway until ...') keeps its own words after `plain`."""
    if rest.split(" ", 1)[0].lower() in ("about", "through"):
        return plain + " ", rest
    return until + " ", rest


def route_question(q: dict, k: int, rng: random.Random | None) -> dict:
    """Route question `q` in pattern `k` (0 or 1), options kept; with `rng`, one word the pattern adds is misspelt
    (never a waypoint: those stay the benchmark's own words)."""
    start, face, goal, steps = route_parts(q["question"])
    blanks = sum(s is None for s in steps)
    segs: list[Seg] = []
    if k == 0:  # first person, ordinals in words, "(blank)" for each turn
        segs += [("Hi, could you help me with directions? Starting from ", False), (start, True),
                 (", looking at ", False), (face, True), (", I'm heading for ", False), (goal, True), (".", False)]
        for i, s in enumerate(steps):
            lead = " " + ORDINAL[i].capitalize() + ", "
            if s is None:
                segs.append((lead + "I turn (blank).", False))
            else:
                verb, place = _move(re.sub(r"\byour\b", "my", s), "I go forward until", "I go")
                segs += [(lead + verb, False), (place, True), (".", False)]
        segs.append((" Which way is the turn at the blank: left, right or back?" if blanks == 1 else
                     f" There are {NUMBER[blanks]} blanks; which way do I turn at each, in order: left, right or "
                     "back?", False))
    else:  # one run-on line, "?" for each turn
        segs += [("um so to get from ", False), (start, True), (" (facing ", False), (face, True),
                 (") over to ", False), (goal, True), (", the steps are: ", False)]
        for i, s in enumerate(steps):
            if i:
                segs.append(("; ", False))
            if s is None:
                segs.append(("turn ?", False))
            else:
                verb, place = _move(s, "head straight on till", "head straight on")
                segs += [(verb, False), (place, True)]
        segs.append((" — and that's the goal. what should the ? be, turn left, turn right or turn back?"
                     if blanks == 1 else
                     " — and that's the goal. what goes in each ?, like turn left, turn right or turn back?", False))
    text = "".join(t for t, _ in segs) if rng is None else _join_route(segs, rng)
    return {**q, "source_id": q["id"], "question": text}


def _join_route(segs: list[Seg], rng: random.Random) -> str:
    """The route question with one slip in a template segment (a segment flagged True is a waypoint)."""
    spots = [(i, a, b, w) for (i, a, b, w) in _slips([(t, False) for t, _ in segs]) if not segs[i][1]]
    if not spots:
        raise ValueError("no word to misspell in a route question")
    i, a, b, w = _pick(spots, rng)
    slip = rng.choice(TYPO_WORDS[w])
    if segs[i][0][a:a + 1].isupper():
        slip = slip[:1].upper() + slip[1:]
    segs = list(segs)
    segs[i] = (segs[i][0][:a] + slip + segs[i][0][b:], False)
    return "".join(t for t, _ in segs)


# --- the set --------------------------------------------------------------------------------------------------------
def build(questions: list[dict], used: set[int], seed: int) -> list[dict]:
    rng = random.Random(seed)
    by_type: dict[str, list[dict]] = {}
    for q in questions:
        by_type.setdefault(q["question_type"], []).append(q)
    rows = []
    n = N_PATTERNS * PER_PATTERN
    for qt in TYPES:
        pool = sorted(by_type[qt], key=lambda q: q["id"])
        fresh = [q for q in pool if q["id"] not in used]
        pick = rng.sample(fresh if len(fresh) >= n else pool, n)  # random order: each pattern gets varied scenes
        typo_rows = set(rng.sample(range(n), TYPO_PER_TYPE))
        rows += [rewrite(q, j // PER_PATTERN, rng, j in typo_rows) for j, q in enumerate(pick)]
    routes = sorted(by_type.get("route_planning", []), key=lambda q: q["id"])
    pairs = [(q, k) for q in routes for k in (0, 1)]
    typo_routes = set(rng.sample(range(len(pairs)), round(len(pairs) / 5)))
    rows += [route_question(q, k, rng if j in typo_routes else None) for j, (q, k) in enumerate(pairs)]
    return [{"id": ID_BASE + i, **{f: r.get(f) for f in ("dataset", "scene_name", "question_type", "question",
                                                         "options", "ground_truth", "source_id")}}
            for i, r in enumerate(rows)]


# --- the distance from the earlier sets -----------------------------------------------------------------------------
OBJ_WORDS = {w for v in SYN.values() for s in v for w in s.lower().split()} | set(TYPO_OBJECTS) | {
    "tv", "tvs", "tellies", "couches", "sofas", "chairs", "tables", "stools", "beds", "fridges", "loos", "baths",
    "refrigerators", "televisions", "washers", "machines", "toilets", "bathtubs", "cookers", "stoves", "settee",
    "tub", "set", "laundry", "bin", "trash", "can", "stovetop", "fire", "place", "dish"}


LIST_RE = re.compile(r"\bOBJ(?:\s+(?:(?:the|or|and|a|an)\s+)*OBJ)+\b")
_DIR = r"(?:front|back|rear|left|right|behind)"
OPTS_RE = re.compile(rf"\b(?:{_DIR}(?:\s+(?:or|and|the|to|on|my))*\s+)+{_DIR}\b")


def _tokens(text: str, waypoints: list[str] = ()) -> list[str]:
    """Words of a question with the benchmark's content masked: object names -> OBJ, a list of objects -> LIST, a
    run of direction option words -> OPTS, a route's waypoint phrases -> OBJ."""
    text = text.lower()
    for w in sorted(waypoints, key=len, reverse=True):
        text = text.replace(w.lower(), " OBJ ")
    words = ["OBJ" if w in OBJ_WORDS or w == "obj" else w for w in re.findall(r"[a-z0-9']+|OBJ", text)]
    joined = OPTS_RE.sub("OPTS", LIST_RE.sub("LIST", " ".join(words)))
    return joined.split()


def _waypoints(q: dict) -> list[str]:
    """The place phrases of a benchmark route question (as the benchmark and the patterns write them)."""
    start, face, goal, steps = route_parts(q["question"])
    out = [start, face, goal] + [s for s in steps if s]
    return out + [re.sub(r"\byour\b", "my", s) for s in out]


def overlap(rows: list[dict], earlier: list[dict], sources: dict[int, dict], n: int = 5) -> list[tuple[int, str, str]]:
    """For each new question, the longest run of words (the benchmark's content masked, see _tokens) it shares with
    any question of an earlier set, when that run is `n` words or longer: (length, run, question), longest first."""
    def toks(r: dict) -> list[str]:
        src = sources.get(r.get("source_id"))
        way = _waypoints(src) if r["question_type"] == "route_planning" and src else []
        return _tokens(r["question"], way)

    grams: set[tuple[str, ...]] = set()
    for r in earlier:
        t = toks(r)
        for size in range(n, len(t) + 1):
            for i in range(len(t) - size + 1):
                grams.add(tuple(t[i:i + size]))
    found = []
    for r in rows:
        t = toks(r)
        best = ()
        for i in range(len(t)):
            for j in range(i + n, len(t) + 1):
                if tuple(t[i:j]) in grams and j - i > len(best):
                    best = tuple(t[i:j])
        if best:
            found.append((len(best), " ".join(best), r["question"]))
    return sorted(set(found), reverse=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--questions", default=str(VSI / "questions.jsonl"))
    ap.add_argument("--seed", type=int, default=9)
    ap.add_argument("--set8", default=str(SET8), help="set 8's rows: their source questions are not drawn again")
    ap.add_argument("--out", default=str(HERE / "data" / "vsibench_paraphrases_holdout9.jsonl"))
    ap.add_argument("--check-overlap", action="store_true",
                    help="print the longest word runs (5+) the new questions share with the earlier sets; write "
                         "nothing")
    a = ap.parse_args()
    with open(a.questions) as f:
        qs = [json.loads(line) for line in f if line.strip()]
    used = set()
    if Path(a.set8).exists():
        with open(a.set8) as f:
            used = {json.loads(line)["source_id"] for line in f if line.strip()}
    rows = build(qs, used, a.seed)
    if a.check_overlap:
        earlier = []
        for p in sorted(glob.glob(str(HERE / "data" / "vsibench_paraphrases*.jsonl"))):
            if "holdout9" not in Path(p).name:
                with open(p) as f:
                    earlier += [json.loads(line) for line in f if line.strip()]
        for size, run, q in overlap(rows, earlier, {q["id"]: q for q in qs}):
            print(f"{size:2d} | {run} | {q}")
        return
    out = Path(a.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_suffix(out.suffix + ".tmp")
    with open(tmp, "w") as f:
        for r in rows:
            f.write(json.dumps(r) + "\n")
    tmp.replace(out)
    print(f"{len(rows)} questions -> {out}")


if __name__ == "__main__":
    main()
