"""`mosaic export --target jetson`: TensorRT settings for every role of a bundle (Jetson Orin, JetPack 6).

Nothing is converted here: TensorRT cannot be installed on the export machine, and an engine is specific to the
GPU, TensorRT version and JetPack it is built on. Instead, per role, variant (fp32, fp16, int8-qdq) and
component this step writes into the manifest (RESERVED `jetson` fields of runtime/infra/bundle.py):

- the onnxruntime **TensorRT execution provider options**: engine cache + timing cache under the container's
  cache folder, EP-context model dump (`trt_dump_ep_context_model`: the first run on the Jetson builds the
  engine and writes `<component>_ctx.onnx` pointing at it; later sessions load that and skip the build),
  `trt_fp16_enable` for fp16, `trt_int8_enable` for the QDQ variant (explicit quantisation from the Q/DQ nodes;
  no calibration table: TensorRT's implicit calibration is deprecated since TensorRT 10),
  and the **optimisation-profile shapes** (`trt_profile_min_shapes` / `opt` / `max`) for every dynamic axis of
  the manifest's inputs;
- the provider chain TensorRT -> CUDA -> CPU (the Jetson profiles' `providers`), as `[name, options]` pairs that
  `runtime/infra/providers.py create_session(preference=...)` takes as is;
- the equivalent **`trtexec`** command line (build a standalone engine, same shapes and precision), collected
  into `jetson/build_engines.sh` in the bundle.

Axis ranges (min/opt/max) come from rules on the axis name and the role's manifest entry: batch -> 1..max_batch,
image axes -> the preprocessing size (fixed), text tokens -> text_range, prompt points -> points_range, KV-cache
past length -> past_range, decoder new tokens -> seq_range, keypoints -> the role's top-K (fixed). An axis no rule
covers is an ExportError naming it (`--axis NAME=MIN:OPT:MAX` sets it) rather than a guess: TensorRT requires
a profile for every dynamic input once any is given.
"""
from __future__ import annotations

import argparse
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

from mosaicthinker.host import bundle_write as B
from mosaicthinker.runtime.infra.errors import ExportError

from . import common as C
from .formats import target_format

SOURCE_PRECISIONS = target_format("jetson").precisions
SCRIPT = "jetson/build_engines.sh"
NOT_RUN = ("TensorRT is not installed on the export machine: no engine was built and no TensorRT run was made "
           "here. The provider options, profile shapes and trtexec lines are generated and checked for form "
           "only; the engines are built on the Jetson on first run (or with jetson/build_engines.sh).")



@dataclass
class JetsonConfig:
    """Options of the Jetson step. Ranges are (min, opt, max)."""

    precisions: tuple[str, ...] = SOURCE_PRECISIONS
    cache_dir: str = "/cache/trt"            # inside the container (jetson/run.sh mounts a host folder there)
    bundle_dir: str = "/bundle"              # where jetson/run.sh mounts the bundle
    workspace_mb: int = 2048
    max_batch: int = 1
    text_range: tuple[int, int, int] = (1, 16, 32)
    prompts_range: tuple[int, int, int] = (1, 4, 64)
    points_range: tuple[int, int, int] = (1, 2, 16)
    queries_range: tuple[int, int, int] = (1, 4, 32)      # open-vocabulary detector: names per text call
    past_range: tuple[int, int, int] = (0, 128, 2048)  # 0: the prefill call has an empty cache (TRT allows it)
    seq_range: tuple[int, int, int] = (1, 1, 1024)      # new positions per decoder call (prefill .. 1)
    images_range: tuple[int, int, int] = (1, 1, 8)      # images per VLM vision call
    builder_optimization_level: int = 3
    dla_core: int | None = None              # Orin AGX/NX have DLA cores; None = GPU only
    roles: tuple[str, ...] | None = None
    overrides: dict[str, tuple[int, int, int]] = field(default_factory=dict)  # axis name -> (min, opt, max)


