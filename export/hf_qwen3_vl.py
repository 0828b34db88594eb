"""Qwen3-VL as the project's own vision + embed + decoder-with-KV-cache graphs (the runtime loop drives them).

Why not an ONNX Runtime GenAI package like Qwen2.5-VL: onnxruntime-genai 0.18.0's builder makes the Qwen3-VL
text decoder (`Qwen3VLForConditionalGeneration` -> `Qwen3VLTextModel`), but that graph has no input for
DeepStack -- Qwen3-VL adds the vision tower's intermediate features (blocks `deepstack_visual_indexes`, each
through its own patch merger) to the hidden states of the first decoder layers at the image-token positions --
and no string of the 0.18.0 library or builder mentions DeepStack, so a GenAI package would silently drop it
(a different model). The issue's rule applies: where the builder lacks an architecture, keep the project's own
graphs and loop (runtime/models/vlm.py: `MRopeDecoder`, `Qwen3VL`).

Graphs (numpy I/O; fixed image grid S x S like the Qwen2.5-VL package, S a multiple of 32):
- vision:  `pixel_values [P, 3*2*16*16]` (P = (S/16)^2 patches, merge-unit order) -> `image_features [P/4, H]`,
           `deepstack_features [K, P/4, H]` (K = len(deepstack_visual_indexes)). The learned position table is
           resampled with transformers' own interpolation indices/weights and the 2-D rotary table is computed
           by its rotary module, both for the fixed grid (constants).
- embed:   `input_ids [1, L]` -> `inputs_embeds [1, L, H]`.
- decoder: `inputs_embeds [1, L, H]`, `attention_mask [1, P+L]`, `position_ids [3, 1, L]` (M-RoPE t/h/w,
           interleaved), `deepstack [K, 1, L, H]` (the DeepStack features scattered to the image-token rows,
           zeros elsewhere: adding zeros is exact, and it keeps the graph free of data-dependent shapes),
           `past_key_i / past_value_i [1, KV, P, D]` -> `logits [1, 1, V]` (last position only),
           `present_key_i / present_value_i`.

Checks at export: each graph vs its torch wrapper on fresh inputs (export_variants), the vision wrapper vs
transformers' own `model.visual` (merged and DeepStack features), and the runtime loop's greedy tokens vs
transformers' `generate` on the same ids + pixel values (fp32: all must agree).
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from mosaicthinker.runtime.infra import jsonio
from mosaicthinker.runtime.infra.errors import ExportError

from . import common as C

ARCH = "qwen3_vl"
from .hf_qwen_vl import IMAGE_TOKEN, QWEN_VOCAB, VISION_END, VISION_START, write_synthetic_tokenizer  # noqa: E402

# Qwen/Qwen3-VL-2B-Instruct's dimensions (vision: depth 24, hidden 1024, MLP 4096, 16 heads, patch 16, merge 2,
# 2304 learned positions, DeepStack from blocks 5/11/17, out 2048; text: 2048 hidden, 28 layers, 16 heads,
# 8 KV heads, head_dim 128, MLP 6144, vocab 151 936, tied embeddings, rope_theta 5e6, interleaved M-RoPE
# sections 24/20/20). Checked without network against pytorch/torchtitan's "2B" Qwen3-VL config
# (torchtitan/experiments/qwen3_vl/__init__.py, commit 0375bb67): every dimension above agrees. Not in that
# source (kept from the published config as recalled): hidden_act, rms_norm_eps 1e-6, max_position_embeddings
# 262144 (only sizes the rotary cache). A `dir:`/`hf:` export reads the checkpoint's own config.json anyway.
REAL_2B = dict(
    text=dict(hidden_size=2048, intermediate_size=6144, num_hidden_layers=28, num_attention_heads=16,
              num_key_value_heads=8, head_dim=128, vocab_size=QWEN_VOCAB, max_position_embeddings=262144,
              rms_norm_eps=1e-6, hidden_act="silu", tie_word_embeddings=True,
              rope_parameters={"rope_type": "default", "rope_theta": 5000000.0, "mrope_section": [24, 20, 20],
                               "mrope_interleaved": True}),
    vision=dict(depth=24, hidden_size=1024, intermediate_size=4096, num_heads=16, out_hidden_size=2048,
                patch_size=16, spatial_merge_size=2, temporal_patch_size=2, num_position_embeddings=2304,
                deepstack_visual_indexes=[5, 11, 17], hidden_act="gelu_pytorch_tanh"),
)
TINY = dict(
    text=dict(hidden_size=64, intermediate_size=128, num_hidden_layers=3, num_attention_heads=4,
              num_key_value_heads=2, head_dim=16, vocab_size=QWEN_VOCAB, max_position_embeddings=4096,
              rms_norm_eps=1e-6, hidden_act="silu", tie_word_embeddings=True,
              rope_parameters={"rope_type": "default", "rope_theta": 5000000.0, "mrope_section": [2, 3, 3],
                               "mrope_interleaved": True}),
    vision=dict(depth=3, hidden_size=32, intermediate_size=64, num_heads=2, out_hidden_size=64, patch_size=16,
                spatial_merge_size=2, temporal_patch_size=2, num_position_embeddings=64,
                deepstack_visual_indexes=[0, 1], hidden_act="gelu_pytorch_tanh"),
)
SIZES = {"tiny": TINY, "2b": REAL_2B}
STOP_TOKENS = ["<|im_end|>", "<|endoftext|>"]


def qwen3_config(size: str):
    """transformers' `Qwen3VLConfig` at `size` ("tiny" test dims or "2b")."""
    from transformers import Qwen3VLConfig

    d = SIZES[size]
    return Qwen3VLConfig(text_config=dict(d["text"]), vision_config=dict(d["vision"]), image_token_id=IMAGE_TOKEN,
                         video_token_id=151656, vision_start_token_id=VISION_START, vision_end_token_id=VISION_END,
                         tie_word_embeddings=True, architectures=["Qwen3VLForConditionalGeneration"])


