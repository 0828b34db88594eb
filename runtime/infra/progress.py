"""Progress a person can see: a tqdm bar per long phase on stderr and one summary line per phase at the end.

Stage code stays pure. The CLI opens a `session()` around a command; the pipeline and the evaluations wrap their
loops in `phase(name, total, unit)`, which yields a `Bar` (`.update(n)`, `.to(position)`, `.note(**facts)`).
With no session open (library use, tests, benchmarks) every bar is a no-op, so nothing is printed and no
timing changes. Bars are drawn only when stderr is a terminal and `--json` is not given; the summary lines are
printed (stderr) whenever `--json` is not given, so logs keep them too.

    with phase("perception", total=len(chosen), unit="key frame") as bar:
        for i in chosen:
            ...
            bar.update()
        bar.note(instances=len(instances))
"""
from __future__ import annotations

import os
import sys
import time
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass, field
from typing import Any, Iterable, Iterator, TextIO

# facts printed in the summary, in this order (others follow in the order noted)
FACT_ORDER = ("frames", "candidates", "scored", "keyframes", "aligned", "unaligned", "instances")


@dataclass
class PhaseRecord:
    """What one phase did: seconds, how many units, and facts noted by the code that ran it."""

    name: str
    unit: str
    seconds: float = 0.0
    count: int = 0
    calls: int = 0
    facts: dict[str, Any] = field(default_factory=dict)

    def line(self, width: int = 12) -> str:
        facts = [k for k in FACT_ORDER if k in self.facts] + [k for k in self.facts if k not in FACT_ORDER]
        what = [f"{self.count} {self.unit}{'' if self.count == 1 else 's'}"] if self.count else []
        what += [f"{k.replace('_', ' ')} {self.facts[k]}" for k in facts]
        return f"  {self.name:<{width}} {self.seconds:6.1f} s   " + ", ".join(what)


def _columns(file: TextIO) -> int:
    try:
        return os.get_terminal_size(file.fileno()).columns
    except (AttributeError, OSError, ValueError):
        return 0


class Bar:
    """One phase's bar (a tqdm bar when drawing, else nothing) and its record."""

    def __init__(self, record: PhaseRecord, total: int | None, draw: bool, file: TextIO,
                 session: "Session | None" = None):
        self.record, self._tq, self._session, self._t0 = record, None, session, time.perf_counter()
        if draw:
            from tqdm import tqdm

            known = _columns(file) > 0  # tqdm draws nothing on a terminal of unknown size (0 x 0): assume one
            self._tq = tqdm(total=total, desc=record.name, unit=record.unit, file=file, leave=False,
                            dynamic_ncols=known, ncols=None if known else 100, nrows=None if known else 24,
                            mininterval=0.2)

    def update(self, n: int = 1) -> None:
        """Advance by n units."""
        self.record.count += n
        if self._tq is not None:
            self._tq.update(n)

    def to(self, position: int) -> None:
        """Move to an absolute position (e.g. the index of the frame being read), never backwards."""
        if position > self.record.count:
            self.update(position - self.record.count)

    def note(self, **facts: Any) -> None:
        """Facts for the summary line (frames, key frames, aligned, instances, ...); later notes win."""
        self.record.facts.update(facts)
        if self._tq is not None and facts:
            self._tq.set_postfix({k: v for k, v in facts.items()}, refresh=False)

    def done(self, **facts: Any) -> None:
        """End the phase (idempotent): note the facts, add its time to the summary, remove the bar."""
        self.note(**facts)
        if self._session is None:
            return
        self.record.seconds += time.perf_counter() - self._t0
        self._session.open.remove(self)
        self._session = None
        if self._tq is not None:
            self._tq.close()


class _NoBar(Bar):
    """The bar outside a session: does nothing."""

    def __init__(self) -> None:  # no record, no tqdm
        pass

    def update(self, n: int = 1) -> None:
        pass

    def to(self, position: int) -> None:
        pass

    def note(self, **facts: Any) -> None:
        pass

    def done(self, **facts: Any) -> None:
        pass


