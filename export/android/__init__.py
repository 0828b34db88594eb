"""`mosaic export --target android`: ONNX Runtime Mobile artifacts for every role of a bundle.

Parts: config.py (AndroidConfig, flags), shapes.py (fixed shapes), feeds.py (random inputs), kvwindow.py
(fixed-window VLM decoder), precision.py (source graphs, derived fp16), convert.py (.ort conversion, operator
config, build line), usability.py (NNAPI/CoreML report, providers), step.py (the step that runs them);
parity in export/parity.py (`ort_parity`, ORT_PARITY_TOL).

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
   its source .onnx on fresh random inputs (export/parity.py `ort_parity`, ORT_PARITY_TOL), and a derived fp16 copy against
   fp32 (export/parity.py `parity_check`, PARITY_TOL["fp16"]).
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

Manifest fields written (all under the RESERVED `android` keys of runtime/infra/bundle.py)::

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

from ..parity import ORT_PARITY_TOL, ort_parity, ort_session  # noqa: F401
from .config import (NOT_CHECKED, OPS_CONFIG, PHONE_RUNS, SOURCE_PRECISIONS, STYLES,  # noqa: F401
                     VARIANT_PREFIX, AndroidConfig, add_arguments, config_from_args)
from .convert import (build_command, config_op_types, convert_to_ort, read_operator_config,  # noqa: F401
                      write_operator_config)
from .feeds import random_feeds_factory  # noqa: F401
from .kvwindow import (KV_WINDOW_PROTOCOL, decoder_dyn_values, kv_io, kv_window_check,  # noqa: F401
                       kv_window_shapes)
from .precision import derive_fp16, source_graphs  # noqa: F401
from .shapes import fixed_shape_plan, make_fixed  # noqa: F401
from .step import export_android, export_role, export_variant, render, target_step  # noqa: F401
from .usability import recommended_providers, usability_report  # noqa: F401
