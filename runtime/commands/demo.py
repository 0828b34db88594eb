"""`mosaic demo`: the whole pipeline on a generated scene, no model files needed.

1. generates a small synthetic room and a walk-through video (`host.synth`: RGB-D frames, ground truth,
   questions in VSI-Bench wording);
2. grounds a handful of its questions (one per type), builds ONE semantic map of their objects from the video:
   dedup -> iterative key-frame search -> perception (the oracle detector/segmenter from the rendered instance
   masks, or the bundle's real detector/segmenter where `--bundle` has them) -> MST alignment of the key frames
   -> gravity -> fusion -> occlusion refinement;
3. answers every question from that map (map reasoner; the bundle's VLM for the rest when it has one), prints
   the answer next to the ground truth, and writes map.png, map.json and trace.json.
"""
from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path
from typing import Any

from ..infra.errors import InputError
from ..infra.outputs import RunOutputs, note_outputs, save_run
from .flags import add_answerer, add_clip, add_complexity, add_keyframes, add_size, deprecated_alias
from ..answer import answer_question
from ..frames import open_source
from ..grounding import parse_question
from ..pipeline import build_map, load_vlm, perception_from_bundle
from ..prompt import render as render_prompt
from ..infra.trace import Trace
from ..infra.bundle import load_bundle

DEMO_TYPES = ("object_counting", "object_size_estimation", "object_abs_distance", "object_rel_distance",
              "object_rel_direction_hard", "object_rel_direction_medium", "route_planning", "obj_appearance_order",
              "room_size_estimation")


COMMON_FLAGS = ("bundle", "out")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--seed", type=int, default=4, help="scene seed")
    add_complexity(p, "low")
    p.add_argument("--room", choices=["small", "medium", "large"], default="medium", help="room-size level")
    add_clip(p, 16.0, 6.0)
    add_size(p, "480x360")
    add_keyframes(p, 12, "the demo's 16 s clip")
    p.add_argument("--num-questions", type=int, default=6, metavar="N",
                   help="how many questions to ask, one per type (default 6)")
    deprecated_alias(p, "--questions", "--num-questions", "num_questions", type=int)
    add_answerer(p)


def run(args: argparse.Namespace) -> dict[str, Any]:
    size = tuple(args.size)
    if not args.out:  # nothing left behind: the scene and the files live in a folder removed afterwards
        with tempfile.TemporaryDirectory(prefix="mosaic_demo_") as tmp:
            outs = RunOutputs(Path(tmp))
            try:
                res = _run(args, Path(tmp), outs, size)
            finally:
                outs.close()
            return {**res, "files": {}, "scene": "(a temporary folder, removed: keep it with --out DIR)"}
    out = Path(args.out)
    outs = RunOutputs(out)  # checked and locked before the scene is generated
    try:
        return _run(args, out, outs, size)
    finally:
        outs.close()


