"""jetson/arm64_check.sh (the aarch64 run itself is slow and needs root for apt-get: run it by hand, see
docs/deployment.md "ARM64"): its shell is clean, its usage errors are clear, and its verdict (arm64_compare.py)
compares the two sides' answers and says aarch64 only when the mosaic process reported it."""
from __future__ import annotations

import json
import platform
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SCRIPT = REPO / "jetson" / "arm64_check.sh"


def test_script_lint_and_usage(shellcheck, tmp_path):
    r = subprocess.run([shellcheck, str(SCRIPT)], capture_output=True, text=True)
    assert r.returncode == 0, r.stdout
    r = subprocess.run(["bash", str(SCRIPT)], capture_output=True, text=True)
    assert r.returncode == 2 and "usage: jetson/arm64_check.sh" in r.stderr
    if platform.machine() != "aarch64":
        r = subprocess.run(["bash", str(SCRIPT), "--native", str(tmp_path / "o")], capture_output=True, text=True)
        assert r.returncode == 2 and "runs on an aarch64 machine" in r.stderr


def _side(root: Path, machine: str, answers: list[str], ask: str) -> None:
    root.mkdir(parents=True)
    qs = [{"type": f"t{i}", "answer": a} for i, a in enumerate(answers)]
    (root / "demo.json").write_text(json.dumps({"mean_score": 0.95, "questions": qs, "seconds": 1.0}))
    (root / "ask.json").write_text(json.dumps({"status": "ok", "answer": ask, "value": ask, "seconds": 2.0}))
    for run in ("demo", "ask"):
        (root / run).mkdir()
        (root / run / "trace.json").write_text(json.dumps({"host": {"machine": machine}}))


def _compare(out: Path) -> tuple[int, dict]:
    r = subprocess.run([sys.executable, str(REPO / "jetson" / "arm64_compare.py"), "--out", str(out), "--start", "0"],
                       capture_output=True, text=True)
    return r.returncode, json.loads(r.stdout.strip().splitlines()[-1])


def test_verdict(tmp_path):
    _side(tmp_path / "a" / "x86", "x86_64", ["1.1", "B"], "3")
    _side(tmp_path / "a" / "arm64", "aarch64", ["1.1", "B"], "3")
    rc, s = _compare(tmp_path / "a")
    assert rc == 0 and s["machine"] == "aarch64" and s["answers_equal_x86"] is True and s["ask_status"] == "ok"
    assert set(s) == {"machine", "demo_score", "ask_status", "answers_equal_x86", "seconds"}
    _side(tmp_path / "b" / "x86", "x86_64", ["1.1", "B"], "3")
    _side(tmp_path / "b" / "arm64", "aarch64", ["1.2", "B"], "3")
    assert _compare(tmp_path / "b")[0] == 1
    _side(tmp_path / "c" / "x86", "x86_64", ["1.1"], "3")
    _side(tmp_path / "c" / "arm64", "x86_64", ["1.1"], "3")  # not an ARM run: target not met
    rc, s = _compare(tmp_path / "c")
    assert rc == 1 and s["machine"] == "x86_64"
