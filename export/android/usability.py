"""Mobile usability (onnxruntime's checker: NNAPI and CoreML partitions) and the provider order per component."""
from __future__ import annotations

import io
import logging
import tempfile
from pathlib import Path
from typing import Any

from mosaicthinker.runtime.infra import jsonio

from .config import NOT_CHECKED, AndroidConfig


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
    Path(json_out).write_text(jsonio.dumps(rep, indent=2) + "\n")
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
