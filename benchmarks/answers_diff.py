"""Before/after check of the question layer: every answer of `mosaic eval vsibench` on the benchmark's own
questions and on every wording set in benchmarks/data/, compared question by question.

    python benchmarks/answers_diff.py --out benchmarks/results/answers/after.json
    python benchmarks/answers_diff.py --compare benchmarks/results/answers/baseline.json \
        benchmarks/results/answers/after.json [--allow route_planning,obj_appearance_order,room_size_estimation]

The successor of `behaviour_diff.py`'s vsibench part for the question layer (parsers, program, executors): it runs
the `mosaic eval vsibench --records --json` command of the checkout it lies in (run it with that checkout's venv),
one run per set, and keeps per question what a user gets: the printed answer (`pred`), status, value, missing
names and score; the explanation is kept too and its changes are counted apart (wording of how an answer was
found is not the answer).

`--compare A B` prints every question whose answer differs. Differences in the `--allow` types (the ones a change
newly answers) are listed one by one with both answers and scores, and do not fail the check; any other
difference exits 1.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("MOSAIC_SHARED", REPO.parent / "shared"))
SCHEMA = "mosaicthinker.bench.answers_diff/1"
ANSWER_KEYS = ("pred", "status", "value", "missing", "score")


def wording_sets() -> dict[str, tuple[Path, Path]]:
    """name -> (questions file, meta file): the benchmark's questions and every wording set in benchmarks/data."""
    meta = SHARED / "data" / "vsibench" / "meta_info.json"
    out = {"vsibench": (SHARED / "data" / "vsibench" / "questions.jsonl", meta)}
    for p in sorted((REPO / "benchmarks" / "data").glob("vsibench_*.jsonl")):
        out[p.stem] = (p, meta)
    return out


def run_set(questions: Path, meta: Path) -> dict[str, Any]:
    cmd = [sys.executable, "-m", "mosaicthinker.runtime.cli", "eval", "vsibench", "--questions", str(questions),
           "--meta", str(meta), "--records", "--json"]
    print("[answers]", " ".join(cmd[2:]), file=sys.stderr, flush=True)
    p = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True)
    if p.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed ({p.returncode}):\n{p.stderr[-3000:]}")
    return json.loads(p.stdout.strip().splitlines()[-1])


def _round(x: Any) -> Any:
    if isinstance(x, float):
        return round(x, 6)
    if isinstance(x, dict):
        return {str(k): _round(v) for k, v in sorted(x.items(), key=lambda kv: str(kv[0]))}
    if isinstance(x, (list, tuple)):
        return [_round(v) for v in x]
    return x


def collect(only: list[str] | None = None) -> dict[str, Any]:
    out: dict[str, Any] = {"schema": SCHEMA, "sets": {}}
    for name, (q, m) in wording_sets().items():
        if only and name not in only:
            continue
        res = run_set(q, m)
        recs = {str(r["id"]): {"question_type": r["question_type"], **{k: _round(r.get(k)) for k in ANSWER_KEYS},
                               "explanation": r.get("explanation")} for r in res["records"]}
        out["sets"][name] = {"per_type": {k: {"n": v["n"], "score": round(v["score"], 4), "status": v["status"]}
                                          for k, v in res["per_type"].items()},
                             "records": recs}
    return out


def compare(a: dict[str, Any], b: dict[str, Any], allow: set[str]) -> tuple[list[str], list[str], int]:
    """(differences outside the allowed types, differences inside them, explanation-only changes)."""
    bad, allowed, expl = [], [], 0
    for name in sorted(set(a["sets"]) | set(b["sets"])):
        if name not in a["sets"] or name not in b["sets"]:
            bad.append(f"{name}: only in {'B' if name not in a['sets'] else 'A'}")
            continue
        ra, rb = a["sets"][name]["records"], b["sets"][name]["records"]
        for qid in sorted(set(ra) | set(rb), key=lambda s: (len(s), s)):
            x, y = ra.get(qid), rb.get(qid)
            if x is None or y is None:
                bad.append(f"{name} #{qid}: only in {'B' if x is None else 'A'}")
                continue
            diff = [k for k in ANSWER_KEYS if x.get(k) != y.get(k)]
            if not diff:
                expl += x.get("explanation") != y.get("explanation")
                continue
            line = (f"{name} #{qid} {x['question_type']}: " + "; ".join(
                f"{k} {json.dumps(x.get(k))[:90]} -> {json.dumps(y.get(k))[:90]}" for k in diff))
            (allowed if x["question_type"] in allow else bad).append(line)
    return bad, allowed, expl


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default=str(REPO / "benchmarks" / "results" / "answers" / "after.json"))
    ap.add_argument("--only", help="comma list of set names (default: all)")
    ap.add_argument("--compare", nargs=2, metavar=("A", "B"))
    ap.add_argument("--allow", default="", help="comma list of question types whose answers may change (listed)")
    args = ap.parse_args(argv)
    if args.compare:
        a, b = (json.loads(Path(p).read_text()) for p in args.compare)
        bad, allowed, expl = compare(a, b, {t for t in args.allow.split(",") if t})
        for line in allowed:
            print("changed (allowed type):", line)
        for line in bad:
            print("DIFFERENT:", line)
        for name in sorted(set(a["sets"]) & set(b["sets"])):
            for qt in sorted(set(a["sets"][name]["per_type"]) | set(b["sets"][name]["per_type"])):
                pa, pb = a["sets"][name]["per_type"].get(qt), b["sets"][name]["per_type"].get(qt)
                if pa != pb:
                    print(f"per type {name} {qt}: {pa and pa['score']} -> {pb and pb['score']} "
                          f"({pa and pa['status']} -> {pb and pb['status']})")
        print(f"{len(bad)} difference(s) outside the allowed types, {len(allowed)} in them, {expl} explanation(s) "
              f"worded differently with the same answer")
        return 1 if bad else 0
    res = collect([s for s in args.only.split(",")] if args.only else None)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(res, indent=1, sort_keys=True) + "\n")
    print(f"wrote {args.out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
