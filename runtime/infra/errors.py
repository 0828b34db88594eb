"""One small exception hierarchy. Messages name the file/field and say what to do."""
from __future__ import annotations

import errno
import os
import signal
import stat
import threading


class MosaicError(Exception):
    """Base of every error the project raises on purpose.

    Messages are API-neutral: a parameter or config field is named in backticks (`answerer`, or `depth=model`
    for a value), and `fields` lists those names; the command line rewrites them as its flags (`--answerer`,
    `--depth model`) from one table, `commands/flags.FLAG_FOR_FIELD`."""

    def __init__(self, *args: object, fields: tuple[str, ...] = ()):
        super().__init__(*args)
        self.fields = tuple(fields)


class InputError(MosaicError):
    """Bad user input: unreadable video/image/folder, unknown object name, malformed question."""


class BundleError(MosaicError):
    """Missing, tampered or malformed model bundle (manifest, sha256, escaping paths, schema version)."""


class ProfileError(MosaicError):
    """A device profile (profiles/*.toml) with unknown keys, wrong units or impossible values."""


class BudgetError(MosaicError):
    """Nothing fits the latency/memory budget; the message says which budget fails and by how much."""


class ProviderError(MosaicError):
    """No execution provider could create or run a session."""


class AlignmentError(MosaicError):
    """Alignment could not proceed (e.g. fewer than two frames with depth)."""


class ExportError(MosaicError):
    """Export failed, including a failed parity check."""


class OutputError(MosaicError):
    """An output folder that cannot be written (a file, read-only, full, locked by another run)."""


def path_kind(path: "str | os.PathLike[str]") -> str:
    """What a path is, in words for an error message: "a file", "a folder", "missing", "a broken symlink (to
    X)", "a symlink loop", "a FIFO (named pipe)", "a socket", "a device", "unreadable (permission denied)",
    "below a file (a path part is not a folder)", "a name too long"."""
    try:
        st = os.stat(path)
    except FileNotFoundError:
        if os.path.islink(path):
            return f"a broken symlink (to {os.readlink(path)})"
        return "missing"
    except OSError as e:
        return {errno.ELOOP: "a symlink loop", errno.ENOTDIR: "below a file (a path part is not a folder)",
                errno.EACCES: "unreadable (permission denied on a folder above it)",
                errno.ENAMETOOLONG: "a name too long"}.get(e.errno, f"not usable ({e.strerror})")
    m = st.st_mode
    kind = ("a folder" if stat.S_ISDIR(m) else "a file" if stat.S_ISREG(m) else "a FIFO (named pipe)"
            if stat.S_ISFIFO(m) else "a socket" if stat.S_ISSOCK(m) else "a device"
            if stat.S_ISCHR(m) or stat.S_ISBLK(m) else "not a file or folder")
    if kind in ("a file", "a folder") and not os.access(path, os.R_OK | (os.X_OK if kind == "a folder" else 0)):
        return f"{kind}, unreadable (permission denied)"
    return kind


def check_path(path: "str | os.PathLike[str]", want: str, what: str, error: "type | None" = None) -> None:
    """Raise `error` (InputError) unless `path` is a readable `want` ("a file", "a folder" or "a file or
    folder"): `<path>: <what> is <kind>; give <want>`. A FIFO is refused before it is opened (reading one
    waits for a writer forever)."""
    kind = path_kind(path)
    if kind in {"a file": ("a file",), "a folder": ("a folder",)}.get(want, ("a file", "a folder")):
        return
    raise (error or InputError)(f"{path}: {what} is {kind}; give {want}")


def read_text(path: "str | os.PathLike[str]", what: str, error: "type | None" = None) -> str:
    """The text of an input file, decoded as UTF-8 before any work uses it: a missing / unreadable file or a byte
    that is not UTF-8 raises `error` (InputError) naming the file and where the bad byte is."""
    check_path(path, "a file", f"the {what} file", error)
    try:
        with open(path, "rb") as f:
            data = f.read()
    except OSError as e:
        raise (error or InputError)(f"{path}: cannot read the {what} file ({e.strerror or e})") from None
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as e:
        raise (error or InputError)(f"{path}: the {what} file is not UTF-8 text (byte 0x{data[e.start]:02x} at "
                                    f"offset {e.start}); save it as UTF-8") from None


class Interrupted(KeyboardInterrupt):
    """The run was stopped by SIGTERM/SIGHUP (temp files and locks are cleaned up on the way out). A
    KeyboardInterrupt, not a MosaicError, so no `except MosaicError` fallback can swallow it."""

    def __init__(self, signum: int):
        self.signum = signum
        super().__init__(f"interrupted by {signal.Signals(signum).name}; no output of this run was kept")


# Outcome classes (docs/reliability.md): exit 2 = bad input the user can fix, 1 = internal error (a bug),
# 130 + n would be a signal death, which `handle_signals` turns into a clean exit 128 + n instead.
_OS_USER_ERRORS = (FileNotFoundError, PermissionError, IsADirectoryError, NotADirectoryError, FileExistsError)


def exit_code_for(e: BaseException) -> int:
    """The exit code of the outcome class of `e`."""
    if isinstance(e, Interrupted):
        return 128 + e.signum
    if isinstance(e, KeyboardInterrupt):
        return 130
    if isinstance(e, MosaicError):
        return 2
    if isinstance(e, _OS_USER_ERRORS) or (isinstance(e, OSError) and e.errno in (28, 30, 36)):  # ENOSPC EROFS
        return 2                                                                                 # ENAMETOOLONG
    return 1


def message_for(e: BaseException) -> str:
    """One line for stderr: `error: ...` for bad input, `internal error: ...` (+ how to report) for a bug."""
    if isinstance(e, KeyboardInterrupt) and not isinstance(e, Interrupted):
        return "error: interrupted (Ctrl-C); no output of this run was kept"
    if exit_code_for(e) != 1:
        if isinstance(e, OSError) and not isinstance(e, MosaicError):
            where = e.filename if e.filename is not None else "a file"
            return f"error: {where}: {e.strerror or e}; check the path and its permissions"
        return f"error: {e}"
    first = (str(e).splitlines() or [""])[0][:300]
    return (f"internal error: {type(e).__name__}: {first} (a bug; rerun with --debug for the traceback and "
            f"report it)")


class handle_signals:
    """Context manager: SIGTERM/SIGHUP raise `Interrupted` in the main thread (so `finally` blocks release
    locks and remove temp files) instead of killing the process; restored on exit. SIGPIPE stays ignored by
    Python, so a closed stdout raises BrokenPipeError, handled by the CLI."""

    def __enter__(self) -> "handle_signals":
        self._old: dict[int, object] = {}
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGTERM, signal.SIGHUP):
                self._old[sig] = signal.signal(sig, self._raise)
        return self

    @staticmethod
    def _raise(signum: int, frame: object) -> None:
        raise Interrupted(signum)

    def __exit__(self, *exc: object) -> None:
        for sig, old in self._old.items():
            signal.signal(sig, old)