def axis_range(name: str, inp: dict[str, Any], ax: int, role_meta: dict[str, Any],
               conf: JetsonConfig) -> tuple[int, int, int]:
    """(min, opt, max) for one dynamic axis of one input (see the module docstring for the rules)."""
    cfg = role_meta.get("config") or {}
    iname = inp["name"]
    if name in conf.overrides:
        return tuple(int(v) for v in conf.overrides[name])  # type: ignore[return-value]
    kind = C.axis_kind(name, inp, ax, role_meta)
    if kind == "images":
        return conf.images_range
    if kind == "batch":
        return (1, 1, conf.max_batch)
    if kind == "image":
        return (C.image_axes(inp, role_meta.get("preprocessing") or {})[ax],) * 3  # type: ignore[return-value]
    if kind == "past":
        return conf.past_range
    if kind == "total":  # total = past + new tokens
        return (conf.past_range[0] + conf.seq_range[0], conf.past_range[1] + conf.seq_range[1],
                conf.past_range[2] + conf.seq_range[2])
    if kind == "keypoints":
        k = int(cfg.get("top_k") or cfg.get("max_keypoints"))
        return (k, k, k)
    if kind == "prompts":
        return conf.prompts_range
    if kind == "queries":
        return conf.queries_range
    if kind == "points":
        return conf.points_range
    if kind == "text":
        return conf.seq_range if "vlm" in str(role_meta.get("arch", "")) else conf.text_range
    raise ExportError(f"input {iname!r} axis {ax} ({name!r}): no rule gives its TensorRT profile range; pass "
                      f"--axis {name}=MIN:OPT:MAX")


def profile_shapes(inputs: Sequence[dict[str, Any]], role_meta: dict[str, Any],
                   conf: JetsonConfig) -> dict[str, dict[str, list[int]]]:
    """{"min"|"opt"|"max": {input: shape}} for every input with a dynamic axis (empty when all are static).

    inputs: manifest input entries ({name, shape, dynamic_axes: {axis: name}}). Axes sharing a symbolic name
    get the same range (they must agree at run time)."""
    out: dict[str, dict[str, list[int]]] = {"min": {}, "opt": {}, "max": {}}
    for inp in inputs:
        dyn = {int(a): str(n) for a, n in (inp.get("dynamic_axes") or {}).items()}
        if not dyn:
            continue
        shp = {k: [int(s) for s in inp["shape"]] for k in out}
        for ax, name in dyn.items():
            lo, opt, hi = axis_range(name, inp, ax, role_meta, conf)
            floor = 0 if C.axis_kind(name, inp, ax, role_meta) == "past" else 1  # empty cache on prefill
            if not (floor <= lo <= opt <= hi) or opt < 1:
                raise ExportError(f"input {inp['name']!r} axis {ax} ({name}): range {lo}:{opt}:{hi} must satisfy "
                                  f"{floor} <= min <= opt <= max, opt >= 1")
            shp["min"][ax], shp["opt"][ax], shp["max"][ax] = lo, opt, hi
        for k in out:
            if any(s <= 0 for a, s in enumerate(shp[k]) if a not in dyn):
                raise ExportError(f"input {inp['name']!r}: shape {inp['shape']} has an unknown axis that is not "
                                  f"listed in dynamic_axes {dyn}")
            out[k][inp["name"]] = shp[k]
    return out


def shape_string(shapes: dict[str, list[int]]) -> str:
    """{"x": [1, 3, 8, 8], "m": [1, 4]} -> 'x:1x3x8x8,m:1x4' (the format of trt_profile_*_shapes and trtexec)."""
    for n in shapes:
        if re.search(r"[,:\s]", n):
            raise ExportError(f"input name {n!r} contains ',', ':' or whitespace, which the TensorRT shape string "
                              f"cannot express; rename the graph input")
    return ",".join(f"{n}:{'x'.join(str(int(d)) for d in s)}" for n, s in shapes.items())


