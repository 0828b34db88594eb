"""Write benchmarks/data/vsibench_paraphrases_holdout8.jsonl: a ninth held-out wording set for VSI-Bench.

Written without reading or running the question parser, and after reading the earlier sets
(`make_paraphrases.py`) only to avoid their wordings. Every row re-asks one real benchmark question (`source_id`)
about the same scene and the same objects, with the benchmark's own ground truth:

- 8 types x 10 wording patterns x 4 questions (object_counting, object_size_estimation, room_size_estimation,
  object_abs_distance, object_rel_distance, object_rel_direction_easy/medium/hard). Rows of one type are in pattern
  order: rows 4k..4k+3 of a type use pattern k (the pattern lists below, in order).
- route_planning: every route question of the benchmark, twice (pattern 0, then pattern 1), options kept.

Numbers asked in another unit carry the ground truth converted exactly (rounded to 4 places): cm, mm, inches and
feet for object sizes; m, cm, mm, inches and feet for distances; m^2 and square feet for room areas. Multiple
choice keeps the benchmark's options and letter, except in the patterns marked "words", where the choices are
written into the question, `options` is null and the ground truth is the right choice's words as the question
writes them (a synonym where the question uses one). Object names are said with everyday synonyms (couch, fridge,
television, washing machine, tub, cooker ...), plurals where a person would use them (from the scene's own
object counts), and a few realistic typos.

    python benchmarks/make_holdout8.py [--questions Q.jsonl] [--meta META.json] [--seed 8] [--out OUT.jsonl]
"""
from __future__ import annotations

import argparse
import json
import random
import re
from pathlib import Path

from holdout_common import (AREA_FROM_M2, FILL_RE, FORWARD_RE, PER_PATTERN, ROUTE_RE, TEMPLATES, TYPES, UNIT_FROM_CM,
                            UNIT_FROM_M, _tidy)

HERE = Path(__file__).resolve().parent
VSI = HERE.parent.parent / "shared" / "data" / "vsibench"
ID_BASE = 900000

# everyday names for the benchmark's categories; a name is swapped for one of these about half the time
SYN = {"sofa": ["couch", "settee", "couch"], "tv": ["TV", "television", "tv set"], "refrigerator": ["fridge"],
       "washer": ["washing machine", "laundry machine"], "dishwasher": ["dish washer"],
       "bathtub": ["tub", "bath"], "stove": ["cooker", "stovetop"], "fireplace": ["fire place"],
       "toilet": ["loo"], "trash bin": ["bin", "trash can"]}
# misspellings people really type, used by the patterns that carry typos
TYPO = {"refrigerator": "refridgerator", "television": "televison", "toilet": "toliet", "bathtub": "bathub",
        "dishwasher": "dishwaser", "fireplace": "fireplce", "couch": "cocuh", "chair": "chiar", "table": "tabel"}
IRREGULAR = {"couch": "couches", "settee": "settees", "tv set": "tv sets", "shelf": "shelves", "bench": "benches"}

