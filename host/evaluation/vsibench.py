"""`mosaic eval vsibench`: the map reasoner on VSI-Bench questions, with the benchmark's own scoring.

For each scene the map is built from the benchmark's per-category boxes (`SemanticMap.from_meta_info`), every
question is answered by `MapReasoner`, and scored as VSI-Bench does: exact match of the option letter for
multiple choice, Mean Relative Accuracy (MRA) for numbers — the share of thresholds θ ∈ {0.50, 0.55, ..., 0.95}
with |pred − gt| / gt <= 1 − θ. Question types that need the video (obj_appearance_order: first-seen times)
are skipped and listed as such.

`--disagreements FILE` writes the questions the reasoner gets wrong with a reason per case, classified from the
geometry (e.g. the answer is within a few degrees of a direction boundary, the benchmark counted instances that
its own box list does not hold, ...).
"""
from __future__ import annotations

import argparse
import json
import math
import time
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np

from mosaicthinker.runtime.answer import Answer, MapReasoner, NUMERIC_QTYPES
from mosaicthinker.runtime.infra import jsonio
from mosaicthinker.runtime.infra.errors import InputError, read_text
from mosaicthinker.runtime.infra.numbers import check_array
from mosaicthinker.runtime.infra.progress import ticked
from mosaicthinker.runtime.map import SemanticMap

SCHEMA = "mosaicthinker.eval.vsibench/1"
MRA_THRESHOLDS = tuple(float(t) for t in np.linspace(0.50, 0.95, 10))  # as lmms-eval's vsibench utils
VIDEO_ONLY = ("obj_appearance_order",)  # needs first-seen times from the video, not in meta_info


def mean_relative_accuracy(pred: float, gt: float, thresholds: tuple[float, ...] = MRA_THRESHOLDS) -> float:
    """VSI-Bench MRA: mean over θ of 1[|pred - gt| / |gt| <= 1 - θ] (the official lmms-eval rule)."""
    if gt == 0:
        return float(pred == 0)
    rel = abs(float(pred) - float(gt)) / abs(float(gt))
    return float(np.mean([rel <= 1.0 - t for t in thresholds]))


def score_answer(qtype: str, pred: Any, gt: Any) -> float:
    """Score one answer as VSI-Bench does: MRA for numeric types; for multiple choice the first word of the
    prediction without a trailing period, matched case-insensitively. A non-number for a numeric type scores 0."""
    if qtype in NUMERIC_QTYPES:
        try:
            p = float(pred)
        except (TypeError, ValueError):
            return 0.0
        if not math.isfinite(p):
            return 0.0
        return mean_relative_accuracy(p, float(gt))
    first = str(pred).strip().split(" ")[0].rstrip(".").strip()
    return float(first.lower() == str(gt).strip().lower())


def load_questions(path: str | Path) -> list[dict[str, Any]]:
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: questions file not found (VSI-Bench questions.jsonl)")
    out = []
    for i, line in enumerate(read_text(path, "questions").splitlines(), 1):  # decoded first: a bad byte is named
        if not line.strip():
            continue
        try:
            q = json.loads(line)
        except json.JSONDecodeError as e:
            raise InputError(f"{path}:{i}: not a JSON line ({e})") from e
        if not isinstance(q, dict):
            raise InputError(f"{path}:{i}: a question must be a JSON object, got {type(q).__name__}")
        for k in ("scene_name", "question_type", "question", "ground_truth"):
            if k not in q:
                raise InputError(f"{path}:{i}: field `{k}` is missing")
        out.append(q)
    return out


def load_meta(path: str | Path) -> dict[str, Any]:
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: meta_info file not found (VSI-Bench meta_info.json)")
    try:
        with open(path) as f:
            meta = json.load(f)
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise InputError(f"{path}: not a JSON file ({e}); give VSI-Bench's meta_info.json") from e
    bad = [k for k, v in meta.items() if not isinstance(v, dict)][:3] if isinstance(meta, dict) else None
    if bad is None or bad:
        raise InputError(f"{path}: meta_info must map scene names to objects with `object_bbox`"
                         + (f" (scene {bad[0]!r} is not an object)" if bad else ""))
    for scene, entry in meta.items():  # ground truth that is not there (NaN / inf) is named, never scored
        for c, boxes in (entry.get("object_bbox") or {}).items() if isinstance(entry.get("object_bbox"), dict) else ():
            for j, b in enumerate(boxes if isinstance(boxes, list) else ()):
                for k in ("centroid", "axesLengths"):
                    v = b.get(k) if isinstance(b, dict) else None
                    if isinstance(v, list) and all(isinstance(x, (int, float)) for x in v):
                        check_array(v, f"{path}: scene {scene!r}: object_bbox.{c}[{j}].{k}", "the box", lo=-1e7,
                                    hi=1e7, fix="fix that box or drop it from meta_info")
    return meta


