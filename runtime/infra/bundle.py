"""The model bundle: a folder with `manifest.json` and the artifacts it lists (one schema for export and runtime).

Manifest shape (schema ``mosaicthinker.bundle/1``)::

    {
      "schema": "mosaicthinker.bundle/1",
      "created": "2026-11-22T01:00:00Z", "tool": "mosaicthinker 0.1.0",
      "roles": {
        "<role>": {                                   # depth | segmenter | matcher | detector | embedder | vlm
          "arch": "pydnet",                           # dispatch key of runtime.models.ARCHS
          "name": "PyDNet++",                         # optional: the model's own name (said in `ran`)
          "preprocessing": {"size": [H, W], "layout": "NHWC"|"NCHW"|"patches", "channel_order": "RGB"|"BGR",
                            "dtype": "float32"|"uint8"|"float16", "scale": 1/255, "mean": [3], "std": [3],
                            "resize": "bilinear", "keep_aspect": false},
          "semantics": {...},                         # depth: {"depth": "metric_m"|"relative"|"relative_inverse"}
                                                      # detector: {"vocabulary": "open"} or
                                                      #           {"vocabulary": "closed", "labels": [...]}
          "provenance": {"source": "hf:ID@rev" | "onnx:PATH" | "pypi:pkg==ver", "sha256": ...},
          "licence": "Apache-2.0",
          "random_weights": false,                    # true: tiny test model, the runtime warns on every load
          "config": {...},                            # arch-specific runtime options (thresholds, top-K ...)
          "default_variant": "fp32",
          "variants": {
            "<variant>": {                            # fp32 | fp16 | int8-dynamic | int8-qdq | android-ort ...
              "precision": "fp32", "target": "cpu",   # target: cpu | gpu | accelerator | android | jetson
              "components": {
                "<component>": {                      # model | pair | extractor | matcher | image | text ...
                  "file": "depth/fp32/model.onnx",    # relative to the bundle folder, never escaping it
                  "sha256": "...", "format": "onnx"|"ort", "opset": 18, "bytes": 1234,
                  "inputs":  [{"name": "im0", "shape": [1, 448, 640, 3], "dtype": "float32",
                               "dynamic_axes": {}}],  # {"0": "batch"}: axis index -> symbolic name
                  "outputs": [...],
                  "extra_files": [{"file": ..., "sha256": ...}]   # external data, optional
                }},
              "parity": {...},                        # figures measured at export (per component)
              "notes": "...",
              "overrides": {"arch": ...},             # optional: another model for this role (its own arch,
                                                      #   preprocessing, semantics, provenance, licence, config)
              "android": {},                          # RESERVED (issue 7): ort_files, required_operators,
                                                      #   usability_report, fixed_shapes ...
              "jetson": {}                            # RESERVED (issue 7): trt_profile_shapes, provider_options,
            }},                                       #   trtexec commands ...
          "android": {}, "jetson": {}                 # RESERVED per role
        }},
      "android": {}, "jetson": {}, "extensions": {}   # RESERVED bundle-wide
    }

Any dict anywhere in the manifest that has both ``file`` and ``sha256`` is an artifact reference: `verify`
checks every one of them, so the Android/Jetson additions (``{"file": "depth/android/model.ort", "sha256": ...}``)
are verified without a schema change. Paths must be relative, must not contain ``..`` and must not resolve
(through symlinks) outside the bundle folder.

Command module for ``mosaic bundle verify DIR`` and ``mosaic bundle show DIR``. This module only reads bundles
(the device side); writing them (`new_manifest`, `write_manifest`, `add_role`, `add_variant`,
`io_spec_from_onnx`) is host-side, in `host/bundle_write.py`.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import textwrap
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath
from typing import Any, Iterator

from .errors import BundleError, InputError, path_kind
from .file_schemas import check_manifest

SCHEMA = "mosaicthinker.bundle/1"
SUPPORTED_SCHEMAS = (SCHEMA,)
MANIFEST = "manifest.json"
ROLES = ("depth", "segmenter", "instance_segmenter", "matcher", "detector", "embedder", "vlm", "reader")
# role-level fields a variant may override: a variant that is another model for the same role (the SSD kept beside
# YOLOX as the detector's `ssd-fp32` variant) carries its own arch, pre-processing, labels, licence ...
OVERRIDABLE = ("arch", "name", "preprocessing", "semantics", "provenance", "licence", "random_weights", "config")
DEPTH_SEMANTICS = ("metric_m", "relative", "relative_inverse")
# Variant preference when the caller names none and the role has no default_variant.
VARIANT_PREFERENCE = ("fp32", "fp16", "int8-dynamic", "int8-qdq")


def sha256_file(path: str | os.PathLike) -> str:
    """Hex sha256 of a file's bytes (streamed)."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def safe_path(root: str | os.PathLike, rel: str, where: str = "file") -> Path:
    """Resolve a manifest path inside the bundle folder; refuse absolute paths, `..` parts and symlink escapes.

    root: the bundle folder; rel: the manifest's relative path (POSIX separators); where: the manifest field
    (named in the error message).
    """
    if not isinstance(rel, str) or not rel:
        raise BundleError(f"manifest field {where}: expected a relative file path, got {rel!r}")
    p = PurePosixPath(rel.replace("\\", "/"))
    if p.is_absolute() or rel.startswith(("/", "\\")) or (len(rel) > 1 and rel[1] == ":"):
        raise BundleError(f"manifest field {where}: path {rel!r} is absolute; bundle paths must be relative "
                          f"to the bundle folder")
    if ".." in p.parts:
        raise BundleError(f"manifest field {where}: path {rel!r} contains '..' and would escape the bundle folder")
    root_r = Path(root).resolve()
    full = (Path(root) / Path(*p.parts))
    resolved = full.resolve()
    if resolved != root_r and root_r not in resolved.parents:
        raise BundleError(f"manifest field {where}: path {rel!r} resolves to {resolved}, outside the bundle "
                          f"folder {root_r} (symlink escape)")
    return full


