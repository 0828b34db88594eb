"""The held-out wording generators share `benchmarks/holdout_common.py` and still write the committed bytes: each set
is rebuilt from the benchmark's questions and compared with its file in benchmarks/data (issue 37)."""
from __future__ import annotations

import subprocess
import sys

import pytest

from conftest import REPO

BENCH = REPO / "benchmarks"


@pytest.mark.parametrize("n", [8, 9, 10, 11, 12])
def test_each_held_out_set_is_rebuilt_byte_for_byte(n, vsibench_dir, tmp_path):
    out = tmp_path / f"set{n}.jsonl"
    args = [sys.executable, str(BENCH / f"make_holdout{n}.py"), "--questions", str(vsibench_dir / "questions.jsonl"),
            "--out", str(out)] + (["--meta", str(vsibench_dir / "meta_info.json")] if n == 8 else [])
    p = subprocess.run(args, capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr
    committed = BENCH / "data" / f"vsibench_paraphrases_holdout{n}.jsonl"
    assert out.read_bytes() == committed.read_bytes() and len(committed.read_bytes()) > 10_000


def test_the_shared_module_is_used_by_every_generator():
    for f in ("make_holdout8", "make_holdout9", "make_holdout10", "make_holdout11", "make_holdout12", "check_holdout10",
              "check_holdout11", "check_holdout12"):
        assert "from holdout_common import" in (BENCH / f"{f}.py").read_text(), f
