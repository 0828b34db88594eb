"""Write benchmarks/data/vsibench_paraphrases_holdout10.jsonl: held-out wording set 10 for VSI-Bench.

Written without reading or running the question parser (nothing under runtime/, host/ or tests/, no query docs, no
golden files, no scores, no `mosaic` command). make_holdout8.py, make_holdout9.py, docs/holdout9.md and the earlier
wording sets (benchmarks/data/vsibench_paraphrases*.jsonl) were read only for the row format and to keep away from
their wordings; `--check` measures that (shared runs of words, below).

Every row re-asks one real benchmark question (`source_id`) about the same scene, the same objects in the same roles
(where I stand, what I face, what is asked about; the reference of a relative distance; the two objects of an
absolute distance) and, for multiple choice, the benchmark's own `options` list and answer letter, unchanged:

- 8 types x 10 wording patterns x 4 questions (object_counting, object_size_estimation, room_size_estimation,
  object_abs_distance, object_rel_distance, object_rel_direction_easy/medium/hard). Rows of one type are in pattern
  order: rows 4k..4k+3 of a type use pattern k (the lists below, in order). The questions are drawn at random
  (seed 10) from the benchmark questions of that type that neither set 8 nor set 9 used as a source. Where fewer
  than 40 such questions remain (object_rel_direction_easy: 17 of 97), every one of them is used and the rest are
  drawn at random from the questions sets 8/9 used (new wording, same question); `--check` prints how many.
- route_planning: every route question of the benchmark, twice (pattern 0, then pattern 1), options kept.

Styles new to this set (see docs/holdout10.md): terse commands and key: value notes, a reason given first ("I'm
pricing new flooring, so: ..."), the answer's form asked first ("Left or right? ..."), parenthetical asides, two or
three short sentences, lowercase chat without punctuation, voice transcription (no punctuation, run-ons, "okay so",
"um"), a robot's pose report, second person ("You're at the ..."), British turns of phrase ("d'you reckon", "give it
me", "turn round") and names (settee, hob, cooker, loo, bath, TV set; in about half the route questions rubbish bin,
bedside table, wardrobe, cupboard ... for the benchmark's place words, ROUTE_SYN), units in words ("Give me feet.",
"Metres, please.", "sqm", "m^2"). About one question in five (exactly 8 of the 40 rows of each type, 42 of the 208
route rows) has one single-letter slip from the fixed lists TYPO_WORDS / TYPO_OBJECTS: one edit from its word, none
of them an English word (`--check` tests both against /usr/share/dict when present); direction words, turn words,
units, numbers and route places are never misspelt.

Numbers asked in another unit carry the ground truth converted exactly and rounded to 4 places (1 in = 2.54 cm,
1 ft = 30.48 cm, 1 sq ft = 0.09290304 m^2): object sizes (benchmark: cm) in cm, mm, m, inches or feet; distances
(benchmark: m) in m, cm, mm, inches or feet; room areas (benchmark: m^2) in m^2 or square feet.

    python benchmarks/make_holdout10.py [--questions Q.jsonl] [--seed 10] [--out OUT.jsonl]
    python benchmarks/make_holdout10.py --check   # the checks below; writes nothing, exits 1 on any failure

`--check` (code in check_holdout10.py, beside this file) builds the set twice and compares the bytes, reads the
written file back (JSON of every row, counts per type), re-derives each converted number from the unit it reads in
the question text (independent of the pattern tables), tests that every source object (or an everyday name of it)
and every route place is named, that options and answer letters are the benchmark's, that room rows keep "combined"
and distance rows keep "closest points", the source overlap with sets 8/9, the slips, and prints the longest runs
of 5+ words (benchmark content masked) shared with any earlier set.
"""
from __future__ import annotations

import argparse
import json
import random
import re
import subprocess
import sys
from pathlib import Path

from holdout_common import (CM_IN, FILL_RE, FORWARD_RE, NUMBER, N_PATTERNS, PER_PATTERN, ROUTE_RE, SQM_IN, Seg,
                            TYPES, TYPO_PER_TYPE, _noun, _segments, _split_objects, _tidy, convert, dumps,
                            join_with_slip, source_objects)

HERE = Path(__file__).resolve().parent
VSI = HERE.parent.parent / "shared" / "data" / "vsibench"
EARLIER_SOURCES = [HERE / "data" / "vsibench_paraphrases_holdout8.jsonl",
                   HERE / "data" / "vsibench_paraphrases_holdout9.jsonl"]
