"""Big saved maps: every answer in O(n log n) in the number of objects (a KD-tree over the boxes, culled by their
bounds; runtime/answer/spatial.py), and the whole `mosaic ask MAP "question" --out DIR` command on a
100 000-object map (count and distance: target <= 10 s each), with what each part of it costs.

    python benchmarks/big_map.py [--objects 1000,10000,100000] [--layouts spread,dense] [--work /tmp/mosaic-bigmap]
                                 [--limit 600] [--part-limit 120] [--out benchmarks/results/big_map.json]

Per map size and layout, a map of N objects (seed 0; five categories of N/5 instances plus one refrigerator and one
door, random boxes turned about the vertical, one object per 4 square metres ("spread"), or N objects in load.py's
dense 20 x 20 m layout ("dense")), written once by the product's own writer (`SemanticMap.save`); then
1. whole commands, each a fresh process (interpreter start, imports, map load and validation included): `mosaic ask
   MAP Q --out DIR` and `mosaic ask MAP Q` for a count and a distance between two categories of N/5 instances:
   wall and CPU seconds and peak RSS (/usr/bin/time), the answer line, the trace's stage times (with --out); a
   command past --limit seconds is stopped and recorded as such;
2. answers in one process, the map loaded once (scipy imported before timing): count, distance between two large
   categories, nearest object to one, which-is-closest, selector ("the chair nearest the door"), where, a location
   count ("how many chairs are near the tables"), which-instance and largest object;
3. the parts of `mosaic ask MAP Q --out` in one process, CPU seconds each: JSON parse, schema check, building the
   objects, each question's answer alone (`pipeline.ask`, render_image=False; stopped after --part-limit seconds),
   the map image + prompt text (`prompt.render`), the PNG, map.json (what `--out` writes for a saved map: its
   file's text with the run id, and the re-encoding a built or changed map takes).
The machine's load (before each command and at the end) and its cores are recorded: on a shared machine wall times
are inflated, so the JSON keeps CPU seconds beside them. Ratios between sizes show the growth (x10 objects:
~x10-13 for n log n, x100 for n^2).
"""
from __future__ import annotations

import argparse
import datetime
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
TARGET_S = 10.0  # issue 29: count and distance with --out on a 100 000-object map
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


def run_command(argv: list[str], limit: int) -> dict[str, Any]:
    """One `mosaic` command in a fresh process: wall / CPU seconds and peak RSS by /usr/bin/time."""
    cmd = ["/usr/bin/time", "-f", "%e %U %S %M", sys.executable, "-m", "mosaicthinker.runtime.cli", *argv]
    load = round(os.getloadavg()[0], 2)
    t0 = time.time()
    try:
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=limit, cwd=REPO)
    except subprocess.TimeoutExpired:
        return {"argv": argv, "timed_out": True, "limit_s": limit, "wall_s": round(time.time() - t0, 1),
                "load_before": load}
    wall, user, sys_, rss = r.stderr.strip().splitlines()[-1].split()
    answer = next((ln for ln in r.stdout.splitlines() if ln.startswith("answer:")), "")
    out = {"argv": argv, "exit": r.returncode, "wall_s": float(wall), "cpu_s": round(float(user) + float(sys_), 2),
           "peak_rss_mb": round(int(rss) / 1024, 1), "answer": answer, "load_before": load,
           "stderr": "\n".join(r.stderr.strip().splitlines()[:-1])[-300:]}
    if "--out" in argv and r.returncode == 0:
        tr = json.loads((Path(argv[argv.index("--out") + 1]) / "trace.json").read_text())
        out["stages_s"] = {k: round(v["seconds"], 2) for k, v in tr["stages"].items()}
    return out


def commands(map_path: Path, work: Path, limit: int) -> dict[str, Any]:
    out = {}
    for name, q in CLI_QUESTIONS.items():
        out[f"{name} --out"] = run_command(["ask", str(map_path), q, "--out", str(work / f"out_{name}")], limit)
        out[name] = run_command(["ask", str(map_path), q], limit)
    return out


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


class _Limit(Exception):
    pass


def part(fn: Any, limit: int | None = None) -> tuple[Any, float | str]:
    """fn() and the CPU seconds it took (a string when stopped after `limit` seconds)."""
    def boom(*_: Any) -> None:
        raise _Limit()

    old = signal.signal(signal.SIGALRM, boom)
    signal.alarm(limit or 0)
    c0 = time.process_time()
    try:
        return fn(), round(time.process_time() - c0, 2)
    except _Limit:
        return None, f"> {limit} s (stopped)"
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


