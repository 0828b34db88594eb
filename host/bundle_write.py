"""Writing model bundles (host side: export/ uses it; the device only reads bundles, `runtime/infra/bundle.py`).

The schema, its checks and the read side (`load_bundle`, `read_manifest`, `safe_path`, `sha256_file`,
`external_data_locations` ...) live in `runtime/infra/bundle.py` and are re-exported here, so export code needs one
import: `from mosaicthinker.host import bundle_write as B`.
"""
from __future__ import annotations

import datetime as _dt
import os
import tempfile
from pathlib import Path, PurePosixPath
from typing import Any

from mosaicthinker.runtime.infra.bundle import (MANIFEST, OVERRIDABLE, ROLES, SCHEMA, SUPPORTED_SCHEMAS, VARIANT_PREFERENCE, Bundle, Component,  # noqa: F401
                      RoleSpec, _varint, bundle_hash, check_schema, external_data_locations, iter_file_refs,
                      load_bundle, parity_text, read_manifest, safe_path, sha256_file, strict_json_loads,
                      task_text)
from mosaicthinker.runtime.infra import jsonio
from mosaicthinker.runtime.infra.errors import BundleError


def new_manifest() -> dict[str, Any]:
    return {"schema": SCHEMA, "created": _now(), "tool": _tool(), "roles": {},
            "android": {}, "jetson": {}, "extensions": {}}


def _now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")


def _tool() -> str:
    try:
        from importlib.metadata import version

        return f"mosaicthinker {version('mosaicthinker')}"
    except Exception:  # not installed (source checkout)
        return "mosaicthinker"


def write_manifest(root: str | os.PathLike, manifest: dict[str, Any]) -> Path:
    """Atomically write manifest.json after a schema check."""
    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    check_schema(manifest, str(root / MANIFEST))
    fd, tmp = tempfile.mkstemp(dir=root, prefix=".manifest.", suffix=".tmp")
    with os.fdopen(fd, "w") as f:
        jsonio.dump(manifest, f, indent=2, sort_keys=False)
        f.write("\n")
    os.chmod(tmp, 0o644)  # mkstemp makes 0600; a bundle is read by other users/services
    os.replace(tmp, root / MANIFEST)
    return root / MANIFEST


def io_spec_from_onnx(path: str | os.PathLike) -> tuple[list[dict], list[dict], int | None]:
    """Inputs/outputs of a graph as manifest entries, via onnxruntime (no `onnx` import needed).

    Returns (inputs, outputs, opset of the default domain or None); a dim that is symbolic or unknown becomes 0 in `shape` with its name in
    `dynamic_axes` ({axis index as str: name}).
    """
    import onnxruntime as ort

    so = ort.SessionOptions()
    so.log_severity_level = 3
    ort.set_default_logger_severity(3)
    so.graph_optimization_level = ort.GraphOptimizationLevel.ORT_DISABLE_ALL
    sess = ort.InferenceSession(str(path), so, providers=["CPUExecutionProvider"])

    def conv(nodes):
        out = []
        for n in nodes:
            shape, dyn = [], {}
            for i, d in enumerate(n.shape or []):
                if isinstance(d, int) and d >= 0:
                    shape.append(int(d))
                else:
                    shape.append(0)
                    dyn[str(i)] = str(d) if d is not None else f"d{i}"
            out.append({"name": n.name, "shape": shape, "dtype": _ort_dtype(n.type), "dynamic_axes": dyn})
        return out

    return conv(sess.get_inputs()), conv(sess.get_outputs()), _onnx_opset(Path(path))


def _ort_dtype(t: str) -> str:
    t = t.replace("tensor(", "").rstrip(")")
    return {"float": "float32", "double": "float64"}.get(t, t)


def add_role(root: str | os.PathLike, role: str, role_meta: dict[str, Any], *, replace: bool = False) -> dict:
    """Create or update a role's metadata (everything except variants) in the bundle at `root`.

    Existing variants of the role are kept unless replace=True. Returns the new manifest.
    """
    root = Path(root)
    manifest = read_manifest(root) if (root / MANIFEST).is_file() else new_manifest()
    roles = manifest.setdefault("roles", {})
    old = roles.get(role, {}) if not replace else {}
    if old and old.get("arch") != role_meta.get("arch", old.get("arch")):
        old = {}  # a different architecture replaces the role: its old variants would not fit the new adapter
    meta = {"android": {}, "jetson": {}, "config": {}, **{k: v for k, v in old.items() if k != "variants"},
            **role_meta}
    meta["variants"] = dict(old.get("variants", {}))
    roles[role] = meta
    return manifest


