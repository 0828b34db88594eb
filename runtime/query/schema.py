"""JSON for programs, generated from the IR's dataclasses: `to_json`, `from_json` (validated) and `json_schema`.

One walk over the type hints of `query.ir` serves all three, so the schema, the writer and the reader cannot
drift apart. JSON objects carry `"kind"` for the members of a union (nodes, selectors, regions, steps); fields
equal to their default are left out when written and filled in when read. `from_json` checks every field by
type, range and enum, names the path of the first bad one (`ProgramError`), and refuses unknown keys: what the
VLM emits under the schema passes it, and what does not pass is refused, never guessed.

`json_schema()` is a draft 2020-12 schema with `$defs` per dataclass, every string and array bounded (so that
constrained decoding of a random-weight model terminates), and LLGuidance's `x-guidance` set to compact JSON.
"""
from __future__ import annotations

import functools
import json
import types
import typing
from dataclasses import MISSING, fields, is_dataclass
from typing import Any, Literal, Union

from ..infra.errors import InputError
from . import ir
from .ir import SCHEMA_VERSION, Program


class ProgramError(InputError):
    """A program that does not follow the schema (the path and what is wrong)."""


@functools.lru_cache(maxsize=None)
def _hints(cls: type) -> dict[str, Any]:
    return typing.get_type_hints(cls, vars(ir))


def _union_args(tp: Any) -> tuple[Any, ...] | None:
    if typing.get_origin(tp) in (Union, types.UnionType):
        return typing.get_args(tp)
    return None


def _default(f: Any) -> Any:
    if f.default is not MISSING:
        return f.default
    if f.default_factory is not MISSING:  # type: ignore[misc]
        return f.default_factory()  # type: ignore[misc]
    return MISSING


# ----------------------------------------------------------------------------- writing


def to_json(x: Any) -> Any:
    """A program (or any IR value) as JSON-ready Python: dicts with "kind" first, defaults left out."""
    if is_dataclass(x):
        out: dict[str, Any] = {}
        if hasattr(type(x), "KIND"):
            out["kind"] = type(x).KIND
        for f in fields(x):
            v = getattr(x, f.name)
            if v != _default(f):
                out[f.name] = to_json(v)
        if isinstance(x, Program):
            out = {"version": SCHEMA_VERSION, **out}
        return out
    if isinstance(x, tuple):
        return [to_json(v) for v in x]
    return x


def dumps(p: Program) -> str:
    return json.dumps(to_json(p), separators=(",", ":"))


# ----------------------------------------------------------------------------- reading (validated)


def from_json(data: Any, cls: Any = Program) -> Any:
    """JSON (a dict, or a string) -> the IR value of type `cls` (default: a `Program`), every field checked;
    `ProgramError` naming the path of the first field that is wrong."""
    if isinstance(data, (str, bytes)):
        try:
            data = json.loads(data)
        except json.JSONDecodeError as e:
            raise ProgramError(f"program: not JSON ({e})") from e
    return _read(cls, data, "program" if cls is Program else cls.__name__)


def _bad(path: str, what: str) -> ProgramError:
    return ProgramError(f"{path}: {what}")


def _read(tp: Any, v: Any, path: str, meta: dict[str, Any] | None = None) -> Any:
    meta = meta or {}
    args = _union_args(tp)
    if args is not None:
        if v is None and type(None) in args:
            return None
        members = [a for a in args if a is not type(None)]
        if len(members) == 1:
            return _read(members[0], v, path, meta)
        kinds = {a.KIND: a for a in members}
        k = v.get("kind") if isinstance(v, dict) else None
        if k not in kinds:
            raise _bad(path, f"kind {k!r} is not one of {sorted(kinds)}")
        return _read(kinds[k], v, path, meta)
    origin = typing.get_origin(tp)
    if origin is Literal:
        if v not in typing.get_args(tp) or isinstance(v, bool):
            raise _bad(path, f"{v!r} is not one of {list(typing.get_args(tp))}")
        return v
    if origin is tuple:
        if not isinstance(v, list):
            raise _bad(path, f"expected a list, got {type(v).__name__}")
        lo, hi = meta.get("min_items", 0), meta.get("max_items", 10 ** 9)
        if not lo <= len(v) <= hi:
            raise _bad(path, f"{len(v)} items, expected {lo} to {hi}")
        item = typing.get_args(tp)[0]
        return tuple(_read(item, x, f"{path}[{i}]", meta.get("item")) for i, x in enumerate(v))
    if is_dataclass(tp):
        return _read_dataclass(tp, v, path)
    if tp is bool:
        if not isinstance(v, bool):
            raise _bad(path, f"expected true or false, got {v!r}")
        return v
    if tp is int:
        if isinstance(v, bool) or not isinstance(v, int):
            raise _bad(path, f"expected an integer, got {v!r}")
        if not meta.get("minimum", -10 ** 18) <= v <= meta.get("maximum", 10 ** 18):
            raise _bad(path, f"{v} outside [{meta.get('minimum')}, {meta.get('maximum')}]")
        return v
    if tp is str:
        if not isinstance(v, str):
            raise _bad(path, f"expected a string, got {type(v).__name__}")
        if not meta.get("min_length", 0) <= len(v) <= meta.get("max_length", 10 ** 6):
            raise _bad(path, f"{len(v)} characters, expected {meta.get('min_length', 0)} to {meta.get('max_length')}")
        return v
    raise TypeError(f"IR type {tp!r} at {path} has no JSON reading")  # a programming error, not bad input


