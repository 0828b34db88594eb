"""Write benchmarks/data/vsibench_paraphrases_holdout12.jsonl: held-out wording set 12 for VSI-Bench.

Written by someone who never read the question reader: nothing under runtime/, host/, export/ or tests/, no query
docs, no reader benchmarks or results, no `mosaic` command, the parser never run. make_holdout11.py,
check_holdout11.py and holdout_common.py were read only for the row format and the checking approach, and the
question texts of sets 8-11 only to keep away from their users and phrasings; `--check` measures the distance from
every earlier wording set (shared runs of words).

Every row re-asks one real benchmark question (`source_id`) about the same scene, the same objects in the same roles
(where I stand, what I face, what is asked about; the reference of a relative distance; the two objects of an
absolute distance) and, for multiple choice, the benchmark's own `options` list and answer letter, unchanged:

- 8 types x 10 wording patterns x 4 questions. Rows 4k..4k+3 of a type use pattern k. Questions are drawn at random
  (seed 12) from those of the type that no earlier wording set (1-11) used as a source; where fewer than 40 remain,
  every fresh one is used and the rest are drawn from the used ones, fewest earlier uses first (new wording, same
  question); `--check` prints how many per type.
- route_planning: every route question of the benchmark once, the four route patterns in turn.

Users new to set 12 (one per pattern index, the same in every type): 0 a voice-assistant transcript (lower case, no
punctuation, fillers "um", "uh", "like"), 1 a question tucked into a longer message about something else, 2 reversed
clause order (the choices or the condition first, the question last), 3 passive voice, 4 comparative phrasing, 5 the
objects listed first, 6 a British estate agent, 7 a carer writing in a second language (Romance-language errors:
"which is the distance", "at my left", "near of", "how much measures"), 8 a tabletop game master, 9 a robot-task
planner giving numbered steps. Everyday names stand for the benchmark's about half the time, British ones for the
British users (settee, telly, cooker, fridge-freezer, lavatory, bath, washing machine) and American ones for the
others (couch, television set, fridge, clothes washer, tub). Exactly 8 of the 40 rows of each type and 21 of the 104
route rows carry one single-letter slip from TYPO_WORDS / TYPO_OBJECTS (one edit, not an English word); direction
and turn words, units, numbers and route places are never misspelt.

Numbers asked in another unit carry the ground truth converted exactly and rounded to 4 places (1 in = 2.54 cm,
1 ft = 30.48 cm, 1 sq ft = 0.09290304 m^2).

    python benchmarks/make_holdout12.py [--questions Q.jsonl] [--seed 12] [--out OUT.jsonl]
    python benchmarks/make_holdout12.py --check   # check_holdout12.py's checks; writes nothing, exit 1 on a failure
"""
from __future__ import annotations

import argparse
import random
import re
import subprocess
import sys
from pathlib import Path

from holdout_common import (CM_IN, NUMBER, N_PATTERNS, PER_PATTERN, SQM_IN, Seg, TYPES, TYPO_PER_TYPE, _noun,
                            _segments, _split_objects, convert, dumps, join_with_slip, source_objects)
from make_holdout11 import draw, earlier_uses, load_questions, route_parts

HERE = Path(__file__).resolve().parent
VSI = HERE.parent.parent / "shared" / "data" / "vsibench"
# every earlier wording set, named one by one so that a later set's file never changes this one's draw
EARLIER_SOURCES = [HERE / "data" / f"vsibench_paraphrases{s}.jsonl"
                   for s in ("", "_holdout", *(f"_holdout{n}" for n in range(2, 12)))]
OUT = HERE / "data" / "vsibench_paraphrases_holdout12.jsonl"
ID_BASE = 1300000

# everyday names, by the user's side of the Atlantic; the benchmark's own name is kept about half the time
SYN = {"brit": {"sofa": "settee", "tv": "telly", "stove": "cooker", "refrigerator": "fridge-freezer",
                "toilet": "lavatory", "bathtub": "bath", "washer": "washing machine"},
       "us": {"sofa": "couch", "tv": "television set", "refrigerator": "fridge", "washer": "clothes washer",
              "bathtub": "tub"}}
REGION = ["us", "brit", "us", "brit", "us", "brit", "brit", "us", "us", "us"]  # per pattern index
PLURAL = {"couch": "couches", "telly": "tellies", "lavatory": "lavatories", "bath": "baths",
          "washing machine": "washing machines", "clothes washer": "clothes washers",
          "television set": "television sets", "fridge-freezer": "fridge-freezers"}
