"""The paper's models at their REAL sizes with RANDOM weights: export cost, artifact sizes, peak RSS, parity and
CPU latency; writes benchmarks/results/paper_models.json (merged per model, so steps can run one at a time).

    python benchmarks/paper_models.py checkpoint --model qwen2.5-vl-3b     # random real-config checkpoint
    python benchmarks/paper_models.py export --model qwen2.5-vl-3b         # mosaic export ... --source dir:CKPT
    python benchmarks/paper_models.py measure --model qwen2.5-vl-3b        # latency (2 threads, p50 of >= 5 runs)
    python benchmarks/paper_models.py all --model depth-anything-v2-small  # the three steps
    python benchmarks/paper_models.py side --model qwen2.5-vl-3b           # vision + embedding fp32 vs int8 alone
    python benchmarks/paper_models.py vision-ab --model qwen2.5-vl-3b      # fp32 vs int8 vision, runs alternated
    python benchmarks/paper_models.py all --model qwen3-vl-2b              # the project's graphs, torch and ORT apart
    python benchmarks/paper_models.py qwen3-profile --prefill-len 256      # the 2B decoder under ORT's profiler
    python benchmarks/paper_models.py qwen3-int8 --model qwen3-vl-2b       # int8 decoder (external data)
    python benchmarks/paper_models.py measure --model qwen3-vl-2b --precision int8
    python benchmarks/paper_models.py scale-profiles                       # other profiles' [paper_costs] (scaled)
    python benchmarks/paper_models.py grounding                            # [paper_costs.grounding] from the e2e run
    python benchmarks/paper_models.py variants                             # cpu-generic's other measured precisions

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
E2E = REPO / "benchmarks" / "results" / "paper_models_e2e_ask.json"  # `mosaic ask --answerer vlm`, whole question
PY = sys.executable
MOSAIC = str(Path(PY).with_name("mosaic"))

# model -> (role, export precisions, exporter options). Sources: the configs published with each checkpoint
# (transformers' config defaults are those checkpoints' configs where noted in `real_config`).
MODELS = {
    # hf_check=1 (transformers fp32 reference, ~15 GB more) was run once: export_fp32_side in the results JSON
    "qwen2.5-vl-3b": ("vlm", "fp32,int4", ["image_size=448", "hf_check=0", "vision_quant=dynamic"]),
    "smolvlm-256m": ("vlm", "fp32,int8-dynamic", []),
    # the project's own graphs (no GenAI DeepStack): steps export/measure run qwen3_export / qwen3_measure
    "qwen3-vl-2b": ("vlm", "fp32", ["image_size=448"]),
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
    elif name == "qwen3-vl-2b":
        from mosaicthinker.export.hf_qwen3_vl import random_checkpoint

        random_checkpoint("2b", ck, dtype="bfloat16")
        n = json.loads((ck / "RANDOM_WEIGHTS.json").read_text())["parameters"]
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


def step_export(name: str, big: Path, text_chars: int | None = None) -> dict:
    if name == "qwen3-vl-2b":
        return qwen3_export(big, text_chars=text_chars)
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
    from mosaicthinker.runtime.infra.bundle import load_bundle

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


def _cpu_timed(fn, n: int) -> dict:
    """p50 wall AND process CPU seconds (every thread) of `fn` over n runs: under shared load the wall time moves
    with the other jobs, the CPU seconds much less."""
    wall, cpu = [], []
    for _ in range(n):
        t, c = time.perf_counter(), time.process_time()
        fn()
        wall.append(time.perf_counter() - t)
        cpu.append(time.process_time() - c)
    return {"p50_s": round(float(np.median(wall)), 3), "runs_s": [round(x, 3) for x in wall],
            "cpu_p50_s": round(float(np.median(cpu)), 3), "cpu_runs_s": [round(x, 3) for x in cpu]}


def vision_ab(big: Path, runs: int, threads: int, quant: str = "dynamic") -> dict:
    """The fp32 and the quantised Qwen2.5-VL vision graphs of the side step in ONE process, runs alternated
    (a, b, a, b, ...), so both see the same shared-CPU load: wall and CPU seconds per 448 px image."""
    import onnxruntime as ort

    side = big / "side" / "qwen2.5-vl-3b"
    so = ort.SessionOptions()
    so.intra_op_num_threads, so.inter_op_num_threads = threads, 1
    paths = {"fp32": side / "fp32" / "vision" / "model.onnx", quant: side / f"vision-{quant}" / "model.onnx"}
    load0 = _load()
    sess = {k: ort.InferenceSession(str(v), so, providers=["CPUExecutionProvider"]) for k, v in paths.items()}
    n = sess["fp32"].get_inputs()[0].shape[0]
    g = int(round(n ** 0.5))
    feeds = {"pixel_values": np.random.default_rng(0).standard_normal((n, 1176)).astype(np.float32),
             "image_grid_thw": np.array([[1, g, g]], np.int64)}
    for x in sess.values():
        x.run(None, feeds)
    rec = {k: {"runs_s": [], "cpu_runs_s": []} for k in sess}
    for _ in range(runs):
        for k, x in sess.items():
            r = _cpu_timed(lambda: x.run(None, feeds), 1)
            rec[k]["runs_s"] += r["runs_s"]
            rec[k]["cpu_runs_s"] += r["cpu_runs_s"]
    for r in rec.values():
        r["p50_s"], r["cpu_p50_s"] = float(np.median(r["runs_s"])), float(np.median(r["cpu_runs_s"]))
    return {"threads": threads, "load_start": load0, **rec,
            "wall_ratio": rec[quant]["p50_s"] / rec["fp32"]["p50_s"],
            "cpu_ratio": rec[quant]["cpu_p50_s"] / rec["fp32"]["cpu_p50_s"], "load_end": _load()}


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


def step_measure(name: str, big: Path, runs: int, threads: int, text_chars: int | None = None,
                 precision: str = "fp32") -> dict:
    role = MODELS[name][0]
    out = big / "bundles" / name
    if name == "qwen2.5-vl-3b":
        return measure_genai_vlm(out, runs, threads, text_chars)
    if name == "qwen3-vl-2b":
        return qwen3_measure(big, runs, threads, precision=precision)
    if role == "vlm":
        return measure_own_vlm(out, runs, threads)
    import onnxruntime as ort

    from mosaicthinker.runtime.infra.bundle import load_bundle

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
    from mosaicthinker.runtime.map import ObjectInstance, SemanticMap

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
    from mosaicthinker.runtime.infra.bundle import load_bundle
    from mosaicthinker.runtime.models import load_role, preprocess_image
    from mosaicthinker.runtime.infra.trace import Trace

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

    from mosaicthinker.runtime.infra.bundle import load_bundle
    from mosaicthinker.runtime.models import load_role
    from mosaicthinker.runtime.infra.trace import Trace

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
        vis = _cpu_timed(lambda: vs.run(None, feeds), runs)
        vis_p50, vis_ts = vis["p50_s"], vis["runs_s"]
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
        res[v] = {"vision_448_p50_s": round(vis_p50, 3), "vision_runs_s": vis_ts,
                  "vision_cpu_p50_s": vis["cpu_p50_s"], "load_s": round(load_s, 2),
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


# ------------------------------------------------------------------------------------------------ Qwen3-VL-2B
# The project's own graphs (export/hf_qwen3_vl.py) at the real 2B size, in two child processes so the torch model
# and the onnxruntime sessions are never loaded together: qwen3_export (torch: graphs with external data, and
# every reference output on fresh inputs saved to disk), then qwen3_measure (onnxruntime only: parity against
# the saved references, latency of the runtime loop).

def _qwen3_dir(big: Path) -> Path:
    return big / "qwen3" / "qwen3-vl-2b"


def _qwen3_prompt_ids(tok, cfg: dict, text_chars: int | None):
    from mosaicthinker.runtime.models import preprocess_image
    from mosaicthinker.runtime.models.vlm import build_prompt, qwen_patches

    vp, prompt = _prompt(text_chars)
    pre = {"size": [cfg["image_size"]] * 2, "layout": "NCHW", "channel_order": "RGB", "dtype": "float32",
           "scale": 1 / 255, "mean": [0.5] * 3, "std": [0.5] * 3}
    px = qwen_patches(preprocess_image(vp.image, pre)[0], cfg["patch_size"], cfg["merge_size"],
                      cfg["temporal_patch_size"])
    ids = tok.encode(build_prompt("qwen3_vl", prompt, 1, cfg["image_seq_len"]), add_special_tokens=False).ids
    return ids, px


def qwen3_export(big: Path, image_size: int = 448, n_new: int = 16, trials: int = 2,
                 text_chars: int | None = None) -> dict:
    """torch side: load the random 2B checkpoint (fp32), export vision / embed / decoder (external data past
    1 GiB, export/hf_common.needs_external_data), and save to disk every reference the measure step compares
    against: each graph's torch wrapper on `trials` fresh inputs, transformers' own vision forward and greedy
    generate (tokens + first-step logits) on the paper prompt with the map image."""
    import gc

    import torch

    from mosaicthinker.export import common as C
    from mosaicthinker.export.hf_common import needs_external_data, torch_reference
    from mosaicthinker.export.hf_qwen3_vl import IMAGE_TOKEN, graph_specs, hf_vision, load_model, runtime_config
    from mosaicthinker.export.parity import parity_rng
    from mosaicthinker.runtime.models.vlm import load_tokenizer

    ck, work = big / "ckpt" / "qwen3-vl-2b", _qwen3_dir(big)
    import shutil

    shutil.rmtree(work, ignore_errors=True)
    (work / "fp32").mkdir(parents=True)
    t = time.time()
    model, prov = load_model(f"dir:{ck}")
    res = {"load_s": round(time.time() - t, 1), "rss_after_load_mb": round(_rss_mb()), "provenance": prov,
           "parameters": sum(p.numel() for p in model.parameters()), "load": _load()}
    cfg = runtime_config(model, image_size)
    refs: dict[str, np.ndarray] = {}
    graphs = {}
    for g in graph_specs(model, image_size):
        t = time.time()
        ext = needs_external_data(g.module)
        path = C.export_torch(g.module, g.example, work / "fp32" / f"{g.name}.onnx", g.input_names,
                              g.output_names, dynamic_shapes=g.dynamic_shapes, external_data=ext)
        secs = time.time() - t
        seed, rng = parity_rng()
        ref = torch_reference(g.module, g.input_names)
        for i in range(trials):
            feeds = g.make_inputs(rng)
            for k, v in feeds.items():
                refs[f"{g.name}/{i}/in/{k}"] = v
            for j, o in enumerate(ref(feeds)):
                refs[f"{g.name}/{i}/out/{j}"] = o
        graphs[g.name] = {"export_s": round(secs, 1), "external_data": ext, "parity_seed": seed,
                          "size_mib": round(sum(f.stat().st_size for f in path.parent.iterdir()
                                                if f.name.startswith(path.name)) / 2**20, 1),
                          "rss_after_mb": round(_rss_mb())}
        C.progress(f"qwen3-vl-2b {g.name}: exported in {secs:.0f} s, {graphs[g.name]['size_mib']} MiB")
    tok = load_tokenizer(str(ck / "tokenizer.json"))
    ids, px = _qwen3_prompt_ids(tok, cfg, text_chars)
    refs["hf/vision/0"], refs["hf/vision/1"] = hf_vision(model, px, image_size)
    g = image_size // cfg["patch_size"]
    tt = torch.tensor([ids])
    t = time.time()
    with torch.no_grad():
        out = model.generate(input_ids=tt, attention_mask=torch.ones_like(tt), pixel_values=torch.from_numpy(px),
                             image_grid_thw=torch.tensor([[1, g, g]]), mm_token_type_ids=(tt == IMAGE_TOKEN).int(),
                             max_new_tokens=n_new, do_sample=False, num_beams=1, eos_token_id=None,
                             pad_token_id=151643, output_logits=True, return_dict_in_generate=True)
    hf_s = time.time() - t
    refs["hf/tokens"] = out.sequences[0, len(ids):].numpy()
    refs["hf/logits0"] = out.logits[0][0].float().numpy()
    refs["prompt/ids"], refs["prompt/pixel_values"] = np.asarray(ids, np.int64), px
    np.savez(work / "refs.npz", **refs)
    (work / "config.json").write_text(json.dumps(cfg))
    del model, out
    gc.collect()
    return {**res, "graphs": graphs, "config": cfg, "image_size": image_size, "prompt_tokens": len(ids),
            "text_block_chars": text_chars, "transformers_fp32_answer_s": round(hf_s, 1),
            "size_mib": {"fp32": round(sum(x["size_mib"] for x in graphs.values()), 1)}, "dir": str(work)}


class _TimedRunner:
    """An onnxruntime session as a runner (`.run(feeds) -> list`) that records (start, end, CPU end, rows) of
    every call and keeps the last multi-row (prefill) call's logits."""

    def __init__(self, sess):
        self.sess, self.calls, self.prefill_logits = sess, [], None

    def run(self, feeds: dict, outputs=None) -> list:
        t = time.perf_counter()
        out = self.sess.run(outputs, feeds)
        rows = feeds["inputs_embeds"].shape[1]
        self.calls.append((t, time.perf_counter(), time.process_time(), rows))
        if rows > 1:
            self.prefill_logits = out[0]
        return out


