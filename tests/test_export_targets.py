"""`mosaic export shared-models --target T` for every target of export/formats.py, through the real CLI (the
path a user takes): the SSD kept as the detector's `ssd-fp32` variant must not make `detector-ssd` a role a
target step asks for (it did: `no role 'detector-ssd' in this bundle`, no .ort written), and the Android step's
.ort files must load and run in onnxruntime and agree with their source graphs."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("onnx")

from mosaicthinker.export import formats  # noqa: E402

pytestmark = [pytest.mark.export, pytest.mark.slow]

# the detector brings its SSD variant (the exporter key `detector-ssd`); the embedder is the smallest other role
ROLES = "detector,embedder"


def _export(shared_models: Path, out: Path, target: str) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "mosaicthinker.runtime.cli", "export", "shared-models", "--source",
           f"dir:{shared_models}", "--set", f"roles={ROLES}", "--target", target, "--out", str(out)]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=900)


def _feeds(sess, rng):
    feeds = {}
    for i in sess.get_inputs():
        shape = [d if isinstance(d, int) and d > 0 else 1 for d in i.shape]
        if "uint8" in i.type:
            feeds[i.name] = rng.integers(0, 256, shape, dtype=np.uint8)
        else:
            feeds[i.name] = (rng.random(shape, dtype=np.float32) * 255).astype(np.float32)
    return feeds


def _check_ort_files(out: Path) -> int:
    """Every .ort file of the bundle loads on the CPU EP, runs on random inputs and matches the .onnx it came from
    (the variant's `android.source_variant` graph). Returns the number of .ort files run."""
    import onnxruntime as ort

    m = json.loads((out / "manifest.json").read_text())
    rng = np.random.default_rng(0)
    n = 0
    for role, rm in m["roles"].items():
        for vname, vm in rm["variants"].items():
            if vm.get("target") != "android":
                continue
            src_v = vm["android"]["source_variant"].split(" ")[0]
            for c, cm in vm["components"].items():
                src = out / rm["variants"][src_v]["components"][c]["file"]
                ref = ort.InferenceSession(str(src), providers=["CPUExecutionProvider"])
                files = [out / cm["file"]] + [out / vm["android"]["components"][c]["runtime_opt"]["file"]]
                for f in files:
                    so = ort.SessionOptions()
                    if f.name.endswith(".with_runtime_opt.ort"):
                        so.add_session_config_entry("session.enable_saved_runtime_optimizations", "1")
                    s = ort.InferenceSession(str(f), so, providers=["CPUExecutionProvider"])
                    feeds = _feeds(s, rng)
                    got, want = s.run(None, feeds), ref.run(None, feeds)
                    for g, w in zip(got, want):
                        assert g.shape == w.shape, f"{f}: output shape {g.shape} vs source {w.shape}"
                        assert np.allclose(g.astype(np.float64), w.astype(np.float64), rtol=1e-3, atol=1e-3), \
                            f"{f}: output differs from {src.name}"
                    n += 1
    return n


@pytest.mark.parametrize("target", formats.targets())
def test_shared_models_export_every_target(shared_models, tmp_path, target):
    out = tmp_path / "bundle"
    r = _export(shared_models, out, target)
    assert r.returncode == 0, f"--target {target} failed:\n{r.stderr[-3000:]}"
    m = json.loads((out / "manifest.json").read_text())
    assert set(m["roles"]) == {"detector", "embedder"}
    assert "ssd-fp32" in m["roles"]["detector"]["variants"]  # the SSD stays a variant, never a role
    if target == "android":
        orts = sorted(p.relative_to(out).as_posix() for p in out.rglob("*.ort"))
        assert "detector/android-ort-fp32/model.ort" in orts and "embedder/android-ort-fp32/model.ort" in orts, orts
        assert _check_ort_files(out) == len(orts)
        assert (out / "android" / "required_operators.config").is_file()
        v = subprocess.run([sys.executable, "-m", "mosaicthinker.runtime.cli", "bundle", "verify", str(out),
                            "--target", "android", "--json"], capture_output=True, text=True, timeout=300)
        assert v.returncode == 0, v.stderr[-2000:]
        rep = json.loads(v.stdout)["android"]["roles"]
        for role in ("detector", "embedder"):
            cr = rep[role]["android-ort-fp32"]["model"]
            assert cr["would_run"] == cr["chain"][0] and set(cr["providers"]) == {"QNN", "NNAPI", "XNNPACK", "CPU"}
            assert cr["providers"]["CPU"]["cpu_ops"] == []
            assert cr["providers"]["XNNPACK"]["supported_nodes"] < cr["providers"]["CPU"]["nodes"]
    if target == "jetson":
        assert (out / "jetson" / "build_engines.sh").is_file()
        for role in ("detector", "embedder"):
            assert m["roles"][role]["variants"]["fp32"].get("jetson"), f"{role}: no jetson fields"
