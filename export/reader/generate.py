"""Generated training questions for the reader: (words, role tags, kind), from sentence shapes written here.

Every question is drawn from a seeded `numpy` generator: a kind, one of many sentence shapes of that kind, object
names from a broad indoor vocabulary (`OBJECTS`, far beyond the benchmark's and the detectors' labels), then noise
that people add: politeness, asides, context sentences, word-order changes, non-native grammar, typos, units in
words. The held-out wording sets (benchmarks/data/vsibench_paraphrases_holdout*) are never read here.

Tags (one per word, BIO): OBJ (the object asked about), STAND (where I stand), FACE (what I face), CAND (compared
objects / listed categories), REF (the object distances are measured from), UNIT, NUM, START / GOAL / WAY (a route's
start, goal and waypoints), TURN (a blank turn of a route), LOC (a place a count is restricted to).
"""
from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from mosaicthinker.runtime.query.reader_spec import KINDS, ROLES

from .shapes import SHAPES2, expand

OBJECT_TEXT = """
chair sofa couch table desk bed lamp tv television monitor screen laptop computer keyboard mouse printer
bookshelf bookcase shelf cabinet cupboard wardrobe closet dresser drawer nightstand ottoman stool bench armchair
recliner pillow cushion blanket rug carpet mat curtain blind window door doorway mirror picture painting poster
clock vase plant flowerpot fern cactus basket box crate suitcase backpack bag trash can bin wastebasket bucket
refrigerator fridge freezer microwave oven stove cooktop kettle toaster dishwasher sink faucet tap counter
countertop island cutting board pan pot bowl plate cup mug glass bottle jar teapot blender coffee maker
toilet bathtub bathroom sink shower towel towel rail radiator heater fan air conditioner vent fireplace mantel
piano guitar drum speaker stereo headphones radio projector whiteboard blackboard bulletin board calendar
coat rack coat hanger hat stand umbrella stand shoe rack boot tray laundry basket washing machine dryer iron
ironing board vacuum cleaner broom mop ladder toolbox sewing machine treadmill exercise bike dumbbell yoga mat
crib cradle high chair toy box dollhouse teddy bear game console router modem telephone phone tablet charger
power strip extension cord light switch ceiling light chandelier floor lamp desk lamp table lamp candle
candlestick photo frame sculpture statue globe map aquarium fish tank bird cage dog bed cat tree litter box
footstool side table coffee table dining table kitchen table console table end table bar stool office chair
rocking chair folding chair beanbag futon bunk bed sofa bed loveseat chaise lounge hutch sideboard buffet
filing cabinet safe locker trunk chest shoe cabinet tv stand media console bookshelf ladder wine rack
spice rack dish rack paper towel holder soap dispenser toothbrush holder hair dryer scale hamper clothes rack
pinboard easel drafting table sewing table workbench tool chest pegboard water heater boiler fuse box
thermostat smoke detector fire extinguisher first aid kit doormat welcome mat stair railing banister
column pillar arch alcove bay window skylight storage bin plastic tub cooler ice chest grill rice cooker
air fryer food processor stand mixer bread box fruit bowl napkin holder tablecloth place mat tissue box
magazine rack newspaper book notebook binder folder pen holder stapler desk organizer monitor stand
webcam microphone amplifier turntable record player cd rack dvd player remote control pouffe hassock
settee divan bureau commode armoire credenza tallboy chiffonier jardiniere planter terrarium humidifier
dehumidifier air purifier space heater electric fan standing fan ceiling fan wall clock alarm clock
mirror cabinet medicine cabinet vanity dressing table makeup table hat box jewelry box shoe box
"""
_GLUE = {"can", "board", "maker", "stand", "box", "rail", "of", "aid", "first", "bath", "paper", "power", "light",
         "air", "high", "toy", "fire", "smoke", "fuse", "ice", "rice", "food", "bread", "fruit", "tissue", "welcome",
         "place", "bay", "electric", "standing", "wall", "alarm", "makeup", "hat", "shoe", "media", "dog", "cat", "bird",
         "player", "detector", "clothes", "hair", "jewelry", "space", "remote", "record", "dvd", "cd", "ceiling",
         "floor", "game", "storage", "plastic", "kit", "stair", "drafting", "sewing", "ironing", "washing",
         "exercise", "litter", "coffee", "cutting", "soap", "toothbrush", "paper", "water", "tool", "dish", "wine",
         "spice", "napkin", "magazine", "pen", "chaise", "dining", "kitchen", "office", "rocking", "folding", "bunk",
         "filing", "side", "end", "bar", "umbrella", "yoga", "teddy", "extension", "photo", "fish", "tree",
         "control", "towel", "holder", "fryer", "processor", "mixer", "cooker", "purifier", "conditioner"}
