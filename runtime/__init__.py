"""MosaicThinker runtime: spatial questions about indoor video through a sparse global semantic map.

The Python API (what the `mosaic` command uses). Names are imported lazily, so `import mosaicthinker.runtime`
stays light (numpy/OpenCV/onnxruntime are loaded only by what you use; torch is never imported)::

    from mosaicthinker.runtime import open_source, build_map, ask, SemanticMap, Trace, load_bundle

    # answer a question about a video or an RGB-D / image folder with the models of a bundle
    res = ask("kitchen.mp4", "How many chair(s) are in this room?", bundle="bundle/")
    print(res.answer.text, res.answer.explanation)
    res.prompt.save_png("map.png"); res.trace.save("trace.json")

    # or build a map once and ask it many questions without running perception again
    from mosaicthinker.runtime import perception_from_bundle
    trace = Trace()
    build = build_map(open_source("scan/"), ["chair", "table"], [], perception_from_bundle("bundle/"), trace=trace)
    build.map.save("map.json")
    res = ask(SemanticMap.load("map.json"), "What is the distance between the chair and the table (in meters)?")

Main names: `open_source` (frames.py), `build_map`, `ask`, `perception_from_bundle`, `Perception`,
`PipelineConfig`, `AskRequest`, `AskResult`, `MapBuild` (pipeline.py), `SemanticMap`, `ObjectInstance` (semantic_map.py),
`MapReasoner`, `Answer`, `answer_question`, `parse_choice` (answer.py), `parse_question`, `ground`
(grounding.py), `render_prompt`, `VisualPrompt` (prompt.py), `Trace` (trace.py), `load_bundle` (bundle.py),
`load_role` (stages), `load_profile` (budget.py), and the errors (`MosaicError`, `InputError`, ...).
"""
from __future__ import annotations

import importlib
from typing import Any

_API: dict[str, tuple[str, str]] = {
    "open_source": ("pipeline", "open_frames"),
    "Frame": ("types", "Frame"),
    "FrameSource": ("frames", "FrameSource"),
    "build_map": ("pipeline", "build_map"),
    "ask": ("pipeline", "ask"),
    "AskRequest": ("pipeline", "AskRequest"),
    "AskResult": ("pipeline", "AskResult"),
    "MapBuild": ("pipeline", "MapBuild"),
    "Perception": ("perceive", "Perception"),
    "PipelineConfig": ("conf", "PipelineConfig"),
    "perception_from_bundle": ("perceive", "perception_from_bundle"),
    "load_vlm": ("perceive", "load_vlm"),
    "SemanticMap": ("map.model", "SemanticMap"),
    "ObjectInstance": ("map.model", "ObjectInstance"),
    "MapReasoner": ("answer", "MapReasoner"),
    "Answer": ("answer", "Answer"),
    "answer_question": ("answer", "answer_question"),
    "parse_choice": ("answer", "parse_choice"),
    "parse_question": ("grounding", "parse_question"),
    "ground": ("grounding", "ground"),
    "render_prompt": ("prompt", "render"),
    "VisualPrompt": ("prompt", "VisualPrompt"),
    "Trace": ("infra.trace", "Trace"),
    "load_bundle": ("infra.bundle", "load_bundle"),
    "load_role": ("models", "load_role"),
    "load_profile": ("budget", "load_profile"),
    "Detections": ("types", "Detections"),
    "MosaicError": ("infra.errors", "MosaicError"),
    "InputError": ("infra.errors", "InputError"),
    "BundleError": ("infra.errors", "BundleError"),
    "BudgetError": ("infra.errors", "BudgetError"),
    "ProviderError": ("infra.errors", "ProviderError"),
    "AlignmentError": ("infra.errors", "AlignmentError"),
}

__all__ = sorted(_API)


def __getattr__(name: str) -> Any:
    if name in _API:
        mod, attr = _API[name]
        value = getattr(importlib.import_module(f"{__name__}.{mod}"), attr)
        globals()[name] = value  # cache: the next access skips __getattr__
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(list(globals()) + __all__)
