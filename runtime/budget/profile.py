"""Device profiles (`profiles/*.toml`): the schema, its validation (`parse_profile`, `load_profile`) and the
write-back of measured costs (`update_profile_costs`). Also the bundle-variant choice a profile implies
(`nearest_variant`: used by both the planner and the model loading, so it lives with the profile).

Profile file (schema ``mosaicthinker.profile/1``), every key carries its unit::

    schema = "mosaicthinker.profile/1"
    [device]   name, description, soc, os, ram_mb, accelerator, notes
    [budget]   latency_budget_ms (per question), memory_budget_mb (this process' RSS)
    [runtime]  providers (ordered chain, must end with CPUExecutionProvider), intra_op_threads,
               inter_op_threads, core_affinity (CPU ids), notes
    [roles.<role>]   precision (fp32|fp16|int8), int8_kind (dynamic|qdq, int8 only), variant (bundle variant),
                     providers (override of the runtime chain), input_size_px ([W, H]), notes
    [costs.<item>]   ms_per_call / ms_per_prompt / ms_per_pair / ms_per_image / ms_per_token / load_ms /
                     resident_mb / mb_per_call (what the item has, see COST_ITEMS), and its provenance:
                     status = "measured" (+ date, bundle_hash: written by `mosaic profile --update-profile`)
                     or "estimated" (+ source: where the figure comes from). Optional: provider, note,
                     variant (the bundle variant the figures are for, e.g. "fp32").
    [paper_costs.<item>]  the same for the paper's models; a model item may add
                     [paper_costs.<item>.variants.<variant>] (the same numeric fields + note, the parent's
                     provenance) measured at another precision: the profile's [roles.<item>] precision picks one
                     (`nearest_variant`, the rule the model loading follows), so plan and run cost the same model.
"""
from __future__ import annotations

import datetime as _dt
import json
import math
import os
import sys
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any, Mapping, Sequence

from ..infra.bundle import ROLES as BUNDLE_ROLES
from ..infra.bundle import load_bundle
from ..infra import jsonio
from ..infra.errors import ProfileError, path_kind
from ..infra.numbers import read_number
from ..infra.file_schemas import profile_spec
from ..infra.schema import check
from ..infra.trace import Trace, as_trace
import psutil

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - python 3.10
    import tomli as tomllib

PROFILE_SCHEMA = "mosaicthinker.profile/1"
ROLES = BUNDLE_ROLES  # the model roles have one home: the bundle
PRECISIONS = ("fp32", "fp16", "int8")
INT8_KINDS = ("dynamic", "qdq")
KNOWN_PROVIDERS = (
    "TensorrtExecutionProvider", "CUDAExecutionProvider", "QNNExecutionProvider", "NnapiExecutionProvider",
    "XnnpackExecutionProvider", "CoreMLExecutionProvider", "ROCMExecutionProvider", "MIGraphXExecutionProvider",
    "OpenVINOExecutionProvider", "DmlExecutionProvider", "ACLExecutionProvider", "ArmNNExecutionProvider",
    "WebGpuExecutionProvider", "CPUExecutionProvider",
)
# Providers that run dynamic-quantised int8 ops (DynamicQuantizeLinear / MatMulInteger); accelerators want QDQ.
CPU_LIKE_PROVIDERS = ("CPUExecutionProvider", "XnnpackExecutionProvider")
ROOT_PROFILES = Path(__file__).resolve().parents[2] / "profiles"

# --------------------------------------------------------------------------------------------- profile schema

# cost item -> (numeric fields it may carry, what one "call" is); the planner's arithmetic uses exactly these.
COST_ITEMS: dict[str, tuple[tuple[str, ...], str]] = {
    "process": (("resident_mb",), "runtime baseline: Python, numpy, OpenCV, onnxruntime, frame cache"),
    "video_decode": (("ms_per_call",), "per frame fetched again later (a scored frame, a key frame): one decode"),
    "dedup": (("ms_per_call",), "per video frame: the redundant-frame-removal pass over the clip (down-sampling, "
                                "ORB tracking, SSIM), including the decoding it does"),
    "grounding": (("ms_per_call",), "per question: question -> target and cue objects"),
    "detector": (("ms_per_call", "load_ms", "resident_mb"), "per scored frame (key frames reuse these boxes)"),
    "segmenter": (("ms_per_call", "ms_per_prompt", "load_ms", "resident_mb"),
                  "per key frame (image encoder) + per prompt (prompt decoder)"),
    "instance_segmenter": (("ms_per_call", "load_ms", "resident_mb"),
                           "per key frame: detections with one mask each (the adapter's whole call)"),
    "depth": (("ms_per_call", "load_ms", "resident_mb"), "per key frame"),
    "embedder": (("ms_per_call", "load_ms", "resident_mb"), "per key frame (frame similarity for the tree)"),
    "matcher": (("ms_per_call", "ms_per_pair", "load_ms", "resident_mb"),
                "per key frame (features) + per matched pair"),
    "geometry": (("ms_per_call",), "per key frame: RANSAC on its tree edge, spanning tree, fusion into the map"),
    "refine": (("ms_per_call",), "per key frame: occlusion refinement (project the map, re-segment what is "
                                 "missing)"),
    "keyframe_state": (("mb_per_call",), "MB held per key frame (image, depth, masks, features)"),
    "vlm": (("ms_per_image", "ms_per_token", "load_ms", "resident_mb"),
            "per image (vision encoder + prefill of its tokens) and per generated token"),
}
REQUIRED_COSTS = ("process", "video_decode", "dedup", "grounding", "detector", "depth", "matcher", "geometry",
                  "keyframe_state")
