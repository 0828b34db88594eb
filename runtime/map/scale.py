"""Metric scale of a map built without a depth sensor, stated with its sources and how sure it is.

A map from colour frames alone (structure from motion, or relative depth chained by Sim(3) edges) has an unknown
scale. `estimate_scale` combines what the map already knows, each cue a log-scale vote with an sd:
- camera height: the cameras' median height above the floor against a hand-held / head-worn prior
  (`ScaleConf.height_prior_m`). The floor is the LOWEST well-supported level layer below the cameras, never the
  biggest plane (a kitchen's counter top is bigger than the floor it hides);
- object sizes: each recognised object's box (horizontal long, short, height) against its category's prior
  (`size_priors.json`, from VSI-Bench's ARKitScenes boxes; `host/synth/size_priors.py` regenerates it);
- a metric depth model: per key frame, its depth over the map's depth at the same pixels.
Votes far from the weighted median (`reject_k` sd) are dropped (a mis-sized object, a counter top taken for the
floor), the survivors form one estimate per cue, and the cues are combined by inverse variance, the sd inflated
when they disagree more than their sds allow. No usable cue: the old prior, said loudly as a guess.

`rescale_map` applies the factor once (boxes, cameras, room); `fit_depth_to_points` fits a relative depth map to
sparse map points (triangulated features), so that depth-model shapes live in the map's units.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field, replace
from functools import lru_cache
from pathlib import Path
from typing import Any, Iterable, Sequence

import numpy as np

from ..geometry import OrientedBox, ScaleShift, fit_scale_shift, sample_depth
from ..infra.errors import InputError
from .conf import ScaleConf
from .floor import fit_floor_plane
from .model import Room, SemanticMap

PRIORS_PATH = Path(__file__).with_name("size_priors.json")
CUE_WORDS = {"depth_model": "a metric depth model", "camera_height": "camera height", "objects": "objects"}


@dataclass
class Vote:
    """One cue's say: log of the factor map units -> metres, its sd (log units), what it came from."""

    cue: str
    label: str
    log_s: float
    sd: float
    kept: bool = True
    detail: str = ""


@dataclass
class MetricScale:
    """scale: metres per map unit; sd: its 1-sigma error in log units; source: "sensor depth", "cues" or "guess";
    votes: every vote (kept or rejected); cues: per cue (log_s, sd, votes kept); notes: what went wrong."""

    scale: float
    sd: float
    source: str
    votes: list[Vote] = field(default_factory=list)
    cues: dict[str, dict[str, Any]] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    z: float = 1.645  # the stated +- is this many sd (`ScaleConf.stated_z`: 1.645 = a 90 % range)

    @property
    def percent(self) -> float:
        """The stated uncertainty as +- percent (`z` sd: the range the answer states)."""
        return 100.0 * (float(np.exp(self.z * self.sd)) - 1.0)

    def message(self) -> str:
        """One line for the printed answer, e.g. "scale from camera height and 3 objects (chair x2, tv), +-12 %"."""
        if self.source == "sensor depth":
            return "scale from sensor depth (metric)"
        if self.source == "guess":
            return ("metric scale is a GUESS: " + "; ".join(self.notes)
                    + "; distances, sizes and areas may be off by 30-50 %")
        parts = []
        for name in ("depth_model", "camera_height", "objects"):
            if name not in self.cues:
                continue
            if name == "objects":
                labels = [v.label for v in self.votes if v.cue == "objects" and v.kept]
                counts = {n: labels.count(n) for n in dict.fromkeys(labels)}
                what = ", ".join(n if k == 1 else f"{n} x{k}" for n, k in counts.items())
                parts.append(f"{len(labels)} object{'s' if len(labels) != 1 else ''} ({what})")
            else:
                parts.append(CUE_WORDS[name])
        said = parts[0] if len(parts) == 1 else ", ".join(parts[:-1]) + " and " + parts[-1]
        out = [f"scale from {said}, +-{self.percent:.0f} % ({100 * _coverage(self.z):.0f} % range)"]
        dropped = [v for v in self.votes if not v.kept]
        if dropped:
            out.append("left out as off the others: " + ", ".join(
                f"{v.label} (x{np.exp(v.log_s - np.log(self.scale)):.2f})" for v in dropped))
        return "; ".join(out + self.notes)

    def to_dict(self) -> dict[str, Any]:
        return {"scale": self.scale, "sd_log": self.sd, "percent": round(self.percent, 1), "stated_z": self.z,
                "source": self.source,
                "cues": self.cues, "notes": list(self.notes), "message": self.message(),
                "votes": [{"cue": v.cue, "label": v.label, "scale": float(np.exp(v.log_s)), "sd_log": v.sd,
                           "kept": v.kept, "detail": v.detail} for v in self.votes]}


