"""The scan stage (paper: preprocessing): redundant-frame removal, returning a `ScanResult` (kept frames, reasons,
thumbnails, colour histograms, counts) that the key-frame search and bridging read. Run on a source
(`remove_redundant`), or while a video's opening scan decodes it (`open_scanned`, the frames decoded once).

1. uniform down-sampling to `sample_fps` (or every `stride`-th frame), undone where two consecutive samples of a
   source with random access share fewer than `min_overlap` of their ORB keypoints (`overlap_sampled`: a folder
   without timestamps has times assumed from its frame numbers, and a sparsely recorded one would lose the frames
   consecutive views need to overlap);
2. ORB keypoint tracking between consecutive KEPT frames: a frame whose keypoints are mostly tracked with a
   small displacement tracks the last kept frame;
3. SSIM against the last kept frame: a frame that tracks it AND has SSIM above `ssim_threshold` is dropped as
   a near-duplicate.

The rule is the paper's conjunction; the code tests it cheapest first. SSIM at the work width costs ~2 ms, ORB
features and tracking ~8 ms, and at the sampling rate most frames of a moving camera fall below the SSIM
threshold, so ORB runs only on the frames SSIM leaves as candidates (the reference's features once, lazily).
The kept frames are the ones the tracking-first order keeps (tested).

Every dropped frame gets a reason. `ssim` reproduces scikit-image's
`structural_similarity(gaussian_weights=True, sigma=1.5, use_sample_covariance=False)` (tested to 1e-3).
"""
from __future__ import annotations

import dataclasses
import queue
import threading
from dataclasses import dataclass, field
from typing import Any, Callable, ClassVar, Mapping, Sequence

import cv2
import numpy as np

from .infra.config import StageConf
from .infra.errors import InputError
from .frames import FrameObserver, FrameSource, open_source, small_gray
from .types import Frame


# ----------------------------------------------------------------------------- SSIM


@dataclass
class SsimMoments:
    """One image's Gaussian-window moments for SSIM (each [H, W] in the working dtype): the image, its local
    mean, squared mean and variance. A video's frame is compared twice (as the new frame, then as the reference
    of the next ones), so its moments are computed once: 3 blurs per comparison instead of 5."""

    x: np.ndarray
    mu: np.ndarray
    mu2: np.ndarray
    var: np.ndarray
    sigma: float


def _blur(a: np.ndarray, sigma: float) -> np.ndarray:
    r = _ssim_radius(sigma)
    # BORDER_REFLECT (abc|cba) is scipy's mode='reflect'
    return cv2.GaussianBlur(a, (2 * r + 1, 2 * r + 1), sigma, sigmaY=sigma, borderType=cv2.BORDER_REFLECT)


def _ssim_radius(sigma: float) -> int:
    return int(3.5 * sigma + 0.5)  # scipy.ndimage's truncate=3.5 radius, as scikit-image uses


def ssim_moments(img: np.ndarray, sigma: float = 1.5, dtype: Any = np.float32) -> SsimMoments:
    """`SsimMoments` of a single-channel image [H, W]."""
    x = np.asarray(img).astype(dtype)
    mu = _blur(x, sigma)
    mu2 = mu * mu
    return SsimMoments(x, mu, mu2, _blur(x * x, sigma) - mu2, sigma)  # population variance (Wang et al. 2004)


def ssim_from_moments(a: SsimMoments, b: SsimMoments, data_range: float) -> float:
    """Mean SSIM of two images from their moments (the same figure as `ssim` in the same dtype)."""
    S, r = _ssim_map(a, b, data_range)
    if min(S.shape) <= 2 * r:
        raise ValueError(f"ssim: image {S.shape} smaller than the {2 * r + 1}x{2 * r + 1} window")
    return float(S[r:-r, r:-r].mean(dtype=np.float64))


def _ssim_map(a: SsimMoments, b: SsimMoments, data_range: float) -> tuple[np.ndarray, int]:
    if a.x.shape != b.x.shape or a.sigma != b.sigma:
        raise ValueError(f"ssim: shapes {a.x.shape} vs {b.x.shape} or windows {a.sigma} vs {b.sigma} differ")
    p = a.mu * b.mu
    cov = _blur(a.x * b.x, a.sigma) - p
    c1, c2 = (0.01 * data_range) ** 2, (0.03 * data_range) ** 2
    S = ((2 * p + c1) * (2 * cov + c2)) / ((a.mu2 + b.mu2 + c1) * (a.var + b.var + c2))
    return S, _ssim_radius(a.sigma)


