"""The `mosaic plan` command: the planner's answer for a clip (or every profile) under a device profile.

runtime/cli.py runs it as `mosaicthinker.runtime.commands.plan`; the package re-exports add_arguments, run, render.
"""
from __future__ import annotations

import argparse
import shutil
import textwrap
from typing import Any

from ..infra.errors import BudgetError, InputError, MosaicError
from ..budget.planner import STARTS, PlanConf, clip_of, plan
from ..budget.profile import MODEL_SETS, list_profiles
from .flags import add_answerer, add_clip
from ..frames import open_source


COMMON_FLAGS = ("bundle", "profile")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    src = parser.add_argument_group("clip (one of)")
    src.add_argument("--video", metavar="V", help="video, image folder or RGB-D folder: its length and fps")
    add_clip(src, None, None, "clip (with --fps; or the --fps of an image folder)")
    parser.add_argument("--candidates", type=int, help="frames kept by redundant-frame removal, if known "
                                                       "(default: an estimate)")
    parser.add_argument("--keyframes-max", type=int, help="upper bound for K (default 32)")
    parser.add_argument("--online", action="store_true",
                        help="decode + dedup run while the video is captured: not in the per-question latency")
    add_answerer(parser, "the answerer `mosaic ask` will use: vlm or auto (default) plan the VLM's costs when the "
                         "profile and bundle have one (auto: the VLM answers what the map reasoner does not "
                         "recognise); map: the map reasoner only, no VLM costs")
    parser.add_argument("--models", choices=MODEL_SETS, default="shared",
                        help="cost set: shared (the shared mobile models) or paper (the paper's models at real "
                             "size, [paper_costs.*]); --profile all plans every profile in profiles/")
    parser.add_argument("--start", choices=STARTS, default="cold",
                        help="cold (default): each question loads its models, as one `mosaic ask` process does; "
                             "warm: a deployed app keeps its sessions open between questions, so the loads are a "
                             "one-time cold start (shown apart) unless the models cannot stay resident in the "
                             "memory budget")


def _clip_from_args(args: argparse.Namespace) -> tuple[float, float]:
    if args.video:
        if args.duration:
            raise InputError("give either --video or --duration, not both")

        return clip_of(open_source(args.video, **({"fps": args.fps} if args.fps else {})), args.fps)
    if args.duration is None or args.fps is None:
        raise InputError("mosaic plan needs --video V, or --duration S and --fps F")
    return float(args.duration), float(args.fps)


def run(args: argparse.Namespace) -> dict[str, Any]:
    if not args.profile:
        raise InputError("mosaic plan needs --profile (a file, or a name from profiles/: "
                         + ", ".join(p.stem for p in list_profiles()) + ")")
    duration, fps = _clip_from_args(args)
    conf = PlanConf.merged(keyframes_max=args.keyframes_max, use_vlm=args.answerer != "map",
                           video_pass="online" if args.online else "question", start=args.start)
    if args.profile == "all":  # K for every profile of profiles/ (those that cannot plan say why)
        rows = {}
        for path in list_profiles():
            try:
                p = plan(path, duration, fps, bundle=args.bundle, conf=conf, candidates=args.candidates,
                         models=args.models)
                rows[path.stem] = {"keyframes": p.keyframes, "limited_by": p.limited_by, "planned_ms": p.total_ms,
                                   "cold_start_ms": p.cold_start_ms,
                                   "loads_per_question_ms": p.fixed_ms.get("model_loads", 0.0)}
            except MosaicError as e:
                rows[path.stem] = {"keyframes": None, "error": str(e), "no_fit": isinstance(e, BudgetError)}
        return {"schema": "mosaicthinker.plan-all/1", "models": args.models, "start": args.start, "profiles": rows}
    p = plan(args.profile, duration, fps, bundle=args.bundle, conf=conf, candidates=args.candidates,
             models=args.models)
    d = p.to_dict()
    d["models"] = args.models
    return d