OUT = HERE / "data" / "vsibench_paraphrases_holdout10.jsonl"
ID_BASE = 1100000

# everyday (often British) names a native speaker reads without context; the benchmark's name is kept ~40 % of the time
SYN = {"sofa": ["settee", "couch", "settee"], "tv": ["TV", "television", "TV set"],
       "refrigerator": ["fridge", "fridge"], "washer": ["washing machine", "washing machine"],
       "stove": ["cooker", "hob", "cooker"], "bathtub": ["bath", "tub"], "toilet": ["loo", "loo"]}
PLURAL = {"couch": "couches", "TV": "TVs", "TV set": "TV sets", "washing machine": "washing machines"}

# one single-letter slip per word (a letter dropped, doubled, swapped with its neighbour or replaced by a keyboard
# neighbour); `--check` confirms each is one edit from its word and not itself an English word
TYPO_OBJECTS = {"table": ["talbe", "tabble"], "chair": ["cahir", "chaiir"], "stool": ["stooll", "stoo"],
                "settee": ["setee", "settwe"], "couch": ["couhc", "cocuh"], "fridge": ["frdige", "fridgw"],
                "television": ["televisoin", "telivision"], "cooker": ["cokker", "cookre"],
                "washing": ["wahsing", "wasshing"], "machine": ["machne", "nachine"],
                "dishwasher": ["dishwashr", "dishwahser"], "fireplace": ["firplace", "fireplcae"],
                "bathtub": ["bathtb", "bahtub"], "toilet": ["toilte", "toilt"], "stove": ["sotve", "stvoe"],
                "refrigerator": ["refrigirator", "refrigeratr"], "washer": ["wsher", "wasehr"]}
TYPO_WORDS = {"count": ["coutn", "cuont"], "number": ["numbr", "nubmer"], "total": ["totl", "tottal"],
              "inventory": ["inventroy", "invetory"], "exact": ["exatc", "exsct"], "there": ["thre", "tehre"],
              "contain": ["contian", "containn"], "reckon": ["reckn", "reckin"], "landlord": ["landlrod", "lanldord"],
              "dimension": ["dimnesion", "dimensoin"], "longest": ["longset", "lonest"], "length": ["lenght", "legth"],
              "width": ["widht", "witdh"], "height": ["heigth", "hieght"], "largest": ["largets", "larget"],
              "biggest": ["biggset", "bigest"], "greatest": ["greatets", "gratest"], "measure": ["meaure", "measrue"],
              "moving": ["movign", "moivng"], "house": ["hosue", "houes"], "whichever": ["whicever", "whichevr"],
              "please": ["pleaes", "plase"], "would": ["wolud", "woudl"], "size": ["sze"], "room": ["roomm", "roon"],
              "rooms": ["rooma", "roms"], "combined": ["combind", "conbined"], "several": ["sevral", "severl"],
              "video": ["vidoe", "vidio"], "flooring": ["floring", "flooing"], "pricing": ["pricign", "prcing"],
              "space": ["spcae", "sapce"], "together": ["togeher", "togehter"], "cover": ["covr", "cvoer"],
              "multiple": ["mutliple", "multple"], "shown": ["shwon", "shonw"], "distance": ["distnce", "distanec"],
              "closest": ["cloesst", "clsest"], "points": ["poitns", "pionts"], "point": ["piont", "poitn"],
              "nearest": ["neareest", "nearst"], "between": ["bewteen", "betwene"], "apart": ["aprat", "apaart"],
              "separation": ["seperation", "separaton"], "measuring": ["measurign", "meassuring"],
              "cable": ["cabel", "cble"], "measured": ["measurd", "meaured"], "answer": ["anwser", "answr"],
              "which": ["whihc", "wihch"], "object": ["objetc", "obejct"], "candidates": ["candiates", "canddiates"],
              "standing": ["standng", "stadning"], "facing": ["facng", "fcaing"], "looking": ["lookng", "looknig"],
              "arranging": ["arrangign", "aranging"], "furniture": ["furnture", "furnitrue"],
              "relative": ["relatvie", "relativ"], "parked": ["parkd", "prked"], "myself": ["mysefl", "myslef"],
              "side": ["sdie"], "where": ["whree", "wher"], "where's": ["whree's"], "what's": ["whta's"],
              "camera": ["camrea", "cmaera"], "setting": ["settign", "seting"],
              "quadrant": ["quadrnat", "quadarnt"], "planning": ["plannign", "plannig"], "lamp": ["lmap"],
              "origin": ["orign", "oirgin"], "robot": ["robto", "rboot"], "heading": ["headng", "haeding"],
              "report": ["reprot", "repotr"], "classify": ["classfy", "clasify"],
              "suppose": ["supose", "suppoe"], "going": ["goign", "giong"], "okay": ["oaky", "okya"], "need": ["nede"],
              "route": ["rotue", "rute"], "drive": ["drvie", "dirve"], "until": ["untl", "unitl"], "keep": ["kepe"],
              "each": ["eahc"], "time": ["tiem"], "order": ["ordr", "orer"], "fill": ["flil", "fiill"],
              "just": ["jsut"], "tell": ["tlel"], "could": ["cuold", "coudl"], "graph": ["grpah"], "check": ["chekc"],
              "thing": ["thign"], "clear": ["cleaar"]}
