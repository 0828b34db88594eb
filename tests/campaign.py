"""The reliability campaign of issue 29: every class of bad input and fault the issue names, with more cases per
class than it names, each run through the real `mosaic` entry point and classified:

    crash           exit 1, a traceback, or death by a signal the CLI does not handle
    hang            still running after the case's time limit
    silently wrong  exit 0 where the case needs a note (`note:` in the answer) or a different answer
    clear error     exit 2 with `error:` naming the file or field
    flagged answer  exit 0 with the note the case asks for
    answered        exit 0 where nothing had to be said (the damage did not matter)

`run_all()` returns one record per case; tests/test_campaign.py asserts 0 crash / 0 hang / 0 silently wrong,
benchmarks/reliability_campaign.py writes the counts per class to benchmarks/results/reliability_campaign.json.
Field-damage cases run in-process (`cli.main`, an alarm as the time limit); stream, signal and process cases run
a real `python -m mosaicthinker.runtime.cli` subprocess.
"""
from __future__ import annotations

import copy
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
from dataclasses import asdict
from pathlib import Path
from typing import Any, Callable, Iterator

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from campaign_core import (CLASSES, Record, _dump, _limit, _proc, _Timeout, classify, cli,  # noqa: E402,F401
                           start_run)
from fuzz_files import (MUTATIONS, base_annotation, base_manifest, base_map, base_profile, mutate,  # noqa: E402
                        paths, show_path, use_roles)

# ------------------------------------------------------------------------------------------------ field damage

KINDS = sorted(MUTATIONS)
PER_PATH = 2  # kinds per field path in the suite's stratified run (every kind still meets many paths)


def _pairs(base: Any, full: bool) -> Iterator[tuple[tuple, str]]:
    """(field path, damage) pairs: all of them (`full`, the benchmark), or PER_PATH kinds per path walking
    round-robin through the kinds (the test suite)."""
    for i, path in enumerate(paths(base)):
        kinds = KINDS if full else [KINDS[(i * PER_PATH + j) % len(KINDS)] for j in range(PER_PATH)]
        for kind in kinds:
            yield path, kind


def _leaf(path: tuple) -> str:
    return next((str(k) for k in reversed(path) if isinstance(k, str)), "")


def map_cases(work: Path, full: bool = True) -> Iterator[Record]:
    base = base_map()
    f = work / "map.json"
    for path, kind in _pairs(base, full):
        _dump(mutate(base, path, kind), f)
        worst = ("answered", "")
        for q in ("How many chairs are in the room?", "What is the distance between the chair and the table?",
                  "How big is the room (in square meters)?"):
            got = classify(*cli(["ask", f, q]), file=str(f), field=_leaf(path))
            if CLASSES.index(got[0]) < CLASSES.index(worst[0]):
                worst = got
        yield Record("map.json field", f"{show_path(path)} <- {kind}", *worst)


def manifest_cases(work: Path, full: bool = True) -> Iterator[Record]:
    from mosaicthinker.runtime.infra.errors import MosaicError

    bundle = work / "bundle"
    base = base_manifest(bundle)
    f = bundle / "manifest.json"
    for path, kind in _pairs(base, full):
        _dump(mutate(base, path, kind), f)
        code, out, err = cli(["bundle", "verify", bundle])
        got = classify(code, out, err, file=str(f), field=_leaf(path))
        if code == 0:
            try:
                with _limit(60):
                    use_roles(bundle)
            except MosaicError:
                got = ("clear error", "at load")
            except _Timeout:
                got = ("hang", "at load")
            except Exception as e:  # noqa: BLE001 - the class this campaign counts
                got = ("crash", f"verify passed, then {type(e).__name__}: {e}"[:200])
        yield Record("manifest field", f"{show_path(path)} <- {kind}", *got)
    _dump(base, f)


