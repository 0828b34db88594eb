"""Precision handling of the Android step: which source graphs each precision converts, an fp16 copy derived
from fp32 when the bundle lacks one, and why a precision is skipped."""
from __future__ import annotations

from pathlib import Path
from typing import Any, Callable

import numpy as np

from mosaicthinker.host import bundle_write as B

from .. import common as C
from ..parity import ort_run, ort_session, parity_check
from .config import AndroidConfig
from .feeds import random_feeds_factory
from .kvwindow import decoder_dyn_values, kv_io
from .shapes import _fixed_copy


def derive_fp16(src: Path, dst: Path, make_inputs: Callable[[np.random.Generator], dict]) -> tuple[bool, Any]:
    """fp16 copy of a float graph (I/O kept fp32; Q/DQ nodes and onnxruntime's default block list stay fp32),
    kept only when its parity vs the fp32 graph passes (export/common.py PARITY_TOL["fp16"]).
    Returns (True, path) or (False, reason)."""
    from onnxruntime.transformers.float16 import DEFAULT_OP_BLOCK_LIST

    try:
        C.to_fp16(src, dst, op_block_list=list(DEFAULT_OP_BLOCK_LIST) + ["QuantizeLinear", "DequantizeLinear"])
        ref = ort_session(src)
        par = parity_check(dst, lambda f: ort_run(ref, f), make_inputs, precision="fp16", require=False,
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


def _derive_fp16_components(fp32_srcs: dict[str, Path], rmeta: dict[str, Any], role: str, conf: AndroidConfig,
                            tmp: Path) -> tuple[dict[str, Path], str | None]:
    """fp16 copies of every fp32 component ({component: path}, None) or ({}, the first refusal)."""
    variants = rmeta["variants"]
    derived: dict[str, Path] = {}
    for c, p in fp32_srcs.items():
        cm32 = variants["fp32"]["components"][c]
        fixed_tmp = _fixed_copy(p, cm32, rmeta, c, conf, tmp, "f32ref", role)
        io = kv_io(cm32["inputs"], cm32["outputs"])
        mk = random_feeds_factory(fixed_tmp, rmeta, decoder_dyn_values(cm32["inputs"], io) if io else None)
        ok, path_or_reason = derive_fp16(p, tmp / f"{c}.fp16.onnx", mk)
        if not ok:
            return {}, f"{c}: {path_or_reason}"
        derived[c] = path_or_reason
    return derived, None


def source_graphs(root: Path, rmeta: dict[str, Any], role: str, conf: AndroidConfig, tmp: Path,
                  log: Callable[[str], None]) -> tuple[dict[str, dict[str, Path]], dict[str, str]]:
    """The source graphs to convert per precision ({variant: {component: .onnx}}: the bundle's variants, plus
    fp16 derived from fp32 when the bundle lacks it and its parity allows) and why a precision is skipped."""
    variants = rmeta["variants"]
    skipped: dict[str, str] = {}
    made: dict[str, dict[str, Path]] = {}
    for v in (v for v in conf.precisions if v in variants):
        made[v] = {c: B.safe_path(root, cm["file"]) for c, cm in variants[v]["components"].items()}
    fp32_srcs = made.get("fp32")
    already_q = fp32_srcs is not None and any(_has_qdq(p) for p in fp32_srcs.values())
    if "fp16" in conf.precisions and "fp16" not in made:
        if fp32_srcs is None:
            skipped["fp16"] = "no fp32 variant to derive it from"
        elif already_q:
            skipped["fp16"] = "graph is already int8-quantised (QDQ): an fp16 copy adds nothing"
        elif conf.make_fp16:
            derived, reason = _derive_fp16_components(fp32_srcs, rmeta, role, conf, tmp)
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
    return made, skipped
