"""Output folders of a run: checked before the pipeline runs, locked, written atomically and as one group.

One `RunOutputs` per command run:

    outs = RunOutputs(folder)          # checks the folder (a file? read-only? full?) and takes its lock
    outs.add_json("map.json", d)       # staged in a hidden temp file beside the target, nothing replaced yet
    outs.add_png("map.png", rgb)       # encoded in memory first: a failed encode raises, never a silent skip
    outs.commit()                      # fsync + rename every staged file, then `run.json` (status complete)
    outs.close()                       # drops the lock and any temp file left (also on errors: use `with`)

Why: a kill -9 during a plain `open(...).write` leaves a truncated map.json beside a new map.png, and two runs
into one folder mix their files. Here every file carries the run id, `run.json` says which run the folder
holds and whether it finished (status "running" from the start until every rename is done), and a second run
on a locked folder is refused. A lock whose process is gone is taken over and the result says so.
"""
from __future__ import annotations

import errno
import io
import json
import os
import secrets
import shutil
import socket
import sys
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from .errors import OutputError, path_kind
from . import jsonio
from .trace import as_trace

LOCK = ".mosaic.lock"
RUN_FILE = "run.json"
TMP_PREFIX = ".mosaic-tmp."
MIN_FREE_MB = 64  # below this the folder counts as full: a map + trace + image of a large room is ~10 MB


def new_run_id() -> str:
    """`20261201T203000Z-1a2b3c4d`: sortable by start time, unique across concurrent runs."""
    return time.strftime("%Y%m%dT%H%M%SZ", time.gmtime()) + "-" + secrets.token_hex(4)


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, owned by someone else
        return True
    return True


def _age_s(path: Path) -> float:
    try:
        return time.time() - path.stat().st_mtime
    except OSError:
        return 1e9


def check_out_dir(folder: Path, what: str = "--out") -> None:
    """Refuse, before any work, an output folder that is a file, cannot be created, is read-only or full."""
    kind = path_kind(folder)
    if kind == "a file":
        raise OutputError(f"{what} {folder}: is a file, not a folder; give a folder path (it is created if needed)")
    if kind not in ("a folder", "missing"):
        raise OutputError(f"{what} {folder}: is {kind}; give a writable folder path (it is created if needed)")
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise OutputError(f"{what} {folder}: cannot create the folder ({e.strerror}); choose a writable place") from e
    probe = folder / f"{TMP_PREFIX}probe-{os.getpid()}"
    try:
        with open(probe, "wb") as f:
            f.write(b"x")
        probe.unlink()
    except OSError as e:
        raise OutputError(f"{what} {folder}: not writable ({e.strerror}); choose a writable folder") from e
    free_mb = shutil.disk_usage(folder).free / 2**20
    if free_mb < MIN_FREE_MB:
        raise OutputError(f"{what} {folder}: only {free_mb:.0f} MB free (need {MIN_FREE_MB} MB); free space or "
                         f"choose another folder")


def unfinished_run_note(path: str | os.PathLike) -> str | None:
    """A sentence for whoever opens `path` (an output folder, or a file in one, e.g. its map.json) when the folder's
    `run.json` says its last run did not finish: still "running" with its process gone (killed: SIGKILL, a power
    cut), "running" now (another process is writing there), "interrupted" or "failed". None when it finished or
    the folder holds no run.json. The folder's files are then an earlier run's (every file is renamed in only
    when the whole group is written)."""
    p = Path(path)
    folder = p if p.is_dir() else p.parent
    try:
        rec = json.loads((folder / RUN_FILE).read_text())
    except (OSError, ValueError, UnicodeDecodeError):
        return None
    if not isinstance(rec, dict) or rec.get("status") in (None, "complete"):
        return None
    status, rid, pid = rec.get("status"), rec.get("run_id"), rec.get("pid")
    held = RunOutputs._read_lock(folder / LOCK)
    if status == "running" and held is not None and held.get("run_id") == rid and \
            held.get("host") == socket.gethostname() and _pid_alive(held["pid"]):
        why = f"it is still running (pid {pid}): its files may replace these at any moment"
    elif status == "running":
        why = f"run.json still says 'running' but its process (pid {pid}) is gone: it was killed before it finished"
    else:
        why = f"it ended '{status}'" + (f": {rec.get('reason')}" if rec.get("reason") else "")
    prev = rec.get("previous") if isinstance(rec.get("previous"), dict) else None
    kept = f"the folder holds the files of an earlier run (run id {prev.get('run_id')})" if prev and \
        prev.get("run_id") else "the folder's files are from an earlier run, if any"
    return f"{folder / RUN_FILE}: the last run in this folder (run id {rid}) did not finish ({why}); {kept}"


