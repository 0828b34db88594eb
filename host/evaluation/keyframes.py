"""Key-frame selection measured on synthetic scenes: `mosaic eval keyframes`.

For N generated scenes (complexity varied one factor at a time, see `--vary`), every question with objects is
grounded (`grounding.parse_question`: targets and cues), the candidates are the frames kept by redundant-frame
removal (`dedup.remove_redundant`, when that module is available; otherwise every frame, noted), and each
method picks K key frames with the same detector:
    iterative   the paper's search (`keyframes.iterative_search`, default configuration)
    uniform     K evenly spaced candidates (nothing scored)
    exhaustive  every candidate scored, top K with a positive score
Metrics per question (ground truth: `scene.json` per-frame `visibility`, the question record's `instances`):
    recall     share of the question's object instances that are seen (visibility >= --min-visible, default
               0.2) in at least one selected frame; instances never that visible in the whole video are left
               out (no method could find them);
    precision  share of the selected frames that show (same visibility rule) at least one of those instances;
               an empty selection has precision 0;
    F1         2PR / (P + R) per question, then averaged (`f1`); means of P and R are reported beside it;
    scored     detector calls / candidates (`scored_candidates`) and / all frames (`scored_frames`).
Questions that name no object (room size) and questions whose objects are never >= min-visible are skipped and
counted. Results are reported per method, per complexity level and per question type.

Long videos (issue 17): `evaluate_long_video` scores a `synth.longvideo.LongVideo` (every frame a candidate,
ground truth from the renderer) with the same metrics plus `found` (recall over every frame the search scored);
benchmarks/keyframes_long.py drives it.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

from mosaicthinker.runtime.infra import jsonio
from mosaicthinker.runtime.infra.errors import InputError
from mosaicthinker.runtime.keyframes import METHODS, KeyFrameConf, select_keyframes
from mosaicthinker.runtime.types import Detections

SCHEMA = "mosaicthinker.eval.keyframes/1"
LEVELS = {"objects": ("low", "med", "high"), "room": ("small", "medium", "large"),
          "duration": ("short", "medium", "long")}
TARGETS = {"f1_min": 0.70, "scored_candidates_max": 0.30, "recall_gap_to_exhaustive_max": 0.05,
           "f1_margin_over_uniform_min": 0.10}


# ------------------------------------------------------------------------------------------------ metrics


def visibility_table(scene_meta: dict[str, Any]) -> list[dict[int, float]]:
    """Per frame: instance id -> visibility (visible fraction x in-frame share) from `scene.json`."""
    rows = scene_meta.get("frames")
    if not isinstance(rows, list):
        raise InputError("scene.json: field `frames` (per-frame visibility) is missing; regenerate the scene")
    out: list[dict[int, float]] = [dict() for _ in rows]
    for r in rows:
        out[int(r["index"])] = {int(v["id"]): float(v["visibility"]) for v in r.get("visible", [])}
    return out


@dataclass
class QuestionScore:
    precision: float
    recall: float
    f1: float
    chosen: int


def score_selection(chosen: list[int], instances: set[int], vis: list[dict[int, float]],
                    min_visible: float = 0.2) -> QuestionScore:
    """Precision/recall/F1 of `chosen` frame indices for the question's `instances` (ids), see the module doc.
    `instances` must already be restricted to the ones that reach `min_visible` somewhere in the video."""
    if not instances:
        raise ValueError("score_selection: no eligible instances")
    seen = {i for f in chosen for i, v in vis[f].items() if v >= min_visible and i in instances}
    recall = len(seen) / len(instances)
    good = sum(any(vis[f].get(i, 0.0) >= min_visible for i in instances) for f in chosen)
    precision = good / len(chosen) if chosen else 0.0
    f1 = 2 * precision * recall / (precision + recall) if precision + recall > 0 else 0.0
    return QuestionScore(precision, recall, f1, len(chosen))


def _summary(rows: list[dict[str, Any]]) -> dict[str, Any]:
    if not rows:
        return {"questions": 0}
    a = {k: np.array([r[k] for r in rows], dtype=np.float64)
         for k in ("precision", "recall", "f1", "scored_candidates", "scored_frames", "chosen")}
    if all("found" in r for r in rows):  # long videos: recall over every scored frame (what the search saw)
        a["found"] = np.array([r["found"] for r in rows], dtype=np.float64)
    return {"questions": len(rows), **{k: round(float(v.mean()), 4) for k, v in a.items()},
            "empty_selections": int((a["chosen"] == 0).sum()),
            "fewer_than_k": int(sum(any(n.startswith("fewer than K") for n in r["notes"]) for r in rows))}


def summarise(records: list[dict[str, Any]], methods: list[str]) -> dict[str, Any]:
    """Per method: overall, by complexity level and by question type."""
    out: dict[str, Any] = {}
    for m in methods:
        rows = [r for r in records if r["method"] == m]
        out[m] = {"all": _summary(rows),
                  "by_level": {lv: _summary([r for r in rows if r["level"] == lv])
                               for lv in sorted({r["level"] for r in rows})},
                  "by_type": {t: _summary([r for r in rows if r["qtype"] == t])
                              for t in sorted({r["qtype"] for r in rows})}}
    return out


def check_targets(summary: dict[str, Any]) -> dict[str, Any]:
    """The issue's targets on the default iterative search; each with its value and the margin (miss if < 0)."""
    it, un, ex = (summary.get(m, {}).get("all", {}) for m in ("iterative", "uniform", "exhaustive"))
    if not it.get("questions"):
        return {}
    t = TARGETS
    res = {
        "iterative_f1": (it["f1"], t["f1_min"], it["f1"] - t["f1_min"]),
        "iterative_scored_candidates": (it["scored_candidates"], t["scored_candidates_max"],
                                        t["scored_candidates_max"] - it["scored_candidates"]),
    }
    if ex.get("questions"):
        gap = ex["recall"] - it["recall"]
        res["recall_gap_to_exhaustive"] = (round(gap, 4), t["recall_gap_to_exhaustive_max"],
                                           t["recall_gap_to_exhaustive_max"] - gap)
    if un.get("questions"):
        marg = it["f1"] - un["f1"]
        res["f1_margin_over_uniform"] = (round(marg, 4), t["f1_margin_over_uniform_min"],
                                         marg - t["f1_margin_over_uniform_min"])
    return {k: {"value": v, "target": tg, "met": bool(m >= 0), "margin": round(m, 4)} for k, (v, tg, m) in res.items()}


