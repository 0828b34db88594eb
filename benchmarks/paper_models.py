"""The paper's models at their REAL sizes with RANDOM weights: export cost, artifact sizes, peak RSS, parity and
CPU latency; writes benchmarks/results/paper_models.json (merged per model, so steps can run one at a time).

    python benchmarks/paper_models.py checkpoint --model qwen2.5-vl-3b     # random real-config checkpoint
    python benchmarks/paper_models.py export --model qwen2.5-vl-3b         # mosaic export ... --source dir:CKPT
    python benchmarks/paper_models.py measure --model qwen2.5-vl-3b        # latency (2 threads, p50 of >= 5 runs)
    python benchmarks/paper_models.py all --model depth-anything-v2-small  # the three steps
    python benchmarks/paper_models.py side --model qwen2.5-vl-3b           # vision + embedding fp32 vs int8 alone

Random weights of the real configurations are honest for everything except accuracy: export at size (2 GB
protobuf limit, external data, quantiser memory), artifact sizes, peak memory and latency. Every record carries
`random_weights: true`. Multi-GB files live under --big (default /work/big/issue16), never in the repository.
Each step runs in a child process under `/usr/bin/time -v` (peak RSS of the whole process tree). Big steps:
run them one at a time (`flock /tmp/bigmem.lock ...`): the Qwen2.5-VL-3B int4 builder peaks near 21 GB.

VLM measurements: the vision encoder alone on one 448 x 448 map image (onnxruntime, the package's vision graph);
then the whole answer through the runtime adapter (one map image, the paper's prompt on a 14-object map, 16 new
tokens): prefill (vision + embedding + prefill: GenAI runs them as one call) and decode tokens/s.
"""
from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
OUT = REPO / "benchmarks" / "results" / "paper_models.json"
PY = sys.executable
MOSAIC = str(Path(PY).with_name("mosaic"))

# model -> (role, export precisions, exporter options). Sources: the configs published with each checkpoint
# (transformers' config defaults are those checkpoints' configs where noted in `real_config`).
MODELS = {
    "qwen2.5-vl-3b": ("vlm", "fp32,int4", ["image_size=448", "hf_check=1"]),
    "smolvlm-256m": ("vlm", "fp32,int8-dynamic", []),
    "depth-anything-v2-small": ("depth", "fp32,int8-dynamic", ["size=518"]),  # random weights default to 70
    "sam-vit-base": ("segmenter", "fp32,int8-dynamic", []),
    "owlv2-base-patch16": ("detector", "fp32,int8-dynamic", []),
    "clip-vit-base-patch32": ("embedder", "fp32,int8-dynamic", []),
    "efficientloftr": ("matcher", "fp32,int8-dynamic", []),
}


def real_config(name: str):
    """(transformers model class, config) of the real checkpoint's dimensions."""
    import transformers as T

    if name == "depth-anything-v2-small":  # transformers' defaults = Depth-Anything-V2-Small (ViT-S/14 DPT)
        return T.DepthAnythingForDepthEstimation, T.DepthAnythingConfig()
    if name == "sam-vit-base":  # defaults = facebook/sam-vit-base (ViT-B, 1024 px)
        return T.SamModel, T.SamConfig()
    if name == "owlv2-base-patch16":  # google/owlv2-base-patch16-ensemble: ViT-B/16 at 960 px
        return T.Owlv2ForObjectDetection, T.Owlv2Config(vision_config={"patch_size": 16, "image_size": 960})
    if name == "clip-vit-base-patch32":  # defaults = openai/clip-vit-base-patch32
        return T.CLIPModel, T.CLIPConfig()
    if name == "efficientloftr":  # defaults = zju-community/efficientloftr
        return T.EfficientLoFTRForKeypointMatching, T.EfficientLoFTRConfig()
    if name == "smolvlm-256m":  # HuggingFaceTB/SmolVLM-256M-Instruct config.json
        # special ids follow the exporter's synthetic tokenizer (random weights: no real tokenizer here)
        from mosaicthinker.export.hf_vlm import tiny_special_ids

        ids = tiny_special_ids("smolvlm")
        return T.SmolVLMForConditionalGeneration, T.SmolVLMConfig(
            vision_config=dict(hidden_size=768, intermediate_size=3072, num_hidden_layers=12, num_attention_heads=12,
                               image_size=512, patch_size=16),
            text_config=dict(model_type="llama", vocab_size=49280, hidden_size=576, intermediate_size=1536,
                             num_hidden_layers=30, num_attention_heads=9, num_key_value_heads=3, rope_theta=100000.0,
                             max_position_embeddings=8192, rms_norm_eps=1e-5, pad_token_id=ids["pad"],
                             bos_token_id=ids["bos"], eos_token_id=ids["eos"], tie_word_embeddings=True),
            image_token_id=ids["image"], scale_factor=4, tie_word_embeddings=True)
    raise SystemExit(f"unknown model {name}")


