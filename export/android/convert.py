"""`.ort` conversion with onnxruntime's converter, the operator configs and the reduced-build command line."""
from __future__ import annotations

import contextlib
import io
import shutil
import tempfile
from pathlib import Path
from typing import Sequence

from mosaicthinker.runtime.infra.errors import ExportError

from .config import STYLES


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


def _ops_to_json(ops: dict[tuple[str, int], set[str]]) -> dict[str, list[str]]:
    return {f"{d};{v}": sorted(o) for (d, v), o in sorted(ops.items())}


def _ops_from_json(d: dict[str, list[str]]) -> dict[tuple[str, int], set[str]]:
    out = {}
    for k, ops in d.items():
        dom, ver = k.rsplit(";", 1)
        out[(dom, int(ver))] = set(ops)
    return out
