"""One owner per setting (issue 27): no field name is defined in two stage configs, so a name means one thing
wherever it is set (`{"alignment": {...}}`, a profile, a flag); the walk can fail (a case below)."""
from __future__ import annotations

import dataclasses
import importlib
import pkgutil
from dataclasses import dataclass
from typing import ClassVar

import mosaicthinker.runtime as runtime
from mosaicthinker.runtime.infra.config import StageConf


def stage_configs() -> list[type]:
    """Every StageConf dataclass of the runtime (each runtime module imported first)."""
    for m in pkgutil.walk_packages(runtime.__path__, runtime.__name__ + "."):
        importlib.import_module(m.name)
    out, todo = [], list(StageConf.__subclasses__())
    while todo:
        c = todo.pop()
        todo += c.__subclasses__()
        if dataclasses.is_dataclass(c) and c.__module__.startswith(runtime.__name__):
            out.append(c)
    return sorted(out, key=lambda c: c.__qualname__)


def shared_names(configs: list[type]) -> dict[str, list[str]]:
    """field name -> the configs defining it, for every name defined in more than one (a sub-config field, e.g.
    `PipelineConfig.alignment`, is the config itself, not a second definition)."""
    owners: dict[str, list[str]] = {}
    for c in configs:
        for f in dataclasses.fields(c):
            owners.setdefault(f.name, []).append(c.__qualname__)
    return {n: cs for n, cs in owners.items() if len(cs) > 1}


def test_every_stage_config_field_name_has_one_owner():
    configs = stage_configs()
    names = {c.__qualname__ for c in configs}
    assert {"DedupConf", "KeyFrameConf", "AlignConf", "MatchConf", "FusionConfig", "PipelineConfig", "PlanConf",
            "PromptConfig"} <= names
    assert shared_names(configs) == {}


def test_a_name_defined_twice_is_found():
    @dataclass
    class ConfA(StageConf):
        conf_name: ClassVar[str] = "a"
        seed: int = 0
        only_a: int = 1

    @dataclass
    class ConfB(StageConf):
        conf_name: ClassVar[str] = "b"
        seed: int = 1

    assert shared_names([ConfA, ConfB]) == {"seed": ["test_a_name_defined_twice_is_found.<locals>.ConfA",
                                                     "test_a_name_defined_twice_is_found.<locals>.ConfB"]}
    assert ConfA in StageConf.__subclasses__() and ConfA not in stage_configs()  # only the runtime's are walked
