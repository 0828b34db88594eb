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

import contextlib
import io
import json
import os
import signal
import sys
import tempfile
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Callable, Iterator

sys.path.insert(0, str(Path(__file__).resolve().parent))
from fuzz_files import (MUTATIONS, base_annotation, base_manifest, base_map, base_profile, mutate,  # noqa: E402
                        paths, show_path, use_roles)

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


# ------------------------------------------------------------------------------------------------ field damage

KINDS = sorted(MUTATIONS)
PER_PATH = 3  # kinds per field path in the suite's stratified run (every kind still meets many paths)


def _pairs(base: Any, full: bool) -> Iterator[tuple[tuple, str]]:
    """(field path, damage) pairs: all of them (`full`, the benchmark), or PER_PATH kinds per path walking
    round-robin through the kinds (the test suite)."""
    for i, path in enumerate(paths(base)):
        kinds = KINDS if full else [KINDS[(i * PER_PATH + j) % len(KINDS)] for j in range(PER_PATH)]
        for kind in kinds:
            yield path, kind


def _leaf(path: tuple) -> str:
    return next((str(k) for k in reversed(path) if isinstance(k, str)), "")


def _dump(doc: Any, path: Path) -> None:
    path.write_text(json.dumps(doc, indent=1))


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
    from mosaicthinker.runtime.errors import MosaicError

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
    from mosaicthinker.runtime.errors import InputError
    from mosaicthinker.runtime.semantic_map import SemanticMap

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


EXTRA_CLASSES: dict[str, Callable[[Path], Iterator[Record]]] = {}
