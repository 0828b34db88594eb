"""`mosaic eval scene`: the real pipeline on a real annotated RGB-D room, scored against the annotation.

    mosaic eval scene --data DIR --annotations FILE [--bundle B] [--depth sensor|model] [--matcher sift|orb|model]
                      [--keyframes K] [--ask N] [--json] [--out DIR]

1. One map of every category the bundle's detector can name plus the annotated ones (`pipeline.build_map`, real
   models), timed per stage with peak RSS.
2. Registration (printed): the best rigid fit (Sim(3) when depth is not metric) of the estimated key-frame cameras
   to their ground truth in the annotation frame — the ATE alignment, with the cameras' orientations fixing the
   rotation (`register_cameras`; a short hand-held track leaves it undetermined by the centres alone; the
   centres-only Umeyama ATE is reported beside it); object positions are never used for it.
3. Scored against the annotated instances visible in the frames given (visibility from the ground-truth poses and
   the sensor depth, for scoring only): per category one-to-one matching (centres within `match_centre_m` or 3D IoU
   >= `match_iou`), precision, recall, count error, median centre error, longest-side error; built instances of
   categories that are not annotated are listed, not counted.
4. Floor: up-axis error (the map's up vs the ground-truth up, seen from every aligned key camera, so it needs no
   registration), the map floor's height in the annotation frame, and every object's bottom vs the map floor.
5. Answers: questions generated from the visible annotation by the box-only ground truth (`box_truth`, which
   shares no code with the reasoner), answered from the built map (`answer.MapReasoner`), scored per type
   (VSI-Bench: exact match / MRA); types with fewer than `min_per_type` questions are listed, not scored. With
   `--ask N`, N of them are also asked on the video (`pipeline.ask`, the per-question key-frame path).
6. A top-down picture of the built map (yellow) over the annotation (white) in `--out`.
"""
from __future__ import annotations

import argparse
import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from mosaicthinker.runtime.infra import jsonio
from mosaicthinker.runtime.infra import schema as S
from mosaicthinker.runtime.infra.bundle import strict_json_loads
from mosaicthinker.runtime.infra.errors import InputError, check_path, read_text
from mosaicthinker.runtime.infra.file_schemas import BOX, rigid_pose
from mosaicthinker.runtime.geometry import OrientedBox, transform

SCHEMA = "mosaicthinker.eval.scene/1"


@dataclass
class SceneEvalConfig:
    match_centre_m: float = 0.3
    match_iou: float = 0.25
    min_per_type: int = 10
    per_type: int = 12
    visible_min_points: int = 3   # of the 27 box sample points, seen (not occluded) in at least one frame
    visibility_stride: int = 2    # every n-th frame checked
    floor_below_tol_m: float = 0.05
    seed: int = 0


# ----------------------------------------------------------------------------- annotation


ANNOTATION_SCHEMA = "mosaicthinker.scene_annotation/1"


def _counts_agree(scene: dict[str, Any]) -> str | None:
    for c, n in (scene.get("object_counts") or {}).items():
        if n != len(scene["object_bbox"].get(c, [])):
            return f"object_counts.{c} is {n} but object_bbox.{c} holds {len(scene['object_bbox'].get(c, []))} boxes"
    for c, ids in (scene.get("instance_ids") or {}).items():
        if len(ids) != len(scene["object_bbox"].get(c, [])):
            return f"instance_ids.{c} names {len(ids)} instances but object_bbox.{c} holds " \
                   f"{len(scene['object_bbox'].get(c, []))} boxes"
    return None


# The scene annotation (`scene_annotate` writes it): one meta_info-style scene in the annotation frame and the
# rigid transform from the pose frame into it.
ANNOTATION_SPEC = S.Obj(fields={
    "schema": S.F(S.Str(enum=(ANNOTATION_SCHEMA,)), required=False),
    "scene": S.F(S.Str(), required=False), "licence": S.F(S.Str(), required=False),
    "frame": S.F(S.Str(), required=False), "n_frames": S.F(S.Int(lo=0, hi=10**9), required=False),
    "not_annotated": S.F(S.AnyValue(), required=False),
    "T_annot_from_pose": S.F(S.Arr(shape=(4, 4), lo=-1e6, hi=1e6, array_rules=(rigid_pose,))),
    "meta_info": S.F(S.MapOf(min_len=1, rules=(lambda v: next(((i, f"holds {len(m)} scenes; an annotation holds "
                                                                  f"exactly one") for i, m in enumerate(v)
                                                                if len(m) != 1), None),),
                             value=S.Obj(fields={
                                 "object_bbox": S.F(S.MapOf(value=S.ListOf(item=BOX))),
                                 "object_counts": S.F(S.MapOf(value=S.Int(lo=0, hi=10**6)), required=False),
                                 "instance_ids": S.F(S.MapOf(value=S.ListOf(item=S.Str())), required=False),
                                 "dataset": S.F(S.Str(), required=False)}, item_rules=(_counts_agree,)))),
})


def load_annotation(path: str | Path) -> tuple[str, dict[str, Any], np.ndarray]:
    """(scene name, meta_info-style scene, T [4, 4] pose frame -> annotation frame) from an annotation file,
    checked against ANNOTATION_SPEC (a malformed field is an InputError naming it)."""
    check_path(path, "a file", "the scene annotation")
    try:
        doc = strict_json_loads(Path(path).read_bytes(), str(path))
    except OSError as e:
        raise InputError(f"{path}: cannot read the scene annotation ({e.strerror or e})") from e
    S.check(doc, ANNOTATION_SPEC, where=str(path), error=InputError,
            fix="fix that field or make the annotation again with scene_annotate")
    (name, scene), = doc["meta_info"].items()
    return name, scene, np.asarray(doc["T_annot_from_pose"], float).reshape(4, 4)


