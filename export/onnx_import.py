"""`--source onnx:PATH`: import an existing ONNX graph into a bundle, and the one-shot import of the four real
models in ../shared/models (PyDNet++ depth, SSD MobileNet v1 COCO detector, DeepLabv3 VOC segmenter,
MobileNetV1 embedding) with their metadata.

Metadata for a generic import comes from a sidecar JSON file (`PATH.mosaic.json` next to the model, or
`--meta FILE`) holding the `role_meta` fields (documented with a worked example in docs/bundle-and-adapters.md)::

    {"arch": "pydnet", "licence": "Apache-2.0", "random_weights": false,
     "preprocessing": {"size": [448, 640], "layout": "NHWC", "channel_order": "RGB", "dtype": "float32",
                       "scale": 0.00392156862745098},
     "semantics": {"depth": "relative"}, "provenance": {"source": "..."}, "config": {}}

The imported file is copied unchanged as the `fp32` variant (parity: identical by construction; the file's
sha256 is the provenance). fp16 / int8 variants are converted here and parity-checked against it on fresh
random inputs; one that fails is not shipped and the reason is recorded in `skipped_variants`.
"""
from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import Any, Callable

import numpy as np

from mosaicthinker.host import bundle_write as B
from mosaicthinker.runtime.infra.errors import ExportError, InputError
from mosaicthinker.runtime.infra.progress import ticked

from .detector_formats import ULTRALYTICS_CONFIG, ULTRALYTICS_PREPROCESSING, YOLOX_CONFIG, YOLOX_PREPROCESSING
from .common import (Feeds, add_variant_files, calibration_frames, progress, quantize_variant,
                     record_skipped_variant, role_meta)

SHARED_PROVENANCE_NOTE = "tf2onnx (opset 17) conversion of the TFLite file beside it in ../shared/models"


def _labels(path: Path) -> list[str]:
    return [ln.strip() for ln in path.read_text().splitlines()]


def shared_model_specs(models_dir: str | os.PathLike) -> dict[str, dict[str, Any]]:
    """key -> {"role", "file": Path, "meta": role_meta dict, "alternative": bool} for the real models in
    ../shared/models (see its README): depth, detector (YOLOX-Nano, the default), detector-ssd (the SSD, kept as
    the detector's `ssd-fp32` variant), instance_segmenter (YOLO11n-seg, AGPL-3.0), segmenter (DeepLab), embedder."""
    d = Path(models_dir)
    voc = [x for x in _labels(d / "deeplabv3-mobilenetv2-voc" / "pascal_voc_segmentation_labels.txt")[:21]]
    coco = _labels(d / "ssd-mobilenet-v1-coco" / "coco_labels.txt")
    coco80 = _labels(d / "yolox-nano-coco" / "coco80_labels.txt")
    coco80_seg = _labels(d / "yolo11n-seg-coco" / "coco80_labels.txt")
    if len(voc) != 21 or voc[0] != "background" or voc[-1] != "tvmonitor":
        raise ExportError(f"{d}/deeplabv3-mobilenetv2-voc/pascal_voc_segmentation_labels.txt: expected the 21 VOC "
                          f"labels background..tvmonitor")
    if len(coco) != 90 or coco[0] != "person":
        raise ExportError(f"{d}/ssd-mobilenet-v1-coco/coco_labels.txt: expected 90 lines starting with person")
    for name, lab in (("yolox-nano-coco", coco80), ("yolo11n-seg-coco", coco80_seg)):
        if len(lab) != 80 or lab[0] != "person" or lab[56] != "chair":
            raise ExportError(f"{d}/{name}/coco80_labels.txt: expected the 80 contiguous COCO labels (person ... "
                              f"56 chair ...)")

    prov = _provenance(d)
    return {**_depth_embedder_specs(d, prov), **_detector_specs(d, prov, coco, coco80),
            **_segmenter_specs(d, prov, voc, coco80_seg)}


def _provenance(d: Path) -> Callable[..., dict[str, Any]]:
    def prov(folder: str, fname: str, upstream: str, conversion: str = SHARED_PROVENANCE_NOTE) -> dict[str, Any]:
        f = d / folder / fname
        return {"source": f"onnx:{folder}/{fname}", "upstream": upstream, "conversion": conversion,
                "sha256": B.sha256_file(f)}

    return prov


