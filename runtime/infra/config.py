"""Stage configuration: one dataclass per stage holding the paper's defaults, merged with user overrides
(LightGlue's `default_conf` idea). The one home for the merge rules, shared by every stage config."""
from __future__ import annotations

from dataclasses import asdict, fields, replace
from typing import Any, ClassVar, Mapping, TypeVar

from .errors import InputError

C = TypeVar("C", bound="StageConf")


class StageConf:
    """Mixin for stage-config dataclasses.

    `Cls.merged(conf=None, **overrides)`: `conf` is an instance of the class (copied) or a mapping of overrides
    (e.g. from a JSON/TOML file or the command line); keyword overrides that are None are ignored (unset
    command-line flags). An unknown key is an `InputError` naming it and listing the known ones; the result is
    checked by `validate()` (override it to add range checks).
    """

    conf_name: ClassVar[str] = "config"

    @classmethod
    def merged(cls: type[C], conf: "C | Mapping[str, Any] | None" = None, **overrides: Any) -> C:
        base = conf if isinstance(conf, cls) else cls()
        upd = dict(conf) if isinstance(conf, Mapping) else {}
        upd.update({k: v for k, v in overrides.items() if v is not None})
        known = {f.name for f in fields(cls)}  # type: ignore[arg-type]
        bad = sorted(set(upd) - known)
        if bad:
            raise InputError(f"{cls.conf_name}: unknown key(s) {bad}; known: {sorted(known)}")
        out = replace(base, **upd)  # type: ignore[type-var]
        out.validate()
        return out

    def validate(self) -> None:
        """Range checks; raise InputError naming the field."""

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)  # type: ignore[call-overload]
