"""The object vocabulary: canonical indoor object names, their true synonyms and kinds, English plurals, and
the name keys that question phrases and map categories are compared by.

Canonical names are the VSI-Bench (ARKitScenes) categories where one exists (`refrigerator`, `tv`, `washer` ...),
otherwise a short common noun. Phrases resolve to the head noun: modifiers before it ("kitchen sink" -> sink) and
attachments after a preposition ("stool by the piano" -> stool) are dropped. Pure text; imports nothing.
"""
from __future__ import annotations

import functools
import re

# canonical name -> synonyms (lower case, singular; plurals are handled by `canonical_name`)
VOCABULARY: dict[str, tuple[str, ...]] = {
    # Only true synonyms and kinds of the same thing ("couch" is a sofa, "office chair" is a chair). Objects
    # that are merely related get their own entry (desk, monitor, freezer, dryer, radiator, cushion ...): a name
    # must never be read as a different object (computer tower != laptop, ceiling light != lamp).
    # the VSI-Bench / ARKitScenes categories
    "chair": ("chair", "armchair", "arm chair", "desk chair", "office chair", "dining chair", "recliner",
              "wicker chair", "rocking chair", "swivel chair"),
    "table": ("table", "dining table", "dinning table", "coffee table", "side table", "end table",
              "kitchen table", "work table"),
    "sofa": ("sofa", "couch", "loveseat", "love seat", "settee", "sectional", "seater sofa", "sofa couch"),
    "tv": ("tv", "television", "telly", "tv monitor", "tv_monitor", "television set", "tv set", "tv screen",
           "flat screen tv", "flatscreen tv"),
    "stool": ("stool", "bar stool", "footstool", "foot stool", "step stool"),
    "bed": ("bed", "bunk bed", "double bed", "single bed", "queen bed", "king bed"),
    "toilet": ("toilet", "wc", "toilet bowl"),
    "stove": ("stove", "gas stove", "cooktop", "cooker", "hob", "stovetop", "stove top", "electric stove"),
    "bathtub": ("bathtub", "bath tub", "bathtube", "tub", "bath"),
    "washer": ("washer", "washing machine", "laundry machine", "clothes washer"),
    "refrigerator": ("refrigerator", "fridge", "refridgerator", "frige"),
    "fireplace": ("fireplace", "fire place", "hearth"),
    "dishwasher": ("dishwasher", "dish washer"),
    # other common indoor objects (the synthetic scenes and detectors use these)
    "lamp": ("lamp", "floor lamp", "standing lamp", "table lamp", "desk lamp", "bedside lamp"),
    "plant": ("plant", "potted plant", "houseplant", "house plant", "green plant", "pot plant"),
    "cabinet": ("cabinet", "cupboard", "kitchen cabinet", "display cabinet", "filing cabinet", "file cabinet"),
    "wardrobe": ("wardrobe", "armoire"),
    "nightstand": ("nightstand", "night stand", "bedside table", "night table"),
    "shelf": ("shelf", "shelves", "shelving"),
    "bookshelf": ("bookshelf", "book shelf", "bookcase", "book case"),
    "door": ("door", "terrace door", "kitchen door"),
    "window": ("window",),
    "sink": ("sink", "bathroom sink", "kitchen sink", "basin", "washbasin", "wash basin"),
    "mirror": ("mirror",),
    "oven": ("oven",),
    "microwave": ("microwave", "microwave oven"),
    "trash bin": ("trash bin", "trash can", "garbage bin", "garbage can", "waste bin", "wastebasket",
                  "waste basket", "dustbin", "rubbish bin", "trashcan", "bin", "recycling bin", "litter bin"),
    "heater": ("heater", "space heater"),
    "laptop": ("laptop", "notebook computer", "laptop computer"),
    "picture": ("picture", "painting", "photo", "photograph"),
    "clock": ("clock", "wall clock"),
    "rug": ("rug", "carpet", "area rug"),
    "pillow": ("pillow",),
    "curtain": ("curtain", "drape", "drapes"),
    "shower": ("shower",),
    "towel": ("towel",),
    "vase": ("vase",),
    "printer": ("printer",),
    "piano": ("piano",),
    "fan": ("fan", "electric fan", "corner fan"),
    "speaker": ("speaker", "loudspeaker"),
    "backpack": ("backpack", "rucksack"),
    "bottle": ("bottle",),
    "cup": ("cup",),
    "book": ("book",),
    "remote": ("remote", "tv remote", "remote control"),
    "stairs": ("stairs", "stair", "staircase", "stairway"),
    "wall": ("wall",),
    "teddy bear": ("teddy bear",),
    "candle": ("candle",),
    "keyboard": ("keyboard",),
    "bench": ("bench",),
    # related but different objects: their own names (ScanNet / ScanNet++ keep them apart)
    "desk": ("desk", "writing desk", "computer desk", "office desk"),
    "monitor": ("monitor", "computer monitor"),
    "telephone": ("telephone", "phone"),
    "whiteboard": ("whiteboard", "white board", "dry erase board"),
    "radiator": ("radiator",),
    "counter": ("counter", "kitchen counter", "countertop", "counter top"),
    "dresser": ("dresser", "chest of drawers"),
    "ottoman": ("ottoman", "pouf", "pouffe"),
    "freezer": ("freezer",),
    "dryer": ("dryer", "clothes dryer", "tumble dryer"),
    "cushion": ("cushion",),
    "mug": ("mug",),
}

