"""The planner: how many key frames K (and scored frames S) one question can afford under a device profile.

`plan` splits the per-question latency budget into

    (1) fixed      model loads + video pass (decode + dedup per frame) + grounding + VLM (images, decoding)
    (2) search     scored frames S x detector cost (the iterative key-frame search of keyframes.py)
    (3) key frames K x (instance segmenter + segmenter + prompts + depth + embedder + features + matching + geometry
                       [+ VLM images])

and picks the largest K (<= PlanConf.keyframes_max) whose latency *and* memory fit, giving the search at least
`plan_min_scored_per_keyframe * K` frames, then as many more as the slack allows up to `budget_fraction` of the
candidates. Nothing fitting raises BudgetError naming the budget and the shortfall. `clip_of` is the one
computation of a frame source's duration and frame rate (the planner's and `ask`'s).
"""
from __future__ import annotations

import math
import os
from dataclasses import asdict, dataclass, field
from typing import Any, ClassVar, Mapping

from ..infra.config import StageConf
from ..infra.errors import BudgetError, InputError
from ..keyframes import KeyFrameConf, scored_budget
from ..models.vlm import VLMConfig
from .profile import MODEL_COSTS, Profile, load_profile, nearest_variant
from ..infra.bundle import load_bundle
from ..infra.bundle import bundle_hash

PLAN_SCHEMA = "mosaicthinker.plan/1"
MAX_CLIP_S = 86400.0      # 24 h: longer clips are not one question's video (and overflow frame counts)
MAX_FPS = 1000.0
MIN_MAP_FRAMES = 2        # alignment needs two views
STARTS = ("cold", "warm")
SEARCH = KeyFrameConf()  # the key-frame search's own settings (fraction scored, iterations): one owner


@dataclass
class PlanConf(StageConf):
    """Planner parameters (device independent; the profile only sets budgets and costs).
    `PlanConf.merged(mapping_or_conf, **overrides)` (None overrides are ignored; unknown keys are an error)."""

    conf_name: ClassVar[str] = "plan config"

    keyframes_max: int = 32            # K never exceeds this (the map gains little beyond it)
    keyframes_min: int = 2             # alignment needs two frames; below this nothing fits
    plan_min_scored_per_keyframe: int = 4  # the search scores at least this many frames per key frame wanted
    max_scored_frames: int | None = None
    plan_max_scored_per_keyframe: float | None = 6.0  # ... at most this many whatever the duration (None: no cap)
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
    # cold: every question loads its models (one `mosaic ask` process per question: what the controller sees);
    # warm: a deployed app keeps its sessions open between questions, so the loads are a one-time cold start,
    # unless the resident set does not fit the memory budget (then sessions are re-opened and loads come back)
    start: str = "cold"

    def validate(self) -> None:
        c = self
        if c.keyframes_min < 1 or c.keyframes_max < c.keyframes_min:
            raise InputError(f"plan config: need 1 <= keyframes_min <= keyframes_max (got {c.keyframes_min}, "
                             f"{c.keyframes_max})")
        if not 0 < c.dedup_keep_fraction <= 1:
            raise InputError("plan config: dedup_keep_fraction must be in (0, 1]")
        if c.video_pass not in ("question", "online"):
            raise InputError(f"plan config: video_pass must be 'question' or 'online' (got {c.video_pass!r})")
        if c.start not in STARTS:
            raise InputError(f"plan config: start must be 'cold' or 'warm' (got {c.start!r})")
        if not 0 <= c.safety_fraction < 1 or c.plan_min_scored_per_keyframe < 1:
            raise InputError("plan config: need 0 <= safety_fraction < 1, plan_min_scored_per_keyframe >= 1")
        if c.plan_max_scored_per_keyframe is not None and \
                not c.plan_max_scored_per_keyframe >= c.plan_min_scored_per_keyframe:
            raise InputError(f"plan config: plan_max_scored_per_keyframe must be >= plan_min_scored_per_keyframe "
                             f"({c.plan_min_scored_per_keyframe}; got {c.plan_max_scored_per_keyframe})")


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
    cold_start_ms: float = 0.0     # every model load once: the app's start (inside each question when cold)
    resident_mb: float = 0.0       # every session open at once: what a warm app holds between questions

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
            "session_policy": self.session_policy, "start": self.conf.start,
            "cold_start_ms": round(self.cold_start_ms, 1), "resident_mb": round(self.resident_mb, 1),
            "loads_per_question_ms": round(self.fixed_ms.get("model_loads", 0.0), 1),
            "stages": {n: {**st.to_dict(), "planned_ms": round(st.ms(k, s), 1)} for n, st in self.stages.items()},
            "providers": self.providers, "resolutions": self.resolutions, "cost_status": self.cost_status,
            "arithmetic": self.arithmetic, "notes": self.notes, "conf": asdict(self.conf),
        }


