#!/usr/bin/env python3
"""Turn the onnxruntime_perf_test outputs pulled back by android/profile.sh into a `mosaic profile` report.

    python3 android/perf_report.py --bundle BUNDLE --raw OUT/raw --out OUT

Reads `OUT/raw/<role>__<variant>__<component>__<provider>.txt` (one perf_test run each, with the
`exit_code: N` line profile.sh appends) and `OUT/raw/device.txt`, and writes report.json / report.md /
latency.png / memory.png with runtime/commands/profile.py's `write_report` (schema mosaicthinker.profile_report/1).
Each provider run becomes a variant entry `<variant>@<provider>` of the role, so the table and charts show the
providers side by side.

What the figures mean on the phone: load_ms = perf_test's session creation time; latency = its per-run
latencies (min, p50, p90, mean over `-r` runs on random `-I` inputs, after one warm-up run); memory = the
perf_test process's peak working set (the runtime plus ONE model, not an increase over a baseline).
perf_test does not report which nodes each provider took: a model NNAPI only partly supports runs the rest
on the CPU EP, so `provider` is the one requested, and the usability report says how the graph splits.
"""
from __future__ import annotations

import argparse
import datetime as _dt
import json
import re
import sys
from pathlib import Path
from typing import Any

PROVIDERS = {"cpu": "CPUExecutionProvider", "xnnpack": "XnnpackExecutionProvider",
             "nnapi": "NnapiExecutionProvider", "qnn": "QNNExecutionProvider"}
_NUM = r"([-+]?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?)"
_PATTERNS = {
    "session_creation_s": rf"Session creation time cost:\s*{_NUM}\s*s",
    "first_inference_ms": rf"First inference time cost:\s*{_NUM}\s*ms",
    "average_ms": rf"Average inference time cost(?: total)?:\s*{_NUM}\s*ms",
    "total_requests": rf"Total inference requests:\s*{_NUM}",
    "peak_working_set_bytes": rf"Peak working set size:\s*{_NUM}\s*bytes",
    "min_s": rf"Min Latency:\s*{_NUM}\s*s",
    "max_s": rf"Max Latency:\s*{_NUM}\s*s",
    "p50_s": rf"P50 Latency:\s*{_NUM}\s*s",
    "p90_s": rf"P90 Latency:\s*{_NUM}\s*s",
    "p95_s": rf"P95 Latency:\s*{_NUM}\s*s",
    "p99_s": rf"P99 Latency:\s*{_NUM}\s*s",
    "exit_code": rf"exit_code:\s*{_NUM}",
}


def parse_perf_output(text: str) -> dict[str, Any]:
    """Figures from one onnxruntime_perf_test stdout (+ profile.sh's `exit_code:` line).

    Returns {session_creation_s, first_inference_ms, average_ms, total_requests, peak_working_set_bytes, min_s,
    max_s, p50_s, p90_s, p95_s, p99_s, exit_code, ok, error}; missing figures are absent. ok = exit code 0 and
    the latency statistics present (perf_test prints them with -s)."""
    res: dict[str, Any] = {}
    for k, pat in _PATTERNS.items():
        m = re.findall(pat, text)
        if m:
            v = float(m[-1])
            res[k] = int(v) if k in ("total_requests", "peak_working_set_bytes", "exit_code") else v
    res["ok"] = res.get("exit_code", 0) == 0 and "p50_s" in res and "average_ms" in res
    if not res["ok"]:
        errs = [ln.strip() for ln in text.splitlines() if re.search(r"error|fail|exception|not found|cannot",
                                                                    ln, re.I)]
        res["error"] = (errs[-1] if errs else "no latency statistics in the perf_test output")[:300]
    return res


def _split_name(stem: str) -> tuple[str, str, str, str]:
    parts = stem.split("__")
    if len(parts) != 4:
        raise ValueError(f"{stem}: expected <role>__<variant>__<component>__<provider>.txt")
    return parts[0], parts[1], parts[2], parts[3]


def _device_info(raw: Path) -> dict[str, str]:
    info = {}
    f = raw / "device.txt"
    if f.is_file():
        for ln in f.read_text().splitlines():
            if "=" in ln:
                k, v = ln.split("=", 1)
                info[k.strip()] = v.strip()
    return info


