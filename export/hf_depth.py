"""Depth-Anything-V2 export (relative and metric-indoor).

Graph: `pixel_values [B, 3, S, S] float32` (ImageNet mean/std, RGB, S a multiple of 14) ->
`depth [B, S, S] float32`: relative inverse depth (disparity-like, larger = nearer) for the relative
checkpoints, metres for the metric ones (sigmoid * max_depth). The driver is export/hf_common.py.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

import numpy as np

from mosaicthinker.runtime.infra.errors import ExportError

from . import common as C
from .hf_common import IMAGENET_MEAN, IMAGENET_STD, GraphSpec, _image_calibration, export_variants, run_exporter
from .sources import load_source


HF_DEFAULTS = {"relative": "depth-anything/Depth-Anything-V2-Small-hf",
               "metric-indoor": "depth-anything/Depth-Anything-V2-Metric-Indoor-Small-hf"}


def depth_wrapper(model: Any):
    import torch

    class DepthAnythingGraph(torch.nn.Module):
        """pixel_values [B, 3, S, S] -> depth [B, S, S] (the DPT head's output at input resolution)."""

        def __init__(self, m: Any):
            super().__init__()
            self.m = m

        def forward(self, pixel_values):
            return self.m(pixel_values=pixel_values).predicted_depth

    return DepthAnythingGraph(model).eval()


def export_depth(source: str, out: str | Path, precisions: Sequence[str], *, size: int | None = None,
                 calibration_frames: list[np.ndarray] | None = None, **_: Any) -> dict[str, Any]:
    """Add the depth role (Depth-Anything-V2) to the bundle at `out`. size: input side (multiple of 14;
    default 518 for real checkpoints, the tiny config's 70 for tiny models)."""
    import torch
    from transformers import DepthAnythingForDepthEstimation

    model, prov = load_source(source, "depth", DepthAnythingForDepthEstimation)
    metric = model.config.depth_estimation_type == "metric"
    size = size or (70 if prov["random_weights"] else 518)
    if size % 14:
        raise ExportError(f"--size {size}: Depth-Anything-V2 needs a multiple of the patch size 14")
    w = depth_wrapper(model)
    B = torch.export.Dim("batch", min=1, max=16)

    def make_inputs(rng: np.random.Generator) -> dict[str, np.ndarray]:
        return {"pixel_values": rng.standard_normal((int(rng.integers(1, 4)), 3, size, size)).astype(np.float32)}

    pre = {"size": [size, size], "layout": "NCHW", "channel_order": "RGB", "dtype": "float32", "scale": 1 / 255,
           "mean": IMAGENET_MEAN, "std": IMAGENET_STD, "resize": "bilinear", "keep_aspect": False}
    g = GraphSpec("model", w, (torch.randn(2, 3, size, size),), ["pixel_values"], ["depth"], make_inputs,
                  dynamic_shapes={"pixel_values": {0: B}},
                  calibration=_image_calibration(calibration_frames, pre, "pixel_values"))
    arch = "depth-anything-v2-metric-indoor" if metric else "depth-anything-v2"
    sem = ({"depth": "metric_m", "max_depth_m": float(model.config.max_depth)} if metric
           else {"depth": "relative_inverse"})
    meta = C.role_meta(arch, preprocessing=pre, semantics=sem, provenance=prov, licence="Apache-2.0",
                       random_weights=prov["random_weights"],
                       config={"output": 0})
    return export_variants(out, "depth", [g], meta, precisions)


def export_role(role: str, source: str, precisions: Sequence[str], out: str | Path, *, calib: str | None = None,
                options: dict[str, str] | None = None, **_: Any) -> dict[str, Any]:
    """`mosaic export depth --source hf:ID|dir:PATH|tiny[:ARCH]` (registered in export/cli.py)."""
    return run_exporter(export_depth, source, precisions, out, calib=calib, options=options)
