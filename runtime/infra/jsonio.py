"""The one JSON writer of the product: strict JSON only (RFC 8259: no NaN, no Infinity).

Python's `json` writes a non-finite float as the bare words `NaN` / `Infinity`, which no strict reader (and not
the project's own `strict_json_loads`) accepts. Every JSON the product prints or writes goes through `dumps` /
`dump` / `encode_fn`: encoded with `allow_nan=False`; where a value is non-finite it is written as `null` (a value
that is missing, e.g. an ATE with one aligned frame), found by one walk that runs only when the fast encode
refused. `tests/test_strict_json.py` scans the code for other `json.dump(s)` call sites.
"""
from __future__ import annotations

import json
import math
from typing import IO, Any, Callable


def json_default(x: Any) -> Any:
    """What the JSON encoder cannot write itself: numpy arrays and scalars, objects with `to_dict`, the rest as
    text (the conversions of `jsonable`, done only where such a value is met)."""
    import numpy as np  # noqa: PLC0415 - the CLI's first line comes before numpy loads

    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, np.generic):
        return x.item()
    if hasattr(x, "to_dict"):
        return x.to_dict()
    if isinstance(x, (set, frozenset)):
        return sorted(x, key=str)
    return str(x)


def finite_or_none(obj: Any, default: Callable[[Any], Any] | None = json_default) -> Any:
    """`obj` as plain JSON values with every non-finite float (Python, numpy, inside arrays) as None. Keys are
    kept (non-string keys as JSON writes them)."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, (str, int, bool)) or obj is None:
        return obj
    if isinstance(obj, dict):
        return {k: finite_or_none(v, default) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [finite_or_none(v, default) for v in obj]
    if default is None:
        return obj
    return finite_or_none(default(obj), default)  # arrays, numpy scalars, to_dict objects: then walked


def dumps(obj: Any, *, indent: int | None = None, separators: tuple[str, str] | None = None,
          sort_keys: bool = False, default: Callable[[Any], Any] | None = json_default) -> str:
    """Strict JSON text of `obj` (non-finite numbers as null; numpy values and `to_dict` objects converted)."""
    kw = dict(indent=indent, separators=separators, sort_keys=sort_keys, default=default, allow_nan=False)
    try:
        return json.dumps(obj, **kw)  # type: ignore[arg-type]
    except ValueError as e:  # a NaN / inf somewhere: written as null (a circular reference still raises)
        if not _non_finite(e):
            raise
        return json.dumps(finite_or_none(obj, default), **kw)  # type: ignore[arg-type]


def _non_finite(e: ValueError) -> bool:
    return "Out of range float values" in str(e)


def dump(obj: Any, f: IO[str], **kw: Any) -> None:
    """`dumps` into an open text file."""
    f.write(dumps(obj, **kw))


def encode_fn(default: Callable[[Any], Any] | None = json_default) -> Callable[[Any], str]:
    """A one-argument strict encoder (the C encoder, compact), for callers that encode many values in a row."""
    enc = json.JSONEncoder(default=default, allow_nan=False).encode

    def encode(v: Any) -> str:
        try:
            return enc(v)
        except ValueError as e:
            if not _non_finite(e):
                raise
            return enc(finite_or_none(v, default))
    return encode


def plain(obj: Any, default: Callable[[Any], Any] | None = json_default) -> Any:
    """`obj` as plain Python JSON values by one encode and decode in C; non-finite floats stay floats (a
    conversion for renderers and records, not a writer: what is written goes through `dumps`)."""
    return json.loads(json.dumps(obj, default=default))


def is_strict(text: str) -> bool:
    """True when `text` parses as JSON without NaN / Infinity (what a strict reader accepts)."""
    def refuse(word: str) -> Any:
        raise ValueError(word)
    try:
        json.loads(text, parse_constant=refuse)
    except ValueError:
        return False
    return True
