"""Write benchmarks/data/vsibench_paraphrases_holdout11.jsonl: held-out wording set 11 for VSI-Bench.

Written without reading or running the question parser (nothing under runtime/, host/ or tests/, no query docs, no
golden files, no scores, no `mosaic` command). make_holdout10.py, check_holdout10.py and docs/holdout10.md were read
only for the row format, the checking approach and to keep away from their wordings; `--check` measures the distance
from every earlier wording set (shared runs of words).

Every row re-asks one real benchmark question (`source_id`) about the same scene, the same objects in the same roles
(where I stand, what I face, what is asked about; the reference of a relative distance; the two objects of an
absolute distance) and, for multiple choice, the benchmark's own `options` list and answer letter, unchanged:

- 8 types x 10 wording patterns x 4 questions. Rows 4k..4k+3 of a type use pattern k. Questions are drawn at random
  (seed 11) from those of the type that none of sets 8, 9, 10 used as a source; where fewer than 40 remain, every
  fresh one is used and the rest are drawn from the used ones, fewest earlier uses first (new wording, same
  question); `--check` prints how many per type.
- route_planning: every route question of the benchmark once, the four route patterns in turn.

Users new to set 11 (one per pattern index, the same in every type): a robot operator giving structured but informal
orders, a non-native speaker or child (simple grammar, some articles dropped), an elderly and very polite user, a
tradesperson (span, clearance, run, square footage), a texter (one abbreviation at most: ngl, pls, r, thx), the
object named first in a clause of its own ("The thing I'm asking about is the stool: ..."), a first sentence that
only gives context, an irrelevant date or time, and two more turns of these. A few everyday names (couch, TV,
television, fridge, washing machine, tub) stand for the benchmark's, about half the time. Exactly 8 of the 40 rows of
each type and 21 of the 104 route rows carry one single-letter slip from TYPO_WORDS / TYPO_OBJECTS (one edit, not an
English word); direction and turn words, units, numbers and route places are never misspelt.

Numbers asked in another unit carry the ground truth converted exactly and rounded to 4 places (1 in = 2.54 cm,
1 ft = 30.48 cm, 1 sq ft = 0.09290304 m^2).

    python benchmarks/make_holdout11.py [--questions Q.jsonl] [--seed 11] [--out OUT.jsonl]
    python benchmarks/make_holdout11.py --check   # check_holdout11.py's checks; writes nothing, exit 1 on a failure
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
EARLIER_SOURCES = [HERE / "data" / f"vsibench_paraphrases_holdout{n}.jsonl" for n in (8, 9, 10)]
OUT = HERE / "data" / "vsibench_paraphrases_holdout11.jsonl"
ID_BASE = 1200000

# everyday names a reader takes in without context; the benchmark's own name is kept about half the time
SYN = {"sofa": ["couch"], "tv": ["TV", "television"], "refrigerator": ["fridge"], "washer": ["washing machine"],
       "bathtub": ["tub"]}
PLURAL = {"couch": "couches", "TV": "TVs", "washing machine": "washing machines"}
# one single-letter slip per word (a letter dropped, doubled, swapped with its neighbour or replaced by a keyboard
# neighbour; drawn once with seed 11 and written out here); `--check` confirms each is one edit from its word and
# not an English word
TYPO_OBJECTS = {"bathtub": ["bathtuub", "bthtub"], "chair": ["chir", "cjair"], "couch": ["cpuch", "coucch"],
    "dishwasher": ["dishwaaher", "dishwsher"], "fireplace": ["firwplace", "fireplaace"],
    "fridge": ["frdge", "fridhe"], "machine": ["machin", "machibe"],
    "refrigerator": ["refirgerator", "refrigetator"], "stool": ["sttool", "stpol"], "stove": ["sove", "stovve"],
    "table": ["tble", "talbe"], "television": ["tleevision", "trlevision"], "toilet": ["toiilet", "toolet"],
    "washer": ["waaher", "washrr"], "washing": ["wadhing", "waashing"]}
TYPO_WORDS = {"about": ["abiut", "abou"], "after": ["afteer", "adter"], "afternoon": ["aftrrnoon", "afternooon"],
    "along": ["aloong", "alog"], "among": ["aomng", "amomg"], "another": ["anothwr", "anoter"],
    "answer": ["answr", "abswer"], "apart": ["aoart", "aprat"], "area": ["areea", "arrea"],
    "around": ["arouund", "aound"], "asking": ["asling", "askig"], "beside": ["besidr", "besid"],
    "between": ["betwren", "betweeen"], "biggest": ["bggest", "bifgest"], "bits": ["btis", "birs"],
    "bumping": ["bumpin", "buming"], "camera": ["camerra", "cammera"], "classify": ["ckassify", "calssify"],
    "clearance": ["cearance", "clearamce"], "closest": ["cloest", "clisest"], "combine": ["combinw", "combinee"],
    "combined": ["combuned", "combinde"], "compute": ["computee", "cmpute"], "confused": ["confuaed", "confusde"],
    "cord": ["corrd", "codr"], "could": ["coulf", "coulld"], "count": ["ciunt", "couunt"],
    "couple": ["cople", "copule"], "covers": ["covees", "coers"], "curiosity": ["ciriosity", "cueiosity"],
    "dead": ["drad", "dwad"], "dear": ["deae", "drar"], "describing": ["describibg", "descriing"],
    "dimension": ["dimwnsion", "dimensiion"], "dimensions": ["dimenions", "dimensons"],
    "direction": ["directuon", "direcion"], "distance": ["disttance", "disyance"],
    "distances": ["distancea", "diatances"], "does": ["doess", "dpes"], "dropped": ["deopped", "dropoed"],
    "each": ["eacg", "eavh"], "earlier": ["earllier", "earloer"], "ever": ["evver", "ecer"],
    "every": ["ecery", "eevry"], "everything": ["everyrhing", "everythong"], "extent": ["extemt", "ectent"],
    "face": ["fsce", "faec"], "facing": ["facingg", "facng"], "figure": ["fifure", "figrue"],
    "fill": ["flil", "fikl"], "filmed": ["fiilmed", "folmed"], "find": ["finf", "fiind"], "flat": ["fllat", "flar"],
    "floor": ["flloor", "flopr"], "forgive": ["forgivve", "fprgive"], "frame": ["fraem", "frrame"],
    "friend": ["friens", "friedn"], "from": ["frmo", "ftom"], "furnishing": ["furnisging", "furrnishing"],
    "give": ["givee", "gvie"], "goal": ["goak", "gooal"], "going": ["gping", "goiing"], "good": ["gopd", "goodd"],
    "graph": ["geaph", "grph"], "grateful": ["graateful", "grareful"], "greatest": ["greaest", "geratest"],
    "hanging": ["hanginng", "hangig"], "have": ["havee", "havw"], "headcount": ["headcountt", "headocunt"],
    "heading": ["hwading", "heaing"], "heads": ["hrads", "heasd"], "height": ["heiht", "heiggt"],
    "help": ["hekp", "hellp"], "here": ["heree", "hete"], "hope": ["hpoe", "hoep"], "into": ["inro", "inot"],
    "just": ["judt", "jist"], "keep": ["keeo", "keepp"], "keys": ["keyss", "keyys"], "kind": ["kimd", "kibd"],
    "know": ["kbow", "kniw"], "large": ["largge", "largw"], "largest": ["larggest", "largset"],
    "last": ["ladt", "laat"], "least": ["leasst", "leaat"], "length": ["lengtth", "lengt"], "like": ["lkie", "lije"],
    "line": ["libe", "lune"], "locate": ["loccate", "locatr"], "long": ["lomg", "ling"],
    "longest": ["lingest", "longets"], "look": ["loik", "lopk"], "looking": ["loking", "loooking"],
    "lost": ["losst", "lostt"], "many": ["mamy", "maby"], "mate": ["maet", "matr"], "mean": ["mran", "meean"],
    "meaning": ["menaing", "maning"], "measure": ["mesaure", "meeasure"], "measured": ["meadured", "meeasured"],
    "measurement": ["measurementt", "measuremeny"], "measuring": ["measiring", "meauring"],
    "might": ["mifht", "mihgt"], "mind": ["mibd", "mins"], "more": ["moee", "morre"],
    "morning": ["mornning", "morniing"], "most": ["mots", "modt"], "much": ["mych", "mucch"],
    "near": ["neaar", "nwar"], "nearest": ["nearwst", "neaeest"], "need": ["nees", "neef"],
    "needs": ["newds", "needss"], "next": ["nexy", "nwxt"], "night": ["niht", "nught"],
    "object": ["objevt", "objrct"], "obliged": ["obilged", "obligwd"], "only": ["onnly", "obly"],
    "operator": ["operatro", "opeeator"], "order": ["orrder", "odrer"],
    "orientation": ["orientaiton", "oroentation"], "output": ["ouptut", "outpuy"], "over": ["ovver", "ovre"],
    "overall": ["overaall", "oberall"], "pardon": ["pardonn", "pardob"], "parked": ["parekd", "psrked"],
    "phone": ["phoe", "pjone"], "pick": ["picj", "piick"], "picture": ["picyure", "picturre"],
    "place": ["plsce", "pllace"], "plan": ["plab", "plann"], "please": ["pleasw", "pleaes"],
    "point": ["poinnt", "pont"], "pointing": ["pointign", "pointiing"], "points": ["pointts", "poins"],
    "pricing": ["pricong", "pricimg"], "query": ["querry", "queey"], "quiz": ["quiiz", "quuz"],
    "quote": ["quotw", "qote"], "range": ["ragne", "rane"], "reach": ["reacg", "reac"],
    "recorded": ["reocrded", "revorded"], "repainting": ["repaintin", "repaintig"], "report": ["repotr", "repot"],
    "request": ["reqyest", "requset"], "robot": ["rovot", "robpt"], "room": ["rpom", "romo"],
    "rooms": ["roims", "rioms"], "runs": ["runns", "rins"], "sensor": ["snsor", "srnsor"],
    "separate": ["separaate", "separrate"], "separates": ["separstes", "separatws"],
    "setting": ["setying", "swtting"], "setup": ["seetup", "setpu"], "several": ["severall", "severla"],
    "should": ["shoould", "sgould"], "shown": ["showb", "shoqn"], "shows": ["shoqs", "shwos"],
    "side": ["sdie", "sidde"], "sister": ["sistrr", "siser"], "size": ["suze", "sizw"],
    "smaller": ["smaaller", "snaller"], "smallest": ["smalkest", "snallest"], "space": ["sppace", "spacw"],
    "span": ["spaan", "spna"], "spans": ["sapns", "spanss"], "stand": ["srand", "staand"],
    "standing": ["standinf", "standinng"], "stands": ["stanfs", "stnds"], "start": ["strt", "statr"],
    "station": ["statipn", "statoon"], "steps": ["stepd", "stepps"], "stood": ["stoo", "sotod"],
    "straight": ["striaght", "straoght"], "taken": ["takeb", "tkaen"], "tally": ["taly", "tallly"],
    "tape": ["taape", "tappe"], "target": ["tarhet", "tarrget"], "task": ["tsak", "taskk"],
    "tell": ["telll", "telk"], "than": ["thab", "tgan"], "thank": ["thabk", "tjank"], "thanks": ["thanjs", "thanls"],
    "that": ["tgat", "thay"], "their": ["thwir", "ther"], "them": ["thhem", "tehm"], "then": ["thhen", "thwn"],
    "there": ["tgere", "tere"], "they": ["thry", "theyy"], "thing": ["thung", "thnig"],
    "things": ["thinga", "thngs"], "think": ["tgink", "thimk"], "thinking": ["thiking", "thniking"],
    "this": ["tgis", "thia"], "through": ["throuhh", "throug"], "till": ["tikl", "tilll"], "time": ["timee", "timr"],
    "today": ["tpday", "tooday"], "together": ["tohether", "tofether"], "total": ["totak", "tptal"],
    "track": ["ttack", "trakc"], "tripped": ["trpiped", "trupped"], "trouble": ["trobule", "troublw"],
    "trying": ["trynig", "tryong"], "until": ["untik", "untill"], "video": ["viedo", "videoo"],
    "walk": ["walkk", "wlak"], "walked": ["waljed", "wlked"], "want": ["wnat", "wanr"], "were": ["wwre", "wree"],
    "what": ["whar", "whhat"], "when": ["whrn", "wgen"], "where": ["whwre", "wehre"],
    "whether": ["whethwr", "whetheer"], "which": ["wgich", "wihch"], "whichever": ["whcihever", "whixhever"],
    "width": ["wifth", "widh"], "with": ["wiyh", "wiith"], "woman": ["woma", "wmoan"],
    "wonder": ["wonedr", "wondre"], "working": ["workinf", "wprking"], "would": ["wouls", "woul"],
    "yesterday": ["yesterdat", "yestwrday"]}
# --- the wording patterns (10 per type) ---------------------------------------------------------------------------
# users new to set 11, same order in every type: 0 robot operator, 1 non-native speaker / child (simple grammar, some
# articles dropped), 2 elderly and very polite, 3 tradesperson, 4 texter (one abbreviation at most), 5 the object
# named first in a clause of its own, 6 a context-only first sentence, 7 an irrelevant date or time, 8 and 9 a
# second turn of personas 1-3/0 (see docs/holdout11.md)
COUNT = [
    "Task for the robot: go through this room and tally every {P} you find. Output one integer.",
    "how many {P} is in room? i want know the number",
    "Good afternoon. I do hope you won't mind my asking, but would you be so kind as to count up the {Ps} in this room "
    "for me? Thank you ever so much.",
    "Pricing up a job here. What's the headcount of {Ps} in this room, mate?",
    "ngl I lost track counting {Ps} here in this room, what's the real number",
    "The thing I'm asking about is the {P}: how many of them does this room have?",
    "My sister is furnishing this room. How many {Ps} are in it right now?",
    "Yesterday I walked through this room with the camera. Can you count the {Ps} that were in it?",
    "Quiz time! Number of {Ps} in this room = ?",
    "Please, in this room, how much {Ps} there are?",
]
SIZE = [
    ("Operator request: measure the {X}. Report the largest of its three dimensions (length, width, height) in "
     "centimetres, number only.", "cm"),
    ("how big is {X}? i want the biggest one of length, width, height. in meters", "m"),
    ("If it's not too much trouble, dear, I'd be most grateful to know how long the {X} is along whichever of its "
     "length, width or height is the greatest, in feet.", "ft"),
    ("What's the overall span of the {X} on its longest dimension, in mm? It's for the cut list.", "mm"),
    ("pls tell me the {X}'s biggest measurement, like length, width or height, whichever is largest, in cm", "cm"),
    ("The thing I want measured is the {X}: what is its greatest dimension out of length, width and height, in "
     "metres?", "m"),
    ("I'm trying to fit everything into a smaller flat. How long is the {X} in its longest direction (length, width "
     "or height), in inches?", "in"),
    ("Last Tuesday I lost my tape measure. In centimetres, what's the {X}'s longest dimension: length, width or "
     "height, whichever is longest?", "cm"),
    ("Give me the max extent of the {X} in feet, whichever of length, width or height runs longest.", "ft"),
    ("Please say me the longest size of {X} (length or width or height, the biggest one) in inch.", "in"),
]
ROOM = [
    ("Robot, compute the floor area of this room in m². Several rooms in the video? Then report their combined "
     "area.", "m2"),
    ("how big is room, in square meter? if many room, give all room combined.", "m2"),
    ("I wonder if you might help an old man: how many square feet would you say this room measures? And should "
     "there be more than one room, I'd be grateful for the combined space of them all.", "ft2"),
    ("What's the square footage of the floor here? If the video covers a couple of rooms, combine them into one "
     "figure.", "ft2"),
    ("pls give me the area of this room in square metres, and if the video shows a few rooms, their combined size",
     "m2"),
    ("What I'm after is the floor area: how many square feet does this room have, all rooms combined if the video "
     "shows several?", "ft2"),
    ("We're thinking of repainting. How large is this room in square metres (combined, if more than one room is "
     "shown)?", "m2"),
    ("This morning I filmed our place. What's its size in square feet, with any separate rooms combined into one "
     "total?", "ft2"),
    ("Floor area for the quote, m2, combined total if it spans more than one room.", "m2"),
    ("Room size please? Answer in square metre. When video have more rooms, give all of them together.", "m2"),
]
ABS = [
    ("Robot: range from the {A} to the {B}, measured at the closest points of the two. Output in meters.", "m"),
    ("how far {A} from {B}? measure at nearest point of each, answer in centimeter", "cm"),
    ("Would you be so kind as to tell me the distance between the {A} and the {B}, measured where they are nearest "
     "to one another? In feet, if you please.", "ft"),
    ("What's the clearance between the {A} and the {B} at their closest points, in inches?", "in"),
    ("how far apart r the {A} and the {B} at their closest bits, in metres", "m"),
    ("The two things I'm asking about are the {A} and the {B}: how much distance separates their closest points, in "
     "millimetres?", "mm"),
    ("I tripped over a cord earlier. How far does the {A} sit from the {B}, nearest point to nearest point, in "
     "feet?", "ft"),
    ("On Sunday I recorded this video. Tell me the {A}-to-{B} distance, taken between the closest points of "
     "each, in cm.", "cm"),
    ("Need the straight-line run between the {A} and the {B}, nearest point to nearest point, in metres.", "m"),
    ("Distance of {A} and {B}, please, from closest points, in inch?", "in"),
]
REL = [
    ("Robot task: among {L}, pick the one nearest to the {R}. Distances are measured between closest points.",
     "the_comma_or"),
    ("which is most near to {R}: {L}? measure from closest points.", "comma_or"),
    ("I should be ever so grateful if you could tell me which of {L} stands closest to the {R}, measuring from their "
     "closest points.", "the_comma_or"),
    ("Which one has the smallest gap to the {R}, closest points measured: {L}?", "slash"),
    ("out of {L}, which one's closest to the {R}? closest points pls", "the_or"),
    ("The object I'm measuring from is the {R}: of {L}, which is nearest, going by closest points?", "the_or"),
    ("I keep bumping into things near the {R}. Which is nearest to it, {L}, when you measure from the closest "
     "points?", "the_comma_or"),
    ("Last night I dropped my keys by the {R}. Which is closest to the {R}, {L}? Use the closest points.",
     "either"),
    ("Closest to the {R}, measuring closest points: {L}?", "lettered"),
    ("which thing closest to {R}? {L}. use nearest points.", "comma_or"),
]
EASY = [
    "Robot setup: you are parked next to the {A}, sensor pointing at the {B}. Query: the {C}, relative to the {B}, "
    "left side or right side?",
    "I stand near {A} and look to {B}. {C} is left of {B} or right?",
    "Pardon me, dear, I'm a little muddled. Supposing I stood beside the {A} with my eyes on the {B}, on which side "
    "of the {B} should I see the {C}: its left or its right? Many thanks.",
    "Working from the {A}, facing the {B}: does the {C} sit on the left-hand or the right-hand side of the {B}?",
    "ok so me at the {A}, looking at the {B}: the {C} is on the left of the {B} or the right? thx",
    "The thing I'm asking about is the {C}: from the {A}, facing the {B}, is it to the left or to the right of the "
    "{B}?",
    "I've just walked in the door. Picture me beside the {A}, turned to the {B}: does the {C} show up on the left-hand "
    "side of the {B}, as I see it, or on the right-hand side?",
    "Yesterday I was next to the {A}, eyes on the {B}. Which side of the {B} did I see the {C} on, left or right?",
    "me next to {A}, I look at {B}. where is {C}, left or right of {B}?",
    "Heads up, bot: start at the {A} and face the {B}. Then report: {C} sits left of the {B} or right?",
]
MEDIUM = [
    "Bot parked by the {A} with the {B} dead ahead: is the {C} left, right, or back? (back = needs a turn of at least "
    "135 degrees)",
    "I am by {A}, I look to {B}. {C} is on my left, my right or behind me?",
    "Forgive an old woman's curiosity: were I by the {A}, my face toward the {B}, where would the {C} be, on my "
    "left, on my right, or at my back, by which I mean I'd have to turn 135 degrees or more to see it?",
    "On the job at the {A}, looking square at the {B}: {C} on my left-hand side, my right-hand side, or behind me?",
    "ngl I'm confused. me by the {A}, eyes on the {B}. {C}: my left, my right, or behind me",
    "The thing I'm asking about is the {C}. From the {A}, facing the {B}: left, right, or back (back meaning a turn of "
    "at least 135 degrees)?",
    "I'm hanging a picture. My position is next to the {A} and I'm turned toward the {B}; does the {C} lie to my "
    "left, to my right, or behind me?",
    "This afternoon I was by the {A}, facing the {B}. Was the {C} on my left, on my right, or behind me?",
    "me stand by {A}, face {B}. {C} where? left, right or back of me? (back = turn 135 degrees or more)",
    "Orientation query. Origin: {A}; heading: {B}; target: {C}. Answer left, right or back (back if the turn is 135 "
    "degrees or more).",
]
HARD = [
    "Bot station: {A}. Bot heading: {B}. Locate the {C} as front-left, front-right, back-left or back-right.",
    "I stand near {A} and I look at {B}. {C} is front-left, front-right, back-left or back-right of me?",
    "I'd be much obliged if you could tell me, were I standing by the {A} with my face toward the {B}, whether the "
    "{C} would be to my front-left, front-right, back-left or back-right.",
    "Setting out from the {A}, facing the {B}: which quarter around me is the {C} in, front-left, front-right, "
    "back-left or back-right?",
    "me next to the {A}, {B} straight in front, {C} is where pls: front-left, front-right, back-left or back-right",
    "The thing I'm asking about is the {C}: with me at the {A} and the {B} straight ahead, is it front-left, "
    "front-right, back-left or back-right of me?",
    "I'm describing the room to a friend on the phone. Me beside the {A}, turned toward the {B}: does the {C} end "
    "up front-left, front-right, back-left or back-right of me?",
    "Earlier today I stood beside the {A}, looking toward the {B}. Around me, the {C} was in what quadrant: "
    "front-left, front-right, back-left or back-right? (Think of me at the origin of a graph, looking along the "
    "positive y-axis.)",
    "i stand at {A}, look at {B}. {C} is where? front-left, front-right, back-left or back-right",
    "Frame: origin at the {A}, +y toward the {B}. Classify the {C} into front-left, front-right, back-left or "
    "back-right.",
]
NEVER_MISSPELT = {"left", "right", "front", "back", "behind", "turn", "turns", "forward", "ahead", "toward",
                  "towards", "degrees", "metres", "meters", "meter", "metre", "feet", "foot", "footage", "inches",
                  "inch", "square", "centimetres", "centimeter", "millimetres", "cm", "mm", "ft", "one", "two",
                  "three", "four", "integer", "number", "hand", "quadrant", "quarter", "origin", "axis", "positive",
                  "ngl", "pls", "thx"}


def say(name: str, rng: random.Random) -> str:
    """An everyday name for a benchmark category (its own name about half the time)."""
    return rng.choice(SYN[name]) if name in SYN and rng.random() < 0.5 else name


def plural(word: str) -> str:
    return PLURAL.get(word, word + ("es" if word.endswith(("sh", "ch", "x", "s")) else "s"))


def listing(words: list[str], style: str) -> str:
    """The four candidates as a person lists them (in the benchmark's order, which is also the options' order)."""
    the = ["the " + w for w in words]
    if style == "slash":
        return " / ".join(words)
    if style == "comma_or":
        return ", ".join(words[:-1]) + " or " + words[-1]
    if style == "the_comma_or":
        return ", ".join(the[:-1]) + ", or " + the[-1]
    if style == "the_or":
        return ", ".join(the[:-1]) + " or " + the[-1]
    if style == "either":
        return "either " + ", ".join(the[:-1]) + " or " + the[-1]
    if style == "lettered":  # the benchmark's own letters: its options list the candidates in this order
        return " ".join(f"{'ABCD'[i]}) {w}" for i, w in enumerate(words))
    raise ValueError(f"unknown list style {style!r}")


# --- one single-letter slip -----------------------------------------------------------------------------------------


def join(segs: list[Seg], rng: random.Random | None, objects_too: bool = True) -> str:
    """The question text; with `rng`, one word of this set's slip tables misspelt once (`join_with_slip`)."""
    return join_with_slip(segs, rng, TYPO_WORDS, TYPO_OBJECTS, NEVER_MISSPELT, objects_too)


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
    text = join(segs, rng if typo else None)
    out["question"] = text[:1].upper() + text[1:] if text[:1] == "{" else text
    return out


