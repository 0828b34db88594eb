"""Task grounding without a VLM: the VSI-Bench question templates and an indoor object vocabulary.

`parse_question(question, options)` -> `ParsedQuestion`: the question type (VSI-Bench names), ranked target
objects and cue objects (canonical vocabulary names), the type's parameters, and every object phrase that is not in
the vocabulary (`unknown`: reported, never dropped silently).

Targets are the objects the question asks about, cues the reference objects that fix the frame or the route
(key-frame scoring weighs targets 1 and cues 0.5):
- object_counting / object_size_estimation: target = the object;
- object_abs_distance: targets = both objects;
- object_rel_distance: targets = the candidate objects, cue = the reference object;
- object_rel_direction_*: target = the queried object, cues = the object stood by and the object faced;
- route_planning: target = the destination, cues = start, facing object and the waypoints;
- obj_appearance_order: targets = the listed categories in the question's order.

Canonical names are the VSI-Bench (ARKitScenes) categories where one exists (`refrigerator`, `tv`, `washer` ...),
otherwise a short common noun. Phrases resolve to the head noun: modifiers before it ("kitchen sink" -> sink) and
attachments after a preposition ("stool by the piano" -> stool) are dropped.
"""
from __future__ import annotations

import functools
import re
from dataclasses import asdict, dataclass, field
from typing import Any

from .infra.trace import as_trace

QTYPES = ("object_counting", "object_size_estimation", "room_size_estimation", "object_abs_distance",
          "object_rel_distance", "object_rel_direction_easy", "object_rel_direction_medium",
          "object_rel_direction_hard", "route_planning", "obj_appearance_order")

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


_singular = singular  # the old private name, used by other modules

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


@dataclass
class ObjectRef:
    """One object phrase from the question: the text and its canonical name (None when unknown)."""

    phrase: str
    name: str | None

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass
class ParsedQuestion:
    """What a question asks. qtype: one of QTYPES or None (not a recognised template); targets, cues: canonical
    names, ranked; params: the type's parameters (object names are canonical; a phrase that is not in the
    vocabulary stays as its text and is listed in `unknown`); unknown: object phrases not in the vocabulary."""

    qtype: str | None
    targets: list[str] = field(default_factory=list)
    cues: list[str] = field(default_factory=list)
    params: dict[str, Any] = field(default_factory=dict)
    unknown: list[str] = field(default_factory=list)
    question: str = ""
    options: list[str] | None = None
    phrases: dict[str, str] = field(default_factory=dict)  # name -> the object phrase as the question wrote it
    selectors: dict[str, dict[str, Any]] = field(default_factory=dict)  # name -> how one instance is selected
    notes: list[str] = field(default_factory=list)  # parts of the question that were not understood / not used
    how: str = "template"  # "template" (VSI-Bench wording) | "natural" (grounding_nl) | "none"

    @property
    def objects(self) -> list[str]:
        """Targets then cues, without repeats."""
        return list(dict.fromkeys(self.targets + self.cues))

    @property
    def whole_map(self) -> bool:
        """About everything in the map (room size, a list, "how many objects", "the biggest object", "the nearest
        object to the cup"): the map is built for every category the detector names, not for named objects."""
        return (self.qtype in ("room_size_estimation", "object_nearest")
                or (self.qtype == "object_list" and not self.params.get("objects"))
                or "*" in (self.params.get("object"), self.params.get("candidates"))
                or "*" in (self.params.get("objects") or []))

    def phrase(self, name: str) -> str:
        """The question's own words for the object called `name` (the name itself when none was recorded)."""
        return self.phrases.get(name, name)

    def describe(self) -> str:
        """One line saying how the question was read (for replies and as a hint in the VLM prompt)."""
        if self.qtype is None:
            return "not understood" + (f" ({'; '.join(self.notes)})" if self.notes else "")
        ps = {k: v for k, v in self.params.items() if k not in ("steps",)}
        return f"{self.qtype} {ps}" + (f"; not used: {'; '.join(self.notes)}" if self.notes else "")

    def to_dict(self) -> dict[str, Any]:
        return {"qtype": self.qtype, "targets": self.targets, "cues": self.cues, "params": self.params,
                "unknown": self.unknown, "phrases": self.phrases, "selectors": self.selectors,
                "notes": self.notes, "how": self.how}


