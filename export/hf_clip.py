"""CLIP / SigLIP vision towers as frame embedders.

Graph: `pixel_values [B, 3, S, S] float32` -> `image_embedding [B, D] float32`, L2-normalised in the graph (CLIP: the
projected image embedding; SigLIP: the attention-pooled `pooler_output`). Runtime adapter: the generic
`embedder:Embedder` (H5) with `config.output = 0`.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

import numpy as np

from mosaicthinker.runtime.infra.errors import ExportError

from . import common as C
from .hf_common import CLIP_MEAN, CLIP_STD, GraphSpec, _image_calibration, export_variants, run_exporter
from .sources import load_source

HF_DEFAULTS = {"clip": "openai/clip-vit-base-patch32", "siglip": "google/siglip-base-patch16-224"}


def embed_wrapper(model: Any, kind: str):
    import torch

    class VisionEmbedding(torch.nn.Module):
        """pixel_values [B, 3, S, S] -> embedding [B, D], unit L2 norm."""

        def __init__(self, m: Any):
            super().__init__()
            self.m = m

        def forward(self, pixel_values):
            out = self.m(pixel_values=pixel_values)
            e = out.image_embeds if kind == "clip" else out.pooler_output
            return torch.nn.functional.normalize(e, dim=-1)

    return VisionEmbedding(model).eval()


def _vision_class(source: str):
    """The transformers class for a source (CLIP with projection vs SigLIP vision tower)."""
    import transformers

    if source.startswith("tiny"):
        from . import tiny

        arch = tiny.resolve("embedder", source)
        return arch, (transformers.CLIPVisionModelWithProjection if arch == "clip" else transformers.SiglipVisionModel)
    kind = "siglip" if "siglip" in source.lower() else "clip"
    return kind, (transformers.CLIPVisionModelWithProjection if kind == "clip" else transformers.SiglipVisionModel)


def export_embedder(source: str, out: str | Path, precisions: Sequence[str], *,
                    calibration_frames: list[np.ndarray] | None = None, **_: Any) -> dict[str, Any]:
    """Add the embedder role (CLIP or SigLIP vision tower) to the bundle at `out`."""
    import torch

    kind, cls = _vision_class(source)
    model, prov = load_source(source, "embedder", cls)
    cfg = model.config
    size = int(cfg.image_size)
    w = embed_wrapper(model, kind)
    with torch.no_grad():
        dim = int(w(torch.zeros(2, 3, size, size)).shape[-1])
    if kind == "clip":
        mean, std = CLIP_MEAN, CLIP_STD
    else:
        mean, std = [0.5, 0.5, 0.5], [0.5, 0.5, 0.5]
    pre = {"size": [size, size], "layout": "NCHW", "channel_order": "RGB", "dtype": "float32", "scale": 1 / 255,
           "mean": mean, "std": std, "resize": "bilinear", "keep_aspect": False}
    B = torch.export.Dim("batch", min=1, max=64)

    def make_inputs(rng: np.random.Generator) -> dict[str, np.ndarray]:
        return {"pixel_values": rng.standard_normal((int(rng.integers(1, 4)), 3, size, size)).astype(np.float32)}

    g = GraphSpec("model", w, (torch.randn(2, 3, size, size),), ["pixel_values"], ["image_embedding"], make_inputs,
                  dynamic_shapes={"pixel_values": {0: B}},
                  calibration=_image_calibration(calibration_frames, pre, "pixel_values"))
    if dim < 2:
        raise ExportError(f"{source}: embedding dimension {dim} is too small")
    licence = "MIT" if kind == "clip" else "Apache-2.0"
    meta = C.role_meta(kind, preprocessing=pre, semantics={"dim": dim, "normalised": True}, provenance=prov,
                       licence=licence, random_weights=prov["random_weights"], config={"output": 0})
    return export_variants(out, "embedder", [g], meta, precisions)


def export_role(role: str, source: str, precisions: Sequence[str], out: str | Path, *, calib: str | None = None,
                options: dict[str, str] | None = None, **_: Any) -> dict[str, Any]:
    """`mosaic export embedder --source hf:ID|dir:PATH|tiny[:ARCH]` (registered in export/cli.py)."""
    return run_exporter(export_embedder, source, precisions, out, calib=calib, options=options)
