"""The Android step: per role and precision, fixed shapes -> .ort (both styles) -> parity -> usability report,
recorded in the manifest; then the bundle-wide operator config and build line."""
from __future__ import annotations

import argparse
import shutil
import tempfile
from pathlib import Path
from typing import Any, Callable, Sequence

from mosaicthinker.host import bundle_write as B

from .. import common as C
from ..parity import ORT_PARITY_TOL, ort_parity
from .config import NOT_CHECKED, OPS_CONFIG, PHONE_RUNS, VARIANT_PREFIX, AndroidConfig, config_from_args
from .convert import _ops_from_json, _ops_to_json, build_command, convert_to_ort, read_operator_config, \
    write_operator_config
from .feeds import random_feeds_factory
from .kvwindow import KV_WINDOW_PROTOCOL, decoder_dyn_values, kv_io, kv_window_check, kv_window_shapes
from .precision import source_graphs
from .shapes import _copy, fixed_shape_plan, make_fixed
from .usability import recommended_providers, usability_report

Log = Callable[[str], None]


def _ref(root: Path, path: Path) -> dict[str, str]:
    return {"file": path.relative_to(root).as_posix(), "sha256": B.sha256_file(path)}


def _kv_window_components(p: Path, c: str, cmeta: dict[str, Any], v: str, conf: AndroidConfig, tmp: Path,
                          log: Log, label: str) -> tuple[dict[str, Any], dict[str, Path], dict[str, dict]]:
    """The fixed-window decoder graphs of a KV-cache component when the protocol reproduces the dynamic
    decoder: (its check, {name: fixed graph}, {name: component info}); nothing for other components."""
    io = kv_io(cmeta["inputs"], cmeta["outputs"])
    if io is None:
        return {}, {}, {}
    chk = kv_window_check(p, cmeta["inputs"], cmeta["outputs"], window=conf.kv_window, prefill=conf.prefill_len)
    log(f"android {label}: fixed-window KV cache (W={conf.kv_window}) "
        f"{'matches' if chk['ok'] else 'does NOT match'} the dynamic decoder "
        f"({chk.get('max_rel', chk.get('reason'))})")
    fixed: dict[str, Path] = {}
    info: dict[str, dict] = {}
    if chk["ok"]:
        for tag, n_new in (("step", 1), ("prefill", conf.prefill_len)):
            name = f"{c}_kvwindow_{tag}"
            shp = kv_window_shapes(cmeta["inputs"], io, conf.kv_window, n_new)
            fixed[name] = make_fixed(p, tmp / f"{v}.{name}.onnx", shp)
            info[name] = {"fixed_shapes": shp, "dynamic_left": {},
                          "kv_window": {"window": conf.kv_window, "new_positions": n_new,
                                        "protocol": KV_WINDOW_PROTOCOL, "check": chk, "of_component": c}}
    return chk, fixed, info


def fixed_components(role: str, rmeta: dict[str, Any], v: str, comps: dict[str, Path],
                     src_meta: dict[str, Any], conf: AndroidConfig, tmp: Path,
                     log: Log) -> tuple[dict[str, Path], dict[str, dict[str, Any]]]:
    """Fixed-shape copies of a variant's components (plus fixed-window decoder graphs), and per component
    {fixed_shapes, dynamic_left, kv_window_check?, kv_window?}."""
    fixed: dict[str, Path] = {}
    comp_info: dict[str, dict[str, Any]] = {}
    for c, p in list(comps.items()):
        shapes, left = fixed_shape_plan(src_meta[c]["inputs"], rmeta, c, conf, role)
        fixed[c] = make_fixed(p, tmp / f"{v}.{c}.onnx", shapes) if shapes else _copy(p, tmp / f"{v}.{c}.onnx")
        comp_info[c] = {"fixed_shapes": shapes, "dynamic_left": left}
        if left and conf.kv_window > 0:
            chk, kv_fixed, kv_info = _kv_window_components(p, c, src_meta[c], v, conf, tmp, log,
                                                           f"{role}/{v}/{c}")
            if chk:
                comp_info[c]["kv_window_check"] = chk
            fixed.update(kv_fixed)
            comp_info.update(kv_info)
    return fixed, comp_info


