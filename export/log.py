"""Progress lines and shortened library messages of the export tools (no dependencies: every export module
imports it)."""
from __future__ import annotations

import time


def brief(text: str, limit: int = 300) -> str:
    """A long library message shortened at a space (never mid-word), marked with ' ...'."""
    text = " ".join(str(text).split())
    if len(text) <= limit:
        return text
    cut = text.rfind(" ", 0, limit)
    return text[:cut if cut > limit // 2 else limit] + " ..."


def progress(msg: str) -> None:
    """One progress line on stderr (long steps: export, quantisation, calibration, parity)."""
    from mosaicthinker.runtime.infra.progress import write

    write(f"[export {time.strftime('%H:%M:%S')}] {msg}")