# ----------------------------------------------------------------------------- options


_OPT_RE = re.compile(r"^\s*([A-Z])\s*[.)::]\s*(.*?)\s*$")


MAX_QUESTION_CHARS = 2000  # longer questions are refused (InputError): no real question is that long
MAX_OPTIONS = 26
_ANSI = re.compile(r"\x1b\[[0-?]*[ -/]*[@-~]|\x1b\][^\x07\x1b]{0,200}(?:\x07|\x1b\\)?|\x1b.?")


def safe_text(s: Any, limit: int | None = None) -> str:
    """`s` with ANSI escapes removed and other control characters shown as `\\xNN` (never echoed raw);
    newlines and tabs become spaces. `limit`: cut to this many characters (with "...")."""
    t = _ANSI.sub("", str(s))
    t = "".join(c if c.isprintable() else (" " if c in "\n\r\t" else f"\\x{ord(c):02x}" if ord(c) < 256
                                            else f"\\u{ord(c):04x}") for c in t)
    return t if limit is None or len(t) <= limit else t[:limit] + "..."


def check_question(question: Any, options: list[str] | None = None) -> None:
    """Refuse questions over `MAX_QUESTION_CHARS` and option lists that are too long (InputError)."""
    from .infra.errors import InputError

    n = len(str(question))
    if n > MAX_QUESTION_CHARS:
        raise InputError(f"question: {n} characters, over the {MAX_QUESTION_CHARS}-character limit; ask a shorter "
                         f"question (one object relation at a time)")
    if options is not None and (len(options) > MAX_OPTIONS or sum(len(str(o)) for o in options) > MAX_QUESTION_CHARS):
        raise InputError(f"options: {len(options)} options / {sum(len(str(o)) for o in options)} characters, over "
                         f"the limit ({MAX_OPTIONS} options, {MAX_QUESTION_CHARS} characters)")


_INLINE_OPT = re.compile(r"(?<![A-Za-z])([A-Z])[.)]\s")


def split_inline_options(question: str) -> tuple[str, list[str] | None]:
    """'... ? A. left B. right C. back' -> (question, ['A. left', 'B. right', 'C. back']) when present.

    One pass over the letter marks (linear in the question's length): the first run A, B, C ... in order."""
    marks = [(m.start(), m.group(1)) for m in _INLINE_OPT.finditer(question)]
    for i, (pos, letter) in enumerate(marks):
        if letter != "A":
            continue
        run = [pos]
        for pos2, l2 in marks[i + 1:]:
            if l2 == chr(ord("A") + len(run)):
                run.append(pos2)
        if len(run) < 2:
            continue
        head = re.sub(r"\s*\boptions?\s*:\s*$", "", question[:pos], flags=re.I).rstrip()
        parts = [question[a:b].strip() for a, b in zip(run, run[1:] + [len(question)])]
        return head, parts
    return question, None


def split_options(options: list[str] | None) -> list[tuple[str, str]]:
    """["A. left", "B. right"] -> [("A", "left"), ("B", "right")]; unlettered options get A, B, ... in order."""
    out: list[tuple[str, str]] = []
    for i, o in enumerate(options or []):
        m = _OPT_RE.match(str(o))
        out.append((m.group(1), m.group(2)) if m else (chr(ord("A") + i), str(o).strip()))
    return out


# ----------------------------------------------------------------------------- templates

# an object phrase (leading articles dropped, lazily up to the template's next words); bounded and without
# commas / question marks so that a template with three phrases cannot backtrack cubically on long input
_O = r"(?:the\s+)*([^,?]{1,80}?)"