def ssim(a: np.ndarray, b: np.ndarray, data_range: float | None = None, sigma: float = 1.5,
         dtype: Any = np.float64) -> float:
    """Mean structural similarity of two images [H, W] or [H, W, C] (channels averaged), Gaussian window
    (sigma 1.5, radius 5), population covariance, borders of the window radius excluded — as scikit-image.
    data_range defaults to 255 for uint8 and 65535 for uint16; float images must give it. dtype: the working
    precision (float64: scikit-image's figure to 1e-12; float32: ~3x faster, within 1e-5 on 8-bit images, which
    is what the redundant-frame removal uses against a threshold given to two decimals)."""
    a = np.asarray(a)
    b = np.asarray(b)
    if a.shape != b.shape:
        raise ValueError(f"ssim: shapes differ {a.shape} vs {b.shape}")
    if data_range is None:
        if a.dtype == np.uint8:
            data_range = 255.0
        elif a.dtype == np.uint16:
            data_range = 65535.0
        else:
            raise ValueError("ssim: give data_range for non-integer images")
    if a.ndim == 3:
        return float(np.mean([ssim(a[..., c], b[..., c], data_range, sigma, dtype) for c in range(a.shape[2])]))
    return ssim_from_moments(ssim_moments(a, sigma, dtype), ssim_moments(b, sigma, dtype), float(data_range))


# ----------------------------------------------------------------------------- redundant-frame removal


@dataclass
class DedupConf(StageConf):
    """Defaults of the scan stage's redundant-frame removal (`DedupConf.merged(overrides)`, see StageConf)."""

    conf_name: ClassVar[str] = "dedup config"

    sample_fps: float | None = 3.0   # uniform down-sampling rate (None: use `stride`)
    stride: int = 1                  # keep every stride-th frame when sample_fps is None
    min_sampled: int = 16            # fewer sampled frames than this (a short input): sample by stride instead
    work_width: int = 320            # frames are resized to this width for ORB and SSIM
    orb_features: int = 500          # ORB keypoints per frame (fewer flipped a borderline frame: docs/settings.md)
    orb_levels: int = 8              # ... over this many pyramid levels (scale 1.2 each)
    # a frame is dropped as a near-duplicate of the last kept one when all three hold: SSIM >= ssim_threshold
    # (tested first: it makes the frame a "candidate"), >= min_tracked of the ORB keypoints tracked, and their
    # median displacement <= max_motion x width
    min_tracked: float = 0.35
    max_motion: float = 0.04
    ssim_threshold: float = 0.80
    thumb_width: int = 64            # kept frames' gray copies (`ScanResult.thumbs`): no candidate decoded twice
    histograms: bool = True          # kept frames' colour histograms when the reader gives colour (the search's)
    # time sampling is undone where it loses overlap: between two consecutive sampled frames that track fewer than
    # this share of ORB keypoints, the frame halfway is compared too (`overlap_sampled`; sources with random
    # access; 0 = off)
    min_overlap: float = 0.2



@dataclass
class ScanResult:
    """What the scan stage gives the stages after it. kept: frame indices kept (time order, the key-frame search's
    candidates); dropped: {frame index: reason}; counts: how many per step; scores: {frame index: {"ssim"} (+
    "tracked", "motion_px" where SSIM made it a candidate)} for frames that were compared; thumbs: small gray copies
    of the kept frames (the search's content prior, bridging by appearance); histograms: the kept frames' colour
    histograms made with `hist_params` (bins, size) (the search's kernel widths); decisions: what the pipeline
    records in the trace (`dedup.*`)."""

    kept: list[int]
    dropped: dict[int, str]
    counts: dict[str, int]
    scores: dict[int, dict[str, float]] = field(default_factory=dict)
    thumbs: dict[int, np.ndarray] = field(default_factory=dict)  # kept frame -> gray [h, thumb_width] uint8
    # kept frame -> colour histogram, when the reader gave colour; `hist_params` (bins, size) they were made with
    histograms: dict[int, np.ndarray] = field(default_factory=dict)
    hist_params: tuple[int, int] | None = None
    decisions: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return {"kept": self.kept, "dropped": {str(k): v for k, v in self.dropped.items()}, "counts": self.counts,
                "scores": {str(k): v for k, v in self.scores.items()}}