def qwen3_int8(big: Path) -> dict:
    """The 2B fp32 decoder through the project's dynamic int8 quantiser (export/common.py; external data past
    protobuf's 2 GiB): time and size (peak RSS: run_child). Vision and embed stay fp32."""
    from mosaicthinker.export import common as C

    src, dst = _qwen3_dir(big) / "fp32" / "decoder.onnx", _qwen3_dir(big) / "int8" / "decoder.onnx"
    dst.parent.mkdir(parents=True, exist_ok=True)
    for f in dst.parent.glob("decoder.onnx*"):
        f.unlink()
    t = time.time()
    C.quantize_int8_dynamic(src, dst)
    files = sorted(f for f in dst.parent.iterdir() if f.name.startswith(dst.name))
    return {"quantize_s": round(time.time() - t, 1), "load": _load(), "files": [f.name for f in files],
            "size_mib": round(sum(f.stat().st_size for f in files) / 2**20, 1),
            "fp32_size_mib": round(sum(f.stat().st_size for f in src.parent.iterdir()
                                       if f.name.startswith(src.name)) / 2**20, 1)}


def qwen3_measure(big: Path, runs: int, threads: int, n_new: int = 16, precision: str = "fp32") -> dict:
    """onnxruntime side (no torch model in this process): each graph vs its saved torch references, the vision
    graph vs transformers' vision forward, then the runtime loop (MRopeDecoder) on the paper prompt with the map
    image: vision alone, prefill, decode tokens/s, the whole answer, and its tokens / first-step KL vs
    transformers' greedy generate."""
    import resource

    import onnxruntime as ort

    from mosaicthinker.export.hf_qwen_vl import kl_next_token
    from mosaicthinker.export.parity import compare_outputs
    from mosaicthinker.runtime.models.vlm import MRopeDecoder, OrtRunner

    work = _qwen3_dir(big)
    refs = dict(np.load(work / "refs.npz"))
    cfg = json.loads((work / "config.json").read_text())
    so = ort.SessionOptions()
    so.intra_op_num_threads, so.inter_op_num_threads = threads, 1
    sess, res = {}, {"threads": threads, "load": _load(), "graphs": {}}
    for name in ("vision", "embed", "decoder"):  # vision and embed stay fp32 at every precision here
        rss0, t = _rss_mb(), time.perf_counter()
        folder = work / (precision if name == "decoder" else "fp32")
        sess[name] = ort.InferenceSession(str(folder / f"{name}.onnx"), so,
                                          providers=["CPUExecutionProvider"])
        rec = {"load_s": round(time.perf_counter() - t, 2), "rss_after_load_mb": round(_rss_mb() - rss0)}
        worst, kls = [], []
        for i in range(len({k.split("/")[1] for k in refs if k.startswith(name + "/")})):
            feeds = {k.split("/")[-1]: v for k, v in refs.items() if k.startswith(f"{name}/{i}/in/")}
            ref = [refs[f"{name}/{i}/out/{j}"] for j in range(len(sess[name].get_outputs()))]
            got = sess[name].run(None, feeds)
            worst += compare_outputs(ref, got)
            if name == "decoder":  # next-token distribution on these fresh inputs (output 0: last-row logits)
                kls.append(kl_next_token(ref[0][0, -1], got[0][0, -1]))
        rec["parity_vs_torch"] = {"rel": max(w["rel"] for w in worst), "cosine": min(w["cosine"] for w in worst)}
        if kls:
            rec["parity_vs_torch"]["next_token_kl_max"] = float(max(kls))
        res["graphs"][name] = rec
    px, ids = refs["prompt/pixel_values"], [int(x) for x in refs["prompt/ids"]]
    vis = sess["vision"].run(None, {"pixel_values": px})
    res["graphs"]["vision"]["vs_transformers"] = compare_outputs([refs["hf/vision/0"], refs["hf/vision/1"]], vis)
    p50, ts = _p50(lambda: sess["vision"].run(None, {"pixel_values": px}), runs)
    res["vision_448_p50_s"], res["vision_runs_s"] = round(p50, 3), ts
    dec = _TimedRunner(sess["decoder"])
    core = MRopeDecoder(OrtRunner(sess["vision"]), OrtRunner(sess["embed"]), dec, cfg)
    answers = []
    for _ in range(runs):  # one pass per run: vision, then prefill and decode timed at the decoder calls
        dec.calls.clear()
        t0, c0 = time.perf_counter(), time.process_time()
        image = core.image_features(px)
        t1, c1 = time.perf_counter(), time.process_time()
        got = core.generate_ids(ids, image, n_new, [])
        t3, c3 = time.perf_counter(), time.process_time()
        (_, t2, c2, _), steps = dec.calls[0], dec.calls[1:]
        answers.append({"vision_s": round(t1 - t0, 3), "prefill_s": round(t2 - t1, 3),
                        "decode_tok_s": round((len(got) - 1) / (t3 - t2), 3),
                        "decode_step_s": [round(b - a, 3) for a, b, _, _ in steps],
                        "answer_s": round(t3 - t0, 3), "cpu_s": {"vision": round(c1 - c0, 2),
                                                                  "prefill": round(c2 - c1, 2),
                                                                  "decode": round(c3 - c2, 2)}})
    logits = dec.prefill_logits
    hf_tokens = [int(x) for x in refs["hf/tokens"]]
    res.update(prompt_tokens=len(ids), answers=answers, new_tokens=len(got),
               prefill_p50_s=float(np.median([a["prefill_s"] for a in answers])),
               decode_tok_s_p50=float(np.median([a["decode_tok_s"] for a in answers])),
               answer_16_tokens_p50_s=float(np.median([a["answer_s"] for a in answers])),
               tokens=got, hf_tokens=hf_tokens,
               token_agreement_vs_transformers=float(np.mean([a == b for a, b in zip(got, hf_tokens)])),
               logits_rel_err_vs_transformers=float(np.abs(logits[0, -1] - refs["hf/logits0"]).max()
                                                    / np.abs(refs["hf/logits0"]).max()),
               kl_vs_transformers=kl_next_token(refs["hf/logits0"], logits[0, -1]),
               rss_sessions_after_runs_mb=round(_rss_mb()),
               peak_rss_mb_so_far=round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024), load_end=_load())
    res["parity"] = {**{g: r["parity_vs_torch"] for g, r in res["graphs"].items()},
                     **{k: res[k] for k in ("token_agreement_vs_transformers", "kl_vs_transformers",
                                            "logits_rel_err_vs_transformers")}}
    res["decoder_precision"] = precision
    return {precision: res}


