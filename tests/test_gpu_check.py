"""benchmarks/gpu_check.py on a machine without a CUDA provider: says so, exits 0 and writes no GPU figure."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def test_gpu_check_without_cuda_says_so_and_writes_nothing(tmp_path):
    import onnxruntime as ort

    if "CUDAExecutionProvider" in ort.get_available_providers():
        pytest.skip("this onnxruntime has the CUDA provider: run benchmarks/gpu_check.py itself")
    r = subprocess.run([sys.executable, str(REPO / "benchmarks" / "gpu_check.py"), "--bundle", str(tmp_path / "none"),
                        "--out-dir", str(tmp_path / "out")], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "no CUDA provider" in r.stdout and "no GPU figures written" in r.stdout
    assert not (tmp_path / "out").exists()
