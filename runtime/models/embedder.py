"""Frame embedder: rgb -> L2-normalised vector (frame similarity for dedup, key frames and the alignment tree).

Works for any single-graph image model whose first output is a feature map or vector (pooled CNN features,
CLIP/SigLIP vision towers). Quantised (uint8) outputs are de-quantised with config.output_scale/zero_point
when given; the cosine similarity is invariant to the scale, the zero point matters and is subtracted.
"""
from __future__ import annotations

import numpy as np

from . import RoleModel, preprocess_image


class Embedder(RoleModel):
    role = "embedder"

    def __init__(self, spec, sessions, trace):
        super().__init__(spec, sessions, trace)
        self._input = self.session().input_names[0]
        self.output_index = int(spec.config.get("output", 0))
        self.zero_point = float(spec.config.get("output_zero_point", 0.0))
        self.scale = float(spec.config.get("output_scale", 1.0))

    @property
    def dim(self) -> int:
        return int(self.spec.semantics.get("dim", 0))

    def embed(self, rgb: np.ndarray) -> np.ndarray:
        """rgb [H, W, 3] uint8 -> [D] float32 with unit L2 norm (all-zero features stay zero)."""
        with self._overhead("embedder"):
            return self._embed(rgb)

    def _embed(self, rgb: np.ndarray) -> np.ndarray:
        x = preprocess_image(rgb, self.spec.preprocessing)
        with self._stage("embedder"):
            out = self.session().run({self._input: x})[self.output_index]
        v = (np.asarray(out).reshape(-1).astype(np.float32) - self.zero_point) * self.scale
        n = float(np.linalg.norm(v))
        return (v / n).astype(np.float32) if n > 0 else v

    def embed_many(self, rgbs) -> np.ndarray:
        """list of rgb -> [N, D] float32."""
        return np.stack([self.embed(r) for r in rgbs]) if len(rgbs) else np.zeros((0, self.dim), np.float32)