def check_out_file(path: str | os.PathLike, what: str) -> None:
    """Refuse, before any work, a result file that cannot be written: a folder, a FIFO or device, below a file,
    in a folder that cannot be created or written (the folder is checked as `check_out_dir` does)."""
    p = Path(path)
    kind = path_kind(p)
    if kind not in ("a file", "missing"):
        raise OutputError(f"{what} {p}: is {kind}; give a file path in a writable folder")
    check_out_dir(p.parent if str(p.parent) else Path("."), f"{what} {p}: its folder")


class RunOutputs:
    """The files one run leaves in one folder (see the module docstring). Not thread-safe."""

    def __init__(self, folder: str | os.PathLike, run_id: str | None = None, *, what: str = "--out"):
        self.folder = Path(folder)
        self.run_id = run_id or new_run_id()
        self.what = what
        self.staged: list[tuple[Path, Path]] = []  # (temp, final)
        self.staged_dirs: list[tuple[Path, Path]] = []  # (temp folder, final folder): whole trees of files
        self.notes: list[str] = []
        self._locked = False
        self._started = False  # run.json says "running": close() must end it as complete, failed or interrupted
        self._done = False
        self.failure: str | None = None  # why the files were not written (set by save_run on a write error)
        check_out_dir(self.folder, what)
        try:
            self._lock()
            self._clean_stale_temps()
            unfinished = unfinished_run_note(self.folder)  # we hold the lock: "running" there is a killed run
            if unfinished:
                self.notes.append(unfinished)
            self._previous = self._read_previous()
            self._started = True  # before the write: a signal landing in it still ends run.json as interrupted
            self._write_run_file("running", [], previous=self._previous)  # a kill leaves it: what is kept
        except BaseException:  # incl. a SIGTERM landing here: never leave our lock behind
            self.close()
            raise

    # -- lock -----------------------------------------------------------------------------------------------
    def _lock(self) -> None:
        lock = self.folder / LOCK
        body = jsonio.dumps({"pid": os.getpid(), "host": socket.gethostname(), "run_id": self.run_id,
                           "started": time.time()}).encode()
        for _ in range(3):
            if not self._create_lock(lock, body):
                held = self._read_lock(lock)
                if held is None and _age_s(lock) < 10.0:  # just created, not yet written: another run's
                    held = {"pid": "?", "run_id": "starting"}
                if held is not None and (held.get("host") != socket.gethostname() or held["pid"] == "?"
                                         or _pid_alive(held["pid"])):
                    raise OutputError(f"{self.what} {self.folder}: another run (pid {held['pid']}, run id "
                                     f"{held.get('run_id')}) is writing there; wait for it to finish or choose "
                                     f"another {self.what} folder") from None
                try:  # the holder is gone (killed): take the lock over and say so
                    lock.unlink()
                except FileNotFoundError:
                    pass
                who = f"pid {held['pid']}, run id {held.get('run_id')}" if held else "unreadable lock file"
                self.notes.append(f"took over a stale lock on {self.folder} ({who}: process gone)")
                continue
            self._locked = True  # an interrupt from here on removes the lock in close()
            return
        raise OutputError(f"{self.what} {self.folder}: could not take the folder's lock {lock}; remove it if no "
                         f"run is writing there")

    def _create_lock(self, lock: Path, body: bytes) -> bool:
        """Create `lock` holding `body` if no lock exists (False if one does). The body is written to a temp file
        first and hard-linked in, so a run killed at any instant never leaves an empty lock that would look like
        a run still starting; where the filesystem has no hard links, create-exclusive then write."""
        tmp = self.folder / f"{TMP_PREFIX}{self.run_id}{LOCK}"
        try:
            tmp.write_bytes(body)
            try:
                os.link(tmp, lock)
                return True
            except FileExistsError:
                return False
            except OSError:  # no hard links here (e.g. some FUSE or FAT mounts)
                try:
                    fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
                except FileExistsError:
                    return False
                self._locked = True  # before writing: an interrupt from here on removes the lock in close()
                with os.fdopen(fd, "wb") as f:
                    f.write(body)
                return True
        finally:
            tmp.unlink(missing_ok=True)

    def _read_previous(self) -> dict[str, Any] | None:
        """The run this folder held before (its run.json), for a run that ends without its files."""
        try:
            d = json.loads((self.folder / RUN_FILE).read_text())
        except (OSError, ValueError):
            return None
        if not isinstance(d, dict):
            return None
        prev = d.get("previous") if d.get("status") != "complete" else None
        return prev if isinstance(prev, dict) else {k: d.get(k) for k in ("run_id", "status", "files")}

    @staticmethod
    def _read_lock(lock: Path) -> dict[str, Any] | None:
        try:
            d = json.loads(lock.read_text())
            return d if isinstance(d, dict) and isinstance(d.get("pid"), int) else None
        except (OSError, ValueError):
            return None

    def _clean_stale_temps(self) -> None:
        for p in self.folder.glob(TMP_PREFIX + "*"):
            try:
                shutil.rmtree(p) if p.is_dir() and not p.is_symlink() else p.unlink()
            except OSError:
                pass

    # -- staging --------------------------------------------------------------------------------------------
    def _stage(self, name: str, data: bytes) -> Path:
        final = self.folder / name
        tmp = self.folder / f"{TMP_PREFIX}{self.run_id}.{name}"
        try:
            with open(tmp, "wb") as f:
                f.write(data)
                f.flush()
                os.fsync(f.fileno())
        except OSError as e:
            try:
                tmp.unlink()
            except OSError:
                pass
            raise OSError(e.errno, f"writing {final}: {e.strerror}") from e
        self.staged = [s for s in self.staged if s[1] != final] + [(tmp, final)]
        return final

    def add_json(self, name: str, obj: dict[str, Any]) -> Path:
        """Stage a JSON object (a `run_id` field is added), written by `json_text`."""
        return self._stage(name, json_text({**obj, "run_id": self.run_id}).encode())

    def add_png(self, name: str, rgb: np.ndarray) -> Path:
        """Stage an RGB image [H, W, 3] uint8 as PNG with the run id in a tEXt chunk; a failed encode raises."""
        data = encode_png(rgb, {"mosaicthinker_run_id": self.run_id})
        return self._stage(name, data)

    def stage_dir(self, name: str = "") -> Path:
        """A hidden temp folder for files a generator writes itself (a synthetic scene's frames): `commit()`
        moves every file in it to `folder/name` (the folder itself for ""), before run.json says complete."""
        tmp = self.folder / f"{TMP_PREFIX}{self.run_id}.dir{len(self.staged_dirs)}"
        tmp.mkdir()
        self.staged_dirs.append((tmp, self.folder / name if name else self.folder))
        return tmp

    def add_text(self, name: str, text: str) -> Path:
        """Stage a text file; its last line names the run (an HTML comment in Markdown, where `#` is a heading)."""
        tag = (f"<!-- run_id: {self.run_id} -->" if Path(name).suffix.lower() in (".md", ".html")
               else f"# run_id: {self.run_id}")
        return self._stage(name, (text.rstrip("\n") + f"\n{tag}\n").encode())

    def commit(self) -> list[str]:
        """Rename every staged file into place, then mark the run complete in run.json. Returns the paths."""
        done = []
        for tmp, final in self.staged:
            os.replace(tmp, final)
            done.append(str(final))
        self.staged = []
        for tmp, final in self.staged_dirs:
            done += _move_tree(tmp, final)
        self.staged_dirs = []
        self._write_run_file("complete", done)
        self._done = True
        _fsync_dir(self.folder)
        return done

    def _write_run_file(self, status: str, files: list[str], **extra: Any) -> None:
        rec = {"schema": "mosaicthinker.run/1", "run_id": self.run_id, "status": status, "pid": os.getpid(),
               "files": [os.path.relpath(f, self.folder) for f in files],
               "time": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), **extra}
        tmp = self.folder / f"{TMP_PREFIX}{self.run_id}.{RUN_FILE}"
        with open(tmp, "w") as f:
            jsonio.dump(rec, f)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, self.folder / RUN_FILE)

    def _end_status(self, exc: BaseException | None) -> tuple[str, str]:
        """How a run that did not commit ended: "interrupted" (a signal, Ctrl-C: the exception in flight) or
        "failed" (a write error, any other exception, or closed before its files were complete), and why."""
        exc = exc if exc is not None else sys.exc_info()[1]  # in a `finally:`, the exception in flight
        if isinstance(exc, KeyboardInterrupt):
            return "interrupted", str(exc) or "interrupted (Ctrl-C)"
        if exc is not None:
            return "failed", f"{type(exc).__name__}: {exc}"[:300]
        return "failed", self.failure or "the run ended before its files were complete"

    def close(self, exc: BaseException | None = None) -> None:
        """Drop temp files and the lock; a run that did not commit ends run.json as failed or interrupted (the
        folder keeps the previous run's files, named in `previous`). exc: the exception that ended the run."""
        if self._started and not self._done:
            status, why = self._end_status(exc)
            for tmp, _ in self.staged:  # first free what was staged (a full disk needs the room for run.json)
                try:
                    tmp.unlink()
                except OSError:
                    pass
            try:
                self._write_run_file(status, [], reason=why, previous=self._previous)
            except OSError:
                pass  # a disk too full even for run.json: it keeps saying "running" (not current)
            self._started = False
        for tmp, _ in self.staged:
            try:
                tmp.unlink()
            except OSError:
                pass
        self.staged = []
        for tmp, _ in self.staged_dirs:
            shutil.rmtree(tmp, ignore_errors=True)
        self.staged_dirs = []
        if self._locked:
            try:
                (self.folder / LOCK).unlink()
            except OSError:
                pass
            self._locked = False

    def __enter__(self) -> "RunOutputs":
        return self

    def __exit__(self, exc_type: Any, exc: BaseException | None, tb: Any) -> None:
        self.close(exc)


