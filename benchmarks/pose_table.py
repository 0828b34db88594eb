"""Pose-accuracy table: sampling x K x strategy x matcher on a 7-Scenes folder with sensor depth.

    python benchmarks/pose_table.py [--data ../shared/data/7scenes-redkitchen] [--seeds 1-10]

Writes benchmarks/results/pose_table.json (every run) and benchmarks/results/pose_table.md (the table), and
prints the table. Uniform sampling uses K = 16, 32, 64; random subsets use K = 16 (and 32) over the seeds.
Per row: ATE RMSE (m), RPE (m, deg), aligned frames, seconds per alignment (excluding feature extraction,
which is cached per frame and matcher and listed separately).
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from mosaicthinker.host.evaluation.pose import ate_rmse, evaluate_pose, pick_frames  # noqa: E402
from mosaicthinker.runtime.frames import open_source  # noqa: E402
from mosaicthinker.runtime.align.matching import FeatureMatcher  # noqa: E402

HERE = Path(__file__).resolve().parent
DEFAULT_DATA = HERE.parent.parent / "shared" / "data" / "7scenes-redkitchen"


def _seeds(s: str) -> list[int]:
    if "-" in s:
        a, b = s.split("-")
        return list(range(int(a), int(b) + 1))
    return [int(x) for x in s.split(",")]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=str(DEFAULT_DATA))
    ap.add_argument("--seeds", default="1-10", help="random-subset seeds, e.g. 1-10 or 1,2,3")
    ap.add_argument("--uniform-k", default="16,32,64")
    ap.add_argument("--random-k", default="16,32")
    ap.add_argument("--matchers", default="sift,orb")
    ap.add_argument("--out", default=str(HERE / "results"))
    ap.add_argument("--conf", action="append", default=[], metavar="KEY=VALUE",
                    help="alignment config override (runtime.alignment.AlignConf), e.g. verify_top=3")
    a = ap.parse_args(argv)
    conf = {k: json.loads(v) for k, v in (c.split("=", 1) for c in a.conf)}
    src = open_source(a.data, cache_size=260)
    runs: list[dict] = []
    uk = [int(k) for k in a.uniform_k.split(",") if k]
    rk = [int(k) for k in a.random_k.split(",") if k]
    # the targets' configurations first (uniform K=32, random K=16), then the rest; results are written after
    # every configuration, so a partial run still leaves a consistent table
    configs = [("uniform", k, [0]) for k in uk if k == 32] + [("random", k, _seeds(a.seeds)) for k in rk if k == 16]
    configs += [("uniform", k, [0]) for k in uk if k != 32] + [("random", k, _seeds(a.seeds)) for k in rk if k != 16]
    matchers = {name: FeatureMatcher(name, cache_size=260) for name in a.matchers.split(",")}  # feature caches
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    meta = {"schema": "mosaicthinker.bench.pose_table/1", "data": str(a.data), "depth": "sensor", "conf": conf,
            "command": "python benchmarks/pose_table.py " + " ".join(argv if argv is not None else sys.argv[1:]),
            "machine": {"python": platform.python_version(), "cpu_count": os.cpu_count(),
                        "platform": platform.platform()}}
    for sampling, k, seeds in configs:
        for matcher_name, fm in matchers.items():
            for seed in seeds:
                idx = pick_frames(len(src), k, sampling, seed)
                placed: dict[str, dict] = {}
                for strategy in ("mst", "sequential"):
                    ext0 = fm.extract_seconds
                    r = evaluate_pose(src, idx, fm, strategy, conf=conf or None)
                    row = {"matcher": matcher_name, "sampling": sampling, "K": k, "seed": seed, "strategy": strategy,
                           "ate_rmse_m": r["ate_rmse_m"], "rpe_trans_m": r["rpe_trans_m"],
                           "rpe_rot_deg": r["rpe_rot_deg"], "aligned_frames": r["aligned_frames"],
                           "total_frames": r["total_frames"], "unaligned": r["unaligned_frames"],
                           "guessed": r["guessed_frames"], "pairs_tried": r["alignment"]["pairs_tried"],
                           "seconds_excl_extract": r["seconds"] - (fm.extract_seconds - ext0),
                           "seconds_ransac": r["seconds_breakdown"].get("ransac", 0.0),
                           "seconds_breakdown": r["seconds_breakdown"]}
                    placed[strategy] = r
                    runs.append(row)
                    print(f"{matcher_name:4s} {sampling:7s} K={k:2d} seed={seed:2d} {strategy:10s} "
                          f"ATE={row['ate_rmse_m']:.4f} aligned={row['aligned_frames']}/{k} "
                          f"pairs={row['pairs_tried']} t={row['seconds_excl_extract']:.2f}s", flush=True)
                _score_on_common_frames(runs[-2:], placed)
            table = summarise(runs)
            (out / "pose_table.json").write_text(json.dumps(
                {**meta, "finished": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), "summary": table,
                 "runs": runs}, indent=1))
            (out / "pose_table.md").write_text(render(table) + "\n")
    md = render(summarise(runs))
    print(md)
    return 0


def _score_on_common_frames(rows: list[dict], placed: dict[str, dict]) -> None:
    """ATE of both strategies on the frames both place (the tree leaves out frames it cannot verify while the
    sequential chain keeps its guesses: comparing each on its own frames favours the tree)."""
    common = sorted(set(placed["mst"]["poses"]) & set(placed["sequential"]["poses"]))
    for row, st in zip(rows, ("mst", "sequential")):
        r = placed[st]
        row["common_frames"] = len(common)
        row["ate_common_m"] = (ate_rmse(np.array([r["poses"][i] for i in common]),
                                        np.array([r["gt_poses"][i] for i in common]))[0]
                               if len(common) >= 3 else float("nan"))


def summarise(runs: list[dict]) -> list[dict]:
    """One row per (matcher, sampling, K, strategy): medians over seeds (a single run for uniform)."""
    keys = sorted({(r["matcher"], r["sampling"], r["K"], r["strategy"]) for r in runs},
                  key=lambda x: (x[1] != "uniform", x[2], x[0], x[3]))
    rows = []
    for m, s, k, st in keys:
        rs = [r for r in runs if (r["matcher"], r["sampling"], r["K"], r["strategy"]) == (m, s, k, st)]
        rows.append({"matcher": m, "sampling": s, "K": k, "strategy": st, "runs": len(rs),
                     "ate_median_m": float(np.median([r["ate_rmse_m"] for r in rs])),
                     "ate_mean_m": float(np.mean([r["ate_rmse_m"] for r in rs])),
                     "rpe_trans_median_m": float(np.median([r["rpe_trans_m"] for r in rs])),
                     "rpe_rot_median_deg": float(np.median([r["rpe_rot_deg"] for r in rs])),
                     "aligned_fraction_median": float(np.median([r["aligned_frames"] / r["total_frames"]
                                                                 for r in rs])),
                     "aligned_fraction_min": float(np.min([r["aligned_frames"] / r["total_frames"] for r in rs])),
                     "ate_common_median_m": float(np.median([r["ate_common_m"] for r in rs])),
                     "common_frames_median": float(np.median([r["common_frames"] for r in rs])),
                     "seconds_median_excl_extract": float(np.median([r["seconds_excl_extract"] for r in rs]))})
    return rows


def render(rows: list[dict]) -> str:
    lines = ["| sampling | K | matcher | strategy | runs | ATE median (m) | ATE on common frames, median (m) "
             "| RPE median (m / deg) | aligned (median / worst run) | s / alignment (excl. features) |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['sampling']} | {r['K']} | {r['matcher']} | {r['strategy']} | {r['runs']} | "
                     f"{r['ate_median_m']:.4f} | {r['ate_common_median_m']:.4f} ({r['common_frames_median']:.0f} "
                     f"frames) | {r['rpe_trans_median_m']:.4f} / {r['rpe_rot_median_deg']:.2f} | "
                     f"{100 * r['aligned_fraction_median']:.0f}% / {100 * r['aligned_fraction_min']:.0f}% | "
                     f"{r['seconds_median_excl_extract']:.2f} |")
    return "\n".join(lines)


if __name__ == "__main__":
    raise SystemExit(main())