NAME_SYNONYMS: dict[str, str] = {s: canon for canon, syns in VOCABULARY.items() for s in (canon, *syns)}
_MAX_NGRAM = max(len(s.split()) for s in NAME_SYNONYMS)
_ARTICLES = {"the", "a", "an", "my", "this", "that", "these", "those", "some", "same"}
# a noun phrase's head ends where an attachment starts ("the stool by the piano", "the tv on the table")
_PREPOSITIONS = {"by", "on", "near", "next", "with", "in", "under", "beside", "behind", "closest", "closer",
                 "nearest", "farthest", "right", "left", "towards", "toward", "at", "above", "below", "against",
                 "facing", "is", "positioned", "from", "to", "into", "between", "that", "which", "where"}


_IRREGULAR = {"people": "person", "children": "child", "men": "man", "women": "woman", "mice": "mouse",
              "feet": "foot", "teeth": "tooth", "knives": "knife", "leaves": "leaf", "shelves": "shelf",
              "wives": "wife", "loaves": "loaf", "halves": "half", "dice": "die", "geese": "goose",
              "cacti": "cactus", "radii": "radius", "series": "series", "species": "species", "scissors": "scissors",
              "glasses": "glasses", "pants": "pants", "stairs": "stairs", "drapes": "drapes", "blinds": "blinds",
              "shoes": "shoe", "tvs": "tv", "tv's": "tv", "boxes": "box", "buses": "bus", "lenses": "lens",
              "vases": "vase", "bases": "base", "cases": "case", "houses": "house", "blouses": "blouse"}
_NO_S = ("ss", "us", "is", "ics")  # glass, cactus, chassis, electronics: not plurals


def singular(w: str) -> str:
    """English singular of one lower-case word ("shelves" -> "shelf", "benches" -> "bench", "tvs" -> "tv")."""
    if w in _IRREGULAR:
        return _IRREGULAR[w]
    if len(w) > 4 and w.endswith(("lves", "rves")):  # shelves, scarves -> shelf, scarf
        return w[:-3] + "f"
    if len(w) > 4 and w.endswith("ives"):  # knives -> knife
        return w[:-3] + "fe"
    if len(w) > 3 and w.endswith("ies"):
        return w[:-3] + "y"
    if len(w) > 3 and w.endswith(("ches", "shes", "sses", "xes", "zzes")):
        return w[:-2]
    if len(w) > 3 and w.endswith("oes") and w not in ("shoes", "toes"):  # potatoes
        return w[:-2]
    if len(w) > 2 and w.endswith("s") and not w.endswith(_NO_S):
        return w[:-1]
    return w


