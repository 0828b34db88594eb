"""`mosaic synth`: generate synthetic indoor scenes with full ground truth (see host/synth/generate.py).

    mosaic synth --out DIR --seed S --complexity low|med|high --room small|medium|large --duration 60 --fps 15 \
        --size 640x480 [--scenes N] [--workers 2] [--no-video] [--no-questions]

One folder per scene: DIR itself for one scene, DIR/scene_000, DIR/scene_001 ... for several (seeds S, S+1, ...).
"""
from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from mosaicthinker.runtime.infra.errors import InputError
from mosaicthinker.host.synth.scene import SceneConfig


COMMON_FLAGS = ("out",)


def add_arguments(p: argparse.ArgumentParser) -> None:
    from mosaicthinker.runtime.commands.flags import add_clip, add_complexity, add_scenes, add_size

    p.add_argument("--seed", type=int, default=0, help="random seed (scene k of --scenes uses seed + k)")
    add_complexity(p, "med")
    p.add_argument("--room", choices=["small", "medium", "large"], default="medium",
                   help="spatial scale: terciles of VSI-Bench room areas")
    add_clip(p, 60.0, 15.0)
    add_size(p, "640x480")
    p.add_argument("--hfov", type=float, default=60.0, help="horizontal field of view (deg)")
    add_scenes(p, 1)
    p.add_argument("--workers", type=int, default=1, help="rendering processes")
    p.add_argument("--no-extras", action="store_true", help="only VSI-Bench categories (no door/lamp/plant/...)")
    p.add_argument("--no-video", action="store_true", help="skip the mp4")
    p.add_argument("--no-questions", action="store_true", help="skip questions.jsonl")
    p.add_argument("--stats", metavar="FILE", help="statistics JSON or a VSI-Bench meta_info.json "
                                                 "(default: the checked-in statistics)")


def run(args: argparse.Namespace) -> dict[str, Any]:
    """Every scene is generated into a hidden staging folder of --out (checked and locked first) and moved
    into place only when all of them are complete; run.json names the run and says when it finished. A kill
    leaves the previous contents and no half-written scene."""
    from mosaicthinker.runtime.infra.outputs import run_group

    if not args.out:
        raise InputError("mosaic synth: --out DIR is required (the folder to write the scene(s) into)")
    out = Path(args.out)
    finals = [out if args.scenes == 1 else out / f"scene_{k:03d}" for k in range(args.scenes)]
    for d in finals:  # checked before rendering: a scene is never mixed with an older one's frames
        if any(d.glob("frame-*.color.jpg")):
            raise InputError(f"{d}: already holds frames; give an empty or new --out folder")
    with run_group(out) as outs:
        results = [_write_one(args, k, d, outs.stage_dir("" if d == out else d.name)) for k, d in enumerate(finals)]
        outs.commit()
    return {"schema": "mosaicthinker.synth/1", "out": str(out), "run_id": outs.run_id, "scenes": results,
            "warnings": list(outs.notes)}


def _write_one(args: argparse.Namespace, k: int, final: Path, stage: Path) -> dict[str, Any]:
    from mosaicthinker.runtime.infra.errors import OutputError
    from mosaicthinker.host.synth.generate import write_scene

    conf = SceneConfig(seed=args.seed + k, objects=args.complexity, room=args.room, duration=args.duration,
                       fps=args.fps, width=args.size[0], height=args.size[1], hfov_deg=args.hfov,
                       extras=not args.no_extras, stats_path=args.stats)
    name = final.resolve().name if args.scenes == 1 else f"synth_{args.seed + k}_{args.complexity}_{args.room}"
    r = write_scene(conf, stage, workers=args.workers, video=not args.no_video, questions=not args.no_questions,
                    name=name)
    video = stage / "video.mp4"
    if not args.no_video and (not video.is_file() or video.stat().st_size == 0):  # VideoWriter.write says nothing
        raise OutputError(f"{final / 'video.mp4'}: the video was not written (OpenCV wrote no bytes); check the "
                          f"disk, or rerun with --no-video")
    return {**r, "out": str(final)}


def render(result: dict[str, Any]) -> str:
    lines = [f"note: {w}" for w in result.get("warnings", [])]
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