def evaluate(questions: list[dict[str, Any]], meta: dict[str, Any], types: list[str] | None = None,
             limit: int | None = None) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """Answer and score. Returns (summary, per-question records)."""
    maps: dict[str, MapReasoner] = {}
    records: list[dict[str, Any]] = []
    skipped: dict[str, int] = defaultdict(int)
    t0 = time.perf_counter()
    for q in ticked(questions, "questions", "question"):
        qt = q["question_type"]
        if types and qt not in types:
            continue
        if limit is not None and len(records) >= limit:
            break
        if qt in VIDEO_ONLY:
            skipped[qt] += 1
            continue
        scene = str(q["scene_name"])
        if scene not in meta:
            raise InputError(f"question {q.get('id')}: scene {scene} is not in the meta_info file")
        if scene not in maps:
            maps[scene] = MapReasoner(SemanticMap.from_meta_info(meta[scene], scene))
        a: Answer = maps[scene].answer(q["question"], q.get("options"))
        s = score_answer(qt, a.text, q["ground_truth"]) if a.ok else 0.0
        records.append({"id": q.get("id"), "scene_name": scene, "question_type": qt, "ground_truth": q["ground_truth"],
                        "pred": a.text, "value": a.value, "status": a.status, "score": s,
                        "explanation": a.explanation, "missing": a.missing})
    per: dict[str, dict[str, Any]] = {}
    for qt in sorted({r["question_type"] for r in records}):
        rs = [r for r in records if r["question_type"] == qt]
        st = defaultdict(int)
        for r in rs:
            st[r["status"]] += 1
        per[qt] = {"n": len(rs), "metric": "MRA" if qt in NUMERIC_QTYPES else "accuracy",
                   "score": float(np.mean([r["score"] for r in rs])), "status": dict(st),
                   "score_answered": float(np.mean([r["score"] for r in rs if r["status"] == "ok"]))
                   if st["ok"] else None}
        if qt in NUMERIC_QTYPES and st["ok"]:  # systematic bias of the computed numbers against the benchmark
            ratio = [float(r["value"]) / float(r["ground_truth"]) for r in rs
                     if r["status"] == "ok" and isinstance(r["value"], (int, float)) and not isinstance(r["value"], bool)
                     and float(r["ground_truth"]) != 0]
            per[qt]["median_value_over_gt"] = float(np.median(ratio)) if ratio else None
    summary = {"n_questions": len(records), "per_type": per,
               "overall": float(np.mean([p["score"] for p in per.values()])) if per else None,
               "overall_micro": float(np.mean([r["score"] for r in records])) if records else None,
               "skipped": {k: {"n": v, "reason": "needs the video (first-seen times); meta_info has none"}
                           for k, v in skipped.items()},
               "seconds": round(time.perf_counter() - t0, 3)}
    return summary, records


# ----------------------------------------------------------------------------- disagreements


def classify_disagreement(q: dict[str, Any], rec: dict[str, Any], meta_scene: dict[str, Any]) -> dict[str, Any]:
    """One disagreement record: the question, both answers and a reason (`_reason_for`)."""
    return {"id": rec["id"], "scene_name": rec["scene_name"], "question_type": rec["question_type"],
            "question": q["question"], "options": q.get("options"), "ground_truth": rec["ground_truth"],
            "pred": rec["pred"], "score": rec["score"], "status": rec["status"],
            "explanation": rec["explanation"], "reason": _reason_for(q, rec, meta_scene)}