# singular -> plural where `singular`'s table is irregular ("person" -> "people"); "tv's" is a possessive, not one
_PLURAL = {one: many for many, one in _IRREGULAR.items() if "'" not in many}


def plural(name: str) -> str:
    """English plural of a name, the inverse of `singular` on its last word ("office chair" -> "office chairs",
    "shelf" -> "shelves", "bench" -> "benches", "person" -> "people"); a word already plural stays."""
    head, _, w = name.rpartition(" ")
    if w in _PLURAL:
        many = _PLURAL[w]
    elif singular(w) != w or w.endswith(("is", "ics")):  # drawers, chassis, electronics: already plural
        many = w
    elif len(w) > 1 and w.endswith("y") and w[-2] not in "aeiou":
        many = w[:-1] + "ies"
    elif w.endswith(("ch", "sh", "s", "x", "z")):
        many = w + "es"
    else:
        many = w + "s"
    return f"{head} {many}" if head else many


def _words(s: str) -> list[str]:
    s = s.lower().replace("(s)", "").replace("(es)", "").replace("_", " ").replace("\u2019", "'")
    s = re.sub(r"'s\b", "", s)  # possessive: "the sofa's" -> "the sofa"
    s = re.sub(r"[^a-z0-9\- ]+", " ", s)
    return [w for w in s.split() if w]


def _match(words: list[str]) -> str | None:
    """The vocabulary name of the longest n-gram that ENDS at the last word (the head noun of an English noun
    phrase is last: "kitchen sink" -> sink, "3-seater sofa" -> sofa), or None. Only the head is matched, so a
    phrase whose head is not in the vocabulary ("computer tower", "ceiling light") names nothing in it."""
    if not words:
        return None
    for n in range(min(_MAX_NGRAM, len(words)), 0, -1):
        gram = words[len(words) - n:]
        for cand in (" ".join(gram), " ".join(gram[:-1] + [singular(gram[-1])])):
            if cand in NAME_SYNONYMS:
                return NAME_SYNONYMS[cand]
    return None


@functools.lru_cache(maxsize=4096)  # pure; a 10 k-object map has a few names, each keyed once
def name_key(s: str) -> str:
    """A name's comparison key: lower case, articles dropped, the last word singular ("The Office Chairs" ->
    "office chair"). Map categories and question phrases are compared by this key before synonyms."""
    words = [w for w in _words(s) if w not in _ARTICLES]
    if words:
        words[-1] = singular(words[-1])
    return " ".join(words)


def canonical_name(s: str) -> str | None:
    """Canonical vocabulary name for an object phrase, or None when it names nothing in the vocabulary.

    "couch" -> "sofa", "fridge" -> "refrigerator", "chair(s)" -> "chair", "the stool by the piano" -> "stool",
    "kitchen sink" -> "sink", "edge of the bed" -> "bed" (a part's owner when the part is not an object);
    "computer tower", "ceiling light", "monitor" -> not laptop / lamp / tv (see `VOCABULARY`).
    """
    words = [w for w in _words(s) if w not in _ARTICLES]
    if not words:
        return None
    joined = " ".join(words)
    if joined in NAME_SYNONYMS:
        return NAME_SYNONYMS[joined]
    while len(words) > 1 and words[0] in _PREPOSITIONS:  # "closest sofa", "nearest chair"
        words = words[1:]
    head: list[str] = []
    for w in words:
        if w in _PREPOSITIONS or w == "of":
            break
        head.append(w)
    found = _match(head)
    if found is None and "of" in words:  # "edge of the bed", "corner of the table"
        found = _match([w for w in words[words.index("of") + 1:] if w not in _PREPOSITIONS][:_MAX_NGRAM])
    return found
