"""Device budgets: profiles (`profiles/*.toml`), the planner that sets key-frame counts, and the run-time
deadlines and memory guard. Also the `mosaic plan` command module.

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
                     or "estimated" (+ source: where the figure comes from). Optional: provider, note.

The planner (`plan`) splits the per-question latency budget into

    (1) fixed      model loads + video pass (decode + dedup per frame) + grounding + VLM (images, decoding)
    (2) search     scored frames S x detector cost (the iterative key-frame search of keyframes.py)
    (3) key frames K x (segmenter + prompts + depth + embedder + features + matching + geometry [+ VLM images])

and picks the largest K (<= PlanConf.keyframes_max) whose latency *and* memory fit, giving the search at least
`min_scored_per_keyframe * K` frames, then as many more as the slack allows up to `scored_fraction` of the
candidates. Nothing fitting raises BudgetError naming the budget and the shortfall.

At run time `BudgetController(plan, trace)` gives each pipeline stage its share of the budget, re-plans the
remaining stages when one overruns (fewer key frames, smaller search batches; `reduced` is then True and the
trace has a "replan" event) and guards memory (`check_headroom`, `allow_keyframes`, idle-session release).
"""
from __future__ import annotations

import argparse
import datetime as _dt
import json
import math
import os
import sys
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any, Callable, ClassVar, Mapping, Sequence

from .answer import VLMConfig
from .config import StageConf
from .errors import BudgetError, InputError, MosaicError, ProfileError
from .bundle import bundle_hash
from .trace import Trace, peak_rss_mb, reset_peak_rss, rss_mb

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - python 3.10
    import tomli as tomllib

PROFILE_SCHEMA = "mosaicthinker.profile/1"
PLAN_SCHEMA = "mosaicthinker.plan/1"
ROLES = ("depth", "segmenter", "matcher", "detector", "embedder", "vlm")
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
ROOT_PROFILES = Path(__file__).resolve().parents[1] / "profiles"

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
OPTIONAL_ROLE_COSTS = ("segmenter", "embedder", "vlm")
MODEL_COSTS = ("detector", "segmenter", "depth", "embedder", "matcher", "vlm")
PROVENANCE_KEYS = ("status", "date", "bundle_hash", "source", "provider", "note")

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

    def get(self, key: str) -> float:
        v = getattr(self, key)
        return 0.0 if v is None else float(v)

    def provenance(self) -> str:
        if self.status == "measured":
            return f"measured {self.date} bundle {self.bundle_hash}"
        return f"estimated ({self.source})"

    def to_dict(self) -> dict[str, Any]:
        return {k: v for k, v in asdict(self).items() if v is not None and k != "name"}


# When a bundle lacks the profile's precision for a role, the closest one it has, in this order: an accelerator's
# int8 QDQ falls back to dynamic int8 (same arithmetic, CPU kernels), then fp16, then fp32; fp16 to fp32 first.
NEAREST_PRECISION = {"int8-qdq": ("int8-qdq", "int8-dynamic", "fp16", "fp32"),
                     "int8-dynamic": ("int8-dynamic", "int8-qdq", "fp32", "fp16"),
                     "fp16": ("fp16", "fp32", "int8-qdq", "int8-dynamic"),
                     "fp32": ("fp32", "fp16", "int8-dynamic", "int8-qdq")}


def nearest_variant(want: str, variants: dict[str, Any]) -> str | None:
    """The variant name to run for a requested one: `want` itself, else the variant whose precision is nearest
    (NEAREST_PRECISION; a variant's `precision` field, so `android-ort-int8-qdq` counts as int8-qdq, exact names
    first). None when nothing matches (an unknown variant name: the bundle's default)."""
    if want in variants:
        return want
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
        return replace(self, costs={**self.costs, **self.paper_costs})

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
        from .bundle import load_bundle

        b = load_bundle(bundle, verify=False) if not hasattr(bundle, "role_meta") else bundle
        if not b.has_role(role):
            return None
        got = nearest_variant(self.roles[role].bundle_variant, b.role_meta(role).get("variants", {}))
        want = self.roles[role].bundle_variant
        if got != want and trace is not None:
            used = got or b.role_meta(role).get("default_variant")
            trace.event("degraded", f"profile {self.name} asks for {role} {want!r}, which the bundle does not have: "
                        f"running its {'nearest' if got else 'default'} variant {used!r}", stage=role,
                        requested=want, used=used)
        return got

    def cost(self, name: str) -> CostEntry | None:
        return self.costs.get(name)

    def uses(self, role: str) -> bool:
        return role in self.costs

    def apply_to_machine(self, trace: Trace | None = None) -> None:
        """Fit the runtime settings to this machine before any session is made: pin to `core_affinity`
        (refused loudly where impossible) and lower thread counts above the usable cores (recorded)."""
        self.apply_affinity(trace)
        try:
            cores = len(os.sched_getaffinity(0))
        except (AttributeError, OSError):
            cores = os.cpu_count() or 1
        for k in ("intra_op_threads", "inter_op_threads"):
            n = getattr(self, k)
            if n and n > cores:
                setattr(self, k, cores)
                if trace is not None:
                    trace.event("degraded", f"profile {self.name}: runtime.{k} = {n} but this machine has {cores} "
                                f"usable cores; using {cores}", stage="budget")

    def apply_affinity(self, trace: Trace | None = None) -> list[int] | None:
        """Pin this process to `core_affinity` where the OS allows it (Linux, Android); recorded in the trace."""
        if not self.core_affinity:
            return None
        import psutil

        proc = psutil.Process()
        try:
            avail = set(range(psutil.cpu_count() or 1))
            cores = [c for c in self.core_affinity if c in avail]
            if not cores:
                raise OSError(f"none of the cores {self.core_affinity} exist here ({sorted(avail)})")
            proc.cpu_affinity(cores)
            if trace is not None:
                trace.decide("budget.core_affinity", cores)
            return cores
        except (AttributeError, OSError, ValueError) as e:  # macOS has no cpu_affinity
            if trace is not None:
                trace.event("degraded", f"profile {self.name}: core_affinity {self.core_affinity} not applied ({e})",
                            warn=True)
            return None


MAX_THREADS = 256         # no edge device has more cores; larger values are typos (100000 took 10 GB)
MAX_CLIP_S = 86400.0      # 24 h: longer clips are not one question's video (and overflow frame counts)
MAX_FPS = 1000.0
MIN_MAP_FRAMES = 2        # alignment needs two views


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
    if not math.isfinite(v):
        raise ProfileError(f"{where}: must be finite, got {v!r}")
    if v < 0:
        raise ProfileError(f"{where}: negative value {v!r}; budgets and costs must be >= 0")
    if positive and v == 0:
        raise ProfileError(f"{where}: must be > 0, got {v!r}")
    return float(v)


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
        _check_keys(ct, nums + PROVENANCE_KEYS, cw)
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
    return costs