def qwen3_profile(big: Path, threads: int, past: int = 921, prefill_len: int = 256, runs: int = 3,
                  precision: str = "fp32") -> dict:
    """Where the decoder's time goes (onnxruntime's own per-node profiler): `runs` decode steps (1 new token
    after `past` cached ones, random cache) and one prefill of `prefill_len` tokens; per op type and the
    top nodes, wall and CPU seconds of each call, and the logits MatMul (lm_head) share."""
    import onnxruntime as ort

    cfg = json.loads((_qwen3_dir(big) / "config.json").read_text())
    L, KV, D, H, K = (cfg[k] for k in ("num_layers", "num_kv_heads", "head_dim", "hidden_size", "deepstack_layers"))
    so = ort.SessionOptions()
    so.intra_op_num_threads, so.inter_op_num_threads = threads, 1
    so.enable_profiling = True
    so.profile_file_prefix = str(Path("/tmp") / f"qwen3_{precision}_prof")
    t = time.perf_counter()
    sess = ort.InferenceSession(str(_qwen3_dir(big) / precision / "decoder.onnx"), so,
                                providers=["CPUExecutionProvider"])
    load_s = time.perf_counter() - t
    rng = np.random.default_rng(0)

    def feeds(s: int, p: int) -> dict:
        f = {"inputs_embeds": rng.standard_normal((1, s, H)).astype(np.float32) * 0.02,
             "attention_mask": np.ones((1, p + s), np.int64),
             "position_ids": np.broadcast_to(np.arange(p, p + s), (3, 1, s)).astype(np.int64),
             "deepstack": np.zeros((K, 1, s, H), np.float32)}
        for i in range(L):
            f[f"past_key_{i}"] = rng.standard_normal((1, KV, p, D)).astype(np.float32)
            f[f"past_value_{i}"] = rng.standard_normal((1, KV, p, D)).astype(np.float32)
        return f

    dec = feeds(1, past)
    sess.run(None, dec)  # warm-up (not profiled apart: dropped below by call index)
    calls = {"decode": _cpu_timed(lambda: sess.run(None, dec), runs)}
    pre = feeds(prefill_len, 0)
    calls["prefill"] = _cpu_timed(lambda: sess.run(None, pre), 1)
    prof = Path(sess.end_profiling())
    ev = [e for e in json.loads(prof.read_text()) if e.get("cat") == "Node" and e["name"].endswith("_kernel_time")]
    runs_ev = [e for e in json.loads(prof.read_text()) if e.get("cat") == "Session" and e["name"] == "model_run"]
    prof.unlink()
    # split the node events by model_run windows: [warm-up, decode x runs, prefill]
    bounds = [(r["ts"], r["ts"] + r["dur"]) for r in runs_ev]

    def summary(lo: int, hi: int, n: int) -> dict:
        sel = [e for e in ev if any(a <= e["ts"] <= b for a, b in bounds[lo:hi])]
        by_op: dict[str, float] = {}
        for e in sel:
            by_op[e["args"]["op_name"]] = by_op.get(e["args"]["op_name"], 0.0) + e["dur"] / 1e6 / n
        nodes = sorted(sel, key=lambda e: -e["dur"])[:8]
        tot = sum(by_op.values())
        def out_shape(e: dict) -> list:  # the profiler's [{"float": [dims]}] of the node's first output
            return next(iter((e["args"].get("output_type_shape") or [{}])[0].values()), [])

        lm = [e for e in sel if cfg["vocab_size"] in out_shape(e)]  # the lm_head (int8: its integer MatMul)
        return {"node_s_per_call": round(tot, 3),
                "by_op_s": {k: round(v, 4) for k, v in sorted(by_op.items(), key=lambda kv: -kv[1])[:10]},
                "top_nodes": [{"name": e["name"][:-12], "op": e["args"]["op_name"], "s": round(e["dur"] / 1e6, 4)}
                              for e in nodes],
                "lm_head_s_per_call": round(sum(e["dur"] for e in lm) / 1e6 / n, 4)}

    rows = sess.get_outputs()[0].shape[1]  # 1: last position's logits; symbolic: every position's
    return {"precision": precision, "threads": threads, "load": _load(), "session_load_s": round(load_s, 1),
            "logits": "last" if rows == 1 else "all",
            "past": past, "prefill_len": prefill_len, "calls": calls,
            "decode_profile": summary(1, 1 + runs, runs), "prefill_profile": summary(1 + runs, 2 + runs, 1),
            "rss_mb": round(_rss_mb()), "load_end": _load()}