def iter_file_refs(obj: Any, where: str = "") -> Iterator[tuple[str, dict]]:
    """Yield (field path, ref dict) for every dict holding both `file` and `sha256` (any depth)."""
    if isinstance(obj, dict):
        if "file" in obj and "sha256" in obj:
            yield where or "<root>", obj
        for k, v in obj.items():
            yield from iter_file_refs(v, f"{where}.{k}" if where else str(k))
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            yield from iter_file_refs(v, f"{where}[{i}]")


@dataclass
class Component:
    """One graph file of a variant. inputs/outputs: list of {name, shape, dtype, dynamic_axes}."""

    name: str
    path: Path
    meta: dict[str, Any]

    @property
    def inputs(self) -> list[dict[str, Any]]:
        return self.meta.get("inputs", [])

    @property
    def outputs(self) -> list[dict[str, Any]]:
        return self.meta.get("outputs", [])

    @property
    def format(self) -> str:
        return self.meta.get("format", "onnx")


@dataclass
class RoleSpec:
    """A role's metadata with one chosen variant resolved to component paths."""

    bundle: "Bundle"
    role: str
    variant: str
    meta: dict[str, Any]
    variant_meta: dict[str, Any]
    components: dict[str, Component] = field(default_factory=dict)

    @property
    def arch(self) -> str:
        return self.meta["arch"]

    @property
    def preprocessing(self) -> dict[str, Any]:
        return self.meta.get("preprocessing", {})

    @property
    def semantics(self) -> dict[str, Any]:
        return self.meta.get("semantics", {})

    @property
    def config(self) -> dict[str, Any]:
        return self.meta.get("config", {})

    @property
    def random_weights(self) -> bool:
        return bool(self.meta.get("random_weights", False))

    def component(self, name: str) -> Component:
        if name not in self.components:
            raise BundleError(f"{self.bundle.root / MANIFEST}: roles.{self.role}.variants.{self.variant}.components "
                              f"has no {name!r} (has {sorted(self.components)})")
        return self.components[name]


