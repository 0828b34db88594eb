"""Regenerate the *estimated* device profiles (profiles/*.toml) from cpu-generic.toml.

cpu-generic is the reference: its costs marked `measured` come from `mosaic profile --update-profile` on a 2-core
x86 machine; every other device's costs are scaled from them by published relative throughput and marked
`estimated` with that reasoning in their `source` field. Run: `python profiles/estimate.py`. Re-measure on the
device itself with `mosaic profile --update-profile` to replace an estimate."""
import sys, tomllib, tomli_w, copy
from pathlib import Path
OUT = Path(__file__).resolve().parent
BASE_SRC = "quick timing of the shared ONNX models on this 2-core x86 machine (onnxruntime 1.31, 2 threads, shared with other jobs), 2026-11-22; replace with `mosaic profile --update-profile`"
# reference costs on cpu-generic (used when cpu-generic.toml has no measured value)
REF = {
  "process": {"resident_mb": 260.0, "source": "RSS of python + numpy + OpenCV + onnxruntime after import (~110 MB here) + a 32-frame 640x480 decode cache (30 MB) + the trace and map (~20 MB) + allocator slack; rounded up"},
  "video_decode": {"ms_per_call": 2.5, "source": "OpenCV software decode of 640x480 H.264, one core (typical 300-500 fps); estimate"},
  "dedup": {"ms_per_call": 4.0, "source": "the whole redundant-frame-removal pass per video frame: sequential decode (~2.5 ms for 640x480 on one core) + uniform down-sampling, ORB tracking and SSIM on candidates (~1.5 ms amortised); estimate"},
  "grounding": {"ms_per_call": 5.0, "source": "template parser (no VLM grounding); estimate"},
  "detector": {"ms_per_call": 36.0, "load_ms": 100.0, "resident_mb": 36.2, "source": "YOLOX-Nano 416x416: 35.6 ms of CPU per run on one thread (median of 6, load 7, 2026-12-03; wall times at that load are not usable); resident_mb measured by mosaic profile"},
  "instance_segmenter": {"ms_per_call": 195.0, "load_ms": 250.0, "resident_mb": 122.8, "source": "YOLO11n-seg at 480x640: 184 ms of CPU per graph run on one thread (median of 12 kitchen frames, load 7, 2026-12-03) + ~10 ms mask decoding and merge; resident_mb measured by mosaic profile"},
  "segmenter": {"ms_per_call": 48.0, "ms_per_prompt": 0.5, "load_ms": 110.0, "resident_mb": 30.0, "source": BASE_SRC + "; semantic segmenter: prompts only select class pixels"},
  "depth": {"ms_per_call": 120.0, "load_ms": 70.0, "resident_mb": 140.0, "source": BASE_SRC + " (40 ms idle per models/README, 378 ms under load)"},
  "embedder": {"ms_per_call": 30.0, "load_ms": 120.0, "resident_mb": 20.0, "source": BASE_SRC},
  "matcher": {"ms_per_call": 60.0, "ms_per_pair": 15.0, "load_ms": 100.0, "resident_mb": 40.0, "source": "XFeat (Potje et al., CVPR 2024) reports ~27 fps at VGA on an Intel i5-1135G7 CPU; halved for 2 shared cores, plus mutual-NN matching of 4096 x 64-d descriptors"},
  "geometry": {"ms_per_call": 6.0, "source": "RANSAC (Umeyama, 200 iterations) on one tree edge + share of the spanning tree and fusion per key frame; estimate"},
  "keyframe_state": {"mb_per_call": 4.5, "source": "arithmetic at 640x480: RGB 0.9 MB + depth float32 1.2 MB + 4 masks 1.2 MB + 4096 XFeat features x (64 x 4 + 12) B = 1.1 MB"},
  "vlm": {"ms_per_image": 4000.0, "ms_per_token": 45.0, "load_ms": 1500.0, "resident_mb": 450.0, "source": "SmolVLM-256M int8-dynamic (not measurable here: no real VLM weights): decoder 135M params -> ~0.27 GFLOP and ~135 MB of int8 weights read per token (memory bound, ~45 ms on 2 cores); image = SigLIP-93M vision pass at 512 px (~45 GFLOP) + prefill of its 64 tokens and the ~400-token text block (~125 GFLOP) at ~45 GFLOP/s"},
}
ACCEL_MODELS = ("detector", "instance_segmenter", "segmenter", "depth", "embedder", "matcher")
CPU_SIDE = ("video_decode", "dedup", "grounding", "geometry", "refine")

