"""Tiny random-weight models of the real architectures (`--source tiny` / `tiny:ARCH`).

Each builder instantiates the *real* transformers class from a small config (same graph structure, few
layers, narrow widths), seeded so every call gives the same weights. They exist so export + parity + the
runtime adapters can be tested without network access; bundles built from them carry `random_weights: true`
and the runtime warns whenever one is used. Nothing here is a stand-in for a trained model.

`TINY_ARCHS[arch] -> (role, builder)`; `ROLE_DEFAULT_ARCH[role]` is what plain `tiny` means for a role.
"""
from __future__ import annotations

from typing import Any, Callable

import torch

SEED = 0

# Tiny VLM tokenizer (export/hf_vlm.py builds it): specials first (fixed ids the tiny configs refer to), then
# a small word list.
TINY_SPECIALS = {
    "smolvlm": ["<|pad|>", "<|im_start|>", "<end_of_utterance>", "<image>", "<fake_token_around_image>",
                "<global-img>", "<|im_end|>", "[UNK]"],
    "internvl": ["<|endoftext|>", "<|im_start|>", "<|im_end|>", "<IMG_CONTEXT>", "<img>", "</img>", "[UNK]"],
}
TINY_WORDS = ("User Assistant user assistant : ? . , ! the a an is are of in on to and what where how many which "
               "chair table sofa bed tv door window sink fridge lamp plant kitchen room left right near far "
               "closest distance size count object objects image images this that there metres one two three "
               "four five yes no").split()
TINY_VOCAB = 96


def tiny_special_ids(family: str) -> dict[str, int]:
    """pad/bos/eos/image token ids of a tiny VLM family ("smolvlm", "internvl")."""
    sp = TINY_SPECIALS[family]
    if family == "smolvlm":
        return {"pad": 0, "bos": 1, "eos": 2, "image": sp.index("<image>")}
    return {"pad": 0, "bos": 1, "eos": 2, "image": sp.index("<IMG_CONTEXT>")}


def _seeded(fn: Callable[..., Any]) -> Callable[..., Any]:
    def wrapper(*a: Any, **k: Any) -> Any:
        torch.manual_seed(SEED)
        model = fn(*a, **k)
        torch_default_init(model)
        post = getattr(model, "_tiny_post", None)
        if post is not None:
            post(model)
        model.eval()
        return model

    wrapper.__name__ = fn.__name__
    wrapper.__doc__ = fn.__doc__
    return wrapper


def torch_default_init(model: Any) -> None:
    """Re-initialise layers with PyTorch's default (fan-in scaled) init. HF's `initializer_range` 0.02 init
    makes a tiny random net's outputs ~1e-7, below fp16 resolution, so fp16/int8 parity would measure noise;
    fan-in init keeps activations O(1) like a trained model's."""
    for mod in model.modules():
        if isinstance(mod, (torch.nn.Linear, torch.nn.Conv2d, torch.nn.ConvTranspose2d, torch.nn.BatchNorm2d,
                            torch.nn.LayerNorm)):
            mod.reset_parameters()


# --------------------------------------------------------------------------------------------- depth
def _dinov2_backbone(hidden: int = 32) -> dict:
    return dict(model_type="dinov2", hidden_size=hidden, num_hidden_layers=4, num_attention_heads=2,
                intermediate_size=hidden * 2, image_size=70, patch_size=14,
                out_features=["stage1", "stage2", "stage3", "stage4"], reshape_hidden_states=False)


@_seeded
def depth_anything_v2(metric: bool = False):
    """Depth-Anything-V2 (DPT head over a DINOv2 backbone); `metric=True` is the metric-indoor head
    (sigmoid * max_depth, max_depth 20 m as in the Hypersim indoor checkpoints)."""
    from transformers import DepthAnythingConfig, DepthAnythingForDepthEstimation

    cfg = DepthAnythingConfig(backbone_config=_dinov2_backbone(), patch_size=14, reassemble_hidden_size=32,
                              neck_hidden_sizes=[8, 16, 32, 32], fusion_hidden_size=16, head_hidden_size=8,
                              depth_estimation_type="metric" if metric else "relative",
                              max_depth=20 if metric else 1)
    model = DepthAnythingForDepthEstimation(cfg)
    # the relative head ends in ReLU: a positive output bias keeps random outputs from being all zero
    model._tiny_post = lambda m: torch.nn.init.constant_(m.head.conv3.bias, 0.1)
    return model


