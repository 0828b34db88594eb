"""Distances and which-is-closest: the two objects, the reference the distances are measured to, the viewer."""
from __future__ import annotations

import re
from typing import Any

from ..ir import EVERYTHING, Distance, DistanceCondition, Nearest, Node
from ..vocabulary import NAME_SYNONYMS, singular
from .intent import distance_condition
from .lexicon import CLOSE, COPULA, FAR
from .state import R, State
from .tokens import before, has, unit_in

_VIEWER_REF_RX = (r"\b(?:to|from) (?:me|us|myself|here|the camera)\b|^(?:am|are) (?:i|we)\b|"
                  r"\b(?:i am|i'm|im|we are) (?:closer|nearer|farther|further)\b")


def abs_distance(st: State, toks: list[str], joined: str, nps: list[dict[str, Any]], extra: dict[str, Any]
                 ) -> Node | None:
    """"How far is the table from the tv?"; with one object and the asker ("how far am I from the tv?", "how
    far away is the fridge?"): from the viewer, the last camera."""
    names = st.refs(nps)
    if len(names) == 1 and has(joined, r"\b(?:me|i|i'm|im|myself|us|we|here|the camera)\b|^how far away (?:is|are)\b"):
        return Distance(R(names[0]), None, unit_in(joined, "m"))
    if len(names) == 1 and has(joined, r"\b(?:two|both)\b|\bapart\b|\b(?:between|from each other|from one "
                                        r"another)\b"):  # "the distance between the two chairs": one pair
        return Distance(R(names[0]), R(names[0]), unit_in(joined, "m"))
    pair = two_names(nps[0]["words"]) if len(nps) == 1 else None
    if pair:  # "distance fireplace sofa?": one phrase that is two names and no name itself
        names = st.refs([{**nps[0], "words": w.split(), "sel": []} for w in pair])
    if len(names) != 2:
        got = ", ".join(f"'{st.phrase(n)}'" for n in names) or "no object"
        return st.fail(f"a distance question naming {got}", "exactly two objects to measure between")
    within = None
    cond = distance_condition(st.question)
    if cond is not None and toks[0] in COPULA and not has(joined, VALUE_ASKED_RX):  # "within 2 m of ...?": yes/no
        if not cond["threshold_m"] * 1000 <= 1_000_000:  # DistanceCondition's bound (ir.py): refused, not a crash
            return st.fail("a within-distance question", "a distance of at most 1 km")
        within = DistanceCondition(cond["op"], round(cond["threshold_m"] * 1000), cond["text"])
    return Distance(R(names[0]), R(names[1]), unit_in(joined, "m"), within)


# "... more than 2 m from the tv? what's the actual distance": the number is asked, not only yes or no
VALUE_ASKED_RX = (r"\b(?:actual|exact|precise|real) (?:distance|figure|number|value)\b|\bhow far exactly\b|"
                  r"\bexactly how far\b")


def two_names(words: list[str]) -> tuple[str, str] | None:
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


def reference_index(toks: list[str], nps: list[dict[str, Any]]) -> int | None:
    """The phrase the distances are measured to: right after a closeness word ("nearest the tv"), or after
    "to/from" following one ("closest to the tv", "farthest away from the bed")."""
    befores = [before(toks, p, 4) for p in nps]
    for k, bw in enumerate(befores):  # first: "the nearest chair to the tv" measures to the tv, not the chair
        if bw and bw[-1] in ("to", "from") and any(
                re.fullmatch(CLOSE + "|" + FAR + r"|\baway\b|\bfar\b|\bapart\b", w) for w in bw[:-1]):
            return k
    for k, bw in enumerate(befores):
        if bw and re.fullmatch(CLOSE + "|" + FAR, bw[-1]):
            return k
    if re.search(r"\b(?:closest|nearest|closer|nearer|farthest|furthest|farther|further)\b(?: \w+)? (?:to |from )?"
                 r"(?:me|myself|i am|i'm|where i am)\b", " ".join(toks)):
        for k, p in enumerate(nps):  # "if I'm at the stove, which ... is closest to me?"
            bw = before(toks, p, 2)
            if bw and (bw[-1] in ("at", "by", "beside", "near") or " ".join(bw) == "next to"):
                return k
    for k, p in enumerate(nps):  # "what's next to the desk?"
        bw = before(toks, p, 2)
        if bw and (bw[-1] in ("beside", "near", "by") or " ".join(bw[-2:]) == "next to"):
            return k
    for k, p in enumerate(nps):  # "which of these is the closest one? (reference: ... to the tv)"
        bw = before(toks, p, 1)
        if bw and bw[-1] in ("to", "from"):
            return k
    return None


def rel_distance(st: State, toks: list[str], joined: str, nps: list[dict[str, Any]], extra: dict[str, Any]
                 ) -> Node | None:
    far = has(joined, FAR + r"|\bfar\b") and not has(joined, CLOSE)
    extreme = "farthest" if far else "closest"
    placed = has(joined, r"\b(?:if|when) (?:i|i'm|im|we)\b|\b(?:i'm|i am|im|standing|sitting|stand|sit) (?:at|by|next "
                         r"to|near|beside|on|in front of)\b")  # "if I'm at the stove, ... closest to me": me = there
    if has(joined, _VIEWER_REF_RX) and nps and not placed:  # "what's the closest chair to me?", "am I closer to ...?"
        names = st.option_names() or st.refs(nps)
        if len(names) == 1:  # which instance of one name: the nearest (farthest) one from the viewer
            return Distance(R(names[0]), None, unit_in(joined, "m"), pick=extreme)
        return Nearest(None, tuple(R(n) for n in names), extreme)
    k = reference_index(toks, nps)
    if k is None:
        return st.fail("a which-is-closest question", "the object the distances are measured to (e.g. '... closest "
                                                      "to the tv')")
    names = st.refs(nps)
    ref = names[k]
    cands = st.option_names() or [n for i, n in enumerate(names) if i != k]
    if not cands:
        return Nearest(R(ref), (EVERYTHING,), extreme)
    yesno = toks[0] in COPULA | {"does", "do", "did"} and "than" in toks and len(names) == 3 and not st.options
    if yesno and has(joined, r"\bthan (?:to|from)\b"):  # "is the cup closer to the table than to the tv?"
        ref, cands = names[0], names[1:]  # distances from the cup: to the table vs to the tv
    elif toks[0] in COPULA and len(names) == 3 and "or" in toks and not st.options and \
            re.fullmatch(CLOSE + "|" + FAR, (before(toks, nps[1], 4)[-2:-1] or [""])[0]):
        ref, cands = names[0], names[1:]  # "is the bin closer to the desk or the couch?": from the bin
    return Nearest(R(ref), tuple(R(c) for c in cands), extreme, yesno=yesno)