# ------------------------------------------------------------------------------------------------ scenes


def _scene_config(i: int, args: argparse.Namespace) -> tuple[Any, str]:
    """Scene i: the varied factor cycles through its three levels, the others stay at their middle level."""
    from mosaicthinker.host.synth.scene import DURATION_LEVELS, SceneConfig

    level = LEVELS[args.vary][i % 3]
    kw: dict[str, Any] = {"objects": "med", "room": "medium", "duration": args.duration}
    if args.vary == "objects":
        kw["objects"] = level
    elif args.vary == "room":
        kw["room"] = level
    else:
        kw["duration"] = DURATION_LEVELS[level] * args.duration / DURATION_LEVELS["medium"]
    from mosaicthinker.runtime.commands.flags import size_of

    w, h = size_of(args)
    conf = SceneConfig(seed=args.seed * 1000 + i, fps=args.fps, width=w, height=h, **kw)
    return conf, level


def _ensure_scene(conf: Any, out: Path, workers: int) -> dict[str, Any]:
    """Generate the scene into `out` unless a scene with the same configuration is already there."""
    from mosaicthinker.host.synth.generate import load_scene, write_scene
    from mosaicthinker.host.synth.scene import config_dict

    if (out / "scene.json").exists() and (out / "questions.jsonl").exists():
        meta = load_scene(out)
        if meta.get("config") == json.loads(jsonio.dumps(config_dict(conf))):
            return {"generated": False}
        raise InputError(f"{out}: holds a scene with another configuration; give another --out or delete it")
    if out.exists() and any(out.iterdir()):
        raise InputError(f"{out}: exists and is not a complete generated scene; delete it or give another --out")
    # rendered into a hidden sibling and renamed when complete: a killed run leaves no half-written scene
    part = out.parent / f".partial-{out.name}-{os.getpid()}"
    shutil.rmtree(part, ignore_errors=True)
    try:
        info = write_scene(conf, part, workers=workers, video=False, name=out.name)
        if out.exists():
            out.rmdir()  # the empty folder checked above
        os.replace(part, out)
    finally:
        shutil.rmtree(part, ignore_errors=True)
    return {"generated": True, "seconds": info.get("seconds")}


