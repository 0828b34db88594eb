"""Qwen2.5-VL -> an ONNX Runtime GenAI package (pinned: onnxruntime-genai 0.18.0) inside the bundle's vlm role.

Package layout (what the GenAI `qwen2_5_vl` multi-modal model loads; read from the 0.18.0 model builder and the
GenAI C++ sources: MultiModalLanguageModel + QwenVisionState + QwenImageProcessor)::

    vlm/<variant>/genai_config.json        model.type "qwen2_5_vl", decoder / embedding / vision sections
    vlm/<variant>/processor_config.json    ort-extensions pipeline: DecodeImage, ConvertRGB, Resize (fixed S x S),
                                           Rescale, Normalize (qwen2_5_vl), PatchImage
    vlm/<variant>/tokenizer.json, tokenizer_config.json, special_tokens_map.json
    vlm/<variant>/decoder/model.onnx(.data) text decoder from `onnxruntime_genai.models.builder` (exclude_embeds:
                                           inputs_embeds, 3-D M-RoPE position_ids [3, B, S], KV cache), fp32 | int8 | int4
    vlm/<variant>/embedding/model.onnx     input_ids [B, S] int64, image_features [N, H] -> inputs_embeds [B, S, H]
                                           (rows of the image token replaced by the features, in order)
    vlm/<variant>/vision/model.onnx(.data) pixel_values [P, 3*T*14*14] (P = gh*gw patches), image_grid_thw [1, 3]
                                           -> image_features [P / 4, H]

Why one vision graph, not the three-stage patch_embed / vision_attn / patch_merger layout: in 0.18.0 that
layout (`vision.pipeline`, window index computed in C++) is read only by `Qwen2_5_VL_PipelineModel`, the
pipelined-decoder (NPU) path; the standard CPU/GPU model (`decoder.filename`) runs `vision.filename` as one
session. The vision graph is exported for a FIXED grid (S x S image, S a multiple of 28): window order, window
masks and the rotary table are constants computed by transformers' own helpers at export, and the processor
resizes every image to S x S so the grid always matches (a map image is one fixed-size picture).

Precision per package: fp32 = everything fp32; int8 / int4 = the builder's int8 / int4 decoder with an int8
vision graph and an int8 embedding table (one fp32 scale per 128 columns, standard Gather + Cast + Mul),
`--option side=fp32` to keep both fp32. The vision quantiser is `--option vision_quant=` (VISION_QUANTS):
`dynamic` (default: onnxruntime's quantize_dynamic, per-channel int8 weights, MatMulInteger -- ~2x faster than the
fp32 graph on this CPU at 3B), `nbits8` / `nbits4` (MatMulNBits weight-only; 8-bit measured ~4x slower than
fp32 here, 4-bit fails the int8 parity gate at 3B), or `fp32` (int8 table, fp32 vision). At 3B the int8 side
takes the vision weights from ~2.5 GB to ~0.65 GB and the table from 1.2 GB to ~0.3 GB.

Qwen3-VL: the builder handles its text decoder (`Qwen3VLForConditionalGeneration`), but its vision tower feeds
DeepStack features into decoder layers, which the 0.18.0 decoder graph has no input for; it is exported with the
project's own graphs instead (export/hf_qwen3_vl.py).
"""
from __future__ import annotations

import json
import logging
import math
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from mosaicthinker.runtime.infra import jsonio
from mosaicthinker.runtime.infra.errors import ExportError

from . import common as C
from .qwen_vl_config import (CLIP_MEAN, CLIP_STD, EOS_IDS, IMAGE_TOKEN, QWEN_VOCAB, REAL_3B, SIZES, TINY,  # noqa: F401
                             VISION_END, VISION_START, qwen_config)

GENAI_VERSION = "0.18.0"
ARCH = "qwen2_5_vl"
# Qwen2 tokenizer special tokens (ids 151643-151656, the real ones)
QWEN_SPECIALS = {151643: "<|endoftext|>", 151644: "<|im_start|>", 151645: "<|im_end|>",
                 151646: "<|object_ref_start|>", 151647: "<|object_ref_end|>", 151648: "<|box_start|>",
                 151649: "<|box_end|>", 151650: "<|quad_start|>", 151651: "<|quad_end|>",
                 151652: "<|vision_start|>", 151653: "<|vision_end|>", 151654: "<|vision_pad|>",
                 151655: "<|image_pad|>", 151656: "<|video_pad|>"}
RANDOM_MARKER = "RANDOM_WEIGHTS.json"  # written next to a random-weight checkpoint: provenance stays honest


# ------------------------------------------------------------------------------------------------ checkpoint

def random_checkpoint(size: str, dst: str | Path, *, dtype: str = "float32", seed: int = 0) -> Path:
    """`save_pretrained` of a seeded random Qwen2.5-VL of `size` into `dst`, with the synthetic tokenizer and a
    RANDOM_WEIGHTS.json marker (so a `dir:` export records random weights). Real size: ~8 GB peak (bf16)."""
    import torch
    from transformers import Qwen2_5_VLForConditionalGeneration

    from .tiny import torch_default_init

    dst = Path(dst)
    dst.mkdir(parents=True, exist_ok=True)
    torch.manual_seed(seed)
    cfg = qwen_config(size)
    prev = torch.get_default_dtype()
    torch.set_default_dtype(getattr(torch, dtype))
    try:
        model = Qwen2_5_VLForConditionalGeneration(cfg)
    finally:
        torch.set_default_dtype(prev)
    torch_default_init(model)  # fan-in init: O(1) activations (HF's 0.02 init makes random logits flat)
    model.eval().save_pretrained(str(dst))
    del model
    write_synthetic_tokenizer(dst, cfg.text_config.vocab_size)
    (dst / RANDOM_MARKER).write_text(jsonio.dumps({"random_weights": True, "size": size, "seed": seed,
                                                 "dtype": dtype}))
    return dst


