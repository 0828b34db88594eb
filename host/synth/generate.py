"""Write one synthetic scene: 7-Scenes-style RGB-D frames, instance masks, an mp4, `scene.json`, `questions.jsonl`.

Folder layout (`write_scene(conf, out_dir)`):
    frame-XXXXXX.color.jpg      RGB (JPEG quality 92)
    frame-XXXXXX.depth.png      uint16 z-depth in millimetres (0 = invalid; never 0 inside the closed room)
    frame-XXXXXX.instances.png  uint16 instance ids (0 = room structure: floor, walls, ceiling, pictures)
    frame-XXXXXX.pose.txt       4x4 camera-to-world (OpenCV camera axes, world z up, metres)
    camera-intrinsics.txt       3x3 K
    timestamps.txt              one time (s) per frame
    gravity-direction.txt       gravity (down) in the world frame of the poses: 0 0 -1 (frames.py convention)
    video.mp4                   the RGB frames (OpenCV 'mp4v')
    scene.json                  ground truth (see `SCENE_SCHEMA` and README)
    questions.jsonl             questions of every VSI-Bench type with ground-truth answers

Visibility per frame and instance (`scene.json` -> frames[i].visible):
    pixels     visible pixels of the instance in the frame;
    fraction   pixels / unoccluded pixels: the share of the instance's in-image silhouette that no other surface
               hides (1 = not occluded; truncation by the image border is not counted here);
    in_frame   share of 27 points on the instance's box (corners, edge and face centres, centre) inside the view
               frustum (truncation);
    visibility fraction * in_frame: the estimate of "how much of the object is visible" (key-frame recall uses it).
An instance is listed when pixels > 0. `first_seen` is the time of the first frame in which at least
`seen_min_pixels` (0.1% of the image, at least 10) of it are visible.
"""
from __future__ import annotations

import json
import math
import os
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from mosaicthinker.runtime.infra import jsonio
from mosaicthinker.runtime.infra.errors import InputError
from mosaicthinker.runtime.geometry import intrinsics_from_fov, project
from mosaicthinker.runtime.infra.progress import start
from mosaicthinker.host.synth.scene import Scene, SceneConfig, config_dict, generate_scene

SCENE_SCHEMA = "mosaicthinker.synth.scene/1"

_G: dict[str, Any] = {}  # per-process renderer state for the worker pool


