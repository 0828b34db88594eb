"""One table over every real room: alignment, objects, answers, time and memory per room, sensor and model depth.

    python benchmarks/real_rooms.py [--bundle B] [--rooms DIR ...] [--keyframes 16,32] [--depths sensor,model]
                                    [--before] [--out out/real_rooms] [--results FILE] [--only-default-rooms]

Rooms: every folder of ../shared/data with frames (`open_source` reads it) - with poses they are scored, without
(an RGB-only walk such as hotel-lounge-rgb) only aligned and round-tripped - plus every `--rooms DIR`. Object
ground truth: the project's annotation for the 7-Scenes kitchen (benchmarks/data/redkitchen_annotation.json), a
room's own `gt_boxes.json` (ScanNet, as shipped), else none. Per room, depth mode (sensor where the room has
depth; model: the bundle's depth model on the colour frames) and K, each in its own process:

- `mosaic eval scene` (the pipeline `mosaic ask` / `mosaic map` run, every category the bundle's detector names,
  matcher = the bundle's matcher): frames, dedup's kept frames, key frames aligned by path (box-matched tree,
  odometry backbone, place revisit, ...), the key-frame ATE after registration, instance precision / recall /
  centre error per category (where there is object ground truth), answers per question type, seconds per stage,
  peak RSS, and a top-down picture over the ground truth;
- `mosaic eval pose --sampling uniform` (same K, same depth, the path ask uses): the ATE target's figure;
- `mosaic ask MAP` on the map eval scene wrote: the map loads and answers (the round trip);
- once per RGB-D room: `mosaic ask ROOM "How many chairs are in the room?"` at K = 16, sensor depth: its wall
  time, and its ratio to the kitchen's in the same run (the machine's load varies; the lead re-measures idle).

`--before` gives the same rows with the alignment and thinning of the landed code instead (eval scene `--conf`
with the backbone and the overlap sampling off; eval pose `--path frames`), into real_rooms_before.json. The JSON records every command, the load
average before each run and the date; `--results` defaults to benchmarks/results/real_rooms.json, and a
markdown table goes beside it (real_rooms.md). Small top-down pictures (boxes and camera paths only, no dataset
pixels or points) go to docs/img/real-rooms-<room>.png with `--pictures`.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("MOSAIC_SHARED", REPO.parent / "shared"))
ANNOTATIONS = {"7scenes-redkitchen": REPO / "benchmarks" / "data" / "redkitchen_annotation.json"}
RESULTS = REPO / "benchmarks" / "results" / "real_rooms.json"
QUESTION = "How many chairs are in the room?"
BEFORE = {"backbone": {"odometry": False}, "dedup": {"min_overlap": 0.0}}
# alternatives measured against the default (`--variants`): eval pose K = 32 uniform, the bundle's matcher
VARIANTS = {"default": {},
            "walks only between parts": {"backbone": {"walk_all": False}},
            "walk every gap, jumps <= 2": {"backbone": {"max_jump": 2, "first_jump": 2}},
            "ORB walks": {"backbone": {"walk_matcher": "orb"}},
            "no pose graph": {"backbone": {"graph": False}},
            "ICP on the walks' edges": {"backbone": {"edge_icp": True}},
            "closures: 48, 2 hops apart": {"backbone": {"closures": 48, "closure_hops": 2}},
            "no backbone (the landed path)": {"backbone": {"odometry": False}, "dedup": {"min_overlap": 0.0}}}
TARGETS = {"aligned_sensor": 0.9, "aligned_model": 0.7,
           "ate_k32_m": {"7scenes-redkitchen": 0.03, "scannet-scene0000_00": 0.05, "hololens-lounge": 0.05},
           "ask_k16_s": 8.0}


def discover(extra: list[Path], only_default: bool = False) -> list[Path]:
    """The shared rooms (folders `open_source` reads, not the VSI-Bench set) and the given ones."""
    from mosaicthinker.runtime.frames import open_source

    rooms = []
    for d in sorted((SHARED / "data").iterdir()) if (SHARED / "data").is_dir() else []:
        if not d.is_dir() or d.name == "vsibench":
            continue
        try:
            open_source(d)
        except Exception:  # noqa: BLE001 - not a frame folder
            continue
        rooms.append(d)
    return rooms + ([] if only_default else [Path(p) for p in extra])


def _mosaic(args: list[str], timeout: float = 3600) -> tuple[dict[str, Any] | None, dict[str, Any]]:
    """One `mosaic` command in a fresh process: (its JSON or None, {cmd, rc, wall_s, load, stderr tail})."""
    cmd = [sys.executable, "-m", "mosaicthinker.runtime.cli", *args]
    load = os.getloadavg()[0]
    t0 = time.perf_counter()
    p = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    meta = {"cmd": "mosaic " + " ".join(args), "rc": p.returncode, "process_wall_s": round(time.perf_counter() - t0, 2),
            "load_avg_1min_before": round(load, 2)}
    if p.returncode != 0:
        meta["stderr"] = p.stderr[-1500:]
    try:
        return json.loads(p.stdout), meta
    except ValueError:
        meta["stdout"] = p.stdout[-500:]
        return None, meta


def scene_row(room: Path, bundle: Path, depth: str, k: int, out: Path, conf: dict | None) -> dict[str, Any]:
    """`mosaic eval scene` + `mosaic ask MAP` on the map it wrote: the room's row for one depth mode and K."""
    args = ["eval", "scene", "--data", str(room), "--bundle", str(bundle), "--depth", depth, "--matcher", "model",
            "--keyframes", str(k), "--json", "--out", str(out)]
    if room.name in ANNOTATIONS:
        args += ["--annotations", str(ANNOTATIONS[room.name])]
    if conf:
        args += ["--conf", json.dumps(conf)]
    r, meta = _mosaic(args)
    row: dict[str, Any] = {"eval_scene": meta}
    if r is None:
        return row
    inst, an = r.get("instances"), r.get("answers")
    n_keys = len(r["keyframes_chosen"])
    row.update({
        "frames": r["frames"], "untracked_frames": r["untracked_frames"],
        "dedup": r.get("dedup"), "keyframes": n_keys, "aligned": n_keys - len(r["unaligned"]),
        "aligned_share": (n_keys - len(r["unaligned"])) / max(1, n_keys), "aligned_by_path": r["aligned_by_path"],
        "unaligned": r["unaligned"], "keyframe_ate_m": r["registration"]["ate_rmse_m"],
        "alignment_events": r.get("alignment_events"),
        "wall_s": round(r["wall_s"], 2), "peak_rss_mb": round(r["peak_rss_mb"]),
        "stages_s": {s: v["seconds"] for s, v in sorted(r["stages"].items(), key=lambda kv: -kv[1]["seconds"])},
        "ground_truth": r.get("ground_truth")})
    if inst is not None:
        row["objects"] = {"precision": inst["precision"], "recall": inst["recall"],
                          "median_centre_err_m": inst["median_centre_err_m"],
                          "per_category": {c: {x: p[x] for x in ("true", "built", "tp", "precision", "recall",
                                                                 "median_centre_err_m", "count_error")}
                                           for c, p in inst["per_category"].items()},
                          "not_scored": inst.get("not_scored"), "built_not_annotated": inst.get("not_annotated")}
    if an is not None:
        row["answers"] = {q: {x: p.get(x) for x in ("n", "metric", "score", "answered", "answered_score",
                                                    "not_in_map")} for q, p in an["per_type"].items()}
        row["answers_pooled"] = {x: an["pooled"][x] for x in ("multiple_choice", "n_mc", "numeric_mra", "n_numeric")}
    row["stages"] = stage_accounting(out / "trace.json", r)
    got, ask_meta = _mosaic(["ask", str(out / "map.json"), QUESTION, "--json"], timeout=600)
    row["map_loads"] = {"ok": ask_meta["rc"] == 0 and got is not None, "answer": None if got is None else got.get("answer"),
                        **ask_meta}
    return row


