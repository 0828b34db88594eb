"""Camera-pose accuracy: ATE / RPE, and the `mosaic eval pose` command.

ATE RMSE: camera centres of the estimated poses are aligned to the ground-truth centres by the best transform
(Umeyama), then the RMS of the residual distances: `ate_rmse_m` after a rigid SE(3) alignment (what a user gets, in
metres), `ate_sim3_m` after a similarity Sim(3) (the trajectory's shape), `sim3_scale` the scale that needed (1.0 =
metric). `ate_m` is the one the run's depth calls for (Sim(3) when depth is not metric; the field older readers use).
RPE: for consecutive evaluated frames (time order), the relative motion estimated vs ground truth; translation
as RMSE (m, after the ATE alignment's scale), rotation as the mean angle (deg).
"""
from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from mosaicthinker.runtime.infra.errors import InputError, MosaicError
from mosaicthinker.runtime.geometry import invert, rotation_angle_deg, transform, transform_scale, umeyama

SCHEMA = "mosaicthinker.eval.pose/1"


def align_trajectories(est: np.ndarray, gt: np.ndarray, with_scale: bool = False) -> np.ndarray:
    """Best transform S [4, 4] with gt ≈ S(est). est, gt: [N, 3] camera centres, N >= 3 (N = 2 and 1 handled by
    translation only)."""
    est = np.asarray(est, np.float64)
    gt = np.asarray(gt, np.float64)
    if len(est) >= 3:
        return umeyama(est, gt, with_scale)
    S = np.eye(4)
    S[:3, 3] = (gt - est).mean(0) if len(est) else 0.0
    return S


def ate_rmse(est_poses: np.ndarray, gt_poses: np.ndarray, with_scale: bool = False) -> tuple[float, np.ndarray]:
    """est_poses, gt_poses: [N, 4, 4] camera-to-world (est in any frame). Returns (ATE RMSE in m,
    S [4, 4] taking the estimate into the ground-truth frame)."""
    P = np.asarray(est_poses)[:, :3, 3]
    Q = np.asarray(gt_poses)[:, :3, 3]
    S = align_trajectories(P, Q, with_scale)
    err = np.linalg.norm(transform(S, P) - Q, axis=1)
    return float(np.sqrt(np.mean(err**2))) if len(err) else float("nan"), S


def rpe(est_poses: np.ndarray, gt_poses: np.ndarray, S: np.ndarray | None = None) -> tuple[float, float]:
    """Relative pose error between consecutive poses: (translation RMSE m, mean rotation error deg).
    est, gt: [N, 4, 4] in time order; S: the ATE alignment (its scale fixes the estimate's units)."""
    est = np.asarray(est_poses, np.float64)
    gt = np.asarray(gt_poses, np.float64)
    if len(est) < 2:
        return float("nan"), float("nan")
    S = np.eye(4) if S is None else S
    E = np.einsum("ij,njk->nik", S, est)
    s = np.array([transform_scale(T) for T in E])
    E[:, :3, :3] /= s[:, None, None]  # rotation part; translations stay scaled into metres
    te, re = [], []
    for i in range(len(E) - 1):
        d_est = invert(E[i]) @ E[i + 1]
        d_gt = invert(gt[i]) @ gt[i + 1]
        err = invert(d_gt) @ d_est
        te.append(np.linalg.norm(err[:3, 3]))
        re.append(rotation_angle_deg(err[:3, :3]))
    return float(np.sqrt(np.mean(np.square(te)))), float(np.mean(re))


