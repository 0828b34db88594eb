"""The int8 side of the Qwen2.5-VL GenAI packages, piece by piece: the block-int8 embedding table and the
Gemm -> MatMul rewrite the weight-only quantiser needs (export/hf_qwen_vl.py)."""
from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")
onnx = pytest.importorskip("onnx")
pytestmark = [pytest.mark.export]


def test_block_int8_table_error_is_bounded_by_half_a_step():
    from mosaicthinker.export.hf_qwen_vl import quantize_rows_int8

    g = torch.Generator().manual_seed(0)
    w = torch.randn(1000, 64, generator=g) * torch.logspace(-3, 1, 1000)[:, None]  # rows of very different scale
    q, s = quantize_rows_int8(w, 16, chunk=300)  # chunks not dividing V
    assert q.dtype == torch.int8 and s.shape == (1000, 4)
    deq = (q.float().reshape(1000, 4, 16) * s[..., None]).reshape(1000, 64)
    step = s.repeat_interleave(16, 1)
    assert torch.all((deq - w).abs() <= 0.5 * step + 1e-7)
    assert torch.allclose(w.reshape(1000, 4, 16).abs().amax(-1), 127 * s)  # each block's max hits the grid end


def test_gemm_rewrite_keeps_the_numbers(tmp_path):
    import onnxruntime as ort
    from onnx import helper, numpy_helper

    from mosaicthinker.export.hf_qwen_vl import gemm_to_matmul

    rng = np.random.default_rng(1)
    w, b = rng.standard_normal((4, 3)).astype(np.float32), rng.standard_normal(4).astype(np.float32)
    w2 = rng.standard_normal((4, 5)).astype(np.float32)
    g = helper.make_graph(
        [helper.make_node("Gemm", ["x", "W", "B"], ["h"], transB=1, name="g1"),
         helper.make_node("Gemm", ["h", "W2"], ["y"], name="g2")], "g",
        [helper.make_tensor_value_info("x", onnx.TensorProto.FLOAT, [2, 3])],
        [helper.make_tensor_value_info("y", onnx.TensorProto.FLOAT, [2, 5])],
        [numpy_helper.from_array(w, "W"), numpy_helper.from_array(b, "B"), numpy_helper.from_array(w2, "W2")])
    m = helper.make_model(g, opset_imports=[helper.make_opsetid("", 18)])
    x = rng.standard_normal((2, 3)).astype(np.float32)
    ref = x @ w.T + b
    ref = ref @ w2
    assert gemm_to_matmul(m) == 2
    assert [n.op_type for n in m.graph.node] == ["MatMul", "Add", "MatMul"]
    onnx.checker.check_model(m)
    got = ort.InferenceSession(m.SerializeToString(), providers=["CPUExecutionProvider"]).run(None, {"x": x})[0]
    np.testing.assert_allclose(got, ref, rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("method,op,bits", [("dynamic", "MatMulInteger", None), ("nbits8", "MatMulNBits", 8),
                                            ("nbits4", "MatMulNBits", 4)])
def test_vision_quantisers_replace_every_constant_matmul(tmp_path, method, op, bits):
    """Each --option vision_quant turns every constant-weight Linear (Gemm or MatMul) into its quantised op, keeps
    the activation x activation MatMul in float, and stays within the int8 parity tolerance on fresh inputs."""
    import onnxruntime as ort
    from onnx import helper, numpy_helper

    from mosaicthinker.export.hf_qwen_vl import quantize_vision

    rng = np.random.default_rng(2)
    w1 = (rng.standard_normal((256, 256)) / 16).astype(np.float32)
    w2 = (rng.standard_normal((256, 128)) / 16).astype(np.float32)
    b1 = rng.standard_normal(256).astype(np.float32)
    g = helper.make_graph(
        [helper.make_node("Gemm", ["x", "W1", "B1"], ["h"], transB=1, name="g1"),
         helper.make_node("MatMul", ["h", "W2"], ["y"], name="m2"),
         helper.make_node("Transpose", ["h"], ["ht"], perm=[1, 0]),
         helper.make_node("MatMul", ["h", "ht"], ["a"], name="act")],  # activation x activation: stays float
        "g", [helper.make_tensor_value_info("x", onnx.TensorProto.FLOAT, [64, 256])],
        [helper.make_tensor_value_info("y", onnx.TensorProto.FLOAT, [64, 128]),
         helper.make_tensor_value_info("a", onnx.TensorProto.FLOAT, [64, 64])],
        [numpy_helper.from_array(w1, "W1"), numpy_helper.from_array(b1, "B1"), numpy_helper.from_array(w2, "W2")])
    src = tmp_path / "fp32" / "model.onnx"
    src.parent.mkdir()
    onnx.save(helper.make_model(g, opset_imports=[helper.make_opsetid("", 18)]), str(src))
    dst = quantize_vision(src, tmp_path / method / "model.onnx", method, block=128)
    nodes = onnx.load(str(dst)).graph.node
    quant = [n for n in nodes if n.op_type == op]
    assert len(quant) == 2
    if bits:
        assert all(a.i == bits for n in quant for a in n.attribute if a.name == "bits")
    assert [n.name for n in nodes if n.op_type == "MatMul"] == ["act"]
    if op == "MatMulInteger":
        # 7-bit weights: onnxruntime's u8s8 kernels add pairs of uint8 x int8 products in int16, which saturates
        # on x86 CPUs without VNNI unless 2 x 255 x |w| <= 32767: with |w| <= 64 every x86 CPU gives these numbers
        model = onnx.load(str(dst))
        inits = {i.name: numpy_helper.to_array(i) for i in model.graph.initializer}
        ws = [inits[n.input[1]] for n in quant if n.input[1] in inits]
        assert len(ws) == 2 and all(w.dtype == np.int8 and np.abs(w.astype(int)).max() <= 64 for w in ws)
    x = rng.standard_normal((64, 256)).astype(np.float32)
    ref = ort.InferenceSession(str(src), providers=["CPUExecutionProvider"]).run(None, {"x": x})
    got = ort.InferenceSession(str(dst), providers=["CPUExecutionProvider"]).run(None, {"x": x})
    for r, q in zip(ref, got):
        rel = np.abs(r - q).max() / np.abs(r).max()
        assert 0 < rel < (0.15 if bits == 4 else 0.05)


def test_unknown_vision_quantiser_is_refused(tmp_path):
    from mosaicthinker.export.hf_qwen_vl import quantize_vision
    from mosaicthinker.runtime.infra.errors import ExportError

    with pytest.raises(ExportError, match="vision_quant"):
        quantize_vision(tmp_path / "x.onnx", tmp_path / "y.onnx", "int3")
