"""Oracle perception for synthetic scenes (evaluation only; the pipeline never imports `runtime.synth`).

Wraps the synthetic ground truth into the pipeline's `Perception`:
- detect: `synth.oracle.OracleDetector` (boxes, masks and instance ids from the rendered instance masks, with a
  configurable miss rate and score noise);
- segment_points: a prompt-driven segmenter for occlusion refinement — the instance under the point prompts
  (majority vote over the prompts that land on an object of the prompted name) -> that instance's visible mask;
  prompts that land on the room or on another category give nothing (as a real promptable segmenter would
  return the occluder, which the pipeline then rejects);
- depth: the source's sensor depth (the synthetic z-depth), so no depth callable is needed.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InputError


class OracleInstances:
    """Per-frame instance-id images `frame-XXXXXX.instances.png` ([H, W] uint16, 0 = room) and the id -> name
    table of `scene.json`, with a small cache."""

    def __init__(self, scene_dir: str | Path, cache: int = 64):
        from ..synth.generate import load_scene

        self.dir = Path(scene_dir)
        self.meta = load_scene(self.dir)
        self.names = {int(o["id"]): str(o["name"]) for o in self.meta["instances"]}
        self._cache: dict[int, np.ndarray] = {}
        self._cache_size = cache

    def ids(self, index: int) -> np.ndarray:
        import cv2

        if index not in self._cache:
            p = self.dir / f"frame-{int(index):06d}.instances.png"
            img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
            if img is None:
                raise InputError(f"{p}: instance mask missing or unreadable (oracle perception needs the "
                                 f"synthetic scene's instance masks)")
            if len(self._cache) >= self._cache_size:
                self._cache.pop(next(iter(self._cache)))
            self._cache[index] = img
        return self._cache[index]


class OraclePromptSegmenter:
    """segment_points(frame, points [P, 2] pixels, name) -> mask [H, W] bool of the prompted instance, or None."""

    def __init__(self, instances: OracleInstances, min_votes: float = 0.5):
        from ..grounding import canonical_name

        self.inst = instances
        self.min_votes = min_votes
        self._canon = canonical_name

    def __call__(self, frame: Any, points: np.ndarray, name: str) -> np.ndarray | None:
        ids = self.inst.ids(frame.index)
        H, W = ids.shape
        P = np.round(np.asarray(points, float).reshape(-1, 2)).astype(int)
        ok = (P[:, 0] >= 0) & (P[:, 0] < W) & (P[:, 1] >= 0) & (P[:, 1] < H)
        if not ok.any():
            return None
        hit = ids[P[ok, 1], P[ok, 0]].astype(int)
        want = self._canon(name) or name
        same = [h for h in hit if h > 0 and (self._canon(self.inst.names.get(h, "")) or "") == want]
        if not same:
            return None
        vals, counts = np.unique(same, return_counts=True)
        best = int(vals[np.argmax(counts)])
        if counts.max() < self.min_votes * len(hit):
            return None
        return ids == best


def oracle_perception(scene_dir: str | Path, miss_rate: float = 0.1, score_noise: float = 0.1, seed: int = 0,
                      matcher: Any = "sift", refine: bool = True) -> Any:
    """The pipeline's `Perception` over a synthetic scene's ground truth (see the module docstring)."""
    from ..pipeline import Perception
    from ..synth.oracle import OracleDetector

    det = OracleDetector(scene_dir, miss_rate=miss_rate, score_noise=score_noise, seed=seed)
    inst = OracleInstances(scene_dir)
    return Perception(detect=lambda frame, names: det.detect(frame.index, names), matcher=matcher,
                      segment_points=OraclePromptSegmenter(inst) if refine else None,
                      describe={"detector": f"oracle (miss_rate={miss_rate}, score_noise={score_noise}, seed={seed})",
                                "segmenter": "oracle masks (detections) + oracle prompt segmenter (refinement)",
                                "depth": "sensor (synthetic z-depth)"})
