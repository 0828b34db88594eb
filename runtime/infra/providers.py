"""Execution providers: the ONE place onnxruntime sessions are created.

`create_session(path, stage, preference, ...)`:
1. normalises provider names (short forms: cpu, cuda, tensorrt/trt, nnapi, qnn, xnnpack, coreml, openvino, dml,
   rocm, webgpu, azure; or the full `XxxExecutionProvider` name; or (name, options) tuples),
2. drops the ones `onnxruntime.get_available_providers()` does not list (each drop is a "fallback" event),
3. tries each remaining provider in order (always with CPU behind it as onnxruntime requires) and confirms with
   `session.get_providers()` which one really got the graph (onnxruntime only WARNS when a requested provider
   cannot be used),
4. optionally runs the graph once (`warmup`): if creation or this first run fails, the next provider is tried.
The returned `Session` also treats its first real `run` as a probe: if it fails, the next provider is tried
with the same inputs. Every fallback and its reason go into the Trace (event kind "fallback") and
`trace.providers[stage]` holds {requested, available, used, attempts, create_s, first_run_s, rss_peak_mb}.

Memory guard: every session is registered with the memory guard of its run (the `budget.BudgetController`
watching the same Trace; `watch(guard)` adopts the sessions opened before it), with a size estimate (the RSS the
creation added, at least the model files' size). Each `run` marks the session used; under memory pressure the
guard `release()`s idle sessions (the onnxruntime session is dropped) and the next use re-opens it on the
provider it ran on, recorded in the trace.
"""
from __future__ import annotations

import os
import time
import weakref
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np

from .ep_support import PROVIDER_DEFAULTS, qnn_context
from .errors import ProviderError
from .trace import Trace, as_trace, rss_mb

SHORT_NAMES = {
    "cpu": "CPUExecutionProvider",
    "cuda": "CUDAExecutionProvider",
    "tensorrt": "TensorrtExecutionProvider",
    "trt": "TensorrtExecutionProvider",
    "nnapi": "NnapiExecutionProvider",
    "qnn": "QNNExecutionProvider",
    "xnnpack": "XnnpackExecutionProvider",
    "coreml": "CoreMLExecutionProvider",
    "openvino": "OpenVINOExecutionProvider",
    "dml": "DmlExecutionProvider",
    "directml": "DmlExecutionProvider",
    "rocm": "ROCMExecutionProvider",
    "migraphx": "MIGraphXExecutionProvider",
    "webgpu": "WebGpuExecutionProvider",
    "azure": "AzureExecutionProvider",
}
CPU = "CPUExecutionProvider"
_ORT_DTYPES = {"float": np.float32, "float16": np.float16, "double": np.float64, "uint8": np.uint8,
               "int8": np.int8, "int32": np.int32, "int64": np.int64, "bool": np.bool_}

def normalize_provider(name: str) -> str:
    """'cuda' -> 'CUDAExecutionProvider'; full names pass through (case-insensitive match); unknown -> error."""
    key = name.strip()
    if key.lower() in SHORT_NAMES:
        return SHORT_NAMES[key.lower()]
    for full in set(SHORT_NAMES.values()):
        if key.lower() == full.lower():
            return full
    if key.endswith("ExecutionProvider"):
        return key
    raise ProviderError(f"unknown execution provider {name!r}; use one of {sorted(SHORT_NAMES)} "
                        f"or a full onnxruntime name like CUDAExecutionProvider")


def normalize_preference(preference: Sequence[Any] | str | None) -> list[tuple[str, dict[str, Any]]]:
    """'cuda,cpu' or ['tensorrt', ('cuda', {...}), 'cpu'] -> [(full name, options), ...] without duplicates."""
    if preference is None:
        preference = ["cpu"]
    if isinstance(preference, str):
        preference = [p for p in preference.split(",") if p.strip()]
    out: list[tuple[str, dict[str, Any]]] = []
    for p in preference:
        name, opts = (p[0], dict(p[1] or {})) if isinstance(p, (tuple, list)) else (p, {})
        full = normalize_provider(name)
        if full not in [o[0] for o in out]:
            out.append((full, opts))
    return out


def available_providers() -> list[str]:
    import onnxruntime as ort

    return list(ort.get_available_providers())