# one single-letter slip per word (a letter dropped, doubled, swapped with its neighbour or replaced by a keyboard
# neighbour; drawn once with seed 12 and written out here); `--check` confirms each is one edit from its word and
# not an English word
TYPO_OBJECTS = {"bath": ["baht", "bqth"], "bathtub": ["batutub", "bathtug"], "chair": ["chhair", "chiar"],
    "clothes": ["clthes", "clothees"], "cooker": ["cookr", "coker"], "couch": ["coch", "coucg"],
    "dishwasher": ["dishwashher", "dishwasherr"], "fireplace": ["fiireplace", "fifeplace"],
    "freezer": ["freeser", "freezdr"], "fridge": ["fidge", "frdige"], "lavatory": ["lavtaory", "lavatorh"],
    "machine": ["macine", "machhine"], "refrigerator": ["refrigreator", "refrigeerator"],
    "settee": ["srttee", "sttee"], "sofa": ["sifa", "soffa"], "stool": ["sttool", "syool"],
    "stove": ["stvoe", "stobe"], "table": ["tablee", "tahle"], "television": ["teleevision", "teleision"],
    "telly": ["telyl", "tellly"], "toilet": ["tilet", "tolet"], "washer": ["washher", "wsaher"],
    "washing": ["washin", "waxhing"]}