NEVER_MISSPELT = {"left", "right", "front", "back", "behind", "turn", "turns", "forward", "ahead", "toward",
                  "towards", "degrees", "metres",
                  "meters", "feet", "foot", "inches", "square", "centimetres", "millimetres", "sqm", "cm", "mm", "ft",
                  "one", "two", "three"}

# --- the wording patterns (10 per type) ---------------------------------------------------------------------------
# counting: {P} one object, {Ps} its plural (every benchmark count is 2 or more)
COUNT = [
    "count {Ps} in this room. just the number",                                          # terse command
    "I'm doing an inventory for the landlord, so: how many {Ps} are there in this room?",  # reason first
    "A number, please: {Ps} in this room, how many are there?",                          # answer form first
    "hey how many {Ps} are there in this room um I need an exact count",                 # voice
    "(it's for an insurance form, so every one counts) How many {Ps} are there in this room?",  # aside
    "You've seen this whole room. How many {Ps} does it contain?",                        # second person, 2 sentences
    "Need a number. The {Ps} in here: what's the total?",                                 # split
    "yo how many {Ps} in this room",                                                      # lowercase chat
    "Reckon you could tell me how many {Ps} there are in this room?",                     # British
    "{Ps} in this room?? how many, exactly",                                              # object first, chat
]
# object size (benchmark: the longest of length, width, height, in cm): (wording, unit)
SIZE = [
    ("size check: {X}, longest of length/width/height, cm", "cm"),
    ("We're moving house and the {X} has to go in the van, so: how long is it along its biggest dimension? Metres, "
     "please.", "m"),
    ("Inches please. The {X}'s largest dimension (length, width or height), roughly?", "in"),
    ("okay so how big is the {X} at its longest like whichever is biggest out of length width or height in "
     "centimetres", "cm"),
    ("How long is the {X} (take whichever of height, width or length is greatest) in millimetres?", "mm"),
    ("Give or take is fine. How many feet does the {X} span along its longest dimension?", "ft"),
    ("You've got eyes on the {X}: how big would you say it is at its biggest, length, width or height? answer in cm",
     "cm"),
    ("Do you reckon you could size up the {X} for me? Its longest dimension, in metres.", "m"),
    ("whats the {X}'s max dimension in inches", "in"),
    ("I'd like the length of the {X} along its longest dimension. Give me feet.", "ft"),
]
# room size (benchmark: m^2, every room shown counted as one combined space): (wording, unit)
ROOM = [
    ("room area in m^2? (if the video covers several rooms, treat them as one combined space)", "m2"),
    ("I'm pricing new flooring, so: what's this room's area in square feet? If the video shows more than one room, I "
     "want the combined total.", "ft2"),
    ("Square metres, roughly: how big is this room? Several rooms shown = add them together.", "m2"),
    ("um so what's the size of this room in square feet and if there's like multiple rooms in the video just give me "
     "the combined space", "ft2"),
    ("What's the floor area here (all rooms together, if there's more than one) in sq m?", "m2"),
    ("You've been round this whole place. How many square metres does it cover? Count multiple rooms as one combined "
     "space.", "m2"),
    ("Need a rough size for this room in sq ft. If it's more than one room, combine them.", "ft2"),
    ("how many sqm is this room (if theres more than 1 room the combined space)", "m2"),
    ("How big is the room, in square metres? Mind, if there's more than one room in the video, I'd like them "
     "combined.", "m2"),
    ("Give me the room's size in square feet, please, and if several rooms are shown, the size of the combined "
     "space.", "ft2"),
]
# absolute distance (benchmark: between the closest points of the two objects, in m): (wording, unit); {A} and {B}
# are the benchmark's first and second object (the distance is the same either way round)
ABS = [
    ("{A} and {B}, nearest-point distance, cm?", "cm"),
    ("I want to run a cable from the {A} to the {B}, so: how far apart are they at their closest points? In feet.",
     "ft"),
    ("Metres please: what's the separation between the {A} and the {B}, measured from the closest point of each?",
     "m"),
    ("okay how far is the {A} from the {B} um measuring from the nearest points on each of them in inches", "in"),
    ("How wide is the gap from the {B} to the {A} (at their nearest parts), in millimetres?", "mm"),
    ("Could you measure between the {A} and the {B} for me, closest point to closest point? Metres.", "m"),
    ("Roughly how far apart are the {A} and the {B}? Closest points, in centimetres.", "cm"),
    ("how far {A} to {B} in ft (closest points)", "ft"),
    ("What's the distance between the {A} and the {B}, taken at their closest points? Give it me in inches.", "in"),
    ("How much clear space is there between the {A} and the {B} where they come closest? Answer in metres.", "m"),
]
# relative distance (every benchmark question asks which candidate is closest to {R}, closest points); {L} the four
# candidates in the benchmark's order (which is also the options' order), listed in the given style; options kept
REL = [
    ("nearest to the {R} (closest-point distance): {L}?", "comma_or"),
    ("I'm putting a rug down by the {R}, so: which of these is closest to it, measured from the closest points: {L}?",
     "the_or"),
    ("Pick one: {L}. Which sits closest to the {R}, judging by the gap between their nearest points?", "slash"),
    ("okay which one is closest to the {R} um is it {L} measuring from the closest points", "or_or"),
    ("Which object is nearest the {R} ({L}; measured between closest points)?", "comma_or"),
    ("From the {R}, which would you say is the shortest distance away: {L}? Count from the closest point of each.",
     "the_comma_or"),
    ("Four candidates: {L}. Going by the closest points, which one is nearest the {R}?", "the_and"),
    ("whats nearest the {R} out of {L} (closest pts)", "comma"),
    ("Of {L}, which is closest to the {R}? (closest point to closest point)", "lettered"),
    ("I need to know which thing is closest to the {R}: {L}. (Closest points, not centres.)", "either"),
]
# directions: {A} where I stand, {B} what I face, {C} the object asked about
EASY = [
    "stand: {A}. face: {B}. is the {C} left or right of the {B}?",
    "I'm arranging furniture and need to check something: standing at the {A} and facing the {B}, does the {C} lie "
    "to the left of the {B} or to its right?",
    "Left or right? The {C}, relative to the {B}, when I'm at the {A} facing the {B}.",
    "okay so I'm standing next to the {A} and I'm facing the {B} is the {C} on the left side of the {B} or the right "
    "side",
    "Is the {C} left or right of the {B} (seen from the {A}, looking straight at the {B})?",
    "You're at the {A}, facing the {B}. From where you are, is the {C} on the left of the {B} or on its right?",
    "I've parked myself by the {A}, facing the {B}. Looking from here, does the {C} sit left or right of the {B}?",
    "im by the {A} lookin at the {B}.. the {C} is left or right of the {B}?",
    "If I'm at the {A} and swing round to face the {B}, would the {C} be to the left of the {B} or to the right of "
    "it, d'you reckon?",
    "Robot pose: at the {A}, heading toward the {B}. Report which side of the {B} the {C} is on, left or right.",
]
MEDIUM = [
    "position {A}, facing {B}. {C}: left, right or back?",
    "I'm setting up a camera and need to know: if I'm stationed by the {A}, facing the {B}, which is the {C}: my "
    "left, my right, or my back (meaning I'd turn 135 degrees or more to face it)?",
    "Left, right or behind: that's what I need for the {C}, while I'm by the {A} and facing the {B}.",
    "so um if I'm standing by the {A} facing the {B} where's the {C} is it on my left my right or behind me",
    "Where is the {C} relative to me (left, right, or back, where back means I'd have to turn at least 135 degrees) "
    "when I stand next to the {A} facing the {B}?",
    "Suppose you stood beside the {A} facing the {B}: is the {C} then on your left, your right, or at your back?",
    "I'm next to the {A}. I'm facing the {B}. Left, right, or behind me: where's the {C}?",
    "me by the {A}, facing the {B}: {C} left right or behind me?",
    "With me by the {A} and facing the {B}, would I find the {C} to my left, to my right, or would I have to turn "
    "round (135 degrees or more) to face it?",
    "Robot at the {A}, oriented toward the {B}. Classify the {C}: left, right, or back (back = a turn of 135 degrees "
    "or more).",
]
HARD = [
    "stand {A}, face {B}: which quadrant is the {C} in? front-left / front-right / back-left / back-right",
    "I'm planning where to put a lamp. With the {A} beside me and the {B} in front, which quadrant holds the {C}: "
    "front-left, front-right, back-left or back-right?",
    "Front-left, front-right, back-left or back-right: that's where the {C} is when I'm at the {A} looking at the "
    "{B}. Which one?",
    "okay so right now I'm at the {A} turned towards the {B} and I wanna know if the {C} is front left front right "
    "back left or back right",
    "Which quadrant (front-left, front-right, back-left, back-right, as on a graph with me at the origin facing up the "
    "y-axis) is the {C} in, if I'm standing by the {A} facing the {B}?",
    "Say you're parked beside the {A}, pointed at the {B}. Is the {C} in your front-left, front-right, back-left or "
    "back-right quadrant?",
    "Standing by the {A}. Facing the {B}. What's the {C}'s quadrant: front-left, front-right, back-left or "
    "back-right?",
    "{C} - front left, front right, back left or back right? me at the {A}, facing the {B}",
    "Me at the {A}, the {B} in front of me: where's the {C} then, d'you reckon? Front-left, front-right, back-left "
    "or back-right?",
    "Robot at the {A}, heading toward the {B}. Give the quadrant of the {C}: front-left, front-right, back-left or "
    "back-right.",
]