def _fmt(x: float) -> str:
    return f"{x:,.0f}" if abs(x) >= 100 else f"{x:,.1f}" if abs(x) >= 10 else f"{x:,.2f}"


def _bundle_roles(bundle: Any) -> tuple[Any, list[str]]:
    b = load_bundle(bundle, verify=False)
    return b, b.roles


def _check_clip(duration_s: float, fps: float, candidates: int | None) -> None:
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


def _roles_used(prof: Profile, broles: list[str] | None, c: PlanConf, notes: list[str]) -> dict[str, bool]:
    """The model roles the plan counts: the profile costs them, the bundle (if given) has them, the VLM is wanted."""
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
    return used


@dataclass
class _Terms:
    """The plan's cost terms: fixed ms, ms per scored frame (c_s) and per key frame (c_k), memory in MB."""

    prof: Profile
    c: PlanConf
    used: dict[str, bool]
    fps: float
    total_frames: int
    n_c: int                 # candidates
    loads: dict[str, float] = field(default_factory=dict)
    load_total: float = 0.0  # every model loaded once (the cold start)
    per_frame_ms: float = 0.0
    video_ms: float = 0.0
    online_factor: float = 0.0
    vlm_fixed: float = 0.0
    fixed: dict[str, float] = field(default_factory=dict)
    c_s: float = 0.0
    per_kf: dict[str, float] = field(default_factory=dict)
    c_k: float = 0.0
    F: float = 0.0           # fixed total
    L: float = 0.0           # latency budget less the safety share
    kf_mb: float = 0.0
    base_mb: float = 0.0
    res: dict[str, float] = field(default_factory=dict)
    M: float = 0.0           # memory budget

    def cost(self, name: str, key: str) -> float:
        e = self.prof.cost(name)
        if e is None or (name in MODEL_COSTS and not self.used.get(name)):
            return 0.0
        return e.get(key)

    def s_floor(self, k: int) -> int:
        return min(self.n_c, self.c.plan_min_scored_per_keyframe * k)

    def s_target(self, k: int) -> int:
        c = self.c
        t = scored_budget(self.n_c, k, SEARCH.budget_fraction, c.plan_min_scored_per_keyframe,
                          c.plan_max_scored_per_keyframe)
        if c.max_scored_frames is not None:
            t = max(min(t, c.max_scored_frames), self.s_floor(k))
        return min(self.n_c, t)

    def lat(self, k: int, s: int) -> float:
        return self.F + s * self.c_s + k * self.c_k

    def loads_in_question(self, policy: str) -> float:
        """Model-load ms inside one question. Warm sessions that all stay resident were loaded at the app's start;
        when they cannot (one at a time), the memory guard releases and re-opens them, so each question pays the
        loads again - as does every cold question."""
        return 0.0 if self.c.start == "warm" and policy == "all_resident" else self.load_total

    def use(self, policy: str) -> None:
        """Settle the session policy: it decides whether the loads are part of the question's fixed cost."""
        self.fixed["model_loads"] = self.loads_in_question(policy)
        self.F = sum(self.fixed.values())

    def fits(self, k: int, models_mb: float) -> bool:
        return self.lat(k, self.s_floor(k)) <= self.L and self.base_mb + models_mb + k * self.kf_mb <= self.M