# --- the wording patterns (10 per type) -------------------------------------------------------------------------
# counting: {P} one object, {Ps} its plural
COUNT = [
    "quick one: how many {Ps} did you spot in this room?",
    "I'm trying to figure out how many {Ps} this place has",
    "count up every {P} in here for me and give me the total",
    "cant rember hwo many {Ps} there were in here, waht was it?",  # typos
    "if you went around counting the {Ps}, what number would you end up with?",
    "any {Ps} in here? if so how many",
    "honestly I lost count of the {Ps}, how many are in this room?",
    "So the {Ps} in this room... what's the tally?",
    "how many {P} is there in this room",  # the plural dropped, as people do
    "Would you mind checking how many {Ps} the room has? just need the number",
]
# object size (benchmark: longest dimension in cm): (wording, unit)
SIZE = [
    ("the {X} — how long is it at its longest, in inches?", "in"),
    ("quick one: what's the biggest measurement of the {X} in feet?", "ft"),
    ("I'm trying to figure out whether the {X} would fit through a doorway. How long is its longest side, in cm?",
     "cm"),
    ("ballpark figure for teh {X}'s longets side? cm pls", "cm"),  # typos
    ("give me a rough measurement of the {X}, longest edge, in metres please", "m"),
    ("how big is the {X} — length, width or height, whichever's the biggest — in millimetres?", "mm"),
    ("roughly how many centimeters does the {X} measure at its longest point, end to end?", "cm"),
    ("if you put a tape measure along the longest side of the {X}, what would it read in feet?", "ft"),
    ("you see the {X}? how big is it across its longest side", "cm"),
    ("{X} dimensions — what's the largest one, in centimetres?", "cm"),
]
# room size (benchmark: m^2, all rooms shown together): (wording, unit)
ROOM = [
    ("how many square feet is this room?", "ft2"),
    ("quick one: what's the floor area of this place in m2?", "m2"),
    ("I'm trying to figure out how big this space is. square meters?", "m2"),
    ("tell me the total area of the whole space, all the rooms you saw, in square metres", "m2"),
    ("whats the sqaure footage of this room", "ft2"),  # typos
    ("the room in this video — how big is it in sq m?", "m2"),
    ("roughly how much floor space is there, counting every room that's shown?", "m2"),
    ("if you add up all the rooms in the video, how many square meters do you get", "m2"),
    ("How large is this room area-wise? Answer in square feet please.", "ft2"),
    ("Estimate the room's area for me (m²).", "m2"),
]
# absolute distance (benchmark: closest points, metres): (wording, unit)
ABS = [
    ("the {A}... how far is that from the {B}, in feet?", "ft"),
    ("quick one - what's the clearance between the {A} and the {B} in mm?", "mm"),
    ("I'm trying to figure out the distance from my {A} over to the {B}, in inches", "in"),
    ("hw far apart do the {A} and teh {B} sit from eachother?", "m"),  # typos
    ("In cm, tell me how close the {B} sits to the {A}.", "cm"),
    ("is the {A} more than a couple of metres away from the {B}? whats the actual distance", "m"),
    ("from the nearest edge of the {A} to the nearest edge of the {B}, how far is it in feet?", "ft"),
    ("how many meters r there between the {A} n the {B}", "m"),
    ("honestly no idea how far the {B} is from the {A}, can you work it out in metres?", "m"),
    ("say you walk straight from the {A} to the {B}. how many centimeters is that?", "cm"),
]
# relative distance (every benchmark question asks for the closest): (wording, list style, mode)
# mode "opts" keeps the benchmark's option list; "words" writes the choices into the question only
REL = [
    ("quick one about the {R}: which of {L} is closer to it than the others?", "bare", "opts"),
    ("I'm trying to work out which thing is the shortest distance from the {R} — {L}?", "the_or", "opts"),
    ("point me to whatever is closest to the {R}: {L}", "slash", "opts"),
    ("looking for whichever is closets to teh {R}: {L}", "bare", "opts"),  # typos
    ("there's {L} in here: which of them sits closest to the {R}?", "counted", "opts"),
    ("you're standing at the {R}. which of {L} is nearest to you?", "the_or", "opts"),
    ("honestly can't tell — is {L} closer to the {R}?", "or_or", "words"),
    ("nearest neighbour of the {R} among {L}?", "the_and", "words"),
    ("which one's got the smallest gap to the {R}: {L}", "the_or", "opts"),
    ("the {R} — what's the nearest of these to it?", None, "opts"),
]
# directions: {A} where I stand, {B} what I face, {C} the object asked about; (wording, mode)
EASY = [
    ("with my back to the {A} and the {B} in front of me, is the {C} on the left or the right?", "opts"),
    ("imagine you're at the {A}, looking over at the {B}. the {C}: left side or right side?", "opts"),
    ("The {B} is dead ahead of me and I'm next to the {A}. Which side is the {C} on, left or right?", "opts"),
    ("teh {C} - is it left or rigth of the {B} when im over by the {A} facing it?", "opts"),  # typos
    ("quick one: the {A} behind me, the {B} in front. the {C}, left or right?", "opts"),
    ("I'm trying to figure out the layout: from the {A}, the {B} is in front. Does the {C} sit to its left or its "
     "right?", "opts"),
    ("tell me whether the {C} is left or right of the {B} when you look at it from the {A}", "opts"),
    ("honestly confused — when I'm at the {A} turned to the {B}, is the {C} on my left-hand side or right-hand side?",
     "words"),
    ("heading from the {A} towards the {B}, would the {C} be on my left or my right?", "words"),
    ("stood at the {A} staring at the {B}, is the {C} off to the left or off to the right", "opts"),
]
MEDIUM = [
    ("with my back to the {A}, looking at the {B}: is the {C} to my left, my right, or behind me?", "opts"),
    ("you're by the {A} and the {B} is in front of you. is the {C} on your left, on your right, or back behind you?",
     "opts"),
    ("I'm at the {A} and the {B} is straight ahead of me. where does that put the {C}: left, right, or behind?",
     "opts"),
    ("so im at teh {A}, lookng at the {B} - {C} is on my left, rigth or behind?", "opts"),  # typos
    ("quick one - facing the {B}, the {A} at my back: is the {C} left, right or behind?", "opts"),
    ("tell me if the {C} would be to my left, to my right or behind me if I stood at the {A} and looked toward the "
     "{B}", "opts"),
    ("honestly can't picture it. I'm next to the {A}, turned toward the {B}. the {C} — left, right, or behind?",
     "words"),
    ("imagine standing at the {A} looking over toward the {B}. which way is the {C}: left, right or back?", "words"),
    ("if I walk up to the {A} and turn to face the {B}, is the {C} on my left, on my right or behind me?", "opts"),
    ("at {A} facing {B} where is {C} left right or behind", "opts"),
]
HARD = [
    ("with my back to the {A} and the {B} ahead, which corner is the {C} in: front left, front right, back left or "
     "back right?", "opts"),
    ("you're standing at the {A}, looking at the {B}. is the {C} in front of you to the left, in front to the right, "
     "behind you on the left, or behind you on the right?", "opts"),
    ("The {B} is straight ahead of me and I'm at the {A}. Is the {C} front-left, front-right, back-left or "
     "back-right?", "opts"),
    ("wich way is the {C} from me - front left, front right, back left or back right - if im standing by teh {A} "
     "lookng at the {B}", "opts"),  # typos
    ("quick one: the {A} at my back, facing the {B} — {C} front-left/front-right/back-left/back-right?", "opts"),
    ("tell me which diagonal the {C} is on if I stand by the {A} facing the {B}: front left, front right, rear left "
     "or rear right", "opts"),
    ("honestly I need help: standing by the {A}, looking at the {B}, is the {C} ahead of me or behind me, and on "
     "which side?", "opts"),
    ("from the {A}, with the {B} in front: which quadrant has the {C}? front-left, front-right, back-left, "
     "back-right", "words"),
    ("say I walk over to the {A} and turn toward the {B}. the {C} would be front-left, front-right, back-left or "
     "back-right of me?", "opts"),
    ("at {A} facing {B} is {C} front left front right back left or back right", "opts"),
]
TYPO_PATTERNS = {"object_counting": {3}, "object_size_estimation": {3}, "object_abs_distance": {3},
                 "object_rel_distance": {3}, "object_rel_direction_easy": {3}, "object_rel_direction_medium": {3},
                 "object_rel_direction_hard": {3}}


