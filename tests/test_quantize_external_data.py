"""export/common.quantize_int8_dynamic on a graph whose weights live in external data (as every 2B graph's do:
protobuf's 2 GiB limit): the int8 copy must also be written with external data, load, and stay close to fp32."""
from __future__ import annotations

import numpy as np
import pytest

onnx = pytest.importorskip("onnx")
ort = pytest.importorskip("onnxruntime")

pytestmark = [pytest.mark.export]


def _matmul_model(path, w: np.ndarray, external: bool):
    from onnx import TensorProto, helper, numpy_helper

    g = helper.make_graph([helper.make_node("MatMul", ["x", "w"], ["y"])], "mm",
                          [helper.make_tensor_value_info("x", TensorProto.FLOAT, [None, w.shape[0]])],
                          [helper.make_tensor_value_info("y", TensorProto.FLOAT, [None, w.shape[1]])],
                          [numpy_helper.from_array(w, "w")])
    m = helper.make_model(g, opset_imports=[helper.make_opsetid("", 17)])
    onnx.save_model(m, str(path), save_as_external_data=external, all_tensors_to_one_file=True,
                    location=path.name + ".data", size_threshold=0)
    return path


@pytest.mark.parametrize("external", [True, False])
def test_int8_copy_keeps_external_data_when_the_source_has_it(tmp_path, external):
    from mosaicthinker.export import common as C
    from mosaicthinker.runtime.infra.bundle import external_data_locations

    rng = np.random.default_rng(0)
    w = rng.standard_normal((256, 128)).astype(np.float32)
    (tmp_path / "fp32").mkdir()
    src = _matmul_model(tmp_path / "fp32" / "g.onnx", w, external)
    dst = C.quantize_int8_dynamic(src, tmp_path / "int8.onnx")
    locs = external_data_locations(dst)
    assert locs == (["int8.onnx.data"] if external else [])
    assert (tmp_path / "int8.onnx.data").is_file() == external
    x = rng.standard_normal((4, 256)).astype(np.float32)
    got = ort.InferenceSession(str(dst), providers=["CPUExecutionProvider"]).run(None, {"x": x})[0]
    ref = x @ w
    assert np.abs(got - ref).max() / np.abs(ref).max() < 0.05  # int8 weights: close, not equal
    assert not np.array_equal(got, ref)
