"""Time to the first line a person sees, for every `mosaic` command, on a pseudo-terminal (40 x 120)
as in an interactive shell; plus, for the long commands, whether progress bars were drawn.

    python benchmarks/first_line.py [--repeats 3] [--scene DIR]

Each command is started as `python -m mosaicthinker.runtime.cli ...`; the figure is the wall time from the
process start to the first byte on its terminal (stdout and stderr both on it). Commands that need inputs get
small ones: a generated scene (`--scene`, else one is generated into a temporary folder) for demo/ask/map, the
shared 7-Scenes kitchen for eval pose, the VSI-Bench files for eval vsibench. Long commands are stopped after
their first line and bar (`--full` lets them finish). Writes benchmarks/results/first_line.json.
"""
from __future__ import annotations

import argparse
import fcntl
import json
import os
import platform
import pty
import select
import struct
import subprocess
import sys
import tempfile
import termios
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
SHARED = Path(os.environ.get("MOSAIC_SHARED", HERE.parents[1] / "shared"))


def first_output(args: list[str], stop_after_s: float, full: bool) -> dict:
    """Start `mosaic ARGS` on a pty (stdout and stderr, as in a shell): seconds to the first byte, and whether
    a progress bar was drawn."""
    master, slave = pty.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 40, 120, 0, 0))
    t0 = time.perf_counter()
    p = subprocess.Popen([sys.executable, "-m", "mosaicthinker.runtime.cli", *args], stdout=slave, stderr=slave)
    os.close(slave)
    first, buf = None, b""
    while True:
        r, _, _ = select.select([master], [], [], 0.05)
        if r:
            try:
                data = os.read(master, 65536)
            except OSError:
                break
            if not data:
                break
            first = first if first is not None else time.perf_counter() - t0
            buf += data
        if p.poll() is not None and not r:
            break
        if not full and first is not None and time.perf_counter() - t0 > max(stop_after_s, first + 2.0):
            p.terminate()
            break
    p.wait()
    os.close(master)
    text = buf.decode(errors="replace")
    return {"first_line_s": None if first is None else round(first, 3),
            "first_line": text.splitlines()[0][:100] if text else None,
            "bar_drawn": "%|" in text, "exit": p.returncode}


def commands(scene: Path) -> dict[str, list[str]]:
    kitchen, vsb = SHARED / "data" / "7scenes-redkitchen", SHARED / "data" / "vsibench"
    out = Path(tempfile.mkdtemp(prefix="mosaic_first_line_"))
    return {
        "--help": ["--help"],
        "--version": ["--version"],
        "demo": ["demo", "--out", str(out / "demo")],
        "ask": ["ask", str(scene), "How many door(s) are in this room?", "--detector", "oracle", "--keyframes", "6"],
        "map": ["map", str(scene), "--detector", "oracle", "--keyframes", "6", "--objects", "door",
                "--out", str(out / "map")],
        "synth": ["synth", "--out", str(out / "synth"), "--duration", "4", "--size", "160x120", "--no-video"],
        "eval pose": ["eval", "pose", "--data", str(kitchen), "--keyframes", "8"],
        "eval vsibench": ["eval", "vsibench", "--questions", str(vsb / "questions.jsonl"),
                          "--meta", str(vsb / "meta_info.json"), "--limit", "200"],
        "eval keyframes": ["eval", "keyframes", "--scenes", "1", "--duration", "10", "--size", "160x120"],
        "eval e2e": ["eval", "e2e", "--scenes", "1", "--duration", "8", "--size", "160x120"],
        "plan": ["plan", "--profile", "pixel-8gb", "--duration", "60", "--fps", "30"],
        "bundle show": ["bundle", "show", str(out / "none")],
        "export": ["export", "embedder", "--source", "onnx:" + str(SHARED / "models" / "mobilenet-v1-embedding" /
                                                               "mobilenet_v1_embedding.onnx"),
                   "--meta", str(HERE.parent / "tests" / "data" / "none.json"), "--out", str(out / "export")],
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--scene", help="a generated scene folder (mosaic synth) for demo/ask/map")
    ap.add_argument("--stop-after", type=float, default=4.0, help="stop long commands after this many seconds")
    ap.add_argument("--full", action="store_true", help="let every command finish")
    ap.add_argument("--out", default=str(HERE / "results" / "first_line.json"))
    a = ap.parse_args()
    scene = Path(a.scene) if a.scene else None
    if scene is None:
        scene = Path(tempfile.mkdtemp(prefix="mosaic_first_line_scene_"))
        subprocess.run([sys.executable, "-m", "mosaicthinker.runtime.cli", "synth", "--out", str(scene),
                        "--seed", "4", "--complexity", "low", "--duration", "10", "--fps", "6", "--size", "400x300",
                        "--no-video"], check=True, capture_output=True)
    res = {}
    for name, args in commands(scene).items():
        runs = [first_output(args, a.stop_after, a.full) for _ in range(a.repeats)]
        times = sorted(r["first_line_s"] for r in runs if r["first_line_s"] is not None)
        res[name] = {"first_line_s_median": times[len(times) // 2] if times else None,
                     "first_line_s_max": times[-1] if times else None, "first_line": runs[0]["first_line"],
                     "bar_drawn": any(r["bar_drawn"] for r in runs), "argv": args}
        print(f"{name:<16} first line {res[name]['first_line_s_median']} s (max {res[name]['first_line_s_max']})"
              f"  bar {res[name]['bar_drawn']}  | {res[name]['first_line']}")
    out = {"schema": "mosaicthinker.bench.first_line/1", "command": "python benchmarks/first_line.py "
           + " ".join(sys.argv[1:]), "repeats": a.repeats, "stop_after_s": a.stop_after, "full": a.full,
           "machine": {"cpus": os.cpu_count(), "python": platform.python_version(),
                       "load_avg_1m": round(os.getloadavg()[0], 2)},
           "target_s": 1.0, "results": res}
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(json.dumps(out, indent=1) + "\n")
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