# ------------------------------------------------------------------------------------------------ side

def step_side(name: str, big: Path, runs: int, threads: int, image_size: int = 448,
              vision_quants: tuple[str, ...] = ("dynamic", "nbits8", "nbits4")) -> dict:
    """Qwen2.5-VL's vision graph (fp32 and each of `vision_quants`, export/hf_qwen_vl.py:VISION_QUANTS) and
    embedding table (fp32, int8) -- the int8/int4 packages' side -- from the checkpoint alone, no GenAI builder,
    no decoder: sizes, parity vs fp32 on fresh inputs, and each graph's session RSS and latency measured in its
    own fresh process (`_probe`). Graphs kept under BIG/side/NAME for a later package."""
    import gc
    import shutil

    from mosaicthinker.export import common as C
    from mosaicthinker.export.hf_qwen_vl import (VISION_QUANTS, export_graphs, export_int8_graphs, load_vision_side,
                                                 quantize_vision)

    if name != "qwen2.5-vl-3b":
        raise SystemExit("side: only qwen2.5-vl-3b (its GenAI package's vision + embedding)")
    work = big / "side" / name
    shutil.rmtree(work, ignore_errors=True)
    t = time.time()
    model = load_vision_side(big / "ckpt" / name)
    g32 = export_graphs(model, work / "fp32", image_size)
    t32 = time.time() - t
    g8 = export_int8_graphs(model, g32, work / "int8", vision_quant="fp32")  # the int8 table only
    t8 = time.time() - t - t32
    del model
    gc.collect()
    res = {"image_size": image_size, "threads": threads, "load": _load(),
           "export_s": {"fp32": round(t32, 1), "embedding_int8": round(t8, 1)},
           "fp32": {"vision": {"parity_vs_transformers": g32["parity"]["vision"]["worst"]}},
           "embedding_int8_quant": g8["embedding_quant"]}
    graphs = {("fp32", "vision"): g32["vision"], ("fp32", "embedding"): g32["embedding"],
              ("int8", "embedding"): g8["embedding"]}
    ref = C.ort_session(g32["vision"], threads)
    for q in vision_quants:
        t = time.time()
        path = quantize_vision(Path(g32["vision"]), work / f"vision-{q}" / "model.onnx", q)
        par = C.parity_check(path, lambda f: C.ort_run(ref, f), g32["vision_inputs"], precision="int8-dynamic",
                             trials=2, require=False, label=f"qwen vision {q} vs fp32")
        res.setdefault(q, {})["vision"] = {"quant": VISION_QUANTS[q].format(block=128),
                                           "quantize_s": round(time.time() - t, 1), "parity_vs_fp32": par["worst"],
                                           "parity_ok": par["ok"]}
        graphs[(q, "vision")] = path
    del ref
    gc.collect()
    for (prec, c), path in graphs.items():
        d = Path(path).parent
        r = subprocess.run([PY, __file__, "_probe", c, str(path), "--runs", str(runs), "--threads", str(threads)],
                           capture_output=True, text=True)
        if r.returncode != 0:
            raise SystemExit(f"probe {prec} {c} failed:\n{r.stderr[-2000:]}")
        res.setdefault(prec, {}).setdefault(c, {}).update(
            size_mib=round(sum(f.stat().st_size for f in d.iterdir()) / 2**20, 1),
            **json.loads(r.stdout.strip().splitlines()[-1]), load=_load())
    res["int8"]["embedding"]["parity_vs_fp32"] = g8["parity"]["embedding"]["worst"]
    return res


