"""The schemas of the files the runtime reads, as data for `schema.check`: the bundle manifest, the saved
semantic map, the device profile (TOML). The scene annotation's schema lives beside its loader, host-side
(`host/evaluation/scene.py`). Each file's loader calls its `check_*` here first: a malformed field is an error
naming the file, the field path and what to do (exit 2), never a crash far from the file.

What a value means is checked too: an arch's preprocessing against the graph's image input
(`image_input_problem`, shared by `mosaic bundle verify` and the model loading), a config index against the
outputs a component has, rotation rows that are orthonormal, a pose that is rigid, a ceiling above the floor.
The roles, schema versions and depth semantics come from `bundle.py` (their one home) as arguments, so this
module imports no loader.
"""
from __future__ import annotations

from functools import lru_cache
from typing import Any, Sequence

import numpy as np

from .errors import BundleError, InputError
from .schema import (AnyValue, Arr, Bool, F, Int, ListOf, MapOf, Num, Obj, OneOf, Str, check, orthonormal_rows,
                     show, unique)

# ------------------------------------------------------------------------------------------------ semantic map

MAX_COORD_M = 1e9     # no map spans more; implausible-but-possible sizes (a 1 km sofa) are noted by `health`
MAX_TIME_S = 1e9


def rigid_pose(T: np.ndarray) -> tuple[int, str] | None:
    last = np.abs(T[:, 3] - [0, 0, 0, 1]).max(1) > 1e-6
    R = T[:, :3, :3]
    det = np.abs(np.linalg.det(R) - 1) > 1e-2
    bad = np.flatnonzero(last | det)
    return (int(bad[0]), "is not a rigid pose (rotation + translation)") if len(bad) else None


def _room_heights(room: dict) -> str | None:
    return None if room["ceiling_z"] > room["floor_z"] else "ceiling_z must be above floor_z"


_COORD = dict(lo=-MAX_COORD_M, hi=MAX_COORD_M)
BOX = Obj(fields={
    "centroid": F(Arr(shape=(3,), **_COORD)),
    "axesLengths": F(Arr(shape=(3,), lo=0, lo_open=True, hi=MAX_COORD_M,
                         want="3 sizes in metres (sizes must be > 0)")),
    "normalizedAxes": F(Arr(shape=(9,), lo=-1.01, hi=1.01, array_rules=(orthonormal_rows(),),
                            want="9 numbers: three orthonormal rows, row-major")),
    "min": F(Arr(shape=(3,), **_COORD), required=False),
    "max": F(Arr(shape=(3,), **_COORD), required=False),
})
_VIEW = Obj(fields={
    "frame": F(Int(lo=0, hi=2**53)), "score": F(Num(lo=0, hi=1)), "n_points": F(Int(lo=0, hi=2**53), required=False),
    "centre": F(Arr(shape=(3,), nullable=True, **_COORD), required=False),
    "size": F(Arr(shape=(3,), lo=0, hi=MAX_COORD_M, nullable=True), required=False),
})
_INSTANCE = Obj(fields={
    "id": F(Int(lo=0, hi=2**53)),
    "name": F(Str(nonempty=True, max_len=200)),
    "box": F(BOX),
    "first_seen": F(Num(lo=-MAX_TIME_S, hi=MAX_TIME_S, nullable=True), required=False),
    "score": F(Num(lo=0, hi=1), required=False),
    "n_points": F(Int(lo=0, hi=2**53), required=False),
    "frames": F(ListOf(item=Int(lo=0, hi=2**53)), required=False),
    "views": F(ListOf(item=_VIEW), required=False),
})
_CAMERA = Obj(fields={"t": F(Num(lo=-MAX_TIME_S, hi=MAX_TIME_S)),
                      "T_wc": F(Arr(shape=(4, 4), **_COORD, array_rules=(rigid_pose,)))})