def _reason_for(q: dict[str, Any], rec: dict[str, Any], meta_scene: dict[str, Any]) -> str:
    """A reason derived from the geometry of the benchmark's own boxes (general rules, no per-question text)."""
    from mosaicthinker.runtime.grounding import canonical_name, parse_question

    qt = rec["question_type"]
    if rec["status"] != "ok":
        return f"reasoner status {rec['status']}: {rec['explanation']}"
    pq = parse_question(q["question"], q.get("options"))
    if qt == "object_counting":
        name = pq.node.objects[0].name
        boxes = sum(len(v) for k, v in meta_scene["object_bbox"].items() if (canonical_name(k) or k) == name)
        cnt = sum(v for k, v in meta_scene.get("object_counts", {}).items() if (canonical_name(k) or k) == name)
        return (f"count: the ground truth says {rec['ground_truth']} but meta_info holds {boxes} {name} box(es) "
                f"and its object_counts says {cnt}: the answer is not derivable from the benchmark's own boxes")
    if qt == "object_abs_distance":
        gt, v = float(rec["ground_truth"]), float(rec["value"])
        if gt > v:
            return (f"distance: the ground truth {gt} m exceeds the closest-point distance of the two boxes "
                    f"({v:.3f} m) by {gt - v:.2f} m, beyond the 0.05 m rounding; the benchmark's distances are "
                    f"not below the box distances (see `abs_distance_excess_m`), consistent with measuring "
                    f"between points inside the boxes rather than the boxes' closest surfaces")
        return (f"distance: the ground truth {gt} m is below the closest-point distance of the two boxes "
                f"({v:.3f} m): the boxes cannot be that close")
    if qt == "object_size_estimation":
        return (f"size: the ground truth {rec['ground_truth']} cm differs from the longest box side "
                f"({float(rec['value']):.1f} cm)")
    return "geometry disagrees with the benchmark answer: " + rec["explanation"]


DISAGREEMENT_EXCLUDED = {
    "route_planning": "routes were written by people and name objects meta_info has no boxes for; reported, "
                      "not explained away",
    "room_size_estimation": "the benchmark's room area comes from the room scan (not in meta_info); the map's "
                            "box extent is a lower bound; reported, not explained away",
}


def _excess_stats(records: list[dict[str, Any]]) -> dict[str, float] | None:
    """Ground truth minus the closest-point box distance over all answered absolute-distance questions (m)."""
    d = [float(r["ground_truth"]) - float(r["value"]) for r in records
         if r["question_type"] == "object_abs_distance" and r["status"] == "ok"]
    if not d:
        return None
    p = np.percentile(d, [1, 5, 50, 95, 99])
    return {"n": len(d), "mean": round(float(np.mean(d)), 4),
            **{f"p{k}": round(float(v), 4) for k, v in zip((1, 5, 50, 95, 99), p)}}


def find_disagreements(questions: list[dict[str, Any]], records: list[dict[str, Any]],
                       meta: dict[str, Any], mra_below: float = 0.5) -> list[dict[str, Any]]:
    """Wrong multiple-choice answers and numeric answers with MRA below `mra_below`, each with a reason."""
    by_id = {q.get("id"): q for q in questions}
    out = []
    for r in records:
        bad = r["score"] < (mra_below if r["question_type"] in NUMERIC_QTYPES else 1.0)
        if bad and r["question_type"] not in DISAGREEMENT_EXCLUDED:
            out.append(classify_disagreement(by_id[r["id"]], r, meta[r["scene_name"]]))
    return out


# ----------------------------------------------------------------------------- command


COMMON_FLAGS = ("out",)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--questions", metavar="Q.jsonl", required=True, help="VSI-Bench questions.jsonl")
    parser.add_argument("--meta", metavar="FILE", required=True, help="VSI-Bench meta_info.json")
    parser.add_argument("--types", nargs="*", help="only these question types")
    parser.add_argument("--limit", type=int, help="at most this many questions")
    parser.add_argument("--disagreements", metavar="FILE", help="write the disagreement list (JSON) here")
    parser.add_argument("--records", action="store_true", help="include every question's record in the output")
    parser.add_argument("--paired", metavar="Q.jsonl",
                        help="the benchmark's own questions: questions with a `source_id` (e.g. a paraphrase set) "
                             "are compared per type with the source questions in this file")
    parser.add_argument("--result", metavar="FILE.json", help="also write the JSON result to this file")


def run(args: argparse.Namespace) -> dict[str, Any]:
    from mosaicthinker.runtime.infra.outputs import run_group

    with run_group(args.out) as outs:  # --out checked and locked before scoring
        return _run(args, outs)


