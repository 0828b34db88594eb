"""Issue 29, streams, run records and paths: a closed or broken stdout / stderr never stops the work; run.json
ends "complete", "interrupted" or "failed"; --json prints JSON only on stdout and `warning:` / `error:` lines
only on stderr; a path error says what the path is (missing, a symlink loop, a FIFO, a folder where a file
belongs); a manifest without preprocessing names the field, not an onnxruntime dimension error."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from test_bad_inputs import _big_map, run_cli, small_map

Q = "How many chair(s) are in this room?"
CLI = [sys.executable, "-m", "mosaicthinker.runtime.cli"]


def _sh(cmd: str, timeout: int = 120) -> subprocess.CompletedProcess:
    return subprocess.run(["bash", "-c", cmd], capture_output=True, text=True, timeout=timeout)


def _mosaic_line(*args: str) -> str:
    return " ".join([sys.executable, "-m", "mosaicthinker.runtime.cli", *[f"'{a}'" for a in args]])


def _run_json(out: Path) -> dict:
    return json.loads((out / "run.json").read_text())


@pytest.mark.slow
def test_closed_or_broken_streams_finish_the_work(tmp_path):
    """stdout closed, stderr closed, both closed, stdout a pipe its reader closed: exit 0, --out complete,
    no traceback; a closed stdout is said on stderr."""
    m = str(_big_map(tmp_path / "big.json", 3000))  # its --json result (~300 kB) overflows a pipe's buffer
    for i, redirect in enumerate([">&-", "2>&-", ">&- 2>&-"]):
        out = tmp_path / f"o{i}"
        r = _sh(f"{_mosaic_line('ask', m, Q, '--out', str(out))} {redirect}")
        assert r.returncode == 0, (redirect, r.stderr)
        assert _run_json(out)["status"] == "complete" and (out / "map.json").is_file(), redirect
        assert "Traceback" not in r.stderr
        if redirect == ">&-":
            assert r.stderr.startswith("warning: stdout is closed"), r.stderr
    out = tmp_path / "piped"
    r = _sh(f"{_mosaic_line('ask', m, Q, '--out', str(out), '--json')} | head -c 10; "
            f"echo \" rc=${{PIPESTATUS[0]}}\"")
    assert "rc=0" in r.stdout and "Traceback" not in r.stderr and "BrokenPipe" not in r.stderr, r
    assert _run_json(out)["status"] == "complete"


def _start(args: list[str], out: Path) -> subprocess.Popen:
    """A run started and holding `out` (its run.json says "running")."""
    p = subprocess.Popen(CLI + args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    t0 = time.time()
    while time.time() - t0 < 60 and p.poll() is None:
        try:
            if _run_json(out)["status"] == "running":
                break
        except (OSError, ValueError):
            pass
        time.sleep(0.02)
    return p


@pytest.mark.slow
@pytest.mark.parametrize("sig, code", [(signal.SIGTERM, 143), (signal.SIGINT, 130)])
def test_a_signal_ends_run_json_as_interrupted(tmp_path, sig, code):
    m = str(_big_map(tmp_path / "big.json", 30000))
    out = tmp_path / "o"
    assert run_cli_sub(["ask", m, Q, "--out", str(out)]).returncode == 0  # a complete run first
    first = _run_json(out)["run_id"]
    p = _start(["ask", m, Q, "--out", str(out)], out)
    p.send_signal(sig)
    _, err = p.communicate(timeout=120)
    if p.returncode == 0:
        pytest.skip("the run finished before the signal landed")
    assert p.returncode == code and "Traceback" not in err, err
    run = _run_json(out)
    assert run["status"] == "interrupted" and "interrupted" in run["reason"]
    assert run["previous"]["run_id"] == first and run["previous"]["status"] == "complete"
    assert json.loads((out / "map.json").read_text())["run_id"] == first  # the previous files, whole
    assert not (out / ".mosaic.lock").exists()


def run_cli_sub(args: list[str]) -> subprocess.CompletedProcess:
    return subprocess.run(CLI + args, capture_output=True, text=True, timeout=300)


def test_a_failed_write_ends_run_json_as_failed_on_a_full_disk(tmp_path, capsys, monkeypatch):
    """A real full file system where one can be mounted (a 1 MB tmpfs, filled), else skipped (the injected
    ENOSPC case is tests/test_bad_inputs.py::test_late_write_failure_still_prints_the_answer)."""
    from mosaicthinker.runtime.infra import outputs

    mnt = tmp_path / "tiny"
    mnt.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=1m", "tmpfs", str(mnt)], capture_output=True).returncode:
        pytest.skip("cannot mount a tmpfs here")
    try:
        monkeypatch.setattr(outputs, "MIN_FREE_MB", 0)  # the folder check would refuse it before the run
        out = mnt / "o"
        m = str(small_map(tmp_path / "m.json"))
        code, stdout, err = run_cli(capsys, ["ask", m, Q, "--out", str(out)])
        assert code == 0 and _run_json(out)["status"] == "complete"
        fill = mnt / "fill"
        with open(fill, "wb") as f:  # leave ~8 kB: run.json fits, map.png does not
            try:
                f.write(b"\0" * (1 << 20))
            except OSError:
                pass
        free = os.statvfs(mnt).f_bavail * os.statvfs(mnt).f_frsize
        with open(fill, "r+b") as f:
            f.truncate(os.path.getsize(fill) - max(0, 8192 - free))
        code, stdout, err = run_cli(capsys, ["ask", m, Q, "--out", str(out)])
        assert code == 2 and stdout.startswith("answer: 1") and "disk is full" in err, (stdout, err)
        run = _run_json(out)
        assert run["status"] == "failed" and "No space left" in run["reason"], run
        assert run["previous"]["status"] == "complete"
        assert not list(out.glob(".mosaic*"))
    finally:
        subprocess.run(["umount", str(mnt)], capture_output=True)


def test_json_mode_prints_json_only_and_warnings_as_lines(tmp_path, capsys):
    """--json: stdout is one JSON object; stderr holds only `warning:` / `error:` lines, also for a Python
    warning (a random-weight model's, raised through `warnings`)."""
    from fuzz_files import base_manifest

    b = tmp_path / "bundle"
    man = base_manifest(b)
    man["roles"]["detector"]["random_weights"] = True
    (b / "manifest.json").write_text(json.dumps(man))
    m = str(small_map(tmp_path / "m.json"))
    code, out, err = run_cli(capsys, ["ask", m, Q, "--bundle", str(b), "--answerer", "map", "--json"])
    assert code == 0, err
    json.loads(out)
    assert all(line.startswith(("warning:", "error:")) for line in err.splitlines()), err
    import warnings

    def warn_then_fail(args):
        warnings.warn("something odd", RuntimeWarning)
        warnings.warn("something odd", RuntimeWarning)  # said once
        return {"schema": "x"}

    from mosaicthinker.runtime.commands import ask

    orig = ask.run
    ask.run = warn_then_fail
    try:
        code, out, err = run_cli(capsys, ["ask", m, Q, "--json"])
    finally:
        ask.run = orig
    assert code == 0 and json.loads(out) == {"schema": "x"}
    assert err.splitlines() == ["warning: something odd (RuntimeWarning from test_streams_and_runs.py)"], err


def _make_kind(p: Path, kind: str) -> Path:
    if kind == "loop":
        os.symlink(p.with_name(p.name + ".2"), p)
        os.symlink(p, p.with_name(p.name + ".2"))
    elif kind == "fifo":
        os.mkfifo(p)
    elif kind == "folder":
        p.mkdir()
    elif kind == "broken_link":
        os.symlink(p.with_name("nowhere"), p)
    elif kind == "below_file":
        p.with_name(p.name + ".f").write_text("x")
        return p.with_name(p.name + ".f") / "x"
    return p


@pytest.mark.parametrize("kind", ["missing", "loop", "fifo", "folder", "broken_link", "below_file"])
def test_path_errors_say_what_the_path_is(tmp_path, capsys, kind):
    """A map, a frame source and a profile path of each kind: exit 2 with one line saying what it is (a FIFO is
    refused before it is opened: reading one would wait forever)."""
    said = {"missing": "no such", "loop": "a symlink loop", "fifo": "a FIFO", "folder": "a folder",
            "broken_link": "a broken symlink", "below_file": "below a file"}[kind]
    plan = ["plan", "--duration", "10", "--fps", "10", "--profile"]
    for argv in (["ask", "{}.json", Q], ["ask", "{}", Q], plan + ["{}.toml"]):
        if kind == "folder" and argv[0] == "ask" and argv[1] == "{}":
            continue  # a folder is a frame source: refused for holding no frames (tests/test_bad_inputs.py)
        p = _make_kind(tmp_path / argv[-1 if argv[0] == "plan" else 1].format(f"x{len(argv)}{argv[0]}"), kind)
        argv = [a if "{}" not in a else p for a in argv]
        code, out, err = run_cli(capsys, argv)
        assert code == 2 and err.startswith("error: ") and len(err.strip().splitlines()) == 1, (argv, err)
        if kind == "missing":
            assert "no such" in err or "missing" in err or "does not exist" in err, (argv, err)
        else:
            assert said in err, (argv, err)


def test_manifest_without_preprocessing_names_the_field(tmp_path, capsys):
    """The graph takes 8x8 images; a manifest with no preprocessing would feed frames as they come and fail
    inside onnxruntime: verify and loading say `preprocessing.size` instead."""
    from fuzz_files import base_manifest, use_roles
    from mosaicthinker.runtime.infra.errors import BundleError

    b = tmp_path / "bundle"
    man = base_manifest(b)
    del man["roles"]["depth"]["preprocessing"]
    (b / "manifest.json").write_text(json.dumps(man))
    code, out, err = run_cli(capsys, ["bundle", "verify", b])
    assert code == 2 and "roles.depth.preprocessing.size is missing but the graph input 'x' takes 8x8" in err, err
    with pytest.raises(BundleError, match=r"roles\.depth\.preprocessing\.size is missing"):
        use_roles(b)


def test_arch_of_another_role_is_refused_by_verify_and_at_load(tmp_path, capsys):
    from fuzz_files import base_manifest, use_roles
    from mosaicthinker.runtime.infra.errors import BundleError

    b = tmp_path / "bundle"
    man = base_manifest(b)
    man["roles"]["depth"]["arch"] = "deeplab"  # a segmenter's architecture on the depth graph
    (b / "manifest.json").write_text(json.dumps(man))
    code, out, err = run_cli(capsys, ["bundle", "verify", b])
    assert code == 2 and "roles.depth.arch is 'deeplab', an architecture of the segmenter role" in err, err
    with pytest.raises(BundleError, match="an architecture of the segmenter role"):
        use_roles(b)


def test_config_of_the_wrong_type_is_refused_by_verify(tmp_path, capsys):
    """The issue's case: `config.score_threshold` a string passed verify and crashed in ask."""
    from fuzz_files import base_manifest

    b = tmp_path / "bundle"
    man = base_manifest(b)
    man["roles"]["detector"]["config"]["score_threshold"] = "0.5"
    (b / "manifest.json").write_text(json.dumps(man))
    code, out, err = run_cli(capsys, ["bundle", "verify", b])
    assert code == 2 and "roles.detector.config.score_threshold must be a number in 0..1" in err, err


def test_map_room_polygon_a_string_is_exit_2(tmp_path, capsys):
    """The issue's case: `room.polygon` a string crashed (`len() of unsized object`)."""
    m = tmp_path / "m.json"
    small_map(m)
    d = json.loads(m.read_text())
    d["room"] = {"polygon": "abc", "floor_z": 0.0, "ceiling_z": 2.5}
    m.write_text(json.dumps(d))
    code, out, err = run_cli(capsys, ["ask", m, Q])
    assert code == 2 and "room.polygon must be" in err and "got a string 'abc'" in err, err
    np.testing.assert_equal(code, 2)


@pytest.mark.parametrize("hard_links", [True, False])
def test_the_lock_is_never_seen_empty(tmp_path, monkeypatch, hard_links):
    """The lock appears with its holder already written (a run killed at any instant leaves no empty lock that
    reads as a run still starting); without hard links the create-exclusive path still takes it; a second run is
    refused while the first holds it, and no temp file stays behind."""
    from mosaicthinker.runtime.infra import outputs

    if not hard_links:
        def no_link(*a, **k):
            raise PermissionError("hard links not supported")
        monkeypatch.setattr(outputs.os, "link", no_link)
    seen: list[bytes] = []
    real_link = os.link

    def watch_link(src, dst, *a, **k):
        seen.append(Path(src).read_bytes())  # what the lock will hold the instant it exists
        return real_link(src, dst, *a, **k)
    if hard_links:
        monkeypatch.setattr(outputs.os, "link", watch_link)
    a = outputs.RunOutputs(tmp_path)
    held = json.loads((tmp_path / outputs.LOCK).read_text())
    assert held["pid"] == os.getpid() and held["run_id"] == a.run_id
    assert (not hard_links) or (seen and json.loads(seen[0])["run_id"] == a.run_id)
    with pytest.raises(Exception, match="another run"):
        outputs.RunOutputs(tmp_path)
    a.close()
    assert not (tmp_path / outputs.LOCK).exists()
    assert not list(tmp_path.glob(outputs.TMP_PREFIX + "*"))
