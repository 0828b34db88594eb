"""Mutations of the files the product reads, shared by the property tests (tests/test_schema_fuzz.py) and the
campaign (tests/test_campaign.py): every field path of a valid document x every kind of damage a hand edit, a
foreign writer or a bit flip makes (type swaps, NaN/inf, empty, huge, wrong enum, missing)."""
from __future__ import annotations

import copy
import hashlib
import json
import math
import sys
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from mosaicthinker.runtime.geometry import OrientedBox
from mosaicthinker.runtime.map import ObjectInstance, Room, SemanticMap

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

REPO = Path(__file__).resolve().parents[1]
TINY = REPO / "tests" / "data" / "tiny_roles"
DELETE = object()

# name -> the value put in place of a field (DELETE: the key / item is removed)
MUTATIONS: dict[str, Any] = {
    "missing": DELETE, "null": None, "true": True, "false": False, "zero": 0, "one": 1, "negative": -1,
    "fraction": 0.5, "huge": 1e300, "huge_int": 10**30, "tiny": 1e-300, "nan": math.nan, "inf": math.inf,
    "minus_inf": -math.inf, "string": "x", "number_string": "1.5", "empty_string": "", "blank": "  ",
    "long_string": "x" * 20000, "wrong_enum": "no-such-value", "empty_list": [], "empty_object": {},
    "list_of_strings": ["a", "b"], "list_of_numbers": [1, 2, 3], "nested_list": [[1, 2], [3]],
    "object": {"a": 1}, "big_list": [0.5] * 5000,
}


def paths(doc: Any, prefix: tuple = (), max_items: int = 2, depth: int = 8) -> Iterator[tuple]:
    """Every field path of `doc` (dict keys and list indices; the first `max_items` items of a list)."""
    if depth == 0:
        return
    if isinstance(doc, dict):
        for k, v in doc.items():
            yield prefix + (k,)
            yield from paths(v, prefix + (k,), max_items, depth - 1)
    elif isinstance(doc, list):
        for i, v in enumerate(doc[:max_items]):
            yield prefix + (i,)
            yield from paths(v, prefix + (i,), max_items, depth - 1)


def mutate(doc: Any, path: tuple, kind: str) -> Any:
    """A deep copy of `doc` with the field at `path` damaged as `kind` says."""
    d = copy.deepcopy(doc)
    parent = d
    for k in path[:-1]:
        parent = parent[k]
    value = MUTATIONS[kind]
    if value is DELETE:
        del parent[path[-1]]
    else:
        parent[path[-1]] = copy.deepcopy(value)
    return d


def show_path(path: tuple) -> str:
    return "".join(f"[{k}]" if isinstance(k, int) else f".{k}" for k in path).lstrip(".")


# ---------------------------------------------------------------------------------------------- base documents

def base_map() -> dict:
    """A small valid map (what `mosaic map` writes): chairs, a table, per-view estimates, a room, cameras."""
    def box(c, s, yaw=0.0):
        ca, sa = math.cos(yaw), math.sin(yaw)
        return OrientedBox(np.array(c, float), np.array(s, float), np.array([[ca, sa, 0], [-sa, ca, 0], [0, 0, 1]]))

    views = [{"frame": 0, "score": 0.9, "n_points": 40, "centre": [0.0, 0.0, 0.5], "size": [0.5, 0.5, 1.0]},
             {"frame": 3, "score": 0.8, "n_points": 30, "centre": None, "size": None}]
    inst = [ObjectInstance(0, "chair", box([0, 0, 0.5], [0.5, 0.5, 1.0]), 1.5, 0.9, 70, [0, 3], views),
            ObjectInstance(1, "chair", box([1.5, 0.2, 0.5], [0.5, 0.5, 1.0], 0.3), 2.0, 0.8, 50, [3]),
            ObjectInstance(2, "table", box([3.0, 4.0, 0.4], [1.2, 0.8, 0.8]), None, 0.95, 90, [5, 6])]
    T1 = np.eye(4)
    T1[:3, 3] = [1.0, -1.0, 1.4]
    room = Room(np.array([[-1, -1], [5, -1], [5, 6], [-1, 6]], float), 0.0, 2.6, "observed_depth_hull")
    return SemanticMap(inst, room, [(0.0, np.eye(4)), (1.0, T1)], {"source": "test", "keyframes": 2}).to_dict()


def base_profile() -> dict:
    with open(REPO / "profiles" / "cpu-generic.toml", "rb") as f:
        return tomllib.load(f)


