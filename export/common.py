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

Parity checks (fresh random inputs, one seed policy, one trial loop) live in export/parity.py.
"""
from __future__ import annotations

import os
import re
import shutil
from dataclasses import replace
from pathlib import Path
from typing import Any, Callable, Iterable, Sequence

import numpy as np

from mosaicthinker.host import bundle_write as B
from mosaicthinker.runtime.infra.errors import ExportError

from .log import brief, progress  # noqa: F401  (re-exported: every exporter logs through common)
# the parity checks live in export/parity.py; re-exported for the exporters that call `C.parity_check`
from .parity import (PARITY_TOL, PARITY_TRIALS, compare_outputs, ort_run, ort_session,  # noqa: F401
                     parity_check, parity_rng, parity_trials)

Feeds = dict[str, np.ndarray]
DEFAULT_OPSET = 18


# ---------------------------------------------------------------------------------------------------------------
# Bundle writing

def role_meta(arch: str, *, preprocessing: dict[str, Any], semantics: dict[str, Any], provenance: dict[str, Any],
              licence: str, random_weights: bool, config: dict[str, Any] | None = None,
              **extra: Any) -> dict[str, Any]:
    """The role-level manifest fields (see runtime/infra/bundle.py for their meaning).

    arch: key in runtime.models.ARCHS (e.g. "pydnet", "xfeat", "owlv2", "sam", "smolvlm");
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
                      extra: dict[str, Any] | None = None, alternative: bool = False) -> Path:
    """Copy (or move) graph files into `out/<role>/<variant>/<component><suffix>` and record the variant.

    files: {component name: path to a .onnx/.ort file}; every external-data file the graph references is
    copied too (same relative name) and listed with its sha256 in `extra_files`. meta: from `role_meta`. component_meta: extra
    per-component fields (e.g. {"pair": {"k": 1024}}). The bundle (and manifest.json) is created if needed.
    alternative: another model for the existing role (`meta` becomes the variant's `overrides`).
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
                         parity=parity, notes=notes, default=default, extra=extra, alternative=alternative)


def record_skipped_variant(out: str | os.PathLike, role: str, variant: str, reason: str) -> None:
    """Note in the role's manifest entry that a variant was NOT shipped and why (e.g. int8 parity failed)."""
    manifest = B.read_manifest(out)
    rm = manifest["roles"].get(role)
    if rm is None:
        raise ExportError(f"{out}: role {role} must exist before recording a skipped variant")
    rm.setdefault("skipped_variants", {})[variant] = reason
    B.write_manifest(out, manifest)


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


# Dynamic int8 weights in 7 bits (onnxruntime's `reduce_range`): its u8s8 kernels add pairs of uint8 x int8
# products in int16, which saturates on x86 CPUs without VNNI; with |w| <= 64 (2 x 255 x 64 < 2^15) one file gives
# the same numbers on every x86 CPU, for one bit less of weight precision (docs/bundle-and-adapters.md)
INT8_REDUCE_RANGE = True


def quantize_int8_dynamic(src: str | os.PathLike, dst: str | os.PathLike, *, per_channel: bool = False,
                          op_types: Sequence[str] | None = None) -> Path:
    """Dynamic int8 (weights int8 in 7 bits, `INT8_REDUCE_RANGE`; activations quantised at run time): the CPU
    variant."""
    from onnxruntime.quantization import QuantType, quantize_dynamic

    ext = bool(B.external_data_locations(src))  # a source past protobuf's 2 GiB: its int8 copy may be too
    progress(f"quantize_dynamic int8 -> {Path(dst).name}" + (" (external data)" if ext else ""))
    quantize_dynamic(str(src), str(dst), weight_type=QuantType.QInt8, per_channel=per_channel,
                     op_types_to_quantize=list(op_types) if op_types else None, use_external_data_format=ext,
                     reduce_range=INT8_REDUCE_RANGE)
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
    src = _at_least_opset(Path(src), 13, Path(dst).with_name(Path(dst).stem + ".op13.onnx"))
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
    for tmp in (pre, Path(dst).with_name(Path(dst).stem + ".op13.onnx")):
        tmp.unlink(missing_ok=True)
    return Path(dst)


def _at_least_opset(src: Path, opset: int, tmp: Path) -> Path:
    """`src`, or a copy converted to `opset` when its default-domain opset is lower (per-channel QDQ needs the
    `axis` of opset-13 DequantizeLinear; an opset-11 graph otherwise quantises into a graph that cannot load)."""
    import onnx
    from onnx import version_converter

    if B.external_data_locations(src):
        return src
    m = onnx.load(str(src))
    have = next((o.version for o in m.opset_import if o.domain in ("", "ai.onnx")), opset)
    if have >= opset:
        return src
    onnx.save(version_converter.convert_version(m, opset), str(tmp))
    return tmp


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


def run_target_step(export: Callable[[Path, Any], dict[str, Any]], conf: Any, out: str | os.PathLike,
                    roles: Sequence[str], render: Callable[[dict[str, Any]], str]) -> dict[str, Any]:
    """A deployment-target step (android, jetson) on `roles` unless its config names roles; prints its table."""
    conf = conf if conf.roles else replace(conf, roles=tuple(roles))
    res = export(Path(out), conf)
    progress(render({"bundle": str(out), **res}))
    return res


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