def stage_accounting(trace_path: Path, r: dict[str, Any]) -> dict[str, Any] | None:
    """What was lost where, from the run's trace: key frames chosen / aligned, detections lifted, placed by the
    triangulated points inside them (RGB only) or by their frame's depth factor, kept by cross-view verification,
    left out as repeats or as one object named twice, instances; and the metric scale the map stated (with the
    registration's scale against the ground truth where there is one: ``scale_error`` = stated / true - 1)."""
    try:
        t = json.loads(trace_path.read_text())
    except (OSError, ValueError):
        return None
    d, ev = t.get("decisions", {}), t.get("events", [])
    an, ver, sc = d.get("anchor") or {}, d.get("verify") or {}, d.get("scale") or {}
    fusion = {e["message"]: e for e in ev if e.get("kind") == "fusion"}.values()  # refinement re-fuses: once each
    twice = [x for e in fusion if e.get("named_twice") for x in e["named_twice"]]
    repeats = sum(len(e.get("dropped") or []) for e in fusion if isinstance(e.get("dropped"), list))
    reg = r.get("registration") or {}
    true_over_map = reg.get("scale") if r.get("depth_relative") else None
    return {"keyframes": len(r.get("keyframes_chosen", [])),
            "aligned": len(r.get("keyframes_chosen", [])) - len(r.get("unaligned", [])),
            "detections_lifted": ver.get("candidates", an.get("observations")),
            "placed_by_points": an.get("anchored"), "placed_by_frame_factor": an.get("frame_factor"),
            "verified": ver.get("kept"), "repeats_left_out": repeats, "named_twice": len(twice),
            "instances": (d.get("instances") or {}).get("count"),
            "scale": {"message": sc.get("message"), "source": sc.get("source"), "percent": sc.get("percent"),
                      "scale_error": None if not true_over_map else 1.0 / true_over_map - 1.0,
                      "covered": None if not true_over_map or sc.get("sd_log") is None
                      else bool(abs(math.log(true_over_map)) <= sc.get("stated_z", 1.0) * sc["sd_log"])}}