def _terms(prof: Profile, c: PlanConf, used: dict[str, bool], fps: float, total_frames: int, n_c: int,
           notes: list[str], template_grounding_ms: float) -> _Terms:
    t = _Terms(prof, c, used, fps, total_frames, n_c)
    cost = t.cost
    # (1) fixed costs
    t.loads = {r: cost(r, "load_ms") for r in MODEL_COSTS if used[r]}
    t.load_total = sum(t.loads.values())
    t.per_frame_ms = cost("dedup", "ms_per_call")  # the pass decodes what it needs itself
    t.video_ms = total_frames * t.per_frame_ms
    t.online_factor = t.per_frame_ms * fps / 1000.0  # share of real time the online video pass needs
    if c.video_pass == "online":
        t.video_ms = 0.0
        if t.online_factor > 1:
            notes.append(f"online video pass: dedup (with its decoding) takes {_fmt(t.per_frame_ms)} ms per frame, "
                         f"more than the "
                         f"{_fmt(1000 / fps)} ms between frames at {fps:g} fps: it cannot keep up with capture "
                         f"(x{t.online_factor:.2f} real time)")
    t.vlm_fixed = c.vlm_images * cost("vlm", "ms_per_image") + c.vlm_max_new_tokens * cost("vlm", "ms_per_token")
    # a model set's grounding figure may be its VLM's grounding call ([paper_costs.grounding]); without a VLM
    # the pipeline grounds with the template parser, the shared [costs.grounding]
    grounding = cost("grounding", "ms_per_call") if used.get("vlm") else template_grounding_ms
    t.fixed = {"model_loads": t.load_total, "video_pass": t.video_ms, "grounding": grounding,
               "vlm_answer": t.vlm_fixed}
    # (2) search, per scored frame: fetching the frame (one decode) + the detector
    t.c_s = cost("detector", "ms_per_call") + cost("video_decode", "ms_per_call")
    # (3) per key frame
    t.per_kf = {"decode": cost("video_decode", "ms_per_call"),  # key frames are fetched again for perception
                "instance_segmenter": cost("instance_segmenter", "ms_per_call"),
                "segmenter": cost("segmenter", "ms_per_call")
                + c.prompts_per_keyframe * cost("segmenter", "ms_per_prompt"),
                "depth": cost("depth", "ms_per_call"), "embedder": cost("embedder", "ms_per_call"),
                "features": cost("matcher", "ms_per_call"),
                "matching": c.pairs_per_keyframe * cost("matcher", "ms_per_pair"),
                "geometry": cost("geometry", "ms_per_call"),
                "refine": cost("refine", "ms_per_call"),
                "vlm_images": c.vlm_images_per_keyframe * cost("vlm", "ms_per_image")}
    t.c_k = sum(t.per_kf.values())
    t.F = sum(t.fixed.values())
    t.L = prof.latency_budget_ms * (1 - c.safety_fraction)
    # memory: process + models (all resident, or one at a time) + K x key-frame state
    t.kf_mb = cost("keyframe_state", "mb_per_call")
    t.base_mb = cost("process", "resident_mb")
    t.res = {r: cost(r, "resident_mb") for r in MODEL_COSTS if used[r]}
    t.M = prof.memory_budget_mb
    return t


def _largest_k(t: _Terms, models_mb: float) -> int | None:
    k_cap = min(t.c.keyframes_max, t.n_c)
    k_lo = min(t.c.keyframes_min, t.n_c)
    return next((k for k in range(k_cap, k_lo - 1, -1) if t.fits(k, models_mb)), None)


def _shortfall(t: _Terms, policy: str, models_mb: float, k: int) -> list[str]:
    """What fails at K = k under a session policy: the latency and/or memory budget, by how much, and its terms."""
    t.use(policy)
    parts = []
    over_l = t.lat(k, t.s_floor(k)) - t.L
    over_m = t.base_mb + models_mb + k * t.kf_mb - t.M
    if over_l > 0:
        parts.append(f"latency budget {_fmt(t.L)} ms fails by {_fmt(over_l)} ms: fixed {_fmt(t.F)} ms "
                     f"(loads {_fmt(t.fixed['model_loads'])}, video pass {_fmt(t.video_ms)} over {t.total_frames} "
                     f"frames, grounding {_fmt(t.fixed['grounding'])}, VLM {_fmt(t.vlm_fixed)}) + search "
                     f"{t.s_floor(k)} x {_fmt(t.c_s)} ms + {k} key frames x {_fmt(t.c_k)} ms")
    if over_m > 0:
        parts.append(f"memory budget {_fmt(t.M)} MB fails by {_fmt(over_m)} MB: runtime {_fmt(t.base_mb)} + models "
                     f"{_fmt(models_mb)} ({policy}) + {k} key frames x {_fmt(t.kf_mb)} MB")
    return parts


