"""Task grounding without a VLM for questions as people type them (the VSI-Bench templates are `grounding.py`).

`parse_natural(question, options) -> ParsedQuestion` reads the intent, the object phrases and their roles, the
units and free-text options of an English question, in one pass over its tokens (linear in its length):

- intents (qtype): the VSI-Bench types `object_counting`, `object_size_estimation`, `room_size_estimation`,
  `object_abs_distance`, `object_rel_distance`, `object_rel_direction_{easy,medium,hard}`,
  `obj_appearance_order`, plus `object_existence`, `object_where`, `object_list`, `object_nearest` (nearest /
  farthest among everything in the map), `object_direction` (free-form direction, no options) and
  `object_size_compare` (which is bigger / is A taller than B / the tallest object in the map);
- object phrases are the runs of content words between function words ("the computer tower", "office chairs",
  "the kitchen's sink" -> "sink"); each keeps the question's words (`ParsedQuestion.phrases`) and a
  vocabulary name when it is one or a listed synonym (`grounding.canonical_name`); others stay as written (an
  open vocabulary: the map's own category names resolve them, `answer.MapReasoner`);
- selectors that pick one instance: size superlatives ("the biggest table"), "the X nearest/closest to/next to
  the Y"; colours, materials and ordinals cannot be resolved from a map and are reported as such;
- locations in counts, lists and is-there questions: on (top of), near / next to / by / beside, in, under /
  below / beneath, above / over, between A and B ("how many cups are on the table?", "what's under the desk?";
  params["where"], `answer.relation_holds`); others (behind, against, along ...) are refused, never dropped;
- heights above the floor ("how high above the floor is the shelf?": dimension "elevation") and box volumes;
  a count of an object's parts ("how many legs does the chair have?") and several questions of different kinds
  in one text are refused with the reason;
- a pronoun after a location ("the chairs next to it", "on top of it") is the one object named before it, read as
  that phrase ("the chairs next to the desk"); with none or several such objects the question is refused;
- units: "in cm / meters / mm / feet / inches" (params["unit"]); options in free text ("..., the lamp, the sofa
  or the tv?") become the candidates.

Nothing here looks at a map: which names exist is the reasoner's business.
"""
from __future__ import annotations

import re
from typing import Any, Callable

from .grounding import NAME_SYNONYMS, ParsedQuestion, canonical_name, name_key, singular, split_options

UNIT_M = {"m": 1.0, "cm": 0.01, "mm": 0.001, "ft": 0.3048, "in": 0.0254}
_UNIT_WORDS = {"m": "m", "meter": "m", "meters": "m", "metre": "m", "metres": "m", "cm": "cm", "centimeter": "cm",
               "centimeters": "cm", "centimetre": "cm", "centimetres": "cm", "mm": "mm", "millimeter": "mm",
               "millimeters": "mm", "millimetre": "mm", "millimetres": "mm", "ft": "ft", "foot": "ft", "feet": "ft",
               "inch": "in", "inches": "in"}
_DET = {"the", "a", "an", "my", "this", "that", "these", "those", "your", "our", "any", "some", "each", "every",
        "all", "its", "his", "her", "their", "another", "other"}
_STOP = set("""
i me you we us he she it they one ones i'm im you're we're it's what's where's that's there's here's who's how's
is are am was were be been being do does did don't doesn't have has had will would should could can may might must
if when while as so and or nor but then than also too either neither both whether not no yes
what which who whom whose where how why there here
of in on at by to from with without into onto toward towards near nearby beside besides next between among amongst
around about across along behind under over above below beneath inside outside within against up down through via
left right front back rear ahead forward forwards backward backwards side sides front-left front-right back-left
back-right left-hand right-hand front-right-hand straight directly direction directions located positioned
situated placed sits sit sitting stand standing stood stands face facing faced faces look looking looked looks
turn turned turning walk walking go going see seen saw spot notice find found show tell give list name named
closest nearest farthest furthest closer nearer farther further close far apart away distance distances gap
many much more most less least number count total quantity amount fewer fewest common numerous plentiful greater
big bigger biggest large larger largest small smaller smallest tall taller tallest short shorter shortest long
longer longest wide wider widest narrow narrower narrowest high higher highest low lower lowest deep size sizes dimension dimensions length
width height depth measure measures measured measuring measurement measurements area footprint square
volume elevation hung installed fixed relative relation respect regard half counting excluding including
leave leaving forgot forget forgotten drop dropped lost present visible separating spacing separation
option options choice choices following eyes gaze oriented orientated position location pointing gazing
watching staring
point points object objects thing things item items stuff furniture piece pieces kind kinds type types
please thanks roughly approximately approx around exactly just only really actually about estimate guess
first second third fourth fifth last order appear appears appeared appearance came come comes seen
cm centimeter centimeters centimetre centimetres mm millimeter millimeters millimetre millimetres m meter meters
metre metres ft foot feet inch inches sq
for about like per upon unto via else off out over onto into than
wonder wondering wondered suppose supposing imagine say know want wanted need think tell give let guess curious
question quick hey hi hello ok okay so um please r u ur pls plz separate separates separated sits lies lie
edge edges extent way ways spot part parts portion
exist exists existing fall falls belong belongs hang hangs hanging rest rests resting lying kept mounted put
placed shown fit fits go goes come comes get gets got keep keeps contain contains include includes hold holds
lie lies occupy occupies measure
maximum max minimum min overall total approximate rough
everything anything something nothing everyone all anywhere somewhere everywhere
me myself mine origin axis y-axis x-axis cartesian plane quadrant quadrants degrees degree
""".split())
_COPULA = {"is", "are", "was", "were", "be", "been", "being", "get", "got", "gets"}
# content words that are also function words: "tv stand", "trash can", "side table", "front door"
_SOFT_AFTER_NOUN = {"stand", "can", "light", "lights", "top", "set", "table"}
_SOFT_BEFORE_NOUN = {"side", "end", "top", "back", "front", "corner", "coffee", "night", "standing", "sitting",
                     "long", "high", "low", "light", "square", "first", "second"}
_SCENE = {"room", "rooms", "kitchen", "bedroom", "bathroom", "living", "dining", "space", "scene", "video", "house",
          "apartment", "flat", "office", "place", "area", "home", "floor", "hall", "hallway", "corridor", "here",
          "interior", "map", "image", "picture", "ground"}
# a part of the room as a location ("in the middle of the room", "in the corner"): no object of that name
_ROOM_REGION_RX = (r"\b(?:in|at|into|near|by|from|to|toward|towards) the (?:middle|center|centre|corner|corners)"
                   r"(?: of (?:the |this |my )?(?:" + "|".join(sorted(_SCENE)) + r"))?"
                   r"(?=$| ?[?,.;:!]| (?:of|and|or|is|are|was|were|facing|looking)\b)")  # not "the corner table"
_COLOURS = {"red", "blue", "green", "yellow", "black", "white", "grey", "gray", "brown", "orange", "pink", "purple",
            "beige", "silver", "gold", "golden", "dark", "light-coloured", "wooden", "wood", "metal", "metallic",
            "leather", "plastic", "glass", "fabric", "striped", "old", "new", "modern", "broken", "open", "closed"}
_ORDINALS = {"first", "second", "third", "fourth", "fifth", "last", "other", "left", "right", "middle", "1st",
             "2nd", "3rd"}
_RANKS = {"second", "third", "fourth", "fifth", "2nd", "3rd", "4th", "5th", "penultimate"}
# size word -> (box measure of `answer._measure`, pick): one table for selectors ("the biggest table") and for
# size comparisons ("which is bigger, ...", "the tallest object")
SUPERLATIVES = {"biggest": ("volume", max), "largest": ("volume", max), "smallest": ("volume", min),
                "tallest": ("height", max), "shortest": ("height", min), "highest": ("top", max),
                "lowest": ("top", min), "longest": ("length", max), "widest": ("width", max),
                "narrowest": ("width", min)}
COMPARATIVES = {"bigger": "biggest", "larger": "largest", "smaller": "smallest", "taller": "tallest",
                "shorter": "shortest", "higher": "highest", "lower": "lowest", "longer": "longest",
                "wider": "widest", "narrower": "narrowest"}
_CMP = "(?:" + "|".join(COMPARATIVES) + ")"
_CMP_RX = rf"\b{_CMP}\b"
_SUP_RX = r"\b(?:" + "|".join(SUPERLATIVES) + r")\b"
# "the longest side of the bed", "the biggest dimension of the tv": a size question, not a comparison
_SUP_DIM_RX = _SUP_RX + r" (?:sides?|dimensions?|edges?|extents?|length|measurements?|axis)\b"
_NEAR_CUES = {"nearest", "closest", "next", "beside", "near", "by", "nearer", "closer"}
_DIR_PHRASES = [  # (regex over the joined tokens, canonical direction)
    (r"front-left|front left|left front|forward left|ahead (?:and )?(?:to the )?left", "front-left"),
    (r"front-right|front right|right front|forward right|ahead (?:and )?(?:to the )?right", "front-right"),
    (r"back-left|back left|rear left|left rear|behind (?:and )?(?:to the )?left|left behind", "back-left"),
    (r"back-right|back right|rear right|right rear|behind (?:and )?(?:to the )?right|right behind", "back-right"),
    (r"\bleft\b", "left"), (r"\bright\b", "right"), (r"\bbehind\b|\bback\b|\brear\b", "back"),
    (r"\bin front\b|\bahead\b|\bfront\b", "front")]
_DIR_RX = [(re.compile(rx), lab) for rx, lab in _DIR_PHRASES]
QUADRANTS = ("front-left", "front-right", "back-left", "back-right")