def _depth_embedder_specs(d: Path, prov: Callable[..., dict[str, Any]]) -> dict[str, dict[str, Any]]:
    return {
        "depth": {"role": "depth", "file": d / "pydnet" / "pydnet.onnx", "meta": role_meta(
            "pydnet", licence="Apache-2.0", name="PyDNet++", random_weights=False,
            preprocessing={"size": [448, 640], "layout": "NHWC", "channel_order": "RGB", "dtype": "float32",
                           "scale": 1.0 / 255.0, "resize": "bilinear"},
            semantics={"depth": "relative", "note": "affine in depth, larger = farther; not metric"},
            provenance=prov("pydnet", "pydnet.onnx",
                            "FilippoAleotti/mobilePydnet Android/app/src/main/assets/optimized_pydnet++.tflite "
                            "(blob f6032de7)"),
            config={"output": 0})},
        "embedder": {"role": "embedder", "file": d / "mobilenet-v1-embedding" / "mobilenet_v1_embedding.onnx",
                     "meta": role_meta(
            "mobilenet_embedding", licence="Apache-2.0", name="MobileNetV1 embedding (ImageNet)",
            random_weights=False,
            preprocessing={"size": [224, 224], "layout": "NHWC", "channel_order": "RGB", "dtype": "uint8",
                           "resize": "bilinear"},
            semantics={"dim": 1024, "kind": "ImageNet MobileNetV1 pooled features (not CLIP)",
                       "output": "uint8 [1,1,1,1024], cast to float and L2-normalise"},
            provenance=prov("mobilenet-v1-embedding", "mobilenet_v1_embedding.onnx",
                            "google-coral/test_data@104342d2 mobilenet_v1_1.0_224_quant_embedding_extractor.tflite"),
            config={"output": 0})},
    }


def _detector_specs(d: Path, prov: Callable[..., dict[str, Any]], coco: list[str], coco80: list[str]
                    ) -> dict[str, dict[str, Any]]:
    return {
        "detector": {"role": "detector", "file": d / "yolox-nano-coco" / "yolox_nano.onnx", "meta": role_meta(
            "yolox", licence="Apache-2.0", name="YOLOX-Nano (COCO)", random_weights=False,
            preprocessing=YOLOX_PREPROCESSING,
            semantics={"vocabulary": "closed", "labels": coco80, "label_source": "coco80_labels.txt (contiguous "
                       "80 COCO classes)", "outputs": "output [1,A,85]: raw anchors (4 box values, objectness, 80 "
                       "class probabilities); decoding and NMS in the adapter"},
            provenance=prov("yolox-nano-coco", "yolox_nano.onnx", "Bigisland1729/object-detection-models@6e770c5e "
                            "yolox_nano.onnx (YOLOX, Megvii)", "PyTorch ONNX export by its publisher (opset 11); "
                            "input height/width and anchor count made symbolic in ../shared/models"),
            config=dict(YOLOX_CONFIG))},
        "detector-ssd": {"role": "detector", "alternative": True,
                         "file": d / "ssd-mobilenet-v1-coco" / "ssd_mobilenet_v1_coco.onnx", "meta": role_meta(
            "ssd_tflite", licence="Apache-2.0", name="SSD MobileNet v1 (COCO)", random_weights=False,
            preprocessing={"size": [300, 300], "layout": "NHWC", "channel_order": "RGB", "dtype": "uint8",
                           "resize": "bilinear"},
            semantics={"vocabulary": "closed", "labels": coco, "label_source": "coco_labels.txt (class id = "
                       "0-based line index, 'n/a' lines are unused ids)",
                       "outputs": "boxes [1,10,4] ymin,xmin,ymax,xmax normalised; classes [1,10]; scores [1,10]; "
                                  "count [1]; NMS inside the graph"},
            provenance=prov("ssd-mobilenet-v1-coco", "ssd_mobilenet_v1_coco.onnx",
                            "tensorflow/tflite-support@dd3362ea coco_ssd_mobilenet_v1_1.0_quant_2018_06_29.tflite"),
            config={"score_threshold": 0.5})},
    }


