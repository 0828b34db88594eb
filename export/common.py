"""Shared export helpers: writing variants into a bundle, parity checks, fp16 and int8 conversion, calibration.

Every exporter (export/onnx_import.py, export/xfeat.py, export/hf_*.py) follows the same steps::

    meta = role_meta("pydnet", preprocessing=..., semantics={"depth": "relative"}, provenance=..., licence=...,
                     random_weights=False, config={...})
    fp32 = export_torch(wrapper, example_args, tmp / "model.onnx", ["image"], ["depth"], dynamic_shapes=None)
    par = parity_check(fp32, reference=lambda feeds: [wrapper(torch.from_numpy(feeds["image"])).numpy()],
                       make_inputs=lambda rng: {"image": rng.random((1, 3, 64, 64), np.float32)})
    add_variant_files(out, "depth", "fp32", {"model": fp32}, meta=meta, precision="fp32", parity={"model": par})
    q = quantize_variant(fp32, tmp / "int8.onnx", "int8-dynamic", make_inputs=...)   # parity vs fp32 ORT
    if q["ok"]: add_variant_files(out, "depth", "int8-dynamic", {"model": q["path"]}, ...)
    else: record q["reason"] (never ship a quantised component whose parity fails)

Parity always runs on FRESH random inputs (a new seed per call, recorded): exporters can bake example inputs
into constants, and a check on the example input would not see that. A failing parity check raises ExportError
(`require=True`, the default) so a broken export never lands in a bundle.
"""
from __future__ import annotations

import os
import re
import shutil
import sys
import time
from pathlib import Path
from typing import Any, Callable, Iterable, Sequence

import numpy as np

from mosaicthinker.runtime.host import bundle_write as B
from mosaicthinker.runtime.errors import ExportError

Feeds = dict[str, np.ndarray]
DEFAULT_OPSET = 18
# Parity tolerances by precision: (max relative error = max|a-b| / max|ref|, min cosine similarity).
PARITY_TOL = {
    "fp32": (1e-3, 0.99999),
    "fp16": (2e-2, 0.999),
    "int8-dynamic": (0.15, 0.98),
    "int8-qdq": (0.15, 0.98),
}
# Fresh random inputs per parity check, by precision. A quantised graph's error varies a lot from input to input
# (PyDNet++ int8-qdq: rel 0.02-0.97 over 40 inputs, 25% above tolerance), so two trials shipped it in about half
# the runs; the worst of 16 makes the ship/refuse decision the same run after run. fp32 is exact to ~1e-6.
PARITY_TRIALS = {"fp32": 4, "fp16": 16, "int8-dynamic": 16, "int8-qdq": 16}


