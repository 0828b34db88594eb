"""`mosaic parse "question"`: the question's program as JSON (what `mosaic ask` executes on the map).

`--grounding rules` reads it with the rule parser; `model` with the trained reader (the `--bundle`'s `reader` role
or MOSAIC_READER's); `vlm` with the `--bundle`'s VLM under the program's JSON schema
(constrained decoding); `auto` (default) with the rules, and the VLM (when the bundle has one) for what they refuse. `--schema` prints the versioned JSON schema instead (`--schema vlm`:
the bounds the VLM decodes under). No map and no frames are read.
"""
from __future__ import annotations

import argparse
from typing import Any

from ..infra import jsonio
from ..infra.errors import InputError
from ..grounding import bundle_reader, check_question, ground, split_inline_options
from ..infra.trace import Trace
from ..pipeline import load_vlm
from ..query.schema import json_schema
from .flags import add_grounding

COMMON_FLAGS = ("bundle",)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("question", nargs="?", help="the question in plain English (or VSI-Bench wording)")
    p.add_argument("--option", action="append", default=None, metavar="TEXT",
                   help='a multiple-choice option, repeat for each ("A. left")')
    add_grounding(p)
    p.add_argument("--schema", nargs="?", const="full", choices=["full", "vlm"],
                   help="print the program's JSON schema (vlm: the bounds the VLM decodes under) and exit")


def run(args: argparse.Namespace) -> dict[str, Any]:
    if args.schema:
        return {"schema": "mosaicthinker.parse.schema/1", "profile": args.schema,
                "json_schema": json_schema("program" if args.schema == "full" else "ask", args.schema)}
    if not args.question or not args.question.strip():
        raise InputError("parse: give QUESTION (`mosaic parse \"How many chairs are there?\"`), or --schema")

    question, options = args.question, args.option
    check_question(question, options)
    if options is None:
        question, options = split_inline_options(question)
    trace = Trace()
    vlm = None
    if args.grounding in ("vlm", "auto") and args.bundle:  # the models only when a VLM may read the question
        vlm = load_vlm(args.bundle, trace)
    if args.grounding == "vlm" and vlm is None:
        raise InputError("`grounding=vlm` needs a bundle with a `vlm` role", fields=("grounding",))
    reader = bundle_reader(args.bundle, trace) if args.grounding in ("model", "auto") else None
    pq = ground(question, options, vlm, None, trace, args.grounding, reader=reader)
    return {"schema": "mosaicthinker.parse/1", "question": pq.question, "options": options, **pq.to_dict(),
            "warnings": [e["message"] for e in trace.events if e["kind"] in ("grounding", "random_weights")]}


def render(r: dict[str, Any]) -> str:
    if "json_schema" in r:
        return jsonio.dumps(r["json_schema"], indent=1)
    if r.get("program") is None:
        lines = ["program: none (not understood)"] + [f"  {n}" for n in r.get("notes", [])]
    else:
        lines = [jsonio.dumps(r["program"], indent=1),
                 f"  read by: {r['reader']}; type {r['qtype']}; targets {r['targets']}; cues {r['cues']}"]
        if r.get("confidence"):
            c = r["confidence"]
            lines.append(f"  reader confidence: {c['kind']} {c['kind_p']:.2f}; " + ", ".join(
                f"{s['role']} '{s['text']}' {s['p']:.2f}" for s in c["spans"]))
        if r.get("unknown"):
            lines.append(f"  not in the vocabulary (matched by name): {', '.join(r['unknown'])}")
        if r.get("notes"):  # spelling read otherwise, clauses set aside, words read as no object
            lines.append(f"  read: {'; '.join(r['notes'])}")
    lines += [f"  note: {w}" for w in r.get("warnings", [])]
    return "\n".join(lines)