@dataclass
class SessionConfig:
    """Session options the budget planner may set."""

    intra_op_threads: int | None = None   # None: onnxruntime default (all cores)
    inter_op_threads: int | None = 1
    graph_optimization: str = "all"        # disable | basic | extended | all
    # intra-op worker threads busy-wait between runs by default: on a CPU shared with the pipeline's own numpy /
    # OpenCV work (and other processes) that burns a core for nothing (SSD 37 vs 18 ms CPU per run, load 3.5).
    # No effect on the outputs
    allow_spinning: bool = False
    allow_cpu_fallback: bool = True        # append CPU when the preference does not end with it
    log_severity: int = 3
    # QNN context binaries (the compiled HTP graph) go here and are reused; None: compiled on every session
    ep_context_dir: str | None = field(default_factory=lambda: os.environ.get("MOSAIC_EP_CONTEXT_DIR"))


def _session_options(cfg: SessionConfig):
    import onnxruntime as ort

    so = ort.SessionOptions()
    if cfg.intra_op_threads:
        so.intra_op_num_threads = int(cfg.intra_op_threads)
    if cfg.inter_op_threads:
        so.inter_op_num_threads = int(cfg.inter_op_threads)
    so.graph_optimization_level = {
        "disable": ort.GraphOptimizationLevel.ORT_DISABLE_ALL,
        "basic": ort.GraphOptimizationLevel.ORT_ENABLE_BASIC,
        "extended": ort.GraphOptimizationLevel.ORT_ENABLE_EXTENDED,
        "all": ort.GraphOptimizationLevel.ORT_ENABLE_ALL,
    }[cfg.graph_optimization]
    so.log_severity_level = cfg.log_severity
    # kernels log through the default logger, not the session's (a TFLite conversion's deprecated Resize mode
    # warns on every load otherwise)
    ort.set_default_logger_severity(cfg.log_severity)
    so.add_session_config_entry("session.intra_op.allow_spinning", "1" if cfg.allow_spinning else "0")
    so.add_session_config_entry("session.inter_op.allow_spinning", "1" if cfg.allow_spinning else "0")
    return so


def dummy_feeds(sess: Any, dynamic_dim: int = 1) -> dict[str, np.ndarray]:
    """Zero inputs matching a session's declared inputs (dynamic dims -> `dynamic_dim`), for a warm-up run."""
    feeds = {}
    for i in sess.get_inputs():
        shape = [d if isinstance(d, int) and d > 0 else dynamic_dim for d in (i.shape or [])]
        dt = _ORT_DTYPES.get(i.type.replace("tensor(", "").rstrip(")"), np.float32)
        feeds[i.name] = np.zeros(shape, dtype=dt)
    return feeds


