"""One small exception hierarchy. Messages name the file/field and say what to do."""
from __future__ import annotations
import signal
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