def load_gt_boxes(path: str | Path) -> tuple[str, dict[str, Any], np.ndarray]:
    """(scene name, meta_info-style scene, T [4, 4] pose frame -> box frame) from a dataset's own boxes as shipped
    (`gt_boxes.json`, ScanNet's: axis-aligned boxes in the axis-aligned frame, `axis_align_matrix` taking a camera
    pose into it; the format is in ../shared/data/README.md). The boxes get identity axes. Decoded and checked
    before any work: a file that is not UTF-8 JSON, an `axis_align_matrix` that is not a finite rigid 4x4 matrix
    are an InputError; a box with a non-finite or non-positive part is left out of the ground truth and listed by
    name in `scene["not_scored"]` (every box so: an InputError, nothing is left to score)."""
    import json

    from mosaicthinker.runtime.frames.source import check_pose
    from mosaicthinker.runtime.infra.numbers import check_array

    text = read_text(path, "box")
    shape = "need `axis_align_matrix` and `object_bbox` with centroid / axesLengths per box"
    try:
        doc = json.loads(text)  # NaN tokens parse: a box holding one is listed below, not the whole file refused
        T = np.asarray(doc["axis_align_matrix"], float).reshape(4, 4)
        boxes = {str(c): list(lst) for c, lst in doc["object_bbox"].items()}
        for lst in boxes.values():
            for b in lst:
                np.asarray(b["centroid"], float).reshape(3), np.asarray(b["axesLengths"], float).reshape(3)
    except (ValueError, KeyError, TypeError, AttributeError, RecursionError) as e:
        raise InputError(f"{path}: not a box file as shipped ({shape}) ({e})"[:400]) from None
    check_pose(check_array(T, f"{path}: axis_align_matrix", "the matrix", lo=-1e7, hi=1e7,
                           fix="fix the matrix (ScanNet's is rigid: a rotation and a translation)"),
               f"{path}: axis_align_matrix")
    bbox: dict[str, list[dict[str, Any]]] = {}
    dropped: list[str] = []
    for c, lst in boxes.items():
        for k, b in enumerate(lst):
            ctr, size = np.asarray(b["centroid"], float), np.asarray(b["axesLengths"], float)
            why = ("centroid holds NaN or infinity" if not np.isfinite(ctr).all() or np.abs(ctr).max() > 1e7 else
                   "axesLengths hold NaN, infinity or a size <= 0" if not (np.isfinite(size).all() and
                                                                          (size > 0).all() and size.max() < 1e4)
                   else None)
            if why:
                dropped.append(f"{c} #{k} ({why})")
            else:
                bbox.setdefault(c, []).append({**b, "normalizedAxes": [1, 0, 0, 0, 1, 0, 0, 0, 1]})
    if dropped and not bbox:
        raise InputError(f"{path}: no box is usable ground truth ({'; '.join(dropped[:3])}"
                         f"{' ...' if len(dropped) > 3 else ''}); nothing is left to score: fix the boxes")
    scene = {"object_bbox": bbox, "dataset": "scannet", "not_scored": dropped}
    return str(doc.get("scene", Path(path).parent.name)), scene, T


def ground_truth_for(data: str | Path, annotations: str | Path | None) -> tuple[str, dict[str, Any], np.ndarray,
                                                                             str] | None:
    """The object ground truth of a room: the given annotation file (the project's, `scene_annotate`, or a
    dataset's `gt_boxes.json`), else the room's own `gt_boxes.json`, else None. Returns (name, scene, T_from_pose,
    what it is). The file is decoded and checked here, before any work."""
    if annotations is not None:
        p = Path(annotations)
        if p.name == "gt_boxes.json" or "axis_align_matrix" in read_text(p, "scene annotation")[:4096]:
            return (*load_gt_boxes(p), f"{p} (as shipped)")
        return (*load_annotation(p), f"{p} (annotation)")
    own = Path(data) / "gt_boxes.json"
    if own.is_file():
        return (*load_gt_boxes(own), f"{own} (as shipped)")
    return None


def scorable_categories(bundle: Any, categories: list[str]) -> tuple[dict[str, str], dict[str, str]]:
    """Which ground-truth categories a map from this bundle can be scored on: ({ground-truth category: the name
    the map uses for it}, {category: why not scored}). A category is scored when the bundle's closed-set detector
    has a label for it (its canonical name or a synonym: ScanNet's table / desk -> COCO "dining table", sofa ->
    "couch"); categories that reach the same labels are scored together under one name (the map holds one name
    per label set); the rest are listed, never counted."""
    from mosaicthinker.runtime.grounding import canonical_name
    from mosaicthinker.runtime.models.detector import closed_labels, map_names, one_name_per_label

    labels = closed_labels(bundle) or []
    canon = {c: canonical_name(c) or c for c in categories}
    mapping, missing = map_names(sorted(set(canon.values())), labels)
    groups: dict[tuple[int, ...], list[str]] = {}
    for n, ids in mapping.items():
        groups.setdefault(tuple(sorted(ids)), []).append(n)
    name_of = {}
    for ids, names in groups.items():
        keep = sorted(one_name_per_label({n: list(ids) for n in names}, labels, []))[0]  # the label's own name
        for n in names:
            name_of[n] = keep
    scored = {c: name_of[canon[c]] for c in categories if canon[c] in name_of}
    why = {c: ("the bundle's detector has no label for it" if canon[c] in missing or canon[c] not in name_of
               else "") for c in categories if c not in scored}
    return scored, why


