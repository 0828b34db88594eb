"""`mosaic bundle verify --target android`: per role, android variant and component, which provider of its chain
would run the graph and which ops each provider leaves to the CPU (`infra/ep_support.py`: onnxruntime's own
placement report where the provider is in this build, else the provider's op table; NNAPI from the export's
usability report on the fixed-shape graph)."""
from __future__ import annotations

from typing import Any

from ..infra.bundle import Bundle, safe_path
from ..infra.ep_support import provider_support
from ..infra.providers import available_providers

ANDROID_PROVIDERS = ("QNN", "NNAPI", "XNNPACK", "CPU")


def _nnapi_from_export(entry: dict[str, Any]) -> dict[str, Any] | None:
    n = entry.get("nnapi")
    if not n:
        return None
    return {"partitions": n["partitions"], "supported_pct": n["supported_pct"],
            "cpu_ops": [o.replace("ai.onnx:", "") for o in n.get("unsupported_ops", [])],
            "method": "onnxruntime mobile usability checker at export (fixed-shape graph)"}


def component_report(b: Bundle, rm: dict[str, Any], vm: dict[str, Any], c: str, avail: list[str]) -> dict[str, Any]:
    """Per provider of ANDROID_PROVIDERS: what it would run of component `c`; `would_run`: the first provider of
    the export's recommended chain for it."""
    am = vm["android"]["components"].get(c, {})
    src_v = str(vm["android"].get("source_variant", "fp32")).split(" ")[0]
    src_c = (am.get("kv_window") or {}).get("of_component", c)
    src = (rm["variants"].get(src_v) or rm["variants"].get("fp32") or {}).get("components", {}).get(src_c)
    if src is None or src.get("format") != "onnx":
        return {"note": f"no ONNX source graph for {c} in variant {src_v}: provider coverage not analysed"}
    path = safe_path(b.root, src["file"])
    per: dict[str, Any] = {}
    for p in ANDROID_PROVIDERS:
        per[p] = (_nnapi_from_export(am) if p == "NNAPI" else None) or provider_support(p, path, avail)
    if vm.get("precision") != "int8-qdq":
        per["QNN"]["note"] = ("float graph: the HTP runs it only in fp16 (enable_htp_fp16_precision=1); the "
                              "int8-qdq variant is the HTP's")
    chain = am.get("providers") or ["XNNPACK", "CPU"]
    first = chain[0]
    return {"source": src["file"], "chain": chain, "would_run": first, "cpu_ops": per[first].get("cpu_ops", []),
            "providers": per}


def android_report(b: Bundle) -> dict[str, Any]:
    """{role: {variant: {component: component_report}} | {"note": ...}} for every role of the bundle."""
    avail = available_providers()
    out: dict[str, Any] = {"available_here": avail, "roles": {}}
    for role in b.roles:
        rm = b.manifest["roles"][role]
        vs = {v: vm for v, vm in rm["variants"].items() if vm.get("target") == "android"}
        if not vs:
            out["roles"][role] = {"note": f"no android variant: mosaic export --target android "
                                          f"--android-roles {role} --out {b.root}"}
            continue
        out["roles"][role] = {v: {c: component_report(b, rm, vm, c, avail) for c in vm["components"]}
                              for v, vm in vs.items()}
    return out


def _support_text(name: str, s: dict[str, Any]) -> str:
    if "partitions" in s:
        head = f"{name} {s['supported_pct']}% in {s['partitions']} partition(s)"
    elif "supported_nodes" in s:
        head = f"{name} {s['supported_nodes']}/{s['nodes']} nodes"
    else:
        return f"{name} ?"
    return head + (f" (CPU: {', '.join(s['cpu_ops'])})" if s.get("cpu_ops") else "")


def render_android(rep: dict[str, Any]) -> str:
    lines = [f"android providers per role (onnxruntime here has {', '.join(rep['available_here'])}; the others "
             f"from their op tables, see docs/deployment.md):"]
    for role, r in rep["roles"].items():
        if "note" in r:
            lines.append(f"  {role}: {r['note']}")
            continue
        for v, comps in r.items():
            for c, cr in comps.items():
                if "note" in cr:
                    lines.append(f"  {role}/{v}/{c}: {cr['note']}")
                    continue
                cpu = ", ".join(cr["cpu_ops"]) or "none"
                lines.append(f"  {role}/{v}/{c}: would run on {cr['would_run']} (chain {'>'.join(cr['chain'])}); "
                             f"ops to CPU: {cpu}")
                lines.append("      " + "; ".join(_support_text(p, s) for p, s in cr["providers"].items()))
    return "\n".join(lines)