def pose_row(room: Path, bundle: Path, depth: str, k: int, path: str, conf: dict | None = None) -> dict[str, Any]:
    r, meta = _mosaic(["eval", "pose", "--data", str(room), "--keyframes", str(k), "--sampling", "uniform",
                       "--bundle", str(bundle), "--matcher", "model", "--depth", depth, "--path", path, "--json"]
                      + (["--conf", json.dumps(conf)] if conf else []))
    if r is None:
        return {"eval_pose": meta}
    fates: dict[str, int] = {}
    for v in (r.get("fates") or {}).values():
        fates[v] = fates.get(v, 0) + 1
    return {"eval_pose": meta, "ate_m": r.get("ate_m", r["ate_rmse_m"]), "ate_se3_m": r["ate_rmse_m"],
            "ate_sim3_m": r.get("ate_sim3_m"), "sim3_scale": r.get("sim3_scale"), "aligned": r["aligned_frames"], "of": r["total_frames"],
            "other_frames_used": len(r.get("other_frames_used", [])), "aligned_by_path": fates,
            "untracked": r.get("untracked_frames"), "sim3": r.get("sim3"), "seconds": round(r["seconds"], 2),
            "seconds_breakdown": r.get("seconds_breakdown"), "sfm": sfm_accounting(r),
            "scale": (r.get("scale") or {}).get("message"), "scale_error": r.get("scale_error"),
            "scale_covered": r.get("scale_covered")}


def sfm_accounting(r: dict[str, Any]) -> dict[str, Any] | None:
    """RGB only (structure from motion): where key frames were lost - the stream's size, the chains, each unaligned
    key frame's reason counted by kind (from the alignment event `eval pose` returns); None on other paths."""
    ev = [e for e in r.get("events", []) if e.get("kind") == "alignment" and "stream_frames" in e]
    if not ev:
        return None
    e = ev[-1]
    kinds: dict[str, int] = {}
    for why in (e.get("unaligned") or {}).values():
        k = why.split(":")[0].split(" (")[0]
        kinds[k] = kinds.get(k, 0) + 1
    notes = [x["message"] for x in r.get("events", []) if x.get("kind") in ("alignment", "degraded")
             and "intrinsics" in x.get("message", "")]
    return {"stream_frames": e.get("stream_frames"), "chains": e.get("chains"), "lost_by_reason": kinds,
            "intrinsics": notes[0] if notes else None}