def say(name: str, rng: random.Random) -> str:
    """An everyday name for a benchmark category (its own name about 40 % of the time)."""
    return rng.choice(SYN[name]) if name in SYN and rng.random() < 0.6 else name


def plural(word: str) -> str:
    return PLURAL.get(word, word + ("es" if word.endswith(("sh", "ch", "x", "s")) else "s"))


def listing(words: list[str], style: str) -> str:
    """The four candidates as a person lists them (in the benchmark's order)."""
    the = ["the " + w for w in words]
    if style == "comma":
        return ", ".join(words)
    if style == "slash":
        return " / ".join(words)
    if style == "comma_or":
        return ", ".join(words[:-1]) + " or " + words[-1]
    if style == "or_or":
        return " or ".join(the)
    if style == "the_comma_or":
        return ", ".join(the[:-1]) + ", or " + the[-1]
    if style == "either":
        return "either " + ", ".join(the[:-1]) + " or " + the[-1]
    if style == "lettered":  # the letters are the benchmark's: its options list the candidates in this order
        return " ".join(f"{'ABCD'[i]}) {w}" for i, w in enumerate(words))
    if style in ("the_or", "the_and"):
        return ", ".join(the[:-1]) + (" or " if style == "the_or" else " and ") + the[-1]
    raise ValueError(f"unknown list style {style!r}")