# ------------------------------------------------------------------------------------------------ steps (children)

def step_checkpoint(name: str, big: Path) -> dict:
    import torch

    ck = big / "ckpt" / name
    t = time.time()
    n = None
    if name == "qwen2.5-vl-3b":
        from mosaicthinker.export.hf_qwen_vl import random_checkpoint

        random_checkpoint("3b", ck, dtype="bfloat16")
    else:
        from mosaicthinker.export.tiny import torch_default_init

        cls, cfg = real_config(name)
        torch.manual_seed(0)
        model = cls(cfg).eval()
        torch_default_init(model)
        if name == "depth-anything-v2-small":  # as export/tiny.py: the ReLU head of a random net is all zero
            torch.nn.init.constant_(model.head.conv3.bias, 0.1)
        n = sum(p.numel() for p in model.parameters())
        model.save_pretrained(str(ck))
        (ck / "RANDOM_WEIGHTS.json").write_text(json.dumps({"random_weights": True, "config": name, "seed": 0}))
    return {"checkpoint_s": round(time.time() - t, 1), "checkpoint": str(ck), "parameters": n}


def step_export(name: str, big: Path) -> dict:
    role, prec, opts = MODELS[name]
    ck = big / "ckpt" / name
    out = big / "bundles" / name
    cmd = [MOSAIC, "export", role, "--source", f"dir:{ck}", "--precision", prec, "--out", str(out)]
    for o in opts + ([f"workdir={big}"] if name == "qwen2.5-vl-3b" else []):
        cmd += ["--option", o]
    t = time.time()
    reuse = os.environ.get("PAPER_MODELS_REUSE_LOG")  # an export already run with this command under time -v
    if reuse:
        log = Path(reuse).read_text()
        wall = re.search(r"Elapsed \(wall clock\) time \(h:mm:ss or m:ss\): ([\d:.]+)", log).group(1).split(":")
        t -= sum(float(x) * 60 ** i for i, x in enumerate(reversed(wall)))
    else:
        r = subprocess.run(cmd, capture_output=True, text=True)
        if r.returncode != 0:
            raise SystemExit(f"export failed: {r.stderr[-2000:]}")
    from mosaicthinker.runtime.bundle import load_bundle

    rm = load_bundle(out).role_meta(role)
    sizes = {}
    for v, vm in rm["variants"].items():
        files = [c["file"] for c in vm["components"].values()] + [e["file"] for c in vm["components"].values()
                                                                 for e in c.get("extra_files", [])]
        if vm.get("genai"):
            files = [f["file"] for f in vm["genai"]["files"]]
        sizes[v] = round(sum((out / f).stat().st_size for f in set(files)) / 2**20, 1)
    res = {"export_s": round(time.time() - t, 1), "bundle": str(out), "command": " ".join(cmd),
           "size_mib": sizes, "variants": sorted(rm["variants"]), "skipped": rm.get("skipped_variants", {}),
           "parity": {v: _brief_parity(vm) for v, vm in rm["variants"].items()}}
    for v, vm in rm["variants"].items():
        if vm.get("genai"):
            res.setdefault("genai_builder", {})[v] = vm["genai"]["builder"]
            res["graphs_export_s"] = vm["genai"]["graphs_export_s"]
    if reuse:
        res["reused_log"] = reuse
        res["log_peak_rss_mb"] = round(int(re.search(r"Maximum resident set size \(kbytes\): (\d+)", log)
                                             .group(1)) / 1024)
    return res