def _box_samples(b: OrientedBox) -> np.ndarray:
    g = np.array([-0.4, 0.0, 0.4])
    u = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3) * b.axes_lengths
    return b.centroid + u @ b.axes


def visible_instances(source: Any, T_annot: np.ndarray, scene: dict[str, Any], conf: SceneEvalConfig
                      ) -> dict[str, list[bool]]:
    """Per category, per box: seen in some frame of `source` (its sample points project into the image in front of
    the sensor depth, within 10 cm or nearer). Ground-truth poses and depth: scoring only."""
    from mosaicthinker.runtime.geometry import project

    boxes = {c: [OrientedBox.from_meta(m) for m in lst] for c, lst in scene["object_bbox"].items()}
    seen = {c: [0] * len(lst) for c, lst in boxes.items()}
    for i in range(0, len(source), conf.visibility_stride):
        f = source[i]
        if f.pose_gt is None and i in set(source.untracked_frames()):
            continue  # a tracking failure: no ground truth there (listed in the result)
        if f.depth is None or f.pose_gt is None:
            raise InputError(f"{getattr(source, 'name', 'data')}: frame {i} lacks sensor depth or a ground-truth "
                             f"pose (eval scene needs both for visibility)")
        H, W = f.depth.shape
        for c, lst in boxes.items():
            for k, b in enumerate(lst):
                uv, z = project(_box_samples(b), f.K, T_annot @ f.pose_gt)
                ok = (z > 0.1) & (uv[:, 0] >= 0) & (uv[:, 0] < W) & (uv[:, 1] >= 0) & (uv[:, 1] < H)
                if not ok.any():
                    continue
                d = f.depth[uv[ok, 1].astype(int), uv[ok, 0].astype(int)]
                seen[c][k] = max(seen[c][k], int(np.sum((d > 0) & (d > z[ok] - 0.1))))
    return {c: [n >= conf.visible_min_points for n in v] for c, v in seen.items()}


# ----------------------------------------------------------------------------- matching


def iou_3d(a: OrientedBox, b: OrientedBox) -> float:
    """3D IoU of two gravity-aligned boxes (footprint polygon intersection x height overlap)."""
    import cv2

    from mosaicthinker.runtime.geometry import local_f32

    _, (fa, fb) = local_f32(a.corners()[:, :2], b.corners()[:, :2])
    ia, _ = cv2.intersectConvexConvex(cv2.convexHull(fa), cv2.convexHull(fb))
    za = (a.centroid[2] - a.axes_lengths[2] / 2, a.centroid[2] + a.axes_lengths[2] / 2)
    zb = (b.centroid[2] - b.axes_lengths[2] / 2, b.centroid[2] + b.axes_lengths[2] / 2)
    inter = float(ia) * max(0.0, min(za[1], zb[1]) - max(za[0], zb[0]))
    va, vb = float(np.prod(a.axes_lengths)), float(np.prod(b.axes_lengths))
    return inter / (va + vb - inter) if va + vb - inter > 1e-12 else 0.0


def match_instances(built: list[OrientedBox], truth: list[OrientedBox], conf: SceneEvalConfig
                    ) -> list[tuple[int, int]]:
    """One-to-one pairs (built index, true index) with centres within `match_centre_m` or IoU >= `match_iou`,
    chosen by minimum total centre distance (Hungarian)."""
    from scipy.optimize import linear_sum_assignment

    if not built or not truth:
        return []
    D = np.array([[np.linalg.norm(p.centroid - t.centroid) for t in truth] for p in built])
    ok = np.array([[D[i, j] <= conf.match_centre_m or iou_3d(p, t) >= conf.match_iou
                    for j, t in enumerate(truth)] for i, p in enumerate(built)])
    r, c = linear_sum_assignment(np.where(ok, D, 1e6))
    return [(int(i), int(j)) for i, j in zip(r, c) if ok[i, j]]


def register_cameras(est: np.ndarray, gt: np.ndarray, with_scale: bool = False) -> np.ndarray:
    """S [4, 4] with gt ≈ S est for camera poses est, gt [N, 4, 4] (camera-to-world): the rotation that best
    agrees with every camera's orientation (chordal mean of R_gt R_est^T), then scale (Sim(3)) and translation
    from the camera centres (least squares). The camera orientations are used besides the centres because a
    short, nearly straight hand-held track leaves the rotation about its own axis undetermined by the centres
    alone (Umeyama on centres then swings the map about that axis); object positions are never used."""
    M = sum(g[:3, :3] @ e[:3, :3].T / np.linalg.norm(e[:3, 0]) for e, g in zip(est, gt))
    U, _, Vt = np.linalg.svd(M)
    R = U @ np.diag([1, 1, np.sign(np.linalg.det(U @ Vt))]) @ Vt
    ce, cg = est[:, :3, 3], gt[:, :3, 3]
    me, mg = ce.mean(0), cg.mean(0)
    de = (ce - me) @ R.T
    s = float(np.sum(de * (cg - mg)) / max(np.sum(de * de), 1e-12)) if with_scale and len(est) > 1 else 1.0
    S = np.eye(4)
    S[:3, :3] = s * R
    S[:3, 3] = mg - s * R @ me
    return S