# roles whose cost entry is optional: absent -> the role is not used on this device (no VLM = map reasoner)
OPTIONAL_ROLE_COSTS = ("segmenter", "instance_segmenter", "embedder", "vlm")
MODEL_COSTS = ("detector", "instance_segmenter", "segmenter", "depth", "embedder", "matcher", "vlm")
PROVENANCE_KEYS = ("status", "date", "bundle_hash", "source", "provider", "note")
VARIANT_KEYS = ("variant", "variants")  # a [paper_costs] model item measured at more than one precision

_SECTIONS: dict[str, dict[str, type | tuple[type, ...]]] = {
    "device": {"name": str, "description": str, "soc": str, "os": str, "ram_mb": (int, float),
               "accelerator": str, "notes": str},
    "budget": {"latency_budget_ms": (int, float), "memory_budget_mb": (int, float)},
    "runtime": {"providers": list, "intra_op_threads": int, "inter_op_threads": int, "core_affinity": list,
                "notes": str},
}
_REQUIRED = {"device": ("name",), "budget": ("latency_budget_ms", "memory_budget_mb"), "runtime": ("providers",)}
_ROLE_KEYS: dict[str, type | tuple[type, ...]] = {"precision": str, "int8_kind": str, "variant": str,
                                                  "providers": list, "input_size_px": list, "notes": str}
_TOP_KEYS = ("schema", "device", "budget", "runtime", "roles", "costs", "paper_costs")
# model sets `mosaic plan --models` can plan with: the shared mobile models ([costs.*]) or the paper's models at
# their real sizes ([paper_costs.*]: measured by benchmarks/paper_models.py with random weights)
MODEL_SETS = ("shared", "paper")
# unit spellings that are NOT the project's (keys carry ms / mb): used to say "wrong unit" instead of "unknown key"
_TIME_UNITS = ("s", "sec", "secs", "second", "seconds", "us", "ns", "min", "minutes", "millis", "msec")
_MEM_UNITS = ("b", "bytes", "kb", "kib", "gb", "gib", "mib", "megabytes", "kilobytes", "gigabytes")


@dataclass
class CostEntry:
    """One `[costs.<name>]` table. Times in ms, memory in MB; None = the item does not have that cost."""

    name: str
    status: str
    ms_per_call: float | None = None
    ms_per_prompt: float | None = None
    ms_per_pair: float | None = None
    ms_per_image: float | None = None
    ms_per_token: float | None = None
    load_ms: float | None = None
    resident_mb: float | None = None
    mb_per_call: float | None = None
    date: str | None = None
    bundle_hash: str | None = None
    source: str | None = None
    provider: str | None = None
    note: str | None = None
    variant: str | None = None   # the bundle variant these figures are for (None: not said)
    variants: dict[str, "CostEntry"] = field(default_factory=dict)  # the same item at other precisions

    def get(self, key: str) -> float:
        v = getattr(self, key)
        return 0.0 if v is None else float(v)

    def provenance(self) -> str:
        of = f" [{self.variant}]" if self.variant else ""
        if self.status == "measured":
            return f"measured {self.date} bundle {self.bundle_hash}{of}"
        return f"estimated ({self.source}){of}"

    def for_variant(self, want: str) -> "CostEntry":
        """The figures of the variant nearest `want` (`nearest_variant`: the model loading's rule) among this
        entry's own and its `variants`; itself when it has no variants or none matches."""
        if not self.variants:
            return self
        own = {self.variant: self} if self.variant else {}
        options = {**own, **self.variants}
        got = nearest_variant(want, {name: {} for name in options})
        return options[got] if got else self

    def to_dict(self) -> dict[str, Any]:
        d = {k: v for k, v in asdict(self).items() if v is not None and k not in ("name", "variants")}
        if self.variants:
            d["variants"] = {n: e.to_dict() for n, e in self.variants.items()}
        return d


