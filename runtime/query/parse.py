"""Question -> program: the VSI-Bench templates first (exact wording), then the rule parser (plain English), then
the trained reader (`reader`, `compose`: any wording, refused when unsure) for what the rules refuse or read with a
name nothing knows.

`parse_question(question, options) -> ParsedQuestion`: the program (None when not understood), how it was read
(`how`: "template", "model", "natural", "vlm" or "none"), the reader's confidence, and notes saying what was and
was not understood. Only the question text and the options are read.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Any, Iterable

from .compose import compose
from .ir import NearestTo, Option, Program, iter_refs, phrases
from .names import NameResolver
from .normalize import normalize
from .reader import default_reader
from .rules.parse import parse_natural
from .schema import to_json
from .templates import parse_template
from .text import check_question, clean_question, split_options
from .vocabulary import name_key


@dataclass
class ParsedQuestion:
    """A question read into a program. how: "template" (VSI-Bench wording), "natural" (the rule parser), "vlm"
    (the VLM under the schema) or "none" (not understood: `notes` say what was and was not)."""

    question: str
    options: list[str] | None = None
    program: Program | None = None
    notes: list[str] = field(default_factory=list)
    how: str = "none"
    read_as: list[str] = field(default_factory=list)  # words read otherwise than typed, said with the answer
    confidence: dict[str, Any] | None = None  # the trained reader's: kind, its probability, each span's

    @property
    def reader(self) -> str:
        """Which reader produced the program: "templates", "model", "rules", "vlm" (or "none")."""
        return {"template": "templates", "natural": "rules"}.get(self.how, self.how)

    @property
    def node(self) -> Any:
        return None if self.program is None else self.program.ask

    @property
    def qtype(self) -> str | None:
        return None if self.program is None else self.program.qtype

    @property
    def targets(self) -> list[str]:
        """Names of the objects asked about, ranked (key-frame search weighs them 1)."""
        return list(dict.fromkeys(self.node.roles()[0])) if self.node is not None else []

    @property
    def cues(self) -> list[str]:
        """Names of the reference objects (weighed 0.5), then the objects a selector needs ("nearest the door")."""
        if self.node is None:
            return []
        targets = self.targets
        cues = [c for c in dict.fromkeys(self.node.roles()[1]) if c not in targets]
        seen: set[str] = set()
        for r in iter_refs(self.node):
            near = [s.name for s in r.select if isinstance(s, NearestTo)]
            if near and r.name not in seen:
                seen.add(r.name)
                cues += [n for n in near if n not in targets]
        return cues

    @property
    def objects(self) -> list[str]:
        """Targets then cues, without repeats."""
        return list(dict.fromkeys(self.targets + self.cues))

    @property
    def whole_map(self) -> bool:
        """About everything in the map (room size, a list, "how many objects", "the biggest object", "the nearest
        object to the cup"): the map is built for every category the detector names, not for named objects."""
        return self.node is not None and self.node.whole_map

    @property
    def unknown(self) -> list[str]:
        """The question's words of every object name the vocabulary does not hold (open vocabulary)."""
        return list(dict.fromkeys(r.words for r in iter_refs(self.node) if not r.known and r.name != "*")) \
            if self.node is not None else []

    def phrase(self, name: str) -> str:
        """The question's own words for the object called `name` (the name itself when none was recorded)."""
        return phrases(self.node).get(name, name) if self.node is not None else name

    def describe(self) -> str:
        """One line saying how the question was read (for replies and as a hint in the VLM prompt)."""
        if self.program is None:
            return "not understood" + (f" ({'; '.join(self.notes)})" if self.notes else "")
        return f"{self.qtype} " + json.dumps(to_json(self.node), separators=(",", ":")) + \
            (f"; not used: {'; '.join(self.notes)}" if self.notes else "")

    def to_dict(self) -> dict[str, Any]:
        return {"how": self.how, "reader": self.reader, "confidence": self.confidence, "qtype": self.qtype, "targets": self.targets, "cues": self.cues,
                "unknown": self.unknown, "notes": list(self.notes), "read_as": list(self.read_as),
                "program": None if self.program is None else to_json(self.program)}


def program_of(node: Any, options: list[str] | None) -> Program:
    return Program(node, tuple(Option(letter, text) for letter, text in split_options(options)))


def parse_question(question: str, options: list[str] | None = None, names: Iterable[str] = (),
                   reader: Any = "env", readers: str = "auto") -> ParsedQuestion:
    """Parse a question: the VSI-Bench templates first (exact wording), then the rule parser, then the trained
    reader for what the rules refuse (`reader`: a `query.reader.ModelReader`, "env" for `MOSAIC_READER`'s, None
    for none; `readers`: "model" = the reader alone, "rules" = the rules alone, "auto" = both). The program
    is None when the question is not understood (`notes` say what was and was not). names: object names beyond
    the vocabulary the question may mention (a map's categories, a detector's labels). Questions over
    `text.MAX_QUESTION_CHARS` are an InputError."""
    check_question(question, options)
    q = clean_question(question)
    opts = list(options) if options is not None else None
    node, notes, matched = parse_template(q)
    if matched:
        return ParsedQuestion(q, opts, program_of(node, opts) if node is not None else None, notes,
                              "template" if node is not None else "none")
    model = default_reader() if reader == "env" else reader
    if readers == "model":
        if model is None:
            return ParsedQuestion(q, opts, None, ["not understood: no trained reader (`mosaic export reader`, "
                                                  "`--bundle` with a reader role or MOSAIC_READER)"], "none")
        return read_with_model(model, q, opts, names)
    pq = parse_rules(q, opts, names)
    if model is None or readers == "rules" or (pq.program is not None and not unread(pq, names)):
        return pq
    # auto: the trained reader reads what the rules refuse, and a question whose rule program names an object no
    # vocabulary or map knows (a typo, another name: the reader matches names by meaning); its program is kept
    # only when it names known objects (docs/query.md: measured, it is not yet ahead of the rules)
    pm = read_with_model(model, q, opts, names)
    if pm.program is not None and (pq.program is None or not unread(pm, names)):
        why = f"the rules refused ({'; '.join(pq.notes)[:200]})" if pq.program is None else \
            f"the rules read {', '.join(repr(w) for w in unread(pq, names))}, a name nothing knows"
        pm.notes = [f"{why}; read by the trained reader"] + pm.notes
        return pm
    if pq.program is None:
        pq.notes = pq.notes + pm.notes
        pq.confidence = pm.confidence
    return pq


def unread(pq: ParsedQuestion, names: Iterable[str]) -> list[str]:
    """The question's words for each object of the program that neither the vocabulary nor `names` knows."""
    keys = {name_key(n) for n in names}
    return list(dict.fromkeys(r.words for r in iter_refs(pq.node)
                              if not r.known and r.name != "*" and name_key(r.name) not in keys))


def read_with_model(model: Any, q: str, opts: list[str] | None, names: Iterable[str]) -> ParsedQuestion:
    """The trained reader's program (or its refusal), names resolved by the vocabulary, the map and by meaning."""
    r = model.read(q)
    node, notes = compose(r, q, opts, NameResolver(model, names))
    conf = {"kind": r.kind, "kind_p": r.kind_confidence,
            "spans": [{"role": s.role, "text": s.text, "p": s.confidence} for s in r.spans]}
    if getattr(model, "random_weights", False):
        notes = notes + ["the reader has RANDOM weights (test model): its readings are meaningless"]
    return ParsedQuestion(q, opts, program_of(node, opts) if node is not None else None, notes,
                          "model" if node is not None else "none", [], conf)


def parse_rules(q: str, opts: list[str] | None, names: Iterable[str]) -> ParsedQuestion:
    """The rule parser (plain English) on a cleaned question that no template matched."""
    node, st = parse_natural(normalize(q, names), opts, names)  # units, numbers in words: the parser's own words
    return ParsedQuestion(q, opts, program_of(node, opts) if node is not None else None, st.notes,
                          "natural" if node is not None else "none")
