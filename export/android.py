"""`mosaic export --target android`: ONNX Runtime Mobile artifacts for every role of a bundle.

Per role and per source variant (fp32, fp16, int8-qdq; fp16 is made from fp32 when the bundle lacks it and
its parity allows), for every component graph:

1. **fixed shapes** where the role allows (batch -> 1, image axes -> the role's preprocessing size, text ->
   `text_len`, SAM prompts/points -> `max_prompts`/`max_points`, detector text queries -> `max_queries`,
   keypoints -> the role's top-K; the VLM's
   token and KV-cache axes stay dynamic) with onnxruntime's own
   `onnxruntime.tools.onnx_model_utils.make_dim_param_fixed` / `make_input_shape_fixed` (what
   `python -m onnxruntime.tools.make_dynamic_shape_fixed` runs). Axes no rule covers stay dynamic and the
   component is marked CPU/XNNPACK-only (NNAPI and QNN need static shapes).
2. **.ort conversion** with `onnxruntime.tools.convert_onnx_models_to_ort` (target platform `arm`), both
   optimisation styles: `Fixed` (`<component>.ort`, for CPU/XNNPACK) and `Runtime`
   (`<component>.with_runtime_opt.ort`, for NNAPI/QNN: leaves fusions to run time so the compiling EP sees the
   plain ops).
3. **parity**: the .ort file (both styles; the Runtime style with its saved optimisations replayed) against
   its source .onnx on fresh random inputs (`ort_parity`, ORT_PARITY_TOL), and a derived fp16 copy against
   fp32 (export/common.py `parity_check`, PARITY_TOL["fp16"]).
4. **mobile usability report** from onnxruntime's checker (`check_onnx_model_mobile_usability`: NNAPI and
   CoreML operator support and partition counts), text + JSON next to the artifacts, summarised in the
   manifest; more than `nnapi_max_partitions` NNAPI partitions is flagged (the "NNAPI slower than CPU" trap).
   XNNPACK and QNN coverage is NOT checked by that tool, nor here.

Bundle-wide: `android/required_operators.config` (union over every converted model and both styles: the
input of a reduced-operator onnxruntime build, `--include_ops_by_config`) and the build line in the manifest.

The VLM decoder (growing KV cache) stays dynamic and CPU/XNNPACK-only; in addition it gets a fixed-window
variant (`<c>_kvwindow_step`, `<c>_kvwindow_prefill`: static W-slot cache, KV_WINDOW_PROTOCOL) when
`kv_window_check` shows that the protocol reproduces the dynamic decoder's logits; otherwise the reason is
recorded (`kv_window_check` in the component's android entry).

Manifest fields written (all under the RESERVED `android` keys of runtime/bundle.py)::

    roles.<role>.variants["android-ort-<precision>"] = {precision, target: "android", components: {c: {file:
        <role>/android-ort-<p>/<c>.ort, format: "ort", ...}}, parity: {c: {...}}, android: {source_variant,
        components: {c: {fixed_shapes, dynamic_left, runtime_opt: {file, sha256}, usability: {file, sha256},
        usability_text: {file, sha256}, nnapi: {...}, coreml_mlprogram: {...}, flags: [...],
        providers: [...], provider_notes: [...], kv_window_check?: {...}, kv_window?: {...}}},
        required_operators: {"domain;opset": [ops]}}}
    roles.<role>.android = {variants: [...], skipped: {variant: reason}}
    android = {onnxruntime_version, required_operators: {file, sha256}, build_command, usability_summary: [...],
               not_checked: "...", phone_runs: "..."}
"""
from __future__ import annotations

import sys

import argparse
import contextlib
import io
import json
import logging
import re
import shutil
import tempfile
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from mosaicthinker.runtime.host import bundle_write as B
from mosaicthinker.runtime.errors import ExportError

from . import common as C

SOURCE_PRECISIONS = ("fp32", "fp16", "int8-qdq")
STYLES = ("Fixed", "Runtime")
VARIANT_PREFIX = "android-ort-"
OPS_CONFIG = "android/required_operators.config"
# .ort vs its source .onnx (same precision): conversion pre-applies graph optimisations (fusions, layout), so
# only rounding-order differences are allowed: ~1e-6 in fp32, fp16 rounding of fused ops, one int8 step.
ORT_PARITY_TOL = {"fp32": (1e-4, 0.99999), "fp16": (1e-2, 0.9999), "int8-qdq": (2e-2, 0.999)}
NOT_CHECKED = ("XNNPACK and QNN operator coverage is not checked here: onnxruntime's mobile usability checker "
               "covers NNAPI and CoreML only. Profile on the phone (android/profile.sh) to see what each "
               "provider actually takes.")
PHONE_RUNS = ("The phone runs the per-model graphs (.ort) through ONNX Runtime Mobile (Java/Kotlin or C/C++ "
              "API, or onnxruntime_perf_test for profiling); the Python pipeline itself is not shipped to the "
              "phone. See android/README.md for the Python-on-Android options that exist and why they are not "
              "used.")


@dataclass
class AndroidConfig:
    """Options of the Android step (defaults are the ones the tests and README use)."""

    precisions: tuple[str, ...] = SOURCE_PRECISIONS      # source variants to convert (when present / makeable)
    make_fp16: bool = True                               # derive fp16 from fp32 when the bundle lacks it
    styles: tuple[str, ...] = STYLES                     # ORT optimisation styles to write
    target_platform: str = "arm"                         # convert_onnx_models_to_ort --target_platform
    batch: int = 1
    text_len: int = 16                                   # detector text branch: tokens per name
    max_prompts: int = 4                                 # segmenter prompts (boxes) per call
    max_points: int = 4                                  # points per prompt (pad with label -1)
    max_queries: int = 8                                 # open-vocabulary detector: object names per text call
    kv_window: int = 256                                 # VLM decoder fixed cache slots W (0: no window variant)
    prefill_len: int = 64                                # VLM decoder prompt chunk P of the window prefill graph
    nnapi_max_partitions: int = 2                        # more -> flagged (onnxruntime's checker says NO > 2)
    parity_trials: int = 2
    roles: tuple[str, ...] | None = None                 # None: every role in the bundle
    overrides: dict[str, int] = field(default_factory=dict)  # dim_param -> value (--fix NAME=VALUE)


# ----------------------------------------------------------------------------------------------------------------
# Fixed shapes

