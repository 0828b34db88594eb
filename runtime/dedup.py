"""Redundant-frame removal (paper: Preprocessing).

1. uniform down-sampling to `sample_fps` (or every `stride`-th frame);
2. ORB keypoint tracking between consecutive KEPT frames: a frame whose keypoints are mostly tracked with a
   small displacement is a candidate near-duplicate of the last kept frame (cheap: no per-pixel work);
3. SSIM only on those candidates: above `ssim_threshold` the frame is dropped as a near-duplicate.

Every dropped frame gets a reason. `ssim` reproduces scikit-image's
`structural_similarity(gaussian_weights=True, sigma=1.5, use_sample_covariance=False)` (tested to 1e-3).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar, Mapping

import numpy as np

from .config import StageConf
from .errors import InputError
from .trace import as_trace


# ----------------------------------------------------------------------------- SSIM


def _ssim_map(x: np.ndarray, y: np.ndarray, data_range: float, sigma: float = 1.5) -> tuple[np.ndarray, int]:
    import cv2

    r = int(3.5 * sigma + 0.5)  # scipy.ndimage's truncate=3.5 radius, as scikit-image uses
    k = 2 * r + 1
    x = x.astype(np.float64)
    y = y.astype(np.float64)

    def blur(a: np.ndarray) -> np.ndarray:
        # BORDER_REFLECT (abc|cba) is scipy's mode='reflect'
        return cv2.GaussianBlur(a, (k, k), sigma, sigmaY=sigma, borderType=cv2.BORDER_REFLECT)

    ux, uy = blur(x), blur(y)
    uxx, uyy, uxy = blur(x * x), blur(y * y), blur(x * y)
    vx, vy, vxy = uxx - ux * ux, uyy - uy * uy, uxy - ux * uy  # population covariance (Wang et al. 2004)
    c1, c2 = (0.01 * data_range) ** 2, (0.03 * data_range) ** 2
    S = ((2 * ux * uy + c1) * (2 * vxy + c2)) / ((ux * ux + uy * uy + c1) * (vx + vy + c2))
    return S, r


def ssim(a: np.ndarray, b: np.ndarray, data_range: float | None = None, sigma: float = 1.5) -> float:
    """Mean structural similarity of two images [H, W] or [H, W, C] (channels averaged), Gaussian window
    (sigma 1.5, radius 5), population covariance, borders of the window radius excluded — as scikit-image.
    data_range defaults to 255 for uint8 and 65535 for uint16; float images must give it."""
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
        return float(np.mean([ssim(a[..., c], b[..., c], data_range, sigma) for c in range(a.shape[2])]))
    S, r = _ssim_map(a, b, float(data_range), sigma)
    if min(S.shape) <= 2 * r:
        raise ValueError(f"ssim: image {S.shape} smaller than the {2 * r + 1}x{2 * r + 1} window")
    return float(S[r:-r, r:-r].mean(dtype=np.float64))


# ----------------------------------------------------------------------------- redundant-frame removal


@dataclass
class DedupConf(StageConf):
    """Defaults of the preprocessing stage (`DedupConf.merged(overrides)`, see config.StageConf)."""

    conf_name: ClassVar[str] = "dedup config"

    sample_fps: float | None = 3.0   # uniform down-sampling rate (None: use `stride`)
    stride: int = 1                  # keep every stride-th frame when sample_fps is None
    work_width: int = 320            # frames are resized to this width for ORB and SSIM
    orb_features: int = 500
    min_tracked: float = 0.35        # tracked ORB fraction above which a frame is a candidate duplicate ...
    max_motion: float = 0.04         # ... when the median keypoint displacement is below this x width
    ssim_threshold: float = 0.80     # candidates with SSIM above this are dropped as near-duplicates



@dataclass
class DedupResult:
    """kept: frame indices kept (time order); dropped: {frame index: reason}; counts: how many per stage;
    scores: {frame index: {"tracked", "motion", "ssim"}} for frames that were compared."""

    kept: list[int]
    dropped: dict[int, str]
    counts: dict[str, int]
    scores: dict[int, dict[str, float]] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return {"kept": self.kept, "dropped": {str(k): v for k, v in self.dropped.items()}, "counts": self.counts,
                "scores": {str(k): v for k, v in self.scores.items()}}


def _small_gray(rgb: np.ndarray, width: int) -> np.ndarray:
    import cv2

    g = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2GRAY) if rgb.ndim == 3 else rgb
    if g.shape[1] > width:
        g = cv2.resize(g, (width, max(1, round(g.shape[0] * width / g.shape[1]))), interpolation=cv2.INTER_AREA)
    return g


def orb_track(g0: np.ndarray, g1: np.ndarray, n_features: int = 500) -> tuple[float, float]:
    """Track ORB keypoints from gray image g0 to g1 ([H, W] uint8): (fraction of g0's keypoints with a mutual,
    ratio-tested match, median displacement in pixels). (0, inf) when nothing can be tracked."""
    import cv2

    orb = cv2.ORB_create(nfeatures=n_features, fastThreshold=12)
    k0, d0 = orb.detectAndCompute(g0, None)
    k1, d1 = orb.detectAndCompute(g1, None)
    if d0 is None or d1 is None or len(k0) < 8 or len(k1) < 2:
        return 0.0, float("inf")
    bf = cv2.BFMatcher(cv2.NORM_HAMMING)
    back = {m.queryIdx: m.trainIdx for m in bf.match(d1, d0)}
    disp = []
    for ms in bf.knnMatch(d0, d1, k=2):
        if len(ms) < 2:
            continue
        m, n = ms
        if m.distance < 0.8 * n.distance and back.get(m.trainIdx) == m.queryIdx:
            disp.append(np.hypot(*(np.subtract(k1[m.trainIdx].pt, k0[m.queryIdx].pt))))
    if not disp:
        return 0.0, float("inf")
    return len(disp) / len(k0), float(np.median(disp))


def remove_redundant(source_or_frames: Any, conf: DedupConf | Mapping[str, Any] | None = None,
                     trace: Any = None) -> DedupResult:
    """Drop redundant frames of a FrameSource (or a sequence of Frames, with .rgb, .t, .index).
    Returns DedupResult with the kept frame indices and a reason for every dropped one."""
    trace = as_trace(trace)
    conf = DedupConf.merged(conf)
    src = source_or_frames
    n = len(src)
    if n == 0:
        raise InputError("remove_redundant: no frames")
    is_source = hasattr(src, "timestamps")  # a FrameSource (else a plain sequence of Frames)
    ts = np.asarray(src.timestamps if is_source else [f.t for f in src], dtype=np.float64)
    get = src.__getitem__

    def index_at(p: int) -> int:
        return src.index_of(p) if is_source else int(src[p].index)

    # 1. uniform down-sampling by time (robust to uneven timestamps) or stride
    if conf.sample_fps:
        sampled, next_t = [], -np.inf
        for i, t in enumerate(ts):
            if t >= next_t - 1e-9:
                sampled.append(i)
                next_t = t + 1.0 / conf.sample_fps
    else:
        sampled = list(range(0, n, max(1, int(conf.stride))))
    sset = set(sampled)
    dropped: dict[int, str] = {}
    # no prefetch of all sampled frames: it would decode them once into a bounded cache that evicts the first
    # ones, and the loop below would then seek back and decode everything again; reading in increasing order
    # decodes a video exactly once, forward
    idx_of = {p: index_at(p) for p in sampled}
    why = f"downsampled to {conf.sample_fps} fps" if conf.sample_fps else f"downsampled (stride {conf.stride})"
    for p in range(n):
        if p not in sset:
            dropped[index_at(p)] = why
    # 2.-3. ORB tracking against the last kept frame, SSIM on candidates
    kept = [sampled[0]]
    g_last = _small_gray(get(sampled[0]).rgb, conf.work_width)
    scores: dict[int, dict[str, float]] = {}
    n_cand = n_dup = 0
    for p in sampled[1:]:
        g = _small_gray(get(p).rgb, conf.work_width)
        if g.shape != g_last.shape:
            raise InputError(f"frame {idx_of[p]}: size {g.shape} differs from the previous frame {g_last.shape}")
        tracked, motion = orb_track(g_last, g, conf.orb_features)
        sc = {"tracked": round(tracked, 4), "motion_px": round(motion, 2) if np.isfinite(motion) else None}
        if tracked >= conf.min_tracked and motion <= conf.max_motion * g.shape[1]:
            n_cand += 1
            s = ssim(g_last, g)
            sc["ssim"] = round(s, 4)
            if s >= conf.ssim_threshold:
                n_dup += 1
                dropped[idx_of[p]] = (f"near-duplicate of frame {idx_of[kept[-1]]} (SSIM {s:.3f} >= "
                                      f"{conf.ssim_threshold}; ORB tracked {tracked:.0%}, motion {motion:.1f} px)")
                scores[idx_of[p]] = sc
                continue
        scores[idx_of[p]] = sc
        kept.append(p)
        g_last = g
    counts = {"input": n, "after_downsampling": len(sampled), "downsampled_away": n - len(sampled),
              "candidates": n_cand, "near_duplicates": n_dup, "kept": len(kept)}
    res = DedupResult([idx_of[p] for p in kept], dict(sorted(dropped.items())), counts, scores)
    trace.decide("dedup.counts", counts)
    return res