def trt_provider_options(role: str, variant: str, component: str, precision: str,
                         profile: dict[str, dict[str, list[int]]], conf: JetsonConfig) -> dict[str, Any]:
    """TensorrtExecutionProvider options for one component (keys as onnxruntime documents them)."""
    cache = f"{conf.cache_dir}/{role}/{variant}"
    opts: dict[str, Any] = {
        "device_id": 0,
        "trt_max_workspace_size": int(conf.workspace_mb) * 1024 * 1024,
        "trt_fp16_enable": precision in ("fp16", "int8-qdq"),  # QDQ: unquantised layers in fp16
        "trt_int8_enable": precision == "int8-qdq",
        "trt_engine_cache_enable": True,
        "trt_engine_cache_path": cache,
        "trt_engine_cache_prefix": component,
        "trt_timing_cache_enable": True,
        "trt_timing_cache_path": conf.cache_dir,
        "trt_dump_ep_context_model": True,
        "trt_ep_context_file_path": f"{cache}/{component}_ctx.onnx",
        "trt_ep_context_embed_mode": 0,
        "trt_builder_optimization_level": int(conf.builder_optimization_level),
    }
    if precision == "int8-qdq":
        # explicit quantisation: scales come from the Q/DQ nodes, no calibration table
        opts["trt_int8_use_native_calibration_table"] = False
    if conf.dla_core is not None:
        opts["trt_dla_enable"] = True
        opts["trt_dla_core"] = int(conf.dla_core)
    if profile.get("min"):
        opts["trt_profile_min_shapes"] = shape_string(profile["min"])
        opts["trt_profile_opt_shapes"] = shape_string(profile["opt"])
        opts["trt_profile_max_shapes"] = shape_string(profile["max"])
    return opts


def provider_chain(trt_opts: dict[str, Any]) -> list[list[Any]]:
    """TensorRT -> CUDA -> CPU as [name, options] pairs (runtime/infra/providers.py takes them as a preference)."""
    return [["TensorrtExecutionProvider", trt_opts],
            ["CUDAExecutionProvider", {"device_id": 0, "cudnn_conv_algo_search": "HEURISTIC"}],
            ["CPUExecutionProvider", {}]]


def trtexec_command(onnx_rel: str, role: str, variant: str, component: str, precision: str,
                    profile: dict[str, dict[str, list[int]]], conf: JetsonConfig) -> list[str]:
    """argv of the equivalent standalone build: `trtexec --onnx=... --saveEngine=...` with the same precision
    and profile shapes (TensorRT 8.6 / 10.x flags)."""
    argv = ["trtexec", f"--onnx={conf.bundle_dir}/{onnx_rel}",
            f"--saveEngine={conf.cache_dir}/{role}/{variant}/{component}.engine",
            f"--timingCacheFile={conf.cache_dir}/timing.cache",
            f"--memPoolSize=workspace:{int(conf.workspace_mb)}M",
            f"--builderOptimizationLevel={int(conf.builder_optimization_level)}"]
    if precision in ("fp16", "int8-qdq"):
        argv.append("--fp16")
    if precision == "int8-qdq":
        argv.append("--int8")  # with Q/DQ nodes: explicit quantisation, no --calib
    if profile.get("min"):
        argv += [f"--minShapes={shape_string(profile['min'])}", f"--optShapes={shape_string(profile['opt'])}",
                 f"--maxShapes={shape_string(profile['max'])}"]
    if conf.dla_core is not None:
        argv += [f"--useDLACore={int(conf.dla_core)}", "--allowGPUFallback"]
    return argv


def script_line(argv: Sequence[str], conf: JetsonConfig) -> str:
    """One shell line for build_engines.sh: bundle/cache prefixes become $BUNDLE/$CACHE, every argument is
    double-quoted (so the variables expand and nothing else does)."""
    out = []
    for a in argv:
        a = a.replace(f"{conf.bundle_dir}/", "$BUNDLE/").replace(f"{conf.cache_dir}/", "$CACHE/")
        if re.search(r'["`\\]', a):
            raise ExportError(f"trtexec argument {a!r} contains a quote/backquote/backslash")
        out.append(a if re.fullmatch(r"[\w./=:-]+", a) else f'"{a}"')
    return " ".join(out)


