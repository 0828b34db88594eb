"""A question as people type it -> the words the rule parser knows, each change said in a note.

`normalize(text, names)` runs, in order: unicode punctuation (quotes, dashes, ellipsis, superscripts) and lower
case; texting shorthand (`SHORTHAND`); spelling against the parser's closed vocabulary (`spelling.correct`:
object names and synonyms, the map's names, cue words, markers, units); phrase synonyms (`PHRASES`: units such as
"sq ft" / "m²" / "square footage", cue words such as "tally" / "clearance" / "end to end"); numbers said in words
before a unit ("two metres", "a dozen"). Every spelling change is a note ("read 'chiars' as 'chairs'") that the
answer repeats; shorthand, punctuation and synonyms are not notes (they change no word's meaning).

All tables are data; this module holds no rule of what a question means (that is `rules/`).
"""
from __future__ import annotations

import re
from typing import Iterable

from .spelling import correct
from .vocabulary import NAME_SYNONYMS, singular

# unicode punctuation people's phones type -> ASCII
_UNICODE = {"\u2018": "'", "\u2019": "'", "\u201a": "'", "\u2032": "'", "\u201c": '"', "\u201d": '"', "\u201e": '"',
            "\u2033": '"', "\u2013": " - ", "\u2014": " - ", "\u2015": " - ", "\u2012": " - ", "\u2212": "-",
            "\u2026": " ... ", "\u00a0": " ", "\u00b2": "2", "\u00b3": "3", "\u00d7": " x "}

# texting shorthand: whole words only (never inside a word)
SHORTHAND = {"hw": "how", "u": "you", "ur": "your", "r": "are", "n": "and", "wat": "what", "wot": "what",
             "whats": "what's", "thx": "thanks", "pls": "please", "plz": "please", "eachother": "each other",
             "b4": "before", "2nd": "second", "abt": "about", "btw": "by the way", "dunno": "do not know"}

