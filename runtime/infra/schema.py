"""One small declarative checker for the files the product reads: field specs (type, range, enum, custom rule)
as data, errors that name the field path (`instances[3].box.axesLengths`, `roles.depth.config.output`).

    SPEC = Obj({"id": F(Int(lo=0)), "name": F(Str(nonempty=True)),
                "box": F(Obj({"centroid": F(Arr((3,)))})),
                "score": F(Num(lo=0, hi=1), required=False)})
    check(doc, SPEC, where="map.json", error=InputError, fix="rebuild the map")   # raises error(...) or returns

A list of objects is checked column by column: one pass per field over all items (numeric fields with numpy),
so a 100 000-object map checks in well under a second. A column rule sees every value of one field at once and
returns the first bad index with what is wrong (`rules=`); it runs after the types are known to be right.

Numbers are JSON numbers only: a bool, a string that looks like a number or a null is refused by type (numpy
would silently read "1.5" or true as numbers).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from itertools import chain, repeat
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from .errors import MosaicError
from .numbers import first_bad

MISSING: Any = type("Missing", (), {"__repr__": lambda self: "<missing>"})()
Path = Callable[[int], str]  # index in the column -> the field path of that value
Rule = Callable[[list], "tuple[int, str] | None"]  # column -> (first bad index, what is wrong) or None
_NUM = (int, float)


class SchemaError(ValueError):
    """A field that breaks its spec: `path` (e.g. `roles.depth.arch`) and `what` (`must be ..., got ...`)."""

    def __init__(self, path: str, what: str):
        super().__init__(f"{path} {what}")
        self.path, self.what = path, what


def show(v: Any) -> str:
    """A value in an error message: its JSON type and a short repr."""
    if v is None:
        return "null"
    kind = {bool: "a boolean", str: "a string", list: "a list", dict: "an object", int: "the number",
            float: "the number"}.get(type(v), type(v).__name__)
    r = repr(v)
    return f"{kind} {r[:60] + '...' if len(r) > 60 else r}"


def _fail(at: Path, i: int, what: str) -> SchemaError:
    return SchemaError(at(i), what)


def _sub(at: Path, idx: Sequence[int]) -> Path:
    return lambda j: at(idx[j])


@dataclass(frozen=True, kw_only=True)
class Spec:
    """Base: `nullable` accepts JSON null; `rules` are column rules (meaning checks); `want` overrides the
    "must be ..." text."""

    nullable: bool = False
    rules: tuple[Rule, ...] = ()
    want: str = ""

    def describe(self) -> str:
        return self.want or self._describe()

    def _describe(self) -> str:
        return "a value"

    def check_column(self, vals: list, at: Path) -> None:
        """Check every value of one field (`vals`); raise SchemaError for the first bad one."""
        if self.nullable:
            idx = [i for i, v in enumerate(vals) if v is not None]
            if len(idx) < len(vals):
                vals, at = [vals[i] for i in idx], _sub(at, idx)
        if not vals:
            return
        self._types(vals, at)
        self._check(vals, at)
        for rule in self.rules:
            bad = rule(vals)
            if bad is not None:
                raise _fail(at, bad[0], bad[1])

    def _allowed(self) -> tuple[type, ...] | None:
        return None

    def _types(self, vals: list, at: Path) -> None:
        ok = self._allowed()
        if ok is None:
            return
        types = set(map(type, vals))
        if not types <= set(ok):
            i = next(i for i, v in enumerate(vals) if type(v) not in ok)
            raise _fail(at, i, f"must be {self.describe()}, got {show(vals[i])}")

    def _check(self, vals: list, at: Path) -> None:
        return None


@dataclass(frozen=True, kw_only=True)
class AnyValue(Spec):
    """Anything (free-form notes, provenance details)."""

    def check_column(self, vals: list, at: Path) -> None:
        return None


def _range_text(lo: float | None, hi: float | None, lo_open: bool, hi_open: bool) -> str:
    if lo is not None and hi is not None and not lo_open and not hi_open:
        return f" in {lo:g}..{hi:g}"
    parts = []
    if lo is not None:
        parts.append(f"{'>' if lo_open else '>='} {lo:g}")
    if hi is not None:
        parts.append(f"{'<' if hi_open else '<='} {hi:g}")
    return (" " + " and ".join(parts)) if parts else ""


@dataclass(frozen=True, kw_only=True)
class Num(Spec):
    """A finite JSON number (int or float; `integer` wants an int) within lo..hi."""

    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    hi_open: bool = False
    integer: bool = False

    def _allowed(self) -> tuple[type, ...]:
        return (int,) if self.integer else _NUM

    def _describe(self) -> str:
        return ("an integer" if self.integer else "a number") + _range_text(self.lo, self.hi, self.lo_open,
                                                                            self.hi_open)

    def _check(self, vals: list, at: Path) -> None:
        try:
            a = np.asarray(vals, dtype=np.float64)
        except OverflowError:  # an int beyond float range
            i = next(i for i, v in enumerate(vals) if isinstance(v, int) and abs(v) > 1e308)
            raise _fail(at, i, f"must be {self.describe()}, got a number with {len(str(vals[i]))} digits") from None
        got = first_bad(a, self.lo, self.hi, self.lo_open, self.hi_open)  # the one check of every number read
        if got is not None:
            i, kind = got
            raise _fail(at, i, f"holds NaN or infinity; must be {self.describe()}" if kind == "non-finite"
                        else f"must be {self.describe()}, got {show(vals[i])}")


def Int(**kw: Any) -> Num:  # noqa: N802 - reads like a type in a spec
    return Num(integer=True, **kw)


@dataclass(frozen=True, kw_only=True)
class Str(Spec):
    """A string; `enum` lists the allowed values (`fold` compares them case-insensitively); `nonempty` refuses
    blank strings."""

    enum: tuple[str, ...] | None = None
    nonempty: bool = False
    fold: bool = False
    max_len: int = 100_000

    def _allowed(self) -> tuple[type, ...]:
        return (str,)

    def _describe(self) -> str:
        if self.enum is not None:
            return "one of " + ", ".join(repr(e) for e in self.enum)
        return "a non-empty string" if self.nonempty else "a string"

    def _check(self, vals: list, at: Path) -> None:
        if self.enum is not None:
            allowed = {e.lower() for e in self.enum} if self.fold else set(self.enum)
            got = {v.lower() for v in vals} if self.fold else set(vals)
            if not got <= allowed:
                i = next(i for i, v in enumerate(vals) if (v.lower() if self.fold else v) not in allowed)
                raise _fail(at, i, f"must be {self.describe()}, got {show(vals[i])}")
        if self.nonempty:
            for i, v in enumerate(vals):
                if not v.strip():
                    raise _fail(at, i, "is empty; it must be a non-empty string")
        if max(map(len, vals)) > self.max_len:
            i = next(i for i, v in enumerate(vals) if len(v) > self.max_len)
            raise _fail(at, i, f"is {len(vals[i])} characters long; at most {self.max_len}")


@dataclass(frozen=True, kw_only=True)
class Bool(Spec):
    """A JSON boolean (true / false; never 1, 0 or "no")."""

    def _allowed(self) -> tuple[type, ...]:
        return (bool,)

    def _describe(self) -> str:
        return "true or false (JSON boolean)"


@dataclass(frozen=True, kw_only=True)
class Arr(Spec):
    """A numeric array written as nested JSON lists, of `shape` (-1: any length, at least `min_rows` for the first
    axis), every element a finite number within lo..hi."""

    shape: tuple[int, ...] = (-1,)
    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    hi_open: bool = False
    integer: bool = False
    min_rows: int = 0
    array_rules: tuple[Callable[[np.ndarray], "tuple[int, str] | None"], ...] = ()  # over [n, *shape] floats

    def _allowed(self) -> tuple[type, ...]:
        return (list,)

    def _describe(self) -> str:
        dims = " x ".join("N" if s < 0 else str(s) for s in self.shape)
        kind = "integers" if self.integer else "numbers"
        nest = "" if len(self.shape) == 1 else " (nested lists)"
        return f"{dims} {kind}{nest}{_range_text(self.lo, self.hi, self.lo_open, self.hi_open)}"

    def _check(self, vals: list, at: Path) -> None:
        level: list = vals
        for depth, n in enumerate(self.shape):  # lists all the way down, with the fixed lengths
            if depth and not set(map(type, level)) <= {list}:
                self._first_bad(vals, at)
            if n >= 0 and level and set(map(len, level)) != {n}:
                self._first_bad(vals, at)
            level = list(chain.from_iterable(level))
        if not set(map(type, level)) <= set((int,) if self.integer else _NUM):
            self._first_bad(vals, at)
        try:
            flat = np.array(level, dtype=np.float64)
        except OverflowError:  # an int beyond float range
            self._first_bad(vals, at)
            raise
        per = int(np.prod([n for n in self.shape if n >= 0], dtype=np.int64))
        counts = np.fromiter(map(len, vals), np.int64, len(vals)) * (per if self.shape[0] < 0 else 1)
        if self.shape[0] >= 0:
            counts[:] = per
        owner = np.repeat(np.arange(len(vals)), counts)
        if self.min_rows:
            short = np.flatnonzero(np.fromiter(map(len, vals), np.int64, len(vals)) < self.min_rows)
            if len(short):
                i = int(short[0])
                raise _fail(at, i, f"has {len(vals[i])} rows; at least {self.min_rows} are needed")
        got = first_bad(flat, self.lo, self.hi, self.lo_open, self.hi_open)
        if got is not None:
            i = int(owner[got[0]])
            raise _fail(at, i, "holds NaN or infinity" if got[1] == "non-finite"
                        else f"is {show(vals[i])}; must be {self.describe()}")
        if self.array_rules and self.shape[0] >= 0:
            arr = flat.reshape(len(vals), *self.shape)
            for rule in self.array_rules:
                got = rule(arr)
                if got is not None:
                    raise _fail(at, got[0], got[1])

    def _first_bad(self, vals: list, at: Path) -> None:
        """The first value that is not an array of this shape: a per-item pass (only on the error path)."""
        for i, v in enumerate(vals):
            why = self._item_problem(v)
            if why:
                raise _fail(at, i, why)
        raise _fail(at, 0, f"must be {self.describe()}")

    def _item_problem(self, v: Any) -> str | None:
        def walk(x: Any, depth: int) -> str | None:
            if depth == len(self.shape):
                ok = (int,) if self.integer else _NUM
                return None if type(x) in ok else f"must be {self.describe()}, holds {show(x)}"
            if type(x) is not list:
                return f"must be {self.describe()}, got {show(x)}" if depth == 0 else \
                    f"must be {self.describe()}, holds {show(x)} where a list belongs"
            n = self.shape[depth]
            if n >= 0 and len(x) != n:
                return f"must be {self.describe()}, got {len(x)} where {n} belong"
            lens = {len(y) for y in x if type(y) is list}
            if depth + 1 < len(self.shape) and len(lens) > 1:
                return f"must be {self.describe()}; its rows have different lengths"
            for y in x:
                w = walk(y, depth + 1)
                if w:
                    return w
            return None

        why = walk(v, 0)
        if why is None:
            try:
                np.asarray(v, dtype=np.float64)
            except OverflowError:
                return f"must be {self.describe()}; holds a number beyond any float"
        return why

@dataclass(frozen=True)
class F:
    """A field of an object: its spec and whether it must be present."""

    spec: Spec
    required: bool = True


@dataclass(frozen=True, kw_only=True)
class Obj(Spec):
    """A JSON object with `fields`; unknown keys pass unless `extra=False` (then `unknown(key, known)` may give
    a better message than "unknown key", e.g. a unit spelt wrong). `item_rule` is a rule over the whole object,
    run per object (for lists of a few objects: cross-field meaning)."""

    fields: Mapping[str, F] = field(default_factory=dict)
    extra: bool = True
    unknown: Callable[[str, tuple[str, ...]], str] | None = None
    item_rules: tuple[Callable[[dict], str | None], ...] = ()

    def _allowed(self) -> tuple[type, ...]:
        return (dict,)

    def _describe(self) -> str:
        return "an object"

    def _check(self, vals: list, at: Path) -> None:
        if not self.extra:
            known = tuple(self.fields)
            for i, v in enumerate(vals):
                for k in v:
                    if k not in self.fields:
                        msg = self.unknown(k, known) if self.unknown else None
                        raise _fail(at, i, msg or f"has an unknown key {k!r}; known keys: {', '.join(known)}")
        for k, f in self.fields.items():
            col = list(map(dict.get, vals, repeat(k), repeat(MISSING)))  # in C: a column of 100 k objects
            sub = (lambda kk: (lambda j: f"{at(j)}.{kk}" if at(j) else str(kk)))(k)
            missing = [i for i, c in enumerate(col) if c is MISSING] if MISSING in col else []
            if missing:
                if f.required:
                    raise _fail(sub, missing[0], "is missing")
                keep = [i for i, c in enumerate(col) if c is not MISSING]
                col, sub = [col[i] for i in keep], _sub(sub, keep)
            f.spec.check_column(col, sub)
        for rule in self.item_rules:
            for i, v in enumerate(vals):
                why = rule(v)
                if why:
                    raise _fail(at, i, why)


@dataclass(frozen=True, kw_only=True)
class ListOf(Spec):
    """A JSON list whose items all follow `item`; min_len..max_len items."""

    item: Spec = field(default_factory=AnyValue)
    min_len: int = 0
    max_len: int | None = None
    list_rules: tuple[Callable[[list], "tuple[str, str] | None"], ...] = ()  # -> (sub-path, what)

    def _allowed(self) -> tuple[type, ...]:
        return (list,)

    def _describe(self) -> str:
        return f"a list of {self.item.describe()}" if not isinstance(self.item, Obj) else "a list of objects"

    def _check(self, vals: list, at: Path) -> None:
        lens = np.fromiter(map(len, vals), np.int64, len(vals))
        bad = np.flatnonzero(lens < self.min_len)
        if len(bad):
            n = int(lens[bad[0]])
            raise _fail(at, int(bad[0]), "is empty; it needs at least one item" if n == 0 else
                        f"has {n} items; at least {self.min_len} are needed")
        if self.max_len is not None and (lens > self.max_len).any():
            i = int(np.flatnonzero(lens > self.max_len)[0])
            raise _fail(at, i, f"has {int(lens[i])} items; at most {self.max_len} are supported")
        flat = list(chain.from_iterable(vals))
        if flat:
            owner = np.repeat(np.arange(len(vals)), lens)
            start = np.concatenate([[0], np.cumsum(lens)[:-1]])
            self.item.check_column(flat, lambda j: f"{at(int(owner[j]))}[{j - int(start[owner[j]])}]")
        for rule in self.list_rules:
            for i, v in enumerate(vals):
                bad = rule(v)
                if bad is not None:
                    raise SchemaError(f"{at(i)}{bad[0]}", bad[1])


@dataclass(frozen=True, kw_only=True)
class MapOf(Spec):
    """A JSON object used as a mapping: any keys (or those `keys` allows), every value following `value`."""

    value: Spec = field(default_factory=AnyValue)
    keys: Str | None = None
    min_len: int = 0

    def _allowed(self) -> tuple[type, ...]:
        return (dict,)

    def _describe(self) -> str:
        return "an object"

    def _check(self, vals: list, at: Path) -> None:
        for i, v in enumerate(vals):
            if len(v) < self.min_len:
                raise _fail(at, i, "is empty; it needs at least one entry")
            if self.keys is not None:
                for k in v:
                    self.keys.check_column([k], lambda j, i=i, k=k: f"{at(i)}.{k} (the key)")
        paths = [(i, k) for i, v in enumerate(vals) for k in v]
        flat = [vals[i][k] for i, k in paths]
        if flat:
            self.value.check_column(flat, lambda j: f"{at(paths[j][0])}.{paths[j][1]}" if at(paths[j][0])
                                    else str(paths[j][1]))


@dataclass(frozen=True, kw_only=True)
class OneOf(Spec):
    """A value that follows one of `options` (checked per value: for small config fields only)."""

    options: tuple[Spec, ...] = ()

    def _describe(self) -> str:
        return " or ".join(o.describe() for o in self.options)

    def _check(self, vals: list, at: Path) -> None:
        for i, v in enumerate(vals):
            if not any(_ok(o, v) for o in self.options):
                raise _fail(at, i, f"must be {self.describe()}, got {show(v)}")


def _ok(spec: Spec, v: Any) -> bool:
    try:
        spec.check_column([v], lambda j: "")
        return True
    except SchemaError:
        return False


# ---------------------------------------------------------------------------------------------- entry points

def violation(doc: Any, spec: Spec, root: str = "") -> SchemaError | None:
    """The first SchemaError of `doc` against `spec` (None when it conforms). `root` prefixes every path."""
    try:
        spec.check_column([doc], lambda j: root)
    except SchemaError as e:
        if not e.path:  # the document itself
            return SchemaError("the top level", e.what)
        return e
    except RecursionError:
        return SchemaError(root or "the top level", "is nested too deeply to check")
    return None


def check(doc: Any, spec: Spec, *, where: str, error: type[MosaicError], fix: str, root: str = "") -> None:
    """Raise `error("<where>: <path> <what>; <fix>")` for the first field of `doc` that breaks `spec`."""
    e = violation(doc, spec, root)
    if e is not None:
        raise error(f"{where}: {e.path} {e.what}; {fix}")


# ---------------------------------------------------------------------------------------------- common rules

def unique(key: str) -> Callable[[list], "tuple[str, str] | None"]:
    """A list rule: the `key` of the list's objects is unique."""
    def rule(items: list) -> tuple[str, str] | None:
        keys = [it.get(key) if isinstance(it, dict) else None for it in items]
        if len(set(keys)) == len(keys):
            return None
        seen: dict[Any, int] = {}
        for i, k in enumerate(keys):
            if k in seen:
                return f"[{i}].{key}", f"is {k!r}, which duplicates [{seen[k]}].{key}; it must be unique"
            seen[k] = i
        return None
    return rule


def orthonormal_rows(tol: float = 1e-2) -> Callable[[np.ndarray], "tuple[int, str] | None"]:
    """An array rule for `[9]` (row-major 3x3) or `[3, 3]` rotation-like arrays: unit rows, perpendicular."""
    def rule(a: np.ndarray) -> tuple[int, str] | None:
        ax = a.reshape(len(a), 3, 3)
        err = np.abs(ax @ ax.transpose(0, 2, 1) - np.eye(3)).max(axis=(1, 2))
        bad = np.flatnonzero(err > tol)
        return (int(bad[0]), "must be three orthonormal rows (unit length, perpendicular)") if len(bad) else None
    return rule


def finite(x: Any) -> bool:
    return isinstance(x, _NUM) and not isinstance(x, bool) and math.isfinite(x)