def ate_fields(est: np.ndarray, gt: np.ndarray, with_scale: bool) -> dict[str, Any]:
    """est, gt: [N, 4, 4] camera-to-world in time order -> {ate_rmse_m (after SE(3)), ate_sim3_m (after Sim(3)),
    sim3_scale (the Sim(3)'s scale: 1.0 = metric), ate_m (Sim(3) if `with_scale` else SE(3)), rpe_trans_m,
    rpe_rot_deg (after the alignment `ate_m` used)}. Fewer than 2 poses: NaN in the old fields, None in the new."""
    if len(est) < 2:
        nan = float("nan")
        return {"ate_m": nan, "ate_rmse_m": nan, "ate_sim3_m": None, "sim3_scale": None, "rpe_trans_m": nan,
                "rpe_rot_deg": nan}
    ate_se3, S_se3 = ate_rmse(est, gt, False)
    ate_sim3, S_sim3 = ate_rmse(est, gt, True)
    rt, rr = rpe(est, gt, S_sim3 if with_scale else S_se3)
    return {"ate_m": ate_sim3 if with_scale else ate_se3, "ate_rmse_m": ate_se3, "ate_sim3_m": ate_sim3,
            "sim3_scale": transform_scale(S_sim3), "rpe_trans_m": rt, "rpe_rot_deg": rr}


def pick_frames(n: int, k: int, sampling: str, seed: int = 0) -> list[int]:
    """K frame indices out of n, in time order: 'uniform' = evenly spaced (first and last included),
    'random' = a random subset (uneven gaps), seeded."""
    if k < 2:
        raise InputError(f"`keyframes` must be at least 2, got {k}", fields=("keyframes",))
    if k > n:
        raise InputError(f"`keyframes={k}` is more than the {n} frames in the sequence", fields=("keyframes",))
    if sampling == "uniform":
        return sorted(set(int(round(x)) for x in np.linspace(0, n - 1, k)))
    if sampling == "random":
        return sorted(int(i) for i in np.random.default_rng(seed).choice(n, k, replace=False))
    raise InputError(f"`sampling` must be 'uniform' or 'random', got {sampling!r}", fields=("sampling",))


def depth_to_metric_like(pred: np.ndarray, semantics: str) -> tuple[np.ndarray, bool]:
    """A depth model's output [H, W] -> (z-depth-like [H, W] float32, metric?). 'relative_inverse' (disparity up
    to scale and shift) is inverted; the shift is unknown, so the result is only approximately proportional to
    depth. Non-metric depth makes alignment use essential-matrix edges whose translation lengths come from the
    depth (`alignment.align_pair_essential`), and ATE is taken after a Sim(3) trajectory alignment."""
    d = np.asarray(pred, dtype=np.float32)
    if semantics == "metric_m":
        return d, True
    if semantics == "relative":
        return np.where(d > 0, d, 0).astype(np.float32), False
    if semantics == "relative_inverse":
        with np.errstate(divide="ignore"):
            z = np.where(d > 1e-6 * max(float(d.max()), 1e-12), 1.0 / d, 0.0)
        return z.astype(np.float32), False
    raise MosaicError(f"depth model semantics {semantics!r} is not one of metric_m, relative, relative_inverse")


def _load_role(bundle: str | None, role: str, trace: Any) -> Any:
    if not bundle:
        raise InputError(f"`{role}=model` needs `bundle` (the bundle holding the {role} model)",
                         fields=(role, "bundle"))
    try:
        from mosaicthinker.runtime.models import load_role  # lazy: the stage adapters are another part of the runtime
    except ImportError as e:
        raise MosaicError(f"--{role} model: the model stages (mosaicthinker.runtime.models.load_role) are not "
                          f"available in this build ({e}); use --{role} "
                          f"{'sensor' if role == 'depth' else 'sift'}") from None
    return load_role(bundle, role, trace=trace)