# ------------------------------------------------------------------------------------------ segmenter
def _sam_config(hidden: int, out_ch: int, image_size: int = 128):
    from transformers import SamConfig

    return SamConfig(
        vision_config=dict(hidden_size=hidden, output_channels=out_ch, num_hidden_layers=2, num_attention_heads=2,
                           image_size=image_size, patch_size=16, window_size=4, global_attn_indexes=[1],
                           mlp_dim=hidden * 2, num_pos_feats=out_ch // 2),
        prompt_encoder_config=dict(hidden_size=out_ch, image_size=image_size, patch_size=16, mask_input_channels=4),
        mask_decoder_config=dict(hidden_size=out_ch, mlp_dim=out_ch * 2, num_hidden_layers=2, num_attention_heads=2,
                                 iou_head_hidden_dim=out_ch),
    )


@_seeded
def sam():
    """SAM (ViT image encoder + prompt encoder + two-way mask decoder)."""
    from transformers import SamModel

    return SamModel(_sam_config(hidden=32, out_ch=32))


@_seeded
def slimsam():
    """SlimSAM: the same SamModel graph with pruned (narrower) encoder widths."""
    from transformers import SamModel

    return SamModel(_sam_config(hidden=16, out_ch=32))


# ------------------------------------------------------------------------------------------- detector
TINY_TEXT_VOCAB = 64
TINY_TEXT_LEN = 16


@_seeded
def owlv2():
    """OWLv2 (CLIP-style vision + text towers, box/class heads). The text tower pools at argmax(input_ids), so
    the tiny tokenizer's end-of-text token has the highest id, as in CLIP's vocabulary."""
    from transformers import Owlv2Config, Owlv2ForObjectDetection

    cfg = Owlv2Config(
        text_config=dict(vocab_size=TINY_TEXT_VOCAB, hidden_size=32, intermediate_size=64, num_hidden_layers=2,
                         num_attention_heads=2, max_position_embeddings=TINY_TEXT_LEN,
                         bos_token_id=TINY_TEXT_VOCAB - 2, eos_token_id=TINY_TEXT_VOCAB - 1, pad_token_id=0),
        vision_config=dict(hidden_size=32, intermediate_size=64, num_hidden_layers=2, num_attention_heads=2,
                           image_size=64, patch_size=16),
        projection_dim=32,
    )
    return Owlv2ForObjectDetection(cfg)


# ------------------------------------------------------------------------------------------- embedder
@_seeded
def clip():
    """CLIP vision tower with its projection (image embeds)."""
    from transformers import CLIPVisionConfig, CLIPVisionModelWithProjection

    cfg = CLIPVisionConfig(hidden_size=32, intermediate_size=64, num_hidden_layers=2, num_attention_heads=2,
                           image_size=64, patch_size=16, projection_dim=24)
    return CLIPVisionModelWithProjection(cfg)


@_seeded
def siglip():
    """SigLIP vision tower (attention-pooling head: pooler_output is the image embedding)."""
    from transformers import SiglipVisionConfig, SiglipVisionModel

    cfg = SiglipVisionConfig(hidden_size=32, intermediate_size=64, num_hidden_layers=2, num_attention_heads=2,
                             image_size=64, patch_size=16)
    return SiglipVisionModel(cfg)


# -------------------------------------------------------------------------------------------- matcher
def _superpoint_config() -> dict:
    return dict(model_type="superpoint", encoder_hidden_sizes=[8, 8, 16, 16], decoder_hidden_size=32,
                keypoint_decoder_dim=65, descriptor_decoder_dim=32, nms_radius=2, border_removal_distance=4)


@_seeded
def superpoint_lightglue():
    """LightGlue over SuperPoint (the HF LightGlueForKeypointMatching holds both)."""
    from transformers import LightGlueConfig, LightGlueForKeypointMatching

    cfg = LightGlueConfig(keypoint_detector_config=_superpoint_config(), descriptor_dim=32, num_hidden_layers=2,
                          num_attention_heads=2, depth_confidence=-1.0, width_confidence=-1.0,
                          filter_threshold=0.0)
    return LightGlueForKeypointMatching(cfg)


@_seeded
def efficientloftr():
    """EfficientLoFTR (the architecture MatchAnything ships weights for)."""
    from transformers import EfficientLoFTRConfig, EfficientLoFTRForKeypointMatching

    # 8 heads: the 2-D rotary embedding needs head_dim * partial_rotary_factor(4) == hidden_size / 4 * 2
    cfg = EfficientLoFTRConfig(stage_num_blocks=[1, 1, 1, 1], out_features=[16, 16, 32, 32],
                               stage_stride=[2, 1, 2, 2], hidden_size=32, num_attention_layers=2,
                               num_attention_heads=8, coarse_matching_threshold=0.0,
                               coarse_matching_border_removal=0)
    return EfficientLoFTRForKeypointMatching(cfg)


# ------------------------------------------------------------------------------------------------ VLM
def _llama_text(vocab: int, **extra: Any) -> dict:
    return dict(vocab_size=vocab, hidden_size=32, intermediate_size=64, num_hidden_layers=2, num_attention_heads=4,
                num_key_value_heads=2, max_position_embeddings=256, **extra)


@_seeded
def smolvlm(vocab: int):
    """SmolVLM (Idefics3 family: SigLIP-style vision tower + pixel-shuffle connector + Llama decoder)."""
    from transformers import SmolVLMConfig, SmolVLMForConditionalGeneration

    ids = tiny_special_ids("smolvlm")
    cfg = SmolVLMConfig(
        vision_config=dict(hidden_size=32, intermediate_size=64, num_hidden_layers=2, num_attention_heads=2,
                           image_size=64, patch_size=16),
        text_config=dict(model_type="llama", **_llama_text(vocab), pad_token_id=ids["pad"],
                         bos_token_id=ids["bos"], eos_token_id=ids["eos"]),
        image_token_id=ids["image"], scale_factor=2, tie_word_embeddings=False,
    )
    return SmolVLMForConditionalGeneration(cfg)


@_seeded
def internvl(vocab: int):
    """InternVL (InternViT + pixel-shuffle MLP projector + Qwen2 decoder)."""
    from transformers import InternVLConfig, InternVLForConditionalGeneration

    ids = tiny_special_ids("internvl")
    cfg = InternVLConfig(
        vision_config=dict(hidden_size=32, intermediate_size=64, num_hidden_layers=2, num_attention_heads=2,
                           image_size=[64, 64], patch_size=[16, 16]),
        text_config=dict(model_type="qwen2", **_llama_text(vocab), pad_token_id=ids["pad"],
                         bos_token_id=ids["bos"], eos_token_id=ids["eos"]),
        image_token_id=ids["image"], image_seq_length=4, downsample_ratio=0.5, tie_word_embeddings=False,
    )
    return InternVLForConditionalGeneration(cfg)


@_seeded
def qwen2_5_vl():
    """Qwen2.5-VL (window-attention ViT + patch merger + Qwen2 decoder with M-RoPE), the real vocabulary size
    and special-token ids; packaged for ONNX Runtime GenAI by export/hf_qwen_vl.py."""
    from transformers import Qwen2_5_VLForConditionalGeneration

    from .qwen_vl_config import qwen_config

    return Qwen2_5_VLForConditionalGeneration(qwen_config("tiny"))


# arch -> (role, builder name in this module, kwargs)
TINY_ARCHS: dict[str, tuple[str, str, dict]] = {
    "depth-anything-v2": ("depth", "depth_anything_v2", {}),
    "depth-anything-v2-metric-indoor": ("depth", "depth_anything_v2", {"metric": True}),
    "sam": ("segmenter", "sam", {}),
    "slimsam": ("segmenter", "slimsam", {}),
    "owlv2": ("detector", "owlv2", {}),
    "clip": ("embedder", "clip", {}),
    "siglip": ("embedder", "siglip", {}),
    "superpoint-lightglue": ("matcher", "superpoint_lightglue", {}),
    "efficientloftr": ("matcher", "efficientloftr", {}),
    "smolvlm": ("vlm", "smolvlm", {}),
    "internvl": ("vlm", "internvl", {}),
    "qwen2_5_vl": ("vlm", "qwen2_5_vl", {}),
}
ROLE_DEFAULT_ARCH = {"depth": "depth-anything-v2", "segmenter": "sam", "detector": "owlv2", "embedder": "clip",
                     "matcher": "superpoint-lightglue", "vlm": "smolvlm"}


def resolve(role: str, source: str) -> str:
    """`tiny` -> the role's default arch; `tiny:ARCH` -> ARCH (checked against the role)."""
    from mosaicthinker.runtime.infra.errors import ExportError

    arch = source.split(":", 1)[1] if ":" in source else ROLE_DEFAULT_ARCH.get(role, "")
    if arch not in TINY_ARCHS:
        raise ExportError(f"--source {source}: unknown tiny architecture {arch!r}; "
                          f"choose one of {sorted(a for a, v in TINY_ARCHS.items() if v[0] == role)}")
    if TINY_ARCHS[arch][0] != role:
        raise ExportError(f"--source {source}: architecture {arch!r} is a {TINY_ARCHS[arch][0]} model, "
                          f"not a {role} model")
    return arch


def build(arch: str, **kwargs: Any):
    """The tiny random-weight torch model of `arch` (eval mode, deterministic weights)."""
    _, fn, kw = TINY_ARCHS[arch]
    return globals()[fn](**{**kw, **kwargs})


