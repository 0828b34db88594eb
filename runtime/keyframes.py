"""Key-frame selection (paper: Key Frame Selection, "Optimizing the selection of key frames").

Only a few candidate frames (the ones kept by redundant-frame removal) can be run through the detector, so
the search decides *which* frames to score:

1. Frame likelihood score: the weighted sum over the task objects of each object's highest detector confidence
   in the frame, targets weigh 1, cues 0.5 (`frame_score`).
2. Threshold (`threshold_mode`): "z" (default) applies the paper's values (1, 1.5, 2) to the score
   **standardised against the scores seen so far** (z over every frame scored up to and including the current
   iteration, population std); "raw" to the score itself (one target at most 1: with 1.5 or 2 a one-object
   question can never pass). Default z >= 1.5. A frame that passes at the end of any iteration stays a key
   frame (later iterations concentrate on positive regions, which raises the mean).
3. Iterative temporal search. Each iteration draws a batch of not-yet-scored candidates (default batch: scoring
   budget / iterations, spread so that the total is exactly the budget) from a sampling distribution built from
   one Gaussian kernel per scored frame, at its candidate index, of width sigma interpolated linearly between
   sigma_min = 1/k and sigma_max = r/k by the frame's mean colour-histogram similarity to the candidates within
   +-r (r = 3; k = 2 in the paper, 0.5 here: chosen on the long-video benchmark's tuning seeds, see
   docs/keyframes.md): a frame that looks like its neighbours spreads its evidence wider.
   Distances (kernels, gaps) are measured along the **content axis** (`content_prior`, default on): every
   candidate's edge density (`edge_density`, a cheap signal computed on every candidate, no detector call)
   sets its step (`content_axis`), so empty views (bare walls, corridors) take almost no room and the
   exploration spends the detector where the views can show something; the step also grows with the
   `view_change` to the neighbouring candidates with `change_power` > 0 (measured, off by default: 32-px grey
   copies, e.g. dedup's thumbnails; where the camera pans every view is new and an object stays in view for a
   few frames only, where it lingers one view stands for its neighbours). Without images: the candidate index
   (said in the notes and the trace). `grid_share` > 0 scores that share of the budget first as an even grid
   along the axis (measured, off by default).
   `sampling`:
   - "expected" (default): the kernel-weighted expected score of every candidate (`expected_scores`,
     Nadaraya-Watson: near a positive frame its score, near zero-score frames ~0, elsewhere the mean score
     seen, weighted by `gap_novelty`: distance to the nearest scored frame / its mean, cubed),
     picked one at a time within a batch, each pick counting as explored for the next: `draw="greedy"`
     (default) takes the most probable candidate (ties at random), `"sequential"` draws it at random. Far from
     any hit the greedy picks are farthest-point picks along the axis: an even grid that refines coarse to
     fine (every prefix is spread out, the widest unscored gap goes first); a positive frame's neighbours
     rise above the gaps once its kernel outweighs them. The exploitation / exploration ratio follows the
     data: a needle (objects in a few % of the frames) gives a small mean and the picks close in on the hits;
     objects everywhere give a flat estimate and the picks stay spread.
   Climb steps (`climb`, default on since the third issue-17 round): each batch first scores the unscored
     neighbours of the best frame of every detected stretch whose best box is cut by the image border
     (`climb_steps`, `cut_by_border`): a hit at the edge of a view often shows a sliver of the object, and
     the whole view is a step or two away; once the best frame is a local maximum of the score (both
     neighbours scored) or shows its objects whole, the stretch is settled and costs nothing more. Only
     while hits are rare (detected stretches at most `climb_share` of the scored frames): where objects are
     everywhere a plain pick is as likely to show one.
   - "paper": weights start at 1 per candidate and each scored frame adds a kernel of amplitude
     `gain * score / max_score` (max_score = sum of the object weights); batches drawn iid (`draw="iid"`).
     Measured (benchmarks/keyframes_long.py): the kernels hardly move this distribution (a kernel's mass
     ~2.5 sigma against M for the uniform part), so it behaves as random scoring.
   gain 0 switches the kernels off in both (expected: the novelty-weighted mean everywhere).
4. If more frames pass than the key-frame budget K, the top K by score are kept, the best frame of each
   detected stretch first (`stretch_first`, `stretches`: positive frames no scored zero-score frame separates;
   a stretch is one view of one object, the next stretch may show another instance); if fewer pass, fewer are
   returned and a note says so (and a "degraded" trace event is recorded). `min_keyframes` (default 0, off: the
   paper's rule; the pipeline sets K) tops the selection up from the scored positive frames below the
   threshold -- objects no chosen frame shows well first (when the image size is known), then by score,
   spaced and from stretches no chosen frame comes from -- noted and recorded too.
5. The budget (`budget`, e.g. the planner's scored-frame count, or `budget_fraction` of the candidates) is what
   the search spends; when it exceeds the candidates all are scored and a note and a "budget" trace event say
   that the candidates ran out first.

Baselines in the same terms: `uniform_keyframes` (K evenly spaced candidates, nothing scored),
`random_keyframes` (K random candidates, nothing scored) and `exhaustive_keyframes` (score every candidate,
keep the top K with a positive score).

Histograms are computed lazily, only for frames with a positive score and their +-r neighbours, from a
downscaled copy (zero-score frames' kernels use sigma_max and need no image).
The detector is injected: `detect(frame_index, names) -> Detections`, so a bundle detector or the synthetic
oracle plug in the same way.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Callable, ClassVar, Mapping, MutableMapping, Sequence

import cv2
import numpy as np

from .infra.config import StageConf
from .infra.errors import InputError
from .types import Detections
from .infra.trace import as_trace

DetectFn = Callable[[int, list[str]], Detections]
ImageFn = Callable[[int], np.ndarray]

METHODS = ("iterative", "uniform", "random", "exhaustive")


@dataclass
class KeyFrameConf(StageConf):
    """Key-frame search parameters; defaults follow the paper. Merge overrides with `KeyFrameConf.merged`."""

    conf_name: ClassVar[str] = "key-frame config"

    keyframes: int = 8              # K: key-frame budget
    threshold: float = 1.5          # z-score threshold (the paper's 1 / 1.5 / 2)
    iterations: int = 20            # search iterations
    budget: int | None = None       # frames the detector may score; None -> budget_fraction of the candidates
    budget_fraction: float = 0.25   # paper: 26% of the frames on LV-Haystack
    batch: int | None = None        # frames per iteration; None -> budget spread evenly over the iterations
    r: int = 3                      # histogram neighbourhood (+-r candidates) and sigma_max = r / k
    k: float = 0.5                  # sigma_min = 1 / k (paper 2; 0.5 on the content axis, issue 17 sweep)
    gain: float = 1.0               # kernel amplitude for a frame with the maximum possible score
    target_weight: float = 1.0
    cue_weight: float = 0.5
    hist_bins: int = 8              # bins per RGB channel
    hist_size: int = 64             # images are downscaled to this width before the histogram
    min_keyframes: int = 0          # top up to this many from the best positive frames below the threshold
    topup_gap: int | None = None    # top-up spacing in frame indices (>=); None: more than r candidates apart
    topup_relax: bool = True        # after the spaced frames, the top-up may take nearer ones too
    cover_min_area: float = 0.02    # top-up coverage: an object counts as well seen from this box-area share
    threshold_mode: str = "z"       # "z": z-score against the scores seen so far; "raw": the score itself
    sampling: str = "expected"      # "expected": kernel-weighted expected score; "paper": 1 + sum of kernels
    draw: str = "greedy"            # "greedy": each pick the most probable, counting as explored for the next;
    #                                 "sequential": the same drawn at random; "iid": the paper's batch draw
    prior_weight: float = 1.0       # "expected": pseudo-observations of the mean score at every candidate
    novelty: float = 3.0            # "expected": prior weighted by (gap to the nearest scored frame) ** novelty
    content_prior: bool = True      # distances along the content axis (edge density of every candidate)
    content_floor: float = 0.01     # content axis: an empty view's step (the mean view's is 1 + floor)
    # content axis: step ~ edge density x (view change / its mean) ** power. Off: measured (docs/keyframes.md,
    # fourth round) +0.01 recall on three held-out groups at 10% scored, but worse on both design groups, on
    # short scenes at 5% and on the 600 s clips' answers (0.934 -> 0.885), so not the default
    change_power: float = 0.0
    change_size: int = 32           # view change: width of the grey copies compared (px)
    grid_share: float = 0.0         # share of the budget scored first as an even grid along the axis
    stretch_first: bool = True      # selection: the best frame of each detected stretch first (`stretches`)
    climb: bool = True              # "expected" draws: each batch first takes the climb steps (`climb_steps`)
    cut_margin: float = 0.01        # climb: a box within this share of the image side from its border is cut
    climb_share: float = 0.15       # climb only while detected stretches <= this share of the scored frames
    seed: int = 0
    record_distributions: bool = False

    def validate(self) -> None:
        if self.keyframes < 1:
            raise InputError(f"key-frame config: keyframes must be >= 1 (got {self.keyframes})")
        if self.iterations < 1:
            raise InputError(f"key-frame config: iterations must be >= 1 (got {self.iterations})")
        if self.r < 0 or self.k <= 0:
            raise InputError(f"key-frame config: need r >= 0 and k > 0 (got r={self.r}, k={self.k})")
        if not 0 < self.budget_fraction <= 1:
            raise InputError(f"key-frame config: budget_fraction must be in (0, 1] (got {self.budget_fraction})")
        if not 0 <= self.min_keyframes <= self.keyframes:
            raise InputError(f"key-frame config: min_keyframes must be in [0, keyframes] (got {self.min_keyframes})")
        if self.gain < 0:
            raise InputError(f"key-frame config: gain must be >= 0 (got {self.gain})")
        if self.budget is not None and self.budget < 1:
            raise InputError(f"key-frame config: budget must be >= 1 (got {self.budget})")
        if self.batch is not None and self.batch < 1:
            raise InputError(f"key-frame config: batch must be >= 1 (got {self.batch})")
        if self.topup_gap is not None and self.topup_gap < 0:
            raise InputError(f"key-frame config: topup_gap must be >= 0 (got {self.topup_gap})")
        if not 0 <= self.cover_min_area <= 1:
            raise InputError(f"key-frame config: cover_min_area must be in [0, 1] (got {self.cover_min_area})")
        for name, val, ok in (("threshold_mode", self.threshold_mode, ("z", "raw")),
                              ("sampling", self.sampling, ("expected", "paper")),
                              ("draw", self.draw, ("sequential", "iid", "greedy"))):
            if val not in ok:
                raise InputError(f"key-frame config: {name} must be one of {', '.join(ok)} (got {val!r})")
        if self.prior_weight <= 0:
            raise InputError(f"key-frame config: prior_weight must be > 0 (got {self.prior_weight})")
        if not 0 <= self.grid_share <= 1:
            raise InputError(f"key-frame config: grid_share must be in [0, 1] (got {self.grid_share})")
        if self.content_floor <= 0:
            raise InputError(f"key-frame config: content_floor must be > 0 (got {self.content_floor})")
        if self.change_power < 0 or self.change_size < 2:
            raise InputError(f"key-frame config: need change_power >= 0 and change_size >= 2 "
                             f"(got {self.change_power}, {self.change_size})")
        for name, val in (("cut_margin", self.cut_margin), ("climb_share", self.climb_share)):
            if not 0 <= val <= 1:
                raise InputError(f"key-frame config: {name} must be in [0, 1] (got {val})")

    @property
    def sigma_min(self) -> float:
        return 1.0 / self.k

    @property
    def sigma_max(self) -> float:
        return max(self.r, 1) / self.k



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


# --------------------------------------------------------------------------------------------- scoring


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


# --------------------------------------------------------------------------------- sampling distribution


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


# -------------------------------------------------------------------------------- content prior (cheap)


def edge_density(rgb: np.ndarray, size: int = 64) -> float:
    """Share of edge pixels (Canny 50/150) in a `size`-wide grey copy of `rgb` [H, W, 3] uint8: how much a view
    could show. A blank wall, floor or ceiling has almost none; any object adds outlines."""
    h, w = rgb.shape[:2]
    g = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2GRAY) if rgb.ndim == 3 else rgb
    if w > size:
        g = cv2.resize(g, (size, max(1, round(h * size / w))), interpolation=cv2.INTER_AREA)
    return float((cv2.Canny(g, 50, 150) > 0).mean())


def grey_thumbnail(rgb: np.ndarray, size: int = 32) -> np.ndarray:
    """A `size`-wide grey float32 copy of `rgb` [H, W, 3] uint8 (or of a grey [H, W] image) minus its mean (an
    exposure change is not a view change): what `view_change` compares."""
    h, w = rgb.shape[:2]
    g = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2GRAY) if rgb.ndim == 3 else np.asarray(rgb)
    g = cv2.resize(g, (size, max(1, round(h * size / w))), interpolation=cv2.INTER_AREA).astype(np.float32)
    return g - g.mean()


def view_change(thumbs: Sequence[np.ndarray]) -> np.ndarray:
    """[M] how fast the view changes at each candidate: the mean absolute difference of its `grey_thumbnail`
    to the previous and to the next candidate's, averaged (an end: its one neighbour). Where the camera pans
    every frame shows something new and an object stays in view for a few frames only; where it lingers one
    frame stands for its neighbours. Thumbnails of different shapes are resized to the first one's."""
    m = len(thumbs)
    if m < 2:
        return np.zeros(m)
    shape = thumbs[0].shape
    t = np.stack([g if g.shape == shape else cv2.resize(g, (shape[1], shape[0]), interpolation=cv2.INTER_AREA)
                  for g in thumbs]).astype(np.float32)
    step = np.abs(t[1:] - t[:-1]).reshape(m - 1, -1).mean(1).astype(np.float64)  # [M-1] between neighbours
    out = np.empty(m)
    out[0], out[-1] = step[0], step[-1]
    out[1:-1] = 0.5 * (step[1:] + step[:-1])
    return out


