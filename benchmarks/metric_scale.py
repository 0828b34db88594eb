"""Metric scale without a depth sensor (`runtime/map/scale.py`), measured apart from the pose work.

    python benchmarks/metric_scale.py [--bundle B] [--rooms 7scenes-redkitchen ...] [--keyframes 32]
                                      [--factors 3] [--out benchmarks/results/metric_scale.json]

Per RGB-D room with ground-truth poses (../shared/data: the 7-Scenes kitchen, ScanNet scene0000_00, the HoloLens
lounge), a map is built as the RGB-only pipeline would build it, with the ground-truth trajectory multiplied by an
unknown factor f (log-uniform in [0.2, 5], seeded) standing in for structure-from-motion output:
1. K key frames, uniform over the stream; sparse map points triangulated from SIFT matches between each key frame
   and stream frames 3 and 6 apart (both sides), with the scaled poses (OpenCV, reprojection <= 2 px, parallax
   >= 1.5 deg): what SfM would hold; the sensor depth is never read for the map;
2. the map normalised so that the median depth of those points is 2 m (`scale.rough_unit`'s rule, the old prior),
   because the map stages' thresholds are in metres;
3. per key frame the bundle's relative depth model fitted to the key frame's map points (`fit_depth_to_points`):
   object shapes in map units; detector + instance segmenter as the pipeline's perception, gravity as the pipeline
   (`gravity: auto`: the source's where it has one, else the floor fit), fusion with cross-view verification;
4. `estimate_scale` on the cameras, the triangulated map points (the floor: the relative depth model's dense points
   smear it, measured: no floor layer at all in two rooms, a counter top in the kitchen) and the fused objects.
The recovered factor metres / map unit is compared with the truth (1 / (f x normalisation)). Also reported and
NOT combined: an oracle depth cue (the sensor's depth over the map's at the map points: what a good metric depth
model could give), the old prior's error (median map-point depth = 2 m), the map's gravity error and the camera-height cue with the true gravity (what an IMU would give). Priors were fixed before any room was run (ScaleConf docstring; size_priors.json from VSI-Bench).
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
ROOMS = ["7scenes-redkitchen", "scannet-scene0000_00", "hololens-lounge"]
NAMES = ["chair", "sofa", "tv", "bed", "toilet", "refrigerator", "table"]  # detector categories with a size prior


def triangulate(src: Any, i: int, T: dict[int, np.ndarray], sift: Any, offsets=(-6, -3, 3, 6)) -> tuple[np.ndarray, np.ndarray]:
    """Map points seen in stream frame i: (uv [N, 2], depth in frame i [N]) from SIFT matches with frames i+o,
    triangulated with the poses T (camera-to-world, map units)."""
    import cv2

    f = src.colour(i) if hasattr(src, "colour") else src[i]
    K = f.K
    g = cv2.cvtColor(f.rgb, cv2.COLOR_RGB2GRAY)
    kp, des = sift.detectAndCompute(g, None)
    if des is None:
        return np.zeros((0, 2)), np.zeros(0)
    uv_all, z_all = [], []
    bf = cv2.BFMatcher(cv2.NORM_L2)
    for o in offsets:
        j = i + o
        if not 0 <= j < len(src) or j not in T:
            continue
        fj = src.colour(j) if hasattr(src, "colour") else src[j]
        kj, dj = sift.detectAndCompute(cv2.cvtColor(fj.rgb, cv2.COLOR_RGB2GRAY), None)
        if dj is None or len(dj) < 8:
            continue
        m = [a for a, b in bf.knnMatch(des, dj, k=2) if a.distance < 0.75 * b.distance]
        if len(m) < 8:
            continue
        p1 = np.float64([kp[a.queryIdx].pt for a in m])
        p2 = np.float64([kj[a.trainIdx].pt for a in m])
        Wi, Wj = np.linalg.inv(T[i]), np.linalg.inv(T[j])
        X = cv2.triangulatePoints(K @ Wi[:3], fj.K @ Wj[:3], p1.T, p2.T)
        X = (X[:3] / X[3]).T
        ok = np.ones(len(X), bool)
        for W, KK, p in ((Wi, K, p1), (Wj, fj.K, p2)):
            c = X @ W[:3, :3].T + W[:3, 3]
            ok &= c[:, 2] > 0
            pr = c @ KK.T
            ok &= np.linalg.norm(pr[:, :2] / np.maximum(pr[:, 2:], 1e-9) - p, axis=1) <= 2.0
        ci, cj = T[i][:3, 3], T[j][:3, 3]
        a, b = X - ci, X - cj
        cosang = (a * b).sum(1) / np.maximum(np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1), 1e-12)
        ok &= cosang <= np.cos(np.radians(1.5))
        z = (X @ Wi[:3, :3].T + Wi[:3, 3])[:, 2]
        uv_all.append(p1[ok])
        z_all.append(z[ok])
    if not uv_all:
        return np.zeros((0, 2)), np.zeros(0)
    return np.concatenate(uv_all), np.concatenate(z_all)


def room_rows(room: Path, bundle: Path, k: int, factors: list[float]) -> dict[str, Any]:
    import cv2

    from mosaicthinker.runtime.conf import PipelineConfig
    from mosaicthinker.runtime.frames import open_source
    from mosaicthinker.runtime.geometry import invert, sample_depth
    from mosaicthinker.runtime.infra.trace import StageLog
    from mosaicthinker.runtime.map import FusionConfig, fuse_frames, gravity_from_frames, verify_observations
    from mosaicthinker.runtime.map.lift import world_points
    from mosaicthinker.runtime.map.scale import estimate_scale, fit_depth_to_points
    from mosaicthinker.runtime.models import load_role
    from mosaicthinker.runtime.perceive import perceive_keyframes, perception_from_bundle

    src = open_source(room)
    conf = PipelineConfig.merged({"depth": "model"})
    fconf = FusionConfig.merged(conf.fusion)
    perception = perception_from_bundle(bundle, conf)
    dm = load_role(bundle, "depth")
    chosen = sorted({int(round(x)) for x in np.linspace(0, len(src) - 1, k)})
    need = sorted({j for i in chosen for j in (i - 6, i - 3, i, i + 3, i + 6) if 0 <= j < len(src)})
    gt = {j: src[j].pose_gt for j in need}
    sift = cv2.SIFT_create(2000)
    tri_m = {i: triangulate(src, i, gt, sift) for i in chosen}  # metric: the factor scales them exactly
    pred = {i: dm.predict((src.colour(i) if hasattr(src, "colour") else src[i]).rgb) for i in chosen}
    out = []
    for f in factors:
        t0 = time.perf_counter()
        T = {j: _scaled(P, f) for j, P in gt.items()}
        tri = {i: (uv, z * f) for i, (uv, z) in tri_m.items()}  # = triangulating with the scaled poses
        zs = np.concatenate([z for _, z in tri.values()])
        norm = 2.0 / float(np.median(zs))  # the map normalised: median map-point depth 2 (rough metres)
        fits, ratios, depth = {}, [], {}
        for i in chosen:
            uv, z = tri[i]
            if len(z) < 3:
                continue
            ss = fit_depth_to_points(pred[i], uv, z * norm, dm.semantics)
            fits[i] = ss
            depth[i] = ss.apply(pred[i], 0.05, 20.0)
            s_d = sample_depth(src[i].depth, uv.astype(np.float32))  # oracle: sensor depth at the map points
            ok = s_d > 0
            if ok.sum() >= 3:
                ratios.append(float(np.median(s_d[ok] / (z[ok] * norm))))
        posed = [i for i in chosen if i in depth]
        perception.depth = lambda fr: depth[fr.index]
        p = perceive_keyframes(src, posed, None, NAMES, perception, conf, fconf)
        root = posed[0]
        Tr = {i: invert(_scaled(T[root], norm)) @ _scaled(T[i], norm) for i in posed}
        log = StageLog()
        down = src.gravity_camera(root) if hasattr(src, "gravity_camera") else None
        W = gravity_from_frames(p.frames, Tr, down, conf.camera_height_m, conf.floor_fit_max_depth_m, log)
        poses = {i: W @ P for i, P in Tr.items()}

        def verify(obs):
            return verify_observations(obs, p.frames, poses, p.dets, conf.verify, False)[0]

        _, inst, _ = fuse_frames(p.frames, p.dets, poses, fconf, log, p.lifted, verify)
        pts = np.concatenate(world_points(p.frames, poses, 8, lambda q: q[:, 2] < conf.floor_fit_max_depth_m))
        sparse = _sparse_world(tri, src, poses, norm)  # the floor from geometry: the relative depth smears it
        ms = estimate_scale(np.array([poses[i] for i in posed]), sparse, inst, up=np.array([0.0, 0.0, 1.0]))
        truth = 1.0 / (f * norm)  # metres per map unit
        down = _true_down(room, src, poses[root] @ invert(_scaled(T[root], norm)))  # diagnosis only, never used
        imu = estimate_scale(np.array([poses[i] for i in posed]), sparse, [], up=-down).cues.get("camera_height")
        if os.environ.get("METRIC_SCALE_DUMP"):  # the inputs of estimate_scale, to look at a room's cues
            np.savez(Path(os.environ["METRIC_SCALE_DUMP"]) / f"{room.name}-{f:.3f}.npz", pts=pts, truth=truth, sparse_pts=sparse,
                     cams=np.array([poses[i] for i in posed]), 
                     down=_true_down(room, src, poses[root] @ invert(_scaled(T[root], norm))))
        cues = {c: v["scale"] / truth - 1 for c, v in ms.cues.items()}
        votes = [{"cue": v.cue, "label": v.label, "error": float(np.exp(v.log_s) / truth - 1), "kept": v.kept,
                  "sd_log": round(v.sd, 3), "detail": v.detail} for v in ms.votes]
        orc = float(np.median(ratios)) / truth - 1 if ratios else None
        out.append({"factor": f, "normalisation": norm, "truth_m_per_unit": truth, "scale": ms.scale,
                    "error": ms.scale / truth - 1, "stated_percent": round(ms.percent, 1), "source": ms.source,
                    "message": ms.message(), "cue_errors": cues, "votes": votes,
                    "oracle_sensor_depth_cue_error": orc,
                    "old_prior_error": 1.0 / truth - 1,  # the old guess: median map-point depth = 2 m
                    "gravity_error_deg": float(np.degrees(np.arccos(np.clip(-down[2], -1, 1)))),
                    "camera_height_cue_error_true_gravity": None if imu is None else imu["scale"] / truth - 1, "objects": {n: sum(o.name == n for o in inst) for n in NAMES},
                    "keyframes": len(posed), "map_points_per_keyframe": float(np.median([len(z) for _, z in tri.values()])),
                    "depth_fit_shift_used": sum(abs(s.t) > 0 for s in fits.values()), "seconds": time.perf_counter() - t0})
        print(f"{room.name} f={f:.3f}: scale error {100 * out[-1]['error']:+.1f} % (stated +-{ms.percent:.0f} %) "
              f"- {ms.message()}", file=sys.stderr)
    return {"room": room.name, "frames": len(src), "runs": out}


def _sparse_world(tri: dict, src: Any, poses: dict, norm: float) -> np.ndarray:
    """The triangulated map points [N, 3] in the map's world (from each key frame's uv, depth)."""
    out = []
    for i, (uv, z) in tri.items():
        if i not in poses or not len(z):
            continue
        K = src[i].K
        c = np.c_[(uv[:, 0] - K[0, 2]) / K[0, 0], (uv[:, 1] - K[1, 2]) / K[1, 1], np.ones(len(z))] * (z * norm)[:, None]
        out.append(c @ poses[i][:3, :3].T + poses[i][:3, 3])
    return np.concatenate(out) if out else np.zeros((0, 3))


def _true_down(room: Path, src: Any, M: np.ndarray) -> np.ndarray:
    """Ground-truth gravity (down) in the map's world (M: ground-truth world -> map world), for diagnosis only:
    7-Scenes' gravity file, ScanNet's raw frame is z up, the HoloLens world y up."""
    g = getattr(src, "gravity", None)
    d = np.asarray(g, float) if g is not None else np.array([0.0, -1, 0]) if "hololens" in room.name else \
        np.array([0.0, 0, -1])
    d = M[:3, :3] @ d
    return d / np.linalg.norm(d)


def _scaled(T: np.ndarray, f: float) -> np.ndarray:
    out = np.array(T, float)
    out[:3, 3] *= f
    return out


def e2e_row(room: Path, bundle: str, k: int, timeout: float = 1800) -> dict[str, Any]:
    """The path `ask` uses, RGB only: `mosaic eval pose --path ask --depth model --keyframes K --sampling uniform`
    in its own process (structure from motion, the bundle's detector and relative depth, the map's metric scale;
    the sensor depth never read). Scale error = the map's metres over the truth - 1 (1 / the Sim(3)'s scale - 1),
    over the key frames structure from motion registered; `covered`: the stated +-% holds it."""
    import subprocess

    cmd = [sys.executable, "-m", "mosaicthinker.runtime.cli", "eval", "pose", "--data", str(room), "--keyframes",
           str(k), "--sampling", "uniform", "--bundle", bundle, "--matcher", "model", "--depth", "model", "--path",
           "ask", "--json"]
    load = os.getloadavg()[0]
    t0 = time.perf_counter()
    p = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    row: dict[str, Any] = {"room": room.name, "cmd": "mosaic " + " ".join(cmd[3:]), "rc": p.returncode,
                           "wall_s": round(time.perf_counter() - t0, 1), "load_before": round(load, 2)}
    try:
        r = json.loads(p.stdout)
    except ValueError:
        return {**row, "stderr": p.stderr[-1500:]}
    sc = r.get("scale") or {}
    return {**row, "aligned": r["aligned_frames"], "of": r["total_frames"], "evaluated": r["evaluated_frames"],
            "error": r.get("scale_error"), "stated_percent": sc.get("percent"), "covered": r.get("scale_covered"),
            "message": sc.get("message"), "source": sc.get("source"), "ate_rmse_m": r.get("ate_rmse_m"),
            "ate_sim3_m": r.get("ate_sim3_m"), "sim3_scale": r.get("sim3_scale"), "instances": r.get("instances"),
            "error_steps": r.get("scale_error_steps"),
            "covered_steps": None if r.get("scale_error_steps") is None or sc.get("sd_log") is None else
            bool(abs(np.log1p(r["scale_error_steps"])) <= sc.get("stated_z", 1.0) * sc["sd_log"])}


def e2e(a: argparse.Namespace) -> dict[str, Any]:
    """Every room on the path `ask` uses (`e2e_row`), with the targets' summary."""
    rows = [e2e_row(SHARED / "data" / r, a.bundle, a.keyframes) for r in a.rooms]
    errs = [abs(x["error"]) for x in rows if x.get("error") is not None]
    steps = [abs(x["error_steps"]) for x in rows if x.get("error_steps") is not None]
    return {"schema": "mosaicthinker.bench.metric_scale_e2e/1", "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
            "command": "python benchmarks/metric_scale.py --e2e " + " ".join(f"--keyframes {a.keyframes}".split()),
            "bundle": a.bundle, "keyframes": a.keyframes, "machine": f"{os.cpu_count()} CPUs (shared)", "rooms": rows,
            "summary": {"median_abs_error_over_rooms": float(np.median(errs)) if errs else None,
                        "worst_abs_error": max(errs) if errs else None, "rooms_scored": len(errs),
                        "covered": [x.get("covered") for x in rows],
                        "from_steps": {"median_abs_error_over_rooms": float(np.median(steps)) if steps else None,
                                       "worst_abs_error": max(steps) if steps else None,
                                       "covered": [x.get("covered_steps") for x in rows],
                                       "why": "the Sim(3)'s scale is no measure of the map's scale where the "
                                              "trajectory's shape is wrong (ate_sim3_m large): the median ratio of "
                                              "true to estimated camera steps is"},
                        "targets": {"median_within": 0.15, "none_worse_than": 0.30},
                        "met": bool(errs and len(errs) == len(rows) and np.median(errs) <= 0.15 and max(errs) <= 0.30)}}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bundle", default=os.environ.get("MOSAIC_BUNDLE"), required="MOSAIC_BUNDLE" not in os.environ,
                    help="an exported bundle (default: $MOSAIC_BUNDLE)")
    ap.add_argument("--rooms", nargs="*", default=ROOMS)
    ap.add_argument("--keyframes", type=int, default=32)
    ap.add_argument("--factors", type=int, default=3, help="random unknown factors per room")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=str(REPO / "benchmarks" / "results" / "metric_scale.json"))
    ap.add_argument("--e2e", action="store_true", help="the path `ask` uses instead (`e2e_row`: eval pose, "
                    "structure from motion, RGB only); results default to metric_scale_e2e.json")
    a = ap.parse_args(argv)
    from mosaicthinker.runtime.infra.outputs import write_file_atomic

    if a.e2e:
        res = e2e(a)
        out = a.out if a.out != ap.get_default("out") else str(REPO / "benchmarks" / "results" / "metric_scale_e2e.json")
        write_file_atomic(out, json.dumps(res, indent=1) + "\n")
        print(json.dumps(res["summary"], indent=1))
        return 0

    g = np.random.default_rng(a.seed)
    load0 = os.getloadavg()
    rows = []
    for r in a.rooms:
        fs = [float(np.exp(x)) for x in g.uniform(np.log(0.2), np.log(5.0), a.factors)]
        rows.append(room_rows(SHARED / "data" / r, Path(a.bundle), a.keyframes, fs))
    worst = [max(abs(x["error"]) for x in row["runs"]) for row in rows]
    med = [float(np.median([abs(x["error"]) for x in row["runs"]])) for row in rows]
    res = {"schema": "mosaicthinker.bench.metric_scale/1", "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
           "command": "python benchmarks/metric_scale.py " + " ".join(argv if argv is not None else sys.argv[1:]),
           "bundle": a.bundle, "keyframes": a.keyframes, "load_before": load0, "load_after": os.getloadavg(),
           "machine": f"{os.cpu_count()} CPUs (shared)", "rooms": rows,
           "summary": {"median_abs_error_over_rooms": float(np.median(med)), "worst_abs_error": float(max(worst)),
                       "per_room_median_abs_error": dict(zip(a.rooms, med)),
                       "targets": {"median_within": 0.15, "none_worse_than": 0.30},
                       "met": bool(np.median(med) <= 0.15 and max(worst) <= 0.30)}}
    write_file_atomic(a.out, json.dumps(res, indent=1) + "\n")
    print(json.dumps(res["summary"], indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