def fixed_shape_plan(inputs: Sequence[dict[str, Any]], role_meta: dict[str, Any], component: str,
                     conf: AndroidConfig, role: str = "") -> tuple[dict[str, list[int]], dict[str, str]]:
    """Decide a static shape for every input with dynamic axes.

    inputs: manifest input entries ({name, shape, dtype, dynamic_axes: {axis: dim name}}); role_meta: the
    role's manifest entry (preprocessing size, config top-K); role: the role name (the VLM's token axes vary
    per call and are left dynamic). Returns (shapes {input: [d0, d1, ...]} for every input that could be
    fixed, left {"input[axis]": reason} for axes no rule covers).
    """
    pp = role_meta.get("preprocessing") or {}
    cfg = role_meta.get("config") or {}
    shapes: dict[str, list[int]] = {}
    left: dict[str, str] = {}
    for inp in inputs:
        dyn = {int(a): str(n) for a, n in (inp.get("dynamic_axes") or {}).items()}
        if not dyn:
            continue
        shape = [int(s) for s in inp.get("shape", [])]
        img = C.image_axes(inp, pp)
        ok = True
        for ax, name in sorted(dyn.items()):
            kind = None if name in conf.overrides else C.axis_kind(name, inp, ax, role_meta)
            if name in conf.overrides:
                shape[ax] = int(conf.overrides[name])
            elif role == "vlm" and ax != 0 and not img:
                ok = False
                left[f"{inp['name']}[{ax}]"] = (f"{name}: VLM token axis (prompt length, then 1 per generated "
                                                f"token; see the fixed-window decoder variant)")
            elif kind in ("past", "total"):
                ok = False
                left[f"{inp['name']}[{ax}]"] = (f"{name}: KV-cache length grows while decoding (see the "
                                                f"fixed-window decoder variant)")
            elif kind in ("batch", "images"):
                shape[ax] = conf.batch
            elif kind == "image":
                shape[ax] = img[ax]
            elif kind == "keypoints":
                shape[ax] = int(cfg.get("top_k") or cfg.get("max_keypoints"))
            elif kind == "prompts":
                shape[ax] = conf.max_prompts
            elif kind == "queries":
                shape[ax] = conf.max_queries
            elif kind == "points":
                shape[ax] = conf.max_points
            elif kind == "text":
                shape[ax] = int(cfg.get("max_text_len", conf.text_len))
            else:
                ok = False
                left[f"{inp['name']}[{ax}]"] = f"{name}: no rule fixes this axis (pass --fix {name}=VALUE)"
        if ok:
            shapes[inp["name"]] = shape
    return shapes, left


def make_fixed(src: str | Path, dst: str | Path, shapes: dict[str, list[int]]) -> Path:
    """Write a copy of `src` whose listed inputs have static shapes (onnxruntime's make_dynamic_shape_fixed
    helpers: dim_params are replaced graph-wide so every use of the same symbol agrees), then re-infer
    output shapes."""
    import onnx
    from onnxruntime.tools.onnx_model_utils import fix_output_shapes, make_dim_param_fixed, make_input_shape_fixed

    model = onnx.load(str(src))
    by_name = {i.name: i for i in model.graph.input}
    for name, shape in shapes.items():
        if name not in by_name:
            raise ExportError(f"{src}: fixed shape given for input {name!r}, which the graph does not have "
                              f"(inputs: {sorted(by_name)})")
        dims = by_name[name].type.tensor_type.shape.dim
        for d, v in zip(dims, shape):  # symbolic dims first: every other use of the symbol follows
            if d.HasField("dim_param") and d.dim_param:
                make_dim_param_fixed(model.graph, d.dim_param, int(v))
    for name, shape in shapes.items():  # then anything still unnamed/unknown on that input
        dims = by_name[name].type.tensor_type.shape.dim
        if any(not d.HasField("dim_value") for d in dims):
            make_input_shape_fixed(model.graph, name, [int(v) for v in shape])
    try:
        fix_output_shapes(model)
    except Exception:  # noqa: BLE001  the fp16 converter leaves stale value_info and appends its Casts last
        del model.graph.value_info[:]
        _toposort(model.graph)
        fix_output_shapes(model)
    onnx.save(model, str(dst))
    return Path(dst)


def _toposort(graph: Any) -> None:
    """Reorder graph.node topologically in place (onnx's checker requires it; onnxruntime does not)."""
    known = {i.name for i in graph.input} | {i.name for i in graph.initializer} | {""}
    nodes, order = list(graph.node), []
    pending = nodes
    while pending:
        rest = []
        for n in pending:
            if all(i in known for i in n.input):
                order.append(n)
                known.update(n.output)
            else:
                rest.append(n)
        if len(rest) == len(pending):  # a cycle or an outer-scope input: keep the remainder as it was
            order += rest
            break
        pending = rest
    del graph.node[:]
    graph.node.extend(order)



# ----------------------------------------------------------------------------------------------------------------
# Random inputs for parity (fixed-shape graphs)

def _dim_value(d: Any, dyn_values: dict[str, int], default: int) -> int:
    """A concrete size for one graph dim: int as is; a symbol from dyn_values (else `default`); a simple
    expression of symbols ('past_sequence_length + 1') evaluated with those values."""
    if isinstance(d, int) and d >= 0:
        return d
    if not isinstance(d, str) or not d:
        return default
    if d in dyn_values:
        return int(dyn_values[d])
    if re.fullmatch(r"[\w\s+*-]+", d) and re.search(r"[+*-]", d):
        expr = re.sub(r"[A-Za-z_]\w*", lambda m: str(int(dyn_values.get(m.group(0), default))), d)
        return int(eval(expr, {"__builtins__": {}}, {}))  # noqa: S307  digits and + - * only (checked above)
    return default


def random_feeds_factory(onnx_path: str | Path, role_meta: dict[str, Any],
                         dyn_values: dict[str, int] | None = None) -> Callable[[np.random.Generator], dict]:
    """make_inputs(rng): images as random pixels through the role's scale/mean/std, token ids in [0, vocab),
    masks all ones, prompt labels in {0, 1}, other floats ~N(0, 0.5). Dynamic dims (graphs that keep them,
    e.g. a KV-cache decoder) get sizes from dyn_values {symbol: size} (default 3)."""
    sess = C.ort_session(onnx_path)
    pp = role_meta.get("preprocessing") or {}
    cfg = role_meta.get("config") or {}
    vocab = int(cfg.get("vocab_size", 10))  # unknown vocabulary: ids 0..9 exist in any tokenizer
    dyn_values = dyn_values or {}
    specs = []
    for i in sess.get_inputs():
        specs.append((i.name, tuple(_dim_value(d, dyn_values, 3) for d in i.shape), i.type))
    img_size = tuple(pp.get("size") or ())

    def make(rng: np.random.Generator) -> dict[str, np.ndarray]:
        feeds = {}
        for name, shape, t in specs:
            lname = name.lower()
            if t == "tensor(uint8)":
                feeds[name] = rng.integers(0, 256, shape, dtype=np.uint8)
            elif t in ("tensor(int64)", "tensor(int32)"):
                dt = np.int64 if t.endswith("int64)") else np.int32
                if "mask" in lname:
                    feeds[name] = np.ones(shape, dt)
                elif "label" in lname:
                    feeds[name] = rng.integers(0, 2, shape).astype(dt)
                elif "position" in lname and len(shape) >= 1:
                    feeds[name] = np.broadcast_to(np.arange(shape[-1]), shape).astype(dt).copy()
                else:
                    feeds[name] = rng.integers(0, vocab, shape).astype(dt)
            elif t in ("tensor(float)", "tensor(float16)"):
                dt = np.float32 if t == "tensor(float)" else np.float16
                is_img = len(shape) == 4 and img_size and (tuple(shape[1:3]) == img_size or tuple(shape[2:4]) == img_size)
                if is_img:
                    px = rng.integers(0, 256, shape).astype(np.float32)
                    x = px * float(pp.get("scale", 1.0 / 255.0)) if "scale" in pp or "mean" not in pp else px
                    if "mean" in pp:
                        ch_axis = 3 if shape[3] == 3 else 1
                        bshape = [1] * 4
                        bshape[ch_axis] = -1
                        mean = np.asarray(pp["mean"], np.float32).reshape(bshape)
                        std = np.asarray(pp.get("std", [1.0, 1.0, 1.0]), np.float32).reshape(bshape)
                        x = (x - mean) / std
                    feeds[name] = x.astype(dt)
                elif "mask" in lname:
                    feeds[name] = np.ones(shape, dt)
                elif "label" in lname:
                    feeds[name] = rng.integers(0, 2, shape).astype(dt)
                elif "coord" in lname or "point" in lname or "box" in lname:
                    feeds[name] = (rng.random(shape) * max(img_size or (64,))).astype(dt)
                else:
                    feeds[name] = (rng.standard_normal(shape) * 0.5).astype(dt)
            elif t == "tensor(bool)":
                feeds[name] = np.ones(shape, bool)
            else:
                raise ExportError(f"{onnx_path}: input {name} has type {t}, which the parity check cannot fill")
        return feeds

    return make


