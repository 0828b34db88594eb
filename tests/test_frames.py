"""Frame sources: 7-Scenes (real and written), TUM, image folders, video; clear errors on bad input."""
from __future__ import annotations

import io
from pathlib import Path

import cv2
import numpy as np
import pytest

from mosaicthinker.runtime.infra.errors import InputError
from mosaicthinker.runtime.frames import (FrameList, ImageFolderSource, SevenScenesSource, TUMSource, VideoSource,
                                          open_source)
from mosaicthinker.runtime.geometry import make_pose, rotation_about


def _img(seed: int, w: int = 64, h: int = 48) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, size=(h, w, 3), dtype=np.uint8)


def _write_7scenes(root: Path, n: int = 3, timestamps: bool = False) -> list[np.ndarray]:
    root.mkdir(parents=True, exist_ok=True)
    poses = []
    for i in range(n):
        cv2.imwrite(str(root / f"frame-{i:06d}.color.png"), _img(i)[:, :, ::-1])
        d = np.full((48, 64), 1000 + 100 * i, np.uint16)
        d[0, 0], d[0, 1] = 0, 65535
        cv2.imwrite(str(root / f"frame-{i:06d}.depth.png"), d)
        T = make_pose(rotation_about([0, 1, 0], 0.1 * i), [0.1 * i, 0, 0])
        np.savetxt(root / f"frame-{i:06d}.pose.txt", T)
        poses.append(T)
    np.savetxt(root / "camera-intrinsics.txt", np.array([[50.0, 0, 32], [0, 50, 24], [0, 0, 1]]))
    if timestamps:
        (root / "timestamps.txt").write_text("".join(f"{i} {0.5 * i:.3f}\n" for i in range(n)))
    return poses


def test_real_7scenes(redkitchen):
    src = open_source(redkitchen)
    assert isinstance(src, SevenScenesSource) and len(src) == 250 and src.size == (640, 480)
    assert np.allclose(np.diff(src.timestamps), 2 / 30)  # every 2nd frame of a 30 fps recording
    f = src[10]
    assert f.rgb.shape == (480, 640, 3) and f.rgb.dtype == np.uint8
    assert f.depth.dtype == np.float32 and 0.3 < np.median(f.depth[f.depth > 0]) < 5
    assert f.pose_gt.shape == (4, 4) and np.allclose(f.pose_gt[3], [0, 0, 0, 1])
    assert f.K[0, 0] == 585 and src.gravity is not None and np.linalg.norm(src.gravity) == pytest.approx(1)
    assert np.linalg.norm(src.gravity_camera(0)) == pytest.approx(1)


def test_written_7scenes_roundtrip(tmp_path):
    poses = _write_7scenes(tmp_path / "s", timestamps=True)
    src = open_source(tmp_path / "s")
    assert len(src) == 3 and np.allclose(src.timestamps, [0, 0.5, 1.0])
    f = src[2]
    assert np.array_equal(f.rgb, _img(2))
    assert f.depth[5, 5] == pytest.approx(1.2) and f.depth[0, 0] == 0 and f.depth[0, 1] == 0  # 65535 invalid
    assert np.allclose(f.pose_gt, poses[2]) and f.K[0, 0] == 50
    assert src[-1].index == 2
    with pytest.raises(IndexError):
        src[3]


@pytest.mark.parametrize("what", ["color", "depth", "pose", "intrinsics"])
def test_7scenes_corrupt_files_name_the_file(tmp_path, what):
    root = tmp_path / "s"
    _write_7scenes(root)
    bad = {"color": root / "frame-000001.color.png", "depth": root / "frame-000001.depth.png",
           "pose": root / "frame-000001.pose.txt", "intrinsics": root / "camera-intrinsics.txt"}[what]
    bad.write_bytes(b"\x89PNG garbage" if what != "pose" else b"1 2 3\nnot numbers")
    with pytest.raises(InputError, match=bad.name):
        src = open_source(root)
        src[1]


def test_empty_and_missing_inputs(tmp_path):
    with pytest.raises(InputError, match="no such"):
        open_source(tmp_path / "nope")
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match="empty"):
        open_source(tmp_path / "empty")
    (tmp_path / "v.mp4").write_bytes(b"")
    with pytest.raises(InputError, match="v.mp4"):
        open_source(tmp_path / "v.mp4")
    (tmp_path / "junk.avi").write_bytes(np.random.default_rng(0).bytes(5000))
    with pytest.raises(InputError, match="junk.avi"):
        open_source(tmp_path / "junk.avi")
    (tmp_path / "imgs").mkdir()
    (tmp_path / "imgs" / "a.jpg").write_bytes(b"")
    with pytest.raises(InputError, match="a.jpg"):
        open_source(tmp_path / "imgs")


