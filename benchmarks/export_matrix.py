"""The full precision x architecture export matrix for the Hugging Face architectures (export/hf_*.py).

For every architecture (tiny random configs by default; `--real` uses the hub checkpoints of each module's
HF_DEFAULTS, which needs network access) and every precision (fp32, fp16, int8-dynamic, int8-qdq), export into
a scratch bundle and record per variant and component: the precision actually shipped (a component whose
parity fails stays fp32, a variant whose components all fail is skipped), the parity figures on fresh random
inputs, the task check (VLM token agreement with transformers' generate, KV-cache consistency), export time
and file size. Writes benchmarks/results/export_matrix.json.

    python benchmarks/export_matrix.py                       # every tiny architecture, every precision
    python benchmarks/export_matrix.py --arch smolvlm,sam    # a subset
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent
PRECISIONS = ["fp32", "fp16", "int8-dynamic", "int8-qdq"]
EXPORTERS = {
    "depth": ("hf_depth", "export_depth"),
    "segmenter": ("hf_sam", "export_segmenter"),
    "detector": ("hf_owlv2", "export_detector"),
    "embedder": ("hf_clip", "export_embedder"),
    "matcher": ("hf_matchers", "export_matcher"),
    "vlm": ("hf_vlm", "export_vlm"),
}


def _summarise(rep: dict, out: Path, role: str) -> dict:
    from mosaicthinker.runtime.infra.bundle import load_bundle

    meta = load_bundle(out).role_meta(role)
    res = {}
    for v, vm in meta["variants"].items():
        comps = {}
        for c, cm in vm["components"].items():
            par = (vm.get("parity") or {}).get(c) or {}
            comps[c] = {"shipped_precision": cm.get("precision"), "bytes": cm.get("bytes"),
                        "fallback_reason": cm.get("fallback_reason"),
                        "parity_worst": par.get("worst"), "agreement": (par.get("agreement") or {}).get("worst")}
        task = vm.get("task_check")
        res[v] = {"components": comps, "notes": vm.get("notes"),
                  "task": None if not task else {k: x for k, x in task.items() if k != "runs"}}
    return {"variants": res, "skipped": meta.get("skipped_variants", {})}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--arch", default="", help="comma list of architectures (default: all tiny archs)")
    ap.add_argument("--precision", default=",".join(PRECISIONS))
    ap.add_argument("--real", action="store_true", help="export the real HF checkpoints (needs network)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out", default=str(ROOT / "results" / "export_matrix.json"))
    ap.add_argument("--update", action="store_true", help="merge these architectures into an existing --out file")
    args = ap.parse_args(argv)

    import importlib

    import torch

    from mosaicthinker.export import tiny

    torch.set_num_threads(args.threads)
    os.environ.setdefault("OMP_NUM_THREADS", str(args.threads))
    archs = [a for a in args.arch.split(",") if a] or list(tiny.TINY_ARCHS)
    precisions = [p for p in args.precision.split(",") if p]
    results = {}
    for arch in archs:
        role = tiny.TINY_ARCHS[arch][0]
        modname, fn = EXPORTERS[role]
        mod = importlib.import_module(f"mosaicthinker.export.{modname}")
        source = f"tiny:{arch}"
        if args.real:
            key = "relative" if arch == "depth-anything-v2" else (
                "metric-indoor" if arch == "depth-anything-v2-metric-indoor" else arch)
            source = "hf:" + mod.HF_DEFAULTS[key]
        with tempfile.TemporaryDirectory(prefix=f"matrix-{arch}-") as d:
            out = Path(d) / "bundle"
            t0 = time.perf_counter()
            try:
                rep = getattr(mod, fn)(source, out, precisions)
                entry = {"role": role, "source": source, "ok": True, **_summarise(rep, out, role)}
            except Exception as e:  # noqa: BLE001  one architecture failing must not hide the others
                entry = {"role": role, "source": source, "ok": False, "error": f"{type(e).__name__}: {str(e)[:500]}"}
            entry["seconds"] = round(time.perf_counter() - t0, 1)
        results[arch] = entry
        print(f"[matrix] {arch}: {'ok' if entry['ok'] else 'FAILED'} in {entry['seconds']} s", file=sys.stderr)
    doc = {"schema": "mosaicthinker.bench.export_matrix/1", "created": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
           "command": "python benchmarks/export_matrix.py " + " ".join(argv if argv is not None else sys.argv[1:]),
           "machine": {"python": platform.python_version(), "cpu_count": os.cpu_count(), "threads": args.threads,
                       "torch": torch.__version__},
           "precisions": precisions, "random_weights": not args.real, "results": results}
    if args.update and Path(args.out).is_file():
        old = json.loads(Path(args.out).read_text())
        doc["results"] = {**old.get("results", {}), **results}
        doc["command"] = old.get("command", "") + " ; " + doc["command"]
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(doc, indent=1))
    print(f"wrote {args.out}", file=sys.stderr)
    return 0 if all(r["ok"] for r in results.values()) else 1


if __name__ == "__main__":
    sys.exit(main())