# ----------------------------------------------------------------------------------------------------------------
# VLM decoder: fixed-window KV cache

KV_WINDOW_PROTOCOL = (
    "Fixed-window KV cache (static shapes for NPU providers): the cache is W slots per layer "
    "(past_* [1, KV, W, D], zeros at start) with a validity mask m[W] (all 0 at start). Every call feeds s new "
    "positions (s = 1 for *_kvwindow_step, s = P for *_kvwindow_prefill; a shorter prompt chunk is padded on "
    "the RIGHT with masked positions): attention_mask = [m, new_valid] (int64, length W + s), position_ids = "
    "number of valid tokens so far + 0, 1, ... for the valid new positions (0 for pads), past_* = the cache. "
    "Then cache = present_*[:, :, s:, :] and m = [m, new_valid][s:]. The s dropped slots must be unused (m = 0): "
    "at most W - s valid tokens fit (prompt + generated), else fall back to the dynamic decoder.")


def kv_io(inputs: Sequence[dict[str, Any]], outputs: Sequence[dict[str, Any]]) -> dict[str, Any] | None:
    """Recognise the decoder-with-cache I/O convention of export/hf_vlm.py (inputs_embeds | input_ids,
    attention_mask, position_ids, past_key_i / past_value_i -> logits, present_key_i / present_value_i).
    Returns {"new", "mask", "pos", "past": [names], "present": [names], "logits"} or None."""
    names = [i["name"] for i in inputs]
    new = next((n for n in ("inputs_embeds", "input_ids") if n in names), None)
    past = [n for n in names if n.startswith("past")]
    outs = [o["name"] for o in outputs]
    present = [n.replace("past", "present", 1) for n in past]
    if not new or "attention_mask" not in names or "position_ids" not in names or not past \
            or any(p not in outs for p in present):
        return None
    return {"new": new, "mask": "attention_mask", "pos": "position_ids", "past": past, "present": present,
            "logits": "logits" if "logits" in outs else outs[0]}


def kv_window_check(decoder: str | Path, inputs: Sequence[dict[str, Any]], outputs: Sequence[dict[str, Any]], *,
                    window: int, prefill: int, prompt_len: int = 5, steps: int = 6, seed: int = 0,
                    rel_tol: float = 1e-3) -> dict[str, Any]:
    """Does the fixed-window protocol (KV_WINDOW_PROTOCOL) give the dynamic decoder's logits?

    Teacher-forced on random embeddings: the dynamic graph prefills `prompt_len` positions (past 0) then steps
    one position at a time with a growing cache; the window path prefills the same positions padded to
    `prefill`, then steps with the W-slot cache. Compares the logits of the last prompt position and of every
    step. Returns {"ok", "max_rel", "steps", "window", "prefill", "reason"?}."""
    io = kv_io(inputs, outputs)
    if io is None:
        return {"ok": False, "reason": "decoder I/O does not follow the inputs_embeds/attention_mask/"
                                       "position_ids/past_* -> logits/present_* convention"}
    prompt_len, steps = min(prompt_len, prefill), min(steps, window - prefill)
    if prompt_len < 1 or steps < 1:
        return {"ok": False, "reason": f"window {window} / prefill {prefill} leave no room for the check"}
    sess = C.ort_session(decoder)
    spec = {i.name: i for i in sess.get_inputs()}
    new_i = spec[io["new"]]
    rng = np.random.default_rng(seed)
    kv_shape = [d if isinstance(d, int) else None for d in spec[io["past"][0]].shape]
    if sum(d is None for d in kv_shape) != 1 or kv_shape[2] is not None:
        return {"ok": False, "reason": f"past shape {spec[io['past'][0]].shape}: expected [1, KV, past, D]"}
    kv, d = int(kv_shape[1]), int(kv_shape[3])
    total = prompt_len + steps
    if io["new"] == "inputs_embeds":
        hidden = int(new_i.shape[2])
        seq = (rng.standard_normal((1, total, hidden)) * 0.5).astype(np.float32)
    else:
        seq = rng.integers(0, 50, (1, total)).astype(np.int64)
    names = [o.name for o in sess.get_outputs()]
    li = names.index(io["logits"])
    pres_i = [names.index(p) for p in io["present"]]

    def run(chunk, mask, pos, past):
        feeds = {io["new"]: chunk, io["mask"]: mask.astype(np.int64)[None], io["pos"]: pos.astype(np.int64)[None]}
        feeds.update(dict(zip(io["past"], past)))
        out = sess.run(None, feeds)
        return out[li], [out[i] for i in pres_i]

    # dynamic reference
    past = [np.zeros((1, kv, 0, d), np.float32) for _ in io["past"]]
    ref = []
    lg, past = run(seq[:, :prompt_len], np.ones(prompt_len), np.arange(prompt_len), past)
    ref.append(lg[0, -1])
    for t in range(prompt_len, total):
        lg, past = run(seq[:, t:t + 1], np.ones(t + 1), np.array([t]), past)
        ref.append(lg[0, -1])
    # window path
    cache = [np.zeros((1, kv, window, d), np.float32) for _ in io["past"]]
    m = np.zeros(window, np.int64)
    chunk = np.zeros((1, prefill) + seq.shape[2:], seq.dtype)
    chunk[:, :prompt_len] = seq[:, :prompt_len]
    new_valid = (np.arange(prefill) < prompt_len).astype(np.int64)
    pos = np.where(new_valid == 1, np.arange(prefill), 0)
    got = []
    lg, pres = run(chunk, np.concatenate([m, new_valid]), pos, cache)
    got.append(lg[0, prompt_len - 1])
    cache, m = [p[:, :, prefill:, :] for p in pres], np.concatenate([m, new_valid])[prefill:]
    for t in range(prompt_len, total):
        if m[0]:
            return {"ok": False, "reason": "window full during the check"}
        lg, pres = run(seq[:, t:t + 1], np.concatenate([m, [1]]), np.array([int(m.sum())]), cache)
        got.append(lg[0, -1])
        cache, m = [p[:, :, 1:, :] for p in pres], np.concatenate([m, [1]])[1:]
    rel = max(float(np.abs(a - b).max() / max(np.abs(a).max(), 1e-12)) for a, b in zip(ref, got))
    finite = all(np.isfinite(g).all() for g in got)
    return {"ok": bool(finite and rel <= rel_tol), "max_rel": rel, "finite": finite, "steps": len(got),
            "window": window, "prefill": prefill, "tolerance_rel": rel_tol,
            "reference": "the same decoder with a growing (dynamic) cache, teacher-forced random inputs"}


