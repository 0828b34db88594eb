"""Redundant-frame removal (paper: Preprocessing).

1. uniform down-sampling to `sample_fps` (or every `stride`-th frame);
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
from dataclasses import dataclass, field
from typing import Any, ClassVar, Mapping

import numpy as np

from .align.thinning import overlap_sampled
from .config import StageConf
from .errors import InputError
from .trace import as_trace


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
    import cv2

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
    """Defaults of the preprocessing stage (`DedupConf.merged(overrides)`, see config.StageConf)."""

    conf_name: ClassVar[str] = "dedup config"

    sample_fps: float | None = 3.0   # uniform down-sampling rate (None: use `stride`)
    stride: int = 1                  # keep every stride-th frame when sample_fps is None
    # a short input (a 1 s clip, ten photos in a folder read at a nominal 30 fps) would keep one or two frames at
    # sample_fps: below this many sampled frames the input is sampled by stride instead, so that at least
    # min(this, all frames) are compared (near-duplicates are still dropped by the comparisons)
    min_sampled: int = 16
    work_width: int = 320            # frames are resized to this width for ORB and SSIM
    # ORB keypoints per frame (the matching cost grows with their square) over `orb_levels` pyramid levels
    # (scale 1.2 each). 300 over 4 levels costs ~2/3 of the comparisons' CPU, keeps the same frames on the
    # 60 s clips and the kitchen but flips one borderline frame (x5, ping-pong) of seed 8's 600 s clip, which
    # moved that run's key frames and cost it 3 aligned key frames: kept at 500 / 8 (docs/performance.md,
    # "the scan's CPU")
    orb_features: int = 500
    orb_levels: int = 8
    # a frame is dropped as a near-duplicate of the last kept one when all three hold: SSIM >= ssim_threshold
    # (tested first: it makes the frame a "candidate"), >= min_tracked of the ORB keypoints tracked, and their
    # median displacement <= max_motion x width
    min_tracked: float = 0.35
    max_motion: float = 0.04
    ssim_threshold: float = 0.80
    # a small gray copy of each kept frame (`DedupResult.thumbs`): later per-candidate signals (the key-frame
    # search's content prior) read it instead of decoding every candidate of the video a second time
    thumb_width: int = 64
    # each kept frame's colour histogram (`keyframes.colour_histogram` with KeyFrameConf's bins and size) when the
    # reader gives the colour frame (a video's scan does): the key-frame search's kernel widths read them instead
    # of decoding every scored frame's +-r neighbours again (~270 extra reads, ~2 s on a 600 s mp4)
    histograms: bool = True
    # time sampling is undone where it loses overlap: between two consecutive sampled frames that track fewer
    # than this share of ORB keypoints, the frames halfway are compared too (`align.thinning.overlap_sampled`;
    # frame sources with random access; 0 = off). A fifth tracked is about where whole-image edges between
    # adjacent frames still verify on the shared rooms (docs/real-rooms.md)
    min_overlap: float = 0.2


@dataclass
class DedupResult:
    """kept: frame indices kept (time order); dropped: {frame index: reason}; counts: how many per stage;
    scores: {frame index: {"ssim"} (+ "tracked", "motion_px" where SSIM made it a candidate)} for frames that
    were compared."""

    kept: list[int]
    dropped: dict[int, str]
    counts: dict[str, int]
    scores: dict[int, dict[str, float]] = field(default_factory=dict)
    thumbs: dict[int, np.ndarray] = field(default_factory=dict)  # kept frame -> gray [h, thumb_width] uint8
    # kept frame -> colour histogram, when the reader gave colour; `hist_params` (bins, size) they were made with
    histograms: dict[int, np.ndarray] = field(default_factory=dict)
    hist_params: tuple[int, int] | None = None

    def to_dict(self) -> dict[str, Any]:
        return {"kept": self.kept, "dropped": {str(k): v for k, v in self.dropped.items()}, "counts": self.counts,
                "scores": {str(k): v for k, v in self.scores.items()}}


def _small_gray(rgb: np.ndarray, width: int) -> np.ndarray:
    import cv2

    g = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2GRAY) if rgb.ndim == 3 else rgb
    if g.shape[1] > width:
        g = cv2.resize(g, (width, max(1, round(g.shape[0] * width / g.shape[1]))), interpolation=cv2.INTER_AREA)
    return g


def orb_features(g: np.ndarray, n_features: int | None = None, n_levels: int | None = None) -> tuple[Any, Any]:
    """ORB keypoints and descriptors of a gray image [H, W] uint8 (computed once per frame: a kept frame's
    features are reused as the reference of the next comparisons). n_features / n_levels: DedupConf's
    orb_features / orb_levels unless given."""
    import cv2

    n_features = DedupConf.orb_features if n_features is None else n_features
    n_levels = DedupConf.orb_levels if n_levels is None else n_levels
    return cv2.ORB_create(nfeatures=n_features, nlevels=n_levels, fastThreshold=12).detectAndCompute(g, None)


def orb_track(g0: np.ndarray, g1: np.ndarray, n_features: int | None = None, f0: Any = None, f1: Any = None,
              n_levels: int | None = None) -> tuple[float, float]:
    """Track ORB keypoints from gray image g0 to g1 ([H, W] uint8): (fraction of g0's keypoints with a mutual,
    ratio-tested match, median displacement in pixels). (0, inf) when nothing can be tracked. f0/f1: their
    `orb_features` when already computed (else computed with n_features / n_levels)."""
    import cv2

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
    gray)` gives the sampled frame's small gray image (`small_gray`); `result(n, index_at)` the DedupResult."""

    def __init__(self, conf: DedupConf | Mapping[str, Any] | None = None):
        self.conf = DedupConf.merged(conf)
        self.sampled: list[int] = []    # positions
        self.kept: list[int] = []       # frame indices
        self.dropped: dict[int, str] = {}
        self.scores: dict[int, dict[str, float]] = {}
        self.thumbs: dict[int, np.ndarray] = {}
        self.histograms: dict[int, np.ndarray] = {}
        self.n_cand = self.n_dup = 0
        self.n_inserted = 0             # sampled for overlap (`align.thinning`), not by the time sampling
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
        if kept and bgr is not None and self.conf.histograms:
            self.histograms[index] = bgr_histogram(bgr)
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
        self.thumbs[index] = _small_gray(g, self.conf.thumb_width)
        self._last = (index, g, mom, feats)
        return True

    def result(self, n: int, index_at: Any) -> DedupResult:
        """DedupResult over n frames (positions 0..n-1; index_at(position) -> frame index)."""
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
        return DedupResult(list(self.kept), dict(sorted(dropped.items())), counts, dict(self.scores),
                           dict(self.thumbs), dict(self.histograms), hist_params() if self.histograms else None)