def content_axis(density: np.ndarray, floor: float = 0.1, change: np.ndarray | None = None,
                 power: float = 1.0) -> np.ndarray:
    """Candidate coordinates [M] for the search: cumulative content, each candidate's step = its edge density
    (times (`change` / its mean) ** `power` when a `view_change` is given: how much *new* content the view
    brings) / the mean of that + `floor` (so an empty view still takes a little room), rescaled to a mean step
    of 1 (x[0] = 0, x[-1] = M - 1; all equal steps give the candidate index). Exploration that is even along
    this axis spends the detector where the views show something new, instead of evenly in time."""
    d = np.asarray(density, np.float64)
    m = d.size
    if m < 2:
        return np.zeros(m)
    if change is not None and power > 0:
        c = np.asarray(change, np.float64)
        d = d * (c / c.mean()) ** power if c.mean() > 0 else d
    mean = d.mean()
    step = (d / mean if mean > 0 else np.ones(m)) + floor
    mid = 0.5 * (step[1:] + step[:-1])  # the distance between neighbours: half of each one's share
    x = np.concatenate([[0.0], np.cumsum(mid)])
    return x * (m - 1) / x[-1]


# ------------------------------------------------------------------------------------------- histograms


def colour_histogram(rgb: np.ndarray, bins: int = 8, size: int = 64, bgr: bool = False) -> np.ndarray:
    """L1-normalised 3-D RGB histogram [bins**3] float32 of `rgb` [H, W, 3] uint8 (downscaled to `size` wide).
    `bgr`: the image is BGR (a decoder's), swapped after the downscale, which works per channel: the same
    figures as the RGB image's, without a full-size RGB copy."""
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise InputError(f"colour_histogram: expected [H, W, 3] RGB, got shape {rgb.shape}")
    h, w = rgb.shape[:2]
    if w > size:
        rgb = cv2.resize(rgb, (size, max(1, round(h * size / w))), interpolation=cv2.INTER_AREA)
    if bgr:
        rgb = rgb[..., ::-1]
    hist = cv2.calcHist([np.ascontiguousarray(rgb)], [0, 1, 2], None, [bins] * 3, [0, 256] * 3).reshape(-1)
    return (hist / max(hist.sum(), 1.0)).astype(np.float32)


