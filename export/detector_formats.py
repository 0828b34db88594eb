"""The three closed-set detector graph formats `mosaic export detector --source onnx:PATH` takes, told apart by the
graph's inputs and outputs, with the pre-processing and runtime settings each format implies.

- `ssd_tflite`: an NHWC image (uint8 or float) -> 4 outputs: boxes [1,N,4], classes [1,N], scores [1,N], count [1]
  (NMS in the graph);
- `yolox`: an NCHW float image -> 1 output [1,A,5+C] of raw anchors (decoding and NMS in the adapter);
- `ultralytics_e2e`: an NCHW or NHWC float image -> [1,N,6+M]: boxes, score, class, M mask coefficients (NMS in
  the graph) and, for a `-seg` model, prototypes [1,M,h,w] / [1,h,w,M].

What the graph cannot say (labels, licence, provenance, whether the weights are trained) still comes from the
metadata sidecar; `arch` and `preprocessing` may be left out of it for these formats (filled in from here), and a
given `arch` that contradicts the graph is refused.
"""
from __future__ import annotations

import os
from typing import Any

from mosaicthinker.runtime.infra.errors import ExportError

# YOLOX (Megvii's demo): letterbox at the top-left on 114 grey, BGR, raw 0-255 floats, NCHW. 416 x 416 is what
# YOLOX-Nano was trained at; the input is symbolic, so another multiple of 32 may be set with --set size=HxW
YOLOX_PREPROCESSING: dict[str, Any] = {"size": [416, 416], "layout": "NCHW", "channel_order": "BGR",
                                       "dtype": "float32", "resize": "letterbox", "letterbox": "top-left",
                                       "pad_value": 114}
# Ultralytics LetterBox: centred on 114 grey, RGB, /255
ULTRALYTICS_PREPROCESSING: dict[str, Any] = {"layout": "NHWC", "channel_order": "RGB", "dtype": "float32",
                                             "scale": 1.0 / 255.0, "resize": "letterbox", "letterbox": "centre",
                                             "pad_value": 114}
# score_threshold: what the key-frame search counts and a view may stand on alone; candidate_threshold: key-frame
# candidates the map verifies across views (docs/perception.md)
YOLOX_CONFIG: dict[str, Any] = {"score_threshold": 0.5, "candidate_threshold": 0.25, "nms_iou": 0.45,
                                "strides": [8, 16, 32]}
ULTRALYTICS_CONFIG: dict[str, Any] = {"score_threshold": 0.5, "candidate_threshold": 0.25}
SSD_CONFIG: dict[str, Any] = {"score_threshold": 0.5}

FORMATS = ("ssd_tflite", "yolox", "ultralytics_e2e")


def _dims(shape: Any) -> list[Any]:
    return list(shape or [])