def base():
    p = OUT / "cpu-generic.toml"
    ref = copy.deepcopy(REF)
    if p.exists():
        d = tomllib.load(open(p, "rb"))
        for k, e in d.get("costs", {}).items():
            if e.get("status") == "measured":
                ref[k] = {**{f: v for f, v in e.items() if f not in ("status", "date", "bundle_hash", "provider", "note")},
                          "measured": f"measured on cpu-generic {e['date']} bundle {e['bundle_hash']}"}
    return ref

def cpu_generic(ref):
    costs = {}
    for k, v in ref.items():
        e = {f: x for f, x in v.items() if f not in ("source", "measured")}
        if "measured" in v:
            p = tomllib.load(open(OUT / "cpu-generic.toml", "rb"))["costs"][k]
            costs[k] = p
        else:
            costs[k] = {**e, "status": "estimated", "source": v["source"]}
    return {
      "schema": "mosaicthinker.profile/1",
      "device": {"name": "cpu-generic", "description": "generic 2-core x86-64 CPU, no accelerator (like the CI/build machine)",
                 "os": "linux", "ram_mb": 4096, "accelerator": "none",
                 "notes": "reference profile: the other profiles scale their estimated costs from this one's costs"},
      "budget": {"latency_budget_ms": 60000, "memory_budget_mb": 1536},
      "runtime": {"providers": ["CPUExecutionProvider"], "intra_op_threads": 2, "inter_op_threads": 1,
                  "notes": "2 intra-op threads = the 2 cores; no affinity pinning (a shared VM)"},
      "roles": {r: {"precision": "fp32"} for r in ("depth", "segmenter", "instance_segmenter", "matcher", "detector",
                                                   "embedder")} | {
                "vlm": {"precision": "int8", "int8_kind": "dynamic", "notes": "dynamic int8 keeps the decoder memory-bound cost low on CPU"}},
      "costs": costs,
    }

def scaled(ref0, name, desc, *, soc, os_, ram, accel, lat, mem, chain, threads, aff, roles, acc_speed, acc_label,
           cpu_factor, cpu_label, load_ms, vlm, rt_notes, mem_note, floor_ms=1.5, dev_notes=""):
    costs = {}
    # devices read an mp4 (hardware or software decode), never an RGB-D folder: decode and dedup come from the
    # video estimates, not from a cpu-generic measurement on a JPEG+PNG folder
    ref = {**ref0, "video_decode": REF["video_decode"], "dedup": REF["dedup"]}
    for k, v in ref.items():
        src0 = (v["measured"] + " (other jobs shared the 2 cores, so if anything pessimistic)") if "measured" in v else ("cpu-generic estimate: " + v["source"])
        e = {f: x for f, x in v.items() if f not in ("source", "measured")}
        if k in ACCEL_MODELS:
            out = {}
            for f, x in e.items():
                if f in ("ms_per_call", "ms_per_prompt", "ms_per_pair"):
                    out[f] = round(max(floor_ms if f == "ms_per_call" else 0.2, x / acc_speed), 2)
                elif f == "load_ms":
                    out[f] = load_ms
                else:
                    out[f] = x
            costs[k] = {**out, "status": "estimated",
                        "source": f"cpu-generic {', '.join(f'{f}={e[f]:g}' for f in e if f.startswith('ms'))} / {acc_speed:g} ({acc_label}), floor {floor_ms:g} ms per call for host-device copies and dispatch; load_ms {load_ms} assumes a cached engine/context binary; resident_mb as on CPU. Base: {src0}"}
        elif k in CPU_SIDE:
            costs[k] = {f: round(x * cpu_factor, 2) for f, x in e.items()} | {"status": "estimated",
                        "source": f"cpu-generic {', '.join(f'{f}={e[f]:g}' for f in e)} x {cpu_factor:g} ({cpu_label}). Base: {src0}"}
        elif k == "vlm":
            costs[k] = {**vlm[0], "status": "estimated", "source": vlm[1]}
        else:
            costs[k] = {**e, "status": "estimated", "source": ("same as cpu-generic (" + src0 + ")") + ("; " + mem_note if k == "process" else "")}
    return {
      "schema": "mosaicthinker.profile/1",
      "device": {"name": name, "description": desc, "soc": soc, "os": os_, "ram_mb": ram, "accelerator": accel, "notes": dev_notes},
      "budget": {"latency_budget_ms": lat, "memory_budget_mb": mem},
      "runtime": {"providers": chain, "intra_op_threads": threads, "inter_op_threads": 1, "core_affinity": aff, "notes": rt_notes},
      "roles": roles, "costs": costs,
    }

