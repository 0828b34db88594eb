"""Per-device profiling reports: `mosaic profile --bundle B [--profile P] [--video V] --out DIR`.

What is measured, on this machine, with the providers and threads of the profile (default: CPU, onnxruntime's
thread default):

- per role x variant x component (the raw graphs): session load time, latency p50/p90/mean over N warm runs
  on random inputs shaped from the graph's declared inputs, the increase of resident memory after loading
  and the peak during load + runs, and the execution provider onnxruntime really used (with any fallback);
- per role (the runtime adapter, pre/post-processing included, on a real frame when --video is given): the same
  latency figures; these are the planner's `ms_per_call` figures;
- the CPU-side pipeline pieces that exist: video decode per frame, redundant-frame removal per frame, RANSAC per
  pair, key-frame state size;
- with --video, one full question (`--question`, default "How many chairs are in this room?") through
  `pipeline.ask` in a fresh process: wall time, per-stage times and calls from its Trace, peak RSS.

Outputs in --out: `report.json` (schema mosaicthinker.profile_report/1), `report.md`, `latency.png` (per call),
`memory.png`, and `pipeline.png` (seconds per stage of the question) when one ran (Pillow charts, no
matplotlib; written by the host-side `host/report.py` as one atomic group, like `ask` and `map`). `--update-profile` writes the measured costs back into the profile TOML (status "measured", today's
date and the bundle hash). Random-weight models are marked everywhere:
their timings are real, their outputs are not.
"""
from __future__ import annotations

import argparse
import datetime as _dt
import gc
import os
import platform
import time
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from ..align import AlignConf
from ..budget import Profile, load_profile, update_profile_costs
from ..infra.bundle import bundle_hash
from ..infra.errors import InputError, MosaicError
from ..infra.outputs import check_out_dir
from ..infra.trace import Trace, peak_rss_mb, reset_peak_rss, rss_mb
from ..infra.providers import create_session
from ..models import load_role
from ..infra.bundle import load_bundle
from ..pipeline import AskRequest, ask
from ..geometry import make_pose, ransac_transform, rotation_about
from .flags import add_keyframes
from ..infra.progress import stderr_is_terminal
from ..frames import open_source
import multiprocessing as mp
from concurrent.futures import ProcessPoolExecutor

REPORT_SCHEMA = "mosaicthinker.profile_report/1"
_ORT_DTYPES = {"float": np.float32, "float16": np.float16, "double": np.float64, "uint8": np.uint8,
               "int8": np.int8, "int32": np.int32, "int64": np.int64, "bool": np.bool_}
DEFAULT_NAMES = ("chair", "table", "sofa", "tv", "bed", "plant")


def percentiles(times_ms: Sequence[float]) -> dict[str, float]:
    """times [N] ms -> {p50, p90, mean, min, n} (numpy's linear interpolation)."""
    a = np.asarray(times_ms, np.float64)
    if a.size == 0:
        return {"p50": float("nan"), "p90": float("nan"), "mean": float("nan"), "min": float("nan"), "n": 0}
    return {"p50": round(float(np.percentile(a, 50)), 3), "p90": round(float(np.percentile(a, 90)), 3),
            "mean": round(float(a.mean()), 3), "min": round(float(a.min()), 3), "n": int(a.size)}


def _dim(d: Any, dynamic_dim: int, past: int) -> int:
    """Size for one declared dimension: fixed sizes as given; symbolic ones by name so that a decoder step is
    consistent (past -> `past`, total = past + 1, everything else -> `dynamic_dim`)."""
    if isinstance(d, int) and d > 0:
        return d
    name = str(d).lower() if d is not None else ""
    if "past" in name or "cache" in name:
        return past
    if "total" in name:
        return past + dynamic_dim
    return dynamic_dim


def random_feeds(sess: Any, rng: np.random.Generator, dynamic_dim: int = 1, past: int = 16
                 ) -> dict[str, np.ndarray]:
    """Random inputs for a session's declared inputs: uint8 images 0..255, floats in [0, 1), ints 0..9 (token
    ids, indices), attention masks all ones; symbolic dims -> `dynamic_dim`, except KV-cache lengths (`past`,
    so a decoder graph is timed as one decoding step with a cache) and totals (past + dynamic_dim).
    sess: onnxruntime InferenceSession or providers.Session."""
    feeds = {}
    for i in sess.get_inputs():
        shape = [_dim(d, dynamic_dim, past) for d in (i.shape or [])]
        dt = _ORT_DTYPES.get(i.type.replace("tensor(", "").rstrip(")"), np.float32)
        if "mask" in i.name.lower():
            x = np.ones(shape, dtype=dt)
        elif dt == np.uint8:
            x = rng.integers(0, 256, shape, dtype=np.uint8)
        elif np.issubdtype(dt, np.integer):
            x = rng.integers(0, 10, shape).astype(dt)
        elif dt == np.bool_:
            x = np.ones(shape, bool)
        else:
            x = rng.random(shape, dtype=np.float32).astype(dt)
        feeds[i.name] = x
    return feeds


