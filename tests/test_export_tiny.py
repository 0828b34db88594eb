"""Tiny-config fp32 export + parity for every Hugging Face role, then the runtime adapters on the bundle.

One session-scoped bundle holds every role (each export runs once); the runtime tests load it through
`runtime.models.load_role` like the pipeline does. The full precision x architecture matrix is
benchmarks/export_matrix.py.
"""
from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("torch")
pytest.importorskip("transformers")

pytestmark = [pytest.mark.export, pytest.mark.slow]

ROLES = ("depth", "segmenter", "detector", "embedder", "matcher")  # vlm: tests/test_vlm.py


@pytest.fixture(scope="session")
def tiny_bundle(tmp_path_factory):
    """One bundle with every image role exported from its default tiny architecture (fp32) + EfficientLoFTR."""
    import torch

    from mosaicthinker.export import hf_clip, hf_depth, hf_matchers, hf_owlv2, hf_sam

    torch.set_num_threads(2)
    out = tmp_path_factory.mktemp("tiny_bundle") / "b"
    reports = {
        "depth": hf_depth.export_depth("tiny", out, ["fp32"]),
        "segmenter": hf_sam.export_segmenter("tiny", out, ["fp32"]),
        "detector": hf_owlv2.export_detector("tiny", out, ["fp32"]),
        "embedder": hf_clip.export_embedder("tiny", out, ["fp32"]),
        "matcher": hf_matchers.export_matcher("tiny", out, ["fp32"]),
    }
    loftr = tmp_path_factory.mktemp("tiny_loftr") / "b"
    reports["loftr"] = hf_matchers.export_matcher("tiny:efficientloftr", loftr, ["fp32"])
    return out, loftr, reports


@pytest.fixture
def rgb():
    rng = np.random.default_rng(5)
    base = rng.integers(0, 256, size=(12, 16, 3), dtype=np.uint8)
    import cv2

    return cv2.resize(base, (96, 72), interpolation=cv2.INTER_CUBIC)  # smooth-ish texture, not square


def test_every_role_exported_with_fp32_parity_on_fresh_inputs(tiny_bundle):
    from mosaicthinker.runtime.infra.bundle import load_bundle

    out, loftr, reports = tiny_bundle
    b = load_bundle(out)  # hashes + schema
    assert set(ROLES) <= set(b.roles)
    for role in ROLES:
        meta = b.role_meta(role)
        assert meta["random_weights"] is True
        assert meta["provenance"]["source"].startswith("tiny:")
        v = meta["variants"]["fp32"]
        for comp, par in v["parity"].items():
            assert par["ok"], (role, comp, par)
            if "worst" in par:  # element-wise parity
                assert par["inputs"] == "fresh random"
                assert par["worst"]["rel"] <= 1e-3
            if "agreement" in par:
                assert par["agreement"]["worst"] >= 0.95
            for c in v["components"].values():
                assert c["opset"] == 18
    assert load_bundle(loftr).role_meta("matcher")["variants"]["fp32"]["parity"]["pair"]["ok"]


def test_dynamic_axes_are_declared(tiny_bundle):
    from mosaicthinker.runtime.infra.bundle import load_bundle

    b = load_bundle(tiny_bundle[0])
    sd = b.role_meta("segmenter")["variants"]["fp32"]["components"]["decoder"]
    ins = {i["name"]: i for i in sd["inputs"]}
    assert ins["point_coords"]["dynamic_axes"] and ins["point_labels"]["dynamic_axes"]
    assert not ins["image_embeddings"]["dynamic_axes"]


def test_depth_runtime(tiny_bundle, rgb):
    from mosaicthinker.runtime.models import load_role

    d = load_role(tiny_bundle[0], "depth")
    assert d.semantics == "relative_inverse"
    out = d.predict(rgb)
    assert out.shape == rgb.shape[:2] and out.dtype == np.float32 and np.isfinite(out).all()


def test_sam_runtime_boxes_and_points(tiny_bundle, rgb):
    from mosaicthinker.runtime.models import load_role
    from mosaicthinker.runtime.infra.trace import Trace

    tr = Trace()
    s = load_role(tiny_bundle[0], "segmenter", trace=tr)
    boxes = np.array([[5, 5, 40, 30], [30, 20, 90, 70]], np.float32)
    m = s.segment(rgb, boxes, ["chair", "table"])
    assert m.shape == (2, 72, 96) and m.dtype == bool
    m2 = s.segment(rgb, boxes, ["chair", "table"], points=np.array([[20, 15], [60, 50]], np.float32))
    assert m2.shape == m.shape
    assert tr.stages["segmenter.encoder"].calls == 1, "the encoder must run once per frame"
    assert tr.stages["segmenter.decoder"].calls == 2
    assert tr.random_weights_used