def main():
    ref = base()
    profs = {"cpu-generic": cpu_generic(ref)}
    TRT = ["TensorrtExecutionProvider", "CUDAExecutionProvider", "CPUExecutionProvider"]
    jroles = {r: {"precision": "fp16"} for r in ("depth", "segmenter", "instance_segmenter", "matcher", "embedder")} | {
        "detector": {"precision": "int8", "int8_kind": "qdq", "notes": "static QDQ (calibrated) for TensorRT; implicit TensorRT calibration is deprecated"},
        "vlm": {"precision": "fp16", "providers": ["CUDAExecutionProvider", "CPUExecutionProvider"], "notes": "growing KV cache: CUDA EP (TensorRT needs fixed profiles)"}}
    jnote = "Jetson unified memory: GPU allocations share the 'RAM'; the budget covers CPU RSS plus model memory"
    jrt = "TensorRT engines are built on the device on first run (minutes) and cached; CUDA then CPU behind it"
    jtops = "NVIDIA Jetson Orin module data sheets: AGX Orin 64GB 275 TOPS (sparse INT8), Orin NX 16GB 100 TOPS (157 in JetPack 6.2 Super mode), Orin Nano 8GB 40 TOPS (67 Super)"
    profs["jetson-agx-orin-64gb"] = scaled(ref, "jetson-agx-orin-64gb", "NVIDIA Jetson AGX Orin 64 GB (MAXN)",
        soc="Orin: 12x Cortex-A78AE 2.2 GHz, 2048-core Ampere GPU, 64 tensor cores, 2x NVDLA v2", os_="linux (JetPack 6)", ram=65536,
        accel="gpu", lat=15000, mem=16384, chain=TRT, threads=4, aff=[0, 1, 2, 3], roles=jroles,
        acc_speed=40, acc_label=f"assumed TensorRT fp16 speed-up over the 2-core CPU; 2.5x the Orin Nano's 15x, below the 6.9x TOPS ratio because small mobile CNNs are launch-bound ({jtops})",
        cpu_factor=1.3, cpu_label="Cortex-A78AE at 2.2 GHz assumed ~1.3x slower per thread than the x86 cores here",
        load_ms=300, vlm=({"ms_per_image": 150.0, "ms_per_token": 6.0, "load_ms": 3000.0, "resident_mb": 700.0},
            "SmolVLM-256M fp16 on the CUDA EP: decode is memory bound, ~512 MB fp16 weights / ~100 GB/s effective of the 204.8 GB/s LPDDR5 = ~5 ms + launch overhead per token; image ~90 GFLOP at ~1 TFLOP/s effective fp16 = ~100 ms + copies; estimate"),
        rt_notes=jrt, mem_note=jnote, dev_notes="estimates only: no Jetson was available to measure")
    profs["jetson-orin-nx-16gb"] = scaled(ref, "jetson-orin-nx-16gb", "NVIDIA Jetson Orin NX 16 GB (MAXN)",
        soc="Orin NX: 8x Cortex-A78AE 2.0 GHz, 1024-core Ampere GPU, 32 tensor cores, 2x NVDLA v2", os_="linux (JetPack 6)", ram=16384,
        accel="gpu", lat=15000, mem=8192, chain=TRT, threads=4, aff=[0, 1, 2, 3], roles=jroles,
        acc_speed=25, acc_label=f"assumed TensorRT fp16 speed-up over the 2-core CPU: Orin Nano's 15x scaled by ~1.7 for twice the GPU clock/bandwidth class ({jtops})",
        cpu_factor=1.4, cpu_label="Cortex-A78AE at 2.0 GHz assumed ~1.4x slower per thread than the x86 cores here",
        load_ms=300, vlm=({"ms_per_image": 300.0, "ms_per_token": 10.0, "load_ms": 3500.0, "resident_mb": 700.0},
            "SmolVLM-256M fp16 on the CUDA EP: ~512 MB fp16 weights per token / ~60 GB/s effective of 102.4 GB/s = ~9 ms + overhead; image ~90 GFLOP at ~0.4 TFLOP/s effective = ~250 ms + copies; estimate"),
        rt_notes=jrt, mem_note=jnote, dev_notes="estimates only: no Jetson was available to measure")
    profs["jetson-orin-nano-8gb"] = scaled(ref, "jetson-orin-nano-8gb", "NVIDIA Jetson Orin Nano 8 GB (developer kit, MAXN)",
        soc="Orin Nano: 6x Cortex-A78AE 1.5 GHz (1.7 Super), 1024-core Ampere GPU, 32 tensor cores, no DLA", os_="linux (JetPack 6)", ram=8192,
        accel="gpu", lat=20000, mem=4096, chain=TRT, threads=4, aff=[0, 1, 2, 3], roles=jroles,
        acc_speed=15, acc_label="assumed TensorRT fp16 speed-up over the 2-core CPU; anchor: YOLOv8n 640x640 (8.7 GFLOP) runs in 3.5 ms GPU time on an Orin Nano 8GB with TensorRT INT8 in MAXN_SUPER (hokwangchoi.com, 2026), i.e. ~2.5 TFLOP/s effective, discounted to fp16 and end-to-end time with copies and Python",
        cpu_factor=1.8, cpu_label="Cortex-A78AE at 1.5 GHz assumed ~1.8x slower per thread than the x86 cores here",
        load_ms=400, vlm=({"ms_per_image": 500.0, "ms_per_token": 16.0, "load_ms": 4000.0, "resident_mb": 700.0},
            "SmolVLM-256M fp16 on the CUDA EP: ~512 MB fp16 weights per token / ~40 GB/s effective of 68 GB/s = ~13 ms + overhead; image ~90 GFLOP at ~0.25 TFLOP/s effective = ~400 ms + copies; estimate"),
        rt_notes=jrt, mem_note=jnote + "; 8 GB shared with the OS and desktop, so 4 GB for this process", dev_notes="estimates only: no Jetson was available to measure")
    proles_q = {r: {"precision": "int8", "int8_kind": "qdq"} for r in ("depth", "segmenter", "detector", "embedder")} | {
        "instance_segmenter": {"precision": "fp32", "notes": "YOLO11n-seg weights are already int8 (float activations)"},
        "matcher": {"precision": "fp16", "providers": ["QNNExecutionProvider", "XnnpackExecutionProvider", "CPUExecutionProvider"], "notes": "descriptor matching precision matters; fp16 on the HTP"},
        "vlm": {"precision": "int8", "int8_kind": "dynamic", "providers": ["XnnpackExecutionProvider", "CPUExecutionProvider"], "notes": "decoder with a growing KV cache: CPU/XNNPACK only (no fixed shapes for the NPU)"}}
    profs["oneplus-12r"] = scaled(ref, "oneplus-12r", "OnePlus 12R: Snapdragon 8 Gen 2 (SM8550), 16 GB LPDDR5X",
        soc="SM8550: 1x Cortex-X3 3.2 GHz + 4x A715/A710 2.8 GHz + 3x A510, Adreno 740, Hexagon NPU (HTP)", os_="android 14", ram=16384,
        accel="npu", lat=20000, mem=4096,
        chain=["QNNExecutionProvider", "NnapiExecutionProvider", "XnnpackExecutionProvider", "CPUExecutionProvider"],
        threads=4, aff=[3, 4, 5, 6, 7], roles=proles_q,
        acc_speed=20, acc_label="assumed QNN HTP int8-QDQ speed-up over the 2-core CPU for fully delegated CNNs; anchor: MobileNetV2 runs in ~0.37 ms on a Snapdragon 8 Gen 3 NPU via Qualcomm AI Hub (edgegate.frozo.ai, 2026) vs ~25 ms for MobileNet-class graphs here; discounted ~4x for the 8 Gen 2, partial delegation and per-call overhead from Python",
        cpu_factor=1.0, cpu_label="Cortex-X3/A715 big cores assumed on par per thread with the x86 cores here",
        load_ms=250, vlm=({"ms_per_image": 3000.0, "ms_per_token": 30.0, "load_ms": 2000.0, "resident_mb": 450.0},
            "SmolVLM-256M int8-dynamic on XNNPACK/CPU with 4 big cores: ~0.75x the cpu-generic estimate (4000 ms / image, 45 ms / token) for twice the threads on LPDDR5X; estimate"),
        rt_notes="QNN (Hexagon HTP) first; NNAPI is deprecated from Android 15 and kept only as a fallback for older builds; XNNPACK then CPU. Affinity: the 5 big cores (3-7); 4 threads",
        mem_note="Android's low-memory killer: keep one app process under ~4 GB on a 16 GB phone", dev_notes="estimates only: no phone was available to measure")
    proles_p = {r: {"precision": "int8", "int8_kind": "qdq"} for r in ("depth", "segmenter", "detector", "embedder")} | {
        "instance_segmenter": {"precision": "fp32", "notes": "YOLO11n-seg weights are already int8 (float activations)"},
        "matcher": {"precision": "fp32", "providers": ["XnnpackExecutionProvider", "CPUExecutionProvider"]},
        "vlm": {"precision": "int8", "int8_kind": "dynamic", "providers": ["XnnpackExecutionProvider", "CPUExecutionProvider"], "notes": "decoder with a growing KV cache: CPU/XNNPACK only"}}
    profs["pixel-8gb"] = scaled(ref, "pixel-8gb", "Pixel-class phone with 8 GB (e.g. Pixel 8: Google Tensor G3)",
        soc="Tensor G3: 1x Cortex-X3 2.9 GHz + 4x A715 2.37 GHz + 4x A510, Mali-G715, Google TPU (reachable through NNAPI only)", os_="android 14", ram=8192,
        accel="npu", lat=30000, mem=2048,
        chain=["NnapiExecutionProvider", "XnnpackExecutionProvider", "CPUExecutionProvider"],
        threads=4, aff=[4, 5, 6, 7, 8], roles=proles_p,
        acc_speed=6, acc_label="assumed NNAPI int8-QDQ speed-up over the 2-core CPU: well below the Snapdragon HTP's 20x because NNAPI drivers split graphs into partitions and fall back per operator",
        cpu_factor=1.2, cpu_label="Cortex-X3 2.9 GHz / A715 2.37 GHz assumed ~1.2x slower per thread than the x86 cores here",
        load_ms=300, vlm=({"ms_per_image": 3500.0, "ms_per_token": 38.0, "load_ms": 2500.0, "resident_mb": 450.0},
            "SmolVLM-256M int8-dynamic on XNNPACK/CPU with 4 big cores: ~0.85x the cpu-generic estimate; estimate"),
        rt_notes="NNAPI is deprecated from Android 15 (still present but unmaintained): keep XNNPACK and CPU behind it; there is no QNN on Tensor SoCs. Affinity: the big and mid cores (4-8); 4 threads",
        mem_note="an 8 GB phone keeps ~2 GB for one foreground app before the low-memory killer acts", dev_notes="estimates only: no phone was available to measure")
    SIZES = {"depth": [640, 448], "detector": [416, 416], "instance_segmenter": [640, 480], "segmenter": [257, 257],
             "embedder": [224, 224],
             "matcher": [640, 480], "vlm": [512, 512]}
    for n, d in profs.items():
        for r, rs in d["roles"].items():
            rs.setdefault("input_size_px", SIZES[r])
        # [paper_costs] is benchmarks/paper_models.py's table (measured / scaled there): carried over, never dropped
        old = OUT / f"{n}.toml"
        if old.exists() and "paper_costs" in (prev := tomllib.load(open(old, "rb"))):
            d["paper_costs"] = prev["paper_costs"]
        with open(OUT / f"{n}.toml", "wb") as f:
            tomli_w.dump(d, f)
        print("wrote", n)
main()