def say(name: str, rng: random.Random, typo: bool = False) -> str:
    """An everyday name for a benchmark category (its own name about half the time), misspelt when `typo`."""
    word = rng.choice(SYN[name]) if name in SYN and rng.random() < 0.5 else name
    return TYPO.get(word, word) if typo else word


def plural(word: str) -> str:
    if word in IRREGULAR:
        return IRREGULAR[word]
    return word + ("es" if word.endswith(("sh", "ch", "x", "s")) else "s")


def listing(words: list[str], style: str) -> str:
    """The candidates as a person lists them."""
    if style == "bare":
        return ", ".join(words)
    if style == "slash":
        return "/".join(words)
    if style == "or_or":
        return " or ".join("the " + w for w in words)
    the = ["the " + w for w in words]
    return ", ".join(the[:-1]) + (" or " if style == "the_or" else " and ") + the[-1]


def convert(value: str, factor: float) -> str:
    return str(round(float(value) * factor, 4))


def option_words(opts: list[str]) -> dict[str, str]:
    return {o.split(".", 1)[0].strip(): o.split(".", 1)[1].strip() for o in opts}


def rewrite(q: dict, k: int, rng: random.Random, counts: dict) -> dict:
    """Question `q` re-asked with pattern `k` of its type."""
    qt, text, gt, opts = q["question_type"], q["question"], q["ground_truth"], q.get("options")
    key = "object_rel_direction" if qt.startswith("object_rel_direction") else qt
    m = re.search(TEMPLATES[key], text)
    if m is None:
        raise ValueError(f"question {q['id']} is not in the benchmark's {qt} wording")
    typo = k in TYPO_PATTERNS.get(qt, ())
    out = {**q, "options": opts, "source_id": q["id"]}
    if qt == "object_counting":
        one = say(m.group(1).strip(), rng, typo)
        new = COUNT[k].format(P=one, Ps=plural(one))
    elif qt == "object_size_estimation":
        tpl, unit = SIZE[k]
        new = tpl.format(X=say(m.group(1), rng, typo))
        out["ground_truth"] = convert(gt, UNIT_FROM_CM[unit])
    elif qt == "room_size_estimation":
        new, unit = ROOM[k]
        out["ground_truth"] = convert(gt, AREA_FROM_M2[unit])
    elif qt == "object_abs_distance":
        tpl, unit = ABS[k]
        new = tpl.format(A=say(m.group(1), rng, typo), B=say(m.group(2), rng))
        out["ground_truth"] = convert(gt, UNIT_FROM_M[unit])
    elif qt == "object_rel_distance":
        tpl, style, mode = REL[k]
        cands = [c.strip() for c in m.group(1).split(",")]
        words = {c: say(c, rng, typo and i == 0) for i, c in enumerate(cands)}
        if style == "counted":  # "chairs, a tv, a fridge and couches": plural where the room has several
            said = [plural(words[c]) if counts.get(c, 1) > 1 else words[c] for c in cands]
            items = [s if counts.get(c, 1) > 1 else ("an " if s[0] in "aeiou" else "a ") + s
                     for c, s in zip(cands, said)]
            lst = ", ".join(items[:-1]) + " and " + items[-1]
        else:
            said = [words[c] for c in cands]
            lst = listing(said, style) if style else ""
        new = tpl.format(R=say(m.group(2), rng), L=lst)
        if mode == "words":
            out["options"], out["ground_truth"] = None, said[cands.index(option_words(opts)[gt])]
    else:
        tpl, mode = {"object_rel_direction_easy": EASY, "object_rel_direction_medium": MEDIUM,
                     "object_rel_direction_hard": HARD}[qt][k]
        new = tpl.format(A=say(m.group(1), rng, typo), B=say(m.group(2), rng), C=say(m.group(3), rng))
        if mode == "words":
            out["options"], out["ground_truth"] = None, option_words(opts)[gt]
    out["question"] = new
    return out