SINGLE = sorted(set(OBJECT_TEXT.split()) - _GLUE)
# multi-word names as units
MULTI = ["trash can", "coffee table", "dining table", "office chair", "floor lamp", "desk lamp", "table lamp",
         "kitchen table", "side table", "end table", "bar stool", "rocking chair", "folding chair", "bunk bed",
         "sofa bed", "filing cabinet", "tv stand", "media console", "wine rack", "spice rack", "dish rack",
         "soap dispenser", "hair dryer", "clothes rack", "water heater", "fuse box", "smoke detector",
         "fire extinguisher", "first aid kit", "stair railing", "storage bin", "ice chest", "rice cooker",
         "air fryer", "food processor", "stand mixer", "bread box", "fruit bowl", "tissue box", "magazine rack",
         "pen holder", "monitor stand", "record player", "remote control", "dressing table", "jewelry box",
         "coat rack", "coat hanger", "hat stand", "umbrella stand", "shoe rack", "laundry basket",
         "washing machine", "ironing board", "vacuum cleaner", "sewing machine", "exercise bike", "yoga mat",
         "high chair", "toy box", "teddy bear", "game console", "power strip", "light switch", "ceiling light",
         "photo frame", "fish tank", "bird cage", "dog bed", "litter box", "coffee maker", "cutting board",
         "towel rail", "air conditioner", "bulletin board", "bathroom sink", "paper towel holder",
         "medicine cabinet", "alarm clock", "wall clock", "ceiling fan", "space heater", "air purifier",
         "picture frame", "computer tower", "shoe cabinet", "chest of drawers", "night stand", "trash bin",
         "recycling bin", "kitchen island", "bath mat", "shower curtain", "toilet paper", "wall shelf",
         "tv set", "tv unit", "bath tub", "dish washer", "fire place", "flat screen", "arm chair", "book shelf",
         "kitchen counter", "range hood", "chest freezer", "shoe stand", "plant pot", "room divider",
         "standing desk", "corner sofa", "bean bag", "glass door", "sliding door", "window sill", "door mat",
         "clothes horse", "drying rack", "wash basin", "hand basin", "shower head", "towel rack", "bath tub",
         "pot plant", "house plant", "coat stand", "key hook", "pizza oven", "wine fridge", "water cooler",
         "vending machine", "reception desk", "waiting chair", "conference table", "meeting table", "swivel chair",
         "gaming chair", "tv cabinet", "display case", "glass cabinet", "china cabinet", "baby gate", "play mat",
         "changing table", "bedside table", "bedside lamp", "reading lamp", "wall lamp", "pendant light",
         "ceiling lamp", "window blind", "roller blind", "laundry hamper", "ironing table", "step stool",
         "foot rest", "garden chair", "deck chair", "patio table", "barbecue grill", "log basket"]
# informal and regional names people use (never a label list of any benchmark)
INFORMAL = ["telly", "loo", "settee", "cooker", "hob", "stovetop", "couch", "washer", "fridge", "bin", "sideboard",
            "wardrobe", "tub", "lav", "sink unit", "cupboard", "bog", "duvet", "doona", "chesterfield", "davenport",
            "icebox", "range", "bureau", "tallboy", "lowboy", "commode", "pouf", "footrest", "lamp stand", "tele",
            "boob tube", "fridge freezer", "kitchen roll", "armoire", "credenza", "escritoire", "wash stand",
            "basin", "cistern", "sofabed", "daybed", "cot", "crib", "pram", "buggy", "hoover", "dustbin",
            "rubbish bin", "garbage can", "waste bin", "pedal bin", "wheelie bin", "radiator", "rad", "aga",
            "microwave oven", "hi-fi", "sound bar", "soundbar", "subwoofer", "tv screen", "computer screen",
            "pc", "desktop", "notebook computer", "ottoman bed", "king size bed", "double bed", "single bed"]