def qdq_info(onnx_path: str | Path) -> dict[str, Any]:
    """Quantisation nodes of a graph and whether TensorRT can take them as explicit int8 quantisation.

    TensorRT's Q/DQ layers are symmetric signed int8 (zero point 0). TFLite-converted graphs and onnxruntime's
    default static QDQ (QUInt8 activations) carry uint8 / non-zero zero points: NNAPI and QNN take those, but
    TensorRT cannot fuse them, so onnxruntime leaves those nodes to CUDA/CPU. Returns {qdq, nodes, weight_only
    (DequantizeLinear only: int8 weights, float compute), zero_point_dtypes, nonzero_zero_points,
    trt_int8_compatible}."""
    import onnx
    from onnx import numpy_helper

    m = onnx.load(str(onnx_path), load_external_data=False)
    init = {i.name: i for i in m.graph.initializer}
    consts = {n.output[0]: n for n in m.graph.node if n.op_type == "Constant"}
    nodes, dtypes, nonzero, quant = 0, set(), 0, 0
    for n in m.graph.node:
        if n.op_type not in ("QuantizeLinear", "DequantizeLinear"):
            continue
        nodes += 1
        quant += n.op_type == "QuantizeLinear"
        if len(n.input) < 3 or not n.input[2]:
            dtypes.add("uint8")  # default zero-point type of QuantizeLinear without one
            continue
        zp = n.input[2]
        arr = None
        if zp in init:
            arr = numpy_helper.to_array(init[zp])
        elif zp in consts:
            arr = numpy_helper.to_array(consts[zp].attribute[0].t)
        if arr is None:
            dtypes.add("unknown")
            continue
        dtypes.add(arr.dtype.name)
        nonzero += int(arr.size and (arr != 0).any())
    ok = nodes > 0 and dtypes <= {"int8"} and nonzero == 0
    return {"qdq": nodes > 0, "nodes": nodes, "weight_only": nodes > 0 and quant == 0,
            "zero_point_dtypes": sorted(dtypes), "nonzero_zero_points": nonzero, "trt_int8_compatible": ok}


def _jetson_entry(root: Path, role: str, v: str, c: str, cm: dict[str, Any], rm: dict[str, Any],
                  conf: JetsonConfig) -> dict[str, Any]:
    """One component's `jetson` entry: profile shapes, provider chain, trtexec line, Q/DQ facts, warnings."""
    profile = profile_shapes(cm.get("inputs", []), rm, conf)
    q = qdq_info(B.safe_path(root, cm["file"]))
    p = rm["variants"].get(v, {}).get("precision", v)  # a variant named for its model (ssd-fp32) has a precision
    # Q/DQ nodes TensorRT takes need the int8 builder flag; ones it cannot take (uint8, non-zero zero
    # points) get no int8 flag and no standalone engine: trtexec would fail on them
    trt_int8 = q["qdq"] and q["trt_int8_compatible"]
    prec = "int8-qdq" if trt_int8 else ("fp16" if p == "int8-qdq" else p)
    opts = trt_provider_options(role, v, c, prec, profile, conf)
    argv = None if q["qdq"] and not trt_int8 else trtexec_command(cm["file"], role, v, c, prec, profile, conf)
    entry = {"trt_profile_shapes": profile if profile["min"] else {},
             "providers": provider_chain(opts), "trtexec": argv, "qdq": q, "warnings": []}
    if q["qdq"] and not q["trt_int8_compatible"]:
        entry["warnings"].append(
            f"Q/DQ nodes with zero-point types {q['zero_point_dtypes']} and {q['nonzero_zero_points']} "
            f"non-zero zero points: TensorRT takes only symmetric int8 Q/DQ, so these run outside "
            f"TensorRT (CUDA/CPU). For Jetson re-quantise with int8 symmetric activations "
            f"(onnxruntime quantize_static activation_type=QInt8, extra_options "
            f"ActivationSymmetric=True) or use the fp16 engine of a float graph.")
    if q["weight_only"]:
        entry["warnings"].append(
            "weight-only int8 (DequantizeLinear on weights, float activations): TensorRT's handling "
            "depends on its version; if the int8 build fails or is slow, use the fp16 engine")
    if p == "fp32" and (not q["qdq"] or q["weight_only"]):
        # the usual Jetson choice: an fp16 engine built from the fp32 graph
        fp16 = trt_provider_options(role, f"{v}-trtfp16", c, "fp16", profile, conf)
        entry["providers_fp16_engine"] = provider_chain(fp16)
        entry["trtexec_fp16_engine"] = trtexec_command(cm["file"], role, f"{v}-trtfp16", c, "fp16", profile, conf)
    return entry