TYPO_WORDS = {"about": ["abotu", "aboutt"], "across": ["acros", "acrsos"], "actually": ["actuallh", "actuallyy"],
    "added": ["addde", "aded"], "adventurer": ["addventurer", "adventurrer"],
    "adventurers": ["advennturers", "adventueers"], "after": ["aftr", "aftef"], "again": ["atain", "agani"],
    "along": ["alongg", "allong"], "also": ["aso", "apso"], "always": ["alqays", "alwaays"],
    "among": ["amogn", "amon"], "answer": ["anzwer", "anwer"], "apart": ["apat", "aparrt"],
    "appear": ["appeear", "appera"], "appears": ["apears", "aplears"], "area": ["areea", "aera"],
    "areas": ["areass", "aras"], "arrived": ["arrvied", "arriived"], "assistant": ["assistatn", "assisstant"],
    "awaken": ["awsken", "awakenn"], "being": ["beinf", "bekng"], "beside": ["besixe", "bside"],
    "between": ["betwene", "beteen"], "bigger": ["bigyer", "biggger"], "biggest": ["bitgest", "biggesst"],
    "blocks": ["bloxks", "blocsk"], "booked": ["bookked", "bokoed"], "boxes": ["bpxes", "boxrs"],
    "brain": ["braim", "braain"], "buyers": ["bueyrs", "byuers"], "came": ["cmae", "cme"],
    "candidate": ["candiate", "caandidate"], "candidates": ["candiidates", "canddiates"], "care": ["caare", "cae"],
    "carpet": ["carpe", "caroet"], "chat": ["cht", "cha"], "cheers": ["chders", "cheesr"],
    "classify": ["clasisfy", "classigy"], "closer": ["cloer", "clpser"], "closest": ["closesg", "closset"],
    "combined": ["combinedd", "comined"], "come": ["cme", "coe"], "comes": ["cmes", "coes"],
    "coming": ["cming", "comingg"], "compute": ["compuge", "cojpute"], "corridor": ["corrdior", "corridorr"],
    "could": ["coul", "coud"], "count": ["counnt", "cout"], "counted": ["countted", "coounted"],
    "counting": ["conting", "counging"], "counts": ["coujts", "coumts"], "covered": ["coveered", "coverde"],
    "covers": ["coovers", "covrrs"], "creeps": ["creepss", "creepd"], "cross": ["cros", "ceoss"],
    "curtains": ["curttains", "curtanis"], "delivery": ["delievry", "delviery"],
    "destination": ["destintaion", "destinatiin"], "detect": ["derect", "detcet"],
    "dimension": ["dimensiion", "dimenison"], "directions": ["directuons", "directtions"],
    "distance": ["distancw", "distanec"], "distances": ["disrances", "distaces"], "does": ["doess", "dooes"],
    "down": ["downn", "donw"], "drawing": ["drawiing", "drawong"], "drinks": ["drinos", "drinnks"],
    "drive": ["drkve", "driev"], "dungeon": ["dungoen", "dugeon"], "each": ["ecah", "eahc"],
    "edges": ["edgess", "edegs"], "every": ["evry", "everry"], "exact": ["exaact", "ecact"],
    "eyes": ["eys", "eyyes"], "falls": ["fapls", "falsl"], "fewer": ["fewwer", "feer"],
    "figure": ["fiugre", "fugure"], "finally": ["finallly", "finaly"], "find": ["fidn", "fibd"],
    "fits": ["fkts", "fitz"], "fitted": ["ftited", "fitteed"], "fixed": ["fxied", "fixeed"],
    "flat": ["flst", "flta"], "floor": ["floro", "foor"], "found": ["fouund", "founnd"], "frame": ["fram", "frmae"],
    "friday": ["fridzy", "fridday"], "fried": ["frid", "frird"], "from": ["frrom", "frmo"],
    "further": ["firther", "furtehr"], "gate": ["gae", "gat"], "gaze": ["gaez", "gze"],
    "getting": ["gettting", "gettinng"], "give": ["gve", "giive"], "given": ["givn", "givenn"],
    "goes": ["gose", "gos"], "going": ["goihg", "gping"], "greatest": ["greatestt", "greateest"],
    "hall": ["halp", "haall"], "handful": ["handfuul", "handfjl"], "have": ["havve", "haave"],
    "head": ["heae", "haed"], "heading": ["headig", "heaxing"], "heating": ["heatng", "heatung"],
    "height": ["heiight", "heightt"], "here": ["heere", "heree"], "holds": ["hoolds", "holdw"],
    "home": ["hme", "homme"], "hope": ["hipe", "hoppe"], "included": ["incluedd", "incuded"],
    "inside": ["insidde", "insid"], "just": ["jusst", "jjst"], "kids": ["kds", "kidss"],
    "kitchen": ["kitcehn", "kitcheen"], "know": ["kbow", "knoww"], "lady": ["lqdy", "ldy"], "lamp": ["lmp", "lapm"],
    "larger": ["laregr", "larer"], "largest": ["largestt", "largst"], "last": ["lasy", "lsat"],
    "later": ["lateer", "latre"], "layout": ["layoit", "lyout"], "least": ["lwast", "leaast"],
    "leave": ["leavd", "lave"], "length": ["lehgth", "lenght"], "lies": ["liess", "liees"], "like": ["lke", "likke"],
    "list": ["lsit", "lidt"], "listing": ["lising", "lisitng"], "localize": ["loclize", "lcoalize"],
    "locate": ["locatte", "locaate"], "located": ["licated", "loated"], "locked": ["lokced", "lcked"],
    "long": ["longg", "lnog"], "longest": ["longet", "longgest"], "look": ["llok", "lok"],
    "looking": ["lookiing", "loooking"], "looks": ["loooks", "loojs"], "love": ["lve", "loe"],
    "lovely": ["loovely", "lovly"], "lurk": ["lurrk", "lurl"], "lurks": ["lruks", "lrks"], "make": ["mzke", "maek"],
    "many": ["manu", "manny"], "march": ["marrch", "maarch"], "meaning": ["meaaning", "meanig"],
    "measure": ["mezsure", "measurw"], "measured": ["measufed", "measuured"],
    "measurement": ["meausrement", "measuremejt"], "measures": ["measurees", "measuures"],
    "measuring": ["masuring", "measruing"], "mission": ["missioj", "missoin"], "more": ["morr", "mor"],
    "morning": ["mornin", "mrning"], "most": ["moost", "moxt"], "move": ["mov", "movr"], "much": ["muuch", "muh"],
    "must": ["muts", "musst"], "myself": ["mysellf", "myseelf"], "name": ["naame", "nzme"],
    "navigate": ["naviggate", "navigatee"], "near": ["nea", "neear"], "nearer": ["nearrr", "ndarer"],
    "nearest": ["nearezt", "nearesr"], "need": ["needd", "newd"], "needed": ["neeedd", "neeeded"],
    "needs": ["nedds", "neds"], "next": ["nwxt", "nexxt"], "nose": ["nse", "nlse"], "okay": ["okat", "oay"],
    "open": ["oepn", "opeh"], "order": ["orrer", "ordwr"], "ordering": ["orderinv", "orderign"],
    "other": ["otther", "othwr"], "output": ["outptu", "ouput"], "over": ["overr", "ovver"],
    "parcel": ["paecel", "parel"], "particulars": ["partivulars", "particularrs"],
    "partner": ["partnerr", "parrner"], "party": ["partyy", "parrty"], "perception": ["percetpion", "perceltion"],
    "picture": ["pictuure", "pictture"], "plan": ["plann", "paln"], "plant": ["poant", "plnat"],
    "please": ["pleae", "pleaase"], "plonk": ["plonl", "plokn"], "plumber": ["plumebr", "plumbr"],
    "plus": ["pluus", "pls"], "point": ["poinnt", "poiint"], "pointed": ["piinted", "ponited"],
    "pointing": ["pointign", "pointung"], "points": ["pooints", "pointx"], "porch": ["porh", "potch"],
    "pose": ["pode", "posee"], "quest": ["qeust", "quuest"], "question": ["quesion", "quesgion"],
    "quick": ["quuick", "quicl"], "random": ["randon", "ranndom"], "reach": ["rrach", "reah"],
    "reads": ["raeds", "reeads"], "relative": ["relatiive", "relatve"], "remember": ["rdmember", "rememberr"],
    "report": ["repor", "reprt"], "resolve": ["resovle", "resolvve"], "return": ["retur", "retrun"],
    "robot": ["rbot", "robpt"], "rogue": ["rogu", "rogud"], "roll": ["rolll", "rlll"], "room": ["rolm", "roomm"],
    "rooms": ["roms", "roosm"], "round": ["rond", "rounnd"], "saturday": ["staurday", "sturday"],
    "scan": ["sacn", "scn"], "searches": ["srarches", "searchse"], "seen": ["seeen", "sedn"],
    "settle": ["settl", "settlr"], "several": ["severaal", "sevwral"], "shop": ["shp", "shol"],
    "should": ["shoul", "sohuld"], "show": ["sho", "shwo"], "shown": ["sohwn", "shwon"], "shows": ["shoqs", "shos"],
    "side": ["sie", "sidw"], "silly": ["slly", "silpy"], "sits": ["sts", "sita"], "size": ["sizee", "sie"],
    "smaller": ["smqller", "smalelr"], "some": ["soke", "soe"], "someone": ["someonne", "someoe"],
    "soon": ["soln", "sooon"], "space": ["sapce", "spaxe"], "speak": ["spaek", "sppeak"],
    "staff": ["staaff", "stafff"], "stand": ["stnad", "sgand"], "standing": ["standng", "stznding"],
    "stands": ["stansd", "stnads"], "starting": ["strting", "startin"], "stay": ["stayy", "stya"],
    "stays": ["stayss", "syays"], "step": ["syep", "sgep"], "steps": ["stepss", "stpes"], "stood": ["stod", "sood"],
    "stretch": ["strethc", "stretxh"], "sunday": ["sunay", "sunda"], "sweeps": ["swepes", "sweepss"],
    "taken": ["takken", "taaken"], "task": ["tasi", "taskk"], "tell": ["telo", "telll"], "than": ["thaan", "tahn"],
    "thanks": ["thhanks", "tahnks"], "that": ["taht", "thqt"], "then": ["thne", "tehn"], "there": ["thre", "therr"],
    "these": ["thsee", "tehse"], "they": ["theey", "tehy"], "think": ["thhink", "thinnk"], "this": ["thi", "thiz"],
    "those": ["thoe", "thise"], "thriving": ["thrivin", "thhriving"], "through": ["theough", "throug"],
    "together": ["tigether", "togetther"], "tomorrow": ["tomorow", "tommorrow"],
    "torchlight": ["torchlgiht", "torclight"], "total": ["tootal", "totla"], "trying": ["tryign", "tryying"],
    "unresolved": ["unnresolved", "unrewolved"], "until": ["untl", "utnil"], "using": ["usin", "usingg"],
    "video": ["vdieo", "vidoe"], "view": ["viw", "vieew"], "viewer": ["veiwer", "vieweer"],
    "viewing": ["veiwing", "viiewing"], "walks": ["wslks", "walkss"], "wandered": ["wndered", "wanndered"],
    "wanna": ["wanja", "waanna"], "want": ["wnt", "wanr"], "watch": ["wattch", "wtach"], "week": ["weke", "wewk"],
    "well": ["welll", "wekl"], "went": ["wnt", "wentt"], "what": ["whatt", "wat"], "when": ["whe", "whne"],
    "where": ["wehre", "wheere"], "whether": ["whehter", "whther"], "which": ["whih", "whicch"],
    "whichever": ["whicheever", "whihever"], "while": ["whild", "whilee"], "whole": ["whold", "whoe"],
    "width": ["widtth", "wiidth"], "will": ["wil", "wiill"], "windowsill": ["windowwill", "windwosill"],
    "with": ["woth", "withh"], "wizard": ["wizrad", "wizadr"], "work": ["wokr", "workk"],
    "would": ["wpuld", "wolud"], "writing": ["writiing", "writign"], "your": ["ypur", "yout"]}
