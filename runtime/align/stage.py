"""The alignment stage of `build_map` (`align_keyframes`): the paper's box-matched spanning tree, then with metric
depth the depth check and the odometry backbone (`backbone`; without one, recovery one edge at a time), with
relative depth a whole-image tree and bridge rounds."""
from __future__ import annotations

from dataclasses import replace
from typing import Callable, Mapping

import numpy as np

from ..frames import FrameSource
from ..infra.trace import StageLog, as_trace
from ..types import Frame
from .backbone import align_rest_backbone
from .conf import AlignConf, BackboneConf, SfmConf
from .matching import KeyedMatcher
from .recover import (BlockPairs, Fates, WithDepth, attach_frames, bridge_attach, bridge_realign,
                      whole_image_realign)
from .rgb_stage import align_keyframes_sfm
from .tree import AlignmentResult, align_frames
from .verify import verify_tree

OverBudget = Callable[[list[int]], "str | None"]  # unaligned key frames -> why bridging is skipped (None: it runs)


def _skipped(over_budget: OverBudget, unaligned: list[int], log: StageLog) -> bool:
    """Whether bridging is skipped for the budget (said as a reduced plan in the log)."""
    why = over_budget(unaligned)
    if why:
        log.event("reduced_plan", why, stage="alignment")
    return bool(why)


def align_rest_relative(al: AlignmentResult, frames: list[Frame], boxes: dict[int, np.ndarray | None], emb: np.ndarray | None,
                        matcher: KeyedMatcher, source: FrameSource, with_depth: WithDepth, with_scale: bool,
                        conf: AlignConf, log: StageLog | None, over_budget: OverBudget,
                        fates: Fates | None = None) -> tuple[AlignmentResult, list[Frame]]:
    """Relative depth (no depth check): the box-matched tree's unaligned frames get a whole-image re-alignment,
    then bridge rounds (`bridge_realign`) while they buy aligned key frames. Returns (alignment, bridge frames
    used)."""
    log = as_trace(log)
    fates = fates or Fates([f.index for f in frames])
    if al.unaligned and conf.whole_image_fallback and any(b is not None for b in boxes.values()):
        al, boxes = whole_image_realign(al, frames, boxes, emb, matcher, with_scale, conf, log)
        fates.after(al, "whole-image tree")
    used: list[Frame] = []
    keys = {f.index for f in frames}
    al.unaligned = [i for i in al.unaligned if i in keys]
    for _ in range(conf.bridge_rounds):
        if not al.unaligned or conf.bridge_frames <= 0 or _skipped(over_budget, al.unaligned, log):
            break
        blocked = BlockPairs(matcher, al.rejected_edges)  # never re-use a rejected edge
        # bridge frames come from the whole video (consecutive frames match best), not only dedup's candidates
        al_b, bridges = bridge_realign(al, frames, boxes, list(range(len(source))), source, blocked, with_depth,
                                       with_scale, conf, log, used)
        if not bridges:
            break
        al_b.unaligned = [i for i in al_b.unaligned if i in keys]  # bridges are not counted: only key frames
        if len(al_b.unaligned) >= len(al.unaligned):
            # another round only pays where it buys aligned key frames: keep the better tree and stop
            log.event("alignment", f"bridge round left {len(al_b.unaligned)} key frame(s) unaligned (before: "
                        f"{len(al.unaligned)}): kept the tree without it, no further rounds", stage="alignment")
            break
        al, used = al_b, bridges
        fates.after(al, "tree with bridge frames")
    return al, used


def align_rest_metric(al: AlignmentResult, frames: list[Frame], matcher: KeyedMatcher, source: FrameSource,
                      with_depth: WithDepth, conf: AlignConf, log: StageLog | None,
                      over_budget: OverBudget, fates: Fates | None = None,
                      thumbs: Mapping[int, np.ndarray] | None = None) -> list[Frame]:
    """Metric depth after the box-matched tree: depth-check its edges, attach what it left out by whole-image
    edges, then bridge what is still out (in time, then by appearance with `thumbs`: `bridge_attach`). Returns
    the bridge frames used."""
    log = as_trace(log)
    fates = fates or Fates([f.index for f in frames])
    with log.stage("alignment.verify"):
        al = verify_tree(al, {f.index: f for f in frames}, conf, log)
    fates.after(al, "re-attached after the depth check")
    keys = {f.index for f in frames}
    al.unaligned = [i for i in al.unaligned if i in keys]
    if al.unaligned and conf.whole_image_fallback:
        before = list(al.unaligned)
        with log.stage("alignment"):
            got = attach_frames(al, {f.index: f for f in frames}, before, matcher, conf)
        log.event("alignment", f"box-matched tree left {len(before)} of {len(frames)} key frames unaligned; "
                    f"whole-image edges attached {len(got)}, {len(al.unaligned)} left", stage="alignment",
                    boxes_unaligned=before, attached=got)
        fates.after(al, "whole-image edge")
    if not al.unaligned or conf.bridge_frames <= 0 or conf.bridge_rounds <= 0 or \
            _skipped(over_budget, al.unaligned, log):
        return []
    with log.stage("alignment"):
        used = bridge_attach(al, frames, source, matcher, with_depth, conf, log, thumbs, fates)
    fates.after(al, "through bridge frames")
    return used