class Bundle:
    """A loaded, schema-checked bundle. Hash checks happen in `load_bundle(verify=True)` / `Bundle.verify()`."""

    def __init__(self, root: str | os.PathLike, manifest: dict[str, Any]):
        self.root = Path(root)
        self.manifest = manifest
        self._verified: set[str] = set()

    @property
    def manifest_path(self) -> Path:
        return self.root / MANIFEST

    @property
    def roles(self) -> list[str]:
        return list(self.manifest.get("roles", {}))

    def has_role(self, role: str) -> bool:
        return role in self.manifest.get("roles", {})

    def role_meta(self, role: str) -> dict[str, Any]:
        roles = self.manifest.get("roles", {})
        if role not in roles:
            raise BundleError(f"{self.manifest_path}: no role {role!r} in this bundle (has {sorted(roles)}); "
                              f"add it with `mosaic export {role} ... --out {self.root}`")
        return roles[role]

    def variant_name(self, role: str, variant: str | None = None) -> str:
        """The variant to use: the one asked for, else the role's default_variant, else the first of
        VARIANT_PREFERENCE present, else the first listed."""
        meta = self.role_meta(role)
        variants = meta.get("variants", {})
        if variant is not None:
            if variant not in variants:
                raise BundleError(f"{self.manifest_path}: role {role!r} has no variant {variant!r} "
                                  f"(has {sorted(variants)})")
            return variant
        dv = meta.get("default_variant")
        if dv in variants:
            return dv
        for v in VARIANT_PREFERENCE:
            if v in variants:
                return v
        if not variants:
            raise BundleError(f"{self.manifest_path}: roles.{role}.variants is empty")
        return next(iter(variants))

    def spec(self, role: str, variant: str | None = None, *, verify: bool = True) -> RoleSpec:
        """Resolve a role + variant into component paths (hash-checked once per file when verify=True)."""
        meta = self.role_meta(role)
        vname = self.variant_name(role, variant)
        vmeta = meta["variants"][vname]
        comps = {}
        for cname, cmeta in vmeta.get("components", {}).items():
            where = f"roles.{role}.variants.{vname}.components.{cname}"
            path = safe_path(self.root, cmeta.get("file"), where + ".file")
            if verify:
                self._check_file(path, cmeta, where)
                for i, extra in enumerate(cmeta.get("extra_files", [])):
                    self._check_file(safe_path(self.root, extra.get("file"), f"{where}.extra_files[{i}].file"),
                                     extra, f"{where}.extra_files[{i}]")
            comps[cname] = Component(cname, path, cmeta)
        if not comps:
            raise BundleError(f"{self.manifest_path}: roles.{role}.variants.{vname}.components is empty")
        return RoleSpec(self, role, vname, variant_meta(meta, vmeta), vmeta, comps)

    def file(self, ref: dict | None, where: str) -> Path:
        """A checked artifact path for a `{file, sha256}` reference of the manifest (e.g. a role's tokenizer):
        refuses paths that escape the bundle, missing files and sha256 mismatches (`where` names the field)."""
        ref = ref or {}
        path = safe_path(self.root, ref.get("file", ""), where + ".file")
        self._check_file(path, ref, where)
        return path

    def _check_file(self, path: Path, ref: dict, where: str) -> None:
        key = str(path)
        if key in self._verified:
            return
        if not path.is_file():
            raise BundleError(f"{self.manifest_path}: {where}.file {ref.get('file')!r} is missing ({path}); "
                              f"re-export the role or restore the file")
        digest = sha256_file(path)
        if digest != str(ref.get("sha256", "")).lower():  # hex digests are case-insensitive
            raise BundleError(f"{path}: sha256 mismatch ({where}.sha256 says {str(ref.get('sha256'))[:12]}..., "
                              f"file has {digest[:12]}...): the file was modified or corrupted; re-export it")
        self._verified.add(key)

    def verify(self) -> dict[str, Any]:
        """Check every artifact reference (paths + sha256). Raises BundleError on the first problem;
        returns {"files": n, "bytes": total, "roles": {...}} when all is well."""
        n, total, listed = 0, 0, set()
        for where, ref in iter_file_refs(self.manifest):
            path = safe_path(self.root, ref.get("file"), where + ".file")
            self._check_file(path, ref, where)
            listed.add(os.path.normpath(path.relative_to(self.root)))
            n += 1
            total += path.stat().st_size
        self._check_external_data()
        self._refuse_unlisted(listed)
        return {"files": n, "bytes": total,
                "roles": {r: sorted(m.get("variants", {})) for r, m in self.manifest.get("roles", {}).items()}}

    def _refuse_unlisted(self, listed: set[str]) -> None:
        """Every file in the bundle folder must be a listed artifact: a graph can load any file beside it
        (ONNX external data), so an unlisted file is weights nobody hash-checked."""
        for dirpath, dirnames, filenames in os.walk(self.root, followlinks=False):
            for name in filenames + [d for d in dirnames if os.path.islink(os.path.join(dirpath, d))]:
                rel = os.path.normpath(os.path.relpath(os.path.join(dirpath, name), self.root))
                if rel != MANIFEST and rel not in listed:
                    raise BundleError(f"{self.root / rel}: file is not listed in {self.manifest_path} (unlisted "
                                      f"files could be loaded by a graph without a hash check); remove it, or "
                                      f"re-export the role so the manifest lists it with its sha256")

    def _check_external_data(self) -> None:
        """Every external-data file an ONNX component references must be listed with a sha256: in its
        `extra_files`, or as a file of the same package (a GenAI package lists each of its files; read from the
        protobuf here, so the runtime needs no `onnx`)."""
        refs = list(iter_file_refs(self.manifest))
        hashed = {os.path.normpath(str(r.get("file", ""))) for _, r in refs if r.get("sha256")}
        for where, ref in refs:
            if ref.get("format", "onnx") != "onnx" or not str(ref.get("file", "")).endswith(".onnx"):
                continue
            path = safe_path(self.root, ref["file"], where + ".file")
            base = PurePosixPath(ref["file"]).parent
            extra = {os.path.normpath(str(e.get("file", ""))) for e in ref.get("extra_files", [])
                     if isinstance(e, dict)}  # bundle-relative, like `file`
            for loc in external_data_locations(path):
                rel = os.path.normpath(str(base / loc))
                if (rel not in extra and rel not in hashed) or ".." in PurePosixPath(loc).parts \
                        or PurePosixPath(loc).is_absolute():
                    raise BundleError(f"{path}: the graph loads external data {loc!r} that {where}.extra_files "
                                      f"does not list with a sha256; re-export the role")

    def summary(self) -> dict[str, Any]:
        """A compact description of every role and variant (for `mosaic bundle show`)."""
        roles = {}
        for r, m in self.manifest.get("roles", {}).items():
            variants = {}
            for v, vm in m.get("variants", {}).items():
                comps = {}
                for c, cm in vm.get("components", {}).items():
                    comps[c] = {"file": cm.get("file"), "format": cm.get("format"), "opset": cm.get("opset"),
                                "bytes": cm.get("bytes"),
                                "inputs": [f"{i['name']}{_shape_str(i)}:{i.get('dtype')}" for i in cm.get("inputs", [])],
                                "outputs": [f"{o['name']}{_shape_str(o)}:{o.get('dtype')}" for o in cm.get("outputs", [])]}
                variants[v] = {"precision": vm.get("precision"), "target": vm.get("target"), "components": comps,
                               "parity": vm.get("parity", {}), "task": task_text(vm.get("task_check")),
                               "notes": vm.get("notes"),
                               **({"model": {k: vm["overrides"][k] for k in ("arch", "name", "licence", "provenance")
                                             if k in vm["overrides"]}} if vm.get("overrides") else {})}
            roles[r] = {"arch": m.get("arch"), "name": m.get("name"), "licence": m.get("licence"),
                        "random_weights": m.get("random_weights"),
                        "semantics": m.get("semantics", {}), "preprocessing": m.get("preprocessing", {}),
                        "provenance": m.get("provenance", {}), "default_variant": m.get("default_variant"),
                        "variants": variants, "skipped_variants": m.get("skipped_variants", {})}
        return {"bundle": str(self.root), "schema_version": self.manifest.get("schema"),
                "created": self.manifest.get("created"), "roles": roles}