def ask_row(room: Path, bundle: Path) -> dict[str, Any]:
    r, meta = _mosaic(["ask", str(room), QUESTION, "--bundle", str(bundle), "--depth", "sensor", "--keyframes", "16",
                       "--answerer", "map", "--json"], timeout=1200)
    return {"ask": meta, "answer": None if r is None else r.get("answer"),
            "unaligned": None if r is None else r.get("unaligned"),
            "keyframes": None if r is None else len(r.get("keyframes") or [])}


def picture(out: Path, room: str, dest: Path) -> None:
    """A small copy of eval scene's top-down picture (its boxes and camera paths only: re-rendered from the JSON
    files, no dataset points) for the docs."""
    import numpy as np

    from mosaicthinker.host.evaluation.scene_annotate import render_topdown

    sc = json.loads((out / "scene_eval.json").read_text())
    track = np.array(sc.get("topdown", {}).get("gt_track", []), float).reshape(-1, 3)
    est = np.array(sc.get("topdown", {}).get("keyframe_cameras", []), float).reshape(-1, 3)
    render_topdown(np.zeros((0, 3)), sc.get("topdown", {}).get("truth_boxes", {}), dest,
                   f"{room}: built (yellow) over ground truth (white boxes, grey camera path)",
                   sc.get("topdown", {}).get("built_boxes", {}), px_per_m=40,
                   tracks=[(track, (160, 160, 160), True), (est, (0, 255, 255), False)])


def diagnose(room: Path, bundle: Path, k: int, conf: dict | None) -> dict[str, Any]:
    """Why each key frame of `mosaic ask ROOM "How many chairs are in the room?"` (K, sensor depth, the bundle's
    matcher) stays unaligned: dedup's counts and reasons, the key frames, every pair alignment tried grouped by
    its failure reason (numbers blanked), the alignment steps' own messages and each key frame's path."""
    import re

    from mosaicthinker.runtime import pipeline
    from mosaicthinker.runtime.frames import open_source
    from mosaicthinker.runtime.infra.trace import Trace

    tr = Trace()
    c = {"matcher": "model", "depth": "sensor", **(conf or {})}
    p = pipeline.perception_from_bundle(str(bundle), c, tr)
    t0 = time.perf_counter()
    b = pipeline.build_map(open_source(room), ["chair"], [], p, c, tr, k)
    al = b.info["alignment"]
    reasons: dict[str, int] = {}
    for st in al["edge_stats"].values():
        key = re.sub(r"(?<![\w.])\d+(\.\d+)?(?![\w.])", "N", st["reason"] or "verified")
        reasons[key] = reasons.get(key, 0) + 1
    return {"room": room.name, "conf": conf or {}, "dedup": tr.decisions.get("dedup"),
            "keyframes": b.keyframes, "unaligned": b.unaligned, "fates": al["fates"],
            "pairs": len(al["edge_stats"]), "pair_outcomes": dict(sorted(reasons.items(), key=lambda kv: -kv[1])),
            "alignment_events": [e["message"] for e in tr.events if e.get("stage") == "alignment"],
            "seconds": round(time.perf_counter() - t0, 1), "load_avg_1min": round(os.getloadavg()[0], 2)}