def time_calls(fn: Callable[[], Any], runs: int, warmup: int) -> tuple[list[float], float]:
    """Run `fn` warmup + runs times; returns (warm times in ms, first-call ms)."""
    t0 = time.perf_counter()
    fn()
    first = (time.perf_counter() - t0) * 1000
    for _ in range(max(0, warmup - 1)):
        fn()
    times = []
    for _ in range(runs):
        t = time.perf_counter()
        fn()
        times.append((time.perf_counter() - t) * 1000)
    return times, first


def synthetic_frame(h: int = 480, w: int = 640, seed: int = 0) -> np.ndarray:
    """A textured RGB test image [h, w, 3] uint8 (smooth colour blobs + edges), so that feature extractors and
    NMS see realistic amounts of structure. Used when no --video is given."""
    import cv2

    rng = np.random.default_rng(seed)
    img = cv2.resize(rng.integers(0, 256, (h // 16, w // 16, 3), dtype=np.uint8), (w, h),
                     interpolation=cv2.INTER_CUBIC)
    for _ in range(25):
        x0, y0 = int(rng.integers(0, w - 40)), int(rng.integers(0, h - 40))
        x1, y1 = x0 + int(rng.integers(20, 160)), y0 + int(rng.integers(20, 120))
        cv2.rectangle(img, (x0, y0), (x1, y1), tuple(int(c) for c in rng.integers(0, 256, 3)), -1)
    return img


class _Mem:
    """RSS before / after / peak around a block (peak via the kernel's VmHWM after a reset, where possible)."""

    def __enter__(self):
        gc.collect()
        self.can_reset = reset_peak_rss()
        self.before = rss_mb()
        return self

    def __exit__(self, *exc):
        self.after = rss_mb()
        self.peak = max(peak_rss_mb() if self.can_reset else self.after, self.after)
        return False

    @property
    def increase(self) -> float:
        return round(self.after - self.before, 1)

    @property
    def peak_increase(self) -> float:
        return round(self.peak - self.before, 1)


def _variant_for(bundle: Any, role: str, profile: Profile | None, which: str) -> list[str]:
    variants = list(bundle.role_meta(role).get("variants", {}))
    if which == "all":
        return variants
    if profile is not None and role in profile.roles:
        want = profile.role(role).bundle_variant
        if want in variants:
            return [want]
    return [bundle.variant_name(role)]


def profile_components(bundle: Any, role: str, variant: str, providers: list[str] | None, threads: int | None,
                       runs: int, warmup: int, trace: Trace, rng: np.random.Generator) -> dict[str, Any]:
    """Per component of one variant: load ms, warm latency, memory, provider used (errors recorded, not raised)."""
    spec = bundle.spec(role, variant, verify=True)
    out: dict[str, Any] = {}
    for cname, comp in spec.components.items():
        stage = f"profile.{role}.{variant}.{cname}"
        rec: dict[str, Any] = {"file": comp.meta.get("file"), "bytes": comp.meta.get("bytes")}
        try:
            with _Mem() as m:
                t0 = time.perf_counter()
                sess = create_session(comp.path, stage, providers, threads=threads, trace=trace)
                rec["load_ms"] = round((time.perf_counter() - t0) * 1000, 2)
                feeds = _at_image_size(random_feeds(sess, rng), spec.preprocessing, rng)
                times, first = time_calls(lambda: sess.run(feeds), runs, warmup)
                if role == "vlm" and "dec" in cname:  # prefill of one image's tokens, empty cache
                    n_tok = int(spec.config.get("image_seq_len", 64))
                    pf = random_feeds(sess, rng, dynamic_dim=n_tok, past=0)
                    pt, _ = time_calls(lambda: sess.run(pf), runs, 1)
                    rec["prefill_latency_ms"], rec["prefill_tokens"] = percentiles(pt), n_tok
            rec.update({"first_run_ms": round(first, 2), "latency_ms": percentiles(times),
                        "rss_increase_mb": m.increase, "peak_rss_increase_mb": m.peak_increase,
                        "provider": sess.provider,
                        "fallbacks": [a for a in sess.attempts if not a.get("ok")],
                        "input_shapes": {k: list(v.shape) for k, v in feeds.items()}})
            del sess
        except MosaicError as e:
            rec["error"] = str(e)
        except Exception as e:  # noqa: BLE001 - a graph that cannot run on random inputs is reported, not fatal
            rec["error"] = f"{type(e).__name__}: {str(e)[:300]}"
        gc.collect()
        out[cname] = rec
    return out


def _at_image_size(feeds: dict[str, np.ndarray], pp: dict[str, Any], rng: np.random.Generator
                   ) -> dict[str, np.ndarray]:
    """A graph with a symbolic image size (YOLOX) runs at the bundle's `preprocessing.size`, not at the 1 x 1 a
    symbolic dim gets in `random_feeds`: its 3-channel rank-4 input is redrawn at [H, W] in the layout."""
    size = pp.get("size")
    if not size:
        return feeds
    h, w = (int(v) for v in size)
    nchw = str(pp.get("layout", "NHWC")).upper() == "NCHW"
    out = dict(feeds)
    for k, x in feeds.items():
        if x.ndim == 4 and x.shape[1 if nchw else 3] == 3 and tuple(x.shape[2:4] if nchw else x.shape[1:3]) != (h, w):
            shape = (x.shape[0], 3, h, w) if nchw else (x.shape[0], h, w, 3)
            out[k] = (rng.integers(0, 256, shape, dtype=np.uint8) if x.dtype == np.uint8
                      else rng.random(shape, dtype=np.float32).astype(x.dtype))
    return out


class _Fresh:
    """Hands out a distinct copy of a frame on every call (one pixel changed), so that adapters' per-image caches
    (segmenter classes, matcher features) never hit and every call pays for the real work."""

    _serial = 0  # process-wide, so two _Fresh never hand out identical images

    def __init__(self, frame: np.ndarray, n: int):
        self.frames = []
        for _ in range(n):
            k = _Fresh._serial = _Fresh._serial + 1
            f = frame.copy()
            f[0, 0] = (k % 256, (k // 256) % 256, (k // 65536) % 256)
            self.frames.append(f)
        self.i = 0

    def __call__(self) -> np.ndarray:
        f = self.frames[self.i % len(self.frames)]
        self.i += 1
        return f


def _adapter_call(model: Any, role: str, frames: list[np.ndarray], n: int
                  ) -> tuple[Callable[[], Any], str] | None:
    a = _Fresh(frames[0], n)
    b = _Fresh(frames[min(1, len(frames) - 1)], n)
    if role == "depth" and hasattr(model, "predict"):
        return (lambda: model.predict(a())), "predict(rgb)"
    if role == "detector" and hasattr(model, "detect"):
        return (lambda: model.detect(a(), list(DEFAULT_NAMES))), f"detect(rgb, {len(DEFAULT_NAMES)} names)"
    if role == "instance_segmenter" and hasattr(model, "detect"):
        labels = list(dict.fromkeys(getattr(model, "labels", DEFAULT_NAMES)))
        floor = getattr(getattr(model, "conf", None), "floor", None)
        return ((lambda: model.detect(a(), labels, min_score=floor, masks=True)),
                f"detect(rgb, every label, candidates, masks=True)")
    if role == "segmenter" and hasattr(model, "segment"):
        H, W = frames[0].shape[:2]
        boxes = np.array([[0, 0, W / 2, H / 2], [W / 2, H / 2, W, H], [W / 4, H / 4, 3 * W / 4, 3 * H / 4],
                          [0, H / 2, W / 2, H]], np.float32)
        names = ["chair", "table", "sofa", "tv"]
        return (lambda: model.segment(a(), boxes, names)), "segment(rgb, 4 boxes)"
    if role == "embedder" and hasattr(model, "embed"):
        return (lambda: model.embed(a())), "embed(rgb)"
    if role == "matcher" and hasattr(model, "match"):
        return (lambda: model.match(a(), b())), "match(rgb0, rgb1), both images new"
    return None


def profile_adapter(bundle: Any, role: str, variant: str, providers: list[str] | None, threads: int | None,
                    runs: int, warmup: int, trace: Trace, frames: list[np.ndarray]) -> dict[str, Any]:
    """The runtime adapter of a role (pre/post-processing included): load ms, warm latency, memory, providers."""
    rec: dict[str, Any] = {}
    try:
        with _Mem() as m:
            t0 = time.perf_counter()
            model = load_role(bundle, role, variant, providers=providers, threads=threads, trace=trace)
            rec["load_ms"] = round((time.perf_counter() - t0) * 1000, 2)
            call = _adapter_call(model, role, frames, runs + warmup)
            if call is None:
                rec["note"] = f"no adapter call for role {role} (component timings only)"
            else:
                fn, what = call
                times, first = time_calls(fn, runs, warmup)
                rec.update({"call": what, "first_run_ms": round(first, 2), "latency_ms": percentiles(times)})
                if role == "matcher" and hasattr(model, "features"):  # two-stage: extraction alone
                    fresh = _Fresh(frames[0], runs + 1)
                    ft, _ = time_calls(lambda: model.features(fresh()), runs, 1)
                    rec["features_latency_ms"] = percentiles(ft)
        rec.update({"rss_increase_mb": m.increase, "peak_rss_increase_mb": m.peak_increase,
                    "providers": model.providers_used(), "random_weights": bool(model.spec.random_weights)})
        del model
    except MosaicError as e:
        rec["error"] = str(e)
    except Exception as e:  # noqa: BLE001
        rec["error"] = f"{type(e).__name__}: {str(e)[:300]}"
    gc.collect()
    return rec


def _role_worker(job: dict[str, Any]) -> dict[str, Any]:
    """Profile one role/variant in THIS process (used in a fresh spawned process, so that memory figures are not
    flattered by memory an earlier model freed). Returns components, adapter, baseline RSS and trace events."""
    import cv2  # noqa: F401 - part of the runtime's baseline

    import onnxruntime  # noqa: F401


    trace = Trace()
    base = rss_mb()
    b = load_bundle(job["bundle"], verify=False)
    rng = np.random.default_rng(0)
    comps = profile_components(b, job["role"], job["variant"], job["providers"], job["threads"], job["runs"],
                               job["warmup"], trace, rng)
    adapter = profile_adapter(b, job["role"], job["variant"], job["providers"], job["threads"], job["runs"],
                              job["warmup"], trace, job["frames"])
    return {"components": comps, "adapter": adapter, "rss_baseline_mb": round(base, 1),
            "events": trace.events, "providers": trace.providers}


def _question_worker(job: dict[str, Any]) -> dict[str, Any]:
    """One full question through `pipeline.ask` in THIS process: wall time, per-stage times, peak RSS."""
    reset_peak_rss()
    base = rss_mb()
    trace = Trace()
    prof = load_profile(job["profile"]) if job.get("profile") else None
    c0 = time.process_time()  # user + system CPU of every thread of this process
    t0 = time.perf_counter()
    req = AskRequest(keyframes=job.get("keyframes"), conf={"depth": "model", "matcher": "model"}, profile=prof)
    res = ask(job["video"], job["question"], request=req, bundle=job["bundle"], trace=trace)
    wall = time.perf_counter() - t0
    cpu = time.process_time() - c0
    td = trace.to_dict()
    kf = td["decisions"].get("keyframes", {})
    return {"question": job["question"], "answer": res.answer.text, "wall_s": round(wall, 3), "cpu_s": round(cpu, 3),
            "stages": td["stages"], "frames_scored": kf.get("frames_scored"), "candidates": kf.get("candidates"),
            "keyframes": len(res.build.keyframes) if res.build is not None else None,
            "frames": (td["decisions"].get("dedup") or {}).get("frames"),
            "peak_rss_mb": round(max(peak_rss_mb(), rss_mb()), 1), "rss_start_mb": round(base, 1),
            "events": [e for e in td["events"] if e["kind"] in ("fallback", "degraded", "replan", "memory_guard",
                                                                "random_weights")]}


def _run_isolated(job: dict[str, Any], fn: Callable[[dict[str, Any]], dict[str, Any]] | None = None
                  ) -> dict[str, Any]:
    with ProcessPoolExecutor(max_workers=1, mp_context=mp.get_context("spawn")) as ex:
        return ex.submit(fn or _role_worker, job).result()


def profile_cpu_side(video: str | None, frames: list[np.ndarray], runs: int, max_frames: int = 150
                     ) -> dict[str, Any]:
    """CPU-side pieces that exist: video decode and dedup per frame (needs --video), RANSAC per pair."""
    out: dict[str, Any] = {}
    if video:
        try:
            src = open_source(video, cache_size=0)
            n = min(len(src), max_frames)
            t0 = time.perf_counter()
            for i in range(n):
                src[i]
            out["video_decode"] = {"ms_per_frame": round((time.perf_counter() - t0) * 1000 / max(n, 1), 3),
                                   "frames": n, "source": type(src).__name__}
        except Exception as e:  # noqa: BLE001
            out["video_decode"] = {"error": f"{type(e).__name__}: {str(e)[:200]}"}
        try:
            from ..scan import remove_redundant
            from ..frames import open_source as _open

            src = _open(video)
            n = len(src)
            t0 = time.perf_counter()
            res = remove_redundant(src)
            total = (time.perf_counter() - t0) * 1000
            out["dedup"] = {"ms_per_frame": round(total / max(n, 1), 3), "frames": n, "kept": len(res.kept),
                            "note": "whole pass per video frame, including the decoding it does"}
        except Exception as e:  # noqa: BLE001
            out["dedup"] = {"error": f"{type(e).__name__}: {str(e)[:200]}"}

    rng = np.random.default_rng(0)
    src_pts = rng.uniform(-2, 2, (400, 3))
    T = make_pose(rotation_about(np.array([0.0, 0.0, 1.0]), 0.3), np.array([0.2, -0.1, 0.05]))
    dst = src_pts @ T[:3, :3].T + T[:3, 3]
    dst[:120] += rng.normal(0, 0.5, (120, 3))
    try:
        pair = lambda: ransac_transform(src_pts, dst, min_inliers=AlignConf.keyframe_min_inliers)  # noqa: E731
        times, _ = time_calls(pair, runs, 1)
        out["ransac_pair"] = {"latency_ms": percentiles(times), "points": 400, "outliers": 120}
    except Exception as e:  # noqa: BLE001
        out["ransac_pair"] = {"error": f"{type(e).__name__}: {str(e)[:200]}"}
    h, w = frames[0].shape[:2]
    # what a key frame keeps: RGB, depth float32, 4 masks (bool), 4096 features x (64 float32 + 3 float32)
    out["keyframe_state"] = {"mb": round((h * w * 3 + h * w * 4 + 4 * h * w + 4096 * (64 + 3) * 4) / 2**20, 3),
                             "arithmetic": f"{w}x{h}: rgb + depth f32 + 4 masks + 4096 x 67 f32 features"}
    return out


def load_frames(video: str | None, n: int = 2) -> tuple[list[np.ndarray], str]:
    """Two real frames from --video (first and a quarter in), else synthetic ones (the second shifted by 8 px)."""
    if video:
        src = open_source(video)
        idx = [0, max(1, len(src) // 4)] if len(src) > 1 else [0]
        return [src[i].rgb for i in idx][:n], f"{video} frames {idx}"
    f0 = synthetic_frame()
    f1 = np.roll(f0, (6, 8), axis=(0, 1))
    return [f0, f1], "synthetic 640x480 textured image (no --video)"


def _costs_from(report: dict[str, Any]) -> tuple[dict[str, dict[str, float]], dict[str, str]]:
    """Measured figures -> profile cost items (only what was measured)."""
    costs: dict[str, dict[str, float]] = {}
    provs: dict[str, str] = {}
    for role, r in report["roles"].items():
        if r.get("skipped"):
            continue
        v = r["variants"][r["planned_variant"]]
        ad = v.get("adapter", {})
        comps = v.get("components", {})
        if "error" in ad or not comps or any("error" in c for c in comps.values()):
            continue
        p50 = ad.get("latency_ms", {}).get("p50")
        load = ad.get("load_ms")
        # the adapter loads after its raw components were freed (allocator reuse): take the larger figure
        res = max(ad.get("rss_increase_mb", 0.0), sum(max(c.get("rss_increase_mb", 0.0), 0.0)
                                                       for c in comps.values()), 0.0)
        provs[role] = ", ".join(sorted({c.get("provider") or "?" for c in comps.values()}))
        if role == "matcher":
            fl = ad.get("features_latency_ms", {}).get("p50")
            if fl is not None and p50 is not None:  # two-stage: features per frame + the pair's own work
                costs[role] = {"ms_per_call": fl, "ms_per_pair": max(p50 - 2 * fl, 0.0), "load_ms": load,
                               "resident_mb": res}
            elif p50 is not None:  # one pair graph extracts both images on every call
                costs[role] = {"ms_per_call": 0.0, "ms_per_pair": p50, "load_ms": load, "resident_mb": res}
        elif role == "segmenter":
            if p50 is not None:
                enc = [c for n, c in comps.items() if "enc" in n or n == "image"]
                dec = [c for n, c in comps.items() if "dec" in n or "prompt" in n]
                if enc and dec:
                    costs[role] = {"ms_per_call": enc[0]["latency_ms"]["p50"],
                                   "ms_per_prompt": dec[0]["latency_ms"]["p50"], "load_ms": load,
                                   "resident_mb": res}
                else:  # semantic: one pass per frame, prompts only select its pixels
                    costs[role] = {"ms_per_call": p50, "ms_per_prompt": 0.0, "load_ms": load, "resident_mb": res}
        elif role == "vlm":
            vis = [c for n, c in comps.items() if "vis" in n or "image" in n]
            dec = [c for n, c in comps.items() if "dec" in n or "text" in n or "lm" in n]
            if vis and dec:
                load = sum(c.get("load_ms", 0.0) for c in comps.values())
                res = sum(max(c.get("rss_increase_mb", 0.0), 0.0) for c in comps.values())
                # an image = the vision graph + the decoder's prefill of its tokens; a token = one cached step
                prefill = dec[0].get("prefill_latency_ms", {}).get("p50", 0.0)
                costs[role] = {"ms_per_image": vis[0]["latency_ms"]["p50"] + prefill,
                               "ms_per_token": dec[0]["latency_ms"]["p50"], "load_ms": load, "resident_mb": res}
        elif p50 is not None:
            costs[role] = {"ms_per_call": p50, "load_ms": load, "resident_mb": res}
    cpu = report.get("cpu_side", {})
    if "ms_per_frame" in cpu.get("video_decode", {}):
        costs["video_decode"] = {"ms_per_call": cpu["video_decode"]["ms_per_frame"]}
    if "ms_per_frame" in cpu.get("dedup", {}):
        costs["dedup"] = {"ms_per_call": cpu["dedup"]["ms_per_frame"]}
    pl = report.get("pipeline") or {}
    if "dedup" not in costs and pl.get("frames") and "dedup" in pl.get("stages", {}):
        costs["dedup"] = {"ms_per_call": pl["stages"]["dedup"]["seconds"] * 1000 / pl["frames"]}
    if pl.get("keyframes") and "refine" in pl.get("stages", {}):
        costs["refine"] = {"ms_per_call": pl["stages"]["refine"]["seconds"] * 1000 / pl["keyframes"]}
    if "latency_ms" in cpu.get("ransac_pair", {}):
        costs["geometry"] = {"ms_per_call": cpu["ransac_pair"]["latency_ms"]["p50"]}
    costs["process"] = {"resident_mb": report["process"]["rss_baseline_mb"]}
    for c in costs.values():
        for k in list(c):
            c[k] = round(float(c[k]), 3)
    return costs, provs


COST_NOTES = {
    "geometry": "RANSAC on one 400-point pair only (the tree and fusion shares are not in this figure)",
    "process": "RSS after importing the runtime, numpy, OpenCV and onnxruntime (no frame cache yet)",
    "dedup": "redundant-frame-removal pass per video frame, including the decoding it does",
    "refine": "occlusion refinement time of the full-question run divided by its key frames",
}


def run_profile(bundle: Any, profile: Profile | str | None = None, *, video: str | None = None,
                out: str | os.PathLike | None = None, runs: int = 10, warmup: int = 2, variants: str = "planned",
                roles: Sequence[str] | None = None, update_profile: bool = False, progress: bool = True,
                trace: Trace | None = None, isolate: bool = True,
                question: str | None = "How many chairs are in this room?", keyframes: int | None = None
                ) -> dict[str, Any]:
    """Profile a bundle on this machine; writes report.json / report.md / PNG charts into `out` when given.

    profile: providers, threads and the planned variant per role (None: CPU, default threads, the bundle's
    default variants); variants: "planned" (the profile's variant per role, else the bundle default) or "all";
    update_profile: write measured costs into the profile file (needs a profile); isolate: profile each role in
    a fresh process (default) so memory figures are not flattered by memory freed by the previous model;
    question: with `video`, one full question through `pipeline.ask` (None: skip); keyframes: its K.
    """
    from tqdm import tqdm


    import cv2  # noqa: F401 - counted in the runtime's baseline

    if out is not None:  # a file-shaped, read-only or full --out fails now, not after minutes of profiling
        check_out_dir(Path(out))
    base_rss = rss_mb()
    prof = load_profile(profile) if isinstance(profile, (str, os.PathLike)) else profile
    if update_profile and prof is None:
        raise InputError("`update_profile` needs `profile` (the file the measured costs are written to)",
                         fields=("update_profile", "profile"))
    b = load_bundle(bundle, verify=True)
    bhash = bundle_hash(b)
    trace = trace if trace is not None else Trace()
    rng = np.random.default_rng(0)
    frames, frames_from = load_frames(video)
    threads = prof.intra_op_threads if prof else None
    todo = []
    for role in b.roles:
        if roles and role not in roles:
            continue
        for v in _variant_for(b, role, prof, variants):
            todo.append((role, v))
    report = _report_header(b, bhash, prof, runs, warmup, threads, frames_from, isolate, base_rss)
    bar = tqdm(total=len(todo) + 1 + int(bool(video and question)), desc="mosaic profile", unit="step",
               disable=not progress, leave=False)
    for role, v in todo:
        bar.set_postfix_str(f"{role}/{v}")
        _profile_role(report, b, role, v, prof, threads, runs, warmup, trace, rng, frames, isolate)
        bar.update(1)
    bar.set_postfix_str("cpu-side stages")
    report["cpu_side"] = profile_cpu_side(video, frames, runs)
    bar.update(1)
    if video and question:
        bar.set_postfix_str("one full question")
        report["pipeline"] = _profile_question(video, question, b, prof, keyframes, isolate)
        bar.update(1)
    bar.close()
    report["fallbacks"] = trace.fallbacks()
    report["random_weights_used"] = list(trace.random_weights_used)
    report["peak_rss_mb"] = round(max(peak_rss_mb(), rss_mb()), 1)
    costs, provs = _costs_from(report)
    report["measured_costs"] = costs
    if update_profile and prof is not None and prof.path is not None:
        _write_costs(report, prof, costs, provs, bhash)
    if out is not None:  # as one group: folder locked, temp files renamed, run id in every file
        from mosaicthinker.host.report import save_report

        save_report(report, out, trace)
    return report


def _report_header(b: Any, bhash: str, prof: Profile | None, runs: int, warmup: int, threads: int | None,
                   frames_from: str, isolate: bool, base_rss: float) -> dict[str, Any]:
    """The report's machine / bundle / settings part (roles are filled in as they are profiled)."""
    report: dict[str, Any] = {
        "schema": REPORT_SCHEMA, "date": _dt.date.today().isoformat(),
        "machine": {"platform": platform.platform(), "processor": platform.processor() or platform.machine(),
                    "cpu_count": os.cpu_count(), "python": platform.python_version(),
                    "load_average_1min": round(os.getloadavg()[0], 2) if hasattr(os, "getloadavg") else None},
        "bundle": str(b.root), "bundle_hash": bhash, "profile": prof.name if prof else None,
        "profile_path": str(prof.path) if prof and prof.path else None,
        "runs": runs, "warmup": warmup, "threads": threads, "frames_from": frames_from, "isolated": isolate,
        "process": {"rss_baseline_mb": round(base_rss, 1)}, "roles": {},
    }
    try:
        import onnxruntime as ort

        report["machine"]["onnxruntime"] = ort.__version__
        report["machine"]["providers_available"] = list(ort.get_available_providers())
    except Exception:  # pragma: no cover
        pass
    return report


def _profile_role(report: dict[str, Any], b: Any, role: str, v: str, prof: Profile | None,
                  threads: int | None, runs: int, warmup: int, trace: Trace, rng: np.random.Generator,
                  frames: list[np.ndarray], isolate: bool) -> None:
    """Profile one role's variant (in a fresh process when `isolate`) into report["roles"]."""
    meta = b.role_meta(role)
    providers = prof.providers_for(role) if prof else None
    rr = report["roles"].setdefault(role, {
        "arch": meta.get("arch"), "random_weights": bool(meta.get("random_weights")),
        "licence": meta.get("licence"), "planned_variant": v, "providers_requested": providers or ["cpu"],
        "variants": {}})
    if rr["random_weights"] and isolate:  # in-process, load_role notes it in this trace itself
        trace.note_random_weights(f"{role}:{meta.get('arch')} ({b.root})")
    if isolate:
        job = {"bundle": str(b.root), "role": role, "variant": v, "providers": providers, "threads": threads,
               "runs": runs, "warmup": warmup, "frames": frames}
        res = _run_isolated(job)
        comps, adapter = res["components"], res["adapter"]
        for e in res["events"]:
            if e["kind"] != "random_weights":
                trace.events.append({**e, "isolated_process": True})
        for k, pv in res["providers"].items():
            trace.providers[k] = pv
    else:
        comps = profile_components(b, role, v, providers, threads, runs, warmup, trace, rng)
        adapter = profile_adapter(b, role, v, providers, threads, runs, warmup, trace, frames)
    rr["variants"][v] = {"precision": meta["variants"][v].get("precision"), "components": comps,
                         "adapter": adapter}


def _profile_question(video: str, question: str, b: Any, prof: Profile | None, keyframes: int | None,
                      isolate: bool) -> dict[str, Any]:
    """One full question through `pipeline.ask`; an error is reported, not raised (the per-model figures stand)."""
    job = {"video": str(video), "question": question, "bundle": str(b.root),
           "profile": str(prof.path) if prof is not None and prof.path else None, "keyframes": keyframes}
    try:
        return _run_isolated(job, _question_worker) if isolate else _question_worker(job)
    except MosaicError as e:
        return {"error": str(e), "question": question}
    except Exception as e:  # noqa: BLE001 - reported; the per-model figures stand on their own
        return {"error": f"{type(e).__name__}: {str(e)[:300]}", "question": question}


def _write_costs(report: dict[str, Any], prof: Profile, costs: dict, provs: dict, bhash: str) -> None:
    """Write the measured costs into the profile file, each with its note (and a load warning when busy)."""
    notes = {k: v for k, v in COST_NOTES.items() if k in costs}
    vd = report["cpu_side"].get("video_decode", {})
    if "video_decode" in costs:
        notes["video_decode"] = f"per frame of a {vd.get('source')} ({report['frames_from'].split(' frames')[0]})"
    load = report["machine"].get("load_average_1min")
    if load is not None and os.cpu_count() and load > os.cpu_count():
        for k in costs:
            notes[k] = (notes.get(k, "") + ("; " if k in notes else "")
                        + f"measured with load average {load} on {os.cpu_count()} CPUs: other jobs shared "
                          f"the CPUs, timings may be inflated")
    update_profile_costs(prof.path, costs, bundle_hash_=bhash, date=report["date"], providers=provs,
                         notes=notes)
    report["updated_profile"] = str(prof.path)


# ------------------------------------------------------------------------------------------------ output


def report_rows(report: dict[str, Any]) -> list[dict[str, Any]]:
    """One row per role/variant/component and per adapter, for the table and charts."""
    rows = []
    for role, r in report["roles"].items():
        for v, vr in r["variants"].items():
            ad = vr.get("adapter", {})
            if ad and "latency_ms" in ad:
                rows.append({"name": f"{role} (adapter)", "role": role, "variant": v, "kind": "adapter",
                             "load_ms": ad.get("load_ms"), "p50": ad["latency_ms"]["p50"],
                             "p90": ad["latency_ms"]["p90"], "mem": ad.get("rss_increase_mb"),
                             "peak": ad.get("peak_rss_increase_mb"),
                             "provider": ", ".join(sorted({str(p) for p in ad.get("providers", {}).values()})),
                             "random": r["random_weights"]})
            for c, cr in vr["components"].items():
                if "error" in cr:
                    rows.append({"name": f"{role}.{c}", "role": role, "variant": v, "kind": "component",
                                 "error": cr["error"], "random": r["random_weights"]})
                    continue
                rows.append({"name": f"{role}.{c}", "role": role, "variant": v, "kind": "component",
                             "load_ms": cr["load_ms"], "p50": cr["latency_ms"]["p50"], "p90": cr["latency_ms"]["p90"],
                             "mem": cr["rss_increase_mb"], "peak": cr["peak_rss_increase_mb"],
                             "provider": cr["provider"], "random": r["random_weights"]})
    return rows


def render(report: dict[str, Any]) -> str:
    """The Markdown summary (also what the command prints)."""
    m = report["machine"]
    lines = [f"# Profile of {report['bundle']} (bundle {report['bundle_hash']})", "",
             f"- date {report['date']}, machine: {m['processor']}, {m['cpu_count']} CPUs, {m['platform']}, "
             f"onnxruntime {m.get('onnxruntime', '?')} (available: {', '.join(m.get('providers_available', []))}); "
             f"load average at start {m.get('load_average_1min')} (other jobs on the machine inflate timings)",
             f"- profile: {report['profile'] or '(none: CPU, default threads)'}; threads {report['threads']}; "
             f"{report['runs']} warm runs after {report['warmup']} warm-up; inputs: {report['frames_from']}",
             f"- runtime baseline RSS {report['process']['rss_baseline_mb']} MB; peak RSS {report['peak_rss_mb']} MB",
             ""]
    if report.get("random_weights_used"):
        lines += [f"**RANDOM WEIGHTS**: {', '.join(report['random_weights_used'])} — timings are real, outputs "
                  f"are meaningless.", ""]
    lines += ["| model | variant | provider | load ms | p50 ms | p90 ms | RSS +MB | peak +MB |",
              "|---|---|---|---:|---:|---:|---:|---:|"]
    for r in report_rows(report):
        tag = " (RANDOM WEIGHTS)" if r["random"] else ""
        if "error" in r:
            lines.append(f"| {r['name']}{tag} | {r['variant']} | error: {r['error'][:80]} | | | | | |")
        else:
            lines.append(f"| {r['name']}{tag} | {r['variant']} | {r['provider']} | {r['load_ms']:.1f} | "
                         f"{r['p50']:.1f} | {r['p90']:.1f} | {r['mem']:.1f} | {r['peak']:.1f} |")
    cpu = report.get("cpu_side", {})
    lines += ["", "CPU-side stages:", ""]
    for k, v in cpu.items():
        lines.append(f"- {k}: " + ", ".join(f"{a}={b}" for a, b in v.items() if a != "latency_ms")
                     + (f", p50 {v['latency_ms']['p50']} ms, p90 {v['latency_ms']['p90']} ms" if "latency_ms" in v
                        else ""))
    pl = report.get("pipeline")
    if pl and "error" in pl:
        lines += ["", f"One full question ({pl.get('question')!r}): error: {pl['error']}"]
    elif pl:
        lines += ["", f"One full question: {pl['question']!r} -> {pl['answer']!r}: {pl['wall_s']} s wall "
                      f"({pl.get('cpu_s')} s CPU), "
                      f"{pl['frames']} frames, {pl['frames_scored']} scored of {pl['candidates']} candidates, "
                      f"{pl['keyframes']} key frames, peak RSS {pl['peak_rss_mb']} MB", "",
                  "| stage | seconds | calls | peak RSS MB |", "|---|---:|---:|---:|"]
        for n, st in pl.get("stages", {}).items():
            lines.append(f"| {n} | {st['seconds']:.3f} | {st['calls']} | {st['rss_peak_mb']:.0f} |")
    if report.get("fallbacks"):
        lines += ["", "Provider fallbacks:", ""] + [f"- {e['message']}" for e in report["fallbacks"]]
    lines += ["", "Measured costs (profile items):", ""]
    for k, v in report.get("measured_costs", {}).items():
        lines.append(f"- {k}: " + ", ".join(f"{a} = {b:g}" for a, b in v.items()))
    if report.get("updated_profile"):
        lines += ["", f"Written back to {report['updated_profile']} (status measured, {report['date']}, "
                      f"bundle {report['bundle_hash']})."]
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------------------------------------ `mosaic profile`


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--video", metavar="V", help="video / image / RGB-D folder: real frames for the adapters, "
                                                     "and the decode + dedup costs")
    parser.add_argument("--runs", type=int, default=10, help="warm runs per model (default 10)")
    parser.add_argument("--warmup", type=int, default=2, help="warm-up runs, not timed (default 2)")
    parser.add_argument("--variants", choices=["planned", "all"], default="planned",
                        help="planned: the profile's variant per role (else the bundle default); all: every variant")
    parser.add_argument("--roles", help="comma-separated roles to profile (default: all in the bundle)")
    parser.add_argument("--update-profile", action="store_true",
                        help="write the measured costs into --profile (status measured, date, bundle hash)")
    parser.add_argument("--question", default="How many chairs are in this room?",
                        help="with --video: one full question through the pipeline, timed per stage")
    parser.add_argument("--no-question", action="store_true", help="skip the full-question run")

    add_keyframes(parser)  # K of the full-question run
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument("--in-process", action="store_true",
                        help="profile every role in this process (faster; memory figures then flatter later roles)")


def run(args: argparse.Namespace) -> dict[str, Any]:
    if not args.bundle:
        raise InputError("mosaic profile needs --bundle DIR")
    if args.runs < 1 or args.warmup < 1:
        raise InputError("--runs and --warmup must be >= 1")
    return run_profile(args.bundle, args.profile, video=args.video, out=args.out, runs=args.runs,
                       warmup=args.warmup, variants=args.variants,
                       roles=[r.strip() for r in args.roles.split(",")] if args.roles else None,
                       update_profile=args.update_profile,
                       progress=not (args.no_progress or args.json) and stderr_is_terminal(),
                       isolate=not args.in_process, question=None if args.no_question else args.question,
                       keyframes=args.keyframes)
