"""The rule parser: a question as people type it -> a program node, in one pass over its tokens.

Steps: the preamble a question may carry (how distances are measured, what "back" means) is set aside; a located
pronoun is replaced by the one object named before it (or the question refused); the kind of question comes
from its cue words (`intent`); its object phrases are read (`tokens.noun_phrases`), with closeness words making
selectors ("the chair nearest the door"); the handler of that kind assigns each phrase its role from the words
near it and builds the node. Every step refuses rather than dropping a word it cannot apply (ranks, exceptions,
negations), and the notes say what was understood and what was not.
"""
from __future__ import annotations

import re
from dataclasses import replace
from typing import Any, Callable, Iterable

from ..cues import kind_of
from ..ir import Nearest, Node
from . import counting, directions, distances, measures, route
from .intent import EXCEPT_RX, WALK_RX, intent, refuse_whole_text, route_options, strip_preamble, unread_negation
from ..vocabulary import NAME_SYNONYMS, canonical_name, name_key
from .distances import two_names
from .lexicon import DET, FACE1, LOCATION, RANKS, RELATION_WORDS, STOP
from .clauses import read_clauses
from .locations import attachments, resolve_pronouns
from .state import R, Refused, State
from .tokens import before, has, noun_phrases, tokens

Handler = Callable[[State, list, str, list, dict], "Node | None"]
HANDLERS: dict[str, Handler] = {
    "count": counting.count, "count_compare": counting.count_compare, "existence": counting.exists,
    "relation": counting.exists, "view_direction": directions.view_direction, "view_list": counting.view_list,
    "size": measures.size, "size_compare": measures.size_compare, "room_size": measures.room_size,
    "abs_distance": distances.abs_distance, "rel_distance": distances.rel_distance, "direction": directions.direction,
    "where": directions.where, "list": counting.list_objects, "obj_appearance_order": directions.appearance_order,
    "route": route.route}

# the cue words after which a question's object comes ("Quick question: how many chairs ...")
_TRIGGERS = {"count": {"many", "count", "number", "quantity", "total"},
             "size": {"big", "large", "long", "tall", "wide", "high", "deep", "size", "dimension", "dimensions",
                      "length", "height", "width", "depth", "measure", "longest", "biggest", "largest"},
             "existence": {"there", "see", "spot", "find", "notice", "have", "contain", "any", "exist", "exists"},
             "where": {"where", "where's", "locate", "location", "position", "whereabouts"}}


def parse_natural(question: str, options: list[str] | None = None, names: Iterable[str] = ()
                  ) -> tuple[Node | None, State]:
    """(the question's node, or None when its kind or its objects are not understood; the parse state, whose
    notes say what was understood and what was not). `question` is already cleaned (`text.clean_question`);
    names: object names beyond the vocabulary that count as mentions (the map's categories, the detector's).

    Mentions first: a phrase is read as an object when it names one (the vocabulary or `names`), when the
    sentence marks it as one (a determiner, a location or facing word before it), or when it does not read as a
    verb or an adverb; words that do ("I'm trying to work out ...", "can
    you help", "honestly") are left out, said in the notes. When that reading is refused, every phrase is read
    as an object, as before."""
    keys = frozenset(name_key(n) for n in names)
    node, st = _attempt(question, options, keys, mentions_first=True)
    if node is not None and st.weak:  # stray words in object slots
        node2, st2 = _attempt(question, options, keys, mentions_first=True, drop_weak=True)
        if node2 is not None and type(node2) is type(node) and node.qtype not in _EVERY_PHRASE:
            return st2.finish(node2), st2
    if node is None and st.weak:  # refused: without the stray words ("..., no rush at all", "bit of a weird one")
        node2, st2 = _attempt(question, options, keys, mentions_first=True, drop_weak=True)
        if node2 is not None and node2.qtype not in _EVERY_PHRASE:
            return st2.finish(node2), st2
    if node is None and st.dropped:  # refused without the dropped words: read every phrase as an object
        node, st = _attempt(question, options, keys, mentions_first=False)
    return (st.finish(node) if node is not None else None), st


# kinds whose every phrase is an object, known or not (a waypoint, a thing seen)
_EVERY_PHRASE = {"route_planning", "obj_appearance_order"}


def _attempt(question: str, options: list[str] | None, keys: frozenset[str], mentions_first: bool,
             drop_weak: bool = False) -> tuple[Node | None, State]:
    st = State(question, options)
    try:
        node = _parse(st, keys if mentions_first else None, drop_weak)
    except Refused:
        node = None
    return node, st


# a phrase after one of these words is an object by the sentence's syntax (a location, what I face, a comparison)
_MARKERS = LOCATION | set(RELATION_WORDS) | FACE1 | {"from", "between", "of", "than", "versus", "vs", "at", "toward",
                                                     "towards", "until", "till"}