def _segmenter_specs(d: Path, prov: Callable[..., dict[str, Any]], voc: list[str], coco80_seg: list[str]
                     ) -> dict[str, dict[str, Any]]:
    return {
        "instance_segmenter": {"role": "instance_segmenter",
                               "file": d / "yolo11n-seg-coco" / "yolo11n-seg_int8.onnx", "meta": role_meta(
            "ultralytics_e2e", licence="AGPL-3.0", name="YOLO11n-seg (COCO)", random_weights=False,
            preprocessing=dict(ULTRALYTICS_PREPROCESSING, size=[640, 640], layout="NHWC"),
            semantics={"vocabulary": "closed", "labels": coco80_seg, "kind": "instance",
                       "label_source": "coco80_labels.txt (the export's metadata.json names)",
                       "outputs": "Identity [1,300,38]: x1,y1,x2,y2 (fractions of the input), score, class, 32 "
                                  "mask coefficients; Identity_1 [1,160,160,32] prototypes; NMS inside the graph"},
            provenance={**prov("yolo11n-seg-coco", "yolo11n-seg_int8.onnx",
                               "HE-22/realtimehitbox-detection@6f7cc564 mobile_export/yolo11n-seg_int8.tflite "
                               "(stock Ultralytics yolo11n-seg.pt, Ultralytics 8.3.240, int8=True, nms=True)"),
                        "licence_note": "Ultralytics weights under AGPL-3.0 (strong copyleft, which also reaches "
                                        "software offered to users over a network): a test asset here"},
            config={**ULTRALYTICS_CONFIG, "box_units": "normalised"},
            notes="weights stored int8 with float activations (onnx2tf dynamic-range quantisation of the TFLite "
                  "export): further int8 conversion is not attempted")},
        "segmenter": {"role": "segmenter", "file": d / "deeplabv3-mobilenetv2-voc" / "deeplabv3_voc.onnx",
                      "meta": role_meta(
            "deeplab", licence="Apache-2.0", name="DeepLabv3 MobileNetV2 (VOC)", random_weights=False,
            preprocessing={"size": [257, 257], "layout": "NHWC", "channel_order": "RGB", "dtype": "float32",
                           "mean": [127.5, 127.5, 127.5], "std": [127.5, 127.5, 127.5], "resize": "bilinear"},
            semantics={"kind": "semantic", "labels": voc, "prompts": "ignores point prompts; boxes select pixels "
                                                                     "of the name's class"},
            provenance=prov("deeplabv3-mobilenetv2-voc", "deeplabv3_voc.onnx",
                            "tensorflow/tflite-support@dd3362ea lite-model_deeplabv3_1_metadata_2.tflite"),
            config={"logits_layout": "NHWC"})},
    }


def random_feeds_for(path: str | os.PathLike) -> Callable[[np.random.Generator], Feeds]:
    """make_inputs(rng) for parity: uniform inputs over each input's natural range (uint8: 0..255,
    float: [0, 1] scaled by `scale`), shapes from the graph (dynamic dims -> 1)."""
    ins, _, _ = B.io_spec_from_onnx(path)

    def make(rng: np.random.Generator) -> Feeds:
        feeds = {}
        for i in ins:
            shape = [s if s > 0 else 1 for s in i["shape"]]
            if i["dtype"] == "uint8":
                feeds[i["name"]] = rng.integers(0, 256, shape, dtype=np.uint8)
            elif i["dtype"].startswith("int"):
                feeds[i["name"]] = rng.integers(0, 8, shape).astype(i["dtype"])
            else:
                feeds[i["name"]] = rng.random(shape, dtype=np.float32).astype(i["dtype"])
        return feeds

    return make


def _float_range_feeds(path: Path, lo: float, hi: float) -> Callable[[np.random.Generator], Feeds]:
    base = random_feeds_for(path)

    def make(rng: np.random.Generator) -> Feeds:
        f = base(rng)
        return {k: (v * (hi - lo) + lo).astype(v.dtype) if v.dtype.kind == "f" else v for k, v in f.items()}

    return make