NEVER_MISSPELT = {"left", "right", "front", "back", "behind", "turn", "turns", "forward", "ahead", "toward",
                  "towards", "degrees", "metres", "meters", "meter", "metre", "feet", "foot", "inches", "inch",
                  "square", "squared", "centimetres", "centimeters", "centimeter", "millimetres", "millimeters",
                  "cm", "mm", "ft", "sq", "one", "two", "three", "four", "hundred", "thirty", "five", "number",
                  "quadrant", "rotate", "rotation", "straight", "her", "their", "them", "facing", "face", "faced"}

# --- the wording patterns (10 per type) ---------------------------------------------------------------------------
# users, same order in every type: 0 voice transcript, 1 message about something else, 2 reversed clause order,
# 3 passive voice, 4 comparative, 5 objects first, 6 British estate agent, 7 carer in a second language, 8 game
# master, 9 robot-task planner with numbered steps (see docs/holdout12.md)
COUNT = [
    "hey assistant um quick one uh how many {Ps} have we actually got in this room like the exact number",
    "Hi Priya, the plumber's coming tomorrow morning so leave the side gate open for him. While I remember: how many "
    "{Ps} are in this room? I'm ordering covers for them. Love to the kids!",
    "A handful or more than that, how many {Ps} would you say are in this room? The exact count, please.",
    "How many {Ps} are found in this room when every one of them is counted?",
    "My partner counted fewer {Ps} in this room than I did. Who's right? How many are there in total?",
    "{Ps}. I need the total number of those in this room.",
    "Writing up the particulars for this flat. How many {Ps} are there in this room, so I can list them as included?",
    "I am carer for an old lady. In this room there are how many {Ps}? I must make the count for her care plan.",
    "Torchlight sweeps across the room as the party steps inside. Roll for perception: how many {Ps} are there?",
    "1. Scan the room. 2. Detect every {P}. 3. Report the number of {Ps} found.",
]
SIZE = [
    ("um how long is the {X} like the longest side of it length width or height whichever is biggest in "
     "centimeters", "cm"),
    ("Morning Tom! The van's booked for Saturday and I've got boxes from the shop. Quick one for you: what's the "
     "longest dimension of the {X} (length, width or height, the biggest of the three) in inches? Need to know if "
     "it fits down the hall. Cheers", "in"),
    ("Length, width or height, whichever is biggest, how many metres is that for the {X}?", "m"),
    ("What is the greatest dimension of the {X} when its length, width and height are each measured? It should be "
     "given in millimetres.", "mm"),
    ("Which is larger for the {X}, its length, its width or its height? Give me that largest one in feet.", "ft"),
    ("{X}: the longest of its length, width and height, in cm?", "cm"),
    ("For the floor plan I'm drawing up, what's the longest measurement of the {X} (length, width or height, "
     "whichever's biggest), in metres?", "m"),
    ("The lady want to move the {X}. How much measures the {X} in its most long side (length, width or height)? In "
     "centimeters please.", "cm"),
    ("The {X} blocks the corridor. How many feet does it stretch along its longest dimension, be it length, width "
     "or height?", "ft"),
    ("Task: 1. Locate the {X}. 2. Measure its length, width and height. 3. Return the largest of the three in "
     "millimeters.", "mm"),
]
ROOM = [
    ("okay um how many square feet is this room and like if the video goes through more than one room just add "
     "them all together", "ft2"),
    ("Hiya, hope the new job's going well! We're finally getting the carpet fitted next week. Could you work out "
     "the floor area of this room in square metres for me? If the video shows more than one room, give me all of "
     "them together. Speak soon", "m2"),
    ("All the rooms added up if there's more than one, what's the floor area here in sq m?", "m2"),
    ("How many square feet are covered by this room's floor? If several rooms are shown, their areas should be "
     "added together.", "ft2"),
    ("Is this room bigger or smaller than my kitchen at home? For that I need its floor area in meters squared, "
     "with the rooms combined if the video has more than one.", "m2"),
    ("Floor space, this room plus every other room the video shows: how many square metres is that all together?",
     "m2"),
    ("For the listing: what's the floor area in sq ft? Buyers want the whole space, so if the video covers more "
     "than one room, give me the combined figure.", "ft2"),
    ("Which is the size of this room in square meter? If in the video are many rooms, make the sum of all.", "m2"),
    ("The dungeon map needs this room's area in square feet. If the party wandered through several rooms, total "
     "them together.", "ft2"),
    ("1. Map the floor. 2. Compute its area in m^2. 3. If more than one room appears, output the combined area.",
     "m2"),
]
ABS = [
    ("um so how far is the {A} from the {B} like from the nearest bit of one to the nearest bit of the other in "
     "meters", "m"),
    ("Hey Sam, thanks again for the plant, it's thriving on the windowsill. Random question: how many feet apart "
     "are the {A} and the {B}, measured where they're closest? Want to put a rug between them. See you Sunday",
     "ft"),
    ("Closest point to closest point, what's the gap in centimetres between the {A} and the {B}?", "cm"),
    ("What distance is measured between the {A} and the {B} if it is taken from the nearest point of each? The "
     "answer should be given in metres.", "m"),
    ("I bet the {A} is further from the {B} than it looks. How many inches are there between their closest "
     "points?", "in"),
    ("{A} and {B}, nearest edges: how many centimetres lie between those two?", "cm"),
    ("Buyers always ask about the layout. What's the distance in metres from the {A} across to the {B}, measuring "
     "between the nearest points of the two?", "m"),
    ("Which is the distance from the {A} until the {B}? Measure from the most near points, in meters. The man walks "
     "with a frame.", "m"),
    ("The rogue creeps from the {A} to the {B}. How many feet must she cross, counting from the closest point of "
     "the one to the closest point of the other?", "ft"),
    ("1. Localize the {A}. 2. Localize the {B}. 3. Output the distance between their closest points in "
     "millimeters.", "mm"),
]
REL = [
    ("uh what's nearest to the {R} um {L} like going by the closest points", "spoken"),
    ("Hi Mum, the heating's fixed at last! Silly question while I think of it: which is nearest to the {R}, {L}? "
     "Measuring from their closest points. Chat later", "the_comma_or"),
    ("Is it {L}, which one sits nearest the {R} when you measure between closest points?", "the_or"),
    ("Of {L}, which is found closest to the {R} when distances are measured from the closest points?",
     "the_comma_or"),
    ("Which sits nearer to the {R} than the other three: {L}? Measure between closest points.", "the_or"),
    ("{L}: of these four, which comes nearest the {R}, closest point to closest point?", "comma_and"),
    ("Buyers like to picture the layout. Of {L}, which has the {R} nearest to it, measuring from closest points?",
     "the_comma_or"),
    ("Which from {L} is more near to the {R}? I measure from closest points.", "the_or"),
    ("The party searches the room. Among {L}, which lies closest to the {R}? Measure from the nearest points, "
     "adventurers.", "the_comma_or"),
    ("1. Detect the {R}. 2. Detect the candidates {L}. 3. Return the candidate nearest to the {R}, using closest "
     "points.", "lettered"),
]
EASY = [
    "okay um picture me next to the {A} like looking straight at the {B} would the {C} be on the left side of the "
    "{B} or the right side",
    "Hi Lou, the new curtains arrived and they're lovely. Odd question: if I stand by the {A} facing the {B}, is "
    "the {C} to the left or the right of the {B}? Trying to plan where the lamp goes. xx",
    "Left of the {B} or right of it, where's the {C}, if I'm by the {A} and facing the {B}?",
    "With the {B} being faced from beside the {A}, is the {C} seen to the left or to the right of the {B}?",
    "From where I am at the {A}, looking toward the {B}: does the {C} sit further left or further right than the "
    "{B} does?",
    "{A}, {B}, {C}. I'm beside the {A} with the {B} in view ahead; does the {C} appear left or right of the {B}?",
    "Picture the viewing: you're stood by the {A}, facing the {B}. Does the {C} come on the left of the {B}, or on "
    "its right?",
    "When I am near of the {A} and I look the {B}, the {C} is at left or at right of the {B}?",
    "You stand beside the {A}, eyes fixed on the {B}. Does the {C} lurk to the left or the right of the {B}?",
    "1. Move to the {A}. 2. Face the {B}. 3. Report whether the {C} is left or right of the {B}.",
]
MEDIUM = [
    "uh say i'm next to the {A} and looking over at the {B} um is the {C} like to my left to my right or behind me",
    "Hey Kim, hope the move went okay! My brain's fried so quick one: if I plonk myself by the {A} and look across "
    "at the {B}, is the {C} off to my left, my right, or behind me (behind meaning a turn of 135 degrees or more)? "
    "Drinks Friday?",
    "Left, right or behind me, which is it for the {C}, when I'm by the {A} facing the {B}?",
    "If the {B} is faced by someone standing at the {A}, is the {C} found on their left, on their right, or behind "
    "them (behind = a turn of at least 135 degrees would be needed)?",
    "By the {A}, facing the {B}: is the {C} closer to my left side, my right side, or my back? (Back if I'd have to "
    "turn at least 135 degrees.)",
    "{A}, {B}, {C}: I stand at the {A}, I face the {B}. Left, right, or behind me for the {C}?",
    "As you show buyers round: stood at the {A}, facing the {B}, will they find the {C} on their left, their right, "
    "or behind them?",
    "I stay near the {A} and I watch to the {B}. The {C} is at my left, at my right or at my back? (back is when I "
    "must turn 135 degrees or more)",
    "Your rogue lurks beside the {A}, gaze locked on the {B}. Does the {C} lie to her left, to her right, or at her "
    "back? A turn of 135 degrees or more counts as back.",
    "1. Go to the {A}. 2. Turn to face the {B}. 3. Classify the {C} as left, right or back (back: a rotation of at "
    "least 135 degrees).",
]
HARD = [
    "okay um so i'm next to the {A} and looking at the {B} and uh where does that put the {C} front left front "
    "right back left or back right",
    "Hi Dev, your parcel came, it's in the porch. Also settle a bet for me: with me next to the {A} and my nose "
    "pointing at the {B}, is the {C} front-left, front-right, back-left or back-right of me? Cheers",
    "Front-left, front-right, back-left or back-right, which is the {C}, if I'm at the {A} facing the {B}?",
    "When the {B} is faced from the {A}, in which quadrant is the {C} located: front-left, front-right, back-left "
    "or back-right?",
    "From the {A}, facing the {B}: is the {C} more in front of me or more behind, and more to my left or my right? "
    "Say front-left, front-right, back-left or back-right.",
    "{A}, {B}, {C}: me at the {A}, facing the {B}. Which quadrant holds the {C}: front-left, front-right, "
    "back-left or back-right?",
    "Stood by the {A} and looking at the {B}, is the {C} front-left, front-right, back-left or back-right of the "
    "viewer?",
    "I am at the {A}, with the face to the {B}. The {C} stays in front-left, front-right, back-left or back-right "
    "of me?",
    "The wizard stands at the {A}, staff pointed at the {B}. Where is the {C} relative to the wizard: front-left, "
    "front-right, back-left or back-right?",
    "1. Navigate to the {A}. 2. Rotate until the {B} is straight ahead. 3. Output which quadrant the {C} falls in: "
    "front-left, front-right, back-left or back-right.",
]


