"""Synthetic scene generator: statistics from VSI-Bench, determinism, ground-truth consistency of depth, masks and
boxes, visibility, the frame-source layout, the oracle detector and the `mosaic synth` command."""
from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from mosaicthinker.runtime import geometry as G
from mosaicthinker.runtime.frames import open_source
from mosaicthinker.host.synth.generate import load_scene, write_scene
from mosaicthinker.host.synth.oracle import OracleDetector
from mosaicthinker.host.synth.scene import SceneConfig, _overlap2d, generate_scene
from mosaicthinker.host.synth.stats import STATS_PATH, box_dims, compute_stats, load_meta_info

SMALL = dict(duration=6.0, fps=8.0, width=256, height=192)


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("synth") / "scene"
    write_scene(SceneConfig(seed=11, objects="high", room="medium", **SMALL), d, name="fixture")
    return d


# ----------------------------------------------------------------------------- statistics


def test_checked_in_statistics_are_reproducible(vsibench_dir):
    stats = compute_stats(load_meta_info(vsibench_dir / "meta_info.json"), "meta_info.json")
    assert json.loads(json.dumps(stats)) == json.loads(STATS_PATH.read_text())


def test_scenes_drawn_from_vsibench_statistics(vsibench_dir):
    meta = load_meta_info(vsibench_dir / "meta_info.json")
    lo_hi: dict[str, list[np.ndarray]] = {}
    for s in meta.values():
        for cat, boxes in s["object_bbox"].items():
            lo_hi.setdefault(cat, []).extend(box_dims(b) for b in boxes)
    rng_dims = {c: (np.min(v, 0), np.max(v, 0)) for c, v in lo_hi.items()}
    areas = np.array([s["room_size"] for s in meta.values()])
    totals = np.array([sum(len(b) for b in s["object_bbox"].values()) for s in meta.values()])
    q1, q2 = np.quantile(areas, [1 / 3, 2 / 3])
    t1, t2 = np.quantile(totals, [1 / 3, 2 / 3])
    room_rng = {"small": (areas.min(), q1), "medium": (q1, q2), "large": (q2, areas.max())}
    obj_rng = {"low": (totals.min(), np.floor(t1)), "med": (np.floor(t1) + 1, np.floor(t2)),
               "high": (np.floor(t2) + 1, totals.max())}
    seen_levels = set()
    for seed in range(4):
        for objects in ("low", "med", "high"):
            for room in ("small", "large"):
                sc = generate_scene(SceneConfig(seed=seed, objects=objects, room=room))
                a, b = room_rng[room]
                assert a - 1e-6 <= sc.room.area <= b + 1e-6
                n_req = sum(sc.composition["requested"].values())
                assert obj_rng[objects][0] <= n_req <= obj_rng[objects][1]
                seen_levels.add(objects)
                for o in sc.objects:
                    if o.source != "vsibench":
                        continue
                    dims = np.array([max(o.size[:2]), min(o.size[:2]), o.size[2]])
                    lo, hi = rng_dims[o.name]
                    assert np.all(dims >= lo - 1e-6) and np.all(dims <= hi + 1e-6), (o.name, dims, lo, hi)
                # inside the room, no two objects overlap (footprint and height)
                for i, o in enumerate(sc.objects):
                    fp = o.footprint()
                    assert np.all(np.abs(fp[:, 0]) <= sc.room.Lx / 2 + 1e-9)
                    assert np.all(np.abs(fp[:, 1]) <= sc.room.Ly / 2 + 1e-9)
                    for p in sc.objects[i + 1:]:
                        zo = o.pos[2] < p.pos[2] + p.size[2] - 1e-9 and p.pos[2] < o.pos[2] + o.size[2] - 1e-9
                        assert not (zo and _overlap2d(fp, p.footprint())), (o.name, p.name)
    assert seen_levels == {"low", "med", "high"}


# ----------------------------------------------------------------------------- determinism


