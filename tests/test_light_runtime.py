"""The runtime must stay dependency-light: importing any of it never imports torch, transformers or onnx, and
no function in it does so later either (checked on the source, function bodies included)."""
from __future__ import annotations

import ast
import pkgutil
import subprocess
import sys
from pathlib import Path

import mosaicthinker.runtime as rt

HEAVY = ("torch", "transformers", "onnx", "onnxscript", "onnx_ir")
LAZY_ONLY = ("onnxruntime_genai",)  # the optional `vlm` extra: allowed inside functions, never at module level
RUNTIME_DIR = Path(rt.__file__).resolve().parent


def _imported_names(tree: ast.AST) -> list[tuple[str, int, bool]]:
    """(top-level package, line, at module level) for every import statement and every
    importlib.import_module / __import__ call with a literal name."""
    top_level = {id(n) for n in tree.body} if isinstance(tree, ast.Module) else set()
    found = []
    for node in ast.walk(tree):
        names: list[str] = []
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names = [node.module]
        elif isinstance(node, ast.Call) and node.args and isinstance(node.args[0], ast.Constant) \
                and isinstance(node.args[0].value, str):
            f = node.func
            fname = f.attr if isinstance(f, ast.Attribute) else getattr(f, "id", "")
            if fname in ("import_module", "__import__"):
                names = [node.args[0].value]
        found += [(n.split(".")[0], node.lineno, id(node) in top_level) for n in names]
    return found


def test_runtime_source_never_imports_heavy_packages():
    files = sorted(RUNTIME_DIR.rglob("*.py"))
    assert len(files) > 20
    bad = []
    for f in files:
        for name, line, module_level in _imported_names(ast.parse(f.read_text(), str(f))):
            if name in HEAVY or (name in LAZY_ONLY and module_level):
                bad.append(f"{f.relative_to(RUNTIME_DIR)}:{line} imports {name}")
    assert not bad, "runtime imports heavy packages:\n" + "\n".join(bad)


def test_source_scan_catches_imports_inside_functions():
    """The scan itself can fail: an import hidden in a function body or behind importlib is found."""
    code = ("import numpy\ndef f():\n    import torch.nn\n    from transformers import AutoModel\n"
            "def g():\n    import importlib\n    return importlib.import_module('onnx.helper')\n"
            "import onnxruntime_genai\ndef h():\n    import onnxruntime_genai\n")
    got = _imported_names(ast.parse(code))
    assert ("torch", 3, False) in got and ("transformers", 4, False) in got and ("onnx", 7, False) in got
    assert ("onnxruntime_genai", 8, True) in got and ("onnxruntime_genai", 10, False) in got


def test_only_the_cli_names_the_export_package():
    """The CLI's lazy command table is the one place the runtime refers to mosaicthinker.export."""
    users = [f.relative_to(RUNTIME_DIR).as_posix() for f in RUNTIME_DIR.rglob("*.py")
             if "mosaicthinker.export" in f.read_text()]
    assert users == ["cli.py"], users


def _runtime_modules() -> list[str]:
    return sorted(m.name for m in pkgutil.walk_packages(rt.__path__, prefix="mosaicthinker.runtime."))


def test_importing_whole_runtime_never_imports_heavy_packages():
    mods = _runtime_modules()
    assert "mosaicthinker.runtime.geometry" in mods
    code = (
        "import importlib, sys\n"
        f"for m in {mods!r}:\n"
        "    importlib.import_module(m)\n"
        "heavy = sorted(k for k in sys.modules if k.split('.')[0] in ('torch', 'transformers', 'onnx', 'onnxscript', 'onnx_ir', 'onnxruntime_genai'))\n"
        "print(','.join(heavy))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "", f"runtime imported heavy packages: {out.stdout}"


def test_cli_help_lists_commands_without_export_extra():
    out = subprocess.run([sys.executable, "-m", "mosaicthinker.runtime.cli", "--help"], capture_output=True,
                         text=True, check=True)
    for cmd in ("demo", "ask", "eval pose", "export", "bundle verify", "plan", "profile", "synth"):
        assert cmd in out.stdout


def test_export_without_the_extra_names_the_extra(tmp_path):
    """In an interpreter where torch cannot be imported, `mosaic export` says which extra to install."""
    code = (
        "import sys\n"
        "class Block:\n"
        "    def find_spec(self, name, path=None, target=None):\n"
        "        if name.split('.')[0] in ('torch', 'transformers', 'onnxscript'):\n"
        "            raise ModuleNotFoundError(f\"No module named '{name}'\", name=name)\n"
        "sys.meta_path.insert(0, Block())\n"
        "from mosaicthinker.runtime.cli import main\n"
        f"sys.exit(main(['export', 'depth', '--source', 'tiny', '--out', r'{tmp_path / 'b'}']))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 2, out.stderr[-2000:]
    assert "needs the `export` extra" in out.stderr and "pip install 'mosaicthinker[export]'" in out.stderr
    assert "Traceback" not in out.stderr
