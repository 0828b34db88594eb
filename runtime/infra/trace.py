"""What happened during a run: stage times, memory, providers, fallbacks and decisions.

A `Trace` is passed explicitly through the pipeline (no globals). It serialises to the versioned
`trace.json` schema. Fallbacks and degradations are *events*: anything that changes an answer's basis
(a provider fallback, a reduced plan, a random-weight model, an unknown object name) is recorded here.
"""
from __future__ import annotations

import os
import platform
import sys
import time
import warnings
from contextlib import contextmanager, nullcontext
from dataclasses import dataclass, field
from typing import Any, Iterator

import psutil

from . import jsonio
from .jsonio import json_default  # its home was here; importers still find it

TRACE_SCHEMA = "mosaicthinker.trace/1"


def rss_mb() -> float:
    """Resident set size of this process in MiB."""
    return psutil.Process(os.getpid()).memory_info().rss / 2**20


def peak_rss_mb() -> float:
    """Peak RSS of this process in MiB since the last `reset_peak_rss()` (Linux VmHWM), else since start."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    try:
        import resource

        r = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        return r / 1024.0 if sys.platform != "darwin" else r / 2**20
    except Exception:  # pragma: no cover - Windows
        return rss_mb()


def reset_peak_rss() -> bool:
    """Reset the kernel's peak-RSS mark (Linux: write 5 to /proc/self/clear_refs). False where unsupported."""
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False


@dataclass
class StageRecord:
    name: str
    seconds: float = 0.0
    calls: int = 0
    # CPU seconds of the whole process (every thread) while the stage ran: on a shared machine the wall time
    # carries other jobs' load, this much less
    cpu_seconds: float = 0.0
    rss_before_mb: float = 0.0
    rss_peak_mb: float = 0.0
    provider: str | None = None

    def to_dict(self) -> dict[str, Any]:
        return {
            "seconds": round(self.seconds, 6),
            "calls": self.calls,
            "cpu_seconds": round(self.cpu_seconds, 6),
            "rss_before_mb": round(self.rss_before_mb, 1),
            "rss_peak_mb": round(self.rss_peak_mb, 1),
            "provider": self.provider,
        }


