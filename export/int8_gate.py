"""The int8 default-variant gate: an int8 variant becomes a role's default only when its accuracy on real data,
measured against the role's fp32 (benchmarks/int8_accuracy.py), stays within the role's tolerance.

The figures and the verdict are written into the variant (`accuracy_gate`), so the runtime can refuse it too:
a device profile asking for that variant runs the default instead, loudly (runtime/budget/profile.py).
"""
from __future__ import annotations

import os
from typing import Any

from mosaicthinker.host import bundle_write as B

# role -> (metric in the benchmark's `accuracy`, "min" | "max", bound, why this bound)
TOLERANCES: dict[str, dict[str, Any]] = {
    "detector": {"metric": "f1_vs_fp32", "op": "min", "bound": 0.90,
                 "why": "at most 1 in 10 of fp32's detections lost or added (same name, IoU >= 0.5)"},
    "depth": {"metric": "absrel_vs_fp32", "op": "max", "bound": 0.05,
              "why": "5 % mean relative change of the depth map: about half of PyDNet's own AbsRel against the "
                       "sensor after the per-frame fit"},
    "segmenter": {"metric": "miou_vs_fp32", "op": "min", "bound": 0.85,
                  "why": "class masks overlap fp32's at mIoU >= 0.85"},
    "matcher": {"metric": "median_err_deg_increase", "op": "max", "bound": 0.5,
                "why": "median rotation error of kitchen-pair edges grows by at most 0.5 deg"},
}


def gate(role: str, accuracy: dict[str, Any]) -> tuple[bool, str]:
    """(within tolerance, the sentence saying why) for a role's int8 accuracy figures."""
    tol = TOLERANCES.get(role)
    if tol is None:
        return False, f"no tolerance stated for {role}: int8 is never made its default"
    v = accuracy.get(tol["metric"])
    if v is None:
        return False, f"{tol['metric']} was not measured: int8 not made default"
    ok = v >= tol["bound"] if tol["op"] == "min" else v <= tol["bound"]
    sign = ">=" if tol["op"] == "min" else "<="
    return bool(ok), (f"{tol['metric']} = {v} {'meets' if ok else 'FAILS'} {sign} {tol['bound']} "
                      f"({tol['why']})")


def record_and_promote(bundle: str | os.PathLike, role: str, variant: str, row: dict[str, Any]) -> str:
    """Write the figures and the verdict into `roles.<role>.variants.<variant>.accuracy_gate`; make the variant
    the role's default when within tolerance, else keep (or restore) fp32. Returns the default variant."""
    m = B.read_manifest(bundle)
    rm = m["roles"][role]
    ok, why = gate(role, row["accuracy"])
    rm["variants"][variant]["accuracy_gate"] = {
        "within_tolerance": ok, "verdict": why, "accuracy": row["accuracy"],
        "speedup": row.get("speedup"), "measured_by": "benchmarks/int8_accuracy.py"}
    if ok:
        rm["default_variant"] = variant
    elif rm.get("default_variant") == variant:
        rm["default_variant"] = "fp32" if "fp32" in rm["variants"] else next(iter(rm["variants"]))
    B.write_manifest(bundle, m)
    return rm["default_variant"]


def refused(variant_meta: dict[str, Any]) -> str | None:
    """The recorded reason a variant failed its accuracy gate, or None (passed, or never measured)."""
    g = variant_meta.get("accuracy_gate") or {}
    return g.get("verdict") if g.get("within_tolerance") is False else None