def write_synthetic_tokenizer(dst: str | Path, vocab_size: int = QWEN_VOCAB) -> Path:
    """A byte-level BPE `tokenizer.json` with the real vocabulary size and the real Qwen special-token ids
    (151643-151656), plus `tokenizer_config.json` (Qwen2Tokenizer). Stands in for the checkpoint's tokenizer
    where none can be downloaded; text is split into bytes (no merges), so token ids differ from the real ones
    but every id the model can emit decodes."""
    from tokenizers import AddedToken, Tokenizer, decoders, models, pre_tokenizers

    dst = Path(dst)
    first_special = min(QWEN_SPECIALS)
    byte_syms = pre_tokenizers.ByteLevel.alphabet()
    vocab = {s: i for i, s in enumerate(sorted(byte_syms))}
    for i in range(len(vocab), first_special):
        vocab[f"t{i}"] = i  # filler ids: reachable only as model outputs
    tok = Tokenizer(models.BPE(vocab=vocab, merges=[]))
    tok.pre_tokenizer = pre_tokenizers.ByteLevel(add_prefix_space=False)
    tok.decoder = decoders.ByteLevel()
    tok.add_special_tokens([AddedToken(QWEN_SPECIALS[i], special=True, normalized=False)
                            for i in sorted(QWEN_SPECIALS)])
    tok.save(str(dst / "tokenizer.json"))
    added = {str(i): {"content": t, "lstrip": False, "normalized": False, "rstrip": False, "single_word": False,
                      "special": True} for i, t in QWEN_SPECIALS.items()}
    (dst / "tokenizer_config.json").write_text(jsonio.dumps({
        "tokenizer_class": "Qwen2Tokenizer", "model_max_length": 32768, "bos_token": None,
        "eos_token": "<|im_end|>", "pad_token": "<|endoftext|>", "unk_token": None, "clean_up_tokenization_spaces": False,
        "added_tokens_decoder": added, "errors": "replace", "split_special_tokens": False}, indent=1))
    (dst / "special_tokens_map.json").write_text(jsonio.dumps({"eos_token": "<|im_end|>",
                                                             "pad_token": "<|endoftext|>"}))
    return dst / "tokenizer.json"


# ------------------------------------------------------------------------------------------------ wrappers

