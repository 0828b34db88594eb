"""`mosaic profile` on the shared real models: report.json / report.md / PNG charts, providers used, memory
figures, measured costs written back into a profile, random-weight roles marked (runtime/commands/profile.py)."""
from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from PIL import Image

from mosaicthinker.runtime import budget as B
from mosaicthinker.runtime.infra.bundle import bundle_hash
from mosaicthinker.runtime.commands import profile as P


@pytest.fixture(scope="module")
def shared_bundle(tmp_path_factory, shared_models):
    from mosaicthinker.export.onnx_import import import_shared_models

    out = tmp_path_factory.mktemp("shared_bundle")
    import_shared_models(shared_models, out, ["fp32"])
    return out


def test_percentiles_and_random_feeds():
    p = P.percentiles([1, 2, 3, 4, 5, 6, 7, 8, 9, 10])
    assert (p["p50"], p["p90"], p["n"]) == (5.5, 9.1, 10)

    class Inp:
        def __init__(self, name, shape, type_):
            self.name, self.shape, self.type = name, shape, type_

    class Sess:
        def get_inputs(self):
            return [Inp("img", [1, 8, 8, 3], "tensor(uint8)"), Inp("ids", ["batch", 5], "tensor(int64)"),
                    Inp("x", [None, 2], "tensor(float)"), Inp("past_key_0", [1, 2, "past", 8], "tensor(float)"),
                    Inp("attention_mask", [1, "total"], "tensor(int64)")]

    f = P.random_feeds(Sess(), np.random.default_rng(0))
    assert f["img"].dtype == np.uint8 and f["img"].shape == (1, 8, 8, 3)
    assert f["ids"].dtype == np.int64 and f["ids"].shape == (1, 5)
    assert f["x"].dtype == np.float32 and f["x"].shape == (1, 2)
    # a decoder step: a 16-token cache, one new token, the mask covers both
    assert f["past_key_0"].shape == (1, 2, 16, 8) and f["attention_mask"].shape == (1, 17)
    assert (f["attention_mask"] == 1).all()


@pytest.mark.export
@pytest.mark.slow
def test_mosaic_profile_report_on_shared_models(shared_bundle, tmp_path, capsys):
    from mosaicthinker.runtime.cli import main

    prof = tmp_path / "cpu.toml"
    shutil.copy(B.resolve_profile_path("cpu-generic"), prof)
    out = tmp_path / "report"
    rc = main(["profile", "--bundle", str(shared_bundle), "--profile", str(prof), "--runs", "2", "--warmup", "1",
               "--roles", "detector,embedder,segmenter", "--out", str(out), "--update-profile", "--no-progress"])
    assert rc == 0
    printed = capsys.readouterr().out
    assert "| detector (adapter) |" in printed
    rep = json.loads((out / "report.json").read_text())
    assert rep["schema"] == P.REPORT_SCHEMA and rep["bundle_hash"] == bundle_hash(shared_bundle)
    assert set(rep["roles"]) == {"detector", "embedder", "segmenter"}
    for role, r in rep["roles"].items():
        assert r["random_weights"] is False
        v = r["variants"][r["planned_variant"]]
        for comp in v["components"].values():
            assert "error" not in comp, comp
            assert comp["provider"] == "CPUExecutionProvider"
            assert comp["load_ms"] > 0 and comp["latency_ms"]["n"] == 2
            assert comp["latency_ms"]["p90"] >= comp["latency_ms"]["p50"] > 0
            assert comp["peak_rss_increase_mb"] >= comp["rss_increase_mb"] - 0.5
        ad = v["adapter"]
        assert "error" not in ad and ad["latency_ms"]["p50"] > 0
    # (adapter vs model time is a benchmark figure, not a unit-test assertion: see benchmarks/)
    assert rep["cpu_side"]["ransac_pair"]["latency_ms"]["p50"] > 0
    md = (out / "report.md").read_text()
    assert "p50 ms" in md and rep["bundle_hash"] in md
    for png in ("latency.png", "memory.png"):
        im = Image.open(out / png)
        assert min(im.size) > 100  # a chart, whatever its layout's exact pixel size
        assert len(np.unique(np.asarray(im.convert("RGB")).reshape(-1, 3), axis=0)) > 3  # bars and text drawn
    # measured costs written back and the profile still validates
    p = B.load_profile(prof)
    for item in ("detector", "embedder", "segmenter", "process", "geometry"):
        e = p.cost(item)
        assert e.status == "measured" and e.bundle_hash == rep["bundle_hash"] and e.date == rep["date"]
    assert p.cost("detector").ms_per_call == pytest.approx(
        rep["roles"]["detector"]["variants"]["fp32"]["adapter"]["latency_ms"]["p50"], rel=1e-3)
    assert p.cost("depth") == B.load_profile("cpu-generic").cost("depth")  # not profiled: untouched
    # the planner no longer flags the re-measured items as measured on another bundle
    plan = B.plan(p, 60, 15, bundle=shared_bundle)
    stale = " ".join(n for n in plan.notes if "another bundle" in n)
    assert not any(item in stale for item in ("detector", "embedder", "segmenter"))


@pytest.mark.export
def test_profile_marks_random_weights_and_reports_fallback(shared_bundle, tmp_path):
    # a copy of the bundle whose embedder claims random weights, profiled under the Jetson provider chain
    from mosaicthinker.host.bundle_write import read_manifest, write_manifest

    b2 = tmp_path / "b2"
    shutil.copytree(shared_bundle, b2)
    m = read_manifest(b2)
    m["roles"]["embedder"]["random_weights"] = True
    write_manifest(b2, m)
    rep = P.run_profile(b2, "jetson-orin-nano-8gb", roles=["embedder"], runs=1, warmup=1, progress=False,
                        out=tmp_path / "r", isolate=False)
    r = rep["roles"]["embedder"]
    assert r["random_weights"] is True and rep["random_weights_used"]
    assert r["providers_requested"][0] == "TensorrtExecutionProvider"
    comp = r["variants"]["fp32"]["components"]["model"]
    assert comp["provider"] == "CPUExecutionProvider"
    assert rep["fallbacks"]
    assert any("TensorrtExecutionProvider" in e["message"] for e in rep["fallbacks"])
    assert "RANDOM WEIGHTS" in (tmp_path / "r" / "report.md").read_text()


@pytest.mark.export
def test_update_profile_needs_a_profile(shared_bundle):
    from mosaicthinker.runtime.infra.errors import InputError

    with pytest.raises(InputError, match="`update_profile` needs `profile`"):  # API words; the CLI says flags
        P.run_profile(shared_bundle, None, update_profile=True, progress=False)


def test_profiled_frames_never_repeat():
    """Adapters cache per image (segmenter classes, matcher features): the profiler must hand out a new image on
    every call, across profilers too, or it would time cache hits instead of the model."""
    frame = np.zeros((4, 5, 3), np.uint8)
    a, b = P._Fresh(frame, 3), P._Fresh(frame, 3)
    seen = [a() for _ in range(3)] + [b() for _ in range(3)]
    keys = {f.tobytes() for f in seen}
    assert len(keys) == 6 and all(f.shape == frame.shape for f in seen)
