"""Gravity and the floor: the world is z up with its origin on the floor below the root camera. Gravity comes from
the source (IMU, `gravity-direction.txt`) or from a floor-plane fit on the key frames' depth (the lowest large level
surface); the floor height from the same fit, else a documented camera-height prior."""
from __future__ import annotations

from typing import Sequence

import numpy as np

from ..infra.trace import StageLog, as_trace
from ..types import Frame
from ..planes import fit_floor_plane
from .lift import world_points


def gravity_world_transform(down_root: np.ndarray, floor_offset: float | None = None,
                            camera_height_m: float = 1.5) -> np.ndarray:
    """T [4, 4] from the root camera frame to the gravity-aligned world: z up, y = the root camera's viewing
    direction projected on the floor, x right, origin on the floor below the root camera.

    down_root: [3] gravity (down) in the root camera frame; floor_offset: d with down·p = d on the floor plane
    (distance of the floor below the root camera); when unknown, `camera_height_m` is used (a documented prior).
    """
    z = -np.asarray(down_root, float) / np.linalg.norm(down_root)
    fwd = np.array([0.0, 0.0, 1.0]) - z * z[2]  # camera z axis, horizontal part
    if np.linalg.norm(fwd) < 1e-6:  # looking straight down/up: use the camera's y axis instead
        fwd = np.array([0.0, -1.0, 0.0]) - z * (-z[1])
    y = fwd / np.linalg.norm(fwd)
    x = np.cross(y, z)
    R = np.stack([x, y, z])  # rows: world axes in root-camera coordinates -> R maps root cam to world
    h = camera_height_m if floor_offset is None else float(floor_offset)
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = np.array([0.0, 0.0, h])
    return T


def _floor_below_seen(P: np.ndarray, down: np.ndarray, offset: float, log: StageLog | None) -> float:
    """Nothing lies below the floor: when a share of the seen points does, the plane found is a table or counter
    top (the key frames did not see the floor); the floor is then at least as low as those points."""
    q = P @ down
    if np.mean(q > offset + 0.05) > 0.005:
        low = float(np.percentile(q, 99.8))
        log.event("degraded", f"floor fit found a plane {low - offset:.2f} m above points the key frames saw "
                    f"(a table or counter top; the floor itself was not seen): floor put at the lowest seen "
                    f"points instead (objects cannot be below it; the floor height is a lower bound)",
                    stage="gravity", plane_m=offset, floor_m=low)
        return low
    return offset


def gravity_from_frames(frames: Sequence[Frame], poses_root: dict[int, np.ndarray], source_down: np.ndarray | None,
                        camera_height_m: float, floor_fit_max_depth_m: float, log: StageLog | None) -> np.ndarray:
    """World-from-root transform [4, 4] (z up, origin on the floor below the root camera). `source_down`: the
    source's gravity in the root camera (None: the floor fit on the key frames' depth points nearer than
    `floor_fit_max_depth_m` gives it); the floor height from the same fit, else `camera_height_m` (recorded)."""
    log = as_trace(log)
    down, offset, how = None, None, ""
    if source_down is not None:
        down, how = np.asarray(source_down, float) / np.linalg.norm(source_down), "source"
    pts = world_points(frames, poses_root, 8, lambda p: p[:, 2] < floor_fit_max_depth_m)
    P = np.concatenate(pts) if pts else np.zeros((0, 3))
    hint = down if down is not None else np.array([0.0, 1.0, 0.0])
    fit = fit_floor_plane(P, hint, max_tilt_deg=15.0 if down is not None else 35.0)
    if down is None and fit is not None:
        down, how = fit[0], "floor_fit"
    if fit is not None:
        offset = float(down @ (fit[0] * fit[1]))  # floor distance below the root camera along `down`
        if offset <= 0.3:
            offset = None
    if offset is not None and len(P):
        offset = _floor_below_seen(P, down, offset, log)
    if down is None:
        down, how = np.array([0.0, 1.0, 0.0]), "camera_axes"
        log.event("degraded", "no gravity from the source and no floor found: assuming the root camera is level",
                    stage="gravity")
    if offset is None:
        log.event("degraded", f"floor height unknown: assuming the root camera is {camera_height_m} m above "
                    f"the floor", stage="gravity")
    log.decide("gravity", {"method": how, "down_root": down.tolist(), "floor_below_root_m": offset})
    return gravity_world_transform(down, offset, camera_height_m)