ADJ = ["small", "big", "white", "black", "wooden", "grey", "old", "round", "tall", "low", "blue", "red", "little",
       "large", "green", "brown", "metal", "glass", "leather", "new", "second", "main", "corner"]
ROOMS = ["room", "space", "place", "apartment", "flat", "house", "home", "lounge", "kitchen", "bedroom",
         "living room", "office", "studio", "hallway", "scene", "video", "clip", "area", "lobby", "den"]

UNITS = {"m": ["meters", "metres", "meter", "metre", "m", "mtrs"], "cm": ["centimeters", "centimetres", "cm", "cms"],
         "mm": ["millimeters", "millimetres", "mm"], "ft": ["feet", "foot", "ft"], "in": ["inches", "inch", "in"],
         "m2": ["square meters", "square metres", "sq m", "m2", "sqm", "meters squared"],
         "ft2": ["square feet", "sq ft", "square foot", "ft2", "feet squared"]}

POLITE_PRE = ["please", "could you tell me", "can you tell me", "i want to know", "i'd like to know", "tell me",
              "hey", "hi", "quick question", "sorry to bother you", "if you don't mind", "just wondering",
              "i was wondering", "help me out", "one thing", "ok so", "so", "right", "hmm", "pls", "kindly tell",
              "i need to know", "would you know", "do you know", "question", "um", "well", "excuse me"]
POLITE_POST = ["please", "thanks", "thank you", "thx", "if you can", "cheers", "ty", "many thanks",
               "thanks a lot", "if possible", "much appreciated", "when you get a chance"]
ASIDES = ["roughly is fine", "an estimate is ok", "approximately", "just a rough number", "no need to be exact",
          "best guess", "as best you can", "more or less", "ballpark", "i'm curious", "for my notes",
          "it's for a project", "i forgot", "can't remember", "not sure myself", "asking for a friend",
          "it matters for moving furniture", "approx", "about is fine", "precision not needed",
          "i think", "if you saw it", "based on the video", "from what you saw", "in the video",
          "from the footage", "judging by the recording"]
CONTEXT = ["i'm rearranging my furniture.", "i just moved in.", "we are redecorating.", "my friend is visiting.",
           "i'm making an inventory.", "i'm writing a report.", "this is for insurance.", "i'm new here.",
           "i'm trying to plan the layout.", "i'm blind-folded in a game.", "i work here."]


@dataclass
class Example:
    """One generated question: words, one BIO tag per word, the kind, and the options (multiple choice)."""

    words: list[str]
    tags: list[str]
    kind: str
    options: list[str] | None = None

    @property
    def text(self) -> str:
        return " ".join(self.words)