def histogram_similarity(h1: np.ndarray, h2: np.ndarray) -> float:
    """Histogram intersection of two L1-normalised histograms: 1 = same colour distribution, 0 = disjoint."""
    return float(cv2.compareHist(h1, h2, cv2.HISTCMP_INTERSECT))


class _HistogramCache:
    """Colour histograms of candidates, computed on first use only (`store`: frame index -> histogram, may be
    shared between searches over the same video)."""

    def __init__(self, candidates: np.ndarray, image: ImageFn, conf: KeyFrameConf,
                 store: MutableMapping[int, np.ndarray] | None = None) -> None:
        self.candidates, self.image, self.conf = candidates, image, conf
        self.store: MutableMapping[int, np.ndarray] = {} if store is None else store

    def __call__(self, pos: int) -> np.ndarray:
        f = int(self.candidates[pos])
        if f not in self.store:
            self.store[f] = colour_histogram(self.image(f), self.conf.hist_bins, self.conf.hist_size)
        return self.store[f]

    def neighbour_similarity(self, pos: int) -> float:
        """Mean similarity of candidate `pos` to the candidates within +-r (0 when it has none)."""
        r, m = self.conf.r, len(self.candidates)
        nb = [j for j in range(pos - r, pos + r + 1) if j != pos and 0 <= j < m]
        if not nb:
            return 0.0
        h = self(pos)
        return float(np.mean([histogram_similarity(h, self(j)) for j in nb]))