def parts(map_path: Path, part_limit: int) -> dict[str, Any]:
    """CPU seconds of each part of `mosaic ask MAP Q --out` in this process (the same functions the command runs).
    The three parts of reading run with the cyclic GC off, as `SemanticMap.load` runs them."""
    import gc

    from mosaicthinker.runtime import pipeline, prompt
    from mosaicthinker.runtime.infra.outputs import encode_png
    from mosaicthinker.runtime.map import SemanticMap, validate_map_dict

    raw = map_path.read_bytes()
    gc.disable()
    try:
        d, t_parse = part(lambda: json.loads(raw))
        _, t_check = part(lambda: validate_map_dict(d, str(map_path)))
        smap, t_build = part(lambda: SemanticMap.from_dict(d, str(map_path)))
    finally:
        gc.enable()
    del d
    t_build = round(t_build - t_check, 2)  # from_dict checks again
    loaded, t_load = part(lambda: SemanticMap.load(map_path))
    vp, t_render = part(lambda: prompt.render(smap))
    _, t_png = part(lambda: encode_png(vp.image))
    _, t_copy = part(lambda: loaded.json_bytes(run_id="x"))
    _, t_encode = part(lambda: smap.json_text(run_id="x").encode())
    res = {"read_map": {"json_parse": t_parse, "schema_check": t_check, "build_objects": t_build,
                        "SemanticMap.load": t_load},
           "answer_only": {},
           "map_png_and_prompt": {"render": t_render, "png": t_png, "labels_drawn": vp.labels_drawn},
           "map_json": {"unchanged_loaded_map (what ask MAP --out writes)": t_copy,
                        "re-encoded (a built or changed map)": t_encode}}
    for name, q in CLI_QUESTIONS.items():
        ans, t = part(lambda: pipeline.ask(smap, q, request=pipeline.AskRequest(render_image=False)).answer.text, part_limit)
        res["answer_only"][name] = {"cpu_s": t, "answer": ans}
    return res


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--objects", default="1000,10000,100000")
    ap.add_argument("--layouts", default="spread,dense")
    ap.add_argument("--work", default="/tmp/mosaic-bigmap")
    ap.add_argument("--limit", type=int, default=600, help="seconds a whole command may run")
    ap.add_argument("--part-limit", type=int, default=120, help="seconds an answer alone may run (parts)")
    ap.add_argument("--out", default=str(REPO / "benchmarks" / "results" / "big_map.json"))
    args = ap.parse_args(argv)
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    res: dict[str, Any] = {"schema": "mosaicthinker.bench.big_map/2",
                           "command": " ".join(["python", "benchmarks/big_map.py", *(argv or sys.argv[1:])]),
                           "date": datetime.datetime.now().isoformat(timespec="seconds"),
                           "load_average_start": [round(x, 2) for x in os.getloadavg()], "cores": os.cpu_count(),
                           "target_s": TARGET_S, "maps": {}}
    for layout in args.layouts.split(","):
        for n in (int(x) for x in args.objects.split(",")):
            path = work / f"{layout}-{n}.json"
            if not path.is_file():
                make_map(path, n, layout)
            row: dict[str, Any] = {"objects": n, "layout": layout, "map_mb": round(path.stat().st_size / 2**20, 1),
                                   "commands": commands(path, work, args.limit), "in_process": in_process(path),
                                   "parts_cpu_s": parts(path, args.part_limit)}
            row["within_target"] = {k: v.get("wall_s", 1e9) <= TARGET_S for k, v in row["commands"].items()
                                    if k.endswith("--out")}
            res["maps"][f"{layout}-{n}"] = row
            print(f"{layout} {n}: " + ", ".join(f"{k} {v.get('wall_s')} s wall / {v.get('cpu_s')} s CPU"
                                                for k, v in row["commands"].items()) +
                  "; in process " + ", ".join(f"{k} {v['seconds']}" for k, v in row["in_process"]["answers"].items()),
                  flush=True)
    res["load_average_end"] = [round(x, 2) for x in os.getloadavg()]
    Path(args.out).write_text(json.dumps(res, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
