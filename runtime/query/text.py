"""Question text: limits, control characters, and multiple-choice options (pure text, linear time)."""
from __future__ import annotations

import re
from typing import Any

from ..infra.errors import InputError

_OPT_RE = re.compile(r"^\s*([A-Z])\s*[.)::]\s*(.*?)\s*$")


MAX_QUESTION_CHARS = 2000  # longer questions are refused (InputError): no real question is that long
MAX_OPTIONS = 26
_ANSI = re.compile(r"\x1b\[[0-?]*[ -/]*[@-~]|\x1b\][^\x07\x1b]{0,200}(?:\x07|\x1b\\)?|\x1b.?")


def safe_text(s: Any, limit: int | None = None) -> str:
    """`s` with ANSI escapes removed and other control characters shown as `\\xNN` (never echoed raw);
    newlines and tabs become spaces. `limit`: cut to this many characters (with "...")."""
    t = _ANSI.sub("", str(s))
    t = "".join(c if c.isprintable() else (" " if c in "\n\r\t" else f"\\x{ord(c):02x}" if ord(c) < 256
                                            else f"\\u{ord(c):04x}") for c in t)
    return t if limit is None or len(t) <= limit else t[:limit] + "..."


def check_question(question: Any, options: list[str] | None = None) -> None:
    """Refuse questions over `MAX_QUESTION_CHARS` and option lists that are too long (InputError)."""
    n = len(str(question))
    if n > MAX_QUESTION_CHARS:
        raise InputError(f"question: {n} characters, over the {MAX_QUESTION_CHARS}-character limit; ask a shorter "
                         f"question (one object relation at a time)")
    if options is not None and (len(options) > MAX_OPTIONS or sum(len(str(o)) for o in options) > MAX_QUESTION_CHARS):
        raise InputError(f"options: {len(options)} options / {sum(len(str(o)) for o in options)} characters, over "
                         f"the limit ({MAX_OPTIONS} options, {MAX_QUESTION_CHARS} characters)")


_INLINE_OPT = re.compile(r"(?<![A-Za-z])([A-Z])[.)]\s")


def split_inline_options(question: str) -> tuple[str, list[str] | None]:
    """'... ? A. left B. right C. back' -> (question, ['A. left', 'B. right', 'C. back']) when present.

    One pass over the letter marks (linear in the question's length): the first run A, B, C ... in order."""
    marks = [(m.start(), m.group(1)) for m in _INLINE_OPT.finditer(question)]
    for i, (pos, letter) in enumerate(marks):
        if letter != "A":
            continue
        run = [pos]
        for pos2, l2 in marks[i + 1:]:
            if l2 == chr(ord("A") + len(run)):
                run.append(pos2)
        if len(run) < 2:
            continue
        head = re.sub(r"\s*\boptions?\s*:\s*$", "", question[:pos], flags=re.I).rstrip()
        parts = [question[a:b].strip() for a, b in zip(run, run[1:] + [len(question)])]
        return head, parts
    return question, None


def split_options(options: list[str] | None) -> list[tuple[str, str]]:
    """["A. left", "B. right"] -> [("A", "left"), ("B", "right")]; unlettered options get A, B, ... in order."""
    out: list[tuple[str, str]] = []
    for i, o in enumerate(options or []):
        m = _OPT_RE.match(str(o))
        out.append((m.group(1), m.group(2)) if m else (chr(ord("A") + i), str(o).strip()))
    return out


def clean_question(question: Any) -> str:
    """The question as the parsers read it: ANSI escapes removed, control characters as spaces (shown as \\xNN
    they would read as words: "chairs\\x07" -> "x07s"), runs of white space as one space."""
    return " ".join("".join(c if c.isprintable() else " " for c in _ANSI.sub("", str(question))).split())
