"""Every number the product reads (from a question or a file) is checked here, where it is read: finite and in its
range, with any length of digits (a distance written with 400 digits is out of range, never an OverflowError).

    read_number(text, what, lo=, hi=, scale=)    one number written as text (a question's "within 2.5 m")
    check_array(a, where, what, lo=, hi=)         every value of an array read from a file (poses, intrinsics ...)
    first_bad(a, lo, hi)                          the first non-finite / out-of-range value (the file schemas')

A failed check raises the caller's error class (InputError by default) with `<where>: <what> ...; <what to do>`.
"""
from __future__ import annotations

import math
from decimal import MAX_EMAX, MIN_EMIN, Context, Decimal, InvalidOperation, localcontext
from typing import Any

import numpy as np

from .errors import InputError


def show_number(text: Any, limit: int = 24) -> str:
    """A number as written, cut to `limit` characters with its digit count ("99999...999 (400 digits)")."""
    s = str(text).strip()
    if len(s) <= limit:
        return s
    return f"{s[:10]}...{s[-6:]} ({sum(c.isdigit() for c in s)} digits)"


def _limit(x: float) -> str:
    return f"{x:,.6g}" if abs(x) < 1e6 else f"{x:.3g}"


def read_number(text: Any, what: str, *, lo: float = -math.inf, hi: float = math.inf, scale: float = 1.0,
                integer: bool = False, unit: str = "", error: type = InputError, fix: str = "") -> Any:
    """`text` (a number written in words' place: "2.5", "1e3", 400 digits ...; or an int / float) times `scale`,
    checked finite and within lo..hi (in the scaled unit; `unit` names it in the message). Exact at any length
    (decimal arithmetic): never an OverflowError. Returns a float (an int with `integer`, which also refuses
    fractions). Raises `error` naming `what` and, when given, `fix`."""
    with localcontext(_WIDE):
        return _read(text, what, lo, hi, scale, integer, unit, error, fix)


_WIDE = Context(prec=60, Emax=MAX_EMAX, Emin=MIN_EMIN)  # "1e999999" and 400 digits compare exactly, never overflow


def _read(text: Any, what: str, lo: float, hi: float, scale: float, integer: bool, unit: str, error: type,
          fix: str) -> Any:
    try:
        d = Decimal(str(text).strip().replace("_", "")) if not isinstance(text, Decimal) else text
    except InvalidOperation:
        raise error(f"{what}: {show_number(text)!r} is not a number{'; ' + fix if fix else ''}") from None
    u = f" {unit}" if unit else ""
    span = (f"from {_limit(lo / scale)} to {_limit(hi / scale)}{u}" if math.isfinite(lo) and math.isfinite(hi) else
            f"at least {_limit(lo / scale)}{u}" if math.isfinite(lo) else f"at most {_limit(hi / scale)}{u}"
            if math.isfinite(hi) else "finite")
    if not d.is_finite():
        give = "" if span == "finite" else " " + span
        raise error(f"{what}: {show_number(text)} is not a finite number; give a finite number{give}"
                    f"{'; ' + fix if fix else ''}")
    v = d * Decimal(scale)  # Decimal(float) is exact: the bound is compared exactly too
    if (math.isfinite(lo) and v < Decimal(lo)) or (math.isfinite(hi) and v > Decimal(hi)):
        raise error(f"{what}: {show_number(text)} is out of range; it must be {span}{'; ' + fix if fix else ''}")
    if not math.isfinite(float(v)):  # no bound given and beyond any float (1e999999)
        raise error(f"{what}: {show_number(text)} is beyond any float; give a finite number{'; ' + fix if fix else ''}")
    if integer:
        if v != v.to_integral_value():
            raise error(f"{what}: {show_number(text)} is not a whole number{'; ' + fix if fix else ''}")
        return int(v)
    return float(v)


def first_bad(a: np.ndarray, lo: float | None = None, hi: float | None = None, lo_open: bool = False,
              hi_open: bool = False) -> tuple[int, str] | None:
    """(flat index, "non-finite" | "range") of the first value of `a` that is NaN / infinite or outside lo..hi
    (open ends exclusive), else None."""
    a = np.asarray(a, dtype=np.float64).ravel()
    bad = np.flatnonzero(~np.isfinite(a))
    if len(bad):
        return int(bad[0]), "non-finite"
    out = np.zeros(a.shape, bool)
    if lo is not None:
        out |= (a <= lo) if lo_open else (a < lo)
    if hi is not None:
        out |= (a >= hi) if hi_open else (a > hi)
    bad = np.flatnonzero(out)
    return (int(bad[0]), "range") if len(bad) else None


def check_array(a: Any, where: str, what: str, *, lo: float | None = None, hi: float | None = None,
                error: type = InputError, fix: str = "fix or replace the file") -> np.ndarray:
    """`a` as float64, refused (`error`: `<where>: <what> holds NaN or infinity at value i` / `... value x at i
    is outside lo..hi`) unless every value is finite and within lo..hi."""
    try:
        arr = np.asarray(a, dtype=np.float64)
    except OverflowError:  # an int beyond any float
        raise error(f"{where}: {what} holds a number beyond any float; {fix}") from None
    got = first_bad(arr, lo, hi)
    if got is not None:
        i, kind = got
        at = f" (value {i + 1} of {arr.size})" if arr.size > 1 else ""
        if kind == "non-finite":
            raise error(f"{where}: {what} holds NaN or infinity{at}; {fix}")
        lo_, hi_ = _limit(lo if lo is not None else -math.inf), _limit(hi if hi is not None else math.inf)
        raise error(f"{where}: {what} holds {arr.ravel()[i]:g}{at}, outside {lo_}..{hi_}; {fix}")
    return arr


def finite_rows(a: np.ndarray) -> np.ndarray:
    """[N] bool: rows of `a` [N, ...] whose values are all finite (ground truth listed per frame / object)."""
    a = np.asarray(a, dtype=np.float64)
    return np.isfinite(a.reshape(len(a), -1)).all(1) if len(a) else np.zeros(0, bool)


def field_max(cls: type, name: str) -> float:
    """The `maximum` a dataclass field's metadata declares (a program field's range, where a reader checks it)."""
    return cls.__dataclass_fields__[name].metadata["maximum"]  # type: ignore[attr-defined]