def test_same_seed_same_files_other_seed_differs(tmp_path):
    conf = dict(objects="med", room="small", duration=1.0, fps=6.0, width=96, height=72)
    a, b, c = tmp_path / "a", tmp_path / "b", tmp_path / "c"
    write_scene(SceneConfig(seed=3, **conf), a, name="s", video=False)
    write_scene(SceneConfig(seed=3, **conf), b, name="s", video=False, workers=2)
    write_scene(SceneConfig(seed=4, **conf), c, name="s", video=False)
    files = sorted(p.name for p in a.iterdir())
    assert files == sorted(p.name for p in b.iterdir()) and len(files) > 20
    for f in files:
        assert (a / f).read_bytes() == (b / f).read_bytes(), f
    assert (a / "scene.json").read_bytes() != (c / "scene.json").read_bytes()
    assert not np.array_equal(cv2.imread(str(a / "frame-000000.color.jpg")),
                              cv2.imread(str(c / "frame-000000.color.jpg")))


# ----------------------------------------------------------------------------- ground truth consistency


def _frames(scene_dir: Path, meta: dict, step: int = 6):
    for i in range(0, meta["camera"]["frames"], step):
        stem = scene_dir / f"frame-{i:06d}"
        depth = cv2.imread(f"{stem}.depth.png", cv2.IMREAD_UNCHANGED).astype(np.float64) / 1000.0
        inst = cv2.imread(f"{stem}.instances.png", cv2.IMREAD_UNCHANGED)
        pose = np.loadtxt(f"{stem}.pose.txt")
        yield i, depth, inst, pose


def test_depth_and_masks_agree_with_boxes(scene_dir):
    meta = load_scene(scene_dir)
    K = np.asarray(meta["camera"]["K"])
    boxes = {o["id"]: G.OrientedBox.from_meta(o["box"]) for o in meta["instances"]}
    room = meta["room"]
    Lx, Ly = room["size_xy"]
    checked = 0
    for i, depth, inst, pose in _frames(scene_dir, meta):
        assert depth.dtype == np.float64 and np.all(depth > 0)  # closed room: every pixel has depth
        for k in np.unique(inst):
            pts, _ = G.backproject(depth, K, inst == k)
            pw = G.transform(pose, pts)
            if k == 0:  # room structure: on the floor, ceiling, walls or a picture 1 cm off a wall
                d = np.min(np.stack([np.abs(pw[:, 2]), np.abs(pw[:, 2] - room["ceiling_z"]),
                                     np.abs(np.abs(pw[:, 0]) - Lx / 2), np.abs(np.abs(pw[:, 1]) - Ly / 2)]), 0)
                assert np.mean(d < 0.03) > 0.99
                continue
            if len(pts) < 20:
                continue
            inside = boxes[int(k)].contains(pw, margin=0.02)
            assert inside.mean() > 0.99, (i, int(k), inside.mean())
            checked += 1
    assert checked >= 20


def test_projected_box_corners_land_on_the_rendered_object(scene_dir):
    meta = load_scene(scene_dir)
    K = np.asarray(meta["camera"]["K"])
    W, H = meta["camera"]["width"], meta["camera"]["height"]
    boxes = {o["id"]: G.OrientedBox.from_meta(o["box"]) for o in meta["instances"]}
    vis = {r["index"]: {v["id"]: v for v in r["visible"]} for r in meta["frames"]}
    n = full = 0
    for i, depth, inst, pose in _frames(scene_dir, meta, step=3):
        for k, v in vis[i].items():
            if v["in_frame"] < 1.0 or v["pixels"] < 150:
                continue
            uv, z = G.project(boxes[k].corners(), K, pose)
            assert np.all(z > 0)
            c0, c1 = uv.min(0), uv.max(0)
            ys, xs = np.nonzero(inst == k)
            m0, m1 = np.array([xs.min(), ys.min()]), np.array([xs.max(), ys.max()])
            # the object's pixels lie within the projected box ...
            assert np.all(m0 >= c0 - 1.5) and np.all(m1 <= c1 + 1.5), (i, k)
            if v["fraction"] >= 0.97:  # ... and, when nothing hides it, fill most of its extent
                area_c = np.prod(np.clip(c1, 0, [W - 1, H - 1]) - np.clip(c0, 0, [W - 1, H - 1]))
                assert np.prod(m1 - m0) > 0.5 * area_c, (i, k)
                cu, _ = G.project(boxes[k].centroid[None], K, pose)
                assert np.all(cu[0] >= m0 - 1) and np.all(cu[0] <= m1 + 1)
                full += 1
            n += 1
    assert n >= 5 and full >= 1


