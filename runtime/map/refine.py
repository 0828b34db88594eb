"""Occlusion refinement (paper): every instance projected into each key frame; where it should be visible but was
not segmented, the segmenter is re-prompted (point prompts from cross-frame matches, or a semantic segmenter's class
mask inside the projected box) and what it recovers is fused in."""
from __future__ import annotations

from typing import Any

import numpy as np

from ..align.matching import make_matcher
from ..geometry import invert, project, transform
from ..infra.trace import StageLog, as_trace
from ..types import Detections, Frame, Observation
from .conf import FusionConfig
from .fuse import fuse_observations
from .lift import lift_observations
from .model import ObjectInstance


def expected_visible(inst: ObjectInstance, K: np.ndarray, T_wc: np.ndarray, size: tuple[int, int],
                     depth: np.ndarray | None = None, min_px: int = 400, occlusion_tol_m: float = 0.25
                     ) -> np.ndarray | None:
    """Projected 2D box [4] of `inst` in a camera, or None when it should not be visible there (behind the
    camera, off-image, too small, or hidden: the observed depth in its projected box is mostly in front of it)."""
    W, H = size
    uv, z = project(inst.box.corners(), K, T_wc)
    if np.any(z <= 0.1):
        return None
    x0, y0 = np.clip(uv.min(0), 0, [W - 1, H - 1])
    x1, y1 = np.clip(uv.max(0), 0, [W - 1, H - 1])
    if (x1 - x0) * (y1 - y0) < min_px:
        return None
    if depth is not None:
        zc = transform(invert(T_wc), inst.center[None])[0, 2]
        patch = depth[int(y0):int(y1) + 1, int(x0):int(x1) + 1]
        valid = patch[patch > 0]
        if len(valid) and np.mean(valid < zc - occlusion_tol_m - 0.5 * max(inst.box.axes_lengths)) > 0.7:
            return None  # something is in front of it
    return np.array([x0, y0, x1, y1], np.float32)


def _prompt_points(inst: ObjectInstance, f: Frame, box: np.ndarray, obs: list[Observation], by_index: dict[int, Frame],
                   n_pts: dict[tuple[str, int], int], matcher: Any, conf_views: int) -> np.ndarray | None:
    """Point prompts for `inst` in frame f: cross-frame matches between its best views (most points) and f,
    inside both boxes; None with fewer than 3."""
    pts = []
    views = sorted(inst.frames, key=lambda g: -n_pts.get((inst.name, g), 0))[:conf_views]
    for g_idx in views:  # matches between a view that has it and this frame, inside both boxes
        g = by_index.get(g_idx)
        if g is None:
            continue
        gb = [o.box2d for o in obs if o.frame == g_idx and o.name == inst.name]
        if not gb:
            continue
        m = matcher.match_keys(g.index, g.rgb, f.index, f.rgb, np.stack(gb), box[None])  # cached features
        if len(m.uv1):
            pts.append(m.uv1)
    if not pts:
        return None
    P = np.concatenate(pts)
    P = P[(P[:, 0] >= box[0]) & (P[:, 0] <= box[2]) & (P[:, 1] >= box[1]) & (P[:, 1] <= box[3])]
    return P if len(P) >= 3 else None


def _recover_mask(inst: ObjectInstance, f: Frame, box: np.ndarray, perception: Any, prompts: Any
                  ) -> np.ndarray | None:
    """The re-prompted mask: a promptable segmenter on the point prompts (`prompts()`), else a semantic
    segmenter's class mask inside the projected box."""
    mask = None
    if perception.segment_points is not None:
        P = prompts()
        if P is not None:
            mask = perception.segment_points(f, P[:16], inst.name)
    if mask is None and perception.segment_class is not None:
        cls = perception.segment_class(f, inst.name)
        if cls is not None:
            x0, y0, x1, y1 = np.round(box).astype(int)
            mask = np.zeros(cls.shape, bool)
            mask[y0:y1 + 1, x0:x1 + 1] = cls[y0:y1 + 1, x0:x1 + 1]
    return mask


def refine(instances: list[ObjectInstance], obs: list[Observation], frames: list[Frame],
           poses: dict[int, np.ndarray], dets: dict[int, Detections], perception: Any,
           conf: FusionConfig, log: StageLog | None, conf_views: int = 2, matcher: Any = None
           ) -> tuple[list[ObjectInstance], list[np.ndarray], int]:
    """Paper, occlusion refinement: project every instance into each key frame; where it should be visible but
    was not segmented, re-prompt the segmenter — with point prompts from cross-frame matches inside its other
    views (promptable segmenter), or the class mask inside the projected box (semantic segmenter) — and add what
    it recovers. `perception`: the pipeline's `Perception` (segment_points, segment_class, matcher). Returns the
    re-fused instances, their clouds and how many instances gained a view."""
    matcher = make_matcher(matcher if matcher is not None else perception.matcher)
    by_index = {f.index: f for f in frames}
    n_pts: dict[tuple[str, int], int] = {}  # (instance name, frame) -> points of its observation there
    for o in obs:
        n_pts[(o.name, o.frame)] = max(n_pts.get((o.name, o.frame), 0), len(o.points))
    found: dict[tuple[int, int], list[Observation]] = {}  # (instance position, frame position) -> recovered
    # frame-major: a semantic segmenter caches its class map for the last image, so all instances of one frame
    # share one segmenter run; the result is put back in instance-major order below (same fusion input)
    for fi, f in enumerate(frames):
        if f.index not in poses:
            continue
        for ii, inst in enumerate(instances):
            if f.index in set(inst.frames):
                continue
            box = expected_visible(inst, f.K, poses[f.index], (f.rgb.shape[1], f.rgb.shape[0]), f.depth)
            if box is None:
                continue
            mask = _recover_mask(inst, f, box, perception, lambda: _prompt_points(
                inst, f, box, obs, by_index, n_pts, matcher, conf_views))
            if mask is None or mask.sum() < conf.min_points:
                continue
            lifted = lift_observations(f.rgb.shape[:2], f.depth, f.K, poses[f.index], box[None], [inst.name],
                                       np.array([inst.score * 0.9]), mask[None], f.index, f.t, conf)
            for ob in lifted:  # keep only what agrees with the instance (the prompt may have hit an occluder)
                inside = inst.box.contains(ob.points, margin=0.15)
                if inside.mean() >= 0.5:
                    ob.points = ob.points[inside]
                    ob.recovered = True
                    found.setdefault((ii, fi), []).append(ob)
    new_obs = [ob for key in sorted(found) for ob in found[key]]
    gained = {instances[ii].id for ii, _ in found}
    if not new_obs:
        return instances, [np.zeros((0, 3))] * len(instances), 0
    as_trace(log).event("refinement", f"occlusion refinement recovered {len(new_obs)} view(s) of {len(gained)} "
                          f"instance(s)", views=len(new_obs), instances=len(gained))
    inst2, clouds = fuse_observations(obs + new_obs, conf, log)
    return inst2, clouds, len(gained)