def _coverage(z: float) -> float:
    """The share of a normal distribution within +-z sd."""
    return math.erf(z / math.sqrt(2.0))


@lru_cache(maxsize=4)
def load_size_priors(path: str | None = None) -> dict[str, dict[str, Any]]:
    """category -> {"median_m": [3], "log_sd": [3]} (horizontal long, horizontal short, height)."""
    p = Path(path) if path else PRIORS_PATH
    try:
        d = json.loads(p.read_text())
        return {k: {"median_m": list(map(float, v["median_m"])), "log_sd": list(map(float, v["log_sd"]))}
                for k, v in d["categories"].items()}
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise InputError(f"{p}: cannot read the object-size priors ({e}); regenerate with `python -m "
                         f"mosaicthinker.host.synth.size_priors --meta META_INFO --out {p}`") from None


def fit_depth_to_points(pred: np.ndarray, uv: np.ndarray, z: np.ndarray, semantics: str = "relative",
                        shift: bool | None = None) -> ScaleShift:
    """A depth model's map pred [H, W] fitted to sparse map points seen at pixels uv [N, 2] (x, y) with depths
    z [N] in map units (triangulated features): returns the (s, t) that put pred in map units (robust least
    squares, `geometry.fit_scale_shift`). shift None: a shift only with >= 8 points over a depth range of at
    least 1.3 x (fewer, or all at one depth, cannot separate scale from shift). Raises InputError under 3 points."""
    uv = np.asarray(uv, np.float32).reshape(-1, 2)
    z = np.asarray(z, np.float64).reshape(-1)
    d = sample_depth(np.asarray(pred, np.float32), uv).astype(np.float64)
    ok = np.isfinite(d) & (d != 0) & np.isfinite(z) & (z > 0)
    d, z = d[ok], z[ok]
    if shift is None:
        shift = len(z) >= 8 and float(np.percentile(z, 90)) >= 1.3 * float(np.percentile(z, 10))
    return fit_scale_shift(d, z, semantics, shift, "map points")


def box_dims(box: OrientedBox, up: np.ndarray) -> np.ndarray:
    """[3] (horizontal long, horizontal short, height) of a box: the height along the axis nearest `up`."""
    k = int(np.argmax(np.abs(np.asarray(box.axes, float) @ up)))
    L = np.asarray(box.axes_lengths, float)
    h = np.sort(np.delete(L, k))[::-1]
    return np.array([h[0], h[1], L[k]])


def object_votes(objects: Iterable[Any], up: np.ndarray, priors: dict[str, dict[str, Any]],
                 conf: ScaleConf) -> list[Vote]:
    """One vote per object of a category with a prior: the prior-weighted mean of log(prior / measured) over its
    informative dimensions (category spread <= `max_prior_sd`); sd: the shared measurement error and the priors'.
    objects: instances, or (name, box) / (name, box, partial height) tuples: an object whose lower part was not
    seen (the floor-standing extension had to reach down for it: a chair's back over a table) has a height that
    is only a part of its own, so that dimension does not vote."""
    out = []
    for o in objects:
        name, box, partial = (o.name, o.box, False) if hasattr(o, "box") else (*o[:2], len(o) > 2 and bool(o[2]))
        pr = priors.get(name)
        if pr is None:
            continue
        d = box_dims(box, up)
        med, psd = np.asarray(pr["median_m"]), np.asarray(pr["log_sd"])
        use = (psd <= conf.max_prior_sd) & (d > 0) & np.array([True, True, not partial])
        if not use.any():
            continue
        w = 1.0 / psd[use] ** 2
        r = np.log(med[use]) - np.log(d[use])
        out.append(Vote("objects", name, float(w @ r / w.sum()), float(np.sqrt(conf.object_meas_sd ** 2 + 1 / w.sum()))))
    return out