_ROOM = Obj(fields={
    "polygon": F(Arr(shape=(-1, 2), **_COORD, want="a floor outline: a list of [x, y] corners (m)")),
    "floor_z": F(Num(**_COORD)), "ceiling_z": F(Num(**_COORD)),
    "source": F(Str(), required=False), "area_m2": F(Num(lo=0), required=False),
}, item_rules=(_room_heights,), nullable=True)


@lru_cache(maxsize=4)
def map_spec(schema_id: str) -> Obj:
    """The saved map (`SemanticMap.to_dict`): what `mosaic map` / `ask --out` write, `mosaic ask MAP` reads."""
    return Obj(fields={
        "schema": F(Str(enum=(schema_id,), want=f"{schema_id!r} (rebuild the map with `mosaic map`)")),
        "instances": F(ListOf(item=_INSTANCE, list_rules=(unique("id"),),
                              want="a list of objects (an empty map is \"instances\": [])")),
        "room": F(_ROOM, required=False),
        "cameras": F(ListOf(item=_CAMERA), required=False),
        "meta": F(Obj(), required=False),
        "run_id": F(Str(), required=False),
    })


def check_map(d: Any, where: str, schema_id: str, max_objects: int) -> None:
    """Raise InputError naming the field for a map dict that breaks the schema (or holds too many objects)."""
    if isinstance(d, dict) and isinstance(d.get("instances"), list) and len(d["instances"]) > max_objects:
        raise InputError(f"{where}: {len(d['instances'])} objects; at most {max_objects} are supported; split the "
                         f"scene or map fewer object kinds")
    check(d, map_spec(schema_id), where=where, error=InputError,
          fix="rebuild the map with `mosaic map` or fix that field")


# ------------------------------------------------------------------------------------------------ bundle manifest

_HEX = frozenset("0123456789abcdefABCDEF")


def _sha(vals: list) -> tuple[int, str] | None:
    for i, v in enumerate(vals):
        if len(v) != 64 or not set(v) <= _HEX:
            return i, f"must be 64 hex digits (a sha256), got {show(v)}"
    return None


def _channels(vals: list) -> tuple[int, str] | None:
    for i, v in enumerate(vals):
        if len(v) not in (1, 3):
            return i, f"must hold 1 or 3 numbers (one per channel), got {len(v)}"
    return None


def _nonzero(vals: list) -> tuple[int, str] | None:
    for i, v in enumerate(vals):
        if any(x == 0 for x in v):
            return i, "must not hold 0 (the pixels are divided by it)"
    return None


def _rel_path(vals: list) -> tuple[int, str] | None:
    for i, v in enumerate(vals):
        parts = v.replace("\\", "/").split("/")
        if v.startswith(("/", "\\")) or (len(v) > 1 and v[1] == ":") or ".." in parts:
            return i, f"must be a path relative to the bundle folder without '..', got {show(v)}"
        if len(v) > 1024 or max(map(len, parts)) > 255 or "\0" in v:
            return i, "is not a usable file path (too long, or a NUL byte)"
    return None