def _largest_terms(t: _Terms, k: int, n: int = 3) -> str:
    """The n largest latency terms at K = k under the settled policy: what would have to shrink to fit."""
    s = t.s_floor(k)
    terms = {"model loads": t.fixed["model_loads"], "video pass": t.video_ms, "grounding": t.fixed["grounding"],
             "VLM answer": t.vlm_fixed, f"search {s} x (detector + decode)": s * t.c_s,
             **{f"{name} x {k} key frames": k * v for name, v in t.per_kf.items()}}
    top = sorted(((v, name) for name, v in terms.items() if v > 0), reverse=True)[:n]
    return ", ".join(f"{name} {_fmt(v)} ms" for v, name in top)


def _nothing_fits(t: _Terms, policy: str, models_mb: float) -> BudgetError:
    """The error when even keyframes_min fails: which budget, by how much, the terms that make it up and the
    largest of them. Cold: for the leanest policy. Warm: with every session resident (no loads) and, where
    that cannot fit the memory, one at a time (the loads back in the question)."""
    k = min(t.c.keyframes_min, t.n_c)
    one = ("one_at_a_time", max(t.res.values(), default=0.0))
    if t.c.start == "cold":
        if len(t.res) > 1:  # the shortfall is reported for the leanest policy
            policy, models_mb = one
        parts, head = _shortfall(t, policy, models_mb, k), ""
    else:
        parts = [f"with every session resident (no loads in the question): "
                 + "; ".join(_shortfall(t, "all_resident", sum(t.res.values()), k))]
        if len(t.res) > 1:
            parts.append("one session at a time (released and re-opened: the loads back in every question): "
                         + "; ".join(_shortfall(t, *one, k)))
        policy, head = "all_resident", " (warm start)"
    t.use(policy)
    hint = (" (or plan with --online: decode + dedup while the video is captured)"
            if t.c.video_pass == "question" and t.video_ms > t.L / 2 else "")
    return BudgetError(f"profile {t.prof.name}: nothing fits even at K = {k} key frames{head}: " + "; ".join(parts)
                       + f". Largest terms ({policy}): {_largest_terms(t, k)}. Raise the budget, use a shorter "
                       f"clip or a cheaper bundle variant" + hint + ".")


def _choose_k(t: _Terms, notes: list[str]) -> tuple[int, str, float, str]:
    """(K, session policy, models MB, what limits K). All sessions resident, unless loading them one at a time
    (stage-major) allows more key frames. BudgetError when nothing fits."""
    all_mb, one_mb = sum(t.res.values()), max(t.res.values(), default=0.0)
    policy, models_mb = "all_resident", all_mb
    t.use("all_resident")
    chosen = _largest_k(t, all_mb)
    k_one = None
    if len(t.res) > 1:
        t.use("one_at_a_time")
        k_one = _largest_k(t, one_mb)
    if k_one is not None and (chosen is None or k_one > chosen):
        policy, models_mb, chosen = "one_at_a_time", one_mb, k_one
        notes.append(f"memory: all models together ({_fmt(all_mb)} MB) leave room for fewer key frames; sessions "
                     f"are loaded one at a time, stage-major (each stage runs over all key frames, then its "
                     f"session is released)")
    if chosen is None:
        raise _nothing_fits(t, policy, models_mb)
    t.use(policy)
    _start_note(t, policy, all_mb, notes)
    K = chosen
    if K == t.c.keyframes_max:
        why = f"keyframes_max ({t.c.keyframes_max})"
    elif K == t.n_c:
        why = f"candidates ({t.n_c})"
    else:
        nxt = K + 1
        l_fail = t.lat(nxt, t.s_floor(nxt)) > t.L
        m_fail = t.base_mb + models_mb + nxt * t.kf_mb > t.M
        why = " and ".join(w for w, f in (("latency", l_fail), ("memory", m_fail)) if f)
    return K, policy, models_mb, why