def _shape_str(io: dict) -> str:
    shape = list(io.get("shape", []))
    for ax, nm in (io.get("dynamic_axes") or {}).items():
        if int(ax) < len(shape):
            shape[int(ax)] = nm
    return "[" + ",".join(str(s) for s in shape) + "]"


def variant_meta(meta: dict[str, Any], vmeta: dict[str, Any]) -> dict[str, Any]:
    """The role entry a variant runs with: the role's fields, with the variant's `overrides` (another model for
    this role: its own arch, labels, licence ...) over them."""
    if not vmeta.get("overrides"):
        return meta
    return {**meta, **{k: v for k, v in vmeta["overrides"].items() if k in OVERRIDABLE}}


def check_schema(manifest: Any, where: str = MANIFEST) -> None:
    """The manifest against its schema (`file_schemas.manifest_spec`: required fields, types, ranges, enums,
    the fields each role's adapters read). Raises BundleError naming the field."""
    if isinstance(manifest, dict) and manifest.get("schema") not in SUPPORTED_SCHEMAS:
        raise BundleError(f"{where}: unknown schema version {manifest.get('schema')!r} (this runtime reads "
                          f"{SUPPORTED_SCHEMAS}); upgrade mosaicthinker or re-export the bundle")
    check_manifest(manifest, where, ROLES, SUPPORTED_SCHEMAS, DEPTH_SEMANTICS, OVERRIDABLE)


