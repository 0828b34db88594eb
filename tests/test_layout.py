"""Issue 11 (the redesign, behaviour kept): the stage layout, the alignment policy's rules, one owner per setting,
and the public API the README names."""
from __future__ import annotations

import ast
import dataclasses
import importlib
import re

import numpy as np
import pytest

from conftest import REPO


class NoMatches:
    """A matcher that never finds a correspondence (a `matching.Matcher`, no feature cache): every edge fails."""

    def match(self, rgb0, rgb1, boxes0=None, boxes1=None):
        from mosaicthinker.runtime.align.matching import Matches

        return Matches.empty()


def test_chain_jumps_halve_then_walk():
    from mosaicthinker.runtime.align import chain_jumps

    # halfway first, halving down to bridge_gap_s, then walking at 2, 3, ... x bridge_gap_s: a finite schedule
    assert chain_jumps(4.0, 0.5) == [2.0, 1.0, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 3.5]
    assert chain_jumps(0.9, 0.5) == []  # no room for a jump of at least bridge_gap_s ... and none to walk
    assert chain_jumps(1.0, 0.5) == [0.5]


def _chain(redkitchen, budget, gap_s=0.4, u=48):
    from mosaicthinker.runtime.align import AlignmentResult, bridge_chain
    from mosaicthinker.runtime.frames import open_source
    from mosaicthinker.runtime.align.matching import make_matcher
    from mosaicthinker.runtime.align import AlignConf

    src = open_source(redkitchen)
    al = AlignmentResult({0: np.eye(4)}, 0, [], [u], "mst")
    pool = {0: src[0], u: src[u]}
    loaded: list[int] = []

    def with_depth(f):
        loaded.append(f.index)
        return f  # sensor depth: the frame as it comes

    conf = AlignConf.merged(bridge_gap_s=gap_s)
    left, used = bridge_chain(al, pool, 0, u, src, make_matcher(NoMatches()), with_depth, conf, budget)
    return src, al, loaded, left, used


def test_bridge_chain_loads_frames_in_jump_halve_walk_order(redkitchen):
    """docs/real-scene.md: `bridge_chain` jumps halfway first, halves on a failure down to `bridge_gap_s`, then
    walks on at that spacing, loading a frame only when the chain reaches it. With edges that never pass, the
    chain stays at its anchor (frame 0, 3.2 s before the key frame 48) and loads exactly the schedule's frames."""
    src, al, loaded, left, used = _chain(redkitchen, 48)
    assert float(src.timestamps[48]) == pytest.approx(3.2)
    # halving: 1.6 s, 0.8 s, 0.4 s -> frames 24, 12, 6; walking 0.8 (12, loaded), 1.2, 1.6 (24, loaded), 2.0, ...
    assert loaded == [24, 12, 6, 18, 30, 36, 42]
    assert left == 48 - len(loaded) and used == [] and 48 not in al.poses
    # every failed pair is kept (the next round does not try it again)
    assert {(0, 48), (0, 24), (0, 6)} <= set(al.edge_stats)


def test_bridge_chain_stops_at_its_frame_budget(redkitchen):
    _, _, loaded, left, used = _chain(redkitchen, 3)
    assert loaded == [24, 12, 6] and left == 0 and used == []


def test_matcher_protocol_and_make_matcher():
    from mosaicthinker.runtime import InputError
    from mosaicthinker.runtime.align.matching import FeatureMatcher, KeyedMatcher, Matcher, make_matcher

    fm = make_matcher("orb")
    assert isinstance(fm, FeatureMatcher) and isinstance(fm, KeyedMatcher) and fm.conf.ratio == 0.8
    plain = NoMatches()
    plain.keypoint_px = 2.0
    m = make_matcher(plain)
    assert isinstance(plain, Matcher) and not isinstance(plain, KeyedMatcher)
    assert isinstance(m, KeyedMatcher) and m.keypoint_px == 2.0  # attributes are the wrapped matcher's
    rgb = np.zeros((8, 8, 3), np.uint8)
    assert len(m.match_keys(0, rgb, 1, rgb)) == 0
    assert make_matcher(fm) is fm
    with pytest.raises(InputError, match="matcher must be"):
        make_matcher(object())


def test_rejected_edges_is_a_declared_field():
    from mosaicthinker.runtime.align import AlignmentResult

    assert "rejected_edges" in {f.name for f in dataclasses.fields(AlignmentResult)}
    assert AlignmentResult({}, 0, [], [], "mst").rejected_edges == []