# When a bundle lacks the profile's precision for a role, the closest one it has, in this order: an accelerator's
# int8 QDQ falls back to dynamic int8 (same arithmetic, CPU kernels), then fp16, then fp32; fp16 to fp32 first.
NEAREST_PRECISION = {"int8-qdq": ("int8-qdq", "int8-dynamic", "fp16", "fp32"),
                     "int8-dynamic": ("int8-dynamic", "int8-qdq", "fp32", "fp16"),
                     "fp16": ("fp16", "fp32", "int8-qdq", "int8-dynamic"),
                     "fp32": ("fp32", "fp16", "int8-dynamic", "int8-qdq")}


def nearest_variant(want: str, variants: dict[str, Any]) -> str | None:
    """The variant name to run for a requested one: `want` itself, else the variant whose precision is nearest
    (NEAREST_PRECISION; a variant's `precision` field, so `android-ort-int8-qdq` counts as int8-qdq, exact names
    first). None when nothing matches (an unknown variant name: the bundle's default). A variant that is another
    model for the role (`overrides`, e.g. the SSD beside YOLOX) is run only when named exactly."""
    if want in variants:
        return want
    variants = {n: vm for n, vm in variants.items() if not (vm or {}).get("overrides")}
    order = NEAREST_PRECISION.get(want)
    if order is None:  # a variant named by the profile, e.g. android-ort-fp16: match its precision suffix
        order = next((v for k, v in NEAREST_PRECISION.items() if want.endswith(k)), ())
    for prec in order:
        names = sorted((n for n, vm in variants.items() if (vm or {}).get("precision") == prec or n == prec),
                       key=lambda n: (n != prec, n))
        if names:
            return names[0]
    return None


@dataclass
class RoleSettings:
    """`[roles.<role>]`: precision and int8 kind, bundle variant, provider override, input size."""

    role: str
    precision: str = "fp32"
    int8_kind: str | None = None
    variant: str | None = None
    providers: list[str] | None = None
    input_size_px: tuple[int, int] | None = None  # (W, H)
    notes: str | None = None

    @property
    def bundle_variant(self) -> str:
        """The bundle variant this precision maps to (fp32 | fp16 | int8-dynamic | int8-qdq) unless named."""
        if self.variant:
            return self.variant
        return f"int8-{self.int8_kind}" if self.precision == "int8" else self.precision