def parse_profile(data: Mapping[str, Any], path: str | os.PathLike | None = None) -> Profile:
    """Validate a profile dict (as read from TOML) and build a Profile. Raises ProfileError naming the
    file and field: unknown key, wrong unit, negative or non-numeric value, missing field, bad provider."""
    path = Path(path) if path else None
    w = _where(path)
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
    bud = data["budget"]
    lat = _check_number(bud["latency_budget_ms"], f"{w}: budget.latency_budget_ms", positive=True)
    mem = _check_number(bud["memory_budget_mb"], f"{w}: budget.memory_budget_mb", positive=True)
    rt = data["runtime"]
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

    roles: dict[str, RoleSettings] = {}
    for role, rt_ in (data.get("roles") or {}).items():
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
            if (not isinstance(size, list) or len(size) != 2 or not all(isinstance(s, int) and not isinstance(s, bool) and s > 0 for s in size)):
                raise ProfileError(f"{rw}.input_size_px: expected [width, height] positive integers, got {size!r}")
            size = (int(size[0]), int(size[1]))
        for k in ("variant", "notes"):
            if k in rt_ and not isinstance(rt_[k], str):
                raise ProfileError(f"{rw}.{k}: expected a string")
        roles[role] = RoleSettings(role, prec, kind, rt_.get("variant"), provs, size, rt_.get("notes"))

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

    dev = dict(data["device"])
    return Profile(name=dev["name"], path=path, latency_budget_ms=lat, memory_budget_mb=mem, providers=chain,
                   intra_op_threads=rt.get("intra_op_threads"), inter_op_threads=rt.get("inter_op_threads"),
                   core_affinity=list(aff) if aff else None, device=dev, runtime_notes=rt.get("notes"),
                   roles=roles, costs=costs, paper_costs=paper_costs, raw=json.loads(json.dumps(data)))


def resolve_profile_path(name_or_path: str | os.PathLike) -> Path:
    """A file path, or a bare profile name looked up in the repository's profiles/ folder."""
    p = Path(name_or_path)
    if p.is_file():
        return p
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


@dataclass
class PlanConf(StageConf):
    """Planner parameters (device independent; the profile only sets budgets and costs).
    `PlanConf.merged(mapping_or_conf, **overrides)` (None overrides are ignored; unknown keys are an error)."""

    conf_name: ClassVar[str] = "plan config"

    keyframes_max: int = 32            # K never exceeds this (the map gains little beyond it)
    keyframes_min: int = 2             # alignment needs two frames; below this nothing fits
    scored_fraction: float = 0.25      # search target: share of candidates scored (keyframes.KeyFrameConf)
    min_scored_per_keyframe: int = 4   # the search scores at least this many frames per key frame wanted
    max_scored_frames: int | None = None
    iterations: int = 20               # search iterations (keyframes.KeyFrameConf.iterations)
    dedup_keep_fraction: float = 0.5   # candidates / frames after redundant-frame removal (estimate)
    prompts_per_keyframe: float = 4.0  # segmenter prompts (objects) per key frame
    pairs_per_keyframe: float = 2.5    # matched pairs per key frame: tree edge + verification + retries (the
                                       # pipeline benchmark tried 38 pairs at K = 16 and 82 at K = 32)
    vlm_images: int = 1                # the visual prompt (map image)
    vlm_images_per_keyframe: float = 0.0  # key-frame images given to the VLM as well (0: map prompt only)
    vlm_max_new_tokens: int = VLMConfig.max_new_tokens  # owned by the answerer's config: plan what it asks
    use_vlm: bool = True               # False: the map reasoner answers (no VLM costs)
    safety_fraction: float = 0.0       # keep this share of the latency budget unplanned
    video_pass: str = "question"       # question: decode + dedup run after the question (a clip is given);
                                       # online: they run while the video is captured (not in the latency)

    def validate(self) -> None:
        c = self
        if c.keyframes_min < 1 or c.keyframes_max < c.keyframes_min:
            raise InputError(f"plan config: need 1 <= keyframes_min <= keyframes_max (got {c.keyframes_min}, "
                             f"{c.keyframes_max})")
        if not 0 < c.scored_fraction <= 1 or not 0 < c.dedup_keep_fraction <= 1:
            raise InputError("plan config: scored_fraction and dedup_keep_fraction must be in (0, 1]")
        if c.video_pass not in ("question", "online"):
            raise InputError(f"plan config: video_pass must be 'question' or 'online' (got {c.video_pass!r})")
        if not 0 <= c.safety_fraction < 1 or c.iterations < 1 or c.min_scored_per_keyframe < 1:
            raise InputError("plan config: need 0 <= safety_fraction < 1, iterations >= 1, "
                             "min_scored_per_keyframe >= 1")


# pipeline stages the controller budgets (names the pipeline passes to start_stage/end_stage)
RUNTIME_STAGES = ("load", "frames", "grounding", "keyframes", "perception", "alignment", "answer")
# other names the pipeline's trace uses for the same work
# (whole stages only: per-call names such as "detect" are timed by trace.stage, not by the controller)
STAGE_ALIASES = {"dedup": "frames", "decode": "frames", "video": "frames", "search": "keyframes",
                 "select": "keyframes", "keyframe_search": "keyframes", "align": "alignment",
                 "map": "alignment", "fusion": "alignment", "vlm": "answer", "prompt": "answer",
                 "models": "load", "load_models": "load"}


@dataclass
class StageBudget:
    """One runtime stage's share: ms = fixed_ms + per_keyframe_ms * K + per_scored_ms * S."""

    name: str
    fixed_ms: float = 0.0
    per_keyframe_ms: float = 0.0
    per_scored_ms: float = 0.0

    def ms(self, k: int, s: int) -> float:
        return self.fixed_ms + self.per_keyframe_ms * k + self.per_scored_ms * s

    def to_dict(self) -> dict[str, float]:
        return {k: round(v, 3) for k, v in asdict(self).items() if k != "name"}