def _brief_parity(vm: dict) -> dict:
    out = {c: (p or {}).get("worst") for c, p in (vm.get("parity") or {}).items() if isinstance(p, dict)}
    task = vm.get("task_check") or {}
    out.update({k: v for k, v in task.items() if k.startswith(("kl_", "token_agreement", "logits_rel"))})
    return out


def _p50(fn, n: int) -> tuple[float, list[float]]:
    ts = []
    for _ in range(n):
        t = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t)
    return float(np.median(ts)), [round(x, 4) for x in ts]


def _feeds(sess, pre: dict) -> dict:
    """Random feeds for a perception graph: symbolic dims -> 1 (batch-like) or the preprocessing size."""
    size = pre.get("size") or [224, 224]
    rng = np.random.default_rng(0)
    feeds = {}
    for i in sess.get_inputs():
        shape = []
        for ax, d in enumerate(i.shape):
            if isinstance(d, int) and d > 0:
                shape.append(d)
            elif ax == 0:
                shape.append(1)
            else:
                shape.append(size[0] if ax == len(i.shape) - 2 else size[1] if ax == len(i.shape) - 1 else 4)
        dt = {"tensor(float)": np.float32, "tensor(int64)": np.int64, "tensor(int32)": np.int32,
              "tensor(bool)": np.bool_}.get(i.type, np.float32)
        feeds[i.name] = (rng.standard_normal(shape).astype(dt) if dt == np.float32 else np.ones(shape, dt))
    return feeds


def step_measure(name: str, big: Path, runs: int, threads: int, text_chars: int | None = None) -> dict:
    role = MODELS[name][0]
    out = big / "bundles" / name
    if name == "qwen2.5-vl-3b":
        return measure_genai_vlm(out, runs, threads, text_chars)
    if role == "vlm":
        return measure_own_vlm(out, runs, threads)
    import onnxruntime as ort

    from mosaicthinker.runtime.bundle import load_bundle

    b = load_bundle(out)
    rm = b.role_meta(role)
    res = {}
    for v, vm in rm["variants"].items():
        so = ort.SessionOptions()
        so.intra_op_num_threads, so.inter_op_num_threads = threads, 1
        per = {}
        for c, cm in vm["components"].items():
            rss0, t = _rss_mb(), time.perf_counter()
            sess = ort.InferenceSession(str(out / cm["file"]), so, providers=["CPUExecutionProvider"])
            load_s = time.perf_counter() - t
            feeds = _feeds(sess, rm.get("preprocessing", {}))
            try:
                sess.run(None, feeds)
            except Exception as e:  # noqa: BLE001  (a graph whose inputs the generic feeds do not fit)
                per[c] = {"error": f"{type(e).__name__}: {str(e)[:160]}"}
                continue
            p50, ts = _p50(lambda: sess.run(None, feeds), runs)
            per[c] = {"p50_s": round(p50, 4), "runs_s": ts, "load_s": round(load_s, 3),
                      "resident_mb": round(_rss_mb() - rss0, 1),
                      "input_shapes": {k: list(a.shape) for k, a in feeds.items()}}
            del sess
        res[v] = per
    return {"latency": res, "threads": threads}


def _rss_mb() -> float:
    import psutil

    return psutil.Process().memory_info().rss / 2**20