# --- route planning ---------------------------------------------------------------------------------------------


def route_parts(text: str) -> tuple[str, str, str, list[str | None]]:
    """(start, facing, goal, steps) of a benchmark route question; a step is None for a turn to fill in, else the
    place to walk to (or the rest of a step that is not 'until ...')."""
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


def _walk(rest: str, verb_until: str, verb_other: str) -> str:
    """'until the TV' in the benchmark is kept as the place; other moves ('about one foot', 'through the doorway
    until ...') keep their words after a plain verb."""
    if rest.split(" ", 1)[0].lower() in ("about", "through"):
        return f"{verb_other} {rest}"
    return f"{verb_until} {rest}"


def route_question(q: dict, k: int) -> dict:
    start, face, goal, steps = route_parts(q["question"])
    blanks = sum(s is None for s in steps)
    if k == 0:
        said = ["turn ___" if s is None else re.sub(r"\byour\b", "my", _walk(s, "walk until", "walk"))
                for s in steps]
        ask = ("What's the missing turn? It's left, right, or turn back." if blanks == 1 else
               "What are the missing turns? Each one is left, right, or turn back.")
        new = (f"I'm at {start}, facing {face}, and I want to get to {goal}. Here's my route: "
               f"{', then '.join(said)}. {ask}")
    else:
        said = [f"{i}) " + ("??" if s is None else _walk(s, "go straight till", "go straight"))
                for i, s in enumerate(steps, 1)]
        ask = "what goes in the ?? spot" if blanks == 1 else "which turns go in the ?? spots, in order"
        new = (f"quick q about directions. you start by {start} facing {face} and need to reach {goal}. "
               f"steps: {' '.join(said)} and you're there. {ask} - turn left, turn right or turn back?")
    return {**q, "source_id": q["id"], "question": new}


def build(questions: list[dict], meta: dict, seed: int) -> list[dict]:
    rng = random.Random(seed)
    by_type: dict[str, list[dict]] = {}
    for q in questions:
        by_type.setdefault(q["question_type"], []).append(q)
    rows = []
    for qt in TYPES:
        pool = sorted(by_type[qt], key=lambda q: q["id"])
        n_patterns = 10
        pick = rng.sample(pool, n_patterns * PER_PATTERN)  # random order: each pattern gets varied scenes
        for j, q in enumerate(pick):
            counts = meta.get(q["scene_name"], {}).get("object_counts", {})
            rows.append(rewrite(q, j // PER_PATTERN, rng, counts))
    routes = sorted(by_type.get("route_planning", []), key=lambda q: q["id"])
    rows += [route_question(q, k) for q in routes for k in (0, 1)]
    return [{"id": ID_BASE + i, **{f: r.get(f) for f in ("dataset", "scene_name", "question_type", "question",
                                                         "options", "ground_truth", "source_id")}}
            for i, r in enumerate(rows)]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--questions", default=str(VSI / "questions.jsonl"))
    ap.add_argument("--meta", default=str(VSI / "meta_info.json"))
    ap.add_argument("--seed", type=int, default=8)
    ap.add_argument("--out", default=str(HERE / "data" / "vsibench_paraphrases_holdout8.jsonl"))
    a = ap.parse_args()
    with open(a.questions) as f:
        qs = [json.loads(line) for line in f if line.strip()]
    with open(a.meta) as f:
        meta = json.load(f)
    rows = build(qs, meta, a.seed)
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