def json_text(obj: Any, indent_below: int = 200_000) -> str:
    """JSON text of `obj`, always by the C encoder: indented by 1 when its compact form is under `indent_below`
    characters (the indenting encoder is pure Python: a trace with 12,500 evidence rows took seconds), else one
    line per top-level key (a long list one line per item). Each value is encoded once."""
    enc = jsonio.encode_fn()
    if not isinstance(obj, dict):
        compact = enc(obj)
        return (jsonio.dumps(obj, indent=1) if len(compact) < indent_below else compact) + "\n"
    parts = []
    for k, v in obj.items():
        if isinstance(v, list) and len(v) > 100:
            parts.append(f" {enc(str(k))}: [\n  " + ",\n  ".join(map(enc, v)) + "\n ]")
        else:
            parts.append(f" {enc(str(k))}: {enc(v)}")
    if sum(map(len, parts)) < indent_below:
        return jsonio.dumps(obj, indent=1) + "\n"
    return "{\n" + ",\n".join(parts) + "\n}\n"


def _move_tree(tmp: Path, final: Path) -> list[str]:
    """Rename every file under `tmp` to the same place under `final` (one rename each), then drop `tmp`."""
    done = []
    for dirpath, _, names in os.walk(tmp):
        dest = final / Path(dirpath).relative_to(tmp)
        dest.mkdir(parents=True, exist_ok=True)
        for n in names:
            os.replace(Path(dirpath) / n, dest / n)
            done.append(str(dest / n))
    shutil.rmtree(tmp, ignore_errors=True)
    return done