def import_onnx(out: str | os.PathLike, role: str, path: str | os.PathLike, meta: dict[str, Any],
                precisions: list[str] = ("fp32",), *, calib: str | os.PathLike | None = None,
                make_inputs: Callable[[np.random.Generator], Feeds] | None = None,
                outputs: list[int] | None = None, prefix: str = "", alternative: bool = False) -> dict[str, Any]:
    """Copy `path` into bundle `out` as role/<prefix>fp32, then make and parity-check the other precisions.
    alternative=True: another model for an existing role (variants `<prefix>...` with their own metadata).

    Returns {"role", "variants": {name: parity}, "skipped": {name: reason}}.
    """
    path = Path(path)
    if not path.is_file():
        raise ExportError(f"--source onnx:{path}: file not found")
    progress(f"import {path.name} as {role}/{prefix}fp32")
    resized = (meta.get("provenance") or {}).get("resized")
    first = ({"ok": True, "reference": "the imported file itself (copied unchanged)"} if not resized else
             {"ok": True, "reference": f"the imported graph re-shaped to {resized['size']} (ultralytics_rect)",
              "task": resized["task_check"]})
    add_variant_files(out, role, f"{prefix}fp32", {"model": path}, meta=meta, precision="fp32",
                      parity={"model": first}, notes=meta.get("notes"), alternative=alternative)
    res: dict[str, Any] = {"role": role, "variants": {f"{prefix}fp32": {"ok": True, "copied": not resized,
                                                                          **({"task": resized["task_check"]}
                                                                             if resized else {})}},
                           "skipped": {}}
    make_inputs = make_inputs or random_feeds_for(path)
    calib_feeds: list[Feeds] = []
    if "int8-qdq" in precisions:
        if calib is None:
            raise ExportError("--precision int8-qdq needs calibration frames: --calib FOLDER_OR_VIDEO")
        calib_feeds = calibration_feeds(path, meta["preprocessing"], calib)
    with tempfile.TemporaryDirectory() as td:
        for prec in ticked([p for p in precisions if p != "fp32"], f"export {role}", "variant"):
            q = quantize_variant(path, Path(td) / f"{prec}.onnx", prec, make_inputs=make_inputs,
                                 calibration=calib_feeds, outputs=outputs)
            name = f"{prefix}{prec}"
            if q["ok"]:
                add_variant_files(out, role, name, {"model": q["path"]}, meta=meta, precision=prec,
                                  target="cpu" if prec != "int8-qdq" else "accelerator",
                                  parity={"model": q["parity"]}, alternative=alternative)
                res["variants"][name] = q["parity"]
            else:
                record_skipped_variant(out, role, name, q["reason"])
                res["skipped"][name] = q["reason"]
                progress(f"{role}/{name} NOT shipped: {q['reason']}")
    return res


def calibration_feeds(path: Path, pp: dict[str, Any], calib: str | os.PathLike, n: int = 16) -> list[Feeds]:
    """int8-qdq calibration inputs: `n` frames of `calib` prepared as the runtime prepares them (a letterbox for
    the YOLO formats, a plain resize otherwise)."""
    from mosaicthinker.runtime.models import preprocess_image
    from mosaicthinker.runtime.models.yolo import letterbox

    name = B.io_spec_from_onnx(path)[0][0]["name"]
    prep = (lambda f: letterbox(f, pp)[0]) if pp.get("resize") == "letterbox" else \
        (lambda f: preprocess_image(f, pp))
    return [{name: prep(f)} for f in calibration_frames(calib, n)]


DETECTOR_ROLES = ("detector", "instance_segmenter")