EXAMPLES: dict[str, list[str]] = {
    "object_counting": ["How many chairs are there?", "Count the cushions in the room.",
                        "How many cups are on the table?", "How many chairs are near the desk?"],
    "object_existence": ["Is there a fridge in this kitchen?", "Do you see any trash cans?",
                         "Is there a laptop on the desk?", "Is the cup on the table?", "Are there two chairs?",
                         "Is there anything between the sofa and the tv?"],
    "object_size_estimation": ["How big is the sofa?", "How tall is the lamp in inches?",
                               "What is the longest side of the bed, in cm?",
                               "How high above the floor is the tv?"],
    "object_abs_distance": ["How far is the table from the tv?", "What's the distance between the sofa and the "
                            "stove in feet?", "How far am I from the tv?", "Is the sofa within 2 m of the tv?"],
    "object_rel_distance": ["Which is closest to the tv: the chair, the stool or the sofa?",
                            "Is the bed or the sofa farther from the door?"],
    "object_nearest": ["What is the nearest object to the fridge?", "What's farthest from the bed?"],
    "object_count_compare": ["Are there more chairs than tables?", "Which are there fewer of, cups or bottles?"],
    "object_size_compare": ["Which is bigger, the table or the sofa?", "Is the fridge taller than the door?",
                            "What's the biggest object in the room?",
                            "How much taller is the fridge than the table?"],
    "object_rel_direction": ["Standing by the sofa facing the tv, is the lamp to my left?",
                             "If I stand at the stove and look at the fridge, is the table front-left, front-right, "
                             "back-left or back-right of me?"],
    "object_where": ["Where is the printer?", "Where's the trash can?", "Which way to the door?"],
    "object_view_direction": ["Is the lamp to the left of the sofa?", "Is the cup behind the tv?"],
    "object_list": ["What objects are in the room?", "List the chairs.", "What's on the table?", "What is to my left?",
                    "What's under the desk?"],
    "room_size_estimation": ["How big is this room?", "What is the floor area of the room in square meters?"],
    "obj_appearance_order": ["Which did I see first, the tv or the sofa?"],
}


def examples() -> list[str]:
    """Example wordings the map reasoner understands (also listed by `mosaic ask --examples`)."""
    return [e for es in EXAMPLES.values() for e in es]


# ----------------------------------------------------------------------------- tokens and noun phrases

_TOK = re.compile(r"[a-z0-9]+(?:[-'][a-z0-9]+)*|[?,.;:!()/&]")
_KEEP_S = {"what's", "where's", "it's", "that's", "there's", "here's", "who's", "how's", "let's"}
# contractions typed without the apostrophe ("whats the distance ..."): read as the contraction, not as a name
# ("its" stays the possessive; "wont", "cant" are words too but not object names)
_NO_APOSTROPHE = {w.replace("'", ""): w for w in (
    "what's", "where's", "that's", "there's", "here's", "who's", "how's", "let's", "i'm", "don't", "doesn't",
    "didn't", "isn't", "aren't", "wasn't", "weren't", "can't", "won't", "couldn't", "wouldn't", "shouldn't",
    "haven't", "hasn't", "i've", "you're", "they're")}  # not "we're": "were" is a word


def tokens(text: str) -> list[str]:
    """Lower-case word and punctuation tokens; a possessive "'s" is its own token."""
    s = text.lower().replace("\u2019", "'").replace("(s)", "").replace("(es)", "").replace("_", " ")
    s = re.sub(r"\s[-\u2013\u2014]+\s", " , ", s)  # a dash between words separates phrases ("the toilet - bed, ...")
    s = re.sub(r"(?<=[a-z0-9])-to-(?=[a-z0-9])", " to ", s)  # "the tv-to-bed distance"
    out: list[str] = []
    for t in _TOK.findall(s):
        t = _NO_APOSTROPHE.get(t, t)
        if t.endswith("'s") and len(t) > 2 and t not in _KEEP_S:
            out += [t[:-2], "'s"]
        else:
            out.append(t)
    return out


def _is_content(toks: list[str], i: int, in_np: bool) -> bool:
    t = toks[i]
    if not re.match(r"[a-z0-9]", t) or t in _DET or "'" in t:  # contractions: i'd, don't, what's ...
        return False
    if t.endswith("ed") and i > 0 and toks[i - 1] in _COPULA:  # "are plugged in": a verb, not a name
        return False
    nxt = toks[i + 1] if i + 1 < len(toks) else ""
    nxt_content = bool(nxt) and re.match(r"[a-z]", nxt) is not None and nxt not in _STOP and nxt not in _DET
    if t in _SOFT_AFTER_NOUN and in_np and nxt not in ("you", "i", "we", "one", "be", "it"):
        return True
    if t in _SOFT_BEFORE_NOUN and nxt_content and nxt not in _SCENE:
        return True
    return t not in _STOP and not t.isdigit()


def noun_phrases(toks: list[str]) -> list[dict[str, Any]]:
    """Object phrases: maximal runs of content words. Each: start, end (token span), words, sel (selector words
    before the head: colours, ordinals, superlatives), scene (a room word, not an object)."""
    nps: list[dict[str, Any]] = []
    i = 0
    while i < len(toks):
        if not _is_content(toks, i, False) and not (toks[i] in SUPERLATIVES and i + 1 < len(toks)
                                                     and _is_content(toks, i + 1, False)):
            i += 1
            continue
        j, words = i, []
        while j < len(toks) and (_is_content(toks, j, bool(words)) or (not words and toks[j] in SUPERLATIVES)):
            words.append(toks[j])
            j += 1
            if j + 1 < len(toks) and toks[j] == "'s" and _is_content(toks, j + 1, False):
                words, j = [], j + 1  # "the kitchen's sink": the owner only qualifies the object
        sel = []
        while len(words) > 1 and (words[0] in SUPERLATIVES or words[0] in _COLOURS or words[0] in _ORDINALS):
            if name_key(" ".join(words)) in NAME_SYNONYMS:  # "white board" is a name, not a white board
                break
            sel.append(words.pop(0))
        if words:
            nps.append({"start": i, "end": j, "words": words, "sel": sel,
                        "scene": all(w in _SCENE for w in words)})
        i = max(j, i + 1)
    return nps


def _before(toks: list[str], np_: dict[str, Any], k: int = 3) -> list[str]:
    """Up to k tokens before a phrase, determiners skipped."""
    out, i = [], np_["start"] - 1
    while i >= 0 and len(out) < k:
        if toks[i] not in _DET:
            out.insert(0, toks[i])
        i -= 1
    return out


def direction_words(text: str) -> list[str]:
    """Canonical directions named in a text, in order of appearance, each span once ("front-left", "left", "back",
    "front" ...)."""
    s = " " + " ".join(tokens(text)) + " "
    found: list[tuple[int, str]] = []
    for rx, lab in _DIR_RX:
        for m in rx.finditer(s):
            found.append((m.start(), lab))
        s = rx.sub(lambda m: " " * len(m.group(0)), s)
    return [lab for _, lab in sorted(found)]


def _unit(joined: str, default: str) -> str:
    m = re.search(r"\b(?:in|into|using|as|how many|number of|many)\s+(?:the\s+)?([a-z]+)\b", joined)
    if m and m.group(1) in _UNIT_WORDS:
        return _UNIT_WORDS[m.group(1)]
    for w in joined.split():
        if w in _UNIT_WORDS and len(w) > 2:
            return _UNIT_WORDS[w]
    return default


# ----------------------------------------------------------------------------- intents

_PREAMBLE = [  # phrases that would be misread as the question's own words
    re.compile(r"(?:measuring|measured|measure|as measured)?\s*(?:from|between)?\s*(?:the\s+)?(?:closest|nearest)"
               r"\s+points?(?:\s+(?:of|on)\s+(?:each|the|both|two)(?:\s+(?:two|the))?\s+objects?)?"),
    re.compile(r"(?:closest|nearest)[- ]point[- ]to[- ](?:closest|nearest)[- ]point"),
    re.compile(r"(?:an object is (?:to )?my back|(?:it|something) counts as (?:behind|back)|count (?:it|that|"
               r"something) as (?:behind|back)) if .{0,120}?(?:face it|degrees(?: or more)?)\b"),
    re.compile(r"(?:the )?directions? (?:refer|refers|are) .{0,160}?(?:y-axis|y axis|quadrants?)\b\)?"),
]


# the viewer addressed as "you" ("picture yourself by the sofa, facing the tv: is the lamp to your left?") is the
# asker: read as "I am ... my left"
_IMAGINED_VIEWER = [(re.compile(rx), to) for rx, to in (
    (r"\b(?:picture|imagine|visuali[sz]e|suppose|pretend) (?:that )?(?:yourself|you're|you are|you)\b", "i am"),
    (r"\b(to|on|at) your (left|right|back|front)\b", r"\1 my \2"), (r"\bbehind you\b", "behind me"),
    (r"\b(in front of|ahead of) you\b", r"\1 me"), (r"\b(left|right) of you\b", r"\1 of me"))]


def _strip_preamble(joined: str) -> tuple[str, dict[str, Any]]:
    extra: dict[str, Any] = {}
    m = re.search(r"(?:turn|turning) (?:at least |more than |over |by )?(\d+)\s+degrees", joined)
    if m:
        extra["back_deg"] = float(m.group(1))
    for rx in _PREAMBLE:
        joined = rx.sub(" ", joined)
    for rx, to in _IMAGINED_VIEWER:  # "picture yourself by the sofa ... to your left": the asker's own place
        joined = rx.sub(to, joined)
    return " ".join(joined.split()), extra


def _has(joined: str, rx: str) -> bool:
    return re.search(rx, joined) is not None


