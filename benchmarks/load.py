"""Load benchmark (issue "Bad input, faults and load"): many questions against one big saved map, and concurrent
full runs into separate output folders.

    python benchmarks/load.py [--work /tmp/mosaic-load] [--objects 10000] [--bundle DIR] [--concurrent 3]
                              [--source ../shared/data/7scenes-redkitchen] [--out benchmarks/results/load.json]

1. questions: a generated map of --objects objects (seed 0, 10 categories, random boxes in a 20 x 20 m area) is
   saved once; 20 questions (count, size, absolute distance, relative distance, room size over several
   categories) are asked twice each through `pipeline.ask` in one process, every one re-loading and
   re-validating map.json (render_image=False: what `mosaic ask MAP Q` without --out does). Per question: wall
   seconds, the answer, and the process RSS after it; the second round must give the same answers and the RSS
   must not keep growing (no leak). One `mosaic ask` process per question type is timed too (interpreter start
   and imports included).
2. concurrent: --concurrent `mosaic ask` processes started together on --source with --bundle (the shared models;
   built with `mosaic export shared-models` into --work when absent), each into its own --out; per run: exit
   code, answer, wall seconds, peak RSS (`/usr/bin/time`'s max resident set). The answers must agree.
Conditions (machine load, cores) are recorded; on a shared machine wall times are inflated.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
NAMES = ("chair", "table", "sofa", "bed", "lamp", "tv", "stool", "cabinet", "sink", "toilet")
QUESTIONS = (
    [f"How many {n}(s) are in this room?" for n in ("chair", "table", "sofa", "lamp")]
    + [f"What is the length of the longest dimension (length, width, or height) of the {n}, measured in "
       f"centimeters?" for n in ("refrigerator", "door", "oven", "toaster")]
    + [f"Measuring from the closest point of each object, what is the distance between the {a} and the {b} "
       f"(in meters)?" for a, b in (("refrigerator", "door"), ("oven", "toaster"), ("door", "oven"),
                                    ("toaster", "refrigerator"))]
    + [f"Measuring from the closest point of each object, which of these objects (chair, table, sofa, lamp) is the "
       f"closest to the {n}?" for n in ("refrigerator", "door", "oven", "toaster")]
    + ["What is the size of this room (in square meters)? If multiple rooms are shown, estimate the size of the "
       "combined space."] * 4)
SINGLES = ("refrigerator", "door", "oven", "toaster")  # one each: unique answers for size/distance questions


def make_map(path: Path, n: int) -> Path:
    from mosaicthinker.runtime.geometry import OrientedBox
    from mosaicthinker.runtime.map import ObjectInstance, SemanticMap

    rng = np.random.default_rng(0)
    inst = []
    for i in range(n):
        name = SINGLES[i] if i < len(SINGLES) else NAMES[i % len(NAMES)]
        inst.append(ObjectInstance(i, name, OrientedBox(rng.uniform([0, 0, 0], [20, 20, 2]),
                                                        rng.uniform(0.2, 1.5, 3), np.eye(3)),
                                   float(i % 100), 1.0, 10, [i % 50]))
    SemanticMap(inst, None, [(float(t), np.eye(4)) for t in range(50)], {"scene": f"load-{n}"}).save(path)
    return path


def questions_in_process(map_path: Path) -> dict[str, Any]:
    import psutil

    from mosaicthinker.runtime import pipeline

    proc = psutil.Process()
    pipeline.ask(map_path, QUESTIONS[0], request=pipeline.AskRequest(render_image=False))  # warm the imports once
    rounds = []
    for _ in range(2):
        rows = []
        for q in QUESTIONS:
            t0, c0 = time.perf_counter(), time.process_time()
            r = pipeline.ask(map_path, q, request=pipeline.AskRequest(render_image=False))
            rows.append({"question": q, "answer": r.answer.text, "status": r.answer.status,
                         "seconds": round(time.perf_counter() - t0, 3),
                         "cpu_s": round(time.process_time() - c0, 3),  # less inflated by other jobs
                         "rss_mb": round(proc.memory_info().rss / 2**20, 1)})
        rounds.append(rows)
    secs = [r["seconds"] for rr in rounds for r in rr]
    cpu = [r["cpu_s"] for rr in rounds for r in rr]
    return {"rounds": rounds, "max_seconds": max(secs), "median_seconds": float(np.median(secs)),
            "max_cpu_s": max(cpu), "median_cpu_s": float(np.median(cpu)),
            "same_answers": [r["answer"] for r in rounds[0]] == [r["answer"] for r in rounds[1]],
            "rss_first_mb": rounds[0][0]["rss_mb"], "rss_last_mb": rounds[1][-1]["rss_mb"],
            "rss_growth_round2_mb": round(rounds[1][-1]["rss_mb"] - rounds[1][0]["rss_mb"], 1)}


def _timed(argv: list[str], out: Path | None = None) -> subprocess.Popen:
    cmd = ["/usr/bin/time", "-f", "MAXRSS_KB=%M", sys.executable, "-m", "mosaicthinker.runtime.cli", *argv,
           "--json"] + (["--out", str(out)] if out else [])
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _collect(p: subprocess.Popen, t0: float, timeout: float) -> dict[str, Any]:
    o, e = p.communicate(timeout=timeout)
    rss = [ln for ln in e.splitlines() if ln.startswith("MAXRSS_KB=")]
    try:
        ans = json.loads(o).get("answer")
    except ValueError:
        ans = None
    return {"rc": p.returncode, "answer": ans, "seconds": round(time.time() - t0, 2),
            "peak_rss_mb": round(int(rss[-1].split("=")[1]) / 1024, 1) if rss else None,
            "stderr_tail": [ln for ln in e.splitlines() if not ln.startswith("MAXRSS_KB=")][-2:]}


def questions_cli(map_path: Path) -> list[dict[str, Any]]:
    rows = []
    for q in QUESTIONS[::4]:  # one per type
        t0 = time.time()
        rows.append({"question": q, **_collect(_timed(["ask", str(map_path), q]), t0, 300)})
    return rows


def concurrent_runs(source: str, bundle: Path, n: int, work: Path) -> dict[str, Any]:
    q = "How many chair(s) are in this room?"
    t0 = time.time()
    ps = [_timed(["ask", source, q, "--bundle", str(bundle), "--detector", "model"], work / f"run{i}")
          for i in range(n)]
    runs = [_collect(p, t0, 1800) for p in ps]
    return {"question": q, "source": source, "runs": runs,
            "same_answers": len({r["answer"] for r in runs}) == 1 and all(r["rc"] == 0 for r in runs)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--work", default="/tmp/mosaic-load")
    ap.add_argument("--objects", type=int, default=10000)
    ap.add_argument("--bundle", default=None, help="bundle with the shared models (default: built in --work)")
    ap.add_argument("--source", default=str(REPO.parent / "shared" / "data" / "7scenes-redkitchen"))
    ap.add_argument("--concurrent", type=int, default=3)
    ap.add_argument("--out", default=str(REPO / "benchmarks" / "results" / "load.json"))
    a = ap.parse_args()
    work = Path(a.work)
    work.mkdir(parents=True, exist_ok=True)
    map_path = make_map(work / f"map{a.objects}.json", a.objects)
    res: dict[str, Any] = {"schema": "mosaicthinker.bench.load/1", "command": " ".join(sys.argv),
                           "objects": a.objects, "map_mb": round(map_path.stat().st_size / 2**20, 1),
                           "cores": os.cpu_count(), "loadavg_start": os.getloadavg()}
    res["questions_in_process"] = questions_in_process(map_path)
    res["questions_cli"] = questions_cli(map_path)
    if a.concurrent > 0:
        bundle = Path(a.bundle) if a.bundle else work / "bundle"
        if not (bundle / "manifest.json").is_file():
            subprocess.run([sys.executable, "-m", "mosaicthinker.runtime.cli", "export", "shared-models",
                            "--source", f"dir:{REPO.parent / 'shared' / 'models'}", "--out", str(bundle)],
                           check=True)
        res["concurrent"] = concurrent_runs(a.source, bundle, a.concurrent, work)
    res["loadavg_end"] = os.getloadavg()
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(json.dumps(res, indent=1) + "\n")
    qi = res["questions_in_process"]
    print(f"{len(QUESTIONS)} questions x 2 on a {a.objects}-object map: max {qi['max_seconds']} s, median "
          f"{qi['median_seconds']} s (cpu max {qi['max_cpu_s']} s, median {qi['median_cpu_s']} s), same answers {qi['same_answers']}, RSS {qi['rss_first_mb']} -> "
          f"{qi['rss_last_mb']} MB")
    for r in res["questions_cli"]:
        print(f"  cli {r['seconds']} s {r['peak_rss_mb']} MB rc {r['rc']}: {r['answer']}")
    for r in res.get("concurrent", {}).get("runs", []):
        print(f"  concurrent run: rc {r['rc']} answer {r['answer']} {r['seconds']} s {r['peak_rss_mb']} MB")


if __name__ == "__main__":
    main()