@dataclass
class Profile:
    """A validated device profile. Build with `load_profile(path)` (or `parse_profile(dict)`)."""

    name: str
    path: Path | None
    latency_budget_ms: float
    memory_budget_mb: float
    providers: list[str]
    intra_op_threads: int | None = None
    inter_op_threads: int | None = None
    core_affinity: list[int] | None = None
    device: dict[str, Any] = field(default_factory=dict)
    runtime_notes: str | None = None
    roles: dict[str, RoleSettings] = field(default_factory=dict)
    costs: dict[str, CostEntry] = field(default_factory=dict)
    paper_costs: dict[str, CostEntry] = field(default_factory=dict)
    raw: dict[str, Any] = field(default_factory=dict)

    def with_models(self, models: str) -> "Profile":
        """This profile with the model costs of `models` ("shared": [costs.*] as written; "paper": each model
        item [paper_costs.<item>] replaces [costs.<item>]; items it lacks keep the shared figure, named)."""
        if models not in MODEL_SETS:
            raise ProfileError(f"`models={models}`: choose one of {MODEL_SETS}", fields=("models",))
        if models == "shared":
            return self
        if not self.paper_costs:
            raise ProfileError(f"{self.path or self.name}: no [paper_costs.*] tables; measure them with "
                               f"benchmarks/paper_models.py or plan with `models=shared`", fields=("models",))
        picked = {k: e.for_variant(self.role(k).bundle_variant) for k, e in self.paper_costs.items()}
        return replace(self, costs={**self.costs, **picked})

    def providers_for(self, role: str) -> list[str]:
        """Ordered provider chain for a role (role override, else the device chain); always ends on CPU."""
        rs = self.roles.get(role)
        return list(rs.providers) if rs and rs.providers else list(self.providers)

    def session_options(self, role: str) -> dict[str, Any]:
        """Keyword arguments for providers.create_session: providers, intra_op_threads, inter_op_threads."""
        return {"providers": self.providers_for(role), "intra_op_threads": self.intra_op_threads,
                "inter_op_threads": self.inter_op_threads}

    def role(self, role: str) -> RoleSettings:
        return self.roles.get(role) or RoleSettings(role)

    def variant_in(self, role: str, bundle: Any, trace: Trace | None = None) -> str | None:
        """The bundle variant that runs `role` under this profile: the profile's own if the bundle has it, else
        the nearest precision the bundle has (NEAREST_PRECISION, recorded as a "degraded" event that `ask` prints);
        None when the profile does not set the role or the bundle lacks it (= the bundle's default variant)."""
        if role not in self.roles:
            return None

        b = load_bundle(bundle, verify=False) if not hasattr(bundle, "role_meta") else bundle
        if not b.has_role(role):
            return None
        got = nearest_variant(self.roles[role].bundle_variant, b.role_meta(role).get("variants", {}))
        want = self.roles[role].bundle_variant
        gate = (b.role_meta(role)["variants"].get(got) or {}).get("accuracy_gate") or {} if got else {}
        if gate.get("within_tolerance") is False:  # benchmarks/int8_accuracy.py measured it out of tolerance
            used = b.variant_name(role)
            as_trace(trace).event("degraded", f"profile {self.name} asks for {role} {got!r}, which failed its "
                                  f"accuracy gate on real data ({gate.get('verdict')}): running {used!r}",
                                  stage=role, requested=got, used=used)
            return used
        if got != want:
            used = got or b.role_meta(role).get("default_variant")
            as_trace(trace).event("degraded", f"profile {self.name} asks for {role} {want!r}, which the bundle "
                                  f"does not have: running its {'nearest' if got else 'default'} variant {used!r}",
                                  stage=role, requested=want, used=used)
        return got

    def cost(self, name: str) -> CostEntry | None:
        return self.costs.get(name)

    def uses(self, role: str) -> bool:
        return role in self.costs

    def apply_to_machine(self, trace: Trace | None = None) -> None:
        """Fit the runtime settings to this machine before any session is made: pin to `core_affinity`
        (refused loudly where impossible) and lower thread counts above the usable cores (recorded)."""
        trace = as_trace(trace)
        self.apply_affinity(trace)
        try:
            cores = len(os.sched_getaffinity(0))
        except (AttributeError, OSError):
            cores = os.cpu_count() or 1
        for k in ("intra_op_threads", "inter_op_threads"):
            n = getattr(self, k)
            if n and n > cores:
                setattr(self, k, cores)
                trace.event("degraded", f"profile {self.name}: runtime.{k} = {n} but this machine has {cores} "
                            f"usable cores; using {cores}", stage="budget")

    def apply_affinity(self, trace: Trace | None = None) -> list[int] | None:
        """Pin this process to `core_affinity` where the OS allows it (Linux, Android); recorded in the trace."""
        if not self.core_affinity:
            return None

        trace = as_trace(trace)
        proc = psutil.Process()
        try:
            avail = set(range(psutil.cpu_count() or 1))
            cores = [c for c in self.core_affinity if c in avail]
            if not cores:
                raise OSError(f"none of the cores {self.core_affinity} exist here ({sorted(avail)})")
            proc.cpu_affinity(cores)
            trace.decide("budget.core_affinity", cores)
            return cores
        except (AttributeError, OSError, ValueError) as e:  # macOS has no cpu_affinity
            trace.event("degraded", f"profile {self.name}: core_affinity {self.core_affinity} not applied ({e})",
                        warn=True)
            return None


MAX_THREADS = 256         # no edge device has more cores; larger values are typos (100000 took 10 GB)


def _where(path: Path | None) -> str:
    return str(path) if path else "<profile>"


def _unit_hint(key: str, known: Sequence[str]) -> str | None:
    """If `key` is a known key spelt with another unit (latency_budget_s, memory_budget_gb, s_per_call ...),
    return the right key."""
    parts = key.lower().split("_")
    for i, p in enumerate(parts):
        for units, right in ((_TIME_UNITS, "ms"), (_MEM_UNITS, "mb")):
            if p in units:
                cand = "_".join(parts[:i] + [right] + parts[i + 1:])
                if cand in known:
                    return cand
    stems = {k.rsplit("_", 1)[0]: k for k in known if k.endswith(("_ms", "_mb"))}
    if key in stems:  # unit left out entirely: latency_budget
        return stems[key]
    return None