def _run(args: argparse.Namespace, outs: Any) -> dict[str, Any]:
    from mosaicthinker.runtime.infra.outputs import check_out_file, write_file_atomic

    for flag, path in (("--result", args.result), ("--disagreements", args.disagreements)):
        if path:
            check_out_file(path, flag)  # before scoring, not after
    questions = load_questions(args.questions)
    meta = load_meta(args.meta)
    summary, records = evaluate(questions, meta, args.types, args.limit)
    result: dict[str, Any] = {"schema": SCHEMA, "questions": str(args.questions), "meta": str(args.meta), **summary}
    if args.disagreements:
        dis = find_disagreements(questions, records, meta)
        n_type = defaultdict(int)
        for d in dis:
            n_type[d["question_type"]] += 1
        share = {k: round(v / summary["per_type"][k]["n"], 4) for k, v in n_type.items()}
        write_file_atomic(args.disagreements, jsonio.dumps(
            {"schema": "mosaicthinker.vsibench_disagreements/1",
             "definition": "wrong multiple-choice answers and numeric answers with MRA < 0.5 (relative "
                           "error >= 25%), computed from the benchmark's own boxes",
             "excluded_types": DISAGREEMENT_EXCLUDED,
             "abs_distance_excess_m": _excess_stats(records), "n": len(dis), "per_type": dict(n_type),
             "share_per_type": share, "cases": dis}, indent=1))
        result["disagreements"] = {"file": str(args.disagreements), "n": len(dis), "share_per_type": share}
    if getattr(args, "paired", None):
        result["paired"] = paired_scores(records, questions, load_questions(args.paired), meta)
    if args.records:
        result["records"] = records
    if getattr(args, "result", None):
        write_file_atomic(args.result, jsonio.dumps(result, indent=1, default=str))
    if outs is not None:
        from mosaicthinker.runtime.infra.outputs import finish_group

        finish_group(outs, [("vsibench_json", "vsibench.json", dict(result))], result)
    return result


def paired_scores(records: list[dict[str, Any]], questions: list[dict[str, Any]], sources: list[dict[str, Any]],
                  meta: dict[str, Any]) -> dict[str, Any]:
    """Per type: the score of the questions that name a `source_id` and of their source questions in the
    benchmark's wording (answered and scored the same way), and the difference."""
    by_id = {q.get("id"): q for q in sources}
    src_of = {q.get("id"): q.get("source_id") for q in questions}
    pairs = [(r, by_id[src_of[r["id"]]]) for r in records if src_of.get(r["id"]) in by_id]
    if not pairs:
        return {"n": 0, "note": "no question has a source_id found in the paired file"}
    _, src_rec = evaluate([s for _, s in pairs], meta)
    src_score = {r["id"]: r["score"] for r in src_rec}
    out: dict[str, Any] = {}
    for qt in sorted({r["question_type"] for r, _ in pairs}):
        ps = [(r["score"], src_score[s.get("id")]) for r, s in pairs if r["question_type"] == qt
              and s.get("id") in src_score]
        if ps:
            a, b = float(np.mean([p for p, _ in ps])), float(np.mean([q for _, q in ps]))
            out[qt] = {"n": len(ps), "score": round(a, 4), "source_score": round(b, 4), "diff": round(a - b, 4)}
    return out


def render(result: dict[str, Any]) -> str:
    lines = [f"VSI-Bench: {result['n_questions']} questions answered from the benchmark's boxes "
             f"({result['seconds']} s)", f"{'type':<30} {'n':>5} {'metric':>8} {'score':>7}  status"]
    for qt, p in result["per_type"].items():
        lines.append(f"{qt:<30} {p['n']:>5} {p['metric']:>8} {p['score']:>7.3f}  {p['status']}")
    if result.get("overall") is not None:
        lines.append(f"{'overall (mean of types)':<30} {'':>5} {'':>8} {result['overall']:>7.3f}")
    for k, v in result.get("skipped", {}).items():
        lines.append(f"skipped {k}: {v['n']} ({v['reason']})")
    for qt, p in (result.get("paired") or {}).items():
        if isinstance(p, dict):
            lines.append(f"paired {qt:<23} {p['n']:>5} {p['score']:>7.3f} vs benchmark wording {p['source_score']:.3f}"
                         f" ({p['diff']:+.3f})")
    if "disagreements" in result:
        d = result["disagreements"]
        lines.append(f"disagreements: {d['n']} -> {d['file']} (share per type {d['share_per_type']})")
    return "\n".join(lines)
