"""YOLO11n-seg (a fixed 640x640 Ultralytics TFLite conversion) re-shaped for 640x480 frames: every size-dependent
constant found and rewritten, the graph runs at 480x640, finds the square graph's detections on real frames, and
the export refuses what it cannot re-shape."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytestmark = [pytest.mark.export, pytest.mark.slow]

SEG = "yolo11n-seg-coco/yolo11n-seg_int8.onnx"


def test_rect_graph_rewrites_the_size_constants_and_agrees_with_the_square_graph(shared_models, redkitchen,
                                                                                  tmp_path: Path):
    import onnxruntime as ort

    from mosaicthinker.export.common import calibration_frames
    from mosaicthinker.export.ultralytics_rect import _anchors, agreement, rect_graph

    info = rect_graph(shared_models / SEG, tmp_path / "r.onnx", [480, 640])
    # 11 reshapes (3 levels x 2 heads + the DFL's 3 + the stride-32 attention's 2), the batch offset, anchors,
    # per-anchor strides
    assert info["patched"] == {"reshape": 11, "offset": 1, "anchors": 1, "strides": 1}
    s = ort.InferenceSession(str(tmp_path / "r.onnx"), providers=["CPUExecutionProvider"])
    dets, protos = s.run(None, {"images": np.zeros((1, 480, 640, 3), np.float32)})
    assert dets.shape == (1, 300, 38) and protos.shape == (1, 120, 160, 32)
    # anchors: x over the width, y over the height; the first cell's centre, the last stride-32 cell's
    a = _anchors([(8, 60, 80), (16, 30, 40), (32, 15, 20)], 480, 640)
    assert a.shape == (1, 2, 6300) and np.allclose(a[0, :, 0], [4 / 640, 4 / 480])
    assert np.allclose(a[0, :, -1], [(19.5 * 32) / 640, (14.5 * 32) / 480])
    task = agreement(shared_models / SEG, tmp_path / "r.onnx", calibration_frames(redkitchen, 6))
    assert task["detections"] >= 10 and task["found"] >= 0.9 and task["mean_iou"] > 0.9


def test_the_export_resizes_only_what_it_can_check(shared_models, redkitchen, tmp_path: Path):
    import json

    from mosaicthinker.export.cli import _export_roles
    from mosaicthinker.runtime.infra.bundle import load_bundle
    from mosaicthinker.runtime.infra.errors import ExportError
    from mosaicthinker.export.ultralytics_rect import rect_graph

    labels = [x.strip() for x in (shared_models / "yolo11n-seg-coco" / "coco80_labels.txt").read_text().splitlines()]
    side = tmp_path / "seg.json"
    side.write_text(json.dumps({"licence": "AGPL-3.0", "random_weights": False,
                                "semantics": {"vocabulary": "closed", "labels": labels}}))

    class Args:
        role, source, precision, meta, weights = "instance_segmenter", f"onnx:{shared_models / SEG}", "fp32", \
            str(side), None
        set, calib, target = ["size=480x640"], None, "cpu"

    with pytest.raises(ExportError, match="--calib"):
        _export_roles(Args, tmp_path / "b")
    Args.calib = str(redkitchen)
    _export_roles(Args, tmp_path / "b")
    spec = load_bundle(tmp_path / "b").spec("instance_segmenter")
    assert spec.preprocessing["size"] == [480, 640] and spec.meta["provenance"]["resized"]["task_check"]["found"] >= 0.9
    with pytest.raises(ExportError, match="multiples of 32"):
        rect_graph(shared_models / SEG, tmp_path / "x.onnx", [470, 640])
    with pytest.raises(ExportError, match="square NHWC input"):
        rect_graph(shared_models / "yolox-nano-coco" / "yolox_nano.onnx", tmp_path / "y.onnx", [480, 640])