def floor_layer(hp: np.ndarray, hc: np.ndarray, conf: ScaleConf) -> tuple[float, int] | None:
    """(height, points) of the floor in rough metres: the lowest layer of point heights hp [M] (along up) that is
    well supported (>= `floor_min_share` of the points and `floor_min_points`), a surface rather than a wall's
    slice (>= `floor_peak_ratio` x the median layer within +-0.4 m) and `floor_clearance_m` below the 90th
    percentile of the camera heights hc [N]; None when no layer qualifies."""
    b = conf.floor_bin_m
    top = float(np.percentile(hc, 90)) - conf.floor_clearance_m
    lo = float(np.percentile(hp, 0.1)) - 2 * b  # the lowest 0.1 % are flying pixels, not a layer
    if top <= lo:
        return None
    edges = np.arange(lo, top + b, b)
    if len(edges) < 3:
        return None
    cnt = np.histogram(hp, bins=edges)[0].astype(float)
    layer = np.convolve(cnt, np.ones(3), mode="same")  # a floor seen through depth noise spans a few bins
    need = max(conf.floor_min_share * len(hp), conf.floor_min_points)
    w = int(round(0.4 / b))
    for k in range(len(layer)):
        if layer[k] < need:
            continue
        around = np.r_[layer[max(0, k - w):max(0, k - 2)], layer[k + 3:k + w + 1]]
        if len(around) and layer[k] < conf.floor_peak_ratio * float(np.median(around)):
            continue
        j = k + int(np.argmax(layer[k:k + 3]))  # climb to the layer's peak
        sel = (hp >= edges[max(0, j - 1)]) & (hp < edges[min(len(edges) - 1, j + 2)])
        return float(np.median(hp[sel])), int(sel.sum())
    return None


def camera_height_vote(centres: np.ndarray, rots: np.ndarray, points: np.ndarray, up: np.ndarray | None,
                       conf: ScaleConf) -> tuple[Vote | None, np.ndarray | None, str]:
    """(vote, up [3], why not) from camera centres [N, 3], rotations [N, 3, 3] (camera-to-world) and points
    [M, 3], all in rough metres. up None: the map's level surfaces give it (`fit_floor_plane`, hinted by the
    cameras' mean down axis)."""
    if len(points) < 50:
        return None, up, "no map points to find the floor in"
    if up is None:
        hint = rots[:, :, 1].mean(0)  # OpenCV cameras: +y is down in the image, roughly gravity for a held camera
        fit = fit_floor_plane(points, hint / max(np.linalg.norm(hint), 1e-9), max_tilt_deg=35.0)
        if fit is None:
            return None, None, "no level surface in the map to give gravity"
        up = -fit[0]
    up = np.asarray(up, float) / np.linalg.norm(up)
    hc, hp = centres @ up, points @ up
    fl = floor_layer(hp, hc, conf)
    if fl is None:
        return None, up, "no floor seen below the cameras"
    h = float(np.median(hc - fl[0]))
    if h <= 0:
        return None, up, "the cameras are not above the floor found"
    sd = float(np.hypot(conf.height_prior_sd, conf.floor_sd))
    return Vote("camera_height", "camera height", float(np.log(conf.height_prior_m / h)), sd,
                detail=f"{h:.2f} rough m above a floor layer of {fl[1]} points"), up, ""