_PATH = Str(nonempty=True, rules=(_rel_path,))
_FILE_REF = Obj(fields={"file": F(_PATH), "sha256": F(Str(rules=(_sha,)))})
_IO = Obj(fields={
    "name": F(Str(nonempty=True)),
    "shape": F(ListOf(item=Int(lo=-1, hi=2**31), want="a list of integers (-1 or 0: a dynamic axis)")),
    "dtype": F(Str(), required=False),
    "dynamic_axes": F(MapOf(value=Str(), nullable=True), required=False),
})
_COMPONENT = Obj(fields={
    "file": F(_PATH), "sha256": F(Str(rules=(_sha,))), "format": F(Str(enum=("onnx", "ort"))),
    "inputs": F(ListOf(item=_IO)), "outputs": F(ListOf(item=_IO)),
    "opset": F(Int(lo=1, hi=1000, nullable=True), required=False),
    "bytes": F(Int(lo=0, hi=2**53, nullable=True), required=False),
    "extra_files": F(ListOf(item=_FILE_REF, want="a list of {file, sha256} objects"), required=False),
})
_VARIANT = Obj(fields={
    "precision": F(Str(nonempty=True), required=False),
    "target": F(Str(nonempty=True), required=False),
    "components": F(MapOf(value=_COMPONENT)),
    "notes": F(Str(nullable=True), required=False),
})
_PREPROCESSING = Obj(fields={
    "size": F(Arr(shape=(2,), integer=True, lo=1, hi=16384, want="[height, width] as two positive integers"),
              required=False),
    "layout": F(Str(enum=("NHWC", "NCHW", "PATCHES"), fold=True), required=False),
    "channel_order": F(Str(enum=("RGB", "BGR"), fold=True), required=False),
    "dtype": F(Str(enum=("float32", "float16", "uint8")), required=False),
    "scale": F(Num(lo=0, lo_open=True, hi=1e6, nullable=True, want="a positive number"), required=False),
    "mean": F(Arr(shape=(-1,), lo=-1e6, hi=1e6, nullable=True, rules=(_channels,),
                  want="a list of 3 numbers"), required=False),
    "std": F(Arr(shape=(-1,), lo=-1e6, hi=1e6, nullable=True, rules=(_channels, _nonzero),
                 want="a list of 3 numbers (non-zero)"), required=False),
    "resize": F(Str(), required=False),
    "keep_aspect": F(Bool(), required=False),
})
# config keys the adapters read (runtime/stages/*), one meaning per name; unknown keys pass (an adapter ignores
# what it does not read)
_POS = dict(lo=0, lo_open=True)
CONFIG_KEYS: dict[str, Any] = {
    "output": Int(lo=0, hi=1024), "min_depth_m": Num(lo=0, hi=1e4), "max_depth_m": Num(hi=1e5, **_POS),
    "score_threshold": Num(lo=0, hi=1), "max_detections": Int(lo=1, hi=100_000),
    "output_scale": Num(hi=1e9, **_POS), "output_zero_point": Num(lo=-1e9, hi=1e9),
    "min_score": Num(lo=-1e9, hi=1e9), "normalize_kpts": Bool(), "keypoint_px": Num(hi=1e4, **_POS),
    "keypoint_threshold": Num(lo=-1e9, hi=1e9), "detection_threshold": Num(lo=-1e9, hi=1e9),
    "coarse_matching_threshold": Num(lo=-1e9, hi=1e9), "min_cossim": Num(lo=-1, hi=1),
    "k": Int(lo=1, hi=1_000_000), "top_k": Int(lo=1, hi=1_000_000), "max_keypoints": Int(lo=1, hi=1_000_000),
    "input_size": Int(lo=1, hi=16384, nullable=True), "mask_threshold": Num(lo=-1e9, hi=1e9),
    "embedding_size": Arr(shape=(2,), integer=True, lo=1, hi=16384),
    "logits_layout": Str(enum=("NHWC", "NCHW")),
    "max_new_tokens": Int(lo=1, hi=100_000), "stop_tokens": ListOf(item=Str(nonempty=True), nullable=True),
    "text_length": Int(lo=1, hi=100_000), "start_token": Str(nonempty=True), "end_token": Str(nonempty=True),
    "pad_id": Int(lo=0, hi=2**31), "query_template": Str(), "nms_iou": Num(lo=0, hi=1),
    "max_per_name": Int(lo=1, hi=100_000), "family": Str(nonempty=True),
    "num_layers": Int(lo=1, hi=10_000), "num_kv_heads": Int(lo=1, hi=10_000), "head_dim": Int(lo=1, hi=100_000),
    "image_token_id": Int(lo=0, hi=2**31), "image_seq_len": Int(lo=1, hi=1_000_000),
    "pad_token_id": Int(lo=0, hi=2**31, nullable=True),
    "merged_grid": Arr(shape=(-1,), integer=True, lo=1, hi=100_000), "deepstack_layers": Int(lo=0, hi=10_000),
    "hidden_size": Int(lo=1, hi=1_000_000), "patch_size": Int(lo=1, hi=16384), "merge_size": Int(lo=1, hi=16384),
    "temporal_patch_size": Int(lo=1, hi=1024), "image_size": OneOf(options=(Int(lo=1, hi=16384),
                                                                           Arr(shape=(2,), integer=True, lo=1))),
}
_CONFIG = Obj(fields={k: F(v, required=False) for k, v in CONFIG_KEYS.items()})