def _start_note(t: _Terms, policy: str, all_mb: float, notes: list[str]) -> None:
    """Warm start: say where the loads went (the cold start) or why they are back in every question."""
    if t.c.start != "warm" or not t.loads:
        return
    if policy == "all_resident":
        notes.append(f"warm start: the {len(t.res)} sessions ({_fmt(all_mb)} MB) stay open between questions; "
                     f"their loads ({_fmt(t.load_total)} ms) are the app's cold start, not in the question")
    else:
        notes.append(f"warm start asked, but the resident set ({_fmt(all_mb)} MB) with the runtime and the key "
                     f"frames does not fit the memory budget ({_fmt(t.M)} MB): the memory guard releases and "
                     f"re-opens sessions, so the loads ({_fmt(t.load_total)} ms) are in every question")


def _stage_budgets(t: _Terms) -> dict[str, StageBudget]:
    """Each runtime stage's share as fixed + per key frame + per scored frame ms (the controller's deadlines)."""
    kf = t.per_kf
    return {
        "load": StageBudget("load", fixed_ms=t.fixed["model_loads"]),
        "frames": StageBudget("frames", fixed_ms=t.video_ms),
        "grounding": StageBudget("grounding", fixed_ms=t.fixed["grounding"]),
        "keyframes": StageBudget("keyframes", per_scored_ms=t.c_s),
        "perception": StageBudget("perception", per_keyframe_ms=kf["decode"] + kf["instance_segmenter"]
                                  + kf["segmenter"] + kf["depth"] + kf["embedder"] + kf["features"]),
        "alignment": StageBudget("alignment", per_keyframe_ms=kf["matching"] + kf["geometry"]
                                 + kf["refine"]),
        "answer": StageBudget("answer", fixed_ms=t.vlm_fixed, per_keyframe_ms=kf["vlm_images"]),
    }


def _providers_and_sizes(prof: Profile, used: dict[str, bool], b: Any,
                         notes: list[str]) -> tuple[dict[str, dict[str, Any]], dict[str, Any]]:
    """Per role: the device's provider chain, the one usable here, the precision and the bundle variant that will
    run (the nearest one the bundle has, said in the notes); and its input size [W, H]."""
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
    return providers, resolutions


def _cost_notes(prof: Profile, bhash: str | None, notes: list[str]) -> dict[str, str]:
    """Where each cost figure comes from; notes for figures measured on another bundle and for estimates."""
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
    return cost_status


def _loads_line(t: _Terms) -> str:
    """The arithmetic's first line: the model loads inside the question (none for resident warm sessions)."""
    if not t.loads:
        return "fixed = no model loads"
    each = " + ".join(f"{r} {_fmt(v)}" for r, v in t.loads.items()) + f" = {_fmt(t.load_total)} ms"
    if t.c.start == "cold":
        return f"fixed = loads {each}"
    if t.fixed["model_loads"] == 0:
        return f"fixed = loads 0 ms (warm start: {each} once, at the app's start)"
    return f"fixed = loads {each} (warm start, but re-opened in every question: the sessions cannot stay resident)"