def evaluate_pose(source: Any, indices: Sequence[int], matcher: Any = "sift", strategy: str = "mst",
                  depth_model: Any = None, conf: Any = None, trace: Any = None, path: str = "frames",
                  embedder: Any = None) -> dict[str, Any]:
    """Align frames `indices` of a source with ground-truth poses and score them. matcher: 'orb' | 'sift' |
    matcher object (a shared FeatureMatcher keeps its feature cache across calls); depth_model: None (sensor
    depth) or an adapter with .predict(rgb) / .predict_metric(rgb) and .semantics.

    path "ask" (the command's default, `mosaic eval pose --path ask`): the alignment `mosaic ask` runs
    (`align.align_keyframes` with the pipeline's config `conf`: the whole-image tree over the given frames - there
    are no detections to restrict matches to - its depth check, then the odometry backbone or bridges over the
    other frames of the source, which are available to it as they are to `ask`); the result lists the other frames
    it used. path "frames" (this function's default, for the benchmarks that compare strategies): the paper's
    alignment of the given frames alone (`align.align_frames` with `strategy` and the alignment config `conf`).
    Frames whose ground truth marks a tracking failure (ScanNet's -inf) are aligned but not scored (listed)."""
    if path not in ("ask", "frames"):
        raise InputError(f"`path` must be 'ask' or 'frames', got {path!r}", fields=("path",))
    frames, with_scale, t_depth = [], False, 0.0
    for i in indices:
        f = source[i]
        if depth_model is not None:
            t0 = time.perf_counter()
            d, metric = depth_to_metric_like(depth_model.predict(f.rgb), getattr(depth_model, "semantics", ""))
            t_depth += time.perf_counter() - t0
            with_scale = with_scale or not metric
            f = replace(f, depth=d)
        elif f.depth is None:
            raise InputError(f"{source.name}: frame {i} has no sensor depth; use `depth=model`", fields=("depth",))
        frames.append(f)
    untracked = [f.index for f in frames if f.pose_gt is None]
    if len(untracked) == len(frames):  # before the alignment: nothing would be left to score
        raise InputError(f"{source.name}: none of the {len(frames)} frames has a ground-truth pose (needed for "
                         f"ATE/RPE)")
    t0 = time.perf_counter()
    if path == "frames":
        from mosaicthinker.runtime.align import align_frames

        res = align_frames(frames, matcher=matcher, strategy=strategy, conf=conf, with_scale=with_scale, log=trace)
        used: list[int] = []
    else:
        res, used = _align_as_ask(source, frames, matcher, depth_model, with_scale, conf, trace, embedder)
    secs = time.perf_counter() - t0
    ev = [f for f in frames if f.index in res.poses and f.pose_gt is not None]  # time order
    est = np.array([res.poses[f.index] for f in ev])
    gt = np.array([f.pose_gt for f in ev])
    scores = ate_fields(est, gt, with_scale)
    return {
        **scores, "path": path,
        "aligned_frames": len([i for i in res.aligned if i in {f.index for f in frames}]),
        "total_frames": len(frames),
        "unaligned_frames": list(res.unaligned), "guessed_frames": list(res.guessed),
        "untracked_frames": untracked, "other_frames_used": sorted(int(i) for i in used),
        "fates": {str(k): v for k, v in res.fates.items()},
        "evaluated_frames": len(ev), "sim3": with_scale, "edge": res.edge, "root": res.root,
        "poses": {f.index: res.poses[f.index] for f in ev}, "gt_poses": {f.index: f.pose_gt for f in ev},
        "frames": list(map(int, indices)),
        "seconds": secs + t_depth, "seconds_breakdown": {**res.seconds, "depth_model": t_depth},
        "alignment": res.to_dict(),
    }


