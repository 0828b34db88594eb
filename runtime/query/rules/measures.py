"""Sizes, size comparisons and the room's size: which measure, which unit, against what."""
from __future__ import annotations

import re
from typing import Any

from ..ir import EVERYTHING, AreaCondition, Node, RoomSize, Size, SizeCompare
from .intent import ELEVATION_RX
from .lexicon import COMPARATIVES, COPULA, SUP_RX, SUPERLATIVES, UNIT_M, UNIT_WORDS
from .locations import single
from .state import R, State
from .tokens import has, unit_in


_DIMS = {"height": r"\b(?:tall|high|height)\b", "width": r"\b(?:wide|width)\b", "length": r"\b(?:long|length)\b",
         "depth": r"\b(?:deep|depth)\b"}
# the one of several dimensions asked for ("whichever of them is biggest")
_MOST = r"\b(?:biggest|largest|longest|greatest|most|max|maximum|bigger|larger|longer|greater|highest|widest)\b"


def _dimension(joined: str) -> str:
    if has(joined, ELEVATION_RX):
        return "elevation"  # "how high above the floor is the lamp?": its bottom over the floor
    if has(joined, r"\bvolume\b"):
        return "volume"
    if (has(joined, r"\bdimensions\b|\bmeasurements\b|\bhow (?:long|wide|tall|high|deep) and (?:wide|long|tall|high|"
                    r"deep)\b") and not has(joined, SUP_RX + r"|\b(?:maximum|max|greatest)\b")):
        return "all"  # "what are the dimensions of the desk?": width x depth x height
    named = [d for d, rx in _DIMS.items() if has(joined, rx)]
    if len(named) > 1 and has(joined, r"\bor\b"):  # "how tall or wide or long is it": one of several
        return "longest" if has(joined, _MOST) else "several"
    for dim, rx in (("longest", r"\b(?:longest|biggest|largest|maximum|max|greatest)\b(?: \w+)? (?:side|dimension|"
                                r"edge|extent|length)|\bsize\b|\bhow (?:big|large)\b|\bdimensions?\b"),
                    ("height", r"\bhow (?:tall|high)\b|\bheight\b|\btall\b"),
                    ("width", r"\bhow wide\b|\bwidth\b|\bwide\b"), ("length", r"\bhow long\b|\blength\b|\blong\b"),
                    ("depth", r"\bhow deep\b|\bdepth\b|\bdeep\b")):
        if has(joined, rx):
            return dim
    return "longest"


def size(st: State, toks: list[str], joined: str, nps: list[dict[str, Any]], extra: dict[str, Any]) -> Node | None:
    sup = next((t for t in toks if t in SUPERLATIVES), None)
    if not nps and sup and has(joined, r"\b(?:object|thing|item|furniture|piece)\b"):
        return SizeCompare(sup, (EVERYTHING,), with_value=True)  # "how tall is the tallest object?": which, how tall
    n = single(st, nps, "size question")
    if n is None:
        return None
    dim = _dimension(joined)
    if dim == "several":  # never one of them picked at random
        names = [d for d, rx in _DIMS.items() if has(joined, rx)]
        return st.fail(f"a size question of '{st.phrase(n)}'", f"which of {' or '.join(names)} (ask for one, or "
                                                               f"'the longest dimension')")
    unit = "m3" if dim == "volume" else unit_in(joined, "m" if dim == "elevation" else "cm")
    return Size(R(n), dim, unit)


def size_compare(st: State, toks: list[str], joined: str, nps: list[dict[str, Any]], extra: dict[str, Any]
                 ) -> Node | None:
    """"Which is bigger, A or B?" / "Is A taller than B?" (yes or no) / "What's the tallest object?" (over the
    whole map) / "Which chair is the tallest?" (one instance of one name) / "how much taller is A than B?"."""
    word = next(t for t in toks if t in COMPARATIVES or t in SUPERLATIVES)
    sup = COMPARATIVES.get(word, word)
    names = st.option_names() or st.refs(nps)
    yesno = word in COMPARATIVES and "than" in toks and toks[0] in COPULA | {"does", "do", "did"}
    diff = word in COMPARATIVES and has(joined, r"\bhow much\b")
    m = re.search(rf"\b{word} than (?:about |around |roughly )?(\d+(?:\.\d+)?) ?([a-z]+)", st.question.lower())
    if yesno and len(names) == 1 and m:  # "is the couch longer than 2 m?": against a length
        unit = UNIT_WORDS.get(m.group(2))
        if unit is None or SUPERLATIVES[sup][0] == "volume":
            return st.fail(f"a '{word}' question about '{st.phrase(names[0])}' and {m.group(1)} {m.group(2)}",
                           "a length to compare with: height, length or width in m, cm, mm, ft or in (e.g. 'is the "
                           "sofa longer than 2 m?')")
        length = float(m.group(1)) * UNIT_M[unit] * 1000
        if not length <= 1_000_000:  # SizeCompare.threshold_mm's bound (ir.py): refused, not an overflow
            return st.fail(f"a '{word}' question about '{st.phrase(names[0])}'", "a length of at most 1 km")
        mm = round(length)
        return SizeCompare(sup, (R(names[0]),), "threshold", mm, f"{m.group(1)} {unit}")
    if ((yesno or diff) and len(names) != 2) or (word in COMPARATIVES and len(names) < 2):
        about = f" about '{st.phrase(names[0])}'" if names else ""
        return st.fail(f"a '{word}' question{about}", "the two objects to compare (e.g. 'is the tv bigger than "
                                                      "the lamp?', 'which is taller, the fridge or the door?')")
    cands = tuple(R(n) for n in names) or (EVERYTHING,)
    if diff:  # "how much taller is A than B?": A's measure minus B's, in the asked unit
        return SizeCompare(sup, cands, "difference", unit=None if SUPERLATIVES[sup][0] == "volume"
                           else unit_in(joined, "cm"))
    return SizeCompare(sup, cands, "yesno" if yesno else "which")


def room_size(st: State, toks: list[str], joined: str, nps: list[dict[str, Any]], extra: dict[str, Any]
              ) -> Node | None:
    """Floor area; "how long / wide is the room?", "the room's dimensions" (the sides of the extent's smallest
    enclosing rectangle); "is the room bigger than 20 square meters?" (against an area)."""
    measure, unit = "area", "ft2" if has(joined, r"square (?:feet|foot)|sq ?ft") else "m2"
    dim = re.search(r"\bhow (long|wide) is\b|\b(length|width|dimensions?|measurements?) of\b", joined)
    if dim:
        word = dim.group(1) or dim.group(2)
        measure = {"long": "length", "wide": "width"}.get(word, word if word in ("length", "width") else "all")
        unit = unit_in(joined, "m")
    than = None
    m = re.search(r"\b(bigger|larger|smaller) than (?:about |around )?(\d+(?:\.\d+)?)", st.question.lower())
    if m and toks[0] in COPULA:
        value = float(m.group(2))
        area = value * (0.3048 ** 2 if unit == "ft2" else 1.0) * 1e4
        if not area <= 10_000_000_000:  # AreaCondition's bound (ir.py): refused, not a program the schema rejects
            return st.fail("a room-size comparison", "an area of at most 1,000,000 m2")
        cm2 = round(area)
        than = AreaCondition("<" if m.group(1) == "smaller" else ">", cm2, f"{value:g} {unit}")
    return RoomSize(measure, unit, than)