def _fsync_dir(folder: Path) -> None:
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def encode_png(rgb: np.ndarray, text: dict[str, str] | None = None) -> bytes:
    """RGB [H, W, 3] uint8 -> PNG bytes (Pillow, so text chunks can carry the run id). Raises on failure."""
    from PIL import Image, PngImagePlugin

    if rgb is None or rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.size == 0:
        raise ValueError(f"cannot encode an image of shape {getattr(rgb, 'shape', None)} as PNG")
    info = PngImagePlugin.PngInfo()
    for k, v in (text or {}).items():
        info.add_text(k, v)
    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(rgb, dtype=np.uint8)).save(buf, format="PNG", pnginfo=info)
    return buf.getvalue()


def write_error_message(e: OSError, folder: Path) -> str:
    """One `error:` line for a write that failed after the answer was computed."""
    why = "the disk is full" if e.errno == errno.ENOSPC else (e.strerror or str(e))
    return (f"error: could not write the output files in {folder} ({why}); the answer above is complete, the "
            f"files are not (the folder keeps the previous run's files); free space / fix permissions and rerun")


def save_run(outs: RunOutputs, items: list[tuple[str, str, Any]]) -> tuple[dict[str, str], str | None, int]:
    """Stage then commit every item `(key, file name, dict | str | RGB [H, W, 3] uint8 | an object with
    `json_bytes(run_id=...)`, e.g. a SemanticMap)` as one group.

    Returns ({key: path}, None, 0) when all were written, else ({}, one `error:` line, exit code): the caller
    still prints its answer, and the folder keeps the previous run's files (nothing was renamed)."""
    try:
        for _, name, obj in items:
            if isinstance(obj, np.ndarray):
                outs.add_png(name, obj)
            elif hasattr(obj, "json_bytes"):  # a semantic map writes its own JSON (a read map unchanged: a copy)
                outs._stage(name, obj.json_bytes(run_id=outs.run_id))
            elif isinstance(obj, str):
                outs.add_text(name, obj)
            else:
                outs.add_json(name, obj)
        outs.commit()
    except OSError as e:
        outs.failure = f"could not write the files: {e.strerror or e}"
        return {}, write_error_message(e, outs.folder), 2
    except ValueError as e:  # an image that cannot be encoded: a bug upstream, said so
        outs.failure = f"could not encode a file: {e}"
        return {}, f"internal error: could not encode an output file in {outs.folder} ({e}); report it", 1
    return {key: str(outs.folder / name) for key, name, _ in items}, None, 0