def read_sidecar(path: Path, meta_file: str | os.PathLike | None, weights: str | None = None,
                 role: str | None = None) -> dict[str, Any]:
    """The role metadata of an imported graph. weights: "real" | "random" from --real-weights /
    --random-weights, required when the sidecar has no boolean `random_weights`. For a detector or instance
    segmenter the graph's format (SSD, YOLOX, Ultralytics end-to-end: `detector_formats.detect_format`) gives
    `arch`, `preprocessing` and `config` defaults; the sidecar may leave them out (what it gives wins; an `arch`
    that contradicts the graph is refused), and an Ultralytics export's own `names` metadata gives the labels."""
    from .detector_formats import detect_format, format_meta

    side = Path(meta_file) if meta_file else path.with_name(path.name + ".mosaic.json")
    if not side.is_file():
        raise ExportError(f"--source onnx:{path}: metadata sidecar {side} not found; write it (see "
                          f"docs/bundle-and-adapters.md) or pass --meta FILE")
    try:
        raw = B.strict_json_loads(side.read_bytes(), str(side))
    except InputError as e:
        raise ExportError(str(e)) from e
    if not isinstance(raw, dict):
        raise ExportError(f"{side}: expected a JSON object")
    if role in DETECTOR_ROLES:
        fmt = detect_format(path)
        raw = {**raw, **format_meta(fmt, raw, str(side))}
        sem = dict(raw.get("semantics") or {})
        if not sem.get("labels") and (names := graph_label_names(path)):
            sem.update(vocabulary="closed", labels=names, label_source="the graph's own metadata (names)")
        if not sem.get("labels") and sem.get("vocabulary") != "open":
            raise ExportError(f"{side}: field 'semantics.labels' is required for a closed-set detector (the class "
                              f"names in class-id order); {path.name} carries no `names` metadata to take them from")
        sem.setdefault("vocabulary", "closed")
        if fmt["arch"] == "ultralytics_e2e" and fmt.get("prototypes"):
            sem.setdefault("kind", "instance")
        raw["semantics"] = sem
        progress(f"{path.name}: {fmt['arch']} format (from its inputs/outputs)")
    for k in ("arch", "licence", "preprocessing", "semantics"):
        if k not in raw:
            raise ExportError(f"{side}: field {k!r} is required")
    rw = raw.get("random_weights")
    if rw is None and weights is None:
        raise ExportError(f"{side}: field 'random_weights' is missing; add \"random_weights\": false (trained "
                          f"weights) or true (a test model), or say --real-weights / --random-weights")
    if rw is not None and not isinstance(rw, bool):
        raise ExportError(f"{side}: field 'random_weights' must be true or false (a JSON boolean), got {rw!r}")
    if rw is not None and weights is not None and rw != (weights == "random"):
        raise ExportError(f"{side}: 'random_weights': {str(rw).lower()} contradicts --{weights}-weights; fix one")
    rw = rw if rw is not None else weights == "random"
    prov = dict(raw.get("provenance", {}))
    prov.setdefault("source", f"onnx:{path.name}")
    prov.setdefault("sha256", B.sha256_file(path))
    return role_meta(raw["arch"], preprocessing=raw["preprocessing"], semantics=raw["semantics"], provenance=prov,
                     licence=raw["licence"], random_weights=rw,
                     config=raw.get("config", {}), **({"notes": raw["notes"]} if raw.get("notes") else {}))


def graph_label_names(path: Path) -> list[str] | None:
    """Class names an exporter wrote into the graph's metadata (Ultralytics: `names`, a dict {id: name} in Python
    or JSON syntax), in class-id order; None when there are none."""
    import ast
    import json

    import onnxruntime as ort

    so = ort.SessionOptions()
    so.log_severity_level = 3
    try:
        meta = ort.InferenceSession(str(path), so, providers=["CPUExecutionProvider"]).get_modelmeta()
    except Exception:  # noqa: BLE001 - detect_format has loaded it already; metadata is optional
        return None
    text = (meta.custom_metadata_map or {}).get("names")
    if not text:
        return None
    try:
        names = json.loads(text)
    except ValueError:
        try:
            names = ast.literal_eval(text)
        except (ValueError, SyntaxError):
            return None
    if isinstance(names, dict):
        try:
            return [str(names[k]) for k in sorted(names, key=lambda k: int(k))]
        except (ValueError, TypeError):
            return None
    return [str(x) for x in names] if isinstance(names, list) else None


def image_feeds(path: Path, pp: dict[str, Any]) -> Callable[[np.random.Generator], Feeds]:
    """Parity inputs for an image graph: random images at the bundle's input size (`pp["size"]`, whatever the
    graph's symbolic dims), in the range the runtime feeds (uint8 0..255; float: 0..255 x `scale`)."""
    ins, _, _ = B.io_spec_from_onnx(path)
    img = next((i for i in ins if len(i["shape"]) == 4), ins[0])
    h, w = (int(v) for v in pp["size"])
    shape = [1, 3, h, w] if str(pp.get("layout", "NHWC")).upper() == "NCHW" else [1, h, w, 3]
    scale = float(pp.get("scale") or 1.0)

    def make(rng: np.random.Generator) -> Feeds:
        x = rng.integers(0, 256, shape).astype(np.uint8)
        return {img["name"]: x if img["dtype"] == "uint8" else (x.astype(np.float32) * scale).astype(img["dtype"])}

    return make