def register_box(b: OrientedBox, S: np.ndarray) -> OrientedBox:
    """Box through a similarity S [4, 4] (rotation*scale + translation)."""
    s = float(np.cbrt(abs(np.linalg.det(S[:3, :3]))))
    R = S[:3, :3] / s
    return OrientedBox(transform(S, b.centroid[None])[0], np.asarray(b.axes_lengths) * s, (R @ b.axes.T).T)


def score_instances(built: dict[str, list[OrientedBox]], truth: dict[str, list[OrientedBox]],
                    conf: SceneEvalConfig) -> dict[str, Any]:
    """Per annotated category: counts, TP, precision, recall, count error, median centre and longest-side errors;
    plus the pooled precision/recall and the built categories that are not annotated."""
    per: dict[str, Any] = {}
    tp_all = nb_all = nt_all = 0
    for cat, tb in truth.items():
        bb = built.get(cat, [])
        pairs = match_instances(bb, tb, conf)
        ce = [float(np.linalg.norm(bb[i].centroid - tb[j].centroid)) for i, j in pairs]
        le = [float(max(bb[i].axes_lengths) - max(tb[j].axes_lengths)) for i, j in pairs]
        per[cat] = {"true": len(tb), "built": len(bb), "tp": len(pairs),
                    "precision": len(pairs) / len(bb) if bb else None, "recall": len(pairs) / len(tb) if tb else None,
                    "count_error": len(bb) - len(tb), "median_centre_err_m": float(np.median(ce)) if ce else None,
                    "median_longest_side_err_m": float(np.median(le)) if le else None, "pairs": pairs}
        tp_all, nb_all, nt_all = tp_all + len(pairs), nb_all + len(bb), nt_all + len(tb)
    all_ce = [e for cat in per for e in _centre_errs(built.get(cat, []), truth[cat], per[cat]["pairs"])]
    return {"per_category": per, "precision": tp_all / nb_all if nb_all else None,
            "recall": tp_all / nt_all if nt_all else None,
            "median_centre_err_m": float(np.median(all_ce)) if all_ce else None,
            "not_annotated": {c: len(v) for c, v in built.items() if c not in truth}}


def _centre_errs(bb: list[OrientedBox], tb: list[OrientedBox], pairs: list[tuple[int, int]]) -> list[float]:
    return [float(np.linalg.norm(bb[i].centroid - tb[j].centroid)) for i, j in pairs]


# ----------------------------------------------------------------------------- floor, answers


def floor_metrics(build: Any, source: Any, T_annot: np.ndarray, S: np.ndarray, conf: SceneEvalConfig
                  ) -> dict[str, Any]:
    """Up-axis error (deg, median over aligned key cameras: the map's up seen from the camera vs the true up seen
    from it; needs no registration), the map floor's height in the annotation frame (through S), and every
    object's bottom vs the map's floor."""
    z = np.array([0.0, 0.0, 1.0])
    errs, root = [], build.map.meta.get("root")
    err_root = None
    for i in [k for k in build.keyframes if k in build.poses_world and source[k].pose_gt is not None]:
        T = build.poses_world[i]
        R = T[:3, :3] / np.linalg.norm(T[:3, 0])
        Rg = (T_annot @ source[i].pose_gt)[:3, :3]
        c = np.clip((R.T @ z) @ (Rg.T @ z), -1, 1)
        errs.append(float(np.degrees(np.arccos(c))))
        if i == root:  # the alignment's root camera has no pose error of its own: the floor fit's error alone
            err_root = errs[-1]
    smap = build.map
    floor_z = float(smap.room.floor_z) if smap.room is not None else 0.0
    cams = np.array([T[:3, 3] for T in build.poses_world.values()])
    on_floor = np.c_[cams[:, :2], np.full(len(cams), floor_z)]
    bottoms = [{"id": o.id, "name": o.name,
                "bottom_m": round(float(o.box.centroid[2] - o.box.axes_lengths[2] / 2 - floor_z), 3)}
               for o in smap.instances]
    return {"up_axis_err_deg": float(np.median(errs)) if errs else None,
            "up_axis_err_max_deg": float(np.max(errs)) if errs else None, "up_axis_err_root_deg": err_root,
            "map_floor_z": floor_z,
            "floor_height_in_annotation_m": float(np.median(transform(S, on_floor)[:, 2])) if len(cams) else None,
            "bottoms": bottoms,
            "below_floor": [b for b in bottoms if b["bottom_m"] < -conf.floor_below_tol_m]}


