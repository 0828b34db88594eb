"""Parity checks of exported graphs: the one onnxruntime session factory, the one seed policy and the one
trial loop every check runs.

Parity always runs on FRESH random inputs (a new seed per call, recorded next to the result): exporters can
bake example inputs into constants, and a check on the example input would not see that. `run_trials` is the
loop (seed policy `parity_rng`, trial counts `PARITY_TRIALS`); the checks differ only in what they compare:

- `parity_check`: a graph against a reference (torch module, or the fp32 graph for a quantised copy),
  element-wise (relative error, cosine), tolerances `PARITY_TOL` by precision;
- `ort_parity`: a converted `.ort` file against its source `.onnx` (same precision, `ORT_PARITY_TOL`);
- `agreement_check`: a task metric over (reference, graph) outputs (e.g. set agreement of discrete selections).

A failing check raises ExportError (`require=True`, the default) so a broken export never lands in a bundle.
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from mosaicthinker.runtime.infra.errors import ExportError

from .log import progress

Feeds = dict[str, np.ndarray]
MakeInputs = Callable[[np.random.Generator], Feeds]
# Parity tolerances by precision: (max relative error = max|a-b| / max|ref|, min cosine similarity).
PARITY_TOL = {
    "fp32": (1e-3, 0.99999),
    "fp16": (2e-2, 0.999),
    "int8-dynamic": (0.15, 0.98),
    "int8-qdq": (0.15, 0.98),
}
# Fresh random inputs per parity check, by precision. A quantised graph's error varies a lot from input to input
# (PyDNet++ int8-qdq: rel 0.02-0.97 over 40 inputs, 25% above tolerance), so two trials shipped it in about half
# the runs; the worst of 16 makes the ship/refuse decision the same run after run. fp32 is exact to ~1e-6.
PARITY_TRIALS = {"fp32": 4, "fp16": 16, "int8-dynamic": 16, "int8-qdq": 16}
# .ort vs its source .onnx (same precision): conversion pre-applies graph optimisations (fusions, layout), so
# only rounding-order differences are allowed: ~1e-6 in fp32, fp16 rounding of fused ops, one int8 step.
ORT_PARITY_TOL = {"fp32": (1e-4, 0.99999), "fp16": (1e-2, 0.9999), "int8-qdq": (2e-2, 0.999)}


# ---------------------------------------------------------------------------------------------------------------
# Sessions and the seed policy

def parity_rng(seed: int | None = None) -> tuple[int, np.random.Generator]:
    """The one seed policy of every parity check: a fresh seed drawn here (unless the caller fixes one for a
    reproduction), returned so the check records it in the manifest next to its result."""
    seed = int.from_bytes(os.urandom(4), "little") if seed is None else int(seed)
    return seed, np.random.default_rng(seed)


def parity_trials(precision: str, trials: int | None = None) -> int:
    """Number of fresh inputs a parity check of `precision` runs (PARITY_TRIALS unless given)."""
    return int(trials) if trials is not None else PARITY_TRIALS.get(precision, PARITY_TRIALS["int8-qdq"])


def ort_session(path: str | os.PathLike, threads: int = 1, *, runtime_opt: bool = False, arm_like: bool = False,
                level: str | None = None):
    """A CPU onnxruntime session for export-time checks (the runtime uses runtime/infra/providers.py).

    runtime_opt=True replays the optimisations saved in a `*.with_runtime_opt.ort` file (without it that file
    runs un-fused: QDQ groups stay float-emulated). arm_like: the .ort converter's settings for the arm target
    (no x86-only NCHWc layout transformer, int8 QDQ kernels allowed), so a source graph optimises here to the
    same graph as its .ort file. level: "basic" | "all" (None: onnxruntime's default, all)."""
    import onnxruntime as ort

    so = ort.SessionOptions()
    so.intra_op_num_threads = threads
    so.inter_op_num_threads = 1
    so.log_severity_level = 3
    ort.set_default_logger_severity(3)
    if level is not None:
        so.graph_optimization_level = {"basic": ort.GraphOptimizationLevel.ORT_ENABLE_BASIC,
                                       "all": ort.GraphOptimizationLevel.ORT_ENABLE_ALL}[level]
    if runtime_opt:
        so.add_session_config_entry("session.enable_saved_runtime_optimizations", "1")
    kw = {}
    if arm_like:
        so.add_session_config_entry("session.qdqisint8allowed", "1")
        kw["disabled_optimizers"] = ["NchwcTransformer"]
    return ort.InferenceSession(str(path), so, providers=["CPUExecutionProvider"], **kw)


def ort_run(path_or_session: Any, feeds: Feeds) -> list[np.ndarray]:
    """Run a graph (path or session) on the feeds it declares (extra feeds are dropped)."""
    sess = ort_session(path_or_session) if isinstance(path_or_session, (str, Path)) else path_or_session
    names = {i.name for i in sess.get_inputs()}
    return sess.run(None, {k: v for k, v in feeds.items() if k in names})


def run_trials(make_inputs: MakeInputs, trials: int, step: Callable[[Feeds], Any], *,
               seed: int | None = None) -> tuple[int, list[Any]]:
    """The one trial loop: `trials` fresh inputs from the seed policy, `step(feeds)` on each.
    Returns (seed, [step results]); the same seed replays the same inputs."""
    seed, rng = parity_rng(seed)
    return seed, [step(make_inputs(rng)) for _ in range(trials)]


# ---------------------------------------------------------------------------------------------------------------
# Comparisons

def compare_outputs(ref: Sequence[np.ndarray], got: Sequence[np.ndarray]) -> list[dict[str, float]]:
    """Per output: max_abs, mean_abs, rel (max_abs / max|ref|), cosine similarity, exact-equality fraction."""
    if len(ref) != len(got):
        raise ExportError(f"parity: reference has {len(ref)} outputs, graph has {len(got)}")
    res = []
    for r, g in zip(ref, got):
        r = np.asarray(r)
        g = np.asarray(g)
        if r.shape != g.shape:
            raise ExportError(f"parity: output shape {g.shape} differs from reference {r.shape}")
        rf, gf = r.astype(np.float64).ravel(), g.astype(np.float64).ravel()
        d = np.abs(rf - gf)
        denom = max(float(np.abs(rf).max()) if rf.size else 0.0, 1e-12)
        nr, ng = np.linalg.norm(rf), np.linalg.norm(gf)
        cos = float(rf @ gf / (nr * ng)) if nr > 0 and ng > 0 else float(nr == ng)
        res.append({"max_abs": float(d.max()) if d.size else 0.0, "mean_abs": float(d.mean()) if d.size else 0.0,
                    "rel": float(d.max() / denom) if d.size else 0.0, "cosine": cos,
                    "equal_frac": float((rf == gf).mean()) if rf.size else 1.0})
    return res


def close_fraction(ref: Sequence[np.ndarray], got: Sequence[np.ndarray], rel_tol: float) -> list[float]:
    """Per output: the fraction of elements within rel_tol * max|ref| (+1e-6) of the reference."""
    out = []
    for r, g in zip(ref, got):
        r64, g64 = np.asarray(r, np.float64), np.asarray(g, np.float64)
        tol = rel_tol * max(float(np.abs(r64).max()) if r64.size else 0.0, 1e-12) + 1e-6
        out.append(float((np.abs(r64 - g64) <= tol).mean()) if r64.size else 1.0)
    return out


def worst_of(per_trial: Sequence[Sequence[dict[str, float]]]) -> dict[str, float]:
    """Worst relative error, cosine and absolute error over every output of every trial."""
    return {"rel": max(o["rel"] for t in per_trial for o in t),
            "cosine": min(o["cosine"] for t in per_trial for o in t),
            "max_abs": max(o["max_abs"] for t in per_trial for o in t)}


def _tolerance(precision: str, rel_tol: float | None, cos_min: float | None) -> tuple[float, float]:
    rel = PARITY_TOL.get(precision, PARITY_TOL["fp32"])[0] if rel_tol is None else rel_tol
    cos = PARITY_TOL.get(precision, PARITY_TOL["fp32"])[1] if cos_min is None else cos_min
    return rel, cos


# ---------------------------------------------------------------------------------------------------------------
# The checks

def parity_check(onnx_path: str | os.PathLike, reference: Callable[[Feeds], Sequence[np.ndarray]],
                 make_inputs: MakeInputs, *, precision: str = "fp32",
                 trials: int | None = None, rel_tol: float | None = None, cos_min: float | None = None,
                 outputs: Sequence[int] | None = None, seed: int | None = None, require: bool = True,
                 label: str = "") -> dict[str, Any]:
    """Run the ONNX graph and a reference on `trials` (default PARITY_TRIALS[precision]) fresh random inputs and
    compare.

    reference(feeds) -> list of output arrays in graph output order (e.g. the torch module, or the fp32 graph
    for a quantised one); make_inputs(rng) -> feeds; outputs: indices of outputs to compare (default all);
    tolerances default to PARITY_TOL[precision]. Returns {"ok", "precision", "trials", "seed", "worst":
    {rel, cosine, max_abs}, "outputs": [...]} and raises ExportError when not ok and require=True.
    """
    rel_tol, cos_min = _tolerance(precision, rel_tol, cos_min)
    trials = parity_trials(precision, trials)
    sess = ort_session(onnx_path)

    def step(feeds: Feeds) -> list[dict[str, float]]:
        got, ref = ort_run(sess, feeds), list(reference(feeds))
        if outputs is not None:
            got, ref = [got[i] for i in outputs], [ref[i] for i in outputs]
        return compare_outputs(ref, got)

    seed, per_out = run_trials(make_inputs, trials, step, seed=seed)
    worst = worst_of(per_out)
    ok = worst["rel"] <= rel_tol and worst["cosine"] >= cos_min
    res = {"ok": bool(ok), "precision": precision, "trials": trials, "seed": seed, "inputs": "fresh random",
           "tolerance": {"rel": rel_tol, "cosine_min": cos_min}, "worst": worst, "outputs": per_out[-1]}
    progress(f"parity {label or Path(onnx_path).name} [{precision}]: rel={worst['rel']:.2e} "
             f"cos={worst['cosine']:.6f} -> {'ok' if ok else 'FAIL'}")
    if require and not ok:
        raise ExportError(f"parity check failed for {onnx_path} ({precision}): worst relative error "
                          f"{worst['rel']:.3g} (tol {rel_tol}), cosine {worst['cosine']:.5f} (min {cos_min}); "
                          f"the artifact was not added to the bundle")
    return res


def _ort_trials(got_s: Any, onnx_path: str | Path, make_inputs: MakeInputs, level: str, trials: int,
                seed: int, rel_tol: float) -> tuple[list, dict[str, float]]:
    ref_s = ort_session(onnx_path, level=level, arm_like=True)

    def step(feeds: Feeds) -> tuple[list[dict[str, float]], list[float]]:
        ref, got = ort_run(ref_s, feeds), ort_run(got_s, feeds)
        return compare_outputs(ref, got), close_fraction(ref, got, rel_tol)

    _, res = run_trials(make_inputs, trials, step, seed=seed)
    per = [r[0] for r in res]
    return per, {**worst_of(per), "close_frac": min(c for r in res for c in r[1])}


def ort_parity(ort_path: str | Path, onnx_path: str | Path, make_inputs: MakeInputs, *,
               runtime_opt: bool = False, trials: int = 2, rel_tol: float = 1e-4, cos_min: float = 0.99999,
               seed: int | None = None, label: str = "") -> dict[str, Any]:
    """Parity of a converted .ort file against the .onnx it came from (same precision) on fresh random inputs.

    The conversion only re-serialises and pre-optimises the graph, so the tolerance is tight (ORT_PARITY_TOL).
    Graphs that end in a top-K / NMS selection (XFeat keypoints, SSD boxes) can flip a few ranks under
    rounding-order differences: such an output still passes when >= 99 % of its elements agree within the
    tolerance and its cosine is >= 0.999, and the result says `selection_flips: true`.
    Returns the same fields as `parity_check`; raises ExportError when it fails."""
    seed, _ = parity_rng(seed)
    got_s = ort_session(ort_path, runtime_opt=runtime_opt, arm_like=True, level="all")
    # the .ort holds the source graph optimised at ALL level (Fixed style) or at BASIC level plus replayable
    # QDQ fusions (Runtime style): compare with the source optimised the same way (same inputs: same seed)
    for level in (["basic", "all"] if runtime_opt else ["all"]):
        per, worst = _ort_trials(got_s, onnx_path, make_inputs, level, trials, seed, rel_tol)
        strict = worst["rel"] <= rel_tol and worst["cosine"] >= cos_min
        if strict:
            break
    flips = not strict and worst["close_frac"] >= 0.99 and worst["cosine"] >= 0.999
    ok = strict or flips
    progress(f"parity {label or Path(ort_path).name}: rel={worst['rel']:.2e} cos={worst['cosine']:.6f} -> "
             f"{'ok' if ok else 'FAIL'}")
    if not ok:
        raise ExportError(f"{ort_path}: .ort output differs from its source graph {Path(onnx_path).name} "
                          f"(rel {worst['rel']:.3g} > {rel_tol} or cosine {worst['cosine']:.5f} < {cos_min}); "
                          f"the conversion is broken for this graph")
    return {"ok": True, "reference": f"source .onnx (same precision), optimised at {level.upper()} level",
            "trials": trials, "seed": seed,
            "inputs": "fresh random", "runtime_opt_replayed": runtime_opt, "selection_flips": flips,
            "tolerance": {"rel": rel_tol, "cosine_min": cos_min}, "worst": worst, "outputs": per[-1]}


def agreement_check(onnx_path: str | Path, reference: Callable[[Feeds], Sequence[np.ndarray]],
                    make_inputs: MakeInputs, metric: Callable[[list, list], float], need: float, *,
                    precision: str, trials: int | None = None, require: bool = True,
                    label: str = "") -> dict[str, Any]:
    """A task metric (e.g. set agreement of discrete selections) of the graph vs a reference, worst over fresh
    inputs; ok when >= need. Raises ExportError when require and it fails."""
    trials = parity_trials(precision, trials)
    sess = ort_session(onnx_path)
    seed, vals = run_trials(make_inputs, trials, lambda feeds: float(metric(list(reference(feeds)),
                                                                          ort_run(sess, feeds))))
    ok = min(vals) >= need
    progress(f"agreement {label or Path(onnx_path).name} [{precision}]: {min(vals):.3f} (min {need}) -> "
             f"{'ok' if ok else 'FAIL'}")
    if require and not ok:
        raise ExportError(f"parity (set agreement) failed for {onnx_path} ({precision}): {min(vals):.3f} < {need}; "
                          f"the artifact was not added to the bundle")
    return {"ok": bool(ok), "worst": min(vals), "min": need, "trials": trials, "seed": seed,
            "inputs": "fresh random"}
