"""Random inputs for the Android parity checks (fixed-shape graphs and decoders that keep dynamic axes)."""
from __future__ import annotations

import re
from pathlib import Path
from typing import Any, Callable

import numpy as np

from mosaicthinker.runtime.infra.errors import ExportError

from ..parity import ort_session


def _dim_value(d: Any, dyn_values: dict[str, int], default: int) -> int:
    """A concrete size for one graph dim: int as is; a symbol from dyn_values (else `default`); a simple
    expression of symbols ('past_sequence_length + 1') evaluated with those values."""
    if isinstance(d, int) and d >= 0:
        return d
    if not isinstance(d, str) or not d:
        return default
    if d in dyn_values:
        return int(dyn_values[d])
    if re.fullmatch(r"[\w\s+*-]+", d) and re.search(r"[+*-]", d):
        expr = re.sub(r"[A-Za-z_]\w*", lambda m: str(int(dyn_values.get(m.group(0), default))), d)
        return int(eval(expr, {"__builtins__": {}}, {}))  # noqa: S307  digits and + - * only (checked above)
    return default


def random_feeds_factory(onnx_path: str | Path, role_meta: dict[str, Any],
                         dyn_values: dict[str, int] | None = None) -> Callable[[np.random.Generator], dict]:
    """make_inputs(rng): images as random pixels through the role's scale/mean/std, token ids in [0, vocab),
    masks all ones, prompt labels in {0, 1}, other floats ~N(0, 0.5). Dynamic dims (graphs that keep them,
    e.g. a KV-cache decoder) get sizes from dyn_values {symbol: size} (default 3)."""
    sess = ort_session(onnx_path)
    pp = role_meta.get("preprocessing") or {}
    cfg = role_meta.get("config") or {}
    vocab = int(cfg.get("vocab_size", 10))  # unknown vocabulary: ids 0..9 exist in any tokenizer
    dyn_values = dyn_values or {}
    specs = []
    for i in sess.get_inputs():
        specs.append((i.name, tuple(_dim_value(d, dyn_values, 3) for d in i.shape), i.type))
    img_size = tuple(pp.get("size") or ())

    def make(rng: np.random.Generator) -> dict[str, np.ndarray]:
        feeds = {}
        for name, shape, t in specs:
            lname = name.lower()
            if t == "tensor(uint8)":
                feeds[name] = rng.integers(0, 256, shape, dtype=np.uint8)
            elif t in ("tensor(int64)", "tensor(int32)"):
                dt = np.int64 if t.endswith("int64)") else np.int32
                if "mask" in lname:
                    feeds[name] = np.ones(shape, dt)
                elif "label" in lname:
                    feeds[name] = rng.integers(0, 2, shape).astype(dt)
                elif "position" in lname and len(shape) >= 1:
                    feeds[name] = np.broadcast_to(np.arange(shape[-1]), shape).astype(dt).copy()
                else:
                    feeds[name] = rng.integers(0, vocab, shape).astype(dt)
            elif t in ("tensor(float)", "tensor(float16)"):
                dt = np.float32 if t == "tensor(float)" else np.float16
                is_img = len(shape) == 4 and img_size and (tuple(shape[1:3]) == img_size or tuple(shape[2:4]) == img_size)
                if is_img:
                    px = rng.integers(0, 256, shape).astype(np.float32)
                    x = px * float(pp.get("scale", 1.0 / 255.0)) if "scale" in pp or "mean" not in pp else px
                    if "mean" in pp:
                        ch_axis = 3 if shape[3] == 3 else 1
                        bshape = [1] * 4
                        bshape[ch_axis] = -1
                        mean = np.asarray(pp["mean"], np.float32).reshape(bshape)
                        std = np.asarray(pp.get("std", [1.0, 1.0, 1.0]), np.float32).reshape(bshape)
                        x = (x - mean) / std
                    feeds[name] = x.astype(dt)
                elif "mask" in lname:
                    feeds[name] = np.ones(shape, dt)
                elif "label" in lname:
                    feeds[name] = rng.integers(0, 2, shape).astype(dt)
                elif "coord" in lname or "point" in lname or "box" in lname:
                    feeds[name] = (rng.random(shape) * max(img_size or (64,))).astype(dt)
                else:
                    feeds[name] = (rng.standard_normal(shape) * 0.5).astype(dt)
            elif t == "tensor(bool)":
                feeds[name] = np.ones(shape, bool)
            else:
                raise ExportError(f"{onnx_path}: input {name} has type {t}, which the parity check cannot fill")
        return feeds

    return make
