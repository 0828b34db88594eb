"""Detections verified across views: a candidate detection enters the map when another key frame agrees with it in
3D, or when it is confident on its own.

Key-frame perception keeps detections down to a low score (the detector's `candidate_threshold`, 0.25 for the
YOLO models). A false box rarely lands on the same 3D spot from another view; a real object the detector scores
low is usually detected again where it is seen again. So, for each lifted detection (an `Observation`, world
points), every other posed key frame is asked whether it agrees:
- in 3D: one of its own lifted detections of the same name lies on the same points (>= `agree_overlap` of the
  smaller one within `agree_radius_m` of the other) or shares their centre (closer than the larger of the two
  radii, at most `agree_centre_m`) -- fusion's own rule for one object seen twice;
- or in 2D, where its detection could not be lifted: it sees those points (in the image, in front of the camera,
  not behind the surface its depth shows) and one of its boxes of the same name holds >= `inside_share` of them
  (box IoU with their projected box >= `min_iou`).
Its views are the frames that agree plus its own. A detection is kept when its views reach `min_views`, or its
score reaches `confident` and its category is in the map on `min_views` views elsewhere (`confident_needs_seen`:
one confident view can add another chair to a room where chairs are seen twice, but cannot bring a category into
the map that no view supports twice) -- the same rule for every category (no per-class thresholds). What was left
out, and why, is reported.

Pure functions over numpy arrays and the pipeline's frames / detections: they return what they found (`Verification`,
its report and message); the pipeline records them.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar, Mapping, Sequence

import numpy as np

from ..geometry import box_iou, invert
from ..models.detector import DetectorConf
from ..infra.config import StageConf
from ..infra.errors import InputError


@dataclass
class VerifyConf(StageConf):
    """Cross-view verification of candidate detections (module docstring)."""

    conf_name: ClassVar[str] = "verify config"

    enabled: bool = True
    confident: float | None = None   # a detection at or above this score stands on its own view ... (None: the
                                     # detector's own threshold, the bundle's `score_threshold`)
    confident_needs_seen: bool = True  # ... when another detection of its name rests on `min_views` views
    min_views: int = 2           # below it, this many key frames (its own included) must agree
    agree_radius_m: float = 0.12  # 3D agreement: points of two views this close count as the same surface ...
    agree_overlap: float = 0.2    # ... for this share of the smaller view's points
    agree_centre_m: float = 0.6   # ... or centres closer than both this and the larger view's radius
    inside_share: float = 0.5     # 2D agreement: this share of the projected points inside a same-name box ...
    min_iou: float = 0.1          # ... whose IoU with their projected box is at least this (not a box over all)
    visible_share: float = 0.3   # a frame sees the detection when this share of its points project visibly in it
    occlusion_m: float = 0.1     # a point more than this (plus `occlusion_rel` x depth) behind the frame's depth
    occlusion_rel: float = 0.1   # ... is hidden there
    sample: int = 200            # points per detection projected (a fixed-seed subsample)

    def validate(self) -> None:
        if not 0 <= (self.confident or 0) <= 1 or not 0 <= self.min_iou <= 1 or not 0 < self.visible_share <= 1:
            raise InputError("verify config: confident, min_iou and visible_share must be in [0, 1]")
        if self.min_views < 1 or self.sample < 4:
            raise InputError("verify config: min_views must be >= 1 and sample >= 4")


@dataclass
class Verification:
    """What verification did: per observation (in the input order) the other key frames that agree with it
    (`support`) and those that saw its place without a detection of its name there (`against`); `kept` flags."""

    support: list[list[int]] = field(default_factory=list)
    against: list[list[int]] = field(default_factory=list)
    kept: list[bool] = field(default_factory=list)
    why: list[str] = field(default_factory=list)
    confident: float | None = None  # the score a lone view stood from

    def message(self, obs: Sequence[Any]) -> str | None:
        """The trace's one line on what was left out, or None when nothing was."""
        out = [(o, a) for o, k, a in zip(obs, self.kept, self.against) if not k]
        if not out:
            return None
        return (f"verification: left out {len(out)} of {len(obs)} detection(s) no other key frame agreed with (a "
                f"lone view counts from score {self.confident} for a category seen twice elsewhere): "
                + ", ".join(f"{o.name} in frame {o.frame} ({o.score:.2f})" for o, _ in out))

    def report(self, obs: Sequence[Any]) -> dict[str, Any]:
        """A JSON-able summary: counts, and each left-out detection (name, frame, score, views that saw it)."""
        dropped = [{"name": o.name, "frame": int(o.frame), "score": round(float(o.score), 3), "why": w,
                    "seen_without_it_in": a} for o, k, a, w in zip(obs, self.kept, self.against, self.why) if not k]
        return {"candidates": len(obs), "kept": int(sum(self.kept)),
                "kept_by_views": int(sum(1 for k, w in zip(self.kept, self.why) if k and w == "views")),
                "kept_confident": int(sum(1 for k, w in zip(self.kept, self.why) if k and w == "confident")),
                "dropped": dropped}