def probe_edges(room: Path, bundle: Path, stride: int, n: int = 40) -> dict[str, Any]:
    """Pairwise edges between frames `stride` apart (n pairs spread over the sequence, the bundle's matcher, whole
    images) against the ground truth: matches, matches with depth at both ends, after the depth-smoothness test
    the 3D-3D edge applies, with smooth depth at one end at least; then each method alone (3d-3d, pnp, essential)
    and the chain (`align.pnp.rgbd_edge`): verified, right (< 5 cm and < 3 deg from the ground truth), and the
    median / 90th percentile error of the verified ones. The pose graph's sigmas (`backbone.EDGE_SIGMA`) are
    these medians."""
    import numpy as np

    from mosaicthinker.runtime.align.pnp import lifted, rgbd_edge
    from mosaicthinker.runtime.align import AlignConf, pose_change
    from mosaicthinker.runtime.frames import open_source
    from mosaicthinker.runtime.geometry import invert
    from mosaicthinker.runtime.models import load_role
    from mosaicthinker.runtime.infra.trace import Trace

    src = open_source(room)
    m = load_role(str(bundle), "matcher", trace=Trace())
    conf = AlignConf(keyframe_edges=True)  # the pipeline's edges: `keyframe_min_inliers`
    px = 1.5 * float(getattr(m, "keypoint_px", 1.0))
    idx = [int(i) for i in np.linspace(0, len(src) - 1 - stride, n).round()]
    counts = []
    per: dict[str, dict[str, Any]] = {k: {"verified": 0, "right": 0, "errors": []}
                                      for k in ("3d-3d", "pnp", "essential", "chain")}
    for i in idx:
        fa, fb = src[i], src[i + stride]
        if fa.pose_gt is None or fb.pose_gt is None:
            continue
        mt = m.match_keys(i, fa.rgb, i + stride, fb.rgb)
        za, zb, ua, ub = lifted(mt, fa, fb, conf)
        counts.append([len(mt), int(((za > 0) & (zb > 0)).sum()), int((ua & ub).sum()), int((ua | ub).sum())])
        gt = invert(fa.pose_gt) @ fb.pose_gt
        for name, methods in (("3d-3d", ("3d-3d",)), ("pnp", ("pnp",)), ("essential", ("essential",)),
                              ("chain", ("3d-3d", "pnp", "essential"))):
            r = rgbd_edge(mt, fa, fb, conf, px, 0, methods)
            if r.ok:
                dt, dr = pose_change(r.T_ab, gt)
                per[name]["verified"] += 1
                per[name]["right"] += int(dt < 0.05 and dr < 3)
                per[name]["errors"].append((dt, dr))
    out = {"room": room.name, "stride": stride, "pairs": len(counts),
           "median_matches_depth_both_smooth_one": np.median(np.array(counts), 0).tolist() if counts else None}
    for name, d in per.items():
        e = np.array(d.pop("errors")).reshape(-1, 2)
        d["median_err_m_deg"] = np.round(np.median(e, 0), 4).tolist() if len(e) else None
        d["p90_err_m_deg"] = np.round(np.percentile(e, 90, axis=0), 4).tolist() if len(e) else None
        out[name] = d
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--bundle", type=Path, default=os.environ.get("MOSAIC_BUNDLE"), required="MOSAIC_BUNDLE" not in os.environ,
                    help="an exported bundle (default: $MOSAIC_BUNDLE)")
    ap.add_argument("--rooms", type=Path, nargs="*", default=[])
    ap.add_argument("--only-default-rooms", action="store_true")
    ap.add_argument("--keyframes", default="16,32")
    ap.add_argument("--depths", default="sensor,model")
    ap.add_argument("--before", action="store_true", help="the landed code's alignment and thinning instead (eval "
                    "scene --conf backbone and overlap sampling off, eval pose --path frames); results default to "
                    "real_rooms_before.json")
    ap.add_argument("--no-ask", action="store_true", help="skip the `mosaic ask` timing runs")
    ap.add_argument("--pictures", action="store_true", help="write docs/img/real-rooms-<room>.png")
    ap.add_argument("--diagnose", action="store_true", help="only the diagnosis (`diagnose`, K = the first of "
                    "--keyframes, sensor depth) -> real_rooms_diagnosis[_before].json")
    ap.add_argument("--probe-edges", default="", metavar="STRIDES", help="only the pairwise-edge probe at these "
                    "frame strides (`probe_edges`) -> real_rooms_edges.json")
    ap.add_argument("--variants", action="store_true", help="only eval pose (K = the last of --keyframes, sensor "
                    "depth) per room for every entry of VARIANTS -> real_rooms_variants.json")
    ap.add_argument("--out", type=Path, default=REPO / "out" / "real_rooms")
    ap.add_argument("--results", type=Path, default=RESULTS)
    a = ap.parse_args(argv)
    from mosaicthinker.runtime.frames import open_source

    if a.variants:
        k = int(a.keyframes.split(",")[-1])
        got = {r.name: {name: pose_row(r, a.bundle, "sensor", k, "ask", conf) for name, conf in VARIANTS.items()}
               for r in discover(a.rooms, a.only_default_rooms) if open_source(r).has_pose}
        dest = RESULTS.with_name("real_rooms_variants.json")
        dest.write_text(json.dumps({"command": " ".join(sys.argv), "date": time.strftime("%Y-%m-%dT%H:%M:%SZ",
                                    time.gmtime()), "variants": VARIANTS, "results": got}, indent=1, default=float))
        for room, rows in got.items():
            for name, r in rows.items():
                print(f"{room:24s} {name:28s} ATE {_f(r.get('ate_m'))} aligned {r.get('aligned')}/{r.get('of')} "
                      f"other frames {r.get('other_frames_used')} {r.get('seconds')} s")
        return 0
    if a.diagnose or a.probe_edges:
        rooms = [r for r in discover(a.rooms, a.only_default_rooms) if open_source(r).has_pose]
        if a.diagnose:
            k = int(a.keyframes.split(",")[0])
            got = [diagnose(r, a.bundle, k, BEFORE if a.before else None) for r in rooms]
            dest = RESULTS.with_name(f"real_rooms_diagnosis{'_before' if a.before else ''}.json")
        else:
            got = [probe_edges(r, a.bundle, int(s)) for r in rooms for s in a.probe_edges.split(",") if s]
            dest = RESULTS.with_name("real_rooms_edges.json")
        dest.write_text(json.dumps({"command": " ".join(sys.argv), "date": time.strftime("%Y-%m-%dT%H:%M:%SZ",
                                    time.gmtime()), "results": got}, indent=1, default=float))
        print(json.dumps(got, indent=1, default=float))
        return 0
    if a.before and a.results == RESULTS:
        a.results = RESULTS.with_name("real_rooms_before.json")
    if a.before:
        a.out = a.out / "before"
    ks = [int(k) for k in a.keyframes.split(",") if k]
    depths = [d for d in a.depths.split(",") if d]
    res: dict[str, Any] = {"schema": "mosaicthinker.bench.real_rooms/1", "command": " ".join(sys.argv),
                           "date": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), "bundle": str(a.bundle),
                           "cpu_count": os.cpu_count(), "targets": TARGETS, "rooms": {}}
    for room in discover(a.rooms, a.only_default_rooms):
        src = open_source(room)
        info: dict[str, Any] = {"path": str(room), "frames": len(src), "has_depth": src.has_depth,
                                "has_pose": src.has_pose, "runs": {}}
        for depth in depths:
            if depth == "sensor" and not src.has_depth:
                continue
            for k in ks:
                for variant, conf in [("before", BEFORE)] if a.before else [("now", None)]:
                    key = f"{depth}/K{k}"
                    print(f"[real_rooms] {room.name} {key}", file=sys.stderr, flush=True)
                    row = scene_row(room, a.bundle, depth, k, a.out / room.name / key.replace("/", "-"), conf)
                    if src.has_pose:
                        row["pose"] = pose_row(room, a.bundle, depth, k, "ask" if variant == "now" else "frames")
                    info["runs"][key] = row
                    res["rooms"][room.name] = info
                    a.results.parent.mkdir(parents=True, exist_ok=True)
                    a.results.write_text(json.dumps(res, indent=1, default=float))
        if src.has_depth and not a.no_ask:
            info["ask_k16"] = ask_row(room, a.bundle)
        if a.pictures and (a.out / room.name / f"{'sensor' if src.has_depth else 'model'}-K16").is_dir():
            picture(a.out / room.name / f"{'sensor' if src.has_depth else 'model'}-K16", room.name,
                    REPO / "docs" / "img" / f"real-rooms-{room.name}.png")
    kitchen = res["rooms"].get("7scenes-redkitchen", {}).get("ask_k16", {}).get("ask", {}).get("process_wall_s")
    for info in res["rooms"].values():
        if kitchen and info.get("ask_k16", {}).get("ask", {}).get("process_wall_s"):
            info["ask_k16"]["ratio_to_kitchen"] = round(info["ask_k16"]["ask"]["process_wall_s"] / kitchen, 2)
    a.results.write_text(json.dumps(res, indent=1, default=float))
    a.results.with_suffix(".md").write_text(markdown(res))
    print(markdown(res))
    return 0


