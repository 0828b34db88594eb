"""Route planning answered from the map, scored against an independent answer key.

    python benchmarks/route_planning.py [--synthetic 40] [--per-room 6] [--seed 0]

- synthetic rooms (`host.synth.scene.generate_scene`, seeds 0..N-1) and the annotated real rooms (the 7-Scenes
  kitchen of benchmarks/data, ScanNet scene0000_00's own boxes, and every VSI-Bench room's meta_info boxes): route
  questions in the benchmark's wording written by `host.evaluation.box_truth` (its own geometry, no code shared with
  the executors; turns at least `Margins.turn_deg` from a boundary), answered by `MapReasoner` on a map of the
  same boxes;
- VSI-Bench's own route questions: how many name only waypoints its boxes hold, how many of those are answered and
  right, and for each refused question the waypoint it names that the map lacks.

Writes benchmarks/results/route_planning.json (the command, date, machine load and every figure).
"""
from __future__ import annotations

import argparse
import datetime
import json
import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("MOSAIC_SHARED", REPO.parent / "shared"))


def _score(meta: dict[str, Any], name: str, rng: int, per_room: int) -> list[dict[str, Any]]:
    from mosaicthinker.host.evaluation.box_truth import generate_questions
    from mosaicthinker.runtime.answer import MapReasoner
    from mosaicthinker.runtime.map import SemanticMap

    qs, _ = generate_questions(meta, name, rng=rng, per_type={"route_planning": per_room})
    reasoner = MapReasoner(SemanticMap.from_meta_info(meta, name))
    out = []
    for q in qs:
        a = reasoner.answer(q["question"], q["options"])
        out.append({"scene": name, "id": q["id"], "status": a.status, "correct": a.text == q["ground_truth"],
                    "pred": a.text, "ground_truth": q["ground_truth"]})
    return out


def _summary(rows: list[dict[str, Any]]) -> dict[str, Any]:
    st: dict[str, int] = {}
    for r in rows:
        st[r["status"]] = st.get(r["status"], 0) + 1
    return {"n": len(rows), "accuracy": round(float(np.mean([r["correct"] for r in rows])), 4) if rows else None,
            "status": st, "rooms": len({r["scene"] for r in rows}),
            "wrong": [r for r in rows if not r["correct"]][:10]}


def _with_axes(meta: dict[str, Any]) -> dict[str, Any]:
    """Axis-aligned boxes (ScanNet's) as meta_info boxes with `normalizedAxes`."""
    eye = np.eye(3).reshape(-1).tolist()
    return {**meta, "object_bbox": {c: [{**b, "normalizedAxes": b.get("normalizedAxes", eye)} for b in bs]
                                    for c, bs in meta["object_bbox"].items()}}


def synthetic(n: int, per_room: int, seed: int) -> dict[str, Any]:
    from mosaicthinker.host.synth.scene import SceneConfig, generate_scene

    rows = []
    for s in range(seed, seed + n):
        scene = generate_scene(SceneConfig(seed=s, objects=("low", "med", "high")[s % 3]))
        rows += _score({"object_bbox": scene.object_bbox(), "room_size": scene.room.area}, f"synthetic-{s}", s,
                       per_room)
    return _summary(rows)


def real_rooms(per_room: int, seed: int) -> dict[str, Any]:
    out: dict[str, Any] = {}
    kitchen = json.loads((REPO / "benchmarks" / "data" / "redkitchen_annotation.json").read_text())["meta_info"]
    (kname, kmeta), = kitchen.items()
    out["7scenes-redkitchen"] = _summary(_score(kmeta, kname, seed, per_room))
    scannet = SHARED / "data" / "scannet-scene0000_00" / "gt_boxes.json"
    if scannet.is_file():
        out["scannet-scene0000_00"] = _summary(_score(_with_axes(json.loads(scannet.read_text())), "scene0000_00",
                                                      seed, per_room))
    meta = json.loads((SHARED / "data" / "vsibench" / "meta_info.json").read_text())
    rows = []
    for i, (name, m) in enumerate(sorted(meta.items())):
        rows += _score(m, name, seed + i, per_room)
    out["vsibench_rooms"] = _summary(rows)
    return out


def vsibench_own() -> dict[str, Any]:
    from mosaicthinker.runtime.answer import MapReasoner
    from mosaicthinker.runtime.map import SemanticMap

    meta = json.loads((SHARED / "data" / "vsibench" / "meta_info.json").read_text())
    qs = [json.loads(x) for x in (SHARED / "data" / "vsibench" / "questions.jsonl").read_text().splitlines()
          if x.strip() and json.loads(x)["question_type"] == "route_planning"]
    rows = []
    for q in qs:
        a = MapReasoner(SemanticMap.from_meta_info(meta[q["scene_name"]], q["scene_name"])).answer(
            q["question"], q["options"])
        rows.append({"id": q["id"], "status": a.status, "correct": a.text == q["ground_truth"],
                     "missing": a.missing, "why": a.explanation[:160] if a.status != "ok" else None})
    held = [r for r in rows if r["status"] != "not_found"]  # every waypoint is in the boxes
    return {"n": len(rows), "all_waypoints_in_boxes": len(held),
            "answered_of_those": sum(r["status"] == "ok" for r in held),
            "answered_share": round(sum(r["status"] == "ok" for r in held) / max(len(held), 1), 4),
            "correct_of_answered": sum(r["correct"] for r in held if r["status"] == "ok"),
            "refused_not_found": sum(r["status"] == "not_found" for r in rows),
            "refused_with_reason": [{"id": r["id"], "status": r["status"], "why": r["why"], "missing": r["missing"]}
                                    for r in rows if r["status"] != "ok"]}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--synthetic", type=int, default=40, help="synthetic rooms (seeds)")
    ap.add_argument("--per-room", type=int, default=6, help="route questions per room (at most)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=str(REPO / "benchmarks" / "results" / "route_planning.json"))
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    res = {"schema": "mosaicthinker.bench.route_planning/1", "command": " ".join(["python"] + sys.argv),
           "date": datetime.datetime.now().isoformat(timespec="seconds"), "load_average": os.getloadavg(),
           "synthetic": synthetic(args.synthetic, args.per_room, args.seed),
           "real_rooms": real_rooms(args.per_room, args.seed), "vsibench_own_questions": vsibench_own()}
    res["seconds"] = round(time.perf_counter() - t0, 1)
    Path(args.out).write_text(json.dumps(res, indent=1) + "\n")
    s, r, v = res["synthetic"], res["real_rooms"], res["vsibench_own_questions"]
    print(f"synthetic: {s['accuracy']} over {s['n']} route questions in {s['rooms']} rooms {s['status']}")
    for k, x in r.items():
        print(f"{k}: {x['accuracy']} over {x['n']} ({x['rooms']} rooms) {x['status']}")
    print(f"VSI-Bench's own: {v['all_waypoints_in_boxes']} of {v['n']} name only boxed waypoints; answered "
          f"{v['answered_of_those']} ({v['answered_share']}), {v['correct_of_answered']} right; "
          f"{v['refused_not_found']} refused naming the missing waypoint")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