def _visible_points(P: np.ndarray, K: np.ndarray, T_cw: np.ndarray, depth: np.ndarray | None,
                    size: tuple[int, int], conf: VerifyConf) -> tuple[np.ndarray, np.ndarray] | None:
    """(box [4] (2nd..98th percentile), uv [M, 2]) of the points P [N, 3] (world) that a camera sees: in front,
    inside the image [H, W], not behind the surface of its depth [H, W] (0 = unknown: not counted as seen); None
    when fewer than `visible_share` of them are seen."""
    H, W = size
    pc = P @ T_cw[:3, :3].T + T_cw[:3, 3]
    z = pc[:, 2]
    front = z > 0.1
    if not front.any():
        return None
    u = np.full(len(z), -1.0)
    v = np.full(len(z), -1.0)
    u[front] = K[0, 0] * pc[front, 0] / z[front] + K[0, 2]
    v[front] = K[1, 1] * pc[front, 1] / z[front] + K[1, 2]
    inside = front & (u >= 0) & (u < W) & (v >= 0) & (v < H)
    seen = inside.copy()
    if depth is not None and inside.any():
        d = depth[v[inside].astype(int), u[inside].astype(int)]
        seen[inside] = (d > 0) & (z[inside] <= d * (1 + conf.occlusion_rel) + conf.occlusion_m)
    if seen.sum() < max(4, conf.visible_share * len(P)):
        return None
    uv = np.stack([u[seen], v[seen]], 1)
    lo, hi = np.percentile(uv, [2, 98], axis=0)
    return np.array([lo[0], lo[1], hi[0], hi[1]], np.float64), uv


def _same_place(a: tuple[np.ndarray, np.ndarray, float, Any], b: tuple[np.ndarray, np.ndarray, float, Any],
                conf: VerifyConf) -> bool:
    """Whether two views' points (each: points [N, 3], centre [3], radius, KD-tree) are one object's: enough of
    the smaller one's points on the other's, or centres closer than the larger radius (and `agree_centre_m`)."""
    small, big = (a, b) if len(a[0]) <= len(b[0]) else (b, a)
    if np.linalg.norm(a[1] - b[1]) < min(conf.agree_centre_m, max(a[2], b[2])):
        return True
    dist, _ = big[3].query(small[0], distance_upper_bound=conf.agree_radius_m)
    return float(np.mean(np.isfinite(dist))) >= conf.agree_overlap


def _box_agrees(box: np.ndarray, uv: np.ndarray, boxes: np.ndarray, conf: VerifyConf) -> bool:
    """2D agreement: some box of `boxes` [M, 4] holds >= `inside_share` of the projected points uv [N, 2] and
    overlaps their box [4] by IoU >= `min_iou`."""
    if not len(boxes):
        return False
    inside = ((uv[:, None, 0] >= boxes[None, :, 0]) & (uv[:, None, 0] <= boxes[None, :, 2])
              & (uv[:, None, 1] >= boxes[None, :, 1]) & (uv[:, None, 1] <= boxes[None, :, 3])).mean(0)
    return bool(np.any((inside >= conf.inside_share) & (box_iou(box[None], boxes)[0] >= conf.min_iou)))


