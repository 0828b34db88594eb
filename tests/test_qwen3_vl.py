"""Qwen3-VL over the project's own graphs (export/hf_qwen3_vl.py, runtime/models/vlm.py): onnxruntime-genai
0.18.0 has no DeepStack input, so the vision graph emits the merged AND the DeepStack features and the decoder
takes them with 3-D M-RoPE positions and the KV cache. A tiny random Qwen3-VL (transformers' own config class,
real vocabulary size and special ids) goes through `mosaic export vlm`; the runtime loop must reproduce
transformers' Qwen3VLForConditionalGeneration greedy generate token for token, with the image."""
from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("transformers")

pytestmark = [pytest.mark.export]
IMAGE = 128  # 8 x 8 patches of 16 px -> 4 x 4 = 16 image tokens


def test_patches_match_the_qwen_processor_layout():
    """qwen_patches == the Qwen2-VL image processor's reshape/transpose (written out independently here)."""
    from mosaicthinker.runtime.models.vlm import qwen_patches

    rng = np.random.default_rng(0)
    img = rng.standard_normal((3, 64, 96)).astype(np.float32)
    got = qwen_patches(img, 16, 2, 2)
    assert got.shape == (4 * 6, 3 * 2 * 16 * 16)
    # patch 0 of merge unit (0, 0) is rows 0-15 / cols 0-15; patch 1 is its right neighbour; patch 2 the one below
    for k, (r, c) in enumerate([(0, 0), (0, 1), (1, 0), (1, 1), (0, 2)]):
        ref = np.stack([img[:, 16 * r:16 * r + 16, 16 * c:16 * c + 16]] * 2, 1).reshape(-1)  # [C, T, p, p]
        np.testing.assert_array_equal(got[k], ref)


def test_mrope_positions_follow_transformers_get_rope_index():
    from transformers import Qwen3VLForConditionalGeneration

    from mosaicthinker.export.hf_qwen3_vl import qwen3_config
    from mosaicthinker.runtime.models.vlm import mrope_positions

    cfg = qwen3_config("tiny")
    ids = [1, 2, 151652] + [151655] * 12 + [151653, 7, 8, 9]
    pos, nxt = mrope_positions(ids, 151655, (3, 4))
    with torch.device("meta"):
        m = Qwen3VLForConditionalGeneration(cfg)
    t = torch.tensor([ids])
    ref, delta = m.model.get_rope_index(t, (t == 151655).int(), image_grid_thw=torch.tensor([[1, 6, 8]]))
    np.testing.assert_array_equal(pos, ref.numpy())
    assert nxt == len(ids) + int(delta)


@pytest.mark.slow
def test_tiny_export_and_runtime_loop_match_transformers(tmp_path):
    from mosaicthinker.export import cli
    from mosaicthinker.runtime.infra.bundle import load_bundle
    from mosaicthinker.runtime.cli import build_parser
    from mosaicthinker.runtime.models import load_role
    from mosaicthinker.runtime.models.vlm import Qwen3VL
    from mosaicthinker.runtime.infra.trace import Trace

    out = tmp_path / "b"
    args = build_parser(("export",), cli).parse_args(
        ["vlm", "--source", "tiny:qwen3_vl", "--precision", "fp32", "--set", f"image_size={IMAGE}",
         "--set", "check_tokens=6", "--out", str(out)])
    cli.run(args)
    rm = load_bundle(out).role_meta("vlm")
    assert rm["arch"] == "qwen3_vl" and rm["random_weights"] is True
    chk = rm["variants"]["fp32"]["task_check"]
    assert chk["ok"] and chk["token_agreement"] == 1.0 and chk["tokens"] == 12
    assert chk["vision_vs_transformers"]["rel"] < 1e-4
    assert all(r["hf"] == r["ort"] for r in chk["runs"])
    assert rm["config"]["deepstack_layers"] == 2 and rm["config"]["image_seq_len"] == (IMAGE // 32) ** 2
    trace = Trace()
    vlm = load_role(out, "vlm", variant="fp32", threads=1, trace=trace)
    assert isinstance(vlm, Qwen3VL)
    rgb = np.full((90, 120, 3), 200, np.uint8)
    ids = vlm.generate_ids([rgb], "How many chairs?", max_new_tokens=4)
    assert len(ids) >= 1 and "vlm.vision" in trace.stages
    assert isinstance(vlm.generate([], "Hello", max_new_tokens=2), str)  # text only: no image, no DeepStack


def test_deepstack_changes_the_answer_so_it_cannot_be_dropped():
    """Why the GenAI 0.18.0 decoder (no DeepStack input) is not used: with the DeepStack features zeroed the
    tiny model's first-step logits differ from transformers' (which adds them)."""
    from mosaicthinker.export.hf_qwen3_vl import decoder_wrapper, random_model

    model = random_model("tiny")
    dec = decoder_wrapper(model)
    H, K, L = 64, 2, 6
    g = torch.Generator().manual_seed(0)
    emb = torch.randn(1, L, H, generator=g)
    pos = torch.arange(L).repeat(3, 1, 1)
    past = [torch.zeros(1, 2, 0, 16)] * 6
    deep = torch.zeros(K, 1, L, H)
    deep[:, :, 2:4] = torch.randn(K, 1, 2, H, generator=g)
    with torch.no_grad():
        with_ds = dec(emb, torch.ones(1, L, dtype=torch.long), pos, deep, *past)[0]
        without = dec(emb, torch.ones(1, L, dtype=torch.long), pos, torch.zeros_like(deep), *past)[0]
        mask = torch.zeros(1, L, dtype=torch.bool)
        mask[0, 2:4] = True
        ref = model.model.language_model(inputs_embeds=emb, position_ids=pos, visual_pos_masks=mask,
                                         deepstack_visual_embeds=[deep[i, 0, 2:4] for i in range(K)])
    # the dense add reproduces transformers' masked add; dropping DeepStack does not
    from mosaicthinker.export import hf_qwen3_vl  # noqa: F401
    assert with_ds.shape == (1, 1, model.config.text_config.vocab_size)  # the last position only
    assert torch.allclose(with_ds, model.lm_head(ref.last_hidden_state[:, -1:]), atol=1e-5)
    assert not torch.allclose(with_ds[0, -1], without[0, -1], atol=1e-3)
