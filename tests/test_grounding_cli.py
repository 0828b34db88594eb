"""`mosaic ask` on a saved map with natural questions: outcome classes (exit 0 answered / not found /
unsupported, exit 2 bad input), the trace written whenever a run started, `--examples`."""
from __future__ import annotations

import json

from mosaicthinker.runtime.cli import main
from mosaicthinker.runtime.grounding import MAX_QUESTION_CHARS

from test_grounding_nl import room_map


def run(capsys, *argv):
    rc = main(list(argv))
    out, err = capsys.readouterr()
    return rc, out, err


def test_natural_questions_on_a_saved_map(tmp_path, capsys):
    m = tmp_path / "map.json"
    room_map().save(m)
    cases = [("Is there a radiator in this room?", "ok", "yes"), ("How many office chairs are there?", "ok", "2"),
             ("Is there a refrigerator in this kitchen?", "ok", "no"),
             ("How far is the computer tower from the grand zither?", "not_found", None),
             ("What colour is the couch?", "unsupported", None)]
    for i, (q, status, text) in enumerate(cases):
        out_dir = tmp_path / f"run{i}"
        rc, out, err = run(capsys, "ask", str(m), q, "--json", "--out", str(out_dir))
        d = json.loads(out)
        assert rc == 0 and d["status"] == status, (q, d)
        if text is not None:
            assert d["answer"] == text
        assert (out_dir / "trace.json").is_file()  # written whatever the outcome
        trace = json.loads((out_dir / "trace.json").read_text())
        assert trace["decisions"]["grounding"]["qtype"] == d["qtype"]


def test_printed_numbers_carry_their_unit_and_json_keeps_the_number(tmp_path, capsys):
    m = tmp_path / "map.json"
    room_map().save(m)
    cases = (("How tall is the whiteboard in inches?", " inches"), ("How far is the desk from the couch?", " m"),
             ("How many office chairs are there?", ""))
    for q, unit in cases:
        rc, out, _ = run(capsys, "ask", str(m), q)
        rc_j, out_j, _ = run(capsys, "ask", str(m), q, "--json")
        number = json.loads(out_j)["answer"]
        assert rc == rc_j == 0 and float(number) >= 0
        assert out.splitlines()[0] == f"answer: {number}{unit}", (q, out)


def test_bad_input_and_examples(tmp_path, capsys):
    m = tmp_path / "map.json"
    room_map().save(m)
    rc, out, err = run(capsys, "ask", str(m), "how many chairs " * (MAX_QUESTION_CHARS // 10))
    assert rc == 2 and err.startswith("error: question:") and str(MAX_QUESTION_CHARS) in err
    rc, out, err = run(capsys, "ask", str(m), "How many \x1b[2Jchairs\x07 are there?")
    assert rc == 0 and "\x1b" not in out and "\x07" not in out
    rc, out, err = run(capsys, "ask", "--examples")
    assert rc == 0 and "How many chairs are there?" in out and "Where is" in out
    rc, out, err = run(capsys, "ask", str(m))
    assert rc == 2 and err.startswith("error: ask:")