def _load() -> str:
    """/proc/loadavg's 1/5/15-minute figures: every timing here is an upper bound under shared load."""
    return " ".join(Path("/proc/loadavg").read_text().split()[:3])


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


def grounding_cost(e2e: dict) -> dict:
    """[paper_costs.grounding]: the VLM's grounding call as `mosaic ask` ran it with the Qwen2.5-VL-3B bundle
    (grounding.ground: frames + question, a short reply) - with a VLM in the bundle the pipeline grounds through
    it, not the template parser. "estimated" by the schema's rule: the run recorded no bundle hash."""
    s = e2e["stages"]["grounding"]
    return {"ms_per_call": round(s["seconds"] * 1000, 1), "status": "estimated",
            "source": f"measured end to end, not by mosaic profile: {E2E.relative_to(REPO)} stages.grounding "
                      f"({s['seconds']} s, {s['calls']} call, {e2e['date']}, load {e2e['load_avg_1min_end']} at "
                      f"the end; {e2e['bundle']}); RANDOM weights; no bundle hash was recorded"}


def write_grounding_cost(profile: Path) -> dict:
    """cpu-generic's [paper_costs.grounding] from the end-to-end run (E2E), then every other profile rescaled."""
    import tomllib

    import tomli_w

    prof = tomllib.loads(profile.read_text())
    prof.setdefault("paper_costs", {})["grounding"] = grounding_cost(json.loads(E2E.read_text()))
    profile.write_text(tomli_w.dumps(prof))
    write_scaled_profiles(profile)
    return prof["paper_costs"]["grounding"]