@dataclass
class Plan:
    """The planner's answer. `to_dict()` is the `mosaic plan --json` object."""

    profile: str
    device: str
    duration_s: float
    fps: float
    total_frames: int
    candidates: int
    keyframes: int
    scored_frames: int
    iterations: int
    batch_size: int
    latency_budget_ms: float
    memory_budget_mb: float
    stages: dict[str, StageBudget]
    fixed_ms: dict[str, float]
    search_ms: float
    per_keyframe_ms: dict[str, float]
    memory_mb: dict[str, float]
    keyframe_mb: float
    session_policy: str
    limited_by: str
    providers: dict[str, dict[str, Any]]
    resolutions: dict[str, Any]
    cost_status: dict[str, str]
    arithmetic: list[str]
    notes: list[str]
    conf: PlanConf
    bundle: str | None = None
    bundle_hash: str | None = None

    @property
    def total_ms(self) -> float:
        return sum(st.ms(self.keyframes, self.scored_frames) for st in self.stages.values())

    @property
    def total_memory_mb(self) -> float:
        return sum(self.memory_mb.values())

    def stage_ms(self, name: str, k: int | None = None, s: int | None = None) -> float:
        st = self.stages.get(name)
        return 0.0 if st is None else st.ms(self.keyframes if k is None else k,
                                             self.scored_frames if s is None else s)

    def to_dict(self) -> dict[str, Any]:
        k, s = self.keyframes, self.scored_frames
        return {
            "schema": PLAN_SCHEMA, "profile": self.profile, "device": self.device,
            "bundle": self.bundle, "bundle_hash": self.bundle_hash,
            "video": {"duration_s": self.duration_s, "fps": self.fps, "frames": self.total_frames,
                      "candidates": self.candidates, "pass": self.conf.video_pass},
            "keyframes": k, "scored_frames": s, "iterations": self.iterations, "batch_size": self.batch_size,
            "scored_fraction": round(s / max(self.candidates, 1), 4), "limited_by": self.limited_by,
            "latency_budget_ms": self.latency_budget_ms, "planned_ms": round(self.total_ms, 1),
            "slack_ms": round(self.latency_budget_ms - self.total_ms, 1),
            "memory_budget_mb": self.memory_budget_mb, "planned_memory_mb": round(self.total_memory_mb, 1),
            "fixed_ms": {a: round(b, 1) for a, b in self.fixed_ms.items()},
            "fixed_total_ms": round(sum(self.fixed_ms.values()), 1),
            "search_ms": round(self.search_ms, 1),
            "per_keyframe_ms": {a: round(b, 2) for a, b in self.per_keyframe_ms.items()},
            "keyframe_unit_ms": round(sum(self.per_keyframe_ms.values()), 2),
            "keyframes_ms": round(k * sum(self.per_keyframe_ms.values()), 1),
            "memory_mb": {a: round(b, 1) for a, b in self.memory_mb.items()}, "keyframe_mb": self.keyframe_mb,
            "session_policy": self.session_policy,
            "stages": {n: {**st.to_dict(), "planned_ms": round(st.ms(k, s), 1)} for n, st in self.stages.items()},
            "providers": self.providers, "resolutions": self.resolutions, "cost_status": self.cost_status,
            "arithmetic": self.arithmetic, "notes": self.notes, "conf": asdict(self.conf),
        }


def _fmt(x: float) -> str:
    return f"{x:,.0f}" if abs(x) >= 100 else f"{x:,.1f}" if abs(x) >= 10 else f"{x:,.2f}"


def _bundle_roles(bundle: Any) -> tuple[Any, list[str]]:
    from .bundle import load_bundle

    b = load_bundle(bundle, verify=False)
    return b, b.roles