def box_probe_points(scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    """27 probe points per object box -> points [N * 27, 3] and their instance ids [N * 27]."""
    g = np.array([[a, b, c] for a in (-0.5, 0, 0.5) for b in (-0.5, 0, 0.5) for c in (-0.5, 0, 0.5)])
    pts, ids = [], []
    for o in scene.objects:
        b = o.box()
        pts.append(b.centroid + (g * b.axes_lengths) @ b.axes)
        ids.append(np.full(len(g), o.id))
    if not pts:
        return np.zeros((0, 3)), np.zeros(0, int)
    return np.concatenate(pts), np.concatenate(ids)


def in_frame_fraction(scene: Scene, K: np.ndarray, T_wc: np.ndarray, W: int, H: int) -> np.ndarray:
    """[N + 1] share of each instance's probe points inside the view frustum (index = instance id)."""
    pts, ids = box_probe_points(scene)
    n = max([o.id for o in scene.objects], default=0) + 1
    if len(pts) == 0:
        return np.zeros(n)
    uv, z = project(pts, K, T_wc)
    ok = (z > 0.05) & (uv[:, 0] >= -0.5) & (uv[:, 0] <= W - 0.5) & (uv[:, 1] >= -0.5) & (uv[:, 1] <= H - 0.5)
    return np.bincount(ids, ok.astype(float), n) / np.maximum(np.bincount(ids, None, n), 1)


def visibility_entries(visible: np.ndarray, covered: np.ndarray, in_frame: np.ndarray) -> list[dict[str, Any]]:
    """One frame's `visible` rows of scene.json from the renderer's per-id counts (`RenderResult.visible`,
    `.covered`, each [N + 1]) and `in_frame_fraction` [N + 1]: every instance with a visible pixel."""
    out = []
    for k in np.flatnonzero(visible[1:] > 0) + 1:
        frac = float(min(1.0, visible[k] / max(covered[k], 1)))
        out.append({"id": int(k), "pixels": int(visible[k]), "fraction": round(frac, 4),
                    "in_frame": round(float(in_frame[k]), 4), "visibility": round(frac * float(in_frame[k]), 4)})
    return out


def _render_one(i: int) -> tuple[int, bytes, np.ndarray, np.ndarray, np.ndarray]:
    r = _G["renderer"]
    out: Path = _G["out"]
    T_wc = _G["poses"][i]
    res = r.render(T_wc, frame_seed=i)
    stem = out / f"frame-{i:06d}"
    bgr = np.ascontiguousarray(res.rgb[:, :, ::-1])
    from mosaicthinker.runtime.frames import imwrite_path  # checked, path-safe writes (any folder name)

    imwrite_path(f"{stem}.color.jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, 92])
    mm = np.clip(np.round(res.depth * 1000.0), 0, 65534).astype(np.uint16)
    imwrite_path(f"{stem}.depth.png", mm, [cv2.IMWRITE_PNG_COMPRESSION, 1])
    imwrite_path(f"{stem}.instances.png", res.instances, [cv2.IMWRITE_PNG_COMPRESSION, 1])
    np.savetxt(f"{stem}.pose.txt", T_wc, fmt="%.9f")
    inf = in_frame_fraction(r.scene, r.K, T_wc, r.W, r.H)
    return i, bgr.tobytes(), res.visible, res.covered, inf


def _init_worker(conf: dict[str, Any], out: str, K: np.ndarray, poses: np.ndarray, threads: int = 1) -> None:
    """Build the renderer in this process (the scene is regenerated from its config: deterministic)."""
    from mosaicthinker.host.synth.render import Renderer

    if threads:
        cv2.setNumThreads(threads)
    scene = generate_scene(SceneConfig(**conf))
    _G.update(renderer=Renderer(scene, K, scene.config.width, scene.config.height, scene.config.noise_sigma),
              out=Path(out), poses=poses)


def render_frames(scene: Scene, out: Path, K: np.ndarray, poses: np.ndarray, workers: int = 1,
                  video: bool = True) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """Render and write every frame (and the mp4). Returns per-frame visibility rows and timing info.
    With workers > 1, frames are rendered in spawned processes (each rebuilds the renderer from the config)."""
    conf = scene.config
    t0 = time.perf_counter()
    workers = max(1, min(int(workers), len(poses)))
    init_args = (config_dict(conf), str(out), np.asarray(K), np.asarray(poses))
    if workers == 1:
        _init_worker(*init_args, threads=0)
    t_init = time.perf_counter() - t0
    writer = None
    if video:
        writer = cv2.VideoWriter(str(out / "video.mp4"), cv2.VideoWriter_fourcc(*"mp4v"), float(conf.fps),
                                 (conf.width, conf.height))
        if not writer.isOpened():
            raise InputError(f"{out / 'video.mp4'}: OpenCV cannot write an mp4v video here (no FFmpeg backend?); "
                             f"rerun with `video=False`", fields=("video",))
    rows: list[dict[str, Any]] = [None] * len(poses)  # type: ignore[list-item]
    n = len(poses)

    def consume(item):
        i, buf, vis, cov, inf = item
        if writer is not None:
            writer.write(np.frombuffer(buf, np.uint8).reshape(conf.height, conf.width, 3))
        rows[i] = {"index": int(i), "visible": visibility_entries(vis, cov, inf)}
        bar.update()

    bar = start("render", n, "frame")
    if workers == 1:
        for i in range(n):
            consume(_render_one(i))
    else:
        import multiprocessing as mp

        # spawn, not fork: OpenCV's thread pool in the parent can deadlock a forked child
        with mp.get_context("spawn").Pool(workers, initializer=_init_worker, initargs=init_args) as pool:
            for item in pool.imap(_render_one, range(n), chunksize=4):
                consume(item)
    bar.done()
    if writer is not None:
        writer.release()
    _G.clear()
    return rows, {"init_s": round(t_init, 3), "render_write_s": round(time.perf_counter() - t0 - t_init, 3),
                  "workers": workers}


def write_scene(conf: SceneConfig, out_dir: str | os.PathLike, workers: int = 1, video: bool = True,
                questions: bool = True, name: str | None = None) -> dict[str, Any]:
    """Generate, render and write one scene into `out_dir` (created). Returns a summary dict."""
    t0 = time.perf_counter()
    from mosaicthinker.host.synth.trajectory import camera_track

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    if any(out.glob("frame-*.color.jpg")):
        raise InputError(f"{out}: already holds frames; give an empty or new `out` folder", fields=("out",))
    scene = generate_scene(conf)
    n_frames = max(1, int(round(conf.duration * conf.fps)))
    times, poses = camera_track(scene, n_frames, conf.fps)
    K = intrinsics_from_fov(conf.width, conf.height, conf.hfov_deg)
    np.savetxt(out / "camera-intrinsics.txt", K, fmt="%.9f")
    (out / "timestamps.txt").write_text("".join(f"{t:.6f}\n" for t in times))
    (out / "gravity-direction.txt").write_text("0 0 -1\n")
    rows, timing = render_frames(scene, out, K, poses, workers, video)
    for r, t in zip(rows, times):
        r["t"] = round(float(t), 6)
    meta = scene_json(scene, name or out.name, K, times, rows)
    (out / "scene.json").write_text(jsonio.dumps(meta, indent=1))
    n_q = 0
    q_skipped: dict[str, Any] = {}
    if questions:
        n_q, q_skipped = write_questions(meta, out)
    return {"scene": meta["scene_name"], "out": str(out), "frames": n_frames, "objects": len(scene.objects),
            "object_counts": meta["object_counts"], "room_size": meta["room_size"], "questions": n_q,
            "questions_skipped": q_skipped, "dropped": scene.dropped,
            "seconds": round(time.perf_counter() - t0, 2), **timing}


def write_questions(meta: dict[str, Any], out: Path, margins: dict[str, float] | None = None,
                    per_type: dict[str, int] | None = None) -> tuple[int, dict[str, Any]]:
    """(Re)write `questions.jsonl` of a scene from its ground truth (deterministic in the scene's seed)
    -> (number of questions, the generator's report: margin removals per type)."""
    from mosaicthinker.host.synth.questions import generate_questions

    qs, report = generate_questions(meta, seed=int(meta["seed"]), margins=margins, per_type=per_type)
    (Path(out) / "questions.jsonl").write_text("".join(jsonio.dumps(q) + "\n" for q in qs))
    return len(qs), report


def scene_json(scene: Scene, name: str, K: np.ndarray, times: np.ndarray, rows: list[dict[str, Any]]
               ) -> dict[str, Any]:
    """The ground truth as a VSI-Bench meta_info scene (object_bbox, object_counts, room_size, room_center) plus
    instances, camera, per-frame visibility and provenance."""
    conf = scene.config
    W, H = conf.width, conf.height
    seen_px = max(10, int(math.ceil(0.001 * W * H)))
    first: dict[int, int] = {}
    nvis: dict[int, int] = {}
    for r in rows:
        for v in r["visible"]:
            nvis[v["id"]] = nvis.get(v["id"], 0) + 1
            if v["pixels"] >= seen_px and v["id"] not in first:
                first[v["id"]] = r["index"]
    instances = []
    for o in scene.objects:
        fi = first.get(o.id)
        instances.append({"id": o.id, "name": o.name, "box": o.box().to_meta(), "yaw": round(o.yaw, 6),
                          "size_source": o.source, "parts": len(o.prims),
                          "first_seen": None if fi is None else float(times[fi]), "first_seen_frame": fi,
                          "frames_visible": nvis.get(o.id, 0)})
    room = scene.room
    return {
        "schema": SCENE_SCHEMA, "scene_name": name, "dataset": "synthetic", "seed": conf.seed,
        "config": config_dict(conf),
        "room_size": round(room.area, 6), "room_center": [0.0, 0.0, round(room.height / 2, 6)],
        "room": {"polygon": room.polygon.tolist(), "floor_z": 0.0, "ceiling_z": room.height,
                 "size_xy": [room.Lx, room.Ly]},
        "object_counts": scene.counts(), "object_bbox": scene.object_bbox(), "instances": instances,
        "dropped": scene.dropped, "composition": _plain(scene.composition),
        "camera": {"K": np.asarray(K).tolist(), "width": W, "height": H, "fps": conf.fps,
                   "frames": len(times), "duration": float(len(times) / conf.fps), "hfov_deg": conf.hfov_deg,
                   "axes": "opencv (x right, y down, z forward); poses camera-to-world; world z up, floor z=0"},
        "gravity": [0.0, 0.0, -1.0],
        "seen_min_pixels": seen_px,
        "visibility_fields": {"pixels": "visible pixels", "fraction": "visible / unoccluded in-image pixels",
                              "in_frame": "share of 27 box probe points inside the view frustum",
                              "visibility": "fraction * in_frame"},
        "frames": rows,
    }


def _plain(x: Any) -> Any:
    from mosaicthinker.runtime.infra.trace import jsonable

    return jsonable(x)


def load_scene(scene_dir: str | os.PathLike) -> dict[str, Any]:
    """Read `scene.json` of a generated scene folder."""
    p = Path(scene_dir) / "scene.json"
    try:
        d = json.loads(p.read_text())
    except (OSError, json.JSONDecodeError) as e:
        raise InputError(f"{p}: cannot read the synthetic scene ground truth ({e}); generate it with "
                         f"`mosaic synth --out DIR`") from None
    if d.get("schema") != SCENE_SCHEMA:
        raise InputError(f"{p}: field `schema` is {d.get('schema')!r}, expected {SCENE_SCHEMA!r}")
    return d