def decoder_dyn_values(inputs: Sequence[dict[str, Any]], io: dict[str, Any], new: int = 2,
                       past: int = 3) -> dict[str, int]:
    """Consistent sizes for a dynamic decoder's symbolic axes (mask length = past + new) for parity runs."""
    vals = {}
    for i in inputs:
        for ax, name in (i.get("dynamic_axes") or {}).items():
            if i["name"] == io["mask"]:
                vals[name] = past + new
            elif i["name"] in io["past"]:
                vals[name] = past
            elif i["name"] in (io["new"], io["pos"]) and int(ax) == 1:
                vals[name] = new
    return vals


def kv_window_shapes(inputs: Sequence[dict[str, Any]], io: dict[str, Any], window: int, s: int) -> dict[str, list[int]]:
    """Static input shapes of the fixed-window decoder for s new positions."""
    shapes = {}
    for i in inputs:
        shp = [int(x) for x in i["shape"]]
        if i["name"] == io["new"]:
            shp[0], shp[1] = 1, s
        elif i["name"] == io["mask"]:
            shp = [1, window + s]
        elif i["name"] == io["pos"]:
            shp = [1, s]
        elif i["name"] in io["past"]:
            shp[0], shp[2] = 1, window
        elif any(v <= 0 for v in shp):
            raise ExportError(f"decoder input {i['name']}: unexpected dynamic shape {i['shape']}")
        shapes[i["name"]] = shp
    return shapes


# ----------------------------------------------------------------------------------------------------------------
# ORT conversion and the operator config

def convert_to_ort(onnx_files: Sequence[Path], out_dir: Path, *, styles: Sequence[str] = STYLES,
                   target_platform: str = "arm") -> tuple[dict[Path, dict[str, Path]], dict[str, Path], str]:
    """Convert .onnx files to .ort with onnxruntime's converter, once per optimisation style.

    The files are staged into one folder so the converter writes one operator config per style covering all
    of them. Returns ({onnx path: {style: .ort path}}, {style: config path}, the converter's log).
    """
    import onnxruntime as ort
    from onnxruntime.tools.convert_onnx_models_to_ort import OptimizationStyle, convert_onnx_models_to_ort

    ort.set_default_logger_severity(3)  # the converter's sessions otherwise print constant-folding warnings

    out_dir.mkdir(parents=True, exist_ok=True)
    log = io.StringIO()
    with tempfile.TemporaryDirectory(prefix="mosaic-ort-") as tmp:
        stage = Path(tmp) / "stage"
        stage.mkdir()
        names = {}
        for i, f in enumerate(onnx_files):
            name = f"m{i:03d}.onnx"
            shutil.copyfile(f, stage / name)
            names[name] = f
        conv_out = Path(tmp) / "out"
        with contextlib.redirect_stdout(log):
            try:
                convert_onnx_models_to_ort(stage, output_dir=conv_out,
                                           optimization_styles=[OptimizationStyle[s] for s in styles],
                                           target_platform=target_platform)
            except Exception as e:  # noqa: BLE001  the converter raises plain exceptions
                raise ExportError(f"ORT conversion failed: {type(e).__name__}: {str(e)[:500]}\n"
                                  f"converter log:\n{log.getvalue()[-2000:]}") from e
        result: dict[Path, dict[str, Path]] = {}
        for name, src in names.items():
            stem = Path(name).stem
            result[src] = {}
            for s in styles:
                suffix = ".with_runtime_opt.ort" if s == "Runtime" else ".ort"
                got = conv_out / f"{stem}{suffix}"
                if not got.is_file():
                    raise ExportError(f"ORT conversion of {src} ({s}) produced no file; log:\n{log.getvalue()[-1500:]}")
                dst = out_dir / f"{stem}{suffix}"
                shutil.copyfile(got, dst)
                result[src][s] = dst
        configs = {}
        for s in styles:
            cname = "required_operators.with_runtime_opt.config" if s == "Runtime" else "required_operators.config"
            if (conv_out / cname).is_file():
                configs[s] = out_dir / f"{s.lower()}.{cname}"
                shutil.copyfile(conv_out / cname, configs[s])
    return result, configs, log.getvalue()


def read_operator_config(path: str | Path) -> dict[tuple[str, int], set[str]]:
    """Parse a required_operators config (`domain;opset;Op1,Op2` lines, `#` comments)."""
    ops: dict[tuple[str, int], set[str]] = {}
    for line in Path(path).read_text().splitlines():
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        try:
            domain, opset, names = line.split(";", 2)
            key = (domain.strip(), int(opset))
        except ValueError as e:
            raise ExportError(f"{path}: malformed operator config line {line!r}") from e
        ops.setdefault(key, set()).update(n.strip().split("{")[0] for n in names.split(",") if n.strip())
    return ops


def write_operator_config(path: str | Path, ops: dict[tuple[str, int], set[str]], models: Sequence[str]) -> Path:
    """Write a merged config in the converter's format (one line per domain and opset)."""
    lines = ["# Required operators for a reduced-operator ONNX Runtime build (--include_ops_by_config).",
             "# Union of onnxruntime.tools.convert_onnx_models_to_ort configs (Fixed + Runtime styles) for:"]
    lines += [f"# - {m}" for m in models]
    for (domain, opset) in sorted(ops):
        lines.append(f"{domain};{opset};{','.join(sorted(ops[(domain, opset)]))}")
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    Path(path).write_text("\n".join(lines) + "\n")
    return Path(path)


def config_op_types(ops: dict[tuple[str, int], set[str]]) -> set[tuple[str, str]]:
    """{(domain, op type)} from a parsed config; domain '' is written as 'ai.onnx'."""
    return {(d, o) for (d, _), names in ops.items() for o in names}


def build_command(config_rel: str, *, android_abi: str = "arm64-v8a", api: int = 27,
                  with_nnapi: bool = True, with_xnnpack: bool = True, with_qnn: bool = False) -> str:
    """The onnxruntime build line for a reduced-operator Android build (run in an onnxruntime checkout with
    the Android SDK/NDK installed; not runnable on this machine)."""
    parts = ["./build.sh", "--config MinSizeRel", "--android", "--android_sdk_path $ANDROID_HOME",
             "--android_ndk_path $ANDROID_NDK_HOME", f"--android_abi {android_abi}", f"--android_api {api}",
             "--minimal_build extended", "--disable_ml_ops",
             f"--include_ops_by_config {config_rel}", "--build_shared_lib", "--build_java", "--skip_tests",
             "--parallel"]
    if with_nnapi:
        parts.append("--use_nnapi")
    if with_xnnpack:
        parts.append("--use_xnnpack")
    if with_qnn:
        parts.append("--use_qnn --qnn_home $QNN_SDK_ROOT")
    return " ".join(parts)


# ----------------------------------------------------------------------------------------------------------------
# Mobile usability (onnxruntime's checker)

def _partition_dict(info: Any) -> dict[str, Any]:
    pct = 100.0 * info.num_supported_nodes / max(info.num_nodes, 1)
    return {"partitions": int(info.num_partitions), "supported_nodes": int(info.num_supported_nodes),
            "nodes": int(info.num_nodes), "supported_pct": round(pct, 1),
            "partition_sizes": [len(g) for g in info.supported_groups],
            "unsupported_ops": sorted(info.unsupported_ops),
            "unsupported_due_to_dynamic_shape": int(info.nodes_unsupported_due_to_dynamic_input),
            "caveats": info.supported_ops_checker.get_caveats(),
            "suitability": info.suitability().name}


