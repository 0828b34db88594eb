"""`mosaic eval e2e`: end-to-end answer accuracy on synthetic scenes, and the quality of the built maps.

For N generated scenes (`host.synth`, seeds S..S+N-1, object level cycling low / med / high) and their
questions (`questions.jsonl`, VSI-Bench types and wording), three maps answer every question with the map
reasoner, scored as VSI-Bench does (exact match for multiple choice, MRA for numbers):

(a) `gt`     the ground-truth map (true boxes, true room, true first-seen times);
(b) `oracle` the map the pipeline builds from the video with oracle perception (detector + masks from the
             rendered instance masks, 10% miss rate, score noise; sensor depth; SIFT alignment);
(c) `models` the same with the bundle's real detector/segmenter (e.g. SSD COCO + DeepLab VOC from
             ../shared/models), only on questions whose objects the detector's label list covers.

One map is built per scene from the union of its questions' objects (`--map-per scene`, default: the same map
answers every question, as `mosaic map` + `mosaic ask MAP` would) or one per question (`--map-per question`,
the paper's setting: the question's objects steer the key-frame search; slower).

Map quality (per built map): the estimated world is aligned to the ground truth **through the camera track**
(Umeyama of estimated vs true key-frame camera centres with outlier rejection; never through the objects);
then each category's built instances are matched to its true instances (Hungarian on centre distance, at most
`--match-m` apart). Instance recall = matched / true instances of the searched categories that the video shows
(first_seen not None); centre error = distance between matched centres; duplicates = unmatched built instances.
Room size uses the map's extent (object and camera hull), which under-estimates the room (reported).
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import time
from pathlib import Path
from typing import Any

import numpy as np

from mosaicthinker.runtime.infra.errors import InputError

LEVELS = ("low", "med", "high")


def robust_track_alignment(est: np.ndarray, gt: np.ndarray, min_thr: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    """T [4, 4] mapping estimated camera centres est [N, 3] onto true ones gt [N, 3] (rigid Umeyama, 3 rounds
    dropping residuals above max(min_thr, 3 x median)); returns (T, inlier mask [N])."""
    from mosaicthinker.runtime.geometry import transform, umeyama

    keep = np.ones(len(est), bool)
    if len(est) < 3:
        raise InputError("track alignment needs at least 3 aligned key frames")
    T = np.eye(4)
    for _ in range(3):
        if keep.sum() < 3:
            break
        T = umeyama(est[keep], gt[keep])
        r = np.linalg.norm(transform(T, est) - gt, axis=1)
        keep = r <= max(min_thr, 3.0 * float(np.median(r)))
    return T, keep


def map_quality(smap: Any, poses_world: dict[int, np.ndarray], source: Any, meta: dict[str, Any],
                names: list[str], match_m: float = 1.0) -> dict[str, Any]:
    """Instance recall, centre errors and duplicates of a built map against the scene's ground truth (see the
    module docstring). poses_world: {frame: T_wc} of the built map (key frames); source: the frame source with
    ground-truth poses; names: the categories that were searched."""
    from scipy.optimize import linear_sum_assignment

    from mosaicthinker.runtime.geometry import transform
    from mosaicthinker.runtime.grounding import canonical_name

    idx = [i for i in sorted(poses_world) if source[i].pose_gt is not None]
    est = np.array([poses_world[i][:3, 3] for i in idx])
    gt = np.array([source[i].pose_gt[:3, 3] for i in idx])
    T, keep = robust_track_alignment(est, gt)
    track_err = np.linalg.norm(transform(T, est) - gt, axis=1)
    canon = lambda n: canonical_name(n) or n  # noqa: E731
    want = {canon(n) for n in names}
    truth = [g for g in meta["instances"] if canon(g["name"]) in want and g.get("first_seen") is not None]
    errs, matched_ids, dup = [], [], 0
    per_inst = []
    for cat in sorted(want):
        G = [g for g in truth if canon(g["name"]) == cat]
        B = [o for o in smap.instances if canon(o.name) == cat]
        if not B:
            continue
        if not G:
            dup += len(B)
            continue
        gc = np.array([g["box"]["centroid"] for g in G])
        bc = transform(T, np.array([o.center for o in B]))
        D = np.linalg.norm(gc[:, None] - bc[None], axis=2)
        r, c = linear_sum_assignment(D)
        ok = D[r, c] <= match_m
        for gi, bi, good in zip(r, c, ok):
            if good:
                errs.append(float(D[gi, bi]))
                matched_ids.append(int(G[gi]["id"]))
                per_inst.append({"id": int(G[gi]["id"]), "name": cat, "err_m": round(float(D[gi, bi]), 3)})
        dup += len(B) - int(ok.sum())
    return {"instances_true": len(truth), "instances_built": len(smap.instances), "matched": len(matched_ids),
            "recall": len(matched_ids) / len(truth) if truth else None,
            "centre_err_median_m": float(np.median(errs)) if errs else None,
            "centre_errs_m": [round(e, 3) for e in errs], "unmatched_built": dup,
            "track_err_median_m": float(np.median(track_err[keep])) if keep.any() else None,
            "track_outliers": int((~keep).sum()), "matches": per_inst}


NO_MARGINS = {"angle_deg": 0.0, "turn_deg": 0.0, "rel_dist_m": 0.0, "min_sep_m": 0.0}


def generate_scenes(n: int, seed: int, data: Path, size: tuple[int, int], fps: float, duration: float,
                    room: str = "medium", all_candidates: bool = False) -> tuple[list[Path], dict[str, Any]]:
    """Generate (or reuse) N synthetic scenes under `data`; returns their folders and the answer key's report.
    A reused scene's questions are rewritten by the current generator (answers from `box_truth`).
    all_candidates: every candidate question, margin rules off (the appearance gap stays), no per-type limit."""
    from mosaicthinker.host.synth.generate import load_scene, write_questions, write_scene
    from mosaicthinker.host.synth.questions import LIMITS
    from mosaicthinker.host.synth.scene import SceneConfig

    out, removed = [], {}
    for k in range(n):
        s = seed + k
        lvl = LEVELS[k % 3]
        d = data / f"scene_s{s}_{lvl}_{size[0]}x{size[1]}_{fps:g}fps_{duration:g}s"
        if not (d / "scene.json").is_file():
            if d.exists():
                shutil.rmtree(d)
            tmp = d.with_name(".mosaic-tmp." + d.name)  # renamed when complete: a kill leaves no half scene
            shutil.rmtree(tmp, ignore_errors=True)
            write_scene(SceneConfig(seed=s, objects=lvl, room=room, duration=duration, fps=fps, width=size[0],
                                    height=size[1]), tmp, video=False, questions=False, name=d.name)
            os.replace(tmp, d)
        _, rep = (write_questions(load_scene(d), d, NO_MARGINS, {t: 10 ** 6 for t in LIMITS}) if all_candidates
                  else write_questions(load_scene(d), d))
        for t, r in rep["removed"].items():  # candidate questions, kept, asked and each margin rule's removals
            for k, v in r.items():
                removed.setdefault(t, {}).setdefault(k, 0)
                removed[t][k] += v
        out.append(d)
    return out, {"source": "evaluation.box_truth (true oriented boxes and first-seen times; not the reasoner)",
                 "margins": rep["margins"] if out else None, "removed": removed}


def _score(q: dict[str, Any], ans: Any) -> float:
    from mosaicthinker.host.evaluation.vsibench import score_answer

    return score_answer(q["question_type"], ans.text if ans.status == "ok" else None, q["ground_truth"])


def _load_questions(d: Path) -> list[dict[str, Any]]:
    p = d / "questions.jsonl"
    return [json.loads(line) for line in p.read_text().splitlines() if line.strip()]


def _detectable(bundle: Any, names: list[str]) -> tuple[set[str], list[str]]:
    """Names the bundle's detector label list covers (closed set) — all names for an open-vocabulary one."""
    from mosaicthinker.runtime.infra.bundle import load_bundle
    from mosaicthinker.runtime.models.detector import map_names

    b = load_bundle(bundle)
    if not b.has_role("detector"):
        raise InputError(f"{bundle}: no `detector` role for the `models` mode")
    labels = b.spec("detector", verify=False).semantics.get("labels")
    if not labels:
        return set(names), []
    mapping, missing = map_names(names, labels)
    return set(mapping), missing