def orb_features(g: np.ndarray, n_features: int | None = None, n_levels: int | None = None) -> tuple[Any, Any]:
    """ORB keypoints and descriptors of a gray image [H, W] uint8 (computed once per frame: a kept frame's
    features are reused as the reference of the next comparisons). n_features / n_levels: DedupConf's
    orb_features / orb_levels unless given."""
    n_features = DedupConf.orb_features if n_features is None else n_features
    n_levels = DedupConf.orb_levels if n_levels is None else n_levels
    return cv2.ORB_create(nfeatures=n_features, nlevels=n_levels, fastThreshold=12).detectAndCompute(g, None)


def orb_track(g0: np.ndarray, g1: np.ndarray, n_features: int | None = None, f0: Any = None, f1: Any = None,
              n_levels: int | None = None) -> tuple[float, float]:
    """Track ORB keypoints from gray image g0 to g1 ([H, W] uint8): (fraction of g0's keypoints with a mutual,
    ratio-tested match, median displacement in pixels). (0, inf) when nothing can be tracked. f0/f1: their
    `orb_features` when already computed (else computed with n_features / n_levels)."""
    k0, d0 = f0 if f0 is not None else orb_features(g0, n_features, n_levels)
    k1, d1 = f1 if f1 is not None else orb_features(g1, n_features, n_levels)
    if d0 is None or d1 is None or len(k0) < 8 or len(k1) < 2:
        return 0.0, float("inf")
    # brute-force Hamming matching as arrays (cv2.batchDistance is what cv2.BFMatcher runs, without a Python
    # DMatch object per match): each g0 keypoint's two nearest in g1 (the ratio test) ...
    dist, nn = cv2.batchDistance(d0, d1, cv2.CV_32S, normType=cv2.NORM_HAMMING, K=2)
    q = np.arange(len(k0))
    t = nn[:, 0]
    good = dist[:, 0] < 0.8 * dist[:, 1]
    if not good.any():
        return 0.0, float("inf")
    # ... and, for the g1 keypoints those pass to, their nearest in g0 (the mutual check: the backward pass
    # only for the targets it can change, the same answer as matching all of g1 back)
    targets = np.unique(t[good])
    _, back = cv2.batchDistance(d1[targets], d0, cv2.CV_32S, normType=cv2.NORM_HAMMING, K=1)
    best_back = np.full(len(k1), -1)
    best_back[targets] = back[:, 0]  # k1 -> its best k0
    good &= best_back[t] == q
    if not good.any():
        return 0.0, float("inf")
    p0, p1 = cv2.KeyPoint_convert(k0), cv2.KeyPoint_convert(k1)
    disp = np.hypot(*(p1[t[good]] - p0[q[good]]).T.astype(np.float64))
    return int(good.sum()) / len(k0), float(np.median(disp))


