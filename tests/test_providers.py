"""Session creation through runtime/infra/providers.py: short names, fallback over providers missing on this machine
(ends on CPU, reasons in the trace), first-run failure, thread settings. Real onnxruntime, no mocks."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from mosaicthinker.runtime.infra import providers as P
from mosaicthinker.runtime.infra.errors import ProviderError
from mosaicthinker.runtime.infra.trace import Trace

DATA = Path(__file__).parent / "data"


def _graph(path: Path, bad_reshape: bool = False) -> Path:
    """A copy of a two-node test graph (y = x + x over [n, 3]; or a Reshape [1,3] -> [5,5] that is valid but fails
    at run time). Committed as files, written once by the onnx package, so these tests run on the light runtime."""
    path.write_bytes((DATA / ("bad_reshape.onnx" if bad_reshape else "add.onnx")).read_bytes())
    return path


def test_short_names():
    assert P.normalize_provider("cuda") == "CUDAExecutionProvider"
    assert P.normalize_provider("TRT") == "TensorrtExecutionProvider"
    assert P.normalize_provider("nnapi") == "NnapiExecutionProvider"
    assert P.normalize_provider("qnn") == "QNNExecutionProvider"
    assert P.normalize_provider("xnnpack") == "XnnpackExecutionProvider"
    assert P.normalize_provider("coreml") == "CoreMLExecutionProvider"
    assert P.normalize_provider("cpuexecutionprovider") == "CPUExecutionProvider"
    assert [n for n, _ in P.normalize_preference("cuda, cpu,cuda")] == ["CUDAExecutionProvider", "CPUExecutionProvider"]
    with pytest.raises(ProviderError, match="unknown execution provider 'gpu9'"):
        P.normalize_provider("gpu9")


def test_fallback_over_missing_providers_ends_on_cpu(tmp_path: Path):
    avail = P.available_providers()
    missing = [p for p in ("tensorrt", "cuda", "nnapi", "qnn", "coreml") if P.normalize_provider(p) not in avail]
    if not missing:
        pytest.skip("every accelerator provider is present on this machine: nothing to fall back over")
    tr = Trace()
    s = P.create_session(_graph(tmp_path / "g.onnx"), "depth", missing + ["cpu"], threads=1, trace=tr)
    assert s.provider == "CPUExecutionProvider"
    out = s.run({"x": np.ones((2, 3), np.float32)})[0]
    assert np.allclose(out, 2.0)
    fb = tr.fallbacks()
    assert [e["requested"] for e in fb] == [P.normalize_provider(p) for p in missing]
    assert all("not available" in e["message"] and e["stage"] == "depth" for e in fb)
    rec = tr.providers["depth"]
    assert rec["used"] == "CPUExecutionProvider" and rec["threads"] == 1
    assert rec["requested"][:len(missing)] == [P.normalize_provider(p) for p in missing]
    assert rec["create_s"] >= 0 and rec["first_run_s"] is not None and rec["rss_peak_mb"] > 0


def _a_missing_provider() -> str:
    avail = P.available_providers()
    for p in ("tensorrt", "cuda", "nnapi", "qnn", "coreml", "rocm"):
        if P.normalize_provider(p) not in avail:
            return p
    pytest.skip("every accelerator provider is present on this machine")


def test_cpu_appended_unless_disabled(tmp_path: Path):
    g = _graph(tmp_path / "g.onnx")
    tr = Trace()
    gone = _a_missing_provider()
    s = P.create_session(g, "matcher", [gone], trace=tr)
    assert s.provider == "CPUExecutionProvider"
    assert any("falling back to CPUExecutionProvider" in e["message"] for e in tr.fallbacks())
    with pytest.raises(ProviderError, match="CPU fallback is disabled"):
        P.create_session(g, "matcher", [gone], config=P.SessionConfig(allow_cpu_fallback=False))


def test_first_run_failure_tries_next_provider_then_fails_clearly(tmp_path: Path):
    """Azure EP (present in the default onnxruntime wheel) takes the session; the first run fails there, so CPU is
    tried next with the same inputs; it fails too, and the error says so. Both attempts are in the trace."""
    if "AzureExecutionProvider" not in P.available_providers():
        pytest.skip("needs a second provider besides CPU")
    tr = Trace()
    s = P.create_session(_graph(tmp_path / "bad.onnx", bad_reshape=True), "segmenter", ["azure", "cpu"], trace=tr)
    assert s.provider == "AzureExecutionProvider"
    with pytest.raises(ProviderError, match="first run failed on CPUExecutionProvider and no provider is left"):
        s.run({"x": np.ones((1, 3), np.float32)})
    msgs = [e["message"] for e in tr.fallbacks()]
    assert any("first run failed on AzureExecutionProvider" in m for m in msgs)
    assert tr.providers["segmenter"]["used"] == "CPUExecutionProvider"


def test_warmup_failure_falls_back_at_creation(tmp_path: Path):
    if "AzureExecutionProvider" not in P.available_providers():
        pytest.skip("needs a second provider besides CPU")
    tr = Trace()
    with pytest.raises(ProviderError, match="no execution provider could create/run"):
        P.create_session(_graph(tmp_path / "bad.onnx", bad_reshape=True), "vlm", "azure,cpu", trace=tr, warmup=True)
    assert len([e for e in tr.fallbacks() if "first run failed" in e["message"]]) == 2
    ok = P.create_session(_graph(tmp_path / "g.onnx"), "vlm", "azure,cpu", trace=Trace(), warmup=True)
    assert ok.first_run_done
