"""`mosaic plan` cold vs warm start (runtime/budget/planner.py: PlanConf.start), the paper set's grounding figure,
the `--profile all` rows wrapped whole, and the scaled [paper_costs] loads (benchmarks/paper_models.py)."""
from __future__ import annotations

import shutil
import subprocess
import sys
from argparse import Namespace
from pathlib import Path

import pytest

from mosaicthinker.runtime import budget as B
from mosaicthinker.runtime.commands import plan as command
from mosaicthinker.runtime.infra.errors import BudgetError, InputError

from test_budget import HAND, hand_profile

ROOT = Path(__file__).resolve().parents[1]
LOADS_MS = 300.0  # hand_profile: detector + depth + matcher, 100 ms each


def _plan(latency_ms: float, memory_mb: float, start: str) -> B.Plan:
    # 100 s at 10 fps: video pass 1000 x 2 ms; K = 2 costs 2000 (+ 300 loads) + 8 x 11 + 2 x 91 ms
    return B.plan(B.parse_profile(hand_profile(latency_ms, memory_mb)), 100, 10, conf={**HAND, "start": start})


def test_warm_start_takes_the_loads_out_of_the_question_and_reports_them_as_the_cold_start():
    with pytest.raises(BudgetError, match=r"fails by 270 ms"):  # cold: 2570 ms > 2300 ms
        _plan(2300, 1000, "cold")
    warm = _plan(2300, 1000, "warm")  # 2270 ms <= 2300 ms
    assert warm.keyframes == 2 and warm.session_policy == "all_resident"
    assert warm.fixed_ms["model_loads"] == 0 and warm.stages["load"].fixed_ms == 0
    assert warm.cold_start_ms == LOADS_MS and warm.resident_mb == 200
    assert any("cold start" in n for n in warm.notes)
    assert "loads 0 ms (warm start" in warm.arithmetic[1]
    cold = _plan(60000, 1000, "cold")
    assert cold.fixed_ms["model_loads"] == cold.cold_start_ms == LOADS_MS


def test_warm_start_whose_models_cannot_stay_resident_pays_the_loads_in_every_question():
    # all resident: 100 + 200 + 2 x 10 = 320 MB > 250 MB; one at a time: 100 + 100 + k x 10 <= 250 -> k <= 5
    p = _plan(60000, 250, "warm")
    assert p.session_policy == "one_at_a_time" and p.keyframes == 5
    assert p.fixed_ms["model_loads"] == LOADS_MS
    assert any("does not fit the memory budget" in n for n in p.notes)


def test_warm_nothing_fits_reports_both_policies_and_the_largest_terms():
    with pytest.raises(BudgetError) as e:
        _plan(2100, 250, "warm")
    msg = str(e.value)
    assert "(warm start)" in msg and "with every session resident" in msg and "one session at a time" in msg
    # resident: 2270 - 2100 = 170 ms over and 320 - 250 = 70 MB over; one at a time: 2570 - 2100 = 470 ms over
    assert "fails by 170 ms" in msg and "fails by 70.0 MB" in msg and "fails by 470 ms" in msg
    assert "Largest terms (all_resident): video pass 2,000 ms" in msg


def test_start_must_be_cold_or_warm():
    with pytest.raises(InputError, match="start must be 'cold' or 'warm'"):
        B.PlanConf.merged(start="hot")


def test_the_paper_grounding_figure_applies_only_when_a_vlm_grounds():
    prof = B.load_profile("cpu-generic")
    vlm_ground = prof.paper_costs["grounding"].ms_per_call  # the paper set fits no K here: read the error
    with pytest.raises(BudgetError, match=f"grounding {vlm_ground:,.0f}"):
        B.plan(prof, 60, 15, models="paper")
    template = prof.cost("grounding").ms_per_call
    with pytest.raises(BudgetError, match=f"grounding {template:.2f}, VLM 0.00"):
        B.plan(prof, 60, 15, models="paper", conf={"use_vlm": False})


def _all_args(**kw) -> Namespace:
    base = dict(profile="all", video=None, duration=60.0, fps=15.0, candidates=None, keyframes_max=None,
                online=False, answerer="auto", models="paper", bundle=None, start="warm")
    return Namespace(**{**base, **kw})


def test_plan_all_rows_are_wrapped_at_word_boundaries_and_never_cut(monkeypatch):
    monkeypatch.setenv("COLUMNS", "80")
    res = command.run(_all_args())
    text = command.render(res)
    assert text.startswith("key frames K per profile (paper models, warm start):")
    assert all(len(line) <= 80 for line in text.splitlines())
    words = " ".join(text.split())
    for name, row in res["profiles"].items():
        reason = row.get("error", "").removeprefix(f"profile {name}: ")  # the row names the profile once
        assert row.get("keyframes") is not None or " ".join(reason.split()) in words, name
    shared = command.render(command.run(_all_args(models="shared")))
    assert "cold start" in shared and "ms once" in shared