def _wrap(head: str, text: str) -> str:
    """`head` + `text` wrapped at word boundaries to the terminal's width, continued under the text (a reason is
    read whole, never cut)."""
    width = max(60, shutil.get_terminal_size((100, 24)).columns - 1)
    return textwrap.fill(text, width=width, initial_indent=head, subsequent_indent=" " * len(head),
                         break_long_words=False, break_on_hyphens=False)


def _all_row(name: str, x: dict[str, Any], start: str) -> str:
    """One profile's line of `--profile all`: K and what limits it, or why no K fits (wrapped, whole)."""
    head = f"  {name:<26} "
    if x.get("keyframes") is None:
        err = x["error"].removeprefix(f"profile {name}: ")  # the row already names it
        return _wrap(head, ("no K fits: " if x.get("no_fit") else "cannot plan: ") + err)
    row = f"K = {x['keyframes']:>3}  (limited by {x['limited_by']}, {x['planned_ms']:,.0f} ms"
    if start == "warm":
        row += (f"; cold start {x['cold_start_ms']:,.0f} ms once" if not x["loads_per_question_ms"]
                else f"; loads {x['loads_per_question_ms']:,.0f} ms in every question: not resident")
    return _wrap(head, row + ")")


def render(result: dict[str, Any]) -> str:
    r = result
    if r.get("schema") == "mosaicthinker.plan-all/1":
        start = r.get("start", "cold")
        return "\n".join([f"key frames K per profile ({r['models']} models, {start} start):"]
                         + [_all_row(n, x, start) for n, x in r["profiles"].items()])
    v = r["video"]
    lines = [f"plan for {r['profile']} ({r['device']})",
             f"clip {v['duration_s']:g} s at {v['fps']:g} fps = {v['frames']} frames, {v['candidates']} candidates"
             + (" (video pass online, during capture)" if v.get("pass") == "online" else "")
             + (f"; bundle {r['bundle']} ({r['bundle_hash']})" if r.get("bundle") else ""), "",
             f"  key frames K      {r['keyframes']:>8}   (limited by {r['limited_by']})",
             f"  scored frames S   {r['scored_frames']:>8}   ({100 * r['scored_fraction']:.1f}% of candidates, "
             f"{r['iterations']} iterations x {r['batch_size']})",
             f"  latency           {r['planned_ms']:>8,.0f} ms of {r['latency_budget_ms']:,.0f} ms "
             f"(slack {r['slack_ms']:,.0f} ms)",
             f"  memory            {r['planned_memory_mb']:>8,.0f} MB of {r['memory_budget_mb']:,.0f} MB "
             f"({r['session_policy']})",
             f"  model loads       {r['loads_per_question_ms']:>8,.0f} ms in the question ({r['start']} start; "
             f"loading every model once {r['cold_start_ms']:,.0f} ms, all sessions open {r['resident_mb']:,.0f} MB)",
             "",
             f"  {'stage':<12} {'fixed ms':>10} {'ms / key fr':>11} {'ms / scored':>11} {'planned ms':>11}"]
    for n, st in r["stages"].items():
        lines.append(f"  {n:<12} {st['fixed_ms']:>10,.1f} {st['per_keyframe_ms']:>11,.1f} "
                     f"{st['per_scored_ms']:>11,.1f} {st['planned_ms']:>11,.1f}")
    w = max([10] + [len(role) for role in r["providers"]])
    lines += ["", f"  {'role':<{w}} {'provider (device)':<28} {'here':<22} {'precision':<13} {'input W x H'}"]
    for role, pv in r["providers"].items():
        size = r["resolutions"].get(role)
        lines.append(f"  {role:<{w}} {pv['device']:<28} {pv['here']:<22} {pv['precision']:<13} "
                     f"{'x'.join(map(str, size)) if size else '-'}")
    lines += ["", "arithmetic:"] + [f"  {a}" for a in r["arithmetic"]]
    lines += ["", "cost sources:"] + [f"  {n:<15} {s}" for n, s in r["cost_status"].items()]
    if r["notes"]:
        lines += ["", "notes:"] + [f"  - {n}" for n in r["notes"]]
    return "\n".join(lines)
