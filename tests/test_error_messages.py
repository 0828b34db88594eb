"""User-input errors: the library names parameters (API-neutral, in backticks), the CLI names its flags (issue 11).

One table maps fields to flags (`commands/flags.FLAG_FOR_FIELD`); a scan of the library's raise statements
keeps flag names out of the messages of code that is not a command.
"""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

from mosaicthinker.runtime.commands.flags import FLAG_FOR_FIELD, cli_message
from mosaicthinker.runtime.infra.errors import InputError

RUNTIME = Path(__file__).resolve().parents[1] / "runtime"
# command modules and the command functions of library modules speak the CLI's words
COMMAND_FILES = {"cli.py", "synth/cli.py"}
COMMAND_DIRS = ("commands/", "evaluation/")
COMMAND_FUNCS = {"run", "run_for", "_run", "main", "add_arguments", "add_arguments_for", "run_cli", "_plan_args"}


def test_cli_message_maps_only_the_named_fields():
    msg = "`depth=model` needs a bundle with a depth role (or use `depth=sensor`); `vlm` role; `method`"
    assert cli_message(msg, ("depth",)) == ("--depth model needs a bundle with a depth role (or use --depth "
                                            "sensor); `vlm` role; `method`")
    assert cli_message("`SceneConfig.objects` must be", ("SceneConfig.objects",)) == "--complexity must be"
    assert cli_message("rerun with `video=False`", ("video",)) == "rerun with --no-video"
    assert all(f.startswith("--") for f in FLAG_FOR_FIELD.values())


def test_api_error_names_the_parameter_and_the_cli_the_flag(tmp_path, capsys):
    from mosaicthinker.runtime.answer import answer_question
    from mosaicthinker.runtime.cli import main
    from mosaicthinker.runtime.map import SemanticMap

    smap = SemanticMap([], None, [], {})
    with pytest.raises(InputError) as e:
        answer_question(smap, "How many chairs are in this room?", answerer="oracle")
    assert "`answerer`" in str(e.value) and "--" not in str(e.value) and e.value.fields == ("answerer",)
    rc = main(["profile", "--bundle", str(tmp_path), "--update-profile", "--no-progress"])
    err = capsys.readouterr().err
    assert rc == 2 and "error: --update-profile needs --profile" in err, err


def _library_raises() -> list[str]:
    bad = []
    files = sorted(RUNTIME.rglob("*.py"))
    assert len(files) > 50, f"only {len(files)} modules under {RUNTIME}"  # an empty glob would pass the check
    for f in files:
        rel = f.relative_to(RUNTIME).as_posix()
        if rel in COMMAND_FILES or rel.startswith(COMMAND_DIRS):
            continue
        tree = ast.parse(f.read_text())
        for fn in ast.walk(tree):
            if not isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)) or fn.name in COMMAND_FUNCS \
                    or [a.arg for a in fn.args.args[:1]] == ["args"]:  # takes the parsed flags: command layer
                continue
            for node in ast.walk(fn):
                if not (isinstance(node, ast.Raise) and isinstance(node.exc, ast.Call)):
                    continue
                text = " ".join(c.value for c in ast.walk(node.exc) if isinstance(c, ast.Constant)
                                and isinstance(c.value, str))
                if "mosaic " in text or "python -m" in text:  # an example command line is a command line
                    continue
                for word in text.split():
                    w = word.strip("(),;:'\"")
                    if w.startswith("--") and len(w) > 2 and w[2].isalpha():
                        bad.append(f"{rel}:{node.lineno} {fn.name}: {w}")
    return bad


def test_library_messages_name_no_cli_flags():
    assert _library_raises() == []