def test_image_folder(tmp_path):
    for i in (10, 2, 1):  # natural sort order: 1, 2, 10
        cv2.imwrite(str(tmp_path / f"img{i}.png"), _img(i)[:, :, ::-1])
    src = open_source(tmp_path, fps=10.0, hfov_deg=90.0)
    assert isinstance(src, ImageFolderSource) and len(src) == 3
    assert np.array_equal(src[2].rgb, _img(10)) and np.allclose(src.timestamps, [0, 0.1, 0.2])
    assert src.K[0, 0] == pytest.approx(32.0)  # 64 px wide at 90 degrees
    cv2.imwrite(str(tmp_path / "img11.png"), _img(3, w=32)[:, :, ::-1])
    with pytest.raises(InputError, match="img11.png"):
        open_source(tmp_path)[3]


def test_tum_layout(tmp_path):
    (tmp_path / "rgb").mkdir()
    (tmp_path / "depth").mkdir()
    rgb_lines, depth_lines, gt_lines = ["# rgb"], ["# depth"], ["# gt"]
    for i in range(3):
        t = 100.0 + 0.1 * i
        big = cv2.resize(_img(i), (640, 480), interpolation=cv2.INTER_NEAREST)  # TUM's published K is for 640x480
        cv2.imwrite(str(tmp_path / f"rgb/{t:.4f}.png"), big[:, :, ::-1])
        cv2.imwrite(str(tmp_path / f"depth/{t + 0.005:.4f}.png"), np.full((480, 640), 5000 * (i + 1), np.uint16))
        rgb_lines.append(f"{t:.4f} rgb/{t:.4f}.png")
        depth_lines.append(f"{t + 0.005:.4f} depth/{t + 0.005:.4f}.png")
        gt_lines.append(f"{t + 0.001:.4f} {i} 0 0 0 0 0.7071068 0.7071068")  # 90 deg about z
    for name, lines in (("rgb.txt", rgb_lines), ("depth.txt", depth_lines), ("groundtruth.txt", gt_lines)):
        (tmp_path / name).write_text("\n".join(lines) + "\n")
    src = open_source(tmp_path)
    assert isinstance(src, TUMSource) and len(src) == 3 and src.has_depth and src.has_pose
    f = src[1]
    big = cv2.resize(_img(1), (640, 480), interpolation=cv2.INTER_NEAREST)
    assert np.array_equal(f.rgb, big) and f.depth[3, 3] == pytest.approx(2.0)  # 10000 / 5000
    assert np.allclose(f.pose_gt[:3, 3], [1, 0, 0]) and np.allclose(f.pose_gt[:3, 0], [0, 1, 0], atol=1e-6)
    assert f.K[0, 0] == 525.0  # ROS default (no freiburg name)


def _write_video(path: Path, n: int = 12, fps: float = 10.0) -> bool:
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), fps, (64, 48))
    if not vw.isOpened():
        return False
    for i in range(n):
        vw.write(np.full((48, 64, 3), 10 + 20 * i, np.uint8))
    vw.release()
    return path.exists() and path.stat().st_size > 0


def test_video_random_access(tmp_path):
    p = tmp_path / "clip.avi"
    if not _write_video(p):
        pytest.skip("this OpenCV build cannot write MJPG video")
    src = open_source(p, cache_size=2)
    assert isinstance(src, VideoSource) and len(src) == 12 and src.size == (64, 48)
    assert np.all(np.diff(src.timestamps) > 0)
    for i in (7, 2, 11, 0, 7):  # out of order: forward decoding, re-open when going back
        assert abs(int(np.median(src[i].rgb)) - (10 + 20 * i)) <= 3
    src.prefetch([3, 4, 5])
    assert abs(int(np.median(src[4].rgb)) - 90) <= 3


def test_frame_list():
    from mosaicthinker.runtime.types import Frame

    K = np.eye(3)
    fl = FrameList([Frame(_img(i), 0.1 * i, 5 + i, K) for i in range(3)])
    assert len(fl) == 3 and fl[1].index == 6 and fl.size == (64, 48)
    with pytest.raises(InputError):
        FrameList([])


def _write_mp4(path: Path, n: int, fps: float = 15.0) -> bool:
    """An mp4 (MPEG-4 part 2, key frame every 12 frames by OpenCV's default) whose frames all differ: a moving
    textured pattern, so an off-by-one frame is detected."""
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (96, 64))
    if not vw.isOpened():
        return False
    rng = np.random.default_rng(0)
    tex = rng.integers(0, 256, (64, 192, 3), dtype=np.uint8)
    tex = cv2.GaussianBlur(tex, (5, 5), 0)
    for i in range(n):
        fr = np.ascontiguousarray(np.roll(tex, 3 * i, axis=1)[:, :96])
        cv2.putText(fr, str(i), (5, 40), cv2.FONT_HERSHEY_SIMPLEX, 1.0, (255, 255, 255), 2)
        vw.write(fr)
    vw.release()
    return path.exists() and path.stat().st_size > 0


