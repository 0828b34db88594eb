"""Every JSON the product prints or writes is strict (no NaN / Infinity): one writer, `infra/jsonio`, and no other
`json.dump(s)` call site in the product's code (runtime/, host/, export/)."""
from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np

from mosaicthinker.runtime.infra import jsonio
from mosaicthinker.runtime.infra.outputs import json_text

REPO = Path(__file__).resolve().parents[1]
# files allowed to call json.dump(s) themselves, each with why no non-finite number can reach it
ALLOWED = {
    "runtime/infra/jsonio.py": "the writer itself",
    # the question reader's program text (runtime/query/ir.py: integers, strings and enums only; its numbers are
    # read by infra/numbers.py, which refuses non-finite values): left to its owner to switch over
    "runtime/query/parse.py": "program text: integers and strings",
    "runtime/query/schema.py": "program / JSON-schema text: integers and strings",
    "runtime/query/vlm.py": "the program's JSON schema (constants)",
}
CALL = re.compile(r"\bjson\.dumps?\(|JSONEncoder\(")


def test_no_other_json_writer_in_the_product():
    found = []
    for top in ("runtime", "host", "export"):
        for p in sorted((REPO / top).rglob("*.py")):
            rel = p.relative_to(REPO).as_posix()
            for i, line in enumerate(p.read_text().splitlines(), 1):
                code = line.split("#", 1)[0]
                if CALL.search(code) and rel not in ALLOWED and '"""' not in line and "`json.dumps" not in line:
                    found.append(f"{rel}:{i}: {line.strip()}")
    assert not found, "write JSON through infra/jsonio (strict: no NaN / Infinity):\n" + "\n".join(found)


def test_non_finite_values_are_written_as_null_and_the_rest_kept():
    doc = {"ate": float("nan"), "rpe": [1.5, float("inf"), -math.inf], "arr": np.array([1.0, np.nan]),
           "np": np.float32("nan"), "ok": np.float64(2.5), "n": np.int64(3), "s": "NaN", "nested": {"x": [None, 1]}}
    for text in (jsonio.dumps(doc), jsonio.dumps(doc, indent=1), json_text(doc), jsonio.encode_fn()(doc)):
        assert jsonio.is_strict(text), text
        back = json.loads(text)
        assert back == {"ate": None, "rpe": [1.5, None, None], "arr": [1.0, None], "np": None, "ok": 2.5, "n": 3,
                        "s": "NaN", "nested": {"x": [None, 1]}}


def test_is_strict_refuses_bare_nan():
    assert not jsonio.is_strict('{"a": NaN}') and not jsonio.is_strict("[Infinity]") and jsonio.is_strict('{"a": 1}')


def test_cli_json_of_a_result_with_nan_is_strict(capsys):
    """The CLI's --json printer (`cli._emit`), as `mosaic eval pose --json` uses it with one aligned frame."""
    import sys
    from mosaicthinker.runtime import cli

    cli._emit({"ate_rmse_m": float("nan"), "frames": [np.nan, 1.0]}, ("eval", "pose"), True, sys.modules[__name__])
    out = capsys.readouterr().out
    assert jsonio.is_strict(out) and json.loads(out)["ate_rmse_m"] is None
