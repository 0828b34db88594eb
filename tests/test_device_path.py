"""The device path never imports the host-side tools (issue 11: a phone or Jetson ships without them).

In a fresh process: `import mosaicthinker.runtime`, load a real bundle (verified), answer a question with `ask`
on a small RGB-D folder, run `mosaic map` on it and `mosaic ask` on the saved map; then no module of `HOST` may
be in `sys.modules`. The bundle and the input are made in this (parent) process, which may import anything.
"""
from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

# Host-side packages: synthetic scenes, evaluation, bundle writing and report files, the export toolchain and
# its heavy dependencies. One list: when a package moves to the host side, add it here.
HOST = [
    "mosaicthinker.host.synth",
    "mosaicthinker.host.evaluation",
    "mosaicthinker.host",
    "mosaicthinker.export",
    "torch",
    "transformers",
    "onnx",
]

_CHILD = r"""
import json, sys
HOST = {host!r}

def host_modules():
    return sorted(m for m in sys.modules if any(m == h or m.startswith(h + ".") for h in HOST))

import mosaicthinker.runtime as R
from mosaicthinker.runtime.cli import main

b = R.load_bundle({bundle!r}, verify=True)
res = R.ask({source!r}, "How many chairs are in this room?", bundle=b)
rc_map = main(["map", {source!r}, "--bundle", {bundle!r}, "--out", {out!r}])
rc_ask = main(["ask", {out!r} + "/map.json", "How many chairs are in this room?", "--json"])
seen = host_modules()
import mosaicthinker.host.bundle_write  # the detector itself sees a host import (the test can fail)
n_map = len(json.load(open({out!r} + "/map.json"))["instances"])
print(json.dumps({{"host": seen, "answer": res.answer.text, "rc_map": rc_map, "rc_ask": rc_ask, "n_map": n_map,
                  "detector_works": "mosaicthinker.host.bundle_write" in host_modules()}}))
"""


@pytest.fixture(scope="module")
def device_bundle(tmp_path_factory, shared_models) -> Path:
    from mosaicthinker.export.onnx_import import import_shared_models

    out = tmp_path_factory.mktemp("device_bundle")
    import_shared_models(shared_models, out, ["fp32"], roles=["detector", "segmenter"])
    return out


@pytest.fixture(scope="module")
def small_rgbd(tmp_path_factory, redkitchen) -> Path:
    """10 RGB-D frames of the shared kitchen (every 4th of the first 40) with their intrinsics."""
    out = tmp_path_factory.mktemp("rk10")
    for i in range(0, 40, 4):
        for f in redkitchen.glob(f"frame-{i:06d}.*"):
            shutil.copy(f, out / f.name)
    shutil.copy(redkitchen / "camera-intrinsics.txt", out / "camera-intrinsics.txt")
    return out


@pytest.mark.slow
def test_ask_and_map_import_no_host_module(device_bundle, small_rgbd, tmp_path):
    code = _CHILD.format(host=HOST, bundle=str(device_bundle), source=str(small_rgbd), out=str(tmp_path / "m"))
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    res = json.loads(proc.stdout.strip().splitlines()[-1])
    assert res["rc_map"] == 0 and res["rc_ask"] == 0, proc.stderr[-2000:]
    assert res["answer"] and res["n_map"] > 0, res  # a map with objects: the renderer ran on the device path
    assert res["detector_works"]
    assert res["host"] == [], f"the device path imported host-side modules: {res['host']}"