@dataclass(eq=False)  # identity semantics: sessions are kept in weak sets
class Session:
    """An onnxruntime session that knows which provider it really runs on and can fall back on first run.

    run(feeds: {input name: array}, outputs=None) -> list of arrays (onnxruntime order).
    release() drops the onnxruntime session (the memory guard's call); the next use re-opens it.
    """

    path: str
    stage: str
    candidates: list[tuple[str, dict[str, Any]]]
    config: SessionConfig
    trace: Trace
    sess: Any = None
    provider: str | None = None
    index: int = -1
    first_run_done: bool = False
    attempts: list[dict[str, Any]] = field(default_factory=list)
    requested: list[tuple[str, dict[str, Any]]] = field(default_factory=list)
    mb: float = 0.0                      # size estimate the memory guard accounts
    released: bool = False
    guard: Callable[[], Any] | None = None  # weak reference to the run's memory guard
    guard_key: str | None = None

    # -- creation ---------------------------------------------------------------------------------------------
    def _open_from(self, start: int, warmup_feeds: dict[str, np.ndarray] | None) -> None:
        last_reason = "no provider left to try"
        for idx in range(start, len(self.candidates)):
            name, opts = self.candidates[idx]
            t0 = time.perf_counter()
            try:
                sess = self._create(name, opts)
            except Exception as e:  # noqa: BLE001  onnxruntime raises plain RuntimeError/Fail/...
                last_reason = f"session creation failed on {name}: {type(e).__name__}: {str(e)[:300]}"
                self._fallback(name, last_reason, time.perf_counter() - t0)
                continue
            create_s = time.perf_counter() - t0
            used = sess.get_providers()
            if not used or used[0] != name:
                last_reason = (f"{name} was requested but onnxruntime assigned {used[:1] or 'nothing'} "
                               f"(provider could not take the graph)")
                self._fallback(name, last_reason, create_s)
                if idx + 1 < len(self.candidates) or not used:
                    continue  # try the next provider in the preference
            first_run_s = None
            if warmup_feeds is not None:
                t1 = time.perf_counter()
                try:
                    sess.run(None, warmup_feeds)
                except Exception as e:  # noqa: BLE001
                    last_reason = f"first run failed on {name}: {type(e).__name__}: {str(e)[:300]}"
                    self._fallback(name, last_reason, time.perf_counter() - t1)
                    continue
                first_run_s = time.perf_counter() - t1
                self.first_run_done = True
            self.sess, self.index, self.provider = sess, idx, used[0]
            self.attempts.append({"provider": name, "ok": True, "used": used[0],
                                  "create_s": round(create_s, 4),
                                  "first_run_s": None if first_run_s is None else round(first_run_s, 4)})
            self._record(create_s, first_run_s)
            return
        raise ProviderError(f"{self.stage}: no execution provider could create/run {self.path} "
                            f"(tried {[c[0] for c in self.candidates]}; last: {last_reason})")

    def _create(self, name: str, opts: dict[str, Any]) -> Any:
        """An onnxruntime session on `name` (+ CPU behind it) with the provider's default options under the
        caller's, and for QNN its context-binary cache (`ep_support.qnn_context`)."""
        import onnxruntime as ort

        so = _session_options(self.config)
        model = self.path
        opts = {**PROVIDER_DEFAULTS.get(name, {}), **opts}
        if name == "QNNExecutionProvider":
            model, entries = qnn_context(self.path, self.config.ep_context_dir)
            for k, v in entries.items():
                so.add_session_config_entry(k, v)
        elif name == "XnnpackExecutionProvider" and self.config.intra_op_threads:
            # XNNPACK has its own thread pool: give it the threads, not ORT's pool too (its docs' advice)
            opts.setdefault("intra_op_num_threads", str(self.config.intra_op_threads))
            so.intra_op_num_threads = 1
        chain = [(name, opts)] + ([(CPU, {})] if name != CPU else [])
        return ort.InferenceSession(model, so, providers=[c[0] for c in chain],
                                    provider_options=[c[1] for c in chain])

    def _fallback(self, name: str, reason: str, seconds: float) -> None:
        self.attempts.append({"provider": name, "ok": False, "reason": reason, "seconds": round(seconds, 4)})
        self.trace.event("fallback", f"{self.stage}: {reason}", stage=self.stage, requested=name)

    def _record(self, create_s: float, first_run_s: float | None) -> None:
        rec = self.trace.providers.setdefault(self.stage, {})
        rec.update({"model": os.path.basename(self.path),
                    "requested": [c[0] for c in (self.requested or self.candidates)],
                    "available": available_providers(), "used": self.provider,
                    "attempts": list(self.attempts), "create_s": round(create_s, 4),
                    "first_run_s": None if first_run_s is None else round(first_run_s, 4),
                    "threads": self.config.intra_op_threads, "rss_peak_mb": round(rss_mb(), 1)})

    # -- memory guard ---------------------------------------------------------------------------------------------
    def attach(self, guard: Any) -> None:
        """Register with `guard` (a budget.BudgetController): it accounts `mb` and may release this session."""
        if self.guard is not None and self.guard() is guard:
            return
        ref = weakref.ref(self)
        self.guard = weakref.ref(guard)
        self.guard_key = guard.register_session(self.stage, self.mb, lambda: (s := ref()) is not None and s.release())

    def release(self) -> None:
        """Drop the onnxruntime session; the next use re-opens it on the provider it ran on."""
        if self.sess is not None:
            self.sess = None
            self.released = True

    def _live(self) -> Any:
        """The onnxruntime session, re-opened first if the memory guard released it (timed, in the trace)."""
        if self.sess is None and self.released:
            t0 = time.perf_counter()
            self._reopen()
            guard = self.guard() if self.guard is not None else None
            if guard is not None:
                guard.session_reopened(self.guard_key, time.perf_counter() - t0)
        return self.sess

    def _reopen(self) -> None:
        name, opts = self.candidates[self.index]
        try:
            self.sess = self._create(name, opts)
        except Exception as e:  # noqa: BLE001  it ran here before: the next provider, as on first creation
            self._fallback(name, f"re-opening failed on {name}: {type(e).__name__}: {str(e)[:300]}", 0.0)
            self._open_from(self.index + 1, None)
        self.released = False

    def _used(self) -> None:
        guard = self.guard() if self.guard is not None else None
        if guard is not None:
            guard.touch_session(self.guard_key)

    # -- running ------------------------------------------------------------------------------------------------
    def get_inputs(self) -> list[Any]:
        return self._live().get_inputs()

    def get_outputs(self) -> list[Any]:
        return self._live().get_outputs()

    @property
    def input_names(self) -> list[str]:
        return [i.name for i in self._live().get_inputs()]

    @property
    def output_names(self) -> list[str]:
        return [o.name for o in self._live().get_outputs()]

    def run(self, feeds: dict[str, np.ndarray], outputs: Sequence[str] | None = None) -> list[np.ndarray]:
        self._live()
        self._used()  # may release other, idle sessions under memory pressure (never this one)
        if self.first_run_done:
            return self.sess.run(list(outputs) if outputs else None, feeds)
        t0 = time.perf_counter()
        while True:
            try:
                out = self.sess.run(list(outputs) if outputs else None, feeds)
                break
            except Exception as e:  # noqa: BLE001
                name = self.candidates[self.index][0]
                if self.index + 1 >= len(self.candidates):
                    raise ProviderError(f"{self.stage}: first run failed on {name} and no provider is left: "
                                        f"{type(e).__name__}: {str(e)[:300]}") from e
                self._fallback(name, f"first run failed on {name}: {type(e).__name__}: {str(e)[:300]}",
                               time.perf_counter() - t0)
                self._open_from(self.index + 1, None)
                t0 = time.perf_counter()
        self.first_run_done = True
        if self.stage in self.trace.providers:
            rec = self.trace.providers[self.stage]
            rec["first_run_s"] = round(time.perf_counter() - t0, 4)
            rec["rss_peak_mb"] = max(rec.get("rss_peak_mb", 0.0), round(rss_mb(), 1))
        return out