def _check_keys(table: Mapping[str, Any], known: Sequence[str], where: str) -> None:
    for k in table:
        if k in known:
            continue
        hint = _unit_hint(k, known)
        if hint:
            raise ProfileError(f"{where}: key {k!r} has the wrong unit; this project writes it as {hint!r} "
                               f"(convert the value)")
        raise ProfileError(f"{where}: unknown key {k!r}; known keys: {', '.join(known)}")


def _check_number(v: Any, where: str, *, integer: bool = False, positive: bool = False) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        unit = "ms" if where.endswith("_ms") or "_ms_" in where or ".ms_" in where else \
            "MB" if where.endswith("_mb") or ".mb_" in where else ""
        raise ProfileError(f"{where}: expected a number{' in ' + unit if unit else ''}, got {v!r} "
                           f"(write the bare number; the unit is in the key name)")
    if integer and not isinstance(v, int):
        raise ProfileError(f"{where}: expected an integer, got {v!r}")
    if positive and v == 0:
        raise ProfileError(f"{where}: must be > 0, got {v!r}")
    return float(read_number(v, where, lo=0, integer=integer, error=ProfileError,  # finite, >= 0, any length
                             fix="budgets and costs are finite numbers >= 0"))


def _check_providers(chain: Any, where: str) -> list[str]:
    if not isinstance(chain, list) or not chain or not all(isinstance(p, str) for p in chain):
        raise ProfileError(f"{where}: expected a non-empty list of onnxruntime provider names")
    for p in chain:
        if p not in KNOWN_PROVIDERS:
            raise ProfileError(f"{where}: unknown execution provider {p!r}; known: {', '.join(KNOWN_PROVIDERS)}")
    if chain[-1] != "CPUExecutionProvider":
        raise ProfileError(f"{where}: the chain must end with 'CPUExecutionProvider' so that fallback always has "
                           f"somewhere to go (got {chain})")
    if len(set(chain)) != len(chain):
        raise ProfileError(f"{where}: provider listed twice in {chain}")
    return list(chain)


def _parse_costs(raw_costs: Mapping[str, Any], w: str, table: str) -> dict[str, CostEntry]:
    """The `[<table>.<item>]` cost tables of a profile (same fields and checks for costs and paper_costs)."""
    costs: dict[str, CostEntry] = {}
    for name, ct in raw_costs.items():
        cw = f"{w}: {table}.{name}"
        if name not in COST_ITEMS:
            raise ProfileError(f"{cw}: unknown cost item {name!r}; items are {', '.join(COST_ITEMS)}")
        if not isinstance(ct, Mapping):
            raise ProfileError(f"{cw}: expected a table")
        nums, _ = COST_ITEMS[name]
        _check_keys(ct, nums + PROVENANCE_KEYS + (VARIANT_KEYS if table == "paper_costs" else ()), cw)
        vals: dict[str, Any] = {}
        for k in nums:
            if k not in ct:
                raise ProfileError(f"{cw}: missing field {k!r} ({COST_ITEMS[name][1]})")
            vals[k] = _check_number(ct[k], f"{cw}.{k}")
        status = ct.get("status")
        if status not in ("measured", "estimated"):
            raise ProfileError(f"{cw}.status: must be 'measured' (by `mosaic profile`) or 'estimated' "
                               f"(with a source); got {status!r}")
        for k in ("date", "bundle_hash", "source", "provider", "note"):
            if k in ct and not isinstance(ct[k], str):
                raise ProfileError(f"{cw}.{k}: expected a string, got {ct[k]!r}")
        if status == "measured":
            for k in ("date", "bundle_hash"):
                if not ct.get(k):
                    raise ProfileError(f"{cw}: status 'measured' needs {k!r} (written by mosaic profile "
                                       f"--update-profile)")
            try:
                _dt.date.fromisoformat(ct["date"][:10])
            except ValueError:
                raise ProfileError(f"{cw}.date: {ct['date']!r} is not an ISO date (YYYY-MM-DD)") from None
        elif not ct.get("source"):
            raise ProfileError(f"{cw}: status 'estimated' needs 'source' (where the figure comes from)")
        costs[name] = CostEntry(name, status, **vals, **{k: ct.get(k) for k in
                                                         ("date", "bundle_hash", "source", "provider", "note")})
        _parse_variants(costs[name], ct, cw)
    return costs


