"""VLM export: SmolVLM (Idefics3 family) and InternVL as vision + embedding + decoder-with-KV-cache graphs.

Graph I/O is documented in runtime/models/vlm.py (the adapter). The decoder graph rebuilds a transformers
`DynamicCache` from flat `past_key_i / past_value_i` tensors and returns the grown cache as flat
`present_key_i / present_value_i`, so the runtime loop owns the cache as plain arrays.

Checks at export (beyond element-wise parity of each graph on fresh random inputs with new sequence/past
lengths): the token check runs the runtime's onnxruntime greedy loop against transformers' `generate` on the
same prompt + image (fp32: every token must agree, else the export fails; lower precisions: the agreement is
recorded in the manifest), and the KV-cache check decodes once with the cache and once re-running the full
sequence without it (must give the same tokens).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

import numpy as np

from mosaicthinker.runtime.infra.errors import ExportError

from . import common as C
from .hf_common import GraphSpec, export_variants, run_exporter, word_level_tokenizer, write_tokenizer
from .sources import load_source
from .tiny import TINY_SPECIALS, TINY_WORDS, TINY_VOCAB, tiny_special_ids  # noqa: F401  (re-exported)

HF_DEFAULTS = {"smolvlm": "HuggingFaceTB/SmolVLM-256M-Instruct", "internvl": "OpenGVLab/InternVL3-1B-hf"}

# fp16/int8 decoders ship when at least this fraction of greedy tokens agree with transformers (fp32 needs all):
# `bundle show` and the README state it next to every such variant.
LOW_PRECISION_TOKEN_AGREEMENT = 0.5

# the tiny models' vocabulary (special ids, word list) is owned by export/tiny.py


def build_tiny_tokenizer(family: str, path: str | Path) -> Path:
    """A WordLevel tokenizer.json with the family's special/image tokens (ids < TINY_VOCAB)."""
    vocab = {t: i for i, t in enumerate(TINY_SPECIALS[family] + TINY_WORDS)}
    if len(vocab) > TINY_VOCAB:
        raise ExportError("tiny tokenizer vocabulary exceeds the tiny model's vocab size")
    return word_level_tokenizer(vocab, TINY_SPECIALS[family], path)


def _family_of(source: str) -> str:
    if source.startswith("tiny"):
        from . import tiny

        return tiny.resolve("vlm", source)
    return "internvl" if "internvl" in source.lower() else "smolvlm"


# ------------------------------------------------------------------------------------------------ wrappers

