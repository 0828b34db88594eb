"""The query language: frozen nodes, the JSON reader refusing every malformed field with its path, the schema
generated from the dataclasses (the VLM's profile a bounded subset), and `mosaic parse`."""
from __future__ import annotations

import dataclasses
import json

import pytest

from mosaicthinker.runtime.query import ir
from mosaicthinker.runtime.query.parse import parse_question
from mosaicthinker.runtime.query.schema import ProgramError, from_json, json_schema, max_output_bytes, to_json
from test_query_golden import validate


def test_nodes_are_frozen_and_every_node_kind_is_in_the_schema():
    node = ir.Count((ir.Ref("chair"),))
    with pytest.raises(dataclasses.FrozenInstanceError):
        node.objects = ()  # type: ignore[misc]
    s = json_schema()
    kinds = {d["properties"]["kind"]["const"] for d in s["$defs"].values() if "kind" in d.get("properties", {})}
    assert {n.KIND for n in ir.NODES} <= kinds
    assert s["$id"] == ir.SCHEMA_VERSION and s["properties"]["version"]["const"] == ir.SCHEMA_VERSION
    assert {n.qtype for n in (ir.Count((ir.Ref("a"),)), ir.Route(ir.Ref("a"), ir.Ref("b"), (ir.Turn(),)))} == \
        {"object_counting", "route_planning"}


@pytest.mark.parametrize("doc, where", [
    ("{", "not JSON"),
    ({"ask": {"kind": "count", "objects": [{"name": "chair"}]}, "extra": 1}, "unknown field(s) ['extra']"),
    ({"version": "mosaicthinker.query/9", "ask": {"kind": "room_size"}}, "program.version"),
    ({"ask": {"kind": "count", "objects": [{"name": ""}]}}, "program.ask.objects[0].name"),
    ({"ask": {"kind": "count", "objects": [{"name": 3}]}}, "program.ask.objects[0].name: expected a string"),
    ({"ask": {"kind": "size", "object": {"name": "sofa"}, "unit": "parsec"}}, "program.ask.unit"),
    ({"ask": {"kind": "distance", "a": {"name": "sofa"}, "within": {"op": "<", "threshold_mm": True}}},
     "program.ask.within.threshold_mm: expected an integer"),
    ({"ask": {"kind": "direction", "stand": {"name": "a"}, "face": {"name": "b"}}}, "program.ask.target: missing"),
    ({"ask": {"kind": "route", "start": {"name": "a"}, "face": {"name": "b"}, "steps": [{"kind": "fly"}]}},
     "program.ask.steps[0]: kind 'fly'"),
    ({"ask": {"kind": "count", "objects": [{"name": "chair", "select": [{"kind": "instance", "id": -1}]}]}},
     "program.ask.objects[0].select[0].id"),
])
def test_the_reader_refuses_each_malformed_field_naming_its_path(doc, where):
    with pytest.raises(ProgramError, match=None) as e:
        from_json(doc if isinstance(doc, str) else json.dumps(doc))
    assert where in str(e.value)


def test_written_programs_read_back_unchanged_and_defaults_are_left_out():
    p = parse_question("Which is closer to the desk, the laptop or the couch?").program
    doc = to_json(p)
    assert doc["ask"]["kind"] == "nearest" and "yesno" not in doc["ask"]  # a default is not written
    assert from_json(doc) == p and from_json(json.dumps(doc)) == p


def test_the_vlm_profile_is_a_bounded_subset_of_the_schema():
    full, vlm = json_schema("ask"), json_schema("ask", profile="vlm")
    assert "phrase" not in vlm["$defs"]["Ref"]["properties"] and vlm["x-guidance"] == {"whitespace_flexible": False}
    bound = max_output_bytes(vlm)
    assert 200 < bound < 4000 and max_output_bytes(full) > 10 * bound
    # a long program the VLM profile allows is valid under the full schema, and its length is within the bound
    ref = {"name": "x" * 24, "select": [{"kind": "described", "words": ["y" * 24, "z" * 24], "phrase": "w" * 24}]}
    doc = {"kind": "route", "start": ref, "face": ref, "destination": ref,
           "steps": [{"kind": "forward", "to": ref}, {"kind": "turn"}] * 4}
    assert validate(doc, vlm) == [] and validate(doc, full) == []
    assert len(json.dumps(doc, separators=(",", ":"))) <= bound
    assert validate({**doc, "steps": doc["steps"] * 2}, vlm)  # 16 steps: beyond the VLM's bound


def _mosaic(capsys, *args: str) -> tuple[int, str, str]:
    """`mosaic ARGS` in this process (the same `cli.main` the command runs): (exit code, stdout, stderr)."""
    from mosaicthinker.runtime.cli import main

    capsys.readouterr()
    code = main(list(args))
    out = capsys.readouterr()
    return code, out.out, out.err


def test_mosaic_parse_prints_the_program_and_refuses_bad_input(capsys):
    code, out, err = _mosaic(capsys, "parse", "--json", "how many chairs are near the desk?")
    assert code == 0, err
    d = json.loads(out)
    assert d["schema"] == "mosaicthinker.parse/1" and d["qtype"] == "object_counting"
    assert d["program"]["ask"] == {"kind": "count", "objects": [{"name": "chair", "phrase": "chairs"}],
                                   "where": {"kind": "relation", "relation": "near", "object": {"name": "desk"}}}
    code, out, _ = _mosaic(capsys, "parse", "Is the bed to my left, standing by the door facing the window? A. yes B. no")
    assert code == 0 and '"kind": "direction"' in out and "targets ['bed']" in out
    code, out, _ = _mosaic(capsys, "parse", "what is the meaning of life?")
    assert code == 0 and "not understood" in out
    code, out, _ = _mosaic(capsys, "parse", "--schema", "vlm", "--json")
    assert code == 0 and json.loads(out)["json_schema"]["x-guidance"]["whitespace_flexible"] is False
    code, _, err = _mosaic(capsys, "parse", " ")
    assert code == 2 and err.startswith("error:")
    code, _, err = _mosaic(capsys, "parse", "--grounding", "vlm", "how many chairs?")
    assert code == 2 and "--grounding" in err


@pytest.mark.slow
def test_mosaic_ask_explain_prints_the_program_with_the_answer(tmp_path, capsys):
    from test_grounding_nl import room_map

    m = tmp_path / "map.json"
    room_map().save(m)
    code, out, err = _mosaic(capsys, "ask", str(m), "how far is the power strip from the desk, in cm?", "--explain")
    assert code == 0, err
    assert "program (natural):" in out and '"kind": "distance"' in out and "power strip" in out
    code, out, _ = _mosaic(capsys, "ask", str(m), "how many chairs are there?", "--json")
    d = json.loads(out)
    assert d["grounding"]["program"]["ask"]["kind"] == "count" and d["answer"] == "3"
