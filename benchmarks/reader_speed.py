"""How long the trained reader takes to read one question on one core, and its size (issue 35: <= 30 ms, <= 25 MB).

    OMP_NUM_THREADS=1 python benchmarks/reader_speed.py --bundle B [--variant int8-dynamic] [--out RESULT.json]

Reads the benchmark's own questions and every held-out wording set's (text only: no answers are scored), each
once after a warm-up, with onnxruntime on one intra-op thread; reports the median / p90 / max of `read()` (the
tokenizer and the graph) and of the whole `parse_question` with the reader (composer and names included). The
machine's load is recorded with the figures.
"""
from __future__ import annotations

import argparse
import glob
import json
import os
import time
from pathlib import Path

import numpy as np

from mosaicthinker.runtime.infra import jsonio
from mosaicthinker.runtime.infra.outputs import write_file_atomic
from mosaicthinker.runtime.infra.bundle import load_bundle
from mosaicthinker.runtime.query.parse import parse_question
from mosaicthinker.runtime.query.reader import load_reader

HERE = Path(__file__).resolve().parent


def questions(limit: int) -> list[tuple[str, list[str] | None]]:
    out = []
    for f in sorted(glob.glob(str(HERE / "data" / "vsibench_paraphrases*.jsonl"))):
        for line in open(f):
            row = json.loads(line)
            out.append((row["question"], row.get("options")))
    rng = np.random.default_rng(0)
    idx = rng.permutation(len(out))[:limit]
    return [out[i] for i in idx]


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--bundle", required=True, help="a bundle with a reader role, or a reader folder")
    p.add_argument("--variant", default=None)
    p.add_argument("--n", type=int, default=300)
    p.add_argument("--out", type=Path)
    a = p.parse_args()
    if (Path(a.bundle) / "reader.json").is_file():  # a reader folder (model.onnx, tokenizer.json, reader.json)
        r, variant, model = load_reader(a.bundle), "folder", Path(a.bundle) / "model.onnx"
    else:
        spec = load_bundle(a.bundle).spec("reader", a.variant)
        r, variant, model = load_reader(load_bundle(a.bundle), a.variant), spec.variant, spec.component("model").path
    qs = questions(a.n)
    for q, _ in qs[:10]:
        r.read(q)
    read_ms, parse_ms = [], []
    for q, o in qs:
        t = time.perf_counter()
        r.read(q)
        read_ms.append((time.perf_counter() - t) * 1e3)
        t = time.perf_counter()
        parse_question(q, o, reader=r, readers="model")
        parse_ms.append((time.perf_counter() - t) * 1e3)
    stat = lambda x: {"median": round(float(np.median(x)), 2), "p90": round(float(np.percentile(x, 90)), 2),  # noqa: E731
                      "max": round(float(np.max(x)), 2)}
    res = {"schema": "mosaicthinker.bench.reader_speed/1", "bundle": str(a.bundle), "variant": variant,
           "model_bytes": model.stat().st_size, "questions": len(qs),
           "read_ms": stat(read_ms), "parse_ms": stat(parse_ms), "threads": 1,
           "load_avg": [round(x, 2) for x in os.getloadavg()], "cpus": os.cpu_count(),
           "command": "OMP_NUM_THREADS=1 python benchmarks/reader_speed.py --bundle B"}
    text = jsonio.dumps(res, indent=1) + "\n"
    print(text, end="")
    if a.out:
        write_file_atomic(a.out, text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