def _variant_fields(item: str, lat: dict, fields: dict) -> dict:
    """One measured variant's numeric fields: p50 ms per field, summed component loads and RSS growth."""
    comps = [c for c, _ in fields.values()]
    e = {f: round(lat[c]["p50_s"] * 1000, 1) for f, (c, _) in fields.items()}
    e.setdefault("ms_per_call", 0.0)
    if item == "segmenter":
        e.setdefault("ms_per_prompt", 0.0)
    if item == "matcher":
        e.setdefault("ms_per_pair", 0.0)
    e["load_ms"] = round(sum(lat[c]["load_s"] for c in comps) * 1000, 1)
    e["resident_mb"] = round(max(0.0, sum(lat[c]["resident_mb"] for c in comps)), 1)
    return e


def measured_variants(data: dict, item: str) -> dict:
    """[paper_costs.<item>.variants.*]: the item's other measured precisions (e.g. int8-dynamic), for the profile's
    [roles] precision to pick. resident_mb stays the main variant's: `measure` reads each variant's RSS growth
    after the previous variant's session in the same process, so freed memory is reused (CLIP int8: 0.4 MB)."""
    model, v, fields = PAPER_COSTS[item]
    lat = ((data["models"].get(model) or {}).get("measure") or {}).get("latency", {})
    if v not in lat:
        return {}
    out = {}
    for other, lv in lat.items():
        if other == v or any("error" in lv.get(c, {"error": 1}) for c, _ in fields.values()):
            continue
        e = _variant_fields(item, lv, fields)
        e["resident_mb"] = _variant_fields(item, lat[v], fields)["resident_mb"]
        out[other] = {**e, "note": f"paper model {model} {other}, RANDOM weights, 2 threads, p50 of 5; "
                                   f"resident_mb = the {v} figure (this variant's RSS was read after the {v} "
                                   f"session in the same process: not a measurement)"}
    return out


def write_variants(profile: Path) -> dict:
    """cpu-generic's [paper_costs.<item>] gain `variant` and their other measured precisions (the figures and
    provenance of the main entries are kept); the other profiles are rescaled (scaled entries carry none)."""
    import tomllib

    import tomli_w

    prof = tomllib.loads(profile.read_text())
    data = json.loads(OUT.read_text())
    done = {}
    for item, (_, v, _) in PAPER_COSTS.items():
        e = prof.get("paper_costs", {}).get(item)
        if e is not None:
            e["variant"] = v
            e.pop("variants", None)
            if others := measured_variants(data, item):  # no empty [..variants] table
                e["variants"] = others
            done[item] = sorted(others)
    profile.write_text(tomli_w.dumps(prof))
    write_scaled_profiles(profile)
    return done


def paper_costs(data: dict, big: Path) -> dict:
    """[paper_costs.*] entries from the measured results (perception fp32 + its other measured precisions as
    variants; VLM: Qwen2.5-VL-3B int4)."""
    from mosaicthinker.runtime.infra.bundle import bundle_hash, load_bundle

    date = time.strftime("%Y-%m-%d")
    out = {}
    for item, (model, v, fields) in PAPER_COSTS.items():
        lat = ((data["models"].get(model) or {}).get("measure") or {}).get("latency", {}).get(v)
        if not lat:
            continue
        out[item] = {**_variant_fields(item, lat, fields), "status": "measured", "date": date,
                     "bundle_hash": bundle_hash(load_bundle(big / "bundles" / model, verify=False)),
                     "provider": "CPUExecutionProvider",
                     "note": f"paper model {model} {v} at its real config with RANDOM weights "
                             f"(benchmarks/paper_models.py; 2 threads, p50 of 5; shared CPUs)",
                     "variant": v, **({"variants": m} if (m := measured_variants(data, item)) else {})}
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
    if E2E.is_file():
        out["grounding"] = grounding_cost(json.loads(E2E.read_text()))
    return out


PERCEPTION = ("depth", "segmenter", "detector", "embedder", "matcher")


def _cpu_factor(base: dict, device: dict) -> float:
    """The profile's host-CPU factor: its geometry cost over cpu-generic's (profiles/estimate.py scales every
    CPU-side item by one per-device factor; geometry is one of them and is measured on cpu-generic)."""
    return device["geometry"]["ms_per_call"] / base["geometry"]["ms_per_call"]