def _f(x: Any, d: int = 3) -> str:
    return "-" if x is None else (f"{x:.{d}f}" if isinstance(x, float) else str(x))


def markdown(res: dict[str, Any]) -> str:
    """The table of the JSON: one line per room, depth mode and K."""
    lines = ["| room | run | frames (kept) | key frames aligned | by path | key-frame ATE m | eval pose ATE m "
             "(aligned) | recall | precision | centre m | wall s | peak MB | map loads |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for name, info in res["rooms"].items():
        for key, r in info["runs"].items():
            if "aligned" not in r:
                lines.append(f"| {name} | {key} | failed: {r['eval_scene'].get('stderr', '')[-120:]} |")
                continue
            o, p = r.get("objects") or {}, r.get("pose") or {}
            kept = (r.get("dedup") or {}).get("kept")
            lines.append(
                f"| {name} | {key} | {r['frames']} ({kept}) | {r['aligned']}/{r['keyframes']} | "
                f"{', '.join(f'{n} {k}' for k, n in r['aligned_by_path'].items())} | {_f(r['keyframe_ate_m'])} | "
                f"{_f(p.get('ate_m'))} ({p.get('aligned', '-')}/{p.get('of', '-')}) | {_f(o.get('recall'), 2)} | "
                f"{_f(o.get('precision'), 2)} | {_f(o.get('median_centre_err_m'), 2)} | {_f(r['wall_s'], 1)} | "
                f"{r['peak_rss_mb']} | {'yes' if r.get('map_loads', {}).get('ok') else 'NO'} |")
    rgb = [(n, k, r) for n, i in res["rooms"].items() for k, r in i["runs"].items()
           if k.startswith("model/") and r.get("stages")]
    if rgb:
        lines += ["", "RGB only (the room's depth ignored): what was lost where, and the metric scale",
                  "", "| room | run | key frames aligned | detections | placed by SfM points / frame factor | "
                  "verified | repeats / named twice out | instances | scale stated | scale error (covered) |",
                  "|---|---|---|---|---|---|---|---|---|---|"]
        for n, k, r in rgb:
            st, sc = r["stages"], r["stages"]["scale"]
            err = sc.get("scale_error")
            lines.append(f"| {n} | {k} | {st['aligned']}/{st['keyframes']} | {st['detections_lifted']} | "
                         f"{st['placed_by_points']} / {st['placed_by_frame_factor']} | {st['verified']} | "
                         f"{st['repeats_left_out']} / {st['named_twice']} | {st['instances']} | {sc.get('message')} | "
                         + ("-" if err is None else f"{100 * err:+.1f} % ({'yes' if sc.get('covered') else 'NO'})")
                         + " |")
    asks = [(n, i["ask_k16"]) for n, i in res["rooms"].items() if i.get("ask_k16")]
    if asks:
        lines += ["", "| room | `mosaic ask` K=16 sensor, wall s | ratio to the kitchen | answer | load before |",
                  "|---|---|---|---|---|"]
        lines += [f"| {n} | {_f(a['ask'].get('process_wall_s'), 1)} | {_f(a.get('ratio_to_kitchen'), 2)} | "
                  f"{a.get('answer')} | {a['ask'].get('load_avg_1min_before')} |" for n, a in asks]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    sys.exit(main())