def cross_view_support(obs: Sequence[Any], frames: Sequence[Any], poses: Mapping[int, np.ndarray],
                       dets: Mapping[int, Any], conf: VerifyConf, use_depth: bool = True
                       ) -> tuple[list[list[int]], list[list[int]]]:
    """For each observation (name, frame, points [N, 3] in the world of `poses`), the other posed key frames
    that agree with it (support: in 3D with one of their observations, or in 2D with one of their boxes; module
    docstring), and those that see its points without agreeing (against). frames: the key frames (`.index`,
    `.K`, `.depth`, `.rgb`); poses: world camera-to-world [4, 4] per frame index; dets: `Detections` per frame
    index. use_depth=False (relative depth whose scale differs per frame): occlusion is not tested. Pure
    (fixed-seed subsample)."""
    from scipy.spatial import cKDTree

    posed = [f for f in frames if f.index in poses]
    T_cw = {f.index: invert(poses[f.index]) for f in posed}
    rng = np.random.default_rng(0)
    views = []
    for o in obs:
        P = np.asarray(o.points, np.float64)
        if len(P) > conf.sample:
            P = P[np.sort(rng.choice(len(P), conf.sample, replace=False))]
        c = np.median(P, 0) if len(P) else np.zeros(3)
        r = float(np.percentile(np.linalg.norm(P - c, axis=1), 90)) if len(P) else 0.0
        views.append((P, c, r, cKDTree(P) if len(P) else None))
    support: list[list[int]] = []
    against: list[list[int]] = []
    for a, o in enumerate(obs):
        sup = {int(obs[b].frame) for b in range(len(obs)) if b != a and obs[b].name == o.name
               and obs[b].frame != o.frame and len(views[a][0]) and len(views[b][0])
               and _same_place(views[a], views[b], conf)}
        con = set()
        for f in posed:
            if f.index == o.frame or f.index in sup:
                continue
            seen = _visible_points(views[a][0], f.K, T_cw[f.index], f.depth if use_depth else None,
                                   f.rgb.shape[:2], conf)
            if seen is None:
                continue
            d = dets.get(f.index)
            same = [j for j, n in enumerate(d.names) if n == o.name] if d is not None else []
            if same and _box_agrees(seen[0], seen[1], d.boxes[same], conf):
                sup.add(int(f.index))
            else:
                con.add(int(f.index))
        support.append(sorted(sup))
        against.append(sorted(con))
    return support, against


def verify_observations(obs: Sequence[Any], frames: Sequence[Any], poses: Mapping[int, np.ndarray],
                        dets: Mapping[int, Any], conf: VerifyConf, use_depth: bool = True,
                        detector_threshold: float = DetectorConf.score_threshold) -> tuple[list[Any], Verification]:
    """The observations the map keeps (a view confident on its own, or agreed by `min_views` key frames in all;
    refinement's `recovered` views are not detections and pass) and what verification found. Each kept
    observation is returned unchanged. use_depth=False (relative depth): low-score candidates are not kept (their
    3D agreement is not a test there). A lone view is confident from `conf.confident`, else from the detector's own
    `detector_threshold` (`Perception.confident_score`). -> (kept observations in input order, Verification over
    all of them)."""
    confident = conf.confident if conf.confident is not None else float(detector_threshold)
    if not conf.enabled or not len(obs):
        n = len(obs)
        return list(obs), Verification([[] for _ in range(n)], [[] for _ in range(n)], [True] * n, ["off"] * n)
    support, against = cross_view_support(obs, frames, poses, dets, conf, use_depth)
    # relative depth: each frame's scale differs, so points of one object need not meet; agreement can still
    # support a confident view's category, but a low-score candidate needs a test it cannot get there
    seen = {o.name for o, sup in zip(obs, support) if 1 + len(sup) >= conf.min_views}
    kept, why = [], []
    for o, sup in zip(obs, support):
        if getattr(o, "recovered", False):
            w = "recovered"
        elif 1 + len(sup) >= conf.min_views and (use_depth or float(o.score) >= confident):
            w = "views"
        elif float(o.score) >= confident and (o.name in seen or not conf.confident_needs_seen):
            w = "confident"
        elif float(o.score) >= confident:
            w = "unseen category"
        else:
            w = "unverified"
        kept.append(w in ("recovered", "views", "confident"))
        why.append(w)
    return [o for o, k in zip(obs, kept) if k], Verification(support, against, kept, why, confident)


def annotate_views(instances: Sequence[Any], obs: Sequence[Any], ver: Verification) -> None:
    """Record on each instance's per-view estimates (`ObjectInstance.views`) the key frames that agreed with that
    view's detection (`agreed_by`, saved in map.json), so the evidence can say how many views an instance rests
    on (`rests_on`). In place."""
    by_key: dict[tuple[str, int, float], list[int]] = {}
    for o, sup, k in zip(obs, ver.support, ver.kept):
        if k:
            by_key.setdefault((o.name, int(o.frame), round(float(o.score), 3)), []).extend(sup)
    for inst in instances:
        for v in inst.views:
            v["agreed_by"] = sorted(set(by_key.get((inst.name, int(v["frame"]), round(float(v["score"]), 3)), [])))


def rests_on(inst: Any) -> int:
    """How many key frames an instance rests on: its fused views plus the frames that agreed with one of them."""
    frames = {int(v["frame"]) for v in getattr(inst, "views", [])}
    for v in getattr(inst, "views", []):
        frames |= {int(x) for x in v.get("agreed_by", [])}
    return len(frames)
