"""Locations and pronouns: which phrases name a place ("on the desk", "between the desk and the couch"), the
selector a closeness word makes ("the chair nearest the door"), and what a located pronoun stands for."""
from __future__ import annotations

from typing import Any

from ..ir import At, Closest, Described, NearestTo, Ref, Relation, Superlative
from ..vocabulary import canonical_name, name_key
from .lexicon import (CLOSE, COPULA, DET, FAR, LOCATION, NEAR_CUES, PRONOUN_CUES, PRONOUNS, RELATION_WORDS,
                      SUPERLATIVES)
from .state import R, State
from .tokens import before, has, is_content, noun_phrases, tokens

_LOOK = {"look", "looks", "looking", "looked", "stare", "staring", "gaze", "gazing", "glance", "glancing", "point",
         "pointing", "pointed"}


def location_start(toks: list[str], i: int) -> int | None:
    """Where the location words before token i begin ("next to it", "on top of it", "near it"), or None when
    token i does not follow a location word."""
    k = i - 1
    if k >= 1 and toks[k] in ("to", "of"):
        k -= 1
    if k < 0 or toks[k] not in PRONOUN_CUES:
        return None
    if toks[k] == "at" and k >= 1 and toks[k - 1] in _LOOK:  # "look at it": what one faces, not a place
        return None
    return k - 1 if toks[k] == "top" and k >= 1 and toks[k - 1] == "on" else k


def antecedents(toks: list[str], i: int, loc: int) -> list[dict[str, Any]]:
    """The object phrases before the located pronoun at token i that it can stand for: not a room word, and not
    the phrase the location describes ("the chairs (are) next to it": the chairs are not next to themselves)."""
    before = [p for p in noun_phrases(toks[:loc]) if not p["scene"]]
    if before and all(t in COPULA | DET for t in toks[before[-1]["end"]:loc]):
        before.pop()
    return before


def resolve_pronouns(st: State, toks: list[str]) -> list[str] | None:
    """The tokens with each located pronoun replaced by the one object named before it ("the chairs next to it"
    -> "the chairs next to the desk"), so the explicit phrase's reading applies; None (the question refused,
    `st.notes` say why) when no single object is named before it: a location is never dropped silently."""
    for i, t in enumerate(toks):
        loc = location_start(toks, i) if t in PRONOUNS else None
        if loc is None or (i + 1 < len(toks) and is_content(toks, i + 1, False)):  # "next to that desk"
            continue
        cands = antecedents(toks, i, loc)
        if len(cands) != 1:
            named = [" ".join(toks[p["start"]:p["end"]]) for p in cands]
            why = f"it could be the {' or the '.join(named)}; say e.g. '{' '.join(toks[loc:i])} the {named[-1]}'" \
                if named else "no object is named before it; name the object instead"
            st.fail(f"the location '{' '.join(toks[loc:i + 1])}'", f"which object '{t}' is ({why})")
            return None
        p = cands[0]
        return resolve_pronouns(st, toks[:i] + ["the"] + toks[p["start"]:p["end"]] + toks[i + 1:])
    return toks


def relation_of(toks: list[str], p: dict[str, Any]) -> str | None:
    """The relation the words before a phrase name ("on (top of)", "near / next to / close to / by", "in"),
    or None."""
    b = before(toks, p, 3)
    if b[-2:] == ["top", "of"]:
        return "on"
    if b[-2:] in (["next", "to"], ["close", "to"]):
        return "near"
    return RELATION_WORDS.get(b[-1]) if b else None


def conditions(toks: list[str], nps: list[dict[str, Any]], every: bool = False
                ) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """Split phrases into the objects asked about and the ones after a location word ("on the desk"); every:
    the question asks about every object ("things on the desk"), so a first phrase can be a location too."""
    objs, conds = [], []
    for p in nps:
        if p["words"] == ["top"] and toks[p["end"]:p["end"] + 1] == ["of"]:
            continue  # "on top of the desk": part of the location words, not an object
        b = before(toks, p, 1)
        located = bool(b) and (b[-1] in LOCATION or relation_of(toks, p) is not None)
        if conds and b == ["and"] and relation_of(toks, conds[-1]) == "between":
            located = True  # "between the desk and the couch": both phrases are the location
        (conds if (objs or every) and located else objs).append(p)
    return objs, conds


def location(st: State, toks: list[str], objs: list[dict[str, Any]], conds: list[dict[str, Any]]
             ) -> Relation | None:
    """A single supported location ("cups on the table"; "between" names two objects); None when it is not one."""
    two = len(conds) == 2 and relation_of(toks, conds[0]) == "between"
    rel = relation_of(toks, conds[0]) if (len(conds) == 1 or two) and len(objs) <= 1 else None
    if rel is None or (rel == "between") != two:
        return None
    refs = st.refs(conds)
    negate = "not" in before(toks, conds[0], 5)[:-1]  # "cups not on the table": the others
    return Relation(rel, R(refs[0]), R(refs[1]) if two else None, negate)


