"""VLM decoder: the fixed-window KV cache variant (static shapes for NPU providers) and its check."""
from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

import numpy as np

from mosaicthinker.runtime.infra.errors import ExportError

from ..parity import ort_session, parity_rng


KV_WINDOW_PROTOCOL = (
    "Fixed-window KV cache (static shapes for NPU providers): the cache is W slots per layer "
    "(past_* [1, KV, W, D], zeros at start) with a validity mask m[W] (all 0 at start). Every call feeds s new "
    "positions (s = 1 for *_kvwindow_step, s = P for *_kvwindow_prefill; a shorter prompt chunk is padded on "
    "the RIGHT with masked positions): attention_mask = [m, new_valid] (int64, length W + s), position_ids = "
    "number of valid tokens so far + 0, 1, ... for the valid new positions (0 for pads), past_* = the cache. "
    "Then cache = present_*[:, :, s:, :] and m = [m, new_valid][s:]. The s dropped slots must be unused (m = 0): "
    "at most W - s valid tokens fit (prompt + generated), else fall back to the dynamic decoder.")


def kv_io(inputs: Sequence[dict[str, Any]], outputs: Sequence[dict[str, Any]]) -> dict[str, Any] | None:
    """Recognise the decoder-with-cache I/O convention of export/hf_vlm.py (inputs_embeds | input_ids,
    attention_mask, position_ids, past_key_i / past_value_i -> logits, present_key_i / present_value_i).
    Returns {"new", "mask", "pos", "past": [names], "present": [names], "logits"} or None."""
    names = [i["name"] for i in inputs]
    new = next((n for n in ("inputs_embeds", "input_ids") if n in names), None)
    past = [n for n in names if n.startswith("past")]
    outs = [o["name"] for o in outputs]
    present = [n.replace("past", "present", 1) for n in past]
    if not new or "attention_mask" not in names or "position_ids" not in names or not past \
            or any(p not in outs for p in present):
        return None
    return {"new": new, "mask": "attention_mask", "pos": "position_ids", "past": past, "present": present,
            "logits": "logits" if "logits" in outs else outs[0]}


