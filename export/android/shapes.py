"""Fixed shapes for NNAPI/QNN: which dynamic axes a role allows to fix, and the fixed copies of a graph."""
from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any, Sequence

from mosaicthinker.runtime.infra.errors import ExportError

from .. import common as C
from .config import AndroidConfig


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


def _copy(src: Path, dst: Path) -> Path:
    shutil.copyfile(src, dst)
    return dst


def _fixed_copy(p: Path, cmeta: dict, rmeta: dict, c: str, conf: AndroidConfig, tmp: Path, tag: str,
                role: str) -> Path:
    """A copy with the fixable axes fixed (axes left dynamic get small sizes in random_feeds_factory)."""
    shapes, _ = fixed_shape_plan(cmeta["inputs"], rmeta, c, conf, role)
    dst = tmp / f"{tag}.{c}.onnx"
    return make_fixed(p, dst, shapes) if shapes else _copy(p, dst)