_TEMPLATES: list[tuple[str, re.Pattern[str]]] = [
    ("object_counting", re.compile(rf"^how many {_O}\s*(?:\(s\))? (?:are|is) (?:there )?in (?:this|the) room", re.I)),
    ("object_size_estimation", re.compile(
        rf"longest dimension \(length, width, or height\) of {_O}, measured in centimeters", re.I)),
    ("room_size_estimation", re.compile(r"size of (?:this|the) room \(in square meters\)", re.I)),
    ("object_abs_distance", re.compile(rf"distance between {_O} and {_O} \(in meters\)", re.I)),
    ("object_rel_distance", re.compile(
        rf"which of these objects \((.+?)\) is (?:the )?(closest|nearest|farthest|furthest) to {_O}\s*\?", re.I)),
    ("object_rel_direction_hard", re.compile(
        rf"standing by {_O} and facing {_O}, is {_O} to my front-left, front-right, back-left, or back-right",
        re.I)),
    ("object_rel_direction_medium", re.compile(
        rf"standing by {_O} and facing {_O}, is {_O} to my left, right, or back", re.I)),
    ("object_rel_direction_easy", re.compile(
        rf"standing by {_O} and facing {_O}, is {_O} to the left or (?:to )?the right of {_O}\s*\?", re.I)),
    ("obj_appearance_order", re.compile(
        r"first-time appearance order of the following categories in the video:\s*(.+?)\s*\?", re.I)),
    ("route_planning", re.compile(r"you are a robot beginning (?:at|by|near) ", re.I)),
]


_TEMPLATE_WINDOW = 1200


def _ref(phrase: str) -> ObjectRef:
    phrase = re.sub(r"^(?:the\s+)+", "", phrase.strip().rstrip(".?,"), flags=re.I).strip()
    return ObjectRef(phrase, canonical_name(phrase))


def _name(r: ObjectRef) -> str:
    return r.name if r.name is not None else r.phrase


def parse_question(question: str, options: list[str] | None = None) -> ParsedQuestion:
    """Parse a question: the VSI-Bench templates first (exact wording), then natural wording
    (`grounding_nl.parse_natural`). qtype None: not understood (`notes` say what was and was not).
    Questions over `MAX_QUESTION_CHARS` are an InputError. Only the text and the options are used."""
    check_question(question, options)
    # control characters are spaces to the parser (shown as \xNN they read as words: "chairs\x07" -> "x07s")
    q = " ".join("".join(c if c.isprintable() else " " for c in _ANSI.sub("", str(question))).split())
    pq = ParsedQuestion(None, question=q, options=list(options) if options is not None else None)
    refs: list[ObjectRef] = []
    for qtype, rx in _TEMPLATES:
        m = rx.search(q[:_TEMPLATE_WINDOW])  # the benchmark's questions are < 600 characters
        if not m:
            continue
        if qtype in ("object_counting", "object_size_estimation") and re.search(r",| and | or ", m.group(1)):
            continue  # "how many chairs and tables are in the room?": several objects, not one named "tables"
        pq.qtype = qtype
        if qtype in ("object_counting", "object_size_estimation"):
            r = _ref(m.group(1))
            refs = [r]
            pq.targets = [_name(r)]
            pq.params = {"object": _name(r)}
        elif qtype == "room_size_estimation":
            pq.params = {}
        elif qtype == "object_abs_distance":
            a, b = _ref(m.group(1)), _ref(m.group(2))
            refs = [a, b]
            pq.targets = [_name(a), _name(b)]
            pq.params = {"a": _name(a), "b": _name(b)}
        elif qtype == "object_rel_distance":
            cands = [_ref(c) for c in m.group(1).split(",")]
            ref = _ref(m.group(3))
            refs = cands + [ref]
            pq.targets = [_name(c) for c in cands]
            pq.cues = [_name(ref)]
            pq.params = {"reference": _name(ref), "candidates": [_name(c) for c in cands],
                         "extreme": "closest" if m.group(2).lower() in ("closest", "nearest") else "farthest"}
        elif qtype.startswith("object_rel_direction"):
            pos, face, query = _ref(m.group(1)), _ref(m.group(2)), _ref(m.group(3))
            refs = [pos, face, query]
            pq.targets = [_name(query)]
            pq.cues = [_name(pos), _name(face)]
            pq.params = {"position": _name(pos), "facing": _name(face), "query": _name(query)}
            if qtype == "object_rel_direction_easy":
                rel = _ref(m.group(4))
                refs.append(rel)
                pq.params["relative_to"] = _name(rel)
        elif qtype == "obj_appearance_order":
            cats = [_ref(c) for c in re.split(r",\s*(?:and\s+)?|\s+and\s+", m.group(1)) if c.strip()]
            refs = cats
            pq.targets = [_name(c) for c in cats]
            pq.params = {"categories": [_name(c) for c in cats]}
        elif qtype == "route_planning":
            refs = _parse_route(q, pq)
        break
    if pq.qtype is None:
        from .grounding_nl import parse_natural

        return parse_natural(q, pq.options)
    pq.phrases = {_name(r): r.phrase for r in refs}
    pq.targets = list(dict.fromkeys(pq.targets))
    pq.cues = [c for c in dict.fromkeys(pq.cues) if c not in pq.targets]
    pq.unknown = list(dict.fromkeys(r.phrase for r in refs if r.name is None))
    return pq