def _scale_rule(item: str, base: dict, device: dict, nums: dict, acc: float,
                base_name: str) -> tuple[dict[str, float], str] | None:
    """(factor per field, the rule in words) for one [paper_costs] item; None when the device lacks the item.
    resident_mb is never scaled (same files and precision: no basis)."""
    if item in ("vlm", "grounding") and ("vlm" not in device or "vlm" not in base):
        return None
    if item == "grounding":  # a VLM call over frames: vision + prefill, as the VLM's per-image cost scales
        f = device["vlm"]["ms_per_image"] / base["vlm"]["ms_per_image"]
        return {"ms_per_call": f}, (f"ms_per_call x {f:.4g} (the VLM's grounding call: this profile's "
                                    f"[costs.vlm].ms_per_image / {base_name}'s)")
    if item == "vlm":
        fac = {f: device["vlm"][f] / base["vlm"][f] for f in ("ms_per_image", "ms_per_token", "load_ms")}
        return fac, (f"ms_per_image x {fac['ms_per_image']:.4g}, ms_per_token x {fac['ms_per_token']:.4g}, "
                     f"load_ms x {fac['load_ms']:.4g} (this profile's [costs.vlm] / {base_name}'s, the shared "
                     f"VLM's device factor per field)")
    cpu = _cpu_factor(base, device)
    fac = {f: (cpu if f == "load_ms" else acc) for f in nums if f.startswith("ms_") or f == "load_ms"}
    return fac, (f"ms fields x {acc:.4g} (this profile's accelerator factor: the smallest ms ratio of its shared "
                 f"perception [costs.*] to {base_name}'s); load_ms x {cpu:.4g} (this profile's host-CPU factor, "
                 f"its [costs.geometry] / {base_name}'s: creating a session is host work - reading, optimising "
                 f"and pre-packing the graph - with engines cached, as profiles/estimate.py assumes)")


def scale_paper_costs(base: dict, device: dict, paper: dict, base_name: str = "cpu-generic") -> dict:
    """[paper_costs.*] for another profile, scaled from the cpu-generic measurements with the device factors the
    profile's own shared-model [costs.*] already encode (profiles/estimate.py):

    - perception items: one accelerator factor per device = the smallest ms ratio device / cpu-generic over the
      shared perception items (the others sit on estimate.py's per-call floor, so their ratio over-states the
      time), applied to every ms field; load_ms x the device's host-CPU factor (`_cpu_factor`);
    - vlm: the ratio of the device's vlm estimate to cpu-generic's, per field (ms_per_image, ms_per_token,
      load_ms);
    - resident_mb: the cpu-generic figure (no basis to scale: same files, same precision).
    Every entry is status "estimated" with the rule and the factor in its `source`."""
    ratios = [device[k][f] / base[k][f] for k in PERCEPTION if k in device and k in base
              for f in ("ms_per_call", "ms_per_pair") if base[k].get(f) and f in device[k]]
    acc = min(ratios) if ratios else 1.0
    out = {}
    for item, e in paper.items():
        nums = {f: v for f, v in e.items() if isinstance(v, (int, float)) and not isinstance(v, bool)}
        got = _scale_rule(item, base, device, nums, acc, base_name)
        if got is None:
            continue
        fac, rule = got
        scaled = {f: round(v * fac[f], 2) if f in fac else v for f, v in nums.items()}
        out[item] = {**scaled, "status": "estimated",
                     "source": f"SCALED from {base_name}'s {e.get('status', 'measured')} [paper_costs.{item}] "
                               f"({'; '.join(x for x in (e.get('note') or e.get('source'), e.get('date')) if x)}): "
                               f"{rule}"
                               + (f"; resident_mb as measured on {base_name}" if "resident_mb" in nums else "")
                               + ". An estimate, not a measurement on this device"}
    return out


def write_profile(big: Path, profile: Path) -> dict:
    """[paper_costs.*] of cpu-generic from the measured results, then every other profile's scaled from them."""
    import tomllib

    import tomli_w

    data = json.loads(OUT.read_text())
    prof = tomllib.loads(profile.read_text())
    prof["paper_costs"] = paper_costs(data, big)
    profile.write_text(tomli_w.dumps(prof))
    write_scaled_profiles(profile)
    return prof["paper_costs"]


def write_scaled_profiles(base_profile: Path) -> dict:
    """Every other profiles/*.toml gets [paper_costs.*] scaled from base_profile's (scale_paper_costs)."""
    import tomllib

    import tomli_w

    base = tomllib.loads(base_profile.read_text())
    done = {}
    for p in sorted(base_profile.parent.glob("*.toml")):
        if p == base_profile:
            continue
        d = tomllib.loads(p.read_text())
        d["paper_costs"] = scale_paper_costs(base["costs"], d["costs"], base["paper_costs"],
                                             base_profile.stem)
        p.write_text(tomli_w.dumps(d))
        done[p.stem] = sorted(d["paper_costs"])
    return done