class OnlineDedup:
    """Redundant-frame removal one frame at a time, in time order (steps 1-3 of the module docstring): a video
    reader can run it while it decodes (`frames.VideoSource` does, in the scan it makes on opening), so the
    video is decoded once and only the sampled frames are converted, as small gray images.

    `wants(t)` says whether the frame at time t is sampled (call it for every frame, in order); `push(index,
    gray)` gives the sampled frame's small gray image (`small_gray`); `result(n, index_at)` the ScanResult."""

    def __init__(self, conf: DedupConf | Mapping[str, Any] | None = None, hist: tuple[int, int] | None = None):
        self.conf = DedupConf.merged(conf)
        self.hist = hist  # (bins, size) of the kept frames' colour histograms (the key-frame search's); None: none
        self.sampled: list[int] = []    # positions
        self.kept: list[int] = []       # frame indices
        self.dropped: dict[int, str] = {}
        self.scores: dict[int, dict[str, float]] = {}
        self.thumbs: dict[int, np.ndarray] = {}
        self.histograms: dict[int, np.ndarray] = {}
        self.n_cand = self.n_dup = 0
        self.n_inserted = 0             # sampled for overlap (`overlap_sampled`), not by the time sampling
        self._pos = -1
        self._next_t = -np.inf
        # (index, gray, SSIM moments, ORB features or None until a comparison needs them) of the last kept frame
        self._last: tuple[int, np.ndarray, SsimMoments, Any] | None = None

    def wants(self, t: float) -> bool:
        self._pos += 1
        c = self.conf
        if c.sample_fps:
            if t >= self._next_t - 1e-9:
                self._next_t = t + 1.0 / c.sample_fps
            else:
                return False
        elif self._pos % max(1, int(c.stride)):
            return False
        self.sampled.append(self._pos)
        return True

    def push(self, index: int, g: np.ndarray | None, bgr: np.ndarray | None = None) -> bool:
        """The sampled frame's gray image [h, w] uint8 (width <= work_width; None: made here from `bgr`) -> True
        when it is kept. `bgr`: the colour frame [H, W, 3] uint8 (BGR, as the frame source gives RGB after its
        own conversion), for the kept frame's colour histogram (`DedupConf.histograms`)."""
        if g is None:
            g = small_gray(bgr, self.conf.work_width, bgr=True)
        kept = self._push(index, g)
        if kept and bgr is not None and self.conf.histograms and self.hist is not None:
            self.histograms[index] = colour_histogram(bgr, *self.hist, bgr=True)
        return kept

    def _push(self, index: int, g: np.ndarray) -> bool:
        c = self.conf
        mom = ssim_moments(g, dtype=np.float32)  # see ssim: 1e-5 against a threshold of two decimals
        if self._last is None:
            return self._keep(index, g, mom, None)
        i0, g0, m0, f0 = self._last
        if g.shape != g0.shape:
            raise InputError(f"frame {index}: size {g.shape} differs from the previous frame {g0.shape}")
        s = ssim_from_moments(m0, mom, 255.0)
        sc: dict[str, Any] = {"ssim": round(s, 4)}
        self.scores[index] = sc
        if s < c.ssim_threshold:
            return self._keep(index, g, mom, None)
        self.n_cand += 1
        if f0 is None:  # the reference's features, computed once when a frame first needs them
            f0 = orb_features(g0, c.orb_features, c.orb_levels)
            self._last = (i0, g0, m0, f0)
        feats = orb_features(g, c.orb_features, c.orb_levels)
        tracked, motion = orb_track(g0, g, f0=f0, f1=feats)
        sc.update(tracked=round(tracked, 4), motion_px=round(motion, 2) if np.isfinite(motion) else None)
        if tracked >= c.min_tracked and motion <= c.max_motion * g.shape[1]:
            self.n_dup += 1
            self.dropped[index] = (f"near-duplicate of frame {i0} (SSIM {s:.3f} >= {c.ssim_threshold}; ORB "
                                   f"tracked {tracked:.0%}, motion {motion:.1f} px)")
            return False
        return self._keep(index, g, mom, feats)

    def _keep(self, index: int, g: np.ndarray, mom: SsimMoments, feats: Any) -> bool:
        self.kept.append(index)
        self.thumbs[index] = small_gray(g, self.conf.thumb_width)
        self._last = (index, g, mom, feats)
        return True

    def result(self, n: int, index_at: Any) -> ScanResult:
        """ScanResult over n frames (positions 0..n-1; index_at(position) -> frame index)."""
        c = self.conf
        why = f"downsampled to {c.sample_fps} fps" if c.sample_fps else f"downsampled (stride {c.stride})"
        sset = set(self.sampled)
        dropped = dict(self.dropped)
        for p in range(n):
            if p not in sset:
                dropped[index_at(p)] = why
        counts = {"input": n, "after_downsampling": len(self.sampled), "downsampled_away": n - len(self.sampled),
                  "candidates": self.n_cand, "near_duplicates": self.n_dup, "kept": len(self.kept),
                  "inserted_for_overlap": self.n_inserted}
        return ScanResult(list(self.kept), dict(sorted(dropped.items())), counts, dict(self.scores),
                           dict(self.thumbs), dict(self.histograms), self.hist if self.histograms else None)