def _candidates(scene_dir: Path, use_dedup: bool) -> tuple[list[int], str]:
    """Frames kept by redundant-frame removal (or every frame, said so)."""
    from mosaicthinker.runtime.frames import open_source

    src = open_source(scene_dir)
    if use_dedup:
        try:
            from mosaicthinker.runtime.scan import remove_redundant
        except ImportError:
            return list(range(len(src))), "all frames (runtime.dedup is not available)"
        res = remove_redundant(src)
        return [int(i) for i in res.kept], "dedup.remove_redundant (default configuration)"
    return list(range(len(src))), "all frames (--no-dedup)"


def _image_reader(scene_dir: Path) -> Callable[[int], np.ndarray]:
    import cv2

    def image(f: int) -> np.ndarray:
        p = scene_dir / f"frame-{int(f):06d}.color.jpg"
        from mosaicthinker.runtime.frames import imread_path

        bgr = imread_path(p, cv2.IMREAD_COLOR)
        if bgr is None:
            raise InputError(f"{p}: cannot read the frame image")
        return bgr[:, :, ::-1]

    return image


def _detector(scene_dir: Path, args: argparse.Namespace, image: Callable[[int], np.ndarray],
              vocabulary: list[str]) -> tuple[Callable[[int, list[str]], Detections], str]:
    """detect(frame, names). The model runs once per frame on the scene's whole question `vocabulary` and each
    call takes the names it asks for (a closed-set detector's answer for one name does not depend on the
    others), so the exhaustive baseline costs one network run per candidate, not one per question."""
    if args.detector == "oracle":
        from mosaicthinker.host.synth.oracle import OracleDetector

        det = OracleDetector(scene_dir, miss_rate=args.miss_rate, score_noise=args.score_noise, seed=args.seed)
        return det.detect, f"oracle (miss_rate={args.miss_rate}, score_noise={args.score_noise})"
    if not args.bundle:
        raise InputError("--detector model needs --bundle DIR (a bundle with a detector role)")
    from mosaicthinker.runtime.models import load_role

    model = load_role(args.bundle, "detector")
    return vocabulary_detector(model, image, vocabulary), f"bundle detector ({args.bundle}: " \
        f"{getattr(model, 'name', 'detector')})"


def vocabulary_detector(model: Any, image: Callable[[int], np.ndarray], vocabulary: list[str],
                        cache: dict[int, Detections] | None = None) -> Callable[[int, list[str]], Detections]:
    """detect(frame, names) over a model run once per frame on the whole `vocabulary` (`cache`: frame ->
    Detections, may be shared and saved); each call keeps the names it asks for."""
    per_frame: dict[int, Detections] = {} if cache is None else cache

    def detect(f: int, names: list[str]) -> Detections:
        if f not in per_frame:
            per_frame[f] = model.detect(image(f), vocabulary)
        d = per_frame[f]
        out = d.select(np.array([n in names for n in d.names], dtype=bool))
        out.undetectable = [n for n in d.undetectable if n in names]
        return out

    return detect


class _Memo:
    """The same detector answer for every method (and for repeated calls): detections per (frame, names)."""

    def __init__(self, fn: Callable[[int, list[str]], Detections]):
        self.fn, self.cache = fn, {}

    def __call__(self, f: int, names: list[str]) -> Detections:
        key = (int(f), tuple(names))
        if key not in self.cache:
            self.cache[key] = self.fn(int(f), list(names))
        return self.cache[key]