# sentence shapes: "{obj}", "{stand}" ... are object slots; "{unit}" a unit; "{cands}" a list; "{room}" a room word
SHAPES: dict[str, list[str]] = {
    "count": [
        "how many {obj} are there", "how many {obj} are in the {room}", "how many {obj} can you see",
        "count the {obj}", "what is the number of {obj}", "number of {obj}", "how many {obj} did you see",
        "how many {obj} in this {room}", "{obj}: how many", "total number of {obj} in the {room}",
        "how many {obj} do i have", "give me a count of the {obj}", "count how many {obj} there are",
        "the {obj} - how many are there", "how many {obj} does this {room} have", "how many {obj} you see",
        "what's the count of {obj}", "how many {obj} altogether", "in this {room}, how many {obj} are there",
        "can you count the {obj} for me", "how many {obj} were visible", "tell me the number of {obj}",
        "how much {obj} is there", "how many {obj} there is", "count {obj}", "how many {obj} exist here",
        "in total how many {obj}", "how many pieces of {obj}", "how many {obj} are present in the {room}",
        "what number of {obj} appear", "how many {obj} are visible in the {room}", "how many {obj} i got",
        "how many {obj} are there next to the {loc}", "how many {obj} are on the {loc}",
        "how many {obj} are near the {loc}", "count the {obj} by the {loc}",
    ],
    "size": [
        "how big is the {obj}", "what is the longest dimension of the {obj}", "how long is the {obj} at its longest",
        "what's the size of the {obj} in {unit}", "longest side of the {obj} in {unit}",
        "how large is the {obj}, longest side", "the {obj}: what is its largest dimension",
        "what is the maximum dimension of the {obj} in {unit}", "measure the {obj}'s longest edge",
        "in {unit}, how big is the {obj}", "biggest dimension of the {obj}", "how long is the {obj}",
        "what size is the {obj}", "tell me the {obj}'s longest measurement in {unit}",
        "how many {unit} is the {obj} along its longest side", "length of the {obj}'s longest side",
        "what is the greatest extent of the {obj}", "the {obj}, how big is it in {unit}",
        "how many {unit} long is the {obj}", "the longest dimension of {obj} please, in {unit}",
        "estimate the size of the {obj}", "what's the {obj}'s max dimension", "{obj} size in {unit}",
        "how big the {obj} is", "what is the longest length of the {obj} (in {unit})",
        "how tall is the {obj}", "what is the height of the {obj}", "how wide is the {obj}",
        "what is the width of the {obj} in {unit}",
    ],
    "room_size": [
        "how big is this {room}", "what is the area of the {room}", "what's the floor area in {unit}",
        "how large is the {room} in {unit}", "size of the {room} in {unit}", "how many {unit} is the {room}",
        "what is the total floor space", "estimate the {room}'s area", "floor area of this {room}, please",
        "the {room}: how many {unit}", "how much floor space does the {room} have", "area of the {room}",
        "what's the square footage", "how big is the floor of the {room} in {unit}",
        "if you combine all the spaces, how big is the {room}", "total area covered by the {room} in {unit}",
        "what size is this {room}", "how spacious is the {room}, in {unit}",
    ],
    "distance": [
        "how far is the {obj} from the {obj}", "what is the distance between the {obj} and the {obj}",
        "distance from the {obj} to the {obj} in {unit}", "how many {unit} between the {obj} and the {obj}",
        "how far apart are the {obj} and the {obj}", "the {obj} and the {obj}: how far apart",
        "what's the gap between the {obj} and the {obj}", "how close is the {obj} to the {obj}",
        "in {unit}, how far is the {obj} from the {obj}", "measure the distance between the {obj} and the {obj}",
        "how far away is the {obj} from the {obj}, nearest points", "how far the {obj} is from the {obj}",
        "how many {unit} from the {obj} to the {obj}", "the {obj} is how far from the {obj}",
        "what distance separates the {obj} and the {obj}", "distance {obj} to {obj}",
        "between the {obj} and the {obj}, what's the distance in {unit}",
        "how long is the walk from the {obj} to the {obj}", "how near is the {obj} to the {obj}",
        "what is the shortest distance between the {obj} and the {obj} in {unit}",
        "from the {obj}, how far is the {obj}", "how far is it from the {obj} to the {obj}",
    ],
    "closest": [
        "which is closest to the {ref}: {cands}", "which of {cands} is nearest to the {ref}",
        "of the {cands}, which one is closest to the {ref}", "what is nearest the {ref}, {cands}",
        "which object is the closest to the {ref}", "which one is closest to the {ref}",
        "which is nearer to the {ref}, {cands}", "what's closest to the {ref} among {cands}",
        "from the {ref}, which is the closest: {cands}", "closest to the {ref} - {cands}",
        "which of these is nearest to the {ref}? {cands}", "the {ref}: which of {cands} is closest to it",
        "what is the nearest to the {ref} out of {cands}", "which is least far from the {ref}: {cands}",
        "among {cands}, which sits closest to the {ref}", "which thing is closest to the {ref}",
        "which is the shortest distance from the {ref}: {cands}", "pick the one nearest the {ref}: {cands}",
    ],
    "farthest": [
        "which is farthest from the {ref}: {cands}", "which of {cands} is furthest from the {ref}",
        "of the {cands}, which one is farthest away from the {ref}", "what is furthest from the {ref}, {cands}",
        "which object is the farthest from the {ref}", "which one is furthest from the {ref}",
        "which is further from the {ref}, {cands}", "what's farthest from the {ref} among {cands}",
        "from the {ref}, which is the farthest: {cands}", "farthest from the {ref} - {cands}",
        "which of these is most distant from the {ref}? {cands}", "the {ref}: which of {cands} is furthest from it",
        "which is the greatest distance from the {ref}: {cands}", "pick the one farthest from the {ref}: {cands}",
    ],
    "direction": [
        "if i am standing by the {stand} and facing the {face}, is the {obj} to my left or right",
        "standing at the {stand}, facing the {face}, where is the {obj}",
        "i'm at the {stand} looking at the {face}. is the {obj} on my left or my right",
        "from the {stand}, facing the {face}, which side is the {obj} on",
        "if i stand next to the {stand} and look towards the {face}, where would the {obj} be",
        "with the {face} in front of me and me at the {stand}, is the {obj} left or right",
        "i'm by the {stand} and the {face} is straight ahead. where's the {obj}",
        "imagine you stand at the {stand} facing the {face}: is the {obj} behind you, left or right",
        "standing beside the {stand} and looking at the {face}, in which direction is the {obj}",
        "facing the {face} from the {stand}, is the {obj} on the left or the right",
        "when i'm at the {stand} and face the {face}, the {obj} is on which side",
        "put me at the {stand}, facing toward the {face}. where is the {obj} relative to me",
        "the {obj}: if i stand by the {stand} and face the {face}, is it to my left or right",
        "my back is to the {stand} and i face the {face}; which way is the {obj}",
        "if i were at the {stand} looking toward the {face}, which quadrant is the {obj} in",
        "standing near the {stand} facing the {face}, is the {obj} front-left, front-right, back-left or back-right",
        "from the {stand} looking at the {face}, is the {obj} to the left or right of the {face}",
        "i stand at the {stand} and i look at the {face}, the {obj} is where",
        "i am next to {stand}, my face to {face}, {obj} is left or right",
        "located at the {stand} and oriented toward the {face}, where is the {obj}",
    ],
    "route": [
        "i'm at the {start} facing the {face}. how do i get to the {goal}? first go forward until the {way}, "
        "then {turn}, then go forward until the {goal}",
        "starting from the {start} and facing the {face}, i want to walk to the {goal}. walk to the {way}, "
        "{turn}, walk until the {goal}",
        "from the {start}, looking at the {face}, plan my route to the {goal}: go to the {way}, {turn}, "
        "go to the {way}, {turn}, go to the {goal}",
        "you begin at the {start} facing the {face} and need to reach the {goal}. 1. go forward until the {way} "
        "2. {turn} 3. go forward until the {goal}",
        "robot at the {start}, heading toward the {face}, target the {goal}: step one walk forward to the {way}; "
        "step two {turn}; step three walk forward to the {goal}",
        "i start next to the {start} with the {face} ahead of me and want to go to the {goal}. move forward past "
        "the {way}, {turn}, keep going until the {goal}. which turns",
        "navigate from the {start} (facing the {face}) to the {goal}: forward until the {way}, {turn}, forward "
        "until the {way}, {turn}, forward until the {goal}",
    ],
    "appearance": [
        "in what order did these first appear in the video: {cands}", "which came first in the video: {cands}",
        "what order do the {cands} show up in", "order of first appearance: {cands}",
        "sort these by when they first appear: {cands}", "which of {cands} was seen first, and then",
        "in which sequence do {cands} first appear", "put {cands} in the order the video shows them",
        "what is the order in which {cands} first appear in the clip",
        "rank {cands} by first time seen", "list {cands} by the time they first come into view",
    ],
    "other": [
        "what color is the {obj}", "who lives here", "is the {obj} made of wood", "what brand is the {obj}",
        "why is the {obj} there", "what time is it", "tell me a joke", "is the {obj} expensive",
        "what is the weather like", "when was the {obj} bought", "what material is the {obj}",
        "is the {obj} clean", "how old is the {obj}", "what is this video about", "who owns the {obj}",
        "how much did the {obj} cost", "is the {obj} comfortable", "can i sit on the {obj}",
        "what is on the {obj}", "what's the temperature in the {room}", "is the light on",
        "how heavy is the {obj}", "what is the {obj} used for", "hello", "thanks for your help",
        "what does the {obj} smell like", "is anyone in the {room}", "what is written on the {obj}",
    ],
}
TURNS = ["[please fill in]", "turn ___", "turn ?", "[?]", "(fill in)", "turn which way", "___", "[blank]"]
DIR_OPTIONS = {"easy": ["left", "right"], "medium": ["left", "right", "back"],
               "hard": ["front-left", "front-right", "back-left", "back-right"]}