class BackgroundDedup:
    """An `OnlineDedup` whose comparisons (ORB, matching, SSIM: ~2/3 of a scan's CPU) run on one worker thread
    while the caller decodes the next frames (OpenCV releases the GIL), so a scan uses two cores. The sampled
    frames reach the worker in order, so the result is the one `OnlineDedup` alone gives. `wants` runs in the
    caller; an error of the worker is raised by the next `push` or by `finish`."""

    def __init__(self, od: OnlineDedup, depth: int = 8):
        self.od, self.conf = od, od.conf
        self._q: Any = queue.Queue(maxsize=depth)  # bounded: decoding never runs far ahead (memory)
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name="dedup", daemon=True)
        self._thread.start()

    def wants(self, t: float) -> bool:
        return self.od.wants(t)

    def push(self, index: int, g: np.ndarray | None, bgr: np.ndarray | None = None) -> None:
        if self._error is not None:
            raise self._error
        self._q.put((index, g, bgr))

    def _run(self) -> None:
        while (item := self._q.get()) is not None:
            if self._error is None:
                try:
                    self.od.push(*item)
                except BaseException as e:  # noqa: BLE001 - handed to the caller's thread
                    self._error = e

    def finish(self) -> OnlineDedup:
        """Wait for the frames pushed so far; the `OnlineDedup` (or the worker's error, raised)."""
        self._q.put(None)
        self._thread.join()
        if self._error is not None:
            raise self._error
        return self.od


# ----------------------------------------------------------------------------- thinning by measured overlap
# A frame folder without timestamps only has frame numbers, so its times are assumed (number / 30 fps), and a
# sequence recorded sparsely (ScanNet's even subsample, a HoloLens walk-through) loses the frames consecutive views
# need to overlap. The time sampling stays where it is harmless and is measured where it is not.


def overlap_sampled(sampled: Sequence[int], load: Callable[[int], Any], overlap: Callable[[Any, Any], float],
                    min_overlap: float) -> Iterator[tuple[int, Any, bool]]:
    """Positions to compare, in order, as (position, item, inserted): every position of `sampled` (sorted) plus,
    between two consecutive ones whose `overlap(item_a, item_b)` is below `min_overlap`, the position halfway,
    recursively (a pair of adjacent positions is never split). load(position) -> item (e.g. a small gray image
    and its keypoints), called once per yielded position; overlap(a, b) -> share of a's keypoints tracked in b.
    Pure apart from the two callables; `min_overlap` <= 0 yields `sampled` unchanged."""
    if not sampled:
        return
    prev = (int(sampled[0]), load(int(sampled[0])))
    yield prev[0], prev[1], False
    for p in sampled[1:]:
        cur = (int(p), load(int(p)))
        if min_overlap > 0:
            yield from _between(prev, cur, load, overlap, min_overlap)
        yield cur[0], cur[1], False
        prev = cur


def _between(a: tuple[int, Any], b: tuple[int, Any], load: Callable[[int], Any],
             overlap: Callable[[Any, Any], float], min_overlap: float) -> Iterator[tuple[int, Any, bool]]:
    """The positions strictly between a and b (each (position, item)) the rule inserts, in order."""
    if b[0] - a[0] <= 1 or overlap(a[1], b[1]) >= min_overlap:
        return
    m = (a[0] + b[0]) // 2
    mid = (m, load(m))
    yield from _between(a, mid, load, overlap, min_overlap)
    yield m, mid[1], True
    yield from _between(mid, b, load, overlap, min_overlap)


