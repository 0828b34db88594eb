"""The types the stages exchange, in one place so signatures name them: `Frame` (a source's frame), `Detections`
(one frame's objects, from any detector: bundle models, the synthetic oracle, tests), `Observation` (one
detection lifted to 3D) and `Matches` (two images' correspondences, from any matcher). No stage imports another
for its types."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ContextManager, Protocol, Sequence

import numpy as np


@dataclass
class Frame:
    """One frame. rgb: [H, W, 3] uint8; t: seconds; index: position in its source; depth: [H, W] float32 z-depth
    in metres (0 = invalid) or None; K: [3, 3] float64; pose_gt: [4, 4] float64 camera-to-world or None;
    dist: [k] OpenCV distortion coefficients or None (images are NOT undistorted)."""

    rgb: np.ndarray
    t: float
    index: int
    K: np.ndarray
    depth: np.ndarray | None = None
    pose_gt: np.ndarray | None = None
    dist: np.ndarray | None = None


@dataclass
class Detections:
    """Objects found in one frame.

    boxes: [N, 4] float32 x0, y0, x1, y1 pixels; scores: [N] float32 in [0, 1]; names: N object names (the
    question's vocabulary, not the model's label); masks: [N, H, W] bool or None; instance_ids: [N] int64 or None
    (only the synthetic oracle knows them); undetectable: names the backend cannot detect at all (reported, never
    silently treated as "absent"); mask_from: N words saying where each mask came from (the role that made it,
    e.g. "instance_segmenter", "segmenter", "box" for the box-prompted depth mask) or None.
    """

    boxes: np.ndarray
    scores: np.ndarray
    names: list[str]
    masks: np.ndarray | None = None
    instance_ids: np.ndarray | None = None
    undetectable: list[str] = field(default_factory=list)
    mask_from: list[str] | None = None

    def __post_init__(self) -> None:
        self.boxes = np.asarray(self.boxes, dtype=np.float32).reshape(-1, 4)
        self.scores = np.asarray(self.scores, dtype=np.float32).reshape(-1)
        if not (len(self.boxes) == len(self.scores) == len(self.names)):
            raise ValueError("Detections: boxes, scores and names must have the same length")

    def __len__(self) -> int:
        return len(self.names)

    @classmethod
    def empty(cls, undetectable: list[str] | None = None) -> "Detections":
        return cls(np.zeros((0, 4), np.float32), np.zeros(0, np.float32), [], undetectable=list(undetectable or []))

    def best_score(self, name: str) -> float:
        """Highest confidence for `name` in this frame (0 if not seen)."""
        s = [float(sc) for n, sc in zip(self.names, self.scores) if n == name]
        return max(s) if s else 0.0

    def select(self, keep: np.ndarray) -> "Detections":
        keep = np.asarray(keep)
        idx = np.flatnonzero(keep) if keep.dtype == bool else keep
        return Detections(self.boxes[idx], self.scores[idx], [self.names[i] for i in idx],
                          None if self.masks is None else self.masks[idx],
                          None if self.instance_ids is None else self.instance_ids[idx], list(self.undetectable),
                          None if self.mask_from is None else [self.mask_from[i] for i in idx])


@dataclass
class Observation:
    """One detection lifted to 3D. points: [N, 3] world (m); frame: key-frame index; t: seconds;
    instance_hint: id from an oracle (evaluation only) or None."""

    name: str
    score: float
    frame: int
    t: float
    points: np.ndarray
    box2d: np.ndarray
    instance_hint: int | None = None
    recovered: bool = False  # a view occlusion refinement re-prompted for one instance (not a detection)


class Budget(Protocol):
    """What the pipeline asks of a device budget (`budget.BudgetController`): the plan's K and scored frames as
    they stand, stage deadlines (an overrun re-plans the stages after it), the memory guard."""

    keyframes: int
    scored_frames: int
    reduced: bool
    reasons: list[str]
    budget_ms: float

    def stage(self, name: str) -> ContextManager[Any]: ...
    def start_stage(self, name: str) -> None: ...
    def end_stage(self, name: str) -> bool: ...
    def update_candidates(self, n: int) -> None: ...
    def allow_keyframes(self, k: int, held: int = 0) -> int: ...
    def check_headroom(self, mb_needed: float, what: str = "", keep: Sequence[str] = ()) -> bool: ...
    def remaining_ms(self) -> float: ...


@dataclass
class Matches:
    """Correspondences between two images. uv0, uv1: [M, 2] float32 pixels (x, y); scores: [M] float32 in
    [0, 1] (higher = more distinctive: 1 - ratio of best to second-best distance for ORB/SIFT)."""

    uv0: np.ndarray
    uv1: np.ndarray
    scores: np.ndarray

    def __post_init__(self) -> None:
        self.uv0 = np.asarray(self.uv0, dtype=np.float32).reshape(-1, 2)
        self.uv1 = np.asarray(self.uv1, dtype=np.float32).reshape(-1, 2)
        self.scores = np.asarray(self.scores, dtype=np.float32).reshape(-1)
        if not (len(self.uv0) == len(self.uv1) == len(self.scores)):
            raise ValueError("Matches: uv0, uv1 and scores must have the same length")

    def __len__(self) -> int:
        return len(self.scores)

    @classmethod
    def empty(cls) -> "Matches":
        return cls(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0))
