"""Writes the tiny role graphs of tests/test_schema_fuzz.py (run once with the `export` extra; the .onnx files
are committed so the fuzz tests run on the light runtime). Each follows its adapter's graph contract on 8x8 RGB:
depth [1,8,8,3] f32 -> [1,8,8,1]; ssd_tflite [1,8,8,3] u8 -> boxes [1,2,4], classes [1,2], scores [1,2], count [1];
deeplab [1,8,8,3] f32 -> logits [1,8,8,3]; embedder [1,8,8,3] u8 -> [1,3]."""
from pathlib import Path

import numpy as np
import onnx
from onnx import TensorProto as T
from onnx import helper as h
from onnx import numpy_helper as nh

HERE = Path(__file__).parent


def save(name, nodes, inputs, outputs, inits=()):
    g = h.make_graph(nodes, name, inputs, outputs, list(inits))
    m = h.make_model(g, opset_imports=[h.make_opsetid("", 17)])
    m.ir_version = 8
    onnx.checker.check_model(m)
    onnx.save(m, str(HERE / f"{name}.onnx"))


img = lambda n, t: h.make_tensor_value_info(n, t, [1, 8, 8, 3])  # noqa: E731
save("depth", [h.make_node("ReduceMean", ["x"], ["m"], axes=[3], keepdims=1),
               h.make_node("Add", ["m", "one"], ["y"])],
     [img("x", T.FLOAT)], [h.make_tensor_value_info("y", T.FLOAT, [1, 8, 8, 1])],
     [nh.from_array(np.array(1.0, np.float32), "one")])
save("detector", [h.make_node("Cast", ["x"], ["xf"], to=T.FLOAT),
                  h.make_node("ReduceSum", ["xf"], ["s"], keepdims=0),
                  h.make_node("Mul", ["s", "zero"], ["z"]),
                  h.make_node("Add", ["b0", "z"], ["boxes"]), h.make_node("Add", ["c0", "z"], ["classes"]),
                  h.make_node("Add", ["s0", "z"], ["scores"]), h.make_node("Add", ["n0", "z"], ["count"])],
     [img("x", T.UINT8)],
     [h.make_tensor_value_info("boxes", T.FLOAT, [1, 2, 4]), h.make_tensor_value_info("classes", T.FLOAT, [1, 2]),
      h.make_tensor_value_info("scores", T.FLOAT, [1, 2]), h.make_tensor_value_info("count", T.FLOAT, [1])],
     [nh.from_array(np.array(0.0, np.float32), "zero"),
      nh.from_array(np.array([[[0.1, 0.1, 0.5, 0.5], [0.4, 0.4, 0.9, 0.9]]], np.float32), "b0"),
      nh.from_array(np.array([[1.0, 2.0]], np.float32), "c0"), nh.from_array(np.array([[0.9, 0.7]], np.float32), "s0"),
      nh.from_array(np.array([2.0], np.float32), "n0")])
save("segmenter", [h.make_node("MatMul", ["x", "w"], ["y"])], [img("x", T.FLOAT)],
     [h.make_tensor_value_info("y", T.FLOAT, [1, 8, 8, 3])],
     [nh.from_array(np.eye(3, dtype=np.float32), "w")])
save("embedder", [h.make_node("Cast", ["x"], ["xf"], to=T.FLOAT),
                  h.make_node("ReduceMean", ["xf"], ["y"], axes=[1, 2], keepdims=0)],
     [img("x", T.UINT8)], [h.make_tensor_value_info("y", T.FLOAT, [1, 3])])
