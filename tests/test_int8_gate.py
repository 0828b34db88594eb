"""export/int8_gate.py: an int8 variant becomes a role's default only within its stated tolerance, the verdict is
written into the manifest, and a device profile asking for a refused variant runs the default, loudly."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

pytest.importorskip("onnx")

from mosaicthinker.export.common import add_variant_files, role_meta  # noqa: E402
from mosaicthinker.export.int8_gate import TOLERANCES, gate, record_and_promote  # noqa: E402
from mosaicthinker.runtime.budget.profile import load_profile  # noqa: E402
from mosaicthinker.runtime.infra.bundle import load_bundle  # noqa: E402
from mosaicthinker.runtime.infra.trace import Trace  # noqa: E402

pytestmark = pytest.mark.export


def test_gate_bounds_both_ways():
    for role, tol in TOLERANCES.items():
        b = tol["bound"]
        good, bad = (b, b - 0.01) if tol["op"] == "min" else (b, b + 0.01)
        assert gate(role, {tol["metric"]: good})[0] is True
        ok, why = gate(role, {tol["metric"]: bad})
        assert ok is False and "FAILS" in why and tol["metric"] in why
    assert gate("detector", {})[0] is False  # not measured: never promoted
    assert gate("embedder", {"x": 1})[0] is False  # no tolerance stated: never promoted


def _bundle(tmp_path: Path, shared_models: Path) -> Path:
    """A depth role with fp32 and an `int8-qdq` variant (the same graph file: only the manifest matters here)."""
    out = tmp_path / "b"
    meta = role_meta("pydnet", licence="Apache-2.0", name="PyDNet++", random_weights=False,
                     preprocessing={"size": [448, 640], "layout": "NHWC", "channel_order": "RGB",
                                    "dtype": "float32", "scale": 1.0 / 255.0, "resize": "bilinear"},
                     semantics={"depth": "relative"}, provenance={"source": "test"}, config={"output": 0})
    src = shared_models / "pydnet" / "pydnet.onnx"
    add_variant_files(out, "depth", "fp32", {"model": src}, meta=meta, precision="fp32")
    add_variant_files(out, "depth", "int8-qdq", {"model": src}, meta=meta, precision="int8-qdq")
    return out


def test_promote_within_tolerance_refuse_beyond(tmp_path, shared_models):
    out = _bundle(tmp_path, shared_models)
    assert load_bundle(out).variant_name("depth") == "fp32"
    assert record_and_promote(out, "depth", "int8-qdq", {"accuracy": {"absrel_vs_fp32": 0.01}, "speedup": 2.0}) \
        == "int8-qdq"
    assert load_bundle(out, verify=True).variant_name("depth") == "int8-qdq"
    assert record_and_promote(out, "depth", "int8-qdq", {"accuracy": {"absrel_vs_fp32": 0.2}}) == "fp32"
    m = json.loads((out / "manifest.json").read_text())
    g = m["roles"]["depth"]["variants"]["int8-qdq"]["accuracy_gate"]
    assert g["within_tolerance"] is False and "FAILS" in g["verdict"]
    assert m["roles"]["depth"]["default_variant"] == "fp32"
    # a phone profile asks for depth int8-qdq: the refused variant does not run, and the trace says why
    prof = load_profile("pixel-8gb")
    tr = Trace()
    assert prof.variant_in("depth", load_bundle(out), tr) == "fp32"
    ev = [e for e in tr.events if e["kind"] == "degraded"]
    assert ev and "failed its accuracy gate" in ev[0]["message"]
