"""The bad-input / fault campaign of issue 12 as tests: every case ends in its outcome class (docs/reliability.md)
with a message naming the file or field, or in a correct answer whose degradation is printed.

Table rows: (case id, make(tmp) -> argv, expected exit code, fragment of stderr (exit 2/1) or stdout (exit 0)).
Commands run in-process through `cli.main` (the same code path as the `mosaic` script, minus the interpreter
start); the kill / concurrency / broken-pipe cases run real processes and are marked slow.
"""
from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Callable

import cv2
import numpy as np
import pytest

from mosaicthinker.runtime.infra import bundle as B
from mosaicthinker.runtime.cli import main
from mosaicthinker.runtime.infra.errors import BundleError, InputError
from mosaicthinker.runtime.frames import open_source
from mosaicthinker.runtime.geometry import OrientedBox
from mosaicthinker.runtime.map import ObjectInstance, SemanticMap

REPO = Path(__file__).resolve().parents[1]
Q_COUNT = "How many chair(s) are in this room?"
Q_DIST = "What is the distance between the chair and the table (in meters)?"


def run_cli(capsys, argv: list[str]) -> tuple[int, str, str]:
    code = main([os.fsdecode(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


# ----------------------------------------------------------------------------- fixtures: maps, folders, bundles

def small_map(path: Path) -> Path:
    """chair at (0, 0), table at (3, 4): distance 5 m between centres."""
    inst = [ObjectInstance(0, "chair", OrientedBox(np.array([0.0, 0, 0.5]), np.array([0.5, 0.5, 1.0]), np.eye(3))),
            ObjectInstance(1, "table", OrientedBox(np.array([3.0, 4, 0.4]), np.array([1.0, 1.0, 0.8]), np.eye(3)))]
    path.parent.mkdir(parents=True, exist_ok=True)
    SemanticMap(inst, None, [(0.0, np.eye(4))], {}).save(path)
    return path


def edit_map(tmp: Path, fn: Callable[[dict], None], raw: tuple[str, str] | None = None) -> Path:
    p = small_map(tmp / "map.json")
    d = json.loads(p.read_text())
    fn(d)
    text = json.dumps(d)
    p.write_text(text.replace(*raw) if raw else text)
    return p


def rgbd_folder(tmp: Path, n: int = 6, size: tuple[int, int] = (64, 48), depth_mm: int = 2000,
                grey: bool = False) -> Path:
    """A 7-Scenes style folder: textured frames, constant depth, identity poses, a plausible K."""
    d = tmp / "rgbd"
    d.mkdir(parents=True, exist_ok=True)
    W, H = size
    rng = np.random.default_rng(0)
    for i in range(n):
        img = rng.integers(0, 255, (H, W) if grey else (H, W, 3), dtype=np.uint8)
        cv2.imwrite(str(d / f"frame-{i:06d}.color.png"), img)
        cv2.imwrite(str(d / f"frame-{i:06d}.depth.png"), np.full((H, W), depth_mm, np.uint16))
        T = np.eye(4)
        T[0, 3] = 0.05 * i
        np.savetxt(d / f"frame-{i:06d}.pose.txt", T)
    K = np.array([[0.9 * W, 0, W / 2], [0, 0.9 * W, H / 2], [0, 0, 1]])
    np.savetxt(d / "camera-intrinsics.txt", K)
    return d


def write_video(path: Path, n: int, size: tuple[int, int]) -> Path:
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, size)
    assert vw.isOpened()
    rng = np.random.default_rng(1)
    for _ in range(n):
        vw.write(rng.integers(0, 255, (size[1], size[0], 3), dtype=np.uint8))
    vw.release()
    return path


def _graph(path: Path, external: bool = False, image: bool = False) -> Path:
    """image=False: y = x * w, x [1, 4] (w external when asked); image=True: x [1, 8, 8, 3] NHWC -> mean."""
    onnx = pytest.importorskip("onnx")
    from onnx import TensorProto as T
    from onnx import helper as h
    from onnx import numpy_helper as nh

    if image:
        g = h.make_graph([h.make_node("ReduceMean", ["x"], ["y"], keepdims=0, axes=[1, 2])], "img",
                         [h.make_tensor_value_info("x", T.FLOAT, [1, 8, 8, 3])],
                         [h.make_tensor_value_info("y", T.FLOAT, [1, 3])])
        m = h.make_model(g, opset_imports=[h.make_opsetid("", 17)])
    else:
        w = nh.from_array(np.arange(1, 5, dtype=np.float32), "w")
        g = h.make_graph([h.make_node("Mul", ["x", "w"], ["y"])], "tiny",
                         [h.make_tensor_value_info("x", T.FLOAT, [1, 4])],
                         [h.make_tensor_value_info("y", T.FLOAT, [1, 4])], [w])
        m = h.make_model(g, opset_imports=[h.make_opsetid("", 18)])
    m.ir_version = 9
    if external:
        onnx.save(m, str(path), save_as_external_data=True, location="weights.bin", size_threshold=0)
    else:
        onnx.save(m, str(path))
    return path


def tiny_bundle(tmp: Path, external: bool = False, image: bool = False) -> Path:
    from mosaicthinker.export.common import add_variant_files, role_meta

    src = tmp / "src"
    src.mkdir(parents=True, exist_ok=True)
    g = _graph(src / "g.onnx", external, image)
    pp = {"size": [8, 8], "layout": "NHWC", "dtype": "float32", "scale": 1 / 255} if image else {}
    meta = role_meta("embedding_generic", preprocessing=pp, semantics={"dim": 3 if image else 4},
                     provenance={"source": "test:tiny"}, licence="Apache-2.0", random_weights=False)
    out = tmp / "bundle"
    add_variant_files(out, "embedder", "fp32", {"model": g}, meta=meta, precision="fp32")
    return out


def edit_manifest(tmp: Path, fn: Callable[[dict], None], text: Callable[[str], str] | None = None) -> Path:
    b = tiny_bundle(tmp)
    mp = b / "manifest.json"
    m = json.loads(mp.read_text())
    fn(m)
    s = json.dumps(m)
    mp.write_text(text(s) if text else s)
    return b


def role(m: dict) -> dict:
    return m["roles"]["embedder"]


PROFILE = (REPO / "profiles" / "cpu-generic.toml").read_text()


def profile_with(tmp: Path, old: str, new: str) -> Path:
    assert old in PROFILE
    p = tmp / "p.toml"
    p.write_text(PROFILE.replace(old, new, 1))
    return p


def _set(d: dict, path: str, value) -> None:
    keys = path.split(".")
    for k in keys[:-1]:
        d = d[int(k)] if isinstance(d, list) else d[k]
    d[int(keys[-1]) if isinstance(d, list) else keys[-1]] = value


# ----------------------------------------------------------------------------- the table

def _case_maps():
    box = "instances.0.box"
    return [
        ("map_nan_centroid", lambda t: ["ask", edit_map(t, lambda d: _set(d, box + ".centroid", [float("nan"), 0, 0])),
                                        Q_COUNT], 2, "NaN"),
        ("map_inf_camera", lambda t: ["ask", edit_map(t, lambda d: _set(d, "cameras.0.T_wc.0.3", 12345.5),
                                                               ("12345.5", "1e999")), Q_COUNT],
         2, "cameras[0].T_wc holds NaN or infinity"),
        ("map_missing_name", lambda t: ["ask", edit_map(t, lambda d: d["instances"][0].pop("name")), Q_COUNT],
         2, "instances[0].name is missing"),
        ("map_missing_box", lambda t: ["ask", edit_map(t, lambda d: d["instances"][1].pop("box")), Q_COUNT],
         2, "instances[1].box is missing"),
        ("map_missing_centroid", lambda t: ["ask", edit_map(t, lambda d: d["instances"][0]["box"].pop("centroid")),
                                            Q_COUNT], 2, "box.centroid is missing"),
        ("map_negative_size", lambda t: ["ask", edit_map(t, lambda d: _set(d, box + ".axesLengths", [-1, 1, 1])),
                                         Q_COUNT], 2, "sizes must be > 0"),
        ("map_zero_axes", lambda t: ["ask", edit_map(t, lambda d: _set(d, box + ".normalizedAxes", [0] * 9)), Q_DIST],
         2, "orthonormal"),
        ("map_missing_instances", lambda t: ["ask", edit_map(t, lambda d: d.pop("instances")), Q_COUNT],
         2, "instances is missing"),
        ("map_duplicate_ids", lambda t: ["ask", edit_map(t, lambda d: _set(d, "instances.1.id", 0)), Q_COUNT],
         2, "duplicates"),
        ("map_not_json", lambda t: ["ask", _write(t / "map.json", b"{\"schema\": "), Q_COUNT], 2, "cannot read"),
        ("map_ok_distance", lambda t: ["ask", small_map(t / "map.json"), Q_DIST], 0,
         "closest points of chair #0 and table #1: 3.953 m"),
        ("map_json_deep", lambda t: ["ask", _write(t / "map.json", b"[" * 100000 + b"]" * 100000), Q_COUNT], 2,
         "map.json"),
        ("map_empty_instances", lambda t: ["ask", edit_map(t, lambda d: d.update(instances=[])), Q_COUNT], 0,
         "not found"),
    ]


def _write(p: Path, data: bytes) -> Path:
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_bytes(data)
    return p


def _case_inputs():
    plan = ["plan", "--profile", "cpu-generic", "--video"]

    def metres(t):
        d = rgbd_folder(t)
        for p in d.glob("*.depth.png"):
            cv2.imwrite(str(p), np.full((48, 64), 2, np.uint16))  # "2" = 2 m written into a mm PNG
        return plan + [d]

    def intr(t, K):
        d = rgbd_folder(t)
        np.savetxt(d / "camera-intrinsics.txt", np.array(K, float))
        return plan + [d]

    def gravity(t, g):
        d = rgbd_folder(t)
        np.savetxt(d / "gravity-direction.txt", np.array(g, float))
        return plan + [d]

    def tiny_video(t):
        return plan + [write_video(t / "v.avi", 8, (1, 1)) if _can_write_1x1(t) else _fake_1x1(t)]

    return [
        ("depth_in_metres", metres, 2, "seems to hold metres"),
        ("intrinsics_zero", lambda t: intr(t, [[0, 0, 32], [0, 0, 24], [0, 0, 1]]), 2, "must be positive"),
        ("intrinsics_negative", lambda t: intr(t, [[-58, 0, 32], [0, 58, 24], [0, 0, 1]]), 2, "must be positive"),
        ("intrinsics_fov", lambda t: intr(t, [[0.5, 0, 32], [0, 0.5, 24], [0, 0, 1]]), 2, "field of view"),
        ("intrinsics_principal", lambda t: intr(t, [[58, 0, 900], [0, 58, 24], [0, 0, 1]]), 2, "principal point"),
        ("gravity_flipped", lambda t: gravity(t, [0, -1, 0]), 2, "gravity points 180 degrees"),
        ("gravity_zero", lambda t: gravity(t, [0, 0, 0]), 2, "gravity direction is zero"),
        ("gravity_ok", lambda t: gravity(t, [0, 1, 0]), 0, "key frames K"),
        ("video_1x1", tiny_video, 2, "at least 16x16"),
        ("video_empty", lambda t: plan + [_write(t / "v.mp4", b"")], 2, "video file is empty"),
        ("video_garbage", lambda t: plan + [_write(t / "v.mp4", b"\x00" * 4096)], 2, "v.mp4"),
        ("folder_missing", lambda t: plan + [t / "nope"], 2, "no such file or folder"),
        ("e2e_scenes_negative", lambda t: ["eval", "e2e", "--scenes", "-1", "--out", str(t / "e2e")], 2,
         "--scenes must be at least 1"),
        ("synth_scenes_zero", lambda t: ["synth", "--scenes", "0", "--out", str(t / "s")], 2,
         "--scenes must be at least 1"),
        ("vsibench_meta_not_json", lambda t: vsi(t, b"x = [", QLINE), 2, "not a JSON file"),
        ("vsibench_meta_a_list", lambda t: vsi(t, b"[1, 2]", QLINE), 2, "must map scene names"),
        ("vsibench_meta_scene_a_list", lambda t: vsi(t, b'{"s": [1]}', QLINE), 2, "scene 's' is not an object"),
        ("vsibench_question_a_number", lambda t: vsi(t, b'{"s": {"object_bbox": {}}}', b"5\n"), 2,
         "a question must be a JSON object"),
    ]


QLINE = b'{"scene_name": "s", "question_type": "object_counting", "question": "How many chair(s)?", "ground_truth": 1}\n'


def vsi(t: Path, meta: bytes, questions: bytes) -> list:
    """`mosaic eval vsibench` on a meta_info and a questions file written as given (an internal error before)."""
    return ["eval", "vsibench", "--meta", _write(t / "meta.json", meta), "--questions", _write(t / "q.jsonl", questions)]


def _can_write_1x1(t: Path) -> bool:
    vw = cv2.VideoWriter(str(t / "probe.avi"), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (1, 1))
    ok = vw.isOpened()
    vw.release()
    return ok


def _fake_1x1(t: Path) -> Path:  # an image folder of 1x1 frames exercises the same size check
    d = t / "tiny"
    d.mkdir()
    for i in range(3):
        cv2.imwrite(str(d / f"{i}.png"), np.zeros((1, 1, 3), np.uint8))
    return d


def _case_profiles():
    pl = ["plan", "--profile"]
    clip = ["--duration", "10", "--fps", "30"]
    return [
        ("duration_huge", lambda t: pl + ["cpu-generic", "--duration", "1e308", "--fps", "30"], 2, "at most 86400"),
        ("duration_nan", lambda t: pl + ["cpu-generic", "--duration", "nan", "--fps", "30"], 2, "duration must be"),
        ("candidates_negative", lambda t: pl + ["cpu-generic", *clip, "--candidates", "-10"], 2, "--candidates"),
        ("clip_one_frame", lambda t: pl + ["cpu-generic", "--duration", "0.001", "--fps", "30"], 2,
         "at least 2 views"),
        ("input_size_int", lambda t: pl + [profile_with(t, "input_size_px = [\n    640,\n    448,\n]", "input_size_px = 640"),
                                           *clip], 2, "input_size_px"),
        ("threads_huge", lambda t: pl + [profile_with(t, "intra_op_threads = 2", "intra_op_threads = 100000"), *clip],
         2, "runtime.intra_op_threads must be an integer in 1..256"),
        ("affinity_bad", lambda t: pl + [profile_with(t, "intra_op_threads = 2",
                                                      "intra_op_threads = 2\ncore_affinity = [1, 1]"), *clip],
         2, "core_affinity"),
        ("toml_not_utf8", lambda t: pl + [_write(t / "p.toml", PROFILE.encode() + b"\n# \xff\xfe\n"), *clip], 2,
         "not UTF-8"),
        ("toml_deep", lambda t: pl + [_write(t / "p.toml", b"a = " + b"[" * 100000 + b"]" * 100000 + b"\n"), *clip],
         2, "p.toml"),
        ("profile_ok", lambda t: pl + ["cpu-generic", *clip], 0, "key frames K"),
        ("fps_inf", lambda t: pl + ["cpu-generic", "--duration", "10", "--fps", "inf"], 2, "--fps must be > 0"),
        ("synth_duration_huge", lambda t: ["synth", "--out", t / "s", "--duration", "1e308"], 2, "at most 86400"),
        ("e2e_duration_huge", lambda t: ["eval", "e2e", "--out", t / "e", "--duration", "1e308"], 2,
         "at most 86400"),
        ("threads_over_cores_ok", lambda t: pl + [profile_with(t, "intra_op_threads = 2", "intra_op_threads = 200"),
                                                  *clip], 0, "key frames K"),
    ]


def _case_bundles():
    verify = ["bundle", "verify"]

    def unlisted(t):
        b = tiny_bundle(t)
        (b / "embedder" / "fp32" / "weights.bin").write_bytes(b"\x00" * 16)
        return verify + [b]

    def ext_tampered(t):
        b = tiny_bundle(t, external=True)
        f = b / "embedder" / "fp32" / "weights.bin"
        w = np.frombuffer(f.read_bytes(), np.float32)
        f.write_bytes((-w).tobytes())  # negated weights: the campaign's silent case
        return verify + [b]

    def ext_unlisted(t):
        b = tiny_bundle(t, external=True)
        m = json.loads((b / "manifest.json").read_text())
        role(m)["variants"]["fp32"]["components"]["model"].pop("extra_files")
        (b / "manifest.json").write_text(json.dumps(m))
        return verify + [b]

    def symlinked(t):
        b = tiny_bundle(t)
        outside = t / "elsewhere.json"
        shutil.move(b / "manifest.json", outside)
        (b / "manifest.json").symlink_to(outside)
        return verify + [b]

    def dup(t):
        return verify + [edit_manifest(t, lambda m: None, lambda s: s.replace('"schema":', '"tool": "x", "tool":', 1)
                                       .replace('"tool": "x", "tool":', '"schema": "x", "schema":', 1))]

    def upper(t):
        def f(m):
            c = role(m)["variants"]["fp32"]["components"]["model"]
            c["sha256"] = c["sha256"].upper()
        return verify + [edit_manifest(t, f)]

    sem = lambda k, v: (lambda t: verify + [edit_manifest(t, lambda m: _set(role(m), k, v))])  # noqa: E731
    return [
        ("bundle_unlisted_file", unlisted, 2, "is not listed"),
        ("bundle_external_data_tampered", ext_tampered, 2, "weights.bin: sha256 mismatch"),
        ("bundle_external_data_unlisted", ext_unlisted, 2, "external data 'weights.bin'"),
        ("bundle_external_data_ok", lambda t: verify + [tiny_bundle(t, external=True)], 0, "all sha256 match"),
        ("bundle_manifest_symlink_out", symlinked, 2, "outside the bundle"),
        ("bundle_duplicate_keys", dup, 2, "duplicate key 'schema'"),
        ("bundle_uppercase_sha", upper, 0, "all sha256 match"),
        ("bundle_labels_string", sem("semantics.labels", "chair,table"), 2, "semantics.labels must be a list"),
        ("bundle_semantics_list", sem("semantics", ["dim"]), 2, "semantics must be an object"),
        ("bundle_size_string", sem("preprocessing", {"size": "8x8"}), 2, "preprocessing.size must be"),
        ("bundle_scale_string", sem("preprocessing", {"scale": "1/255"}), 2, "preprocessing.scale must be"),
        ("bundle_dtype_bad", sem("preprocessing", {"dtype": "float"}), 2, "preprocessing.dtype must be"),
        ("bundle_config_list", sem("config", [1]), 2, "config must be an object"),
        ("bundle_default_variant_int", sem("default_variant", 3), 2, "default_variant must be"),
        ("bundle_random_weights_no", sem("random_weights", "no"), 2, "random_weights must be true or false"),
        ("bundle_random_weights_missing", lambda t: verify + [edit_manifest(t, lambda m: role(m).pop("random_weights"))],
         2, "random_weights is missing"),
    ]


CASES = _case_maps() + _case_inputs() + _case_profiles() + _case_bundles()


@pytest.mark.parametrize("make,code,fragment", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_bad_input_table(tmp_path, capsys, make, code, fragment):
    argv = make(tmp_path)
    got, out, err = run_cli(capsys, argv)
    assert got == code, (out, err)
    text = out if code == 0 else err
    assert fragment in text, (out, err)
    if code == 2:
        assert err.startswith("error: ") and len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert "Traceback" not in err


# ----------------------------------------------------------------------------- degraded but correct: noted

def test_truncated_video_is_reported(tmp_path):
    v = write_video(tmp_path / "v.avi", 40, (64, 48))
    data = v.read_bytes()
    v.write_bytes(data[:len(data) // 2])
    src = open_source(v)
    assert len(src) < 40 and any("partial video" in n and "of the 40 frames" in n for n in src.notes)


def test_missing_depth_files_are_noted_and_unreadable_ones_refused(tmp_path):
    d = rgbd_folder(tmp_path, n=8)
    (d / "frame-000003.depth.png").unlink()
    src = open_source(d)
    assert not src.has_depth and any("1 of 8 frames have no depth file" in n for n in src.notes)
    (d / "frame-000005.depth.png").write_bytes(b"not a png")
    with pytest.raises(InputError, match=r"frame-000005\.depth\.png: cannot decode the depth image"):
        src[5]


def test_zero_pose_is_refused_naming_the_file(tmp_path):
    d = rgbd_folder(tmp_path)
    np.savetxt(d / "frame-000002.pose.txt", np.zeros((4, 4)))
    with pytest.raises(InputError, match=r"frame-000002\.pose\.txt: not a rigid camera-to-world pose"):
        open_source(d)[2]


def test_greyscale_folder_is_noted_and_delivered_as_rgb(tmp_path):
    src = open_source(rgbd_folder(tmp_path, grey=True))
    f = src[0]
    assert f.rgb.shape[2] == 3 and any(n.startswith("greyscale") for n in src.notes)


def test_huge_frames_are_downscaled_at_decode_with_K(tmp_path):
    d = rgbd_folder(tmp_path, n=2, size=(4000, 3000))
    src = open_source(d)
    f = src[1]
    assert f.rgb.shape == (1440, 1920, 3) and f.depth.shape == (1440, 1920) and src.size == (1920, 1440)
    assert f.K[0, 0] == pytest.approx(0.9 * 4000 * 1920 / 4000) and any("downscaled" in n for n in src.notes)


def test_non_utf8_file_names_and_out_path(tmp_path, capsys):
    d = tmp_path / os.fsdecode(b"imgs-\xff")
    d.mkdir()
    rng = np.random.default_rng(0)
    for i in range(3):
        name = os.fsdecode(b"frame-\xfe" + str(i).encode() + b".png")
        ok, buf = cv2.imencode(".png", rng.integers(0, 255, (48, 64, 3), dtype=np.uint8))
        (d / name).write_bytes(buf.tobytes())
    src = open_source(d)
    assert len(src) == 3 and src[2].rgb.shape == (48, 64, 3)
    v = write_video(tmp_path / "plain.avi", 12, (64, 48)).rename(tmp_path / os.fsdecode(b"v\xff.avi"))
    vs = open_source(v)
    assert len(vs) == 12 and vs[11].rgb.shape == (48, 64, 3)
    out = tmp_path / os.fsdecode(b"out-\xff")
    code, stdout, err = run_cli(capsys, ["ask", str(small_map(tmp_path / "m.json")), Q_COUNT, "--out", str(out)])
    assert code == 0, err
    assert (out / "map.png").read_bytes()[:4] == b"\x89PNG" and json.loads((out / "map.json").read_text())


def test_core_affinity_is_applied_or_refused_loudly():
    from mosaicthinker.runtime.budget import load_profile
    from mosaicthinker.runtime.infra.trace import Trace

    p = load_profile("cpu-generic")
    p.core_affinity = [10_000]  # no such core here
    p.intra_op_threads = 10_000
    tr = Trace()
    before = os.sched_getaffinity(0)
    p.apply_to_machine(tr)
    msgs = [e["message"] for e in tr.events if e["kind"] == "degraded"]
    assert any("core_affinity [10000] not applied" in m for m in msgs)
    assert p.intra_op_threads == len(before) and any("usable cores" in m for m in msgs)
    assert os.sched_getaffinity(0) == before


def test_core_affinity_that_exists_is_applied():
    from mosaicthinker.runtime.budget import load_profile
    from mosaicthinker.runtime.infra.trace import Trace

    before = os.sched_getaffinity(0)
    p = load_profile("cpu-generic")
    p.core_affinity = [min(before)]
    tr = Trace()
    try:
        p.apply_to_machine(tr)
        assert os.sched_getaffinity(0) == {min(before)}  # really pinned, not only accepted
        assert tr.decisions["budget.core_affinity"] == [min(before)]
        assert not [e for e in tr.events if "core_affinity" in e["message"]]
    finally:
        os.sched_setaffinity(0, before)


def test_profile_out_is_written_as_one_group_and_checked_first(tmp_path, capsys):
    from mosaicthinker.host.report import save_report

    f = tmp_path / "file"
    f.write_text("x")
    code, _, err = run_cli(capsys, ["profile", "--bundle", str(tmp_path / "nobundle"), "--out", str(f)])
    assert code == 2 and "is a file, not a folder" in err  # refused before the bundle is even read
    rep = {"schema": "x", "bundle": "b", "bundle_hash": "h", "date": "d", "profile": None, "threads": None,
           "runs": 1, "warmup": 1, "frames_from": "f", "peak_rss_mb": 1.0, "process": {"rss_baseline_mb": 1.0},
           "machine": {"processor": "p", "cpu_count": 1, "platform": "l"}, "roles": {}, "cpu_side": {}}
    out = tmp_path / "rep"
    res = save_report(rep, out)
    run = json.loads((out / "run.json").read_text())
    assert run["status"] == "complete" and run["run_id"] == res["run_id"] and "write_error" not in res
    assert sorted(run["files"]) == ["latency.png", "memory.png", "report.json", "report.md"]
    assert json.loads((out / "report.json").read_text())["run_id"] == res["run_id"]
    assert (out / "report.md").read_text().rstrip().endswith(f"<!-- run_id: {res['run_id']} -->")
    assert not list(out.glob(".mosaic*"))


def test_synth_out_is_one_group(tmp_path, capsys):
    out = tmp_path / "s"
    code, stdout, err = run_cli(capsys, ["synth", "--out", str(out), "--duration", "1", "--fps", "4", "--size",
                                         "64x48", "--scenes", "2", "--no-video", "--json"])
    assert code == 0, err
    rid = json.loads(stdout)["run_id"]
    run = json.loads((out / "run.json").read_text())
    assert run["status"] == "complete" and run["run_id"] == rid
    assert "scene_001/scene.json" in run["files"] and (out / "scene_000" / "frame-000000.color.jpg").is_file()
    assert not list(out.glob(".mosaic*"))
    code, _, err = run_cli(capsys, ["synth", "--out", str(out), "--duration", "1", "--fps", "4", "--scenes", "2"])
    assert code == 2 and "already holds frames" in err


def test_synth_failure_leaves_no_half_scene(tmp_path, capsys, monkeypatch):
    from mosaicthinker.host.synth import generate

    def boom(*a, **k):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(generate, "write_questions", boom)  # after every frame was written
    out = tmp_path / "s"
    code, _, err = run_cli(capsys, ["synth", "--out", str(out), "--duration", "1", "--fps", "4", "--size", "64x48",
                                    "--no-video"])
    assert code == 2 and "No space left" in err
    assert not list(out.glob("frame-*")) and not list(out.glob(".mosaic*"))


def test_preprocessing_mismatch_names_the_manifest_field(tmp_path):
    from mosaicthinker.runtime.models import load_role

    b = tiny_bundle(tmp_path, image=True)
    load_role(b, "embedder")  # consistent: loads
    for field_, value, msg in (("size", [16, 16], "preprocessing.size is [16, 16]"),
                               ("dtype", "uint8", "preprocessing.dtype is 'uint8'"),
                               ("layout", "NCHW", "preprocessing.layout is NCHW")):
        m = json.loads((b / "manifest.json").read_text())
        good = dict(role(m)["preprocessing"])
        role(m)["preprocessing"][field_] = value
        (b / "manifest.json").write_text(json.dumps(m))
        with pytest.raises(BundleError, match=msg.replace("[", r"\[").replace("]", r"\]")):
            load_role(b, "embedder")
        role(m)["preprocessing"] = good
        (b / "manifest.json").write_text(json.dumps(m))


def test_manifest_is_world_readable_and_import_needs_random_weights_said(tmp_path, capsys):
    b = tiny_bundle(tmp_path)
    assert (b / "manifest.json").stat().st_mode & 0o777 == 0o644
    g = _graph(tmp_path / "imp.onnx")
    side = tmp_path / "imp.onnx.mosaic.json"
    side.write_text(json.dumps({"arch": "embedding_generic", "licence": "MIT", "preprocessing": {},
                                "semantics": {"dim": 4}}))
    out = tmp_path / "b2"
    code, _, err = run_cli(capsys, ["export", "embedder", "--source", f"onnx:{g}", "--out", str(out)])
    assert code == 2 and "random_weights' is missing" in err and "--real-weights" in err
    side.write_text(json.dumps({"arch": "embedding_generic", "licence": "MIT", "preprocessing": {},
                                "semantics": {"dim": 4}, "random_weights": "no"}))
    code, _, err = run_cli(capsys, ["export", "embedder", "--source", f"onnx:{g}", "--out", str(out)])
    assert code == 2 and "must be true or false" in err
    side.write_text(json.dumps({"arch": "embedding_generic", "licence": "MIT", "preprocessing": {},
                                "semantics": {"dim": 4}}))
    code, _, err = run_cli(capsys, ["export", "embedder", "--source", f"onnx:{g}", "--out", str(out),
                                    "--random-weights"])
    assert code == 0, err
    assert B.load_bundle(out).role_meta("embedder")["random_weights"] is True


def test_map_beyond_the_stated_size_is_refused(tmp_path, capsys, monkeypatch):
    from mosaicthinker.runtime.map import model as semantic_map

    monkeypatch.setattr(semantic_map, "MAX_MAP_OBJECTS", 1)
    code, _, err = run_cli(capsys, ["ask", str(small_map(tmp_path / "m.json")), Q_COUNT])
    assert code == 2 and "2 objects; at most 1 are supported" in err


# ----------------------------------------------------------------------------- outputs and outcome classes

def test_out_that_is_a_file_is_refused_before_the_pipeline(tmp_path, capsys):
    f = tmp_path / "file"
    f.write_text("x")
    code, out, err = run_cli(capsys, ["ask", str(small_map(tmp_path / "m.json")), Q_COUNT, "--out", str(f)])
    assert code == 2 and "is a file, not a folder" in err and out == ""


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
def test_read_only_out_is_refused_before_the_pipeline(tmp_path, capsys):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    code, out, err = run_cli(capsys, ["ask", str(small_map(tmp_path / "m.json")), Q_COUNT, "--out", str(ro)])
    assert code == 2 and "not writable" in err and out == ""


def test_every_file_carries_the_run_id(tmp_path, capsys):
    from PIL import Image

    out = tmp_path / "o"
    code, stdout, err = run_cli(capsys, ["ask", str(small_map(tmp_path / "m.json")), Q_COUNT, "--out", str(out),
                                         "--json"])
    assert code == 0, err
    rid = json.loads(stdout)["run_id"]
    run = json.loads((out / "run.json").read_text())
    assert run["status"] == "complete" and run["run_id"] == rid
    assert json.loads((out / "map.json").read_text())["run_id"] == rid
    assert json.loads((out / "trace.json").read_text())["run_id"] == rid
    assert Image.open(out / "map.png").text["mosaicthinker_run_id"] == rid
    assert not list(out.glob(".mosaic*"))  # no lock, no temp file left


def test_live_lock_refuses_and_stale_lock_is_taken_over(tmp_path, capsys):
    out = tmp_path / "o"
    out.mkdir()
    m = str(small_map(tmp_path / "m.json"))
    import socket

    (out / ".mosaic.lock").write_text(json.dumps({"pid": os.getpid(), "host": socket.gethostname(), "run_id": "x"}))
    code, _, err = run_cli(capsys, ["ask", m, Q_COUNT, "--out", str(out)])
    assert code == 2 and "another run (pid" in err
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    (out / ".mosaic.lock").write_text(json.dumps({"pid": dead.pid, "host": socket.gethostname(), "run_id": "y"}))
    code, stdout, err = run_cli(capsys, ["ask", m, Q_COUNT, "--out", str(out)])
    assert code == 0, err
    assert "took over a stale lock" in stdout and (out / "map.json").is_file()


def test_late_write_failure_still_prints_the_answer(tmp_path, capsys, monkeypatch):
    import errno

    from mosaicthinker.runtime.infra import outputs

    out = tmp_path / "o"
    m = str(small_map(tmp_path / "m.json"))
    assert run_cli(capsys, ["ask", m, Q_COUNT, "--out", str(out)])[0] == 0
    before = (out / "map.json").read_bytes()

    def full(self, name, data):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(outputs.RunOutputs, "_stage", full)
    code, stdout, err = run_cli(capsys, ["ask", m, Q_DIST, "--out", str(out)])
    assert code == 2 and stdout.startswith("answer: 4.0")
    assert err.startswith("error: could not write the output files") and "disk is full" in err
    assert (out / "map.json").read_bytes() == before  # the previous run's files, untouched
    run = json.loads((out / "run.json").read_text())
    assert run["status"] == "failed" and "No space left" in run["reason"]  # and marked as not current
    assert run["previous"]["status"] == "complete" and run["previous"]["files"]  # whose files the folder keeps


def test_internal_error_is_one_line_and_traceback_only_with_debug(tmp_path, capsys, monkeypatch):
    from mosaicthinker.runtime import pipeline

    def boom(*a, **k):
        raise ValueError("synthetic bug")

    monkeypatch.setattr(pipeline, "ask", boom)
    m = str(small_map(tmp_path / "m.json"))
    code, _, err = run_cli(capsys, ["ask", m, Q_COUNT])
    assert code == 1 and err.startswith("internal error: ValueError: synthetic bug") and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1
    code, _, err = run_cli(capsys, ["ask", m, Q_COUNT, "--debug"])
    assert code == 1 and "Traceback" in err


# ----------------------------------------------------------------------------- processes: kill, concurrency, pipes

def _mosaic(*args: str, **kw) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "mosaicthinker.runtime.cli", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, **kw)


def _big_map(path: Path, n: int = 3000) -> Path:
    rng = np.random.default_rng(0)
    names = ("chair", "table", "sofa", "lamp")
    inst = [ObjectInstance(i, names[i % 4], OrientedBox(rng.uniform(0, 10, 3), rng.uniform(0.2, 1, 3), np.eye(3)))
            for i in range(n)]
    SemanticMap(inst, None, [], {}).save(path)
    return path


@pytest.mark.slow
def test_kill_concurrency_and_broken_pipe(tmp_path):
    m = str(_big_map(tmp_path / "big.json"))
    out = tmp_path / "o"
    # 1. two runs into one --out at once: one answers and leaves a valid map, the other is refused (or both
    #    finish one after the other); never an invalid map.json or a mixed folder.
    ps = [_mosaic("ask", m, Q_COUNT, "--out", str(out), "--json") for _ in range(2)]
    res = [(p.returncode, *p.communicate(timeout=120)) for p in ps]
    res = [(p.returncode, o, e) for p, (_, o, e) in zip(ps, res)]
    assert all(c in (0, 2) for c, _, _ in res) and any(c == 0 for c, _, _ in res), res
    for c, o, e in res:
        assert "Traceback" not in e
        if c == 2:
            assert "another run" in e
    done = [json.loads(o)["run_id"] for c, o, _ in res if c == 0]
    run = json.loads((out / "run.json").read_text())
    assert run["status"] == "complete" and run["run_id"] in done
    assert json.loads((out / "map.json").read_text())["run_id"] == run["run_id"]
    assert json.loads((out / "trace.json").read_text())["run_id"] == run["run_id"]
    before = (out / "map.json").read_bytes()
    # 2. kill -9 while a run holds the folder: the old files stay whole, run.json says the folder is not current,
    #    and the next run takes the stale lock over and says so.
    p = _mosaic("ask", m, Q_DIST, "--out", str(out))
    t0 = time.time()
    while not (out / ".mosaic.lock").exists() and time.time() - t0 < 60:
        time.sleep(0.02)
    os.kill(p.pid, signal.SIGKILL)
    p.communicate(timeout=30)
    assert (out / "map.json").read_bytes() == before
    assert json.loads((out / "run.json").read_text())["status"] in ("running", "complete")
    q = _mosaic("ask", m, Q_COUNT, "--out", str(out))
    o, e = q.communicate(timeout=120)
    assert q.returncode == 0, e
    assert "took over a stale lock" in o  # the killed run held the lock (we waited for it)
    assert json.loads((out / "run.json").read_text())["status"] == "complete"
    # 3. SIGTERM: a clean exit 143 with one line, the lock released
    p = _mosaic("ask", m, Q_DIST, "--out", str(out))
    t0 = time.time()
    while not (out / ".mosaic.lock").exists() and time.time() - t0 < 60:
        time.sleep(0.02)
    p.send_signal(signal.SIGTERM)
    o, e = p.communicate(timeout=60)
    assert p.returncode in (143, 0, 2), (p.returncode, e)  # 0/2: it finished before the signal landed
    assert "Traceback" not in e and not (out / ".mosaic.lock").exists()
    # 4. stdout piped to `head`: no BrokenPipe traceback, no signal death
    sh = subprocess.run(f"{sys.executable} -m mosaicthinker.runtime.cli ask {m} '{Q_COUNT}' --json | head -c 10; "
                        f"echo \" rc=${{PIPESTATUS[0]}}\"", shell=True, executable="/bin/bash", capture_output=True,
                        text=True, timeout=120)
    assert "rc=0" in sh.stdout and "Traceback" not in sh.stderr and "BrokenPipe" not in sh.stderr, sh


def test_one_view_says_why_there_is_no_map(tmp_path, capsys, shared_models, redkitchen):
    """A video that shows one view (three copies of one frame) cannot be mapped: exit 2, and the error says that
    redundant-frame removal kept one frame (was "only 1 key frame(s) available", with no reason)."""
    from mosaicthinker.export.onnx_import import import_shared_models

    b = tmp_path / "bundle"
    import_shared_models(shared_models, b, ["fp32"], roles=["detector", "depth"])
    frame = cv2.imread(str(sorted(Path(redkitchen).glob("frame-*.color.jpg"))[0]))
    vw = cv2.VideoWriter(str(tmp_path / "still.mp4"), cv2.VideoWriter_fourcc(*"mp4v"), 15.0, frame.shape[1::-1])
    for _ in range(3):
        vw.write(frame)
    vw.release()
    code, _, err = run_cli(capsys, ["ask", str(tmp_path / "still.mp4"), "how many chairs?", "--bundle", str(b)])
    assert code == 2 and "redundant-frame removal kept 1 of the 3 frames" in err, err
