"""`mosaic bundle verify|show DIR`: the bundle command over `runtime/infra/bundle.py`.

`verify` checks what loading a role would find wrong, without creating a session: the manifest against its
schema (at read), every file's sha256, every role's arch against its role (`models.check_archs`), every ONNX graph's inputs against the
manifest's `inputs` and `preprocessing` (read from the protobuf, no `onnx` needed), after every file's sha256.
"""
from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from ..infra.bundle import COMMON_FLAGS, Bundle, _fields, load_bundle, safe_path, variant_meta
from ..infra.bundle import add_arguments_for as _bundle_arguments_for
from ..infra.bundle import render as _bundle_render
from ..infra.bundle import run_for as _bundle_run_for
from ..infra.errors import BundleError, InputError
from ..infra.file_schemas import image_input_problem
from ..models import check_archs
from .android_report import android_report, render_android

__all__ = ["COMMON_FLAGS", "add_arguments_for", "run_for", "render", "graph_inputs", "check_graph_inputs"]

# TensorProto.DataType -> the manifest's dtype names (others keep their number)
_ELEM = {1: "float32", 2: "uint8", 3: "int8", 6: "int32", 7: "int64", 9: "bool", 10: "float16", 11: "float64"}


def graph_inputs(path: Any) -> list[tuple[str, list[Any], str | None]]:
    """The graph inputs of an ONNX file as (name, shape with ints / names / None for unknown axes, dtype), read
    from the protobuf (ModelProto.graph = 7; GraphProto.input = 11, initializer = 5; ValueInfoProto name = 1,
    type = 2; TypeProto.tensor_type = 1: elem_type = 1, shape = 2; Dimension dim_value = 1, dim_param = 2).
    Initializers listed as inputs (old IR versions) are left out. Raises BundleError on an unreadable file."""
    try:
        buf = memoryview(Path(path).read_bytes())
        graph = next((v for f, wt, v in _fields(buf) if f == 7 and wt == 2), None)
        if graph is None:
            raise ValueError("no graph")
        inits, ins = set(), []
        for f, wt, v in _fields(graph):
            if f == 5 and wt == 2:
                inits.update(bytes(x).decode("utf-8", "replace") for g, w, x in _fields(v) if g == 8 and w == 2)
            elif f == 11 and wt == 2:
                ins.append(_value_info(v))
    except (ValueError, IndexError, OSError) as e:
        raise BundleError(f"{path}: not a readable ONNX file ({e}); re-export the role") from e
    return [i for i in ins if i[0] not in inits]


def _value_info(buf: Any) -> tuple[str, list[Any], str | None]:
    name, shape, dtype = "", [], None
    for f, wt, v in _fields(buf):
        if f == 1 and wt == 2:
            name = bytes(v).decode("utf-8", "replace")
        elif f == 2 and wt == 2:
            for f2, w2, tensor in _fields(v):
                if f2 != 1 or w2 != 2:
                    continue
                for f3, w3, v3 in _fields(tensor):
                    if f3 == 1 and w3 == 0:
                        dtype = _ELEM.get(v3, str(v3))
                    elif f3 == 2 and w3 == 2:
                        for f4, w4, dim in _fields(v3):
                            if f4 == 1 and w4 == 2:
                                shape.append(_dim(dim))
    return name, shape, dtype


def _dim(buf: Any) -> Any:
    for f, wt, v in _fields(buf):
        if f == 1 and wt == 0:
            return v
        if f == 2 and wt == 2:
            return bytes(v).decode("utf-8", "replace")
    return None


def check_graph_inputs(b: Bundle) -> int:
    """Every ONNX component's graph inputs agree with the manifest: the `inputs` it lists (names, fixed axes)
    and the role's `preprocessing` (`image_input_problem`). Returns the number of graphs read."""
    n = 0
    for role in b.roles:
        meta = b.role_meta(role)
        for vname, vm in meta["variants"].items():
            for cname, cm in vm["components"].items():
                if cm["format"] != "onnx" or vm.get("genai"):
                    continue
                where = f"{b.manifest_path}: roles.{role}.variants.{vname}.components.{cname}"
                path = safe_path(b.root, cm["file"], where + ".file")
                if not path.is_file():
                    continue  # the sha256 pass names the missing file
                got = graph_inputs(path)
                n += 1
                _compare_inputs(cm["inputs"], got, where)
                eff = variant_meta(meta, vm)  # a variant may be another model, with its own preprocessing
                bad = image_input_problem(eff.get("preprocessing") or {}, got)
                if bad is not None:
                    at = f"variants.{vname}.overrides." if "preprocessing" in (vm.get("overrides") or {}) else ""
                    raise BundleError(f"{b.manifest_path}: roles.{role}.{at}preprocessing.{bad[0]} {bad[1]} (graph "
                                      f"{cm['file']})")
    return n


def _compare_inputs(listed: list[dict[str, Any]], got: list[tuple[str, list[Any], str | None]], where: str) -> None:
    names = [g[0] for g in got]
    if [io["name"] for io in listed] != names:
        raise BundleError(f"{where}.inputs names {[io['name'] for io in listed]} but the graph's inputs are "
                          f"{names}; re-export the role")
    for i, (io, (name, shape, dtype)) in enumerate(zip(listed, got)):
        want = io["shape"]
        fixed = [a == b for a, b in zip(want, shape) if isinstance(a, int) and a > 0 and isinstance(b, int) and b > 0]
        if len(want) != len(shape) or not all(fixed):
            raise BundleError(f"{where}.inputs[{i}].shape is {want} but the graph input {name!r} is {shape}; "
                              f"re-export the role")
        if io.get("dtype") and dtype in _ELEM.values() and io["dtype"] != dtype:
            raise BundleError(f"{where}.inputs[{i}].dtype is {io['dtype']!r} but the graph input {name!r} takes "
                              f"{dtype}; re-export the role")


def add_arguments_for(sub: str, parser: argparse.ArgumentParser) -> None:
    _bundle_arguments_for(sub, parser)
    if sub == "verify":
        parser.add_argument("--target", default="cpu",
                            help="cpu | android (default cpu); android: also say per role which provider would run "
                                 "each .ort graph and which ops fall back to the CPU (docs/deployment.md)")


def run_for(sub: str, args: argparse.Namespace) -> dict[str, Any]:
    if sub == "verify":
        root = args.dir or getattr(args, "bundle", None)
        if root:
            res = _bundle_run_for(sub, args)  # schema (at read), then every file's sha256
            b = load_bundle(root, verify=False)
            check_archs(b)
            res = {**res, "graphs_checked": check_graph_inputs(b)}
            target = getattr(args, "target", "cpu") or "cpu"
            if target not in ("cpu", "android"):
                raise InputError(f"--target {target}: bundle verify knows cpu and android (the Jetson settings are "
                                 f"checked by `mosaic export --target jetson`)")
            if target == "android":
                res["android"] = android_report(b)
            return res
    return _bundle_run_for(sub, args)


def render(result: dict[str, Any]) -> str:
    text = _bundle_render(result)
    if "android" in result:
        text += "\n" + render_android(result["android"])
    return text