# --- route planning -------------------------------------------------------------------------------------------------


def route_parts(text: str) -> tuple[str, str, str, list[tuple[str, str] | None]]:
    """(start, facing, goal, steps) of a benchmark route question: a step is None for a turn to fill in, else
    (kind, words): 'until' for 'Go forward until X' (words X), 'plain' for another forward step (words kept)."""
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
        plain = not re.match(r"Go forward\s+(?:until|untli)\b", raw)
        steps.append(("plain" if plain else "until", _tidy(f.group(1))))
    return start, face, goal, steps


# route patterns: (opening, step 'until', step plain, blank, joiner, closing for one blank, closing for several,
# first person?) -- {start} {face} {goal} {n} filled in; places keep the benchmark's words ("your" -> "my" in the
# first person)
ROUTES = [
    ("Nav plan for the robot. Start: {start}, facing {face}. Goal: {goal}. Steps: ", "forward until ", "forward ",
     "turn ?", "; ", ". Fill in the ? with left, right or back.",
     ". Fill in each ? with left, right or back, in order.", False),
    ("I wonder if you could help me find my way. I'm at {start}, facing {face}, and I should like to reach {goal}. ",
     "I walk on until ", "I walk on ", "I turn (which way?)", ", then ",
     ". Would you tell me whether that turn is left, right or back?",
     ". Would you tell me, in order, whether each of the {n} turns is left, right or back?", True),
    ("I am at {start}, I face {face}. I want go to {goal}. ", "I go forward until ", "I go forward ", "I turn ?",
     ", then ", ". The turn is left, right or back?", ". Each turn is left, right or back? Say in order.", True),
    ("ok so I'm at {start} facing {face} and trying to reach {goal}: ", "walk till ", "walk ", "turn ?", ", ",
     " -- which way is that turn, left, right or back, pls",
     " -- which way is each turn, left, right or back, in order pls", True),
]