def build_report(bundle: str | Path, raw: str | Path) -> dict[str, Any]:
    """The `mosaic profile` report (mosaicthinker.profile_report/1) for the perf_test outputs in `raw`."""
    from mosaicthinker.runtime.budget import bundle_hash
    from mosaicthinker.runtime.infra.bundle import load_bundle
    from mosaicthinker.runtime.commands.profile import REPORT_SCHEMA

    b = load_bundle(bundle, verify=True)
    raw = Path(raw)
    files = sorted(raw.glob("*__*__*__*.txt"))
    if not files:
        raise SystemExit(f"error: {raw}: no perf_test outputs (<role>__<variant>__<component>__<provider>.txt); "
                         f"run android/profile.sh first")
    dev = _device_info(raw)
    report: dict[str, Any] = {
        "schema": REPORT_SCHEMA, "date": _dt.date.today().isoformat(),
        "machine": {"platform": f"android {dev.get('android', '?')}", "processor": dev.get("soc", "?"),
                    "device": dev.get("model", "?"), "cpu_count": None, "python": None,
                    "load_average_1min": None, "onnxruntime": "onnxruntime_perf_test (phone build)",
                    "providers_available": []},
        "bundle": str(b.root), "bundle_hash": bundle_hash(b), "profile": None, "profile_path": None,
        "runs": None, "warmup": 1, "threads": None, "frames_from": "random inputs (onnxruntime_perf_test -I)",
        "isolated": True, "process": {"rss_baseline_mb": None}, "roles": {}, "cpu_side": {}, "fallbacks": [],
        "random_weights_used": [], "measured_costs": {}, "source": "android/profile.sh (onnxruntime_perf_test)",
        "memory_note": "rss_increase_mb / peak_rss_increase_mb = perf_test process peak working set "
                       "(runtime + one model)",
    }
    peak = 0.0
    runs = set()
    for f in files:
        role, variant, comp, prov = _split_name(f.stem)
        meta = b.role_meta(role)
        cm = meta["variants"].get(variant, {}).get("components", {}).get(comp)
        if cm is None:
            raise SystemExit(f"error: {f.name}: {role}/{variant}/{comp} is not in {b.root}/manifest.json")
        r = parse_perf_output(f.read_text(errors="replace"))
        rr = report["roles"].setdefault(role, {
            "arch": meta.get("arch"), "random_weights": bool(meta.get("random_weights")),
            "licence": meta.get("licence"), "planned_variant": None, "providers_requested": [], "variants": {}})
        full = PROVIDERS.get(prov, prov)
        if full not in rr["providers_requested"]:
            rr["providers_requested"].append(full)
        if rr["random_weights"] and f"{role}:{meta.get('arch')}" not in report["random_weights_used"]:
            report["random_weights_used"].append(f"{role}:{meta.get('arch')}")
        key = f"{variant}@{prov}"
        rr["planned_variant"] = rr["planned_variant"] or key
        vr = rr["variants"].setdefault(key, {"precision": meta["variants"][variant].get("precision"),
                                             "components": {}, "adapter": {}})
        rec: dict[str, Any] = {"file": cm.get("file"), "bytes": cm.get("bytes"), "raw": f.name}
        if r["ok"]:
            mb = r.get("peak_working_set_bytes", 0) / 2**20
            peak = max(peak, mb)
            runs.add(r.get("total_requests"))
            rec.update({"load_ms": round(r.get("session_creation_s", float("nan")) * 1000, 2),
                        "first_run_ms": r.get("first_inference_ms"),
                        "latency_ms": {"p50": round(r["p50_s"] * 1000, 3), "p90": round(r["p90_s"] * 1000, 3),
                                       "mean": round(r["average_ms"], 3),
                                       "min": round(r.get("min_s", float("nan")) * 1000, 3),
                                       "n": r.get("total_requests")},
                        "rss_increase_mb": round(mb, 1), "peak_rss_increase_mb": round(mb, 1),
                        "provider": full, "fallbacks": [],
                        "provider_note": "requested provider; perf_test does not report node assignment"})
        else:
            rec["error"] = f"{full}: {r['error']} (exit code {r.get('exit_code')})"
            report["fallbacks"].append({"kind": "fallback", "message": f"{role}/{variant}/{comp}: {rec['error']}"})
        vr["components"][comp] = rec
    report["peak_rss_mb"] = round(peak, 1)
    report["runs"] = sorted(r for r in runs if r)[0] if any(runs) else None
    return report


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--bundle", required=True, help="the bundle folder that was pushed")
    p.add_argument("--raw", required=True, help="folder with the pulled perf_test outputs")
    p.add_argument("--out", required=True, help="where report.json / report.md / PNGs go")
    args = p.parse_args(argv)
    from mosaicthinker.host.report import write_report

    report = build_report(args.bundle, args.raw)
    files = write_report(report, args.out)
    print(json.dumps({"report": files["report.json"], "components": sum(
        len(v["components"]) for r in report["roles"].values() for v in r["variants"].values())}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