def _dense_enough(conf: DedupConf, ts: np.ndarray, decisions: dict[str, Any]) -> DedupConf:
    """`conf`, or (when sampling at `sample_fps` leaves fewer than `min_sampled` of the frames at times `ts`)
    the same config sampling every k-th frame so that at least min(min_sampled, all) are compared."""
    if not conf.sample_fps or len(ts) <= 1:
        return conf
    probe = OnlineDedup(conf)
    n_time = sum(probe.wants(float(t)) for t in ts)
    want = min(conf.min_sampled, len(ts))
    if n_time >= want:
        return conf
    stride = max(1, len(ts) // want)
    decisions["dedup.short_input"] = {"frames": len(ts), "at_sample_fps": n_time, "stride": stride}
    return dataclasses.replace(conf, sample_fps=None, stride=stride)


def remove_redundant(source_or_frames: FrameSource | Sequence[Frame], conf: DedupConf | Mapping[str, Any] | None = None
                     ) -> ScanResult:
    """The scan stage: drop redundant frames of a FrameSource (or a sequence of Frames, with .rgb, .t, .index).
    Returns the ScanResult: the kept frame indices, a reason for every dropped one, the kept frames' thumbnails,
    and the decisions the pipeline records.

    A source whose opening scan already ran the same removal while decoding (`open_scanned`) gives its result
    without decoding the video again."""
    conf = DedupConf.merged(conf)
    src = source_or_frames
    n = len(src)
    if n == 0:
        raise InputError("remove_redundant: no frames")
    is_source = hasattr(src, "timestamps")  # a FrameSource (else a plain sequence of Frames)
    ts = np.asarray(src.timestamps if is_source else [f.t for f in src], dtype=np.float64)
    decisions: dict[str, Any] = {}
    conf = _dense_enough(conf, ts, decisions)
    res = online_result(src, conf) if is_source else None  # None when the scan sampled by another rule
    if res is not None:
        res.decisions = {**decisions, "dedup.online": True, "dedup.counts": res.counts}
        return res

    def index_at(p: int) -> int:
        return src.index_of(p) if is_source else int(src[p].index)

    # reading in increasing order decodes a video exactly once, forward (no prefetch into an evicting cache);
    # sources with a `gray(position, width)` read skip the colour conversion and the frame cache
    gray = getattr(src, "gray", None) if is_source else None
    def load(p: int) -> list[Any]:  # [gray, its ORB features once a measurement needs them]
        return [gray(p, conf.work_width) if gray is not None else small_gray(src[p].rgb, conf.work_width), None]

    def overlap(a: list[Any], b: list[Any]) -> float:
        for x in (a, b):
            x[1] = x[1] if x[1] is not None else orb_features(x[0], conf.orb_features, conf.orb_levels)
        return orb_track(a[0], b[0], f0=a[1], f1=b[1])[0]

    od = BackgroundDedup(OnlineDedup(conf))
    sampled = [p for p, t in enumerate(ts) if od.wants(float(t))]
    inserted: list[int] = []
    try:
        # a video decodes forward only and its times are measured: the time sampling stands there
        min_overlap = 0.0 if getattr(src, "sequential", False) else conf.min_overlap
        for p, (g, _), extra in overlap_sampled(sampled, load, overlap, min_overlap):
            if extra:
                inserted.append(p)
            od.push(index_at(p), g)
    finally:
        done = od.finish()
    done.sampled = sorted(set(done.sampled) | set(inserted))
    done.n_inserted = len(inserted)
    res = done.result(n, index_at)
    res.decisions = {**decisions, "dedup.counts": res.counts}
    return res


def online_result(source: FrameSource, conf: DedupConf) -> ScanResult | None:
    """The removal a video's opening scan made while decoding (`open_scanned`), when it ran with `conf`; else
    None (`remove_redundant` then decodes the sampled frames again)."""
    od = getattr(source, "observed", None)
    if not isinstance(od, OnlineDedup) or od.conf != conf:
        return None
    return od.result(len(source), source.index_of)


def scanner(conf: DedupConf | Mapping[str, Any] | None = None, hist: tuple[int, int] | None = None
            ) -> Callable[[], FrameObserver]:
    """An observer factory for a video's opening scan (`frames.VideoSource(observer=...)`): redundant-frame
    removal with `conf` on a worker thread, keeping colour histograms of `hist` (bins, size)."""
    return lambda: BackgroundDedup(OnlineDedup(conf, hist))


def open_scanned(path: Any, conf: DedupConf | Mapping[str, Any] | None = None, hist: tuple[int, int] | None = None,
                 **opts: Any) -> FrameSource:
    """`frames.open_source` with the scan stage running while a video decodes (its frames are then decoded once;
    `remove_redundant` with the same `conf` takes the result). `opts` go to `open_source`."""
    return open_source(path, observer=scanner(conf, hist), **opts)


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