def _read_dataclass(cls: type, v: Any, path: str) -> Any:
    if not isinstance(v, dict):
        raise _bad(path, f"expected an object, got {type(v).__name__}")
    allowed = {f.name for f in fields(cls)} | ({"kind"} if hasattr(cls, "KIND") else set()) | \
        ({"version"} if cls is Program else set())
    extra = sorted(set(v) - allowed)
    if extra:
        raise _bad(path, f"unknown field(s) {extra} for {cls.__name__}")
    if cls is Program and v.get("version", SCHEMA_VERSION) != SCHEMA_VERSION:
        raise _bad(f"{path}.version", f"{v['version']!r}; this reader knows {SCHEMA_VERSION}")
    if hasattr(cls, "KIND") and v.get("kind", cls.KIND) != cls.KIND:
        raise _bad(f"{path}.kind", f"{v['kind']!r}, expected {cls.KIND!r}")
    kw = {}
    hints = _hints(cls)
    for f in fields(cls):
        if f.name in v:
            kw[f.name] = _read(hints[f.name], v[f.name], f"{path}.{f.name}", dict(f.metadata))
        elif _default(f) is MISSING:
            raise _bad(f"{path}.{f.name}", "missing")
    return cls(**kw)


# ----------------------------------------------------------------------------- the schema


# what the VLM decodes under: the same schema, shorter strings and lists, the derived Ref fields left out (so that
# any decoding ends within `query.vlm.VLM_MAX_TOKENS` tokens of one character each)
PROFILES: dict[str, dict[str, Any]] = {
    "full": {"max_length": 10 ** 6, "max_items": 10 ** 6, "drop": set()},
    "vlm": {"max_length": 24, "max_items": 4, "steps": 8, "pattern": "^[A-Za-z0-9*' -]{{{lo},{hi}}}$",
            "caps": {("Ref", "select"): 1, ("Described", "words"): 2}, "drop": {("Ref", "phrase"), ("Ref", "known"), ("NearestTo", "phrase"),
                                                       ("Direction", "stand_by_order"), ("Direction", "relative_to")}},
}


def _schema_of(tp: Any, meta: dict[str, Any], defs: dict[str, Any], prof: dict[str, Any]) -> dict[str, Any]:
    """The schema of one IR type (`meta`: the field's bounds; `defs`: the dataclasses met so far)."""
    args = _union_args(tp)
    if args is not None:
        alts = [_schema_of(a, meta, defs, prof) for a in args if a is not type(None)]
        if type(None) in args:
            alts.append({"type": "null"})
        return alts[0] if len(alts) == 1 else {"anyOf": alts}
    origin = typing.get_origin(tp)
    if origin is Literal:
        return {"enum": list(typing.get_args(tp))}
    if origin is tuple:
        s = {"type": "array", "items": _schema_of(typing.get_args(tp)[0], meta.get("item") or {}, defs, prof)}
        if "min_items" in meta:
            s["minItems"] = meta["min_items"]
        cap = prof.get("steps", prof["max_items"]) if meta.get("steps") else prof["max_items"]
        s["maxItems"] = max(min(meta.get("max_items", 8), cap), meta.get("min_items", 0))
        return s
    if is_dataclass(tp):
        if tp.__name__ not in defs:
            defs[tp.__name__] = {}  # placeholder: a type refers to itself at most through a $ref
            defs[tp.__name__] = _object_schema(tp, defs, prof)
        return {"$ref": f"#/$defs/{tp.__name__}"}
    if tp is bool:
        return {"type": "boolean"}
    if tp is int:
        return {"type": "integer", "minimum": meta.get("minimum", 0), "maximum": meta.get("maximum", 10 ** 9)}
    if tp is str:
        hi = min(meta.get("max_length", 400), prof["max_length"])
        if prof.get("pattern"):  # plain words only: no escapes, so a character is one byte of output
            return {"type": "string", "pattern": prof["pattern"].format(lo=meta.get("min_length", 0), hi=hi)}
        return {"type": "string", **({"minLength": meta["min_length"]} if "min_length" in meta else {}),
                "maxLength": hi}
    raise TypeError(f"IR type {tp!r} has no JSON schema")


