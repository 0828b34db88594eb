"""The VLM emits the question's program, under constrained decoding (LLGuidance with the program's JSON schema,
through ONNX Runtime GenAI's `GeneratorParams.set_guidance("json_schema", ...)`).

`ground_with_vlm(vlm, question, options, frames, trace)` asks a VLM that can decode under a schema
(`vlm.generate(images, prompt, max_new_tokens, guidance=("json_schema", schema))`, the GenAI adapter) for the
node of the question (`schema.json_schema("ask", profile="vlm")`: the IR's own schema with tighter bounds on
strings and lists, so a decoding of any model ends within `VLM_MAX_TOKENS`), validates the reply against the full
schema (`schema.from_json`), canonicalises its object names through the vocabulary, and returns it as a
`ParsedQuestion` (how "vlm"). A VLM without constrained decoding, a reply that is not a valid program (cut off at
the token limit, say) or a failed generation is refused with the reason (how "none", the note says why): the
program is never repaired or guessed.
"""
from __future__ import annotations

import json
from typing import Any

from .ir import SCHEMA_VERSION, Node, Program, Ref, map_refs
from .parse import ParsedQuestion, program_of
from .schema import ProgramError, from_json, json_schema, max_output_bytes
from .text import clean_question, split_options
from .vocabulary import canonical_name, name_key

# the longest reply the VLM profile's schema accepts (bytes; a token is at least one byte) and the end token: a
# decoding under the schema is never cut off before its program is complete
VLM_MAX_TOKENS = max_output_bytes(json_schema("ask", profile="vlm")) + 1

PROMPT = (
    "Write the question as a JSON program. kind: count, exists, count_compare, size, size_compare, room_size, "
    "distance (b null: from me), nearest (candidates closest to origin), direction (at stand facing face, where is "
    "target), view_direction, where, list, route (start, face, steps), appearance_order. An object: "
    "{{\"name\":\"chair\"}}; every object: {{\"name\":\"*\"}}.\nQuestion: {question}\n{options}")


def vlm_prompt(question: str, options: list[str] | None) -> str:
    opts = "".join(f"Option {letter}: {text}\n" for letter, text in split_options(options))
    return PROMPT.format(question=" ".join(str(question).split()), options=opts)


def can_constrain(vlm: Any) -> bool:
    """Whether the VLM adapter decodes under a grammar (ONNX Runtime GenAI packages do)."""
    return bool(getattr(vlm, "supports_guidance", False))


def canonical(node: Node) -> Node:
    """The VLM's object names through the vocabulary ("couch" -> sofa, phrase "couch"; unknown names kept as
    their name key, `known` False)."""
    def fix(r: Ref) -> Ref:
        if r.name == "*":
            return Ref("*", "everything", True, r.select)
        canon = canonical_name(r.name)
        name = canon or name_key(r.name) or r.name
        phrase = r.phrase or r.name
        return Ref(name, "" if phrase == name else phrase, canon is not None, r.select)
    return map_refs(node, fix)


def decode_program(reply: str) -> Node:
    """The VLM's reply -> a validated node (`ProgramError` naming the first field that is wrong)."""
    return canonical(from_json(reply.strip(), Node))


def ground_with_vlm(vlm: Any, question: str, options: list[str] | None, frames: Any, trace: Any,
                    rules: ParsedQuestion | None = None, max_new_tokens: int = VLM_MAX_TOKENS) -> ParsedQuestion:
    """The question's program from the VLM (see the module doc); frames: [H, W, 3] uint8 RGB images, or a function
    returning them (decoded only when the VLM is asked); `rules`: the rule parser's reading, whose notes a refusal
    keeps (so the reply says what the rules and the VLM each did not understand)."""
    q = clean_question(question)
    opts = list(options) if options is not None else None
    notes = list(rules.notes) if rules is not None and rules.program is None else []

    def refuse(why: str) -> ParsedQuestion:
        trace.event("grounding", f"VLM grounding refused: {why}", stage="grounding", warn=True)
        return ParsedQuestion(q, opts, None, notes + [f"the VLM's program was refused: {why}"], "none")

    if not can_constrain(vlm):
        return refuse("this VLM cannot decode under a JSON schema (only ONNX Runtime GenAI packages can); "
                      "ask with --grounding rules")
    recorded = getattr(vlm, "query_schema", None)
    if recorded is not None and recorded != SCHEMA_VERSION:  # exported for another program version: said, loudly
        trace.event("degraded", f"the VLM was exported for question programs {recorded}; this runtime reads "
                                f"{SCHEMA_VERSION} (decoded under this runtime's schema)", stage="grounding", warn=True)
    schema = json.dumps(json_schema("ask", profile="vlm"))
    try:
        with trace.stage("grounding.vlm"):
            images = list((frames() if callable(frames) else frames) or [])
            reply = str(vlm.generate(images, vlm_prompt(q, opts), max_new_tokens=max_new_tokens,
                                     guidance=("json_schema", schema)))
    except Exception as e:  # noqa: BLE001 - a VLM failure must not lose the question: refused, loudly
        return refuse(f"generation failed ({type(e).__name__}: {e})")
    trace.decide("grounding.vlm_reply", reply)
    try:
        node = decode_program(reply)
    except ProgramError as e:
        return refuse(f"{e} (reply {reply[:120]!r})")
    program: Program = program_of(node, opts)
    return ParsedQuestion(q, opts, program, [], "vlm")
