"""What the mobile execution providers would run of a graph, and their session settings (no `onnx` needed).

Two sources, named in every result (`method`):
- "ort placement": onnxruntime's own partitioning report (`session_state.cc` "Node placements", logged at
  VERBOSE while a session is created), read when the provider is in this onnxruntime build;
- "op table": the provider's documented operator list, when it is not (QNN and NNAPI never are on a host;
  XNNPACK is not in PyPI's x86 or aarch64 wheels). A node whose op type has no entry falls back to the CPU; an
  op with an entry may still be refused for its shapes or types, so the table is an upper bound.
Tables: QNN HTP = the op builders of onnxruntime's QNN EP (`onnxruntime/core/providers/qnn/builder/
op_builder_factory.cc`, main 2026); XNNPACK = the kernels its EP registers (`xnnpack_execution_provider.cc`:
float Conv/ConvTranspose/MaxPool/AveragePool/Softmax/Resize/Gemm/MatMul, QDQ units of Conv/ConvTranspose/
AveragePool/Softmax, Relu/Clip fused into the op before them); NNAPI = `onnxruntime.tools.mobile_helpers/
nnapi_supported_ops.md` (the usability checker's table; the export records its partition report per graph).
"""
from __future__ import annotations

import importlib.util
import os
import re
import tempfile
from pathlib import Path
from typing import Any

from .bundle import _fields

QNN_HTP_OPS = frozenset("""
ArgMax ArgMin BatchNormalization Cast Clip Concat Conv ConvTranspose CumSum Einsum Expand FusedMatMul Gather
GatherElements GatherND Gemm GroupNormalization GRU Identity InstanceNormalization Inverse IsNaN LayerNormalization
LRN LSTM MatMul MatMulNBits Mean Mod NonZero Pad AveragePool GlobalAveragePool GlobalMaxPool MaxPool QuickGelu
RandomNormalLike RandomUniformLike Reciprocal ReduceL2 ReduceMax ReduceMean ReduceMin ReduceProd ReduceSum Flatten
Reshape Squeeze Unsqueeze Resize RMSNormalization SimplifiedLayerNormalization RoiAlign RotaryEmbedding Abs Add And
Asin Atan Ceil Cos DequantizeLinear DepthToSpace Div Elu Equal Exp Floor Gelu Greater GreaterOrEqual GridSample
HardSigmoid HardSwish LeakyRelu Less LessOrEqual Log LpNormalization Max Min Mul Neg Not Or Pow PRelu
QuantizeLinear Relu Round ScatterElements ScatterND Selu Sigmoid Sign Sin Softplus SpaceToDepth Sqrt Sub Sum Tanh
Where Xor Slice LogSoftmax Softmax Split STFT Tan ThresholdedRelu Tile TopK Transpose Upsample
""".split())
_XNNPACK_CORE = frozenset("Conv ConvTranspose MaxPool AveragePool Softmax Resize Gemm MatMul".split())
_XNNPACK_QDQ = frozenset("Conv ConvTranspose AveragePool Softmax".split())  # as Q/DQ node units
_XNNPACK_FUSED = frozenset("Relu Clip".split())  # only behind a node XNNPACK took
_XNNPACK_QLINEAR = frozenset("QLinearConv QLinearConvTranspose QLinearAveragePool QLinearSoftmax".split())
QDQ_OPS = frozenset(("QuantizeLinear", "DequantizeLinear"))
TABLE_SOURCES = {
    "QNN": "onnxruntime QNN EP op builders (core/providers/qnn/builder/op_builder_factory.cc, main 2026)",
    "XNNPACK": "onnxruntime XNNPACK EP kernel registry (core/providers/xnnpack/xnnpack_execution_provider.cc)",
    "NNAPI": "onnxruntime.tools.mobile_helpers/nnapi_supported_ops.md",
}
EP_NAMES = {"QNN": "QNNExecutionProvider", "XNNPACK": "XnnpackExecutionProvider",
            "NNAPI": "NnapiExecutionProvider", "CPU": "CPUExecutionProvider"}

# Provider options applied unless the caller sets them (runtime/infra/providers.py): the HTP backend at full
# clock, the longest graph finalisation (paid once: the context binary caches it)
PROVIDER_DEFAULTS: dict[str, dict[str, str]] = {
    "QNNExecutionProvider": {"backend_path": "libQnnHtp.so", "htp_performance_mode": "burst",
                             "htp_graph_finalization_optimization_mode": "3"},
}


def qnn_context(model: str | os.PathLike, cache_dir: str | os.PathLike | None) -> tuple[str, dict[str, str]]:
    """(model file to load, session config entries) for the QNN EP's context-binary cache in `cache_dir`.

    First session: load `model` with ep.context_enable=1 so QNN writes `<cache>/<stem>_qnn_ctx.onnx` (+ its
    .bin: the HTP graph, compiled once, minutes for big graphs). Later sessions load that context model instead.
    cache_dir None: no cache (compile on every session). Only ONNX files can be dumped (not .ort)."""
    if cache_dir is None or not str(model).endswith(".onnx"):
        return str(model), {}
    ctx = Path(cache_dir) / f"{Path(model).stem}_qnn_ctx.onnx"
    if ctx.is_file() and ctx.stat().st_mtime >= Path(model).stat().st_mtime:
        return str(ctx), {}
    Path(cache_dir).mkdir(parents=True, exist_ok=True)
    return str(model), {"ep.context_enable": "1", "ep.context_file_path": str(ctx), "ep.context_embed_mode": "0"}