# phrase synonyms (regex over the lower-case, spelled text -> the parser's own words). Units first, then cues.
PHRASES: list[tuple[str, str]] = [
    # areas
    (r"\b(?:m2|m\^2|sq\.? ?m|sqm|sq\.? ?met(?:er|re)s?|square met(?:er|re)s?|meters? squared|metres? squared)(?![a-z])",
     "square meters"),
    (r"\b(?:ft2|ft\^2|sq\.? ?ft|sqft|sq\.? ?f(?:ee|oo)t|square f(?:ee|oo)t(?:age)?|feet squared)(?![a-z])",
     "square feet"),
    (r"\barea-?wise\b", "in area"),
    (r"\bhow (?:spacious|roomy|sizeable|sizable)\b", "how big"),
    # idioms of not knowing that carry no negation of the question ("honestly no idea how far ...")
    (r"\b(?:i have |i've |i've got |got )?(?:no idea|no clue|not a clue)\b", ""),
    (r"\bi (?:don't|do not|can't|cannot) (?:remember|recall|tell|say)\b(?! (?:if|whether)\b)", ""),
    # courtesies with a "no" that negate nothing asked ("no rush", "no worries if not")
    (r"\b(?:there's |there is )?no (?:rush|hurry|pressure|worries|worry|stress|biggie)(?: at all)?(?: if not)?\b", ""),
    # asides about precision that ask nothing ("give or take is fine", "roughly is ok"): not before a number
    (r"\b(?:give or take|roughly|approximately|approx|ballpark)(?: is| would be| will be|'s|'d be)? "
     r"(?:fine|ok|okay|good|enough|alright|all right)\b", ""),
    # counts
    (r"\b(?:tally|headcount|head count)\b", "count"), (r"\bhow much of\b", "how many"),
    # sizes
    (r"\b(?:from )?(?:end[- ]to[- ]end|tip[- ]to[- ]tip|edge[- ]to[- ]edge|head[- ]to[- ](?:foot|toe)|top[- ]to[- ]bottom|"
     r"side[- ]to[- ]side|wall[- ]to[- ]wall)\b", ""),
    (r"\b(?:whichever|whatever) ?(?:'s| is)(?: the)? (biggest|largest|longest|greatest)\b", r"the \1"),
    (r"\bat (its|their) (longest|biggest|largest|greatest)(?: point| side)?\b", r"at \1 \2 dimension"),
    # "the longest of its three dimensions", "whichever of the three is biggest": the count of sides is no object
    (r"\b(its|their|the|all|all of its|all of the) (?:two|three|four|2|3|4) (dimensions|sides|measurements|axes|"
     r"edges|directions|quadrants|options|choices|answers|possibilities)\b", r"\1 \2"),
    (r"\b(?:of )?(?:the|those|these|all) (?:two|three|four|2|3|4)(?= (?:is|are|was|were|would|will|gives?)\b|\s*[,?.!]|$)",
     ""),
    # how it is measured, said in words: no object ("closest point to closest point", "from the nearest points on
    # each of them", "count from the closest point of each")
    (r"\b(?:(?:measur(?:e|ing|ed)|count(?:ing|ed)?|going|taken|take it) )?(?:from )?(?:the )?(?:closest|nearest) "
     r"(?:points?|bits?|edges?|parts?|surfaces?)(?: to (?:the )?(?:closest|nearest) (?:points?|bits?|edges?|parts?|"
     r"surfaces?))?(?: (?:on|of) (?:each of them|each of the two|both of them|each|both|either|them))?"
     r"(?= ?[,:;.?!)]| - |$| in | please\b)", ""),
    (r"\b(?:measure|measuring) (?:the (?:distance|gap|space) )?between\b", "distance between"),
    # the reference first, the candidates after ("from the bed, which is the shortest distance away: ...")
    (r"\b(?:is )?(?:the )?(?:shortest|smallest|least) (?:distance|way) (?:away|off)\b", "is closest"),
    (r"\b(?:is )?(?:the )?(?:longest|biggest|largest|greatest) (?:distance|way) (?:away|off)\b", "is farthest"),
    # distances
    (r"\b(?:measure|measuring|measured) (?:the (?:way|gap|space|span) )?from\b", "distance from"),
    (r"\bwhatever\b", "whichever"),
    (r"\b(closest|nearest|farthest|furthest) (?:one )?of (?:these|those|them|the following|the options)\b", r"\1"),
    (r"\b(?:clearance|separation distance)\b", "distance"),
    (r"\b(?:smallest|shortest|least|tiniest) (?:gap|distance|space|way) (?:to|from)\b", "closest to"),
    (r"\b(?:biggest|largest|longest|greatest|most) (?:gap|distance|space|way) (?:to|from)\b", "farthest from"),
    (r"\bnearest neighbou?rs? (?:of|to)\b", "nearest to"),
    # a turn left blank in a numbered route ("2) ??", "3. ___"): the benchmark's "[please fill in]"
    (r"(\b\d[.)] ?)(?:\?{2,}|_{2,}|\[ ?(?:blank|\?+|_+) ?\])", r"\1[please fill in]"),
    # a part of an object as a place is the object ("at the foot of the bed", "by the end of the counter"); not the
    # parts of a room, which are refused ("the middle of the room")
    (r"\bthe (?:foot|head|end|edge|side|far side|near side|front|back|top|bottom) of (the|a|an|my|this|that) ", r"\1 "),
    # directions
    (r"\bdead ahead\b", "straight ahead"),
    # a stance told in a form's colons ("stand: table. face: fireplace.")
    (r"(^|[.;,/|] |- )(?:stand|standing|stand at|standing at|position|location|at|start|starting|start at|me)\s*: ",
     r"\1standing at "),
    (r"(^|[.;,/|] |- )(?:face|facing|looking at|look at|heading|facing toward|facing towards)\s*: ", r"\1facing "),
    # turning to face, in other verbs ("swing round to face", "spin around and face")
    (r"\b(?:swing|swings|swung|spin|spins|spun|swivel|swivels|pivot|pivots|wheel|wheels|twist|twists|rotate|rotates)"
     r"(?: (?:round|around|about))?(?= (?:to|and) fac)", "turn"),
    # a measure told by a verb after the object ("how many feet does the chair span")
    (r"\b(does|do|did|would|will) (the|that|this|each|its|their|a|an|my) ([a-z]+(?: [a-z]+)?) (?:span|stretch|extend|"
     r"run|reach|cover|go|come to|take up)\b", r"\1 \2 \3 measure"),
    (r"\b(looking|look|looks|staring|gazing|turned|facing) (?:over|straight|directly|right|across|out) "
     r"(at|toward|towards|to)\b", r"\1 \2"),
    # "the stove in front", "the bed ahead": in front of the asker
    (r"(\bthe [a-z]+(?: [a-z]+)?(?: is)?(?: straight| right| directly)?) (in front|ahead)(?= ?[,:;.?!]| - | and\b|$)",
     r"\1 \2 of me"),
    # the same at a clause's start without "the" ("bed at my side, stool straight in front - is ...")
    (r"((?:^|[,:;.] |- )[a-z]+(?: [a-z]+)?(?: is)? (?:straight|right|directly|dead)) (in front|ahead)(?= ?[,:;.?!]| - | and\b|$)",
     r"\1 \2 of me"), (r"\b(?:which|what) (?:diagonal|corner)\b", "which quadrant"),
    (r"\b(?:ahead|forward|in front)[- ](left|right)\b", r"front-\1"), (r"\b(?:behind|rear)[- ](left|right)\b", r"back-\1"),
    (r"\b(left|right)[- ](?:front|ahead|forward)\b", r"front-\1"), (r"\b(left|right)[- ](?:back|rear|behind)\b", r"back-\1"),
    (r"\b(?:off )?to the (left|right)-hand side\b", r"to the \1"),
]
_PHRASES = [(re.compile(rx), to) for rx, to in PHRASES]