def profile_cases(work: Path, full: bool = True) -> Iterator[Record]:
    import tomli_w

    base = base_profile()
    f = work / "p.toml"
    for path, kind in _pairs(base, full):
        try:
            f.write_bytes(tomli_w.dumps(mutate(base, path, kind)).encode())
        except TypeError:  # TOML has no null
            continue
        got = classify(*cli(["plan", "--profile", f, "--duration", "20", "--fps", "15"]), file=str(f),
                       field=_leaf(path).rsplit("_", 1)[0])
        yield Record("profile field", f"{show_path(path)} <- {kind}", *got)


def annotation_cases(work: Path, full: bool = True) -> Iterator[Record]:
    from mosaicthinker.host.evaluation.scene import SceneEvalConfig, load_annotation, score_answers, visible_meta
    from mosaicthinker.runtime.infra.errors import InputError
    from mosaicthinker.runtime.map import SemanticMap

    base = base_annotation()
    f = work / "annotation.json"
    for path, kind in _pairs(base, full):
        _dump(mutate(base, path, kind), f)
        try:
            with _limit(60):
                name, scene, _ = load_annotation(f)
                smap = SemanticMap.from_meta_info(scene, name)
                vm = visible_meta(scene, {c: [True] * len(v) for c, v in scene["object_bbox"].items()})
                score_answers(smap, name, vm, SceneEvalConfig(per_type=2, min_per_type=1))
            got = ("answered", "")
        except InputError as e:
            got = ("clear error", str(e)[:200]) if str(f) in str(e) else ("crash", f"unnamed: {e}"[:200])
        except _Timeout:
            got = ("hang", "")
        except Exception as e:  # noqa: BLE001
            got = ("crash", f"{type(e).__name__}: {e}"[:200])
        yield Record("annotation field", f"{show_path(path)} <- {kind}", *got)


FIELD_CLASSES: dict[str, Callable[[Path], Iterator[Record]]] = {
    "map": map_cases, "manifest": manifest_cases, "profile": profile_cases, "annotation": annotation_cases}


def run_all(only: tuple[str, ...] | None = None, work: Path | None = None, full: bool = True) -> list[Record]:
    """Every case of the campaign's classes (`only`: a subset of their names; `full`: every field damage pair,
    else the stratified subset)."""
    recs: list[Record] = []
    with tempfile.TemporaryDirectory(prefix="mosaic-campaign-") as tmp:
        work = Path(work or tmp)
        for name, gen in {**FIELD_CLASSES, **EXTRA_CLASSES}.items():
            if only and name not in only:
                continue
            d = work / name
            d.mkdir(parents=True, exist_ok=True)
            recs += list(gen(d, full))
    return recs


def summary(recs: list[Record]) -> dict[str, Any]:
    by: dict[str, dict[str, int]] = {}
    for r in recs:
        by.setdefault(r.cls, {c: 0 for c in CLASSES})[r.outcome] += 1
    total = {c: sum(v[c] for v in by.values()) for c in CLASSES}
    return {"cases": len(recs), "total": total, "by_class": by,
            "failures": [asdict(r) for r in recs if r.outcome in ("crash", "hang", "silently wrong")]}


# ------------------------------------------------------------------------------------------------ paths

def _kinds(base: Path) -> Iterator[tuple[str, Path]]:
    """A path of each kind that is not a usable file: missing, loop, FIFO, folder, broken link, below a file,
    a device."""
    base.mkdir(parents=True, exist_ok=True)
    yield "missing", base / "missing"
    a, b = base / "loop-a", base / "loop-b"
    os.symlink(b, a)
    os.symlink(a, b)
    yield "symlink loop", a
    os.mkfifo(base / "fifo")
    yield "FIFO", base / "fifo"
    (base / "folder").mkdir()
    yield "folder", base / "folder"
    os.symlink(base / "nowhere", base / "broken")
    yield "broken link", base / "broken"
    (base / "file").write_text("x")
    yield "below a file", base / "file" / "x"
    yield "device", Path("/dev/null")