def random_model(size: str, seed: int = 0) -> Any:
    import torch
    from transformers import Qwen3VLForConditionalGeneration

    from .tiny import torch_default_init

    torch.manual_seed(seed)
    model = Qwen3VLForConditionalGeneration(qwen3_config(size)).float().eval()
    torch_default_init(model)  # fan-in init: O(1) activations, so random logits are not flat
    return model


def random_checkpoint(size: str, dst: str | Path, *, dtype: str = "bfloat16", seed: int = 0) -> Path:
    """`save_pretrained` of a seeded random Qwen3-VL of `size` (built in `dtype`: bf16 halves the 2B build's
    memory) with the synthetic Qwen tokenizer and the RANDOM_WEIGHTS.json marker a `dir:` export records."""
    import torch
    from transformers import Qwen3VLForConditionalGeneration

    from .hf_qwen_vl import RANDOM_MARKER
    from .tiny import torch_default_init

    dst = Path(dst)
    dst.mkdir(parents=True, exist_ok=True)
    torch.manual_seed(seed)
    prev = torch.get_default_dtype()
    torch.set_default_dtype(getattr(torch, dtype))
    try:
        model = Qwen3VLForConditionalGeneration(qwen3_config(size)).eval()
    finally:
        torch.set_default_dtype(prev)
    torch_default_init(model)  # fan-in init: O(1) activations, so random logits are not flat
    model.save_pretrained(str(dst))
    n = sum(p.numel() for p in model.parameters())
    del model
    write_synthetic_tokenizer(dst)
    (dst / RANDOM_MARKER).write_text(jsonio.dumps({"random_weights": True, "size": size, "seed": seed,
                                                 "dtype": dtype, "parameters": n}))
    return dst


def is_qwen3_source(source: str) -> bool:
    if source.startswith("tiny"):
        return source.split(":", 1)[-1] in ("qwen3_vl", "qwen3-vl")
    if source.startswith("dir:"):
        cfg = Path(source[4:]) / "config.json"
        return cfg.is_file() and json.loads(cfg.read_text()).get("model_type") == "qwen3_vl"
    return "qwen3-vl" in source.lower() or "qwen3_vl" in source.lower()


# ------------------------------------------------------------------------------------------------ wrappers