def test_mp4_random_access_equals_sequential(tmp_path):
    p = tmp_path / "clip.mp4"
    if not _write_mp4(p, 90):
        pytest.skip("this OpenCV build cannot write mp4v video")
    seq = [f.rgb.copy() for f in open_source(p, cache_size=0)]  # forward decoding only
    assert len(seq) == 90
    src = open_source(p, cache_size=4)
    order = np.random.default_rng(1).permutation(90)[:40].tolist() + [89, 0, 60, 59, 5, 88, 1]
    for i in order:  # backward seeks and long forward jumps
        assert np.array_equal(src[i].rgb, seq[i]), f"frame {i} differs from sequential decoding ({src.seek_mode})"
    assert src.seek_mode in ("verified", "sequential")
    src.prefetch([70, 10, 40, 11])  # one sorted pass, then served from the cache
    for i in (10, 11, 40, 70):
        assert i in src._cache and np.array_equal(src[i].rgb, seq[i])


def test_scan_decoder_threads_change_no_frame(tmp_path, monkeypatch):
    """VideoSource.scan_decoder_threads sets FFmpeg's decoder threads of the opening scan: a speed setting,
    the same timestamps, frames and online redundant-frame removal whatever its value."""
    from mosaicthinker.runtime.scan import DedupConf, online_result, open_scanned

    p = tmp_path / "clip.mp4"
    if not _write_mp4(p, 60):
        pytest.skip("this OpenCV build cannot write mp4v video")
    runs = []
    for threads in (None, 1, 2):
        monkeypatch.setattr(VideoSource, "scan_decoder_threads", threads)
        src = open_scanned(p)
        if threads:
            assert src._open(threads).get(cv2.CAP_PROP_N_THREADS) == threads  # the backend took the setting
        runs.append((src.timestamps, src[37].rgb, online_result(src, DedupConf()).to_dict()))
    for ts, rgb, dd in runs[1:]:
        assert np.array_equal(ts, runs[0][0]) and np.array_equal(rgb, runs[0][1]) and dd == runs[0][2]
    assert len(runs[0][0]) == 60 and len(runs[0][2]["kept"]) > 5


def test_the_scan_keeps_the_searchs_colour_histograms_and_the_search_reads_them(tmp_path):
    """A video's opening scan stores each kept frame's colour histogram (`DedupConf.histograms`): exactly the
    search's `colour_histogram` of the frame the source gives, so the search's kernel widths read them instead
    of decoding every scored frame's +-r neighbours: the same key frames, only the scored frames decoded."""
    from mosaicthinker.runtime.pipeline import open_frames
    from mosaicthinker.runtime.scan import DedupConf, colour_histogram, online_result
    from mosaicthinker.runtime.types import Detections
    from mosaicthinker.runtime.pipeline import Perception, PipelineConfig, select
    from mosaicthinker.runtime.infra.trace import Trace

    p = tmp_path / "clip.mp4"
    if not _write_mp4(p, 150):
        pytest.skip("this OpenCV build cannot write mp4v video")
    dd = online_result(open_frames(p), DedupConf())  # the pipeline's scan: the search's histograms kept
    assert len(dd.histograms) == len(dd.kept) > 20
    src = open_source(p)
    assert all(np.array_equal(dd.histograms[f], colour_histogram(src.colour(f).rgb)) for f in dd.kept)

    def chair(frame, names):  # every frame shows a chair, its score varying with the frame
        s = 0.3 + 0.6 * ((int(frame.index) * 7) % 10) / 10
        return Detections(np.array([[10, 10, 60, 50]], np.float32), np.array([s], np.float32), ["chair"])

    runs = []
    for conf in ({}, {"dedup": {"histograms": False}}):
        src = open_frames(p)
        read: set[int] = set()
        colour = src.colour
        src.colour = lambda i, _c=colour: (read.add(int(i)), _c(i))[1]
        _, _, res, _ = select(src, ["chair"], [], Perception(detect=chair), PipelineConfig.merged(
            {**conf, "keyframe": {"budget": 8}}), Trace(), keyframes=3)
        runs.append((res.chosen.tolist(), set(res.order), read))
    (chosen, scored, read), (chosen_b, _, read_b) = runs
    assert chosen == chosen_b and read <= scored < read_b


def test_opening_a_video_is_a_stage_of_its_own(tmp_path):
    """A video's opening scan decodes every frame and removes redundant ones on the way: `pipeline.open_frames`
    times it as the "open" stage (trace and summary line), which `ask` and `map` print before "dedup" (whose
    own time is then ~0): the summary accounts for the scan."""
    from mosaicthinker.runtime.infra import progress
    from mosaicthinker.runtime.pipeline import open_frames
    from mosaicthinker.runtime.infra.trace import Trace

    p = tmp_path / "clip.mp4"
    if not _write_mp4(p, 60):
        pytest.skip("this OpenCV build cannot write mp4v video")
    t = Trace()
    with progress.session(quiet=False, draw=False, file=io.StringIO()) as s:
        src = open_frames(p, t)
    assert src.observed is not None and len(src) == 60 and "open" in t.to_dict()["stages"]
    line = [ln for ln in s.lines() if ln.split()[0] == "open"]
    assert line and "60 frames" in line[0] and "removed while decoding" in line[0]
    seen: list[int] = []
    open_source(p, progress=seen.append)  # the scan reports how far it decoded (the bar's ticks)
    assert seen == [32]
