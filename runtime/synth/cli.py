"""`mosaic synth`: generate synthetic indoor scenes with full ground truth (see runtime/synth/generate.py).

    mosaic synth --out DIR --seed S --objects low|med|high --room small|medium|large --duration 60 --fps 15 \
        --size 640x480 [--scenes N] [--workers 2] [--no-video] [--no-questions]

One folder per scene: DIR itself for one scene, DIR/scene_000, DIR/scene_001 ... for several (seeds S, S+1, ...).
"""
from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from ..errors import InputError
from .scene import DURATION_LEVELS, SceneConfig


def _size(s: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in s.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"--size must look like 640x480, got {s!r}") from None
    return w, h


def _duration(s: str) -> float:
    if s in DURATION_LEVELS:
        return DURATION_LEVELS[s]
    try:
        return float(s)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--duration: seconds or one of {list(DURATION_LEVELS)}, got {s!r}") from None


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--seed", type=int, default=0, help="random seed (scene k of --scenes uses seed + k)")
    p.add_argument("--objects", choices=["low", "med", "high"], default="med",
                   help="object number: terciles of VSI-Bench per-room object counts")
    p.add_argument("--room", choices=["small", "medium", "large"], default="medium",
                   help="spatial scale: terciles of VSI-Bench room areas")
    p.add_argument("--duration", type=_duration, default=60.0,
                   help="video length in seconds, or short|medium|long (30|60|120 s)")
    p.add_argument("--fps", type=float, default=15.0)
    p.add_argument("--size", type=_size, default=(640, 480), help="WxH, e.g. 640x480 or 320x240")
    p.add_argument("--hfov", type=float, default=60.0, help="horizontal field of view (deg)")
    p.add_argument("--scenes", type=int, default=1, help="number of scenes")
    p.add_argument("--workers", type=int, default=1, help="rendering processes")
    p.add_argument("--no-extras", action="store_true", help="only VSI-Bench categories (no door/lamp/plant/...)")
    p.add_argument("--no-video", action="store_true", help="skip the mp4")
    p.add_argument("--no-questions", action="store_true", help="skip questions.jsonl")
    p.add_argument("--stats", metavar="FILE", help="statistics JSON or a VSI-Bench meta_info.json "
                                                 "(default: the checked-in statistics)")


def run(args: argparse.Namespace) -> dict[str, Any]:
    from .generate import write_scene

    if not args.out:
        raise InputError("mosaic synth: --out DIR is required (the folder to write the scene(s) into)")
    if args.scenes < 1:
        raise InputError(f"--scenes must be >= 1, got {args.scenes}")
    out = Path(args.out)
    results = []
    for k in range(args.scenes):
        conf = SceneConfig(seed=args.seed + k, objects=args.objects, room=args.room, duration=args.duration,
                           fps=args.fps, width=args.size[0], height=args.size[1], hfov_deg=args.hfov,
                           extras=not args.no_extras, stats_path=args.stats)
        d = out if args.scenes == 1 else out / f"scene_{k:03d}"
        results.append(write_scene(conf, d, workers=args.workers, video=not args.no_video,
                                   questions=not args.no_questions, name=None if args.scenes == 1 else
                                   f"synth_{args.seed + k}_{args.objects}_{args.room}"))
    return {"schema": "mosaicthinker.synth/1", "out": str(out), "scenes": results}


def render(result: dict[str, Any]) -> str:
    lines = []
    for s in result["scenes"]:
        counts = ", ".join(f"{k} {v}" for k, v in s["object_counts"].items())
        lines.append(f"{s['out']}: {s['frames']} frames, room {s['room_size']:.1f} m^2, {s['objects']} objects "
                     f"({counts}), {s['questions']} questions, {s['seconds']:.1f} s")
        removed = (s.get("questions_skipped") or {}).get("removed", {})
        rules: dict[str, int] = {}
        for r in removed.values():  # candidate questions removed by each margin rule, over all types
            for k, v in r.items():
                if k not in ("candidates", "kept", "asked"):
                    rules[k] = rules.get(k, 0) + v
        if removed:
            lines.append(f"  candidate questions {sum(r['candidates'] for r in removed.values())}, removed by "
                         f"margin rules: {', '.join(f'{k} {v}' for k, v in sorted(rules.items())) or 'none'}")
        if s["dropped"]:
            lines.append(f"  not placed (no free space): {', '.join(d['name'] for d in s['dropped'])}")
    return "\n".join(lines)
