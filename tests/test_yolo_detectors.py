"""YOLOX-Nano and YOLO11n-seg adapters on the real models of ../shared/models and real kitchen frames: decoding,
letterbox geometry, NMS, instance masks, the merged key-frame detections and the three detector formats."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from mosaicthinker.runtime.geometry import box_iou
from mosaicthinker.runtime.infra.trace import Trace
from mosaicthinker.runtime.perceive import merge_detections
from mosaicthinker.runtime.types import Detections


def _rgb(redkitchen: Path, i: int) -> np.ndarray:
    import cv2

    return cv2.cvtColor(cv2.imread(str(redkitchen / f"frame-{i:06d}.color.jpg")), cv2.COLOR_BGR2RGB)


@pytest.fixture(scope="module")
def models(shared_bundle: Path):
    from mosaicthinker.runtime.models import load_role

    tr = Trace()
    return (load_role(shared_bundle, "detector", threads=1, trace=tr),
            load_role(shared_bundle, "instance_segmenter", threads=1, trace=tr), tr)


def test_nms_keeps_the_best_of_each_overlapping_group_per_class():
    from mosaicthinker.runtime.models.yolo import class_nms, nms

    boxes = np.array([[0, 0, 10, 10], [1, 1, 11, 11], [20, 20, 30, 30], [0, 0, 10, 10]], np.float32)
    scores = np.array([0.9, 0.8, 0.7, 0.6], np.float32)
    # IoU(0, 1) = 81 / 119 = 0.68: suppressed at 0.45, kept at 0.7; box 3 repeats box 0 exactly
    assert nms(boxes, scores, 0.45).tolist() == [0, 2]
    assert nms(boxes, scores, 0.7).tolist() == [0, 1, 2]
    # the same boxes in another class never suppress each other
    assert class_nms(boxes, scores, np.array([0, 0, 0, 1]), 0.45).tolist() == [0, 2, 3]


def test_yolox_sees_the_kitchen_objects_and_undoes_its_letterbox(models, redkitchen: Path):
    det, seg, _ = models
    rgb = _rgb(redkitchen, 200)  # the table, chairs and both mugs in view
    d = det.detect(rgb, ["table", "chair", "cup", "pillow"])
    assert d.undetectable == ["pillow"] and {"table", "chair", "cup"} <= set(d.names)
    assert np.all(d.scores >= det.conf.score_threshold)
    assert np.all(d.boxes[:, 2] <= 640) and np.all(d.boxes[:, 3] <= 480)
    # the letterbox is undone: the same frame at half size gives the same objects at half the coordinates
    import cv2

    small = cv2.resize(rgb, (320, 240), interpolation=cv2.INTER_AREA)
    h = det.detect(small, ["table", "chair", "cup"])
    for name in ("table", "chair"):
        a, b = d.boxes[[n == name for n in d.names]], h.boxes[[n == name for n in h.names]] * 2
        assert len(a) and len(b) and box_iou(a, b).max(1).min() > 0.6, name
    # candidates below the search's threshold come only when asked for
    low = det.detect(rgb, ["table", "chair", "cup"], min_score=0.0)
    assert len(low) >= len(d) and low.scores.min() >= det.conf.candidate_threshold


def test_the_two_yolo_models_agree_on_the_chair_and_masks_follow_it(models, redkitchen: Path):
    det, seg, tr = models
    rgb = _rgb(redkitchen, 100)
    a = det.detect(rgb, ["chair"])
    s = seg.detect(rgb, ["chair"], masks=True)
    assert len(a) and len(s) and box_iou(s.boxes, a.boxes).max() > 0.5  # two independent models, one chair
    assert s.masks.shape == (len(s), 480, 640) and s.mask_from == ["instance_segmenter"] * len(s)
    for b, m in zip(s.boxes, s.masks):
        (x0, y0), (x1, y1) = np.floor(b[:2]).astype(int), np.ceil(b[2:]).astype(int)
        inside = m[max(0, y0):y1, max(0, x0):x1].sum()
        assert m.sum() == inside and inside > 0.25 * (x1 - x0) * (y1 - y0)  # in its box, and fills much of it
    # the segmenter interface: the mask of its own detection over a given box (YOLOX's), empty elsewhere
    got = seg.segment(rgb, np.concatenate([a.boxes[:1], [[0, 0, 40, 40]]]), ["chair", "chair"])
    assert got[0].sum() > 0.5 * s.masks[0].sum() and got[1].sum() == 0
    assert seg.class_mask(rgb, "chair").sum() >= s.masks[0].sum() and seg.class_mask(rgb, "pillow") is None
    assert tr.stages["instance_segmenter"].calls == 1  # one graph run per image, whatever is asked


def test_ultralytics_letterbox_is_centred_and_undone(models, redkitchen: Path):
    import cv2

    _, seg, _ = models
    rgb = _rgb(redkitchen, 200)
    d = seg.detect(rgb, ["chair", "cup"])
    tall = np.ascontiguousarray(rgb[:, 200:560])  # another aspect: padded left and right, not top and bottom
    t = seg.detect(tall, ["chair", "cup"])
    back = t.boxes + np.array([200, 0, 200, 0], np.float32)
    inner = (d.boxes[:, 0] > 205) & (d.boxes[:, 2] < 555)  # whole in the crop
    assert inner.sum() >= 2 and box_iou(d.boxes[inner], back).max(1).min() > 0.7


def test_merged_keyframe_detections_pair_one_object_once():
    H, W = 20, 30
    m = np.zeros((1, H, W), bool)
    m[0, 2:8, 2:8] = True
    inst = Detections([[2, 2, 8, 8]], [0.4], ["chair"], masks=m, mask_from=["instance_segmenter"])
    boxes = Detections([[2.5, 2, 8, 8.5], [15, 10, 25, 18], [2, 2, 8, 8]], [0.7, 0.6, 0.3], ["chair", "cup", "sink"])
    out = merge_detections(inst, boxes)
    # the chair once, with the segmenter's box and mask and the better score; the cup and the (other name) sink kept
    assert out.names == ["chair", "cup", "sink"] and np.allclose(out.scores, [0.7, 0.6, 0.3])
    assert out.boxes[0].tolist() == [2, 2, 8, 8] and out.masks[0].sum() == 36 and not out.masks[1:].any()
    assert out.mask_from == ["instance_segmenter", "none", "none"]
    assert merge_detections(inst, Detections.empty()).names == ["chair"]


def test_detector_formats_are_told_apart_by_their_outputs(shared_models: Path, tmp_path: Path):
    from mosaicthinker.export.detector_formats import detect_format, format_meta
    from mosaicthinker.runtime.infra.errors import ExportError

    fmt = {n: detect_format(shared_models / p) for n, p in (
        ("ssd", "ssd-mobilenet-v1-coco/ssd_mobilenet_v1_coco.onnx"), ("yolox", "yolox-nano-coco/yolox_nano.onnx"),
        ("seg", "yolo11n-seg-coco/yolo11n-seg_int8.onnx"))}
    assert fmt["ssd"]["arch"] == "ssd_tflite" and fmt["ssd"]["dtype"] == "uint8"
    assert fmt["yolox"] == {"arch": "yolox", "layout": "NCHW", "size": None, "classes": 80}
    assert fmt["seg"]["arch"] == "ultralytics_e2e" and fmt["seg"]["mask_coefficients"] == 32
    assert fmt["seg"]["box_units"] == "normalised" and fmt["seg"]["size"] == [640, 640]
    assert format_meta(fmt["yolox"], {}, "x")["preprocessing"]["channel_order"] == "BGR"
    with pytest.raises(ExportError, match="arch 'ssd_tflite' but the graph is the 'yolox' format"):
        format_meta(fmt["yolox"], {"arch": "ssd_tflite"}, "sidecar.json")
    with pytest.raises(ExportError, match="not a detector format"):
        detect_format(shared_models / "pydnet" / "pydnet.onnx")