def vision_wrapper(model: Any, image_size: int):
    """pixel_values [P, 3*T*p*p], image_grid_thw [1, 3] -> image_features [P / m^2, H] for a fixed S x S grid."""
    import torch
    from transformers.vision_utils import get_vision_position_ids, get_vision_window_index

    visual = model.model.visual
    vc = visual.config
    g = image_size // vc.patch_size
    grid = torch.tensor([[1, g, g]])
    unit = vc.spatial_merge_size ** 2
    pos = get_vision_position_ids(grid, vc.spatial_merge_size)
    win, cu_win = get_vision_window_index(grid, vc.spatial_merge_size, vc.window_size, vc.patch_size)
    seq = g * g

    def permute(t):  # window order of merge units, as the transformers forward does
        return t.reshape(seq // unit, unit, -1)[win].reshape(seq, -1)

    with torch.no_grad():
        cos, sin = visual.rotary_pos_emb(torch.zeros(seq, 1), pos)
    seg = torch.searchsorted(cu_win[1:].long(), torch.arange(seq), right=True)
    win_mask = torch.where(seg[:, None] == seg[None, :], 0.0, float("-inf"))[None, None]

    class VisionGraph(torch.nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.visual = visual
            self.full = set(vc.fullatt_block_indexes)
            self.register_buffer("cos", permute(cos).float(), persistent=False)
            self.register_buffer("sin", permute(sin).float(), persistent=False)
            self.register_buffer("win_mask", win_mask.float(), persistent=False)
            self.register_buffer("rev", torch.argsort(win), persistent=False)
            self.register_buffer("win", win, persistent=False)

        def attn(self, a, x, mask):
            from transformers.models.qwen2_5_vl.modeling_qwen2_5_vl import apply_rotary_pos_emb_vision

            n = x.shape[0]
            q, k, v = a.qkv(x).reshape(n, 3, a.num_heads, -1).permute(1, 0, 2, 3).unbind(0)
            q, k = apply_rotary_pos_emb_vision(q, k, self.cos, self.sin)
            q, k, v = (t.transpose(0, 1)[None] for t in (q, k, v))
            o = torch.nn.functional.scaled_dot_product_attention(q, k, v, attn_mask=mask)
            return a.proj(o[0].transpose(0, 1).reshape(n, -1))

        def forward(self, pixel_values, image_grid_thw):
            h = self.visual.patch_embed(pixel_values)
            h = h.reshape(seq // unit, unit, -1)[self.win].reshape(seq, -1)
            for i, blk in enumerate(self.visual.blocks):
                h = h + self.attn(blk.attn, blk.norm1(h), None if i in self.full else self.win_mask)
                h = h + blk.mlp(blk.norm2(h))
            out = self.visual.merger(h)[self.rev]
            # the grid is fixed at export; the input is kept (GenAI feeds it) and tied in so it is not pruned
            return out + 0.0 * image_grid_thw.sum().to(out.dtype)

    return VisionGraph().eval(), seq


def quantize_rows_int8(w: Any, block: int, chunk: int = 8192) -> tuple[Any, Any]:
    """Symmetric int8 of a [V, H] table in blocks of `block` columns (block must divide H): (q int8 [V, H],
    scale fp32 [V, H / block]). Row chunks keep the fp32 temporaries small (the 3B table is 1.2 GB in fp32)."""
    import torch

    V, H = w.shape
    q = torch.empty(V, H, dtype=torch.int8)
    s = torch.empty(V, H // block, dtype=torch.float32)
    for i in range(0, V, chunk):
        b = w[i:i + chunk].float().reshape(-1, H // block, block)
        sc = b.abs().amax(-1).clamp_min(1e-12) / 127.0
        q[i:i + chunk] = torch.round(b / sc[..., None]).clamp(-127, 127).to(torch.int8).reshape(-1, H)
        s[i:i + chunk] = sc
    return q, s


def embedding_wrapper(model: Any, image_token_id: int, int8_block: int | None = None):
    """input_ids [B, S], image_features [N, H] -> inputs_embeds [B, S, H] (image-token rows = features).

    int8_block: store the table as int8 with one fp32 scale per `int8_block` columns of a row (standard Gather +
    Cast + Mul, no contrib op; 4x smaller than fp32) -- the rows are dequantised after the gather, so only the
    prompt's rows are ever fp32."""
    import torch

    table = model.get_input_embeddings()
    if int8_block:
        int8_block = math.gcd(int(int8_block), int(table.weight.shape[1]))  # a block that divides the width

    class EmbeddingGraph(torch.nn.Module):
        def __init__(self) -> None:
            super().__init__()
            if int8_block:
                q, s = quantize_rows_int8(table.weight.detach(), int8_block)
                self.register_buffer("q", q)
                self.register_buffer("s", s)
            else:
                self.emb = table

        def lookup(self, input_ids):
            if not int8_block:
                return self.emb(input_ids)
            H = self.q.shape[1]
            rows = self.q[input_ids].to(torch.float32).reshape(*input_ids.shape, H // int8_block, int8_block)
            return (rows * self.s[input_ids][..., None]).reshape(*input_ids.shape, H)

        def forward(self, input_ids, image_features):
            e = self.lookup(input_ids)
            mask = (input_ids == image_token_id).reshape(-1)
            n = image_features.shape[0]
            feats = torch.cat([image_features.to(e.dtype), torch.zeros_like(e[0, :1])], 0)
            idx = torch.where(mask, torch.cumsum(mask.long(), 0) - 1, n).clamp(0, n)
            return torch.where(mask.reshape(e.shape[:2])[..., None], feats[idx].reshape(e.shape), e)

    return EmbeddingGraph().eval()


def gemm_to_matmul(model: Any) -> int:
    """Rewrite Gemm(A, W, C) with a constant W (torch Linear on 2-D input) as MatMul(A, W') + Add(C), in place:
    the weight-only quantiser (MatMulNBits) targets MatMul. Returns the number of nodes rewritten."""
    from onnx import helper, numpy_helper

    inits = {t.name: t for t in model.graph.initializer}
    nodes, n = [], 0
    for node in model.graph.node:
        attrs = {a.name: helper.get_attribute_value(a) for a in node.attribute}
        if (node.op_type != "Gemm" or node.input[1] not in inits or attrs.get("transA", 0)
                or attrs.get("alpha", 1.0) != 1.0 or attrs.get("beta", 1.0) != 1.0):
            nodes.append(node)
            continue
        w = numpy_helper.to_array(inits[node.input[1]])
        if attrs.get("transB", 0):
            w = np.ascontiguousarray(w.T)
        wname = node.input[1] + "_kn"
        model.graph.initializer.append(numpy_helper.from_array(w, wname))
        mm_out = node.output[0] + ("_mm" if len(node.input) > 2 and node.input[2] else "")
        nodes.append(helper.make_node("MatMul", [node.input[0], wname], [mm_out], name=node.name + "_mm"))
        if mm_out != node.output[0]:
            nodes.append(helper.make_node("Add", [mm_out, node.input[2]], [node.output[0]], name=node.name + "_add"))
        n += 1
    del model.graph.node[:]
    model.graph.node.extend(nodes)
    used = {i for nd in model.graph.node for i in nd.input}
    keep = [t for t in model.graph.initializer if t.name in used]
    del model.graph.initializer[:]
    model.graph.initializer.extend(keep)
    return n


# vision weight quantisers (--option vision_quant=...): name -> what the manifest records
VISION_QUANTS = {
    "dynamic": "int8 per output channel (quantize_dynamic, MatMulInteger with const weights only; activations "
               "quantised per tensor at run time)",
    "nbits8": "MatMulNBits bits=8 symmetric block {block} accuracy_level 4 (weight-only, int8 compute)",
    "nbits4": "MatMulNBits bits=4 symmetric block {block} accuracy_level 4 (weight-only, int8 compute)",
    "fp32": "fp32 (not quantised)",
}


def quantize_vision(src: Path, dst: Path, method: str = "dynamic", block: int = 128) -> Path:
    """The vision graph's constant MatMul/Linear weights quantised with onnxruntime's own tools, after a
    Gemm -> MatMul rewrite (both quantisers target MatMul); written with external data.

    dynamic: int8 weights per output channel + activations quantised per tensor at run time (MatMulInteger:
    VNNI/AMX kernels, ~7x faster than the fp32 MatMul on this CPU for the vision's 1024-row matmuls);
    nbits8 / nbits4: weight-only MatMulNBits (the builder's decoder op), int8 compute."""
    import onnx

    if method not in VISION_QUANTS or method == "fp32":
        raise ExportError(f"--option vision_quant={method}: expected one of {sorted(VISION_QUANTS)}")
    m = onnx.load(str(src))
    n = gemm_to_matmul(m)
    dst.parent.mkdir(parents=True, exist_ok=True)
    if method == "dynamic":
        _quantize_dynamic_matmul(m, dst)
    else:
        _quantize_nbits(m, dst, 8 if method == "nbits8" else 4, block)
    for f in dst.parent.iterdir():  # the quantisers write their .data 0600 (a temp file): readable like the rest
        f.chmod(0o644)
    nodes = onnx.load(str(dst), load_external_data=False).graph.node
    left = sum(nd.op_type in ("MatMul", "Gemm") for nd in nodes)
    C.progress(f"vision {method}: {n} Gemm rewritten; {left} MatMul/Gemm left (activation x activation)")
    return dst


def _quantize_dynamic_matmul(m: Any, dst: Path) -> None:
    import tempfile

    import onnx
    from onnxruntime.quantization import QuantType, quantize_dynamic

    with tempfile.TemporaryDirectory(dir=dst.parent) as t:
        src = Path(t) / "rewritten.onnx"
        onnx.save(m, str(src), save_as_external_data=True, location="rewritten.onnx.data")
        # reduce_range: 7-bit weights; onnxruntime's u8s8 kernels saturate on x86 CPUs without VNNI
        # (`common.INT8_REDUCE_RANGE`)
        quantize_dynamic(str(src), str(dst), weight_type=QuantType.QInt8, per_channel=True,
                         op_types_to_quantize=["MatMul"], use_external_data_format=True,
                         reduce_range=C.INT8_REDUCE_RANGE, extra_options={"MatMulConstBOnly": True})


def _quantize_nbits(m: Any, dst: Path, bits: int, block: int) -> None:
    root, had = logging.getLogger(), list(logging.getLogger().handlers)
    level0 = root.level
    from onnxruntime.quantization.matmul_nbits_quantizer import MatMulNBitsQuantizer

    for h in [h for h in root.handlers if h not in had]:  # its import calls logging.basicConfig(level=INFO)
        root.removeHandler(h)
    root.setLevel(level0)
    q = MatMulNBitsQuantizer(m, bits=bits, block_size=block, is_symmetric=True, accuracy_level=4,
                             op_types_to_quantize=("MatMul",))
    log = logging.getLogger("onnxruntime.quantization.matmul_nbits_quantizer")
    level = log.level
    log.setLevel(logging.WARNING)  # one INFO line per node otherwise
    try:
        q.process()
    finally:
        log.setLevel(level)
    q.model.save_model_to_file(str(dst), use_external_data_format=True)


def hf_image_features(model: Any, pixel_values: np.ndarray, image_size: int) -> np.ndarray:
    """transformers' own vision forward (the parity reference of the vision graph)."""
    import torch

    g = image_size // model.config.vision_config.patch_size
    with torch.no_grad():
        out = model.model.visual(torch.from_numpy(pixel_values), grid_thw=torch.tensor([[1, g, g]]))
    return out.pooler_output.float().numpy()


# ------------------------------------------------------------------------------------------------ package files

def processor_config(image_size: int, vc: Any) -> dict[str, Any]:
    """ort-extensions `processor_config.json` of GenAI's qwen2_5_image_processor: every image to S x S (fixed
    grid, see the module doc), CLIP normalisation, patches of temporal_patch_size x patch x patch."""
    op = lambda name, typ, **attrs: {"operation": {"name": name, "type": typ, **({"attrs": attrs} if attrs else {})}}
    return {"processor": {"name": "qwen2_5_image_processor", "transforms": [
        op("decode_image", "DecodeImage", color_space="RGB"),
        op("convert_to_rgb", "ConvertRGB"),
        op("resize", "Resize", width=image_size, height=image_size, smart_resize=0, keep_aspect_ratio=0,
           interpolation="LINEAR"),
        op("rescale", "Rescale", rescale_factor=1 / 255),
        op("normalize", "Normalize", mean=CLIP_MEAN, std=CLIP_STD, qwen2_5_vl=1),
        op("patch_image", "PatchImage", patch_size=int(vc.patch_size), temporal_patch_size=int(vc.temporal_patch_size),
           merge_size=int(vc.spatial_merge_size))]}}


def genai_config(builder_cfg: dict[str, Any], vc: Any, context_length: int) -> dict[str, Any]:
    """The builder's genai_config.json with the embedding and vision sections of the qwen2_5_vl model added."""
    g = json.loads(jsonio.dumps(builder_cfg))
    m = g["model"]
    m["decoder"]["filename"] = "decoder/" + m["decoder"]["filename"]
    m["embedding"] = {"filename": "embedding/model.onnx",
                      "inputs": {"input_ids": "input_ids", "image_features": "image_features"},
                      "outputs": {"inputs_embeds": "inputs_embeds"}}
    m["vision"] = {"filename": "vision/model.onnx", "spatial_merge_size": int(vc.spatial_merge_size),
                   "patch_size": int(vc.patch_size), "window_size": int(vc.window_size),
                   "tokens_per_second": float(getattr(vc, "tokens_per_second", 2)),
                   "inputs": {"pixel_values": "pixel_values", "image_grid_thw": "image_grid_thw"},
                   "outputs": {"image_features": "image_features"}}
    m.update(image_token_id=IMAGE_TOKEN, video_token_id=151656, vision_start_token_id=VISION_START,
             eos_token_id=list(EOS_IDS), pad_token_id=151643, context_length=int(context_length))
    g["search"].update(do_sample=False, top_k=1, top_p=1.0, temperature=1.0, max_length=int(context_length))
    return g


def run_builder(ckpt: Path, dst: Path, precision: str, cache: Path) -> dict[str, Any]:
    """`python -m onnxruntime_genai.models.builder` in a child process (its memory is freed when it exits; peak
    RSS measured). precision: fp32 | int8 | int4 (CPU). Returns {"seconds", "peak_rss_mb", "genai_config"}."""
    import resource

    dst.mkdir(parents=True, exist_ok=True)
    cmd = [sys.executable, "-m", "onnxruntime_genai.models.builder", "-i", str(ckpt), "-o", str(dst), "-p",
           precision, "-e", "cpu", "-c", str(cache), "--extra_options", "exclude_embeds=true"]
    C.progress(f"GenAI model builder ({precision}): {' '.join(cmd[3:])}")
    before = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    t = time.time()
    res = subprocess.run(cmd, capture_output=True, text=True)
    secs = time.time() - t
    peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    if res.returncode != 0:
        raise ExportError(f"onnxruntime_genai model builder failed ({precision}, rc {res.returncode}): "
                          f"{(res.stderr or res.stdout)[-1500:]}")
    cfg_path = dst / "genai_config.json"
    if not cfg_path.is_file():
        raise ExportError(f"{dst}: the model builder wrote no genai_config.json")
    return {"seconds": round(secs, 1), "peak_rss_mb": round(peak / 1024) if peak > before else None,
            "genai_config": json.loads(cfg_path.read_text())}


def _link(src: Path, dst: Path) -> None:
    """Hard link (no second copy of multi-GB files across variants), copy where links are not possible."""
    dst.parent.mkdir(parents=True, exist_ok=True)
    if dst.exists():
        dst.unlink()
    try:
        os.link(src, dst)
    except OSError:
        shutil.copyfile(src, dst)


def _graph_io(path: Path) -> tuple[list[dict], list[dict]]:
    """Graph inputs/outputs as manifest entries without loading weights (external data untouched)."""
    import onnx

    m = onnx.load(str(path), load_external_data=False)

    def conv(vals):
        out = []
        for v in vals:
            t = v.type.tensor_type
            shape, dyn = [], {}
            for i, d in enumerate(t.shape.dim):
                shape.append(int(d.dim_value) if d.HasField("dim_value") else 0)
                if not d.HasField("dim_value"):
                    dyn[str(i)] = d.dim_param or f"d{i}"
            out.append({"name": v.name, "shape": shape, "dtype": onnx.helper.tensor_dtype_to_np_dtype(
                t.elem_type).name if t.elem_type else "unknown", "dynamic_axes": dyn})
        return out

    return conv(m.graph.input), conv(m.graph.output)


def package_components(out: Path, pkg: Path) -> tuple[dict[str, dict], list[dict[str, str]]]:
    """Manifest components (decoder / embedding / vision, external data as extra_files) and the list of every
    file of the package (hashes filled in by bundle.add_variant / here)."""
    from mosaicthinker.runtime.infra.bundle import sha256_file

    comps = {}
    for c in ("decoder", "embedding", "vision"):
        f = pkg / c / "model.onnx"
        ins, outs = _graph_io(f)
        extra = [{"file": p.relative_to(out).as_posix(), "sha256": ""} for p in sorted((pkg / c).iterdir())
                 if p.name != "model.onnx"]
        comps[c] = {"file": f.relative_to(out).as_posix(), "format": "onnx", "inputs": ins, "outputs": outs,
                    "extra_files": extra}
    files = [{"file": p.relative_to(out).as_posix(), "sha256": sha256_file(p)} for p in sorted(pkg.rglob("*"))
             if p.is_file()]
    return comps, files


# ------------------------------------------------------------------------------------------------ export

def resolve_checkpoint(source: str, work: Path) -> tuple[Path, dict[str, Any]]:
    """A local checkpoint folder for `tiny[:qwen2_5_vl]`, `dir:PATH` or `hf:ID[@rev]` and its provenance."""
    if source.startswith("tiny"):
        ckpt = random_checkpoint("tiny", work / "ckpt")
        return ckpt, {"source": "tiny:qwen2_5_vl", "arch": ARCH, "random_weights": True, "seed": 0}
    if source.startswith("dir:"):
        ckpt = Path(source[4:])
        if not (ckpt / "config.json").is_file():
            raise ExportError(f"--source {source}: {ckpt}/config.json not found (expected a checkpoint folder)")
        marker = ckpt / RANDOM_MARKER
        rnd = json.loads(marker.read_text()) if marker.is_file() else None
        return ckpt, {"source": source, "random_weights": rnd is not None, **({"random": rnd} if rnd else {})}
    if source.startswith("hf:"):
        ident, _, rev = source[3:].partition("@")
        try:
            from huggingface_hub import snapshot_download

            ckpt = Path(snapshot_download(ident, revision=rev or None))
        except Exception as e:  # noqa: BLE001  (network / auth errors)
            raise ExportError(f"--source {source}: download failed ({type(e).__name__}: {str(e)[:300]}); on a "
                              f"machine without the hub pass dir:PATH of a downloaded checkpoint") from e
        return ckpt, {"source": source, "random_weights": False}
    raise ExportError(f"--source {source}: expected hf:ID, dir:PATH or tiny:qwen2_5_vl for the Qwen2.5-VL exporter")


def load_vision_side(ckpt: Path) -> Any:
    """The checkpoint with only what the vision and embedding graphs need, in fp32: loaded in its stored dtype,
    the decoder layers dropped before the fp32 cast (a 3B model never sits in memory at fp32 whole)."""
    import gc

    import torch
    from transformers import Qwen2_5_VLForConditionalGeneration

    model = Qwen2_5_VLForConditionalGeneration.from_pretrained(str(ckpt), dtype="auto").eval()
    model.model.language_model.layers = torch.nn.ModuleList()
    model.lm_head = torch.nn.Identity()
    gc.collect()
    model.model.visual.float()
    model.get_input_embeddings().float()
    return model


def export_graphs(model: Any, work: Path, image_size: int) -> dict[str, Any]:
    """vision + embedding graphs (fp32, external data) with parity against transformers on fresh inputs."""
    import torch

    vc = model.config.vision_config
    vis, seq = vision_wrapper(model, image_size)
    g = image_size // vc.patch_size
    pdim = 3 * vc.temporal_patch_size * vc.patch_size ** 2
    grid = np.array([[1, g, g]], np.int64)
    vpath = C.export_torch(vis, (torch.zeros(seq, pdim), torch.from_numpy(grid)), work / "vision" / "model.onnx",
                           ["pixel_values", "image_grid_thw"], ["image_features"], external_data=True)
    vpar = C.parity_check(vpath, lambda f: [hf_image_features(model, f["pixel_values"], image_size)],
                          lambda rng: {"pixel_values": rng.standard_normal((seq, pdim)).astype(np.float32),
                                       "image_grid_thw": grid}, trials=1, label="qwen vision vs transformers")
    emb = embedding_wrapper(model, IMAGE_TOKEN)
    H = model.get_input_embeddings().weight.shape[1]
    V = model.get_input_embeddings().weight.shape[0]
    dims = {"input_ids": {0: torch.export.Dim("batch", min=1, max=64), 1: torch.export.Dim("seq", min=1, max=32768)},
            "image_features": {0: torch.export.Dim("num_image_tokens", min=1, max=65536)}}
    ex_ids = torch.tensor([[1, IMAGE_TOKEN, IMAGE_TOKEN, 5], [7, 8, 9, 10]])
    epath = C.export_torch(emb, (ex_ids, torch.zeros(2, H)), work / "embedding" / "model.onnx",
                           ["input_ids", "image_features"], ["inputs_embeds"], dynamic_shapes=dims,
                           external_data=True)

    def emb_inputs(rng):
        n_img = int(rng.integers(1, 6))
        ids = rng.integers(0, 151643, size=(1, n_img + int(rng.integers(1, 9)))).astype(np.int64)
        ids[0, rng.choice(ids.shape[1], n_img, replace=False)] = IMAGE_TOKEN
        return {"input_ids": ids, "image_features": rng.standard_normal((n_img, H)).astype(np.float32)}

    from .hf_common import torch_reference

    epar = C.parity_check(epath, torch_reference(emb, ["input_ids", "image_features"]), emb_inputs, trials=2,
                          label="qwen embedding vs torch")
    return {"vision": vpath, "embedding": epath, "parity": {"vision": vpar, "embedding": epar},
            "image_tokens": seq // vc.spatial_merge_size ** 2, "hidden": int(H), "vocab": int(V),
            "emb_inputs": emb_inputs, "vision_inputs": lambda rng: {
                "pixel_values": rng.standard_normal((seq, pdim)).astype(np.float32), "image_grid_thw": grid}}


def export_int8_graphs(model: Any, fp32: dict[str, Any], work: Path, block: int = 128,
                       vision_quant: str = "dynamic") -> dict[str, Any]:
    """The int8 / int4 packages' side: the vision graph quantised with `vision_quant` (VISION_QUANTS; "fp32"
    keeps the fp32 graph) and the int8 embedding table (embedding_wrapper int8_block), with parity on fresh
    inputs: vision vs the fp32 graph, embedding vs the fp32 torch table."""
    import torch

    from .hf_common import torch_reference

    if vision_quant == "fp32":
        vpath, vpar = Path(fp32["vision"]), fp32["parity"]["vision"]
    else:
        vpath = quantize_vision(Path(fp32["vision"]), work / "vision" / "model.onnx", vision_quant, block)
        ref = C.ort_session(fp32["vision"])
        vpar = C.parity_check(vpath, lambda f: C.ort_run(ref, f), fp32["vision_inputs"], precision="int8-dynamic",
                              trials=2, label=f"qwen vision {vision_quant} vs fp32")
        del ref
    emb8 = embedding_wrapper(model, IMAGE_TOKEN, int8_block=block)
    H = int(fp32["hidden"])
    dims = {"input_ids": {0: torch.export.Dim("batch", min=1, max=64), 1: torch.export.Dim("seq", min=1, max=32768)},
            "image_features": {0: torch.export.Dim("num_image_tokens", min=1, max=65536)}}
    ex_ids = torch.tensor([[1, IMAGE_TOKEN, IMAGE_TOKEN, 5], [7, 8, 9, 10]])
    epath = C.export_torch(emb8, (ex_ids, torch.zeros(2, H)), work / "embedding" / "model.onnx",
                           ["input_ids", "image_features"], ["inputs_embeds"], dynamic_shapes=dims,
                           external_data=True)
    del emb8
    emb = embedding_wrapper(model, IMAGE_TOKEN)
    epar = C.parity_check(epath, torch_reference(emb, ["input_ids", "image_features"]), fp32["emb_inputs"],
                          precision="int8-dynamic", trials=4, label="qwen embedding int8 vs fp32 table")
    return {"vision": vpath, "embedding": epath, "parity": {"vision": vpar, "embedding": epar},
            "block": block, "vision_quant": VISION_QUANTS[vision_quant].format(block=block),
            "precision": {"vision": {"fp32": "fp32", "nbits4": "int4"}.get(vision_quant, "int8"), "embedding": "int8"},
            "embedding_quant": "int8 table, one fp32 scale per %d columns (Gather + Cast + Mul)" % block}


def chat_prompt(text: str, n_images: int) -> str:
    """The Qwen2.5-VL chat template (one user turn; GenAI's processor expands each <|image_pad|>)."""
    img = "<|vision_start|><|image_pad|><|vision_end|>" * n_images
    return (f"<|im_start|>system\nYou are a helpful assistant.<|im_end|>\n<|im_start|>user\n{img}{text}<|im_end|>\n"
            f"<|im_start|>assistant\n")


def genai_generate(pkg: Path, image_path: str | None, prompt: str, n_tokens: int) -> dict[str, Any]:
    """The standard GenAI API on the package as it is: og.Model, og.MultiModalProcessor, og.Generator;
    greedy `n_tokens` new tokens from one image + prompt. Returns ids, the processor's inputs, first-step
    logits and timings."""
    import onnxruntime_genai as og

    t0 = time.time()
    model = og.Model(str(pkg))
    proc = model.create_multimodal_processor()
    t1 = time.time()
    images = og.Images.open(image_path) if image_path else None
    inputs = proc(chat_prompt(prompt, 1 if image_path else 0), images=images)
    feeds = {k: inputs[k].as_numpy().copy() for k in ("input_ids", "pixel_values", "image_grid_thw")
             if image_path or k == "input_ids"}
    params = og.GeneratorParams(model)
    params.set_search_options(do_sample=False, top_k=1, max_length=int(feeds["input_ids"].shape[-1]) + n_tokens)
    gen = og.Generator(model, params)
    t2 = time.time()
    gen.set_inputs(inputs)  # 0.18.0 runs vision + embedding + prefill here
    ids, logits0, t_first = [], None, None
    while len(ids) < n_tokens and not gen.is_done():
        gen.generate_next_token()
        if logits0 is None:
            t_first = time.time() - t2
            logits0 = np.asarray(gen.get_output("logits"), np.float32).reshape(-1)[-model_vocab(pkg):]
        ids.append(int(gen.get_next_tokens()[0]))
    total = time.time() - t2
    del gen, model
    return {"ids": ids, "feeds": feeds, "logits0": logits0, "load_s": t1 - t0, "first_token_s": t_first,
            "decode_tok_s": (len(ids) - 1) / max(total - t_first, 1e-9) if len(ids) > 1 else None,
            "total_s": total}


def model_vocab(pkg: Path) -> int:
    return int(json.loads((Path(pkg) / "genai_config.json").read_text())["model"]["vocab_size"])


def hf_generate_ids(ckpt: Path, feeds: dict[str, np.ndarray], n_tokens: int) -> tuple[list[int], np.ndarray]:
    """transformers' greedy generate (fp32) on the GenAI processor's own inputs: the fp32 token reference,
    and its first-step logits."""
    import torch
    from transformers import Qwen2_5_VLForConditionalGeneration

    model = Qwen2_5_VLForConditionalGeneration.from_pretrained(str(ckpt), dtype=torch.float32).eval()
    ids = torch.from_numpy(feeds["input_ids"].astype(np.int64)).reshape(1, -1)
    kw = {}
    if "pixel_values" in feeds:
        # mm_token_type_ids (1 = image token): without it transformers 5 falls back to 1-D positions, not M-RoPE
        kw = {"pixel_values": torch.from_numpy(feeds["pixel_values"]),
              "image_grid_thw": torch.from_numpy(feeds["image_grid_thw"].astype(np.int64)),
              "mm_token_type_ids": (ids == IMAGE_TOKEN).int()}
    with torch.no_grad():
        out = model.generate(input_ids=ids, attention_mask=torch.ones_like(ids), max_new_tokens=n_tokens,
                             do_sample=False, num_beams=1, eos_token_id=None, pad_token_id=151643,
                             output_logits=True, return_dict_in_generate=True, **kw)
    return out.sequences[0, ids.shape[1]:].tolist(), out.logits[0][0].float().numpy()


def kl_next_token(ref_logits: np.ndarray, logits: np.ndarray) -> float:
    """KL(p_ref || p) of the next-token distributions (nats)."""
    def logsoft(x):
        x = x.astype(np.float64) - x.max()
        return x - np.log(np.exp(x).sum())

    lp, lq = logsoft(ref_logits), logsoft(logits)
    return float((np.exp(lp) * (lp - lq)).sum())


def check_image(path: Path, size: int = 320) -> Path:
    """A fixed synthetic test picture (PNG) for the package check: shapes on a gradient, not dataset data."""
    import cv2

    y, x = np.mgrid[0:size, 0:size]
    img = np.stack([x * 255 // size, y * 255 // size, (x + y) * 127 // size], -1).astype(np.uint8)
    cv2.rectangle(img, (40, 60), (150, 200), (255, 0, 0), -1)
    cv2.circle(img, (230, 120), 50, (0, 200, 0), -1)
    cv2.imwrite(str(path), img[..., ::-1])
    return path


def _builder_precision(variant: str) -> str | None:
    return {"fp32": "fp32", "int8-dynamic": "int8", "int8-qdq": "int8", "int4": "int4"}.get(variant)


def assemble_package(pkg: Path, dec_dir: Path, graphs: dict[str, Any], ckpt: Path, vc: Any, image_size: int,
                     context_length: int) -> Path:
    """One variant's GenAI package folder: builder decoder (moved), vision/embedding (linked), configs, tokenizer."""
    if pkg.exists():
        shutil.rmtree(pkg)
    (pkg / "decoder").mkdir(parents=True)
    builder_cfg = json.loads((dec_dir / "genai_config.json").read_text())
    for f in dec_dir.iterdir():
        if f.name.startswith(builder_cfg["model"]["decoder"]["filename"]):
            shutil.move(str(f), pkg / "decoder" / f.name)
    for c in ("vision", "embedding"):
        for f in Path(graphs[c]).parent.iterdir():
            _link(f, pkg / c / f.name)
    tok_src = dec_dir if (dec_dir / "tokenizer.json").is_file() else ckpt
    for name in ("tokenizer.json", "tokenizer_config.json", "special_tokens_map.json", "vocab.json", "merges.txt"):
        if (tok_src / name).is_file():
            shutil.copyfile(tok_src / name, pkg / name)
        elif (ckpt / name).is_file():
            shutil.copyfile(ckpt / name, pkg / name)
    if not (pkg / "tokenizer.json").is_file():
        raise ExportError(f"{ckpt}: no tokenizer.json (the GenAI package needs one)")
    (pkg / "genai_config.json").write_text(jsonio.dumps(genai_config(builder_cfg, vc, context_length), indent=2))
    (pkg / "processor_config.json").write_text(jsonio.dumps(processor_config(image_size, vc), indent=2))
    return pkg


def package_check(pkg: Path, ckpt: Path, work: Path, variant: str, n_tokens: int, fp32_ref: dict | None,
                  hf_check: bool) -> dict[str, Any]:
    """Acceptance: GenAI loads the package as it is and makes `n_tokens` from an image + prompt. fp32 (when
    hf_check): the tokens must equal transformers' greedy generate on the same processor inputs; lower
    precisions: KL of the first next-token distribution vs the fp32 package (token agreement is meaningless on
    random weights, recorded only)."""
    img = check_image(work / "check.png")
    r = genai_generate(pkg, str(img), "Where is the red box? Answer with one word.", n_tokens)
    res = {"ok": len(r["ids"]) == n_tokens, "tokens": r["ids"], "prompt_tokens": int(r["feeds"]["input_ids"].size),
           "image_grid_thw": r["feeds"]["image_grid_thw"].reshape(-1).tolist(), "load_s": round(r["load_s"], 2),
           "first_token_s": round(r["first_token_s"], 3)}
    if variant == "fp32" and hf_check:
        hf_ids, hf_logits = hf_generate_ids(ckpt, r["feeds"], n_tokens)
        agree = float(np.mean([a == b for a, b in zip(hf_ids, r["ids"])])) if hf_ids else 0.0
        rel = float(np.abs(hf_logits - r["logits0"]).max() / max(np.abs(hf_logits).max(), 1e-12))
        res.update(hf_tokens=hf_ids, token_agreement_vs_transformers=agree, logits_rel_err_vs_transformers=rel,
                   kl_vs_transformers=kl_next_token(hf_logits, r["logits0"]))
        res["ok"] = res["ok"] and agree == 1.0 and rel < 1e-3
    if fp32_ref is not None and variant != "fp32":
        res["kl_vs_fp32"] = kl_next_token(fp32_ref["logits0"], r["logits0"])
        res["token_agreement_vs_fp32"] = float(np.mean([a == b for a, b in zip(fp32_ref["ids"], r["ids"])]))
    C.progress(f"vlm/{variant} GenAI check: {n_tokens} tokens {r['ids']} "
               + ", ".join(f"{k} {v:.3g}" for k, v in res.items() if k.startswith(("kl_", "token_agree", "logits_"))))
    return {"result": res, "logits0": r["logits0"], "ids": r["ids"]}


def side_only_check(fp32_pkg: Path, g8: dict[str, Any], work: Path, n_tokens: int,
                    fp32_ref: dict[str, Any]) -> dict[str, Any]:
    """The fp32 package with its vision + embedding swapped for the int8 ones (hard links, a scratch folder):
    KL of the first next-token distribution vs the fp32 package -- what the int8 side alone costs, apart from
    the decoder's quantisation."""
    pkg = work / "side-check"
    shutil.rmtree(pkg, ignore_errors=True)
    for f in fp32_pkg.rglob("*"):
        if f.is_file() and f.parent.name not in ("vision", "embedding"):
            _link(f, pkg / f.relative_to(fp32_pkg))
    for c in ("vision", "embedding"):
        for f in Path(g8[c]).parent.iterdir():
            _link(f, pkg / c / f.name)
    r = package_check(pkg, fp32_pkg, work, "fp32+int8-side", n_tokens, fp32_ref, False)["result"]
    shutil.rmtree(pkg)
    return {k: r[k] for k in ("kl_vs_fp32", "token_agreement_vs_fp32", "tokens")}


def export_qwen_vl(source: str, out: str | Path, precisions: Sequence[str], *, image_size: int = 448,
                   check_tokens: int = 8, hf_check: int | None = None, context_length: int = 4096,
                   side: str = "int8", side_block: int = 128, vision_quant: str = "dynamic",
                   workdir: str | None = None, **_: Any) -> dict[str, Any]:
    """Add the vlm role as GenAI packages (one per precision: fp32, int8, int4) to the bundle at `out`.

    image_size: the fixed map-image side S (multiple of 28); hf_check: compare fp32 tokens with transformers
    (default on for tiny, off at real size where fp32 transformers alone needs ~15 GB); side: precision of the
    vision graph and the embedding table in the int8 / int4 packages (int8: 2.7 GB less at 3B; fp32: as the
    fp32 package), side_block: their int8 block size (columns per scale); vision_quant: how the int8 side's
    vision graph is quantised (VISION_QUANTS: dynamic | nbits8 | nbits4 | fp32 = int8 table, fp32 vision)."""
    import tempfile

    from mosaicthinker.host import bundle_write as B

    from .hf_common import drop_role

    if image_size % 28:
        raise ExportError(f"--option image_size={image_size}: must be a multiple of 28 (patch 14 x merge 2)")
    if side not in ("int8", "fp32"):
        raise ExportError(f"--option side={side}: expected int8 or fp32 (vision + embedding of int8/int4 packages)")
    out = Path(out)
    variants = [v for v in dict.fromkeys(precisions) if _builder_precision(v)]
    variants = list(dict.fromkeys("int8" if v.startswith("int8") else v for v in variants))
    skipped = {v: "no GenAI builder precision (CPU: fp32, int8, int4)" for v in precisions if not _builder_precision(v)}
    tmp = tempfile.TemporaryDirectory(prefix="mosaic-qwen-", dir=workdir)
    work = Path(tmp.name)
    report: dict[str, Any] = {"variants": {}, "skipped": skipped}
    try:
        ckpt, prov = resolve_checkpoint(source, work)
        hf_check = bool(prov["random_weights"] and source.startswith("tiny")) if hf_check is None else bool(hf_check)
        builds = {v: run_builder(ckpt, work / f"dec-{v}", _builder_precision(v) or v, work / "cache")
                  for v in variants}  # child processes first: this process holds no model meanwhile
        t = time.time()
        model = load_vision_side(ckpt)
        vc = model.config.vision_config
        graphs = export_graphs(model, work / "graphs", image_size)
        graphs["seconds"] = round(time.time() - t, 1)
        sides = {v: graphs for v in variants}
        if side == "int8" and any(v != "fp32" for v in variants):
            t = time.time()
            g8 = export_int8_graphs(model, graphs, work / "graphs-int8", int(side_block), str(vision_quant))
            g8.update(seconds=round(time.time() - t, 1), image_tokens=graphs["image_tokens"], vocab=graphs["vocab"])
            sides.update({v: g8 for v in variants if v != "fp32"})
        del model
        drop_role(out, "vlm")
        fp32_ref = None
        for v in variants:
            pkg = assemble_package(out / "vlm" / v, work / f"dec-{v}", sides[v], ckpt, vc, image_size, context_length)
            chk = package_check(pkg, ckpt, work, v, check_tokens, fp32_ref, hf_check)
            if v == "fp32":
                fp32_ref = chk
                if not chk["result"]["ok"]:
                    raise ExportError(f"vlm/fp32 GenAI package check failed: {chk['result']}")
            sp = sides[v].get("precision", {"vision": "fp32", "embedding": "fp32"})
            if sides[v] is not graphs and fp32_ref is not None:  # the int8 side alone: fp32 decoder + int8 vision/embedding
                chk["result"]["side_only"] = side_only_check(out / "vlm" / "fp32", sides[v], work, check_tokens,
                                                             fp32_ref)
            _add_variant(out, v, pkg, prov, sides[v], builds[v], chk["result"], image_size, vc, sp)
            report["variants"][v] = {"components": {"decoder": v, **sp},
                                     "parity": {**sides[v]["parity"], "decoder": None}, "task": chk["result"],
                                     "build": builds[v], "side_seconds": sides[v]["seconds"]}
    finally:
        if os.environ.get("MOSAIC_KEEP_WORK"):
            C.progress(f"work folder kept: {work}")
        else:
            tmp.cleanup()
    B.load_bundle(out)  # every listed file re-hashed
    return report


def _add_variant(out: Path, v: str, pkg: Path, prov: dict, graphs: dict, build: dict, check: dict,
                 image_size: int, vc: Any, side: dict[str, str] | None = None) -> None:
    from mosaicthinker.host import bundle_write as B

    comps, files = package_components(out, pkg)
    cfg = {"family": ARCH, "runtime": "onnxruntime-genai", "genai_version": GENAI_VERSION, "image_size": image_size,
           "image_token_id": IMAGE_TOKEN, "image_seq_len": graphs["image_tokens"], "max_new_tokens": 64,
           "stop_tokens": ["<|im_end|>", "<|endoftext|>"], "vocab_size": graphs["vocab"]}
    pre = {"size": [image_size, image_size], "layout": "patches", "channel_order": "RGB", "dtype": "float32",
           "scale": 1 / 255, "mean": CLIP_MEAN, "std": CLIP_STD, "resize": "bilinear", "keep_aspect": False,
           "done_by": "processor_config.json (GenAI MultiModalProcessor)"}
    big = prov.get("random", {}).get("size") == "3b" or "3B" in prov["source"]
    meta = C.role_meta(ARCH, preprocessing=pre, semantics={"kind": "vlm", "tiling": False}, provenance=prov,
                       licence="LicenseRef-Qwen-Research" if big else "Apache-2.0",
                       random_weights=prov["random_weights"], config=cfg)
    from mosaicthinker.runtime.query.ir import SCHEMA_VERSION

    genai = {"package": pkg.relative_to(out).as_posix(), "version": GENAI_VERSION, "files": files,
             "guidance": {"json_schema": SCHEMA_VERSION},  # the question-program schema it decodes under
             "builder": {k: build[k] for k in ("seconds", "peak_rss_mb")},
             "graphs_export_s": graphs["seconds"],
             "component_precision": {"decoder": v, **(side or {"vision": "fp32", "embedding": "fp32"})}}
    if "vision_quant" in graphs:
        genai["side_quant"] = {"vision": graphs["vision_quant"], "embedding": graphs["embedding_quant"]}
    B.add_variant(out, "vlm", v, comps, role_meta=meta, precision=v, parity=graphs["parity"],
                  notes=f"ONNX Runtime GenAI package: decoder from the GenAI model builder ({v}); vision "
                        f"{genai['component_precision']['vision']}, embedding "
                        f"{genai['component_precision']['embedding']}",
                  extra={"genai": genai, "task_check": check}, default=(v == "int4"))


def export_role(role: str, source: str, precisions: Sequence[str], out: str | Path, *, calib: str | None = None,
                options: dict[str, str] | None = None, **_: Any) -> dict[str, Any]:
    """`mosaic export vlm --source hf:Qwen/Qwen2.5-VL-3B-Instruct | dir:PATH | tiny:qwen2_5_vl`."""
    from .hf_common import run_exporter

    return run_exporter(export_qwen_vl, source, precisions, out, calib=None, options=options)


def is_qwen_source(source: str) -> bool:
    """Whether `source` names a Qwen2.5-VL checkpoint (hf id, tiny arch, or a folder whose config says so)."""
    if source.startswith("tiny"):
        return source.split(":", 1)[-1] in ("qwen2_5_vl", "qwen2.5-vl")
    if source.startswith("dir:"):
        cfg = Path(source[4:]) / "config.json"
        return cfg.is_file() and json.loads(cfg.read_text()).get("model_type") == "qwen2_5_vl"
    return "qwen2.5-vl" in source.lower() or "qwen2_5_vl" in source.lower()