def plan(profile: Profile | str | os.PathLike, duration_s: float, fps: float, bundle: Any = None,
         conf: PlanConf | Mapping[str, Any] | None = None, *, candidates: int | None = None,
         models: str = "shared") -> Plan:
    """Plan one question over a clip of `duration_s` seconds at `fps` under the profile's budgets.

    Returns the largest key-frame count K (keyframes_min..keyframes_max, at most the candidates) whose planned
    latency and memory both fit, and the search budget S (scored frames) that fits beside it. Raises BudgetError
    naming the failing budget and the shortfall when even keyframes_min does not fit.
    bundle: a bundle folder/Bundle (optional): roles missing from it are not planned (no VLM -> map reasoner),
    input sizes come from its preprocessing. candidates: frames kept by dedup if known (else estimated).
    models: "shared" (the shared mobile models' costs) or "paper" (the paper's models at real size).
    """
    prof = (profile if isinstance(profile, Profile) else load_profile(profile)).with_models(models)
    c = conf if isinstance(conf, PlanConf) else PlanConf.merged(conf)
    if not (duration_s > 0 and math.isfinite(duration_s)) or duration_s > MAX_CLIP_S:
        raise InputError(f"plan: duration must be > 0 and at most {MAX_CLIP_S:g} s (24 h) (got {duration_s:g}); "
                         f"give the clip length in seconds")
    if not (fps > 0 and math.isfinite(fps)) or fps > MAX_FPS:
        raise InputError(f"plan: fps must be > 0 and at most {MAX_FPS:g} (got {fps:g})")
    if candidates is not None and candidates < 2:
        raise InputError(f"plan: `candidates` must be >= 2 (frames kept by dedup; got {candidates})",
                         fields=("candidates",))
    if duration_s * fps + 1 < MIN_MAP_FRAMES:  # frames at t = 0, 1/fps, ...: a 0.001 s clip is one frame
        raise InputError(f"plan: a {duration_s:g} s clip at {fps:g} fps has {int(duration_s * fps) + 1} frame(s); "
                         f"a map needs at least {MIN_MAP_FRAMES} views of the scene")
    notes: list[str] = []
    arith: list[str] = []
    total_frames = max(1, int(round(duration_s * fps)))
    if candidates is None:
        n_c = max(1, int(math.ceil(total_frames * c.dedup_keep_fraction)))
        cand_how = f"{total_frames} frames x dedup keep {c.dedup_keep_fraction:g} (estimate)"
    else:
        n_c = max(1, min(int(candidates), total_frames))
        cand_how = "given"

    b, broles, bhash = None, None, None
    if bundle is not None:
        b, broles = _bundle_roles(bundle)
        bhash = bundle_hash(b)
    used: dict[str, bool] = {}
    for r in MODEL_COSTS:
        u = prof.uses(r)
        if u and broles is not None and r not in broles:
            notes.append(f"{r}: the bundle has no {r} model; not planned"
                         + (" (the map reasoner answers)" if r == "vlm" else ""))
            u = False
        if r == "vlm" and u and not c.use_vlm:
            notes.append("vlm: not planned (use_vlm = false: the map reasoner answers)")
            u = False
        if r == "vlm" and not prof.uses("vlm"):
            notes.append("vlm: the profile has no [costs.vlm]; the map reasoner answers")
        used[r] = u

    def cost(name: str, key: str) -> float:
        e = prof.cost(name)
        if e is None or (name in MODEL_COSTS and not used.get(name)):
            return 0.0
        return e.get(key)

    # (1) fixed costs
    loads = {r: cost(r, "load_ms") for r in MODEL_COSTS if used[r]}
    per_frame_ms = cost("dedup", "ms_per_call")  # the pass decodes what it needs itself
    video_ms = total_frames * per_frame_ms
    online_factor = per_frame_ms * fps / 1000.0  # share of real time the online video pass needs
    if c.video_pass == "online":
        video_ms = 0.0
        if online_factor > 1:
            notes.append(f"online video pass: dedup (with its decoding) takes {_fmt(per_frame_ms)} ms per frame, "
                         f"more than the "
                         f"{_fmt(1000 / fps)} ms between frames at {fps:g} fps: it cannot keep up with capture "
                         f"(x{online_factor:.2f} real time)")
    vlm_fixed = c.vlm_images * cost("vlm", "ms_per_image") + c.vlm_max_new_tokens * cost("vlm", "ms_per_token")
    fixed = {"model_loads": sum(loads.values()), "video_pass": video_ms,
             "grounding": cost("grounding", "ms_per_call"), "vlm_answer": vlm_fixed}
    # (2) search, per scored frame: fetching the frame (one decode) + the detector
    c_s = cost("detector", "ms_per_call") + cost("video_decode", "ms_per_call")
    # (3) per key frame
    per_kf = {"decode": cost("video_decode", "ms_per_call"),  # key frames are fetched again for perception
              "segmenter": cost("segmenter", "ms_per_call")
              + c.prompts_per_keyframe * cost("segmenter", "ms_per_prompt"),
              "depth": cost("depth", "ms_per_call"), "embedder": cost("embedder", "ms_per_call"),
              "features": cost("matcher", "ms_per_call"),
              "matching": c.pairs_per_keyframe * cost("matcher", "ms_per_pair"),
              "geometry": cost("geometry", "ms_per_call"),
              "refine": cost("refine", "ms_per_call"),
              "vlm_images": c.vlm_images_per_keyframe * cost("vlm", "ms_per_image")}
    c_k = sum(per_kf.values())
    F = sum(fixed.values())
    L = prof.latency_budget_ms * (1 - c.safety_fraction)

    # memory: process + models (all resident, or one at a time) + K x key-frame state
    kf_mb = cost("keyframe_state", "mb_per_call")
    base_mb = cost("process", "resident_mb")
    res = {r: cost(r, "resident_mb") for r in MODEL_COSTS if used[r]}
    all_mb = sum(res.values())
    one_mb = max(res.values(), default=0.0)
    M = prof.memory_budget_mb

    def s_floor(k: int) -> int:
        return min(n_c, c.min_scored_per_keyframe * k)

    def s_target(k: int) -> int:
        t = max(int(math.ceil(c.scored_fraction * n_c)), s_floor(k))
        if c.max_scored_frames is not None:
            t = max(min(t, c.max_scored_frames), s_floor(k))
        return min(n_c, t)

    def lat(k: int, s: int) -> float:
        return F + s * c_s + k * c_k

    k_cap = min(c.keyframes_max, n_c)
    k_lo = min(c.keyframes_min, n_c)

    def largest_k(models: float) -> int | None:
        for k in range(k_cap, k_lo - 1, -1):
            if lat(k, s_floor(k)) <= L and base_mb + models + k * kf_mb <= M:
                return k
        return None

    # all sessions resident, unless loading them one at a time (stage-major) allows more key frames
    policy, models_mb = "all_resident", all_mb
    chosen = largest_k(all_mb)
    k_one = largest_k(one_mb) if len(res) > 1 else None
    if k_one is not None and (chosen is None or k_one > chosen):
        policy, models_mb, chosen = "one_at_a_time", one_mb, k_one
        notes.append(f"memory: all models together ({_fmt(all_mb)} MB) leave room for fewer key frames; sessions "
                     f"are loaded one at a time, stage-major (each stage runs over all key frames, then its "
                     f"session is released)")
    why = ""
    if chosen is None:
        k = k_lo
        parts = []
        if len(res) > 1:  # the shortfall is reported for the leanest policy
            policy, models_mb = "one_at_a_time", one_mb
        over_l = lat(k, s_floor(k)) - L
        over_m = base_mb + models_mb + k * kf_mb - M
        if over_l > 0:
            parts.append(f"latency budget {_fmt(L)} ms fails by {_fmt(over_l)} ms: fixed {_fmt(F)} ms "
                         f"(loads {_fmt(fixed['model_loads'])}, video pass {_fmt(video_ms)} over {total_frames} "
                         f"frames, grounding {_fmt(fixed['grounding'])}, VLM {_fmt(vlm_fixed)}) + search "
                         f"{s_floor(k)} x {_fmt(c_s)} ms + {k} key frames x {_fmt(c_k)} ms")
        if over_m > 0:
            parts.append(f"memory budget {_fmt(M)} MB fails by {_fmt(over_m)} MB: runtime {_fmt(base_mb)} + models "
                         f"{_fmt(models_mb)} ({policy}) + {k} key frames x {_fmt(kf_mb)} MB")
        hint = (" (or plan with --online: decode + dedup while the video is captured)"
                if c.video_pass == "question" and video_ms > L / 2 else "")
        raise BudgetError(f"profile {prof.name}: nothing fits even at K = {k} key frames: " + "; ".join(parts)
                          + ". Raise the budget, use a shorter clip or a cheaper bundle variant" + hint + ".")
    K = chosen
    if K == c.keyframes_max:
        why = f"keyframes_max ({c.keyframes_max})"
    elif K == n_c:
        why = f"candidates ({n_c})"
    else:
        nxt = K + 1
        l_fail = lat(nxt, s_floor(nxt)) > L
        m_fail = base_mb + models_mb + nxt * kf_mb > M
        why = " and ".join(w for w, f in (("latency", l_fail), ("memory", m_fail)) if f)
    slack = L - F - K * c_k
    s_max_fit = int(math.floor(slack / c_s)) if c_s > 0 else n_c
    S = max(s_floor(K), min(s_target(K), s_max_fit))
    if S < s_target(K):
        notes.append(f"search: {S} scored frames instead of the target {s_target(K)} "
                     f"({c.scored_fraction:g} of {n_c} candidates): the latency budget limits it")
    iters = max(1, min(c.iterations, S))
    batch = int(math.ceil(S / iters))

    stages = {
        "load": StageBudget("load", fixed_ms=fixed["model_loads"]),
        "frames": StageBudget("frames", fixed_ms=video_ms),
        "grounding": StageBudget("grounding", fixed_ms=fixed["grounding"]),
        "keyframes": StageBudget("keyframes", per_scored_ms=c_s),
        "perception": StageBudget("perception", per_keyframe_ms=per_kf["decode"] + per_kf["segmenter"]
                                  + per_kf["depth"] + per_kf["embedder"] + per_kf["features"]),
        "alignment": StageBudget("alignment", per_keyframe_ms=per_kf["matching"] + per_kf["geometry"]
                                 + per_kf["refine"]),
        "answer": StageBudget("answer", fixed_ms=vlm_fixed, per_keyframe_ms=per_kf["vlm_images"]),
    }
    mem = {"process": base_mb, "models": models_mb, "keyframes": K * kf_mb}

    # providers and resolutions per stage
    try:
        import onnxruntime as ort

        here = set(ort.get_available_providers())
    except Exception:  # pragma: no cover - onnxruntime is a runtime dependency
        here = {"CPUExecutionProvider"}
    providers: dict[str, dict[str, Any]] = {}
    resolutions: dict[str, Any] = {}
    for r in MODEL_COSTS:
        if not used[r]:
            continue
        chain = prof.providers_for(r)
        rs = prof.role(r)
        providers[r] = {"device": chain[0], "chain": chain,
                        "here": next((p for p in chain if p in here), "CPUExecutionProvider"),
                        "precision": rs.precision + (f"-{rs.int8_kind}" if rs.int8_kind else ""),
                        "variant": rs.bundle_variant}
        if b is not None and b.has_role(r):  # what will run: the nearest variant the bundle has
            have = nearest_variant(rs.bundle_variant, b.role_meta(r).get("variants", {}))
            ran = providers[r]["variant"] = have or b.role_meta(r).get("default_variant")
            if ran != rs.bundle_variant:
                notes.append(f"{r}: the bundle has no {rs.bundle_variant!r} variant; "
                             f"{'the nearest' if have else 'its default'}, {ran!r}, runs")
        size = list(rs.input_size_px) if rs.input_size_px else None
        if b is not None and b.has_role(r):
            pre = b.role_meta(r).get("preprocessing", {})
            if pre.get("size"):
                size = [int(pre["size"][1]), int(pre["size"][0])]  # manifest [H, W] -> [W, H]
        resolutions[r] = size
    cost_status = {n: e.provenance() for n, e in prof.costs.items()}
    if bhash:
        stale = [n for n, e in prof.costs.items() if e.status == "measured" and e.bundle_hash != bhash]
        if stale:
            notes.append(f"costs measured on another bundle (hash != {bhash}): {', '.join(stale)}; re-run "
                         f"`mosaic profile --update-profile` with this bundle")
    n_est = sum(e.status == "estimated" for e in prof.costs.values())
    if n_est:
        notes.append(f"{n_est} of {len(prof.costs)} cost items are estimates (see cost_status); measure them "
                     f"on the device with `mosaic profile`")

    # the arithmetic, as the user reads it
    arith.append(f"candidates = {cand_how} = {n_c}")
    arith.append("fixed = loads " + " + ".join(f"{r} {_fmt(v)}" for r, v in loads.items())
                 + f" = {_fmt(fixed['model_loads'])} ms"
                 if loads else "fixed = no model loads")
    arith.append(f"      + video pass (decode + dedup) {total_frames} frames x {_fmt(per_frame_ms)} ms = "
                 f"{_fmt(video_ms)} ms" if c.video_pass == "question"
                 else f"      + video pass 0 ms (online, during capture: {_fmt(per_frame_ms)} ms per frame = "
                      f"x{online_factor:.2f} real time)")
    arith.append(f"      + grounding {_fmt(fixed['grounding'])} ms")
    arith.append(f"      + VLM {c.vlm_images} image x {_fmt(cost('vlm', 'ms_per_image'))} ms + "
                 f"{c.vlm_max_new_tokens} tokens x {_fmt(cost('vlm', 'ms_per_token'))} ms = {_fmt(vlm_fixed)} ms"
                 if used.get("vlm") else "      + VLM 0 ms (not used: map reasoner)")
    arith.append(f"      = {_fmt(F)} ms")
    arith.append("per key frame = " + " + ".join(f"{n} {_fmt(v)}" for n, v in per_kf.items() if v)
                 + f" = {_fmt(c_k)} ms   (segmenter incl. {c.prompts_per_keyframe:g} prompts, matching "
                   f"{c.pairs_per_keyframe:g} pairs)")
    arith.append(f"K = largest k <= min(keyframes_max {c.keyframes_max}, candidates {n_c}) with "
                 f"fixed + {c.min_scored_per_keyframe}k x {_fmt(c_s)} (decode + detector) + k x {_fmt(c_k)} "
                 f"<= {_fmt(L)} ms and "
                 f"{_fmt(base_mb)} + {_fmt(models_mb)} + k x {_fmt(kf_mb)} <= {_fmt(M)} MB  ->  K = {K} "
                 f"(limited by {why})")
    arith.append(f"search S = min(target {s_target(K)}, floor(({_fmt(L)} - {_fmt(F)} - {K} x {_fmt(c_k)}) / "
                 f"{_fmt(c_s)}) = {s_max_fit if c_s > 0 else 'inf'}), at least {s_floor(K)}  ->  S = {S} scored "
                 f"frames in {iters} iterations of {batch}")
    total = lat(K, S)
    arith.append(f"latency = {_fmt(F)} + {S} x {_fmt(c_s)} + {K} x {_fmt(c_k)} = {_fmt(total)} ms of "
                 f"{_fmt(prof.latency_budget_ms)} ms (slack {_fmt(prof.latency_budget_ms - total)} ms)")
    arith.append(f"memory = runtime {_fmt(base_mb)} + models {_fmt(models_mb)} ({policy}) + {K} x {_fmt(kf_mb)} "
                 f"= {_fmt(sum(mem.values()))} MB of {_fmt(M)} MB")
    if S < c.iterations:
        notes.append(f"search: only {S} frames to score, so {iters} iterations of 1")
    return Plan(profile=prof.name, device=prof.device.get("description", prof.name), duration_s=float(duration_s),
                fps=float(fps), total_frames=total_frames, candidates=n_c, keyframes=K, scored_frames=S,
                iterations=iters, batch_size=batch, latency_budget_ms=prof.latency_budget_ms,
                memory_budget_mb=M, stages=stages, fixed_ms=fixed, search_ms=S * c_s, per_keyframe_ms=per_kf,
                memory_mb=mem, keyframe_mb=kf_mb, session_policy=policy, limited_by=why, providers=providers,
                resolutions=resolutions, cost_status=cost_status, arithmetic=arith, notes=notes, conf=c,
                bundle=str(b.root) if b is not None else None, bundle_hash=bhash)


