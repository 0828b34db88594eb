"""Before/after behaviour check for refactors (issue 11, "the redesign, behaviour kept").

    python benchmarks/behaviour_diff.py --out benchmarks/results/behaviour/after.json [--work /tmp/mosaic-behaviour]
        [--only vsibench,e2e,pose,pipeline60] [--e2e-scenes 6]
    python benchmarks/behaviour_diff.py --compare benchmarks/results/behaviour/baseline.json \
        benchmarks/results/behaviour/after.json

Runs a fixed set of outputs with the code of the repository this script lies in (run it with that checkout's
venv) and writes one canonical JSON with the volatile fields stripped (times, dates, load, RSS, paths, run
ids), so two checkouts can be compared field by field:

- `mosaic eval vsibench` on all of ../shared/data/vsibench (the map reasoner; per-question records included);
- `mosaic eval e2e --scenes N --seed 30 --size 480x360 --fps 8 --duration 24 --modes gt,oracle` (the README's
  row; scenes are generated once in --work/e2e and reused, the generator is seeded);
- `benchmarks/pose_table.py --seeds 1-2 --uniform-k 16 --random-k 16` on 7-Scenes (alignment only);
- the 60 s pipeline benchmark (`benchmarks/pipeline.py`'s scene, frame folder, K = 16, real models of
  --bundle, cpu-generic profile): the built map, the key frames, the counts and the trace's decisions/events;
- `kitchen`: the same record for a map of 7-Scenes redkitchen (sensor depth, SIFT, K = 16, the bundle's SSD):
  the metric-depth path (depth check, whole-image attach, bridge chains), which the synthetic clips rarely need.

`--compare A B` prints every differing path and exits 1 when there is any difference (0 when identical).
Floats are rounded to `--digits` decimals (default 6) before writing: far below any figure the project reports.
"""
from __future__ import annotations

import argparse
import importlib.util
import json
import math
import os
import re
import subprocess
import sys
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("MOSAIC_SHARED", REPO.parent / "shared"))
SCHEMA = "mosaicthinker.bench.behaviour/1"
PARTS = ("vsibench", "e2e", "pose", "pipeline60", "kitchen")
# keys whose values change from run to run or machine to machine, not with behaviour
VOLATILE = re.compile(r"^(seconds.*|.*_seconds|.*_s|t|time|times|date|finished|started|machine|load_average.*|"
                      r".*rss.*|command|run_id|data|out|work|bundle_hash|video|path)$")


def canon(x: Any, digits: int, repl: list[tuple[str, str]]) -> Any:
    """Volatile keys dropped, floats rounded, absolute paths of this run replaced by placeholders."""
    if isinstance(x, dict):
        return {str(k): canon(v, digits, repl) for k, v in sorted(x.items(), key=lambda kv: str(kv[0]))
                if not VOLATILE.match(str(k))}
    if isinstance(x, (list, tuple)):
        return [canon(v, digits, repl) for v in x]
    if isinstance(x, float):
        if math.isnan(x) or math.isinf(x):
            return str(x)
        r = round(x, digits)
        return 0.0 if r == 0 else r
    if isinstance(x, str):
        for a, b in repl:
            x = x.replace(a, b)
        return x
    return x


def _mosaic(args: list[str]) -> dict[str, Any]:
    cmd = [sys.executable, "-m", "mosaicthinker.runtime.cli", *args, "--json"]
    print("[behaviour]", " ".join(cmd[2:]), file=sys.stderr, flush=True)
    p = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True)
    if p.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed ({p.returncode}):\n{p.stderr[-3000:]}")
    return json.loads(p.stdout.strip().splitlines()[-1])


def run_vsibench() -> dict[str, Any]:
    d = SHARED / "data" / "vsibench"
    return _mosaic(["eval", "vsibench", "--questions", str(d / "questions.jsonl"), "--meta",
                    str(d / "meta_info.json"), "--records"])


def run_e2e(work: Path, scenes: int) -> dict[str, Any]:
    return _mosaic(["eval", "e2e", "--scenes", str(scenes), "--seed", "30", "--size", "480x360", "--fps", "8",
                    "--duration", "24", "--modes", "gt,oracle", "--data", str(work / "e2e")])


def run_pose(work: Path) -> dict[str, Any]:
    out = work / f"pose-{os.getpid()}"
    cmd = [sys.executable, str(REPO / "benchmarks" / "pose_table.py"), "--seeds", "1-2", "--uniform-k", "16",
           "--random-k", "16", "--out", str(out)]
    print("[behaviour]", " ".join(cmd[1:]), file=sys.stderr, flush=True)
    p = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True)
    if p.returncode != 0:
        raise SystemExit(f"pose_table failed ({p.returncode}):\n{p.stderr[-3000:]}")
    return json.loads((out / "pose_table.json").read_text())


def _bench_module() -> Any:
    spec = importlib.util.spec_from_file_location("bench_pipeline", REPO / "benchmarks" / "pipeline.py")
    mod = importlib.util.module_from_spec(spec)  # type: ignore[arg-type]
    spec.loader.exec_module(mod)  # type: ignore[union-attr]
    return mod


def run_pipeline60(work: Path, bundle: Path) -> dict[str, Any]:
    """benchmarks/pipeline.py's 60 s K = 16 run (frame folder, real models), keeping the map and the trace."""
    bench = _bench_module()
    scene = bench.ensure_scene(work)
    folder = bench.ensure_frame_folder(work, scene, 1)
    meta = json.loads((scene / "scene.json").read_text())
    names = sorted(set(meta.get("object_counts", {})) & set(bench.DETECTABLE)) or ["chair"]
    print(f"[behaviour] pipeline 60 s, K = 16, objects {names}", file=sys.stderr, flush=True)
    from mosaicthinker.runtime.frames import open_source

    return _build_record(open_source(folder), names, {"depth": "model", "matcher": "model"}, bundle, "cpu-generic")