def test_sam_decoder_graph_matches_hf_prompt_path(tiny_bundle):
    """Boxes through our corner-label decoder == SamModel's own box prompt path (real prompt encoder)."""
    import torch

    from mosaicthinker.export import common as C
    from mosaicthinker.export import tiny

    b = tiny_bundle[0]
    model = tiny.build("sam")
    px = torch.randn(1, 3, 128, 128)
    box = torch.tensor([[[10.0, 20.0, 90.0, 100.0]]])
    with torch.no_grad():
        ref = model(pixel_values=px, input_boxes=box, multimask_output=True)
        emb = model.get_image_embeddings(px)
    got = C.ort_run(b / "segmenter/fp32/decoder.onnx",
                    {"image_embeddings": emb.numpy(), "point_coords": box.reshape(1, 2, 2).numpy(),
                     "point_labels": np.array([[2.0, 3.0]], np.float32)})
    np.testing.assert_allclose(got[0], ref.pred_masks[0].numpy(), rtol=1e-3, atol=1e-4)
    np.testing.assert_allclose(got[1], ref.iou_scores[0].numpy(), rtol=1e-3, atol=1e-4)


def test_owlv2_runtime_matches_hf_detection_head(tiny_bundle, rgb):
    """Split graphs + numpy class head == Owlv2ForObjectDetection's logits and boxes on the same inputs."""
    import torch

    from mosaicthinker.export import tiny
    from mosaicthinker.runtime.models import load_role
    from mosaicthinker.runtime.models.owlv2 import owl_preprocess

    d = load_role(tiny_bundle[0], "detector")
    names = ["chair", "dining table"]
    sc, boxes = d.scores(rgb, names)
    model = tiny.build("owlv2")
    x, side = owl_preprocess(rgb, d.spec.preprocessing)
    ids, mask = d.tokenize(names)
    with torch.no_grad():
        ref = model(input_ids=torch.from_numpy(ids), attention_mask=torch.from_numpy(mask),
                    pixel_values=torch.from_numpy(x))
    np.testing.assert_allclose(sc, torch.sigmoid(ref.logits[0]).numpy(), rtol=1e-3, atol=1e-5)
    cx, cy, w, h = (ref.pred_boxes[0].numpy()[:, i] * side for i in range(4))
    xyxy = np.clip(np.stack([cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2], 1), 0, [96, 72, 96, 72])
    np.testing.assert_allclose(boxes, xyxy, rtol=1e-3, atol=1e-3)
    # text embeddings are cached per name: a repeated name costs no text pass
    calls = d.trace.stages["detector.text"].calls
    d.score_threshold = float(np.quantile(sc, 0.95))
    det = d.detect(rgb, names)
    assert d.trace.stages["detector.text"].calls == calls
    assert len(det) > 0 and set(det.names) <= set(names)
    assert (det.boxes[:, 2] >= det.boxes[:, 0]).all()


def test_embedder_runtime_unit_norm(tiny_bundle, rgb):
    from mosaicthinker.runtime.models import load_role

    e = load_role(tiny_bundle[0], "embedder")
    v = e.embed(rgb)
    assert v.ndim == 1 and abs(float(np.linalg.norm(v)) - 1.0) < 1e-4
    assert e.dim == v.shape[0]
    assert float(v @ e.embed(rgb[:, ::-1].copy())) < 0.99999  # a different image gives a different vector


def test_superpoint_lightglue_runtime_returns_wellformed_matches(tiny_bundle, rgb):
    """The adapter runs the two graphs and maps matches back to image pixels. It cannot be asked to find a shift:
    with random weights LightGlue's assignment is arbitrary (one match at dx = 0 for a 4, 8 or 16 px roll), so the
    shift is checked on EfficientLoFTR below, whose correlation stays translation-equivariant with random weights."""
    from mosaicthinker.runtime.models import load_role

    m = load_role(tiny_bundle[0], "matcher")
    res = m.match(rgb, np.roll(rgb, 4, axis=1))
    assert len(res.uv0) > 0
    assert res.uv0.shape == res.uv1.shape == (len(res.uv0), 2) and res.scores.shape == (len(res.uv0),)
    h, w = rgb.shape[:2]
    for uv in (res.uv0, res.uv1):  # pixel coordinates of the input image, not of the network's resolution
        assert (uv >= 0).all() and (uv[:, 0] < w).all() and (uv[:, 1] < h).all()
    assert ((res.scores > 0) & (res.scores <= 1)).all()