def _default_variant(role: dict) -> str | None:
    dv = role.get("default_variant")
    if dv is None or dv in role["variants"]:
        return None
    return f"default_variant must be one of the variant names {sorted(role['variants'])}, got {show(dv)}"


def _output_index(role: dict) -> str | None:
    """config.output indexes the graph's outputs: an index past them fails on the first image."""
    out = (role.get("config") or {}).get("output")
    if out is None:
        return None
    for vname, vm in role["variants"].items():
        for cname, cm in vm["components"].items():
            if len(vm["components"]) == 1 and cm["outputs"] and out >= len(cm["outputs"]):
                return (f"config.output is {out} but variants.{vname}.components.{cname} has "
                        f"{len(cm['outputs'])} output(s)")
    return None


def _depth_range(role: dict) -> str | None:
    cfg = role.get("config") or {}
    lo, hi = cfg.get("min_depth_m", 0.05), cfg.get("max_depth_m", 20.0)
    return None if lo < hi else f"config.min_depth_m ({lo}) must be below config.max_depth_m ({hi})"


_LISTS_LABELS = ("detector", "instance_segmenter")  # roles whose semantics say their vocabulary (labels when closed)


def _semantics_problem(role: str, r: dict) -> str | None:
    """What a role's semantics must say together: a closed vocabulary lists its labels, a semantic segmenter its
    classes."""
    sem = r.get("semantics") or {}
    if role in _LISTS_LABELS and sem.get("vocabulary") == "closed" and not sem.get("labels"):
        return "semantics.labels is required (non-empty) for a closed vocabulary"
    if role == "segmenter" and sem.get("kind", "semantic") == "semantic" and not sem.get("labels"):
        return "semantics.labels is required (non-empty) for a semantic segmenter"
    return None


def _overrides_problem(role: str) -> Any:
    """A variant that is another model for the role (`overrides`): the role entry it makes must still mean
    something (its own labels, depth units ...)."""
    def rule(r: dict) -> str | None:
        for vname, vm in r["variants"].items():
            ov = vm.get("overrides")
            why = _semantics_problem(role, {**r, **ov}) if ov else None
            if why:
                return f"variants.{vname}.overrides: {why}"
        return None
    return rule


def _role_spec(role: str, depth_semantics: Sequence[str], overridable: Sequence[str]) -> Obj:
    """One role's entry; what a role's adapters must read is required here (a depth role says its units, a
    closed-vocabulary detector or instance segmenter and a semantic segmenter list their labels). A variant's
    `overrides` (another model for the role) take the role's own field specs."""
    sem: dict[str, F] = {"labels": F(ListOf(item=Str(), want="a list of strings"), required=False),
                         "vocabulary": F(Str(enum=("open", "closed")), required=role in _LISTS_LABELS),
                         "dim": F(Int(lo=0, hi=1_000_000), required=False),
                         "k": F(Int(lo=1, hi=1_000_000), required=False),
                         "kind": F(Str(), required=False)}
    sem["depth"] = F(Str(enum=tuple(depth_semantics)), required=role == "depth")
    fields = {
        "arch": F(Str(nonempty=True)),
        "name": F(Str(), required=False),
        "licence": F(Str(nonempty=True)),
        "random_weights": F(Bool()),
        "provenance": F(Obj(fields={"source": F(Str(), required=False)})),
        "preprocessing": F(_PREPROCESSING, required=False),
        "semantics": F(Obj(fields=sem), required=role in ("depth", *_LISTS_LABELS)),
        "config": F(_CONFIG, required=False),
        "default_variant": F(Str(), required=False),
        "tokenizer": F(_FILE_REF, required=False),
        "skipped_variants": F(MapOf(value=AnyValue()), required=False),
    }
    overrides = Obj(fields={k: F(fields[k].spec, required=False) for k in overridable}, extra=False,
                    unknown=lambda k, known: f"has a field {k!r} a variant cannot override; it may override "
                                             f"{', '.join(known)}")
    variant = Obj(fields={**_VARIANT.fields, "overrides": F(overrides, required=False)})
    return Obj(fields={**fields, "variants": F(MapOf(value=variant, min_len=1))},
               item_rules=(_default_variant, _output_index, _depth_range, lambda r: _semantics_problem(role, r),
                           _overrides_problem(role)))