def say(name: str, k: int, rng: random.Random) -> str:
    """An everyday name for benchmark category `name` in pattern `k`'s region (its own name about half the time)."""
    table = SYN[REGION[k]]
    return table[name] if name in table and rng.random() < 0.5 else name


def cap(text: str) -> str:
    """`text` opening a sentence: first letter upper case ('tv' is written TV there)."""
    if re.match(r"tvs?\b", text):
        return "TV" + text[2:]
    return text[:1].upper() + text[1:]


def plural(word: str) -> str:
    return PLURAL.get(word, word + ("es" if word.endswith(("sh", "ch", "x", "s")) else "s"))


def listing(words: list[str], style: str) -> str:
    """The four candidates as a person lists them (in the benchmark's order, which is also the options' order)."""
    the = ["the " + w for w in words]
    if style == "spoken":
        return " ".join(the[:-1]) + " or " + the[-1]
    if style == "the_comma_or":
        return ", ".join(the[:-1]) + ", or " + the[-1]
    if style == "the_or":
        return ", ".join(the[:-1]) + " or " + the[-1]
    if style == "comma_and":
        return ", ".join([cap(words[0])] + words[1:-1]) + " and " + words[-1]
    if style == "lettered":  # the benchmark's own letters: its options list the candidates in this order
        return " ".join(f"({'abcd'[i]}) {w}" for i, w in enumerate(words))
    raise ValueError(f"unknown list style {style!r}")


