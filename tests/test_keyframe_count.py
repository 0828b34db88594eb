"""The key-frame count K is resolved in one place (`keyframes/count.py`, issue 37): flag -> budget -> config ->
memory guard, the per-clip plan, then the uniform floor, the coverage frames and the cut to a re-planned budget,
each change said in the log it is given."""
from __future__ import annotations

import numpy as np

from mosaicthinker.runtime.infra.trace import StageLog
from mosaicthinker.runtime.keyframes import (KeyFrameConf, KeyFrameResult, finish_keyframes, plan_keyframes,
                                             requested_keyframes)


class FakeBudget:
    """A device budget as the count reads it: its K, scored frames, reasons and a memory guard allowing `room`."""

    def __init__(self, keyframes: int, room: int = 1000):
        self.keyframes, self.scored_frames, self.reasons, self.room = keyframes, 40, [], room

    def allow_keyframes(self, k: int, held: int = 0) -> int:
        return min(k, self.keyframes, self.room)


def _result(chosen, scores=None) -> KeyFrameResult:
    return KeyFrameResult("iterative", np.asarray(chosen, np.int64), scores or {}, [], 0, 100, 16)


def test_the_flag_wins_then_the_budget_then_the_config_and_the_memory_guard_lowers_it():
    conf = KeyFrameConf()
    log = StageLog()
    assert requested_keyframes(8, conf, None, log) == 8 and "budget.keyframes" not in log.decisions
    assert requested_keyframes(None, conf, None, log) == conf.keyframes == 16
    assert requested_keyframes(None, conf, FakeBudget(12), log) == 12 and log.decisions["budget.keyframes"] == 12
    assert requested_keyframes(20, conf, FakeBudget(12), log) == 12  # the budget's K caps the flag
    assert requested_keyframes(10, conf, FakeBudget(12, room=5), log) == 5 and log.decisions["budget.keyframes"] == 5


def test_floor_reserve_and_budget_cut_are_applied_in_order_and_said():
    cands = list(range(0, 200, 2))
    conf = KeyFrameConf()
    plan = plan_keyframes(conf, None, len(cands), 200, 2, 16)
    log = StageLog()
    got = finish_keyframes(_result([50]), plan, cands, 2, None, log)  # one frame passed: the floor tops it up to 3
    assert len(got) == conf.uniform_floor == 3 and 50 in got
    assert [e["kind"] for e in log.events] == ["degraded"] and "evenly spaced" in log.events[0]["message"]
    many = plan_keyframes(conf, None, len(cands), 200, 6, 16)  # six names: half of K reserved for coverage
    assert many.reserve == 8 and many.search.keyframes == 8
    log = StageLog()
    got = finish_keyframes(_result(list(range(100, 116, 2))), many, cands, 6, None, log)
    assert len(got) == 16 and min(got) < 50 and max(got) > 150  # the reserve fills the clip's gaps
    assert [e["kind"] for e in log.events] == ["keyframes"]
    budget = FakeBudget(16)
    budget.keyframes, budget.reasons = 6, ["reduced plan: stage keyframes took 900 ms of its 40 ms share"]
    log = StageLog()
    cut = finish_keyframes(_result(list(range(100, 116, 2))), many, cands, 6, budget, log)
    assert len(cut) == 6 and set(cut) <= set(got)
    assert log.events[-1]["kind"] == "reduced_plan" and "16 -> 6 key frames" in log.events[-1]["message"]