# ---------------------------------------------------------------------------------------------- selection


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


def _fill(chosen: list[int], scores: Mapping[int, float], candidates: np.ndarray, n: int, conf: KeyFrameConf,
          seen: Mapping[int, Mapping[str, float]] | None = None,
          stretch: Mapping[int, int] | None = None) -> tuple[list[int], int]:
    """Top-up behind `min_keyframes`: positive-score frames not chosen, up to `n` in all. Returns (added frames,
    how many of them were added for coverage).

    1. Coverage (only with `seen`: frame -> name -> largest box area, share of the image): while an object the
       detector saw in some scored frame has no view of at least `cover_min_area` in a chosen frame, add the
       scored frame with its largest box;
    2. then the rest by score, first from stretches (`stretch`: frame -> id, see `stretches`) no chosen frame
       comes from, then from any;
    both only among frames spaced from every chosen one (near neighbours add no new view): at least `topup_gap`
    frame indices apart when set, else more than `r` candidates apart; 3. with `topup_relax`, then any by score.
    """
    pos = {int(f): i for i, f in enumerate(candidates)}
    out: list[int] = []
    taken = lambda: chosen + out  # noqa: E731

    def new_stretch(f: int) -> bool:  # a preference, not a rule: a stretch's second frame may still come
        return stretch is None or stretch.get(f) not in {stretch.get(g) for g in taken()}

    def spaced(f: int) -> bool:
        if conf.topup_gap is not None:
            return all(abs(f - g) >= conf.topup_gap for g in taken())
        return all(abs(pos[f] - pos[g]) > conf.r for g in taken())

    def free(f: int) -> bool:
        return scores.get(f, 0) > 0 and f not in chosen and f not in out

    n_cov = 0
    if seen:
        def covered() -> set[str]:
            return {nm for f in taken() for nm, a in seen.get(f, {}).items() if a >= conf.cover_min_area}

        missing = {nm for d in seen.values() for nm in d} - covered()
        while len(chosen) + len(out) < n and missing:
            cand = [(a, f, nm) for f in seen if free(f) and spaced(f) for nm, a in seen[f].items() if nm in missing]
            if not cand:
                break
            a, f, nm = max(cand, key=lambda c: (c[0], -c[1]))
            out.append(int(f))
            missing -= covered() | {nm}
            n_cov += 1
    ranked = [f for f in sorted(scores, key=lambda f: (-scores[f], f))]
    tiers = [lambda f: new_stretch(f) and spaced(f), spaced] + ([lambda f: True] if conf.topup_relax else [])
    for ok in tiers:
        for f in ranked:
            if len(chosen) + len(out) >= n:
                return out, n_cov
            if free(f) and ok(f):
                out.append(int(f))
    return out, n_cov


def _check_candidates(candidates: Sequence[int]) -> np.ndarray:
    c = np.asarray(candidates, dtype=np.int64).reshape(-1)
    if c.size == 0:
        raise InputError("key frames: no candidate frames (did redundant-frame removal drop everything?)")
    return c


def uniform_keyframes(candidates: Sequence[int], conf: KeyFrameConf | None = None) -> KeyFrameResult:
    """Baseline: K candidates evenly spaced in candidate order (centres of K equal bins); nothing is scored."""
    conf = conf or KeyFrameConf()
    c = _check_candidates(candidates)
    k = min(conf.keyframes, len(c))
    pos = np.unique(np.floor((np.arange(k) + 0.5) * len(c) / k).astype(np.int64))
    notes = [f"only {len(c)} candidates for {conf.keyframes} key frames"] if len(c) < conf.keyframes else []
    return KeyFrameResult("uniform", c[pos], {}, [], 0, len(c), conf.keyframes, notes=notes)