_ROUTE_START = re.compile(
    r"beginning (?:at|by|near) (.+?)(?:,)? (?:and )?facing (?:into |toward |towards |to |out )?(.+?)\s*\. "
    r"you want to navigate to (.+?)\s*\. ", re.I)
_STEP = re.compile(r"\d+\.\s*(\[please fill in\]\.?|go forward (?:until|to)\s+(.+?))\s*(?=\d+\.\s|you have reached|$)",
                   re.I)


def _parse_route(q: str, pq: ParsedQuestion) -> list[ObjectRef]:
    """Route questions are written by people: start, facing, destination, then numbered steps, each
    "[please fill in]" (a turn to choose) or "Go forward until X"."""
    m = _ROUTE_START.search(q)
    if not m:
        pq.params = {"parse_error": "route start/facing/destination not found"}
        return []
    start, facing, dest = _ref(m.group(1)), _ref(m.group(2)), _ref(m.group(3))
    steps: list[dict[str, Any]] = []
    refs = [start, facing, dest]
    for sm in _STEP.finditer(q[m.end():]):
        if sm.group(2) is None:
            steps.append({"action": "turn"})
        else:
            r = _ref(re.sub(r"\s*(?:is on your (?:left|right)|on your (?:left|right))\s*\.?$", "", sm.group(2)))
            refs.append(r)
            steps.append({"action": "forward", "until": _name(r), "phrase": r.phrase})
    pq.targets = [_name(dest)]
    pq.cues = [_name(start), _name(facing)] + [s["until"] for s in steps if s["action"] == "forward"]
    pq.params = {"start": _name(start), "facing": _name(facing), "destination": _name(dest), "steps": steps,
                 "n_turns": sum(s["action"] == "turn" for s in steps)}
    return refs


# ----------------------------------------------------------------------------- grounding with a VLM (paper)

GROUNDING_PROMPT = (
    "You will answer a question about an indoor video. First list the objects needed to answer it.\n"
    "Question: {question}\n"
    "Reply in exactly this format:\n"
    "targets: <objects the question asks about, comma separated>\n"
    "cues: <reference objects that fix a position, direction or route, comma separated, or none>")


def parse_grounding_reply(reply: str) -> tuple[list[str], list[str]] | None:
    """`targets: a, b` / `cues: c` lines (or a JSON object with those keys) -> (target phrases, cue phrases);
    None when the reply has no usable targets."""
    import json

    text = str(reply or "").strip()
    targets: list[str] = []
    cues: list[str] = []
    m = re.search(r"\{.*\}", text, re.S)
    if m:
        try:
            d = json.loads(m.group(0))
            if isinstance(d, dict):
                targets = [str(x) for x in d.get("targets", []) or []]
                cues = [str(x) for x in d.get("cues", []) or []]
        except (json.JSONDecodeError, TypeError):
            pass
    if not targets:
        for key, dest in (("targets?", targets), ("cues?", cues)):
            mm = re.search(rf"(?im)^\W*{key}\s*[:=-]\s*(.+)$", text)
            if mm:
                dest += [p for p in re.split(r",|;|\band\b", mm.group(1))]
    clean = lambda xs: [x.strip(" .*'\"[]") for x in xs if x.strip(" .*'\"[]") and  # noqa: E731
                        x.strip(" .*'\"[]").lower() not in ("none", "n/a", "-")]
    targets, cues = clean(targets), clean(cues)
    return (targets, cues) if targets else None


