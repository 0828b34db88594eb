"""Big saved maps (issue 29): `mosaic ask MAP "question" --out DIR` on a 100 000-object map, count and distance,
target <= 10 s each, and which part of the command costs what.

    python benchmarks/big_map.py [--objects 100000] [--work /tmp/mosaic-big-map] [--limit 600]
                                 [--out benchmarks/results/big_map.json]

1. The map: --objects objects (seed 0, 8 categories, random boxes with random yaw over a 100 x 100 m floor),
   written by the product's own writer (`SemanticMap.save`).
2. Whole commands: `mosaic ask MAP Q --out DIR` for a count and a distance question, each a fresh process
   (interpreter start and imports included), wall and CPU seconds and peak RSS by /usr/bin/time, the trace's
   stage times; a command past --limit seconds is stopped and recorded as such. The same count without --out.
3. Parts, in one process (CPU seconds): reading the map (JSON parse, schema check, instances), the map image
   and prompt text (`prompt.render`), the PNG, map.json (`SemanticMap.json_text`), and each question's answer
   alone (`pipeline.ask` with render_image=False; stopped after --part-limit seconds).
Conditions (load before and after, cores) are recorded: on a shared machine wall times are inflated, so the
JSON keeps CPU seconds beside them.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
NAMES = ("chair", "table", "sofa", "lamp", "tv", "bed", "cup", "door")
QUESTIONS = {"count": "How many chairs are in the room?",
             "distance": "What is the distance between the chair and the table (in meters)?"}


def make_map(path: Path, n: int) -> None:
    from mosaicthinker.runtime.geometry import OrientedBox
    from mosaicthinker.runtime.semantic_map import ObjectInstance, SemanticMap

    rng = np.random.default_rng(0)
    yaw = rng.uniform(0, math.pi, n)
    c = np.stack([rng.uniform(0, 100, n), rng.uniform(0, 100, n), rng.uniform(0.1, 1.5, n)], 1)
    s = rng.uniform(0.2, 1.5, (n, 3))
    inst = []
    for i in range(n):
        ca, sa = math.cos(yaw[i]), math.sin(yaw[i])
        ax = np.array([[ca, sa, 0.0], [-sa, ca, 0.0], [0.0, 0.0, 1.0]])
        inst.append(ObjectInstance(i, NAMES[i % len(NAMES)], OrientedBox(c[i], s[i], ax)))
    SemanticMap(inst, None, [(0.0, np.eye(4))], {"source": "benchmarks/big_map.py", "seed": 0}).save(path)


def run_command(argv: list[str], limit: int) -> dict[str, Any]:
    cmd = ["/usr/bin/time", "-f", "%e %U %S %M", sys.executable, "-m", "mosaicthinker.runtime.cli", *argv]
    t0 = time.time()
    try:
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=limit)
    except subprocess.TimeoutExpired:
        return {"argv": argv, "timed_out": True, "limit_s": limit, "wall_s": round(time.time() - t0, 1)}
    wall, user, sys_, rss = r.stderr.strip().splitlines()[-1].split()
    out = {"argv": argv, "exit": r.returncode, "wall_s": float(wall), "cpu_s": round(float(user) + float(sys_), 2),
           "peak_rss_mb": round(int(rss) / 1024, 1), "answer": (r.stdout.splitlines() or [""])[0]}
    if "--out" in argv:
        tr = json.loads((Path(argv[argv.index("--out") + 1]) / "trace.json").read_text())
        out["stages_s"] = {k: round(v["seconds"], 2) for k, v in tr["stages"].items()}
    return out


class _Limit(Exception):
    pass


def part(fn: Any, limit: int | None = None) -> tuple[Any, float | str]:
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
    from mosaicthinker.runtime import bundle, pipeline, prompt
    from mosaicthinker.runtime.outputs import encode_png
    from mosaicthinker.runtime.semantic_map import MAP_SCHEMA, SemanticMap, validate_map_dict

    raw = map_path.read_bytes()
    d, t_parse = part(lambda: json.loads(raw))
    _, t_check = part(lambda: validate_map_dict(d, str(map_path)))
    smap, t_build = part(lambda: SemanticMap.from_dict(d, str(map_path)))
    t_build = round(t_build - t_check, 2)  # from_dict checks again
    vp, t_render = part(lambda: prompt.render(smap))
    _, t_png = part(lambda: encode_png(vp.image))
    _, t_json = part(lambda: smap.json_text(run_id="x"))
    res = {"read_map": {"json_parse": t_parse, "schema_check": t_check, "instances": t_build},
           "map_png_and_prompt": {"render": t_render, "png": t_png, "labels_drawn": vp.labels_drawn},
           "map_json_write": t_json, "answer_only": {}}
    for name, q in QUESTIONS.items():
        ans, t = part(lambda: pipeline.ask(smap, q, render_image=False).answer.text, part_limit)
        res["answer_only"][name] = {"cpu_s": t, "answer": ans}
    del bundle, MAP_SCHEMA
    return res


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--objects", type=int, default=100_000)
    ap.add_argument("--work", default="/tmp/mosaic-big-map")
    ap.add_argument("--limit", type=int, default=600, help="seconds a whole command may run")
    ap.add_argument("--part-limit", type=int, default=120, help="seconds an answer alone may run (parts)")
    ap.add_argument("--out", default=str(REPO / "benchmarks" / "results" / "big_map.json"))
    a = ap.parse_args()
    work = Path(a.work)
    work.mkdir(parents=True, exist_ok=True)
    m = work / f"map{a.objects}.json"
    load0 = os.getloadavg()
    if not m.is_file():
        make_map(m, a.objects)
    res: dict[str, Any] = {"command": "python " + " ".join(sys.argv), "date": time.strftime("%Y-%m-%d %H:%M"),
                           "objects": a.objects, "map_mb": round(m.stat().st_size / 2**20, 1),
                           "cpus": os.cpu_count(), "load_start": [round(x, 2) for x in load0], "target_s": 10,
                           "commands": {}}
    for name, q in QUESTIONS.items():
        res["commands"][f"{name} --out"] = run_command(["ask", str(m), q, "--out", str(work / f"out_{name}")],
                                                       a.limit)
    res["commands"]["count (no --out)"] = run_command(["ask", str(m), QUESTIONS["count"]], a.limit)
    res["parts_cpu_s"] = parts(m, a.part_limit)
    res["load_end"] = [round(x, 2) for x in os.getloadavg()]
    Path(a.out).write_text(json.dumps(res, indent=1) + "\n")
    print(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