def _component_parity(fx: Path, paths: dict[str, Path], cmeta: dict[str, Any] | None, rmeta: dict[str, Any],
                      v: str, conf: AndroidConfig, label: str) -> dict[str, Any]:
    """Each .ort style against its fixed-shape source graph (fresh random inputs; axes left dynamic, e.g. a
    KV cache, get small concrete sizes)."""
    io = kv_io(cmeta["inputs"], cmeta["outputs"]) if cmeta else None
    mk = random_feeds_factory(fx, rmeta, decoder_dyn_values(cmeta["inputs"], io) if io else None)
    rel_tol, cos_min = ORT_PARITY_TOL[v]
    return {s: ort_parity(pth, fx, mk, runtime_opt=(s == "Runtime"), trials=conf.parity_trials,
                          rel_tol=rel_tol, cos_min=cos_min, label=f"{label}/{pth.name} vs .onnx")
            for s, pth in paths.items()}


def _usability_entry(root: Path, out_dir: Path, c: str, fx: Path, info: dict[str, Any], paths: dict[str, Path],
                     v: str, conf: AndroidConfig) -> dict[str, Any]:
    """The component's android manifest entry: usability report files and figures, providers, runtime_opt."""
    rep = usability_report(fx, out_dir / f"{c}.usability.txt", out_dir / f"{c}.usability.json",
                           nnapi_max_partitions=conf.nnapi_max_partitions)
    providers, why = recommended_providers(rep, v, bool(info["dynamic_left"]), conf)
    if "kv_window_check" in info:
        chk = info["kv_window_check"]
        why.append(f"fixed-window KV variant {c}_kvwindow_step/_prefill for NPU providers"
                   if chk["ok"] else f"no fixed-window KV variant: {chk.get('reason') or chk}")
    entry = {**info, "usability": _ref(root, out_dir / f"{c}.usability.json"),
             "usability_text": _ref(root, out_dir / f"{c}.usability.txt"),
             "nnapi": {k: rep["nnapi"][k] for k in ("partitions", "supported_pct", "suitability",
                                                     "partition_sizes", "unsupported_ops")},
             "coreml_mlprogram": {k: rep["coreml_mlprogram"][k] for k in ("partitions", "supported_pct", "suitability")},
             "flags": rep["flags"], "providers": providers, "provider_notes": why}
    if "Runtime" in paths:
        entry["runtime_opt"] = {**_ref(root, paths["Runtime"]),
                                "session_config": {"session.enable_saved_runtime_optimizations": "1"},
                                "use_for": ["NNAPI", "QNN"]}
    return entry


def _usability_row(role: str, vname: str, c: str, entry: dict[str, Any]) -> dict[str, Any]:
    """One line of the bundle's android.usability_summary."""
    return {"role": role, "variant": vname, "component": c, "nnapi_partitions": entry["nnapi"]["partitions"],
            "nnapi_supported_pct": entry["nnapi"]["supported_pct"],
            "nnapi_suitability": entry["nnapi"]["suitability"],
            "coreml_mlprogram_partitions": entry["coreml_mlprogram"]["partitions"],
            "flags": [f.split(":")[0] for f in entry["flags"]], "providers": entry["providers"]}


def _variant_ops(configs: dict[str, Path]) -> dict[tuple[str, int], set[str]]:
    v_ops: dict[tuple[str, int], set[str]] = {}
    for cfg in configs.values():
        for k, ops in read_operator_config(cfg).items():
            v_ops.setdefault(k, set()).update(ops)
    return v_ops