def vision_wrapper(model: Any, image_size: int):
    """pixel_values [P, 3*T*p*p] -> (image_features [P/m^2, H], deepstack_features [K, P/m^2, H]), fixed grid."""
    import torch
    from transformers.models.qwen3_vl.modeling_qwen3_vl import apply_rotary_pos_emb_vision
    from transformers.vision_utils import get_vision_interpolation_indices_and_weights, get_vision_position_ids

    visual = model.model.visual
    vc = visual.config
    if image_size % (vc.patch_size * vc.spatial_merge_size):
        raise ExportError(f"image_size {image_size}: must be a multiple of {vc.patch_size * vc.spatial_merge_size}")
    g = image_size // vc.patch_size
    grid = torch.tensor([[1, g, g]])
    idx, wts = get_vision_interpolation_indices_and_weights(
        grid, num_grid_per_side=visual.num_grid_per_side, mode=visual.interpolation_mode,
        align_corners=visual.interpolation_align_corners, spatial_merge_size=vc.spatial_merge_size)
    pos = get_vision_position_ids(grid, vc.spatial_merge_size)
    with torch.no_grad():
        cos, sin = visual.rotary_pos_emb(torch.zeros(g * g, 1), pos)

    class VisionGraph(torch.nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.visual = visual
            self.ds = list(vc.deepstack_visual_indexes)
            for n, t in (("idx", idx), ("wts", wts.float()), ("cos", cos.float()), ("sin", sin.float())):
                self.register_buffer(n, t, persistent=False)

        def attn(self, a, x):  # one image: full attention over its patches
            n = x.shape[0]
            q, k, v = a.qkv(x).reshape(n, 3, a.num_heads, -1).permute(1, 0, 2, 3).unbind(0)
            q, k = apply_rotary_pos_emb_vision(q, k, self.cos, self.sin)
            q, k, v = (t.transpose(0, 1)[None] for t in (q, k, v))
            o = torch.nn.functional.scaled_dot_product_attention(q, k, v)
            return a.proj(o[0].transpose(0, 1).reshape(n, -1))

        def forward(self, pixel_values):
            h = self.visual.patch_embed(pixel_values)
            h = h + (self.visual.pos_embed(self.idx) * self.wts[:, :, None]).sum(1)
            deep = []
            for i, blk in enumerate(self.visual.blocks):
                h = h + self.attn(blk.attn, blk.norm1(h))
                h = h + blk.mlp(blk.norm2(h))
                if i in self.ds:
                    deep.append(self.visual.deepstack_merger_list[self.ds.index(i)](h))
            return self.visual.merger(h), torch.stack(deep, 0)

    return VisionGraph().eval(), g * g


def decoder_wrapper(model: Any):
    """inputs_embeds, attention_mask, position_ids [3, 1, L], deepstack [K, 1, L, H], *past -> logits
    [1, 1, V] (the last position's), *presents.
    transformers' own text model, with its DeepStack step (masked row add) replaced by the dense add of
    features already scattered to the image rows (same numbers: the other rows get + 0)."""
    import types

    import torch
    from transformers import DynamicCache

    text = model.model.language_model
    dense = types.MethodType(lambda self, h, mask, v: h + v.to(h.dtype), text)
    n_layers = text.config.num_hidden_layers

    class DecoderGraph(torch.nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.text = text
            self.lm_head = model.lm_head

        def forward(self, inputs_embeds, attention_mask, position_ids, deepstack, *past):
            cache = DynamicCache(ddp_cache_data=[(past[2 * i], past[2 * i + 1]) for i in range(n_layers)],
                                 config=self.text.config)
            self.text._deepstack_process = dense  # only inside this call: transformers' generate keeps its own
            try:
                out = self.text(inputs_embeds=inputs_embeds, attention_mask=attention_mask,
                                position_ids=position_ids, cache=cache, use_cache=True, visual_pos_masks=None,
                                deepstack_visual_embeds=[deepstack[i] for i in range(deepstack.shape[0])])
            finally:
                del self.text._deepstack_process
            presents = []
            for layer in out.cache.layers:
                presents += [layer.keys, layer.values]
            # the last position's logits only (transformers' generate: logits_to_keep=1): the lm_head over
            # every prompt row cost ~20% of a 2B prefill and greedy decoding reads only the last row
            return (self.lm_head(out.last_hidden_state[:, -1:]), *presents)

    return DecoderGraph().eval()


def hf_vision(model: Any, pixel_values: np.ndarray, image_size: int) -> list[np.ndarray]:
    """transformers' own vision forward: [merged features, stacked DeepStack features] (the reference)."""
    import torch

    g = image_size // model.config.vision_config.patch_size
    with torch.no_grad():
        o = model.model.visual(torch.from_numpy(pixel_values), grid_thw=torch.tensor([[1, g, g]]))
    return [o.pooler_output.float().numpy(), torch.stack(list(o.deepstack_features), 0).float().numpy()]


def hf_generate(model: Any, ids: list[int], pixel_values: np.ndarray, image_size: int, n_new: int) -> list[int]:
    """transformers' greedy generate on the same ids + pixel values (M-RoPE via mm_token_type_ids)."""
    import torch

    g = image_size // model.config.vision_config.patch_size
    t = torch.tensor([ids])
    with torch.no_grad():
        out = model.generate(input_ids=t, attention_mask=torch.ones_like(t),
                             pixel_values=torch.from_numpy(pixel_values),
                             image_grid_thw=torch.tensor([[1, g, g]]), mm_token_type_ids=(t == IMAGE_TOKEN).int(),
                             max_new_tokens=n_new, do_sample=False, num_beams=1, eos_token_id=None,
                             pad_token_id=151643)
    return out[0, len(ids):].tolist()


# ------------------------------------------------------------------------------------------------ export

def load_model(source: str) -> tuple[Any, dict[str, Any]]:
    """(fp32 eval model, provenance) for `tiny[:qwen3_vl]` (random tiny dims), `dir:PATH` or `hf:ID`."""
    from transformers import Qwen3VLForConditionalGeneration

    from .hf_qwen_vl import RANDOM_MARKER

    if source.startswith("tiny"):
        return random_model("tiny"), {"source": "tiny:qwen3_vl", "arch": ARCH, "random_weights": True, "seed": 0}
    if source.startswith("dir:"):
        path = Path(source[4:])
        marker = path / RANDOM_MARKER
        rnd = json.loads(marker.read_text()) if marker.is_file() else None
        prov = {"source": source, "arch": ARCH, "random_weights": rnd is not None, **({"random": rnd} if rnd else {})}
    elif source.startswith("hf:"):
        path, prov = source[3:], {"source": source, "arch": ARCH, "random_weights": False}
    else:
        raise ExportError(f"--source {source}: expected hf:ID, dir:PATH or tiny:qwen3_vl")
    model = Qwen3VLForConditionalGeneration.from_pretrained(str(path), dtype="float32").eval()
    return model, prov


def _tokenizer(out: Path, source: str, random_weights: bool) -> Path:
    """OUT/vlm/tokenizer.json: the synthetic Qwen tokenizer (real vocabulary size and special ids) for random
    weights, else the checkpoint's own."""
    import tempfile

    from .hf_common import write_tokenizer

    def synthetic(dst: Path) -> Path:
        with tempfile.TemporaryDirectory() as t:
            dst.write_bytes(write_synthetic_tokenizer(t).read_bytes())
        return dst

    return write_tokenizer(out, "vlm", source, random_weights, synthetic)


def runtime_config(model: Any, image_size: int) -> dict[str, Any]:
    tc, vc = model.config.text_config, model.config.vision_config
    g = image_size // vc.patch_size // vc.spatial_merge_size
    return {"family": ARCH, "num_layers": int(tc.num_hidden_layers), "num_kv_heads": int(tc.num_key_value_heads),
            "head_dim": int(tc.head_dim), "hidden_size": int(tc.hidden_size), "vocab_size": int(tc.vocab_size),
            "image_token_id": IMAGE_TOKEN, "image_seq_len": g * g, "merged_grid": [g, g], "image_size": image_size,
            "patch_size": int(vc.patch_size), "merge_size": int(vc.spatial_merge_size),
            "temporal_patch_size": int(vc.temporal_patch_size),
            "deepstack_layers": len(vc.deepstack_visual_indexes), "stop_tokens": STOP_TOKENS,
            "max_new_tokens": 64, "pad_token_id": 151643}


def graph_specs(model: Any, image_size: int) -> list[Any]:
    """GraphSpecs (export/hf_common.py) of the vision, embed and decoder graphs with their fresh-input draws."""
    import torch

    from .hf_common import GraphSpec
    from .hf_vlm import embed_wrapper

    cfg = runtime_config(model, image_size)
    vision, P = vision_wrapper(model, image_size)
    vc = model.config.vision_config
    pdim = 3 * vc.temporal_patch_size * vc.patch_size ** 2
    L, KV, D, H, V, K = (cfg[k] for k in ("num_layers", "num_kv_heads", "head_dim", "hidden_size", "vocab_size",
                                          "deepstack_layers"))
    scale = float(model.get_input_embeddings().weight.detach().std())

    def dec_inputs(rng, s=None, p=None):
        s = int(rng.integers(1, 6)) if s is None else s
        p = int(rng.integers(0, 9)) if p is None else p
        f = {"inputs_embeds": (scale * rng.standard_normal((1, s, H))).astype(np.float32),
             "attention_mask": np.ones((1, p + s), np.int64),
             "position_ids": np.stack([np.arange(p, p + s)] * 3)[:, None].astype(np.int64)
             + rng.integers(0, 3, size=(3, 1, s)),
             "deepstack": (scale * rng.standard_normal((K, 1, s, H)) * (rng.random((1, 1, s, 1)) < 0.5)
                           ).astype(np.float32)}
        for i in range(L):
            f[f"past_key_{i}"] = rng.standard_normal((1, KV, p, D)).astype(np.float32)
            f[f"past_value_{i}"] = rng.standard_normal((1, KV, p, D)).astype(np.float32)
        return f

    names = ["inputs_embeds", "attention_mask", "position_ids", "deepstack"] + [
        f"past_{kv}_{i}" for i in range(L) for kv in ("key", "value")]
    ex = dec_inputs(np.random.default_rng(1), s=3, p=4)
    Sd, Pd = torch.export.Dim("seq", min=1, max=8192), torch.export.Dim("past", min=0, max=8192)
    tot = torch.export.Dim("total", min=1, max=16384)
    dyn = ({1: Sd}, {1: tot}, {2: Sd}, {2: Sd}, tuple({2: Pd} for _ in names[4:]))
    return [
        GraphSpec("vision", vision, (torch.zeros(P, pdim),), ["pixel_values"], ["image_features", "deepstack_features"],
                  lambda rng: {"pixel_values": rng.standard_normal((P, pdim)).astype(np.float32)}),
        GraphSpec("embed", embed_wrapper(model), (torch.randint(0, V, (1, 4)),), ["input_ids"], ["inputs_embeds"],
                  lambda rng: {"input_ids": rng.integers(0, V, size=(1, int(rng.integers(1, 9)))).astype(np.int64)},
                  dynamic_shapes={"input_ids": {1: Sd}}, quantize=False),
        GraphSpec("decoder", decoder_wrapper(model), tuple(torch.from_numpy(ex[n]) for n in names), names,
                  ["logits"] + [f"present_{kv}_{i}" for i in range(L) for kv in ("key", "value")], dec_inputs,
                  dynamic_shapes=dyn),
    ]


def task_check(model: Any, files: dict[str, Path], cfg: dict[str, Any], tok_path: Path, pre: dict[str, Any],
               variant: str, n_new: int, seed: int = 0) -> dict[str, Any]:
    """The runtime loop (MRopeDecoder over onnxruntime) vs transformers' greedy generate on the same ids and
    pixel values (fp32: every token, and the vision graph vs transformers' own vision forward)."""
    from mosaicthinker.runtime.models import preprocess_image
    from mosaicthinker.runtime.models.vlm import MRopeDecoder, OrtRunner, build_prompt, load_tokenizer, qwen_patches

    tok = load_tokenizer(str(tok_path))
    core = MRopeDecoder(*(OrtRunner(C.ort_session(files[c])) for c in ("vision", "embed", "decoder")), cfg)
    rng = np.random.default_rng(seed)
    runs, agree, total, vis = [], 0, 0, []
    for prompt in ("how many chairs are in the room?", "which object is closest to the sofa?"):
        rgb = rng.integers(0, 256, size=(40, 56, 3), dtype=np.uint8)
        px = qwen_patches(preprocess_image(rgb, pre)[0], cfg["patch_size"], cfg["merge_size"],
                          cfg["temporal_patch_size"])
        ids = tok.encode(build_prompt(ARCH, prompt, 1, cfg["image_seq_len"]), add_special_tokens=False).ids
        image = core.image_features(px)
        if variant == "fp32":
            vis.append(C.compare_outputs(hf_vision(model, px, cfg["image_size"]), list(image)))
        got = core.generate_ids(ids, image, n_new, [])
        ref = hf_generate(model, ids, px, cfg["image_size"], n_new)
        agree += sum(a == b for a, b in zip(ref, got))
        total += max(len(ref), len(got))
        runs.append({"prompt": prompt, "hf": ref, "ort": got, "prompt_tokens": len(ids)})
    res = {"token_agreement": agree / max(total, 1), "tokens": total, "runs": runs}
    if vis:
        res["vision_vs_transformers"] = {"rel": max(o["rel"] for v in vis for o in v),
                                         "cosine": min(o["cosine"] for v in vis for o in v)}
    return res


def export_qwen3_vl(source: str, out: str | Path, precisions: Sequence[str], *, image_size: int = 448,
                    check_tokens: int = 8, **_: Any) -> dict[str, Any]:
    """Add the vlm role (vision with DeepStack, embed, M-RoPE decoder graphs + tokenizer) to the bundle."""
    from mosaicthinker.runtime.infra.bundle import sha256_file

    from .hf_common import export_variants
    from .hf_vlm import LOW_PRECISION_TOKEN_AGREEMENT

    model, prov = load_model(source)
    out = Path(out)
    tok = _tokenizer(out, source, prov["random_weights"])
    cfg = runtime_config(model, image_size)
    pre = {"size": [image_size, image_size], "layout": "NCHW", "channel_order": "RGB", "dtype": "float32",
           "scale": 1 / 255, "mean": [0.5, 0.5, 0.5], "std": [0.5, 0.5, 0.5], "resize": "bilinear",
           "keep_aspect": False, "then": "qwen_patches (runtime/models/vlm.py)"}

    def task(files: dict[str, Path], variant: str) -> dict[str, Any]:
        res = task_check(model, files, cfg, tok, pre, variant, check_tokens)
        need = 1.0 if variant == "fp32" else LOW_PRECISION_TOKEN_AGREEMENT
        ok = res["token_agreement"] >= need
        if variant == "fp32":
            ok = ok and res["vision_vs_transformers"]["rel"] < 1e-3
        vis = res.get("vision_vs_transformers")
        C.progress(f"qwen3_vl/{variant}: token agreement vs transformers {res['token_agreement']:.3f} over "
                   f"{res['tokens']} tokens" + (f", vision vs transformers rel {vis['rel']:.2e}" if vis else ""))
        return {"ok": bool(ok), "accepted_at": need, **res}

    meta = C.role_meta(ARCH, preprocessing=pre, semantics={"kind": "vlm", "tiling": False}, provenance=prov,
                       licence="Apache-2.0", random_weights=prov["random_weights"], config=cfg,
                       tokenizer={"file": "vlm/tokenizer.json", "sha256": sha256_file(tok)})
    return export_variants(out, "vlm", graph_specs(model, image_size), meta, precisions, task_check=task)


def export_role(role: str, source: str, precisions: Sequence[str], out: str | Path, *, calib: str | None = None,
                options: dict[str, str] | None = None, **_: Any) -> dict[str, Any]:
    """`mosaic export vlm --source tiny:qwen3_vl | dir:PATH | hf:Qwen/Qwen3-VL-2B-Instruct`."""
    from .hf_common import run_exporter

    return run_exporter(export_qwen3_vl, source, precisions, out, calib=None, options=options)