def usability_report(onnx_path: str | Path, text_out: str | Path, json_out: str | Path, *,
                     nnapi_max_partitions: int = 2) -> dict[str, Any]:
    """Run onnxruntime's mobile usability checker on a graph (as `python -m
    onnxruntime.tools.check_onnx_model_mobile_usability` does: basic-level optimisation first) and store its
    text report plus a JSON of the figures (NNAPI, CoreML NeuralNetwork, CoreML MLProgram partitions).

    Returns the JSON dict: {nnapi: {...}, coreml_neuralnetwork: {...}, coreml_mlprogram: {...},
    dynamic_inputs: [...], flags: [...], try_eps: bool, not_checked: str}.
    """
    from onnxruntime.tools.mobile_helpers import usability_checker as U
    from onnxruntime.tools.onnx_model_utils import ModelProtoWithShapeInfo, optimize_model

    buf = io.StringIO()
    logger = logging.getLogger(f"mosaic.usability.{Path(onnx_path).stem}")
    logger.handlers.clear()
    h = logging.StreamHandler(buf)
    h.setFormatter(logging.Formatter("%(levelname)s:  %(message)s"))
    logger.addHandler(h)
    logger.setLevel(logging.INFO)
    logger.propagate = False
    try_eps = bool(U.analyze_model(Path(onnx_path), skip_optimize=False, logger=logger))
    logger.removeHandler(h)
    Path(text_out).write_text(buf.getvalue())

    with tempfile.TemporaryDirectory(prefix="mosaic-usab-") as tmp:
        opt = Path(tmp) / Path(onnx_path).name
        optimize_model(Path(onnx_path), opt, use_external_initializers=True)
        model = ModelProtoWithShapeInfo(opt.resolve()).model_with_shape_info
        dyn_inputs, _ = U.check_shapes(model.graph)
        nnapi = _partition_dict(U.check_nnapi_partitions(model, require_fixed_input_sizes=True))
        cml_nn = _partition_dict(U.check_coreml_partitions(model, True, "coreml_supported_neuralnetwork_ops.md"))
        cml_mlp = _partition_dict(U.check_coreml_partitions(model, True, "coreml_supported_mlprogram_ops.md"))
    flags = []
    if nnapi["partitions"] > nnapi_max_partitions:
        flags.append(f"nnapi_many_partitions: {nnapi['partitions']} NNAPI partitions (> {nnapi_max_partitions}); "
                     f"device copies between partitions will likely make NNAPI slower than the CPU EP")
    if nnapi["partitions"] == 0:
        flags.append("nnapi_unusable: NNAPI can run no node of this graph")
    if dyn_inputs:
        flags.append("dynamic_inputs: " + ", ".join(i.name for i in dyn_inputs)
                     + " (NNAPI needs fixed shapes; the graph runs on CPU/XNNPACK)")
    rep = {"model": Path(onnx_path).name, "tool": "onnxruntime.tools.check_onnx_model_mobile_usability",
           "nnapi": nnapi, "coreml_neuralnetwork": cml_nn, "coreml_mlprogram": cml_mlp,
           "dynamic_inputs": [i.name for i in dyn_inputs], "flags": flags, "try_eps": try_eps,
           "not_checked": NOT_CHECKED}
    Path(json_out).write_text(json.dumps(rep, indent=2) + "\n")
    return rep


def recommended_providers(rep: dict[str, Any], precision: str, dynamic_left: bool,
                          conf: AndroidConfig) -> tuple[list[str], list[str]]:
    """Provider order to try on the phone for one component, with the reasons (the profile's chain
    QNN -> NNAPI -> XNNPACK -> CPU, pruned by what this component can use)."""
    why = []
    chain = []
    if dynamic_left:
        why.append("dynamic shapes left: CPU/XNNPACK only")
        return ["XNNPACK", "CPU"], why
    if precision == "int8-qdq":
        chain.append("QNN")
        why.append("QDQ int8: QNN HTP candidate (coverage not checked here)")
    else:
        why.append("QNN HTP takes QDQ models (float graphs only with enable_htp_fp16_precision): try int8-qdq")
    n = rep["nnapi"]
    if n["partitions"] == 0 or n["partitions"] > conf.nnapi_max_partitions:
        why.append(f"NNAPI skipped: {n['partitions']} partitions, {n['supported_pct']}% of nodes")
    else:
        chain.append("NNAPI")
    chain += ["XNNPACK", "CPU"]
    return chain, why


# ----------------------------------------------------------------------------------------------------------------
# The step

def derive_fp16(src: Path, dst: Path, make_inputs: Callable[[np.random.Generator], dict]) -> tuple[bool, Any]:
    """fp16 copy of a float graph (I/O kept fp32; Q/DQ nodes and onnxruntime's default block list stay fp32),
    kept only when its parity vs the fp32 graph passes (export/common.py PARITY_TOL["fp16"]).
    Returns (True, path) or (False, reason)."""
    from onnxruntime.transformers.float16 import DEFAULT_OP_BLOCK_LIST

    try:
        C.to_fp16(src, dst, op_block_list=list(DEFAULT_OP_BLOCK_LIST) + ["QuantizeLinear", "DequantizeLinear"])
        ref = C.ort_session(src)
        par = C.parity_check(dst, lambda f: C.ort_run(ref, f), make_inputs, precision="fp16", require=False,
                             label=f"{dst.name} vs fp32")
    except Exception as e:  # noqa: BLE001  a graph the converter cannot handle: keep fp32, say why
        return False, f"fp16 conversion failed: {type(e).__name__}: {str(e)[:200]}"
    if not par["ok"]:
        return False, (f"parity vs fp32 failed: rel {par['worst']['rel']:.3g} (tol {par['tolerance']['rel']}), "
                       f"cosine {par['worst']['cosine']:.4f}")
    return True, dst


def _has_qdq(path: Path) -> bool:
    """True when activations are quantised (QuantizeLinear / QLinear* nodes); weight-only DequantizeLinear
    (e.g. PyDNet's int8 weights) does not count: the compute is float and an fp16 copy can still help."""
    import onnx

    m = onnx.load(str(path), load_external_data=False)
    return any(n.op_type == "QuantizeLinear" or n.op_type.startswith("QLinear") for n in m.graph.node)


def _ref(root: Path, path: Path) -> dict[str, str]:
    return {"file": path.relative_to(root).as_posix(), "sha256": B.sha256_file(path)}


