"""runtime/infra/ep_support.py: the QNN context-binary cache protocol, graph ops read without `onnx`, the op-table
coverage of QNN / XNNPACK / NNAPI and onnxruntime's own placement report (real onnxruntime, CPU EP here)."""
from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np

from mosaicthinker.runtime.infra import ep_support as E
from mosaicthinker.runtime.infra import providers as P
from mosaicthinker.runtime.infra.trace import Trace

DATA = Path(__file__).parent / "data"


def test_qnn_context_cache_protocol(tmp_path: Path):
    model = tmp_path / "det.onnx"
    model.write_bytes((DATA / "add.onnx").read_bytes())
    assert E.qnn_context(model, None) == (str(model), {})  # no cache folder: compile every session
    path, entries = E.qnn_context(model, tmp_path / "cache")
    ctx = tmp_path / "cache" / "det_qnn_ctx.onnx"
    assert path == str(model)
    assert entries == {"ep.context_enable": "1", "ep.context_file_path": str(ctx), "ep.context_embed_mode": "0"}
    ctx.write_bytes(b"compiled")  # what QNN writes on the first session
    assert E.qnn_context(model, tmp_path / "cache") == (str(ctx), {})
    later = time.time() + 10
    os.utime(model, (later, later))  # a newer model invalidates the cached context
    assert E.qnn_context(model, tmp_path / "cache")[1]["ep.context_enable"] == "1"
    assert E.qnn_context(tmp_path / "m.ort", tmp_path / "cache") == (str(tmp_path / "m.ort"), {})


def test_graph_ops_and_tables():
    ops = E.graph_ops(DATA / "add.onnx")
    assert ops == [("ai.onnx", "Add")]
    assert E.table_support("QNN", ops)["supported_nodes"] == 1
    x = E.table_support("XNNPACK", ops)
    assert x["supported_nodes"] == 0 and x["cpu_ops"] == ["Add"]
    assert E.table_support("NNAPI", ops)["supported_nodes"] == 1
    conv = [("ai.onnx", "DequantizeLinear"), ("ai.onnx", "Conv"), ("ai.onnx", "Relu"), ("ai.onnx", "QuantizeLinear"),
            ("ai.onnx", "Reshape"), ("ai.onnx", "Relu")]
    got = E.table_support("XNNPACK", conv)  # Q/DQ around a Conv and the Relu behind it go to XNNPACK
    assert got["supported_nodes"] == 4 and got["cpu_ops"] == ["Relu", "Reshape"]


def test_ort_placement_reads_onnxruntimes_own_report():
    got = E.ort_placement(DATA / "add.onnx", "CPUExecutionProvider")
    assert got["placements"] == {"CPUExecutionProvider": {"nodes": 1, "ops": []}}
    assert got["supported_nodes"] == got["nodes"] == 1 and got["method"].startswith("ort placement")
    log = ("2026 [V:onnxruntime:, session_state.cc:1598 VerifyEachNodeIsAssignedToAnEp] Node placements\n"
           "2026 [V:onnxruntime:, session_state.cc:1601 VerifyEachNodeIsAssignedToAnEp]  Node(s) placed on "
           "[XnnpackExecutionProvider]. Number of nodes: 2\n"
           "2026 [V:onnxruntime:, session_state.cc:1603 VerifyEachNodeIsAssignedToAnEp]   Conv (conv1)\n"
           "2026 [V:onnxruntime:, session_state.cc:1603 VerifyEachNodeIsAssignedToAnEp]   MaxPool (pool)\n"
           "2026 [V:onnxruntime:, session_state.cc:1601 VerifyEachNodeIsAssignedToAnEp]  Node(s) placed on "
           "[CPUExecutionProvider]. Number of nodes: 1\n"
           "2026 [V:onnxruntime:, session_state.cc:1603 VerifyEachNodeIsAssignedToAnEp]   Reshape (r)\n"
           "2026 [V:onnxruntime:, session_state.cc:196 CreateGraphInfo] SaveMLValueNameIndexMapping\n")
    assert E.parse_placements(log) == {"XnnpackExecutionProvider": {"nodes": 2, "ops": ["Conv", "MaxPool"]},
                                       "CPUExecutionProvider": {"nodes": 1, "ops": ["Reshape"]}}


def test_phone_chain_falls_back_loudly_with_the_qnn_cache_set(tmp_path: Path, monkeypatch):
    """The 2026 Android chain QNN > NNAPI > XNNPACK > CPU on a host without them: CPU, one fallback event per
    absent provider (onnxruntime itself would only warn), nothing written to the context cache."""
    monkeypatch.setenv("MOSAIC_EP_CONTEXT_DIR", str(tmp_path / "ctx"))
    g = tmp_path / "g.onnx"
    g.write_bytes((DATA / "add.onnx").read_bytes())
    tr = Trace()
    chain = ["qnn", "nnapi", "xnnpack", "cpu"]
    absent = [P.normalize_provider(p) for p in chain[:-1] if P.normalize_provider(p) not in P.available_providers()]
    s = P.create_session(g, "detector", chain, threads=1, trace=tr)
    assert np.allclose(s.run({"x": np.ones((2, 3), np.float32)})[0], 2.0)
    if len(absent) == 3:
        assert s.provider == "CPUExecutionProvider"
        assert [e["requested"] for e in tr.fallbacks()] == absent
        assert not (tmp_path / "ctx").exists()
    assert tr.providers["detector"]["used"] == s.provider
