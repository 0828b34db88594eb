"""Run a program on a map: one executor per node, the answer's text in the question's units and options, and
its evidence. `execute` is pure (a program and a map in, an `Answer` out); `MapReasoner` parses and executes
with a map's index built once.

Conventions (general geometric rules; they reproduce the benchmark's own answers, see docs/reasoner-vsibench.md):
counting = instances of the category; size = longest box side (cm); room size = floor area of the map's room
extent; distances = closest points of the solid boxes over the nearest instance pair; directions on the floor
plane from A's centre facing B's centre (counter-clockwise angle of C's centre, left positive); routes turn at
each waypoint (back from `ReasonerConfig.back_deg`); appearance order by earliest first-seen time.
"""
from __future__ import annotations

import re
from dataclasses import replace
from typing import Any, Callable

import numpy as np

from ..query.ir import (AppearanceOrder, Count, CountCompare, Direction, Distance, Exists, List, Nearest, Program,
                        RoomSize, Route, Size, SizeCompare, ViewDirection, Where, phrases)
from ..query.parse import ParsedQuestion, parse_question, program_of
from ..query.rules.lexicon import examples
from ..query.rules.tokens import direction_words, noun_phrases, tokens
from ..query.text import safe_text, split_options
from . import counting, directions, distances, evidence, measures
from .context import Ctx
from .index import MapIndex
from .result import NUMERIC_QTYPES, Answer, NotFound, ReasonerConfig, Unsupported

Executor = Callable[[Any, Ctx], "tuple[Any, str]"]
EXECUTORS: dict[type, Executor] = {
    Count: counting.count, Exists: counting.exists, CountCompare: counting.count_compare, List: counting.list_objects,
    Size: measures.size, SizeCompare: measures.size_compare, RoomSize: measures.room_size,
    Distance: distances.distance, Nearest: distances.nearest, Direction: directions.direction,
    ViewDirection: directions.view_direction, Where: directions.where, Route: directions.route,
    AppearanceOrder: directions.appearance_order}


def execute(program: Program, index: Any, conf: ReasonerConfig | dict | None = None,
            parsed: ParsedQuestion | None = None) -> Answer:
    """The answer of `program` on a map (`SemanticMap` or its `MapIndex`). An object the map lacks gives
    status "not_found" (never a guess); a program the map cannot decide "unsupported", saying why."""
    index = index if isinstance(index, MapIndex) else MapIndex(index)
    conf = ReasonerConfig.merged(conf)
    node, qtype = program.ask, program.qtype
    options = [f"{o.letter}. {o.text}" for o in program.options] or None
    ctx = Ctx(index, conf, program.options)
    try:
        value, expl = EXECUTORS[type(node)](node, ctx)
    except NotFound as e:
        hint = f" (the map has no such name; similar names in the map: {', '.join(e.hints)})" if e.hints else ""
        return Answer(f"not found: {', '.join(e.names)}", 0 if qtype == "object_counting" else None, "not_found",
                      f"not in the map: {', '.join(e.names)}{hint}", e.names, qtype, parsed, hints=e.hints)
    except Unsupported as e:
        return Answer(f"unsupported: {e}", None, "unsupported", str(e), [], qtype, parsed)
    ans = _answer(program, index, conf, value, expl, options, parsed)
    if ans.ok:
        q = ctx.spread or (None, [], None)
        ans.evidence = evidence.build(ctx.used, q[0], q[1], q[2], ctx.ambiguous)
        if ctx.ambiguous:  # said in the answer itself, not only in the evidence
            ans.explanation += "; " + "; ".join(evidence.ambiguity_text(a) for a in ctx.ambiguous)
    if parsed is not None and parsed.read_as:  # the words read otherwise than typed are said with the answer
        ans.explanation += "; " + "; ".join(parsed.read_as)
    return ans


def _answer(program: Program, index: MapIndex, conf: ReasonerConfig, value: Any, expl: str,
            options: list[str] | None, parsed: ParsedQuestion | None) -> Answer:
    """The answer's text: a number in the question's unit, the option letter, or the value's own text."""
    qtype = program.qtype
    unit = getattr(program.ask, "unit", None) if qtype in NUMERIC_QTYPES else None
    if not options and isinstance(value, dict) and "text" in value:  # e.g. a count per object
        return Answer(value["text"], value, "ok", expl, [], qtype, parsed)
    if qtype in NUMERIC_QTYPES and not options:
        return Answer(format_number(qtype, value, unit, conf), value, "ok", expl, [], qtype, parsed, unit)
    if not options and isinstance(value, str):  # an object or a direction, in the question's own words
        return Answer(phrases(program.ask).get(value, value), value, "ok", expl, [], qtype, parsed)
    letter, text = choose(value, options, index, program, conf)
    if letter is None:
        return Answer(f"unsupported: the answer {value!r} fits none of the options", value, "unsupported",
                      expl + f"; options: {options}", [], qtype, parsed, unit)
    if options:
        expl += f" -> option {letter}. {text}"
    return Answer(letter, value, "ok", expl, [], qtype, parsed, unit)