# ---------------------------------------------------------------------------------------------- run time


@dataclass
class _Session:
    name: str
    mb: float
    release: Callable[[], None]
    last_stage: str | None = None
    released: bool = False


class BudgetController:
    """Run-time side of a Plan: stage deadlines with re-planning, and the memory guard.

    Usage in the pipeline::

        ctl = BudgetController(plan, trace)
        with ctl.stage("keyframes"):                       # or ctl.start_stage(...) / ctl.end_stage(...)
            conf = KeyFrameConf.merged(keyframes=ctl.keyframes, budget=ctl.scored_frames,
                                       iterations=ctl.iterations)
            ...
        k = ctl.allow_keyframes(len(chosen))               # after re-plans and memory headroom
        if not ctl.check_headroom(model_mb, "load depth"): # releases idle sessions first
            ...                                            # lower K / skip, recorded in the trace
        result["reduced_plan"] = ctl.reduced

    Stage names are free; those in RUNTIME_STAGES carry the plan's share. A stage overruns when its time exceeds
    its share by `tolerance` (relative) or the run is behind the cumulative plan. Then the remaining stages are
    re-planned against the time left, scaling their planned costs by the observed slowdown (elapsed / planned
    so far, at least 1): K (and, before the search ran, the scored frames and batch) shrink to what fits.
    """

    def __init__(self, plan: Plan, trace: Trace | None = None, *, tolerance: float = 0.1,
                 clock: Callable[[], float] = time.perf_counter, rss: Callable[[], float] = rss_mb):
        self.plan = plan
        self.trace = trace if trace is not None else Trace()
        self.tolerance = tolerance
        self._clock = clock
        self._rss = rss
        self.keyframes = plan.keyframes
        self.scored_frames = plan.scored_frames
        self.iterations = plan.iterations
        self.batch_size = plan.batch_size
        self.budget_ms = plan.latency_budget_ms
        self.memory_budget_mb = plan.memory_budget_mb
        self.reduced = False
        self.reasons: list[str] = []
        self.t0 = clock()
        self._open: dict[str, float] = {}
        self.done: dict[str, float] = {}  # stage -> ms spent
        self.peaks: dict[str, float] = {}
        self.sessions: dict[str, _Session] = {}
        self._current: str | None = None
        self.trace.decide("budget.plan", {"profile": plan.profile, "keyframes": plan.keyframes,
                                          "scored_frames": plan.scored_frames, "iterations": plan.iterations,
                                          "latency_budget_ms": plan.latency_budget_ms,
                                          "memory_budget_mb": plan.memory_budget_mb})

    # ------------------------------------------------------------------ time
    def elapsed_ms(self) -> float:
        return (self._clock() - self.t0) * 1000.0

    def remaining_ms(self) -> float:
        return self.budget_ms - self.elapsed_ms()

    def share_ms(self, name: str) -> float:
        """This stage's share of the budget under the current (possibly reduced) plan."""
        return self.plan.stage_ms(self.canonical(name), self.keyframes, self.scored_frames)

    def deadline_ms(self, name: str) -> float:
        """Milliseconds from now by which `name` should end (its share, or what is left if that is less)."""
        name = self.canonical(name)
        left = self.remaining_ms() - sum(self.share_ms(s) for s in self.plan.stages
                                         if s not in self.done and s != name)
        return max(0.0, min(self.share_ms(name), left) if name in self.plan.stages else left)

    @staticmethod
    def canonical(name: str) -> str:
        """Plan stage for a pipeline stage name (RUNTIME_STAGES or an alias such as 'dedup' -> 'frames')."""
        return STAGE_ALIASES.get(name, name)

    def update_candidates(self, n: int) -> None:
        """After redundant-frame removal the candidate count is known: K and S never exceed it (recorded)."""
        n = int(n)
        k, s = min(self.keyframes, n), min(self.scored_frames, n)
        if (k, s) != (self.keyframes, self.scored_frames):
            self.trace.event("plan", f"{n} candidates after dedup (planned {self.plan.candidates}): key frames "
                             f"{self.keyframes} -> {k}, scored frames {self.scored_frames} -> {s}", candidates=n)
        self.keyframes, self.scored_frames = max(k, 0), max(s, 0)
        self.iterations = max(1, min(self.iterations, max(s, 1)))
        self.batch_size = int(math.ceil(max(s, 1) / self.iterations))
        self.trace.decide("budget.candidates", n)

    def start_stage(self, name: str) -> None:
        name = self.canonical(name)
        self._open[name] = self._clock()
        self._current = name
        reset_peak_rss()
        self.peaks[name] = max(self.peaks.get(name, 0.0), self._rss())

    def end_stage(self, name: str) -> bool:
        """Close a stage; returns True when it caused a re-plan."""
        name = self.canonical(name)
        if name not in self._open:
            raise RuntimeError(f"BudgetController.end_stage({name!r}) without start_stage")
        spent = (self._clock() - self._open.pop(name)) * 1000.0
        self.done[name] = self.done.get(name, 0.0) + spent
        self.peaks[name] = max(self.peaks.get(name, 0.0), peak_rss_mb(), self._rss())
        self._current = None
        share = self.share_ms(name) if name in self.plan.stages else None
        planned_so_far = sum(self.share_ms(s) for s in self.done if s in self.plan.stages)
        behind = self.elapsed_ms() > planned_so_far * (1 + self.tolerance) and planned_so_far > 0
        over = share is not None and self.done[name] > share * (1 + self.tolerance)
        if over or behind or self.remaining_ms() < 0:
            why = (f"stage {name} took {self.done[name]:.0f} ms of its {share:.0f} ms share" if over and share is not
                   None else f"after stage {name} the run is at {self.elapsed_ms():.0f} ms, planned "
                   f"{planned_so_far:.0f} ms")
            return self.replan(why)
        return False

    class _Ctx:
        def __init__(self, ctl: "BudgetController", name: str):
            self.ctl, self.name = ctl, name

        def __enter__(self):
            self.ctl.start_stage(self.name)
            self._trace_cm = self.ctl.trace.stage(self.name)
            return self._trace_cm.__enter__()

        def __exit__(self, *exc):
            r = self._trace_cm.__exit__(*exc)
            self.ctl.end_stage(self.name)
            return r

    def stage(self, name: str) -> "BudgetController._Ctx":
        """Context manager: the trace's stage timing plus this controller's deadline bookkeeping."""
        return BudgetController._Ctx(self, name)

    def replan(self, why: str) -> bool:
        """Fit the remaining stages into the time left. Returns True when K or S was lowered."""
        p = self.plan
        planned_done = sum(self.share_ms(s) for s in self.done if s in p.stages)
        slowdown = max(1.0, self.elapsed_ms() / planned_done) if planned_done > 0 else 1.0
        left = self.remaining_ms()
        rest = [st for n, st in p.stages.items() if n not in self.done and n not in self._open]
        search_left = any(st.name == "keyframes" for st in rest)
        fixed = sum(st.fixed_ms for st in rest)
        per_k = sum(st.per_keyframe_ms for st in rest)
        per_s = sum(st.per_scored_ms for st in rest)
        k_min = min(p.conf.keyframes_min, self.keyframes)

        def s_for(k: int) -> int:
            if not search_left:
                return self.scored_frames
            return min(self.scored_frames, max(min(p.candidates, p.conf.min_scored_per_keyframe * k), 1))

        def need(k: int, s: int) -> float:
            return slowdown * (fixed + per_k * k + (per_s * s if search_left else 0.0))

        new_k = next((k for k in range(self.keyframes, k_min - 1, -1) if need(k, s_for(k)) <= left), None)
        late = new_k is None
        if late:
            new_k = k_min
        new_s = self.scored_frames
        if search_left:
            room = left / slowdown - fixed - per_k * new_k
            fit = int(room // per_s) if per_s > 0 else self.scored_frames
            new_s = max(s_for(new_k), min(self.scored_frames, fit))
        if new_k >= self.keyframes and new_s >= self.scored_frames and not late:
            self.trace.event("deadline", f"{why}; remaining stages still fit ({left:.0f} ms left, slowdown "
                             f"x{slowdown:.2f})", stage=why.split()[1] if why.startswith("stage") else None)
            return False
        old = (self.keyframes, self.scored_frames, self.batch_size)
        self.keyframes, self.scored_frames = new_k, new_s
        self.iterations = max(1, min(self.iterations, new_s))
        self.batch_size = int(math.ceil(new_s / self.iterations))
        self.reduced = True
        msg = (f"reduced plan: {why}; {left:.0f} ms left, observed slowdown x{slowdown:.2f}: key frames "
               f"{old[0]} -> {new_k}" + (f", scored frames {old[1]} -> {new_s}, batch {old[2]} -> "
                                           f"{self.batch_size}" if search_left else ""))
        if late:
            msg += f"; even {new_k} key frames will overrun the {self.budget_ms:.0f} ms budget"
        self.reasons.append(msg)
        self.trace.event("replan", msg, warn=True, keyframes=new_k, scored_frames=new_s,
                         batch_size=self.batch_size, slowdown=round(slowdown, 3), remaining_ms=round(left, 1))
        self.trace.decide("budget.reduced_plan", True)
        self.trace.decide("budget.keyframes", new_k)
        return True

    # ------------------------------------------------------------------ memory
    def headroom_mb(self) -> float:
        return self.memory_budget_mb - self._rss()

    def register_session(self, name: str, mb: float, release: Callable[[], None]) -> None:
        """Make a loaded session releasable by the guard. `release` must drop every reference to it."""
        self.sessions[name] = _Session(name, float(mb), release, self._current)

    def touch_session(self, name: str) -> None:
        """Mark a session as used by the current stage (idle = not used by it)."""
        if name in self.sessions:
            self.sessions[name].last_stage = self._current
            self.sessions[name].released = False

    def release_idle(self, keep: Sequence[str] = (), *, need_mb: float | None = None) -> list[str]:
        """Release sessions not in `keep` and not used by the current stage (largest first, until `need_mb` is
        free if given). Returns the names released; each is a trace event."""
        import gc

        out = []
        idle = sorted((s for s in self.sessions.values() if not s.released and s.name not in keep
                       and (self._current is None or s.last_stage != self._current)), key=lambda s: -s.mb)
        for s in idle:
            if need_mb is not None and self.headroom_mb() >= need_mb:
                break
            s.release()
            s.released = True
            gc.collect()
            out.append(s.name)
            self.trace.event("memory_guard", f"released idle session {s.name} (~{s.mb:.0f} MB) to keep within "
                             f"the {self.memory_budget_mb:.0f} MB budget", session=s.name,
                             rss_mb=round(self._rss(), 1))
        return out

    def check_headroom(self, mb_needed: float, what: str = "", keep: Sequence[str] = ()) -> bool:
        """Before loading a model or adding key frames: is there `mb_needed` MB below the memory budget?
        If not, release idle sessions and check again. False (recorded in the trace) means: do not do it."""
        if self.headroom_mb() >= mb_needed:
            return True
        released = self.release_idle(keep, need_mb=mb_needed)
        ok = self.headroom_mb() >= mb_needed
        if not ok:
            self.reduced = True
            msg = (f"memory guard: {what or 'allocation'} needs {mb_needed:.0f} MB but only "
                   f"{self.headroom_mb():.0f} MB are left of the {self.memory_budget_mb:.0f} MB budget "
                   f"(RSS {self._rss():.0f} MB" + (f", after releasing {', '.join(released)}" if released else "")
                   + ")")
            self.reasons.append(msg)
            self.trace.event("memory_guard", msg, warn=True, needed_mb=round(mb_needed, 1),
                             rss_mb=round(self._rss(), 1))
            self.trace.decide("budget.reduced_plan", True)
        return ok

    def allow_keyframes(self, k: int, held: int = 0) -> int:
        """How many key frames (in total, of the `k` wanted) to process now: at most the current plan's K and
        what the memory headroom holds at the plan's MB per key frame beyond the `held` ones already in memory.
        Lowering it is a reduced plan (trace event); at least min(k, keyframes_min) unless memory is exhausted."""
        allowed = min(k, self.keyframes)
        per = self.plan.keyframe_mb
        if per > 0:
            room = held + int(max(0.0, self.headroom_mb()) // per)
            if room < allowed:  # try releasing idle sessions before lowering K
                self.release_idle(need_mb=(allowed - held) * per)
                room = held + int(max(0.0, self.headroom_mb()) // per)
                allowed = min(allowed, room)
        if allowed < k:
            msg = (f"key frames {k} -> {allowed} (plan K {self.keyframes}, headroom {self.headroom_mb():.0f} MB at "
                   f"{per:g} MB per key frame)")
            if allowed < min(k, self.keyframes):
                self.reduced = True
                self.reasons.append("memory guard: " + msg)
                self.trace.event("memory_guard", msg, warn=True, keyframes=allowed)
                self.trace.decide("budget.reduced_plan", True)
        return max(0, allowed)

    def summary(self) -> dict[str, Any]:
        """For the answer/trace: reduced flag, reasons, per-stage spent vs planned ms and peak RSS."""
        return {"reduced_plan": self.reduced, "reasons": list(self.reasons), "keyframes": self.keyframes,
                "scored_frames": self.scored_frames, "elapsed_ms": round(self.elapsed_ms(), 1),
                "latency_budget_ms": self.budget_ms, "memory_budget_mb": self.memory_budget_mb,
                "stages": {n: {"spent_ms": round(v, 1), "planned_ms": round(self.share_ms(n), 1)
                               if n in self.plan.stages else None, "peak_rss_mb": round(self.peaks.get(n, 0.0), 1)}
                           for n, v in self.done.items()}}


def clip_of(source: Any, fps: float | None = None) -> tuple[float, float]:
    """(duration s, fps) of a frames.FrameSource from its timestamps (`fps` when they cannot tell)."""
    n = len(source)
    ts = getattr(source, "timestamps", None)
    if ts is not None and n > 1 and float(ts[-1] - ts[0]) > 0:
        f = (n - 1) / float(ts[-1] - ts[0])
    elif fps:
        f = float(fps)
    else:
        raise InputError(f"{getattr(source, 'name', 'source')}: cannot tell its frame rate; give `fps`",
                         fields=("fps",))
    return n / f, f


def controller_for(profile: Profile | str | os.PathLike, source: Any, trace: Trace, bundle: Any = None,
                   conf: PlanConf | Mapping[str, Any] | None = None) -> BudgetController:
    """Plan for a frame source under a profile and return the run-time controller (the pipeline's entry point).
    The plan is recorded in the trace (`decisions["budget.plan"]`); BudgetError when nothing fits."""
    duration, fps = clip_of(source)
    return BudgetController(plan(profile, duration, fps, bundle, conf), trace)


# ------------------------------------------------------------------------------------------ `mosaic plan`


COMMON_FLAGS = ("bundle", "profile")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from .commands.flags import add_answerer, add_clip

    src = parser.add_argument_group("clip (one of)")
    src.add_argument("--video", metavar="V", help="video, image folder or RGB-D folder: its length and fps")
    add_clip(src, None, None, "clip (with --fps; or the --fps of an image folder)")
    parser.add_argument("--candidates", type=int, help="frames kept by redundant-frame removal, if known "
                                                       "(default: an estimate)")
    parser.add_argument("--keyframes-max", type=int, help="upper bound for K (default 32)")
    parser.add_argument("--online", action="store_true",
                        help="decode + dedup run while the video is captured: not in the per-question latency")
    add_answerer(parser, "the answerer `mosaic ask` will use: vlm or auto (default) plan the VLM's costs when the "
                         "profile and bundle have one (auto: the VLM answers what the map reasoner does not "
                         "recognise); map: the map reasoner only, no VLM costs")
    parser.add_argument("--models", choices=MODEL_SETS, default="shared",
                        help="cost set: shared (the shared mobile models) or paper (the paper's models at real "
                             "size, [paper_costs.*]); --profile all plans every profile in profiles/")


def _clip_from_args(args: argparse.Namespace) -> tuple[float, float]:
    if args.video:
        if args.duration:
            raise InputError("give either --video or --duration, not both")
        from .frames import open_source

        return clip_of(open_source(args.video, **({"fps": args.fps} if args.fps else {})), args.fps)
    if args.duration is None or args.fps is None:
        raise InputError("mosaic plan needs --video V, or --duration S and --fps F")
    return float(args.duration), float(args.fps)


def run(args: argparse.Namespace) -> dict[str, Any]:
    if not args.profile:
        raise InputError("mosaic plan needs --profile (a file, or a name from profiles/: "
                         + ", ".join(p.stem for p in list_profiles()) + ")")
    duration, fps = _clip_from_args(args)
    conf = PlanConf.merged(keyframes_max=args.keyframes_max, use_vlm=args.answerer != "map",
                           video_pass="online" if args.online else "question")
    if args.profile == "all":  # K for every profile of profiles/ (those that cannot plan say why)
        rows = {}
        for path in list_profiles():
            try:
                p = plan(path, duration, fps, bundle=args.bundle, conf=conf, candidates=args.candidates,
                         models=args.models)
                rows[path.stem] = {"keyframes": p.keyframes, "limited_by": p.limited_by, "planned_ms": p.total_ms}
            except MosaicError as e:
                rows[path.stem] = {"keyframes": None, "error": str(e)}
        return {"schema": "mosaicthinker.plan-all/1", "models": args.models, "profiles": rows}
    p = plan(args.profile, duration, fps, bundle=args.bundle, conf=conf, candidates=args.candidates,
             models=args.models)
    d = p.to_dict()
    d["models"] = args.models
    return d


def render(result: dict[str, Any]) -> str:
    r = result
    if r.get("schema") == "mosaicthinker.plan-all/1":
        return "\n".join([f"key frames K per profile ({r['models']} models):"] + [
            f"  {n:<26} " + (f"K = {x['keyframes']:>3}  (limited by {x['limited_by']}, {x['planned_ms']:,.0f} ms)"
                             if x.get("keyframes") is not None else f"cannot plan: {x['error'][:150]}")
            for n, x in r["profiles"].items()])
    v = r["video"]
    lines = [f"plan for {r['profile']} ({r['device']})",
             f"clip {v['duration_s']:g} s at {v['fps']:g} fps = {v['frames']} frames, {v['candidates']} candidates"
             + (" (video pass online, during capture)" if v.get("pass") == "online" else "")
             + (f"; bundle {r['bundle']} ({r['bundle_hash']})" if r.get("bundle") else ""), "",
             f"  key frames K      {r['keyframes']:>8}   (limited by {r['limited_by']})",
             f"  scored frames S   {r['scored_frames']:>8}   ({100 * r['scored_fraction']:.1f}% of candidates, "
             f"{r['iterations']} iterations x {r['batch_size']})",
             f"  latency           {r['planned_ms']:>8,.0f} ms of {r['latency_budget_ms']:,.0f} ms "
             f"(slack {r['slack_ms']:,.0f} ms)",
             f"  memory            {r['planned_memory_mb']:>8,.0f} MB of {r['memory_budget_mb']:,.0f} MB "
             f"({r['session_policy']})", "",
             f"  {'stage':<12} {'fixed ms':>10} {'ms / key fr':>11} {'ms / scored':>11} {'planned ms':>11}"]
    for n, st in r["stages"].items():
        lines.append(f"  {n:<12} {st['fixed_ms']:>10,.1f} {st['per_keyframe_ms']:>11,.1f} "
                     f"{st['per_scored_ms']:>11,.1f} {st['planned_ms']:>11,.1f}")
    lines += ["", f"  {'role':<10} {'provider (device)':<28} {'here':<22} {'precision':<13} {'input W x H'}"]
    for role, pv in r["providers"].items():
        size = r["resolutions"].get(role)
        lines.append(f"  {role:<10} {pv['device']:<28} {pv['here']:<22} {pv['precision']:<13} "
                     f"{'x'.join(map(str, size)) if size else '-'}")
    lines += ["", "arithmetic:"] + [f"  {a}" for a in r["arithmetic"]]
    lines += ["", "cost sources:"] + [f"  {n:<15} {s}" for n, s in r["cost_status"].items()]
    if r["notes"]:
        lines += ["", "notes:"] + [f"  - {n}" for n in r["notes"]]
    return "\n".join(lines)