class BackgroundDedup:
    """An `OnlineDedup` whose comparisons (ORB, matching, SSIM: ~2/3 of a scan's CPU) run on one worker thread
    while the caller decodes the next frames (OpenCV releases the GIL), so a scan uses two cores. The sampled
    frames reach the worker in order, so the result is the one `OnlineDedup` alone gives. `wants` runs in the
    caller; an error of the worker is raised by the next `push` or by `finish`."""

    def __init__(self, od: OnlineDedup, depth: int = 8):
        import queue
        import threading

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


def hist_params() -> tuple[int, int]:
    """(bins, size) of the colour histograms the removal stores: the key-frame search's (`KeyFrameConf`)."""
    from .keyframes import KeyFrameConf

    return KeyFrameConf.hist_bins, KeyFrameConf.hist_size


def bgr_histogram(bgr: np.ndarray) -> np.ndarray:
    """`keyframes.colour_histogram` of the RGB frame a BGR frame [H, W, 3] uint8 converts to, with `hist_params`."""
    from .keyframes import colour_histogram

    return colour_histogram(bgr, *hist_params(), bgr=True)


def small_gray(rgb: np.ndarray, width: int, bgr: bool = False) -> np.ndarray:
    """Gray image [h, w] uint8 at most `width` wide (INTER_AREA) of an RGB (or BGR) image [H, W, 3]."""
    import cv2

    if rgb.ndim == 3:
        rgb = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_BGR2GRAY if bgr else cv2.COLOR_RGB2GRAY)
    return _small_gray(rgb, width)


def _dense_enough(conf: DedupConf, ts: np.ndarray, trace: Any) -> DedupConf:
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
    trace.decide("dedup.short_input", {"frames": len(ts), "at_sample_fps": n_time, "stride": stride})
    return dataclasses.replace(conf, sample_fps=None, stride=stride)


def remove_redundant(source_or_frames: Any, conf: DedupConf | Mapping[str, Any] | None = None,
                     trace: Any = None) -> DedupResult:
    """Drop redundant frames of a FrameSource (or a sequence of Frames, with .rgb, .t, .index).
    Returns DedupResult with the kept frame indices and a reason for every dropped one.

    A source that already ran the same removal while decoding (`online_dedup()`: VideoSource's opening scan,
    with the same config) gives its result without decoding the video again."""
    trace = as_trace(trace)
    conf = DedupConf.merged(conf)
    src = source_or_frames
    n = len(src)
    if n == 0:
        raise InputError("remove_redundant: no frames")
    is_source = hasattr(src, "timestamps")  # a FrameSource (else a plain sequence of Frames)
    ts = np.asarray(src.timestamps if is_source else [f.t for f in src], dtype=np.float64)
    conf = _dense_enough(conf, ts, trace)
    online = getattr(src, "online_dedup", None) if is_source else None
    res = online(conf) if online is not None else None  # None when the scan sampled by another rule
    if res is not None:
        trace.decide("dedup.online", True)
        trace.decide("dedup.counts", res.counts)
        return res

    def index_at(p: int) -> int:
        return src.index_of(p) if is_source else int(src[p].index)

    # reading in increasing order decodes a video exactly once, forward (no prefetch into an evicting cache);
    # sources with a `gray(position, width)` read skip the colour conversion and the frame cache
    gray = getattr(src, "gray", None) if is_source else None
    def load(p: int) -> list[Any]:  # [gray, its ORB features once a measurement needs them]
        return [gray(p, conf.work_width) if gray is not None else _small_gray(src[p].rgb, conf.work_width), None]

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
    trace.decide("dedup.counts", res.counts)
    return res