def _oracle_matcher(conf: dict[str, Any], bundle: Any, trace: Any) -> Any:
    """The oracle mode's matcher: OpenCV by name, or the bundle's matcher model for --matcher model."""
    if conf.get("matcher", "sift") != "model":
        return conf.get("matcher", "sift")
    from mosaicthinker.runtime.infra.bundle import load_bundle
    from mosaicthinker.runtime.models import load_role

    b = load_bundle(bundle)
    if not b.has_role("matcher"):
        raise InputError(f"{bundle}: `matcher=model` needs a bundle with a matcher role", fields=("matcher",))
    return load_role(b, "matcher", trace=trace)


def evaluate_scene(d: Path, modes: list[str], conf: dict[str, Any], bundle: Any, map_per: str,
                   keyframes: int, miss_rate: float, seed: int) -> dict[str, Any]:
    """All questions of one scene under each mode -> per-question records and per-map quality."""
    from mosaicthinker.runtime.answer import MapReasoner
    from mosaicthinker.runtime.frames import open_source
    from mosaicthinker.runtime.grounding import parse_question
    from mosaicthinker.runtime.pipeline import build_map, perception_from_bundle
    from mosaicthinker.host.synth.generate import load_scene
    from mosaicthinker.host.synth.questions import ground_truth_map
    from mosaicthinker.runtime.infra.trace import Trace
    from mosaicthinker.host.evaluation.oracle_perception import oracle_perception

    meta = load_scene(d)
    qs = _load_questions(d)
    src = open_source(d)
    parsed = {q["id"]: parse_question(q["question"], q.get("options")) for q in qs}
    records: list[dict[str, Any]] = []
    maps: list[dict[str, Any]] = []
    gtmap = ground_truth_map(meta)
    for q in qs:
        if "gt" in modes:
            a = MapReasoner(gtmap).answer(q["question"], q.get("options"))
            records.append({"scene": d.name, "id": q["id"], "qtype": q["question_type"], "mode": "gt",
                            "level": meta["config"]["objects"], "answer": a.text, "truth": q["ground_truth"],
                            "score": _score(q, a)})
    for mode in [m for m in modes if m != "gt"]:
        qs_m = qs
        note = None
        if mode == "models":
            allnames = sorted({n for q in qs for n in parsed[q["id"]].objects})
            ok_names, missing = _detectable(bundle, allnames)
            qs_m = [q for q in qs if parsed[q["id"]].objects and set(parsed[q["id"]].objects) <= ok_names]
            note = {"undetectable": missing, "questions_kept": len(qs_m), "questions": len(qs)}
        groups = ([(q["id"],) for q in qs_m] if map_per == "question"
                  else [tuple(q["id"] for q in qs_m)] if qs_m else [])
        for g in groups:
            gq = [q for q in qs_m if q["id"] in g]
            targets = list(dict.fromkeys(n for q in gq for n in parsed[q["id"]].targets))
            cues = [n for n in dict.fromkeys(n for q in gq for n in parsed[q["id"]].cues) if n not in targets]
            if not targets and not cues:  # room size only: the map still needs objects; search every category
                targets = sorted(meta["object_counts"])
            trace = Trace()
            t0 = time.perf_counter()
            try:
                if mode == "oracle":
                    perc = oracle_perception(d, miss_rate=miss_rate, seed=seed,
                                             matcher=_oracle_matcher(conf, bundle, trace))
                else:
                    perc = perception_from_bundle(bundle, {**conf, "depth": "sensor"}, trace)
                mb = build_map(src, targets, cues, perc, {**conf, "depth": "sensor"}, trace, keyframes)
                err = None
            except Exception as e:  # a failed build is a result (every question of the map scores 0), not a crash
                mb, err = None, f"{type(e).__name__}: {e}"
            secs = time.perf_counter() - t0
            mq = None
            if mb is not None:
                try:
                    mq = map_quality(mb.map, {i: mb.poses_world[i] for i in mb.keyframes if i in mb.poses_world},
                                     src, meta, targets + cues)
                except InputError as e:
                    mq = {"error": str(e)}
            maps.append({"scene": d.name, "mode": mode, "questions": list(g), "seconds": round(secs, 2),
                         "keyframes": None if mb is None else len(mb.keyframes),
                         "unaligned": None if mb is None else len(mb.unaligned),
                         "recovered": None if mb is None else mb.recovered, "error": err, "quality": mq,
                         "note": note,
                         "fallbacks": [e["message"] for e in trace.events if e["kind"] in ("fallback",)],
                         "random_weights": trace.random_weights_used})
            for q in gq:
                if mb is None:
                    rec_ans, score, status = f"error: {err}", 0.0, "error"
                else:
                    a = MapReasoner(mb.map).answer(q["question"], q.get("options"))
                    rec_ans, score, status = a.text, _score(q, a), a.status
                records.append({"scene": d.name, "id": q["id"], "qtype": q["question_type"], "mode": mode,
                                "level": meta["config"]["objects"], "answer": rec_ans, "truth": q["ground_truth"],
                                "status": status, "score": score})
    return {"records": records, "maps": maps}


