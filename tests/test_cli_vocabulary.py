"""One CLI that agrees with itself: every `mosaic` command's parser is built (as `mosaic` builds it) and its flags
compared with the same flag of every other command."""
from __future__ import annotations

import argparse
import importlib
import inspect
import re
import subprocess
import sys
from collections import defaultdict

import pytest

from mosaicthinker.runtime.cli import COMMANDS, COMMON, build_parser, main
from mosaicthinker.runtime.pipeline import default_conf

# flags whose choices may be a subset of the other commands' (the command cannot do the rest)
SUBSET_CHOICES = {"--depth": "eval pose aligns RGB-D frames: no `auto`", "--prompt": "map writes an image: no text"}
# choice flags whose default in one command differs from the others', and why
OWN_DEFAULTS = {("--complexity", "demo"): "a room with few objects keeps the demo short",
                ("--detector", "eval keyframes"): "the key-frame study scores synthetic scenes with the oracle",
                ("--depth", "eval pose"): "the pose benchmark reads RGB-D folders (no auto)",
                ("--depth", "eval scene"): "the real-room benchmark reads RGB-D folders (no auto)",
                ("--gravity", "eval scene"): "the real-room targets are measured with the floor fit alone",
                ("--matcher", "ask"): "ask runs the bundle's matcher model when the bundle has one, else sift"}
# --keyframes defaults that are not the pipeline's K, and why (the help must say the number and the why)
OWN_KEYFRAMES = {"demo": 12, "eval pose": 32, "eval keyframes": 8}


def _commands():
    out = []
    for words, (mod, _, extra) in COMMANDS.items():
        try:
            module = importlib.import_module(mod)
        except ModuleNotFoundError:  # the export extra is not installed
            assert extra, f"{mod} failed to import without an extra"
            continue
        out.append((" ".join(words), module, build_parser(words, module)))
    return out


COMMANDS_BUILT = _commands()


def _visible(parser: argparse.ArgumentParser) -> dict[str, argparse.Action]:
    return {o: a for a in parser._actions if a.help != argparse.SUPPRESS for o in a.option_strings
            if o.startswith("--")}


def _signature(a: argparse.Action) -> tuple:
    return type(a).__name__, getattr(a.type, "__name__", a.type), a.nargs, a.metavar


def test_a_flag_means_the_same_in_every_command():
    seen: dict[str, list[tuple[str, argparse.Action]]] = defaultdict(list)
    for name, _, parser in COMMANDS_BUILT:
        for opt, a in _visible(parser).items():
            seen[opt].append((name, a))
    assert len(seen) > 30
    for opt, uses in seen.items():
        sigs = {_signature(a) for _, a in uses}
        assert len(sigs) == 1, f"{opt} differs across commands: {[(n, _signature(a)) for n, a in uses]}"
        choices = [set(a.choices) for _, a in uses if a.choices is not None]
        if choices:
            assert len(choices) == len(uses), f"{opt}: choices in some commands only"
            widest = set().union(*choices)
            if opt in SUBSET_CHOICES:
                assert all(c <= widest for c in choices)
            else:
                assert all(c == widest for c in choices), f"{opt}: {[(n, a.choices) for n, a in uses]}"
            common = [a.default for n, a in uses if (opt, n) not in OWN_DEFAULTS]
            assert len(set(common)) <= 1, f"{opt}: defaults {[(n, a.default) for n, a in uses]}"


def test_keyframes_default_has_one_owner():
    K = default_conf.keyframe.keyframes
    uses = {n: _visible(p)["--keyframes"] for n, _, p in COMMANDS_BUILT if "--keyframes" in _visible(p)}
    assert {"ask", "map", "demo", "eval e2e", "profile"} <= set(uses)
    for name, a in uses.items():
        if name in OWN_KEYFRAMES:
            assert a.default == OWN_KEYFRAMES[name] and f"default {a.default}:" in a.help, (name, a.help)
        else:  # None = the pipeline's K, and the help says which number that is
            assert a.default is None and f"default {K}, the pipeline's" in a.help, (name, a.default, a.help)