# a word after a subject or a modal is a verb ("I'm trying", "can you help", "please check"), after a bare "to" an
# infinitive ("to figure out"): not an object
_SUBJECTS = {"i", "i'm", "im", "you", "we", "they", "he", "she", "it", "me", "us", "them", "can", "could", "would",
             "will", "should", "may", "might", "must", "do", "does", "did", "please", "let's", "lets", "to", "just",
             "also"}


# a word after one of these is a property asked about ("more comfortable", "is it cosy"), never left out
_DEGREE = {"more", "less", "most", "least", "as", "so", "too", "very", "really", "quite", "is", "are", "was", "were",
           "be", "being", "looks", "seems"}


def mentions(toks: list[str], nps: list[dict[str, Any]], keys: frozenset[str], known_only: bool = False
             ) -> list[bool]:
    """Per phrase: read as an object? (see `parse_natural`). A phrase is left out only when it names no object,
    nothing marks it as one, and it reads as a verb or an adverb: after a subject, an object pronoun, a modal or
    a bare "to", or words ending in -ing / -ly / -ed."""
    def named(p: dict[str, Any]) -> bool:
        phrase = " ".join(p["words"])
        return canonical_name(phrase) is not None or name_key(phrase) in keys or two_names(p["words"]) is not None

    def marked(p: dict[str, Any]) -> bool:
        b = before(toks, p, 1)
        return (p["start"] > 0 and toks[p["start"] - 1] in DET) or (bool(b) and b[-1] in _MARKERS)

    def verb_like(p: dict[str, Any]) -> bool:
        prev = toks[p["start"] - 1] if p["start"] > 0 else ""
        return len(p["words"]) <= 2 and not p["sel"] and (
            prev in _SUBJECTS or re.fullmatch(r"(?:i|you|we|they|he|she)'(?:d|ll|ve|re|m)", prev) is not None
            or all(re.search(r"(?:ing|ly)$", w) or (len(w) > 4 and w.endswith("ed")) for w in p["words"]))

    if known_only:  # only the phrases that name a known object
        return [named(p) for p in nps]
    return [named(p) or marked(p) or not verb_like(p) for p in nps]


# between two phrases of one list of objects ("the chair, the zither or the lamp")
_COORD = {"and", "or", ",", "nor", "versus", "vs", "&", "/", "plus"}


def weak(toks: list[str], nps: list[dict[str, Any]], known: list[bool]) -> list[bool]:
    """Per phrase: a word that names no known object and that nothing in the sentence holds as one? Such a phrase
    is held when it is listed with a known object ("chairs and zithers") or comes right after a location,
    facing or comparison word ("near the zither", "than the zither") and does not read as a participle
    ("my face pointed at"); else it is weak ("if you can")."""
    def gap(i: int, j: int) -> list[str]:
        if not 0 <= j < len(nps):
            return []
        a, b = (nps[j], nps[i]) if j < i else (nps[i], nps[j])
        return [t for t in toks[a["end"]:b["start"]] if t not in DET]

    def listed(i: int) -> bool:  # a comma alone lists only inside a list ("the sofa, whereabouts is ...": none)
        for j, other in ((i - 1, i + 1), (i + 1, i - 1)):
            g = gap(i, j)
            if g and known[j] and set(g) <= _COORD and (g != [","] or set(gap(i, other) or ["x"]) <= _COORD):
                return True
        return False

    def placed(p: dict[str, Any]) -> bool:  # "of" places only after a word of the parser ("left of", "size of";
        b = before(toks, p, 2)                # not "a bit of a weird one", "the top of your head")
        participle = all(re.search(r"(?:ing|ed)$", w) for w in p["words"])
        of_ok = b[-1:] != ["of"] or (len(b) > 1 and b[-2] in STOP)
        return bool(b) and b[-1] in _MARKERS and of_ok and not participle

    return [not k and not listed(i) and not placed(p) for i, (p, k) in enumerate(zip(nps, known))]


_VAGUE = {"whichever", "whatever", "thing", "object", "item"}
# "is there anything on the desk?", "how many things are on it?": every object the map holds, a reading of its own
_WILDCARD = {"something", "anything", "things", "stuff", "objects", "items"}
_ASKS_ALL = {"many", "there", "which", "what", "whats", "any"}  # the words that ask for every object


def told_by_place(toks: list[str], nps: list[dict[str, Any]], known: list[bool]) -> str | None:
    """The words of an object told only by its place ("whatever sits by the window", "the one next to the door"),
    else None: a vague word, then within a few words a location word, then a known object."""
    starts = {p["start"]: k for p, k in zip(nps, known)}
    inside = {i for p, k in zip(nps, known) if k for i in range(p["start"], p["end"])}
    for i, w in enumerate(toks):
        one = w in ("one", "ones") and i > 0 and toks[i - 1] in ("the", "that", "this", "those")
        asked_all = w in _WILDCARD and bool(set(toks[max(0, i - 3):i]) & _ASKS_ALL)  # "is there anything on it?"
        vague = w in _VAGUE or (w in _WILDCARD and not asked_all) or one
        if not vague or i in inside:
            continue
        seen_loc = False
        for j in range(i + 1, min(i + 6, len(toks))):
            if j in starts:
                if seen_loc and starts[j]:
                    return " ".join(toks[i:j + 1])
                break
            if toks[j] in LOCATION:
                seen_loc = True
            elif not re.match(r"^[a-z']+$", toks[j]):
                break
    return None