def test_scaled_paper_loads_follow_the_host_cpu_and_the_vlm_load_factor():
    sys.path.insert(0, str(ROOT / "benchmarks"))
    import paper_models as PM

    base = {"depth": {"ms_per_call": 100.0}, "geometry": {"ms_per_call": 2.0},
            "vlm": {"ms_per_image": 4000.0, "ms_per_token": 40.0, "load_ms": 1500.0}}
    dev = {"depth": {"ms_per_call": 2.5}, "geometry": {"ms_per_call": 3.0},
           "vlm": {"ms_per_image": 1000.0, "ms_per_token": 20.0, "load_ms": 3000.0}}
    paper = {"depth": {"ms_per_call": 1000.0, "load_ms": 200.0, "resident_mb": 500.0, "note": "n"},
             "vlm": {"ms_per_image": 40000.0, "ms_per_token": 200.0, "load_ms": 10000.0, "resident_mb": 6000.0},
             "grounding": {"ms_per_call": 80000.0, "source": "e2e"}}
    out = PM.scale_paper_costs(base, dev, paper)
    assert out["depth"]["ms_per_call"] == pytest.approx(25.0) and out["depth"]["load_ms"] == pytest.approx(300.0)
    assert out["depth"]["resident_mb"] == 500.0 and "host-CPU factor" in out["depth"]["source"]
    assert out["vlm"]["load_ms"] == pytest.approx(20000.0) and out["vlm"]["resident_mb"] == 6000.0
    assert out["grounding"]["ms_per_call"] == pytest.approx(20000.0)


def test_estimate_py_regenerates_the_device_profiles_byte_for_byte_keeping_paper_costs(tmp_path):
    profiles = sorted((ROOT / "profiles").glob("*.toml"))
    assert len(profiles) >= 2, f"no device profiles found under {ROOT / 'profiles'}"  # an empty glob proves nothing
    for f in profiles + [ROOT / "profiles" / "estimate.py"]:
        shutil.copy(f, tmp_path / f.name)
    subprocess.run([sys.executable, str(tmp_path / "estimate.py")], check=True, capture_output=True)
    for f in profiles:
        assert (tmp_path / f.name).read_bytes() == f.read_bytes(), f.name
        assert "[paper_costs." in f.read_text(), f.name


def _cpu_generic_with(roles: dict) -> B.Profile:
    import tomllib

    data = tomllib.loads(B.resolve_profile_path("cpu-generic").read_text())
    for role, rs in roles.items():
        data["roles"][role] = {**data["roles"].get(role, {}), **rs}
    return B.parse_profile(data)


def test_the_profile_precision_picks_the_paper_variant_the_model_loading_would_run():
    int8 = {"precision": "int8", "int8_kind": "dynamic"}
    base = B.load_profile("cpu-generic")
    det = base.paper_costs["detector"]
    assert det.variant == "fp32" and "int8-dynamic" in det.variants
    assert base.with_models("paper").cost("detector").ms_per_call == det.ms_per_call  # fp32 roles: fp32
    p8 = _cpu_generic_with({"detector": int8, "segmenter": int8})
    assert p8.with_models("paper").cost("detector").ms_per_call == det.variants["int8-dynamic"].ms_per_call
    assert p8.with_models("paper").cost("segmenter").ms_per_prompt == \
        base.paper_costs["segmenter"].variants["int8-dynamic"].ms_per_prompt
    assert "[int8-dynamic]" in p8.with_models("paper").cost("detector").provenance()
    # fp16 has no measured variant: the nearest (fp32) is costed, as nearest_variant would load it
    assert _cpu_generic_with({"detector": {"precision": "fp16"}}).with_models("paper").cost(
        "detector").ms_per_call == det.ms_per_call


def test_cost_variants_are_validated(tmp_path):
    import tomllib

    from mosaicthinker.runtime.infra.errors import ProfileError

    data = tomllib.loads(B.resolve_profile_path("cpu-generic").read_text())
    det = {**data["paper_costs"]["detector"], "variants": {"int8-dynamic": {"ms_per_call": 1}}}
    bad = {**data, "paper_costs": {**data["paper_costs"], "detector": det}}
    with pytest.raises(ProfileError, match=r"variants\.int8-dynamic: missing field\(s\) load_ms, resident_mb"):
        B.parse_profile(bad)
    no_own = {k: v for k, v in data["paper_costs"]["depth"].items() if k != "variant"}
    with pytest.raises(ProfileError, match="names its own `variant`"):
        B.parse_profile({**data, "paper_costs": {**data["paper_costs"], "depth": no_own}})
    shared = {**data, "costs": {**data["costs"], "depth": {**data["costs"]["depth"], "variant": "fp32"}}}
    with pytest.raises(ProfileError, match="unknown key 'variant'"):
        B.parse_profile(shared)