def path_cases(work: Path, full: bool = True) -> Iterator[Record]:
    from fuzz_files import base_map as _bm

    good_map = work / "good.json"
    _dump(_bm(), good_map)
    uses = {  # what is given the bad path -> argv (a FIFO must be refused before it is opened: a read blocks)
        "map": lambda p: ["ask", _as(p, ".json"), "How many chairs?"],
        "frames": lambda p: ["ask", p, "How many chairs?"],
        "profile": lambda p: ["plan", "--duration", "10", "--fps", "10", "--profile", _as(p, ".toml")],
        "bundle": lambda p: ["bundle", "verify", p],
        "out": lambda p: ["ask", good_map, "How many chairs?", "--out", p],
    }
    for use, argv in uses.items():
        for kind, p in _kinds(work / use):
            if use == "out" and kind in ("missing", "folder"):
                continue  # a missing --out folder is created, an existing one written: not errors
            if use == "frames" and kind == "folder":
                continue  # an empty folder: refused for holding no frames (the field-damage classes)
            code, out, err = cli(argv(p), limit=30)
            got = classify(code, out, err, file=str(p))
            if got[0] == "clear error" and not any(w in err for w in _SAID[kind]):
                got = ("crash", f"unclear error: does not say the path is {kind}: {err.strip()[:150]}")
            yield Record("path kind", f"{use}: {kind}", *got)


_SAID = {"missing": ("no such", "missing", "does not exist"), "symlink loop": ("symlink loop",),
         "FIFO": ("FIFO",), "folder": ("folder",), "broken link": ("broken symlink",),
         "below a file": ("below a file",), "device": ("device",)}


def _as(p: Path, suffix: str) -> Path:
    """The same kind of path with the file suffix a command expects (a link to it, a FIFO of that name ...)."""
    if p == Path("/dev/null") or p.suffix == suffix:
        return p
    q = p.with_name(p.name + suffix)
    if os.path.lexists(p) and not os.path.lexists(q):
        os.rename(p, q) if not p.is_symlink() or p.name != "loop-a" else os.symlink(p, q)
    return q


# ------------------------------------------------------------------------------------------------ health

def health_map_cases(work: Path, full: bool = True) -> Iterator[Record]:
    """Implausible magnitudes in a map: answered with a note, never silently."""
    base = base_map()
    damages = {
        "object 1,000 km long": lambda d: d["instances"][2]["box"].__setitem__("axesLengths", [1e6, 0.8, 0.8]),
        "object 100 m long": lambda d: d["instances"][0]["box"].__setitem__("axesLengths", [100.0, 0.5, 1.0]),
        "room larger than a stadium": lambda d: d["room"].__setitem__(
            "polygon", [[-1, -1], [400, -1], [400, 300], [-1, 300]]),
        "room 200 m high": lambda d: d["room"].__setitem__("ceiling_z", 200.0),
        "objects 5 km apart": lambda d: d["instances"][1]["box"].__setitem__("centroid", [5000.0, 0.2, 0.5]),
        "room outline of 2 corners": lambda d: d["room"].__setitem__("polygon", [[0, 0], [5, 0]]),
    }
    qs = {"count": "How many chairs are in the room?", "size": "What is the length of the longest dimension of "
          "the table in centimeters?", "distance": "What is the distance between the chair and the table?",
          "room": "How big is the room (in square meters)?"}
    f = work / "map.json"
    for name, damage in damages.items():
        d = copy.deepcopy(base)
        damage(d)
        _dump(d, f)
        for qn, q in qs.items():
            got = classify(*cli(["ask", f, q]), file=str(f), note="note: ")
            yield Record("implausible map", f"{name}: {qn}", *got)


def _synth(work: Path) -> Path:
    d = work / "scene"
    if not d.is_dir():
        code, out, err = cli(["synth", "--out", d, "--duration", "8", "--fps", "4", "--size", "160x120",
                              "--no-video", "--seed", "3"], limit=300)
        assert code == 0, err
    return d