def graph_ops(path: str | os.PathLike) -> list[tuple[str, str]]:
    """(domain, op type) of every top-level node of an ONNX file, read from the protobuf (ModelProto.graph = 7,
    GraphProto.node = 1, NodeProto.op_type = 4, domain = 7)."""
    buf = memoryview(Path(path).read_bytes())
    graph = next((v for f, wt, v in _fields(buf) if f == 7 and wt == 2), None)
    ops = []
    for f, wt, node in _fields(graph) if graph is not None else ():
        if f == 1 and wt == 2:
            op, dom = "", ""
            for g, w, v in _fields(node):
                if g == 4 and w == 2:
                    op = bytes(v).decode()
                elif g == 7 and w == 2:
                    dom = bytes(v).decode()
            ops.append((dom or "ai.onnx", op))
    return ops


def _nnapi_table() -> frozenset[str] | None:
    spec = importlib.util.find_spec("onnxruntime")  # the file only: importing onnxruntime.tools pulls in onnx
    if spec is None or not spec.submodule_search_locations:
        return None
    md = Path(list(spec.submodule_search_locations)[0]) / "tools" / "mobile_helpers" / "nnapi_supported_ops.md"
    if not md.is_file():
        return None
    return frozenset(m.group(1) for m in re.finditer(r"^\|ai\.onnx:(\w+)\|", md.read_text(), re.M))


def _xnnpack_takes(ops: list[tuple[str, str]]) -> list[bool]:
    """Per node: would the XNNPACK EP take it (core ops; Q/DQ nodes when a QDQ-capable op sits among them;
    Relu/Clip right behind a node it took)."""
    types = [o for _, o in ops]
    has_qdq_core = any(t in _XNNPACK_QDQ for t in types) and any(t in QDQ_OPS for t in types)
    took = []
    for t in types:
        ok = t in _XNNPACK_CORE or t in _XNNPACK_QLINEAR or (t in QDQ_OPS and has_qdq_core)
        ok = ok or (t in _XNNPACK_FUSED and bool(took) and took[-1])
        took.append(ok)
    return took


def table_support(provider: str, ops: list[tuple[str, str]]) -> dict[str, Any]:
    """{supported_nodes, nodes, cpu_ops (op types left to the CPU), method} of `ops` for QNN | XNNPACK | NNAPI."""
    if provider == "XNNPACK":
        took = _xnnpack_takes(ops)
    else:
        table = QNN_HTP_OPS if provider == "QNN" else _nnapi_table()
        if table is None:
            return {"method": "unknown: onnxruntime's nnapi_supported_ops.md is not installed"}
        took = [d == "ai.onnx" and o in table for d, o in ops]
    cpu = sorted({f"{d}:{o}" if d != "ai.onnx" else o for (d, o), t in zip(ops, took) if not t})
    return {"supported_nodes": sum(took), "nodes": len(ops), "cpu_ops": cpu,
            "method": f"op table: {TABLE_SOURCES[provider]}"}


_PLACED = re.compile(r"(All nodes|Node\(s\)) placed on \[(\w+)\]\. Number of nodes: (\d+)")
_NODE = re.compile(r"\]\s{2,}(\S+) \((.*)\)\s*$")


def parse_placements(log: str) -> dict[str, dict[str, Any]]:
    """onnxruntime's VERBOSE "Node placements" block -> {provider: {nodes, ops: sorted op types}}."""
    out: dict[str, dict[str, Any]] = {}
    cur = None
    for line in log.splitlines():
        m = _PLACED.search(line)
        if m:
            cur = out.setdefault(m.group(2), {"nodes": 0, "ops": set()})
            cur["nodes"] += int(m.group(3))
            continue
        n = _NODE.search(line)
        if n and cur is not None and "placed on" not in line:
            cur["ops"].add(n.group(1))
        elif cur is not None and "VerifyEachNodeIsAssignedToAnEp" not in line:
            cur = None
    return {k: {"nodes": v["nodes"], "ops": sorted(v["ops"])} for k, v in out.items()}


def ort_placement(path: str | os.PathLike, provider: str) -> dict[str, Any]:
    """Create a session of `path` on `provider` (+ CPU) and read onnxruntime's own node placement report (its
    VERBOSE log on stderr, captured through the file descriptor). Needs the provider in this build."""
    import onnxruntime as ort

    so = ort.SessionOptions()
    so.log_severity_level = 0
    so.log_verbosity_level = 0
    chain = [provider] + (["CPUExecutionProvider"] if provider != "CPUExecutionProvider" else [])
    with tempfile.TemporaryFile(mode="w+b") as cap:
        saved = os.dup(2)
        try:
            os.dup2(cap.fileno(), 2)
            ort.InferenceSession(str(path), so, providers=chain)
        finally:
            os.dup2(saved, 2)
            os.close(saved)
        cap.seek(0)
        log = cap.read().decode("utf-8", "replace")
    placed = parse_placements(log)
    total = sum(p["nodes"] for p in placed.values())
    mine = placed.get(provider, {"nodes": 0, "ops": []})
    cpu = placed.get("CPUExecutionProvider", {"ops": []})["ops"] if provider != "CPUExecutionProvider" else []
    return {"supported_nodes": mine["nodes"], "nodes": total, "cpu_ops": cpu, "placements": placed,
            "method": "ort placement (onnxruntime's partitioning of the optimised graph)"}


def provider_support(provider: str, path: str | os.PathLike, available: list[str]) -> dict[str, Any]:
    """What `provider` (QNN | NNAPI | XNNPACK | CPU) would run of the ONNX graph `path`: ORT's own placement when
    the provider is in this build, else its op table."""
    if provider == "CPU":
        n = len(graph_ops(path))
        return {"supported_nodes": n, "nodes": n, "cpu_ops": [], "method": "all ops (CPU EP)"}
    if EP_NAMES[provider] in available:
        return ort_placement(path, EP_NAMES[provider])
    return table_support(provider, graph_ops(path))