@lru_cache(maxsize=8)
def manifest_spec(roles: tuple[str, ...], schemas: tuple[str, ...], depth_semantics: tuple[str, ...],
                  overridable: tuple[str, ...] = ()) -> Obj:
    """The bundle manifest (runtime/infra/bundle.py's docstring) for the roles the runtime knows; `overridable`:
    the role fields a variant's `overrides` may set."""
    role_fields = {r: F(_role_spec(r, depth_semantics, overridable), required=False) for r in roles}
    return Obj(fields={
        "schema": F(Str(enum=schemas)),
        "created": F(Str(), required=False), "updated": F(Str(), required=False), "tool": F(Str(), required=False),
        "roles": F(Obj(fields=role_fields, extra=False,
                       unknown=lambda k, known: f"has an unknown role {k!r}; roles are {', '.join(known)}")),
    })


def check_manifest(manifest: Any, where: str, roles: Sequence[str], schemas: Sequence[str],
                   depth_semantics: Sequence[str], overridable: Sequence[str] = ()) -> None:
    """Raise BundleError naming the manifest field that breaks the schema."""
    check(manifest, manifest_spec(tuple(roles), tuple(schemas), tuple(depth_semantics), tuple(overridable)),
          where=where,
          error=BundleError, fix="fix the manifest or re-export the role")


# ------------------------------------------------------------------------------- graph inputs vs the manifest

def image_input_problem(pp: dict[str, Any], inputs: Sequence[tuple[str, Sequence[Any], str | None]]
                        ) -> tuple[str, str] | None:
    """Whether `preprocessing` fits a graph's image input: (preprocessing field, what is wrong) or None.

    inputs: the graph's inputs as (name, shape with ints / None / names for dynamic axes, dtype
    float32|float16|uint8|other|None). The image input is the one rank-4 input with 3 channels where the layout
    puts them; graphs without one (decoders, text branches, matchers over descriptors) pass. A graph with a fixed
    height and width needs `size` (frames of any size would be fed as they come)."""
    layout = str(pp.get("layout", "NHWC")).upper()
    if layout == "PATCHES":
        return None
    nchw = layout == "NCHW"
    ins = [i for i in inputs if len(i[1] or []) == 4]
    if len(ins) != 1:
        return None
    name, shape, dtype = ins[0]
    chan, other = (shape[1], shape[3]) if nchw else (shape[3], shape[1])
    if chan != 3 and other != 3:
        return None  # not an RGB image input (feature maps, masks)
    if chan != 3 and isinstance(chan, int) and chan > 0:
        return "layout", (f"is {'NCHW' if nchw else 'NHWC'} but the graph input {name!r} is {list(shape)}; fix "
                          f"preprocessing.layout or re-export the role")
    hw = list(shape[2:4] if nchw else shape[1:3])
    fixed = [g if isinstance(g, int) and g > 0 else None for g in hw]
    size = pp.get("size")
    if size is None and all(fixed):
        return "size", (f"is missing but the graph input {name!r} takes {fixed[0]}x{fixed[1]} images ({list(shape)}); "
                        f"add \"size\": {fixed} or re-export the role")
    if size and any(g is not None and g != int(s) for g, s in zip(fixed, size)):
        return "size", (f"is {list(size)} but the graph input {name!r} is {list(shape)}; fix preprocessing.size or "
                        f"re-export the role")
    want = str(pp.get("dtype", "float32"))
    if dtype in ("float32", "float16", "uint8") and dtype != want:
        return "dtype", (f"is {want!r} but the graph input {name!r} takes {dtype}; fix preprocessing.dtype or "
                         f"re-export the role")
    return None


