"""Wording sets scored per reader: the trained reader alone, the rules alone, and both (issue 35).

    python benchmarks/reader_holdout.py --bundle B --sets 8,9,10,11 --modes model,rules,auto [--variant V] \
        --meta ../shared/data/vsibench/meta_info.json --out benchmarks/results/reader_holdout.json

Each question of `benchmarks/data/vsibench_paraphrases_holdoutN.jsonl` is parsed by `parse_question` with the
bundle's reader and `readers=MODE`, then answered on the benchmark's boxes (`MapReasoner`, the same executor and
scorer as `mosaic eval vsibench`). Per type: the score (refusals count 0), how many were answered, the score of
the answered ones (multiple choice: the share right; numbers: MRA), and the answered ones scoring below 0.5
(confident wrong). Video-only types are skipped as `mosaic eval vsibench` does.
"""
from __future__ import annotations

import argparse
import os
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

from mosaicthinker.host.evaluation.vsibench import VIDEO_ONLY, load_meta, load_questions, score_answer
from mosaicthinker.runtime.infra import jsonio
from mosaicthinker.runtime.infra.outputs import write_file_atomic
from mosaicthinker.runtime.answer.execute import MapReasoner
from mosaicthinker.runtime.map.model import SemanticMap
from mosaicthinker.runtime.query.parse import parse_question
from mosaicthinker.runtime.query.reader import load_reader

HERE = Path(__file__).resolve().parent


def score_set(path: Path, meta: dict, reader, mode: str) -> dict:
    maps: dict[str, MapReasoner] = {}
    per: dict[str, list] = defaultdict(list)
    wrong: list[dict] = []
    for q in load_questions(path):
        qt = q["question_type"]
        if qt in VIDEO_ONLY:
            continue
        scene = str(q["scene_name"])
        if scene not in maps:
            maps[scene] = MapReasoner(SemanticMap.from_meta_info(meta[scene], scene))
        m = maps[scene]
        pq = parse_question(q["question"], q.get("options"), m.index.names, reader=reader if mode != "rules"
                            else None, readers=mode)
        a = m.answer(q["question"], q.get("options"), parsed=pq)
        s = score_answer(qt, a.text, q["ground_truth"]) if a.ok else 0.0
        per[qt].append((a.ok, s, pq.reader))
        if a.ok and s < 0.5:
            wrong.append({"id": q.get("id"), "type": qt, "question": q["question"], "pred": a.text,
                          "gt": q["ground_truth"], "reader": pq.reader, "program": pq.describe()[:300]})
    out = {}
    for qt, rs in sorted(per.items()):
        ok = [s for a, s, _ in rs if a]
        out[qt] = {"n": len(rs), "score": round(float(np.mean([s for _, s, _ in rs])), 3), "answered": len(ok),
                   "score_answered": round(float(np.mean(ok)), 3) if ok else None,
                   "confident_wrong": sum(1 for s in ok if s < 0.5),
                   "by_reader": {k: sum(1 for a, _, r in rs if r == k) for k in sorted({r for _, _, r in rs})}}
    return {"per_type": out, "overall": round(float(np.mean([v["score"] for v in out.values()])), 3),
            "wrong": wrong}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--bundle", required=True)
    p.add_argument("--sets", default="8,9,10,11")
    p.add_argument("--modes", default="model,rules,auto")
    p.add_argument("--meta", default=str(HERE.parent.parent / "shared/data/vsibench/meta_info.json"))
    p.add_argument("--variant", default=None, help="the reader role's variant (default: the bundle's default)")
    p.add_argument("--out", type=Path)
    a = p.parse_args()
    meta = load_meta(a.meta)
    reader = load_reader(a.bundle, a.variant)
    res = {"schema": "mosaicthinker.bench.reader_holdout/1", "bundle": str(a.bundle), "variant": a.variant,
           "head": reader.meta.get("head"), "sets": {},
           "load_avg_start": [round(x, 2) for x in os.getloadavg()]}
    t0 = time.time()
    for s in a.sets.split(","):
        path = HERE / "data" / (f"vsibench_paraphrases_holdout{s}.jsonl" if s not in ("", "0", "bench")
                                else "vsibench_paraphrases.jsonl")
        for mode in a.modes.split(","):
            r = score_set(path, meta, reader, mode)
            res["sets"][f"{s}:{mode}"] = r
            print(f"set {s} {mode}: overall {r['overall']} " + ", ".join(
                f"{k.replace('object_', '')} {v['score']} ({v['answered']}/{v['n']}, wrong {v['confident_wrong']})"
                for k, v in r["per_type"].items()), flush=True)
    res["seconds"] = round(time.time() - t0, 1)
    res["load_avg_end"] = [round(x, 2) for x in os.getloadavg()]
    if a.out:
        write_file_atomic(a.out, jsonio.dumps(res, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
