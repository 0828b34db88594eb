"""`mosaic ask VIDEO_OR_FOLDER_OR_MAP "question"`: answer a spatial question, write map.png and trace.json.

Thin argument parsing over `pipeline.ask` (the Python API). Options of a multiple-choice question go in
`--option` (repeatable, "A. left") or are read from the question text ("... Options: A. x B. y").
"""
from __future__ import annotations

import argparse
import gc
import json
import re
from pathlib import Path
from typing import Any

from ..infra import jsonio
from ..infra.errors import InputError
from ..infra.outputs import RunOutputs, note_outputs, save_run, unfinished_run_note
from ..grounding import split_inline_options  # linear; lives with the question parser
from ..cli import add_stage_flags
from .flags import add_answerer, add_grounding, add_keyframes
from .. import pipeline
from ..budget import load_profile
from ..infra.trace import Trace
from ..grounding import check_question
from ..infra.bundle import COPYLEFT, load_bundle
from ..map import SemanticMap
from ..answer import UNIT_WORDS
from ..answer.evidence import line
from ..query.rules.lexicon import EXAMPLES


# trace events the printed answer repeats (a degraded or re-planned run says so next to its answer)
WARNING_KINDS = ("fallback", "degraded", "random_weights", "not_in_map", "unknown_objects", "output", "input",
                 "replan", "reduced_plan", "scale")

def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("source", nargs="?", help="video file, image / RGB-D folder, or a saved map (map.json)")
    p.add_argument("question", nargs="?", help="the question in plain English (`--examples` lists wordings the "
                                               "map reasoner understands)")
    p.add_argument("--examples", action="store_true", help="list example questions the map reasoner answers")
    p.add_argument("--option", action="append", default=None, metavar="TEXT",
                   help='a multiple-choice option, repeat for each ("A. left")')
    add_answerer(p)
    add_grounding(p)
    p.add_argument("--explain", action="store_true", help="print the question's program (JSON) with the answer")
    p.add_argument("--method", choices=["mosaic", "direct"], default="mosaic",
                   help="mosaic (semantic map) or direct (Direct Input baseline: sampled frames to the VLM)")
    p.add_argument("--prompt", choices=["grid", "points", "text", "json"], default="grid",
                   help="visual prompt mode (json: compact spatial code, no image)")
    add_keyframes(p)
    p.add_argument("--keyframe-method", choices=["iterative", "uniform", "exhaustive"], default="iterative")
    add_stage_flags(p, matcher=True, detector=True)
    for a in p._actions:  # one flag definition (cli.add_stage_flags); ask's own default: the bundle's matcher
        if a.dest == "matcher":
            a.help = "feature matcher (default: the bundle's matcher model when it has one, else sift)"
    p.set_defaults(detector="model", matcher=None)
    p.add_argument("--depth", choices=["auto", "sensor", "model"], default="auto",
                   help="depth source (auto: sensor depth when the source has it, else the bundle's depth model)")
    p.add_argument("--miss-rate", type=float, default=0.1, help="oracle detector miss rate (synthetic scenes)")




def run(args: argparse.Namespace) -> dict[str, Any]:
    if args.examples:
        return {"schema": "mosaicthinker.ask.examples/1", "examples": EXAMPLES}
    if not args.source or not args.question or not args.question.strip():
        raise InputError("ask: give SOURCE and QUESTION (`mosaic ask map.json \"How many chairs are there?\"`), "
                         "or --examples")

    question, options = args.question, args.option
    check_question(question, options)
    if options is None:
        question, options = split_inline_options(question)
    trace = Trace()
    profile = load_profile(args.profile) if args.profile else None
    if profile is not None:
        profile.apply_to_machine(trace)  # core_affinity applied (or refused loudly), threads fit to the cores
    matcher = args.matcher or default_matcher(args.bundle)
    trace.decide("ask.matcher", {"matcher": matcher, "given": args.matcher is not None})
    conf = {"depth": args.depth, "matcher": matcher, "keyframe": {"keyframe_method": args.keyframe_method}}
    perception = None
    src = Path(args.source)
    is_map = src.suffix.lower() == ".json"
    if args.detector == "oracle" and not is_map and args.method == "mosaic":
        if not (src.is_dir() and (src / "scene.json").is_file()):
            raise InputError(f"{src}: --detector oracle needs a synthetic scene folder (with scene.json, from "
                             f"`mosaic synth`); use --detector model with a --bundle for real videos")
        from mosaicthinker.host.evaluation.oracle_perception import oracle_perception

        perception = oracle_perception(src, miss_rate=args.miss_rate, matcher=matcher
                                       if matcher != "model" else "sift")
        trace.decide("perception", perception.describe)
    out = Path(args.out) if args.out else None
    outs, gc_off = None, False
    try:
        outs = RunOutputs(out) if out is not None else None  # checked and locked before the pipeline runs
        note_outputs(outs, trace)
        source: Any = args.source
        # a map or frame folder written by a run that did not finish (killed, interrupted) says so
        held = src if src.is_dir() else src.parent if is_map and src.exists() else None
        unfinished = unfinished_run_note(held) if held is not None else None
        if unfinished and (outs is None or outs.folder.resolve() != held.resolve()):
            trace.event("input", unfinished, warn=False)
        if is_map:
            source = SemanticMap.load(src)
            # answering a saved map makes no reference cycles worth collecting, while the cyclic collector would
            # walk the map's objects again and again (100 k objects: 1-1.5 s of CPU): off until the command ends
            gc_off = gc.isenabled()
            gc.disable()
        req = pipeline.AskRequest(answerer=args.answerer, method=args.method, prompt_mode=args.prompt,
                                  grounding=args.grounding, keyframes=args.keyframes,
                                  render_image=out is not None, conf=conf, profile=profile)
        res = pipeline.ask(source, question, options, req, perception=perception, bundle=args.bundle, trace=trace)
        files, write_error, code = {}, None, 0
        if outs is not None:
            items = []
            if res.prompt is not None and res.prompt.image is not None:
                items.append(("map_png", "map.png", res.prompt.image))
            if res.prompt is not None:  # the text the VLM gets (with the image unless --prompt text)
                items.append(("prompt_txt", "prompt.txt", res.prompt.full_text(question, options)))
            if res.map is not None:
                items.append(("map_json", "map.json", res.map))
            items.append(("trace_json", "trace.json", trace.to_dict()))
            files, write_error, code = save_run(outs, items)
    finally:
        if outs is not None:
            outs.close()
        if gc_off:
            gc.enable()
    d = res.to_dict(rows=bool(getattr(args, "json", True)))  # printed: the object count alone
    d.update({"schema": "mosaicthinker.ask/1", "question": question, "options": options, "files": files,
              "explain": bool(args.explain),
              "warnings": [e["message"] for e in trace.events if e["kind"] in WARNING_KINDS],
              "random_weights_used": trace.random_weights_used, "evidence": res.answer.evidence,
              "ran": what_ran(trace, args.depth, res.build is not None),
              "undetectable": sorted({n for e in trace.events if e["kind"] == "undetectable"
                                      for n in e.get("names", [])}),
              "seconds": trace.wall_seconds()})
    if outs is not None:
        d.update({"run_id": outs.run_id, "write_error": write_error, "exit_code": code or d.get("exit_code", 0)})
    return d