def test_visibility_and_first_seen(scene_dir):
    meta = load_scene(scene_dir)
    seen_px = meta["seen_min_pixels"]
    first: dict[int, float] = {}
    for r, t in zip(meta["frames"], np.loadtxt(scene_dir / "timestamps.txt")):
        assert abs(r["t"] - t) < 1e-6
        for v in r["visible"]:
            assert 0 < v["pixels"] and 0 <= v["fraction"] <= 1 and 0 <= v["in_frame"] <= 1
            assert abs(v["visibility"] - v["fraction"] * v["in_frame"]) < 1e-3
            if v["pixels"] >= seen_px:
                first.setdefault(v["id"], r["t"])
        inst = cv2.imread(str(scene_dir / f"frame-{r['index']:06d}.instances.png"), cv2.IMREAD_UNCHANGED)
        ids, cnt = np.unique(inst, return_counts=True)
        assert {int(i): int(c) for i, c in zip(ids, cnt) if i} == {v["id"]: v["pixels"] for v in r["visible"]}
    for o in meta["instances"]:
        assert o["first_seen"] == first.get(o["id"])
    # some occlusion happens and not every object is visible all the time
    fr = [v["fraction"] for r in meta["frames"] for v in r["visible"]]
    assert min(fr) < 0.8
    assert any(o["frames_visible"] < meta["camera"]["frames"] for o in meta["instances"])


def test_folder_reads_as_a_frame_source_and_video(scene_dir):
    meta = load_scene(scene_dir)
    src = open_source(scene_dir)
    assert len(src) == meta["camera"]["frames"] and src.has_depth and src.has_pose
    np.testing.assert_allclose(src.K, meta["camera"]["K"])
    np.testing.assert_allclose(src.gravity, [0, 0, -1])
    f = src[5]
    assert f.rgb.shape == (SMALL["height"], SMALL["width"], 3) and abs(f.t - 5 / SMALL["fps"]) < 1e-6
    R = f.pose_gt[:3, :3]
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-6)
    assert 1.3 < f.pose_gt[2, 3] < 1.7  # eye height
    cap = cv2.VideoCapture(str(scene_dir / "video.mp4"))
    n = 0
    while cap.grab():
        n += 1
    assert n == len(src)
    # the scene.json is a VSI-Bench meta_info scene
    from mosaicthinker.runtime.map import SemanticMap
    smap = SemanticMap.from_meta_info(meta, "fixture")
    assert smap.counts() == meta["object_counts"]
    for cat, bl in meta["object_bbox"].items():
        for b in bl:
            lo, hi = G.OrientedBox.from_meta(b).aabb()
            np.testing.assert_allclose(lo, b["min"], atol=1e-9)
            np.testing.assert_allclose(hi, b["max"], atol=1e-9)