def random_keyframes(candidates: Sequence[int], conf: KeyFrameConf | None = None) -> KeyFrameResult:
    """Baseline: K candidates drawn at random (seed `conf.seed`, without replacement); nothing is scored."""
    conf = conf or KeyFrameConf()
    c = _check_candidates(candidates)
    k = min(conf.keyframes, len(c))
    pick = np.sort(np.random.default_rng([int(conf.seed), 5]).choice(len(c), size=k, replace=False))
    notes = [f"only {len(c)} candidates for {conf.keyframes} key frames"] if len(c) < conf.keyframes else []
    return KeyFrameResult("random", c[pick], {}, [], 0, len(c), conf.keyframes, notes=notes)


def exhaustive_keyframes(candidates: Sequence[int], targets: Sequence[str], cues: Sequence[str],
                         detect: DetectFn, conf: KeyFrameConf | None = None) -> KeyFrameResult:
    """Baseline: score every candidate, keep the top K among those with a positive score."""
    conf = conf or KeyFrameConf()
    c = _check_candidates(candidates)
    weights = object_weights(targets, cues, conf)
    names = task_names(targets, cues)
    scores = {int(f): frame_score(detect(int(f), names), weights) for f in c}
    positive = [f for f in scores if scores[f] > 0]
    chosen = top_k(positive, scores, conf.keyframes)
    notes = []
    if len(chosen) < conf.keyframes:
        notes.append(f"fewer than K: {len(chosen)} of {conf.keyframes} key frames (only {len(positive)} "
                     f"candidates with a positive score)")
    return KeyFrameResult("exhaustive", chosen, scores, [int(f) for f in c], len(c), len(c), conf.keyframes,
                          notes=notes)


