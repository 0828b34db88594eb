"""A question as people type it -> the words the rule parser knows.

`normalize(text, names)` runs, in order: unicode punctuation (quotes, dashes, ellipsis, superscripts) and lower
case; hyphenated names as the vocabulary writes them; `PHRASES` (unit spellings such as "sq ft" / "m2", and the
few cue-word synonyms without which a question is read as another kind); numbers said in words before a unit
("two metres", "a dozen"). None of these changes a word's meaning. Typos, texting shorthand and other wordings
are the trained reader's (`parse.parse_question`, docs/query.md): the spelling corrector and the phrase tables
written for wording sets 8-10 retired with issue 35.
"""
from __future__ import annotations

import re
from typing import Iterable

from .vocabulary import NAME_SYNONYMS, singular

# unicode punctuation people's phones type -> ASCII
_UNICODE = {"\u2018": "'", "\u2019": "'", "\u201a": "'", "\u2032": "'", "\u201c": '"', "\u201d": '"', "\u201e": '"',
            "\u2033": '"', "\u2013": " - ", "\u2014": " - ", "\u2015": " - ", "\u2012": " - ", "\u2212": "-",
            "\u2026": " ... ", "\u00a0": " ", "\u00b2": "2", "\u00b3": "3", "\u00d7": " x "}

# unit synonyms (regex over the lower-case text -> the parser's own words)
PHRASES: list[tuple[str, str]] = [
    # areas
    (r"\b(?:m2|m\^2|sq\.? ?m|sqm|sq\.? ?met(?:er|re)s?|square met(?:er|re)s?|meters? squared|metres? squared)(?![a-z])",
     "square meters"),
    (r"\b(?:ft2|ft\^2|sq\.? ?ft|sqft|sq\.? ?f(?:ee|oo)t|square f(?:ee|oo)t(?:age)?|feet squared)(?![a-z])",
     "square feet"),
    # cue-word synonyms that are read as another kind without them (measured: a confidently wrong program each)
    (r"\b(?:tally|headcount|head count)\b", "count"),
    (r"\bat (its|their) (longest|biggest|largest|greatest)(?: point| side)?\b", r"at \1 \2 dimension"),
    (r"\b(?:smallest|shortest|least|tiniest) (?:gap|distance|space|way) (?:to|from)\b", "closest to"),
    (r"\b(?:biggest|largest|longest|greatest|most) (?:gap|distance|space|way) (?:to|from)\b", "farthest from"),
    (r"\bnearest neighbou?rs? (?:of|to)\b", "nearest to"),
    (r"\bdead ahead\b", "straight ahead"),
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


def synonyms(text: str) -> str:
    """`PHRASES` applied in order (units, then cue words)."""
    for rx, to in _PHRASES:
        text = rx.sub(to, text)
    return " ".join(text.split())


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


def normalize(text: str, names: Iterable[str] = ()) -> str:
    """The question in the parser's words. `names`: object names beyond the vocabulary (the map's categories),
    whose hyphenated forms are joined as the map writes them."""
    return _number_words(synonyms(compounds(unicode_ascii(text), list(names))))