def evaluate_pose_map(source: Any, indices: Sequence[int], bundle: str | None, conf: Any = None, trace: Any = None,
                      matcher: str = "model", perception: Any = None, names: Sequence[str] | None = None
                      ) -> dict[str, Any]:
    """`evaluate_pose` for RGB only on the path `ask` uses, in the units a user gets: the frames `indices` go
    through `pipeline.build_map` as its key frames (alignment, every category the bundle's detector names,
    fusion, gravity and the metric scale `ask` applies), and the map's poses are scored: `ate_rmse_m` after an
    SE(3) registration is then in metres as the user gets them, `sim3_scale` the factor the map's scale missed
    by (1.0 = right), `scale` what the map stated (where the scale came from, +-%) and whether that covered the
    error (`scale_covered`: |log sim3_scale| within the stated range, `stated_z` sd). perception / names: injected
    (tests: the synthetic oracle) instead of the bundle's models and every category its detector names."""
    from mosaicthinker.runtime import pipeline
    from mosaicthinker.runtime.conf import PipelineConfig
    from mosaicthinker.runtime.detectable import detectable_names
    from mosaicthinker.runtime.infra.trace import Trace

    trace = trace if trace is not None else Trace()  # its decisions hold the scale statement
    extra = dict(conf or {}) if not isinstance(conf, PipelineConfig) else {}
    pconf = PipelineConfig.merged({**extra, "depth": "model", "matcher": matcher})
    perception = perception if perception is not None else pipeline.perception_from_bundle(str(bundle), pconf, trace)
    names = list(names) if names is not None else detectable_names(bundle)
    frames_gt = {int(i): source[int(i)].pose_gt for i in indices}
    t0 = time.perf_counter()
    build = pipeline.build_map(source, names, [], perception, pconf, trace, len(indices), chosen=indices)
    secs = time.perf_counter() - t0
    ev = [i for i in sorted(frames_gt) if i in build.poses_world and frames_gt[i] is not None]
    est = np.array([build.poses_world[i] for i in ev]).reshape(-1, 4, 4)
    gt = np.array([frames_gt[i] for i in ev]).reshape(-1, 4, 4)
    scores = ate_fields(est, gt, with_scale=perception.depth_relative)
    al = build.info.get("alignment", {})
    ms = build.map.meta.get("scale") or trace.decisions.get("scale") or {}
    s3 = scores.get("sim3_scale")
    steps = step_scale(est, gt)
    return {
        **scores, "path": "ask", "metric_path": "build_map", "objects": names,
        "aligned_frames": len([i for i in indices if i in build.poses_world]), "total_frames": len(indices),
        "unaligned_frames": list(build.unaligned), "guessed_frames": list(al.get("guessed", [])),
        "untracked_frames": [i for i in sorted(frames_gt) if frames_gt[i] is None],
        "other_frames_used": sorted(int(i) for i in al.get("other_frames", []) or []),
        "fates": {str(k): v for k, v in (al.get("fates") or {}).items()},
        "evaluated_frames": len(ev), "sim3": perception.depth_relative, "edge": al.get("edge"),
        "root": al.get("root"), "poses": {i: build.poses_world[i] for i in ev},
        "gt_poses": {i: frames_gt[i] for i in ev}, "frames": list(map(int, indices)),
        "seconds": secs, "seconds_breakdown": {**(al.get("seconds") or {}),
                                               **{k: round(v.seconds, 3) for k, v in trace.stages.items()}},
        "alignment": al,
        "scale": {k: ms.get(k) for k in ("scale", "percent", "sd_log", "source", "message")},
        "scale_error": None if not s3 else 1.0 / s3 - 1.0,
        "scale_covered": None if not s3 or ms.get("sd_log") is None else bool(abs(np.log(s3)) <= ms.get("stated_z", 1.0) * ms["sd_log"]),
        "instances": len(build.map.instances),
        "step_scale": steps, "scale_error_steps": None if not steps else 1.0 / steps - 1.0,
    }


def step_scale(est: np.ndarray, gt: np.ndarray, min_step_m: float = 0.05) -> float | None:
    """The map's scale error from its own steps: the median over consecutive scored frames (est, gt [N, 4, 4] in
    time order) of the true camera step over the estimated one (steps under `min_step_m` left out). Unlike the
    Sim(3)'s scale it holds where the trajectory's shape is wrong (a misplaced chain): None under 2 steps."""
    if len(est) < 3:
        return None
    de = np.linalg.norm(np.diff(np.asarray(est)[:, :3, 3], axis=0), axis=1)
    dg = np.linalg.norm(np.diff(np.asarray(gt)[:, :3, 3], axis=0), axis=1)
    ok = (dg > min_step_m) & (de > 1e-9)
    return float(np.median(dg[ok] / de[ok])) if ok.sum() >= 2 else None