def vision_wrapper(model: Any, family: str):
    import torch

    class VisionGraph(torch.nn.Module):
        """pixel_values [N, 3, S, S] -> image_features [N, T, H] (connector/projector applied)."""

        def __init__(self) -> None:
            super().__init__()
            self.m = model.model

        def forward(self, pixel_values):
            if family == "smolvlm":
                n, _, h, w = pixel_values.shape
                ps = self.m.config.vision_config.patch_size
                pmask = torch.ones((n, h // ps, w // ps), dtype=torch.bool, device=pixel_values.device)
                hid = self.m.vision_model(pixel_values=pixel_values, patch_attention_mask=pmask).last_hidden_state
                return self.m.connector(hid)
            cfg = self.m.config
            return self.m.get_image_features(pixel_values, vision_feature_layer=cfg.vision_feature_layer,
                                             vision_feature_select_strategy=cfg.vision_feature_select_strategy
                                             ).pooler_output

    return VisionGraph().eval()


def embed_wrapper(model: Any):
    import torch

    class EmbedGraph(torch.nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.emb = model.get_input_embeddings()

        def forward(self, input_ids):
            return self.emb(input_ids)

    return EmbedGraph().eval()


def _text_model(model: Any, family: str):
    return model.model.text_model if family == "smolvlm" else model.model.language_model


def decoder_wrapper(model: Any, family: str):
    import torch
    from transformers import DynamicCache

    text = _text_model(model, family)
    n_layers = text.config.num_hidden_layers

    class DecoderGraph(torch.nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.text = text
            self.lm_head = model.lm_head
            self.n = n_layers

        def forward(self, inputs_embeds, attention_mask, position_ids, *past):
            cache = DynamicCache(ddp_cache_data=[(past[2 * i], past[2 * i + 1]) for i in range(self.n)],
                                 config=self.text.config)
            out = self.text(inputs_embeds=inputs_embeds, attention_mask=attention_mask, position_ids=position_ids,
                            past_key_values=cache, use_cache=True)
            logits = self.lm_head(out.last_hidden_state)
            presents = []
            for layer in out.past_key_values.layers:
                presents += [layer.keys, layer.values]
            return (logits, *presents)

    return DecoderGraph().eval()


def _text_dims(model: Any, family: str) -> dict[str, int]:
    tc = _text_model(model, family).config
    heads = int(tc.num_attention_heads)
    return {"num_layers": int(tc.num_hidden_layers), "num_kv_heads": int(getattr(tc, "num_key_value_heads", heads)),
            "head_dim": int(getattr(tc, "head_dim", None) or tc.hidden_size // heads),
            "hidden_size": int(tc.hidden_size), "vocab_size": int(tc.vocab_size)}


# ------------------------------------------------------------------------------------------------ checks

def hf_generate(model: Any, family: str, ids: list[int], pixel_values: np.ndarray, max_new_tokens: int,
                stop_ids: list[int], pad_id: int) -> list[int]:
    """transformers' greedy `generate` on the same ids + images (the token-agreement reference)."""
    import torch

    px = torch.from_numpy(pixel_values)
    if family == "smolvlm":
        px = px[None]  # [B, N_images, 3, S, S]
    inp = torch.tensor([ids], dtype=torch.long)
    with torch.no_grad():
        out = model.generate(input_ids=inp, attention_mask=torch.ones_like(inp), pixel_values=px,
                             max_new_tokens=max_new_tokens, do_sample=False, eos_token_id=stop_ids,
                             pad_token_id=pad_id, num_beams=1)
    new = out[0, len(ids):].tolist()
    # generate pads after an early stop; keep up to and including the first stop token
    res = []
    for t in new:
        res.append(t)
        if t in stop_ids:
            break
    return res


def token_check(model: Any, family: str, files: dict[str, Path], cfg: dict[str, Any], tokenizer_path: Path,
                pre: dict[str, Any], *, prompts: Sequence[str], max_new_tokens: int, reference_ids=None,
                seed: int = 0) -> dict[str, Any]:
    """Runtime onnxruntime loop vs transformers generate (and, for fp32, the KV-cache consistency check)."""
    from mosaicthinker.runtime.models import preprocess_image
    from mosaicthinker.runtime.models.vlm import GreedyDecoder, OrtRunner, build_prompt, load_tokenizer

    tok = load_tokenizer(str(tokenizer_path))
    core = GreedyDecoder(*(OrtRunner(C.ort_session(files[c])) for c in ("vision", "embed", "decoder")), cfg)
    stop_ids = [tok.token_to_id(t) for t in cfg["stop_tokens"] if tok.token_to_id(t) is not None]
    rng = np.random.default_rng(seed)
    total = agree = 0
    cache_ok = True
    runs = []
    for i, prompt in enumerate(prompts):
        rgb = rng.integers(0, 256, size=(48 + 8 * i, 64, 3), dtype=np.uint8)
        px = preprocess_image(rgb, pre)
        ids = tok.encode(build_prompt(family, prompt, 1, cfg["image_seq_len"]), add_special_tokens=False).ids
        ort_ids = core.generate_ids(ids, core.image_features(px), max_new_tokens, stop_ids)
        ref = hf_generate(model, family, ids, px, max_new_tokens, stop_ids, cfg["pad_token_id"])
        n = max(len(ref), len(ort_ids))
        same = sum(1 for a, b in zip(ref, ort_ids) if a == b)
        # agreement counts positions up to the first divergence-independent length
        total += n
        agree += same
        rec = {"prompt": prompt, "hf": ref, "ort": ort_ids}
        if reference_ids is None:  # fp32: the cache must not change the result
            nc = core.generate_ids_nocache(ids, core.image_features(px), max_new_tokens, stop_ids)
            rec["nocache"] = nc
            cache_ok &= nc == ort_ids
        runs.append(rec)
    frac = agree / max(total, 1)
    return {"token_agreement": frac, "tokens": total,
            "kv_cache_consistent": cache_ok if reference_ids is None else None,
            "runs": runs}


# ------------------------------------------------------------------------------------------------ export

def _vlm_preprocessing(family: str, S: int) -> dict[str, Any]:
    mean, std = ([0.5, 0.5, 0.5], [0.5, 0.5, 0.5]) if family == "smolvlm" else \
        ([0.485, 0.456, 0.406], [0.229, 0.224, 0.225])
    return {"size": [S, S], "layout": "NCHW", "channel_order": "RGB", "dtype": "float32", "scale": 1 / 255,
            "mean": mean, "std": std, "resize": "bilinear", "keep_aspect": False}


def _vlm_graphs(model: Any, family: str, dims: dict[str, int], S: int) -> list[GraphSpec]:
    """The vision, embed and decoder-with-KV-cache graphs, with their fresh parity inputs and dynamic axes."""
    import torch

    vision, embed, dec = vision_wrapper(model, family), embed_wrapper(model), decoder_wrapper(model, family)
    L, KV, D = dims["num_layers"], dims["num_kv_heads"], dims["head_dim"]
    Hs, V = dims["hidden_size"], dims["vocab_size"]
    Nd = torch.export.Dim("images", min=1, max=16)
    Sd = torch.export.Dim("seq", min=1, max=4096)
    Pd = torch.export.Dim("past", min=0, max=4096)
    emb_scale = float(model.get_input_embeddings().weight.detach().std())

    def vision_inputs(rng):
        return {"pixel_values": rng.standard_normal((int(rng.integers(1, 3)), 3, S, S)).astype(np.float32)}

    def embed_inputs(rng):
        return {"input_ids": rng.integers(0, V, size=(1, int(rng.integers(1, 9)))).astype(np.int64)}

    def dec_inputs(rng, s=None, p=None):
        s = int(rng.integers(1, 6)) if s is None else s
        p = int(rng.integers(0, 9)) if p is None else p
        f = {"inputs_embeds": (emb_scale * rng.standard_normal((1, s, Hs))).astype(np.float32),
             "attention_mask": np.ones((1, p + s), np.int64),
             "position_ids": np.arange(p, p + s, dtype=np.int64)[None]}
        for i in range(L):
            f[f"past_key_{i}"] = rng.standard_normal((1, KV, p, D)).astype(np.float32)
            f[f"past_value_{i}"] = rng.standard_normal((1, KV, p, D)).astype(np.float32)
        return f

    ex = dec_inputs(np.random.default_rng(1), s=3, p=4)  # export example, not parity
    dec_names = ["inputs_embeds", "attention_mask", "position_ids"] + [f"past_{kv}_{i}" for i in range(L)
                                                                      for kv in ("key", "value")]
    dec_out = ["logits"] + [f"present_{kv}_{i}" for i in range(L) for kv in ("key", "value")]
    total = torch.export.Dim("total", min=1, max=8192)
    dec_dyn = {"inputs_embeds": {1: Sd}, "attention_mask": {1: total}, "position_ids": {1: Sd}}
    dec_dyn.update({n: {2: Pd} for n in dec_names[3:]})
    # the decoder takes *past: dynamic shapes as one positional structure
    dec_dyn_pos = (dec_dyn["inputs_embeds"], dec_dyn["attention_mask"], dec_dyn["position_ids"],
                   tuple(dec_dyn[n] for n in dec_names[3:]))
    return [
        GraphSpec("vision", vision, (torch.randn(2, 3, S, S),), ["pixel_values"], ["image_features"], vision_inputs,
                  dynamic_shapes={"pixel_values": {0: Nd}}),
        GraphSpec("embed", embed, (torch.randint(0, V, (1, 4)),), ["input_ids"], ["inputs_embeds"], embed_inputs,
                  dynamic_shapes={"input_ids": {1: Sd}}, quantize=False),
        GraphSpec("decoder", dec, tuple(torch.from_numpy(ex[n]) for n in dec_names), dec_names, dec_out, dec_inputs,
                  dynamic_shapes=dec_dyn_pos),
    ]


def _vlm_task(model: Any, family: str, cfg: dict[str, Any], tok_dst: Path, pre: dict[str, Any],
              max_new_tokens: int):
    """task(files, variant): greedy tokens of the exported graphs vs transformers generate."""
    prompts = ["what is the closest object to the sofa ?", "how many chairs are in the room ?"]

    def task(files: dict[str, Path], variant: str) -> dict[str, Any]:
        fp32 = variant == "fp32"
        res = token_check(model, family, files, cfg, tok_dst, pre, prompts=prompts, max_new_tokens=max_new_tokens,
                          reference_ids=None if fp32 else True)
        C.progress(f"vlm token agreement vs transformers generate: {res['token_agreement']:.3f} over "
                   f"{res['tokens']} tokens" + (f", KV cache consistent: {res['kv_cache_consistent']}" if fp32 else ""))
        # fp32 must reproduce transformers exactly (and the cache must not change the result); lower
        # precisions ship when their element-wise parity passed and at least half the tokens agree
        need = 1.0 if fp32 else LOW_PRECISION_TOKEN_AGREEMENT
        ok = (res["token_agreement"] == 1.0 and res["kv_cache_consistent"]) if fp32 else res["token_agreement"] >= need
        return {"ok": bool(ok), "accepted_at": need, **res}

    return task


def export_vlm(source: str, out: str | Path, precisions: Sequence[str], *, max_new_tokens: int = 12,
               **_: Any) -> dict[str, Any]:
    """Add the vlm role (vision + embed + decoder graphs, tokenizer.json) to the bundle at `out`."""
    import torch
    from transformers import AutoModelForImageTextToText

    from mosaicthinker.runtime.infra.bundle import sha256_file
    from mosaicthinker.runtime.models.vlm import TEMPLATES

    family = _family_of(source)
    if source.startswith("tiny"):
        model, prov = load_source(source, "vlm", None, tiny_kwargs={"vocab": TINY_VOCAB})
    else:
        model, prov = load_source(source, "vlm", AutoModelForImageTextToText)
    model.config.use_cache = True
    dims = _text_dims(model, family)
    out = Path(out)
    tok_dst = write_tokenizer(out, "vlm", source, prov["random_weights"], lambda p: build_tiny_tokenizer(family, p))
    vc = model.config.vision_config
    S = int(vc.image_size[0] if isinstance(vc.image_size, (list, tuple)) else vc.image_size)
    with torch.no_grad():
        T = int(vision_wrapper(model, family)(torch.zeros(2, 3, S, S)).shape[1])
    pre = _vlm_preprocessing(family, S)
    cfg = {"family": family, **dims, "image_token_id": int(model.config.image_token_id), "image_seq_len": T,
           "image_size": S, "stop_tokens": TEMPLATES[family]["stop"], "max_new_tokens": 64,
           "pad_token_id": int(getattr(_text_model(model, family).config, "pad_token_id", None) or 0)}
    graphs = _vlm_graphs(model, family, dims, S)
    licence = "Apache-2.0" if family == "smolvlm" else "MIT"
    meta = C.role_meta(family, preprocessing=pre, semantics={"kind": "vlm", "tiling": False}, provenance=prov,
                       licence=licence, random_weights=prov["random_weights"], config=cfg,
                       tokenizer={"file": "vlm/tokenizer.json", "sha256": ""})
    meta["tokenizer"]["sha256"] = sha256_file(tok_dst)
    return export_variants(out, "vlm", graphs, meta, precisions,
                           task_check=_vlm_task(model, family, cfg, tok_dst, pre, max_new_tokens))


def export_role(role: str, source: str, precisions: Sequence[str], out: str | Path, *, calib: str | None = None,
                options: dict[str, str] | None = None, **_: Any) -> dict[str, Any]:
    """SmolVLM / InternVL through the project's own graphs (export/vlm.py picks this exporter per source)."""
    return run_exporter(export_vlm, source, precisions, out, calib=calib, options=options)
