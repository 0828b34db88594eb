"""Device budgets: profiles (`profiles/*.toml`), the planner that sets key-frame counts, and the run-time
deadlines and memory guard. Also the `mosaic plan` command module (runtime/cli.py imports this package).

- `profile`    the profile schema, its validation (`parse_profile`, `load_profile`) and `update_profile_costs`
- `planner`    `plan(profile, duration_s, fps, bundle)` -> `Plan` (K, S, stage shares, arithmetic); `clip_of`
- `controller` `BudgetController(plan, trace)`: stage deadlines with re-planning, the memory guard over every
               model session of the run; `controller_for(profile, source, trace)` (the pipeline's entry point)
- `command`    `mosaic plan` (add_arguments / run / render)

Every public name is re-exported here, so `from mosaicthinker.runtime.budget import plan` keeps working.
"""
from __future__ import annotations

from ..bundle import bundle_hash  # noqa: F401  (re-exported: android/perf_report.py imports it from here)
from .command import COMMON_FLAGS, add_arguments, render, run
from .controller import BudgetController, controller_for
from .planner import (MAX_CLIP_S, MAX_FPS, MIN_MAP_FRAMES, PLAN_SCHEMA, RUNTIME_STAGES, STAGE_ALIASES, Plan,
                      PlanConf, StageBudget, clip_of, plan)
from .profile import (COST_ITEMS, CPU_LIKE_PROVIDERS, INT8_KINDS, KNOWN_PROVIDERS, MAX_THREADS, MODEL_COSTS,
                      MODEL_SETS, NEAREST_PRECISION, OPTIONAL_ROLE_COSTS, PRECISIONS, PROFILE_SCHEMA,
                      PROVENANCE_KEYS, REQUIRED_COSTS, ROLES, ROOT_PROFILES, CostEntry, Profile, RoleSettings,
                      list_profiles, load_profile, nearest_variant, parse_profile, resolve_profile_path,
                      update_profile_costs)

__all__ = [
    "COMMON_FLAGS", "add_arguments", "render", "run",
    "BudgetController", "controller_for",
    "MAX_CLIP_S", "MAX_FPS", "MIN_MAP_FRAMES", "PLAN_SCHEMA", "RUNTIME_STAGES", "STAGE_ALIASES", "Plan", "PlanConf",
    "StageBudget", "clip_of", "plan",
    "COST_ITEMS", "CPU_LIKE_PROVIDERS", "INT8_KINDS", "KNOWN_PROVIDERS", "MAX_THREADS", "MODEL_COSTS", "MODEL_SETS",
    "NEAREST_PRECISION", "OPTIONAL_ROLE_COSTS", "PRECISIONS", "PROFILE_SCHEMA", "PROVENANCE_KEYS",
    "REQUIRED_COSTS", "ROLES", "ROOT_PROFILES", "CostEntry", "Profile", "RoleSettings", "list_profiles",
    "load_profile", "nearest_variant", "parse_profile", "resolve_profile_path", "update_profile_costs",
    "bundle_hash",
]
