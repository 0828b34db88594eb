"""Task grounding (the paper's first stage): the question -> a typed program whose object references are the
key-frame search's targets and cues.

`ground(question, options, vlm, frames, trace, grounding, names, reader)`: `grounding="rules"` reads the question
with the rule parser (the VSI-Bench templates, then plain English: `query.parse_question`); `"model"` with the
templates then the trained reader alone (`query.reader`: a bundle's `reader` role, or `MOSAIC_READER`); `"vlm"`
asks the VLM for the
program under constrained decoding (`query.vlm`: LLGuidance with the program's JSON schema, the reply validated;
refused clearly when it cannot); `"auto"` (default) uses the templates, the rules, the trained reader (when there is
one) for what the rules refuse, and the VLM only for what they all refuse.
Targets are weighed 1 and cues 0.5 by key-frame scoring (`ParsedQuestion.targets` / `.cues`).

The vocabulary, question-text helpers and the parser live in `query/`; their public names are re-exported here.
"""
from __future__ import annotations

from typing import Any, Iterable

from .infra.bundle import Bundle, load_bundle
from .infra.errors import InputError
from .query.ir import QTYPES
from .query.parse import ParsedQuestion, parse_question
from .query.reader import default_reader, load_reader
from .query.vlm import ground_with_vlm
from .query.text import (MAX_OPTIONS, MAX_QUESTION_CHARS, check_question, safe_text, split_inline_options,
                         split_options)
from .query.vocabulary import NAME_SYNONYMS, VOCABULARY, canonical_name, name_key, plural, singular
from .infra.trace import as_trace

GROUNDINGS = ("rules", "model", "vlm", "auto")

__all__ = ["GROUNDINGS", "MAX_OPTIONS", "MAX_QUESTION_CHARS", "NAME_SYNONYMS", "QTYPES", "VOCABULARY",
           "ParsedQuestion", "canonical_name", "check_question", "ground", "name_key", "parse_question", "plural",
           "safe_text", "singular", "split_inline_options", "split_options"]


def ground(question: str, options: list[str] | None = None, vlm: Any = None, frames: Any = None,
           trace: Any = None, grounding: str = "auto", names: Iterable[str] = (), reader: Any = "env"
           ) -> ParsedQuestion:
    """Task grounding: question -> `ParsedQuestion` (its program, targets and cues).

    grounding: "rules" | "model" | "vlm" | "auto" (see the module doc); names: object names beyond the vocabulary the
    rule parser reads as mentions (a saved map's categories). With "vlm" or "auto" and a VLM that can decode
    under a JSON schema (`generate_json`), the VLM sees the question and `frames` ([H, W, 3] uint8 RGB) and emits
    the program; what it emits is validated (`query.schema.from_json`), and an output that fails validation is
    refused with the reason (trace event "grounding"), never guessed. Names outside the vocabulary are reported
    (trace event "unknown_objects")."""
    trace = as_trace(trace)
    if grounding not in GROUNDINGS:
        raise InputError(f"`grounding` must be one of {GROUNDINGS}, got {grounding!r}", fields=("grounding",))
    if grounding == "model":
        reader = default_reader() if reader == "env" else reader
        if reader is None:
            raise InputError("`grounding=model` needs a bundle with a `reader` role (`mosaic export reader`) or "
                             "MOSAIC_READER naming one", fields=("grounding",))
    pq = parse_question(question, options, names, reader=None if grounding == "rules" else reader,
                        readers={"rules": "rules", "model": "model"}.get(grounding, "auto"))
    if pq.confidence is not None and pq.program is not None and "RANDOM" in " ".join(pq.notes):
        trace.event("random_weights", "the question reader has RANDOM weights (test model)", stage="grounding")
    how = pq.reader
    if grounding == "vlm" or (grounding == "auto" and pq.program is None and vlm is not None):
        if vlm is None:
            raise InputError("`grounding=vlm` needs a bundle with a `vlm` role", fields=("grounding",))
        pq = ground_with_vlm(vlm, question, options, frames, trace, rules=pq)
        how = pq.reader
    if pq.unknown:
        trace.event("unknown_objects", f"question names objects outside the vocabulary: {', '.join(pq.unknown)} "
                    f"(looked for by name in the map)", names=pq.unknown, stage="grounding")
    trace.decide("grounding", {"method": how, "confidence": pq.confidence, "qtype": pq.qtype, "targets": pq.targets, "cues": pq.cues,
                               "unknown": pq.unknown})
    return pq


def bundle_reader(bundle: Any, trace: Any = None) -> Any:
    """The bundle's trained question reader (its `reader` role), else `MOSAIC_READER`'s, else None."""
    if bundle is not None:
        b = bundle if isinstance(bundle, Bundle) else load_bundle(bundle, verify=False)  # the role's files are
        # hash-checked when its spec is resolved (`load_reader`), not every file of the bundle again
        if b.has_role("reader"):
            r = load_reader(b)
            if r.random_weights and trace is not None:
                as_trace(trace).event("random_weights", "the question reader has RANDOM weights (test model)",
                                      stage="grounding")
            return r
    return default_reader()