def evaluate_scene(scene_dir: Path, level: str, args: argparse.Namespace,
                   methods: dict[str, tuple[str, KeyFrameConf]]) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """All questions of one generated scene x all methods (label -> (method, config)) -> per-question records
    and a scene summary."""
    from mosaicthinker.runtime.grounding import parse_question
    from mosaicthinker.host.synth.generate import load_scene

    meta = load_scene(scene_dir)
    vis = visibility_table(meta)
    cands, how = _candidates(scene_dir, not args.no_dedup)
    image = _image_reader(scene_dir)
    h, w = image(int(cands[0])).shape[:2]  # as the pipeline: the search knows the image size (top-up, climbing)
    names_by_id = {int(o["id"]): str(o["name"]) for o in meta["instances"]}
    qpath = scene_dir / "questions.jsonl"
    questions = [json.loads(line) for line in qpath.read_text().splitlines() if line.strip()]
    vocab = sorted({n for q in questions for n in parse_question(q["question"], q.get("options")).objects})
    det_fn, det_desc = _detector(scene_dir, args, image, vocab)
    histograms: dict[int, np.ndarray] = {}
    densities: dict[int, float] = {}
    thumbs: dict[int, np.ndarray] = {}  # the view change's grey copies, once per frame
    records: list[dict[str, Any]] = []
    skipped: dict[str, int] = {}
    for q in questions:
        pq = parse_question(q["question"], q.get("options"))
        if not pq.objects:
            skipped["no objects"] = skipped.get("no objects", 0) + 1
            continue
        ids = q.get("instances")
        if ids is None:
            raise InputError(f"{qpath}: question {q.get('id')} has no `instances` field; regenerate the scene")
        eligible = {int(i) for i in ids if any(v.get(int(i), 0.0) >= args.min_visible for v in vis)}
        if not eligible:
            skipped["objects never visible enough"] = skipped.get("objects never visible enough", 0) + 1
            continue
        detect = _Memo(det_fn)  # per question: every method sees identical detections
        for label, (m, conf) in methods.items():
            t0 = time.perf_counter()
            res = select_keyframes(m, cands, pq.targets, pq.cues, detect, image, conf, histograms=histograms,
                                   densities=densities, image_size=(w, h), thumbs=thumbs)
            sc = score_selection([int(f) for f in res.chosen], eligible, vis, args.min_visible)
            records.append({
                "scene": meta["scene_name"], "level": level, "question": int(q.get("id", -1)),
                "qtype": q["question_type"], "method": label, "targets": pq.targets, "cues": pq.cues,
                "instances": sorted(eligible), "instance_names": sorted({names_by_id.get(i, "?") for i in eligible}),
                "precision": sc.precision, "recall": sc.recall, "f1": sc.f1, "chosen": sc.chosen,
                "chosen_frames": [int(f) for f in res.chosen],
                "scored_candidates": res.frames_scored / len(cands), "scored_frames": res.frames_scored / len(vis),
                "notes": res.notes, "seconds": round(time.perf_counter() - t0, 4)})
    info = {"scene": meta["scene_name"], "level": level, "frames": len(vis), "candidates": len(cands),
            "candidates_from": how, "detector": det_desc, "questions": len(questions),
            "objects": len(meta["instances"]), "room_size": meta.get("room_size"),
            "duration_s": meta.get("camera", {}).get("duration"), "skipped": skipped,
            "histograms_computed": len(histograms)}
    return records, info


# ------------------------------------------------------------------------------------------------ long videos


def search_seed(video_seed: int, question: int, repeat: int = 0) -> int:
    """The search's own seed for one question of one long video (and one repeat of the run)."""
    return 1000 * int(video_seed) + int(question) + 10 ** 6 * int(repeat)


