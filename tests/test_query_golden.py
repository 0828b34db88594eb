"""Golden programs: every question of every wording set (the benchmark's own 1601 in ../shared, the eight
paraphrase sets in benchmarks/data, the example wordings) parsed to exactly the program recorded in
tests/data/query_golden/<set>.jsonl; every program valid under the JSON schema, checked by an independent
validator written here (not the reader the product uses) and read back by the product's reader unchanged.

Regenerate after an intended change of the parser (and say why in the commit):
    python tests/test_query_golden.py --write
"""
from __future__ import annotations

import json
import os
import re
import sys
from pathlib import Path

import pytest

from mosaicthinker.runtime.query.parse import parse_question
from mosaicthinker.runtime.query.rules.lexicon import EXAMPLES
from mosaicthinker.runtime.query.schema import from_json, json_schema, to_json

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("MOSAIC_SHARED", REPO.parent / "shared"))
GOLDEN = Path(__file__).parent / "data" / "query_golden"


def wording_sets() -> dict[str, list[dict]]:
    sets = {"examples": [{"id": f"{k}/{i}", "question": q, "options": None}
                         for k, qs in EXAMPLES.items() for i, q in enumerate(qs)]}
    shared = SHARED / "data" / "vsibench" / "questions.jsonl"
    if shared.is_file():
        sets["vsibench"] = [json.loads(x) for x in shared.read_text().splitlines() if x.strip()]
    for p in sorted((REPO / "benchmarks" / "data").glob("vsibench_*.jsonl")):
        sets[p.stem] = [json.loads(x) for x in p.read_text().splitlines() if x.strip()]
    return sets


def reading(q: dict) -> dict:
    """What the golden file records of one question: its program (or the notes of a refusal)."""
    pq = parse_question(q["question"], q.get("options"))
    out = {"id": q.get("id"), "how": pq.how}
    if pq.program is None:
        out["notes"] = pq.notes
    else:
        out["program"] = to_json(pq.program)
    return out


# ----------------------------------------------------------------------------- an independent schema validator


def validate(doc, schema, root=None, path="$"):
    """Errors of `doc` under the subset of JSON Schema the product's schema uses (type, const, enum, anyOf, $ref,
    properties, required, additionalProperties, items, min/maxItems, min/maxLength, pattern, minimum/maximum)."""
    root = root or schema
    if "$ref" in schema:
        return validate(doc, root["$defs"][schema["$ref"].rsplit("/", 1)[1]], root, path)
    if "anyOf" in schema:
        if any(not validate(doc, s, root, path) for s in schema["anyOf"]):
            return []
        return [f"{path}: matches none of anyOf"]
    errs = []
    if "const" in schema and doc != schema["const"]:
        errs.append(f"{path}: {doc!r} != const {schema['const']!r}")
    if "enum" in schema and doc not in schema["enum"]:
        errs.append(f"{path}: {doc!r} not in enum")
    t = schema.get("type")
    types = {"object": dict, "array": list, "string": str, "boolean": bool, "null": type(None)}
    if t in types and not isinstance(doc, types[t]):
        return errs + [f"{path}: not {t}"]
    if t in ("integer", "number") and (isinstance(doc, bool) or not isinstance(doc, (int, float)) or
                                       (t == "integer" and not isinstance(doc, int))):
        return errs + [f"{path}: not {t}"]
    if t == "object":
        props = schema.get("properties", {})
        errs += [f"{path}.{k}: required" for k in schema.get("required", []) if k not in doc]
        if schema.get("additionalProperties") is False:
            errs += [f"{path}.{k}: not allowed" for k in doc if k not in props]
        for k, v in doc.items():
            if k in props:
                errs += validate(v, props[k], root, f"{path}.{k}")
    if t == "array":
        if not schema.get("minItems", 0) <= len(doc) <= schema.get("maxItems", 10 ** 9):
            errs.append(f"{path}: {len(doc)} items")
        for i, v in enumerate(doc):
            errs += validate(v, schema["items"], root, f"{path}[{i}]")
    if t == "string":
        if not schema.get("minLength", 0) <= len(doc) <= schema.get("maxLength", 10 ** 9):
            errs.append(f"{path}: length {len(doc)}")
        if "pattern" in schema and not re.fullmatch(schema["pattern"].strip("^$"), doc):
            errs.append(f"{path}: {doc!r} does not match {schema['pattern']}")
    if t == "integer" and not schema.get("minimum", -10 ** 18) <= doc <= schema.get("maximum", 10 ** 18):
        errs.append(f"{path}: {doc} out of range")
    return errs


def test_the_validator_rejects_what_the_schema_forbids():
    s = json_schema()
    ok = {"version": "mosaicthinker.query/1", "ask": {"kind": "count", "objects": [{"name": "chair"}]}}
    assert validate(ok, s) == []
    for bad in ({"ask": {"kind": "count", "objects": []}}, {"ask": {"kind": "count"}},
                {"ask": {"kind": "count", "objects": [{"name": "chair", "colour": "red"}]}},
                {"ask": {"kind": "size", "object": {"name": "sofa"}, "unit": "parsecs"}},
                {"ask": {"kind": "distance", "a": {"name": "sofa"}, "within": {"op": "<", "threshold_mm": -1}}}):
        assert validate(bad, s), bad


# ----------------------------------------------------------------------------- the golden files


SETS = wording_sets()


@pytest.mark.parametrize("name", sorted(SETS))
def test_every_wording_set_parses_to_its_golden_programs(name):
    path = GOLDEN / f"{name}.jsonl"
    assert path.is_file(), f"{path}: missing; write it with `python tests/test_query_golden.py --write`"
    golden = [json.loads(x) for x in path.read_text().splitlines() if x.strip()]
    got = [reading(q) for q in SETS[name]]
    assert len(got) == len(golden)
    diff = [(g["id"], g, r) for g, r in zip(golden, got) if g != r]
    assert not diff, f"{len(diff)} question(s) read differently, first: {diff[0]}"
    schema = json_schema()
    for r in got:
        if "program" in r:
            assert validate(r["program"], schema) == [], (r["id"], validate(r["program"], schema))
            assert to_json(from_json(r["program"])) == r["program"]  # the reader gives back what was written


def main(argv: list[str]) -> int:
    if argv[1:] != ["--write"]:
        print(__doc__)
        return 2
    GOLDEN.mkdir(parents=True, exist_ok=True)
    for name, qs in SETS.items():
        rows = [json.dumps(reading(q), sort_keys=True) for q in qs]
        (GOLDEN / f"{name}.jsonl").write_text("\n".join(rows) + "\n")
        print(f"wrote {GOLDEN / name}.jsonl ({len(rows)} questions)")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