def score_answers(smap: Any, scene_name: str, meta_entry: dict[str, Any], conf: SceneEvalConfig
                  ) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """Questions from the annotation (box-only ground truth), answered from the map, scored per type."""
    from mosaicthinker.runtime.answer import MapReasoner
    from mosaicthinker.host.evaluation.box_truth import generate_questions
    from mosaicthinker.host.evaluation.vsibench import NUMERIC_QTYPES, score_answer

    qs, removed = generate_questions(meta_entry, scene_name, rng=conf.seed, per_type=conf.per_type)
    reasoner = MapReasoner(smap)
    recs = []
    for q in qs:
        a = reasoner.answer(q["question"], q.get("options"))
        recs.append({"id": q["id"], "question_type": q["question_type"], "question": q["question"],
                     "options": q.get("options"), "ground_truth": q["ground_truth"], "pred": a.text,
                     "status": a.status, "score": score_answer(q["question_type"], a.text, q["ground_truth"])
                     if a.ok else 0.0, "evidence": a.explanation, "support": a.evidence, "missing": a.missing})
    per = {}
    for qt in sorted({r["question_type"] for r in recs}):
        rs = [r for r in recs if r["question_type"] == qt]
        per[qt] = {"n": len(rs), "metric": "MRA" if qt in NUMERIC_QTYPES else "accuracy",
                   "score": float(np.mean([r["score"] for r in rs])) if len(rs) >= conf.min_per_type else None,
                   "not_scored": None if len(rs) >= conf.min_per_type else f"fewer than {conf.min_per_type}",
                   **why_wrong(rs)}
    mc = [p["score"] for q, p in per.items() if p["score"] is not None and p["metric"] == "accuracy"]
    num = [p["score"] for q, p in per.items() if p["score"] is not None and p["metric"] == "MRA"]
    # a small room yields fewer than `min_per_type` questions of some types: also pooled over all of them
    pool_mc = [r["score"] for r in recs if r["question_type"] not in NUMERIC_QTYPES]
    pool_num = [r["score"] for r in recs if r["question_type"] in NUMERIC_QTYPES]
    return {"per_type": per, "multiple_choice": float(np.mean(mc)) if mc else None,
            "numeric_mra": float(np.mean(num)) if num else None,
            "pooled": {"multiple_choice": float(np.mean(pool_mc)) if pool_mc else None, "n_mc": len(pool_mc),
                       "numeric_mra": float(np.mean(pool_num)) if pool_num else None, "n_numeric": len(pool_num),
                       "mc_why": why_wrong([r for r in recs if r["question_type"] not in NUMERIC_QTYPES]),
                       "numeric_why": why_wrong([r for r in recs if r["question_type"] in NUMERIC_QTYPES])},
            "generator_removed": removed}, recs


def why_wrong(recs: list[dict[str, Any]]) -> dict[str, Any]:
    """Where the score of these questions went (a breakdown, the score itself unchanged): how many were not
    answered because a category they name is not in the map (`not_in_map`, by name), how many were answered,
    and the mean score of the answered ones (`answered_score`: what the map got right where it had the objects)."""
    names: dict[str, int] = {}
    for r in recs:
        for n in r.get("missing") or []:
            names[n] = names.get(n, 0) + 1
    ok = [r["score"] for r in recs if r["status"] == "ok"]
    return {"not_in_map": sum(r["status"] == "not_found" for r in recs), "missing_names": names,
            "answered": len(ok), "answered_score": float(np.mean(ok)) if ok else None}


def visible_meta(scene: dict[str, Any], visible: dict[str, list[bool]]) -> dict[str, Any]:
    """The annotation restricted to the visible boxes (meta_info-style entry)."""
    bbox = {c: [m for m, v in zip(lst, visible[c]) if v] for c, lst in scene["object_bbox"].items()}
    bbox = {c: lst for c, lst in bbox.items() if lst}
    return {"object_bbox": bbox, "object_counts": {c: len(v) for c, v in bbox.items()},
            "dataset": scene.get("dataset", "unknown")}


# ----------------------------------------------------------------------------- the command


def map_names_for(bundle: Any, annotated: list[str]) -> list[str]:
    """Every vocabulary name the bundle's closed-set detector can detect, one per set of detector labels (the
    annotated name where it is one of them: `detectable.detectable_names`), plus the annotated categories."""
    from mosaicthinker.runtime.grounding import canonical_name
    from mosaicthinker.runtime.detectable import detectable_names

    want = [canonical_name(c) or c for c in annotated]
    return sorted(set(detectable_names(bundle, want)) | set(want))