def _object_schema(cls: type, defs: dict[str, Any], prof: dict[str, Any]) -> dict[str, Any]:
    props: dict[str, Any] = {}
    required: list[str] = []
    if cls is Program:
        props["version"] = {"const": SCHEMA_VERSION}
    if hasattr(cls, "KIND"):
        props["kind"] = {"const": cls.KIND}
        required.append("kind")
    hints = _hints(cls)
    for f in fields(cls):
        if (cls.__name__, f.name) in prof["drop"] and _default(f) is not MISSING:
            continue
        meta = dict(f.metadata)
        if (cls.__name__, f.name) in prof.get("caps", {}):
            meta["max_items"] = prof["caps"][(cls.__name__, f.name)]
        props[f.name] = _schema_of(hints[f.name], meta, defs, prof)
        if _default(f) is MISSING:
            required.append(f.name)
    s: dict[str, Any] = {"type": "object", "properties": props, "required": required,
                         "additionalProperties": False}
    if cls.__doc__:
        s["description"] = " ".join(cls.__doc__.split())
    return s


@functools.lru_cache(maxsize=None)
def _schema_text(root: str, profile: str) -> str:
    defs: dict[str, Any] = {}
    top = _schema_of(Program if root == "program" else ir.Node, {}, defs, PROFILES[profile])
    if "$ref" in top:  # the program itself inline at the top, its parts in $defs
        top = defs.pop(top["$ref"].rsplit("/", 1)[1])
    schema = {"$schema": "https://json-schema.org/draft/2020-12/schema", "$id": SCHEMA_VERSION,
              "title": "MosaicThinker question program" if root == "program" else "MosaicThinker question node",
              "x-guidance": {"whitespace_flexible": False}, **top, "$defs": defs}
    return json.dumps(schema, sort_keys=False)


def json_schema(root: str = "program", profile: str = "full") -> dict[str, Any]:
    """The versioned JSON schema of a `Program` (root "program") or of one question node (root "ask": what the
    VLM emits; the options come from the question). profile "vlm": the bounds the VLM decodes under (`PROFILES`;
    every document it accepts is valid under "full"). A fresh dict each call."""
    if root not in ("program", "ask") or profile not in PROFILES:
        raise ValueError(f"root {root!r} / profile {profile!r}: expected program or ask / {sorted(PROFILES)}")
    return json.loads(_schema_text(root, profile))


def max_output_bytes(schema: dict[str, Any]) -> int:
    """The longest compact JSON document `schema` accepts, in bytes (strings by their `pattern`'s or maxLength's
    bound, at one byte per character for a pattern of plain characters, 12 otherwise: an escaped surrogate pair):
    a decoding under the schema can never need more tokens than this."""
    defs = schema.get("$defs", {})

    def size(s: dict[str, Any]) -> int:
        if "$ref" in s:
            return size(defs[s["$ref"].rsplit("/", 1)[1]])
        if "anyOf" in s:
            return max(size(a) for a in s["anyOf"])
        if "const" in s:
            return len(json.dumps(s["const"]))
        if "enum" in s:
            return max(len(json.dumps(v)) for v in s["enum"])
        t = s.get("type")
        if t == "object":
            props = s.get("properties", {})
            return 2 + sum(len(json.dumps(k)) + 1 + size(v) for k, v in props.items()) + max(len(props) - 1, 0)
        if t == "array":
            n = s.get("maxItems", 0)
            return 2 + n * size(s["items"]) + max(n - 1, 0)
        if t == "string":
            if "pattern" in s:
                return 2 + int(s["pattern"].rsplit(",", 1)[1].split("}")[0])
            return 2 + 12 * s.get("maxLength", 10 ** 6)
        if t == "integer":
            return max(len(str(s.get("minimum", -10 ** 18))), len(str(s.get("maximum", 10 ** 18))))
        if t == "boolean":
            return 5
        if t == "null":
            return 4
        raise ValueError(f"no length bound for {s}")
    return size(schema)