def _paper_map(n: int = 14):
    """A fixed 14-object map (the prompt's real length; not dataset data)."""
    from mosaicthinker.runtime.geometry import OrientedBox, rotation_about
    from mosaicthinker.runtime.semantic_map import ObjectInstance, SemanticMap

    rng = np.random.default_rng(3)
    names = ["sofa", "table", "chair", "tv", "lamp", "bed", "sink", "fridge", "door", "window", "plant", "shelf",
             "stool", "oven"]
    inst = [ObjectInstance(i, names[i % len(names)], OrientedBox(rng.uniform([-3, -3, 0.2], [3, 3, 1.0]),
            rng.uniform(0.3, 2.0, 3), rotation_about([0, 0, 1], rng.uniform(0, np.pi)).T), float(i))
            for i in range(n)]
    cams = [(float(t), np.eye(4)) for t in range(8)]
    return SemanticMap(inst, None, cams)


def _prompt(text_chars: int | None = None):
    """The map image and the paper's prompt over the 14-object map. text_chars cuts the object block: the
    synthetic byte-level tokenizer makes ~1 token per character, ~3-4x what Qwen's real BPE makes, so a cut
    block gives the real prompt's token count (see the docs)."""
    from mosaicthinker.runtime.prompt import render, vlm_prompt

    vp = render(_paper_map())
    block = vp.text if text_chars is None else vp.text[:text_chars]
    return vp, vlm_prompt("Which object is closest to the sofa?", ["A. table", "B. chair", "C. tv", "D. lamp"],
                          block, "grid")


def measure_own_vlm(out: Path, runs: int, threads: int) -> dict:
    """The project's own loop (SmolVLM: vision + embed + decoder graphs): whole answer, 16 new tokens."""
    from mosaicthinker.runtime.bundle import load_bundle
    from mosaicthinker.runtime.stages import load_role, preprocess_image
    from mosaicthinker.runtime.trace import Trace

    vp, prompt = _prompt()
    res = {"threads": threads, "map_image": list(vp.image.shape)}
    for v in sorted(load_bundle(out).role_meta("vlm")["variants"]):
        trace = Trace()
        rss0, t = _rss_mb(), time.perf_counter()
        vlm = load_role(out, "vlm", variant=v, threads=threads, trace=trace)
        load_s, load_rss = time.perf_counter() - t, _rss_mb() - rss0
        ids, _ = vlm.encode([vp.image], prompt)
        rec = []
        for _ in range(runs):
            t = time.perf_counter()
            ids_new = vlm.core.generate_ids(ids, vlm.encode([vp.image], prompt)[1], 16, [])  # no early stop
            rec.append(round(time.perf_counter() - t, 3))
        t = time.perf_counter()
        feats = vlm.core.image_features(preprocess_image(vp.image, vlm.spec.preprocessing))
        vis = time.perf_counter() - t
        res[v] = {"answer_16_tokens_p50_s": float(np.median(rec)), "runs_s": rec, "prompt_tokens": len(ids),
                  "load_s": round(load_s, 2), "resident_mb_after_load": round(load_rss),
                  "resident_mb_after_runs": round(_rss_mb() - rss0),
                  "vision_s": round(vis, 3), "new_tokens": len(ids_new), "image_features": list(feats.shape)}
    return res