def summarise(records: list[dict[str, Any]], maps: list[dict[str, Any]]) -> dict[str, Any]:
    """Accuracy per mode: overall (mean over questions), per question type, per object level; map quality."""
    out: dict[str, Any] = {}
    for mode in sorted({r["mode"] for r in records}):
        rs = [r for r in records if r["mode"] == mode]
        by_t: dict[str, list[float]] = {}
        by_l: dict[str, list[float]] = {}
        for r in rs:
            by_t.setdefault(r["qtype"], []).append(r["score"])
            by_l.setdefault(r["level"], []).append(r["score"])
        agg = lambda d: {k: {"n": len(v), "score": round(float(np.mean(v)), 4)} for k, v in sorted(d.items())}  # noqa: E731
        out[mode] = {"n": len(rs), "overall": round(float(np.mean([r["score"] for r in rs])), 4) if rs else None,
                     "by_type": agg(by_t), "by_level": agg(by_l)}
        ms = [m for m in maps if m["mode"] == mode and m.get("quality") and "recall" in m["quality"]]
        if ms:
            true = sum(m["quality"]["instances_true"] for m in ms)
            matched = sum(m["quality"]["matched"] for m in ms)
            errs = [e for m in ms for e in m["quality"]["centre_errs_m"]]
            out[mode]["map"] = {"maps": len(ms), "instance_recall": round(matched / true, 4) if true else None,
                                "centre_err_median_m": round(float(np.median(errs)), 4) if errs else None,
                                "unmatched_built": sum(m["quality"]["unmatched_built"] for m in ms),
                                "seconds_per_map": round(float(np.mean([m["seconds"] for m in ms])), 2),
                                "failed_builds": sum(1 for m in maps if m["mode"] == mode and m["error"])}
    return out


