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
from typing import Callable

from ..ir import Nearest, Node
from . import counting, directions, distances, measures
from .intent import EXCEPT_RX, intent, refuse_whole_text, strip_preamble, unread_negation
from .lexicon import RANKS
from .locations import attachments, resolve_pronouns
from .state import R, Refused, State
from .tokens import noun_phrases, tokens

Handler = Callable[[State, list, str, list, dict], "Node | None"]
HANDLERS: dict[str, Handler] = {
    "count": counting.count, "count_compare": counting.count_compare, "existence": counting.exists,
    "relation": counting.exists, "view_direction": directions.view_direction, "view_list": counting.view_list,
    "size": measures.size, "size_compare": measures.size_compare, "room_size": measures.room_size,
    "abs_distance": distances.abs_distance, "rel_distance": distances.rel_distance, "direction": directions.direction,
    "where": directions.where, "list": counting.list_objects, "obj_appearance_order": directions.appearance_order}

# the cue words after which a question's object comes ("Quick question: how many chairs ...")
_TRIGGERS = {"count": {"many", "count", "number", "quantity", "total"},
             "size": {"big", "large", "long", "tall", "wide", "high", "deep", "size", "dimension", "dimensions",
                      "length", "height", "width", "depth", "measure", "longest", "biggest", "largest"},
             "existence": {"there", "see", "spot", "find", "notice", "have", "contain", "any", "exist", "exists"},
             "where": {"where", "where's", "locate", "location", "position", "whereabouts"}}


def parse_natural(question: str, options: list[str] | None = None) -> tuple[Node | None, State]:
    """(the question's node, or None when its kind or its objects are not understood; the parse state, whose
    notes say what was understood and what was not). `question` is already cleaned (`text.clean_question`)."""
    st = State(question, options)
    try:
        node = _parse(st)
    except Refused:
        node = None
    return (st.finish(node) if node is not None else None), st


def _parse(st: State) -> Node | None:
    """The parse steps, each refusing (`Refused`) rather than dropping a word it cannot apply."""
    joined, extra = strip_preamble(" ".join(tokens(st.question)))
    toks = resolve_pronouns(st, joined.split())
    if toks is None:
        raise Refused
    joined = " ".join(toks)
    refuse_whole_text(st, joined, bool(st.options))
    nps_all = [p for p in noun_phrases(toks) if not p["scene"]]
    kind_word = intent(joined, len(nps_all), bool(st.options))
    if kind_word is None:
        st.notes.append("no question type recognised (counting, count comparison, existence, size, size comparison, "
                        "distance, nearest, direction, left-of / behind, where, list, room size, appearance order)")
        raise Refused
    nps = attachments(toks, nps_all) if kind_word not in ("rel_distance", "direction") else nps_all
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