def _jetson_role(root: Path, role: str, rm: dict[str, Any], conf: JetsonConfig) -> dict[str, Any]:
    """Write the `jetson` entries of one role's variants (ONNX components only) into `rm`; its summary."""
    role_sum = {}
    # the precisions asked for, and variants that are another model for the role (ssd-fp32) at one of them
    for v in [v for v, vm in rm["variants"].items() if v in conf.precisions
              or (vm.get("overrides") and vm.get("precision") in conf.precisions)]:
        vm = rm["variants"][v]
        meta = {**rm, **(vm.get("overrides") or {})}  # the variant's own model: its pre-processing sizes
        comps = {c: _jetson_entry(root, role, v, c, cm, meta, conf) for c, cm in vm["components"].items()
                 if cm.get("format", "onnx") == "onnx"}
        if comps:
            p = vm.get("precision", v)
            vm["jetson"] = {"components": comps, "precision": p,
                            "int8": ("explicit (QDQ nodes), no calibration table" if p == "int8-qdq" else None),
                            "engine_built_here": False}
            role_sum[v] = {c: {"profile": d["trt_profile_shapes"],
                               "trtexec": " ".join(d["trtexec"]) if d["trtexec"] else None,
                               "warnings": d["warnings"]} for c, d in comps.items()}
    rm["jetson"] = {"variants": sorted(role_sum)}
    return role_sum


def build_script(manifest: dict[str, Any], conf: JetsonConfig) -> str:
    """jetson/build_engines.sh: a trtexec line for every role with Jetson settings so far."""
    lines = ["#!/usr/bin/env bash",
             "# Standalone TensorRT engines for this bundle (generated by `mosaic export --target jetson`).",
             "# Run on the Jetson (inside the container of jetson/Dockerfile): BUNDLE=/bundle CACHE=/cache/trt.",
             "# NOT run on the export machine (no TensorRT there).", "set -euo pipefail",
             f'BUNDLE="${{BUNDLE:-{conf.bundle_dir}}}"', f'CACHE="${{CACHE:-{conf.cache_dir}}}"']
    for role, rm in manifest["roles"].items():
        for v, vm in rm["variants"].items():
            for c, d in ((vm.get("jetson") or {}).get("components") or {}).items():
                if not d["trtexec"] and not d.get("trtexec_fp16_engine"):
                    lines.append(f"# {role}/{v}/{c}: no engine (TensorRT cannot take its int8 Q/DQ; "
                                 f"onnxruntime runs those nodes on CUDA/CPU)")
                for argv in (d["trtexec"], d.get("trtexec_fp16_engine")):
                    if argv:
                        lines.append(f'mkdir -p "{Path(argv[2].split("=", 1)[1]).parent}"'
                                     .replace(f"{conf.cache_dir}/", "$CACHE/"))
                        lines.append(script_line(argv, conf))
    return "\n".join(lines) + "\n"