def _build_record(source: Any, names: list[str], conf: dict[str, Any], bundle: Path, profile: str | None
                  ) -> dict[str, Any]:
    from mosaicthinker.runtime.budget import load_profile
    from mosaicthinker.runtime.pipeline import build_map, perception_from_bundle
    from mosaicthinker.runtime.infra.trace import Trace

    trace = Trace()
    perception = perception_from_bundle(str(bundle), conf, trace, load_profile(profile) if profile else None)
    mb = build_map(source, names, [], perception, conf, trace, keyframes=16)
    td = trace.to_dict()
    return {"targets": names, "frames": len(source), "keyframes": mb.keyframes, "aligned": sorted(mb.poses_world),
            "unaligned": mb.unaligned, "recovered": mb.recovered, "instances": len(mb.map.instances),
            "map": mb.map.to_dict(), "poses_world": {str(k): v.tolist() for k, v in sorted(mb.poses_world.items())},
            "world_from_root": mb.world_from_root.tolist(), "alignment": mb.info.get("alignment"),
            "decisions": td["decisions"], "events": td["events"],
            "stage_calls": {k: v["calls"] for k, v in td["stages"].items()}}


def run_kitchen(bundle: Path) -> dict[str, Any]:
    """A map of the real 7-Scenes kitchen with sensor depth: the metric alignment path."""
    from mosaicthinker.runtime.frames import open_source

    names = ["chair", "table", "refrigerator", "sink", "oven", "microwave", "cup", "bottle"]
    print(f"[behaviour] 7-Scenes kitchen, sensor depth, SIFT, K = 16, objects {names}", file=sys.stderr, flush=True)
    src = open_source(SHARED / "data" / "7scenes-redkitchen")
    return _build_record(src, names, {"depth": "sensor", "matcher": "sift"}, bundle, "cpu-generic")


def collect(args: argparse.Namespace) -> dict[str, Any]:
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    parts = [p for p in args.only.split(",") if p]
    out: dict[str, Any] = {"schema": SCHEMA, "settings": {"e2e_scenes": args.e2e_scenes, "parts": parts,
                                                          "digits": args.digits}}
    if "vsibench" in parts:
        out["vsibench"] = run_vsibench()
    if "e2e" in parts:
        out["e2e"] = run_e2e(work, args.e2e_scenes)
    if "pose" in parts:
        out["pose"] = run_pose(work)
    if "pipeline60" in parts:
        out["pipeline60"] = run_pipeline60(work, Path(args.bundle))
    if "kitchen" in parts:
        out["kitchen"] = run_kitchen(Path(args.bundle))
    repl = [(str(REPO), "<REPO>"), (str(work.resolve()), "<WORK>"), (str(work), "<WORK>"),
            (str(SHARED.resolve()), "<SHARED>"), (str(SHARED), "<SHARED>")]
    return canon(out, args.digits, repl)


def differences(a: Any, b: Any, path: str = "") -> list[str]:
    """Every path where a and b differ (missing keys, types, values, list lengths)."""
    if isinstance(a, dict) and isinstance(b, dict):
        out = []
        for k in sorted(set(a) | set(b)):
            p = f"{path}.{k}" if path else k
            if k not in a:
                out.append(f"{p}: only in B")
            elif k not in b:
                out.append(f"{p}: only in A")
            else:
                out += differences(a[k], b[k], p)
        return out
    if isinstance(a, list) and isinstance(b, list):
        out = [] if len(a) == len(b) else [f"{path}: length {len(a)} vs {len(b)}"]
        for i, (x, y) in enumerate(zip(a, b)):
            out += differences(x, y, f"{path}[{i}]")
        return out
    if a != b:
        sa, sb = json.dumps(a)[:200], json.dumps(b)[:200]
        return [f"{path}: {sa} != {sb}"]
    return []


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--compare", nargs=2, metavar=("A", "B"), help="compare two outputs; exit 1 if they differ")
    ap.add_argument("--out", default=str(REPO / "benchmarks" / "results" / "behaviour" / "after.json"))
    ap.add_argument("--work", default="/tmp/mosaic-behaviour", help="scenes and caches (shared by both runs)")
    ap.add_argument("--bundle", default=os.environ.get("MOSAIC_BUNDLE"), required="MOSAIC_BUNDLE" not in os.environ,
                    help="bundle of the real shared models + XFeat (default: $MOSAIC_BUNDLE)")
    ap.add_argument("--only", default=",".join(PARTS), help=f"comma list of {', '.join(PARTS)}")
    ap.add_argument("--e2e-scenes", type=int, default=6)
    ap.add_argument("--digits", type=int, default=6)
    args = ap.parse_args(argv)
    if args.compare:
        # canonical again: a key added to VOLATILE later drops from older outputs too
        a, b = (canon(json.loads(Path(p).read_text()), args.digits, []) for p in args.compare)
        diff = differences(a, b)
        for line in diff:
            print(line)
        print(f"{len(diff)} difference(s) between {args.compare[0]} and {args.compare[1]}")
        return 1 if diff else 0
    res = collect(args)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(res, indent=1, sort_keys=True) + "\n")
    print(f"wrote {args.out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
