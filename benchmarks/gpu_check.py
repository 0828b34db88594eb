"""Every role of a bundle on the CUDA and TensorRT execution providers (and a GenAI VLM package on ORT GenAI's
CUDA path): parity against CPU on fresh inputs, timings, and the fallback when TensorRT is absent. One prepared
run, under 8 minutes (`--budget-s`, default 420: roles left when it runs out are listed as not run).

    python benchmarks/gpu_check.py --bundle B [--vlm GENAI_PACKAGE_DIR] [--out-dir benchmarks/results]

Needs onnxruntime-gpu (CUDA EP; TensorRT EP where TensorRT is installed) and an NVIDIA GPU. Without a CUDA
provider in this onnxruntime build it says so and exits 0 writing nothing: no GPU figure is ever made up.
Writes OUT_DIR/gpu_check_<card>.json (the card named by nvidia-smi).

Per role (default variant) and ONNX component: sessions through runtime/infra/providers.py on [CUDA, CPU],
[TensorRT, CUDA, CPU] (engine cache in a temporary folder: the first session's build time is `create_s`) and
CPU; `used` = what onnxruntime really assigned (`session.get_providers()`); parity of every output against CPU
on 3 fresh random inputs (max relative error, cosine); median wall ms of 20 runs after 3 warm-ups (CPU: 5 runs).
TensorRT fallback: a session asked for [TensorRT, CUDA, CPU] with TensorRT absent (really absent, or filtered
out of the available list when this build has it) must land on CUDA with a "fallback" trace event.
"""
from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
CUDA, TRT, CPU = "CUDAExecutionProvider", "TensorrtExecutionProvider", "CPUExecutionProvider"
DTYPES = {"float32": np.float32, "float16": np.float16, "uint8": np.uint8, "int8": np.int8, "int32": np.int32,
          "int64": np.int64, "bool": np.bool_}


def card() -> dict[str, str]:
    """The GPU as nvidia-smi names it (name, driver, memory), or {"name": "unknown"}."""
    try:
        out = subprocess.run(["nvidia-smi", "--query-gpu=name,driver_version,memory.total", "--format=csv,noheader"],
                             capture_output=True, text=True, timeout=20).stdout.strip().splitlines()
        name, driver, mem = [x.strip() for x in out[0].split(",")]
        return {"name": name, "driver": driver, "memory": mem}
    except Exception:  # noqa: BLE001  no nvidia-smi: the file still says which build ran
        return {"name": "unknown"}