def strict_json_loads(data: bytes | str, where: str) -> Any:
    """json.loads that refuses what the standard parser accepts silently or crashes on: duplicate keys (the
    last one would win unseen), NaN/Infinity literals, non-UTF-8 bytes and nesting too deep to parse.
    Raises InputError naming `where`."""
    def pairs(kv: list[tuple[str, Any]]) -> dict[str, Any]:
        d: dict[str, Any] = {}
        for k, v in kv:
            if k in d:
                raise InputError(f"{where}: duplicate key {k!r} in one JSON object; keep exactly one")
            d[k] = v
        return d

    def no_const(name: str) -> Any:
        raise InputError(f"{where}: {name} is not valid JSON; write a finite number")

    if isinstance(data, bytes):
        try:
            data = data.decode("utf-8")
        except UnicodeDecodeError as e:
            raise InputError(f"{where}: not UTF-8 text ({e}); save the file as UTF-8") from e
    try:
        return json.loads(data, object_pairs_hook=pairs, parse_constant=no_const)
    except json.JSONDecodeError as e:
        raise InputError(f"{where}: not valid JSON ({e})") from e
    except RecursionError as e:
        raise InputError(f"{where}: JSON nested too deeply to read; flatten it") from e


def read_manifest(root: str | os.PathLike) -> dict[str, Any]:
    root = Path(root)
    mp = root / MANIFEST
    if not root.is_dir():
        kind = path_kind(root)
        raise BundleError(f"{root}: bundle folder does not exist" if kind == "missing" else
                          f"{root}: the bundle folder is {kind}; give a bundle folder")
    if not mp.is_file():
        kind = path_kind(mp)
        raise BundleError(f"{mp}: manifest.json is missing; is {root} a bundle folder?" if kind == "missing" else
                          f"{mp}: manifest.json is {kind}; re-export the bundle")
    safe_path(root, MANIFEST, "manifest.json (a symlink out of the bundle)")
    try:
        manifest = strict_json_loads(mp.read_bytes(), str(mp))
    except InputError as e:
        raise BundleError(str(e)) from e
    check_schema(manifest, str(mp))
    return manifest


