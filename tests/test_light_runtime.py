"""The runtime must stay dependency-light: importing any of it never imports torch, transformers or onnx."""
from __future__ import annotations

import pkgutil
import subprocess
import sys

import mosaicthinker.runtime as rt


def _runtime_modules() -> list[str]:
    return sorted(m.name for m in pkgutil.walk_packages(rt.__path__, prefix="mosaicthinker.runtime."))


def test_importing_whole_runtime_never_imports_heavy_packages():
    mods = _runtime_modules()
    assert "mosaicthinker.runtime.geometry" in mods
    code = (
        "import importlib, sys\n"
        f"for m in {mods!r}:\n"
        "    importlib.import_module(m)\n"
        "heavy = sorted(k for k in sys.modules if k.split('.')[0] in ('torch', 'transformers', 'onnx', 'onnxscript'))\n"
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