def brief(text: str, limit: int = 300) -> str:
    """A long library message shortened at a space (never mid-word), marked with ' ...'."""
    text = " ".join(str(text).split())
    if len(text) <= limit:
        return text
    cut = text.rfind(" ", 0, limit)
    return text[:cut if cut > limit // 2 else limit] + " ..."


def progress(msg: str) -> None:
    """One progress line on stderr (long steps: export, quantisation, calibration, parity)."""
    from mosaicthinker.runtime.progress import write

    write(f"[export {time.strftime('%H:%M:%S')}] {msg}")


# ---------------------------------------------------------------------------------------------------------------
# Bundle writing

def role_meta(arch: str, *, preprocessing: dict[str, Any], semantics: dict[str, Any], provenance: dict[str, Any],
              licence: str, random_weights: bool, config: dict[str, Any] | None = None,
              **extra: Any) -> dict[str, Any]:
    """The role-level manifest fields (see runtime/bundle.py for their meaning).

    arch: key in runtime.stages.ARCHS (e.g. "pydnet", "xfeat", "owlv2", "sam", "smolvlm");
    preprocessing: {"size": [H, W], "layout": "NCHW"|"NHWC", "channel_order": "RGB", "dtype": "float32",
    "scale": 1/255, "mean": [...], "std": [...]} (omit what does not apply); semantics: depth
    {"depth": "metric_m"|"relative"|"relative_inverse"}, detector {"vocabulary": "open"} or
    {"vocabulary": "closed", "labels": [...]}, segmenter {"kind": "promptable"|"semantic", "labels": [...]},
    embedder {"dim": D}, matcher {"contract": "pair"|"extractor+matcher"}; provenance: {"source": "hf:ID@rev" ...};
    licence: SPDX id; random_weights: True for tiny random-config models.
    """
    if not arch:
        raise ExportError("role_meta: arch is required")
    if not licence:
        raise ExportError(f"role_meta({arch}): licence is required (SPDX id, e.g. Apache-2.0)")
    return {"arch": arch, "preprocessing": dict(preprocessing), "semantics": dict(semantics),
            "provenance": dict(provenance), "licence": licence, "random_weights": bool(random_weights),
            "config": dict(config or {}), **extra}


def add_variant_files(out: str | os.PathLike, role: str, variant: str, files: dict[str, str | os.PathLike], *,
                      meta: dict[str, Any], precision: str, target: str = "cpu", parity: dict | None = None,
                      notes: str | None = None, default: bool = False, move: bool = False,
                      component_meta: dict[str, dict[str, Any]] | None = None,
                      extra: dict[str, Any] | None = None) -> Path:
    """Copy (or move) graph files into `out/<role>/<variant>/<component><suffix>` and record the variant.

    files: {component name: path to a .onnx/.ort file}; every external-data file the graph references is
    copied too (same relative name) and listed with its sha256 in `extra_files`. meta: from `role_meta`. component_meta: extra
    per-component fields (e.g. {"pair": {"k": 1024}}). The bundle (and manifest.json) is created if needed.
    Returns the manifest path.
    """
    out = Path(out)
    dst_dir = out / role / variant
    dst_dir.mkdir(parents=True, exist_ok=True)
    comps: dict[str, dict[str, Any]] = {}
    for cname, src in files.items():
        src = Path(src)
        if not src.is_file():
            raise ExportError(f"{src}: component {role}/{variant}/{cname} file does not exist")
        dst = dst_dir / f"{cname}{src.suffix}"
        if src.resolve() != dst.resolve():
            (shutil.move if move else shutil.copyfile)(str(src), str(dst))
        c: dict[str, Any] = {"file": dst.relative_to(out).as_posix(), **(component_meta or {}).get(cname, {})}
        if src.suffix == ".onnx":  # external data keeps the name the graph refers to; add_variant lists it
            for loc in B.external_data_locations(src):
                if Path(loc).is_absolute() or ".." in Path(loc).parts:
                    raise ExportError(f"{src}: external data location {loc!r} leaves the graph's folder")
                ddst = dst.parent / loc
                if (src.parent / loc).resolve() != ddst.resolve():
                    ddst.parent.mkdir(parents=True, exist_ok=True)
                    (shutil.move if move else shutil.copyfile)(str(src.parent / loc), str(ddst))
        comps[cname] = c
    return B.add_variant(out, role, variant, comps, role_meta=meta, precision=precision, target=target,
                         parity=parity, notes=notes, default=default, extra=extra)


def record_skipped_variant(out: str | os.PathLike, role: str, variant: str, reason: str) -> None:
    """Note in the role's manifest entry that a variant was NOT shipped and why (e.g. int8 parity failed)."""
    manifest = B.read_manifest(out)
    rm = manifest["roles"].get(role)
    if rm is None:
        raise ExportError(f"{out}: role {role} must exist before recording a skipped variant")
    rm.setdefault("skipped_variants", {})[variant] = reason
    B.write_manifest(out, manifest)


# ---------------------------------------------------------------------------------------------------------------
# Running graphs and parity

def parity_rng(seed: int | None = None) -> tuple[int, np.random.Generator]:
    """The one seed policy of every parity check: a fresh seed drawn here (unless the caller fixes one for a
    reproduction), returned so the check records it in the manifest next to its result."""
    seed = int.from_bytes(os.urandom(4), "little") if seed is None else int(seed)
    return seed, np.random.default_rng(seed)


def parity_trials(precision: str, trials: int | None = None) -> int:
    """Number of fresh inputs a parity check of `precision` runs (PARITY_TRIALS unless given)."""
    return int(trials) if trials is not None else PARITY_TRIALS.get(precision, PARITY_TRIALS["int8-qdq"])


def ort_session(path: str | os.PathLike, threads: int = 1):
    """A plain CPU onnxruntime session for export-time checks (the runtime uses runtime/providers.py)."""
    import onnxruntime as ort

    so = ort.SessionOptions()
    so.intra_op_num_threads = threads
    so.inter_op_num_threads = 1
    so.log_severity_level = 3
    return ort.InferenceSession(str(path), so, providers=["CPUExecutionProvider"])


def ort_run(path_or_session: Any, feeds: Feeds) -> list[np.ndarray]:
    sess = ort_session(path_or_session) if isinstance(path_or_session, (str, Path)) else path_or_session
    names = {i.name for i in sess.get_inputs()}
    return sess.run(None, {k: v for k, v in feeds.items() if k in names})


def compare_outputs(ref: Sequence[np.ndarray], got: Sequence[np.ndarray]) -> list[dict[str, float]]:
    """Per output: max_abs, mean_abs, rel (max_abs / max|ref|), cosine similarity, exact-equality fraction."""
    if len(ref) != len(got):
        raise ExportError(f"parity: reference has {len(ref)} outputs, graph has {len(got)}")
    res = []
    for r, g in zip(ref, got):
        r = np.asarray(r)
        g = np.asarray(g)
        if r.shape != g.shape:
            raise ExportError(f"parity: output shape {g.shape} differs from reference {r.shape}")
        rf, gf = r.astype(np.float64).ravel(), g.astype(np.float64).ravel()
        d = np.abs(rf - gf)
        denom = max(float(np.abs(rf).max()) if rf.size else 0.0, 1e-12)
        nr, ng = np.linalg.norm(rf), np.linalg.norm(gf)
        cos = float(rf @ gf / (nr * ng)) if nr > 0 and ng > 0 else float(nr == ng)
        res.append({"max_abs": float(d.max()) if d.size else 0.0, "mean_abs": float(d.mean()) if d.size else 0.0,
                    "rel": float(d.max() / denom) if d.size else 0.0, "cosine": cos,
                    "equal_frac": float((rf == gf).mean()) if rf.size else 1.0})
    return res


def parity_check(onnx_path: str | os.PathLike, reference: Callable[[Feeds], Sequence[np.ndarray]],
                 make_inputs: Callable[[np.random.Generator], Feeds], *, precision: str = "fp32",
                 trials: int | None = None, rel_tol: float | None = None, cos_min: float | None = None,
                 outputs: Sequence[int] | None = None, seed: int | None = None, require: bool = True,
                 label: str = "") -> dict[str, Any]:
    """Run the ONNX graph and a reference on `trials` (default PARITY_TRIALS[precision]) fresh random inputs and
    compare.

    reference(feeds) -> list of output arrays in graph output order (e.g. the torch module, or the fp32 graph
    for a quantised one); make_inputs(rng) -> feeds; outputs: indices of outputs to compare (default all);
    tolerances default to PARITY_TOL[precision]. Returns {"ok", "precision", "trials", "seed", "worst":
    {rel, cosine, max_abs}, "outputs": [...]} and raises ExportError when not ok and require=True.
    """
    rel_tol = PARITY_TOL.get(precision, PARITY_TOL["fp32"])[0] if rel_tol is None else rel_tol
    cos_min = PARITY_TOL.get(precision, PARITY_TOL["fp32"])[1] if cos_min is None else cos_min
    seed, rng = parity_rng(seed)
    trials = parity_trials(precision, trials)
    sess = ort_session(onnx_path)
    per_out: list[list[dict]] = []
    for _ in range(trials):
        feeds = make_inputs(rng)
        got = ort_run(sess, feeds)
        ref = list(reference(feeds))
        if outputs is not None:
            got = [got[i] for i in outputs]
            ref = [ref[i] for i in outputs]
        per_out.append(compare_outputs(ref, got))
    worst = {"rel": max(o["rel"] for t in per_out for o in t),
             "cosine": min(o["cosine"] for t in per_out for o in t),
             "max_abs": max(o["max_abs"] for t in per_out for o in t)}
    ok = worst["rel"] <= rel_tol and worst["cosine"] >= cos_min
    res = {"ok": bool(ok), "precision": precision, "trials": trials, "seed": seed, "inputs": "fresh random",
           "tolerance": {"rel": rel_tol, "cosine_min": cos_min}, "worst": worst, "outputs": per_out[-1]}
    progress(f"parity {label or Path(onnx_path).name} [{precision}]: rel={worst['rel']:.2e} "
             f"cos={worst['cosine']:.6f} -> {'ok' if ok else 'FAIL'}")
    if require and not ok:
        raise ExportError(f"parity check failed for {onnx_path} ({precision}): worst relative error "
                          f"{worst['rel']:.3g} (tol {rel_tol}), cosine {worst['cosine']:.5f} (min {cos_min}); "
                          f"the artifact was not added to the bundle")
    return res


# ---------------------------------------------------------------------------------------------------------------
# Torch export (imported lazily: only exporters need torch)

def export_torch(module: Any, args: tuple, path: str | os.PathLike, input_names: list[str],
                 output_names: list[str], *, dynamic_shapes: Any = None, opset: int = DEFAULT_OPSET,
                 external_data: bool = False) -> Path:
    """`torch.onnx.export(dynamo=True)` of a thin wrapper with plain-tensor I/O into ONE self-contained file
    (external_data=True: weights in `<file>.data` beside it, needed past protobuf's 2 GB limit).

    dynamic_shapes: as torch.export expects (e.g. {"image": {2: torch.export.Dim("h"), ...}}), or None for
    fixed shapes. Raises ExportError with the exporter's message on failure.
    """
    import torch

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    progress(f"torch.onnx.export(dynamo=True, opset {opset}) -> {path.name}")
    module.eval()
    try:
        with torch.no_grad():
            prog = torch.onnx.export(module, args, dynamo=True, opset_version=opset, input_names=input_names,
                                     output_names=output_names, dynamic_shapes=dynamic_shapes,
                                     external_data=external_data, verbose=False)
            prog.save(str(path), external_data=external_data)
    except Exception as e:  # noqa: BLE001  (torch raises many types)
        raise ExportError(f"torch.onnx.export failed for {path.name}: {type(e).__name__}: {str(e)[:800]}") from e
    return path


# ---------------------------------------------------------------------------------------------------------------
# Precision conversion

def to_fp16(src: str | os.PathLike, dst: str | os.PathLike, *, keep_io_types: bool = True,
            op_block_list: Sequence[str] | None = None) -> Path:
    """fp16 copy of an ONNX graph (weights + compute); I/O stays fp32 when keep_io_types (the runtime feeds
    fp32). For torch exports prefer a `.half()` copy of the module; this is for imported graphs."""
    import onnx
    from onnxruntime.transformers.float16 import convert_float_to_float16

    model = onnx.load(str(src))
    kw = {"keep_io_types": keep_io_types}
    if op_block_list is not None:
        kw["op_block_list"] = list(op_block_list)
    m16 = convert_float_to_float16(model, **kw)
    onnx.save(m16, str(dst))
    return Path(dst)


def quantize_int8_dynamic(src: str | os.PathLike, dst: str | os.PathLike, *, per_channel: bool = False,
                          op_types: Sequence[str] | None = None) -> Path:
    """Dynamic int8 (weights int8, activations quantised at run time): the CPU variant."""
    from onnxruntime.quantization import QuantType, quantize_dynamic

    progress(f"quantize_dynamic int8 -> {Path(dst).name}")
    quantize_dynamic(str(src), str(dst), weight_type=QuantType.QInt8, per_channel=per_channel,
                     op_types_to_quantize=list(op_types) if op_types else None)
    return Path(dst)


class FeedsReader:
    """onnxruntime CalibrationDataReader over a list of feeds dicts."""

    def __init__(self, feeds: Iterable[Feeds]):
        self._feeds = list(feeds)
        self._it = iter(self._feeds)

    def get_next(self) -> Feeds | None:
        return next(self._it, None)

    def rewind(self) -> None:
        self._it = iter(self._feeds)


def calibration_frames(folder: str | os.PathLike, n: int = 16, pattern: str = "*.color.jpg") -> list[np.ndarray]:
    """Up to n RGB frames [H, W, 3] uint8 evenly spaced over the sorted images in `folder` (for QDQ calibration).

    pattern falls back to *.jpg / *.png when it matches nothing. A video file is read with OpenCV.
    """
    import cv2

    folder = Path(folder)
    if folder.is_file():
        cap = cv2.VideoCapture(str(folder))
        total = int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) or 0
        idx = set(np.linspace(0, max(total - 1, 0), n).astype(int).tolist())
        frames, i = [], 0
        while True:
            ok, bgr = cap.read()
            if not ok:
                break
            if i in idx:
                frames.append(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB))
            i += 1
        if not frames:
            raise ExportError(f"{folder}: no frames could be read for calibration")
        return frames
    files = sorted(folder.glob(pattern)) or sorted(folder.glob("*.jpg")) or sorted(folder.glob("*.png"))
    if not files:
        raise ExportError(f"{folder}: no calibration images ({pattern}, *.jpg, *.png)")
    pick = [files[i] for i in np.unique(np.linspace(0, len(files) - 1, min(n, len(files))).astype(int))]
    return [cv2.cvtColor(cv2.imread(str(f), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB) for f in pick]


def quantize_int8_qdq(src: str | os.PathLike, dst: str | os.PathLike, calibration: Iterable[Feeds], *,
                      per_channel: bool = True, op_types: Sequence[str] | None = None,
                      method: str = "minmax") -> Path:
    """Static QDQ int8 (QuantizeLinear/DequantizeLinear pairs, uint8 activations, int8 weights) calibrated on
    `calibration` feeds: the variant NNAPI, QNN and TensorRT take."""
    from onnxruntime.quantization import CalibrationMethod, QuantFormat, QuantType, quantize_static
    from onnxruntime.quantization.shape_inference import quant_pre_process

    feeds = list(calibration)
    if not feeds:
        raise ExportError("quantize_int8_qdq: no calibration inputs")
    progress(f"quantize_static QDQ int8 ({len(feeds)} calibration inputs) -> {Path(dst).name}")
    pre = Path(dst).with_name(Path(dst).stem + ".pre.onnx")
    try:
        quant_pre_process(str(src), str(pre), skip_symbolic_shape=True)
        model_in = pre
    except Exception:  # noqa: BLE001  pre-processing is an optimisation only
        model_in = Path(src)
    cm = {"minmax": CalibrationMethod.MinMax, "entropy": CalibrationMethod.Entropy,
          "percentile": CalibrationMethod.Percentile}[method]
    quantize_static(str(model_in), str(dst), FeedsReader(feeds), quant_format=QuantFormat.QDQ,
                    activation_type=QuantType.QUInt8, weight_type=QuantType.QInt8, per_channel=per_channel,
                    op_types_to_quantize=list(op_types) if op_types else None, calibrate_method=cm)
    if pre.exists():
        pre.unlink()
    return Path(dst)


def quantize_variant(fp32: str | os.PathLike, dst: str | os.PathLike, variant: str, *,
                     make_inputs: Callable[[np.random.Generator], Feeds], calibration: Iterable[Feeds] = (),
                     outputs: Sequence[int] | None = None, rel_tol: float | None = None,
                     cos_min: float | None = None, op_types: Sequence[str] | None = None,
                     task_check: Callable[[Path], dict[str, Any]] | None = None) -> dict[str, Any]:
    """Make an fp16 / int8-dynamic / int8-qdq copy of an fp32 graph and check its parity against the fp32 graph
    (fresh random inputs, plus `task_check(path)` -> {"ok": bool, ...} when given).

    Returns {"ok", "path", "parity", "task", "reason"}; when not ok the file is deleted and `reason` says why
    (the caller keeps the higher precision and records the choice with `record_skipped_variant`).
    """
    dst = Path(dst)
    try:
        if variant == "fp16":
            to_fp16(fp32, dst)
        elif variant == "int8-dynamic":
            quantize_int8_dynamic(fp32, dst, op_types=op_types)
        elif variant == "int8-qdq":
            quantize_int8_qdq(fp32, dst, calibration, op_types=op_types)
        else:
            raise ExportError(f"quantize_variant: unknown variant {variant!r}")
    except ExportError:
        raise
    except Exception as e:  # noqa: BLE001
        return {"ok": False, "path": None, "parity": None, "task": None,
                "reason": f"{variant} conversion failed: {type(e).__name__}: {brief(e)}"}
    try:  # a converted graph onnxruntime cannot even load is refused, not a crash
        ort_session(dst)
    except Exception as e:  # noqa: BLE001
        dst.unlink(missing_ok=True)
        return {"ok": False, "path": None, "parity": None, "task": None,
                "reason": f"{variant} conversion gave a graph onnxruntime cannot load: {brief(e)}"}
    ref = ort_session(fp32)
    par = parity_check(dst, lambda feeds: ort_run(ref, feeds), make_inputs, precision=variant, outputs=outputs,
                       rel_tol=rel_tol, cos_min=cos_min, require=False, label=f"{dst.name} vs fp32")
    task = task_check(dst) if (task_check is not None and par["ok"]) else None
    ok = par["ok"] and (task is None or bool(task.get("ok")))
    reason = None
    if not par["ok"]:
        reason = (f"parity vs fp32 failed: rel {par['worst']['rel']:.3g} (tol {par['tolerance']['rel']}), "
                  f"cosine {par['worst']['cosine']:.4f} (min {par['tolerance']['cosine_min']}), worst of "
                  f"{par['trials']} fresh inputs, seed {par['seed']}")
    elif task is not None and not task.get("ok"):
        reason = f"task check failed: {task}"
    if not ok and dst.exists():
        dst.unlink()
    return {"ok": ok, "path": dst if ok else None, "parity": par, "task": task, "reason": reason}


def parse_precisions(text: str) -> list[str]:
    """'fp32,fp16,int8' -> ['fp32', 'fp16', 'int8-dynamic', 'int8-qdq'] ('int8' means both int8 variants)."""
    out: list[str] = []
    for p in (t.strip() for t in text.split(",") if t.strip()):
        names = {"int8": ["int8-dynamic", "int8-qdq"], "int8-dynamic": ["int8-dynamic"],
                 "int8-qdq": ["int8-qdq"], "qdq": ["int8-qdq"], "fp32": ["fp32"], "fp16": ["fp16"],
                 "int4": ["int4"]}.get(p)
        if names is None:
            raise ExportError(f"--precision: unknown precision {p!r} (use fp32, fp16, int8, int8-dynamic, int8-qdq; "
                              f"int4 for GenAI VLM decoders)")
        out += [n for n in names if n not in out]
    if "fp32" not in out:
        out.insert(0, "fp32")  # the reference every other precision is checked against
    return out


def target_step_main(module: Any, argv: Sequence[str] | None = None) -> int:
    """`python -m mosaicthinker.export.<target> BUNDLE`: run one deployment-target step (a module with
    add_arguments/run/render) alone on an existing bundle."""
    import argparse
    import json

    from mosaicthinker.runtime.errors import MosaicError

    p = argparse.ArgumentParser(prog=f"python -m {module.__name__}", description=(module.__doc__ or "").split("\n")[0])
    p.add_argument("bundle", metavar="BUNDLE")
    p.add_argument("--json", action="store_true")
    module.add_arguments(p)
    args = p.parse_args(argv)
    args.out = args.bundle
    try:
        res = module.run(args)
    except MosaicError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(json.dumps(res, default=str) if args.json else module.render(res))
    return 0


# ---------------------------------------------------------------------------------------------------------------
# Dynamic axes: what a named axis means (shared by the Android fixed-shape step and the Jetson profile step)

_AXIS_RULES = (  # checked in this order; the first match wins
    ("past", re.compile(r"past|cache|kv", re.I)),
    ("total", re.compile(r"total|mask_len", re.I)),
    ("keypoints", re.compile(r"keypoint|kpt|num_kp|top_?k", re.I)),
    ("prompts", re.compile(r"prompt|box|object", re.I)),
    ("queries", re.compile(r"quer|names?$|labels?$", re.I)),
    ("points", re.compile(r"point", re.I)),
)
_TEXT_AXIS = re.compile(r"seq|token|text|length|len$", re.I)
_BATCH_AXIS = re.compile(r"batch|^(b|n|bs)$", re.I)


def image_axes(inp: dict[str, Any], pp: dict[str, Any]) -> dict[int, int]:
    """Spatial axes of a 4-D image input -> sizes from the role's preprocessing (layout NCHW or NHWC)."""
    size = pp.get("size")
    shape = inp.get("shape") or []
    if not size or len(shape) != 4 or inp.get("dtype") not in ("float32", "float16", "uint8"):
        return {}
    h, w = int(size[0]), int(size[1])
    layout = pp.get("layout")
    if layout is None:  # guess from the channel axis
        layout = "NHWC" if shape[3] == 3 else "NCHW"
    if shape[3 if layout == "NHWC" else 1] not in (1, 3):  # not an image (e.g. a KV cache [1, heads, T, d])
        return {}
    return {1: h, 2: w} if layout == "NHWC" else {2: h, 3: w}


def axis_kind(name: str, inp: dict[str, Any], ax: int, role_meta: dict[str, Any]) -> str | None:
    """Kind of dynamic axis `ax` (symbolic `name`) of manifest input `inp`: "images" (a count of images on axis
    0), "batch", "image" (a spatial axis fixed by the preprocessing size), "past" (KV-cache length), "total"
    (past + new tokens), "keypoints" (fixed by the role's top_k), "prompts", "queries", "points", "text"
    (sequence/token axes), or None when no rule applies (the caller asks for an explicit value)."""
    iname = inp["name"]
    cfg = role_meta.get("config") or {}
    if ax == 0 and re.fullmatch(r"(num_)?images?", name, re.I):
        return "images"
    if ax == 0 and (_BATCH_AXIS.search(name) or name in ("d0", "0")):
        return "batch"
    for kind, rx in _AXIS_RULES[:2]:  # KV-cache axes first: a [1, heads, past, d] cache looks like an image
        if rx.search(name) or (kind == "past" and rx.search(iname)):
            return kind
    if ax in image_axes(inp, role_meta.get("preprocessing") or {}):
        return "image"
    for kind, rx in _AXIS_RULES[2:]:
        if kind == "keypoints" and not (cfg.get("top_k") or cfg.get("max_keypoints")):
            continue
        if rx.search(name) or (kind == "points" and rx.search(iname)):
            return kind
    if "input_ids" in iname or "position" in iname or _TEXT_AXIS.search(name) or _TEXT_AXIS.search(iname):
        return "text"
    return None