class Session:
    """Phases of one command. `draw`: tqdm bars; `summary`: print one line per phase when the session ends."""

    def __init__(self, draw: bool, summary: bool, file: TextIO | None = None):
        self.draw, self.summary, self.file = draw, summary, file or sys.stderr
        self.records: dict[str, PhaseRecord] = {}
        self.open: list[Bar] = []

    def lines(self) -> list[str]:
        width = max([12] + [len(n) for n in self.records])
        return [r.line(width) for r in self.records.values()]


_current: ContextVar[Session | None] = ContextVar("mosaic_progress", default=None)


def stderr_is_terminal() -> bool:
    try:
        return sys.stderr.isatty()
    except (AttributeError, ValueError):  # replaced or closed stderr
        return False


@contextmanager
def session(*, quiet: bool = False, draw: bool | None = None, file: TextIO | None = None) -> Iterator[Session]:
    """Open a progress session (the CLI, around one command). quiet (--json): no bars, no summary; draw=None:
    bars when stderr is a terminal."""
    s = Session(not quiet and (stderr_is_terminal() if draw is None else draw), not quiet, file)
    token = _current.set(s)
    try:
        yield s
    finally:
        _current.reset(token)
        for bar in list(s.open):  # phases an error left open
            bar.done()
    if s.summary and s.records:  # only after a command that finished: an error message stays the first line
        print("\n".join(s.lines()), file=s.file, flush=True)


def start(name: str, total: int | None = None, unit: str = "step") -> Bar:
    """Begin a long phase; end it with `bar.done(**facts)`. Its time and counts are summed into one summary
    line (a phase run twice, e.g. alignment before and after bridging, is one line). A phase inside a phase (an
    eval running the pipeline) is recorded but draws no bar of its own. Outside a session: a no-op bar."""
    s = _current.get()
    if s is None:
        return _NoBar()
    rec = s.records.setdefault(name, PhaseRecord(name, unit))
    rec.calls += 1
    bar = Bar(rec, total, s.draw and not s.open, s.file, s)
    s.open.append(bar)
    return bar


@contextmanager
def phase(name: str, total: int | None = None, unit: str = "step") -> Iterator[Bar]:
    """`start` ... `done` around a block."""
    bar = start(name, total, unit)
    try:
        yield bar
    finally:
        bar.done()


def ticking(seq: Any, bar: Bar) -> Any:
    """`seq` seen through `bar` (see `Ticking`); `seq` itself outside a session."""
    return seq if isinstance(bar, _NoBar) else Ticking(seq, bar)


def ticked(items: Iterable[Any], name: str, unit: str = "step") -> Iterator[Any]:
    """Iterate `items` under a phase: one tick per item (an evaluation's scenes or questions)."""
    items = list(items)
    with phase(name, len(items), unit) as bar:
        for x in items:
            yield x
            bar.update()


class Ticking:
    """A sequence seen through a bar: reading item p moves the bar to p + 1 (a frame source read in order by
    redundant-frame removal shows how far decoding got). Everything else is the wrapped object's."""

    def __init__(self, seq: Any, bar: Bar):
        self._seq, self._bar = seq, bar

    def __len__(self) -> int:
        return len(self._seq)

    def __getitem__(self, p: Any) -> Any:
        item = self._seq[p]
        if isinstance(p, int):
            self._bar.to(p + 1)
        return item

    def __getattr__(self, name: str) -> Any:
        return getattr(self._seq, name)


def write(msg: str) -> None:
    """A log line on stderr that does not break a bar being drawn (printed above it)."""
    s = _current.get()
    drawn = [b._tq for b in (s.open if s else []) if b._tq is not None]
    if drawn:
        drawn[0].write(msg, file=s.file)
    else:
        sys.stderr.write(msg + "\n")
        sys.stderr.flush()


def first_line(words: tuple[str, ...], help_: str, argv: list[str]) -> None:
    """The command's first line, on stderr at once (before its heavy imports), when a person is watching."""
    if "--json" in argv or "-h" in argv or "--help" in argv or not stderr_is_terminal():
        return
    print(f"mosaic {' '.join(words)}: {help_} ...", file=sys.stderr, flush=True)