def export_role(role: str, source: str, precisions: list[str], out: Path, *, calib: str | None = None,
                meta_file: str | None = None, weights: str | None = None, options: dict[str, str] | None = None,
                **_: Any) -> dict[str, Any]:
    """`mosaic export ROLE --source onnx:PATH` entry point. `--set size=HxW` re-shapes a fixed square
    Ultralytics TFLite graph for rectangular frames (`ultralytics_rect`; needs --calib frames for its check)."""
    path = Path(source.split(":", 1)[1])
    if not path.is_file():
        raise ExportError(f"--source onnx:{path}: file not found")
    meta = read_sidecar(path, meta_file, weights, role)
    unknown = sorted(set(options or {}) - {"size"})
    if unknown:
        raise ExportError(f"--set {unknown[0]}: not an option of an onnx: import (known: size=HxW for an "
                          f"Ultralytics end-to-end graph)")
    with tempfile.TemporaryDirectory() as td:
        if (options or {}).get("size"):
            path, meta = rect_variant(path, meta, options["size"], calib, Path(td))
        mk = image_feeds(path, meta["preprocessing"]) if role in DETECTOR_ROLES else None
        return import_onnx(out, role, path, meta, precisions, calib=calib, make_inputs=mk)


def rect_variant(path: Path, meta: dict[str, Any], size: str, calib: str | os.PathLike | None, tmp: Path,
                 min_found: float = 0.9) -> tuple[Path, dict[str, Any]]:
    """The graph re-shaped to `size` ("HxW", `ultralytics_rect.rect_graph`) and its metadata, after a task check
    on real frames: at least `min_found` of the square graph's detections >= 0.5 found again. ExportError
    otherwise, or without calibration frames, or for another format."""
    from .ultralytics_rect import agreement, rect_graph

    if meta["arch"] != "ultralytics_e2e":
        raise ExportError(f"--set size: only an Ultralytics end-to-end graph is re-shaped here ({path.name} is "
                          f"{meta['arch']}); a YOLOX graph takes any size from its symbolic input")
    if calib is None:
        raise ExportError("--set size=HxW checks the re-shaped graph against the original on real frames: give "
                          "them with --calib FOLDER_OR_VIDEO")
    try:
        hw = [int(v) for v in size.lower().split("x")]
    except ValueError:
        hw = []
    if len(hw) != 2:
        raise ExportError(f"--set size={size}: expected HxW, e.g. 480x640")
    dst = tmp / path.name
    info = rect_graph(path, dst, hw)
    task = agreement(path, dst, calibration_frames(calib, 16))
    progress(f"{path.name} at {hw[0]}x{hw[1]}: {task['found']:.0%} of the square graph's {task['detections']} "
             f"detections found again (IoU {task['mean_iou']}, score change {task['median_score_change']})")
    if task["found"] < min_found:
        raise ExportError(f"--set size={size}: the re-shaped graph finds only {task['found']:.0%} of the square "
                          f"graph's detections on the --calib frames (need {min_found:.0%}); keep the square size")
    meta = {**meta, "preprocessing": {**meta["preprocessing"], "size": hw},
            "provenance": {**meta["provenance"], "resized": {**info, "task_check": task}},
            "notes": ((meta.get("notes") or "") + f" Input re-shaped from {info['square']}x{info['square']} to "
                      f"{hw[0]}x{hw[1]} (export/ultralytics_rect.py); checked against the square graph: "
                      f"{task['found']:.0%} of its detections found again.").strip()}
    return dst, meta


def import_shared_models(models_dir: str | os.PathLike, out: str | os.PathLike,
                         precisions: list[str] = ("fp32",), roles: list[str] | None = None,
                         calib: str | os.PathLike | None = None, instance_size: str | None = None) -> dict[str, Any]:
    """Import the real models of ../shared/models into ONE bundle at `out` (fp32 = the files as given; other
    precisions converted and parity-checked): YOLOX-Nano as the detector with the SSD as its `ssd-fp32` variant,
    YOLO11n-seg as the instance segmenter (AGPL-3.0), DeepLab, PyDNet++, the MobileNet embedder. `roles` limits
    the roles imported; instance_size "HxW": YOLO11n-seg re-shaped for that input (`rect_variant`, checked on
    the `calib` frames). Returns {key: import result} (keys of `shared_model_specs`)."""
    specs = shared_model_specs(models_dir)
    results = {}
    for key, sp in specs.items():
        role = sp["role"]
        if roles and role not in roles:
            continue
        if not Path(sp["file"]).is_file():
            raise ExportError(f"{sp['file']}: shared model missing")
        mk = _shared_feeds(key, Path(sp["file"]))
        # Only the first (finest) depth output is used at run time, so parity is checked on it; of a detector's
        # outputs, those the adapter reads
        outputs = [0] if role == "depth" else None
        # the SSD and YOLO11n-seg files are already quantised (TFLite int8): only the files as given
        precs = ["fp32"] if sp.get("alternative") or role == "instance_segmenter" else list(precisions)
        with tempfile.TemporaryDirectory() as td:
            path, meta = Path(sp["file"]), sp["meta"]
            if role == "instance_segmenter" and instance_size:
                path, meta = rect_variant(path, meta, instance_size, calib, Path(td))
            results[key] = import_onnx(out, role, path, meta, precs, calib=calib, make_inputs=mk,
                                       outputs=outputs, prefix="ssd-" if key == "detector-ssd" else "",
                                       alternative=bool(sp.get("alternative")))
    return results