def cost_table(data: dict) -> str:
    """Markdown: per model and precision, export time / peak RSS, size, parity, CPU latency (2 threads)."""
    rows = ["| model (random weights) | params | export s / peak RSS GB | precision | size MiB | parity | CPU 2 threads |",
            "|---|---|---|---|---|---|---|"]
    for name, r in data["models"].items():
        e, ck = r.get("export") or r.get("export_text300") or {}, r.get("checkpoint") or {}
        meas = dict(r.get("measure_text300") or r.get("measure") or {})
        sizes = dict(e.get("size_mib") or {})
        if "qwen3-int8" in r and "measure_int8" in r:  # int8 decoder, fp32 vision + embed (qwen3_int8)
            q = r["qwen3-int8"]
            sizes["int8 decoder"] = round(sizes["fp32"] - q["fp32_size_mib"] + q["size_mib"], 1)
            meas["int8 decoder"] = r["measure_int8"]["int8"]
        for v, size in sizes.items():
            par = e.get("parity", {}).get(v) or (meas.get(v) or {}).get("parity", {})
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
            rows.append(f"| {name} | {ck.get('parameters') or '-'} | {e.get('export_s') or e.get('export_wall_s') or '-'} / "
                        f"{(e.get('export_peak_rss_mb') or 0) / 1024:.1f} | {v} | {size} | {ptxt or '-'} | {ltxt} |")
    return "\n".join(rows)


# ------------------------------------------------------------------------------------------------ driver

def run_child(step: str, name: str, args) -> dict:
    """One step in a child process under /usr/bin/time -v: its result JSON plus wall time and peak RSS."""
    cmd = ["/usr/bin/time", "-v", PY, __file__, "_child", step, "--model", name, "--big", str(args.big),
           "--runs", str(args.runs), "--threads", str(args.threads)]
    if args.text_chars:
        cmd += ["--text-chars", str(args.text_chars)]
    if step == "side":
        cmd += ["--vision-quants", args.vision_quants]
    if args.precision != "fp32":
        cmd += ["--precision", args.precision]
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
    ap.add_argument("step", choices=["checkpoint", "export", "measure", "side", "vision-ab", "all", "profile",
                                     "scale-profiles", "grounding", "variants", "table",
                                     "qwen3-profile", "qwen3-int8", "_child", "_probe"])
    ap.add_argument("child_step", nargs="?")
    ap.add_argument("probe_path", nargs="?")
    ap.add_argument("--model", choices=sorted(MODELS))
    ap.add_argument("--big", type=Path, default=Path(os.environ.get("MOSAIC_BIG", "/work/big/issue16")))
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--vision-quants", default="dynamic,nbits4",
                    help="side: vision quantisers to measure against fp32 (export/hf_qwen_vl.py:VISION_QUANTS)")
    ap.add_argument("--text-chars", type=int, help="VLM: cut the object text block to N characters (the real "
                                                   "tokenizer's prompt length with the synthetic byte tokenizer)")
    ap.add_argument("--prefill-len", type=int, default=256, help="qwen3-profile: prefill tokens")
    ap.add_argument("--precision", default="fp32", help="qwen3-profile / measure (qwen3-vl-2b): the decoder's folder under "
                                                    "BIG/qwen3/qwen3-vl-2b (fp32, int8)")
    args = ap.parse_args(argv)
    if args.step == "profile":  # [paper_costs.*] of profiles/cpu-generic.toml from the measured results
        print(json.dumps(write_profile(args.big, REPO / "profiles" / "cpu-generic.toml"), indent=1))
        return 0
    if args.step == "variants":  # cpu-generic's [paper_costs.*.variants] from the measured precisions
        print(json.dumps(write_variants(REPO / "profiles" / "cpu-generic.toml"), indent=1))
        return 0
    if args.step == "grounding":  # cpu-generic's [paper_costs.grounding] from the end-to-end run, then rescaled
        print(json.dumps(write_grounding_cost(REPO / "profiles" / "cpu-generic.toml"), indent=1))
        return 0
    if args.step == "scale-profiles":  # the other profiles' [paper_costs.*] scaled from cpu-generic's
        print(json.dumps(write_scaled_profiles(REPO / "profiles" / "cpu-generic.toml"), indent=1))
        return 0
    if args.step == "table":
        print(cost_table(json.loads(OUT.read_text())))
        return 0
    if args.step == "qwen3-profile":  # the 2B decoder graph under onnxruntime's profiler (no torch)
        res = qwen3_profile(args.big, args.threads, past=921, prefill_len=args.prefill_len, runs=args.runs,
                            precision=args.precision)
        save("qwen3-vl-2b", f"profile_{args.precision}_prefill{args.prefill_len}_{res['logits']}_logits", res)
        print(json.dumps(res, indent=1))
        return 0
    if args.step == "_probe":  # one graph's session in this fresh process (step_side)
        print(json.dumps(probe(args.child_step, args.probe_path, args.runs, args.threads)))
        return 0
    if not args.model:
        ap.error("--model is required")
    if args.step == "_child":
        fn = {"checkpoint": step_checkpoint, "export": step_export, "measure": step_measure,
              "qwen3-int8": lambda name, big: qwen3_int8(big),
              "side": step_side, "vision-ab": lambda name, big, **kw: vision_ab(big, **kw)}[args.child_step]
        kw = ({"runs": args.runs, "threads": args.threads, "text_chars": args.text_chars,
               **({"precision": args.precision} if args.precision != "fp32" else {})}
              if args.child_step == "measure" else {"text_chars": args.text_chars}
              if args.child_step == "export" else
              {"runs": args.runs, "threads": args.threads,
               "vision_quants": tuple(args.vision_quants.split(","))} if args.child_step == "side" else
              {"runs": args.runs, "threads": args.threads} if args.child_step == "vision-ab" else {})
        print(json.dumps(fn(args.model, args.big, **kw)))
        return 0
    for step in (["checkpoint", "export", "measure"] if args.step == "all" else [args.step]):
        res = run_child(step, args.model, args)
        save(args.model, step + (f"_text{args.text_chars}" if args.text_chars else "")
             + (f"_{args.precision}" if args.precision != "fp32" and step == "measure" else ""), res)
        print(json.dumps({args.model: {step: res}}, indent=1)[:3000])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