# Every open session, and the memory guards watching runs: a guard governs the sessions opened under its trace.
# Weak both ways, so a finished run keeps nothing alive.
_OPEN: "weakref.WeakSet[Session]" = weakref.WeakSet()
_GUARDS: "weakref.WeakSet[Any]" = weakref.WeakSet()


def watch(guard: Any) -> None:
    """Let `guard` (budget.BudgetController) govern every session opened under `guard.trace`: those open now
    (e.g. the VLM, loaded before the run was planned) and those opened later."""
    _GUARDS.add(guard)
    for s in list(_OPEN):
        if s.trace is guard.trace:
            s.attach(guard)


def _adopt(s: Session) -> None:
    _OPEN.add(s)
    for g in list(_GUARDS):
        if g.trace is s.trace:
            s.attach(g)


def files_mb(path: str | os.PathLike, extra: Sequence[str | os.PathLike] = ()) -> float:
    """MB of a model's files (the graph and its external data): the floor of a session's size estimate."""
    total = 0
    for p in (path, *extra):
        try:
            total += os.path.getsize(p)
        except OSError:
            pass
    return total / 2**20


def create_session(path: str | os.PathLike, stage: str, preference: Sequence[Any] | str | None = None, *,
                   threads: int | None = None, trace: Trace | None = None, warmup: bool | dict = False,
                   config: SessionConfig | None = None, model_mb: float | None = None) -> Session:
    """Create a session for `path` on the first usable provider of `preference` (see module docstring).

    stage: the name recorded in the trace (e.g. "depth", "matcher.pair"); preference: ordered provider names
    (short or full) or (name, options) tuples, default ["cpu"]; threads: intra-op thread count (None =
    onnxruntime default); warmup: True runs zero inputs once (dynamic dims = 1), a dict runs those feeds;
    model_mb: the model files' size (default: the graph file's), the floor of the memory guard's estimate.
    Raises ProviderError when nothing works.
    """
    trace = as_trace(trace)
    cfg = config or SessionConfig()
    if threads is not None:
        cfg = SessionConfig(**{**cfg.__dict__, "intra_op_threads": threads})
    requested = normalize_preference(preference)
    avail = available_providers()
    cands = []
    for name, opts in requested:
        if name in avail:
            cands.append((name, opts))
        else:
            trace.event("fallback", f"{stage}: {name} is not available in this onnxruntime build "
                        f"(available: {avail})", stage=stage, requested=name)
    if cfg.allow_cpu_fallback and CPU not in [c[0] for c in cands] and CPU in avail:
        if cands != requested:
            trace.event("fallback", f"{stage}: falling back to CPUExecutionProvider", stage=stage, requested=CPU)
        cands.append((CPU, {}))
    if not cands:
        raise ProviderError(f"{stage}: none of the requested providers {[r[0] for r in requested]} is available "
                            f"(available: {avail}) and CPU fallback is disabled")
    s = Session(str(path), stage, cands, cfg, trace, requested=requested)
    if warmup is True:
        import onnxruntime as ort

        probe = ort.InferenceSession(str(path), _session_options(SessionConfig(graph_optimization="disable")),
                                     providers=[CPU])
        feeds = dummy_feeds(probe)
        del probe
    else:
        feeds = warmup if isinstance(warmup, dict) else None
    rss0 = rss_mb()
    s._open_from(0, feeds)
    # what the session holds: the RSS its creation added (weights, arena, first run), at least its files
    s.mb = max(rss_mb() - rss0, model_mb if model_mb is not None else files_mb(path))
    _adopt(s)
    return s