def load_bundle(root: str | os.PathLike | Bundle, *, verify: bool = True) -> Bundle:
    """Open a bundle folder. verify=True checks every artifact's path and sha256 now (recommended)."""
    if isinstance(root, Bundle):
        return root
    b = Bundle(root, read_manifest(root))
    if verify:
        b.verify()
    return b


def _fields(buf: Any) -> Iterator[tuple[int, int, Any]]:
    """(field number, wire type, value) of one protobuf message; value is a memoryview for length-delimited
    fields, else an int (fixed-size fields are skipped as 0)."""
    i, n = 0, len(buf)
    while i < n:
        key, i = _varint(buf, i)
        fnum, wt = key >> 3, key & 7
        if wt == 0:
            val, i = _varint(buf, i)
            yield fnum, wt, val
        elif wt in (1, 5):
            i += 8 if wt == 1 else 4
            yield fnum, wt, 0
        elif wt == 2:
            ln, i = _varint(buf, i)
            yield fnum, wt, buf[i:i + ln]
            i += ln
        else:
            raise ValueError(f"unsupported protobuf wire type {wt}")


# Sub-messages that can hold tensors: GraphProto node=1 initializer=5 sparse_initializer=15; NodeProto
# attribute=5; AttributeProto t=5 g=6 tensors=10 graphs=11; SparseTensorProto values=1 indices=2.
_GRAPH_TENSOR_FIELDS = {1: "node", 5: "tensor", 15: "sparse"}
_ATTR_FIELDS = {5: "tensor", 6: "graph", 10: "tensor", 11: "graph"}


def _tensor_locations(buf: Any, out: set[str]) -> None:
    for f, wt, v in _fields(buf):  # TensorProto external_data=13: StringStringEntryProto key=1 value=2
        if f == 13 and wt == 2:
            kv = {k: bytes(x).decode("utf-8", "replace") for k, w, x in _fields(v) if w == 2}
            if kv.get(1) == "location" and 2 in kv:
                out.add(kv[2])


def _graph_locations(buf: Any, out: set[str], depth: int = 0) -> None:
    if depth > 64:
        raise ValueError("graph nesting deeper than 64")
    for f, wt, v in _fields(buf):
        kind = _GRAPH_TENSOR_FIELDS.get(f) if wt == 2 else None
        if kind == "tensor":
            _tensor_locations(v, out)
        elif kind == "sparse":
            for f2, w2, v2 in _fields(v):
                if f2 in (1, 2) and w2 == 2:
                    _tensor_locations(v2, out)
        elif kind == "node":
            for f2, w2, attr in _fields(v):
                if f2 == 5 and w2 == 2:
                    for f3, w3, v3 in _fields(attr):
                        k3 = _ATTR_FIELDS.get(f3) if w3 == 2 else None
                        if k3 == "tensor":
                            _tensor_locations(v3, out)
                        elif k3 == "graph":
                            _graph_locations(v3, out, depth + 1)


def external_data_locations(path: str | os.PathLike) -> list[str]:
    """The external-data file names (relative to the graph's folder) an ONNX file references, read from the
    protobuf without the `onnx` package. ModelProto field 7 is the graph. Raises BundleError on a file that
    is not a readable ONNX protobuf."""
    out: set[str] = set()
    try:
        buf = memoryview(Path(path).read_bytes())  # views, not copies, for the nested messages
        if not len(buf):
            raise ValueError("empty file")
        for fnum, wt, v in _fields(buf):
            if fnum == 7 and wt == 2:
                _graph_locations(v, out)
    except (ValueError, IndexError, OSError) as e:
        raise BundleError(f"{path}: not a readable ONNX file ({e}); re-export the role") from e
    return sorted(out)