class _Search:
    """State of one iterative search over M candidates: scored positions, their scores and kernel widths, the
    paper's sampling weights (`sampling="paper"`) and the passes of the threshold."""

    def __init__(self, m: int, conf: KeyFrameConf, max_score: float, axis: np.ndarray | None = None):
        self.m, self.conf, self.max_score = m, conf, max_score
        self.axis = axis                        # candidate coordinates (`content_axis`); None: the index
        self.w = np.ones(m, dtype=np.float64)   # paper: uniform start, + one kernel per scored frame
        self.scored = np.zeros(m, dtype=bool)
        self.pos: list[int] = []
        self.score: list[float] = []
        self.sigma: list[float] = []
        self.passed: dict[int, float] = {}      # candidate position -> z (or raw score) when it passed
        self._kernel_part: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self.cut: set[int] = set()              # scored positions whose best box is cut by the image border

    def add(self, pos: int, score: float, sigma: float, cut: bool = True) -> None:
        if cut:
            self.cut.add(pos)
        self.pos.append(pos), self.score.append(score), self.sigma.append(sigma)
        self.scored[pos] = True
        amp = self.conf.gain * score / self.max_score if self.max_score > 0 else 0.0
        if self.conf.sampling == "paper" and amp > 0:
            self.w = update_distribution(self.w, pos, amp, sigma)

    def probabilities(self, pending: Sequence[int] = ()) -> np.ndarray:
        """[M] probabilities of drawing each not-yet-scored candidate next; `pending` (drawn for this batch, not
        scored yet) are excluded and count as explored for the gap novelty."""
        taken = self.scored.copy()
        taken[list(pending)] = True
        if self.conf.sampling == "paper":
            return sampling_probabilities(self.w, taken)
        pos = np.array(self.pos, np.int64)
        explored = np.concatenate([pos, np.asarray(pending, np.int64)])
        nov = gap_novelty(self.m, explored, self.conf.novelty, self.axis)
        if self._kernel_part is None:  # the scored frames' part is the same for the whole batch
            self._kernel_part = expected_scores(self.m, pos, np.array(self.score), np.array(self.sigma),
                                                self.conf.gain, self.conf.prior_weight, 0.0, parts=True,
                                                axis=self.axis)
        num, den, prior = self._kernel_part
        p = sampling_probabilities((self.conf.prior_weight * prior * nov + num) / den, taken)
        # nothing positive seen yet: explore by the gaps alone
        return p if p.sum() > 0 else sampling_probabilities(nov + 1e-9, taken)

    def draw(self, size: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """A batch of `size` candidates: `draw="sequential"` one at a time, each pick counting as explored for
        the next (a batch spreads over the gaps instead of clumping in the widest); `"iid"` (the paper's) all at
        once from the same distribution. Returns (positions, the distribution of the first pick)."""
        self._kernel_part = None
        p0 = self.probabilities()
        size = min(size, int((p0 > 0).sum()))
        if self.conf.draw == "iid":
            return rng.choice(self.m, size=size, replace=False, p=p0), p0
        picks = self.climbs()[:size] if self.conf.climb else []
        p = self.probabilities(picks) if picks else p0
        for _ in range(size - len(picks)):
            picks.append(_argmax(p, rng) if self.conf.draw == "greedy" else int(rng.choice(self.m, p=p)))
            if len(picks) < size:
                p = self.probabilities(picks)
        return np.array(picks, np.int64), p0

    def climbs(self) -> list[int]:
        """The climb steps of every stretch not settled yet (`climb_steps`), in time order; none while the
        detected stretches outnumber `climb_share` of the scored frames (climbing pays when hits are rare: in
        a short walk through one room it only took budget from exploration, F1 -0.05 at 5% scored without
        this gate). Stretches, not positive frames: the climb steps themselves add positives, not stretches."""
        steps = climb_steps(self.pos, self.score, self.scored, self.cut)
        if len(steps) > self.conf.climb_share * len(self.pos):
            return []  # hits are common (objects everywhere): a plain pick is as likely to show one, explore on
        return list(dict.fromkeys(n for i in steps for n in steps[i]))

    def grid(self, size: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """The first batch as an even grid of `size` along the axis (random offset; the candidate nearest each
        point, each once): low discrepancy instead of random gaps. Returns (positions, uniform [M])."""
        x = _axis(self.m, self.axis)
        pts = (np.arange(size) + rng.random()) * (x[-1] - x[0]) / size + x[0]
        k = np.clip(np.searchsorted(x, pts), 1, self.m - 1) if self.m > 1 else np.zeros(size, np.int64)
        near = np.where(np.abs(x[k - 1] - pts) <= np.abs(x[k] - pts), k - 1, k) if self.m > 1 else k
        picks = list(dict.fromkeys(int(j) for j in near))
        return np.array(picks, np.int64), np.full(self.m, 1.0 / self.m)

    def threshold(self) -> None:
        """Judge every scored frame against all scores seen so far (z) or the raw score; a pass is kept."""
        v = np.array(self.score)
        stat = zscores(v) if self.conf.threshold_mode == "z" else v
        for q, sq, zq in zip(self.pos, v, stat):
            if zq >= self.conf.threshold and sq > 0 and q not in self.passed:
                self.passed[q] = float(zq)



def _argmax(p: np.ndarray, rng: np.random.Generator) -> int:
    """The most probable candidate, ties drawn at random (the first pick of a search: a random grid offset)."""
    best = np.flatnonzero(p >= p.max() * (1 - 1e-9))
    return int(best[0] if best.size == 1 else rng.choice(best))


def cut_by_border(det: Detections, names: Sequence[str], image_size: tuple[int, int] | None,
                  margin: float = 0.01) -> bool:
    """Whether the best box of some task object reaches the image border (within `margin` of a side, as a share
    of it): the view shows only part of the object, a neighbouring view may show it whole (`climb_steps`).
    False without the image size (no evidence of a partial view: the search does not climb)."""
    if image_size is None:
        return False
    W, H = image_size
    for n in names:
        idx = [i for i, nm in enumerate(det.names) if nm == n]
        if idx:
            x0, y0, x1, y1 = (float(v) for v in det.boxes[max(idx, key=lambda i: float(det.scores[i]))])
            if min(x0, W - x1) <= margin * W or min(y0, H - y1) <= margin * H:
                return True
    return False


def _record_boxes(seen: dict[int, dict[str, float]], frame: int, det: Detections, area: float | None) -> None:
    if area is None:
        return
    for nm, b in zip(det.names, det.boxes):
        d = seen.setdefault(frame, {})
        d[nm] = max(d.get(nm, 0.0), float((b[2] - b[0]) * (b[3] - b[1])) / area)


def _budget_note(m: int, conf: KeyFrameConf, trace: Any | None) -> list[str]:
    """The budget asked for more frames than there are candidates: say so (all are scored)."""
    trace = as_trace(trace)
    if conf.budget is None or conf.budget <= m:
        return []
    msg = (f"candidates ran out before the budget: {conf.budget} frames could be scored but only {m} candidates "
           f"exist (all are scored; the search decides nothing beyond the threshold)")
    trace.event("budget", "key frames: " + msg, stage="keyframes", budget=conf.budget, candidates=m)
    return [msg]


def iterative_search(candidates: Sequence[int], targets: Sequence[str], cues: Sequence[str], detect: DetectFn,
                     image: ImageFn | None = None, conf: KeyFrameConf | None = None,
                     trace: Any | None = None,
                     histograms: MutableMapping[int, np.ndarray] | None = None,
                     prefetch: Callable[[Sequence[int]], None] | None = None,
                     image_size: tuple[int, int] | None = None,
                     densities: MutableMapping[int, float] | None = None,
                     thumbs: MutableMapping[int, np.ndarray] | None = None) -> KeyFrameResult:
    """The paper's iterative temporal search over `candidates` [M] frame indices.

    detect(frame_index, names) -> Detections scores one frame; image(frame_index) -> [H, W, 3] uint8 RGB feeds
    the histogram similarity that sets each kernel's width (without it every kernel uses sigma_min, noted);
    `histograms` (frame index -> colour histogram) is filled lazily and may be shared across questions.
    `prefetch(frame indices)` (optional; default `image.prefetch` when the callable has one, e.g. a bound
    `FrameSource.prefetch`) is called once per iteration with the batch's frames and their +-r neighbours, in
    time order, before they are scored: a video source then decodes them in one forward pass instead of seeking
    back and forth. It changes no result, only the decoding order.
    `trace` (a runtime.trace.Trace) receives a "degraded" event when fewer than K frames pass, a "fallback"
    event when the question names no object (uniform key frames), a "budget" event when the budget exceeds the
    candidates, and the decisions `keyframes.method`, `keyframes.frames_scored`.
    `image_size` (W, H) lets the `min_keyframes` top-up cover objects first (the largest box per name is kept
    per scored frame; see `_fill`); without it the top-up goes by score only.
    `content_prior` (default on) takes every candidate's edge density (`edge_density`, a Canny on a 64-px copy,
    ~0.1 ms; `densities` caches them per frame index) from its small gray copy in `thumbs` (uint8, at least
    `hist_size` wide: the pipeline passes dedup's thumbnails, so no candidate is decoded again), else from its
    image, and measures every distance of the search along `content_axis`: a cheap signal on every candidate,
    no detector call. With `change_power` > 0 (measured, off by default) each step also grows with the
    `view_change` to the neighbouring candidates, from 32-px grey copies (stored back into `thumbs`).
    """
    trace = as_trace(trace)
    conf = conf or KeyFrameConf()
    c = _check_candidates(candidates)
    m = len(c)
    names = task_names(targets, cues)
    if not names:
        res = uniform_keyframes(c, conf)
        res.notes.append("no task objects to score: uniform key frames instead of the iterative search")
        trace.event("fallback", "key frames: the question names no object, using uniform key frames",
                    stage="keyframes")
        return res
    weights = object_weights(targets, cues, conf)
    if prefetch is None:
        prefetch = getattr(image, "prefetch", None)
    hist = _HistogramCache(c, image, conf, histograms) if image is not None else None
    rng = np.random.default_rng(conf.seed)
    area = float(image_size[0] * image_size[1]) if image_size else None
    seen: dict[int, dict[str, float]] = {}     # frame -> name -> largest box area share (top-up coverage)
    notes = _budget_note(m, conf, trace)
    axis = _content_axis(c, image, conf, notes, trace, densities, thumbs)
    st = _Search(m, conf, sum(weights.values()), axis)
    order: list[int] = []
    dists: list[np.ndarray] = []
    if hist is None:
        notes.append("no images given: every kernel uses sigma_min (histogram similarity unavailable)")

    owed = 0  # frames a batch could not take (grid points on one candidate): the next batch spends them
    for t, size in enumerate(_schedule(resolve_budget(m, conf), conf)):
        if st.scored.all():
            break
        size += owed
        if size == 0:
            continue
        batch, p = st.grid(size, rng) if t == 0 and conf.grid_share > 0 else st.draw(size, rng)
        owed = size - len(batch)
        if conf.record_distributions:
            dists.append(p.copy())
        if prefetch is not None:
            need = {int(c[j]) for b in batch for j in range(max(0, int(b) - conf.r), min(m, int(b) + conf.r + 1))
                    if j == int(b) or hist is None or int(c[j]) not in hist.store}
            prefetch(sorted(need))
        for pos in sorted(int(b) for b in batch):
            det = detect(int(c[pos]), names)
            s = frame_score(det, weights)
            _record_boxes(seen, int(c[pos]), det, area)
            order.append(int(c[pos]))
            st.add(pos, s, _kernel_sigma(pos, s, hist, conf), cut_by_border(det, names, image_size, conf.cut_margin))
        st.threshold()
    return _finish(c, st, order, conf, notes, trace, seen, dists)


def _schedule(budget: int, conf: KeyFrameConf) -> list[int]:
    """Frames per iteration: with `grid_share` > 0 the first iteration is that share of the budget (an even
    grid, `_Search.grid`) and the rest is spread over the other iterations; else `batch_sizes`."""
    if conf.grid_share <= 0 or conf.batch is not None or conf.iterations < 2:
        return batch_sizes(budget, conf.iterations, conf.batch)
    n0 = min(budget, max(1, int(round(conf.grid_share * budget))))
    return [n0] + batch_sizes(budget - n0, conf.iterations - 1)


def _content_axis(c: np.ndarray, image: ImageFn | None, conf: KeyFrameConf, notes: list[str], trace: Any,
                  store: MutableMapping[int, float] | None,
                  thumbs: MutableMapping[int, np.ndarray] | None = None) -> np.ndarray | None:
    """The content axis of the candidates (`content_prior`): one edge density per candidate (`store`: frame
    index -> density, may be shared between searches over the same video) and, with `change_power` > 0, the
    `view_change` between neighbouring candidates (`thumbs`: frame index -> grey image, e.g. dedup's thumbnails;
    missing ones are made from `image`; every one is stored back as its `grey_thumbnail`). Without images the search runs on the candidate index, said
    in the notes and the trace. Only with `sampling="expected"` (the paper's rule has no distances but its
    kernels')."""
    if not conf.content_prior or conf.sampling != "expected":
        return None
    if image is None:
        msg = "no images given: the content prior is off (the search explores evenly in time)"
        notes.append(msg)
        as_trace(trace).event("degraded", "key frames: " + msg, stage="keyframes")
        return None
    store = {} if store is None else store
    for f in c:
        if int(f) not in store:  # from the frame's small gray copy when one is given wide enough (dedup's), else read
            g = thumbs.get(int(f)) if thumbs is not None else None
            usable = g is not None and g.dtype == np.uint8 and g.ndim == 2 and g.shape[1] >= conf.hist_size
            store[int(f)] = edge_density(g if usable else image(int(f)), conf.hist_size)
    change = None
    if conf.change_power > 0:
        thumbs = {} if thumbs is None else thumbs
        for f in c:  # stored back as compared, so the next search over these candidates only reads them
            g = thumbs.get(int(f))
            thumbs[int(f)] = (grey_thumbnail(image(int(f)), conf.change_size) if g is None
                              else _as_thumbnail(g, conf.change_size))
        change = view_change([thumbs[int(f)] for f in c])
    return content_axis(np.array([store[int(f)] for f in c]), conf.content_floor, change, conf.change_power)


def _as_thumbnail(g: np.ndarray, size: int) -> np.ndarray:
    """A stored grey image as `view_change` compares it: as stored when it is already a `grey_thumbnail` of
    this width (the search's own), else made one (e.g. dedup's 64-px uint8 thumbnails)."""
    return g if g.dtype == np.float32 and g.shape[-1] == size else grey_thumbnail(g, size)


def _kernel_sigma(pos: int, score: float, hist: _HistogramCache | None, conf: KeyFrameConf) -> float:
    """A positive frame's kernel width from its histogram similarity (sigma_min without images); a zero-score
    frame's (used by `sampling="expected"` as evidence of absence) is sigma_max, computed without images."""
    if score <= 0:
        return conf.sigma_max
    return sigma_from_similarity(hist.neighbour_similarity(pos) if hist is not None else 0.0, conf)


def _finish(c: np.ndarray, st: _Search, order: list[int], conf: KeyFrameConf, notes: list[str], trace: Any | None,
            seen: dict[int, dict[str, float]], dists: list[np.ndarray]) -> KeyFrameResult:
    """Top K of the passes by rank score, the `min_keyframes` top-up, notes and trace events."""
    trace = as_trace(trace)
    m = len(c)
    frame_scores = {int(c[q]): s for q, s in zip(st.pos, st.score)}
    passed_frames = [int(c[q]) for q in st.passed]
    stretch = ({int(c[q]): i for q, i in stretches(st.pos, st.score).items()} if conf.stretch_first else None)
    if stretch is not None:  # one frame per stretch first: several passes of one view add no new object
        chosen = top_k_stretches(passed_frames, frame_scores, conf.keyframes, stretch)
    else:
        chosen = top_k(passed_frames, frame_scores, conf.keyframes)
    if len(passed_frames) > conf.keyframes:
        how = "by score, the best of each stretch first" if stretch is not None else "by score"
        notes.append(f"{len(passed_frames)} frames passed the threshold: kept the top {conf.keyframes} {how}")
    if len(chosen) < conf.keyframes:
        msg = (f"fewer than K: {len(chosen)} of {conf.keyframes} key frames passed the threshold "
               f"({conf.threshold_mode} >= {conf.threshold}) after scoring {len(order)} of {m} candidates")
        notes.append(msg)
        trace.event("degraded", "key frames: " + msg, stage="keyframes", chosen=len(chosen),
                    requested=conf.keyframes)
    if len(chosen) < conf.min_keyframes:
        extra, n_cov = _fill(chosen.tolist(), frame_scores, c, conf.min_keyframes, conf, seen or None, stretch)
        if extra:
            chosen = np.array(sorted(chosen.tolist() + extra), dtype=np.int64)
            msg = (f"filled {len(extra)} key frame(s) from the scored frames below the threshold "
                   f"(min_keyframes={conf.min_keyframes}; {n_cov} for objects no chosen frame showed well, "
                   f"the rest by score)")
            notes.append(msg)
            trace.event("degraded", "key frames: " + msg, stage="keyframes", filled=len(extra))
    trace.decide("keyframes.method", "iterative")
    trace.decide("keyframes.frames_scored", len(order))
    return KeyFrameResult("iterative", chosen, frame_scores, order, len(order), m, conf.keyframes,
                          zscores={int(c[q]): z for q, z in st.passed.items()}, distributions=dists, notes=notes)


def scored_budget(n_candidates: int, keyframes: int, fraction: float, min_per_keyframe: float = 0.0,
                  max_per_keyframe: float | None = None) -> int:
    """Frames the search scores for K key frames: `fraction` of the candidates (the paper's 25%), at least
    min_per_keyframe x K (short videos), at most max_per_keyframe x K (None: no cap) whatever the candidates, so
    a 600 s video's search costs what a 60 s one's does (issue 14). Not capped at the candidates (the search says
    when they run out). The planner's target (`budget.planner`) and the pipeline's default without a plan."""
    b = math.ceil(fraction * n_candidates)
    if max_per_keyframe is not None:
        b = min(b, math.ceil(max_per_keyframe * keyframes))
    return int(max(b, math.ceil(min_per_keyframe * keyframes)))


def select_keyframes(method: str, candidates: Sequence[int], targets: Sequence[str], cues: Sequence[str],
                     detect: DetectFn, image: ImageFn | None = None, conf: KeyFrameConf | None = None,
                     trace: Any | None = None,
                     histograms: MutableMapping[int, np.ndarray] | None = None,
                     prefetch: Callable[[Sequence[int]], None] | None = None,
                     image_size: tuple[int, int] | None = None,
                     densities: MutableMapping[int, float] | None = None,
                     thumbs: MutableMapping[int, np.ndarray] | None = None) -> KeyFrameResult:
    """Run one of `METHODS` ("iterative", "uniform", "random", "exhaustive") with the same inputs (`prefetch`,
    `image_size`, `densities`, `thumbs`: see `iterative_search`)."""
    if method == "iterative":
        return iterative_search(candidates, targets, cues, detect, image, conf, trace, histograms, prefetch,
                                image_size, densities, thumbs)
    if method == "uniform":
        return uniform_keyframes(candidates, conf)
    if method == "random":
        return random_keyframes(candidates, conf)
    if method == "exhaustive":
        return exhaustive_keyframes(candidates, targets, cues, detect, conf)
    raise InputError(f"key frames: unknown method {method!r}; choose one of {', '.join(METHODS)}")