# --- one single-letter slip -----------------------------------------------------------------------------------------


def join(segs: list[Seg], rng: random.Random | None, objects_too: bool = True) -> str:
    """The question text; with `rng`, one word of this set's slip tables misspelt once (`join_with_slip`)."""
    return join_with_slip(segs, rng, TYPO_WORDS, TYPO_OBJECTS, NEVER_MISSPELT, objects_too, word_re=r"[A-Za-z']+")


# --- the eight types ------------------------------------------------------------------------------------------------


def rewrite(q: dict, k: int, rng: random.Random, typo: bool) -> dict:
    """Question `q` re-asked with pattern `k` of its type (options and answer letter kept)."""
    qt, gt = q["question_type"], q["ground_truth"]
    objs = source_objects(q)
    out = {**q, "source_id": q["id"]}
    if qt == "object_counting":
        one = say(objs[0], rng)
        segs = _segments(COUNT[k], {"P": one, "Ps": plural(one)})
    elif qt == "object_size_estimation":
        tpl, unit = SIZE[k]
        segs = _segments(tpl, {"X": say(objs[0], rng)})
        out["ground_truth"] = convert(gt, CM_IN[unit])
    elif qt == "room_size_estimation":
        tpl, unit = ROOM[k]
        segs = _segments(tpl, {})
        out["ground_truth"] = convert(gt, SQM_IN[unit])
    elif qt == "object_abs_distance":
        tpl, unit = ABS[k]
        segs = _segments(tpl, {"A": say(objs[0], rng), "B": say(objs[1], rng)})
        out["ground_truth"] = convert(gt, CM_IN[unit] / 100.0)
    elif qt == "object_rel_distance":
        tpl, style = REL[k]
        cands, ref = objs[:-1], objs[-1]
        if len(cands) != 4:
            raise ValueError(f"question {q['id']}: {len(cands)} candidates, the patterns say four")
        said = [say(c, rng) for c in cands]
        segs = _split_objects(_segments(tpl.replace("{L}", listing(said, style)), {"R": say(ref, rng)}), said)
    else:
        tpl = {"object_rel_direction_easy": EASY, "object_rel_direction_medium": MEDIUM,
               "object_rel_direction_hard": HARD}[qt][k]
        segs = _segments(tpl, {"A": say(objs[0], rng), "B": say(objs[1], rng), "C": say(objs[2], rng)})
    out["question"] = join(segs, rng if typo else None)
    return out


