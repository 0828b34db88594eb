"""What the product writes, it reads back: every map `mosaic map` and `mosaic ask --out` write - sensor depth,
model depth (relative: PyDNet++), an RGB-only folder and a video - loads in `mosaic ask MAP` and answers.
(An RGB-only map was refused before: its cameras carried their frame's depth scale, `cameras[1].T_wc is not a
rigid pose`.)"""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

pytestmark = [pytest.mark.slow, pytest.mark.export]

Q = "How many chairs are in this room?"


@pytest.fixture(scope="module")
def bundle(tmp_path_factory, shared_models) -> Path:
    from mosaicthinker.export.onnx_import import import_shared_models

    out = tmp_path_factory.mktemp("rt_bundle")
    import_shared_models(shared_models, out, ["fp32"], roles=["detector", "depth"])
    return out


@pytest.fixture(scope="module")
def inputs(tmp_path_factory, redkitchen) -> dict[str, Path]:
    """Ten kitchen frames as an RGB-D folder, as colour images alone, and as an mp4."""
    from mosaicthinker.host.evaluation.scene import video_of_frames

    root = tmp_path_factory.mktemp("rt_inputs")
    rgbd, rgb = root / "rgbd", root / "rgb"
    rgbd.mkdir()
    rgb.mkdir()
    for i in range(0, 200, 20):
        for f in redkitchen.glob(f"frame-{i:06d}.*"):
            shutil.copy(f, rgbd / f.name)
        shutil.copy(redkitchen / f"frame-{i:06d}.color.jpg", rgb / f"img{i:04d}.jpg")
    shutil.copy(redkitchen / "camera-intrinsics.txt", rgbd)
    return {"rgbd": rgbd, "rgb": rgb, "video": video_of_frames(rgbd, root / "kitchen.mp4", fps=3.0)}


def _run(argv: list[str], capsys) -> tuple[int, str]:
    from mosaicthinker.runtime.cli import main

    capsys.readouterr()
    code = main(argv)
    return code, capsys.readouterr().out


@pytest.mark.parametrize("kind,depth,writer", [
    ("rgbd", "sensor", "map"), ("rgbd", "model", "map"), ("rgb", "auto", "map"), ("video", "auto", "map"),
    ("rgbd", "sensor", "ask"), ("rgb", "auto", "ask")])
def test_every_written_map_loads_and_answers(kind, depth, writer, inputs, bundle, tmp_path, capsys):
    out = tmp_path / "out"
    common = ["--bundle", str(bundle), "--depth", depth, "--matcher", "sift", "--keyframes", "6", "--out", str(out)]
    if writer == "map":
        code, _ = _run(["map", str(inputs[kind]), "--objects", "chair,table,cup", *common], capsys)
    else:
        code, _ = _run(["ask", str(inputs[kind]), Q, "--answerer", "map", *common], capsys)
    assert code == 0 and (out / "map.json").is_file()
    saved = json.loads((out / "map.json").read_text())
    assert saved["cameras"], "a map from frames keeps its cameras"
    for target in (out / "map.json", out):  # the file, and the --out folder that holds it beside map.png
        code, text = _run(["ask", str(target), Q, "--json"], capsys)
        res = json.loads(text)
        assert code == 0 and res["status"] in ("ok", "not_found") and "rigid pose" not in text, text[-500:]