_CLOSE = r"\b(?:closest|nearest|closer|nearer)\b"
_FAR = r"\b(?:farthest|furthest|farther|further)\b"
# a choice is asked (else a closeness word selects): "which ...", "... or ...", "name / pick the object closest to"
_WHICH = (r"\b(?:which|whichever|what|what's|or|than)\b|^(?:name|pick|identify|choose|select)\b|"
          r"\b(?:name|pick|identify|choose|select) the (?:object|thing|item|one)\b")


_ROOMS = r"(?:room|space|kitchen|bedroom|bathroom|apartment|flat|office|house|living room|area|whole space)"
_UNITS_RX = r"(?:cm|centimet\w+|mm|millimet\w+|m|meters?|metres?|feet|foot|ft|inch(?:es)?)"
_SIMPLE_INTENTS = [(name, re.compile(rx)) for name, rx in (  # tried in this order, after the choice questions
    ("room_size", rf"\bhow (?:big|large|long|wide) is (?:the |this |our )?{_ROOMS}\b|\b(?:length|width|dimensions?|"
                  rf"measurements?) of (?:the |this |our )?{_ROOMS}\b|^(?:is|are) (?:the |this |our )?{_ROOMS} "
                  rf"(?:bigger|larger|smaller) than [\d.]+|floor (?:area|space|size)|square "
                  rf"(?:meters?|metres?|feet)|\bsq\b|(?:size|area|footprint) of (?:the |this )?{_ROOMS}\b|"
                  rf"\b{_ROOMS} 's (?:floor )?(?:size|area|footprint)\b|^(?:the |this )?{_ROOMS} (?:floor )?(?:size|area|"
                  rf"footprint)\b"),
    ("size", rf"\bhow (?:big|large|long|tall|wide|high|deep)\b|\b(?:size|dimensions?|length|height|width|depth|volume|"
             rf"measure|measures|measurements?)\b|\b(?:longest|biggest|largest|greatest|widest|max|maximum) (?:side|"
             rf"edge|dimension|extent|length|measurement)\b|how many {_UNITS_RX}\b"),
    ("count", r"\bhow many\b|\bcount\b|\bnumber of\b|\bquantity of\b|\btotal of\b|^(?:the )?total\b|"
              r"\b(?:give|tell) (?:me )?(?:the |a )?(?:number|count|total)\b"),
    ("existence", r"^(?:is|are|isn't|aren't|was|were) there\b|\bis there (?:one|any)\b|\b(?:is|are) (?:a |an |any )?"
                  r"[^?]{1,60}? (?:present|around|visible)\b|^(?:have|has|did) (?:you|we|i) (?:seen|see|spotted|spot|"
                  r"noticed|notice|found|find)\b|\b(?:do|can|did|could) (?:you|i|we) (?:see|spot|find|notice)\b|"
                  r"\b(?:does|do) (?:the|this|our|your) \w+(?: \w+)? (?:have|contain|include|hold)\b|\bexists?\b|"
                  r"^(?:do|does) (?:we|you|i|they|it) (?:have|got)\b|"
                  r"^(?:any|got any)\b|\bis (?:a|an) [^?]{1,80}? (?:in|here)\b"))]


# "the number of chairs greater than (the number of) cups": a count comparison in other words
_COUNT_CMP_RX = (r"\b(?:number|count|amount|quantity) of \w+(?: \w+)? (?:is |are )?(?:greater|larger|bigger|higher|"
                 r"smaller|lower)\b")


# "how high above the floor is the lamp?", "how far off the ground is the shelf?": the bottom's height over the floor
_ELEVATION_RX = (r"\bhow (?:high|far)\b[^?]{0,60}? (?:above|off|from|over) the (?:floor|ground)\b|\b(?:height|elevation)"
                 r"\b[^?]{0,40}? (?:above|off|from) the (?:floor|ground)\b|\bhow high up\b|\bat what height\b|\belevation\b|"
                 r"\bhow high (?:is|are) [^?]{1,60}? (?:mounted|hung|hanging|placed|fixed|installed)\b")


# "is the sofa within 2 m of the tv?", "is the bin more than half a metre from the desk?": a distance against a length
_DIST_OPS = {"within": "<=", "less than": "<", "closer than": "<", "nearer than": "<", "under": "<", "at most": "<=",
             "no more than": "<=", "more than": ">", "further than": ">", "farther than": ">", "over": ">",
             "at least": ">=", "no less than": ">="}
_DIST_CMP_RX = (r"\b(" + "|".join(sorted(_DIST_OPS, key=len, reverse=True)) + r") (?:about |around |roughly )?"
                r"(\d+(?:\.\d+)?|half an?|an?|one|two|three|four|five|six|seven|eight|nine|ten) ?" + r"(cm|centimet\w+|mm|"
                r"millimet\w+|m|meters?|metres?|feet|foot|ft|inch(?:es)?)\b (?:away )?(?:of|from|to)\b")


def _distance_condition(text: str) -> dict[str, Any] | None:
    """{"op", "threshold_m", "text"} of "within 2 m of" / "more than half a metre from" in the raw question text
    (decimals intact), else None."""
    m = re.search(_DIST_CMP_RX, text.lower())
    if m is None:
        return None
    n = m.group(2)
    v = float(n) if n[0].isdigit() else 0.5 if n.startswith("half") else 1.0 if n in ("a", "an") else \
        float(_NUMBERS[n])
    unit = _UNIT_WORDS.get(m.group(3)) or _unit(m.group(3), "m")
    return {"op": _DIST_OPS[m.group(1)], "threshold_m": v * UNIT_M[unit], "text": f"{m.group(1)} {n} {m.group(3)}"}


def _intent(j: str, n_obj: int, has_opts: bool) -> str | None:
    """The intent from cue words (order matters: the more specific first)."""
    if _has(j, _ELEVATION_RX):
        return "size"
    if _has(j, rf"^(?:is|are) (?:the |this |our )?{_ROOMS} (?:bigger|larger|smaller) than (?:about |around )?\d"):
        return "room_size"  # "is the room bigger than 20 square meters?": its floor area against a number
    if _has(j, r"^(?:is|are|was|were)\b") and _has(j.replace(" . ", "."), _DIST_CMP_RX):
        return "abs_distance"  # "is the sofa within 2 m of the tv?": yes or no, with the distance
    stance = _has(j, r"\b(?:facing|face|faces|faced|looking at|look at|looking towards?|look towards?|turned towards?|"
                     r"looking in the direction of|eyes on|gaze on|pointed at|pointing at|oriented towards?|"
                     r"turn(?:s|ing)? (?:to|towards?)|gazing at|gaze at|watching|staring at|my face to)\b|" +
                  _FACING_AHEAD_RX)
    if not _has(j, r"\bhow many\b") and _has(j, r"\b(?:appear|appears|appeared|appearance|show up|showed up|"
                                              r"came into view)\b|"
               r"\b(?:see|saw|seen|spot|spotted|notice|noticed)\b.*\bfirst\b|\bfirst\b.*\b(?:see|saw|seen)\b|"
               r"\bin (?:what|which) order\b"):
        return "obj_appearance_order"
    where_i = re.sub(r"\b(?:looking|look|looked|staring) at\b", " ", j)  # "looking at A, B or C, which ...": no place
    if stance and _has(where_i, r"\b(?:standing|stand|stood|sitting|sit|i am|i'm|im|i was|you are|from|at|by|next "
                                r"to|beside|near|positioned|located|my (?:position|location|spot|place))\b"):
        return "direction"
    if _has(j, r"\b(?:distance|how far|far apart|far away|far from|how close|how near|gap (?:between|from)|separat\w*|"
               r"spacing|"
               r"how much (?:space|room|gap)|how many (?:m|meters?|"
               r"metres?|cm|centimet\w+|feet|foot|ft|inch(?:es)?|mm)\b.*\b(?:between|from|apart|away|to)\b)"):
        if _has(j, _CLOSE + "|" + _FAR) and _has(j, r"\b(?:which|whichever|or|than)\b"):
            return "rel_distance"
        return "abs_distance"  # "what is the distance from the laptop to the nearest chair": instances' minimum  # "how far is the chair nearest the door from the tv": a selector, not the question
    if _has(j, _CLOSE + "|" + _FAR) and _has(j, _WHICH):
        return "rel_distance"
    if _has(j, r"\b(?:what|what's|which)\b(?: \w+){0,3} (?:next to|beside|near|by)\b") and \
            not _has(j, r"\b(?:objects|things|items)\b"):
        return "rel_distance"  # "what's next to the desk?": the nearest other object
    if _has(j, r"\b(?:more|fewer|less)\b") and _has(j, r"\b(?:than|or)\b") and not _has(j, r"\d|\bmore or less\b") \
            and n_obj >= 2:
        return "count_compare"  # "are there more chairs than cups?", "which are there fewer of, cups or chairs?"
    if _has(j, _COUNT_CMP_RX) and _has(j, r"\b(?:than|or)\b") and n_obj >= 2:
        return "count_compare"  # "is the number of chairs greater than the number of cups?"
    if _has(j, rf"\bhow much {_CMP} (?:is|are|was|were)\b|\bby how much (?:is|are|was|were)\b.*{_CMP_RX}|"
               rf"\bhow much (?:is|are|was|were)\b.*{_CMP_RX}") and _has(j, r"\bthan\b"):
        return "size_compare"  # "how much taller is the fridge than the table?": the difference
    if not _has(j, r"\bhow\b") and (_has(j, _CMP_RX) and _has(j, r"\b(?:which|whichever|what|or|than)\b")
                                     or _has(j, _SUP_RX) and _has(j, r"^(?:which|what|what's)\b")
                                     and not _has(j, _SUP_DIM_RX)
                                     and not _has(j, r"\b(?:height|length|width|size|depth|dimensions?) of\b|"
                                                     r"\bat (?:its|their) (?:longest|biggest|largest|widest|"
                                                     r"tallest|highest)\b")):  # "what would X measure at its longest"
        return "size_compare"  # "which is bigger, the table or the sofa?", "what's the tallest thing here?"
    if _has(j, r"^(?:is|are|was|were) (?!there\b)") and _has(j, _VIEW_RX) and n_obj >= 2:
        return "view_direction"  # "is the chair to the left of the table?": as seen from the camera
    if _has(j, r"^(?:is|are|was|were) (?!there\b)") and _has(j, rf"\b{_LOCATED}\b") and n_obj >= 2:
        return "relation"  # "is the cup on the table?": an is-there question with a location
    if _has(j, r"^(?:what|what's|which (?:objects|things|items))(?: is| are|'s)? (?:to the |on the )?(?:left|right)"
               r"(?: hand side| side)? of\b|^(?:what|what's|which (?:objects|things|items))(?: is| are|'s)? "
               r"(?:behind|in front of)\b(?! me\b)"):
        return "view_list"  # as the viewer (the last camera) sees them
    if _has(j, _WHAT_AT_RX) or _has(j, r"^(?:what|which \w+) (?:do|can|did|could) (?:you|i|we) (?:see|spot|notice)\b"):
        return "list"  # "what's on the table?", "what is near the door?", "what do you see?"
    for intent, rx in _SIMPLE_INTENTS:
        if rx.search(j) and not (intent == "existence" and _has(j, r"^(?:where|where's)\b")):
            return intent  # "where can I find the bin?" asks where, not whether
    if _has(j, r"\b(?:where|whereabouts|locate|location of|position of)\b|^(?:show me|find|point (?:me )?to)\b|"
               r"\bwhich way (?:is|to)\b|\bhow (?:do|can|could) (?:i|we) (?:get|go|walk) to\b|\bhow to get to\b|"
               r"\b(?:guide|take|lead) me to\b|\bdirections? to\b"):
        return "direction" if _has(j, r"\b(?:if i|standing|when i)\b") and stance else "where"
    if _has(j, r"\b(?:list|enumerate|inventory)\b|\b(?:what|which) (?:objects|things|items|furniture)\b|"
               r"\bwhat (?:are|is) the (?:objects|things|items|furniture)\b|"
               r"\bwhat(?:'s| is| are) (?:in|there)\b|\bwhat do you see\b|\bwhat can you see\b"):
        return "list"
    if _has(j, _MY_SIDE_RX):
        if _has(j, r"^(?:what|what's|which (?:objects|things|items))\b") and n_obj == 0:
            return "list"  # "what is to my left?": every object on that side of the viewer (the last camera)
        return "direction"
    return None