def feeds(inputs: list[dict[str, Any]], rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Fresh random inputs from the manifest's input specs (dynamic axes -> 1; images in their natural range)."""
    out = {}
    for i in inputs:
        shape = [d if isinstance(d, int) and d > 0 else 1 for d in i["shape"]]
        dt = DTYPES.get(i.get("dtype") or "float32", np.float32)
        if dt == np.uint8:
            out[i["name"]] = rng.integers(0, 256, shape, dtype=np.uint8)
        elif np.issubdtype(dt, np.integer):
            out[i["name"]] = rng.integers(0, 4, shape).astype(dt)
        elif dt == np.bool_:
            out[i["name"]] = np.ones(shape, bool)
        else:
            out[i["name"]] = rng.random(shape, dtype=np.float32).astype(dt)
    return out


def parity(got: list[np.ndarray], ref: list[np.ndarray]) -> dict[str, float]:
    rel, cos = 0.0, 1.0
    for g, r in zip(got, ref):
        g64, r64 = np.asarray(g, np.float64).ravel(), np.asarray(r, np.float64).ravel()
        if g64.size == 0:
            continue
        rel = max(rel, float(np.max(np.abs(g64 - r64)) / (np.max(np.abs(r64)) + 1e-12)))
        den = np.linalg.norm(g64) * np.linalg.norm(r64)
        cos = min(cos, float(g64 @ r64 / den) if den > 0 else 1.0)
    return {"max_rel": rel, "cosine": cos}


def timed(sess: Any, f: dict[str, np.ndarray], runs: int, warm: int) -> float:
    for _ in range(warm):
        sess.run(f)
    ts = []
    for _ in range(runs):
        t0 = time.perf_counter()
        sess.run(f)
        ts.append(time.perf_counter() - t0)
    return round(1000 * float(np.median(ts)), 3)


def component_check(path: Path, inputs: list[dict[str, Any]], stage: str, cache: Path) -> dict[str, Any]:
    from mosaicthinker.runtime.infra.providers import create_session
    from mosaicthinker.runtime.infra.trace import Trace

    rng = np.random.default_rng(0)
    fs = [feeds(inputs, rng) for _ in range(3)]
    cpu = create_session(path, stage, ["cpu"], trace=Trace())
    refs = [cpu.run(f) for f in fs]
    res: dict[str, Any] = {"cpu_ms": timed(cpu, fs[0], 5, 1)}
    trt_opts = {"trt_engine_cache_enable": "1", "trt_engine_cache_path": str(cache / stage),
                "trt_timing_cache_enable": "1"}
    for name, pref in (("cuda", [CUDA, CPU]), ("tensorrt", [(TRT, trt_opts), CUDA, CPU])):
        tr = Trace()
        t0 = time.perf_counter()
        s = create_session(path, stage, pref, trace=tr)
        create_s = time.perf_counter() - t0
        par = [parity(s.run(f), r) for f, r in zip(fs, refs)]
        res[name] = {"used": s.provider, "create_s": round(create_s, 3), "ms": timed(s, fs[0], 20, 3),
                     "max_rel": max(p["max_rel"] for p in par), "cosine": min(p["cosine"] for p in par),
                     "fallbacks": [e["message"] for e in tr.fallbacks()]}
    return res


def trt_fallback(path: Path, stage: str) -> dict[str, Any]:
    """[TensorRT, CUDA, CPU] with TensorRT absent must land on CUDA, loudly."""
    from mosaicthinker.runtime.infra import providers as P
    from mosaicthinker.runtime.infra.trace import Trace

    orig = P.available_providers
    real = orig()
    how = "absent from this onnxruntime build"
    if TRT in real:  # simulate its absence the way the runtime sees it: the available list
        how = "present here: filtered out of the available list"
        P.available_providers = lambda: [p for p in real if p != TRT]  # noqa: E731
    try:
        tr = Trace()
        s = P.create_session(path, stage, [TRT, CUDA, CPU], trace=tr)
    finally:
        P.available_providers = orig
    ev = [e["message"] for e in tr.fallbacks()]
    return {"tensorrt": how, "used": s.provider, "fallback_events": ev,
            "ok": s.provider == CUDA and any("TensorrtExecutionProvider" in m for m in ev)}


def vlm_check(pkg: Path, n_tokens: int = 16) -> dict[str, Any]:
    """Greedy tokens of a text prompt on GenAI's CPU and CUDA paths: equal ids, ms per token."""
    import onnxruntime_genai as og

    out: dict[str, Any] = {"package": str(pkg), "genai": og.__version__}
    ids: dict[str, list[int]] = {}
    for dev in ("cpu", "cuda"):
        cfg = og.Config(str(pkg))
        cfg.clear_providers()
        if dev == "cuda":
            cfg.append_provider("cuda")
        t0 = time.perf_counter()
        model = og.Model(cfg)
        load_s = time.perf_counter() - t0
        tok = og.Tokenizer(model)
        prompt = tok.encode("<|im_start|>user\nHow many chairs are in a kitchen?<|im_end|>\n<|im_start|>assistant\n")
        params = og.GeneratorParams(model)
        params.set_search_options(do_sample=False, top_k=1, max_length=len(prompt) + n_tokens)
        gen = og.Generator(model, params)
        gen.append_tokens(prompt)
        t1 = time.perf_counter()
        got = []
        while not gen.is_done() and len(got) < n_tokens:
            gen.generate_next_token()
            got.append(int(gen.get_next_tokens()[0]))
        dt = time.perf_counter() - t1
        ids[dev] = got
        out[dev] = {"load_s": round(load_s, 2), "tokens": len(got), "ms_per_token": round(1000 * dt / max(len(got), 1), 2)}
        del gen, model
    out["same_tokens"] = ids["cpu"] == ids["cuda"]
    out["first_difference"] = next((i for i, (a, b) in enumerate(zip(ids["cpu"], ids["cuda"])) if a != b), None)
    return out


def main(argv: list[str] | None = None) -> int:
    import onnxruntime as ort

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bundle", type=Path, required=True)
    ap.add_argument("--vlm", type=Path, help="an ONNX Runtime GenAI package folder (genai_config.json)")
    ap.add_argument("--out-dir", type=Path, default=REPO / "benchmarks" / "results")
    ap.add_argument("--budget-s", type=float, default=420.0)
    a = ap.parse_args(argv)
    avail = ort.get_available_providers()
    if CUDA not in avail:
        print(f"no CUDA provider in this onnxruntime build ({ort.__version__}; available: {', '.join(avail)}): "
              f"nothing to check, no GPU figures written. Install onnxruntime-gpu on a machine with an NVIDIA GPU.")
        return 0
    from mosaicthinker.runtime.infra.bundle import load_bundle

    t_start = time.time()
    b = load_bundle(a.bundle, verify=True)
    gpu = card()
    res: dict[str, Any] = {"schema": "mosaicthinker.gpu_check/1", "card": gpu, "onnxruntime": ort.__version__,
                           "available": avail, "bundle": str(a.bundle), "roles": {}, "not_run": []}
    first = None
    with tempfile.TemporaryDirectory(prefix="mosaic-trt-") as cache:
        for role in b.roles:
            v = b.variant_name(role)
            vm = b.role_meta(role)["variants"][v]
            if vm.get("genai"):
                continue  # a GenAI package: --vlm
            for c, cm in vm["components"].items():
                if time.time() - t_start > a.budget_s:
                    res["not_run"].append(f"{role}/{v}/{c}")
                    continue
                path = b.root / cm["file"]
                if cm.get("format") != "onnx":
                    continue
                print(f"[gpu] {role}/{v}/{c}", file=sys.stderr, flush=True)
                try:
                    res["roles"].setdefault(role, {"variant": v})[c] = component_check(path, cm["inputs"],
                                                                                       f"{role}.{c}", Path(cache))
                    first = first or path
                except Exception as e:  # noqa: BLE001  one graph failing must not hide the others
                    res["roles"].setdefault(role, {"variant": v})[c] = {"error": f"{type(e).__name__}: {e}"[:500]}
    if first is not None:
        res["tensorrt_fallback"] = trt_fallback(first, "fallback_check")
    if a.vlm:
        try:
            res["vlm"] = vlm_check(a.vlm)
        except Exception as e:  # noqa: BLE001
            res["vlm"] = {"error": f"{type(e).__name__}: {e}"[:500]}
    res["seconds"] = round(time.time() - t_start, 1)
    slug = re.sub(r"[^a-z0-9]+", "-", gpu["name"].lower()).strip("-") or "unknown"
    a.out_dir.mkdir(parents=True, exist_ok=True)
    dst = a.out_dir / f"gpu_check_{slug}.json"
    tmp = dst.with_suffix(f".tmp-{os.getpid()}")
    tmp.write_text(json.dumps(res, indent=2) + "\n")
    os.replace(tmp, dst)
    print(f"wrote {dst} ({res['seconds']} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