def add_variant(root: str | os.PathLike, role: str, variant: str, components: dict[str, dict[str, Any]], *,
                role_meta: dict[str, Any], precision: str, target: str = "cpu", parity: dict | None = None,
                notes: str | None = None, extra: dict[str, Any] | None = None, default: bool = False,
                alternative: bool = False) -> Path:
    """Record one variant of a role (its component files must already be inside `root`).

    components: {component name: {"file": relative path, optional "format", "opset", ...}}; sha256, bytes and
    the I/O spec are filled in from the file when absent. role_meta: arch, preprocessing, semantics,
    provenance, licence, random_weights, config (merged into the role). alternative=True: the variant is another
    model for an existing role (e.g. the SSD beside YOLOX): `role_meta` goes into the variant's `overrides`, the
    role's own fields stay. Returns the manifest path.
    """
    root = Path(root)
    if alternative:
        manifest = read_manifest(root) if (root / MANIFEST).is_file() else None
        if manifest is None or role not in manifest.get("roles", {}):
            raise BundleError(f"{root}: add the {role} role's default model before an alternative variant {variant!r}")
        extra = {**(extra or {}), "overrides": {k: role_meta[k] for k in OVERRIDABLE if k in role_meta}}
    else:
        manifest = add_role(root, role, role_meta)
    rm = manifest["roles"][role]
    comps = {}
    for cname, c in components.items():
        c = dict(c)
        path = safe_path(root, c["file"], f"roles.{role}.variants.{variant}.components.{cname}.file")
        if not path.is_file():
            raise BundleError(f"{path}: component file missing while adding {role}/{variant}/{cname}")
        c.setdefault("format", "ort" if path.suffix == ".ort" else "onnx")
        c["sha256"] = sha256_file(path)
        c["bytes"] = path.stat().st_size
        if "inputs" not in c or "outputs" not in c:
            ins, outs, _ = io_spec_from_onnx(path)
            c.setdefault("inputs", ins)
            c.setdefault("outputs", outs)
        c.setdefault("opset", _onnx_opset(path) if c["format"] == "onnx" else None)
        c["extra_files"] = _extra_files(root, path, c.get("extra_files", []),
                                        f"roles.{role}.variants.{variant}.components.{cname}.extra_files")
        if not c["extra_files"]:
            del c["extra_files"]
        comps[cname] = c
    vm = {"precision": precision, "target": target, "components": comps, "parity": parity or {},
          "notes": notes, "android": {}, "jetson": {}, **(extra or {})}
    rm["variants"][variant] = vm
    if default or "default_variant" not in rm or rm.get("default_variant") not in rm["variants"]:
        rm["default_variant"] = variant
    manifest["updated"] = _now()
    return write_manifest(root, manifest)


def _extra_files(root: Path, graph: Path, given: list[dict], where: str) -> list[dict]:
    """The given extra files plus every external-data file the graph references, each with its sha256
    (bundle-relative paths), so verification can hash-check everything the graph loads."""
    files = [dict(e) for e in given]
    if graph.suffix == ".onnx":
        have = {os.path.normpath(e["file"]) for e in files}
        for loc in external_data_locations(graph):
            rel = (graph.parent / loc).relative_to(root).as_posix() if not PurePosixPath(loc).is_absolute() else loc
            if os.path.normpath(rel) not in have:
                files.append({"file": rel})
    for e in files:
        ep = safe_path(root, e["file"], where)
        if not ep.is_file():
            raise BundleError(f"{ep}: external data of {graph} is missing ({where}); copy it into the bundle")
        e["sha256"] = sha256_file(ep)
    return files


def _onnx_opset(path: Path) -> int | None:
    """Default-domain opset read from the ONNX protobuf without the `onnx` package (tiny varint parser)."""
    try:
        data = path.read_bytes()
    except OSError:
        return None
    return _parse_opset(data)


def _parse_opset(buf: bytes) -> int | None:
    """ModelProto field 8 = opset_import (OperatorSetIdProto: 1 domain string, 2 version int64)."""
    i, n = 0, len(buf)
    try:
        while i < n:
            key, i = _varint(buf, i)
            fnum, wt = key >> 3, key & 7
            if wt == 0:
                _, i = _varint(buf, i)
            elif wt == 1:
                i += 8
            elif wt == 5:
                i += 4
            elif wt == 2:
                ln, i = _varint(buf, i)
                if fnum == 8:
                    sub, j, dom, ver = buf[i:i + ln], 0, "", None
                    while j < len(sub):
                        k2, j = _varint(sub, j)
                        if k2 >> 3 == 1 and k2 & 7 == 2:
                            l2, j = _varint(sub, j)
                            dom = sub[j:j + l2].decode(errors="replace")
                            j += l2
                        elif k2 >> 3 == 2 and k2 & 7 == 0:
                            ver, j = _varint(sub, j)
                        else:
                            return None
                    if dom in ("", "ai.onnx") and ver is not None:
                        return int(ver)
                i += ln
            else:
                return None
    except IndexError:
        return None
    return None