def test_pipeline_stage_configs_are_typed_and_merge_over_the_pipeline_defaults():
    from mosaicthinker.runtime import InputError, PipelineConfig
    from mosaicthinker.runtime.align import AlignConf
    from mosaicthinker.runtime.align.matching import FeatureMatcher, MatchConf

    c = PipelineConfig()
    # one owner: alignment on its own needs 20 inliers, the key frames' tree 12 (the depth check verifies it)
    assert isinstance(c.alignment, AlignConf) and c.alignment == AlignConf()
    assert (AlignConf().min_inliers, AlignConf().keyframe_min_inliers) == (20, 12)
    assert isinstance(c.match, MatchConf) and c.match.ratio is None  # the ratio is chosen per method later
    assert FeatureMatcher("orb", c.match).conf.ratio == 0.8 and FeatureMatcher("sift", c.match).conf.ratio == 0.9
    c2 = PipelineConfig.merged({"alignment": {"ransac_iterations": 500}, "fusion": {"max_depth_m": 6.0}})
    assert c2.alignment.ransac_iterations == 500 and c2.alignment.keyframe_min_inliers == 12
    assert c2.fusion.max_depth_m == 6.0
    with pytest.raises(InputError, match="min_inlierz"):
        PipelineConfig.merged({"alignment": {"min_inlierz": 3}})


def test_each_edge_inlier_minimum_has_one_owner_and_none_is_rebound():
    """`min_inliers` means 20 wherever it is read; the key frames' alignment names its own 12 and the solvers say
    which applies (`edge_min_inliers`); their mathematical floors are named once (`SOLVER_MIN_POINTS`)."""
    from dataclasses import replace

    from mosaicthinker.runtime.align import AlignConf
    from mosaicthinker.runtime.align.conf import SOLVER_MIN_POINTS

    c = AlignConf()
    assert c.edge_min_inliers == c.min_inliers == 20
    assert replace(c, keyframe_edges=True).edge_min_inliers == c.keyframe_min_inliers == 12
    assert AlignConf.merged(min_inliers=15).edge_min_inliers == 15
    assert set(SOLVER_MIN_POINTS) == {"3d-3d", "pnp", "essential", "refit"}
    files = sorted((REPO / "runtime" / "align").glob("*.py"))
    assert {"pairwise.py", "pnp.py", "essential.py", "stage.py"} <= {f.name for f in files}
    for f in files + [REPO / "benchmarks" / "real_rooms.py"]:
        src = f.read_text()
        assert "min_inliers=conf.keyframe_min_inliers" not in src and "conf.min_inliers" not in src, f.name
        assert "AlignConf(min_inliers=" not in src, f.name
        assert not re.search(r"max\((3|6|8), ", src), f.name


def test_sift_contrast_threshold_has_one_owner():
    """The SIFT contrast threshold is MatchConf's alone (it was also set in the pipeline's defaults)."""
    src = (REPO / "runtime" / "pipeline.py").read_text()
    assert "sift_contrast_threshold" not in src and "min_inliers\": 12" not in src


def test_render_names_an_unknown_prompt_key():
    from mosaicthinker.runtime import InputError, SemanticMap
    from mosaicthinker.runtime.prompt import render

    with pytest.raises(InputError, match=r"unknown key\(s\) \['size'\].*size_px"):
        render(SemanticMap(), {"size": 3})
    assert render(SemanticMap(), {"size_px": 128}).image.shape[:2] == (128, 128)


def _imports(path) -> set[str]:
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.level == 1:
            out.add(node.module or "")
    return out


def test_no_semantic_map_prompt_import_circle():
    rt = REPO / "runtime"
    assert not any("prompt" in m for m in _imports(rt / "map" / "model.py"))
    assert "map.model" in _imports(rt / "prompt.py")


def test_pipeline_imports_its_stages_at_module_level_in_the_papers_order():
    tree = ast.parse((REPO / "runtime" / "pipeline.py").read_text())
    top = [n.module.split(".")[0] for n in tree.body if isinstance(n, ast.ImportFrom) and n.level == 1 and n.module]
    paper = ["scan", "grounding", "keyframes", "perceive", "align", "map", "prompt", "answer"]
    order = list(dict.fromkeys(m for m in top if m in paper))
    assert order == sorted(order, key=paper.index) and {"scan", "keyframes", "align", "map", "answer"} <= set(order)
    # no geometry of its own: back-projection and transforms live in the stage modules
    assert "geometry" not in top


def test_readme_public_api_imports():
    """Every `module.name` the README names for a runtime module, and its `from mosaicthinker.runtime import`
    line, import."""
    text = (REPO / "README.md").read_text()
    rt = REPO / "runtime"
    mods = {p.stem for p in rt.glob("*.py")} | {p.parent.name for p in rt.glob("*/__init__.py")}
    named = set(re.findall(r"`([a-z_]+)\.([A-Za-z_]\w*)`", text))
    checked = 0
    for mod, name in sorted(named):
        if mod in mods and name not in ("py", "json", "md", "png", "txt"):  # not file names
            m = importlib.import_module(f"mosaicthinker.runtime.{mod}")
            assert hasattr(m, name), f"README names {mod}.{name}"
            checked += 1
    assert checked >= 6  # geometry.ransac_transform, alignment.align_frames, prompt.render, ...
    for line in re.findall(r"from (mosaicthinker\.runtime[\w.]*) import ([\w, ]+)", text):
        m = importlib.import_module(line[0])
        for name in (n.strip() for n in line[1].split(",")):
            assert getattr(m, name) is not None, f"README imports {name} from {line[0]}"
    import mosaicthinker.runtime as r

    for name in r.__all__:
        assert getattr(r, name) is not None