def _align_as_ask(source: Any, frames: list[Any], matcher: Any, depth_model: Any, with_scale: bool, conf: Any,
                  trace: Any, embedder: Any) -> tuple[Any, list[int]]:
    """`pipeline`'s alignment of the key frames `frames` with the rest of `source` available (module doc of
    `evaluate_pose`). Returns (alignment, the other frames it used)."""
    from mosaicthinker.runtime.align import align_keyframes, make_matcher
    from mosaicthinker.runtime.conf import PipelineConfig
    from mosaicthinker.runtime.infra.trace import StageLog, as_trace
    from mosaicthinker.runtime.scan import remove_redundant

    pconf = conf if isinstance(conf, PipelineConfig) else PipelineConfig.merged(conf)
    trace = as_trace(trace)
    m = make_matcher(matcher, pconf.match)
    if depth_model is None:
        with_depth = lambda f: f  # noqa: E731 - sensor depth as read
    else:
        def with_depth(f: Any) -> Any:
            return replace(f, depth=depth_to_metric_like(depth_model.predict(f.rgb),
                                                         getattr(depth_model, "semantics", ""))[0])
    with trace.stage("dedup"):
        scan = remove_redundant(source, pconf.dedup)
    emb = np.stack([embedder.embed(f.rgb) for f in frames]) if embedder is not None else None
    log = StageLog()
    al, used = align_keyframes(frames, m, {f.index: None for f in frames}, emb, source, with_depth, with_scale,
                               pconf.alignment, log, thumbs=scan.thumbs, backbone=pconf.backbone,
                               describe=embedder.embed if embedder is not None else None, sfm=pconf.sfm)
    trace.record(log)
    return al, [int(getattr(f, "index", f)) for f in used]


# ----------------------------------------------------------------------------- command


COMMON_FLAGS = ("bundle", "out")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from mosaicthinker.runtime.cli import add_stage_flags
    from mosaicthinker.runtime.commands.flags import add_keyframes

    parser.add_argument("--data", required=True, metavar="DIR",
                        help="RGB-D folder with ground-truth poses (7-Scenes or TUM layout)")
    add_keyframes(parser, 32, "the number of frames the pose benchmark aligns")
    parser.add_argument("--sampling", choices=["uniform", "random"], default="uniform",
                        help="evenly spaced frames, or a random subset kept in time order")
    parser.add_argument("--seed", type=int, default=0, help="seed of the random subset")
    parser.add_argument("--strategy", choices=["mst", "sequential"], default="mst",
                        help="maximum spanning tree (paper) or sequential chaining (baseline); --path frames only")
    parser.add_argument("--conf", default=None, metavar="JSON", help="pipeline config keys as JSON for --path ask "
                        "(e.g. '{\"backbone\": {\"walk_all\": true}}'), alignment config keys for --path frames")
    parser.add_argument("--path", choices=["ask", "frames"], default="ask",
                        help="ask: the alignment `mosaic ask` runs, the other frames of the sequence available to it "
                             "(default); frames: the given frames alone (the paper's tree or chain)")
    add_stage_flags(parser, depth=True, matcher=True)


def run(args: argparse.Namespace) -> dict[str, Any]:
    from mosaicthinker.runtime.infra.outputs import run_group

    with run_group(args.out) as outs:  # --out checked and locked before the evaluation runs
        return _run(args, outs)


def _run(args: argparse.Namespace, outs: Any) -> dict[str, Any]:
    from mosaicthinker.runtime.frames import open_source
    from mosaicthinker.runtime.infra.trace import Trace

    trace = Trace()
    t0 = time.perf_counter()
    src = open_source(args.data)
    if not src.has_pose:
        raise InputError(f"{args.data}: needs ground-truth poses for every frame (7-Scenes .pose.txt or TUM "
                         f"groundtruth.txt)")
    idx = pick_frames(len(src), args.keyframes, args.sampling, args.seed)
    depth_model = _load_role(args.bundle, "depth", trace) if args.depth == "model" else None
    matcher = _load_role(args.bundle, "matcher", trace) if args.matcher == "model" else args.matcher
    embedder = _bundle_embedder(args.bundle, trace) if args.path == "ask" else None
    from mosaicthinker.runtime.infra.progress import phase

    with phase("alignment", len(idx), "frame") as bar:  # one call: the bar shows the time it takes
        if args.path == "ask" and args.depth == "model" and _has_detector(args.bundle):
            out = evaluate_pose_map(src, idx, args.bundle, _conf_arg(args.conf), trace, args.matcher)
        else:
            out = evaluate_pose(src, idx, matcher, args.strategy, depth_model, conf=_conf_arg(args.conf),
                                trace=trace, path=args.path, embedder=embedder)
        bar.to(len(idx))
    out["seconds"] = time.perf_counter() - t0
    out.update({"schema": SCHEMA, "data": str(args.data), "keyframes": args.keyframes, "sampling": args.sampling,
                "seed": args.seed, "strategy": args.strategy if args.path == "frames" else "ask", "conf": args.conf,
                "embedder": None if embedder is None else getattr(embedder, "name", "embedder"),
                "depth": args.depth, "matcher": args.matcher,
                "events": trace.events})
    if outs is not None:
        from mosaicthinker.runtime.infra.outputs import finish_group

        finish_group(outs, [("eval_pose_json", "eval_pose.json", dict(out)),
                            ("trace_json", "trace.json", trace.to_dict())], out, trace)
    return out