COMMON_FLAGS = ("bundle", "out")


def add_arguments(p: argparse.ArgumentParser) -> None:
    from mosaicthinker.runtime.cli import add_stage_flags
    from mosaicthinker.runtime.commands.flags import add_clip, add_gravity, add_keyframes, add_scenes, add_size

    add_scenes(p, 3, "number of synthetic scenes")
    p.add_argument("--seed", type=int, default=0, help="first scene seed")
    p.add_argument("--modes", default="gt,oracle", help="comma list of gt, oracle, models (models needs --bundle)")
    p.add_argument("--data", default=None, metavar="DIR", help="folder to generate / reuse scenes in (default: --out/scenes or "
                                                "a temporary folder)")
    add_size(p, "640x480")
    add_clip(p, 30.0, 10.0, "video per scene")
    add_keyframes(p)
    p.add_argument("--map-per", choices=["scene", "question"], default="scene")
    p.add_argument("--miss-rate", type=float, default=0.1, help="oracle detector miss rate")
    add_stage_flags(p, matcher=True)  # model: the bundle's matcher role, in the oracle and models modes
    add_gravity(p, "auto")
    p.add_argument("--all-candidates", action="store_true",
                   help="ask every candidate question: box_truth margin rules off, no per-type limit (rewrites "
                        "the scenes' questions.jsonl)")


def run(args: argparse.Namespace) -> dict[str, Any]:
    modes = [m.strip() for m in args.modes.split(",") if m.strip()]
    bad = set(modes) - {"gt", "oracle", "models"}
    if bad:
        raise InputError(f"--modes: unknown {sorted(bad)} (gt, oracle, models)")
    if "models" in modes and not args.bundle:
        raise InputError("--modes models needs --bundle (e.g. a bundle of ../shared/models built with "
                         "export/onnx_import.py)")
    if args.matcher == "model" and not args.bundle:
        raise InputError("--matcher model needs --bundle (a bundle with a `matcher` role)")
    from mosaicthinker.runtime.infra.outputs import run_group

    with run_group(args.out) as outs:  # --out checked and locked before generating and evaluating
        return _run(args, modes, outs)