def export_android(bundle_dir: str | Path, conf: AndroidConfig | None = None,
                   log: Callable[[str], None] = C.progress) -> dict[str, Any]:
    """Write the Android artifacts for every role (or `conf.roles`) of the bundle and record them in its
    manifest. Returns a summary {roles: {role: {variant: {...}}}, required_operators, build_command,
    usability: [...]}. Raises ExportError when a .ort file fails parity with its source graph."""
    import onnxruntime as ort

    conf = conf or AndroidConfig()
    root = Path(bundle_dir)
    bundle = B.load_bundle(root, verify=True)
    roles = list(conf.roles or bundle.roles)
    for r in roles:
        bundle.role_meta(r)  # clear error for an unknown role
    all_ort: list[str] = []
    merged: dict[tuple[str, int], set[str]] = {}
    summary: dict[str, Any] = {"roles": {}, "usability": []}
    for role in roles:
        rmeta = bundle.role_meta(role)
        variants = rmeta["variants"]
        skipped: dict[str, str] = {}
        role_sum: dict[str, Any] = {}
        sources = [v for v in conf.precisions if v in variants]
        with tempfile.TemporaryDirectory(prefix=f"mosaic-android-{role}-") as tmpd:
            tmp = Path(tmpd)
            made: dict[str, dict[str, Path]] = {}  # variant -> {component: source onnx}
            for v in sources:
                made[v] = {c: B.safe_path(root, cm["file"]) for c, cm in variants[v]["components"].items()}
            fp32_srcs = made.get("fp32")
            already_q = fp32_srcs is not None and any(_has_qdq(p) for p in fp32_srcs.values())
            if "fp16" in conf.precisions and "fp16" not in made:
                if fp32_srcs is None:
                    skipped["fp16"] = "no fp32 variant to derive it from"
                elif already_q:
                    skipped["fp16"] = "graph is already int8-quantised (QDQ): an fp16 copy adds nothing"
                elif conf.make_fp16:
                    derived, reason = {}, None
                    for c, p in fp32_srcs.items():
                        fixed_tmp = _fixed_copy(p, variants["fp32"]["components"][c], rmeta, c, conf, tmp, "f32ref", role)
                        cm32 = variants["fp32"]["components"][c]
                        io = kv_io(cm32["inputs"], cm32["outputs"])
                        mk = random_feeds_factory(fixed_tmp, rmeta,
                                                  decoder_dyn_values(cm32["inputs"], io) if io else None)
                        ok, path_or_reason = derive_fp16(p, tmp / f"{c}.fp16.onnx", mk)
                        if not ok:
                            reason = f"{c}: {path_or_reason}"
                            break
                        derived[c] = path_or_reason
                    if reason:
                        skipped["fp16"] = f"derived fp16 not shipped: {reason}"
                    else:
                        made["fp16"] = derived
                        log(f"android {role}: fp16 derived from fp32 (graph-level conversion, parity ok)")
            if "int8-qdq" in conf.precisions and "int8-qdq" not in made:
                why_not = (rmeta.get("skipped_variants") or {}).get("int8-qdq")
                skipped["int8-qdq"] = ("fp32 graph is already int8 QDQ (see android-ort-fp32)" if already_q else
                                       f"the export did not ship int8-qdq: {why_not}" if why_not else
                                       "no int8-qdq variant in the bundle: run `mosaic export "
                                       f"{role} ... --precision int8 --calib FRAMES` first (QDQ needs calibration)")
            for v, comps in made.items():
                vname = VARIANT_PREFIX + v
                log(f"android {role}/{v}: fixing shapes, converting {len(comps)} component(s) to .ort")
                src_meta = variants.get(v, variants.get("fp32"))["components"]
                fixed: dict[str, Path] = {}
                comp_info: dict[str, dict[str, Any]] = {}
                for c, p in list(comps.items()):
                    shapes, left = fixed_shape_plan(src_meta[c]["inputs"], rmeta, c, conf, role)
                    fixed[c] = make_fixed(p, tmp / f"{v}.{c}.onnx", shapes) if shapes else _copy(p, tmp / f"{v}.{c}.onnx")
                    comp_info[c] = {"fixed_shapes": shapes, "dynamic_left": left}
                    if left and conf.kv_window > 0:
                        io = kv_io(src_meta[c]["inputs"], src_meta[c]["outputs"])
                        if io is not None:
                            chk = kv_window_check(p, src_meta[c]["inputs"], src_meta[c]["outputs"],
                                                  window=conf.kv_window, prefill=conf.prefill_len)
                            comp_info[c]["kv_window_check"] = chk
                            log(f"android {role}/{v}/{c}: fixed-window KV cache (W={conf.kv_window}) "
                                f"{'matches' if chk['ok'] else 'does NOT match'} the dynamic decoder "
                                f"({chk.get('max_rel', chk.get('reason'))})")
                            if chk["ok"]:
                                for tag, n_new in (("step", 1), ("prefill", conf.prefill_len)):
                                    name = f"{c}_kvwindow_{tag}"
                                    shp = kv_window_shapes(src_meta[c]["inputs"], io, conf.kv_window, n_new)
                                    fixed[name] = make_fixed(p, tmp / f"{v}.{name}.onnx", shp)
                                    comp_info[name] = {"fixed_shapes": shp, "dynamic_left": {},
                                                       "kv_window": {"window": conf.kv_window, "new_positions": n_new,
                                                                     "protocol": KV_WINDOW_PROTOCOL,
                                                                     "check": chk, "of_component": c}}
                out_dir = root / role / vname
                if out_dir.exists():
                    shutil.rmtree(out_dir)
                out_dir.mkdir(parents=True)
                conv, configs, _ = convert_to_ort(list(fixed.values()), tmp / f"ort-{v}",
                                                  styles=conf.styles, target_platform=conf.target_platform)
                v_ops: dict[tuple[str, int], set[str]] = {}
                for cfg in configs.values():
                    for k, ops in read_operator_config(cfg).items():
                        v_ops.setdefault(k, set()).update(ops)
                components, parity = {}, {}
                for c, fx in fixed.items():
                    info = comp_info[c]
                    dyn_left = bool(info["dynamic_left"])
                    paths = {}
                    for s, pth in conv[fx].items():
                        dst = out_dir / (f"{c}.with_runtime_opt.ort" if s == "Runtime" else f"{c}.ort")
                        shutil.copyfile(pth, dst)
                        paths[s] = dst
                    # parity: each .ort against its fixed-shape source graph (fresh random inputs; axes left
                    # dynamic, e.g. a KV cache, get small concrete sizes)
                    io = kv_io(src_meta[c]["inputs"], src_meta[c]["outputs"]) if c in src_meta else None
                    mk = random_feeds_factory(fx, rmeta, decoder_dyn_values(src_meta[c]["inputs"], io) if io else None)
                    rel_tol, cos_min = ORT_PARITY_TOL[v]
                    parity[c] = {s: ort_parity(pth, fx, mk, runtime_opt=(s == "Runtime"), trials=conf.parity_trials,
                                               rel_tol=rel_tol, cos_min=cos_min,
                                               label=f"{role}/{vname}/{pth.name} vs .onnx")
                                 for s, pth in paths.items()}
                    rep = usability_report(fx, out_dir / f"{c}.usability.txt", out_dir / f"{c}.usability.json",
                                           nnapi_max_partitions=conf.nnapi_max_partitions)
                    providers, why = recommended_providers(rep, v, dyn_left, conf)
                    if "kv_window_check" in info:
                        chk = info["kv_window_check"]
                        why.append(f"fixed-window KV variant {c}_kvwindow_step/_prefill for NPU providers"
                                   if chk["ok"] else f"no fixed-window KV variant: {chk.get('reason') or chk}")
                    main = paths.get("Fixed") or next(iter(paths.values()))
                    components[c] = {"file": main}
                    entry = {**info, "usability": _ref(root, out_dir / f"{c}.usability.json"),
                             "usability_text": _ref(root, out_dir / f"{c}.usability.txt"),
                             "nnapi": {k: rep["nnapi"][k] for k in ("partitions", "supported_pct", "suitability",
                                                                     "partition_sizes", "unsupported_ops")},
                             "coreml_mlprogram": {k: rep["coreml_mlprogram"][k] for k in
                                                  ("partitions", "supported_pct", "suitability")},
                             "flags": rep["flags"], "providers": providers, "provider_notes": why}
                    if "Runtime" in paths:
                        entry["runtime_opt"] = {**_ref(root, paths["Runtime"]),
                                                "session_config": {"session.enable_saved_runtime_optimizations": "1"},
                                                "use_for": ["NNAPI", "QNN"]}
                    info.update(entry)
                    summary["usability"].append({"role": role, "variant": vname, "component": c,
                                                 "nnapi_partitions": rep["nnapi"]["partitions"],
                                                 "nnapi_supported_pct": rep["nnapi"]["supported_pct"],
                                                 "nnapi_suitability": rep["nnapi"]["suitability"],
                                                 "coreml_mlprogram_partitions": rep["coreml_mlprogram"]["partitions"],
                                                 "flags": [f.split(":")[0] for f in rep["flags"]],
                                                 "providers": providers})
                # the .ort files are recorded directly (they already sit in out_dir)
                comps_meta = {c: {"file": d["file"].relative_to(root).as_posix(), "format": "ort"}
                              for c, d in components.items()}
                notes = (f"ONNX Runtime Mobile ({ort.__version__}) .ort of {v}; fixed shapes per component in "
                         f"android.components.*.fixed_shapes; use *.with_runtime_opt.ort with NNAPI/QNN")
                B.add_variant(root, role, vname, comps_meta, role_meta={}, precision=v, target="android",
                              parity=parity, notes=notes,
                              extra={"android": {"source_variant": v if v in variants else f"{v} (derived from fp32)",
                                                 "ort_styles": list(conf.styles),
                                                 "target_platform": conf.target_platform,
                                                 "required_operators": _ops_to_json(v_ops),
                                                 "components": comp_info}})
                role_sum[vname] = {"components": {c: {"fixed_shapes": comp_info[c]["fixed_shapes"],
                                                      "dynamic_left": comp_info[c]["dynamic_left"],
                                                      "nnapi_partitions": comp_info[c]["nnapi"]["partitions"],
                                                      "flags": comp_info[c]["flags"],
                                                      "providers": comp_info[c]["providers"],
                                                      "parity": _parity_brief(parity[c]),
                                                      **({"kv_window_check": comp_info[c]["kv_window_check"]}
                                                         if "kv_window_check" in comp_info[c] else {})}
                                                  for c in comp_info}}
        m = B.read_manifest(root)
        rm = m["roles"][role]
        rm["android"] = {"variants": sorted(role_sum), "skipped": skipped}
        B.write_manifest(root, m)
        summary["roles"][role] = {"variants": role_sum, "skipped": skipped}
    # one config for the whole bundle: every android variant recorded so far (also from earlier runs)
    m = B.read_manifest(root)
    for rname, rm in m["roles"].items():
        for vname, vm in rm["variants"].items():
            if vm.get("target") == "android":
                for k, ops in _ops_from_json((vm.get("android") or {}).get("required_operators", {})).items():
                    merged.setdefault(k, set()).update(ops)
                all_ort += [c["file"] for c in vm["components"].values()]
                all_ort += [c["runtime_opt"]["file"] for c in (vm.get("android") or {}).get("components", {}).values()
                            if "runtime_opt" in c]
    cfg_path = write_operator_config(root / OPS_CONFIG, merged, sorted(set(all_ort)))
    cmd = build_command("$BUNDLE/" + OPS_CONFIG)
    m["android"] = {"onnxruntime_version": ort.__version__, "required_operators": _ref(root, cfg_path),
                    "build_command": cmd, "usability_summary": summary["usability"],
                    "nnapi_max_partitions": conf.nnapi_max_partitions, "not_checked": NOT_CHECKED,
                    "phone_runs": PHONE_RUNS}
    B.write_manifest(root, m)
    summary.update({"required_operators": str(cfg_path), "build_command": cmd, "not_checked": NOT_CHECKED})
    return summary