def _conf_arg(text: str | None) -> dict[str, Any] | None:
    """--conf JSON -> a mapping of config keys (None without)."""
    import json

    if not text:
        return None
    try:
        conf = json.loads(text)
    except ValueError as e:
        raise InputError(f"--conf: not JSON ({e})") from None
    if not isinstance(conf, dict):
        raise InputError("--conf: must be a JSON object of config keys")
    return conf


def _has_detector(bundle: str | None) -> bool:
    """Whether the bundle can map objects (a closed-set detector): RGB only, the metric scale then comes from the
    map `ask` builds; without one the poses are scored in the alignment's own units (Sim(3) only)."""
    if not bundle:
        return False
    from mosaicthinker.runtime.infra.bundle import load_bundle

    return load_bundle(bundle).has_role("detector")


def _bundle_embedder(bundle: str | None, trace: Any) -> Any:
    """The bundle's embedder (the tree's similarity and the backbone's revisits use it in `ask`), or None."""
    if not bundle:
        return None
    from mosaicthinker.runtime.infra.bundle import load_bundle

    return _load_role(bundle, "embedder", trace) if load_bundle(bundle).has_role("embedder") else None


def _num(x: Any, digits: int = 3) -> str:
    return "n/a" if x is None or not np.isfinite(x) else f"{x:.{digits}f}"


def render(r: dict[str, Any]) -> str:
    un = r.get("unaligned_frames", [])
    gs = r.get("guessed_frames", [])
    fates: dict[str, int] = {}
    for v in (r.get("fates") or {}).values():
        fates[v] = fates.get(v, 0) + 1
    lines = [f"pose evaluation on {r.get('data')}: {r.get('keyframes')} frames ({r.get('sampling')}, seed "
             f"{r.get('seed')}), strategy {r.get('strategy')}, depth {r.get('depth')}, matcher {r.get('matcher')}",
             f"  edges           {r.get('edge', 'rgbd')}" + ("  (essential matrix + depth scale: relative depth)"
                                                          if r.get('edge') == 'essential' else ""),
             f"  ATE RMSE        {_num(r['ate_rmse_m'], 4)} m after SE(3) (metric), {_num(r.get('ate_sim3_m'), 4)} m after Sim(3)"
             f" (scale {_num(r.get('sim3_scale'))}, 1.0 = metric)",
             f"  RPE             {r['rpe_trans_m']:.4f} m, {r['rpe_rot_deg']:.2f} deg",
             f"  aligned frames  {r['aligned_frames']} / {r['total_frames']}"
             + (f"  unaligned: {un}" if un else "") + (f"  guessed (failed links): {gs}" if gs else ""),
             f"  seconds         {r['seconds']:.2f}"]
    if r.get("path") == "ask":
        lines.insert(1, f"  path            the alignment `mosaic ask` runs: {len(r.get('other_frames_used', []))} other "
                        f"frame(s) of the sequence used" + (f" ({', '.join(f'{n} {k}' for k, n in fates.items())})"
                                                           if fates else ""))
    sc = r.get("scale") or {}
    if sc.get("message"):
        err = r.get("scale_error")
        lines.append(f"  metric scale    {sc['message']}" + ("" if err is None else
                     f"; against the ground truth {100 * err:+.1f} % ("
                     + ("within" if r.get("scale_covered") else "NOT within") + " the stated +-)"))
    if r.get("untracked_frames"):
        lines.append(f"  not scored      {r['untracked_frames']} (ground truth marks a tracking failure)")
    return "\n".join(lines)