@dataclass
class Trace:
    """Accumulates stage records, events (fallbacks, warnings, re-plans) and named decisions."""

    stages: dict[str, StageRecord] = field(default_factory=dict)
    events: list[dict[str, Any]] = field(default_factory=list)
    decisions: dict[str, Any] = field(default_factory=dict)
    providers: dict[str, dict[str, Any]] = field(default_factory=dict)
    random_weights_used: list[str] = field(default_factory=list)
    started: float = field(default_factory=time.time)
    started_cpu: float = field(default_factory=time.process_time)

    @contextmanager
    def stage(self, name: str) -> Iterator[StageRecord]:
        """Time a stage and sample RSS before/after (peak is the max seen over all calls)."""
        rec = self.stages.setdefault(name, StageRecord(name))
        before = rss_mb()
        if rec.calls == 0:
            rec.rss_before_mb = before
        t0, c0 = time.perf_counter(), time.process_time()
        try:
            yield rec
        finally:
            rec.seconds += time.perf_counter() - t0
            rec.cpu_seconds += time.process_time() - c0
            rec.calls += 1
            rec.rss_peak_mb = max(rec.rss_peak_mb, before, rss_mb())

    def add_time(self, name: str, seconds: float, calls: int = 1) -> StageRecord:
        """Book `seconds` over `calls` to stage `name` without timing a block (counters kept elsewhere: frame
        decoding, feature extraction, an adapter's own overhead); no RSS sampling (cheap per call)."""
        rec = self.stages.setdefault(name, StageRecord(name))
        rec.seconds += float(seconds)
        rec.calls += int(calls)
        return rec

    def event(self, kind: str, message: str, *, warn: bool = False, **data: Any) -> None:
        """Record something the user must be able to see afterwards (fallback, degradation, warning)."""
        self.events.append({"kind": kind, "message": message, "t": round(time.time() - self.started, 4), **data})
        if warn:
            warnings.warn(f"[{kind}] {message}", RuntimeWarning, stacklevel=2)

    def fallbacks(self) -> list[dict[str, Any]]:
        return [e for e in self.events if e["kind"] == "fallback"]

    def decide(self, key: str, value: Any) -> None:
        self.decisions[key] = value

    def note_random_weights(self, what: str) -> None:
        if what not in self.random_weights_used:
            self.random_weights_used.append(what)
            self.event("random_weights", f"{what} has RANDOM weights (test model): its outputs are meaningless",
                       warn=True, component=what)

    def record(self, log: "Trace") -> None:
        """Append a stage's log to this trace: its events in order (times re-based on this trace's start), its
        decisions, sub-stage times and calls, providers and random-weight notes."""
        shift = log.started - self.started
        self.events += [{**e, "t": round(e.get("t", 0.0) + shift, 4)} for e in log.events]
        self.decisions.update(log.decisions)
        for name, r in log.stages.items():
            rec = self.stages.setdefault(name, StageRecord(name))
            if rec.calls == 0:
                rec.rss_before_mb = r.rss_before_mb
            rec.seconds += r.seconds
            rec.cpu_seconds += r.cpu_seconds
            rec.calls += r.calls
            rec.rss_peak_mb = max(rec.rss_peak_mb, r.rss_peak_mb)
            rec.provider = rec.provider or r.provider
        self.providers.update(log.providers)
        self.random_weights_used += [w for w in log.random_weights_used if w not in self.random_weights_used]

    def wall_seconds(self) -> float:
        """Seconds since the trace started."""
        return round(time.time() - self.started, 4)

    def to_dict(self) -> dict[str, Any]:
        return {
            "schema": TRACE_SCHEMA,
            "wall_seconds": self.wall_seconds(),
            "cpu_seconds": round(time.process_time() - self.started_cpu, 4),
            "peak_rss_mb": round(max([r.rss_peak_mb for r in self.stages.values()] + [rss_mb()]), 1),
            "stages": {k: v.to_dict() for k, v in self.stages.items()},
            "providers": self.providers,
            "events": self.events,
            "decisions": to_plain(self.decisions),
            "random_weights_used": self.random_weights_used,
            # which CPU/OS the run was on (jetson/arm64_check.sh reads `machine` to prove an aarch64 run)
            "host": {"machine": platform.machine(), "system": platform.system(),
                     "python": platform.python_version()},
        }

    def save(self, path: str | os.PathLike) -> None:
        """Write trace.json atomically (temp file + rename: a kill leaves the old file or the new, never half)."""
        tmp = f"{os.fspath(path)}.tmp-{os.getpid()}"
        try:
            with open(tmp, "w") as f:
                jsonio.dump(self.to_dict(), f, indent=2)
                f.flush()
                os.fsync(f.fileno())
            os.replace(tmp, path)
        finally:
            if os.path.exists(tmp):
                os.unlink(tmp)


class StageLog(Trace):
    """What one stage reports besides its result: events, decisions and the time of its sub-steps, in order. A stage
    records into its own log (the one it is given, or a new one it returns); only the pipeline writes the run's
    Trace (`Trace.record`)."""


def _jsonable(x: Any) -> Any:
    """Convert numpy scalars/arrays and dataclass-ish values into JSON-friendly objects."""
    import numpy as np  # noqa: PLC0415 - the CLI's first line comes before numpy loads

    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, (np.ndarray, np.generic)) or hasattr(x, "to_dict"):
        return json_default(x)  # the one numpy / to_dict conversion; other values stay as they are
    return x


jsonable = _jsonable


def to_plain(obj: Any) -> Any:
    """`obj` as plain JSON values (dicts with string keys, lists, numbers, strings): one encode and one decode in
    C, linear in the size (the per-value walk of `jsonable` took seconds on a 100 k-object answer's evidence)."""
    try:
        return jsonio.plain(obj)
    except TypeError:  # a key JSON cannot hold (a tuple): the per-value walk names keys as text
        return jsonio.plain(jsonable(obj))


class NullTrace(Trace):
    """The trace of a caller that keeps none: records nothing, but a warning event still reaches the user (a
    degraded answer is never silent). Lets stage code call trace methods without `if trace is not None`."""

    def stage(self, name: str) -> Any:
        return nullcontext(StageRecord(name))

    def event(self, kind: str, message: str, *, warn: bool = False, **data: Any) -> None:
        if warn:
            warnings.warn(f"[{kind}] {message}", RuntimeWarning, stacklevel=2)

    def decide(self, key: str, value: Any) -> None:
        return None

    def add_time(self, name: str, seconds: float, calls: int = 1) -> StageRecord:
        return StageRecord(name)


def as_trace(trace: Trace | None) -> Trace:
    """`trace`, or a NullTrace when the caller passed none."""
    return trace if trace is not None else NullTrace()

