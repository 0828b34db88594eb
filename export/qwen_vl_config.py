"""Qwen2.5-VL dimensions (the real 3B config and a tiny test config) and the transformers config built from them.

Imports nothing from the rest of export/, so the tiny-model registry (export/tiny.py) and the GenAI packager
(export/hf_qwen_vl.py) can both use it without importing each other."""
from __future__ import annotations

QWEN_VOCAB = 151936
IMAGE_TOKEN, VISION_START, VISION_END, EOS_IDS = 151655, 151652, 151653, [151645, 151643]
CLIP_MEAN = [0.48145466, 0.4578275, 0.40821073]
CLIP_STD = [0.26862954, 0.26130258, 0.27577711]

# Qwen/Qwen2.5-VL-3B-Instruct config.json (dimensions as published on the model card's config)
REAL_3B = dict(
    text=dict(hidden_size=2048, intermediate_size=11008, num_hidden_layers=36, num_attention_heads=16,
              num_key_value_heads=2, vocab_size=QWEN_VOCAB, max_position_embeddings=128000, rms_norm_eps=1e-6,
              rope_parameters={"rope_type": "default", "rope_theta": 1000000.0, "mrope_section": [16, 24, 24]},
              bos_token_id=151643, eos_token_id=151645, tie_word_embeddings=True),
    vision=dict(depth=32, hidden_size=1280, intermediate_size=3420, num_heads=16, out_hidden_size=2048,
                patch_size=14, spatial_merge_size=2, temporal_patch_size=2, window_size=112,
                fullatt_block_indexes=[7, 15, 23, 31], tokens_per_second=2, hidden_act="silu"),
)
TINY = dict(
    text=dict(hidden_size=64, intermediate_size=128, num_hidden_layers=2, num_attention_heads=4,
              num_key_value_heads=2, vocab_size=QWEN_VOCAB, max_position_embeddings=4096, rms_norm_eps=1e-6,
              rope_parameters={"rope_type": "default", "rope_theta": 1000000.0, "mrope_section": [2, 3, 3]},
              bos_token_id=151643, eos_token_id=151645, tie_word_embeddings=True),
    vision=dict(depth=2, hidden_size=32, intermediate_size=64, num_heads=2, out_hidden_size=64, patch_size=14,
                spatial_merge_size=2, temporal_patch_size=2, window_size=112, fullatt_block_indexes=[1],
                tokens_per_second=2, hidden_act="silu"),
)
SIZES = {"tiny": TINY, "3b": REAL_3B}


def qwen_config(size: str):
    """The transformers `Qwen2_5_VLConfig` of `size` ("tiny" test config or "3b", the real dimensions)."""
    from transformers import Qwen2_5_VLConfig

    d = SIZES[size]
    return Qwen2_5_VLConfig(text_config=dict(d["text"]), vision_config=dict(d["vision"]),
                            image_token_id=IMAGE_TOKEN, video_token_id=151656, vision_start_token_id=VISION_START,
                            vision_end_token_id=VISION_END, tie_word_embeddings=d["text"]["tie_word_embeddings"],
                            architectures=["Qwen2_5_VLForConditionalGeneration"])
