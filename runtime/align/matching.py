"""Weight-free feature matching (ORB, SIFT from OpenCV): mutual nearest neighbour + Lowe ratio test.

Matching can be restricted to keypoints inside object boxes (the paper's trick: no walls and floors, whose
repeated texture gives wrong matches); with no boxes the whole image is used. Learned matchers
(`runtime/models/matcher.py`) expose the same `.match(rgb0, rgb1, boxes0=None, boxes1=None) -> Matches`.

`FeatureMatcher` caches keypoints and descriptors per frame key, so aligning K frames extracts K feature sets,
however many pairs are tried.
"""
from __future__ import annotations

import os
import time
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, replace
from typing import Any, ClassVar, Hashable, Mapping, Protocol, Sequence, runtime_checkable

import numpy as np

from ..infra.config import StageConf
from ..infra.errors import InputError
from ..geometry import in_boxes
from ..infra.lru import LRU
from ..types import Matches


@dataclass
class MatchConf(StageConf):
    """Defaults: SIFT (Lowe 2004) and ORB (Rublee 2011) with mutual nearest neighbours and the ratio test."""

    conf_name: ClassVar[str] = "matcher config"

    method: str = "sift"
    max_keypoints: int = 3000
    ratio: float | None = None   # Lowe's ratio test (best / second-best distance); None = 0.9 SIFT, 0.8 ORB
    mutual: bool = True          # keep only mutual nearest neighbours
    max_side: int = 640          # images are downscaled so that the longer side is at most this (speed)
    orb_fast_threshold: int = 12
    sift_contrast_threshold: float = 0.02  # OpenCV's default is 0.04; lower finds more keypoints indoors
    box_margin: float = 4.0      # pixels added around each box when restricting keypoints

    @classmethod
    def merged(cls, conf: "MatchConf | Mapping[str, Any] | None" = None, **overrides: Any) -> "MatchConf":
        """Defaults merged with a conf object or dict and keyword overrides; the ratio defaults per method."""
        out = super().merged(conf, **overrides)
        return out if out.ratio is not None else replace(out, ratio=0.9 if out.method == "sift" else 0.8)

    def validate(self) -> None:
        if self.method not in ("sift", "orb"):
            raise InputError(f"matcher config: method must be 'sift' or 'orb', got {self.method!r}")


@dataclass
class Features:
    """Keypoints of one image. uv: [N, 2] float32 pixels in the ORIGINAL image; desc: [N, D] (float32 SIFT,
    uint8 ORB)."""

    uv: np.ndarray
    desc: np.ndarray
    method: str

    def __len__(self) -> int:
        return len(self.uv)


def _gray(rgb: np.ndarray) -> np.ndarray:
    import cv2

    if rgb.ndim == 2:
        return rgb
    return cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2GRAY)


def extract_features(rgb: np.ndarray, conf: MatchConf | None = None) -> Features:
    """Detect and describe keypoints. rgb: [H, W, 3] uint8 (or [H, W] gray) -> Features."""
    import cv2

    conf = MatchConf.merged(conf)
    g = _gray(rgb)
    s = min(1.0, conf.max_side / max(g.shape))
    if s < 1.0:
        g = cv2.resize(g, (round(g.shape[1] * s), round(g.shape[0] * s)), interpolation=cv2.INTER_AREA)
    if conf.method == "sift":
        det = cv2.SIFT_create(nfeatures=conf.max_keypoints, contrastThreshold=conf.sift_contrast_threshold)
        dim, dtype = 128, np.float32
    else:
        det = cv2.ORB_create(nfeatures=conf.max_keypoints, fastThreshold=conf.orb_fast_threshold)
        dim, dtype = 32, np.uint8
    kps, desc = det.detectAndCompute(g, None)
    if desc is None or not kps:
        return Features(np.zeros((0, 2), np.float32), np.zeros((0, dim), dtype), conf.method)
    uv = np.array([k.pt for k in kps], dtype=np.float32) / s
    return Features(uv, desc.astype(dtype, copy=False), conf.method)