def _variant_summary(comp_info: dict[str, dict[str, Any]], parity: dict[str, Any]) -> dict[str, Any]:
    return {"components": {c: {"fixed_shapes": comp_info[c]["fixed_shapes"],
                               "dynamic_left": comp_info[c]["dynamic_left"],
                               "nnapi_partitions": comp_info[c]["nnapi"]["partitions"],
                               "flags": comp_info[c]["flags"], "providers": comp_info[c]["providers"],
                               "parity": _parity_brief(parity[c]),
                               **({"kv_window_check": comp_info[c]["kv_window_check"]}
                                  if "kv_window_check" in comp_info[c] else {})}
                           for c in comp_info}}


def export_variant(root: Path, role: str, rmeta: dict[str, Any], v: str, comps: dict[str, Path],
                   conf: AndroidConfig, tmp: Path, log: Log, usability: list) -> dict[str, Any]:
    """One source precision of one role: fixed shapes, .ort files, parity, usability; recorded as variant
    `android-ort-<v>`. Appends the usability rows to `usability`; returns the variant's summary."""
    import onnxruntime as ort

    variants = rmeta["variants"]
    vname = VARIANT_PREFIX + v
    log(f"android {role}/{v}: fixing shapes, converting {len(comps)} component(s) to .ort")
    src_meta = variants.get(v, variants.get("fp32"))["components"]
    fixed, comp_info = fixed_components(role, rmeta, v, comps, src_meta, conf, tmp, log)
    out_dir = root / role / vname
    if out_dir.exists():
        shutil.rmtree(out_dir)
    out_dir.mkdir(parents=True)
    conv, configs, _ = convert_to_ort(list(fixed.values()), tmp / f"ort-{v}", styles=conf.styles,
                                      target_platform=conf.target_platform)
    components, parity = {}, {}
    for c, fx in fixed.items():
        paths = {}
        for s, pth in conv[fx].items():
            paths[s] = out_dir / (f"{c}.with_runtime_opt.ort" if s == "Runtime" else f"{c}.ort")
            shutil.copyfile(pth, paths[s])
        parity[c] = _component_parity(fx, paths, src_meta.get(c), rmeta, v, conf, f"{role}/{vname}")
        comp_info[c].update(_usability_entry(root, out_dir, c, fx, comp_info[c], paths, v, conf))
        usability.append(_usability_row(role, vname, c, comp_info[c]))
        components[c] = {"file": (paths.get("Fixed") or next(iter(paths.values()))).relative_to(root).as_posix(),
                         "format": "ort"}  # the .ort files already sit in out_dir
    notes = (f"ONNX Runtime Mobile ({ort.__version__}) .ort of {v}; fixed shapes per component in "
             f"android.components.*.fixed_shapes; use *.with_runtime_opt.ort with NNAPI/QNN")
    B.add_variant(root, role, vname, components, role_meta={}, precision=v, target="android", parity=parity,
                  notes=notes, extra={"android": {"source_variant": v if v in variants else f"{v} (derived from fp32)",
                                                  "ort_styles": list(conf.styles),
                                                  "target_platform": conf.target_platform,
                                                  "required_operators": _ops_to_json(_variant_ops(configs)),
                                                  "components": comp_info}})
    return _variant_summary(comp_info, parity)


def export_role(root: Path, bundle: Any, role: str, conf: AndroidConfig, log: Log,
                usability: list) -> dict[str, Any]:
    """Every source precision of one role; the role's `android` manifest entry. Returns {variants, skipped}."""
    rmeta = bundle.role_meta(role)
    role_sum: dict[str, Any] = {}
    with tempfile.TemporaryDirectory(prefix=f"mosaic-android-{role}-") as tmpd:
        tmp = Path(tmpd)
        made, skipped = source_graphs(root, rmeta, role, conf, tmp, log)
        for v, comps in made.items():
            role_sum[VARIANT_PREFIX + v] = export_variant(root, role, rmeta, v, comps, conf, tmp, log, usability)
    m = B.read_manifest(root)
    m["roles"][role]["android"] = {"variants": sorted(role_sum), "skipped": skipped}
    B.write_manifest(root, m)
    return {"variants": role_sum, "skipped": skipped}


