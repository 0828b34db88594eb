"""[paper_costs.*] of the non-reference profiles: scaled from cpu-generic's measurements by the device factors the
profiles' own shared-model costs encode (benchmarks/paper_models.py: scale_paper_costs), labelled as estimates."""
from __future__ import annotations

import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))


def test_factor_is_the_least_floored_perception_ratio_and_vlm_scales_per_field():
    import paper_models as PM

    base = {"depth": {"ms_per_call": 100.0}, "detector": {"ms_per_call": 40.0}, "geometry": {"ms_per_call": 2.0},
            "vlm": {"ms_per_image": 4000.0, "ms_per_token": 40.0, "load_ms": 1500.0}}
    # detector sits on a 1.5 ms floor on the device: its ratio (0.0375) over-states the time; depth's is 1/40
    dev = {"depth": {"ms_per_call": 2.5}, "detector": {"ms_per_call": 1.5}, "geometry": {"ms_per_call": 2.0},
           "vlm": {"ms_per_image": 1000.0, "ms_per_token": 20.0, "load_ms": 1500.0}}
    paper = {"detector": {"ms_per_call": 10000.0, "load_ms": 700.0, "resident_mb": 3000.0, "note": "n",
                          "date": "2026-12-01"},
             "vlm": {"ms_per_image": 40000.0, "ms_per_token": 200.0, "load_ms": 9.0, "resident_mb": 6000.0}}
    out = PM.scale_paper_costs(base, dev, paper)
    assert out["detector"]["ms_per_call"] == pytest.approx(250.0)
    # host-CPU factor 1 (same geometry cost), VLM load factor 1: loads as on cpu-generic here
    assert out["detector"]["load_ms"] == 700.0 and out["detector"]["resident_mb"] == 3000.0
    assert out["vlm"]["ms_per_image"] == pytest.approx(10000.0) and out["vlm"]["ms_per_token"] == pytest.approx(100.0)
    assert all(e["status"] == "estimated" and e["source"].startswith("SCALED from cpu-generic") for e in out.values())


def test_every_profile_plans_with_the_paper_models():
    from mosaicthinker.runtime.budget.profile import load_profile

    profiles = sorted((ROOT / "profiles").glob("*.toml"))
    assert len(profiles) >= 2, f"no device profiles found under {ROOT / 'profiles'}"  # an empty glob proves nothing
    for p in profiles:
        prof = load_profile(p)
        assert {"depth", "segmenter", "detector", "embedder", "matcher", "vlm"} <= set(prof.paper_costs), p.name
        paper = prof.with_models("paper")
        assert paper.costs["detector"] == prof.paper_costs["detector"]
        if p.stem != "cpu-generic":
            assert all(e.status == "estimated" and "SCALED" in e.source for e in prof.paper_costs.values())
