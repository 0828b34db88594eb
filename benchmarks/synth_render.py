"""Rendering-speed benchmark of the synthetic scene generator (target: a 60 s, 15 fps clip at 640x480 in <= 2 min
on 2 cores, everything written: JPEG, depth and instance PNGs, poses, mp4, scene.json, questions).

    python benchmarks/synth_render.py [--duration 60] [--fps 15] [--size 640x480] [--workers 2] [--seed 0]

Writes benchmarks/results/synth_render.json (wall time, per-frame time, the machine's CPU count and load).
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import shutil
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")


def _cpu() -> float:
    """User + system CPU seconds of this process and its finished children (the render workers)."""
    a, b = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return a.ru_utime + a.ru_stime + b.ru_utime + b.ru_stime


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=60.0)
    ap.add_argument("--fps", type=float, default=15.0)
    ap.add_argument("--size", default="640x480")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--objects", default="med")
    ap.add_argument("--room", default="medium")
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "synth_render.json"))
    a = ap.parse_args()
    from mosaicthinker.host.synth.generate import write_scene
    from mosaicthinker.host.synth.scene import SceneConfig

    w, h = (int(v) for v in a.size.split("x"))
    conf = SceneConfig(seed=a.seed, objects=a.objects, room=a.room, duration=a.duration, fps=a.fps, width=w,
                       height=h)
    tmp = Path(tempfile.mkdtemp(prefix="synth_bench_"))
    load0 = os.getloadavg()
    t0 = time.perf_counter()
    cpu0 = _cpu()
    try:
        summary = write_scene(conf, tmp / "scene", workers=a.workers)
        wall = time.perf_counter() - t0
        cpu = _cpu() - cpu0
        size_mb = sum(p.stat().st_size for p in (tmp / "scene").iterdir()) / 1e6
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    frames = summary["frames"]
    res = {
        "schema": "mosaicthinker.bench.synth_render/1",
        "command": f"python benchmarks/synth_render.py --duration {a.duration:g} --fps {a.fps:g} --size {a.size} "
                   f"--workers {a.workers} --seed {a.seed}",
        "config": {"duration_s": a.duration, "fps": a.fps, "size": a.size, "workers": a.workers, "seed": a.seed,
                   "objects": a.objects, "room": a.room},
        "frames": frames, "objects": summary["objects"], "questions": summary["questions"],
        "wall_s": round(wall, 2), "ms_per_frame": round(1000 * wall / frames, 1),
        "cpu_s": round(cpu, 1),
        # the machine is shared: CPU seconds over the cores used tell the wall time on idle cores
        "wall_on_idle_cores_est_s": round(cpu / max(1, min(a.workers, os.cpu_count() or 1)), 1),
        "renderer_init_s": summary["init_s"], "output_mb": round(size_mb, 1),
        "target_wall_s": 120.0, "meets_target": bool(wall <= 120.0),
        "machine": {"cpus": os.cpu_count(), "loadavg_before": [round(x, 2) for x in load0],
                    "loadavg_after": [round(x, 2) for x in os.getloadavg()], "python": platform.python_version(),
                    "processor": platform.processor() or platform.machine()},
    }
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(json.dumps(res, indent=1) + "\n")
    print(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