# --- route planning -------------------------------------------------------------------------------------------------


# British names for route places (a whole word inside the benchmark's phrase), each swapped in about half the
# questions, the same way everywhere in one question, and never where the new name is already in the question
ROUTE_SYN = {"trash bin": "rubbish bin", "trash can": "bin", "nightstand": "bedside table", "refrigerator": "fridge",
             "closet": "wardrobe", "cabinet": "cupboard", "cabinets": "cupboards", "sofa": "settee",
             "bathtub": "bath", "toilet": "loo", "washer": "washing machine", "tv": "television"}


def route_names(text: str, rng: random.Random) -> dict[str, str]:
    """The swaps chosen for one route question (benchmark text `text`)."""
    out = {}
    for key in sorted(ROUTE_SYN):
        if re.search(rf"\b{key}\b", text, re.I) and rng.random() < 0.5 \
                and not re.search(rf"\b{ROUTE_SYN[key]}\b", text, re.I):
            out[key] = ROUTE_SYN[key]
    return out


def rename(phrase: str, names: dict[str, str]) -> str:
    if not names:
        return phrase
    pat = re.compile(r"\b(" + "|".join(sorted(names, key=len, reverse=True)) + r")\b", re.I)
    return pat.sub(lambda m: names[m.group(0).lower()], phrase)


def route_parts(text: str) -> tuple[str, str, str, list[tuple[str, str] | None]]:
    """(start, facing, goal, steps) of a benchmark route question: a step is None for a turn to fill in, else
    (kind, words): kind 'until' for 'Go forward until X' (words X), 'plain' for another forward step ('about one
    foot', 'through the doorway until the painting', words kept)."""
    m = ROUTE_RE.search(text)
    if m is None:
        raise ValueError(f"route question not in the benchmark's wording: {text[:80]}")
    start, face, goal, body = (_tidy(g) for g in m.groups())
    steps: list[tuple[str, str] | None] = []
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
        rest = _tidy(f.group(1))
        plain = not re.match(r"Go forward\s+(?:until|untli)\b", raw)
        steps.append(("plain" if plain else "until", rest))
    return start, face, goal, steps


def route_question(q: dict, k: int, names: random.Random, rng: random.Random | None) -> dict:
    """Route question `q` in pattern `k` (0 or 1), options kept, some places given British names (ROUTE_SYN, drawn
    with `names`); with `rng`, one word the pattern adds is misspelt (never a place: those keep the benchmark's
    words)."""
    start, face, goal, steps = route_parts(q["question"])
    swap = route_names(q["question"], names)
    start, face, goal = rename(start, swap), rename(face, swap), rename(goal, swap)
    steps = [s if s is None else (s[0], rename(s[1], swap)) for s in steps]
    blanks = sum(s is None for s in steps)
    segs: list[Seg] = []
    if k == 0:  # voice transcription, first person, no punctuation: each blank is "I turn"
        segs += [("okay so I'm at ", False), (start, True), (" facing ", False), (_noun(face), True),
                 (" and I need to get to ", False), (goal, True), (" so first ", False)]
        for i, s in enumerate(steps):
            if i:
                segs.append((" then ", False))
            if s is None:
                segs.append(("I turn", False))
            else:
                kind, words = s
                segs += [("I keep going until " if kind == "until" else "I keep going ", False),
                         (re.sub(r"\byour\b", "my", words), True)]
        segs.append((" and that's it um which way do I turn there left right or turn back" if blanks == 1 else
                     " and that's it um which way do I turn each time in order left right or turn back", False))
    else:  # answer form first, robot in the second person, the route as arrows with [?] for each blank
        segs.append(("Fill in the turn (left, right or back). " if blanks == 1 else
                     f"Fill in each of the {NUMBER[blanks]} turns (left, right or back), in order. ", False))
        segs += [("You're a robot at ", False), (start, True), (" with ", False), (_noun(face), True),
                 (" in front of you, going to ", False), (goal, True), (". Route: ", False)]
        for i, s in enumerate(steps):
            if i:
                segs.append((" -> ", False))
            if s is None:
                segs.append(("[turn ?]", False))
            else:
                kind, words = s
                segs += [("drive forward until " if kind == "until" else "drive forward ", False), (words, True)]
        segs.append((" -> done.", False))
    text = join(segs, rng, objects_too=False)
    return {**q, "source_id": q["id"], "question": text}