def format_number(qtype: str, v: float, unit: str | None, conf: ReasonerConfig) -> str:
    if qtype == "object_counting":
        return str(int(round(v)))
    if qtype == "object_size_estimation" and unit in (None, "cm", "mm"):
        return str(int(round(v)))
    if qtype == "room_size_estimation":
        d = conf.room_decimals
    elif qtype == "object_abs_distance" and unit in (None, "m"):
        d = conf.distance_decimals
    else:  # other units keep the precision of a centimetre
        d = {"m": 2, "ft": 2, "in": 1, "cm": 0, "mm": 0}.get(unit or "m", 2)
    return f"{round(float(v), d):.{d}f}"


def _norm(s: str) -> str:
    return " ".join(str(s).lower().replace(",", " , ").split())


def _option_key(text: str) -> str:
    """An option's text as a comparable value: a direction word, a turn list, or an object's map key."""
    t = _norm(text)
    dirs = direction_words(t)
    if dirs and len(t.split()) <= 6 and not re.search(r"\bturn\b", t):
        return dirs[0]
    return t


def choose(value: Any, options: list[str] | None, index: MapIndex, program: Program,
           conf: ReasonerConfig) -> tuple[str | None, Any]:
    """Option letter for a computed value: the same text, direction or object (through the map's names and
    synonyms), else the nearest number when it is plausibly close (`option_rel_tol`)."""
    if not options:  # a list of objects in the question's own words ("couch, desk"), of turns as they are
        words = phrases(program.ask)
        return (str(value) if not isinstance(value, list) else ", ".join(words.get(v, v) for v in value)), value
    opts = split_options(options)
    want = _norm(", ".join(value) if isinstance(value, list) else value)
    for letter, text in opts:
        if _norm(text) == want or (isinstance(value, str) and _option_key(text) == want):
            return letter, text
    if isinstance(value, list) and value and all(isinstance(v, str) for v in value) and not any(
            re.fullmatch(r"Turn (?:Left|Right|Back)", v) for v in value):  # an order of objects, in other words
        want_ids = [{id(o) for o in index.find(v, phrases(program.ask).get(v, v))} for v in value]
        hits = []
        for letter, text in opts:
            items = [t for t in re.split(r",|;|->|\bthen\b|\band\b", text) if t.strip()]
            got = [{id(o) for o in index.find(_name_of(t))} for t in items]
            if len(got) == len(want_ids) and all(g and g == w for g, w in zip(got, want_ids)):
                hits.append((letter, text))
        if len(hits) == 1:
            return hits[0]
    if isinstance(value, list) and value and all(re.fullmatch(r"Turn (?:Left|Right|Back)", v) for v in value):
        turns = [v.split()[1].lower() for v in value]  # "left then right", "L, R": the turns in order
        hits = [(letter, text) for letter, text in opts if re.findall(r"\b(left|right|back)\b", text.lower()) == turns]
        if len(hits) == 1:
            return hits[0]
    if isinstance(value, str):
        ids = {id(o) for o in index.find(value, phrases(program.ask).get(value, value))}
        if ids:  # "A. couch" for the map's sofa
            for letter, text in opts:
                nps = [p for p in noun_phrases(tokens(text)) if not p["scene"]]
                name = " ".join(nps[0]["words"]) if nps else text
                hit = {id(o) for o in index.find(name)}
                if hit and hit == ids:
                    return letter, text
    if isinstance(value, (int, float, np.floating, np.integer)) and not isinstance(value, bool):
        nums = []
        for letter, text in opts:
            m = re.match(r"\s*([-+]?\d+(?:\.\d+)?)", text)  # "2.5", "2.5 m", "160 cm"
            if m:
                nums.append((abs(float(m.group(1)) - float(value)), letter, text, float(m.group(1))))
        if nums:
            d, letter, text, x = min(nums)
            if d <= conf.option_rel_tol * max(abs(x), abs(float(value)), 1e-9):
                return letter, text
    return None, value


def _name_of(text: str) -> str:
    """The object an option's item names (its first object phrase, else the text)."""
    nps = [p for p in noun_phrases(tokens(text)) if not p["scene"]]
    return " ".join(nps[0]["words"]) if nps else text.strip()


def not_understood(pq: ParsedQuestion) -> Answer:
    """The reply to a question without a program: what was understood, what was not, example wordings."""
    why = "; ".join(pq.notes) or "not a question type the map reasoner knows"
    ex = examples()[::4][:4]
    return Answer(f"unsupported: {safe_text(why, 240)}. Try e.g.: " + " | ".join(ex), None, "unsupported",
                  f"{why}; `mosaic ask --examples` lists the wordings the map reasoner understands", [], None, pq)


class MapReasoner:
    """Answers questions from a `SemanticMap`: parse (`query.parse_question`) then `execute`. Holds the map's
    index (built once, shared by every question) and the conventions; nothing of any one question."""

    def __init__(self, smap: Any, conf: ReasonerConfig | dict | None = None):
        self.map = smap
        self.conf = ReasonerConfig.merged(conf)
        self.index = MapIndex(smap)

    def answer(self, question: str, options: list[str] | None = None,
               parsed: ParsedQuestion | None = None) -> Answer:
        """Answer one question. `parsed` may be given (e.g. from a VLM's program); else `parse_question`."""
        pq = parsed if parsed is not None else parse_question(question, options, self.index.names)
        if pq.program is None:
            return not_understood(pq)
        program = pq.program
        if options is not None and [f"{o.letter}. {o.text}" for o in program.options] != \
                [f"{a}. {b}" for a, b in split_options(options)]:  # options given apart from the parse
            program = replace(program, options=program_of(program.ask, options).options)
        return execute(program, self.index, self.conf, pq)