def evaluate_long_video(video: Any, questions: list[dict[str, Any]], detect: Callable[[int, list[str]], Detections],
                        methods: dict[str, tuple[str, KeyFrameConf]], min_visible: float = 0.2,
                        name: str = "long", seed: int = 0, repeat: int = 0) -> list[dict[str, Any]]:
    """Every question of a `synth.longvideo.LongVideo` x every method (label -> (method, config)) -> records
    as `evaluate_scene`'s (level = `name`). Every frame is a candidate; each question's search gets its own seed
    (`search_seed`: 1000 * seed + question id, + 10**6 * `repeat` for a repeat of the whole run with other
    draws), so the random draws are not shared by the questions of one video."""
    import dataclasses

    vis = video.visibility()
    cands = list(range(len(video)))
    histograms: dict[int, np.ndarray] = {}
    densities: dict[int, float] = {}  # the content prior's edge densities, once per frame for every question
    thumbs: dict[int, np.ndarray] = {}  # and its view change's grey copies
    records = []
    for q in questions:
        memo = _Memo(detect)  # every method sees identical detections
        for label, (m, conf) in methods.items():
            qc = dataclasses.replace(conf, seed=search_seed(seed, q["id"], repeat))
            t0 = time.perf_counter()
            res = select_keyframes(m, cands, q["targets"], q["cues"], memo, lambda f: video.rgb[f], qc,
                                   histograms=histograms, image_size=video.size, densities=densities,
                                   thumbs=thumbs)
            sc = score_selection([int(f) for f in res.chosen], set(q["instances"]), vis, min_visible)
            found = score_selection(res.order, set(q["instances"]), vis, min_visible).recall if res.order \
                else sc.recall
            records.append({
                "scene": name, "level": name, "question": int(q["id"]), "qtype": q["qtype"], "method": label,
                "targets": q["targets"], "cues": q["cues"], "instances": q["instances"], "share": q["share"],
                "precision": sc.precision, "recall": sc.recall, "f1": sc.f1, "chosen": sc.chosen,
                "found": found, "scored_candidates": res.frames_scored / len(cands), "repeat": repeat,
                "scored_frames": res.frames_scored / len(cands), "notes": res.notes,
                "seconds": round(time.perf_counter() - t0, 4)})
    return records


# ------------------------------------------------------------------------------------------------ command


COMMON_FLAGS = ("bundle", "out")


def add_arguments(p: argparse.ArgumentParser) -> None:
    from mosaicthinker.runtime.cli import add_stage_flags
    from mosaicthinker.runtime.commands.flags import (add_clip, add_deprecated_size_parts, add_keyframes, add_scenes,
                                                      add_size)

    add_scenes(p, 3, "number of generated scenes")
    p.add_argument("--seed", type=int, default=0, help="scene i uses seed 1000*S + i; also the oracle's seed")
    add_keyframes(p, 8, "the key-frame study's budget")
    add_stage_flags(p, detector=True)
    p.add_argument("--vary", choices=sorted(LEVELS), default="objects",
                   help="complexity factor cycled over low/medium/high across the scenes (default objects)")
    add_clip(p, 60.0, 15.0, "video (at the medium level of --vary duration)")
    add_size(p, "320x240")
    add_deprecated_size_parts(p)
    p.add_argument("--workers", type=int, default=1, help="rendering processes")
    p.add_argument("--miss-rate", type=float, default=0.1, help="oracle detector miss rate (default 0.1)")
    p.add_argument("--score-noise", type=float, default=0.1, help="oracle detector score noise (default 0.1)")
    p.add_argument("--min-visible", type=float, default=0.2,
                   help="an instance counts as seen in a frame from this visibility on (default 0.2)")
    p.add_argument("--no-dedup", action="store_true", help="use every frame as a candidate")
    p.add_argument("--conf", default=None, metavar="JSON",
                   help='key-frame config overrides, e.g. \'{"threshold": 2, "budget_fraction": 0.2}\'')
    p.add_argument("--variant", action="append", default=[], metavar="LABEL=JSON",
                   help='an extra iterative configuration reported as its own method, e.g. '
                        '\'topup={"min_keyframes": 8}\' (repeatable; the targets are judged on the default only)')
    p.add_argument("--records", action="store_true", help="include per-question records in the output")