def _shared_feeds(key: str, path: Path) -> Callable[[np.random.Generator], Feeds] | None:
    """Parity inputs in each model's natural range: images as the runtime feeds them (YOLOX raw 0-255 at its
    bundle size), PyDNet [0, 1], DeepLab [-1, 1]."""
    if key == "detector":
        return image_feeds(path, YOLOX_PREPROCESSING)
    ranges = {"depth": (0.0, 1.0), "segmenter": (-1.0, 1.0)}
    return _float_range_feeds(path, *ranges[key]) if key in ranges else None


# ---------------------------------------------------------------------------------------------------------------
# Task checks of the imported real models on an RGB-D folder (7-Scenes layout): used by the tests (a handful of
# frames) and by benchmarks/shared_models.py (all frames).

ABSENT_FROM_KITCHEN = ("bed", "toilet", "car", "person", "bicycle", "horse", "sheep", "cow", "airplane", "boat")
AGREEMENT_NAMES = ("chair", "dining table")


def depth_errors(pred_m: np.ndarray, gt_m: np.ndarray, max_depth_m: float = 10.0) -> dict[str, float]:
    """AbsRel and delta<1.25 of a metric map [H, W] against ground truth [H, W] (0 = invalid), on pixels valid in
    both."""
    ok = (gt_m > 0) & (gt_m < max_depth_m) & (pred_m > 0)
    if not ok.any():
        return {"absrel": float("nan"), "delta1": float("nan"), "n": 0}
    p, g = pred_m[ok].astype(np.float64), gt_m[ok].astype(np.float64)
    return {"absrel": float(np.mean(np.abs(p - g) / g)), "delta1": float(np.mean(np.maximum(p / g, g / p) < 1.25)),
            "n": int(ok.sum())}


def _depth_row(depth: Any, f: Any) -> dict[str, Any]:
    """PyDNet++ vs sensor depth on one frame: scale+shift fit, scale-only fit, constant baseline."""
    from mosaicthinker.runtime.models.depth import fit_to_sensor

    pred = depth.predict(f.rgb)
    ss = fit_to_sensor(pred, f.depth, depth.semantics, shift=True)
    so = fit_to_sensor(pred, f.depth, depth.semantics, shift=False)
    gt = f.depth
    valid = (gt > 0) & (gt < 10.0)
    const = np.where(valid, np.median(gt[valid]), 0).astype(np.float32)
    return {"scale_shift": depth_errors(ss.apply(pred), gt), "scale_only": depth_errors(so.apply(pred), gt),
            "constant": depth_errors(const, gt), "s": ss.s, "t": ss.t}


def _agreement_row(n: str, dets: Any, lab: np.ndarray, seg: Any, shape: tuple[int, int], agree: dict,
                   min_seg_fraction: float, box_fill: float) -> tuple[float | None, float]:
    """Detector vs segmenter on class `n` in one frame (counts into `agree[n]`); (best box fill, seg fraction)."""
    from mosaicthinker.runtime.models.detector import map_names

    H, W = shape
    cm = np.isin(lab, map_names([n], seg.labels)[0].get(n, []))
    seg_sees = cm.mean() >= min_seg_fraction
    boxes = dets.boxes[[k for k, x in enumerate(dets.names) if x == n]]
    det_sees = len(boxes) > 0
    fills = []
    for b in boxes:
        x0, y0, x1, y1 = [int(round(v)) for v in b]
        win = cm[max(0, y0):min(H, y1), max(0, x0):min(W, x1)]
        fills.append(float(win.mean()) if win.size else 0.0)
    ok = det_sees and max(fills) >= box_fill
    if det_sees or seg_sees:
        a = agree[n]
        a["either"] += 1
        a["agree"] += int(ok)
        a["det_only"] += int(det_sees and not seg_sees)
        a["seg_only"] += int(seg_sees and not det_sees)
    return (max(fills) if fills else None), float(cm.mean())


