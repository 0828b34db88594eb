"""The VLM emits the question's program under constrained decoding: validity and cost per question.

    python benchmarks/vlm_grounding.py --bundle B [--questions 200] [--out benchmarks/results/vlm_grounding.json]

B: a bundle whose `vlm` role is an ONNX Runtime GenAI package (e.g. `mosaic export vlm --source tiny:qwen2_5_vl
--precision fp32 --out B`: random weights, the real vocabulary and chat format). For N questions taken in turn
from the benchmark's wording and every wording set in benchmarks/data (the same for every run): the program the
VLM emits under LLGuidance with the IR's JSON schema (`query.vlm.ground_with_vlm`), whether it is valid (the
product's reader; a random-weight model must still be 100 % valid: that is what the constraint guarantees), its
tokens, and the time of prefill and decode; then the same prompt decoded without the constraint for the same
number of tokens, so the difference is the cost of the constraint itself (mask computation per token).
"""
from __future__ import annotations

import argparse
import datetime
import json
import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("MOSAIC_SHARED", REPO.parent / "shared"))


def questions(n: int) -> list[dict[str, Any]]:
    """n questions in turn from the benchmark's file and each wording set (deterministic)."""
    files = [SHARED / "data" / "vsibench" / "questions.jsonl"] + sorted((REPO / "benchmarks" / "data").glob(
        "vsibench_*.jsonl"))
    pools = [[json.loads(x) for x in f.read_text().splitlines() if x.strip()] for f in files if f.is_file()]
    out, k = [], 0
    while len(out) < n and any(pools):
        pool = pools[k % len(pools)]
        if pool:
            out.append(pool.pop(len(pool) * 7 // 13))  # spread over each file, not its first lines
        k += 1
    return out[:n]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--bundle", required=True)
    ap.add_argument("--questions", type=int, default=200)
    ap.add_argument("--unconstrained", type=int, default=20, help="questions also decoded without the constraint")
    ap.add_argument("--out", default=str(REPO / "benchmarks" / "results" / "vlm_grounding.json"))
    args = ap.parse_args(argv)
    from mosaicthinker.runtime.infra.bundle import load_bundle
    from mosaicthinker.runtime.query.schema import json_schema
    from mosaicthinker.runtime.query.vlm import VLM_MAX_TOKENS, ground_with_vlm, vlm_prompt
    from mosaicthinker.runtime.models import load_role
    from mosaicthinker.runtime.infra.trace import Trace

    trace = Trace()
    t0 = time.perf_counter()
    vlm = load_role(load_bundle(args.bundle), "vlm", trace=trace)
    load_s = time.perf_counter() - t0
    rows = []
    for q in questions(args.questions):
        t = Trace()
        t0 = time.perf_counter()
        pq = ground_with_vlm(vlm, q["question"], q.get("options"), [], t)
        rows.append({"id": q.get("id"), "valid": pq.how == "vlm", "kind": pq.qtype, "seconds": time.perf_counter() - t0,
                     **{k: vlm.last.get(k) for k in ("prompt_tokens", "new_tokens", "prefill_s", "decode_s")},
                     "notes": pq.notes[-1:] if pq.how != "vlm" else []})
    free = []
    schema = json.dumps(json_schema("ask", profile="vlm"))
    for r, q in list(zip(rows, questions(args.questions)))[:args.unconstrained]:
        prompt = vlm_prompt(q["question"], q.get("options"))
        for guidance in (("json_schema", schema), None):  # the same prompt and length, with and without it
            vlm.generate([], prompt, max_new_tokens=r["new_tokens"], guidance=guidance)
            free.append({"constrained": guidance is not None, **{k: vlm.last[k] for k in ("new_tokens", "decode_s")}})
    con = [f for f in free if f["constrained"]]
    unc = [f for f in free if not f["constrained"]]
    per_tok = lambda xs: float(np.sum([x["decode_s"] for x in xs]) / max(np.sum([x["new_tokens"] - 1 for x in xs]), 1))  # noqa: E731
    kinds: dict[str, int] = {}
    for r in rows:
        kinds[str(r["kind"])] = kinds.get(str(r["kind"]), 0) + 1
    res = {"schema": "mosaicthinker.bench.vlm_grounding/1", "command": " ".join(["python"] + sys.argv),
           "date": datetime.datetime.now().isoformat(timespec="seconds"), "load_average": os.getloadavg(),
           "bundle": str(args.bundle), "vlm": vlm.describe() if hasattr(vlm, "describe") else None,
           "random_weights": trace.random_weights_used, "model_load_s": round(load_s, 2),
           "max_new_tokens": VLM_MAX_TOKENS, "n": len(rows), "valid": sum(r["valid"] for r in rows),
           "kinds": kinds, "seconds_per_question": {"mean": round(float(np.mean([r["seconds"] for r in rows])), 3),
                                                    "p50": round(float(np.median([r["seconds"] for r in rows])), 3),
                                                    "max": round(float(np.max([r["seconds"] for r in rows])), 3)},
           "new_tokens": {"mean": round(float(np.mean([r["new_tokens"] for r in rows])), 1),
                          "max": int(np.max([r["new_tokens"] for r in rows]))},
           "prefill_s_mean": round(float(np.mean([r["prefill_s"] for r in rows])), 3),
           "decode_s_mean": round(float(np.mean([r["decode_s"] for r in rows])), 3),
           "constraint_cost": {"questions": len(con), "decode_s_per_token_constrained": round(per_tok(con), 5),
                               "decode_s_per_token_unconstrained": round(per_tok(unc), 5),
                               "ratio": round(per_tok(con) / max(per_tok(unc), 1e-9), 3)},
           "invalid": [r for r in rows if not r["valid"]][:10]}
    Path(args.out).write_text(json.dumps(res, indent=1) + "\n")
    print(f"{res['valid']} of {res['n']} programs valid (random weights: {res['random_weights']}); "
          f"{res['seconds_per_question']['mean']} s per question (prefill {res['prefill_s_mean']} s, decode "
          f"{res['decode_s_mean']} s, {res['new_tokens']['mean']} tokens); constrained decode "
          f"{res['constraint_cost']['decode_s_per_token_constrained'] * 1e3:.2f} ms/token vs "
          f"{res['constraint_cost']['decode_s_per_token_unconstrained'] * 1e3:.2f} unconstrained "
          f"(x{res['constraint_cost']['ratio']})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