def _knn2_from_distances(D: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Two nearest neighbours per row of a distance matrix D [N, M] (modified in place) and the mutual flag.
    Returns idx [N, 2], dist [N, 2] and mutual [N] bool (row i is also the nearest row of its best column)."""
    rows = np.arange(len(D))
    j1 = D.argmin(1)
    d1 = D[rows, j1].copy()
    mutual = d1 <= D.min(0)[j1]
    D[rows, j1] = np.inf
    j2 = D.argmin(1)
    d2 = D[rows, j2]
    return np.stack([j1, j2], 1), np.stack([d1, d2], 1).astype(np.float64), mutual


def _integer_exact(a: np.ndarray, b: np.ndarray, aa: np.ndarray, bb: np.ndarray) -> bool:
    """Whether every squared distance between rows of a and b, and every partial sum on the way, is an integer
    float32 holds exactly (< 2^24): integer-valued descriptors (OpenCV's SIFT: 0..255) with small norms. Then
    the order of the additions cannot change a single bit of the distances."""
    if not (len(aa) and len(bb)):
        return False
    bound = (np.sqrt(float(aa.max())) + np.sqrt(float(bb.max()))) ** 2  # >= every |partial sum| (Cauchy-Schwarz)
    return bound < 2.0 ** 24 and np.array_equal(a, np.rint(a)) and np.array_equal(b, np.rint(b))


def _knn2_l2(d0: np.ndarray, d1: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Euclidean two nearest neighbours (one matmul; see `_knn2_from_distances`). Integer descriptors (SIFT)
    get the squared distances |a|^2 + |b|^2 - 2 a.b from ONE matmul of [a, |a|^2, 1] by [-2b, 1, |b|^2]: exact
    (`_integer_exact`), so bit for bit the distances of the three-pass form, without three passes over the
    [N, M] matrix."""
    a = np.ascontiguousarray(d0, dtype=np.float32)
    b = np.ascontiguousarray(d1, dtype=np.float32)
    aa, bb = (a * a).sum(1), (b * b).sum(1)
    if _integer_exact(a, b, aa, bb):
        n, dim = a.shape
        A = np.empty((n, dim + 2), np.float32)
        A[:, :dim], A[:, dim], A[:, dim + 1] = a, aa, 1.0
        B = np.empty((len(b), dim + 2), np.float32)
        B[:, :dim], B[:, dim], B[:, dim + 1] = b * np.float32(-2.0), 1.0, bb
        idx, dd, mutual = _knn2_from_distances(A @ B.T)  # exact integers >= 0: nothing to clip
        return idx, np.sqrt(dd), mutual
    D = a @ b.T
    D *= -2.0
    D += bb[None, :]
    D += aa[:, None]  # squared distances, in place (no [N, M] temporaries)
    np.maximum(D, 0.0, out=D)
    idx, dd, mutual = _knn2_from_distances(D)
    return idx, np.sqrt(dd), mutual


def _knn2_hamming(d0: np.ndarray, d1: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Hamming two nearest neighbours of binary descriptors [N, 32] uint8: |x| + |y| - 2 x.y over the unpacked
    bits, as one float32 matmul (exact for these integer counts, and faster than OpenCV's brute force here)."""
    a = np.unpackbits(np.ascontiguousarray(d0, dtype=np.uint8), axis=1).astype(np.float32)
    b = np.unpackbits(np.ascontiguousarray(d1, dtype=np.uint8), axis=1).astype(np.float32)
    D = a @ b.T
    D *= -2.0
    D += b.sum(1)[None, :]
    D += a.sum(1)[:, None]
    return _knn2_from_distances(D)


def match_descriptors(f0: Features, f1: Features, conf: MatchConf | None = None,
                      keep0: np.ndarray | None = None, keep1: np.ndarray | None = None) -> Matches:
    """Mutual nearest neighbours passing the ratio test between two feature sets, optionally restricted to
    keypoints with keep0 [N0] / keep1 [N1] True."""
    conf = MatchConf.merged(conf or MatchConf(method=f0.method))
    i0 = np.flatnonzero(keep0) if keep0 is not None else np.arange(len(f0))
    i1 = np.flatnonzero(keep1) if keep1 is not None else np.arange(len(f1))
    if len(i0) < 2 or len(i1) < 2:
        return Matches.empty()
    d0, d1 = f0.desc[i0], f1.desc[i1]
    idx, dd, mutual = _knn2_l2(d0, d1) if f0.method == "sift" else _knn2_hamming(d0, d1)
    nn = idx[:, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(dd[:, 1] > 0, dd[:, 0] / dd[:, 1], 1.0)
    ok = (nn >= 0) & (ratio < conf.ratio)
    if conf.mutual:
        ok &= mutual
    q = np.flatnonzero(ok)
    return Matches(f0.uv[i0[q]], f1.uv[i1[nn[q]]], 1.0 - ratio[q])


class FeatureMatcher:
    """ORB/SIFT matcher with a per-frame feature cache (LRU over `cache_size` frame keys).

    `.match(rgb0, rgb1, boxes0, boxes1)` is the common matcher interface; `.match_keys(k0, rgb0, k1, rgb1, ...)`
    reuses cached features for frames identified by hashable keys (frame indices)."""

    def __init__(self, method: str = "sift", conf: MatchConf | Mapping[str, Any] | None = None,
                 cache_size: int = 256):
        self.conf = MatchConf.merged(conf, method=method)
        self.name = self.conf.method
        self._cache = LRU(cache_size)
        # counters the pipeline books as trace stages "features.extract" / "features.match"
        self.extract_seconds = 0.0
        self.extracts = 0
        self.match_seconds = 0.0
        self.matches_done = 0
        self._pending: dict[Hashable, tuple[Future, np.ndarray]] = {}
        self._pool: ThreadPoolExecutor | None = None

    def hold(self, n: int) -> None:
        """Keep the features of at least `n` frame keys (`LRU.hold`)."""
        self._cache.hold(n)

    def prefetch(self, items: Sequence[tuple[Hashable, np.ndarray]], workers: int = 1) -> None:
        """Start extracting the features of these (key, rgb) frames on `workers` threads (OpenCV releases the GIL;
        SIFT itself runs on one core): the caller's next steps run meanwhile, and `features` extracts a frame no
        worker has started itself, and while it waits for a started one extracts the last queued (so the caller's
        thread is one more extractor). The features are the same as
        extracted in turn; `extract_seconds` sums every thread's seconds. One worker by default: each thread
        extracting at once holds its own image pyramid (2 workers: +80 MB peak RSS)."""
        todo = [(k, rgb) for k, rgb in items if k is not None and k not in self._cache and k not in self._pending]
        if not todo:
            return
        if self._pool is None:
            self._pool = ThreadPoolExecutor(max(1, min(int(workers), os.cpu_count() or 1)),
                                            thread_name_prefix="features")
        for k, rgb in todo:
            self._pending[k] = (self._pool.submit(_timed_extract, rgb, self.conf), rgb)

    def _collect(self, key: Hashable, rgb: np.ndarray) -> Features:
        job, _ = self._pending.pop(key)
        if job.cancel():  # not started: extract here
            f, dt = _timed_extract(rgb, self.conf)
        else:
            while not job.done() and self._steal():
                pass
            f, dt = job.result()
        self._book(dt)
        if not self._pending and self._pool is not None:  # idle workers are not kept
            self._pool.shutdown(wait=False)
            self._pool = None
        return f

    def _steal(self) -> bool:
        """Extract the last queued frame no worker has started on this thread; False when there is none."""
        for k in reversed(list(self._pending)):
            job, rgb = self._pending[k]
            if job.cancel():
                del self._pending[k]
                f, dt = _timed_extract(rgb, self.conf)
                self._book(dt)
                self._remember(k, f)
                return True
        return False

    def _book(self, dt: float) -> None:
        self.extract_seconds += dt
        self.extracts += 1

    def _remember(self, key: Hashable, f: Features) -> None:
        self._cache.put(key, f)

    def features(self, key: Hashable | None, rgb: np.ndarray) -> Features:
        if key is not None and key in self._cache:
            return self._cache.get(key)
        if key is not None and key in self._pending:
            f = self._collect(key, rgb)
        else:
            f, dt = _timed_extract(rgb, self.conf)
            self._book(dt)
        if key is not None:
            self._remember(key, f)
        return f

    def match_keys(self, k0: Hashable, rgb0: np.ndarray, k1: Hashable, rgb1: np.ndarray,
                   boxes0: np.ndarray | None = None, boxes1: np.ndarray | None = None) -> Matches:
        f0, f1 = self.features(k0, rgb0), self.features(k1, rgb1)
        m = self.conf.box_margin
        t0 = time.perf_counter()
        out = match_descriptors(f0, f1, self.conf, in_boxes(f0.uv, boxes0, m) if boxes0 is not None else None,
                                in_boxes(f1.uv, boxes1, m) if boxes1 is not None else None)
        self.match_seconds += time.perf_counter() - t0
        self.matches_done += 1
        return out

    def match(self, rgb0: np.ndarray, rgb1: np.ndarray, boxes0: np.ndarray | None = None,
              boxes1: np.ndarray | None = None) -> Matches:
        return self.match_keys(None, rgb0, None, rgb1, boxes0, boxes1)


def _timed_extract(rgb: np.ndarray, conf: MatchConf) -> tuple[Features, float]:
    t0 = time.perf_counter()
    return extract_features(rgb, conf), time.perf_counter() - t0


def match_features(rgb0: np.ndarray, rgb1: np.ndarray, boxes0: np.ndarray | None = None,
                   boxes1: np.ndarray | None = None, method: str = "sift",
                   conf: MatchConf | Mapping[str, Any] | None = None) -> Matches:
    """Match two images. rgb0, rgb1: [H, W, 3] uint8; boxes: [N, 4] x0, y0, x1, y1 (keypoints outside every box
    are ignored) or None (whole image). Returns Matches (uv0 in image 0, uv1 in image 1)."""
    return FeatureMatcher(method, conf, cache_size=0).match(rgb0, rgb1, boxes0, boxes1)


@runtime_checkable
class Matcher(Protocol):
    """What alignment needs of a matcher (OpenCV `FeatureMatcher`, learned matchers in `runtime/models/matcher.py`):
    matches between two images, optionally only for keypoints inside the given boxes."""

    def match(self, rgb0: np.ndarray, rgb1: np.ndarray, boxes0: np.ndarray | None = None,
              boxes1: np.ndarray | None = None) -> Matches: ...


@runtime_checkable
class KeyedMatcher(Matcher, Protocol):
    """A matcher that caches features per frame key (frame index): `match_keys` reuses them across pairs."""

    def match_keys(self, k0: Hashable, rgb0: np.ndarray, k1: Hashable, rgb1: np.ndarray,
                   boxes0: np.ndarray | None = None, boxes1: np.ndarray | None = None) -> Matches: ...


class _Keyed:
    """A plain `Matcher` seen as a `KeyedMatcher`: the keys are ignored (no cache); other attributes (the
    matcher's `keypoint_px`, `extract_seconds`, ...) are the wrapped matcher's."""

    def __init__(self, matcher: Matcher):
        self.m = matcher

    def match(self, rgb0: np.ndarray, rgb1: np.ndarray, boxes0: np.ndarray | None = None,
              boxes1: np.ndarray | None = None) -> Matches:
        return self.m.match(rgb0, rgb1, boxes0, boxes1)

    def match_keys(self, k0: Hashable, rgb0: np.ndarray, k1: Hashable, rgb1: np.ndarray,
                   boxes0: np.ndarray | None = None, boxes1: np.ndarray | None = None) -> Matches:
        return self.m.match(rgb0, rgb1, boxes0, boxes1)

    def __getattr__(self, name: str) -> Any:
        if name == "m":  # not set yet (copy, pickle): no recursion
            raise AttributeError(name)
        return getattr(self.m, name)


def make_matcher(matcher: "str | Matcher", conf: MatchConf | Mapping[str, Any] | None = None) -> KeyedMatcher:
    """'orb' | 'sift' (an OpenCV `FeatureMatcher` with `conf`) or a `Matcher` object, as a `KeyedMatcher`
    (a matcher without a feature cache gets one that ignores the keys). Anything else is an `InputError`."""
    if isinstance(matcher, str):
        return FeatureMatcher(matcher, conf)
    if isinstance(matcher, KeyedMatcher):
        return matcher
    if isinstance(matcher, Matcher):
        return _Keyed(matcher)
    raise InputError(f"matcher must be 'orb', 'sift' or an object with .match(rgb0, rgb1, boxes0, boxes1), "
                     f"got {type(matcher).__name__}")
