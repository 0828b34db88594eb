"""Learned matcher adapters: `.match(rgb0, rgb1, boxes0=None, boxes1=None) -> types.Matches`, the same
interface as the ORB/SIFT `FeatureMatcher` in runtime/align/matching.py.

Graph I/O contract (every learned matcher export MUST follow one of the two; `semantics.contract` says which):

A. "pair" -- ONE component named `pair`:
     inputs  image0, image1: the two images preprocessed per the manifest (e.g. [1, 3, H, W] float32)
     outputs kpts0 [K, 2] float32, kpts1 [K, 2] float32: matched pixel positions (x, y) in the MODEL INPUT
             resolution (the adapter rescales them to each original image),
             scores [K] float32 in [0, 1]: match confidence; score 0 = no match (fixed K, padded).
   (Extra outputs are allowed and ignored.) For SuperPoint+LightGlue in one graph, EfficientLoFTR, ...

B. "extractor+matcher" -- two components:
     extractor: input `image` -> kpts [K, 2] float32 (model-input pixels), kpt_scores [K] float32 (0 = padding),
                desc [K, D] float32
     matcher:   inputs drawn by name from {desc0, desc1, kpt_scores0, kpt_scores1, kpts0, kpts1} (the graph
                declares which it needs; kpts are normalised to [-1, 1] when config.normalize_kpts is true,
                otherwise fed as model-input pixels) -> matches0 [K] int64 (index into image 1's keypoints,
                -1 = none), scores [K] float32 (0 = none).
   The extractor runs once per image (results cached by image content), so aligning N frames extracts N
   times however many pairs are tried. For XFeat (export/xfeat.py) and SuperPoint + LightGlue.

Boxes restrict the result to matches whose points lie inside any box of their image (the paper's trick: walls
and floors give repeated-texture mismatches); with no boxes the whole image is used.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from ..infra.lru import LRU
from ..geometry import in_boxes
from ..types import Matches
from . import ImageLRU, RoleModel, preprocess_image


def _model_size(spec) -> tuple[int, int] | None:
    size = spec.preprocessing.get("size")
    return (int(size[0]), int(size[1])) if size else None


def _rescale(uv: np.ndarray, in_hw: tuple[int, int], img_hw: tuple[int, int]) -> np.ndarray:
    """Model-input pixels -> original-image pixels (pixel-centre convention of cv2.resize)."""
    sy, sx = img_hw[0] / in_hw[0], img_hw[1] / in_hw[1]
    out = uv.astype(np.float32).copy()
    out[:, 0] = (out[:, 0] + 0.5) * sx - 0.5
    out[:, 1] = (out[:, 1] + 0.5) * sy - 0.5
    return out


def _restrict(m: Matches, boxes0, boxes1, margin: float = 4.0) -> Matches:
    if boxes0 is None and boxes1 is None:
        return m
    keep = in_boxes(m.uv0, boxes0, margin) & in_boxes(m.uv1, boxes1, margin)
    return Matches(m.uv0[keep], m.uv1[keep], m.scores[keep])


class PairMatcher(RoleModel):
    """Contract A: one `pair` graph."""

    role = "matcher"

    def __init__(self, spec, sessions, trace):
        super().__init__(spec, sessions, trace)
        sess = self.session("pair") if "pair" in sessions else self.session()
        self._sess = sess
        names = sess.input_names
        self._in0, self._in1 = ("image0", "image1") if {"image0", "image1"} <= set(names) else names[:2]
        outs = sess.output_names
        self._outs = ["kpts0", "kpts1", "scores"] if {"kpts0", "kpts1", "scores"} <= set(outs) else outs[:3]
        self.min_score = float(spec.config.get("min_score", 0.0))

    def match(self, rgb0: np.ndarray, rgb1: np.ndarray, boxes0: np.ndarray | None = None,
              boxes1: np.ndarray | None = None) -> Matches:
        """rgb0, rgb1: [H, W, 3] uint8 -> Matches in original-image pixels."""
        pp = self.spec.preprocessing
        x0, x1 = preprocess_image(rgb0, pp), preprocess_image(rgb1, pp)
        with self._stage("matcher", "pair" if "pair" in self.sessions else None):
            k0, k1, sc = self._sess.run({self._in0: x0, self._in1: x1}, self._outs)
        sc = np.asarray(sc, np.float32).reshape(-1)
        ok = sc > self.min_score
        hw = _model_size(self.spec) or rgb0.shape[:2]
        m = Matches(_rescale(np.asarray(k0).reshape(-1, 2)[ok], hw, rgb0.shape[:2]),
                    _rescale(np.asarray(k1).reshape(-1, 2)[ok], hw, rgb1.shape[:2]), sc[ok])
        return _restrict(m, boxes0, boxes1)


class TwoStageMatcher(RoleModel):
    """Contract B: `extractor` once per image (LRU cache) + `matcher` per pair."""

    role = "matcher"
    cache_size = 64
    pair_cache_size = 128

    def __init__(self, spec, sessions, trace):
        super().__init__(spec, sessions, trace)
        # whole-image matches per keyed pair: boxes only filter them afterwards (`_restrict`), so the box round
        # and the whole-image round of alignment (and the tree's re-verifications) share one matcher run per pair
        self._pairs = LRU(self.pair_cache_size)
        self._ext = self.session("extractor")
        self._mat = self.session("matcher")
        self._ext_in = self._ext.input_names[0]
        self._cache = ImageLRU(self.cache_size)
        self.normalize_kpts = bool(spec.config.get("normalize_kpts", False))
        # keypoint noise (px) for the essential edges' threshold: heatmap keypoints are coarser than SIFT's
        self.keypoint_px = float(spec.config.get("keypoint_px", 2.0))

    def hold(self, n: int) -> None:
        """Keep the features of at least `n` frames (the backbone's walks return to frames they loaded: past the
        default bound a frame would be extracted twice)."""
        self._cache.hold(n)

    def features(self, rgb: np.ndarray, key: Any = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """rgb [H, W, 3] uint8 -> (kpts [K, 2] model-input pixels, kpt_scores [K], desc [K, D]), cached by
        `key` (default: a hash of the image bytes)."""
        with self._overhead("matcher.extract", "matcher.match"):
            return self._features(rgb, key)

    def _features(self, rgb: np.ndarray, key: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        key = self._cache.key(rgb) if key is None else key
        hit = self._cache.get(key)
        if hit is not None:
            return hit
        x = preprocess_image(rgb, self.spec.preprocessing)
        with self._stage("matcher.extract", "extractor"):
            out = self._ext.run({self._ext_in: x})
        names = self._ext.output_names
        d = dict(zip(names, out))
        feats = (d.get("kpts", out[0]).reshape(-1, 2), d.get("kpt_scores", out[1]).reshape(-1),
                 d.get("desc", out[2]).reshape(len(d.get("kpt_scores", out[1]).reshape(-1)), -1))
        return self._cache.put(key, feats)

    def match_keys(self, k0: Any, rgb0: np.ndarray, k1: Any, rgb1: np.ndarray, boxes0: np.ndarray | None = None,
                   boxes1: np.ndarray | None = None) -> Matches:
        """Same as `match`, caching features under the caller's frame keys (e.g. frame indices)."""
        return self.match(rgb0, rgb1, boxes0, boxes1, key0=("key", k0), key1=("key", k1))

    def match(self, rgb0: np.ndarray, rgb1: np.ndarray, boxes0: np.ndarray | None = None,
              boxes1: np.ndarray | None = None, key0: Any = None, key1: Any = None) -> Matches:
        """rgb0, rgb1: [H, W, 3] uint8 -> Matches in original-image pixels (key0/key1: optional cache keys)."""
        with self._overhead("matcher.extract", "matcher.match"):
            return self._match(rgb0, rgb1, boxes0, boxes1, key0, key1)

    def _match(self, rgb0: np.ndarray, rgb1: np.ndarray, boxes0: np.ndarray | None, boxes1: np.ndarray | None,
               key0: Any, key1: Any) -> Matches:
        pk = None if key0 is None or key1 is None else (key0, key1, rgb0.shape, rgb1.shape)
        m = self._pairs.get(pk) if pk is not None else None
        if m is None:
            m = self._match_whole(rgb0, rgb1, key0, key1)
            if pk is not None:
                for a in (m.uv0, m.uv1, m.scores):
                    a.setflags(write=False)  # shared by every later call on the pair
                self._pairs.put(pk, m)
        return _restrict(m, boxes0, boxes1)

    def _match_whole(self, rgb0: np.ndarray, rgb1: np.ndarray, key0: Any, key1: Any) -> Matches:
        k0, s0, d0 = self.features(rgb0, key0)
        k1, s1, d1 = self.features(rgb1, key1)
        hw = _model_size(self.spec) or rgb0.shape[:2]

        def kp(k):
            if not self.normalize_kpts:
                return k.astype(np.float32)
            return (2.0 * k / np.array([hw[1] - 1, hw[0] - 1], np.float32) - 1.0).astype(np.float32)

        avail = {"desc0": d0, "desc1": d1, "kpt_scores0": s0, "kpt_scores1": s1, "kpts0": kp(k0), "kpts1": kp(k1)}
        feeds = {n: avail[n] for n in self._mat.input_names}
        with self._stage("matcher.match", "matcher"):
            m0, sc = self._mat.run(feeds)[:2]
        m0 = np.asarray(m0).reshape(-1).astype(np.int64)
        sc = np.asarray(sc, np.float32).reshape(-1)
        ok = (m0 >= 0) & (sc > 0)
        return Matches(_rescale(k0[ok], hw, rgb0.shape[:2]), _rescale(k1[m0[ok]], hw, rgb1.shape[:2]),
                       np.clip(sc[ok], 0.0, 1.0))