# "on my left", "to my right", "behind me", "in front of me" -> the side asked (`_my_side`)
_MY_SIDE_RX = r"\b(?:on|to) my (left|right|back|front)\b|\b(behind) me\b|\b(in front of|ahead of) me\b"


def _my_side(joined: str) -> str | None:
    """The side of the viewer a question asks about: left | right | back | front (None: none named)."""
    m = re.search(_MY_SIDE_RX, joined)
    if m is None:
        return None
    w = next(g for g in m.groups() if g)
    return {"behind": "back", "in front of": "front", "ahead of": "front"}.get(w, w)


def _refs(pq: ParsedQuestion, nps: list[dict[str, Any]]) -> list[str]:
    """Record each phrase: its name (vocabulary name, else the phrase itself), the question's words, selectors,
    unknown names. Returns the names in order."""
    names = []
    for p in nps:
        phrase = " ".join(p["words"])
        canon = canonical_name(phrase)
        name = canon or name_key(phrase)
        if canon is None:
            pq.unknown.append(phrase)
        pq.phrases.setdefault(name, phrase)
        if p["sel"]:
            pq.selectors[name] = {"words": p["sel"], "phrase": " ".join(p["sel"] + p["words"])}
        if p.get("attach") is not None:
            pq.selectors.setdefault(name, {})["near"] = p["attach"]
        names.append(name)
    return names