# --- one single-letter slip -----------------------------------------------------------------------------------------


def join(segs: list[Seg], rng: random.Random | None, objects_too: bool = True) -> str:
    """The question text; with `rng`, one word of this set's slip tables misspelt once (`join_with_slip`)."""
    return join_with_slip(segs, rng, TYPO_WORDS, TYPO_OBJECTS, NEVER_MISSPELT, objects_too)


# --- the eight types ------------------------------------------------------------------------------------------------


def _direction_segments(qt: str, k: int, objs: list[str], rng: random.Random) -> list[Seg]:
    tpl = {"object_rel_direction_easy": EASY, "object_rel_direction_medium": MEDIUM,
           "object_rel_direction_hard": HARD}[qt][k]
    return _segments(tpl, {"A": say(objs[0], k, rng), "B": say(objs[1], k, rng), "C": say(objs[2], k, rng)})


def rewrite(q: dict, k: int, rng: random.Random, typo: bool) -> dict:
    """Question `q` re-asked with pattern `k` of its type (options and answer letter kept)."""
    qt, gt = q["question_type"], q["ground_truth"]
    objs = source_objects(q)
    out = {**q, "source_id": q["id"]}
    if qt == "object_counting":
        one = say(objs[0], k, rng)
        segs = _segments(COUNT[k], {"P": one, "Ps": plural(one)})
    elif qt == "object_size_estimation":
        tpl, unit = SIZE[k]
        segs = _segments(tpl, {"X": say(objs[0], k, rng)})
        out["ground_truth"] = convert(gt, CM_IN[unit])
    elif qt == "room_size_estimation":
        tpl, unit = ROOM[k]
        segs = _segments(tpl, {})
        out["ground_truth"] = convert(gt, SQM_IN[unit])
    elif qt == "object_abs_distance":
        tpl, unit = ABS[k]
        segs = _segments(tpl, {"A": say(objs[0], k, rng), "B": say(objs[1], k, rng)})
        out["ground_truth"] = convert(gt, CM_IN[unit] / 100.0)
    elif qt == "object_rel_distance":
        tpl, style = REL[k]
        cands, ref = objs[:-1], objs[-1]
        if len(cands) != 4:
            raise ValueError(f"question {q['id']}: {len(cands)} candidates, the patterns say four")
        said = [say(c, k, rng) for c in cands]
        named = said + [cap(w) for w in said]
        segs = _split_objects(_segments(tpl.replace("{L}", listing(said, style)), {"R": say(ref, k, rng)}), named)
    else:
        segs = _direction_segments(qt, k, objs, rng)
    text = join(segs, rng if typo else None)
    out["question"] = cap(text) if k != 0 else text  # the voice transcript stays lower case
    return out


