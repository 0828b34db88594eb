"""Questions on big maps: every answer in O(n log n) in the number of objects (a KD-tree over the boxes, culled by
their bounds; runtime/answer/spatial.py).

    python benchmarks/big_map.py [--objects 1000,10000,100000] [--work /tmp/mosaic-bigmap]

Per map size: a map of N objects (seed 0; five categories of N/5 instances plus one refrigerator and one door,
random boxes turned about the vertical, one object per 4 square metres; and N objects in load.py's dense 20 x 20 m
layout) is saved once; then
- `mosaic ask MAP "question"` in a fresh process (no --out: what a user runs; interpreter start, map load and
  validation included) for a count and a distance between two categories of N/5 instances each;
- in one process with the map loaded once (and scipy imported before timing): the answer time of count, distance between two large categories,
  nearest object to one, which-is-closest, selector ("the chair nearest the door"), where, a location count
  ("how many chairs are near the tables"), which-instance and largest object.
Writes benchmarks/results/big_map.json with the command, date, machine load and each time; the ratios between
sizes show the growth (x10 objects: ~x10-13 for n log n, x100 for n^2).
"""
from __future__ import annotations

import argparse
import datetime
import json
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
CLI_QUESTIONS = {"count": "How many chairs are in this room?",
                 "distance": "How far is the chair from the table?"}
QUESTIONS = {**CLI_QUESTIONS,
             "nearest_of_all": "What is the nearest object to the refrigerator?",
             "which_is_closest": "Which is closest to the door: the chair, the sofa or the lamp?",
             "selector": "How far is the chair nearest the door from the sofa?",
             "where": "Where is the refrigerator?",
             "located_count": "How many chairs are near the tables?",
             "which_instance": "Which chair is farthest from the door?",
             "largest": "What is the biggest object in the room?"}


def make_map(path: Path, n: int, layout: str) -> Path:
    from mosaicthinker.runtime.geometry import OrientedBox, rotation_about
    from mosaicthinker.runtime.map import ObjectInstance, SemanticMap

    rng = np.random.default_rng(0)
    names = ("chair", "table", "sofa", "lamp", "cabinet")
    side = np.sqrt(n * 4.0) if layout == "spread" else 20.0
    inst = []
    for i in range(n):
        name = ("refrigerator", "door")[i] if i < 2 else names[i % len(names)]
        R = rotation_about([0, 0, 1], rng.uniform(0, 6.3)).T if layout == "spread" else np.eye(3)
        c = np.array([*rng.uniform(0, side, 2), rng.uniform(0.2, 1.0)])
        inst.append(ObjectInstance(i, name, OrientedBox(c, rng.uniform(0.3, 1.2, 3), R), float(i % 100), 1.0, 10,
                                   [i % 50]))
    SemanticMap(inst, None, [(float(t), np.eye(4)) for t in range(50)], {"scene": f"big-{layout}-{n}"}).save(path)
    return path


def cli(map_path: Path, question: str) -> dict[str, Any]:
    t0 = time.perf_counter()
    p = subprocess.run([sys.executable, "-m", "mosaicthinker.runtime.cli", "ask", str(map_path), question, "--json"],
                       capture_output=True, text=True, cwd=REPO, timeout=1200)
    wall = time.perf_counter() - t0
    d = json.loads(p.stdout.strip().splitlines()[-1]) if p.returncode == 0 else {}
    return {"exit": p.returncode, "seconds": round(wall, 2), "answer": d.get("answer"), "status": d.get("status"),
            "stderr": p.stderr[-300:] if p.returncode else ""}


def in_process(map_path: Path) -> dict[str, Any]:
    from mosaicthinker.runtime.answer import MapReasoner
    from mosaicthinker.runtime.map import SemanticMap

    t0 = time.perf_counter()
    smap = SemanticMap.load(map_path)
    t1 = time.perf_counter()
    r = MapReasoner(smap)
    out = {"load_s": round(t1 - t0, 3), "index_s": round(time.perf_counter() - t1, 3), "answers": {}}
    import scipy.spatial  # noqa: F401 - imported once before timing (the answers' times, not the import's)
    for k, q in QUESTIONS.items():
        t0, c0 = time.perf_counter(), time.process_time()
        a = r.answer(q)
        out["answers"][k] = {"seconds": round(time.perf_counter() - t0, 3), "cpu_s": round(time.process_time() - c0, 3),
                             "status": a.status, "answer": a.text[:60]}
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--objects", default="1000,10000,100000")
    ap.add_argument("--layouts", default="spread,dense")
    ap.add_argument("--work", default="/tmp/mosaic-bigmap")
    ap.add_argument("--out", default=str(REPO / "benchmarks" / "results" / "big_map.json"))
    args = ap.parse_args(argv)
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    res: dict[str, Any] = {"schema": "mosaicthinker.bench.big_map/1", "command": " ".join(["python"] + sys.argv),
                           "date": datetime.datetime.now().isoformat(timespec="seconds"),
                           "load_average_start": os.getloadavg(), "cores": os.cpu_count(), "maps": {}}
    for layout in args.layouts.split(","):
        for n in (int(x) for x in args.objects.split(",")):
            path = work / f"{layout}-{n}.json"
            if not path.is_file():
                make_map(path, n, layout)
            row = {"objects": n, "layout": layout, "cli": {k: cli(path, q) for k, q in CLI_QUESTIONS.items()},
                   "in_process": in_process(path)}
            res["maps"][f"{layout}-{n}"] = row
            print(f"{layout} {n}: cli " + ", ".join(f"{k} {v['seconds']} s" for k, v in row["cli"].items()) +
                  "; in process " + ", ".join(f"{k} {v['seconds']}" for k, v in row["in_process"]["answers"].items()),
                  flush=True)
    res["load_average_end"] = os.getloadavg()
    Path(args.out).write_text(json.dumps(res, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