def _subset(scene: Path, out: Path, idx: list[int]) -> Path:
    """The frames `idx` of a synthetic scene, renumbered from 0 (the oracle reads masks by position)."""
    out.mkdir(parents=True)
    for f in scene.glob("*.json"):
        shutil.copy(f, out / f.name)
    shutil.copy(scene / "camera-intrinsics.txt", out)
    for j, i in enumerate(idx):
        for p in scene.glob(f"frame-{i:06d}.*"):
            shutil.copy(p, out / p.name.replace(f"{i:06d}", f"{j:06d}"))
    return out


def health_frame_cases(work: Path, full: bool = True) -> Iterator[Record]:
    """Degenerate sensor input on a synthetic scene (oracle detector): said in the answer or refused."""
    import cv2
    import numpy as np

    scene = _synth(work)
    n = len(list(scene.glob("frame-*.color.*")))
    q = "How many tables are in the room?"
    damages = {
        "depth zero everywhere": ("depth", lambda a, i: np.zeros_like(a), "is invalid everywhere"),
        "depth constant": ("depth", lambda a, i: np.full_like(a, 2000), "is one constant value"),
        # half the frames: the even ones, those the down-sampling keeps (a damaged frame no key frame uses need
        # not be said)
        "depth zero in half the frames": ("depth", lambda a, i: a if i % 2 else np.zeros_like(a),
                                          "is invalid everywhere"),
        "all frames black": ("color", lambda a, i: np.zeros_like(a), "are black"),
        "half the frames black": ("color", lambda a, i: np.zeros_like(a) if i % 2 else a, "are black"),
        "frames nearly black (<= 8/255)": ("color", lambda a, i: np.full_like(a, 6), "are black"),
    }
    for name, (what, fn, said) in damages.items():
        d = _subset(scene, work / name.replace(" ", "_"), list(range(n)))
        for i, p in enumerate(sorted(d.glob(f"frame-*.{what}.*"))):
            a = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
            cv2.imwrite(str(p), fn(a, i))
        code, out, err = cli(["ask", d, q, "--detector", "oracle"], limit=300)
        got = classify(code, out, err, file=str(d), note=said)
        if code == 2 and said not in err:
            got = ("silently wrong", f"refused without saying {said!r}: {err[:150]}")
        yield Record("degenerate frames", name, *got)


def short_input_cases(work: Path, full: bool = True) -> Iterator[Record]:
    """Every input size from one frame up, synthetic RGB-D (oracle detector, sensor depth): frames spread over
    the walk (far apart) and consecutive; a static input (one frame repeated)."""
    scene = _synth(work)
    n = len(list(scene.glob("frame-*.color.*")))
    q = "How many tables are in the room?"
    sets = {f"{k} frame(s) far apart": [int(i) for i in np.linspace(0, n - 1, k).round()] for k in (1, 2, 3, 5, 8)}
    sets.update({f"{k} consecutive frame(s)": list(range(k)) for k in (2, 3, 5)})
    sets["static: frame 0 ten times"] = [0] * 10
    for name, idx in sets.items():
        d = _subset(scene, work / name.replace(" ", "_").replace(":", ""), idx)
        got = classify(*cli(["ask", d, q, "--detector", "oracle"], limit=300), file=str(d))
        yield Record("short input", name, *got)


# ------------------------------------------------------------------------------------------------ processes