def measure_genai_vlm(out: Path, runs: int, threads: int, text_chars: int | None = None) -> dict:
    import resource

    import onnxruntime as ort

    from mosaicthinker.runtime.bundle import load_bundle
    from mosaicthinker.runtime.stages import load_role
    from mosaicthinker.runtime.trace import Trace

    vp, prompt = _prompt(text_chars)
    rm = load_bundle(out).role_meta("vlm")
    res = {"prompt_chars": len(prompt), "text_block_chars": text_chars, "map_image": list(vp.image.shape), "threads": threads}
    for v in sorted(rm["variants"], key=lambda v: v != "int4"):
        pkg = out / rm["variants"][v]["genai"]["package"]
        so = ort.SessionOptions()
        so.intra_op_num_threads, so.inter_op_num_threads = threads, 1
        vs = ort.InferenceSession(str(pkg / "vision" / "model.onnx"), so, providers=["CPUExecutionProvider"])
        g = rm["config"]["image_size"] // 14
        feeds = {"pixel_values": np.random.default_rng(0).standard_normal((g * g, 1176)).astype(np.float32),
                 "image_grid_thw": np.array([[1, g, g]], np.int64)}
        vs.run(None, feeds)
        vis_p50, vis_ts = _p50(lambda: vs.run(None, feeds), runs)
        del vs
        trace = Trace()
        rss0, t = _rss_mb(), time.perf_counter()
        vlm = load_role(out, "vlm", variant=v, threads=threads, trace=trace)
        load_s, load_rss = time.perf_counter() - t, _rss_mb() - rss0
        rec = []
        for _ in range(runs):
            t = time.perf_counter()
            vlm.generate_ids([vp.image], prompt, max_new_tokens=16)
            rec.append({**vlm.last, "answer_s": round(time.perf_counter() - t, 3)})
        res[v] = {"vision_448_p50_s": round(vis_p50, 3), "vision_runs_s": vis_ts, "load_s": round(load_s, 2),
                  "resident_mb_after_load": round(load_rss), "resident_mb_after_runs": round(_rss_mb() - rss0),
                  "prompt_tokens": rec[0]["prompt_tokens"],
                  "prefill_p50_s": float(np.median([r["prefill_s"] for r in rec])),
                  "decode_tok_s_p50": float(np.median([r["decode_tokens_per_s"] for r in rec])),
                  "answer_16_tokens_p50_s": float(np.median([r["answer_s"] for r in rec])), "runs": rec,
                  "peak_rss_mb_so_far": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)}
        del vlm
        if v == "int4":
            break  # fp32 (13 GB session) only when asked: --variant fp32
    return res


# ------------------------------------------------------------------------------------------------ side

def step_side(name: str, big: Path, runs: int, threads: int, image_size: int = 448) -> dict:
    """Qwen2.5-VL's vision graph and embedding table, fp32 and int8 (the int8/int4 packages' side), from the
    checkpoint alone -- no GenAI builder, no decoder: sizes, parity (int8 vs fp32 on fresh inputs), and each
    graph's session RSS and latency measured in its own fresh process (`_probe`). Graphs kept under
    BIG/side/NAME for a later package."""
    import gc
    import shutil

    from mosaicthinker.export.hf_qwen_vl import export_graphs, export_int8_graphs, load_vision_side

    if name != "qwen2.5-vl-3b":
        raise SystemExit("side: only qwen2.5-vl-3b (its GenAI package's vision + embedding)")
    work = big / "side" / name
    shutil.rmtree(work, ignore_errors=True)
    t = time.time()
    model = load_vision_side(big / "ckpt" / name)
    g32 = export_graphs(model, work / "fp32", image_size)
    t32 = time.time() - t
    g8 = export_int8_graphs(model, g32, work / "int8")
    t8 = time.time() - t - t32
    del model
    gc.collect()
    res = {"image_size": image_size, "threads": threads, "export_s": {"fp32": round(t32, 1), "int8": round(t8, 1)},
           "int8_quant": {"vision": g8["vision_quant"], "embedding": g8["embedding_quant"]}}
    for prec, g in (("fp32", g32), ("int8", g8)):
        for c in ("vision", "embedding"):
            d = Path(g[c]).parent
            r = subprocess.run([PY, __file__, "_probe", c, str(g[c]), "--runs", str(runs), "--threads", str(threads)],
                               capture_output=True, text=True)
            if r.returncode != 0:
                raise SystemExit(f"probe {prec} {c} failed:\n{r.stderr[-2000:]}")
            res.setdefault(prec, {})[c] = {
                "size_mib": round(sum(f.stat().st_size for f in d.iterdir()) / 2**20, 1),
                **json.loads(r.stdout.strip().splitlines()[-1]),
                **({"parity_vs_fp32": g["parity"][c]["worst"]} if prec == "int8" else {})}
    for prec in ("fp32", "int8"):
        res[prec]["rss_after_run_mb_sum"] = round(sum(res[prec][c]["rss_after_run_mb"]
                                                      for c in ("vision", "embedding")))
    return res