def ort_session(path: str | Path, *, runtime_opt: bool = False, threads: int = 1, arm_like: bool = True,
                level: str = "all"):
    """CPU session for an .ort/.onnx file; runtime_opt=True replays the optimisations saved in a
    `*.with_runtime_opt.ort` file (without it that file runs un-fused: QDQ groups stay float-emulated).
    arm_like: the converter's settings for the arm target (no x86-only NCHWc layout transformer, int8 QDQ
    kernels allowed), so a source graph optimises here to the same graph as its .ort file."""
    import onnxruntime as ort

    so = ort.SessionOptions()
    so.intra_op_num_threads = threads
    so.inter_op_num_threads = 1
    so.log_severity_level = 3
    so.graph_optimization_level = {"basic": ort.GraphOptimizationLevel.ORT_ENABLE_BASIC,
                                   "all": ort.GraphOptimizationLevel.ORT_ENABLE_ALL}[level]
    if runtime_opt:
        so.add_session_config_entry("session.enable_saved_runtime_optimizations", "1")
    kw = {}
    if arm_like:
        so.add_session_config_entry("session.qdqisint8allowed", "1")
        kw["disabled_optimizers"] = ["NchwcTransformer"]
    return ort.InferenceSession(str(path), so, providers=["CPUExecutionProvider"], **kw)


def ort_parity(ort_path: str | Path, onnx_path: str | Path, make_inputs: Callable[[np.random.Generator], dict], *,
               runtime_opt: bool = False, trials: int = 2, rel_tol: float = 1e-4, cos_min: float = 0.99999,
               seed: int | None = None, label: str = "") -> dict[str, Any]:
    """Parity of a converted .ort file against the .onnx it came from (same precision) on fresh random inputs.

    The conversion only re-serialises and pre-optimises the graph, so the tolerance is tight (ORT_PARITY_TOL).
    Graphs that end in a top-K / NMS selection (XFeat keypoints, SSD boxes) can flip a few ranks under
    rounding-order differences: such an output still passes when >= 99 % of its elements agree within the
    tolerance and its cosine is >= 0.999, and the result says `selection_flips: true`.
    Returns the same fields as export/common.py `parity_check`; raises ExportError when it fails."""
    seed, _ = C.parity_rng(seed)
    got_s = ort_session(ort_path, runtime_opt=runtime_opt)
    # the .ort holds the source graph optimised at ALL level (Fixed style) or at BASIC level plus replayable
    # QDQ fusions (Runtime style): compare with the source optimised the same way
    levels = ["basic", "all"] if runtime_opt else ["all"]
    for level in levels:
        rng = np.random.default_rng(seed)
        ref_s = ort_session(onnx_path, level=level)
        per: list[list[dict]] = []
        close: list[float] = []
        for _ in range(trials):
            feeds = make_inputs(rng)
            ref, got = C.ort_run(ref_s, feeds), C.ort_run(got_s, feeds)
            per.append(C.compare_outputs(ref, got))
            for r, g in zip(ref, got):
                r64, g64 = np.asarray(r, np.float64), np.asarray(g, np.float64)
                tol = rel_tol * max(float(np.abs(r64).max()) if r64.size else 0.0, 1e-12) + 1e-6
                close.append(float((np.abs(r64 - g64) <= tol).mean()) if r64.size else 1.0)
        worst = {"rel": max(o["rel"] for t in per for o in t), "cosine": min(o["cosine"] for t in per for o in t),
                 "max_abs": max(o["max_abs"] for t in per for o in t), "close_frac": min(close)}
        strict = worst["rel"] <= rel_tol and worst["cosine"] >= cos_min
        if strict:
            break
    flips = not strict and worst["close_frac"] >= 0.99 and worst["cosine"] >= 0.999
    ok = strict or flips
    C.progress(f"parity {label or Path(ort_path).name}: rel={worst['rel']:.2e} cos={worst['cosine']:.6f} -> "
               f"{'ok' if ok else 'FAIL'}")
    if not ok:
        raise ExportError(f"{ort_path}: .ort output differs from its source graph {Path(onnx_path).name} "
                          f"(rel {worst['rel']:.3g} > {rel_tol} or cosine {worst['cosine']:.5f} < {cos_min}); "
                          f"the conversion is broken for this graph")
    return {"ok": True, "reference": f"source .onnx (same precision), optimised at {level.upper()} level",
            "trials": trials, "seed": seed,
            "inputs": "fresh random", "runtime_opt_replayed": runtime_opt, "selection_flips": flips,
            "tolerance": {"rel": rel_tol, "cosine_min": cos_min}, "worst": worst, "outputs": per[-1]}


