"""The paper's iterative temporal search for key frames (`iterative_search`; the method, the measurements behind
its defaults and the variants tried: docs/keyframes.md).

Each iteration scores a batch of not-yet-scored candidates (redundant-frame removal's kept frames) with the
detector, drawn from the kernel-weighted expected score of every candidate (Gaussian kernels at the scored frames,
widened by colour-histogram similarity, distances along the content axis, unexplored gaps first); frames whose
score passes a z-score threshold against the scores seen so far are key frames; the top K are kept (the best of
each detected stretch first), and `min_keyframes` tops a short selection up from the scored frames.
"""
from __future__ import annotations

from typing import Callable, Mapping, MutableMapping, Sequence

import numpy as np

from ..infra.errors import InputError
from ..infra.trace import StageLog, as_trace
from ..types import Detections
from .baselines import exhaustive_keyframes, random_keyframes, uniform_keyframes
from .conf import METHODS, KeyFrameConf
from .score import (KeyFrameResult, _axis, _check_candidates, batch_sizes, climb_steps, expected_scores,
                    frame_score, gap_novelty, object_weights, resolve_budget, sampling_probabilities,
                    sigma_from_similarity, stretches, task_names, top_k, top_k_stretches, update_distribution,
                    zscores)
from .signals import _HistogramCache, content_axis, edge_density, grey_thumbnail, view_change

DetectFn = Callable[[int, list[str]], Detections]
ImageFn = Callable[[int], np.ndarray]


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
    tiers = [lambda f: new_stretch(f) and spaced(f), spaced] + ([lambda f: True] if conf.topup_relax is not False else [])
    for ok in tiers:
        for f in ranked:
            if len(chosen) + len(out) >= n:
                return out, n_cov
            if free(f) and ok(f):
                out.append(int(f))
    return out, n_cov


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


def _budget_note(m: int, conf: KeyFrameConf, log: StageLog | None) -> list[str]:
    """The budget asked for more frames than there are candidates: say so (all are scored)."""
    log = as_trace(log)
    if conf.budget is None or conf.budget <= m:
        return []
    msg = (f"candidates ran out before the budget: {conf.budget} frames could be scored but only {m} candidates "
           f"exist (all are scored; the search decides nothing beyond the threshold)")
    log.event("budget", "key frames: " + msg, stage="keyframes", budget=conf.budget, candidates=m)
    return [msg]


