"""`mosaic ask VIDEO_OR_FOLDER_OR_MAP "question"`: answer a spatial question, write map.png and trace.json.

Thin argument parsing over `pipeline.ask` (the Python API). Options of a multiple-choice question go in
`--option` (repeatable, "A. left") or are read from the question text ("... Options: A. x B. y").
"""
from __future__ import annotations

import argparse
import re
from pathlib import Path
from typing import Any

from ..errors import InputError


def add_arguments(p: argparse.ArgumentParser) -> None:
    from ..cli import add_stage_flags

    p.add_argument("source", help="video file, image / RGB-D folder, or a saved map (map.json)")
    p.add_argument("question", help="the question (VSI-Bench wording is answered exactly by the map reasoner)")
    p.add_argument("--option", action="append", default=None, metavar="TEXT",
                   help='a multiple-choice option, repeat for each ("A. left")')
    p.add_argument("--answerer", choices=["map", "vlm", "auto"], default="auto",
                   help="map reasoner, VLM on the visual prompt, or auto (reasoner when it recognises the question)")
    p.add_argument("--method", choices=["mosaic", "direct"], default="mosaic",
                   help="mosaic (semantic map) or direct (Direct Input baseline: sampled frames to the VLM)")
    p.add_argument("--prompt", choices=["grid", "points", "text", "json"], default="grid",
                   help="visual prompt mode (json: compact spatial code, no image)")
    p.add_argument("--keyframes", type=int, default=None, help="key-frame budget K (default 16)")
    p.add_argument("--keyframe-method", choices=["iterative", "uniform", "exhaustive"], default="iterative")
    add_stage_flags(p, matcher=True, detector=True)
    p.set_defaults(detector="model")
    p.add_argument("--depth", choices=["auto", "sensor", "model"], default="auto",
                   help="depth source (auto: sensor depth when the source has it, else the bundle's depth model)")
    p.add_argument("--miss-rate", type=float, default=0.1, help="oracle detector miss rate (synthetic scenes)")


def split_inline_options(question: str) -> tuple[str, list[str] | None]:
    """'... ? A. left B. right C. back' -> (question, ['A. left', 'B. right', 'C. back']) when present."""
    m = re.search(r"(?:\boptions?\s*:\s*)?(?<![A-Za-z])A[.)]\s+.+?\s+B[.)]\s+.+", question, re.I | re.S)
    if not m:
        return question, None
    head, tail = question[:m.start()].rstrip(), question[m.start():]
    tail = re.sub(r"^\s*options?\s*:\s*", "", tail, flags=re.I)
    parts = re.split(r"\s+(?=[B-Z][.)]\s)", tail.strip())
    return (head, parts) if len(parts) >= 2 else (question, None)


def run(args: argparse.Namespace) -> dict[str, Any]:
    from .. import pipeline
    from ..budget import load_profile
    from ..trace import Trace

    question, options = args.question, args.option
    if options is None:
        question, options = split_inline_options(question)
    trace = Trace()
    profile = load_profile(args.profile) if args.profile else None
    conf = {"depth": args.depth, "matcher": args.matcher, "keyframe_method": args.keyframe_method}
    perception = None
    src = Path(args.source)
    is_map = src.suffix.lower() == ".json"
    if args.detector == "oracle" and not is_map and args.method == "mosaic":
        if not (src.is_dir() and (src / "scene.json").is_file()):
            raise InputError(f"{src}: --detector oracle needs a synthetic scene folder (with scene.json, from "
                             f"`mosaic synth`); use --detector model with a --bundle for real videos")
        from ..evaluation.oracle_perception import oracle_perception

        perception = oracle_perception(src, miss_rate=args.miss_rate, matcher=args.matcher
                                       if args.matcher != "model" else "sift")
        trace.decide("perception", perception.describe)
    out = Path(args.out) if args.out else None
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
    res = pipeline.ask(args.source, question, options, perception=perception, bundle=args.bundle,
                       profile=profile, conf=conf, answerer=args.answerer, method=args.method,
                       prompt_mode=args.prompt, trace=trace, keyframes=args.keyframes)
    files = {}
    if out is not None:
        if res.prompt is not None and res.prompt.image is not None:
            res.prompt.save_png(out / "map.png")
            files["map_png"] = str(out / "map.png")
        if res.map is not None:
            res.map.save(out / "map.json")
            files["map_json"] = str(out / "map.json")
        (out / "trace.json").write_text(__import__("json").dumps(trace.to_dict(), indent=1))
        files["trace_json"] = str(out / "trace.json")
    d = res.to_dict()
    d.update({"schema": "mosaicthinker.ask/1", "question": question, "options": options, "files": files,
              "warnings": [e["message"] for e in trace.events if e["kind"] in ("fallback", "degraded",
                                                                                 "random_weights", "not_in_map",
                                                                                 "unknown_objects")],
              "random_weights_used": trace.random_weights_used,
              "seconds": trace.to_dict()["wall_seconds"]})
    return d


def render(r: dict[str, Any]) -> str:
    lines = [f"answer: {r['answer']}"]
    if r.get("explanation"):
        lines.append(f"  how: {r['explanation']}")
    if r.get("instances") is not None:
        lines.append(f"  map: {len(r['instances'])} object(s)" + (f" from {len(r['keyframes'])} key frames"
                                                                   if r.get("keyframes") else ""))
    for w in r.get("warnings", []):
        lines.append(f"  note: {w}")
    if r.get("random_weights_used"):
        lines.append("  WARNING: random-weight (test) models were used: the answer is meaningless")
    for k, v in r.get("files", {}).items():
        lines.append(f"  wrote {v}")
    lines.append(f"  ({r.get('seconds', 0):.1f} s)")
    return "\n".join(lines)