def _parse_variants(entry: CostEntry, ct: Mapping[str, Any], cw: str) -> None:
    """`variant` (str) and [<table>.<item>.variants.<name>] of a cost entry: each variant has the item's numeric
    fields (+ an optional note) and takes the parent's provenance."""
    if "variant" in ct and not (isinstance(ct["variant"], str) and ct["variant"]):
        raise ProfileError(f"{cw}.variant: expected a bundle variant name such as 'fp32', got {ct['variant']!r}")
    entry.variant = ct.get("variant")
    raw = ct.get("variants", {})
    if not isinstance(raw, Mapping):
        raise ProfileError(f"{cw}.variants: expected tables [..variants.<name>] (e.g. variants.int8-dynamic)")
    if raw and (entry.name not in MODEL_COSTS or not entry.variant):
        raise ProfileError(f"{cw}.variants: only a model item that names its own `variant` may list others")
    nums = COST_ITEMS[entry.name][0]
    for vname, vt in raw.items():
        vw = f"{cw}.variants.{vname}"
        if vname == entry.variant or not isinstance(vt, Mapping):
            raise ProfileError(f"{vw}: expected a table for a variant other than the entry's own "
                               f"({entry.variant!r})")
        _check_keys(vt, nums + ("note",), vw)
        missing = [k for k in nums if k not in vt]
        if missing:
            raise ProfileError(f"{vw}: missing field(s) {', '.join(missing)} ({COST_ITEMS[entry.name][1]})")
        if "note" in vt and not isinstance(vt["note"], str):
            raise ProfileError(f"{vw}.note: expected a string, got {vt['note']!r}")
        vals = {k: _check_number(vt[k], f"{vw}.{k}") for k in nums}
        entry.variants[vname] = replace(entry, **vals, note=vt.get("note", entry.note), variant=vname,
                                        variants={})


def _check_sections(data: Mapping[str, Any], w: str) -> None:
    """Top-level keys, schema, and the [device] / [budget] / [runtime] tables: known keys, required fields, types."""
    if not isinstance(data, Mapping):
        raise ProfileError(f"{w}: expected a TOML table at top level")
    _check_keys(data, _TOP_KEYS, w)
    if data.get("schema") != PROFILE_SCHEMA:
        raise ProfileError(f"{w}: field 'schema' is {data.get('schema')!r}; expected {PROFILE_SCHEMA!r}")
    for sec, req in _REQUIRED.items():
        if sec not in data or not isinstance(data[sec], Mapping):
            raise ProfileError(f"{w}: missing table [{sec}]")
        _check_keys(data[sec], tuple(_SECTIONS[sec]), f"{w}: [{sec}]")
        for k in req:
            if k not in data[sec]:
                raise ProfileError(f"{w}: [{sec}] is missing the required field {k!r}")
        for k, v in data[sec].items():
            t = _SECTIONS[sec][k]
            if t in ((int, float), int):
                _check_number(v, f"{w}: {sec}.{k}", integer=t is int)
            elif not isinstance(v, t):
                raise ProfileError(f"{w}: {sec}.{k}: expected {t.__name__}, got {type(v).__name__} {v!r}")


def _check_runtime(rt: Mapping[str, Any], w: str) -> tuple[list[str], list[int] | None]:
    """[runtime]: the provider chain, thread counts and core affinity. Returns (chain, core_affinity)."""
    chain = _check_providers(rt["providers"], f"{w}: runtime.providers")
    for k in ("intra_op_threads", "inter_op_threads"):
        if k in rt and not 1 <= rt[k] <= MAX_THREADS:  # 100000 threads grew to 10 GB before failing
            raise ProfileError(f"{w}: runtime.{k} must be 1..{MAX_THREADS} (got {rt[k]}); use the device's core "
                               f"count")
    aff = rt.get("core_affinity")
    if aff is not None and (not aff or not all(isinstance(c, int) and not isinstance(c, bool) and c >= 0
                                               for c in aff)):
        raise ProfileError(f"{w}: runtime.core_affinity must be a non-empty list of CPU ids >= 0 (got {aff!r})")
    if aff is not None and (len(set(aff)) != len(aff) or max(aff) >= MAX_THREADS):
        raise ProfileError(f"{w}: runtime.core_affinity has repeated or impossible CPU ids (got {aff!r})")
    return chain, aff