def align_keyframes(frames: list[Frame], matcher: KeyedMatcher, boxes: dict[int, np.ndarray | None], emb: np.ndarray | None,
                    source: FrameSource, with_depth: WithDepth, with_scale: bool, conf: AlignConf, log: StageLog | None,
                    over_budget: OverBudget = lambda unaligned: None,
                    thumbs: Mapping[int, np.ndarray] | None = None, backbone: BackboneConf | None = None,
                    describe: Callable[[np.ndarray], np.ndarray] | None = None, sfm: SfmConf | None = None
                    ) -> tuple[AlignmentResult, list[Frame]]:
    """The key frames' alignment: matches restricted to object boxes (the paper's trick; with relative depth
    only when `relative_box_matching`), MST over frame similarity; then, with metric depth and `verify_depth`,
    every tree edge depth-checked and the frames left out attached one edge at a time (`align_rest_metric`),
    else a whole-image re-alignment and bridge rounds (`align_rest_relative`). `over_budget(unaligned)` gives
    (and records) when bridge rounds are skipped. `thumbs` (frame -> small gray image, e.g. dedup's) lets
    metric bridging look for places the video revisits; with metric depth they are also the grid the odometry
    `backbone` walks (`backbone.align_rest_backbone`, when given and `odometry` is on: it replaces
    `align_rest_metric`; `describe`: rgb -> a place descriptor for its revisits, e.g. the bundle's embedder).
    Relative depth with `sfm.sfm_on`: structure from motion over the key frames and the scan's kept frames
    between them instead (`rgb_stage.align_keyframes_sfm`). Returns (alignment over the key frames only, the
    bridge or walk frames used)."""
    log = as_trace(log)
    if with_scale and sfm is not None and sfm.sfm_on:
        with log.stage("alignment"):
            al, used_i, _ = align_keyframes_sfm(frames, matcher, source, sfm, log, thumbs, describe)
        fates = Fates([f.index for f in frames])
        fates.after(al, "structure from motion")
        _record_fates(log, al, fates)
        return al, used_i  # type: ignore[return-value]  # frame numbers: the stream's frames are not kept
    walks = backbone is not None and backbone.odometry and conf.verify_depth and not with_scale
    hold = getattr(matcher, "hold", None)  # every frame this alignment may load stays cached: none extracted twice
    if callable(hold):
        hold(len(frames) + (backbone.max_frames if walks else conf.bridge_frames * max(1, conf.bridge_rounds)))
    conf = replace(conf, keyframe_edges=True)  # every edge below needs `keyframe_min_inliers` (`edge_min_inliers`)
    if with_scale and not conf.relative_box_matching:  # essential edges: whole images from the first tree
        boxes = {i: None for i in boxes}
    with log.stage("alignment"):
        al = align_frames(frames, matcher, "mst", conf, emb, boxes, with_scale=with_scale, log=log,
                          step=True)
    keys = {f.index for f in frames}
    fates = Fates(keys)
    fates.after(al, "box-matched tree" if any(b is not None for b in boxes.values()) else "whole-image tree")
    if conf.verify_depth and not with_scale:  # metric depth: one edge at a time onto the verified tree (cheap)
        if backbone is not None and backbone.odometry:
            used = align_rest_backbone(al, frames, matcher, source, with_depth, conf, backbone, log, over_budget,
                                       fates, thumbs, describe)
        else:
            used = align_rest_metric(al, frames, matcher, source, with_depth, conf, log, over_budget, fates, thumbs)
    else:
        al, used = align_rest_relative(al, frames, boxes, emb, matcher, source, with_depth, with_scale, conf, log,
                                       over_budget, fates)
    al.unaligned = [i for i in al.unaligned if i in keys]
    _record_fates(log, al, fates)
    return al, used


def _record_fates(log: StageLog | None, al: AlignmentResult, fates: Fates) -> None:
    """The final state after every step, once: per key frame in `al.fates` and the trace decision
    `alignment.frames`; one count in an event the printed answer repeats ("degraded" when frames stay out)."""
    for i in fates.keys:  # every step recorded its frames; a frame no step placed has no pose
        if i not in al.poses:
            fates.how[i] = "unaligned"
    al.fates = {i: fates.how.get(i, "unaligned") for i in fates.keys}
    log.decide("alignment.frames", {str(i): f for i, f in al.fates.items()})
    log.decide("alignment.root", al.root)  # the depth check may have moved it to the larger part
    out = sorted(i for i in fates.keys if al.fates[i] == "unaligned")
    msg = f"alignment: {fates.summary()}"
    if out:
        msg += f"; {len(out)} unaligned, left out of the map: {out}"
    log.event("degraded" if out else "alignment", msg, stage="alignment", unaligned=out,
                fates={str(i): f for i, f in al.fates.items()})