def _run(args: argparse.Namespace, modes: list[str], outs: Any) -> dict[str, Any]:
    import tempfile

    w, h = args.size
    data = Path(args.data) if args.data else (Path(args.out) / "scenes" if args.out else
                                             Path(tempfile.mkdtemp(prefix="mosaic_e2e_")))
    data.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    dirs, key = generate_scenes(args.scenes, args.seed, data, (w, h), args.fps, args.duration,
                                all_candidates=args.all_candidates)
    t_gen = time.perf_counter() - t0
    records, maps = [], []
    conf = {"matcher": args.matcher, "gravity": args.gravity}
    if args.keyframes is None:
        from mosaicthinker.runtime.commands.flags import pipeline_keyframes

        args.keyframes = pipeline_keyframes()  # recorded in the settings as the K used
    from mosaicthinker.runtime.infra.progress import ticked

    for d in ticked(dirs, "scenes", "scene"):
        r = evaluate_scene(d, modes, conf, args.bundle, args.map_per, args.keyframes, args.miss_rate, args.seed)
        records += r["records"]
        maps += r["maps"]
    summ = summarise(records, maps)
    res = {"schema": "mosaicthinker.eval.e2e/1", "scenes": [d.name for d in dirs], "modes": modes,
           "settings": {"size": [w, h], "fps": args.fps, "duration": args.duration, "keyframes": args.keyframes,
                        "map_per": args.map_per, "miss_rate": args.miss_rate, "matcher": args.matcher,
                        "seed": args.seed, "depth": "sensor", "all_candidates": args.all_candidates,
                        "gravity": args.gravity},
           "answer_key": key, "summary": summ, "targets": _targets(summ), "seconds": {"generate": round(t_gen, 1),
                                                                 "total": round(time.perf_counter() - t0, 1)},
           "maps": maps, "records": records}
    if outs is not None:
        from mosaicthinker.runtime.infra.outputs import finish_group

        finish_group(outs, [("e2e_json", "e2e.json", dict(res))], res)
    return res


def _targets(s: dict[str, Any]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    if "gt" in s and "oracle" in s and s["gt"]["overall"] is not None and s["oracle"]["overall"] is not None:
        gap = 100 * (s["gt"]["overall"] - s["oracle"]["overall"])
        out["oracle_within_5_points_of_gt"] = {"gap_points": round(gap, 2), "met": gap <= 5.0}
    m = s.get("oracle", {}).get("map")
    if m:
        out["instance_recall_ge_0.9"] = {"value": m["instance_recall"], "met": (m["instance_recall"] or 0) >= 0.9}
        out["centre_err_median_le_0.3m"] = {"value": m["centre_err_median_m"],
                                            "met": m["centre_err_median_m"] is not None
                                            and m["centre_err_median_m"] <= 0.3}
    return out


def _cell(v: dict[str, Any] | None) -> str:
    return "-" if v is None else f"{v['score']:.3f} (n={v['n']})"


def render(r: dict[str, Any]) -> str:
    lines = [f"e2e on {len(r['scenes'])} synthetic scene(s), modes {', '.join(r['modes'])} "
             f"({r['seconds']['total']} s, scenes generated in {r['seconds']['generate']} s)"]
    s = r["summary"]
    types = sorted({t for m in s.values() for t in m["by_type"]})
    lines.append(f"{'question type':<30}" + "".join(f"{m:>16}" for m in s))
    for t in types:
        row = f"{t:<30}"
        for m in s:
            v = s[m]["by_type"].get(t)
            row += f"{_cell(v):>16}"
        lines.append(row)
    lines.append(f"{'overall':<30}" + "".join(f"{_cell({'score': s[m]['overall'], 'n': s[m]['n']}):>16}"
                                             for m in s))
    for lvl in LEVELS:
        row = f"{'objects ' + lvl:<30}"
        for m in s:
            v = s[m]["by_level"].get(lvl)
            row += f"{_cell(v):>16}"
        lines.append(row)
    for m in s:
        if "map" in s[m]:
            q = s[m]["map"]
            lines.append(f"map quality [{m}]: instance recall {q['instance_recall']}, centre error median "
                         f"{q['centre_err_median_m']} m, unmatched built instances {q['unmatched_built']}, "
                         f"{q['seconds_per_map']} s per map, failed builds {q['failed_builds']}")
    rem = r.get("answer_key", {}).get("removed", {})
    if rem:
        cut = sum(v for x in rem.values() for k, v in x.items() if k not in ("candidates", "kept", "asked"))
        lines.append(f"ground truth from the boxes (box_truth); margin rules removed {cut} of "
                     f"{sum(x['candidates'] for x in rem.values())} candidate questions")
    for k, v in r.get("targets", {}).items():
        lines.append(f"target {k}: {v}")
    return "\n".join(lines)