def kv_window_check(decoder: str | Path, inputs: Sequence[dict[str, Any]], outputs: Sequence[dict[str, Any]], *,
                    window: int, prefill: int, prompt_len: int = 5, steps: int = 6, seed: int = 0,
                    rel_tol: float = 1e-3) -> dict[str, Any]:
    """Does the fixed-window protocol (KV_WINDOW_PROTOCOL) give the dynamic decoder's logits?

    Teacher-forced on random embeddings: the dynamic graph prefills `prompt_len` positions (past 0) then steps
    one position at a time with a growing cache; the window path prefills the same positions padded to
    `prefill`, then steps with the W-slot cache. Compares the logits of the last prompt position and of every
    step. Returns {"ok", "max_rel", "steps", "window", "prefill", "reason"?}."""
    io = kv_io(inputs, outputs)
    if io is None:
        return {"ok": False, "reason": "decoder I/O does not follow the inputs_embeds/attention_mask/"
                                       "position_ids/past_* -> logits/present_* convention"}
    prompt_len, steps = min(prompt_len, prefill), min(steps, window - prefill)
    if prompt_len < 1 or steps < 1:
        return {"ok": False, "reason": f"window {window} / prefill {prefill} leave no room for the check"}
    sess = ort_session(decoder)
    spec = {i.name: i for i in sess.get_inputs()}
    new_i = spec[io["new"]]
    _, rng = parity_rng(seed)  # a protocol test: seed 0 unless the caller picks one
    kv_shape = [d if isinstance(d, int) else None for d in spec[io["past"][0]].shape]
    if sum(d is None for d in kv_shape) != 1 or kv_shape[2] is not None:
        return {"ok": False, "reason": f"past shape {spec[io['past'][0]].shape}: expected [1, KV, past, D]"}
    kv, d = int(kv_shape[1]), int(kv_shape[3])
    total = prompt_len + steps
    if io["new"] == "inputs_embeds":
        hidden = int(new_i.shape[2])
        seq = (rng.standard_normal((1, total, hidden)) * 0.5).astype(np.float32)
    else:
        seq = rng.integers(0, 50, (1, total)).astype(np.int64)
    names = [o.name for o in sess.get_outputs()]
    li = names.index(io["logits"])
    pres_i = [names.index(p) for p in io["present"]]

    def run(chunk, mask, pos, past):
        feeds = {io["new"]: chunk, io["mask"]: mask.astype(np.int64)[None], io["pos"]: pos.astype(np.int64)[None]}
        feeds.update(dict(zip(io["past"], past)))
        out = sess.run(None, feeds)
        return out[li], [out[i] for i in pres_i]

    # dynamic reference
    past = [np.zeros((1, kv, 0, d), np.float32) for _ in io["past"]]
    ref = []
    lg, past = run(seq[:, :prompt_len], np.ones(prompt_len), np.arange(prompt_len), past)
    ref.append(lg[0, -1])
    for t in range(prompt_len, total):
        lg, past = run(seq[:, t:t + 1], np.ones(t + 1), np.array([t]), past)
        ref.append(lg[0, -1])
    # window path
    cache = [np.zeros((1, kv, window, d), np.float32) for _ in io["past"]]
    m = np.zeros(window, np.int64)
    chunk = np.zeros((1, prefill) + seq.shape[2:], seq.dtype)
    chunk[:, :prompt_len] = seq[:, :prompt_len]
    new_valid = (np.arange(prefill) < prompt_len).astype(np.int64)
    pos = np.where(new_valid == 1, np.arange(prefill), 0)
    got = []
    lg, pres = run(chunk, np.concatenate([m, new_valid]), pos, cache)
    got.append(lg[0, prompt_len - 1])
    cache, m = [p[:, :, prefill:, :] for p in pres], np.concatenate([m, new_valid])[prefill:]
    for t in range(prompt_len, total):
        if m[0]:
            return {"ok": False, "reason": "window full during the check"}
        lg, pres = run(seq[:, t:t + 1], np.concatenate([m, [1]]), np.array([int(m.sum())]), cache)
        got.append(lg[0, -1])
        cache, m = [p[:, :, 1:, :] for p in pres], np.concatenate([m, [1]])[1:]
    rel = max(float(np.abs(a - b).max() / max(np.abs(a).max(), 1e-12)) for a, b in zip(ref, got))
    finite = all(np.isfinite(g).all() for g in got)
    return {"ok": bool(finite and rel <= rel_tol), "max_rel": rel, "finite": finite, "steps": len(got),
            "window": window, "prefill": prefill, "tolerance_rel": rel_tol,
            "reference": "the same decoder with a growing (dynamic) cache, teacher-forced random inputs"}


def decoder_dyn_values(inputs: Sequence[dict[str, Any]], io: dict[str, Any], new: int = 2,
                       past: int = 3) -> dict[str, int]:
    """Consistent sizes for a dynamic decoder's symbolic axes (mask length = past + new) for parity runs."""
    vals = {}
    for i in inputs:
        for ax, name in (i.get("dynamic_axes") or {}).items():
            if i["name"] == io["mask"]:
                vals[name] = past + new
            elif i["name"] in io["past"]:
                vals[name] = past
            elif i["name"] in (io["new"], io["pos"]) and int(ax) == 1:
                vals[name] = new
    return vals


def kv_window_shapes(inputs: Sequence[dict[str, Any]], io: dict[str, Any], window: int, s: int) -> dict[str, list[int]]:
    """Static input shapes of the fixed-window decoder for s new positions."""
    shapes = {}
    for i in inputs:
        shp = [int(x) for x in i["shape"]]
        if i["name"] == io["new"]:
            shp[0], shp[1] = 1, s
        elif i["name"] == io["mask"]:
            shp = [1, window + s]
        elif i["name"] == io["pos"]:
            shp = [1, s]
        elif i["name"] in io["past"]:
            shp[0], shp[2] = 1, window
        elif any(v <= 0 for v in shp):
            raise ExportError(f"decoder input {i['name']}: unexpected dynamic shape {i['shape']}")
        shapes[i["name"]] = shp
    return shapes