def export_jetson(bundle_dir: str | Path, conf: JetsonConfig | None = None) -> dict[str, Any]:
    """Record TensorRT provider options, profile shapes and trtexec commands for every role/variant/component
    of the bundle (ONNX components only) and write jetson/build_engines.sh. Returns a summary."""
    conf = conf or JetsonConfig()
    root = Path(bundle_dir)
    bundle = B.load_bundle(root, verify=True)
    manifest = bundle.manifest
    summary: dict[str, Any] = {"roles": {}}
    for role in list(conf.roles or bundle.roles):
        summary["roles"][role] = _jetson_role(root, role, bundle.role_meta(role), conf)
    script = root / SCRIPT
    script.parent.mkdir(parents=True, exist_ok=True)
    script.write_text(build_script(manifest, conf))
    script.chmod(0o755)
    manifest["jetson"] = {"provider_chain": ["TensorrtExecutionProvider", "CUDAExecutionProvider",
                                             "CPUExecutionProvider"],
                          "build_engines": {"file": SCRIPT, "sha256": B.sha256_file(script)},
                          "cache_dir": conf.cache_dir, "bundle_dir": conf.bundle_dir,
                          "container": "jetson/Dockerfile (repository)", "not_run": NOT_RUN}
    B.write_manifest(root, manifest)
    summary.update({"script": str(script), "not_run": NOT_RUN})
    return summary


# ----------------------------------------------------------------------------------------------------------------
# CLI (hooked into `mosaic export --target jetson` by export/cli.py)

def add_arguments(parser: argparse.ArgumentParser) -> None:
    g = parser.add_argument_group("jetson target")
    g.add_argument("--axis", action="append", default=[], metavar="NAME=MIN:OPT:MAX",
                   help="TensorRT profile range for a named dynamic axis (repeatable)")
    g.add_argument("--trt-cache", default="/cache/trt", help="engine/timing cache folder on the Jetson")
    g.add_argument("--trt-workspace-mb", type=int, default=2048)
    g.add_argument("--dla-core", type=int, default=None, help="build for a DLA core (GPU fallback allowed)")
    g.add_argument("--jetson-roles", default=None, help="comma-separated roles (default: all)")


def config_from_args(args: argparse.Namespace) -> JetsonConfig:
    over = {}
    for item in getattr(args, "axis", []) or []:
        m = re.fullmatch(r"\s*([^=\s]+)\s*=\s*(\d+):(\d+):(\d+)\s*", item)
        if not m:
            raise ExportError(f"--axis {item!r}: expected NAME=MIN:OPT:MAX with integers")
        over[m.group(1)] = (int(m.group(2)), int(m.group(3)), int(m.group(4)))
    roles = getattr(args, "jetson_roles", None)
    return JetsonConfig(cache_dir=getattr(args, "trt_cache", "/cache/trt"),
                        workspace_mb=int(getattr(args, "trt_workspace_mb", 2048)),
                        dla_core=getattr(args, "dla_core", None), overrides=over,
                        roles=tuple(r.strip() for r in roles.split(",")) if roles else None)


def target_step(out: str | Path, roles: Sequence[str], args: argparse.Namespace) -> dict[str, Any]:
    """`mosaic export [ROLE] ... --target jetson` (export/cli.py TARGETS): --jetson-roles when given, else `roles`
    (the roles just exported, or every role of the bundle)."""
    return C.run_target_step(export_jetson, config_from_args(args), out, roles, render)


def render(result: dict[str, Any]) -> str:
    lines = [f"jetson settings written into {result['bundle']}/manifest.json"]
    for role, vs in result["roles"].items():
        for v, comps in vs.items():
            for c, d in comps.items():
                lines.append(f"  {role}/{v}/{c}: {d['trtexec'] or 'no standalone engine (see warnings)'}")
                lines += [f"    WARNING: {w}" for w in d.get("warnings", [])]
    lines += [f"engine build script: {result['script']}", result["not_run"]]
    return "\n".join(lines)