def _ops_to_json(ops: dict[tuple[str, int], set[str]]) -> dict[str, list[str]]:
    return {f"{d};{v}": sorted(o) for (d, v), o in sorted(ops.items())}


def _ops_from_json(d: dict[str, list[str]]) -> dict[tuple[str, int], set[str]]:
    out = {}
    for k, ops in d.items():
        dom, ver = k.rsplit(";", 1)
        out[(dom, int(ver))] = set(ops)
    return out


def _parity_brief(par: dict[str, Any]) -> Any:
    return {s: {"ok": p["ok"], "rel": p["worst"]["rel"], "cosine": p["worst"]["cosine"]} for s, p in par.items()}


def _copy(src: Path, dst: Path) -> Path:
    shutil.copyfile(src, dst)
    return dst


def _fixed_copy(p: Path, cmeta: dict, rmeta: dict, c: str, conf: AndroidConfig, tmp: Path, tag: str,
                role: str) -> Path:
    """A copy with the fixable axes fixed (axes left dynamic get small sizes in random_feeds_factory)."""
    shapes, _ = fixed_shape_plan(cmeta["inputs"], rmeta, c, conf, role)
    dst = tmp / f"{tag}.{c}.onnx"
    return make_fixed(p, dst, shapes) if shapes else _copy(p, dst)


# ----------------------------------------------------------------------------------------------------------------
# CLI (hooked into `mosaic export --target android` by export/cli.py)

def add_arguments(parser: argparse.ArgumentParser) -> None:
    g = parser.add_argument_group("android target")
    g.add_argument("--android-precisions", default=",".join(SOURCE_PRECISIONS),
                   help="source variants to convert to .ort (default: fp32,fp16,int8-qdq)")
    g.add_argument("--android-roles", default=None, help="comma-separated roles (default: all in the bundle)")
    g.add_argument("--fix", action="append", default=[], metavar="DIM=VALUE",
                   help="fix a named dynamic axis (repeatable), e.g. --fix num_points=5")
    g.add_argument("--nnapi-max-partitions", type=int, default=2)
    g.add_argument("--no-derive-fp16", action="store_true", help="do not make fp16 from fp32 when missing")
    g.add_argument("--kv-window", type=int, default=256,
                   help="VLM decoder: KV-cache slots of the fixed-window variant (0 = none; default 256)")
    g.add_argument("--prefill-len", type=int, default=64,
                   help="VLM decoder: prompt positions per fixed-window prefill call (default 64)")


def config_from_args(args: argparse.Namespace) -> AndroidConfig:
    over = {}
    for item in getattr(args, "fix", []) or []:
        if "=" not in item:
            raise ExportError(f"--fix {item!r}: expected DIM=VALUE")
        k, v = item.split("=", 1)
        try:
            over[k.strip()] = int(v)
        except ValueError as e:
            raise ExportError(f"--fix {item!r}: VALUE must be an integer") from e
        if over[k.strip()] <= 0:
            raise ExportError(f"--fix {item!r}: VALUE must be > 0")
    precs = tuple(p.strip() for p in getattr(args, "android_precisions", ",".join(SOURCE_PRECISIONS)).split(",") if p.strip())
    bad = [p for p in precs if p not in SOURCE_PRECISIONS]
    if bad:
        raise ExportError(f"--android-precisions: unknown {bad} (use {', '.join(SOURCE_PRECISIONS)})")
    roles = getattr(args, "android_roles", None)
    kvw, pre = int(getattr(args, "kv_window", 256)), int(getattr(args, "prefill_len", 64))
    if kvw < 0 or pre < 1 or (kvw and pre >= kvw):
        raise ExportError(f"--kv-window {kvw} / --prefill-len {pre}: need 0 (off) or window > prefill >= 1")
    return AndroidConfig(precisions=precs, overrides=over, make_fp16=not getattr(args, "no_derive_fp16", False),
                         kv_window=kvw, prefill_len=pre,
                         nnapi_max_partitions=int(getattr(args, "nnapi_max_partitions", 2)),
                         roles=tuple(r.strip() for r in roles.split(",")) if roles else None)


def target_step(out: str | Path, roles: Sequence[str], args: argparse.Namespace) -> dict[str, Any]:
    """`mosaic export ROLE ... --target android` (export/cli.py TARGETS): the roles just exported."""
    conf = config_from_args(args)  # --android-roles when given, else the roles just exported
    conf = conf if conf.roles else replace(conf, roles=tuple(roles))
    res = export_android(out, conf)
    C.progress(render({"bundle": str(out), **res}))
    return res


def run(args: argparse.Namespace) -> dict[str, Any]:
    bundle = getattr(args, "out", None) or getattr(args, "bundle", None)
    if not bundle:
        raise ExportError("--target android needs the bundle folder (--out DIR or --bundle DIR)")
    res = export_android(bundle, config_from_args(args))
    return {"schema": "mosaicthinker.export.android/1", "bundle": str(bundle), **res}


def render(result: dict[str, Any]) -> str:
    lines = [f"android artifacts in {result['bundle']}"]
    for role, r in result["roles"].items():
        for v, vm in r["variants"].items():
            for c, cm in vm["components"].items():
                par = cm["parity"]
                ptxt = ", ".join(f"{s} rel={p['rel']:.1e}" for s, p in par.items())
                lines.append(f"  {role}/{v}/{c}: NNAPI partitions={cm['nnapi_partitions']} "
                             f"providers={'>'.join(cm['providers'])} parity[{ptxt}]"
                             + (f" FLAGS: {'; '.join(f.split(':')[0] for f in cm['flags'])}" if cm["flags"] else ""))
        for v, why in r["skipped"].items():
            lines.append(f"  {role}/{v}: skipped ({why})")
    lines.append(f"required operators: {result['required_operators']}")
    lines.append(f"reduced build: {result['build_command']}")
    lines.append(result["not_checked"])
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    """`python -m mosaicthinker.export.android BUNDLE`: the Android step alone on an existing bundle."""
    from mosaicthinker.export.common import target_step_main

    return target_step_main(sys.modules[__name__], argv)


if __name__ == "__main__":
    raise SystemExit(main())
