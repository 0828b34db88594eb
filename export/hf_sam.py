"""SAM / SlimSAM export: an image-encoder graph (once per frame) and a prompt-decoder graph (per prompt batch).

Components (runtime adapter: runtime/models/sam.py):
- encoder: `pixel_values [B, 3, S, S] float32` (longest side resized to S, zero-padded bottom/right, ImageNet
  mean/std on 0..255 pixels) -> `image_embeddings [B, C, S/16, S/16] float32`.
- decoder: `image_embeddings [1, C, h, w]`, `point_coords [P, N, 2] float32` (x, y pixels in the S x S model
  input), `point_labels [P, N] float32` (1 foreground, 0 background, 2 box top-left, 3 box bottom-right,
  -1 padding) -> `masks [P, 3, 4h, 4w] float32` low-resolution mask logits (SAM's three multimask outputs),
  `iou_scores [P, 3] float32`. P prompts and N points per prompt are dynamic. Boxes are two labelled corner
  points, as in the original SAM ONNX export, so one graph serves points, boxes and both.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

import numpy as np

from . import common as C
from .hf_common import IMAGENET_MEAN, IMAGENET_STD, GraphSpec, export_variants, run_exporter
from .sources import load_source

HF_DEFAULTS = {"sam": "facebook/sam-vit-base", "slimsam": "nielsr/slimsam-50-uniform"}


def encoder_wrapper(model: Any):
    import torch

    class SamEncoder(torch.nn.Module):
        def __init__(self, m: Any):
            super().__init__()
            self.enc = m.vision_encoder

        def forward(self, pixel_values):
            return self.enc(pixel_values).last_hidden_state

    return SamEncoder(model).eval()


def decoder_wrapper(model: Any):
    import torch

    class SamPromptDecoder(torch.nn.Module):
        """Prompt encoder (points with labels 0..3) + two-way mask decoder, multimask output."""

        def __init__(self, m: Any):
            super().__init__()
            pe = m.prompt_encoder
            self.shared = m.shared_image_embedding
            self.point_embed = torch.nn.ModuleList(pe.point_embed)
            self.not_a_point = pe.not_a_point_embed
            self.no_mask = pe.no_mask_embed
            self.mask_decoder = m.mask_decoder
            self.input_size = int(pe.input_image_size)
            self.register_buffer("image_pe", m.get_image_wide_positional_embeddings().detach().clone(),
                                 persistent=False)

        def forward(self, image_embeddings, point_coords, point_labels):
            coords = (point_coords + 0.5) / self.input_size
            emb = self.shared(coords[None])                                    # [1, P, N, C]
            lab = point_labels[None, :, :, None]
            emb = torch.where(lab == -1, self.not_a_point.weight, emb)
            for i in range(4):
                emb = emb + (lab == i).to(emb.dtype) * self.point_embed[i].weight
            h, w = image_embeddings.shape[-2:]
            dense = self.no_mask.weight.reshape(1, -1, 1, 1).expand(1, -1, h, w)
            masks, iou = self.mask_decoder(image_embeddings, self.image_pe, emb, dense, multimask_output=True)[:2]
            return masks[0], iou[0]

    return SamPromptDecoder(model).eval()


def export_segmenter(source: str, out: str | Path, precisions: Sequence[str], *,
                     calibration_frames: list[np.ndarray] | None = None, **_: Any) -> dict[str, Any]:
    """Add the segmenter role (SAM or SlimSAM, encoder + prompt decoder) to the bundle at `out`."""
    import torch
    from transformers import SamModel

    model, prov = load_source(source, "segmenter", SamModel)
    arch = "slimsam" if ("slimsam" in source.lower()) else "sam"
    S = int(model.config.vision_config.image_size)
    C_ = int(model.config.vision_config.output_channels)
    hw = S // int(model.config.vision_config.patch_size)
    enc, dec = encoder_wrapper(model), decoder_wrapper(model)
    with torch.no_grad():
        emb_scale = float(enc(torch.randn(1, 3, S, S)).std())
    Bd = torch.export.Dim("batch", min=1, max=8)
    Pd = torch.export.Dim("prompts", min=1, max=256)
    Nd = torch.export.Dim("points", min=1, max=16)

    def enc_inputs(rng: np.random.Generator) -> dict[str, np.ndarray]:
        return {"pixel_values": rng.standard_normal((int(rng.integers(1, 3)), 3, S, S)).astype(np.float32)}

    def dec_inputs(rng: np.random.Generator) -> dict[str, np.ndarray]:
        p, n = int(rng.integers(1, 5)), int(rng.integers(1, 5))
        lab = rng.integers(-1, 4, size=(p, n)).astype(np.float32)
        lab[:, 0] = 1.0  # at least one real point per prompt
        return {"image_embeddings": (emb_scale * rng.standard_normal((1, C_, hw, hw))).astype(np.float32),
                "point_coords": (rng.random((p, n, 2)) * S).astype(np.float32), "point_labels": lab}

    ex_emb = emb_scale * np.random.default_rng(4).standard_normal((1, C_, hw, hw))
    ex_dec = {"image_embeddings": ex_emb.astype(np.float32),
              "point_coords": (np.random.default_rng(5).random((3, 2, 2)) * S).astype(np.float32),
              "point_labels": np.array([[1, 0], [2, 3], [1, -1]], np.float32)}
    pre = {"size": [S, S], "layout": "NCHW", "channel_order": "RGB", "dtype": "float32", "scale": 1.0,
           "mean": [m * 255 for m in IMAGENET_MEAN], "std": [s * 255 for s in IMAGENET_STD],
           "resize": "longest_side_pad", "keep_aspect": True}

    def calib():
        from mosaicthinker.runtime.models.sam import sam_preprocess

        return [{"pixel_values": sam_preprocess(f, S)[0]} for f in calibration_frames]

    graphs = [
        GraphSpec("encoder", enc, (torch.randn(2, 3, S, S),), ["pixel_values"], ["image_embeddings"], enc_inputs,
                  dynamic_shapes={"pixel_values": {0: Bd}}, calibration=calib if calibration_frames else None),
        GraphSpec("decoder", dec, tuple(torch.from_numpy(ex_dec[k]) for k in ("image_embeddings", "point_coords",
                                                                             "point_labels")),
                  ["image_embeddings", "point_coords", "point_labels"], ["masks", "iou_scores"], dec_inputs,
                  dynamic_shapes={"image_embeddings": None, "point_coords": {0: Pd, 1: Nd},
                                  "point_labels": {0: Pd, 1: Nd}}),
    ]
    meta = C.role_meta(arch, preprocessing=pre, semantics={"kind": "promptable", "multimask": 3},
                       provenance=prov, licence="Apache-2.0", random_weights=prov["random_weights"],
                       config={"input_size": S, "mask_threshold": 0.0, "embedding_size": [hw, hw]})
    return export_variants(out, "segmenter", graphs, meta, precisions)


def export_role(role: str, source: str, precisions: Sequence[str], out: str | Path, *, calib: str | None = None,
                options: dict[str, str] | None = None, **_: Any) -> dict[str, Any]:
    """`mosaic export segmenter --source hf:ID|dir:PATH|tiny[:ARCH]` (registered in export/cli.py)."""
    return run_exporter(export_segmenter, source, precisions, out, calib=calib, options=options)