def _summary(per_frame: list[dict], agree: dict, absent_counts: dict, nf: int) -> dict[str, Any]:
    dr = [r["depth"] for r in per_frame if "depth" in r]

    def mean(key, metric):
        return float(np.nanmean([d[key][metric] for d in dr])) if dr else float("nan")

    depth_sum = {k: {"absrel": mean(k, "absrel"), "delta1": mean(k, "delta1")}
                 for k in ("scale_shift", "scale_only", "constant")}
    depth_sum["beats_constant"] = bool(depth_sum["scale_shift"]["absrel"] < depth_sum["constant"]["absrel"])
    agreement = {n: {**a, "rate": a["agree"] / a["either"] if a["either"] else float("nan")} for n, a in agree.items()}
    absent = {m: {n: c / nf for n, c in d.items()} for m, d in absent_counts.items()}
    return {"depth": depth_sum, "agreement": agreement, "absent_rate": absent,
            "absent_max_rate": max([v for d in absent.values() for v in d.values()] or [0.0])}


def shared_model_checks(bundle: str | os.PathLike, frames_dir: str | os.PathLike, indices: list[int] | None = None,
                        *, threads: int = 1, min_seg_fraction: float = 0.005, box_fill: float = 0.10,
                        trace: Any = None) -> dict[str, Any]:
    """Real-data checks of the four imported models on the frames `indices` of a 7-Scenes folder.

    depth: PyDNet++ vs sensor depth after a per-frame least-squares scale+shift fit (`fit_to_sensor`), and a
    scale-only fit; baseline: the best constant depth per frame (the sensor's median). AbsRel / delta<1.25 per
    frame and mean.
    detector vs segmenter, per name in AGREEMENT_NAMES: a frame where either model "sees" the class (>= 1 box, or
    >= min_seg_fraction of the image labelled with it) agrees when some detector box is at least `box_fill` filled
    with the segmenter's pixels of that class.
    absent: fraction of frames in which each model reports a class absent from a kitchen (detector: any box;
    segmenter: >= min_seg_fraction of the image).
    """
    from mosaicthinker.runtime.frames import open_source
    from mosaicthinker.runtime.models import load_role
    from mosaicthinker.runtime.models.detector import map_names
    from mosaicthinker.runtime.infra.trace import Trace

    trace = trace if trace is not None else Trace()
    src = open_source(frames_dir)
    idx = list(range(len(src))) if indices is None else list(indices)
    depth, det, seg = (load_role(bundle, r, threads=threads, trace=trace) for r in ("depth", "detector", "segmenter"))
    absent_det = [n for n in ABSENT_FROM_KITCHEN if not map_names([n], det.labels)[1]]
    absent_seg = [n for n in ABSENT_FROM_KITCHEN if not map_names([n], seg.labels)[1]]
    per_frame, agree = [], {n: {"either": 0, "agree": 0, "det_only": 0, "seg_only": 0} for n in AGREEMENT_NAMES}
    absent_counts = {"detector": {n: 0 for n in absent_det}, "segmenter": {n: 0 for n in absent_seg}}
    for i in idx:
        f = src[i]
        row: dict[str, Any] = {"frame": int(i)}
        if f.depth is not None:
            row["depth"] = _depth_row(depth, f)
        dets = det.detect(f.rgb, list(AGREEMENT_NAMES) + absent_det)
        lab = seg.classes(f.rgb)
        row["detections"] = {n: int(sum(1 for x in dets.names if x == n)) for n in set(dets.names)}
        for n in AGREEMENT_NAMES:
            row[f"fill_{n}"], row[f"seg_fraction_{n}"] = _agreement_row(n, dets, lab, seg, f.rgb.shape[:2], agree,
                                                                        min_seg_fraction, box_fill)
        for n in absent_det:
            absent_counts["detector"][n] += int(n in dets.names)
        for n in absent_seg:
            cm = np.isin(lab, map_names([n], seg.labels)[0][n])
            absent_counts["segmenter"][n] += int(cm.mean() >= min_seg_fraction)
        per_frame.append(row)
    return {"frames": len(idx), **_summary(per_frame, agree, absent_counts, max(len(idx), 1)),
            "thresholds": {"min_seg_fraction": min_seg_fraction, "box_fill": box_fill,
                           "detector_score": det.conf.score_threshold},
            "per_frame": per_frame}