# --- route planning -------------------------------------------------------------------------------------------------

# route patterns: (opening, step 'until', step plain, blank, joiner, closing for one blank, closing for several,
# whose places: 'your' becomes this word) -- {start} {face} {goal} {n} filled in; {i} is the step's number
ROUTES = [
    ("okay assistant um directions please uh i'm starting from {start} looking at {face} and i wanna end up at "
     "{goal} so ", "i head straight until i reach ",
     "i head ", "i turn some way", " then ", " um so which way is that turn left right or back",
     " um so which way is each of the {n} turns left right or back in order", "my"),
    ("You awaken at {start}, facing {face}. Your quest: reach {goal}. The old map reads: ", "march on until ",
     "march ", "turn [?]", "; ", ". Which way is the turn, adventurer: left, right or back?",
     ". Name each turn in order, adventurer: left, right or back?", "your"),
    ("Mrs Rossi is by {start}, she look to {face}. She want to go to {goal}. ", "she go straight until ", "she go ",
     "she turn (where?)", ", after ", ". The turn is to left, to right or back?",
     ". Every turn is to left, to right or back? Tell me in the order.", "her"),
    ("Mission for the delivery robot. Pose: {start}, heading toward {face}. Destination: {goal}. ",
     "Step {i}: drive forward until ", "Step {i}: drive ", "Step {i}: rotate (unresolved).", " ",
     " Resolve the rotation: left, right or back?", " Resolve each rotation in order: left, right or back?",
     "your"),
]