def _parse(st: State, keys: frozenset[str] | None, drop_weak: bool = False
           ) -> Node | None:
    """The parse steps, each refusing (`Refused`) rather than dropping a word it cannot apply."""
    toks, read = read_clauses(tokens(st.question), lambda ph: name_key(ph) in NAME_SYNONYMS or name_key(ph) in
                              (keys or frozenset()))
    st.notes += [n for n in read if n not in st.notes]
    joined, extra = strip_preamble(" ".join(toks))
    toks = resolve_pronouns(st, joined.split())
    if toks is None:
        raise Refused
    joined = " ".join(toks)
    refuse_whole_text(st, joined, bool(st.options))
    nps_all = [p for p in noun_phrases(toks) if not p["scene"]]
    if keys is not None:  # mentions first: words that name no object and are marked as none are left out
        keep = mentions(toks, nps_all, keys)
        known = mentions(toks, nps_all, keys, True)
        frail = weak(toks, nps_all, known)
        if drop_weak:  # the stray words leave; the rest of the reading stays as it was
            keep = [k and not f for k, f in zip(keep, frail)]
        st.weak = [" ".join(p["words"]) for p, k, f in zip(nps_all, keep, frail) if k and f]
        prop = [p for p, k in zip(nps_all, known) if not k and p["start"] > 0 and toks[p["start"] - 1] in _DEGREE]
        if drop_weak and prop:  # never left out: they say what is asked ("more comfortable than")
            st.notes.append(f"'{' '.join(prop[0]['words'])}': a property the map does not hold")
            raise Refused
        vague = told_by_place(toks, nps_all, known)
        if vague:  # "bigger than whatever sits by the window": the window places the object, never stands in for it
            st.notes.append(f"'{vague}': an object told by its place, not named")
            raise Refused
        st.dropped = [" ".join(p["words"]) for p, k in zip(nps_all, keep) if not k]
        if st.dropped:
            nps_all = [p for p, k in zip(nps_all, keep) if k]
            st.notes.append(f"read as no object: {', '.join(repr(w) for w in st.dropped)}")
    walk = has(joined, WALK_RX) or has(joined, r"\bturn")
    kind_word = "route" if route_options(st.options) and walk else intent(joined, len(nps_all), bool(st.options))
    if kind_word is None:  # no wording rule applies: the kind whose cue words score highest, if only one does
        kind_word, why = kind_of(joined.split())
        if kind_word is None:
            st.notes.append("no question type recognised (counting, count comparison, existence, size, size "
                            "comparison, distance, nearest, direction, left-of / behind, where, list, room size, "
                            f"appearance order): {why}")
            raise Refused
        st.notes.append(f"the kind read from its cue words ({why})")
    nps = attachments(toks, nps_all) if kind_word not in ("rel_distance", "direction", "route") else nps_all
    first = next((i for i, t in enumerate(toks) if t in _TRIGGERS.get(kind_word, ())), None)
    if first is not None:  # "Quick question: how many chairs ...": the object comes after the question's cue
        nps = [p for p in nps if p["start"] > first] or nps
    kind = f"{'an' if kind_word[0] in 'aeiou' else 'a'} {kind_word.replace('_', ' ')} question"
    used = {w for sel in (p["sel"] for p in nps_all) for w in sel}
    ordinal = [w for w in toks if w in RANKS and w not in used]
    if ordinal:  # "the second closest object": a rank the reasoner does not compute; never dropped silently
        st.refuse(kind, f"the rank '{ordinal[0]}' (only the nearest / farthest or one object at a time)")
    cut = re.search(EXCEPT_RX, joined)
    exclude = [p for p in nps if cut and p["start"] >= len(joined[:cut.start()].split())]
    node = HANDLERS[kind_word](st, toks, joined, [p for p in nps if p not in exclude], extra)
    if node is None:
        return None
    if exclude:  # "closest to the sofa, apart from the bin": those leave the candidates
        if not (isinstance(node, Nearest) and node.among_everything):  # never answered as if it had not been said
            st.refuse(kind, f"the exception '{cut.group(0)} {' '.join(exclude[0]['words'])}' (only 'what is "
                            f"nearest to X, apart from Y?' takes one)")
        node = replace(node, exclude=tuple(R(n) for n in st.refs(exclude)))
    where = counting.where_of(node)
    negation = unread_negation(toks, where is not None and where.negate)
    if negation:  # never answer the question without its "not"
        st.refuse(kind, f"the negation '{negation}' (ask it without: e.g. 'is there a ...?', 'how many ... are on "
                        f"the ...?')")
    return node