def evaluate_scene(data: str | Path, annotations: str | Path | None, bundle: str | Path, depth: str = "sensor",
                   matcher: str = "sift", keyframes: int = 16, ask_n: int = 0, gravity: str = "floor",
                   keyframe_method: str = "iterative",
                   conf: SceneEvalConfig | None = None, out: str | Path | None = None,
                   video: str | Path | None = None, pipeline_conf: dict[str, Any] | None = None) -> dict[str, Any]:
    """Build, register and score (see the module doc). Returns the JSON result. annotations: the project's
    annotation or a dataset's boxes as shipped; None: the room's own `gt_boxes.json` when it has one, else no
    object scoring (alignment, registration and time only). video: the pipeline reads this video of `data`'s
    frames (the same frames, in order: `video_of_frames`) instead of the folder; the ground truth (poses,
    visibility) still comes from `data`. A video has no sensor depth: use depth="model". pipeline_conf: extra
    `PipelineConfig` keys (e.g. {"backbone": {"odometry": False}} for the previous alignment)."""
    from mosaicthinker.runtime import pipeline
    from mosaicthinker.runtime.frames import open_source
    from mosaicthinker.runtime.grounding import canonical_name
    from mosaicthinker.runtime.infra.trace import Trace, peak_rss_mb, reset_peak_rss
    from mosaicthinker.host.evaluation.pose import align_trajectories

    conf = conf or SceneEvalConfig()
    if out:  # every output place and input file checked before the work (minutes of it)
        from mosaicthinker.runtime.infra.outputs import check_out_dir

        check_out_dir(Path(out))
    gt = ground_truth_for(data, annotations)
    src = open_source(data)
    name, scene, T_annot, gt_what = gt if gt is not None else (Path(data).name, {"object_bbox": {}},
                                                               _z_up(src), "none (camera poses only)")
    untracked = src.untracked_frames()
    reset_peak_rss()
    t0 = time.perf_counter()
    run_src = src if video is None else open_source(video, K=src.K)
    if len(run_src) != len(src):
        raise InputError(f"{video}: {len(run_src)} frames, but {data} has {len(src)}: the video must hold the "
                         f"folder's frames in order (make it with host.evaluation.scene.video_of_frames)")
    trace = Trace()
    extra = dict(pipeline_conf or {})
    pconf = {"depth": depth, "matcher": matcher, "gravity": gravity, **extra,
             "keyframe": {"keyframe_method": keyframe_method, **extra.get("keyframe", {})}}
    perception = pipeline.perception_from_bundle(str(bundle), pconf, trace)
    scored, not_scored = scorable_categories(bundle, list(scene["object_bbox"]))
    names = map_names_for(bundle, sorted(set(scored.values())))
    build = pipeline.build_map(run_src, names, [], perception, pconf, trace, keyframes)
    wall = time.perf_counter() - t0
    peak = peak_rss_mb()
    idx = [i for i in build.keyframes if i in build.poses_world and src[i].pose_gt is not None]
    reg: dict[str, Any] = {"method": "Sim(3)" if perception.depth_relative else "rigid", "n_cameras": len(idx),
                           "ate_rmse_m": None, "ate_centres_only_umeyama_m": None, "scale": None, "S": None,
                           "fit": "estimated key-frame camera poses -> ground truth (rotation from the camera "
                                  "orientations, translation/scale from the centres; never object positions)"}
    S = np.eye(4)
    if len(idx) >= 2 and src.has_pose:
        est_T = np.stack([build.poses_world[i] for i in idx])
        gt_T = np.stack([T_annot @ src[i].pose_gt for i in idx])
        S = register_cameras(est_T, gt_T, with_scale=perception.depth_relative)
        S_c = align_trajectories(est_T[:, :3, 3], gt_T[:, :3, 3], with_scale=perception.depth_relative)
        reg.update(ate_rmse_m=float(np.sqrt(np.mean(np.sum((transform(S, est_T[:, :3, 3]) - gt_T[:, :3, 3]) ** 2, 1)))),
                   ate_centres_only_umeyama_m=float(np.sqrt(np.mean(np.sum(
                       (transform(S_c, est_T[:, :3, 3]) - gt_T[:, :3, 3]) ** 2, 1)))),
                   scale=float(np.cbrt(np.linalg.det(S[:3, :3]))), S=S.tolist())
    al = build.info.get("alignment", {})
    res = {"schema": SCHEMA, "data": str(data), "video": None if video is None else str(video),
           "annotations": None if annotations is None else str(annotations), "ground_truth": gt_what,
           "bundle": str(bundle), "depth": depth, "matcher": matcher, "keyframes": keyframes, "gravity": gravity,
           "keyframe_method": keyframe_method, "depth_relative": perception.depth_relative,
           "pipeline_conf": pipeline_conf or {}, "perception": trace.decisions.get("perception"),
           "registration": reg, "keyframes_chosen": build.keyframes, "unaligned": build.unaligned,
           "aligned_by_path": _count(al.get("fates", {}).values()), "fates": al.get("fates", {}),
           "untracked_frames": untracked, "frames": len(src),
           "dedup": trace.decisions.get("dedup"), "wall_s": wall, "peak_rss_mb": peak,
           "stages": {k: {"seconds": round(v.seconds, 3), "calls": v.calls} for k, v in trace.stages.items()},
           "warnings": [e["message"] for e in trace.events if e["kind"] in ("fallback", "degraded", "not_in_map")],
           "alignment_events": [e["message"] for e in trace.events if e.get("stage") == "alignment"],
           "ground_truth_not_scored": list(scene.get("not_scored", []))}
    res["warnings"] += [f"ground truth {d}: left out of the scoring" for d in scene.get("not_scored", [])]
    res["warnings"] += [n for n in src.notes if "pose files hold non-finite" in n]
    vmeta, recs = {"object_bbox": {}}, []
    if gt is not None:
        visible = visible_instances(src, T_annot, scene, conf)
        vmeta = visible_meta(scene, visible)
        truth: dict[str, list[OrientedBox]] = {}
        for c, lst in vmeta["object_bbox"].items():
            if c in scored:
                truth.setdefault(scored[c], []).extend(OrientedBox.from_meta(m) for m in lst)
        built: dict[str, list[OrientedBox]] = {}
        for o in build.map.instances:
            built.setdefault(o.name, []).append(register_box(o.box, S))
        inst = score_instances(built, truth, conf)
        inst["scored_as"] = scored
        inst["not_scored"] = not_scored
        answers, recs = score_answers(build.map, name, visible_meta(
            {"object_bbox": {scored[c]: v for c, v in scene["object_bbox"].items() if c in scored}},
            {scored[c]: v for c, v in visible.items() if c in scored}), conf)
        res.update({"visible": {c: int(sum(v)) for c, v in visible.items()},
                    "annotated": {c: len(v) for c, v in scene["object_bbox"].items()},
                    "instances": inst, "floor": floor_metrics(build, src, T_annot, S, conf) if idx else None,
                    "answers": answers, "questions": recs})
    if ask_n and recs:
        res["ask"] = ask_questions(run_src, recs, ask_n, perception, pconf, keyframes)
    if out:
        gt_poses = [src[i].pose_gt for i in range(len(src))] if src.has_pose else None
        _write_out(Path(out), res, build, S, vmeta, trace, T_annot, gt_poses)
    return res