def route_question(q: dict, k: int, rng: random.Random | None) -> dict:
    """Route question `q` in route pattern `k`, options kept; with `rng`, one word the pattern adds is misspelt
    (never a place: those keep the benchmark's words)."""
    start, face, goal, steps = route_parts(q["question"])
    opening, until, plain, blank, sep, one, several, first = ROUTES[k]
    blanks = sum(s is None for s in steps)
    mine = (lambda w: re.sub(r"\byour\b", "my", w)) if first else (lambda w: w)
    segs = _segments(opening, {"start": mine(start), "face": mine(_noun(face)), "goal": mine(goal)})
    for i, s in enumerate(steps):
        if i:
            segs.append((sep, False))
        if k == 0:
            segs.append((f"{i + 1}) ", False))
        if s is None:
            segs.append((blank, False))
        else:
            segs += [(until if s[0] == "until" else plain, False), (mine(s[1]), True)]
    segs += _segments(one if blanks == 1 else several.replace("{n}", NUMBER[blanks]), {})
    return {**q, "source_id": q["id"], "question": join(segs, rng, objects_too=False)}


# --- the set --------------------------------------------------------------------------------------------------------
def earlier_uses(paths: list[Path]) -> dict[int, int]:
    """source id -> how many of the earlier sets used it."""
    uses: dict[int, int] = {}
    for p in paths:
        if Path(p).exists():
            with open(p) as f:
                for sid in {json.loads(line)["source_id"] for line in f if line.strip()}:
                    uses[sid] = uses.get(sid, 0) + 1
    return uses