def ground(question: str, options: list[str] | None = None, vlm: Any = None, frames: list[Any] | None = None,
           trace: Any = None, max_new_tokens: int = 48) -> ParsedQuestion:
    """Task grounding: question -> ranked targets and cues (+ the template's type and parameters).

    With a VLM (`.generate(images, prompt, max_new_tokens=...) -> str`) it is prompted with the question and a
    few sampled frames (`frames`: [H, W, 3] uint8 RGB) and its object names are canonicalised through the
    vocabulary; names it gives that are not in the vocabulary are reported (trace event "unknown_objects" and
    `ParsedQuestion.unknown`), never dropped silently. An unusable reply (no parsable targets, or none in the
    vocabulary) falls back to the template parser with a "fallback" trace event. Without a VLM the template
    parser is used (`parse_question`). The template's qtype/params are kept whenever a template matches, so
    the map reasoner can still answer.
    """
    trace = as_trace(trace)
    pq = parse_question(question, options)
    how = "templates"
    if vlm is not None:
        prompt = GROUNDING_PROMPT.format(question=" ".join(str(question).split()))
        try:
            with trace.stage("grounding.vlm"):
                reply = str(vlm.generate(list(frames or []), prompt, max_new_tokens=max_new_tokens))
        except Exception as e:  # a VLM failure must not lose the question: fall back, loudly
            reply, err = "", f"{type(e).__name__}: {e}"
        else:
            err = ""
        got = parse_grounding_reply(reply)
        if got is not None:
            t_phr, c_phr = got
            tn = [canonical_name(p) for p in t_phr]
            cn = [canonical_name(p) for p in c_phr]
            unknown = [p for p, n in zip(t_phr + c_phr, tn + cn) if n is None]
            targets = list(dict.fromkeys(n for n in tn if n))
            cues = [n for n in dict.fromkeys(n for n in cn if n) if n not in targets]
            if targets or cues:
                if unknown:
                    trace.event("unknown_objects", f"VLM grounding named objects outside the vocabulary: "
                                f"{', '.join(unknown)} (not searched)", names=unknown, stage="grounding")
                template_only = [n for n in pq.objects if n not in targets and n not in cues]
                # objects the matched template needs but the VLM did not name are searched too (as cues), so
                # the map reasoner can still answer; recorded
                pq.targets = targets or cues[:1]
                pq.cues = [c for c in (cues if targets else cues[1:]) + template_only if c not in pq.targets]
                pq.unknown = list(dict.fromkeys(pq.unknown + unknown))
                how = "vlm"
                trace.decide("grounding.vlm_reply", reply)
                if template_only:
                    trace.event("grounding", f"template objects the VLM did not name, added as cues: "
                                f"{', '.join(template_only)}", names=template_only, stage="grounding")
            else:
                err = f"none of the named objects is in the vocabulary: {t_phr + c_phr}"
        else:
            err = err or f"no `targets:` in the reply {reply[:120]!r}"
        if how != "vlm":
            trace.event("fallback", f"VLM grounding unusable ({err}); using the question-template parser",
                        stage="grounding", warn=True)
    if pq.unknown and how == "templates":
        trace.event("unknown_objects", f"question names objects outside the vocabulary: {', '.join(pq.unknown)} "
                    f"(not searched)", names=pq.unknown, stage="grounding")
    trace.decide("grounding", {"method": how, "qtype": pq.qtype, "targets": pq.targets, "cues": pq.cues,
                               "unknown": pq.unknown})
    return pq