def test_objects_names_things_and_complexity_is_the_level():
    for name, _, parser in COMMANDS_BUILT:
        v = _visible(parser)
        if "--objects" in v:
            assert name == "map" and v["--objects"].choices is None  # names to map, not a level
        if name in ("demo", "synth"):
            assert v["--complexity"].choices == ["low", "med", "high"]


def test_deprecated_aliases_still_work_and_warn(capsys):
    for words, argv, dest, value in [
            (("synth",), ["--objects", "high"], "complexity", "high"),
            (("demo",), ["--questions", "3"], "num_questions", 3),
            (("eval", "keyframes"), ["--width", "96", "--height", "72"], "old_width", 96)]:
        module = importlib.import_module(COMMANDS[words][0])
        args = build_parser(words, module).parse_args(argv)
        assert getattr(args, dest) == value
        assert "is deprecated here, use" in capsys.readouterr().err
    from mosaicthinker.runtime.commands.flags import size_of

    module = importlib.import_module(COMMANDS[("eval", "keyframes")][0])
    args = build_parser(("eval", "keyframes"), module).parse_args(["--width", "96", "--height", "72"])
    assert size_of(args) == (96, 72)


def test_size_is_wxh_everywhere():
    for name, _, parser in COMMANDS_BUILT:
        v = _visible(parser)
        assert "--width" not in v and "--height" not in v, name
        if "--size" in v:
            assert v["--size"].type.__name__ == "parse_size" and isinstance(v["--size"].default, tuple)
    module = importlib.import_module(COMMANDS[("synth",)][0])
    with pytest.raises(SystemExit):
        build_parser(("synth",), module).parse_args(["--size", "640"])


def test_a_command_lists_only_common_flags_it_reads():
    """No flag that does nothing: each common flag a command lists is read by its module."""
    for name, module, parser in COMMANDS_BUILT:
        src = inspect.getsource(module)
        for flag in COMMON:
            if f"--{flag}" in _visible(parser):
                assert re.search(rf"args\.{flag}\b|getattr\(args, \"{flag}\"", src), f"{name} lists --{flag}"
    v = {n: _visible(p) for n, _, p in COMMANDS_BUILT}
    assert "--bundle" not in v["synth"] and "--profile" not in v["bundle verify"] and "--out" not in v["bundle verify"]


def test_matcher_and_answerer_choices():
    v = {n: _visible(p) for n, _, p in COMMANDS_BUILT}
    assert "model" in v["eval e2e"]["--matcher"].choices
    assert v["plan"]["--answerer"].choices == v["ask"]["--answerer"].choices == ["map", "vlm", "auto"]


def test_version_and_group_help(capsys):
    assert main(["--version"]) == 0
    out = capsys.readouterr().out
    assert re.fullmatch(r"mosaic \d+\.\d+\.\d+\S*\n", out)
    for group, subs in (("eval", ["pose", "vsibench", "keyframes", "e2e"]), ("bundle", ["verify", "show"])):
        assert main([group, "--help"]) == 0
        out = capsys.readouterr().out
        for s in subs:  # each subcommand on its own line with its one-line help
            assert re.search(rf"^  {s}\s+\S.+$", out, re.M), (group, s, out)
    assert main(["eval", "nope"]) == 2
    assert "unknown subcommand" in capsys.readouterr().err


def test_version_from_the_installed_command():
    r = subprocess.run([sys.executable, "-m", "mosaicthinker.runtime.cli", "--version"], capture_output=True,
                       text=True)
    assert r.returncode == 0 and r.stdout.startswith("mosaic ")


@pytest.mark.parametrize("argv", [["ask", "map.json", "how many chairs?", "--keyframes", "0"],
                                  ["map", "frames", "--keyframes", "-3"], ["ask", "map.json", "   "]])
def test_a_keyframe_count_below_one_or_a_blank_question_is_bad_input(argv, capsys):
    """--keyframes 0 silently meant the default K; a question of spaces was read as one: both exit 2, naming
    what to give."""
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "error:" in err and ("--keyframes must be at least 1" in err or "give SOURCE and QUESTION" in err)