_SMALL = {w: i for i, w in enumerate("zero one two three four five six seven eight nine ten eleven twelve thirteen "
                                     "fourteen fifteen sixteen seventeen eighteen nineteen".split())}
_TENS = {w: 10 * (i + 2) for i, w in enumerate("twenty thirty forty fifty sixty seventy eighty ninety".split())}
_UNIT_AFTER = (r"(?= ?(?:m|cm|mm|ft|in|meters?|metres?|centimet\w+|millimet\w+|feet|foot|inch(?:es)?|square|"
               r"percent|degrees?)\b)")


def _number_words(s: str) -> str:
    """Numbers said in words before a unit -> digits ("two and a half metres" -> "2.5 metres", "twenty-five cm"
    -> "25 cm", "a couple of metres" -> "2 metres"); "a dozen" / "half a dozen" anywhere. A number word that
    counts objects ("two chairs") is left for the parser (it reads one..twelve)."""
    s = re.sub(r"\bhalf a dozen\b", "6", s)
    s = re.sub(r"\b(?:a|one) dozen\b", "12", s)
    s = re.sub(r"\ba couple of\b" + _UNIT_AFTER, "2", s)
    tens = "|".join(_TENS)
    small = "|".join(sorted(_SMALL, key=len, reverse=True))

    rx = rf"\b(?:(a|one|two|three) hundred(?: and)? )?(?:({tens})(?:[- ]({small}))?|({small}))( and a half)?\b{_UNIT_AFTER}"

    def value2(m: re.Match) -> str:
        v = (100 * (_SMALL.get(m.group(1), 1)) if m.group(1) else 0) + (_TENS[m.group(2)] if m.group(2) else 0) + \
            (_SMALL[m.group(3)] if m.group(3) else 0) + (_SMALL[m.group(4)] if m.group(4) else 0)
        return f"{v}.5" if m.group(5) else str(v)

    return re.sub(rx, value2, s)


def unicode_ascii(text: str) -> str:
    """Unicode quotes, dashes, ellipsis and superscripts as ASCII; lower case; white space runs as one."""
    s = "".join(_UNICODE.get(c, c) for c in str(text)).lower()
    s = re.sub(r"\.{3,}", " ... ", s)
    return " ".join(s.split())


def shorthand(text: str) -> str:
    """Texting shorthand as words ("hw far" -> "how far", "pls" -> "please"); whole words only."""
    return re.sub(r"(?<![\w'])[a-z0-9]+(?![\w'])", lambda m: SHORTHAND.get(m.group(0), m.group(0)), text)


def synonyms(text: str) -> str:
    """`PHRASES` applied in order (units, then cue words)."""
    for rx, to in _PHRASES:
        text = rx.sub(to, text)
    return " ".join(text.split())


def _blanks(s: str) -> str:
    """A blank turn in a route told in words ("then ___, then walk to the sofa"): the benchmark's "[please fill
    in]"; "turn ___" is one turn already. Only in a text that speaks of turning."""
    if not re.search(r"\bturn", s):
        return s
    s = re.sub(r"\b(turn(?:s|ing)?) (?:_{2,}|\?{2,}|\.{3})", r"\1", s)
    return re.sub(r"(?<![\w])_{2,}(?![\w])", "[please fill in]", s)


def compounds(text: str, names: Iterable[str] = ()) -> str:
    """A hyphenated name ("dish-washer", "flat-screen tv", "night-stand") as the vocabulary writes it, joined or
    spaced; other hyphenated words ("front-left", "tv-to-bed") are left."""
    known = set(NAME_SYNONYMS) | {n.lower() for n in names}

    def fix(m: re.Match) -> str:
        w = m.group(0)
        for cand in (w.replace("-", ""), w.replace("-", " ")):
            if cand in known or singular(cand) in known or " ".join(cand.split()[:-1] + [singular(cand.split()[-1])]) \
                    in known:
                return cand
        return w
    return re.sub(r"\b[a-z]+(?:-[a-z]+)+\b", fix, text)


def normalize(text: str, names: Iterable[str] = ()) -> tuple[str, list[str], list[str]]:
    """(the question in the parser's words; notes of each spelling change; words too close to several words the
    parser uses to be read, which refuse the question). `names`: object names beyond the vocabulary (the map's
    categories), which spelling also corrects to and never away from."""
    names = list(names)
    s = compounds(shorthand(unicode_ascii(text)), names)
    s, notes, unclear = correct(s, names)
    s = _blanks(_number_words(synonyms(s)))
    return s, notes, unclear