def detect_format(path: str | os.PathLike) -> dict[str, Any]:
    """The detector format of an ONNX graph from its inputs/outputs (onnxruntime, no `onnx` needed):
    {"arch", "layout" (of the image input), "size" [h, w] or None when symbolic, "classes" (C, when the graph
    tells), "mask_coefficients" (M, Ultralytics), "prototypes" (bool), "box_units" (Ultralytics guess: "pixels" for
    an NCHW PyTorch export, "normalised" for an NHWC TFLite conversion)}. ExportError naming the outputs when
    the graph is none of the three."""
    import onnxruntime as ort

    so = ort.SessionOptions()
    so.log_severity_level = 3
    ort.set_default_logger_severity(3)
    so.graph_optimization_level = ort.GraphOptimizationLevel.ORT_DISABLE_ALL
    try:
        sess = ort.InferenceSession(str(path), so, providers=["CPUExecutionProvider"])
    except Exception as e:  # noqa: BLE001 - onnxruntime raises its own types; say which file
        raise ExportError(f"{path}: onnxruntime cannot load the graph ({e})") from e
    ins, outs = sess.get_inputs(), sess.get_outputs()
    images = [i for i in ins if len(_dims(i.shape)) == 4]
    if len(images) != 1:
        raise ExportError(f"{path}: expected one image input [1, 3, H, W] or [1, H, W, 3], got "
                          f"{[(i.name, i.shape) for i in ins]}")
    shp = _dims(images[0].shape)
    layout = "NCHW" if shp[1] == 3 else "NHWC" if shp[3] == 3 else None
    if layout is None:
        raise ExportError(f"{path}: image input {images[0].name} {shp} has no 3-channel axis")
    hw = shp[2:4] if layout == "NCHW" else shp[1:3]
    size = [int(v) for v in hw] if all(isinstance(v, int) and v > 0 for v in hw) else None
    ranks = sorted(len(_dims(o.shape)) for o in outs)
    described = [(o.name, o.shape) for o in outs]
    if len(outs) == 4 and ranks == [1, 2, 2, 3]:
        return {"arch": "ssd_tflite", "layout": layout, "size": size, "dtype": _dtype(images[0].type)}
    three = [o for o in outs if len(_dims(o.shape)) == 3]
    four = [o for o in outs if len(_dims(o.shape)) == 4]
    if len(outs) == 1 and len(three) == 1:
        last = _dims(three[0].shape)[-1]
        if isinstance(last, int) and last == 6 and layout is not None and _fixed_rows(three[0]):
            return {"arch": "ultralytics_e2e", "layout": layout, "size": size, "mask_coefficients": 0,
                    "prototypes": False, "box_units": "pixels" if layout == "NCHW" else "normalised"}
        if isinstance(last, int) and last > 5 and layout == "NCHW":
            return {"arch": "yolox", "layout": layout, "size": size, "classes": last - 5}
    if len(outs) == 2 and len(three) == 1 and len(four) == 1:
        last = _dims(three[0].shape)[-1]
        p = _dims(four[0].shape)
        m = last - 6 if isinstance(last, int) else None
        if m and m > 0 and (p[1] == m or p[3] == m):
            return {"arch": "ultralytics_e2e", "layout": layout, "size": size, "mask_coefficients": m,
                    "prototypes": True, "box_units": "pixels" if layout == "NCHW" else "normalised"}
    raise ExportError(f"{path}: not a detector format this exporter knows: outputs {described}; expected an "
                      f"SSD with NMS (boxes, classes, scores, count), YOLOX raw anchors [1, A, 5 + C], or an "
                      f"Ultralytics end-to-end export [1, N, 6 + M] (+ prototypes)")


def _fixed_rows(o: Any) -> bool:
    d = _dims(o.shape)
    return isinstance(d[1], int) and d[1] <= 1000  # an end-to-end graph's fixed top-N, not an anchor count


def _dtype(t: str) -> str:
    return {"tensor(uint8)": "uint8", "tensor(float)": "float32", "tensor(float16)": "float16"}.get(t, "float32")


def format_meta(fmt: dict[str, Any], given: dict[str, Any], where: str) -> dict[str, Any]:
    """`arch`, `preprocessing` and `config` for a detected format, merged under what the sidecar `given` says
    (given values win; a given arch that differs from the graph's format is an error naming `where`)."""
    arch = fmt["arch"]
    if given.get("arch") and given["arch"] != arch:
        raise ExportError(f"{where}: arch {given['arch']!r} but the graph is the {arch!r} format (its outputs); "
                          f"fix the arch or leave it out")
    if arch == "yolox":
        pp, cfg = dict(YOLOX_PREPROCESSING), dict(YOLOX_CONFIG)
        if fmt.get("size"):
            pp["size"] = fmt["size"]
    elif arch == "ultralytics_e2e":
        pp = dict(ULTRALYTICS_PREPROCESSING, layout=fmt["layout"])
        pp["size"] = fmt.get("size") or [640, 640]
        cfg = dict(ULTRALYTICS_CONFIG, box_units=fmt["box_units"])
    else:
        pp = {"size": fmt.get("size") or [300, 300], "layout": "NHWC", "channel_order": "RGB",
              "dtype": fmt.get("dtype", "uint8"), "resize": "bilinear"}
        cfg = dict(SSD_CONFIG)
    return {"arch": arch, "preprocessing": {**pp, **(given.get("preprocessing") or {})},
            "config": {**cfg, **(given.get("config") or {})}}