def test_textures_give_geometrically_correct_feature_matches(scene_dir):
    meta = load_scene(scene_dir)
    K = np.asarray(meta["camera"]["K"])
    sift = cv2.SIFT_create()
    good_pairs = 0
    for i in (4, 20, 36):
        j = i + 2
        im = [cv2.imread(str(scene_dir / f"frame-{k:06d}.color.jpg"), cv2.IMREAD_GRAYSCALE) for k in (i, j)]
        (k1, d1), (k2, d2) = (sift.detectAndCompute(x, None) for x in im)
        if d1 is None or d2 is None:
            continue
        m = cv2.BFMatcher().knnMatch(d1, d2, k=2)
        m = [a for a, b in (p for p in m if len(p) == 2) if a.distance < 0.75 * b.distance]
        depth = cv2.imread(str(scene_dir / f"frame-{i:06d}.depth.png"), cv2.IMREAD_UNCHANGED) / 1000.0
        Ti, Tj = (np.loadtxt(scene_dir / f"frame-{k:06d}.pose.txt") for k in (i, j))
        uv1 = np.array([k1[a.queryIdx].pt for a in m])
        uv2 = np.array([k2[a.trainIdx].pt for a in m])
        z = G.sample_depth(depth, uv1)
        pw = G.transform(Ti, G.backproject_pixels(uv1, z, K))
        proj, _ = G.project(pw, K, Tj)
        err = np.linalg.norm(proj - uv2, axis=1)
        if len(m) >= 20 and np.mean(err < 3.0) > 0.6:
            good_pairs += 1
    assert good_pairs >= 2


# ----------------------------------------------------------------------------- oracle and command


def test_oracle_detector(scene_dir):
    meta = load_scene(scene_dir)
    names = sorted({o["name"] for o in meta["instances"]})
    exact = OracleDetector(scene_dir, miss_rate=0.0, score_noise=0.0)
    total = missed = 0
    for i in range(0, meta["camera"]["frames"], 5):
        d = exact.detect(i, names)
        inst = exact.instance_mask(i)
        expect = {int(k) for k, c in zip(*np.unique(inst, return_counts=True)) if k and c >= exact.min_pixels}
        assert set(d.instance_ids.tolist()) == expect
        for b, k, mk, n, s in zip(d.boxes, d.instance_ids, d.masks, d.names, d.scores):
            ys, xs = np.nonzero(inst == k)
            assert list(b) == [xs.min(), ys.min(), xs.max() + 1, ys.max() + 1]
            assert np.array_equal(mk, inst == k) and exact.names[int(k)] == n and s == 1.0
        noisy = OracleDetector(scene_dir, miss_rate=0.5, score_noise=0.2, seed=1)
        dn = noisy.detect(i, names)
        assert set(dn.instance_ids.tolist()) <= expect
        assert np.all((dn.scores >= 0.05) & (dn.scores <= 1))
        d2 = noisy.detect(i, names[::-1])
        assert sorted(zip(dn.instance_ids.tolist(), dn.scores.tolist())) == \
            sorted(zip(d2.instance_ids.tolist(), d2.scores.tolist()))
        total += len(expect)
        missed += len(expect) - len(dn)
    assert total > 10 and 0.2 < missed / total < 0.8
    assert len(OracleDetector(scene_dir, miss_rate=1.0).detect(0, names)) == 0
    if "table" in names:  # vocabulary synonyms resolve to the category, names come back as asked
        d = exact.detect(next(r["index"] for r in meta["frames"] if any(exact.names[v["id"]] == "table" and
                                                                      v["pixels"] > 50 for v in r["visible"])),
                         ["desk"])
        assert d.names and set(d.names) == {"desk"}


def test_mosaic_synth_command(tmp_path, capsys):
    from mosaicthinker.runtime.cli import main

    rc = main(["synth", "--out", str(tmp_path / "o"), "--seed", "2", "--objects", "low", "--room", "small",
               "--duration", "1", "--fps", "4", "--size", "64x48", "--scenes", "2", "--json"])
    assert rc == 0
    res = json.loads(capsys.readouterr().out)
    assert res["schema"] == "mosaicthinker.synth/1" and len(res["scenes"]) == 2
    for k in range(2):
        d = tmp_path / "o" / f"scene_{k:03d}"
        assert len(list(d.glob("frame-*.color.jpg"))) == 4 and (d / "scene.json").exists()
    assert main(["synth", "--out", str(tmp_path / "o" / "scene_000"), "--duration", "1", "--fps", "2",
                 "--size", "64x48"]) == 2  # refuses to overwrite frames