def _owner(word: str) -> callable:
    return lambda place: re.sub(r"\byour\b", word, place)


def route_question(q: dict, k: int, rng: random.Random | None) -> dict:
    """Route question `q` in route pattern `k`, options kept; with `rng`, one word the pattern adds is misspelt
    (never a place: those keep the benchmark's words)."""
    start, face, goal, steps = route_parts(q["question"])
    opening, until, plain, blank, sep, one, several, owner = ROUTES[k]
    blanks = sum(s is None for s in steps)
    mine = _owner(owner)
    segs = _segments(opening, {"start": mine(start), "face": mine(_noun(face)), "goal": mine(goal)})
    first = len(segs)
    for i, s in enumerate(steps):
        if i:
            segs.append((sep, False))
        if s is None:
            segs.append((blank.replace("{i}", str(i + 1)), False))
            continue
        words = mine(s[1]) + ("." if k == 3 and not s[1].endswith(".") else "")
        segs += [((until if s[0] == "until" else plain).replace("{i}", str(i + 1)), False), (words, True)]
    segs += _segments(one if blanks == 1 else several.replace("{n}", NUMBER[blanks]), {})
    if opening.endswith(". "):  # the first step opens a sentence
        segs[first] = (segs[first][0][:1].upper() + segs[first][0][1:], False)
    return {**q, "source_id": q["id"], "question": join(segs, rng, objects_too=False)}


# --- the set --------------------------------------------------------------------------------------------------------


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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--questions", default=str(VSI / "questions.jsonl"))
    ap.add_argument("--seed", type=int, default=12)
    ap.add_argument("--out", default=str(OUT))
    ap.add_argument("--check", action="store_true", help="run the checks on --out; write nothing")
    a = ap.parse_args()
    if a.check:  # the checks import this generator: they run as their own script, so no import goes back
        sys.exit(subprocess.run([sys.executable, str(HERE / "check_holdout12.py"), "--questions", a.questions,
                                 "--seed", str(a.seed), "--out", a.out]).returncode)
    qs = load_questions(a.questions)
    uses = earlier_uses(EARLIER_SOURCES)
    out = Path(a.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_suffix(out.suffix + ".tmp")
    tmp.write_bytes(dumps(build(qs, uses, a.seed)))
    tmp.replace(out)
    print(f"{len(qs)} benchmark questions read; set 12 written -> {out}")


if __name__ == "__main__":
    main()