def _attachments(toks: list[str], nps: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """"the chair nearest (to) the door", "the lamp next to the bed": the second phrase selects among the first's
    instances; returns the phrases that remain (attached ones folded into their owner's `attach`)."""
    out: list[dict[str, Any]] = []
    for p in nps:
        if out:
            prev = out[-1]
            gap = [t for t in toks[prev["end"]:p["start"]] if t not in _DET]
            if gap and gap[0] in _NEAR_CUES and all(t in _NEAR_CUES | {"to", "the", "one", "from"} for t in gap) \
                    and len(gap) <= 3 and prev.get("attach") is None:
                prev["attach"] = canonical_name(" ".join(p["words"])) or name_key(" ".join(p["words"]))
                prev["attach_phrase"] = " ".join(p["words"])
                continue
        out.append(p)
    return out


_TRIGGERS = {"count": {"many", "count", "number", "quantity", "total"},
             "size": {"big", "large", "long", "tall", "wide", "high", "deep", "size", "dimension", "dimensions",
                      "length", "height", "width", "depth", "measure", "longest", "biggest", "largest"},
             "existence": {"there", "see", "spot", "find", "notice", "have", "contain", "any", "exist", "exists"},
             "where": {"where", "where's", "locate", "location", "position", "whereabouts"}}


class _Refused(Exception):
    """Raised by a parse step that refused the question (`_refuse`: its `notes` say why)."""


def _refuse(pq: ParsedQuestion, understood: str, missing: str) -> None:
    _fail(pq, understood, missing)
    raise _Refused


def parse_natural(question: str, options: list[str] | None = None) -> ParsedQuestion:
    """Parse a natural English question (see the module docstring). `question` is already cleaned
    (`grounding.parse_question`); the result's qtype is None when the intent or its objects are not understood,
    with `notes` saying what was understood and what was not."""
    pq = ParsedQuestion(None, question=question, options=list(options) if options is not None else None,
                        how="natural")
    try:
        _parse_into(pq, options)
    except _Refused:
        pass
    if pq.qtype is None:
        pq.how = "none"
        return pq
    pq.targets = list(dict.fromkeys(pq.targets))
    pq.cues = [c for c in dict.fromkeys(pq.cues) if c not in pq.targets]
    for sel in pq.selectors.values():  # attached objects are needed to resolve the selector
        if sel.get("near") and sel["near"] not in pq.targets:
            pq.cues.append(sel["near"])
    pq.unknown = list(dict.fromkeys(pq.unknown))
    return pq


_HANDLERS: dict[str, Callable[..., None]] = {}  # intent -> handler(pq, toks, joined, nps, extra), filled below


def _parse_into(pq: ParsedQuestion, options: list[str] | None) -> None:
    """The parse steps, each refusing (`_Refused`) rather than dropping a word it cannot apply."""
    joined, extra = _strip_preamble(" ".join(tokens(pq.question)))
    toks = _resolve_pronouns(pq, joined.split())
    if toks is None:
        raise _Refused
    joined = " ".join(toks)
    _refuse_whole_text(pq, joined, bool(options))
    nps_all = [p for p in noun_phrases(toks) if not p["scene"]]
    intent = _intent(joined, len(nps_all), bool(options))
    if intent is None:
        pq.notes.append("no question type recognised (counting, count comparison, existence, size, size comparison, "
                        "distance, nearest, direction, left-of / behind, where, list, room size, appearance order)")
        raise _Refused
    nps = _attachments(toks, nps_all) if intent not in ("rel_distance", "direction") else nps_all
    first = next((i for i, t in enumerate(toks) if t in _TRIGGERS.get(intent, ())), None)
    if first is not None:  # "Quick question: how many chairs ...": the object comes after the question's cue
        nps = [p for p in nps if p["start"] > first] or nps
    kind = f"{'an' if intent[0] in 'aeiou' else 'a'} {intent.replace('_', ' ')} question"
    used = {w for sel in (p["sel"] for p in nps_all) for w in sel}
    ordinal = [w for w in toks if w in _RANKS and w not in used]
    if ordinal:  # "the second closest object": a rank the reasoner does not compute; never dropped silently
        _refuse(pq, kind, f"the rank '{ordinal[0]}' (only the nearest / farthest or one object at a time)")
    cut = re.search(_EXCEPT_RX, joined)
    exclude = [p for p in nps if cut and p["start"] >= len(joined[:cut.start()].split())]
    _HANDLERS[intent](pq, toks, joined, [p for p in nps if p not in exclude], extra)
    if exclude and pq.qtype is not None:  # "closest to the sofa, apart from the bin": those leave the candidates
        if pq.qtype != "object_nearest":  # never answered as if the exception had not been said
            _refuse(pq, kind, f"the exception '{cut.group(0)} {' '.join(exclude[0]['words'])}' (only 'what is "
                              f"nearest to X, apart from Y?' takes one)")
        pq.params["exclude"] = _refs(pq, exclude)
    negation = _unread_negation(pq, toks)
    if negation and pq.qtype is not None:  # never answer the question without its "not"
        _refuse(pq, kind, f"the negation '{negation}' (ask it without: e.g. 'is there a ...?', 'how many ... are on "
                          f"the ...?')")


def _refuse_whole_text(pq: ParsedQuestion, joined: str, has_opts: bool) -> None:
    """Refuse a place in the room as a location, and several questions in one text."""
    region = re.search(_ROOM_REGION_RX, joined)
    if region:  # "is the table in the middle of the room?": not an object called "middle"; never guessed
        _refuse(pq, "a position in the room", f"'{region.group(0)}' (the map reasoner places objects relative to "
                                              f"other objects or to you, not to parts of the room)")
    several = _several_questions(joined, has_opts)
    if several:  # "how many chairs and how far is the sofa?": never one answer for two questions
        _refuse(pq, f"several questions in one ({several})", "which one to answer: ask them one at a time")


_EXCEPT_RX = r"\b(?:apart from|aside from|except(?: for)?|other than|besides|excluding|not counting|but not)\b"


def _several_questions(joined: str, has_opts: bool) -> str | None:
    """The kinds of question asked when a text asks several of different kinds ("how many chairs? where is the
    sofa?", "how many chairs and how far is the sofa?"), else None (one question, or several counts)."""
    parts = [c for c in re.split(r"\?|\band (?=(?:how|what|what's|where|where's|which)\b)", joined) if c.strip()]
    if len(parts) < 2:  # one clause: one question (its intent is found once, by the caller)
        return None
    kinds = []
    for c in parts:
        n = len([p for p in noun_phrases(c.split()) if not p["scene"]])
        k = _intent(c.strip(), n, has_opts) if n else None  # "..., how many exactly?" names nothing: a follow-up
        kinds += [k] if k else []
    return " and ".join(dict.fromkeys(k.replace("_", " ") for k in kinds)) if len(set(kinds)) > 1 else None


_NEGATIONS = {"not", "no", "none", "never", "without", "nothing", "nobody", "neither", "nor"}
# a negative question asks the same as the positive one ("isn't there a chair?" = "is there a chair?")
_NEGATIVE_QUESTION = {"isn't", "aren't", "doesn't", "don't", "didn't", "wasn't", "weren't", "can't", "won't"}


def _unread_negation(pq: ParsedQuestion, toks: list[str]) -> str | None:
    """A negation the parse did not use ("is there no laptop?", "which chair is not near the desk?"), or None.
    Read: "not" before a location the parse negated ("cups not on the table"); "yes or no"; "whether or not";
    a negative question form at the start ("isn't there a chair?")."""
    where = pq.params.get("where") if isinstance(pq.params, dict) else None
    words = re.sub(r"\byes or no\b|\bor not\b|\bnot only\b|\bno more than\b|\bnot more than\b", " ",
                   " ".join(toks)).split()
    found = [t for t in words if t in _NEGATIONS or (t.endswith("n't") and t not in _NEGATIVE_QUESTION)]
    found += [t for t in words[1:] if t in _NEGATIVE_QUESTION]  # "how many aren't ...": not a question form
    if "not" in found and isinstance(where, dict) and where.get("negate"):
        found.remove("not")
    return found[0] if found else None


def _fail(pq: ParsedQuestion, understood: str, missing: str) -> None:
    pq.qtype = None
    pq.notes.append(f"understood: {understood}; not understood: {missing}")


def _single(pq: ParsedQuestion, nps: list[dict[str, Any]], what: str, qtype: str, allow_extra: bool = False) -> str | None:
    if not nps:
        _fail(pq, what, "which object it is about")
        return None
    names = _refs(pq, nps)
    if len(names) > 1 and not allow_extra:
        extra = ", ".join(f"'{pq.phrase(n)}'" for n in names[1:])
        pq.notes.append(f"{extra}: a location or condition that cannot be applied to a {what}")
        _fail(pq, f"a {what} of '{pq.phrase(names[0])}'", f"what {extra} means for it")
        return None
    pq.qtype = qtype
    return names[0]


_LOCATION = {"on", "in", "at", "near", "by", "under", "behind", "beside", "above", "below", "inside", "against",
             "around", "next", "between", "over", "beneath", "underneath", "along", "across", "close"}


# "A is left of / in front of / behind B" without a stance: as the viewer (the last camera) sees them
_VIEW_RX = r"\b(?:(?:to|on|at) the (?:left|right)(?: hand side| side)? of|left of|right of|in front of|behind)\b"
_VIEW_WORDS = {"left": "left", "right": "right", "front": "front", "behind": "back"}
# location words the map reasoner can apply to a count or an is-there question (`answer.relation_holds`)
_RELATION_WORDS = {"on": "on", "atop": "on", "onto": "on", "upon": "on", "near": "near", "by": "near",
                   "beside": "near", "around": "near", "in": "in", "inside": "in", "within": "in",
                   "under": "under", "below": "under", "beneath": "under", "underneath": "under",
                   "above": "above", "over": "above", "between": "between"}
_TESTED = "on, near, in, under and above one object, or between two"  # the relations, in words
# any location word, as a regex alternation for the intents: tested by the map, or refused naming it
_LOCATED = "(?:" + "|".join(sorted(_LOCATION | set(_RELATION_WORDS))) + ")"
_WHAT_AT_RX = (rf"^(?:what|what's|which (?:objects|things|items))(?: is| are| was| were|'s)? (?:there )?(?:sitting |"
               rf"lying |standing |placed |kept |stored |located |hanging |resting )?{_LOCATED}\b")


# a pronoun after a location ("the chairs next to it") stands for an object named earlier: resolved or refused
_PRONOUNS = {"it", "them", "that", "this", "those", "these"}
# the words a located pronoun may follow: every location word the parser tests or refuses, and the selectors'
# closeness words ("nearest (to) it"); left / right / front of a stance question are `_stance`'s
_PRONOUN_CUES = _LOCATION | set(_RELATION_WORDS) | _NEAR_CUES | {"top"}


def _location_start(toks: list[str], i: int) -> int | None:
    """Where the location words before token i begin ("next to it", "on top of it", "near it"), or None when
    token i does not follow a location word."""
    k = i - 1
    if k >= 1 and toks[k] in ("to", "of"):
        k -= 1
    if k < 0 or toks[k] not in _PRONOUN_CUES:
        return None
    return k - 1 if toks[k] == "top" and k >= 1 and toks[k - 1] == "on" else k


def _antecedents(toks: list[str], i: int, loc: int) -> list[dict[str, Any]]:
    """The object phrases before the located pronoun at token i that it can stand for: not a room word, and not
    the phrase the location describes ("the chairs (are) next to it": the chairs are not next to themselves)."""
    before = [p for p in noun_phrases(toks[:loc]) if not p["scene"]]
    if before and all(t in _COPULA | _DET for t in toks[before[-1]["end"]:loc]):
        before.pop()
    return before


def _resolve_pronouns(pq: ParsedQuestion, toks: list[str]) -> list[str] | None:
    """The tokens with each located pronoun replaced by the one object named before it ("the chairs next to it"
    -> "the chairs next to the desk"), so the explicit phrase's reading applies; None (the question refused,
    `pq.notes` say why) when no single object is named before it: a location is never dropped silently."""
    for i, t in enumerate(toks):
        loc = _location_start(toks, i) if t in _PRONOUNS else None
        if loc is None or (i + 1 < len(toks) and _is_content(toks, i + 1, False)):  # "next to that desk"
            continue
        cands = _antecedents(toks, i, loc)
        if len(cands) != 1:
            named = [" ".join(toks[p["start"]:p["end"]]) for p in cands]
            why = f"it could be the {' or the '.join(named)}; say e.g. '{' '.join(toks[loc:i])} the {named[-1]}'" \
                if named else "no object is named before it; name the object instead"
            _fail(pq, f"the location '{' '.join(toks[loc:i + 1])}'", f"which object '{t}' is ({why})")
            return None
        p = cands[0]
        return _resolve_pronouns(pq, toks[:i] + ["the"] + toks[p["start"]:p["end"]] + toks[i + 1:])
    return toks


def _relation(toks: list[str], p: dict[str, Any]) -> str | None:
    """The relation the words before a phrase name ("on (top of)", "near / next to / close to / by", "in"),
    or None."""
    b = _before(toks, p, 3)
    if b[-2:] == ["top", "of"]:
        return "on"
    if b[-2:] in (["next", "to"], ["close", "to"]):
        return "near"
    return _RELATION_WORDS.get(b[-1]) if b else None


def _conditions(toks: list[str], nps: list[dict[str, Any]], every: bool = False
                ) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """Split phrases into the objects asked about and the ones after a location word ("on the desk"); every:
    the question asks about every object ("things on the desk"), so a first phrase can be a location too."""
    objs, conds = [], []
    for p in nps:
        if p["words"] == ["top"] and toks[p["end"]:p["end"] + 1] == ["of"]:
            continue  # "on top of the desk": part of the location words, not an object
        b = _before(toks, p, 1)
        located = bool(b) and (b[-1] in _LOCATION or _relation(toks, p) is not None)
        if conds and b == ["and"] and _relation(toks, conds[-1]) == "between":
            located = True  # "between the desk and the couch": both phrases are the location
        (conds if (objs or every) and located else objs).append(p)
    return objs, conds


def _location(pq: ParsedQuestion, toks: list[str], objs: list[dict[str, Any]], conds: list[dict[str, Any]]
              ) -> dict[str, Any] | None:
    """{"relation", "object"} of a single supported location ("cups on the table"; "between" also names
    "object2"); None when it is not one."""
    two = len(conds) == 2 and _relation(toks, conds[0]) == "between"
    rel = _relation(toks, conds[0]) if (len(conds) == 1 or two) and len(objs) <= 1 else None
    if rel is None or (rel == "between") != two:
        return None
    refs = _refs(pq, conds)
    where = {"relation": rel, "object": refs[0], **({"object2": refs[1]} if two else {})}
    if "not" in _before(toks, conds[0], 5)[:-1]:  # "cups not on the table": the others
        where["negate"] = True
    return where


def where_objects(where: dict[str, Any]) -> list[str]:
    """The reference objects of a location: one, or two for "between"."""
    return [where[k] for k in ("object", "object2") if where.get(k)]


def _attached_near(pq: ParsedQuestion, joined: str, objs: list[dict[str, Any]]) -> dict[str, Any] | None:
    """"chairs near / by / next to the door" read as a selector by `_attachments`: for a count it is a location
    (a superlative, "the chair nearest the door", stays a selector: one instance)."""
    if len(objs) != 1 or objs[0].get("attach") is None or _has(joined, _CLOSE + "|" + _FAR):
        return None
    ref = objs[0].pop("attach")
    pq.phrases.setdefault(ref, objs[0].pop("attach_phrase"))
    return {"relation": "near", "object": ref}


# "how many legs does the chair have?": parts of an object, which the map does not hold
_PARTS_RX = re.compile(r"^how many ([a-z' -]+?) (?:does|do|did) (?:the|this|that|a|an|each|every|your|my|our) "
                       r"([a-z' -]+?) (?:have|has|got)\b")


def _count(pq, toks, joined, nps, extra) -> None:
    if _has(joined, r"^how many (?:steps|paces|strides) (?:to|until|till|away|from|is it)\b"):
        return _fail(pq, "a walking distance in steps", "steps: the map measures in metres; ask 'how far am I "
                                                        "from the ...?'")
    m = _PARTS_RX.search(joined)
    if m and not set(m.group(2).split()) & _SCENE:  # "how many chairs does the kitchen have?" is a count
        return _fail(pq, f"a count of the {m.group(1)} of the {m.group(2)}", "parts of an object: the map holds "
                                                                          "whole objects, not their parts")
    every = _has(joined, r"\b(?:objects|things|items|pieces of furniture)\b")
    if not nps and every:
        pq.qtype, pq.params = "object_counting", {"object": "*"}  # every object in the map
        return
    objs, conds = _conditions(toks, nps, every)
    where = _location(pq, toks, objs, conds) if conds else _attached_near(pq, joined, objs)
    if where is not None:  # "how many cups are on the table?", "how many things are near the door?"
        target = _refs(pq, objs)[0] if objs else "*"
        pq.qtype, pq.targets, pq.cues = "object_counting", [target] if objs else [], where_objects(where)
        pq.params = {"object": target, "where": where}
        return
    if len(objs) > 1 and conds:  # "how many chairs are on the desk and the couch?": never drop the location
        return _fail(pq, "a count of " + " and ".join(f"'{' '.join(p['words'])}'" for p in objs),
                     "several objects with a location; ask about one object at a time")
    if len(objs) > 1:  # "how many chairs and (how many) cups are there?": one count per object
        names = list(dict.fromkeys(_refs(pq, objs)))
        pq.qtype, pq.targets, pq.params = "object_counting", names, {"object": names[0], "objects": names}
        return
    n = _single(pq, objs + conds, "count", "object_counting")
    if n is not None:
        pq.targets, pq.params = [n], {"object": n}


def _view_direction(pq, toks, joined, nps, extra) -> None:
    """"Is the chair to the left of the table?", "is the cup behind the tv?": no stance named, so as the viewer
    sees them (from the last camera, looking at the second object): params object, reference, asked
    (left|right|front|back)."""
    names = _refs(pq, nps)
    if len(names) != 2:
        return _fail(pq, "a left-of / in-front-of question", "exactly two objects (e.g. 'is the chair to the left "
                                                             "of the table?')")
    word = re.search(r"\b(left|right|front|behind)\b", joined).group(1)
    pq.qtype, pq.targets = "object_view_direction", names
    pq.params = {"object": names[0], "reference": names[1], "asked": _VIEW_WORDS[word]}


def _view_list(pq, toks, joined, nps, extra) -> None:
    """"What is to the left of the couch?", "what's behind the desk?": every object there as the viewer (the last
    camera) sees them (params view {reference, asked})."""
    n = _single(pq, nps, "what-is-there question", "object_list")
    if n is not None:
        word = re.search(r"\b(left|right|front|behind)\b", joined).group(1)
        pq.cues, pq.params = [n], {"objects": [], "view": {"reference": n, "asked": _VIEW_WORDS[word]}}


def _count_compare(pq, toks, joined, nps, extra) -> None:
    """"Are there more chairs than cups?" (yes or no), "which are there fewer of, cups or chairs?" (a name), "how
    many more chairs than cups are there?" (the difference): params objects [2 names], compare more|fewer, form
    yesno|which|difference."""
    names = _option_names(pq) or _refs(pq, nps)
    if len(names) != 2:
        return _fail(pq, "a more-or-fewer question", "exactly two objects to count against each other, without a "
                                                     "location (e.g. 'are there more chairs than tables?')")
    form = "difference" if _has(joined, r"\bhow many (?:more|fewer|less)\b") else \
        "yesno" if "than" in toks and not _has(joined, r"^(?:which|what|whichever)\b") else "which"
    pq.qtype, pq.targets = "object_count_compare", names
    more = _has(joined, r"\bmore\b|\b(?:greater|larger|bigger|higher)\b")
    pq.params = {"objects": names, "compare": "more" if more else "fewer", "form": form}


_NUMBERS = {w: i for i, w in enumerate("zero one two three four five six seven eight nine ten eleven twelve".split())}
_COUNT_OPS = {"more than": ">", "over": ">", "at least": ">=", "fewer than": "<", "less than": "<", "under": "<",
              "at most": "<=", "exactly": "==", "only": "==", "just": "=="}
_COUNT_RX = re.compile(r"^(?:is|are) there (?:(" + "|".join(_COUNT_OPS) + r") )?(\d+|" + "|".join(_NUMBERS) + r")\b")


def _count_condition(joined: str) -> dict[str, Any] | None:
    """"are there two chairs?" -> {"op": "==", "n": 2}; "is there more than one cup?" -> {">", 1}; else None."""
    m = _COUNT_RX.search(joined)
    if m is None:
        return None
    n = int(m.group(2)) if m.group(2).isdigit() else _NUMBERS[m.group(2)]
    return {"op": _COUNT_OPS.get(m.group(1) or "exactly"), "n": n}


def _existence(pq, toks, joined, nps, extra) -> None:
    """"Is there a fridge?", "is there a cup on the table?", "is the cup on the table?" (the same question),
    "is there anything on the chair?" (every object: "*")."""
    if not nps:
        return _fail(pq, "an is-there question", "which object it is about")
    every = _has(joined, r"\b(?:anything|something|any ?things?|objects|things|items|stuff)\b")
    objs, conds = _conditions(toks, nps, every)
    rel = _location(pq, toks, objs, conds) if conds and (objs or every) else None
    rel = rel or _attached_near(pq, joined, objs)  # "is there a chair near the table?" (read as a selector)
    count = _count_condition(joined)  # "are there two chairs?": a count, not "is there a chair?"
    if count is not None and len(objs) > 1:
        return _fail(pq, "an are-there-N question", "one object to count (e.g. 'are there two chairs?')")
    if count is not None and objs and len(objs[0]["words"]) > 1 and objs[0]["words"][0] in _NUMBERS:
        objs[0] = {**objs[0], "words": objs[0]["words"][1:]}  # "two chairs": the object is "chairs"
    if rel is not None:  # "is there a cup on the table?"
        names = _refs(pq, objs) if objs else ["*"]
        pq.qtype, pq.targets, pq.cues = "object_existence", names, where_objects(rel)
        pq.params = {"objects": names, "all": False, "where": rel, **({"count": count} if count else {})}
        return
    if conds:
        where = ", ".join(" ".join(_before(toks, p, 1) + p["words"]) for p in conds)
        about = ", ".join(f"'{' '.join(p['words'])}'" for p in objs) or "anything"
        ask = (f"'is there a {' '.join(objs[0]['words'])} on the ...?' or 'where is the "
               f"{' '.join(objs[0]['words'])}?'") if objs else f"'what is on / near the {' '.join(conds[0]['words'])}?'"
        return _fail(pq, f"an is-there question about {about}", f"the location ('{where}'): the map tests {_TESTED}; "
                                                                f"ask {ask}")
    names = _refs(pq, objs)
    pq.qtype = "object_existence"
    pq.targets, pq.params = names, {"objects": names, "all": " and " in f" {joined} "}
    if count is not None:
        pq.params["count"] = count


def _size(pq, toks, joined, nps, extra) -> None:
    sup = next((t for t in toks if t in SUPERLATIVES), None)
    if not nps and sup and _has(joined, r"\b(?:object|thing|item|furniture|piece)\b"):
        pq.qtype = "object_size_compare"  # "how tall is the tallest object?": which one, and its measure
        pq.params = {"measure": sup, "candidates": "*", "yesno": False, "with_value": True}
        return
    n = _single(pq, nps, "size question", "object_size_estimation")
    if n is None:
        return
    if _has(joined, _ELEVATION_RX):
        dim = "elevation"  # "how high above the floor is the lamp?": its bottom over the floor
    elif _has(joined, r"\bvolume\b"):
        dim = "volume"
    elif (_has(joined, r"\bdimensions\b|\bmeasurements\b|\bhow (?:long|wide|tall|high|deep) and (?:wide|long|tall|high|"
                     r"deep)\b") and not _has(joined, _SUP_RX + r"|\b(?:maximum|max|greatest)\b")):
        dim = "all"  # "what are the dimensions of the desk?": width x depth x height
    elif _has(joined, r"\b(?:longest|biggest|largest|maximum|max|greatest)\b(?: \w+)? (?:side|dimension|edge|extent|"
                      r"length)|\bsize\b|\bhow (?:big|large)\b|\bdimensions?\b"):
        dim = "longest"
    elif _has(joined, r"\bhow (?:tall|high)\b|\bheight\b|\btall\b"):
        dim = "height"
    elif _has(joined, r"\bhow wide\b|\bwidth\b|\bwide\b"):
        dim = "width"
    elif _has(joined, r"\bhow long\b|\blength\b|\blong\b"):
        dim = "length"
    elif _has(joined, r"\bhow deep\b|\bdepth\b|\bdeep\b"):
        dim = "depth"
    else:
        dim = "longest"
    pq.targets = [n]
    pq.params = {"object": n, "dimension": dim, "unit": "m3" if dim == "volume" else
                 _unit(joined, "m" if dim == "elevation" else "cm")}


def _size_compare(pq, toks, joined, nps, extra) -> None:
    """"Which is bigger, A or B?" / "Is A taller than B?" (yes or no) / "What's the tallest object?" (over the
    whole map) / "Which chair is the tallest?" (one instance of one name): params measure (a `SUPERLATIVES`
    key), candidates (names, or "*" for every object), yesno."""
    word = next(t for t in toks if t in COMPARATIVES or t in SUPERLATIVES)
    sup = COMPARATIVES.get(word, word)
    names = _option_names(pq) or _refs(pq, nps)
    yesno = word in COMPARATIVES and "than" in toks and toks[0] in _COPULA | {"does", "do", "did"}
    diff = word in COMPARATIVES and _has(joined, r"\bhow much\b")
    m = re.search(rf"\b{word} than (?:about |around |roughly )?(\d+(?:\.\d+)?) ?([a-z]+)", pq.question.lower())
    if yesno and len(names) == 1 and m:  # "is the couch longer than 2 m?": against a length
        unit = _UNIT_WORDS.get(m.group(2))
        if unit is None or SUPERLATIVES[sup][0] == "volume":
            return _fail(pq, f"a '{word}' question about '{pq.phrase(names[0])}' and {m.group(1)} {m.group(2)}",
                         "a length to compare with: height, length or width in m, cm, mm, ft or in (e.g. 'is the "
                         "sofa longer than 2 m?')")
        pq.qtype, pq.targets = "object_size_compare", names
        pq.params = {"measure": sup, "candidates": names, "yesno": True,
                     "threshold_m": float(m.group(1)) * UNIT_M[unit], "threshold_text": f"{m.group(1)} {unit}"}
        return
    if ((yesno or diff) and len(names) != 2) or (word in COMPARATIVES and len(names) < 2):
        about = f" about '{pq.phrase(names[0])}'" if names else ""
        return _fail(pq, f"a '{word}' question{about}", "the two objects to compare (e.g. 'is the tv bigger than "
                                                        "the lamp?', 'which is taller, the fridge or the door?')")
    pq.qtype = "object_size_compare"
    pq.targets = names
    pq.params = {"measure": sup, "candidates": names or "*", "yesno": yesno}
    if diff:  # "how much taller is A than B?": A's measure minus B's, in the asked unit
        pq.params["difference"] = True
        if SUPERLATIVES[sup][0] != "volume":
            pq.params["unit"] = _unit(joined, "cm")


def _room_size(pq, toks, joined, nps, extra) -> None:
    """Floor area; "how long / wide is the room?", "the room's dimensions" (params dimension: the sides of the
    extent's smallest enclosing rectangle); "is the room bigger than 20 square meters?" (params than_m2)."""
    pq.qtype = "room_size_estimation"
    unit = "ft2" if _has(joined, r"square (?:feet|foot)|sq ?ft") else "m2"
    pq.params = {"unit": unit}
    dim = re.search(r"\bhow (long|wide) is\b|\b(length|width|dimensions?|measurements?) of\b", joined)
    if dim:
        word = dim.group(1) or dim.group(2)
        pq.params = {"dimension": {"long": "length", "wide": "width"}.get(word, word if word in ("length", "width")
                                                                           else "all"), "unit": _unit(joined, "m")}
    m = re.search(r"\b(bigger|larger|smaller) than (?:about |around )?(\d+(?:\.\d+)?)", pq.question.lower())
    if m and toks[0] in _COPULA:
        pq.params["than"] = {"op": "<" if m.group(1) == "smaller" else ">", "value": float(m.group(2))}


def _abs_distance(pq, toks, joined, nps, extra) -> None:
    """"How far is the table from the tv?"; with one object and the asker ("how far am I from the tv?", "how
    far away is the fridge?"): from the viewer, the last camera (params from="camera")."""
    names = _refs(pq, nps)
    if len(names) == 1 and _has(joined, r"\b(?:me|i|i'm|im|myself|us|we|here|the camera)\b|^how far away (?:is|are)\b"):
        pq.qtype, pq.targets = "object_abs_distance", names
        pq.params = {"a": names[0], "b": None, "from": "camera", "unit": _unit(joined, "m")}
        return
    if len(names) == 1 and _has(joined, r"\b(?:two|both)\b|\bapart\b|\b(?:between|from each other|from one "
                                          r"another)\b"):  # "the distance between the two chairs": one pair
        pq.qtype, pq.targets = "object_abs_distance", names
        pq.params = {"a": names[0], "b": names[0], "unit": _unit(joined, "m")}
        return
    pair = _two_names(nps[0]["words"]) if len(nps) == 1 else None
    if pair:  # "distance fireplace sofa?": one phrase that is two names and no name itself
        pq.unknown = [u for u in pq.unknown if u != " ".join(nps[0]["words"])]
        names = _refs(pq, [{**nps[0], "words": w.split(), "sel": []} for w in pair])
    if len(names) != 2:
        got = ", ".join(f"'{pq.phrase(n)}'" for n in names) or "no object"
        return _fail(pq, f"a distance question naming {got}", "exactly two objects to measure between")
    pq.qtype = "object_abs_distance"
    pq.targets = names
    pq.params = {"a": names[0], "b": names[1], "unit": _unit(joined, "m")}
    cond = _distance_condition(pq.question)
    if cond is not None and toks[0] in _COPULA:  # "is the sofa within 2 m of the tv?": yes or no
        pq.params["within"] = cond


def _two_names(words: list[str]) -> tuple[str, str] | None:
    """Two vocabulary names (each exactly a name or a listed synonym) that a phrase which is not itself one
    splits into ("fireplace sofa"), else None ("coffee table" is one name)."""
    def exact(ws: list[str]) -> bool:
        return " ".join(singular(w) for w in ws) in NAME_SYNONYMS or " ".join(ws) in NAME_SYNONYMS

    if len(words) < 2 or exact(words):
        return None
    for k in range(1, len(words)):
        if exact(words[:k]) and exact(words[k:]):
            return " ".join(words[:k]), " ".join(words[k:])
    return None


def _reference_index(toks: list[str], nps: list[dict[str, Any]]) -> int | None:
    """The phrase the distances are measured to: right after a closeness word ("nearest the tv"), or after
    "to/from" following one ("closest to the tv", "farthest away from the bed")."""
    befores = [_before(toks, p, 4) for p in nps]
    for k, before in enumerate(befores):  # first: "the nearest chair to the tv" measures to the tv, not the chair
        if before and before[-1] in ("to", "from") and any(
                re.fullmatch(_CLOSE + "|" + _FAR + r"|\baway\b|\bfar\b|\bapart\b", w) for w in before[:-1]):
            return k
    for k, before in enumerate(befores):
        if before and re.fullmatch(_CLOSE + "|" + _FAR, before[-1]):
            return k
    if re.search(r"\b(?:closest|nearest|closer|nearer|farthest|furthest|farther|further)\b(?: \w+)? (?:to |from )?"
                 r"(?:me|myself|i am|i'm|where i am)\b", " ".join(toks)):
        for k, p in enumerate(nps):  # "if I'm at the stove, which ... is closest to me?"
            before = _before(toks, p, 2)
            if before and (before[-1] in ("at", "by", "beside", "near") or " ".join(before) == "next to"):
                return k
    for k, p in enumerate(nps):  # "what's next to the desk?"
        before = _before(toks, p, 2)
        if before and (before[-1] in ("beside", "near", "by") or " ".join(before[-2:]) == "next to"):
            return k
    for k, p in enumerate(nps):  # "which of these is the closest one? (reference: ... to the tv)"
        before = _before(toks, p, 1)
        if before and before[-1] in ("to", "from"):
            return k
    return None


def _option_names(pq: ParsedQuestion) -> list[str]:
    """The object each of the question's options names (its first object phrase, else its whole text)."""
    cands = []
    for _, text in split_options(pq.options):
        onps = [p for p in noun_phrases(tokens(text)) if not p["scene"]]
        cands.append(_refs(pq, onps[:1])[0] if onps else name_key(text))
    return cands


_VIEWER_REF_RX = (r"\b(?:to|from) (?:me|us|myself|here|the camera)\b|^(?:am|are) (?:i|we)\b|"
                  r"\b(?:i am|i'm|im|we are) (?:closer|nearer|farther|further)\b")


def _rel_distance(pq, toks, joined, nps, extra) -> None:
    far = _has(joined, _FAR + r"|\bfar\b") and not _has(joined, _CLOSE)
    placed = _has(joined, r"\b(?:if|when) (?:i|i'm|im|we)\b|\b(?:i'm|i am|im|standing|sitting|stand|sit) (?:at|by|next "
                          r"to|near|beside|on|in front of)\b")  # "if I'm at the stove, ... closest to me": me = there
    if _has(joined, _VIEWER_REF_RX) and nps and not placed:  # "what's the closest chair to me?", "am I closer to ...?"
        names = _option_names(pq) or _refs(pq, nps)
        extreme = "farthest" if far else "closest"
        if len(names) == 1:  # which instance of one name: the nearest (farthest) one from the viewer
            pq.qtype, pq.targets = "object_abs_distance", names
            pq.params = {"a": names[0], "b": None, "from": "camera", "unit": _unit(joined, "m"), "which": extreme}
        else:
            pq.qtype, pq.targets = "object_rel_distance", names
            pq.params = {"reference": None, "from": "camera", "candidates": names, "extreme": extreme}
        return
    k = _reference_index(toks, nps)
    if k is None:
        return _fail(pq, "a which-is-closest question", "the object the distances are measured to "
                                                         "(e.g. '... closest to the tv')")
    names = _refs(pq, nps)
    ref = names[k]
    cands = _option_names(pq) or [n for i, n in enumerate(names) if i != k]
    extreme = "farthest" if far else "closest"
    pq.cues = [ref]
    if not cands:
        pq.qtype = "object_nearest"
        pq.targets, pq.cues = [], [ref]
        pq.params = {"reference": ref, "extreme": extreme}
        return
    yesno = toks[0] in _COPULA | {"does", "do", "did"} and "than" in toks and len(names) == 3 and not pq.options
    if yesno and _has(joined, r"\bthan (?:to|from)\b"):  # "is the cup closer to the table than to the tv?"
        ref, cands = names[0], names[1:]  # distances from the cup: to the table vs to the tv
    elif toks[0] in _COPULA and len(names) == 3 and "or" in toks and not pq.options and \
            re.fullmatch(_CLOSE + "|" + _FAR, (_before(toks, nps[1], 4)[-2:-1] or [""])[0]):
        ref, cands = names[0], names[1:]  # "is the bin closer to the desk or the couch?": from the bin
    pq.qtype = "object_rel_distance"
    pq.targets = cands
    pq.params = {"reference": ref, "candidates": cands, "extreme": extreme, **({"yesno": True} if yesno else {})}


_FACE1 = {"facing", "face", "faces", "faced", "towards", "toward", "watching"}
_PLACED_VERBS = {"am", "i'm", "im", "standing", "stand", "sitting", "sit", "be", "was", "were", "stood", "sat"}
# "standing by the bed with the sofa in front of me": facing the sofa
_AHEAD_OF_ME = r"(?:in front of|ahead of|before) me\b"  # "with the sofa in front of me"
_IS_AHEAD = r"(?:is|are) (?:straight |directly |right )?(?:ahead|in front of me)\b"  # "the tv is straight ahead"
_FACING_AHEAD_RX = rf"\bwith (?:the |a |an )?[^,?]{{1,40}}? {_AHEAD_OF_ME}|\b{_IS_AHEAD}"
_FACE2 = {"looking at", "look at", "looked at", "staring at", "turned to", "turn to", "direction of", "looking toward",
          "gazing at", "gaze at", "face to", "faced to",
          "look toward", "looking towards", "look towards", "eyes on", "gaze on", "looking over", "pointed at",
          "pointing at", "oriented toward", "oriented towards"}


def _stance(toks: list[str], nps: list[dict[str, Any]]) -> tuple[int | None, int | None, int | None]:
    """Indices of the phrases for where I stand, what I face, and the object a side is relative to."""
    pos = face = rel = None
    for k, p in enumerate(nps):
        b = _before(toks, p, 3)
        last = b[-1] if b else ""
        two = " ".join(b[-2:])
        b4 = _before(toks, p, 4)
        if pos is None and b4[-3:] == ["in", "front", "of"] and len(b4) == 4 and b4[0] in _PLACED_VERBS:
            pos = k  # "I am in front of the desk, facing ...": where I stand, not a side of the desk
            continue
        after = " ".join(toks[p["end"]:p["end"] + 5])
        ahead = re.match(_AHEAD_OF_ME, after) is not None
        ahead_is = re.match(_IS_AHEAD, after) is not None
        if face is None and (last in _FACE1 or two in _FACE2 or (last == "with" and ahead) or ahead_is):
            face = k
            continue
        if rel is None and last == "of" and len(b) >= 2 and b[-2] in ("left", "right", "front", "behind", "back",
                                                                     "side"):
            rel = k
            continue
        seated = last in ("on", "in") and len(b) >= 2 and b[-2] in ("sitting", "sit", "sat", "lying", "standing",
                                                                    "seated")  # "sitting on the couch"
        if pos is None and (last in ("by", "at", "beside", "near", "from") or seated or
                            two in ("next to", "close to", "front of", "from where", "position is", "location is",
                                    "place is", "spot is", "position were", "position was", "location were")):
            pos = k
    return pos, face, rel


def _direction(pq, toks, joined, nps, extra) -> None:
    pos, face, rel = _stance(toks, nps)
    names = _refs(pq, nps)
    rest = [k for k in range(len(nps)) if k not in (pos, face, rel)]
    by_order = pos is None and face is not None and len(rest) >= 2 and nps[rest[0]]["start"] < nps[face]["start"]
    if by_order:  # "my spot is the stove and I look at the tv, is the sofa ...": the object named before what I face
        pos, rest = rest[0], rest[1:]
        pq.params["position_by_order"] = True
    side = _my_side(joined)
    if pos is not None and face is not None and not rest and side and _has(joined, r"\b(?:what|what's|which)\b"):
        pq.qtype, pq.cues = "object_list", [names[pos], names[face]]  # "..., what is on my left?": every object
        pq.params = {"objects": [], "from_stance": {"position": names[pos], "facing": names[face], "side": side}}
        return
    if pos is None or face is None or not rest:
        have = {"where I stand": pos, "what I face": face, "the object asked about": rest[0] if rest else None}
        got = [f"{k} = '{pq.phrase(names[v])}'" for k, v in have.items() if v is not None]
        miss = [k for k, v in have.items() if v is None]
        return _fail(pq, "a direction question" + (f" ({', '.join(got)})" if got else ""), ", ".join(miss) +
                     " (say e.g. 'standing by the sofa facing the tv, is the lamp to my left?')")
    query = names[rest[0]]
    if len(rest) > 1:  # "what's on my right: the radiator or the laptop?"
        pq.params["candidates"] = [names[k] for k in rest]
    opts = split_options(pq.options)
    asked = [d for _, t in opts for d in direction_words(t)[:1]] if opts else direction_words(
        " ".join(t for i, t in enumerate(toks) if not any(p["start"] <= i < p["end"] for p in nps)))
    if any(d in QUADRANTS for d in asked) or "quadrant" in toks:  # "which quadrant is the lamp in?"
        level = "hard"
    elif "back" in asked:
        level = "medium"
    elif opts or len(set(asked)) > 1:
        level = "easy"
    else:
        level = "free"
    if not opts and len(set(asked)) <= 1 and "quadrant" not in toks:  # "is the lamp on my left?": yes/no or words
        level = "free"
    pq.params = {"position": names[pos], "facing": names[face], "query": query, **extra, **pq.params}
    if rel is not None:
        pq.params["relative_to"] = names[rel]
    pq.targets, pq.cues = pq.params.get("candidates", [query]), [names[pos], names[face]]
    if pq.params.get("candidates") and not opts:
        level = "free"
    if level == "free":
        pq.qtype = "object_direction"
        pq.params["asked"] = list(dict.fromkeys(asked))
    else:
        pq.qtype = f"object_rel_direction_{level}"


def _where(pq, toks, joined, nps, extra) -> None:
    """"Where is the printer?"; "where is the printer relative to / in relation to the desk?" (params
    relative_to: that object first among the landmarks)."""
    if len(nps) == 2 and _before(toks, nps[1], 2) in (["relative", "to"], ["relation", "to"], ["respect", "to"],
                                                      ["regard", "to"], ["compared", "to"]):
        names = _refs(pq, nps)
        pq.qtype, pq.targets, pq.cues = "object_where", names[:1], names[1:]
        pq.params = {"object": names[0], "relative_to": names[1]}
        return
    n = _single(pq, nps, "where-is question", "object_where")
    if n is not None:
        pq.targets, pq.params = [n], {"object": n}


def _list(pq, toks, joined, nps, extra) -> None:
    """"What objects are in the room?", "list the chairs", "what's on the table?" (every object on it), "what
    is to my left?" (every object on that side of the viewer)."""
    side = _my_side(joined)
    if side is not None and not nps:
        pq.qtype, pq.params = "object_list", {"objects": [], "from_viewer": side}
        return
    if nps and _has(joined, r"^(?:what|what's|which)\b"):
        objs, conds = _conditions(toks, nps, every=True)
        if conds and (not objs or _has(joined, _WHAT_AT_RX)):  # what is there at one place: nothing else named
            where = _location(pq, toks, objs, conds) if not objs else None
            if where is None:  # "under the desk", "between the desk and the couch"
                words = " ".join(_before(toks, conds[0], 1) + conds[0]["words"])
                return _fail(pq, "a what-is-there question", f"the location '{words}' (the map tests {_TESTED})")
            pq.qtype, pq.cues = "object_list", where_objects(where)
            pq.params = {"objects": [], "where": where}
            return
    names = _refs(pq, nps)
    pq.qtype = "object_list"
    pq.targets = names
    pq.params = {"objects": names}


def _order(pq, toks, joined, nps, extra) -> None:
    names = _refs(pq, nps)
    opts = split_options(pq.options)
    if len(names) < 2 and opts:  # "in which order did these appear?" with the orders as options
        names = list(dict.fromkeys(n for _, t in opts for n in _refs(pq, [p for p in noun_phrases(tokens(t))
                                                                            if not p["scene"]])))
    if len(names) < 2:
        return _fail(pq, "an appearance-order question", "at least two objects to order")
    pq.qtype = "obj_appearance_order"
    pq.targets = names
    pq.params = {"categories": names}


_HANDLERS.update({"count": _count, "count_compare": _count_compare, "existence": _existence, "relation": _existence,
                  "view_direction": _view_direction, "view_list": _view_list, "size": _size,
                  "size_compare": _size_compare, "room_size": _room_size, "abs_distance": _abs_distance,
                  "rel_distance": _rel_distance, "direction": _direction, "where": _where, "list": _list,
                  "obj_appearance_order": _order})