def test_efficientloftr_runtime(tiny_bundle, rgb):
    from mosaicthinker.runtime.models import load_role

    m = load_role(tiny_bundle[1], "matcher")
    res = m.match(rgb, np.roll(rgb, 8, axis=1))
    assert res.uv0.shape == res.uv1.shape
    assert (res.scores > 0).all()
    # pairs are image-0 cell i with its mutual match j (transformers pairs index-aligned cells, which breaks
    # for any motion): even the random tiny net finds the 8 px shift at the cells it matches
    assert len(res.uv0) > 0
    dx = res.uv1[:, 0] - res.uv0[:, 0]
    assert abs(float(np.median(dx)) - 8.0) <= 1.0


def test_cli_export_tiny_role(tmp_path):
    """`mosaic export embedder --source tiny:siglip` end to end through the CLI (fp32)."""
    out = tmp_path / "cli_b"
    r = subprocess.run([sys.executable, "-m", "mosaicthinker.runtime.cli", "export", "embedder", "--source",
                        "tiny:siglip", "--precision", "fp32,fp16", "--out", str(out), "--json"],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    res = json.loads(r.stdout)
    assert res["bundle_roles"]["embedder"] == ["fp16", "fp32"]
    man = json.loads((out / "manifest.json").read_text())
    assert man["roles"]["embedder"]["arch"] == "siglip"
    assert man["roles"]["embedder"]["variants"]["fp16"]["parity"]["model"]["ok"]
    # re-exporting the role from another architecture replaces it (no stale fp16 of the old model)
    from mosaicthinker.export import hf_clip

    hf_clip.export_embedder("tiny:clip", out, ["fp32"])
    man = json.loads((out / "manifest.json").read_text())
    assert man["roles"]["embedder"]["arch"] == "clip"
    assert sorted(man["roles"]["embedder"]["variants"]) == ["fp32"]


def test_tiny_source_errors():
    from mosaicthinker.export import tiny
    from mosaicthinker.runtime.infra.errors import ExportError

    with pytest.raises(ExportError, match="not a depth model"):
        tiny.resolve("depth", "tiny:sam")
    with pytest.raises(ExportError, match="unknown tiny architecture"):
        tiny.resolve("vlm", "tiny:gpt5")
    assert tiny.resolve("matcher", "tiny") == "superpoint-lightglue"


def test_parity_catches_shapes_specialised_at_export(tmp_path):
    """Exported from a batch-1 example without dynamic axes, the graph is specialised to batch 1 (the exporter
    bakes the example's shape in): parity on fresh inputs of another batch size must fail the export."""
    import torch

    from mosaicthinker.export import hf_common
    from mosaicthinker.runtime.infra.errors import ExportError

    class Net(torch.nn.Module):
        def forward(self, x):
            return torch.tanh(x).reshape(x.shape[0], -1).sum(1)

    g = hf_common.GraphSpec("model", Net().eval(), (torch.randn(1, 4),), ["x"], ["y"],
                           lambda rng: {"x": rng.standard_normal((3, 4)).astype(np.float32)})
    meta = {"arch": "depth-anything-v2", "preprocessing": {}, "semantics": {"depth": "relative"},
            "provenance": {"source": "test"}, "licence": "Apache-2.0", "random_weights": True, "config": {}}
    with pytest.raises(ExportError, match="parity"):
        hf_common.export_variants(tmp_path / "b", "depth", [g], meta, ["fp32"])
    assert not (tmp_path / "b" / "manifest.json").exists()


def test_checkpoint_sources_fail_clearly(tmp_path):
    """`dir:` of a missing or non-checkpoint folder -> ExportError naming the source (no hub access needed)."""
    from transformers import DepthAnythingForDepthEstimation

    from mosaicthinker.export.sources import load_source
    from mosaicthinker.runtime.infra.errors import ExportError

    with pytest.raises(ExportError, match="does not exist"):
        load_source(f"dir:{tmp_path / 'nope'}", "depth", DepthAnythingForDepthEstimation)
    with pytest.raises(ExportError, match="could not load DepthAnythingForDepthEstimation"):
        load_source(f"dir:{tmp_path}", "depth", DepthAnythingForDepthEstimation)
    with pytest.raises(ExportError, match="expected hf:ID"):
        load_source("s3://bucket/x", "depth", DepthAnythingForDepthEstimation)
