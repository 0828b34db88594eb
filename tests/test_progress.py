"""Progress you can see (runtime/infra/progress.py): bars only on a terminal and without --json, one summary line per
stage at the end, the first line before the command's imports, and `mosaic demo` leaving nothing in /tmp."""
from __future__ import annotations

import fcntl
import io
import os
import pty
import re
import select
import struct
import subprocess
import sys
import termios
import time
from pathlib import Path

import pytest

from mosaicthinker.runtime import cli
from mosaicthinker.runtime.infra import progress
from test_pipeline import synthetic_scene


@pytest.fixture(scope="module")
def scene(tmp_path_factory) -> Path:
    return synthetic_scene(tmp_path_factory)


def test_phases_are_silent_outside_a_session_and_summed_inside():
    with progress.phase("dedup", 10, "frame") as bar:  # no session: a no-op
        bar.update(3)
        bar.note(candidates=2)
    buf = io.StringIO()
    with progress.session(draw=False, file=buf) as s:
        for _ in range(2):  # the same phase twice: one summary line, counts and time summed
            with progress.phase("alignment", unit="round") as bar:
                bar.update()
        outer = progress.start("scenes", 2, "scene")
        inner = progress.start("dedup", 5, "frame")  # inside another phase: recorded, never drawn
        inner.to(5)
        inner.done(candidates=3)
        outer.update(2)
        bar = progress.start("fusion", 4, "key frame")  # left open (an error): closed by the session
        bar.note(instances=7)
    lines = buf.getvalue().splitlines()
    assert [ln.split()[0] for ln in lines] == ["alignment", "scenes", "dedup", "fusion"]
    assert "2 rounds" in lines[0] and "5 frames, candidates 3" in lines[2] and "instances 7" in lines[3]
    assert s.records["alignment"].calls == 2 and not s.open


def test_no_summary_when_the_command_fails():
    buf = io.StringIO()
    with pytest.raises(RuntimeError), progress.session(draw=False, file=buf):
        with progress.phase("dedup", 3):
            raise RuntimeError("boom")
    assert buf.getvalue() == ""  # the error message stays the first line on stderr


def test_first_line_comes_before_the_command_module_is_imported(monkeypatch, capsys):
    """A person sees the command start before its (slow) imports: the line is printed, then the import fails."""
    monkeypatch.setitem(cli.COMMANDS, ("demo",), ("mosaicthinker.no_such_module", "a test command", None))
    monkeypatch.setattr(progress, "stderr_is_terminal", lambda: True)
    assert cli.main(["demo"]) == 1  # an internal error (the outcome table), after the first line
    err = capsys.readouterr().err
    assert err.startswith("mosaic demo: a test command ...") and "no_such_module" in err
    assert cli.main(["demo", "--json"]) == 1  # --json: machine use, no first line
    assert not capsys.readouterr().err.startswith("mosaic demo:")


def _run_on_terminal(args: list[str], timeout: float = 300) -> tuple[int, bytes, list[tuple[float, bytes]]]:
    """Run `mosaic ARGS` with stderr on a pseudo-terminal. Returns (exit code, stdout, [(seconds, stderr chunk)])."""
    master, slave = pty.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 40, 120, 0, 0))  # a terminal of 40 x 120
    t0 = time.perf_counter()
    p = subprocess.Popen([sys.executable, "-m", "mosaicthinker.runtime.cli", *args], stdout=subprocess.PIPE,
                         stderr=slave)
    os.close(slave)
    chunks: list[tuple[float, bytes]] = []
    while True:
        r, _, _ = select.select([master], [], [], 0.5)
        if r:
            try:
                data = os.read(master, 65536)
            except OSError:  # the child closed the terminal
                break
            if not data:
                break
            chunks.append((time.perf_counter() - t0, data))
        elif p.poll() is not None:
            break
        if time.perf_counter() - t0 > timeout:
            p.kill()
            raise TimeoutError(args)
    out = p.stdout.read()
    p.wait()
    os.close(master)
    return p.returncode, out, chunks


@pytest.mark.slow
def test_map_on_a_terminal_shows_bars_then_one_line_per_stage(scene, tmp_path):
    args = ["map", str(scene), "--detector", "oracle", "--keyframes", "5", "--objects", "door,cabinet,stove",
            "--out", str(tmp_path / "m")]
    rc, out, chunks = _run_on_terminal(args)
    err = b"".join(c for _, c in chunks).decode(errors="replace")
    assert rc == 0, err
    assert err.startswith("mosaic map: build a semantic map")
    assert "\r" in err and re.search(r"(dedup|keyframes)\S*:\s+\d+%", err)  # tqdm bars, redrawn in place
    tail = [ln.strip() for ln in err.replace("\r", "\n").splitlines() if ln.strip()][-6:]
    assert [ln.split()[0] for ln in tail] == ["open", "dedup", "keyframes", "perception", "alignment", "fusion"], tail
    assert "frames" in tail[0] and "candidates" in tail[1] and "keyframes 5" in tail[2] and "aligned" in tail[4]
    assert "instances" in tail[5]
    assert (tmp_path / "m" / "prompt.txt").read_text().startswith("Objects in the map")
    # --json on a terminal: only the JSON on stdout, nothing on stderr
    rc, out, chunks = _run_on_terminal(args + ["--json"])
    assert rc == 0 and out.decode().count("\n") == 1 and b"".join(c for _, c in chunks).strip() == b""
    # stderr not a terminal: no bars, the summary lines only
    r = subprocess.run([sys.executable, "-m", "mosaicthinker.runtime.cli", *args], capture_output=True, text=True)
    assert r.returncode == 0 and "\r" not in r.stderr and r.stderr.split()[0] == "open"


@pytest.mark.slow
def test_demo_without_out_leaves_nothing_in_tmp(tmp_path):
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    r = subprocess.run([sys.executable, "-m", "mosaicthinker.runtime.cli", "demo", "--duration", "8", "--size",
                        "320x240", "--keyframes", "6", "--num-questions", "2"], capture_output=True, text=True,
                       env={**os.environ, "TMPDIR": str(tmp)}, timeout=300)
    assert r.returncode == 0, r.stderr
    assert "score" in r.stdout and "wrote" not in r.stdout and "temporary folder" in r.stdout
    assert list(tmp.iterdir()) == []