def probe(component: str, path: str, runs: int, threads: int) -> dict:
    """One graph in this fresh process: RSS after the session load and after runs (vision: one 448 map image;
    embedding: the real prompt length, 979 ids with 256 image rows), p50 latency, peak RSS."""
    import resource

    import onnxruntime as ort

    base = _rss_mb()
    so = ort.SessionOptions()
    so.intra_op_num_threads, so.inter_op_num_threads = threads, 1
    t = time.perf_counter()
    sess = ort.InferenceSession(path, so, providers=["CPUExecutionProvider"])
    load_s, load_mb = time.perf_counter() - t, _rss_mb() - base
    rng = np.random.default_rng(0)
    if component == "vision":
        n = {i.name: i.shape for i in sess.get_inputs()}["pixel_values"][0]
        g = int(round(n ** 0.5))
        feeds = {"pixel_values": rng.standard_normal((n, 1176)).astype(np.float32),
                 "image_grid_thw": np.array([[1, g, g]], np.int64)}
    else:
        ids = rng.integers(0, 151643, size=(1, 979)).astype(np.int64)
        ids[0, 20:276] = 151655
        h = {i.name: i.shape for i in sess.get_inputs()}["image_features"][1]  # static: the text hidden size
        feeds = {"input_ids": ids, "image_features": rng.standard_normal((256, h)).astype(np.float32)}
    sess.run(None, feeds)
    p50, ts = _p50(lambda: sess.run(None, feeds), runs)
    return {"load_s": round(load_s, 2), "rss_after_load_mb": round(load_mb),
            "rss_after_run_mb": round(_rss_mb() - base),
            "p50_s": round(p50, 3), "runs_s": ts,
            "process_peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)}


# ------------------------------------------------------------------------------------------------ profile

# profile cost item -> (model, variant, {field: (component, what)}); what: p50 | load | rss
PAPER_COSTS = {
    "depth": ("depth-anything-v2-small", "fp32", {"ms_per_call": ("model", "p50")}),
    "segmenter": ("sam-vit-base", "fp32", {"ms_per_call": ("encoder", "p50"), "ms_per_prompt": ("decoder", "p50")}),
    "detector": ("owlv2-base-patch16", "fp32", {"ms_per_call": ("image", "p50")}),
    "embedder": ("clip-vit-base-patch32", "fp32", {"ms_per_call": ("model", "p50")}),
    "matcher": ("efficientloftr", "fp32", {"ms_per_pair": ("pair", "p50")}),
}


def paper_costs(data: dict, big: Path) -> dict:
    """[paper_costs.*] entries from the measured results (perception fp32; VLM: Qwen2.5-VL-3B int4)."""
    from mosaicthinker.runtime.bundle import bundle_hash, load_bundle

    date = time.strftime("%Y-%m-%d")
    out = {}
    for item, (model, v, fields) in PAPER_COSTS.items():
        lat = ((data["models"].get(model) or {}).get("measure") or {}).get("latency", {}).get(v)
        if not lat:
            continue
        comps = [c for c, _ in fields.values()]
        e = {f: round(lat[c]["p50_s"] * 1000, 1) for f, (c, _) in fields.items()}
        e.setdefault("ms_per_call", 0.0)
        if item == "segmenter":
            e.setdefault("ms_per_prompt", 0.0)
        if item == "matcher":
            e.setdefault("ms_per_pair", 0.0)
        e["load_ms"] = round(sum(lat[c]["load_s"] for c in comps) * 1000, 1)
        e["resident_mb"] = round(max(0.0, sum(lat[c]["resident_mb"] for c in comps)), 1)
        out[item] = {**e, "status": "measured", "date": date,
                     "bundle_hash": bundle_hash(load_bundle(big / "bundles" / model, verify=False)),
                     "provider": "CPUExecutionProvider",
                     "note": f"paper model {model} {v} at its real config with RANDOM weights "
                             f"(benchmarks/paper_models.py; 2 threads, p50 of 5; shared CPUs)"}
    q = data["models"].get("qwen2.5-vl-3b", {})
    m = (q.get("measure_text300") or q.get("measure") or {}).get("int4")
    if m:
        out["vlm"] = {"ms_per_image": round(m["prefill_p50_s"] * 1000, 1),
                      "ms_per_token": round(1000 / m["decode_tok_s_p50"], 1), "load_ms": round(m["load_s"] * 1000, 1),
                      "resident_mb": float(m["resident_mb_after_runs"]), "status": "measured", "date": date,
                      "bundle_hash": bundle_hash(load_bundle(big / "bundles" / "qwen2.5-vl-3b", verify=False)),
                      "provider": "CPUExecutionProvider",
                      "note": f"Qwen2.5-VL-3B int4 ONNX Runtime GenAI package, RANDOM weights; ms_per_image = "
                              f"vision + prefill of the whole prompt ({m['prompt_tokens']} tokens, one 448 px map "
                              f"image); 2 threads, p50 of 5"}
    return out


def write_profile(big: Path, profile: Path) -> dict:
    import tomllib

    import tomli_w

    data = json.loads(OUT.read_text())
    prof = tomllib.loads(profile.read_text())
    prof["paper_costs"] = paper_costs(data, big)
    profile.write_text(tomli_w.dumps(prof))
    return prof["paper_costs"]


def cost_table(data: dict) -> str:
    """Markdown: per model and precision, export time / peak RSS, size, parity, CPU latency (2 threads)."""
    rows = ["| model (random weights) | params | export s / peak RSS GB | precision | size MiB | parity | CPU 2 threads |",
            "|---|---|---|---|---|---|---|"]
    for name, r in data["models"].items():
        e, ck = r.get("export") or {}, r.get("checkpoint") or {}
        meas = r.get("measure_text300") or r.get("measure") or {}
        for v, size in (e.get("size_mib") or {}).items():
            par = e.get("parity", {}).get(v, {})
            ptxt = ", ".join(f"{k} {x['rel']:.1e}" if isinstance(x, dict) else f"{k} {x:.3g}"
                             for k, x in par.items() if x is not None)
            lat = (meas.get("latency") or {}).get(v)
            if lat:
                ltxt = ", ".join(f"{c} {x['p50_s'] * 1000:.0f} ms" for c, x in lat.items() if "p50_s" in x)
            elif v in meas and "prefill_p50_s" in meas[v]:
                m = meas[v]
                ltxt = (f"vision 448 {m['vision_448_p50_s']:.1f} s; prefill ({m['prompt_tokens']} tok) "
                        f"{m['prefill_p50_s']:.1f} s; decode {m['decode_tok_s_p50']:.1f} tok/s; answer (16 tok) "
                        f"{m['answer_16_tokens_p50_s']:.1f} s; RSS {m['peak_rss_mb_so_far'] / 1024:.1f} GB")
            elif v in meas:
                ltxt = f"answer (16 tok, {meas[v]['prompt_tokens']} prompt tok) {meas[v]['answer_16_tokens_p50_s']:.1f} s"
            else:
                ltxt = "-"
            rows.append(f"| {name} | {ck.get('parameters') or '-'} | {e.get('export_s', '-')} / "
                        f"{(e.get('export_peak_rss_mb') or 0) / 1024:.1f} | {v} | {size} | {ptxt or '-'} | {ltxt} |")
    return "\n".join(rows)


# ------------------------------------------------------------------------------------------------ driver

def run_child(step: str, name: str, args) -> dict:
    """One step in a child process under /usr/bin/time -v: its result JSON plus wall time and peak RSS."""
    cmd = ["/usr/bin/time", "-v", PY, __file__, "_child", step, "--model", name, "--big", str(args.big),
           "--runs", str(args.runs), "--threads", str(args.threads)]
    if args.text_chars:
        cmd += ["--text-chars", str(args.text_chars)]
    t = time.time()
    r = subprocess.run(cmd, capture_output=True, text=True)
    peak = re.search(r"Maximum resident set size \(kbytes\): (\d+)", r.stderr)
    if r.returncode != 0:
        raise SystemExit(f"{step} {name} failed:\n{r.stderr[-3000:]}")
    res = json.loads(r.stdout.strip().splitlines()[-1])
    res.update({f"{step}_wall_s": round(time.time() - t, 1),
                f"{step}_peak_rss_mb": round(int(peak.group(1)) / 1024) if peak else None})
    if "log_peak_rss_mb" in res:  # a reused export: its own run's figures, not this re-reading's
        res.update({f"{step}_wall_s": res["export_s"], f"{step}_peak_rss_mb": res["log_peak_rss_mb"]})
    return res


def save(name: str, step: str, res: dict) -> None:
    data = json.loads(OUT.read_text()) if OUT.is_file() else {"schema": "mosaicthinker.bench.paper_models/1"}
    data.setdefault("models", {}).setdefault(name, {"random_weights": True})[step] = res
    data["machine"] = {"cpus": os.cpu_count(), "note": "2 CPU cores shared with other jobs, 24 GB RAM, no GPU"}
    data["command"] = "python benchmarks/paper_models.py all --model NAME (see the module doc)"
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text(json.dumps(data, indent=1))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("step", choices=["checkpoint", "export", "measure", "side", "all", "profile", "table",
                                     "_child", "_probe"])
    ap.add_argument("child_step", nargs="?")
    ap.add_argument("probe_path", nargs="?")
    ap.add_argument("--model", choices=sorted(MODELS))
    ap.add_argument("--big", type=Path, default=Path(os.environ.get("MOSAIC_BIG", "/work/big/issue16")))
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--text-chars", type=int, help="VLM: cut the object text block to N characters (the real "
                                                   "tokenizer's prompt length with the synthetic byte tokenizer)")
    args = ap.parse_args(argv)
    if args.step == "profile":  # [paper_costs.*] of profiles/cpu-generic.toml from the measured results
        print(json.dumps(write_profile(args.big, REPO / "profiles" / "cpu-generic.toml"), indent=1))
        return 0
    if args.step == "table":
        print(cost_table(json.loads(OUT.read_text())))
        return 0
    if args.step == "_probe":  # one graph's session in this fresh process (step_side)
        print(json.dumps(probe(args.child_step, args.probe_path, args.runs, args.threads)))
        return 0
    if not args.model:
        ap.error("--model is required")
    if args.step == "_child":
        fn = {"checkpoint": step_checkpoint, "export": step_export, "measure": step_measure,
              "side": step_side}[args.child_step]
        kw = ({"runs": args.runs, "threads": args.threads, "text_chars": args.text_chars}
              if args.child_step == "measure" else
              {"runs": args.runs, "threads": args.threads} if args.child_step == "side" else {})
        print(json.dumps(fn(args.model, args.big, **kw)))
        return 0
    for step in (["checkpoint", "export", "measure"] if args.step == "all" else [args.step]):
        res = run_child(step, args.model, args)
        save(args.model, step + (f"_text{args.text_chars}" if args.text_chars else ""), res)
        print(json.dumps({args.model: {step: res}}, indent=1)[:3000])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