def _run(args: argparse.Namespace, out: Path, outs: "RunOutputs", size: tuple[int, int]) -> dict[str, Any]:
    from mosaicthinker.host.evaluation.oracle_perception import oracle_perception
    from mosaicthinker.host.evaluation.vsibench import score_answer
    from mosaicthinker.host.synth.generate import write_scene
    from mosaicthinker.host.synth.scene import SceneConfig

    w, h = size
    scene_dir = out / "scene"
    t0 = time.perf_counter()
    trace = Trace()
    note_outputs(outs, trace)
    with trace.stage("synth"):
        if scene_dir.exists() and (scene_dir / "scene.json").is_file():
            info = {"reused": str(scene_dir)}
        else:
            info = write_scene(SceneConfig(seed=args.seed, objects=args.complexity, room=args.room,
                                           duration=args.duration, fps=args.fps, width=w, height=h),
                               scene_dir, video=False)
    qs = [json.loads(line) for line in (scene_dir / "questions.jsonl").read_text().splitlines() if line.strip()]
    picked: list[dict[str, Any]] = []
    for t in DEMO_TYPES:  # one question per type, in this order, up to --questions
        q = next((q for q in qs if q["question_type"] == t), None)
        if q is not None and len(picked) < args.num_questions:
            picked.append(q)
    if not picked:
        raise InputError(f"{scene_dir}: the generated scene has no questions; try another --seed")
    parsed = [parse_question(q["question"], q.get("options")) for q in picked]
    targets = list(dict.fromkeys(n for p in parsed for n in p.targets))
    cues = [n for n in dict.fromkeys(n for p in parsed for n in p.cues) if n not in targets]
    if not targets and not cues:
        targets = sorted(json.loads((scene_dir / "scene.json").read_text())["object_counts"])

    # perception: the bundle's real detector where it has one, else the oracle (no model files)

    use_models = bool(args.bundle) and load_bundle(args.bundle).has_role("detector")
    if use_models:
        perception = perception_from_bundle(args.bundle, {"depth": "sensor"}, trace)
        how = "bundle models (" + ", ".join(sorted(perception.describe)) + ")"
    else:
        perception = oracle_perception(scene_dir, miss_rate=0.1, seed=args.seed)
        trace.decide("perception", perception.describe)
        how = "oracle (ground-truth instance masks, 10% misses); sensor depth; SIFT"
    vlm = load_vlm(args.bundle, trace) if args.bundle else None
    source = open_source(scene_dir)
    build = build_map(source, targets, cues, perception, {"depth": "sensor"}, trace, args.keyframes)
    vp = render_prompt(build.map)
    rows = []
    for q, pq in zip(picked, parsed):
        with trace.stage("answer"):
            a = answer_question(build.map, q["question"], q.get("options"), args.answerer, vlm, vp, trace, pq)
        score = score_answer(q["question_type"], a.text if a.ok else None, q["ground_truth"])
        rows.append({"type": q["question_type"], "question": q["question"], "options": q.get("options"),
                     "answer": a.text, "value": a.value, "truth": q["ground_truth"], "score": round(score, 3),
                     "explanation": a.explanation})
    files, write_error, code = save_run(outs, [("map_png", "map.png", vp.image),
                                               ("prompt_txt", "prompt.txt", vp.full_text()),
                                               ("map_json", "map.json", build.map.to_dict()),
                                               ("trace_json", "trace.json", trace.to_dict())])
    return {"schema": "mosaicthinker.demo/1", "run_id": outs.run_id, "write_error": write_error,
            "exit_code": code, "scene": str(scene_dir), "scene_info": info, "perception": how,
            "objects": targets + cues, "keyframes": build.keyframes, "instances": len(build.map.instances),
            "counts": build.map.counts(), "recovered_by_refinement": build.recovered, "questions": rows,
            "mean_score": round(sum(r["score"] for r in rows) / len(rows), 3),
            "files": files,
            "stage_seconds": {k: round(v["seconds"], 2) for k, v in trace.to_dict()["stages"].items()},
            "seconds": round(time.perf_counter() - t0, 1)}


def render(r: dict[str, Any]) -> str:
    lines = [f"MosaicThinker demo: synthetic scene {r['scene']}",
             f"  perception: {r['perception']}",
             f"  map: {r['instances']} objects ({', '.join(f'{k} x{v}' for k, v in sorted(r['counts'].items()))}) "
             f"from {len(r['keyframes'])} key frames; {r['recovered_by_refinement']} recovered by occlusion "
             f"refinement", ""]
    for i, q in enumerate(r["questions"], 1):
        opts = f"  [{' | '.join(q['options'])}]" if q.get("options") else ""
        lines.append(f"Q{i} ({q['type']}): {q['question'].splitlines()[0]}{opts}")
        mark = "ok" if q["score"] >= 0.999 else ("close" if q["score"] > 0 else "wrong")
        lines.append(f"   answer {q['answer']}   truth {q['truth']}   score {q['score']:.2f} ({mark})")
    lines.append("")
    lines.append(f"mean score {r['mean_score']:.3f} (VSI-Bench scoring: exact match / mean relative accuracy)")
    for v in r["files"].values():
        lines.append(f"  wrote {v}")
    lines.append(f"  {r['seconds']} s (" + ", ".join(f"{k} {v}" for k, v in r["stage_seconds"].items()
                                                       if v >= 0.05) + ")")
    return "\n".join(lines)
