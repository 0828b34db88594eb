"""Scoring and the sampling distribution of the key-frame search, and the ranking of the frames it scored (pure
functions over arrays): frame scores, z-scores, Gaussian kernels, expected scores, novelty, stretches and climbs."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

import numpy as np

from ..infra.errors import InputError
from ..types import Detections
from .conf import KeyFrameConf


@dataclass
class KeyFrameResult:
    """Outcome of one key-frame selection.

    chosen: [k] int64 frame indices (video frame numbers, not candidate positions), in time order;
    scores: frame index -> likelihood score for every scored frame; order: frame indices in the order scored;
    zscores: frame index -> z-score at the iteration the frame became a key frame (iterative only);
    distributions: per iteration the sampling probabilities [M] over candidates used for that draw (only when
    `record_distributions`); frames_scored: detector calls; candidates: M; notes: anything the caller must know
    (e.g. fewer than K frames passed).
    """

    method: str
    chosen: np.ndarray
    scores: dict[int, float]
    order: list[int]
    frames_scored: int
    candidates: int
    keyframes_requested: int
    zscores: dict[int, float] = field(default_factory=dict)
    distributions: list[np.ndarray] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    @property
    def fraction_scored(self) -> float:
        return self.frames_scored / self.candidates if self.candidates else 0.0

    def to_dict(self) -> dict[str, Any]:
        return {
            "method": self.method,
            "chosen": [int(i) for i in self.chosen],
            "scores": {str(k): round(float(v), 6) for k, v in self.scores.items()},
            "order": [int(i) for i in self.order],
            "zscores": {str(k): round(float(v), 4) for k, v in self.zscores.items()},
            "frames_scored": self.frames_scored,
            "candidates": self.candidates,
            "fraction_scored": round(self.fraction_scored, 4),
            "keyframes_requested": self.keyframes_requested,
            "notes": list(self.notes),
        }


def task_names(targets: Sequence[str], cues: Sequence[str] = ()) -> list[str]:
    """Targets then cues, each name once (a name that is both counts as a target)."""
    out: list[str] = []
    for n in list(targets) + list(cues):
        if n not in out:
            out.append(n)
    return out


def object_weights(targets: Sequence[str], cues: Sequence[str] = (),
                   conf: KeyFrameConf | None = None) -> dict[str, float]:
    """name -> weight (targets `target_weight`, cues `cue_weight`)."""
    conf = conf or KeyFrameConf()
    w = {n: conf.target_weight for n in targets}
    for n in cues:
        w.setdefault(n, conf.cue_weight)
    return w


def frame_score(det: Detections, weights: Mapping[str, float]) -> float:
    """Likelihood that a frame serves the task: sum over objects of weight * highest confidence of that object."""
    return float(sum(w * det.best_score(n) for n, w in weights.items()))


def zscores(values: np.ndarray) -> np.ndarray:
    """Standardise `values` [n] against themselves (population std); all zeros when the spread is zero."""
    v = np.asarray(values, dtype=np.float64)
    if v.size == 0:
        return v
    sd = v.std()
    if sd <= 1e-12:
        return np.zeros_like(v)
    return (v - v.mean()) / sd


def sigma_from_similarity(similarity: float, conf: KeyFrameConf) -> float:
    """Kernel width in candidate-index units: sigma_min + (sigma_max - sigma_min) * similarity (clipped to [0, 1])."""
    s = float(np.clip(similarity, 0.0, 1.0))
    return conf.sigma_min + (conf.sigma_max - conf.sigma_min) * s


def gaussian_kernel(n: int, center: float, amplitude: float, sigma: float) -> np.ndarray:
    """[n] float64: amplitude * exp(-(i - center)^2 / (2 sigma^2)) for i = 0 .. n-1."""
    i = np.arange(n, dtype=np.float64)
    return amplitude * np.exp(-0.5 * ((i - center) / sigma) ** 2)


def update_distribution(weights: np.ndarray, center: int, amplitude: float, sigma: float) -> np.ndarray:
    """Add one frame's Gaussian kernel to the (unnormalised) sampling weights [M]; returns a new array."""
    return np.asarray(weights, dtype=np.float64) + gaussian_kernel(len(weights), center, amplitude, sigma)


