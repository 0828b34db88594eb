"""The Qwen3-VL real-size benchmark path (benchmarks/paper_models.py: qwen3_export then qwen3_measure) on a tiny
random checkpoint: the torch side exports the project's graphs and saves every reference to disk, the
onnxruntime side (no torch model loaded) must reproduce them -- each graph vs its torch wrapper, and the runtime
loop's greedy tokens and first-step logits vs transformers' generate. Real sizes run only in the benchmark."""
from __future__ import annotations

import sys
from pathlib import Path

import pytest

pytest.importorskip("torch")
pytest.importorskip("transformers")

pytestmark = [pytest.mark.export, pytest.mark.slow]
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))


def test_two_process_split_reproduces_transformers(tmp_path):
    import paper_models as PM

    from mosaicthinker.export.hf_qwen3_vl import random_checkpoint

    random_checkpoint("tiny", tmp_path / "ckpt" / "qwen3-vl-2b", dtype="float32")
    exp = PM.qwen3_export(tmp_path, image_size=128, n_new=5, text_chars=120)
    assert set(exp["graphs"]) == {"vision", "embed", "decoder"}
    assert not any(g["external_data"] for g in exp["graphs"].values())  # tiny: one protobuf each
    assert exp["provenance"]["random_weights"] is True
    m = PM.qwen3_measure(tmp_path, runs=1, threads=1, n_new=5)["fp32"]
    for g in m["graphs"].values():
        assert g["parity_vs_torch"]["rel"] < 1e-4 and g["parity_vs_torch"]["cosine"] > 0.9999
    assert max(o["rel"] for o in m["graphs"]["vision"]["vs_transformers"]) < 1e-4
    assert m["prompt_tokens"] == exp["prompt_tokens"] and m["new_tokens"] == 5
    assert m["token_agreement_vs_transformers"] == 1.0
    assert m["kl_vs_transformers"] < 1e-6 and m["logits_rel_err_vs_transformers"] < 1e-4
    # the int8 decoder path: the project's quantiser, then the same measure with that decoder (vision/embed fp32)
    q = PM.qwen3_int8(tmp_path)
    assert q["files"] == ["decoder.onnx"] and q["size_mib"] < q["fp32_size_mib"] / 2  # tiny: one protobuf
    m8 = PM.qwen3_measure(tmp_path, runs=1, threads=1, n_new=5, precision="int8")["int8"]
    assert m8["decoder_precision"] == "int8" and m8["new_tokens"] == 5
    d8 = m8["graphs"]["decoder"]["parity_vs_torch"]
    assert d8["rel"] > 100 * m["graphs"]["decoder"]["parity_vs_torch"]["rel"]  # really the int8 graph
    assert 0 < d8["next_token_kl_max"] < 10 and m8["kl_vs_transformers"] > 0


def test_external_data_threshold_follows_the_weight_bytes():
    import torch

    from mosaicthinker.export.hf_common import EXTERNAL_DATA_BYTES, needs_external_data

    small = torch.nn.Linear(8, 8)
    assert not needs_external_data(small)
    big = torch.nn.Module()
    big.register_buffer("w", torch.empty(EXTERNAL_DATA_BYTES // 4 + 1, dtype=torch.float32))
    assert needs_external_data(big)
