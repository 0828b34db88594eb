"""Device budgets: profiles (`profiles/*.toml`), the planner that sets key-frame counts, and the run-time
deadlines and memory guard (`mosaic plan` is `runtime/commands/plan.py`).

- `profile`    the profile schema, its validation (`parse_profile`, `load_profile`) and `update_profile_costs`
- `planner`    `plan(profile, duration_s, fps, bundle)` -> `Plan` (K, S, stage shares, arithmetic); `clip_of`
- `controller` `BudgetController(plan, trace)`: stage deadlines with re-planning, the memory guard over every
               model session of the run; `controller_for(profile, source, trace)` (the pipeline's entry point)

Every public name is re-exported here, so `from mosaicthinker.runtime.budget import plan` keeps working.
"""
from __future__ import annotations

from ..infra.bundle import bundle_hash  # noqa: F401  (re-exported: android/perf_report.py imports it from here)
from .controller import BudgetController, controller_for
from .planner import (MAX_CLIP_S, MAX_FPS, MIN_MAP_FRAMES, PLAN_SCHEMA, RUNTIME_STAGES, STAGE_ALIASES, Plan,
                      PlanConf, StageBudget, clip_of, plan)
from .profile import (COST_ITEMS, CPU_LIKE_PROVIDERS, INT8_KINDS, KNOWN_PROVIDERS, MAX_THREADS, MODEL_COSTS,
                      MODEL_SETS, NEAREST_PRECISION, OPTIONAL_ROLE_COSTS, PRECISIONS, PROFILE_SCHEMA,
                      PROVENANCE_KEYS, REQUIRED_COSTS, ROLES, ROOT_PROFILES, CostEntry, Profile, RoleSettings,
                      list_profiles, load_profile, nearest_variant, parse_profile, resolve_profile_path,
                      update_profile_costs)

__all__ = [
    "BudgetController", "controller_for",
    "MAX_CLIP_S", "MAX_FPS", "MIN_MAP_FRAMES", "PLAN_SCHEMA", "RUNTIME_STAGES", "STAGE_ALIASES", "Plan", "PlanConf",
    "StageBudget", "clip_of", "plan",
    "COST_ITEMS", "CPU_LIKE_PROVIDERS", "INT8_KINDS", "KNOWN_PROVIDERS", "MAX_THREADS", "MODEL_COSTS", "MODEL_SETS",
    "NEAREST_PRECISION", "OPTIONAL_ROLE_COSTS", "PRECISIONS", "PROFILE_SCHEMA", "PROVENANCE_KEYS",
    "REQUIRED_COSTS", "ROLES", "ROOT_PROFILES", "CostEntry", "Profile", "RoleSettings", "list_profiles",
    "load_profile", "nearest_variant", "parse_profile", "resolve_profile_path", "update_profile_costs",
    "bundle_hash",
]