def _inverse_variance(x: np.ndarray, sd: np.ndarray) -> tuple[float, float]:
    """(mean, sd) inflated by the Birge ratio when the values disagree more than their sds allow."""
    w = 1.0 / sd ** 2
    m = float(w @ x / w.sum())
    s = float(np.sqrt(1.0 / w.sum()))
    if len(x) > 1:
        s *= max(1.0, float(np.sqrt(w @ (x - m) ** 2 / (len(x) - 1))))
    return m, s


def combine(votes: list[Vote], conf: ScaleConf) -> tuple[float, float, dict[str, dict[str, Any]]]:
    """(log scale, sd, per cue) from votes: with 3 or more, those beyond `reject_k` sd of their median are marked
    not kept (the plain median: one confident vote, e.g. a counter top taken for the floor, must not move the
    centre that judges it); the kept votes of each cue give one estimate (objects: inverse variance, sd floored at
    `objects_min_sd`), and the cues are combined by inverse variance."""
    x = np.array([v.log_s for v in votes])
    if len(votes) >= 3:
        m = float(np.median(x))
        for v in votes:
            v.kept = abs(v.log_s - m) <= conf.reject_k * v.sd
    cues: dict[str, dict[str, Any]] = {}
    for name in ("depth_model", "camera_height", "objects"):
        k = [v for v in votes if v.cue == name and v.kept]
        if not k:
            continue
        m, s = _inverse_variance(np.array([v.log_s for v in k]), np.array([v.sd for v in k]))
        if name == "objects":
            s = max(s, conf.objects_min_sd)
        cues[name] = {"log_s": m, "sd_log": s, "scale": float(np.exp(m)), "votes": len(k)}
    m, s = _inverse_variance(np.array([c["log_s"] for c in cues.values()]),
                             np.array([c["sd_log"] for c in cues.values()]))
    return m, s, cues


def depth_vote(ratios: Sequence[float], conf: ScaleConf) -> Vote | None:
    """The metric depth model's vote from per-key-frame ratios (its depth over the map's): their median, sd the
    model's own (`depth_model_sd`) or their spread when wider; None without a usable ratio."""
    r = np.asarray([x for x in ratios if np.isfinite(x) and x > 0], float)
    if not len(r):
        return None
    lr = np.log(r)
    spread = 1.4826 * float(np.median(np.abs(lr - np.median(lr)))) / np.sqrt(len(r))
    return Vote("depth_model", "metric depth model", float(np.median(lr)), max(conf.depth_model_sd, spread),
                detail=f"{len(r)} key frames")