def _parse_role(role: str, rt_: Any, chain: list[str], w: str) -> RoleSettings:
    """One [roles.<role>] table: precision and int8 kind (and whether the first provider can run it), providers,
    input size."""
    rw = f"{w}: roles.{role}"
    if role not in ROLES:
        raise ProfileError(f"{rw}: unknown role {role!r}; roles are {', '.join(ROLES)}")
    if not isinstance(rt_, Mapping):
        raise ProfileError(f"{rw}: expected a table")
    _check_keys(rt_, tuple(_ROLE_KEYS), rw)
    prec = rt_.get("precision", "fp32")
    if prec not in PRECISIONS:
        raise ProfileError(f"{rw}.precision: {prec!r} is not one of {PRECISIONS}")
    kind = rt_.get("int8_kind")
    if prec == "int8" and kind not in INT8_KINDS:
        raise ProfileError(f"{rw}.int8_kind: precision int8 needs int8_kind = one of {INT8_KINDS} "
                           f"(dynamic for CPU, qdq for accelerators); got {kind!r}")
    if prec != "int8" and kind is not None:
        raise ProfileError(f"{rw}.int8_kind: only meaningful with precision = 'int8' (precision is {prec!r})")
    provs = _check_providers(rt_["providers"], f"{rw}.providers") if "providers" in rt_ else None
    if prec == "int8" and kind == "dynamic" and (provs or chain)[0] not in CPU_LIKE_PROVIDERS:
        raise ProfileError(f"{rw}: int8_kind 'dynamic' (DynamicQuantizeLinear/MatMulInteger) runs on CPU only, "
                           f"but the first provider is {(provs or chain)[0]}; use int8_kind = 'qdq' for "
                           f"accelerators or give the role a CPU provider chain")
    size = rt_.get("input_size_px")
    if size is not None:
        if (not isinstance(size, list) or len(size) != 2
                or not all(isinstance(s, int) and not isinstance(s, bool) and s > 0 for s in size)):
            raise ProfileError(f"{rw}.input_size_px: expected [width, height] positive integers, got {size!r}")
        size = (int(size[0]), int(size[1]))
    for k in ("variant", "notes"):
        if k in rt_ and not isinstance(rt_[k], str):
            raise ProfileError(f"{rw}.{k}: expected a string")
    return RoleSettings(role, prec, kind, rt_.get("variant"), provs, size, rt_.get("notes"))


def _parse_cost_tables(data: Mapping[str, Any], w: str) -> tuple[dict[str, CostEntry], dict[str, CostEntry]]:
    """[costs.*] (the required items present) and [paper_costs.*]."""
    raw_costs = data.get("costs")
    if not isinstance(raw_costs, Mapping):
        raise ProfileError(f"{w}: missing table [costs] (per-stage costs: [costs.detector] ms_per_call = ...)")
    costs = _parse_costs(raw_costs, w, "costs")
    raw_paper = data.get("paper_costs", {})
    if not isinstance(raw_paper, Mapping):
        raise ProfileError(f"{w}: paper_costs: expected a table of [paper_costs.<item>] tables")
    paper_costs = _parse_costs(raw_paper, w, "paper_costs")
    for name in REQUIRED_COSTS:
        if name not in costs:
            raise ProfileError(f"{w}: missing cost table [costs.{name}] ({COST_ITEMS[name][1]})")
    return costs, paper_costs


def _unknown_key(key: str, known: tuple[str, ...]) -> str:
    hint = _unit_hint(key, known)
    if hint:
        return f"key {key!r} has the wrong unit; this project writes it as {hint!r} (convert the value)"
    return f"has an unknown key {key!r}; known keys: {', '.join(known)}"


def _spec() -> Any:
    return profile_spec(COST_ITEMS, ROLES, PRECISIONS, INT8_KINDS, KNOWN_PROVIDERS, MAX_THREADS, _unknown_key)


def parse_profile(data: Mapping[str, Any], path: str | os.PathLike | None = None) -> Profile:
    """Validate a profile dict (as read from TOML) and build a Profile. Raises ProfileError naming the
    file and field: unknown key, wrong unit, negative or non-numeric value, missing field, bad provider.
    Types, ranges and enums come from the schema (`file_schemas.profile_spec`); what fields mean together
    (a chain ending on CPU, int8 kinds, provenance) is checked below."""
    path = Path(path) if path else None
    w = _where(path)
    if isinstance(data, Mapping) and data.get("schema") != PROFILE_SCHEMA:
        raise ProfileError(f"{w}: field 'schema' is {data.get('schema')!r}; expected {PROFILE_SCHEMA!r}")
    check(dict(data) if isinstance(data, Mapping) else data, _spec(), where=w, error=ProfileError,
          fix="fix the profile (docs/budgets.md lists its fields)")
    _check_sections(data, w)
    bud = data["budget"]
    lat = _check_number(bud["latency_budget_ms"], f"{w}: budget.latency_budget_ms", positive=True)
    mem = _check_number(bud["memory_budget_mb"], f"{w}: budget.memory_budget_mb", positive=True)
    rt = data["runtime"]
    chain, aff = _check_runtime(rt, w)
    roles = {role: _parse_role(role, rt_, chain, w) for role, rt_ in (data.get("roles") or {}).items()}
    costs, paper_costs = _parse_cost_tables(data, w)
    dev = dict(data["device"])
    return Profile(name=dev["name"], path=path, latency_budget_ms=lat, memory_budget_mb=mem, providers=chain,
                   intra_op_threads=rt.get("intra_op_threads"), inter_op_threads=rt.get("inter_op_threads"),
                   core_affinity=list(aff) if aff else None, device=dev, runtime_notes=rt.get("notes"),
                   roles=roles, costs=costs, paper_costs=paper_costs, raw=jsonio.plain(data))