# --- the set --------------------------------------------------------------------------------------------------------
def earlier_sources(paths: list[Path]) -> set[int]:
    used: set[int] = set()
    for p in paths:
        if Path(p).exists():
            with open(p) as f:
                used |= {json.loads(line)["source_id"] for line in f if line.strip()}
    return used


def draw(pool: list[dict], used: set[int], n: int, rng: random.Random) -> list[dict]:
    """`n` questions at random, none an earlier set used while enough fresh ones remain; otherwise every fresh one
    and the rest drawn from the used ones. Random order, so each pattern gets varied scenes."""
    fresh = [q for q in pool if q["id"] not in used]
    if len(fresh) >= n:
        return rng.sample(fresh, n)
    pick = fresh + rng.sample([q for q in pool if q["id"] in used], n - len(fresh))
    rng.shuffle(pick)
    return pick


def build(questions: list[dict], used: set[int], seed: int) -> list[dict]:
    rng = random.Random(seed)
    by_type: dict[str, list[dict]] = {}
    for q in questions:
        by_type.setdefault(q["question_type"], []).append(q)
    rows = []
    n = N_PATTERNS * PER_PATTERN
    for qt in TYPES:
        pick = draw(sorted(by_type[qt], key=lambda q: q["id"]), used, n, rng)
        typo_rows = set(rng.sample(range(n), TYPO_PER_TYPE))
        rows += [rewrite(q, j // PER_PATTERN, rng, j in typo_rows) for j, q in enumerate(pick)]
    routes = sorted(by_type.get("route_planning", []), key=lambda q: q["id"])
    pairs = [(q, k) for q in routes for k in (0, 1)]
    typo_routes = set(rng.sample(range(len(pairs)), round(len(pairs) / 5)))
    rows += [route_question(q, k, rng, rng if j in typo_routes else None) for j, (q, k) in enumerate(pairs)]
    return [{"id": ID_BASE + i, **{f: r.get(f) for f in ("dataset", "scene_name", "question_type", "question",
                                                         "options", "ground_truth", "source_id")}}
            for i, r in enumerate(rows)]


def load_questions(path: str) -> list[dict]:
    try:
        with open(path) as f:
            return [json.loads(line) for line in f if line.strip()]
    except (OSError, json.JSONDecodeError) as e:
        print(f"error: {path}: {e}", file=sys.stderr)
        sys.exit(2)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--questions", default=str(VSI / "questions.jsonl"))
    ap.add_argument("--seed", type=int, default=10)
    ap.add_argument("--out", default=str(OUT))
    ap.add_argument("--check", action="store_true", help="run the checks on --out; write nothing")
    a = ap.parse_args()
    if a.check:  # the checks import this generator: they run as their own script, so no import goes back
        sys.exit(subprocess.run([sys.executable, str(HERE / "check_holdout10.py"), "--questions", a.questions,
                                 "--seed", str(a.seed), "--out", a.out]).returncode)
    qs = load_questions(a.questions)
    used = earlier_sources(EARLIER_SOURCES)
    out = Path(a.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_suffix(out.suffix + ".tmp")
    tmp.write_bytes(dumps(build(qs, used, a.seed)))
    tmp.replace(out)
    print(f"{len(qs)} benchmark questions read; set 10 written -> {out}")


if __name__ == "__main__":
    main()