def write_bundle_config(root: Path, conf: AndroidConfig, usability: list) -> dict[str, Any]:
    """One operator config for the whole bundle (every android variant recorded so far, also from earlier
    runs), the reduced-build line and the manifest's top-level `android` entry."""
    import onnxruntime as ort

    merged: dict[tuple[str, int], set[str]] = {}
    all_ort: list[str] = []
    m = B.read_manifest(root)
    for rm in m["roles"].values():
        for vm in rm["variants"].values():
            if vm.get("target") != "android":
                continue
            am = vm.get("android") or {}
            for k, ops in _ops_from_json(am.get("required_operators", {})).items():
                merged.setdefault(k, set()).update(ops)
            all_ort += [c["file"] for c in vm["components"].values()]
            all_ort += [c["runtime_opt"]["file"] for c in am.get("components", {}).values() if "runtime_opt" in c]
    cfg_path = write_operator_config(root / OPS_CONFIG, merged, sorted(set(all_ort)))
    cmd = build_command("$BUNDLE/" + OPS_CONFIG)
    m["android"] = {"onnxruntime_version": ort.__version__, "required_operators": _ref(root, cfg_path),
                    "build_command": cmd, "usability_summary": usability,
                    "nnapi_max_partitions": conf.nnapi_max_partitions, "not_checked": NOT_CHECKED,
                    "phone_runs": PHONE_RUNS}
    B.write_manifest(root, m)
    return {"required_operators": str(cfg_path), "build_command": cmd, "not_checked": NOT_CHECKED}


def export_android(bundle_dir: str | Path, conf: AndroidConfig | None = None,
                   log: Log = C.progress) -> dict[str, Any]:
    """Write the Android artifacts for every role (or `conf.roles`) of the bundle and record them in its
    manifest. Returns a summary {roles: {role: {variant: {...}}}, required_operators, build_command,
    usability: [...]}. Raises ExportError when a .ort file fails parity with its source graph."""
    conf = conf or AndroidConfig()
    root = Path(bundle_dir)
    bundle = B.load_bundle(root, verify=True)
    roles = list(conf.roles or bundle.roles)
    for r in roles:
        bundle.role_meta(r)  # clear error for an unknown role
    summary: dict[str, Any] = {"roles": {}, "usability": []}
    for role in roles:
        summary["roles"][role] = export_role(root, bundle, role, conf, log, summary["usability"])
    summary.update(write_bundle_config(root, conf, summary["usability"]))
    return summary


def _parity_brief(par: dict[str, Any]) -> Any:
    return {s: {"ok": p["ok"], "rel": p["worst"]["rel"], "cosine": p["worst"]["cosine"]} for s, p in par.items()}


def target_step(out: str | Path, roles: Sequence[str], args: argparse.Namespace) -> dict[str, Any]:
    """`mosaic export [ROLE] ... --target android` (export/cli.py TARGETS): --android-roles when given, else `roles`
    (the roles just exported, or every role of the bundle)."""
    return C.run_target_step(export_android, config_from_args(args), out, roles, render)


def render(result: dict[str, Any]) -> str:
    lines = [f"android artifacts in {result['bundle']}"]
    for role, r in result["roles"].items():
        for v, vm in r["variants"].items():
            for c, cm in vm["components"].items():
                par = cm["parity"]
                ptxt = ", ".join(f"{s} rel={p['rel']:.1e}" for s, p in par.items())
                lines.append(f"  {role}/{v}/{c}: NNAPI partitions={cm['nnapi_partitions']} "
                             f"providers={'>'.join(cm['providers'])} parity[{ptxt}]"
                             + (f" FLAGS: {'; '.join(f.split(':')[0] for f in cm['flags'])}" if cm["flags"] else ""))
        for v, why in r["skipped"].items():
            lines.append(f"  {role}/{v}: skipped ({why})")
    lines.append(f"required operators: {result['required_operators']}")
    lines.append(f"reduced build: {result['build_command']}")
    lines.append(result["not_checked"])
    return "\n".join(lines)