def resolve_profile_path(name_or_path: str | os.PathLike) -> Path:
    """A file path, or a bare profile name looked up in the repository's profiles/ folder."""
    p = Path(name_or_path)
    if p.is_file():
        return p
    if os.path.lexists(p) or os.sep in str(name_or_path) or str(name_or_path).endswith(".toml"):
        kind = path_kind(p)
        if kind != "missing":
            raise ProfileError(f"{p}: the profile is {kind}; give a profile file (profiles/*.toml)")
    for cand in (ROOT_PROFILES / f"{name_or_path}.toml", ROOT_PROFILES / str(name_or_path)):
        if cand.is_file():
            return cand
    avail = ", ".join(sorted(q.stem for q in ROOT_PROFILES.glob("*.toml"))) if ROOT_PROFILES.is_dir() else "none"
    raise ProfileError(f"{name_or_path}: no such profile file (profiles in {ROOT_PROFILES}: {avail})")


def load_profile(name_or_path: str | os.PathLike) -> Profile:
    """Read and validate a profile TOML (a path, or a name from profiles/ such as 'cpu-generic')."""
    path = resolve_profile_path(name_or_path)
    try:
        with open(path, "rb") as f:
            data = tomllib.load(f)
    except tomllib.TOMLDecodeError as e:
        raise ProfileError(f"{path}: not valid TOML ({e})") from e
    except UnicodeDecodeError as e:
        raise ProfileError(f"{path}: not UTF-8 text ({e.reason} at byte {e.start}); save the profile as UTF-8") from e
    except RecursionError as e:
        raise ProfileError(f"{path}: tables or arrays nested too deeply to read; a profile is two levels deep") from e
    except OSError as e:
        raise ProfileError(f"{path}: cannot read the profile ({e.strerror})") from e
    return parse_profile(data, path)


def list_profiles() -> list[Path]:
    return sorted(ROOT_PROFILES.glob("*.toml"))


def update_profile_costs(path: str | os.PathLike, measured: Mapping[str, Mapping[str, float]], *,
                         bundle_hash_: str, date: str | None = None, providers: Mapping[str, str] | None = None,
                         notes: Mapping[str, str] | None = None) -> dict[str, Any]:
    """Write measured costs back into a profile TOML (tomli_w). `measured`: item -> {field: value}; each item
    touched becomes status "measured" with `date` and `bundle_hash`; its old `source` is dropped. Fields not
    measured keep their value (and the item's note says which were kept from the estimate). The result is
    re-validated before it is written. Returns the new raw dict."""
    import tomli_w

    path = Path(path)
    with open(path, "rb") as f:
        data = tomllib.load(f)
    date = date or _dt.date.today().isoformat()
    costs = data.setdefault("costs", {})
    for item, vals in measured.items():
        if item not in COST_ITEMS:
            raise ProfileError(f"update_profile_costs: unknown cost item {item!r}")
        entry = costs.setdefault(item, {})
        nums = COST_ITEMS[item][0]
        kept = [k for k in nums if k not in vals]
        for k, v in vals.items():
            if k not in nums:
                raise ProfileError(f"update_profile_costs: {item} has no field {k!r} (has {nums})")
            entry[k] = round(float(v), 3)
        for k in kept:
            entry.setdefault(k, 0.0)
        prev_source = entry.pop("source", None)
        entry["status"] = "measured"
        entry["date"] = date
        entry["bundle_hash"] = bundle_hash_
        if providers and item in providers:
            entry["provider"] = providers[item]
        entry.pop("note", None)
        parts = [notes[item]] if notes and item in notes else []
        if kept:
            parts.append(f"{', '.join(kept)} kept from the previous value (not measured by mosaic profile)"
                         + (f"; previous source: {prev_source}" if prev_source else ""))
        if parts:
            entry["note"] = "; ".join(parts)
    parse_profile(data, path)  # never write an invalid profile
    with open(path, "wb") as f:
        tomli_w.dump(data, f)
    return data


# ---------------------------------------------------------------------------------------------------- planner