def _varint(buf: bytes, i: int) -> tuple[int, int]:
    shift, val = 0, 0
    while True:
        b = buf[i]
        i += 1
        val |= (b & 0x7F) << shift
        if not b & 0x80:
            return val, i
        shift += 7


# ----------------------------------------------------------------------------------------------------------------
# `mosaic bundle verify|show`

COMMON_FLAGS = ("bundle",)  # verify/show read a bundle and write nothing: no --profile, no --out


def add_arguments_for(sub: str, parser: argparse.ArgumentParser) -> None:
    parser.add_argument("dir", nargs="?", metavar="DIR", help="bundle folder (or use --bundle)")


def run_for(sub: str, args: argparse.Namespace) -> dict[str, Any]:
    root = args.dir or getattr(args, "bundle", None)
    if not root:
        raise BundleError("no bundle folder given: mosaic bundle " + sub + " DIR")
    if sub == "verify":
        b = load_bundle(root, verify=False)
        rep = b.verify()
        warn = [r for r, m in b.manifest["roles"].items() if m.get("random_weights")]
        return {"schema": "mosaicthinker.bundle.verify/1", "bundle": str(root), "ok": True,
                "schema_version": b.manifest["schema"], **rep, "random_weights_roles": warn}
    if sub == "show":
        b = load_bundle(root, verify=False)
        return {"schema": "mosaicthinker.bundle.show/1", **b.summary()}
    raise BundleError(f"unknown bundle subcommand {sub!r}")


def render(result: dict[str, Any]) -> str:
    if result.get("schema", "").endswith("verify/1"):
        lines = [f"bundle {result['bundle']}: OK ({result['schema_version']}, {result['files']} files, "
                 f"{result['bytes'] / 2**20:.1f} MiB, all sha256 match)"]
        for r, vs in result["roles"].items():
            lines.append(f"  {r:<10} {', '.join(vs)}")
        for r in result.get("random_weights_roles", []):
            lines.append(f"  WARNING: role {r} has RANDOM weights (test model): its outputs are meaningless")
        return "\n".join(lines)
    lines = [f"bundle {result['bundle']}  ({result['schema_version']}, created {result.get('created')})"]
    for r, m in result["roles"].items():
        rw = "  ** RANDOM WEIGHTS (test model) **" if m.get("random_weights") else ""
        named = f" model={m['name']!r}" if m.get("name") else ""
        lines.append(f"\n[{r}] arch={m['arch']}{named} licence={m['licence']}{_licence_warning(m['licence'])}{rw}")
        if m.get("semantics"):
            sem = {k: (v if not isinstance(v, list) or len(v) < 8 else f"<{len(v)} labels>")
                   for k, v in m["semantics"].items()}
            lines.append(f"  semantics: {sem}")
        pp = m.get("preprocessing") or {}
        if pp:
            lines.append("  preprocessing: " + ", ".join(f"{k}={v}" for k, v in pp.items()))
        prov = m.get("provenance") or {}
        if prov.get("source"):
            lines.append(f"  source: {prov['source']}")
        for v, vm in m["variants"].items():
            star = "*" if v == m.get("default_variant") else " "
            other = vm.get("model") or {}
            alt = (f" arch={other.get('arch')}" + (f" model={other['name']!r}" if other.get("name") else "")
                   + f" licence={other.get('licence')}"
                   f"{_licence_warning(other.get('licence'))}") if other else ""
            lines.append(f" {star}{v:<14} precision={vm['precision']} target={vm['target']}{alt}")
            for c, cm in vm["components"].items():
                size = f"{cm['bytes'] / 2**20:.1f} MiB" if cm.get("bytes") else "?"
                lines.append(f"     {c}: {cm['file']} ({cm['format']}, opset {cm['opset']}, {size})")
                lines.append(f"       in : {' '.join(cm['inputs'])}")
                lines.append(f"       out: {' '.join(cm['outputs'])}")
            for key in ("parity", "task", "notes"):  # wrapped at spaces, never cut
                if vm.get(key):
                    text = parity_text(vm[key]) if key == "parity" else str(vm[key])
                    lines.append(textwrap.fill(text, 110, initial_indent=f"     {key}: ", subsequent_indent=" " * 7,
                                               break_long_words=False, break_on_hyphens=False))
        for v, why in (m.get("skipped_variants") or {}).items():
            lines.append(textwrap.fill(str(why), 110, initial_indent=f"  {v:<14} NOT shipped: ",
                                       subsequent_indent=" " * 7, break_long_words=False, break_on_hyphens=False))
    return "\n".join(lines)


