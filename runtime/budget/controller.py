"""Run time: `BudgetController(plan, trace)` gives each pipeline stage its share of the latency budget, re-plans
the remaining stages when one overruns (fewer key frames, smaller search batches; `reduced` is then True and the
trace has a "replan" event), and is the run's memory guard.

Memory guard: every model session the run opens (`providers.create_session` under the same Trace) registers here
with its size estimate; each use marks it (stage, time). When the process RSS, or the modelled total (the plan's
runtime baseline + the open sessions + the key frames' state), exceeds the profile's memory budget, sessions idle
in the current stage are released, largest first, until it fits; a released session re-opens on its next use.
Every release and re-open is a "memory_guard" trace event, and one "degraded" line in the answer counts them.
`check_headroom` / `allow_keyframes` release idle sessions before refusing a load or lowering K.
"""
from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass
from typing import Any, Callable, Mapping, Sequence

from ..infra.trace import Trace, as_trace, peak_rss_mb, reset_peak_rss, rss_mb
from .planner import STAGE_ALIASES, Plan, PlanConf, clip_of, plan
from .profile import Profile
from ..infra import providers
import gc


@dataclass(eq=False)
class _Session:
    name: str
    mb: float
    release: Callable[[], None]
    last_stage: str | None = None
    released: bool = False
    epoch: int = 0          # the stage (counted by start_stage) it was last used in: idle when older
    last_used: float = 0.0  # clock seconds
    releases: int = 0
    reopens: int = 0


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
        self.trace = as_trace(trace)
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
        self._epoch = 0                       # stages started so far: sessions used in an older one are idle
        self._first_pressure: str | None = None
        self._guard_note: dict[str, Any] | None = None
        self.trace.decide("budget.plan", {"profile": plan.profile, "keyframes": plan.keyframes,
                                          "scored_frames": plan.scored_frames, "iterations": plan.iterations,
                                          "latency_budget_ms": plan.latency_budget_ms,
                                          "memory_budget_mb": plan.memory_budget_mb})

        providers.watch(self)  # the memory guard of every model session opened under this trace

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
        self._epoch += 1  # what the earlier stages used is idle now: released if memory is over the budget
        reset_peak_rss()
        self.peaks[name] = max(self.peaks.get(name, 0.0), self._rss())
        self.relieve()

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
            return min(self.scored_frames, max(min(p.candidates, p.conf.plan_min_scored_per_keyframe * k), 1))

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

    def sessions_mb(self) -> float:
        """MB of the registered sessions that are open now."""
        return sum(s.mb for s in self.sessions.values() if not s.released)

    def modelled_mb(self) -> float:
        """The plan's memory model with the real sessions: runtime baseline + open sessions + K key frames."""
        return (self.plan.memory_mb.get("process", 0.0) + self.sessions_mb()
                + self.keyframes * self.plan.keyframe_mb)

    def pressure(self) -> str | None:
        """Why memory is over the budget now (RSS, or the modelled total), or None. At the budget, not above."""
        budget = self.memory_budget_mb
        rss = self._rss()
        if rss > budget:
            return f"RSS {rss:.0f} MB is over the {budget:.0f} MB memory budget"
        total = self.modelled_mb()
        if total > budget:
            return (f"runtime {self.plan.memory_mb.get('process', 0.0):.0f} MB + open model sessions "
                    f"{self.sessions_mb():.1f} MB + {self.keyframes} key frames x {self.plan.keyframe_mb:g} MB = "
                    f"{total:.1f} MB is over the {budget:.0f} MB memory budget")
        return None

    def register_session(self, name: str, mb: float, release: Callable[[], None]) -> str:
        """Make a loaded session releasable by the guard. `release` must drop every reference to it. Returns the
        key it is registered under (`name`, numbered when another session already has it)."""
        key, n = name, 1
        while key in self.sessions:
            n += 1
            key = f"{name}#{n}"
        self.sessions[key] = _Session(key, float(mb), release, self._current, epoch=self._epoch,
                                      last_used=self._clock())
        self.trace.decide("budget.sessions", {k: round(s.mb, 1) for k, s in self.sessions.items()})
        return key

    def touch_session(self, name: str) -> None:
        """Mark a session used by the current stage (idle = not used since it began); under memory pressure the
        other idle sessions are released."""
        s = self.sessions.get(name)
        if s is None:
            return
        s.last_stage, s.epoch, s.last_used = self._current, self._epoch, self._clock()
        if s.released:  # re-opened by its owner without saying so (a callback session): count it
            self.session_reopened(name, 0.0)
        self.relieve(keep=(name,))

    def session_reopened(self, name: str, seconds: float) -> None:
        """A released session was opened again for its next use (recorded; counted in the answer's note)."""
        s = self.sessions.get(name)
        if s is None or not s.released:
            return
        s.released = False
        s.reopens += 1
        s.epoch, s.last_used = self._epoch, self._clock()
        self.trace.event("memory_guard", f"re-opened session {name} (~{s.mb:.0f} MB) in {seconds * 1000:.0f} ms: "
                         f"it had been released as idle", session=name, action="reopen",
                         seconds=round(seconds, 4), rss_mb=round(self._rss(), 1))
        self._note_guard()

    def _idle(self, keep: Sequence[str]) -> list[_Session]:
        """Open sessions not in `keep` and not used since the current stage began, largest first."""
        return sorted((s for s in self.sessions.values() if not s.released and s.name not in keep
                       and s.epoch < self._epoch), key=lambda s: (-s.mb, s.last_used))

    def _release(self, s: _Session, why: str) -> None:
        s.release()
        s.released = True
        s.releases += 1
        self.trace.event("memory_guard", f"released idle session {s.name} (~{s.mb:.0f} MB): {why}",
                         session=s.name, action="release", rss_mb=round(self._rss(), 1))
        if self._first_pressure is None:
            self._first_pressure = why
        self._note_guard()

    def relieve(self, keep: Sequence[str] = ()) -> list[str]:
        """While memory is over the budget, release idle sessions (largest first). Returns the names released."""
        out = []
        why = self.pressure()
        for s in self._idle(keep) if why else ():
            self._release(s, why)
            out.append(s.name)
            why = self.pressure()
            if why is None:
                break
        return out

    def release_idle(self, keep: Sequence[str] = (), *, need_mb: float | None = None) -> list[str]:
        """Release sessions not in `keep` and not used in the current stage (largest first, until `need_mb` is
        free if given). Returns the names released; each is a trace event."""
        out = []
        for s in self._idle(keep):
            if need_mb is not None and self.headroom_mb() >= need_mb:
                break
            self._release(s, f"{need_mb or 0:.0f} MB wanted below the {self.memory_budget_mb:.0f} MB memory "
                             f"budget (RSS {self._rss():.0f} MB)")
            gc.collect()
            out.append(s.name)
        return out

    def _note_guard(self) -> None:
        """One line in the answer's warnings that counts the releases and re-opens so far (updated in place)."""
        rel = sum(s.releases for s in self.sessions.values())
        reo = sum(s.reopens for s in self.sessions.values())
        per = ", ".join(f"{s.name} {s.releases}/{s.reopens}" for s in self.sessions.values()
                        if s.releases or s.reopens)
        msg = (f"memory guard: {rel} release(s) and {reo} re-open(s) of idle model sessions to stay within the "
               f"{self.memory_budget_mb:.0f} MB memory budget ({self._first_pressure}); released/re-opened: {per}")
        self.trace.decide("budget.memory_guard", {"releases": rel, "reopens": reo, "why": self._first_pressure,
                                                  "sessions": {s.name: {"mb": round(s.mb, 1), "releases": s.releases,
                                                                        "reopens": s.reopens}
                                                               for s in self.sessions.values()}})
        if self._guard_note is None:
            n = len(self.trace.events)
            self.trace.event("degraded", msg, stage="memory_guard", releases=rel, reopens=reo)
            self._guard_note = self.trace.events[n] if len(self.trace.events) > n else {}
        else:
            self._guard_note.update(message=msg, releases=rel, reopens=reo)

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


def controller_for(profile: Profile | str | os.PathLike, source: Any, trace: Trace, bundle: Any = None,
                   conf: PlanConf | Mapping[str, Any] | None = None) -> BudgetController:
    """Plan for a frame source under a profile and return the run-time controller (the pipeline's entry point).
    The plan is recorded in the trace (`decisions["budget.plan"]`); BudgetError when nothing fits."""
    duration, fps = clip_of(source)
    return BudgetController(plan(profile, duration, fps, bundle, conf), trace)