def rough_unit(centres: np.ndarray, points: np.ndarray, conf: ScaleConf, max_points: int = 4000) -> float:
    """Rough metres per map unit: the median distance from a map point to its nearest camera becomes
    `rough_depth_m` (only the thresholds of the floor search use it); 1 without points."""
    if len(points) == 0 or len(centres) == 0:
        return 1.0
    p = points[:: max(1, len(points) // max_points)]
    d = np.sqrt(((p[:, None, :] - centres[None, ::max(1, len(centres) // 64), :]) ** 2).sum(-1)).min(1)
    med = float(np.median(d))
    return conf.rough_depth_m / med if med > 0 else 1.0


def estimate_scale(cameras: np.ndarray, points: np.ndarray | None = None, objects: Sequence[Any] = (),
                   up: np.ndarray | None = None, depth_ratios: Sequence[float] | None = None,
                   conf: ScaleConf | dict | None = None, priors: dict[str, dict[str, Any]] | None = None
                   ) -> MetricScale:
    """The factor from map units to metres, its sources and its sd.

    cameras: [N, 4, 4] camera-to-world poses (OpenCV axes) in map units; points: [M, 3] map points (key frames'
    depth, triangulated features) or None; objects: `ObjectInstance`s or (name, OrientedBox) with canonical
    names; up: [3] gravity up in the map (None: from the floor fit; objects then use it, else z); depth_ratios:
    per key frame, a metric depth model's depth over the map's depth at the same pixels (median), or None.
    """
    conf = ScaleConf.merged(conf) if not isinstance(conf, ScaleConf) else conf
    priors = load_size_priors() if priors is None else priors
    T = np.asarray(cameras, float).reshape(-1, 4, 4)
    P = np.zeros((0, 3)) if points is None else np.asarray(points, float).reshape(-1, 3)
    P = P[np.isfinite(P).all(1)]
    rough = rough_unit(T[:, :3, 3], P, conf)
    votes, notes = [], []
    cam, up_found, why = camera_height_vote(T[:, :3, 3] * rough, T[:, :3, :3], P * rough, up, conf)
    if cam is not None:
        cam.log_s += float(np.log(rough))  # rough metres -> map units
        votes.append(cam)
    else:
        no_height = f"no camera height ({why})"
        notes.append(no_height)
    up_obj = np.asarray(up_found if up_found is not None else [0.0, 0.0, 1.0], float)
    ov = object_votes(objects, up_obj / np.linalg.norm(up_obj), priors, conf)
    votes += ov
    if not ov:
        notes.append(f"no object of a known size (priors for: {', '.join(sorted(priors))})")
    dv = depth_vote(depth_ratios or [], conf)
    votes += [dv] if dv is not None else []
    if not votes:  # the old prior: the median depth becomes `fallback_median_m`, about +-50 %
        notes.append(f"relative depth scaled by a prior (median depth {conf.fallback_median_m} m)")
        return MetricScale(rough * conf.fallback_median_m / conf.rough_depth_m, float(np.log(1.5)), "guess", [],
                           {}, notes, conf.stated_z)
    m, s, cues = combine(votes, conf)
    notes = [no_height] if cam is None else []  # a cue that could not vote is said with why; the object list is not
    if len(cues) > 1 and s > 1.5 * min(c["sd_log"] for c in cues.values()):
        said = ", ".join(f"{CUE_WORDS[k]} x{c['scale']:.3g}" for k, c in cues.items())
        notes.append(f"the cues disagree ({said})")
    return MetricScale(float(np.exp(m)), s, "cues", votes, cues, notes, conf.stated_z)


def sensor_scale() -> MetricScale:
    """The statement for a map from sensor depth: scale 1, exact."""
    return MetricScale(1.0, 0.0, "sensor depth")  # exact: no range to state


def rescale_box(box: OrientedBox, s: float) -> OrientedBox:
    return OrientedBox(np.asarray(box.centroid, float) * s, np.asarray(box.axes_lengths, float) * s,
                       np.asarray(box.axes, float))


def rescale_pose(T: np.ndarray, s: float) -> np.ndarray:
    """Camera-to-world [4, 4] with its translation scaled (the rotation is unit-free)."""
    out = np.array(T, float)
    out[:3, 3] *= s
    return out


def _rescale_view(v: dict[str, Any], s: float) -> dict[str, Any]:
    v = dict(v)
    for k in ("centre", "size"):
        if v.get(k) is not None:
            v[k] = (np.asarray(v[k], float) * s).round(4).tolist()
    return v


def rescale_map(smap: SemanticMap, ms: MetricScale) -> SemanticMap:
    """The map with every length multiplied by `ms.scale` once (boxes, their views, cameras, room), and the
    statement in `meta["scale"]`. Pure: the input map is unchanged."""
    s = float(ms.scale)
    inst = [replace(o, box=rescale_box(o.box, s), views=[_rescale_view(v, s) for v in o.views])
            for o in smap.instances]
    room = None if smap.room is None else Room(np.asarray(smap.room.polygon, float) * s, smap.room.floor_z * s,
                                                smap.room.ceiling_z * s, smap.room.source)
    cams = [(t, rescale_pose(T, s)) for t, T in smap.cameras]
    return SemanticMap(inst, room, cams, {**smap.meta, "scale": ms.to_dict()})


__all__ = ["MetricScale", "Vote", "estimate_scale", "fit_depth_to_points", "rescale_map", "rescale_pose",
           "sensor_scale", "load_size_priors", "combine", "floor_layer", "object_votes", "box_dims"]
