"""Issue 29, short and sparse inputs: every input size from one frame up maps or says why (exit 0 with an answer,
or exit 2 naming the reason), never an internal error. A table over sizes on the real kitchen with the shared
detector and sensor depth: RGB-D folders of 1, 2, 3, 5 and 8 frames far apart (frame numbers with gaps, so the
frames between key frames that bridging looks for do not exist: the "empty candidate range" crash), videos of
1 to 5 frames, a static input (one frame repeated); and the health of degenerate frames (black, depth invalid
everywhere, depth constant) said in the answer."""
from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from test_bad_inputs import run_cli

Q = "How many chairs are in the room?"
pytestmark = [pytest.mark.slow, pytest.mark.export]


@pytest.fixture(scope="module")
def bundle(tmp_path_factory, shared_models) -> Path:
    from mosaicthinker.export.onnx_import import import_shared_models

    b = tmp_path_factory.mktemp("short") / "bundle"
    import_shared_models(shared_models, b, ["fp32"], roles=["detector", "depth"])
    return b


def _kitchen_frames(redkitchen: Path) -> list[Path]:
    return sorted(Path(redkitchen).glob("frame-*.color.jpg"))


def _rgbd_subset(redkitchen: Path, out: Path, n: int) -> Path:
    """n frames spread over the whole kitchen walk, keeping their frame numbers (gaps of ~100 frames)."""
    out.mkdir(parents=True)
    for f in ("camera-intrinsics.txt", "gravity-direction.txt"):
        shutil.copy(Path(redkitchen) / f, out / f)
    colours = _kitchen_frames(redkitchen)
    for i in np.linspace(0, len(colours) - 1, n).round().astype(int):
        stem = colours[i].name.replace(".color.jpg", "")
        for p in Path(redkitchen).glob(stem + ".*"):
            shutil.copy(p, out / p.name)
    return out


def _video(redkitchen: Path, out: Path, n: int, static: bool = False) -> Path:
    colours = _kitchen_frames(redkitchen)
    idx = [0] * 10 if static else np.linspace(0, len(colours) - 1, n).round().astype(int)
    first = cv2.imread(str(colours[0]))
    vw = cv2.VideoWriter(str(out), cv2.VideoWriter_fourcc(*"mp4v"), 2.0, first.shape[1::-1])
    for i in idx:
        vw.write(cv2.imread(str(colours[i])))
    vw.release()
    return out


CASES = ([("rgbd", n) for n in (1, 2, 3, 5, 8)] + [("video", n) for n in (1, 2, 3, 4, 5)] + [("static", 10)])


@pytest.mark.parametrize("kind,n", CASES, ids=[f"{k}-{n}" for k, n in CASES])
def test_every_input_size_maps_or_says_why(tmp_path, capsys, bundle, redkitchen, kind, n):
    src = (_rgbd_subset(redkitchen, tmp_path / "rgbd", n) if kind == "rgbd" else
           _video(redkitchen, tmp_path / "v.mp4", n, static=kind == "static"))
    code, out, err = run_cli(capsys, ["ask", src, Q, "--bundle", bundle])
    assert code in (0, 2), (kind, n, out, err)
    assert "Traceback" not in err and "internal error" not in err, err
    if code == 0:
        assert out.startswith("answer: ") and ("not found" not in out.splitlines()[0] or "note:" in out), out
    else:
        assert err.startswith("error: ") and ("frame" in err or "view" in err), err


@pytest.mark.parametrize("damage, said", [
    ("depth_zero", "is invalid everywhere"), ("depth_constant", "is one constant value"),
    ("black_half", "are black"), ("black_all", "are black")])
def test_degenerate_frames_are_said(tmp_path, capsys, bundle, redkitchen, damage, said):
    src = _rgbd_subset(redkitchen, tmp_path / "rgbd", 12)
    for i, p in enumerate(sorted(src.glob("*.depth.png"))):
        d = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
        if damage == "depth_zero":
            cv2.imwrite(str(p), np.zeros_like(d))
        elif damage == "depth_constant":
            cv2.imwrite(str(p), np.full_like(d, 2000))
    for i, p in enumerate(sorted(src.glob("*.color.jpg"))):
        if damage == "black_all" or (damage == "black_half" and i % 2):
            cv2.imwrite(str(p), np.zeros_like(cv2.imread(str(p))))
    code, out, err = run_cli(capsys, ["ask", src, Q, "--bundle", bundle])
    assert code in (0, 2) and "internal error" not in err, (out, err)
    assert said in (out if code == 0 else err), (out, err)