def _z_up(src: Any) -> np.ndarray:
    """A rotation [4, 4] of the source's pose world that puts its vertical axis on z (`frames.world_down`: a
    HoloLens world is y up), for registration and pictures of a room without object ground truth."""
    from mosaicthinker.runtime.frames import world_down
    from mosaicthinker.host.evaluation.scene_annotate import up_transform

    got = world_down(src) if src.has_pose else None
    if got is None:
        return np.eye(4)
    down = got[0]
    x = np.eye(3)[int(np.argmin(np.abs(down)))]
    return up_transform(down, x)


def _count(values: Any) -> dict[str, int]:
    out: dict[str, int] = {}
    for v in values:
        out[v] = out.get(v, 0) + 1
    return out


def video_of_frames(data: str | Path, out: str | Path, fps: float | None = None) -> Path:
    """An mp4 (MPEG-4 part 2) of a frame folder's colour frames in order, at the folder's frame rate (from its
    timestamps): the input a user with a phone recording gives, for `evaluate_scene(video=...)`."""
    import cv2

    from mosaicthinker.runtime.frames import open_source

    src = open_source(data)
    if fps is None:
        fps = 1.0 / float(np.median(np.diff(src.timestamps))) if len(src) > 1 else 15.0
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    H, W = src[0].rgb.shape[:2]
    w = cv2.VideoWriter(str(out), cv2.VideoWriter_fourcc(*"mp4v"), float(fps), (W, H))
    try:
        for i in range(len(src)):
            w.write(cv2.cvtColor(src.colour(i).rgb, cv2.COLOR_RGB2BGR))
    finally:
        w.release()
    return out