def sampling_probabilities(weights: np.ndarray, scored: np.ndarray) -> np.ndarray:
    """Probabilities [M] of drawing each candidate next: weights renormalised over the not-yet-scored ones."""
    w = np.where(np.asarray(scored, bool), 0.0, np.asarray(weights, np.float64))
    tot = w.sum()
    if tot <= 0:
        return w
    return w / tot


def batch_sizes(budget: int, iterations: int, batch: int | None = None) -> list[int]:
    """Frames to draw at each iteration: `batch` each (never past the budget in total), or the budget spread so
    that the total is exactly it: the budget is what the search spends, whatever the batch."""
    if batch is not None:
        return [max(0, min(batch, budget - t * batch)) for t in range(iterations)]
    return [(t + 1) * budget // iterations - t * budget // iterations for t in range(iterations)]


def resolve_budget(n_candidates: int, conf: KeyFrameConf) -> int:
    """Detector calls the iterative search may spend on `n_candidates` candidates (at least 1, at most all)."""
    b = conf.budget if conf.budget is not None else math.ceil(conf.budget_fraction * n_candidates)
    return int(min(max(b, 1), n_candidates))


def _axis(m: int, axis: np.ndarray | None) -> np.ndarray:
    """Candidate coordinates [m]: `axis` (a `content_axis`) or the candidate index itself."""
    return np.arange(m, dtype=np.float64) if axis is None else np.asarray(axis, np.float64)


def kernel_matrix(m: int, centres: np.ndarray, sigmas: np.ndarray, axis: np.ndarray | None = None) -> np.ndarray:
    """[n, m] float64: row i is the unit-amplitude Gaussian of width sigmas[i] at candidate centres[i]
    (distances along `axis`, default the candidate index)."""
    x = _axis(m, axis)
    c = x[np.asarray(centres, np.int64)][:, None]
    return np.exp(-0.5 * ((x[None, :] - c) / np.asarray(sigmas, np.float64)[:, None]) ** 2)


def gap_novelty(m: int, centres: np.ndarray, power: float = 2.0, axis: np.ndarray | None = None) -> np.ndarray:
    """[m] how unexplored each candidate is: (distance to the nearest scored candidate / its mean over the
    candidates) ** power; all ones before anything is scored. Weighting the prior by it sends exploration into
    the widest unscored gaps first (coarse to fine) instead of anywhere at random. Distances along `axis`
    (default the candidate index; `content_axis` stretches frames with content, shrinks empty views)."""
    c = np.asarray(centres, np.int64)
    if c.size == 0 or power == 0:
        return np.ones(m)
    c = np.sort(c)
    j = np.arange(m)
    x = _axis(m, axis)
    k = np.searchsorted(c, j)  # nearest scored candidate: the one at or after j, or the one before
    d = np.minimum(np.abs(x[c[np.minimum(k, len(c) - 1)]] - x), np.abs(x - x[c[np.maximum(k - 1, 0)]]))
    mean = d.mean()
    return (d / mean) ** power if mean > 0 else np.ones(m)


def expected_scores(m: int, centres: np.ndarray, scores: np.ndarray, sigmas: np.ndarray, gain: float = 1.0,
                    prior_weight: float = 1.0, novelty: float = 0.0, parts: bool = False,
                    axis: np.ndarray | None = None) -> Any:
    """Kernel-weighted expected score [m] of every candidate from the frames scored so far (Nadaraya-Watson
    with a prior): (w0 * mean + gain * sum_i s_i G_i(j)) / (w0 + gain * sum_i G_i(j)).

    Far from every scored frame the estimate is the mean score seen (w0 = `prior_weight` pseudo-observations of
    it); near a positive frame it rises towards that frame's score, near zero-score frames it falls towards 0.
    Sampling in proportion to it explores where nothing is known and exploits around positives, in a ratio
    set by the data: when positives are rare (a needle in a long video) the mean is small and the draws
    concentrate around them; when most frames are positive (a short walk in one room) it stays near uniform.
    `novelty` > 0 weights the prior by `gap_novelty` (coarse-to-fine exploration). parts=True returns
    (numerator [m], denominator [m], mean [m]) without the novelty, for a caller that updates it. Distances
    along `axis` (default the candidate index)."""
    s = np.asarray(scores, np.float64)
    mean = np.full(m, float(s.mean()) if s.size else 0.0)
    if s.size == 0 or gain <= 0:
        num, den = np.zeros(m), np.full(m, float(prior_weight))
    else:
        G = gain * kernel_matrix(m, centres, sigmas, axis)
        num, den = s @ G, prior_weight + G.sum(0)
    if parts:  # (kernel numerator, denominator, mean): the caller applies its own novelty
        return num, den, mean
    return (prior_weight * mean * gap_novelty(m, centres, novelty, axis) + num) / den


def top_k(frames: Sequence[int], scores: Mapping[int, float], k: int) -> np.ndarray:
    """The k highest-scoring `frames` (ties: earlier frame first), returned in time order [<=k] int64."""
    ranked = sorted(frames, key=lambda f: (-scores[f], f))[:k]
    return np.array(sorted(ranked), dtype=np.int64)


def stretches(positions: Sequence[int], scores: Sequence[float]) -> dict[int, int]:
    """Stretch id of every positive scored candidate position: runs of positive frames (in candidate order) that
    no zero-score scored frame separates. One stretch is most likely one view of one object (or one false
    positive); a second object the question needs shows up as another stretch."""
    out: dict[int, int] = {}
    sid, prev_pos = -1, False
    for p, sc in sorted(zip((int(q) for q in positions), scores)):
        if sc > 0:
            if not prev_pos:
                sid += 1
            out[p] = sid
        prev_pos = sc > 0
    return out


def climb_steps(positions: Sequence[int], scores: Sequence[float], scored: np.ndarray,
                cut: set[int] | None = None) -> dict[int, list[int]]:
    """Stretch id (`stretches`) -> the unscored candidates adjacent to its best frame (`scored` [M] bool). An
    empty list: the best frame is a local maximum of the score (both neighbours scored, or an end), the stretch
    is *settled* -- scoring more of it finds no better view of what it shows. Otherwise the next step of a hill
    climb towards the stretch's best view (a hit at the edge of a view often shows only a sliver)."""
    sid = stretches(positions, scores)
    best: dict[int, tuple[float, int]] = {}
    for p, sc in sorted(zip((int(q) for q in positions), scores)):  # in position order: ties keep the first
        i = sid.get(p)
        if i is not None and (i not in best or sc > best[i][0]):
            best[i] = (float(sc), p)
    m = len(scored)
    return {i: [n for n in (b - 1, b + 1) if 0 <= n < m and not scored[n] and (cut is None or b in cut)]
            for i, (_, b) in best.items()}


def top_k_stretches(frames: Sequence[int], scores: Mapping[int, float], k: int,
                    stretch: Mapping[int, int]) -> np.ndarray:
    """The k best `frames` by score, first the best of each stretch (`stretch`: frame -> stretch id, see
    `stretches`), then the best of the rest; in time order [<=k] int64. Several frames of one stretch show the
    same object; the next stretch may show another."""
    ranked = sorted(frames, key=lambda f: (-scores[f], f))
    out: list[int] = []
    used: set[int] = set()
    for f in ranked:
        if len(out) < k and stretch.get(f, -1 - f) not in used:
            out.append(f)
            used.add(stretch.get(f, -1 - f))
    out += [f for f in ranked if f not in out][:k - len(out)]
    return np.array(sorted(out), dtype=np.int64)


def _check_candidates(candidates: Sequence[int]) -> np.ndarray:
    c = np.asarray(candidates, dtype=np.int64).reshape(-1)
    if c.size == 0:
        raise InputError("key frames: no candidate frames (did redundant-frame removal drop everything?)")
    return c
