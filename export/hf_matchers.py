"""Learned matchers: SuperPoint (fixed top-K) + LightGlue, and EfficientLoFTR, following the I/O contract of
runtime/models/matcher.py so its adapters run them unchanged.

SuperPoint + LightGlue: contract B ("extractor+matcher"), arch `superpoint_lightglue` -> TwoStageMatcher.
- extractor: `image [1, 3, H, W] float32` (RGB, 0..1; the graph converts to gray) -> `kpts [K, 2]` (x, y
  model-input pixels), `kpt_scores [K]` (0 = padding: below `keypoint_threshold` after NMS), `desc [K, D]`
  (L2-normalised). SuperPoint's variable-length threshold list becomes a fixed top-K over the NMS'd,
  border-cleared score map, so shapes are static.
- matcher: `kpts0, kpts1 [K, 2]` pixels, `desc0, desc1 [K, D]`, `kpt_scores0, kpt_scores1 [K]` ->
  `matches0 [K] int64` (-1 = none), `scores [K] float32`. LightGlue with adaptive depth/width switched off
  (static graph); keypoints are normalised inside the graph with the export size (config.normalize_kpts false).

EfficientLoFTR: contract A ("pair"), arch `efficientloftr` -> PairMatcher.
- pair: `image0, image1 [1, 3, H, W] float32` (RGB 0..1) -> `kpts0, kpts1 [N, 2]` model-input pixels,
  `scores [N]` (0 = no match; N = coarse cells, fixed by H, W). Row i pairs image-0 coarse cell i with its
  mutual nearest neighbour in image 1, then the model's fine stage refines that pair (transformers'
  forward pairs cells by position in two differently indexed lists; see `loftr_pair`).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

import numpy as np

from mosaicthinker.runtime.infra.errors import ExportError

from . import common as C
from .hf_common import GraphSpec, export_variants, run_exporter
from .sources import load_source

HF_DEFAULTS = {"superpoint-lightglue": "ETH-CVG/lightglue_superpoint", "efficientloftr": "zju-community/efficientloftr"}
GRAY = (0.299, 0.587, 0.114)


def _gray(image):
    return image[:, 0:1] * GRAY[0] + image[:, 1:2] * GRAY[1] + image[:, 2:3] * GRAY[2]


def superpoint_extractor(sp: Any, k: int, threshold: float):
    import torch

    class SuperPointTopK(torch.nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.sp = sp
            self.k = k
            self.threshold = threshold
            self.border = int(sp.keypoint_decoder.border_removal_distance)

        def forward(self, image):
            enc = self.sp.encoder(_gray(image)).last_hidden_state
            heat = self.sp.keypoint_decoder._get_pixel_scores(enc)[0]          # [H, W], NMS applied
            H, W = heat.shape
            b = self.border
            ys = torch.arange(H, device=heat.device)[:, None]
            xs = torch.arange(W, device=heat.device)[None, :]
            inside = (ys >= b) & (ys < H - b) & (xs >= b) & (xs < W - b)
            heat = torch.where(inside, heat, torch.zeros_like(heat))
            vals, idx = torch.topk(heat.reshape(-1), self.k)
            kpts = torch.stack([idx % W, idx // W], dim=-1).to(heat.dtype)
            scores = torch.where(vals > self.threshold, vals, torch.zeros_like(vals))
            desc = self.sp.descriptor_decoder(enc, kpts)                       # [K, D], unit norm
            return kpts, scores, desc

    return SuperPointTopK().eval()


def lightglue_matcher(lg: Any, height: int, width: int):
    import torch

    class LightGlueStatic(torch.nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.lg = lg
            self.h, self.w = height, width

        def forward(self, kpts0, kpts1, desc0, desc1, kpt_scores0, kpt_scores1):
            kp = torch.stack([kpts0, kpts1])[None]
            desc = torch.stack([desc0, desc1])[None]
            mask = torch.stack([kpt_scores0 > 0, kpt_scores1 > 0])[None]
            matches, mscores = self.lg._match_image_pair(kp, desc, self.h, self.w, mask=mask)[:2]
            m0, s0 = matches[0].to(torch.int64), mscores[0]
            return m0, torch.where(m0 >= 0, s0, torch.zeros_like(s0))

    return LightGlueStatic().eval()


def loftr_pair(model: Any):
    import torch

    class EfficientLoFTRPair(torch.nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.m = model

        def forward(self, image0, image1):
            # EfficientLoFTRForKeypointMatching.forward with one change: transformers' `matches[:, 0]` is
            # indexed by the image-1 cell and `matches[:, 1]` by the image-0 cell, and its forward pairs the two
            # at the same index (right only when both cells have the same index). Here row i pairs image-0
            # cell i with its mutual match j = matches[:, 1][i], and the fine stage refines those true pairs.
            m = self.m
            H = image0.shape[-2]
            g = torch.stack([_gray(image0), _gray(image1)], dim=1).expand(-1, -1, 3, -1, -1)
            feats = m.efficientloftr(g).feature_maps
            coarse = feats[0]                                                    # [1, 2, C, h, w]
            ch, cw = coarse.shape[-2:]
            coarse_scale = H / ch
            _, scores, idx = m._coarse_matching(coarse, coarse_scale)           # idx [1, 2, N]
            n = idx.shape[-1]
            i_idx = torch.arange(n, device=idx.device)[None]
            j_idx = idx[:, 1].clamp(min=0)
            pair_idx = torch.stack([i_idx, j_idx], dim=1)                      # [1, 2, N]
            cw_t = torch.tensor(cw, device=idx.device)
            kp_coarse = torch.stack([pair_idx % cw_t, pair_idx // cw_t], dim=-1) * coarse_scale
            f0, f1 = m.refinement_layer(coarse / m.config.hidden_size ** 0.5, feats[1:])
            b = torch.arange(1, device=idx.device)[..., None]
            f0, f1 = f0[b, pair_idx[:, 0]], f1[b, pair_idx[:, 1]]
            fine_scale = H / int(ch * coarse_scale)
            kp = m._fine_matching(f0, f1, kp_coarse, fine_scale)                # [1, 2, N, 2] pixels
            s = scores[0, 1]
            s = torch.where(idx[0, 1] > -1, s, torch.zeros_like(s))
            return kp[0, 0], kp[0, 1], s

    return EfficientLoFTRPair().eval()


def keypoint_agreement(ref: list[np.ndarray], got: list[np.ndarray]) -> float:
    """Extractor outputs (kpts, kpt_scores, desc): fraction of keypoints found by both at the same pixel with
    descriptors of cosine >= 0.98 (over the larger of the two keypoint sets)."""
    def table(o):
        return {tuple(k): d for k, s, d in zip(np.round(o[0]).astype(int).tolist(), o[1], o[2]) if s > 0}

    r, g = table(ref), table(got)
    if not r and not g:
        return 1.0
    same = sum(1 for k in r.keys() & g.keys() if float(np.dot(r[k], g[k])) >= 0.98 * float(
        np.linalg.norm(r[k]) * np.linalg.norm(g[k]) + 1e-12))
    return same / max(len(r), len(g), 1)


def match_agreement(ref: list[np.ndarray], got: list[np.ndarray]) -> float:
    """Matcher outputs (matches0, scores): fraction of keypoints with the same match decision, over those
    matched by either."""
    r, g = np.asarray(ref[0]).reshape(-1), np.asarray(got[0]).reshape(-1)
    rows = (r >= 0) | (g >= 0)
    return float((r[rows] == g[rows]).mean()) if rows.any() else 1.0


def pair_agreement(ref: list[np.ndarray], got: list[np.ndarray]) -> float:
    """Pair outputs (kpts0, kpts1, scores): fraction of matched pairs found by both (to 0.5 px)."""
    def pairs(o):
        k = np.round(np.concatenate([o[0], o[1]], axis=1) * 2).astype(int)
        return {tuple(v) for v, s in zip(k.tolist(), np.asarray(o[2]).reshape(-1)) if s > 0}

    r, g = pairs(ref), pairs(got)
    if not r and not g:
        return 1.0
    return len(r & g) / max(len(r), len(g))


def _arch_for(source: str) -> str:
    if source.startswith("tiny"):
        from . import tiny

        return tiny.resolve("matcher", source)
    return "efficientloftr" if "loftr" in source.lower() else "superpoint-lightglue"


def _image_inputs(H: int, W: int):
    def image_inputs(rng: np.random.Generator, names=("image",)) -> dict[str, np.ndarray]:
        # a random image, and for pairs a shifted noisy copy of it: the pair has true matches to find
        base = rng.random((1, 3, H, W)).astype(np.float32)
        out = {names[0]: base}
        for n in names[1:]:
            dy, dx = (int(v) for v in rng.integers(-6, 7, size=2))
            shifted = np.roll(base, (dy, dx), axis=(2, 3)) + rng.normal(0, 0.02, base.shape)
            out[n] = np.clip(shifted, 0, 1).astype(np.float32)
        return out

    return image_inputs


def _calibration(frames: list[np.ndarray] | None, pre: dict[str, Any]):
    """calib(names) -> a GraphSpec calibration callable over the --calib frames (None without frames)."""
    def calib(names):
        if not frames:
            return None
        from mosaicthinker.runtime.models import preprocess_image

        return lambda: [{n: preprocess_image(frames[(i + j) % len(frames)], pre) for j, n in enumerate(names)}
                        for i in range(len(frames))]

    return calib


def _match_inputs(K: int, D: int, H: int, W: int):
    def match_inputs(rng: np.random.Generator) -> dict[str, np.ndarray]:
        # image 1 sees a shuffled, slightly moved and noisy copy of image 0's keypoints: real matches exist
        feeds = {}
        perm = rng.permutation(K)
        d0 = rng.standard_normal((K, D)).astype(np.float32)
        d1 = d0[perm] + 0.3 * rng.standard_normal((K, D)).astype(np.float32)
        k0 = (rng.random((K, 2)) * [W, H]).astype(np.float32)
        k1 = np.clip(k0[perm] + rng.normal(0, 2, (K, 2)) + [3, -2], 0, [W - 1, H - 1]).astype(np.float32)
        for i, (kk, d) in enumerate(((k0, d0), (k1, d1))):
            feeds[f"kpts{i}"] = kk
            feeds[f"desc{i}"] = d / np.linalg.norm(d, axis=1, keepdims=True)
            s = (0.05 + rng.random(K)).astype(np.float32)
            s[int(rng.integers(K // 2, K)):] = 0.0  # padded tail, as the extractor produces
            feeds[f"kpt_scores{i}"] = s
        return feeds

    return match_inputs


def _export_loftr(source: str, out: str | Path, precisions: Sequence[str], H: int, W: int, pre: dict[str, Any],
                  calib: Any) -> dict[str, Any]:
    import torch
    from transformers import EfficientLoFTRForKeypointMatching

    if H % 32 or W % 32:
        raise ExportError(f"EfficientLoFTR needs height/width multiples of 32, got {H}x{W}")
    model, prov = load_source(source, "matcher", EfficientLoFTRForKeypointMatching)
    pair = loftr_pair(model)
    image_inputs = _image_inputs(H, W)
    ex = image_inputs(np.random.default_rng(3), ("image0", "image1"))  # export example, not parity
    g = GraphSpec("pair", pair, (torch.from_numpy(ex["image0"]), torch.from_numpy(ex["image1"])),
                  ["image0", "image1"], ["kpts0", "kpts1", "scores"],
                  lambda rng: image_inputs(rng, ("image0", "image1")), quantize=False,
                  calibration=calib(("image0", "image1")), parity_outputs=[], agreement=pair_agreement)
    meta = C.role_meta("efficientloftr", preprocessing=pre, semantics={"contract": "pair"}, provenance=prov,
                       licence="Apache-2.0", random_weights=prov["random_weights"],
                       config={"min_score": 0.0, "coarse_matching_threshold":
                               float(model.config.coarse_matching_threshold)})
    # int8 disabled: argmax/mutual-NN over quantised similarities flips matches discretely, so an
    # element-wise parity figure would not mean anything; fp16 keeps the same discrete risk and is checked.
    return export_variants(out, "matcher", [g], meta, precisions)


def _export_lightglue(source: str, out: str | Path, precisions: Sequence[str], H: int, W: int,
                      pre: dict[str, Any], calib: Any, k: int | None, threshold: float) -> dict[str, Any]:
    import torch
    from transformers import LightGlueForKeypointMatching

    model, prov = load_source(source, "matcher", LightGlueForKeypointMatching)
    # static graph: no adaptive depth (early stop) nor width (point pruning)
    model.depth_confidence = -1.0
    model.width_confidence = -1.0
    sp = model.keypoint_detector
    K = int(k or (64 if source.startswith("tiny") else 1024))
    ext = superpoint_extractor(sp, K, threshold)
    mat = lightglue_matcher(model, H, W)
    image_inputs, match_inputs = _image_inputs(H, W), _match_inputs(K, int(sp.config.descriptor_decoder_dim), H, W)
    exm = match_inputs(np.random.default_rng(11))  # export examples, not parity
    names_m = ["kpts0", "kpts1", "desc0", "desc1", "kpt_scores0", "kpt_scores1"]
    graphs = [
        GraphSpec("extractor", ext, (torch.from_numpy(image_inputs(np.random.default_rng(2))["image"]),), ["image"],
                  ["kpts", "kpt_scores", "desc"], image_inputs, calibration=calib(("image",)),
                  parity_outputs=[], agreement=keypoint_agreement, meta={"k": K}),
        GraphSpec("matcher", mat, tuple(torch.from_numpy(exm[n]) for n in names_m), names_m, ["matches0", "scores"],
                  match_inputs, quantize=False, parity_outputs=[], agreement=match_agreement, meta={"k": K}),
    ]
    # SuperPoint's released weights are non-commercial (Magic Leap); LightGlue's are Apache-2.0
    licence = "Apache-2.0" if prov["random_weights"] else "LicenseRef-MagicLeap-SuperPoint-NonCommercial AND Apache-2.0"
    meta = C.role_meta("superpoint_lightglue", preprocessing=pre, semantics={"contract": "extractor+matcher"},
                       provenance=prov, licence=licence, random_weights=prov["random_weights"],
                       config={"k": K, "normalize_kpts": False, "keypoint_threshold": threshold, "min_score": 0.0})
    return export_variants(out, "matcher", graphs, meta, precisions)


def export_matcher(source: str, out: str | Path, precisions: Sequence[str], *, height: int | None = None,
                   width: int | None = None, k: int | None = None, threshold: float = 0.005,
                   calibration_frames: list[np.ndarray] | None = None, **_: Any) -> dict[str, Any]:
    """Add the matcher role to the bundle at `out` (SuperPoint+LightGlue or EfficientLoFTR by source)."""
    arch = _arch_for(source)
    tiny_src = source.startswith("tiny")
    H = int(height or (64 if tiny_src else 480))
    W = int(width or (96 if tiny_src else 640))
    pre = {"size": [H, W], "layout": "NCHW", "channel_order": "RGB", "dtype": "float32", "scale": 1 / 255,
           "resize": "bilinear", "keep_aspect": False}
    calib = _calibration(calibration_frames, pre)
    if arch == "efficientloftr":
        return _export_loftr(source, out, precisions, H, W, pre, calib)
    return _export_lightglue(source, out, precisions, H, W, pre, calib, k, threshold)


def export_role(role: str, source: str, precisions: Sequence[str], out: str | Path, *, calib: str | None = None,
                options: dict[str, str] | None = None, **_: Any) -> dict[str, Any]:
    """`mosaic export matcher --source hf:ID|dir:PATH|tiny[:ARCH]` (registered in export/cli.py)."""
    return run_exporter(export_matcher, source, precisions, out, calib=calib, options=options)