def attached_near(st: State, joined: str, objs: list[dict[str, Any]]) -> Relation | None:
    """"chairs near / by / next to the door" read as a selector by `_attachments`: for a count it is a location
    (a superlative, "the chair nearest the door", stays a selector: one instance)."""
    if len(objs) != 1 or objs[0].get("attach") is None or has(joined, CLOSE + "|" + FAR):
        return None
    ref = objs[0].pop("attach")
    st.phrases.setdefault(ref, objs[0].pop("attach_phrase"))
    return Relation("near", R(ref))


def attachments(toks: list[str], nps: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """"the chair nearest (to) the door", "the lamp next to the bed": the second phrase selects among the first's
    instances; returns the phrases that remain (attached ones folded into their owner's `attach`)."""
    out: list[dict[str, Any]] = []
    for p in nps:
        if out:
            prev = out[-1]
            gap = [t for t in toks[prev["end"]:p["start"]] if t not in DET]
            if gap and gap[0] in NEAR_CUES and all(t in NEAR_CUES | {"to", "the", "one", "from"} for t in gap) \
                    and len(gap) <= 3 and prev.get("attach") is None:
                prev["attach"] = canonical_name(" ".join(p["words"])) or name_key(" ".join(p["words"]))
                prev["attach_phrase"] = " ".join(p["words"])
                continue
        out.append(p)
    return out


def single(st: State, nps: list[dict[str, Any]], what: str) -> str | None:
    """The one object a question of this kind is about (None and a note when there is none or several)."""
    if not nps:
        st.fail(what, "which object it is about")
        return None
    names = st.refs(nps)
    if len(names) > 1:
        extra = ", ".join(f"'{st.phrase(n)}'" for n in names[1:])
        st.notes.append(f"{extra}: a location or condition that cannot be applied to a {what}")
        st.fail(f"a {what} of '{st.phrase(names[0])}'", f"what {extra} means for it")
        return None
    return names[0]


_CLOSENESS = {"closest": "closest", "nearest": "closest", "farthest": "farthest", "furthest": "farthest"}


def ref_of_phrase(text: str) -> Ref | None:
    """One object phrase with what picks its instance ("the stool by the piano" -> stool, nearest to the piano;
    "the laptop on the desk" -> laptop on a desk; "the closest sofa" -> the sofa nearest the viewer; "the black
    nightstand" -> described by a colour the map does not hold; "the wardrobe with two mirrors on it" -> described
    by words the map does not hold). None when the text names no object."""
    toks = tokens(text)
    nps = [p for p in noun_phrases(toks) if not p["scene"] and not (p["words"] == ["top"] and
                                                                     toks[p["end"]:p["end"] + 1] == ["of"])]
    while len(nps) > 1 and canonical_name(" ".join(nps[0]["words"])) is None and \
            [t for t in toks[nps[0]["end"]:nps[1]["start"]] if t not in DET] == ["of"]:
        nps = nps[1:]  # "the end of the cabinet", "the corner of the shower": the part's owner
    if not nps:
        return None
    head = nps[0]
    phrase = " ".join(head["words"])
    name = canonical_name(phrase) or name_key(phrase)
    select: list[Any] = []
    words = [w for w in head["sel"] if w not in SUPERLATIVES]
    if words:
        select.append(Described(tuple(words), " ".join(head["sel"] + head["words"])))
    select += [Superlative(w) for w in head["sel"] if w in SUPERLATIVES]
    ahead = [t for t in toks[:head["start"]] if t not in DET]
    if ahead and ahead[-1] in _CLOSENESS:  # "the closest sofa": from the viewer
        select.append(Closest(_CLOSENESS[ahead[-1]]))
    rest = " ".join(toks[head["end"]:]).strip(" .?,")
    if len(nps) > 1 and rest:
        other = nps[1]
        gap = [t for t in toks[head["end"]:other["start"]] if t not in DET]
        oname = canonical_name(" ".join(other["words"])) or name_key(" ".join(other["words"]))
        ophrase = " ".join(other["words"])
        rel = relation_of(toks, other)
        if gap and gap[0] in NEAR_CUES | {"close", "closer", "nearer"} and len(gap) <= 3:
            select.append(NearestTo(oname, "" if ophrase == oname else ophrase))
        elif rel in ("on", "near", "in", "under", "above") and len(gap) <= 3:
            select.append(At(rel, oname, "" if ophrase == oname else ophrase))
        elif gap and gap[0] != "of":  # "with two mirrors on it", "to your right": words a map does not hold
            select.append(Described((rest,), f"{phrase} {rest}"))
    elif rest and rest.split()[0] in _CLOSENESS:  # "the chair farthest away", "the sofa closest to me"
        select.append(Closest(_CLOSENESS[rest.split()[0]]))
    elif rest and rest.split()[0] not in ("of",):
        select.append(Described((rest,), f"{phrase} {rest}"))
    return Ref(name, "" if phrase == name else phrase, canonical_name(phrase) is not None, tuple(select[:4]))