def stream_cases(work: Path, full: bool = True) -> Iterator[Record]:
    """Closed or broken stdout / stderr / stdin: the run finishes, writes --out, exits 0."""
    from test_bad_inputs import _big_map

    m = str(_big_map(work / "big.json", 3000))
    base = f"{sys.executable} -m mosaicthinker.runtime.cli ask {m} 'How many chairs?' --json --out"
    cases = {"stdout closed": ">&-", "stderr closed": "2>&-", "both closed": ">&- 2>&-", "stdin closed": "<&-",
             "stdout to a pipe closed early": "| head -c 10", "stdout and stderr to a pipe closed early":
             "2>&1 | head -c 10", "stdout to /dev/full": ">/dev/full"}
    for name, redirect in cases.items():
        out = work / name.replace(" ", "_")
        code, so, se = _proc(f"{base} {out} {redirect}; exit ${{PIPESTATUS[0]}}")
        got = classify(code, "", se)
        if got[0] == "answered":
            try:
                ok = json.loads((out / "run.json").read_text())["status"] == "complete"
            except (OSError, ValueError):
                ok = False
            got = got if ok else ("crash", "--out not complete")
        yield Record("streams", name, *got)


def signal_cases(work: Path, full: bool = True) -> Iterator[Record]:
    """A signal during a run: the documented exit (128 + n), run.json says interrupted, the lock is gone."""
    from test_bad_inputs import _big_map

    m = str(_big_map(work / "big.json", 30000))
    for sig in (signal.SIGTERM, signal.SIGINT, signal.SIGHUP):
        out = work / sig.name
        p = start_run(["ask", m, "How many chairs?", "--out", out], out, text=True, step=0.02)
        p.send_signal(sig)
        try:
            _, err = p.communicate(timeout=120)
        except subprocess.TimeoutExpired:
            p.kill()
            yield Record("signals", sig.name, "hang")
            continue
        status = json.loads((out / "run.json").read_text()).get("status")
        if p.returncode == 0:
            got = ("answered", "finished before the signal")
        elif p.returncode == 128 + sig and status == "interrupted" and not (out / ".mosaic.lock").exists() \
                and "Traceback" not in err:
            got = ("clear error", err.strip()[:200])
        else:
            got = ("crash", f"exit {p.returncode}, run.json {status}: {err.strip()[-200:]}")
        yield Record("signals", sig.name, *got)


def json_mode_cases(work: Path, full: bool = True) -> Iterator[Record]:
    """--json: stdout one JSON object, stderr only `warning:` / `error:` lines (a random-weight model's warning,
    degraded notes, a bad input, an implausible map)."""
    from fuzz_files import base_manifest

    b = work / "bundle"
    man = base_manifest(b)
    man["roles"]["detector"]["random_weights"] = True
    (b / "manifest.json").write_text(json.dumps(man))
    m = work / "map.json"
    _dump(base_map(), m)
    big = copy.deepcopy(base_map())
    big["instances"][0]["box"]["axesLengths"] = [1e6, 1, 1]
    _dump(big, work / "big.json")
    runs = {"random-weight bundle": ["ask", m, "How many chairs?", "--bundle", b, "--answerer", "map"],
            "implausible map": ["ask", work / "big.json", "How many chairs?"],
            "bad question": ["ask", m, ""], "bad flag": ["plan", "--fps", "-3"],
            "missing map": ["ask", work / "nope.json", "How many chairs?"]}
    for name, argv in runs.items():
        code, out, err = cli(argv + ["--json"])
        bad_err = [ln for ln in err.splitlines() if not ln.startswith(("warning:", "error:"))]
        try:
            ok_out = code != 0 or isinstance(json.loads(out), dict)
        except ValueError:
            ok_out = False
        got = classify(code, out, err) if not bad_err and ok_out else \
            ("crash", f"not JSON only: {bad_err[:2] or out[:100]}")
        yield Record("--json streams", name, *got)


EXTRA_CLASSES: dict[str, Callable[[Path], Iterator[Record]]] = {
    "paths": path_cases, "health_map": health_map_cases, "health_frames": health_frame_cases,
    "short_inputs": short_input_cases, "streams": stream_cases, "signals": signal_cases,
    "json_mode": json_mode_cases}


from campaign_round4 import ROUND4_CLASSES  # noqa: E402 - issue 36's classes (they import this module's helpers)

EXTRA_CLASSES.update(ROUND4_CLASSES)