COPYLEFT = ("AGPL", "GPL", "LGPL", "SSPL", "CC-BY-SA", "CC-BY-NC")


def _licence_warning(licence: Any) -> str:
    """A loud note beside a copyleft or non-commercial licence (AGPL-3.0 also reaches software offered over a
    network): whoever ships the bundle must know."""
    text = str(licence or "")
    return (f"  ** {text}: copyleft / restricted licence, check before you ship it **"
            if any(text.upper().startswith(c) for c in COPYLEFT) else "")


def task_text(task: Any) -> str | None:
    """An export's task check in words: a VLM's greedy-token agreement with transformers and the threshold it
    shipped at (lower precisions ship at >= 0.5, not at full agreement: say so wherever the variant is shown)."""
    if not isinstance(task, dict):
        return None
    if "token_agreement" in task:
        need = task.get("accepted_at")
        return (f"token agreement {task['token_agreement']:.2f} with transformers over {task.get('tokens', '?')} "
                f"greedy tokens" + (f" (ships at >= {need:g}" + (": not full agreement)" if need < 1 else ")")
                                    if isinstance(need, (int, float)) else ""))
    return ", ".join(f"{k}={v}" for k, v in task.items() if not isinstance(v, (dict, list))) or None


def parity_text(p: Any) -> str:
    """A parity record in a few words, never cut (`bundle show`, the export table; the manifest keeps it all):
    a check's {"worst": {rel, cosine}, "tolerance": ...}, a per-component mapping of those, or a plain dict."""
    if not isinstance(p, dict):
        return "" if p is None else str(p)
    if p.get("copied"):
        return "copied unchanged (the reference)"
    if isinstance(p.get("task"), dict) and "found" in p["task"]:  # a re-shaped graph's check on real frames
        t = p["task"]
        return (f"task check: {t['found']:.0%} of the original graph's {t.get('detections')} detections found "
                f"again (IoU {t.get('mean_iou')}, score change {t.get('median_score_change')})")
    if isinstance(p.get("worst"), dict):
        w, tol = p["worst"], p.get("tolerance") or {}
        return (f"parity rel {w.get('rel', float('nan')):.3g}" + (f" (tol {tol['rel']:g})" if "rel" in tol else "")
                + f", cosine {w.get('cosine', float('nan')):.4f}"
                + (f" (min {tol['cosine_min']:g})" if "cosine_min" in tol else ""))
    if p and all(isinstance(v, dict) for v in p.values()):  # per component: {component: check or worst}
        return "; ".join(f"{c}: {parity_text(v if 'rel' not in v else {'worst': v})}" for c, v in p.items())
    parts = [f"{k}={v}" for k, v in p.items() if not isinstance(v, (dict, list)) and v is not None]
    return ", ".join(parts) or "recorded in the manifest"



def bundle_hash(bundle: Any) -> str:
    """Short content hash of a bundle: sha256 over every artifact's (manifest field, sha256), so it changes when
    any model file changes but not when only the manifest's timestamps do. 16 hex characters."""
    b = load_bundle(bundle, verify=False)
    h = hashlib.sha256()
    for where, ref in sorted(iter_file_refs(b.manifest), key=lambda x: x[0]):
        h.update(f"{where}={ref.get('sha256')}\n".encode())
    return h.hexdigest()[:16]