def default_matcher(bundle: Any) -> str:
    """'model' when the bundle has a `matcher` role (its learned matcher is what it was built with), else sift."""
    if not bundle:
        return "sift"

    try:
        return "model" if load_bundle(bundle).has_role("matcher") else "sift"
    except InputError:
        return "sift"  # an unreadable bundle fails later with its own message, where it is loaded


def what_ran(trace: Any, depth: str, built: bool) -> dict[str, Any] | None:
    """Depth source, matcher and model variants that ran (None for a saved map: no perception ran). Depth: the
    `depth` stage ran only when the depth model did (auto on RGB-D uses the sensor)."""
    if not built:
        return None
    desc = trace.decisions.get("perception") or {}
    model_depth = "depth" in trace.stages
    dd = desc.get("depth")
    out: dict[str, Any] = {"depth": ("model " + _variant(dd)) if model_depth and dd else
                           "model" if model_depth else "sensor"}
    if depth == "auto":
        out["depth"] += " (auto)"
    m = desc.get("matcher")
    out["matcher"] = _variant(m) if m is not None else "?"
    out["models"] = {r: _variant(v) for r, v in desc.items() if isinstance(v, dict) and r not in ("matcher",)
                     and not (r == "depth" and not model_depth)}
    return out


def _variant(v: Any) -> str:
    """A model that ran, in a few words: its name (else its arch) and variant, and a copyleft or restricted
    licence in brackets (AGPL-3.0 reaches whoever ships or serves the answer)."""
    if isinstance(v, dict):
        text = " ".join(str(v[k]) for k in (("model" if v.get("model") else "arch"), "variant") if v.get(k))
        lic = str(v.get("licence") or "")
        if any(lic.upper().startswith(c) for c in COPYLEFT):
            text += f" [{lic}]"
        return text or str(v.get("role", "?"))
    return str(v)


def _unit_suffix(r: dict[str, Any]) -> str:
    """" m" after a plain number in a unit (a person reads "1.3 m", the benchmark scores the number alone)."""
    unit, text = r.get("unit"), str(r.get("answer", ""))
    if r.get("status") != "ok" or not unit or not re.fullmatch(r"-?\d+(?:\.\d+)?", text):
        return ""
    return " " + UNIT_WORDS.get(unit, unit)


def render(r: dict[str, Any]) -> str:
    if "examples" in r:
        return "\n".join(f"{k}:\n" + "\n".join(f"  {e}" for e in v) for k, v in r["examples"].items())
    lines = [f"answer: {r['answer']}" + _unit_suffix(r)]
    if r.get("explanation"):
        lines.append(f"  how: {r['explanation']}")
    if r.get("explain"):
        g = r.get("grounding") or {}
        prog = g.get("program")
        lines.append(f"  program ({g.get('how', 'none')}): " + (jsonio.dumps(prog["ask"]) if prog else
                                                                "none (" + "; ".join(g.get("notes") or []) + ")"))
    if r.get("objects") is not None:
        lines.append(f"  map: {r['objects']} object(s)" + (f" from {len(r['keyframes'])} key frames"
                                                                   if r.get("keyframes") else "")
                     + (f" ({len(r['unaligned'])} unaligned, left out)" if r.get("unaligned") is not None else ""))

    if r.get("evidence"):
        lines.append("  " + line(r["evidence"]))
    if r.get("ran"):
        ran = r["ran"]
        models = ", ".join(f"{k} {v}" for k, v in ran.get("models", {}).items())
        lines.append(f"  ran: depth {ran['depth']}; matcher {ran['matcher']}" + (f"; {models}" if models else ""))
    if r.get("undetectable"):
        lines.append(f"  cannot detect (no such class in the bundle's detector; not looked for): "
                     f"{', '.join(r['undetectable'])}")
    for w in r.get("warnings", []):
        lines.append(f"  note: {w}")
    if r.get("random_weights_used"):
        lines.append("  WARNING: random-weight (test) models were used: the answer is meaningless")
    for k, v in r.get("files", {}).items():
        lines.append(f"  wrote {v}")
    lines.append(f"  ({r.get('seconds', 0):.1f} s)")
    return "\n".join(lines)
