"""Geometric core of multi-frame alignment at K key frames: RANSAC + similarity + spanning tree, with feature
extraction AND descriptor matching taken out (matches are computed once and replayed), on 7-Scenes frames with
sensor depth and SIFT.

    python benchmarks/align_core.py [--keyframes 32] [--repeats 5] [--matcher sift]

Prints and writes benchmarks/results/align_core.json: median wall and CPU seconds per alignment (strategy mst
and sequential; CPU time is the fairer figure on a shared machine), pairs tried, RANSAC seconds, seconds per
pair, ATE (unchanged by the replay). Single-threaded BLAS
(OMP_NUM_THREADS=1), as on a 2-core device sharing its cores with the model stages.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from mosaicthinker.runtime import alignment as al  # noqa: E402
from mosaicthinker.runtime.evaluation.pose import ate_rmse, pick_frames  # noqa: E402
from mosaicthinker.runtime.frames import open_source  # noqa: E402
from mosaicthinker.runtime.matching import FeatureMatcher  # noqa: E402

HERE = Path(__file__).resolve().parent
DEFAULT_DATA = HERE.parent.parent / "shared" / "data" / "7scenes-redkitchen"


class ReplayMatcher:
    """The common matcher interface over pre-computed matches (pairs computed on first use, then replayed)."""

    def __init__(self, fm: FeatureMatcher):
        self.fm, self.cache = fm, {}
        self.extract_seconds = 0.0

    def match_keys(self, k0, rgb0, k1, rgb1, boxes0=None, boxes1=None):
        if (k0, k1) not in self.cache:
            self.cache[(k0, k1)] = self.fm.match_keys(k0, rgb0, k1, rgb1, boxes0, boxes1)
        return self.cache[(k0, k1)]

    def match(self, rgb0, rgb1, boxes0=None, boxes1=None):  # pragma: no cover - match_keys is used
        return self.fm.match(rgb0, rgb1, boxes0, boxes1)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=str(DEFAULT_DATA))
    ap.add_argument("--keyframes", type=int, default=32)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--matcher", default="sift")
    ap.add_argument("--out", default=str(HERE / "results" / "align_core.json"))
    a = ap.parse_args(argv)
    src = open_source(a.data)
    frames = [src[i] for i in pick_frames(len(src), a.keyframes, "uniform")]
    rm = ReplayMatcher(FeatureMatcher(a.matcher, cache_size=512))
    out: dict = {"schema": "mosaicthinker.bench.align_core/1", "data": str(a.data), "keyframes": a.keyframes,
                 "matcher": a.matcher, "command": "python benchmarks/align_core.py " + " ".join(
                     argv if argv is not None else sys.argv[1:]), "strategies": {}}
    for strategy in ("mst", "sequential"):
        al.align_frames(frames, rm, strategy)  # warm-up: fills the match cache
        walls, cpus, ransac, res = [], [], [], None
        for _ in range(a.repeats):
            t0, c0 = time.perf_counter(), time.process_time()
            res = al.align_frames(frames, rm, strategy)
            walls.append(time.perf_counter() - t0)
            cpus.append(time.process_time() - c0)
            ransac.append(res.seconds["ransac"])
        ev = [f for f in frames if f.index in res.poses]
        ate = ate_rmse(np.array([res.poses[f.index] for f in ev]), np.array([f.pose_gt for f in ev]))[0]
        n = len(res.edge_stats)
        out["strategies"][strategy] = {
            "seconds_median": round(float(np.median(walls)), 4),
            "cpu_seconds_median": round(float(np.median(cpus)), 4),
            "ransac_seconds_median": round(float(np.median(ransac)), 4), "pairs_tried": n,
            "pairs_failed": sum(not r.ok for r in res.edge_stats.values()),
            "ms_per_pair": round(1000 * float(np.median(ransac)) / max(n, 1), 3), "ate_rmse_m": round(ate, 4),
            "aligned": len(res.aligned)}
    out["load_average_1min"] = os.getloadavg()[0]
    out["date"] = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(json.dumps(out, indent=1))
    print(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