def draw(pool: list[dict], uses: dict[int, int], n: int, rng: random.Random) -> list[dict]:
    """`n` questions at random, none an earlier set used while enough fresh ones remain; otherwise every fresh one
    and the rest from the used ones, fewest earlier uses first. Random order, so each pattern gets varied scenes."""
    fresh = [q for q in pool if q["id"] not in uses]
    if len(fresh) >= n:
        return rng.sample(fresh, n)
    rest = [q for q in pool if q["id"] in uses]
    rng.shuffle(rest)
    rest.sort(key=lambda q: uses[q["id"]])  # stable: random among equal use counts
    pick = fresh + rest[:n - len(fresh)]
    rng.shuffle(pick)
    return pick


def build(questions: list[dict], uses: dict[int, int], seed: int) -> list[dict]:
    rng = random.Random(seed)
    by_type: dict[str, list[dict]] = {}
    for q in questions:
        by_type.setdefault(q["question_type"], []).append(q)
    rows = []
    n = N_PATTERNS * PER_PATTERN
    for qt in TYPES:
        pick = draw(sorted(by_type[qt], key=lambda q: q["id"]), uses, n, rng)
        typo_rows = set(rng.sample(range(n), TYPO_PER_TYPE))
        rows += [rewrite(q, j // PER_PATTERN, rng, j in typo_rows) for j, q in enumerate(pick)]
    routes = sorted(by_type.get("route_planning", []), key=lambda q: q["id"])
    typo_routes = set(rng.sample(range(len(routes)), round(len(routes) / 5)))
    rows += [route_question(q, j % len(ROUTES), rng if j in typo_routes else None) for j, q in enumerate(routes)]
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
    ap.add_argument("--seed", type=int, default=11)
    ap.add_argument("--out", default=str(OUT))
    ap.add_argument("--check", action="store_true", help="run the checks on --out; write nothing")
    a = ap.parse_args()
    if a.check:  # the checks import this generator: they run as their own script, so no import goes back
        sys.exit(subprocess.run([sys.executable, str(HERE / "check_holdout11.py"), "--questions", a.questions,
                                 "--seed", str(a.seed), "--out", a.out]).returncode)
    qs = load_questions(a.questions)
    uses = earlier_uses(EARLIER_SOURCES)
    out = Path(a.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_suffix(out.suffix + ".tmp")
    tmp.write_bytes(dumps(build(qs, uses, a.seed)))
    tmp.replace(out)
    print(f"{len(qs)} benchmark questions read; set 11 written -> {out}")


if __name__ == "__main__":
    main()