def base_annotation() -> dict:
    """The kitchen annotation cut to two categories (chair, tv)."""
    doc = json.loads((REPO / "benchmarks" / "data" / "redkitchen_annotation.json").read_text())
    (name, scene), = doc["meta_info"].items()
    keep = ("chair", "tv")
    scene = {"object_counts": {c: min(2, scene["object_counts"][c]) for c in keep},
             "object_bbox": {c: scene["object_bbox"][c][:2] for c in keep},
             "instance_ids": {c: scene["instance_ids"][c][:2] for c in keep}, "dataset": scene["dataset"]}
    doc["meta_info"] = {name: scene}
    doc["not_annotated"] = {}
    return doc


def _sha(p: Path) -> str:
    return hashlib.sha256(p.read_bytes()).hexdigest()


def _io(name: str, shape: list[int], dtype: str) -> dict:
    return {"name": name, "shape": shape, "dtype": dtype, "dynamic_axes": {}}


def base_manifest(bundle: Path) -> dict:
    """A bundle of four tiny graphs (tests/data/tiny_roles, each following its adapter's contract) copied into
    `bundle`; returns its manifest (also written there)."""
    import shutil

    img = {"size": [8, 8], "layout": "NHWC", "channel_order": "RGB", "resize": "bilinear"}
    roles = {
        "depth": ("depth_generic", {**img, "dtype": "float32", "scale": 1 / 255},
                  {"depth": "relative"}, {"output": 0}, [_io("y", [1, 8, 8, 1], "float32")], "float32"),
        "detector": ("ssd_tflite", {**img, "dtype": "uint8"},
                     {"vocabulary": "closed", "labels": ["person", "chair", "tv"]}, {"score_threshold": 0.5},
                     [_io("boxes", [1, 2, 4], "float32"), _io("classes", [1, 2], "float32"),
                      _io("scores", [1, 2], "float32"), _io("count", [1], "float32")], "uint8"),
        "segmenter": ("deeplab", {**img, "dtype": "float32", "mean": [127.5] * 3, "std": [127.5] * 3},
                      {"kind": "semantic", "labels": ["background", "chair", "tv"]}, {"logits_layout": "NHWC"},
                      [_io("y", [1, 8, 8, 3], "float32")], "float32"),
        "embedder": ("embedding_generic", {**img, "dtype": "uint8"}, {"dim": 3}, {"output": 0},
                     [_io("y", [1, 3], "float32")], "uint8"),
    }
    man: dict[str, Any] = {"schema": "mosaicthinker.bundle/1", "created": "2026-12-03T00:00:00Z", "tool": "test",
                           "roles": {}}
    for role, (arch, pp, sem, cfg, outs, dtype) in roles.items():
        rel = f"{role}/fp32/model.onnx"
        (bundle / role / "fp32").mkdir(parents=True, exist_ok=True)
        shutil.copyfile(TINY / f"{role}.onnx", bundle / rel)
        comp = {"file": rel, "sha256": _sha(bundle / rel), "format": "onnx", "opset": 17,
                "bytes": (bundle / rel).stat().st_size, "inputs": [_io("x", [1, 8, 8, 3], dtype)], "outputs": outs}
        man["roles"][role] = {"arch": arch, "preprocessing": pp, "semantics": sem,
                              "provenance": {"source": "test:tiny_roles"}, "licence": "Apache-2.0",
                              "random_weights": False, "config": cfg, "default_variant": "fp32",
                              "variants": {"fp32": {"precision": "fp32", "target": "cpu",
                                                    "components": {"model": comp}, "parity": {}}}}
    (bundle / "manifest.json").write_text(json.dumps(man, indent=1))
    return man


def use_roles(bundle: Path) -> None:
    """Load every role of `bundle` and run it once on a small image, as the pipeline would."""
    from mosaicthinker.runtime.infra.bundle import load_bundle
    from mosaicthinker.runtime.models import load_role

    rgb = np.random.default_rng(0).integers(0, 255, (24, 32, 3), dtype=np.uint8)
    b = load_bundle(bundle)
    for role in b.roles:
        m = load_role(b, role)
        if role == "depth":
            m.predict_metric(rgb)
        elif role == "detector":
            m.detect(rgb, ["chair", "tv"])
        elif role == "segmenter":
            m.segment(rgb, np.array([[2, 2, 20, 20]], np.float32), ["chair"])
        elif role == "embedder":
            m.embed(rgb)