def note_outputs(outs: RunOutputs | None, trace: Any) -> None:
    """Record what the output folder handling did (stale lock taken over, run id) in the trace."""
    if outs is None:
        return
    trace.decide("output", {"folder": str(outs.folder), "run_id": outs.run_id})
    for n in outs.notes:
        trace.event("output", n)


def finish_group(outs: RunOutputs, items: list[tuple[str, str, Any]], result: dict[str, Any],
                 trace: Any = None) -> dict[str, Any]:
    """Write `items` as one group into a run's locked folder (see `save_run`) and record the outcome in
    `result` (`files`, `run_id`, and `write_error` + `exit_code` when the write failed: the CLI still prints
    the result)."""
    note_outputs(outs, as_trace(trace))
    files, err, code = save_run(outs, items)
    result.update({"run_id": outs.run_id, "files": files, **({"write_error": err, "exit_code": code}
                                                              if err else {})})
    for n in outs.notes:
        result.setdefault("warnings", []).append(n)
    return result


def write_group(folder: str | os.PathLike, items: list[tuple[str, str, Any]], result: dict[str, Any],
                trace: Any = None) -> dict[str, Any]:
    """Lock `folder` and write `items` as one group (`finish_group`). For a long run, hold the folder from
    the start instead (`run_group`), so it is checked and locked before the work."""
    with RunOutputs(folder) as outs:
        return finish_group(outs, items, result, trace)


@contextmanager
def run_group(folder: str | os.PathLike | None, what: str = "--out") -> Iterator[RunOutputs | None]:
    """The run's RunOutputs for its whole duration (checked and locked before any work; lock and temp files
    released on every exit), or None when the command writes no folder."""
    if folder is None:
        yield None
        return
    with RunOutputs(folder, what=what) as outs:
        yield outs


def write_file_atomic(path: str | os.PathLike, data: bytes | str) -> Path:
    """One file written as temp + fsync + rename beside it (a kill leaves the old file or the new one, never
    a truncated one). For single result files a user names (`--result FILE`); folders use RunOutputs."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.parent / f"{TMP_PREFIX}{os.getpid()}.{path.name}"
    try:
        with open(tmp, "wb") as f:
            f.write(data.encode() if isinstance(data, str) else data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()
    return path