def iterative_search(candidates: Sequence[int], targets: Sequence[str], cues: Sequence[str], detect: DetectFn,
                     image: ImageFn | None = None, conf: KeyFrameConf | None = None,
                     log: StageLog | None = None,
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
    `log` (a StageLog the pipeline records) receives a "degraded" event when fewer than K frames pass, a "fallback"
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
    log = as_trace(log)
    conf = conf or KeyFrameConf()
    c = _check_candidates(candidates)
    m = len(c)
    names = task_names(targets, cues)
    if not names:
        res = uniform_keyframes(c, conf)
        res.notes.append("no task objects to score: uniform key frames instead of the iterative search")
        log.event("fallback", "key frames: the question names no object, using uniform key frames",
                    stage="keyframes")
        return res
    weights = object_weights(targets, cues, conf)
    if prefetch is None:
        prefetch = getattr(image, "prefetch", None)
    hist = _HistogramCache(c, image, conf, histograms) if image is not None else None
    rng = np.random.default_rng(conf.seed)
    area = float(image_size[0] * image_size[1]) if image_size else None
    seen: dict[int, dict[str, float]] = {}     # frame -> name -> largest box area share (top-up coverage)
    notes = _budget_note(m, conf, log)
    axis = _content_axis(c, image, conf, notes, log, densities, thumbs)
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
    return _finish(c, st, order, conf, notes, log, seen, dists)


def _schedule(budget: int, conf: KeyFrameConf) -> list[int]:
    """Frames per iteration: with `grid_share` > 0 the first iteration is that share of the budget (an even
    grid, `_Search.grid`) and the rest is spread over the other iterations; else `batch_sizes`."""
    if conf.grid_share <= 0 or conf.batch is not None or conf.iterations < 2:
        return batch_sizes(budget, conf.iterations, conf.batch)
    n0 = min(budget, max(1, int(round(conf.grid_share * budget))))
    return [n0] + batch_sizes(budget - n0, conf.iterations - 1)


def _content_axis(c: np.ndarray, image: ImageFn | None, conf: KeyFrameConf, notes: list[str], log: StageLog | None,
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
        as_trace(log).event("degraded", "key frames: " + msg, stage="keyframes")
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


def _finish(c: np.ndarray, st: _Search, order: list[int], conf: KeyFrameConf, notes: list[str], log: StageLog | None,
            seen: dict[int, dict[str, float]], dists: list[np.ndarray]) -> KeyFrameResult:
    """Top K of the passes by rank score, the `min_keyframes` top-up, notes and trace events."""
    log = as_trace(log)
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
        log.event("degraded", "key frames: " + msg, stage="keyframes", chosen=len(chosen),
                    requested=conf.keyframes)
    min_k = conf.min_keyframes or 0  # None: the paper's rule (no top-up) when the search runs alone
    if len(chosen) < min_k:
        extra, n_cov = _fill(chosen.tolist(), frame_scores, c, min_k, conf, seen or None, stretch)
        if extra:
            chosen = np.array(sorted(chosen.tolist() + extra), dtype=np.int64)
            msg = (f"filled {len(extra)} key frame(s) from the scored frames below the threshold "
                   f"(min_keyframes={min_k}; {n_cov} for objects no chosen frame showed well, "
                   f"the rest by score)")
            notes.append(msg)
            log.event("degraded", "key frames: " + msg, stage="keyframes", filled=len(extra))
    log.decide("keyframes.method", "iterative")
    log.decide("keyframes.frames_scored", len(order))
    return KeyFrameResult("iterative", chosen, frame_scores, order, len(order), m, conf.keyframes,
                          zscores={int(c[q]): z for q, z in st.passed.items()}, distributions=dists, notes=notes)


def select_keyframes(method: str, candidates: Sequence[int], targets: Sequence[str], cues: Sequence[str],
                     detect: DetectFn, image: ImageFn | None = None, conf: KeyFrameConf | None = None,
                     log: StageLog | None = None,
                     histograms: MutableMapping[int, np.ndarray] | None = None,
                     prefetch: Callable[[Sequence[int]], None] | None = None,
                     image_size: tuple[int, int] | None = None,
                     densities: MutableMapping[int, float] | None = None,
                     thumbs: MutableMapping[int, np.ndarray] | None = None) -> KeyFrameResult:
    """Run one of `METHODS` ("iterative", "uniform", "random", "exhaustive") with the same inputs (`prefetch`,
    `image_size`, `densities`, `thumbs`: see `iterative_search`)."""
    if method == "iterative":
        return iterative_search(candidates, targets, cues, detect, image, conf, log, histograms, prefetch,
                                image_size, densities, thumbs)
    if method == "uniform":
        return uniform_keyframes(candidates, conf)
    if method == "random":
        return random_keyframes(candidates, conf)
    if method == "exhaustive":
        return exhaustive_keyframes(candidates, targets, cues, detect, conf)
    raise InputError(f"key frames: unknown method {method!r}; choose one of {', '.join(METHODS)}")


def spread_keyframes(chosen: Sequence[int], cands: Sequence[int], scores: Mapping[int, float], n: int) -> list[int]:
    """n more frames, each in the largest remaining gap (in frame order, the clip's ends included) between the
    frames chosen so far: among the candidates in the middle half of that gap, the one the search scored highest
    (unscored count 0), ties to the gap's middle. Pure; returns the new frames in time order."""
    pool = sorted(int(c) for c in cands)
    if not pool:
        return []
    lo, hi = pool[0], pool[-1]
    have = sorted(set(int(c) for c in chosen))
    out: list[int] = []
    for _ in range(n):
        marks = sorted(have + out)
        if not marks:
            gaps = [(hi - lo, lo, hi)]
        else:  # an uncovered end is as open as an inner gap twice its length (a virtual mark beyond the end)
            gaps = [(2 * (marks[0] - lo), 2 * lo - marks[0], marks[0]), (2 * (hi - marks[-1]), marks[-1], 2 * hi - marks[-1])]
            gaps += [(b - a, a, b) for a, b in zip(marks, marks[1:])]
        free = [c for c in pool if c not in marks]
        best = None
        for _, a, b in sorted(gaps, reverse=True):
            mid, q = (a + b) / 2.0, (b - a) / 4.0
            inside = [c for c in free if abs(c - mid) <= q]
            if inside:
                best = max(inside, key=lambda c: (float(scores.get(c, 0.0)), -abs(c - mid)))
                break
        if best is None:
            break
        out.append(best)
    return sorted(out)


def reduce_keyframes(chosen: Sequence[int], k: int) -> list[int]:
    """`k` of the chosen key frames (at least 2), evenly spread in time: the map still covers the clip. Pure."""
    chosen = sorted(chosen)
    return sorted({chosen[int(j)] for j in np.linspace(0, len(chosen) - 1, max(k, 2)).round()})