def _arithmetic(t: _Terms, cand_how: str, K: int, S: int, s_max_fit: int, iters: int, batch: int, policy: str,
                models_mb: float, why: str, mem: dict[str, float]) -> list[str]:
    """The plan's arithmetic, as the user reads it (`mosaic plan`)."""
    c, cost, _f = t.c, t.cost, _fmt
    arith = [f"candidates = {cand_how} = {t.n_c}"]
    arith.append(_loads_line(t))
    arith.append(f"      + video pass (decode + dedup) {t.total_frames} frames x {_f(t.per_frame_ms)} ms = "
                 f"{_f(t.video_ms)} ms" if c.video_pass == "question"
                 else f"      + video pass 0 ms (online, during capture: {_f(t.per_frame_ms)} ms per frame = "
                      f"x{t.online_factor:.2f} real time)")
    arith.append(f"      + grounding {_f(t.fixed['grounding'])} ms")
    arith.append(f"      + VLM {c.vlm_images} image x {_f(cost('vlm', 'ms_per_image'))} ms + "
                 f"{c.vlm_max_new_tokens} tokens x {_f(cost('vlm', 'ms_per_token'))} ms = {_f(t.vlm_fixed)} ms"
                 if t.used.get("vlm") else "      + VLM 0 ms (not used: map reasoner)")
    arith.append(f"      = {_f(t.F)} ms")
    arith.append("per key frame = " + " + ".join(f"{n} {_f(v)}" for n, v in t.per_kf.items() if v)
                 + f" = {_f(t.c_k)} ms   (segmenter incl. {c.prompts_per_keyframe:g} prompts, matching "
                   f"{c.pairs_per_keyframe:g} pairs)")
    arith.append(f"K = largest k <= min(keyframes_max {c.keyframes_max}, candidates {t.n_c}) with "
                 f"fixed + {c.plan_min_scored_per_keyframe}k x {_f(t.c_s)} (decode + detector) + k x {_f(t.c_k)} "
                 f"<= {_f(t.L)} ms and "
                 f"{_f(t.base_mb)} + {_f(models_mb)} + k x {_f(t.kf_mb)} <= {_f(t.M)} MB  ->  K = {K} "
                 f"(limited by {why})")
    arith.append(f"search S = min(target {t.s_target(K)}, floor(({_f(t.L)} - {_f(t.F)} - {K} x {_f(t.c_k)}) / "
                 f"{_f(t.c_s)}) = {s_max_fit if t.c_s > 0 else 'inf'}), at least {t.s_floor(K)}  ->  S = {S} scored "
                 f"frames in {iters} iterations of {batch}")
    total = t.lat(K, S)
    budget_ms = t.prof.latency_budget_ms
    arith.append(f"latency = {_f(t.F)} + {S} x {_f(t.c_s)} + {K} x {_f(t.c_k)} = {_f(total)} ms of "
                 f"{_f(budget_ms)} ms (slack {_f(budget_ms - total)} ms)")
    arith.append(f"memory = runtime {_f(t.base_mb)} + models {_f(models_mb)} ({policy}) + {K} x {_f(t.kf_mb)} "
                 f"= {_f(sum(mem.values()))} MB of {_f(t.M)} MB")
    return arith


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
    shared = profile if isinstance(profile, Profile) else load_profile(profile)
    prof = shared.with_models(models)
    c = conf if isinstance(conf, PlanConf) else PlanConf.merged(conf)
    _check_clip(duration_s, fps, candidates)
    notes: list[str] = []
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
    used = _roles_used(prof, broles, c, notes)
    g = shared.cost("grounding")
    t = _terms(prof, c, used, fps, total_frames, n_c, notes, g.get("ms_per_call") if g is not None else 0.0)
    K, policy, models_mb, why = _choose_k(t, notes)
    # the search gets what the key frames leave, at least its floor, at most its target
    slack = t.L - t.F - K * t.c_k
    s_max_fit = int(math.floor(slack / t.c_s)) if t.c_s > 0 else n_c
    S = max(t.s_floor(K), min(t.s_target(K), s_max_fit))
    if S < t.s_target(K):
        notes.append(f"search: {S} scored frames instead of the target {t.s_target(K)} "
                     f"({SEARCH.budget_fraction:g} of {n_c} candidates): the latency budget limits it")
    iters = max(1, min(SEARCH.iterations, S))
    batch = int(math.ceil(S / iters))
    mem = {"process": t.base_mb, "models": models_mb, "keyframes": K * t.kf_mb}
    providers, resolutions = _providers_and_sizes(prof, used, b, notes)
    cost_status = _cost_notes(prof, bhash, notes)
    arith = _arithmetic(t, cand_how, K, S, s_max_fit, iters, batch, policy, models_mb, why, mem)
    if S < SEARCH.iterations:
        notes.append(f"search: only {S} frames to score, so {iters} iterations of 1")
    return Plan(profile=prof.name, device=prof.device.get("description", prof.name), duration_s=float(duration_s),
                fps=float(fps), total_frames=total_frames, candidates=n_c, keyframes=K, scored_frames=S,
                iterations=iters, batch_size=batch, latency_budget_ms=prof.latency_budget_ms,
                memory_budget_mb=t.M, stages=_stage_budgets(t), fixed_ms=t.fixed, search_ms=S * t.c_s,
                per_keyframe_ms=t.per_kf, memory_mb=mem, keyframe_mb=t.kf_mb, session_policy=policy,
                limited_by=why, providers=providers, resolutions=resolutions, cost_status=cost_status,
                arithmetic=arith, notes=notes, conf=c, bundle=str(b.root) if b is not None else None,
                bundle_hash=bhash, cold_start_ms=t.load_total, resident_mb=sum(t.res.values()))


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
