"""Oracle perception for synthetic scenes (evaluation only; the pipeline never imports `host.synth`).

Wraps the synthetic ground truth into the pipeline's `Perception`:
- detect: `synth.oracle.OracleDetector` (boxes, masks and instance ids from the rendered instance masks, with a
  configurable miss rate and score noise);
- segment_points: a prompt-driven segmenter for occlusion refinement (`OraclePromptSegmenter`) — the instance
  under the point prompts (majority over the prompts that land on an object of the prompted category) -> that
  instance's visible mask; prompts that land on the room or on another category give nothing;
- depth: the source's sensor depth (the synthetic z-depth), so no depth callable is needed.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np


class OraclePromptSegmenter:
    """segment_points(frame, points [P, 2] pixels, name) -> mask [H, W] bool of the prompted instance, or None.

    detector: the scene's `OracleDetector` (its instance masks and id -> category table are used)."""

    def __init__(self, detector: Any, min_votes: float = 0.5, cache: int = 16):
        from mosaicthinker.runtime.grounding import canonical_name

        self.det = detector
        self.min_votes = min_votes
        self._canon = canonical_name
        self.names = {int(o["id"]): str(o["name"]) for o in detector.meta["instances"]}
        self._cache: dict[int, np.ndarray] = {}
        self._cache_size = cache

    def _ids(self, index: int) -> np.ndarray:
        if index not in self._cache:
            if len(self._cache) >= self._cache_size:
                self._cache.pop(next(iter(self._cache)))
            self._cache[index] = self.det.instance_mask(index)
        return self._cache[index]

    def __call__(self, frame: Any, points: np.ndarray, name: str) -> np.ndarray | None:
        ids = self._ids(int(frame.index))
        H, W = ids.shape
        P = np.round(np.asarray(points, float).reshape(-1, 2)).astype(int)
        ok = (P[:, 0] >= 0) & (P[:, 0] < W) & (P[:, 1] >= 0) & (P[:, 1] < H)
        if not ok.any():
            return None
        hit = ids[P[ok, 1], P[ok, 0]].astype(int)
        want = self._canon(name) or name
        same = [h for h in hit if h > 0 and (self._canon(self.names.get(h, "")) or "") == want]
        if not same:
            return None
        vals, counts = np.unique(same, return_counts=True)
        if counts.max() < self.min_votes * len(hit):
            return None
        return ids == int(vals[np.argmax(counts)])


def oracle_perception(scene_dir: str | Path, miss_rate: float = 0.1, score_noise: float = 0.1, seed: int = 0,
                      matcher: Any = "sift", refine: bool = True) -> Any:
    """The pipeline's `Perception` over a synthetic scene's ground truth (see the module docstring)."""
    from mosaicthinker.runtime.pipeline import Perception
    from mosaicthinker.host.synth.oracle import OracleDetector

    det = OracleDetector(scene_dir, miss_rate=miss_rate, score_noise=score_noise, seed=seed)
    return Perception(detect=lambda frame, names: det.detect(frame.index, names), matcher=matcher,
                      segment_points=OraclePromptSegmenter(det) if refine else None,
                      describe={"detector": f"oracle (miss_rate={miss_rate}, score_noise={score_noise}, seed={seed})",
                                "segmenter": "oracle masks (detections) + oracle prompt segmenter (refinement)",
                                "depth": "sensor (synthetic z-depth)", "matcher": str(matcher)})