def ask_questions(src: Any, recs: list[dict[str, Any]], n: int, perception: Any, pconf: dict[str, Any],
                  keyframes: int) -> dict[str, Any]:
    """`pipeline.ask` on the video (per-question key frames) for n questions, spread over the types."""
    from mosaicthinker.runtime import pipeline
    from mosaicthinker.host.evaluation.vsibench import score_answer

    order = sorted(range(len(recs)), key=lambda k: (recs[k]["id"] % max(1, len(recs) // n), k))[:n]
    out = []
    for k in sorted(order):
        q = recs[k]
        t0 = time.perf_counter()
        r = pipeline.ask(src, q["question"], q.get("options"),
                         pipeline.AskRequest(answerer="map", keyframes=keyframes, conf=pconf), perception=perception)
        a = r.answer
        out.append({"id": q["id"], "question_type": q["question_type"], "pred": a.text, "status": a.status,
                    "ground_truth": q["ground_truth"], "evidence": a.explanation, "support": a.evidence,
                    "seconds": time.perf_counter() - t0,
                    "score": score_answer(q["question_type"], a.text, q["ground_truth"]) if a.ok else 0.0})
    return {"n": len(out), "score": float(np.mean([r["score"] for r in out])) if out else None, "records": out}


def _write_out(out: Path, res: dict[str, Any], build: Any, S: np.ndarray, vmeta: dict[str, Any], trace: Any,
               T_annot: np.ndarray | None = None, gt_poses: list[np.ndarray | None] | None = None) -> None:
    from mosaicthinker.host.evaluation.scene_annotate import render_topdown

    out.mkdir(parents=True, exist_ok=True)
    clouds = [transform(S, c) for c in build.clouds if len(c)]
    pts = np.concatenate(clouds) if clouds else np.zeros((0, 3))
    extra: dict[str, list[dict]] = {}
    for o in build.map.instances:
        extra.setdefault(o.name, []).append(register_box(o.box, S).to_meta())
    T_annot = np.eye(4) if T_annot is None else T_annot
    gt_track = np.array([(T_annot @ f)[:3, 3] for f in gt_poses if f is not None]) if gt_poses else np.zeros((0, 3))
    est = np.array([transform(S, T[:3, 3][None])[0] for i, T in sorted(build.poses_world.items())
                    if i in build.keyframes])
    shift = np.zeros(3)
    if not vmeta["object_bbox"] and len(pts):  # no annotation frame: the floor (lowest points) at z = 0
        shift[2] = -float(np.percentile(pts[:, 2], 2))
    render_topdown(pts + shift, vmeta["object_bbox"], out / "map_over_annotation.png",
                   f"built map (yellow boxes, dots: key-frame cameras, {res['registration']['method']} camera "
                   f"registration) over the ground truth (white: boxes, grey line: camera path)",
                   {k: [{**m, "centroid": list(np.asarray(m["centroid"]) + shift)} for m in v] for k, v in extra.items()},
                   tracks=[(gt_track + shift, (160, 160, 160), True), (est + shift, (0, 255, 255), False)])
    # the picture's geometry alone (boxes and camera paths, no dataset points), for redrawing it small elsewhere
    res["topdown"] = {"gt_track": np.round(gt_track[::3] + shift, 3).tolist(),
                      "keyframe_cameras": np.round(est + shift, 3).tolist() if len(est) else [],
                      "truth_boxes": vmeta["object_bbox"],
                      "built_boxes": {k: [{**m, "centroid": list(np.asarray(m["centroid"]) + shift)} for m in v]
                                      for k, v in extra.items()}}
    build.map.save(out / "map.json")
    (out / "scene_eval.json").write_text(jsonio.dumps(res, indent=1, default=float))
    trace.save(out / "trace.json")


COMMON_FLAGS = ("bundle", "out")  # the common flags this command reads


def add_arguments(p: argparse.ArgumentParser) -> None:
    from mosaicthinker.runtime.cli import add_stage_flags
    from mosaicthinker.runtime.commands.flags import add_gravity, add_keyframes

    p.add_argument("--data", required=True, metavar="DIR",
                   help="RGB-D frame folder with ground-truth poses (7-Scenes / ScanNet layout)")
    p.add_argument("--conf", default=None, metavar="JSON", help="extra pipeline config keys as JSON (e.g. "
                   "'{\"backbone\": {\"odometry\": false}}' for the alignment before the odometry backbone)")
    p.add_argument("--annotations", default=None, help="object ground truth: the project's annotation "
                   "(scene_annotate) or a dataset's boxes as shipped (gt_boxes.json); default: the room's own "
                   "gt_boxes.json when it has one, else no object scoring")
    p.add_argument("--video", default=None, metavar="V", help="run the pipeline on this video of the --data "
                   "frames (same frames, in order; no sensor depth: --depth model); ground truth from --data")
    add_keyframes(p)
    p.add_argument("--ask", type=int, default=0, metavar="N", help="also ask N of the questions on the video")
    p.add_argument("--keyframe-method", choices=["iterative", "uniform", "exhaustive"], default="iterative")
    add_gravity(p, "floor")  # the real-room targets are measured without ground-truth gravity
    add_stage_flags(p, depth=True, matcher=True)


def run(args: argparse.Namespace) -> dict[str, Any]:
    if not args.bundle:
        raise InputError("mosaic eval scene needs --bundle (the real models: `mosaic export shared-models`)")
    from mosaicthinker.runtime.commands.flags import pipeline_keyframes

    k = args.keyframes if args.keyframes is not None else pipeline_keyframes()
    extra = None
    if args.conf:
        try:
            extra = json.loads(args.conf)
        except ValueError as e:
            raise InputError(f"--conf: not JSON ({e})") from None
        if not isinstance(extra, dict):
            raise InputError("--conf: must be a JSON object of pipeline config keys")
    return evaluate_scene(args.data, args.annotations, args.bundle, args.depth, args.matcher, k,
                          args.ask, args.gravity, args.keyframe_method, out=args.out, video=args.video,
                          pipeline_conf=extra)


def render(r: dict[str, Any]) -> str:
    reg, ins, fl, an = r["registration"], r["instances"], r["floor"], r["answers"]
    f = (lambda x, d=2: "-" if x is None else f"{x:.{d}f}")
    lines = [f"eval scene: {r['data']}  depth {r['depth']}  matcher {r['matcher']}  K={r['keyframes']}",
             f"registration: {reg['method']} fit of {reg['n_cameras']} key-frame camera poses to ground truth "
             f"(ATE {f(reg['ate_rmse_m'], 3)} m, scale {f(reg['scale'], 3)}); unaligned key frames: {len(r['unaligned'])}",
             f"instances: precision {f(ins['precision'])} recall {f(ins['recall'])} "
             f"median centre error {f(ins['median_centre_err_m'])} m",
             f"  {'category':14s} true built tp  P     R     count  centre_m  longest_m"]
    for c, p in ins["per_category"].items():
        lines.append(f"  {c:14s} {p['true']:4d} {p['built']:5d} {p['tp']:3d}  {f(p['precision'])}  {f(p['recall'])}"
                     f"  {p['count_error']:+d}     {f(p['median_centre_err_m'])}      {f(p['median_longest_side_err_m'])}")
    if ins["not_annotated"]:
        lines.append(f"  built, not annotated (not counted): {ins['not_annotated']}")
    lines.append(f"floor: up-axis error {f(fl['up_axis_err_deg'], 1)} deg (max {f(fl['up_axis_err_max_deg'], 1)}, "
                 f"root camera {f(fl.get('up_axis_err_root_deg'), 1)}), "
                 f"map floor at {f(fl['floor_height_in_annotation_m'], 3)} m in the annotation frame, "
                 f"{len(fl['below_floor'])} object(s) more than 5 cm below it")
    po = an["pooled"]
    lines.append(f"answers: multiple choice {f(an['multiple_choice'])}, numeric MRA {f(an['numeric_mra'])} (types with "
                 f">= 10 questions); pooled: multiple choice {f(po['multiple_choice'])} (n={po['n_mc']}), numeric MRA "
                 f"{f(po['numeric_mra'])} (n={po['n_numeric']})")
    for qt, p in an["per_type"].items():
        lines.append(f"  {qt:28s} n={p['n']:3d}  {p['metric']:8s} {f(p['score'])}{'  ' + p['not_scored'] if p['not_scored'] else ''}"
                     f"  (answered {p['answered']}, score {f(p['answered_score'])}; not in the map: {p['not_in_map']})")
    for k in ("mc_why", "numeric_why"):
        w = po[k]
        if w["missing_names"]:
            lines.append(f"  {'multiple choice' if k == 'mc_why' else 'numeric'}: {w['not_in_map']} question(s) name a "
                         f"category not in the map ({', '.join(f'{n} {c}' for n, c in sorted(w['missing_names'].items()))})")
    if r.get("ask"):
        lines.append(f"ask on the video: {r['ask']['n']} questions, score {f(r['ask']['score'])}")
    st = ", ".join(f"{k} {v['seconds']:.1f}s" for k, v in sorted(r["stages"].items(), key=lambda kv: -kv[1]["seconds"])[:8])
    lines.append(f"time: wall {r['wall_s']:.1f} s, peak RSS {r['peak_rss_mb']:.0f} MB; stages: {st}")
    for w in r["warnings"]:
        lines.append(f"  warning: {w}")
    return "\n".join(lines)