# ------------------------------------------------------------------------------------------------ device profile

def profile_spec(cost_items: dict[str, tuple[tuple[str, ...], str]], roles: Sequence[str],
                 precisions: Sequence[str], int8_kinds: Sequence[str], providers: Sequence[str],
                 max_threads: int, unknown: Any) -> Obj:
    """A device profile (runtime/budget/profile.py's docstring). `unknown(key, known)` words an unknown key
    (a unit spelt another way is named)."""
    num = Num(lo=0, hi=1e12, want="a number >= 0, never negative (the unit is in the key name: write the bare "
                                   "number)")
    pos = Num(lo=0, lo_open=True, hi=1e12, want="a number > 0, never negative (the unit is in the key name: write "
                                                "the bare number)")
    chain = ListOf(item=Str(enum=tuple(providers), want="a known execution provider (" + ", ".join(providers) + ")"),
                   min_len=1,
                   want="a non-empty list of onnxruntime provider names")
    threads = Int(lo=1, hi=max_threads, want=f"an integer in 1..{max_threads} (use the device's core count)")
    text = Str()

    def cost(item: str, paper: bool) -> Obj:
        nums = cost_items[item][0]
        fields = {k: F(num, required=False) for k in nums}
        fields.update({k: F(text, required=False) for k in ("status", "date", "bundle_hash", "source", "provider",
                                                              "note")})
        if paper:
            fields["variant"] = F(Str(nonempty=True), required=False)
            fields["variants"] = F(MapOf(value=Obj(fields={**{k: F(num, required=False) for k in nums},
                                                           "note": F(text, required=False)},
                                                   extra=False, unknown=unknown)), required=False)
        return Obj(fields=fields, extra=False, unknown=unknown)

    def costs(paper: bool) -> Obj:
        return Obj(fields={k: F(cost(k, paper), required=False) for k in cost_items}, extra=False,
                   unknown=lambda k, known: f"has an unknown cost item {k!r}; items are {', '.join(known)}")

    role = Obj(fields={"precision": F(Str(enum=tuple(precisions)), required=False),
                       "int8_kind": F(Str(enum=tuple(int8_kinds)), required=False),
                       "variant": F(Str(nonempty=True), required=False), "providers": F(chain, required=False),
                       "input_size_px": F(Arr(shape=(2,), integer=True, lo=1, hi=16384,
                                              want="[width, height] positive integers"), required=False),
                       "notes": F(text, required=False)}, extra=False, unknown=unknown)
    return Obj(fields={
        "schema": F(Str()),
        "device": F(Obj(fields={"name": F(Str(nonempty=True)), "description": F(text, required=False),
                                "soc": F(text, required=False), "os": F(text, required=False),
                                "ram_mb": F(pos, required=False), "accelerator": F(text, required=False),
                                "notes": F(text, required=False)}, extra=False, unknown=unknown)),
        "budget": F(Obj(fields={"latency_budget_ms": F(pos), "memory_budget_mb": F(pos)}, extra=False,
                        unknown=unknown)),
        "runtime": F(Obj(fields={"providers": F(chain), "intra_op_threads": F(threads, required=False),
                                 "inter_op_threads": F(threads, required=False),
                                 "core_affinity": F(ListOf(item=Int(lo=0, hi=max_threads - 1), min_len=1,
                                                           want="a non-empty list of CPU ids >= 0"),
                                                    required=False),
                                 "notes": F(text, required=False)}, extra=False, unknown=unknown)),
        "roles": F(Obj(fields={r: F(role, required=False) for r in roles}, extra=False,
                       unknown=lambda k, known: f"has an unknown role {k!r}; roles are {', '.join(known)}"),
                   required=False),
        "costs": F(costs(False)),
        "paper_costs": F(costs(True), required=False),
    }, extra=False, unknown=unknown)
