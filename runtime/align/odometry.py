"""Frame-to-frame odometry between two frames of a video: the chain of edges the backbone composes.

Key frames of a walk-through are often too far apart to share a view (the lounge's uniform key frames are
0.7-1.3 m apart). A real RGB-D tracker never matches such frames directly: it follows the camera through the
frames in between. `walk` does that between two frames a and b over a grid of frames (the redundant-frame
removal's kept frames, which are thinned by measured overlap: `align.thinning`), loading a frame only when the
walk reaches it: each step tries the end frame b itself (its features are cached), then a jump of twice the last
successful jump, the last jump, and halves of it down to the next grid frame, then a frame between two grid frames.
Long jumps use only edges with depth (3D-3D or PnP); the essential matrix, whose scale rests on a few
triangulated points, is used only between neighbours. Every edge is depth-checked both ways before it is taken.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Callable, Hashable, Sequence

import numpy as np

from ..infra.lru import LRU
from .matching import Matches
from .graph import Edge
from .pnp import EdgeResult

# an edge estimator: (frame index a, frame index b, adjacent?) -> EdgeResult (T_ab: b camera -> a camera)
Estimate = Callable[[int, int, bool], EdgeResult]


@dataclass
class Walk:
    """One walk from `start` towards `goal`: the edges taken (in order), the frame it ended at, the frames it
    loaded, the pairs it tried, and why its last step failed (when it did not reach the goal)."""

    start: int
    goal: int
    edges: list[Edge] = field(default_factory=list)
    end: int = -1
    loaded: int = 0
    tried: int = 0
    why: str = ""

    @property
    def reached(self) -> bool:
        return self.end == self.goal


def _jumps(n: int, last: int, max_jump: int = 1 << 30) -> list[int]:
    """Grid steps to try, in order, when n grid frames remain before the goal (the goal itself is step n + 1):
    the goal when within `max_jump`, then 2 x last, last and halves down to 1 (each once, within 1..min(n,
    max_jump)). A goal further away is reached through the grid: a walk is a path independent of the direct edge
    between its ends."""
    out = [n + 1] if n + 1 <= max_jump else []  # the goal itself only within a jump (else: an independent path)
    for s in [2 * last, last] + [last // 2 ** k for k in range(1, 8)] + [1]:
        s = min(max(int(s), 1), n, max_jump)
        if n >= 1 and s not in out:
            out.append(s)
    return out


def walk(a: int, b: int, grid: Sequence[int], estimate: Estimate, budget: int, known: Callable[[int], bool],
         first_jump: int = 4, sigma: Callable[[EdgeResult], tuple[float, float]] | None = None,
         max_jump: int = 1 << 30) -> tuple[Walk, int]:
    """Walk from frame a towards frame b (indices; a may be after b: the walk then goes back in time) over the
    grid frames strictly between them, then over any frame between two grid neighbours (module docstring).
    known(i): whether frame i is loaded already (costs no budget); budget: frames it may load. Returns (the walk,
    budget left). sigma(result) -> (metres, radians): the expected error of an edge, for the pose graph."""
    step = 1 if b > a else -1
    path = sorted((g for g in grid if min(a, b) < g < max(a, b)), reverse=step < 0) + [b]
    w = Walk(a, b, end=a)
    cur, ci, last = a, -1, first_jump
    tried: set[tuple[int, int]] = set()

    def attempt(j: int, adjacent: bool) -> bool:
        nonlocal budget
        if (cur, j) in tried:
            return False
        if not known(j):
            if budget <= 0:
                return False
            budget -= 1
            w.loaded += 1
        tried.add((cur, j))
        w.tried += 1
        r = estimate(cur, j, adjacent)
        if not r.ok:
            w.why = f"{cur}->{j}: {r.reason}"
            return False
        st, sr = sigma(r) if sigma is not None else (0.02, 0.0175)
        # after the tree's own edges, before loop closures (`backbone.key_edges`)
        w.edges.append(Edge(cur, j, r.T_ab, f"odometry/{r.method}", st, sr, 1e3 + r.n_inliers))
        return True

    while cur != b:
        n = len(path) - ci - 2  # grid frames left before the goal
        moved = False
        for s in _jumps(n, last, max_jump):
            j = path[ci + s]
            if attempt(j, s == 1 and j != b or n == 0):
                ci, cur, last, moved = ci + s, j, max(1, min(s, n)), True
                break
            if budget <= 0 and not known(j):
                break
        if not moved:  # the next grid frame failed: a frame between the two, then one grid frame further
            nxt = path[ci + 1]
            between = list(range(cur + step, nxt, step))
            # ... and up to three grid frames further (a blurred or featureless frame is skipped)
            for j in ([between[len(between) // 2]] if between else []) + path[ci + 2:ci + 5]:
                if attempt(j, True):
                    if j in path:
                        ci = path.index(j)
                    cur, moved = j, True
                    break
        if not moved:
            break
        if cur not in path:  # moved onto a frame between grid frames: continue from the next grid frame
            ci = max(k for k, g in enumerate(path) if (g - cur) * step <= 0) if any(
                (g - cur) * step <= 0 for g in path) else -1
    w.end = cur
    return w, budget


class OrbWalker:
    """The walks' matcher: ORB keypoints per frame (cached by key, LRU) matched by Hamming distance with OpenCV's
    `batchDistance` (two nearest neighbours, ratio test, mutual check) - about ten times cheaper per frame than a
    learned matcher, and enough between neighbouring frames of a video. `.match_keys` as `matching.KeyedMatcher`
    (boxes are ignored: walks match whole images); `keypoint_px` 1 (full-resolution corners)."""

    keypoint_px = 1.0

    def __init__(self, n_features: int = 2000, ratio: float = 0.8, cache_size: int = 64):
        self.n_features, self.ratio = int(n_features), float(ratio)
        self._cache = LRU(cache_size)
        self.extract_seconds = self.match_seconds = 0.0
        self.extracts = self.matches_done = 0

    def hold(self, n: int) -> None:
        """Keep the features of at least `n` frame keys (`LRU.hold`)."""
        self._cache.hold(n)

    def features(self, key: Hashable, rgb: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """(keypoints [N, 2] float32 pixels, descriptors [N, 32] uint8 or None) of an image [H, W, 3] uint8."""
        import cv2

        got = self._cache.get(key) if key is not None else None
        if got is not None:
            return got
        t0 = time.perf_counter()
        g = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2GRAY) if rgb.ndim == 3 else rgb
        kp, desc = cv2.ORB_create(nfeatures=self.n_features, fastThreshold=12).detectAndCompute(g, None)
        uv = np.array([k.pt for k in kp], np.float32).reshape(-1, 2)
        self.extract_seconds += time.perf_counter() - t0
        self.extracts += 1
        return self._cache.put(key, (uv, desc)) if key is not None else (uv, desc)

    def match_keys(self, k0: Hashable, rgb0: np.ndarray, k1: Hashable, rgb1: np.ndarray, boxes0: Any = None,
                   boxes1: Any = None) -> Matches:
        import cv2

        (u0, d0), (u1, d1) = self.features(k0, rgb0), self.features(k1, rgb1)
        if d0 is None or d1 is None or len(u0) < 2 or len(u1) < 2:
            return Matches.empty()
        t0 = time.perf_counter()
        dist, nn = cv2.batchDistance(d0, d1, cv2.CV_32S, normType=cv2.NORM_HAMMING, K=2)
        _, back = cv2.batchDistance(d1, d0, cv2.CV_32S, normType=cv2.NORM_HAMMING, K=1)
        j = nn[:, 0]
        ratio = dist[:, 0] / np.maximum(dist[:, 1], 1)
        ok = (j >= 0) & (ratio < self.ratio) & (back[np.clip(j, 0, None), 0] == np.arange(len(u0)))
        self.match_seconds += time.perf_counter() - t0
        self.matches_done += 1
        return Matches(u0[ok], u1[j[ok]], 1.0 - ratio[ok])

    def match(self, rgb0: np.ndarray, rgb1: np.ndarray, boxes0: Any = None, boxes1: Any = None) -> Matches:
        return self.match_keys(None, rgb0, None, rgb1)