def run(args: argparse.Namespace) -> dict[str, Any]:
    if not 0 <= args.miss_rate < 1:
        raise InputError(f"--miss-rate must be in [0, 1) (got {args.miss_rate})")
    try:
        over = json.loads(args.conf) if args.conf else {}
    except json.JSONDecodeError as e:
        raise InputError(f"--conf: not valid JSON ({e})") from None
    conf = KeyFrameConf.merged({**over, "keyframes": args.keyframes})
    methods: dict[str, tuple[str, KeyFrameConf]] = {m: (m, conf) for m in METHODS}
    for v in args.variant:
        label, _, js = v.partition("=")
        try:
            vo = json.loads(js)
        except json.JSONDecodeError as e:
            raise InputError(f"--variant {v!r}: expected LABEL=JSON ({e})") from None
        if not label or label in methods or not isinstance(vo, dict):
            raise InputError(f"--variant {v!r}: give a new label and a JSON object of key-frame config overrides")
        methods[label] = ("iterative", KeyFrameConf.merged({**over, **vo, "keyframes": args.keyframes}))
    t0 = time.perf_counter()
    tmp = None
    if args.out:
        from mosaicthinker.runtime.infra.outputs import check_out_dir

        check_out_dir(Path(args.out))  # before generating and evaluating, not after
    root = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="mosaic-kf-"))
    if not args.out:
        tmp = root
    records: list[dict[str, Any]] = []
    scenes: list[dict[str, Any]] = []
    from mosaicthinker.runtime.infra.progress import ticked

    try:
        for i in ticked(range(args.scenes), "scenes", "scene"):
            sconf, level = _scene_config(i, args)
            sdir = root / f"scene-{sconf.seed:05d}-{args.vary}-{level}"
            gen = _ensure_scene(sconf, sdir, args.workers)
            recs, info = evaluate_scene(sdir, level, args, methods)
            records += recs
            scenes.append({**info, **gen, "seed": sconf.seed})
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
    summary = summarise(records, list(methods))
    out: dict[str, Any] = {
        "schema": SCHEMA,
        "command": "mosaic eval keyframes " + " ".join(_argv(args)),
        "detector": args.detector, "keyframes": args.keyframes, "vary": args.vary, "seed": args.seed,
        "min_visible": args.min_visible, "config": conf.to_dict(),
        "variants": {k: {"method": m, "overrides": {f: v for f, v in c.to_dict().items() if v != conf.to_dict()[f]}}
                     for k, (m, c) in methods.items() if k not in METHODS},
        "methods": summary, "targets": check_targets(summary), "scenes": scenes,
        "seconds": round(time.perf_counter() - t0, 2), "cpu_count": os.cpu_count(),
    }
    if args.records:
        out["records"] = records
    if args.out:  # the result beside the scenes, written atomically (locked, temp file + rename, run.json)
        from mosaicthinker.runtime.infra.outputs import write_group

        write_group(args.out, [("keyframes_json", "keyframes.json", dict(out))], out)
    return out


def _argv(args: argparse.Namespace) -> list[str]:
    from mosaicthinker.runtime.commands.flags import size_of

    keep = ["scenes", "seed", "keyframes", "detector", "vary", "duration", "fps", "miss_rate", "score_noise",
            "min_visible"]
    out = [f"--{k.replace('_', '-')} {getattr(args, k)}" for k in keep] + ["--size {}x{}".format(*size_of(args))]
    if args.no_dedup:
        out.append("--no-dedup")
    if args.conf:
        out.append(f"--conf '{args.conf}'")
    out += [f"--variant '{v}'" for v in args.variant]
    if args.bundle:
        out.append(f"--bundle {args.bundle}")
    return out


def render(result: dict[str, Any]) -> str:
    lines = [f"key frames: {len(result['scenes'])} scenes, K={result['keyframes']}, detector={result['detector']}, "
             f"varying {result['vary']}", ""]
    head = f"{'method':<14} {'level':<8} {'n':>4} {'P':>6} {'R':>6} {'F1':>6} {'scored/cand':>11} {'scored/all':>10}"
    lines.append(head)
    for m, s in result["methods"].items():
        groups = [("all", s["all"])] + list(s["by_level"].items())
        for lv, g in groups:
            if not g.get("questions"):
                continue
            lines.append(f"{m:<14} {lv:<8} {g['questions']:>4} {g['precision']:>6.3f} {g['recall']:>6.3f} "
                         f"{g['f1']:>6.3f} {g['scored_candidates']:>11.3f} {g['scored_frames']:>10.3f}")
    if result.get("targets"):
        lines += ["", "targets (iterative, default configuration):"]
        for k, t in result["targets"].items():
            lines.append(f"  {k:<30} {t['value']!s:>8} vs {t['target']:<5} {'met' if t['met'] else 'MISSED'} "
                         f"(margin {t['margin']:+.3f})")
    for s in result["scenes"]:
        lines.append(f"scene {s['scene']}: {s['level']}, {s['frames']} frames, {s['candidates']} candidates "
                     f"({s['candidates_from']}), {s['objects']} objects, skipped {s['skipped']}")
    return "\n".join(lines)
