"""The key-frame count K of one clip, resolved in this one place, in this order:

1. `requested_keyframes`: the `--keyframes` flag, else the device budget's K (the planner's largest K that fits,
   `PlanConf.keyframes_min` .. `keyframes_max`; the controller lowers it when a stage overruns), else
   `KeyFrameConf.keyframes`; then the budget's memory guard (`allow_keyframes`);
2. `plan_keyframes`, after the scan: at most the budget's K as it then stands, the coverage reserve for a map of
   many names taken out, the search's scored-frame budget and its top-up (`KeyFrameConf.min_keyframes`) derived;
3. `finish_keyframes`, after the search: fewer than `KeyFrameConf.uniform_floor` filled with evenly spaced frames,
   the reserved coverage frames added (`search.spread_keyframes`), and a budget re-planned during the search cuts
   the set to its K (`search.reduce_keyframes`).

Each step that changes K says why in the `StageLog` it is given (only the pipeline writes the trace). The three
"minimum K" settings mean three things, one owner each (docs/settings.md): `KeyFrameConf.min_keyframes` (the
search's top-up target from frames it scored), `KeyFrameConf.uniform_floor` (the evenly spaced last resort) and
`PlanConf.keyframes_min` (the fewest key frames a device plan may have)."""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, Protocol, Sequence

from ..infra.trace import StageLog
from .baselines import uniform_keyframes
from .conf import KeyFrameConf, scored_budget
from .score import KeyFrameResult
from .search import reduce_keyframes, spread_keyframes


def coverage_reserve(K: int, n_names: int, conf: KeyFrameConf) -> int:
    """Key frames kept back from the search for temporal coverage: a map of many categories (an "everything"
    question, `mosaic map`) needs every part of the video, not only the frames dense in detections."""
    if conf.coverage_share <= 0 or n_names < max(conf.coverage_min_names, 1) or K < 4:
        return 0
    return int(min(K - 2, round(conf.coverage_share * K)))


class KeyFrameBudget(Protocol):
    """What the key-frame count reads of a device budget (`budget.BudgetController`): its K and scored frames as
    they stand (after re-plans), why it was last reduced, and its memory guard."""

    keyframes: int
    scored_frames: int
    reasons: list[str]

    def allow_keyframes(self, k: int, held: int = 0) -> int: ...


@dataclass(frozen=True)
class KeyFramePlan:
    """K for one clip, resolved once. k: the key frames the map gets (after the budget); reserve: of which
    `spread_keyframes` picks for temporal coverage; search: the search's config (k - reserve key frames, its
    scored-frame budget and top-up); capped: the note when `max_scored_per_keyframe` lowered the budget."""

    k: int
    reserve: int
    search: KeyFrameConf
    capped: dict[str, Any] | None = None


def plan_keyframes(conf: KeyFrameConf, budget: KeyFrameBudget | None, n_candidates: int, n_frames: int,
                   n_names: int, keyframes: int | None = None) -> KeyFramePlan:
    """K (`keyframes`, else `conf.keyframes`, at most the budget's), the coverage reserve for `n_names` object
    names, the scored-frame budget (the budget's, else `conf.budget`, else `scored_budget` over `n_candidates`)
    and the iterative search's top-up (`topup`: up to its K, frames len/(topup_spacing x K) apart over `n_frames`).
    Pure: reads the budget, changes nothing."""
    K = int(keyframes or conf.keyframes)
    if budget is not None:
        K = min(K, int(budget.keyframes))
    reserve = coverage_reserve(K, n_names, conf)
    scored, capped = conf.budget, None
    if budget is not None:
        scored = int(budget.scored_frames)
    elif scored is None and conf.min_scored_per_keyframe > 0:
        scored = scored_budget(n_candidates, K, conf.budget_fraction, conf.min_scored_per_keyframe,
                               conf.max_scored_per_keyframe)
        uncapped = scored_budget(n_candidates, K, conf.budget_fraction, conf.min_scored_per_keyframe)
        if scored < uncapped:
            capped = {"scored": scored, "fraction_would_score": uncapped,
                      "max_per_keyframe": conf.max_scored_per_keyframe}
    k = K - reserve
    upd: dict[str, Any] = {"keyframes": k, "budget": scored}
    if conf.topup and conf.keyframe_method == "iterative":
        if conf.min_keyframes is None:
            upd["min_keyframes"] = k
        if conf.topup_gap is None:
            upd["topup_gap"] = max(1, n_frames // (conf.topup_spacing * k))
        if conf.topup_relax is None:
            upd["topup_relax"] = False
    search = replace(conf, **upd)
    search.validate()
    return KeyFramePlan(K, reserve, search, capped)


def requested_keyframes(flag: int | None, conf: KeyFrameConf, budget: KeyFrameBudget | None,
                        log: StageLog) -> int:
    """Step 1: K asked for before the scan: `flag`, else the budget's K, else `conf.keyframes`; under a budget,
    what its memory guard allows (a lowering is the controller's reduced plan, recorded by it), decided as
    "budget.keyframes" in `log`."""
    K = int(flag or getattr(budget, "keyframes", None) or conf.keyframes)
    if budget is not None:
        K = int(budget.allow_keyframes(K))
        log.decide("budget.keyframes", K)
    return K


def finish_keyframes(res: KeyFrameResult, plan: KeyFramePlan, cands: Sequence[int], n_names: int,
                     budget: KeyFrameBudget | None, log: StageLog) -> list[int]:
    """Step 3: the key frames perception gets, from the search's `res` (frame indices in time order, as
    `res.chosen`): the uniform floor, the coverage frames of `plan.reserve` and the cut to a budget re-planned
    meanwhile, each said in `log`."""
    chosen = [int(i) for i in res.chosen]
    floor = plan.search.uniform_floor
    if len(chosen) < min(floor, len(cands)):
        extra = [int(i) for i in uniform_keyframes(cands, KeyFrameConf.merged(keyframes=floor)).chosen
                 if int(i) not in chosen]
        chosen = sorted(chosen + extra[:floor - len(chosen)])
        log.event("degraded", f"only {len(res.chosen)} frames passed the key-frame threshold; topped up with "
                  f"{min(floor - len(res.chosen), len(extra))} evenly spaced frames", stage="keyframes")
    if plan.reserve:
        spread = spread_keyframes(chosen, cands, res.scores, plan.reserve)
        log.event("keyframes", f"{n_names} object names: {plan.reserve} of {plan.search.keyframes} key "
                  f"frames reserved for temporal coverage (largest gaps between the search's frames): {spread}",
                  stage="keyframes", coverage=spread)
        chosen = sorted(chosen + spread)
    if budget is not None and len(chosen) > budget.keyframes:  # the search overran and the plan was reduced
        chosen = cut_keyframes(chosen, int(budget.keyframes), budget.reasons, log)
    return chosen


def cut_keyframes(chosen: list[int], k: int, reasons: Sequence[str], log: StageLog) -> list[int]:
    """`search.reduce_keyframes` to `k`, said as a reduced plan with the budget's last reason (`reasons`)."""
    keep = reduce_keyframes(chosen, k)
    why = reasons[-1].removeprefix("reduced plan: ") if reasons else "the budget was re-planned"
    log.event("reduced_plan", f"reduced plan: {len(chosen)} -> {len(keep)} key frames, because {why}",
              stage="keyframes", keyframes=len(keep))
    return keep