NUMBER_WORDS = ["one", "two", "three", "four", "five", "a couple of", "half a", "a dozen", "twenty", "ten"]
ARTICLES = ["a", "this", "that", "my", "the", "", "the"]


def _typo(word: str, rng: np.random.Generator) -> str:
    """One edit (swap, drop, double, substitute) of a word of 4+ letters."""
    if len(word) < 4 or not word.isalpha():
        return word
    i = int(rng.integers(1, len(word) - 1))
    op = int(rng.integers(4))
    if op == 0:
        return word[:i] + word[i + 1] + word[i] + word[i + 2:]
    if op == 1:
        return word[:i] + word[i + 1:]
    if op == 2:
        return word[:i] + word[i] + word[i:]
    return word[:i] + "qwertyuiopasdfghjklzxcvbnm"[int(rng.integers(26))] + word[i + 1:]


def _words(text: str) -> list[str]:
    return text.replace(",", " , ").replace(":", " : ").replace(";", " ; ").replace("?", " ? ").split()


class Generator:
    """Seeded question generator; `sample(kind)` -> one `Example`."""

    def __init__(self, seed: int, objects: list[str] | None = None, typo_rate: float = 0.06):
        self.rng = np.random.default_rng(seed)
        self.objects = objects or (SINGLE + MULTI + INFORMAL)
        self.typo_rate = typo_rate

    def _pick(self, xs: list) -> str:
        return xs[int(self.rng.integers(len(xs)))]

    def _name(self, plural: bool = False) -> list[str]:
        name = self._pick(self.objects)
        if plural and self.rng.random() < 0.8:
            name = name + ("es" if name.endswith(("s", "x", "ch", "sh")) else "s")
        words = name.split()
        if self.rng.random() < 0.08:
            words = [self._pick(ADJ)] + words
        return words

    def _span(self, words: list[str], tag: str) -> list[tuple[str, str]]:
        return [(w, ("B-" if i == 0 else "I-") + tag) for i, w in enumerate(words)]

    def _cands(self, n: int) -> list[tuple[str, str]]:
        out: list[tuple[str, str]] = []
        for i in range(n):
            if i:
                out += [(w, "O") for w in self._pick([",", ",", "or", "and", ", or", ";", "/"]).split()]
            if self.rng.random() < 0.6:
                out.append(("the", "O"))
            out += self._span(self._name(), "CAND")
        return out

    def sample(self, kind: str) -> Example:
        # composed shapes (export/reader/shapes.py) most of the time, the fixed ones of SHAPES otherwise
        shape = expand(self._pick(SHAPES2[kind]), self.rng) if kind in SHAPES2 and self.rng.random() < 0.75 \
            else self._pick(SHAPES[kind])
        unit_key = self._pick(["m2", "ft2"] if kind == "room_size" else ["m", "cm", "mm", "ft", "in"])
        ncand = int(self.rng.integers(2, 5))
        out = self.fill(shape, kind, ncand, unit_key)
        options = None
        if kind == "direction" and self.rng.random() < 0.7:
            options = [f"{chr(65 + i)}. {o}" for i, o in enumerate(DIR_OPTIONS[self._pick(list(DIR_OPTIONS))])]
        elif kind in ("closest", "farthest") and not any(t.endswith("CAND") for _, t in out):
            options = [f"{chr(65 + i)}. {' '.join(self._name())}" for i in range(ncand)]
        out = self._noise(out, kind)
        return Example([w for w, _ in out], [t for _, t in out], kind, options)

    def fill(self, shape: str, kind: str, ncand: int = 3, unit_key: str = "m") -> list[tuple[str, str]]:
        """(word, tag) of a sentence shape with its slots filled: names, units (of `unit_key`), numbers, lists of
        `ncand` objects, turns."""
        out: list[tuple[str, str]] = []
        drawn: dict[str, list[str]] = {}
        for piece in re.split(r"(\{\w+@?\})", shape):
            if not piece.startswith("{"):
                out += [(w, "O") for w in _words(piece)]
                continue
            slot = piece[1:-1]
            if slot.endswith("@"):  # the name drawn before for this slot, said again
                slot = slot[:-1]
                role = "OBJ" if slot == "obj" else slot.upper()
                out += self._span(drawn.get(slot) or self._name(), role)
            elif slot == "obj":
                drawn[slot] = self._name(plural=kind == "count")
                out += self._span(drawn[slot], "OBJ")
            elif slot in ("stand", "face", "ref", "start", "goal", "way", "loc"):
                drawn[slot] = self._name()
                out += self._span(drawn[slot], slot.upper())
            elif slot == "cands":
                out += self._cands(ncand)
            elif slot == "room":
                out += [(w, "O") for w in self._pick(ROOMS).split()]
            elif slot == "unit":
                out += self._span(self._pick(UNITS[unit_key]).split(), "UNIT")
            elif slot == "num":
                out += self._span(self._pick(NUMBER_WORDS + [str(int(self.rng.integers(1, 500)))]).split(), "NUM")
            elif slot == "turn":
                out += self._span(self._pick(TURNS).split(), "TURN")
        return out

    def _noise(self, out: list[tuple[str, str]], kind: str) -> list[tuple[str, str]]:
        rng = self.rng
        if kind in ("size", "distance", "room_size") and not any(t.endswith("UNIT") for _, t in out) \
                and rng.random() < 0.5:  # a unit said at the end
            unit_key = self._pick(["m2", "ft2"] if kind == "room_size" else ["m", "cm", "mm", "ft", "in"])
            lead = self._pick(["in", "in", ", in", "answer in", "( in", ", units :", "give it in"])
            out = out + [(w, "O") for w in lead.split()] + self._span(self._pick(UNITS[unit_key]).split(), "UNIT")
        if kind in ("distance", "size") and rng.random() < 0.1:  # a number with a unit, as a guess aside
            out = out + [(w, "O") for w in self._pick(["is it about", "more than", "i guess around"]).split()] \
                + self._span([self._pick(NUMBER_WORDS[:6] + [str(int(rng.integers(1, 400)))])], "NUM") \
                + self._span(self._pick(UNITS["m"]).split(), "UNIT")
        if rng.random() < 0.25:  # non-native grammar: articles dropped or swapped
            out = [(self._pick(ARTICLES) if w == "the" and t == "O" else w, t) for w, t in out]
            out = [(w, t) for w, t in out if w]
        if rng.random() < 0.15:
            out = [(w, t) for w, t in out if not (t == "O" and w in ("is", "are", "do", "does", "the"))]
        if rng.random() < self.typo_rate * 5:
            out = [(_typo(w, rng) if rng.random() < 0.15 else w, t) for w, t in out]
        q = self._pick(["?", "?", "?", "", ".", "??", "?!"])
        if q:
            out = out + [(q, "O")]
        if rng.random() < 0.35:
            out = [(w, "O") for w in _words(self._pick(POLITE_PRE)) + [self._pick([",", ":", "-", ","])]] + out
        if rng.random() < 0.25:
            extra = _words(self._pick(POLITE_POST + ASIDES))
            out = out + [(w, "O") for w in ([self._pick(["(", ",", "-"])] + extra + [self._pick([")", ".", "!"])])]
        if rng.random() < 0.1:
            out = [(w, "O") for w in _words(self._pick(CONTEXT))] + out
        if rng.random() < 0.1:
            out = [(w.upper() if rng.random() < 0.5 else w.capitalize(), t) for w, t in out]
        return out


def dataset(n: int, seed: int) -> list[Example]:
    """n examples, kinds balanced (each kind n / len(KINDS) times, in random order)."""
    g = Generator(seed)
    kinds = [KINDS[i % len(KINDS)] for i in range(n)]
    g.rng.shuffle(kinds)
    return [g.sample(k) for k in kinds]
