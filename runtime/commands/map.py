"""`mosaic map VIDEO --out map.json`: build a semantic map once, ask questions of it later without perception.

`--out` may name the map file (`map.json`; `map.png` and `trace.json` are written beside it) or a folder (the
three files inside). The objects to map are `--objects a,b,c` (vocabulary names; synonyms resolve), by default
every category the detector can detect (the oracle: the scene's categories; a closed-set model: its label list
mapped onto the vocabulary; an open-vocabulary model needs --objects).
"""
from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from ..infra.errors import InputError
from ..infra.outputs import RunOutputs, note_outputs, save_run
from ..cli import add_stage_flags
from .flags import add_keyframes
from ..grounding import canonical_name
from ..detectable import detectable_names
from .. import pipeline
from ..budget import load_profile
from ..prompt import render as render_prompt
from ..infra.trace import Trace
import numpy as np


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("source", help="video file or image / RGB-D folder")
    p.add_argument("--objects", default=None, help="comma-separated object names to map (default: all the "
                                                   "detector can detect)")
    add_keyframes(p)
    p.add_argument("--keyframe-method", choices=["iterative", "uniform", "exhaustive"], default="iterative")
    p.add_argument("--prompt", choices=["grid", "points"], default="grid", help="map image mode")
    add_stage_flags(p, matcher=True, detector=True)
    p.set_defaults(detector="model")
    p.add_argument("--depth", choices=["auto", "sensor", "model"], default="auto",
                   help="depth source (auto: sensor depth when the source has it, else the bundle's depth model)")
    p.add_argument("--miss-rate", type=float, default=0.1, help="oracle detector miss rate (synthetic scenes)")


def _out_paths(out: str | None, source: Path) -> tuple[Path, Path, Path]:
    if out is None:
        raise InputError("mosaic map needs --out (map.json or a folder)")
    o = Path(out)
    if o.suffix.lower() == ".json":  # the folder itself is checked (file-shaped, read-only, full) by RunOutputs
        return o, o.with_suffix(".png"), o.parent / (o.stem + ".trace.json")
    return o / "map.json", o / "map.png", o / "trace.json"


def default_objects(args: argparse.Namespace, source: Path) -> list[str]:
    """Every category the chosen detector can detect, as vocabulary names."""
    if args.detector == "oracle":
        from mosaicthinker.host.synth.generate import load_scene

        return sorted({canonical_name(n) or n for n in load_scene(source)["object_counts"]})
    if not args.bundle:
        raise InputError("mosaic map with --detector model needs --bundle (or give --detector oracle on a "
                         "synthetic scene)")

    return detectable_names(args.bundle)


def run(args: argparse.Namespace) -> dict[str, Any]:
    src = Path(args.source)
    map_path, png_path, trace_path = _out_paths(args.out, src)
    outs = RunOutputs(map_path.parent)  # checked and locked before the pipeline runs
    try:
        return _run(args, src, outs, (map_path, png_path, trace_path))
    finally:
        outs.close()


def _run(args: argparse.Namespace, src: Path, outs: RunOutputs, paths: tuple[Path, Path, Path]) -> dict[str, Any]:
    map_path, png_path, trace_path = paths
    trace = Trace()
    note_outputs(outs, trace)
    profile = load_profile(args.profile) if args.profile else None
    if profile is not None:
        profile.apply_to_machine(trace)  # core_affinity applied (or refused loudly), threads fit to the cores
    if args.objects:
        raw = [s.strip() for s in args.objects.split(",") if s.strip()]
        names = [canonical_name(s) for s in raw]
        unknown = [r for r, n in zip(raw, names) if n is None]
        if unknown:
            trace.event("unknown_objects", f"not in the vocabulary (mapped by their own name): {unknown}",
                        names=unknown, warn=True)
        names = list(dict.fromkeys(n or r.lower() for r, n in zip(raw, names)))
    else:
        names = default_objects(args, src)
    conf = {"depth": args.depth, "matcher": args.matcher if args.matcher != "model" else "model",
            "keyframe": {"keyframe_method": args.keyframe_method}}
    if args.detector == "oracle":
        if not (src.is_dir() and (src / "scene.json").is_file()):
            raise InputError(f"{src}: --detector oracle needs a synthetic scene folder (with scene.json)")
        from mosaicthinker.host.evaluation.oracle_perception import oracle_perception

        perception = oracle_perception(src, miss_rate=args.miss_rate,
                                       matcher=args.matcher if args.matcher != "model" else "sift")
        trace.decide("perception", perception.describe)
    else:
        perception = pipeline.perception_from_bundle(args.bundle, conf, trace, profile)
    build = pipeline.build_map(pipeline.open_frames(src, trace), names, [], perception, conf, trace, args.keyframes)
    pts = ids = None
    if args.prompt == "points":
        pts = np.concatenate([c for c in build.clouds if len(c)] or [np.zeros((0, 3))])
        ids = np.concatenate([np.full(len(c), o.id) for o, c in zip(build.map.instances, build.clouds)
                              if len(c)] or [np.zeros(0, int)])
    vp = render_prompt(build.map, {"mode": args.prompt}, pts, ids)
    # the text the VLM gets with map.png: prompt.txt beside it (NAME.prompt.txt beside NAME.png)
    txt_name = "prompt.txt" if png_path.name == "map.png" else png_path.stem + ".prompt.txt"
    files, write_error, code = save_run(outs, [("map_json", map_path.name, build.map),
                                               ("map_png", png_path.name, vp.image),
                                               ("prompt_txt", txt_name, vp.full_text()),
                                               ("trace_json", trace_path.name, trace.to_dict())])
    return {"schema": "mosaicthinker.map/1", "run_id": outs.run_id, "write_error": write_error, "exit_code": code, "objects": names, "instances": len(build.map.instances),
            "counts": build.map.counts(), "keyframes": build.keyframes, "unaligned": build.unaligned,
            "recovered_by_refinement": build.recovered,
            "files": files,
            "warnings": [e["message"] for e in trace.events if e["kind"] in ("fallback", "degraded",
                                                                             "random_weights", "not_in_map",
                                                                             "output", "input", "scale")],
            "seconds": trace.wall_seconds()}


def render(r: dict[str, Any]) -> str:
    lines = [f"map: {r['instances']} object(s) from {len(r['keyframes'])} key frames: "
             + ", ".join(f"{k} x{v}" for k, v in sorted(r["counts"].items()))]
    for w in r.get("warnings", []):
        lines.append(f"  note: {w}")
    for v in r["files"].values():
        lines.append(f"  wrote {v}")
    if r["files"].get("map_json"):
        lines.append(f"  ask it: mosaic ask {r['files']['map_json']} \"How many chair(s) are in this room?\"")
    lines.append(f"  ({r['seconds']:.1f} s)")
    return "\n".join(lines)
