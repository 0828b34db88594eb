"""Oracle perception for synthetic scenes: detections from the rendered instance masks, with controlled errors.

`OracleDetector(scene_dir, miss_rate=0.1, score_noise=0.1, seed=0).detect(frame_index, names) -> Detections`
returns, for every instance whose category matches one of `names` (through the grounding vocabulary) and has at
least `min_pixels` visible pixels in the frame: its mask, the mask's bounding box, a score 1 - |e| (e ~ N(0,
score_noise), clipped to [0.05, 1]) and its instance id; each such instance is missed with probability `miss_rate`.
Errors are drawn from (seed, frame, instance), so asking again gives the same answer, whatever the order of calls.
This measures the key-frame search and the pipeline apart from detector quality.
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from mosaicthinker.runtime.infra.errors import InputError
from mosaicthinker.runtime.types import Detections
from mosaicthinker.host.synth.generate import load_scene


class OracleDetector:
    """Detections from a generated scene folder (`mosaic synth`). scene_dir: the folder with scene.json and the
    frame-XXXXXX.instances.png masks."""

    def __init__(self, scene_dir: str | os.PathLike, miss_rate: float = 0.1, score_noise: float = 0.1, seed: int = 0,
                 min_pixels: int | None = None):
        if not 0.0 <= miss_rate <= 1.0:
            raise InputError(f"oracle detector: miss_rate must be in [0, 1], got {miss_rate}")
        if score_noise < 0:
            raise InputError(f"oracle detector: score_noise must be >= 0, got {score_noise}")
        self.root = Path(scene_dir)
        self.meta = load_scene(self.root)
        self.miss_rate, self.score_noise, self.seed = float(miss_rate), float(score_noise), int(seed)
        cam = self.meta["camera"]
        self.size = (int(cam["width"]), int(cam["height"]))
        self.n_frames = int(cam["frames"])
        # default: the scene's own "seen" threshold (0.1% of the image, at least 10 pixels)
        self.min_pixels = int(self.meta.get("seen_min_pixels", 10) if min_pixels is None else min_pixels)
        from mosaicthinker.runtime.grounding import canonical_name

        self._canon = canonical_name
        self.names = {int(o["id"]): o["name"] for o in self.meta["instances"]}
        self._key = {i: (canonical_name(n) or n.lower()) for i, n in self.names.items()}

    def __len__(self) -> int:
        return self.n_frames

    def instance_mask(self, frame_index: int) -> np.ndarray:
        """[H, W] uint16 instance ids of a frame (0 = room)."""
        import cv2

        if not 0 <= int(frame_index) < self.n_frames:
            raise IndexError(f"{self.root}: frame {frame_index} out of range (0..{self.n_frames - 1})")
        p = self.root / f"frame-{int(frame_index):06d}.instances.png"
        from mosaicthinker.runtime.frames import imread_path

        m = imread_path(p, cv2.IMREAD_UNCHANGED, "instance mask")
        if m is None or m.ndim != 2:
            raise InputError(f"{p}: missing or not a single-channel instance mask")
        return m

    def detect(self, frame_index: int, names: list[str]) -> Detections:
        """Detections of the `names` categories in frame `frame_index` (boxes [N, 4] x0, y0, x1, y1 pixels, with
        x1/y1 exclusive; masks [N, H, W] bool; instance_ids [N])."""
        want: dict[str, list[str]] = {}
        for n in names:
            want.setdefault(self._canon(n) or n.strip().lower(), []).append(n)
        m = self.instance_mask(frame_index)
        ids, counts = np.unique(m, return_counts=True)
        boxes, scores, out_names, masks, inst = [], [], [], [], []
        for k, c in zip(ids.tolist(), counts.tolist()):
            if k == 0 or c < self.min_pixels or k not in self._key or self._key[k] not in want:
                continue
            rng = np.random.default_rng([self.seed, int(frame_index), int(k)])
            if rng.random() < self.miss_rate:
                continue
            score = float(np.clip(1.0 - abs(rng.normal(0.0, self.score_noise)) if self.score_noise > 0 else 1.0,
                                  0.05, 1.0))
            mk = m == k
            ys, xs = np.nonzero(mk)
            for n in want[self._key[k]]:
                boxes.append([xs.min(), ys.min(), xs.max() + 1, ys.max() + 1])
                scores.append(score)
                out_names.append(n)
                masks.append(mk)
                inst.append(k)
        if not out_names:
            d = Detections.empty()
            d.masks = np.zeros((0, self.size[1], self.size[0]), bool)
            d.instance_ids = np.zeros(0, np.int64)
            return d
        return Detections(np.array(boxes, np.float32), np.array(scores, np.float32), out_names, np.stack(masks),
                          np.array(inst, np.int64))
