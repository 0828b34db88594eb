"""What every class of the reliability campaign shares (tests/campaign.py, tests/campaign_round4.py): the outcome
classes, a case record, the in-process and subprocess runners, and the classifier. Its own module so that the
campaign's class modules import it and the campaign imports them, without a circle."""
from __future__ import annotations

import contextlib
import io
import json
import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator

CLASSES = ("crash", "hang", "silently wrong", "clear error", "flagged answer", "answered")


@dataclass
class Record:
    cls: str      # campaign class (field damage: map, manifest ...)
    case: str
    outcome: str  # one of CLASSES
    detail: str = ""


class _Timeout(BaseException):
    pass


@contextlib.contextmanager
def _limit(seconds: int) -> Iterator[None]:
    def boom(signum, frame):
        raise _Timeout()

    old = signal.signal(signal.SIGALRM, boom)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


def cli(argv: list, limit: int = 60) -> tuple[int | str, str, str]:
    """`mosaic ARGV` in this process: (exit code or "hang", stdout, stderr)."""
    from mosaicthinker.runtime import cli as C

    out, err = io.StringIO(), io.StringIO()
    try:
        with _limit(limit), contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            code = C.main([os.fsdecode(a) for a in argv])
    except _Timeout:
        return "hang", out.getvalue(), err.getvalue()
    return code, out.getvalue(), err.getvalue()


def classify(code: int | str, out: str, err: str, file: str | None = None, note: str | None = None,
             answer: str | None = None, field: str | None = None) -> tuple[str, str]:
    """The outcome class of one run. file / field: what an error must name (either); note: a fragment the
    answer must carry; answer: the answer it must give."""
    if code == "hang":
        return "hang", ""
    if code not in (0, 2) or "Traceback" in err or "internal error" in err:
        return "crash", (err.strip().splitlines() or [f"exit {code}"])[-1][:200]
    if code == 2:
        names = [x for x in (file, file and Path(file).name, field, field and field.replace("_", " ")) if x]
        ok = err.startswith("error:") and (not names or any(n in err for n in names))
        return ("clear error", err.strip()[:200]) if ok else ("crash", f"unclear error: {err.strip()[:200]}")
    if answer is not None and not out.startswith(f"answer: {answer}") and f'"answer": "{answer}"' not in out:
        return "silently wrong", out.strip().splitlines()[0][:200] if out.strip() else ""
    if note is not None:
        return ("flagged answer", "") if note in out else ("silently wrong", f"no note {note!r}: {out[:200]}")
    return "answered", ""


def _dump(doc: Any, path: Path) -> None:
    path.write_text(json.dumps(doc, indent=1))


def _proc(cmd: str, limit: int = 300) -> tuple[int | str, str, str]:
    try:
        r = subprocess.run(["bash", "-c", cmd], capture_output=True, text=True, timeout=limit)
    except subprocess.TimeoutExpired:
        return "hang", "", ""
    return r.returncode, r.stdout, r.stderr


def start_run(argv: list, out: Path, *, text: bool = False, limit: float = 60, step: float = 0.01) -> subprocess.Popen:
    """`mosaic ARGV` in a subprocess, returned once its `--out` folder `out` says the run is running (or it ended,
    or `limit` seconds passed): the moment a signal sent to it lands in the middle of a run."""
    p = subprocess.Popen([sys.executable, "-m", "mosaicthinker.runtime.cli", *map(str, argv)],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=text)
    t0 = time.time()
    while time.time() - t0 < limit and p.poll() is None:
        try:
            if json.loads((out / "run.json").read_text())["status"] == "running":
                break
        except (OSError, ValueError):
            pass
        time.sleep(step)
    return p
