"""The key-frame stage's settings (one owner: K, the search, its budget, the top-up, the coverage reserve); K itself
is resolved in one place, `count.py`. Why each default is what it is: docs/settings.md."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

from ..infra.config import StageConf
from ..infra.errors import InputError

METHODS = ("iterative", "uniform", "random", "exhaustive")


@dataclass
class KeyFrameConf(StageConf):
    """Key-frame selection; defaults follow the paper. Merge overrides with `KeyFrameConf.merged`. The fields the
    pipeline derives per clip are None here (`count.plan_keyframes` resolves them; the search alone reads None as noted)."""

    conf_name: ClassVar[str] = "key-frame config"

    keyframe_method: str = "iterative"  # one of METHODS
    keyframes: int = 16             # K, the key-frame budget (a device budget may lower it)
    # --- the scored-frame budget
    budget: int | None = None       # frames the detector may score; None: derived (`scored_budget`)
    budget_fraction: float = 0.25   # paper: 26% of the frames on LV-Haystack
    min_scored_per_keyframe: int = 3    # ... at least this x K frames (short videos; capped at the candidates)
    max_scored_per_keyframe: float | None = 3.0  # ... at most this x K whatever the duration (None: no cap)
    # --- the search
    threshold: float = 1.5          # z-score threshold (the paper's 1 / 1.5 / 2)
    threshold_mode: str = "z"       # "z": z-score against the scores seen so far; "raw": the score itself
    iterations: int = 20            # search iterations
    batch: int | None = None        # frames per iteration; None -> budget spread evenly over the iterations
    r: int = 3                      # histogram neighbourhood (+-r candidates) and sigma_max = r / k
    k: float = 0.5                  # sigma_min = 1 / k (the paper's 2; 0.5 on the content axis)
    gain: float = 1.0               # kernel amplitude for a frame with the maximum possible score
    target_weight: float = 1.0
    cue_weight: float = 0.5
    hist_bins: int = 8              # bins per RGB channel
    hist_size: int = 64             # images are downscaled to this width before the histogram
    sampling: str = "expected"      # "expected": kernel-weighted expected score; "paper": 1 + sum of kernels
    draw: str = "greedy"            # "greedy": each pick the most probable, counting as explored for the next;
    #                                 "sequential": the same drawn at random; "iid": the paper's batch draw
    prior_weight: float = 1.0       # "expected": pseudo-observations of the mean score at every candidate
    novelty: float = 3.0            # "expected": prior weighted by (gap to the nearest scored frame) ** novelty
    content_prior: bool = True      # distances along the content axis (edge density of every candidate)
    content_floor: float = 0.01     # content axis: an empty view's step (the mean view's is 1 + floor)
    change_power: float = 0.0       # content axis: step ~ edge density x (view change / its mean) ** power (off)
    change_size: int = 32           # view change: width of the grey copies compared (px)
    grid_share: float = 0.0         # share of the budget scored first as an even grid along the axis
    stretch_first: bool = True      # selection: the best frame of each detected stretch first (`stretches`)
    climb: bool = True              # "expected" draws: each batch first takes the climb steps (`climb_steps`)
    cut_margin: float = 0.01        # climb: a box within this share of the image side from its border is cut
    climb_share: float = 0.15       # climb only while detected stretches <= this share of the scored frames
    seed: int = 0
    record_distributions: bool = False
    # --- fewer than K passing the threshold
    topup: bool = True              # the pipeline tops the search up to K from the frames it scored
    min_keyframes: int | None = None    # top up to this many from the best positive frames below the threshold;
                                        # None: K when `topup` (the search alone: 0, the paper's rule)
    topup_spacing: int = 4          # the pipeline's top-up frames at least len(video) / (this x K) frames apart
    topup_gap: int | None = None    # top-up spacing in frame indices (>=); None: from `topup_spacing` (the search
                                    # alone: more than r candidates apart)
    topup_relax: bool | None = None     # after the spaced frames, the top-up may take nearer ones too; None:
                                        # not with `topup` (the search alone: yes)
    cover_min_area: float = 0.02    # top-up coverage: an object counts as well seen from this box-area share
    uniform_floor: int = 3          # fewer key frames than this after the top-up: evenly spaced ones fill up
    # --- a map of many object names keeps part of K for temporal coverage (the search clusters on detections)
    coverage_min_names: int = 4     # a map of this many object names or more (e.g. "everything") ...
    coverage_share: float = 0.5     # ... reserves this share of K for the largest gaps (`spread_keyframes`)

    def validate(self) -> None:
        if self.keyframe_method not in METHODS:
            raise InputError(f"key-frame config: keyframe_method must be one of {', '.join(METHODS)} "
                             f"(got {self.keyframe_method!r})")
        if self.keyframes < 1:
            raise InputError(f"key-frame config: keyframes must be >= 1 (got {self.keyframes})")
        if self.iterations < 1:
            raise InputError(f"key-frame config: iterations must be >= 1 (got {self.iterations})")
        if self.r < 0 or self.k <= 0:
            raise InputError(f"key-frame config: need r >= 0 and k > 0 (got r={self.r}, k={self.k})")
        if not 0 < self.budget_fraction <= 1:
            raise InputError(f"key-frame config: budget_fraction must be in (0, 1] (got {self.budget_fraction})")
        if self.min_keyframes is not None and not 0 <= self.min_keyframes <= self.keyframes:
            raise InputError(f"key-frame config: min_keyframes must be in [0, keyframes] (got {self.min_keyframes})")
        if self.gain < 0:
            raise InputError(f"key-frame config: gain must be >= 0 (got {self.gain})")
        for name in ("budget", "batch"):
            if getattr(self, name) is not None and getattr(self, name) < 1:
                raise InputError(f"key-frame config: {name} must be >= 1 (got {getattr(self, name)})")
        if self.topup_gap is not None and self.topup_gap < 0:
            raise InputError(f"key-frame config: topup_gap must be >= 0 (got {self.topup_gap})")
        if not 0 <= self.cover_min_area <= 1:
            raise InputError(f"key-frame config: cover_min_area must be in [0, 1] (got {self.cover_min_area})")
        for name, val, ok in (("threshold_mode", self.threshold_mode, ("z", "raw")),
                              ("sampling", self.sampling, ("expected", "paper")),
                              ("draw", self.draw, ("sequential", "iid", "greedy"))):
            if val not in ok:
                raise InputError(f"key-frame config: {name} must be one of {', '.join(ok)} (got {val!r})")
        if self.prior_weight <= 0:
            raise InputError(f"key-frame config: prior_weight must be > 0 (got {self.prior_weight})")
        if not 0 <= self.grid_share <= 1:
            raise InputError(f"key-frame config: grid_share must be in [0, 1] (got {self.grid_share})")
        if self.content_floor <= 0:
            raise InputError(f"key-frame config: content_floor must be > 0 (got {self.content_floor})")
        if self.change_power < 0 or self.change_size < 2:
            raise InputError(f"key-frame config: need change_power >= 0 and change_size >= 2 "
                             f"(got {self.change_power}, {self.change_size})")
        for name, val in (("cut_margin", self.cut_margin), ("climb_share", self.climb_share)):
            if not 0 <= val <= 1:
                raise InputError(f"key-frame config: {name} must be in [0, 1] (got {val})")
        if self.uniform_floor < 0 or self.min_scored_per_keyframe < 0:
            raise InputError("key-frame config: uniform_floor and min_scored_per_keyframe must be >= 0")
        if self.max_scored_per_keyframe is not None and not self.max_scored_per_keyframe >= self.min_scored_per_keyframe:
            raise InputError(f"key-frame config: max_scored_per_keyframe must be >= min_scored_per_keyframe "
                             f"({self.min_scored_per_keyframe}; got {self.max_scored_per_keyframe}) or null")
        if self.topup_spacing < 1:
            raise InputError(f"key-frame config: topup_spacing must be >= 1 (got {self.topup_spacing})")

    @property
    def sigma_min(self) -> float:
        return 1.0 / self.k

    @property
    def sigma_max(self) -> float:
        return max(self.r, 1) / self.k


def scored_budget(n_candidates: int, keyframes: int, fraction: float, min_per_keyframe: float = 0.0,
                  max_per_keyframe: float | None = None) -> int:
    """Frames the search scores for K key frames: `fraction` of the candidates (the paper's 25%), at least
    min_per_keyframe x K (short videos), at most max_per_keyframe x K (None: no cap) whatever the candidates, so
    a long video's search costs what a short one's does. Not capped at the candidates (the search says when they
    run out). The planner's target (`budget.planner`) and the pipeline's default without a plan."""
    b = math.ceil(fraction * n_candidates)
    if max_per_keyframe is not None:
        b = min(b, math.ceil(max_per_keyframe * keyframes))
    return int(max(b, math.ceil(min_per_keyframe * keyframes)))
