"""Directions on the floor plane (z up): signed angles, their words at each granularity, turns, and the direction
of a point from a camera. Pure numpy."""
from __future__ import annotations

import math
from typing import Any

import numpy as np


def signed_angle_deg(facing: np.ndarray, target: np.ndarray) -> float:
    """Counter-clockwise angle (degrees, (-180, 180]) from 2D vector `facing [2]` to `target [2]` (z up:
    positive = to the left)."""
    f = np.asarray(facing, float)[:2]
    t = np.asarray(target, float)[:2]
    a = float(np.degrees(math.atan2(f[0] * t[1] - f[1] * t[0], f[0] * t[0] + f[1] * t[1])))
    return 180.0 if a <= -180.0 else a


def direction_label(theta_deg: float, level: str, back_deg: float = 135.0) -> str:
    """Direction word for a counter-clockwise angle `theta_deg` from the facing direction.

    level: 'easy' (left/right), 'medium' (left/right/back), 'hard' (front-left/front-right/back-left/back-right).
    """
    th = theta_deg % 360.0
    if level == "hard":
        return ("front-left", "back-left", "back-right", "front-right")[int(th // 90) % 4]
    if level == "medium":
        if back_deg <= th <= 360.0 - back_deg:
            return "back"
        return "left" if th < 180.0 else "right"
    if level == "easy":
        return "left" if 0.0 < th < 180.0 else "right"
    raise ValueError(f"direction level {level!r}: expected easy, medium or hard")


def turn_label(theta_deg: float, back_deg: float = 135.0) -> str:
    """'turn left' / 'turn right' / 'turn back' for a heading change of `theta_deg` (counter-clockwise +)."""
    if abs(theta_deg) >= back_deg:
        return "turn back"
    return "turn left" if theta_deg > 0 else "turn right"


def describe_direction(theta_deg: float, back_deg: float = 135.0) -> dict[str, Any]:
    """Every reading of a counter-clockwise angle from the facing direction: side (left/right), front_back,
    quadrant (front-left ...), medium (left/right/back), eight-way words and the angle."""
    side = direction_label(theta_deg, "easy")
    quad = direction_label(theta_deg, "hard")
    med = direction_label(theta_deg, "medium", back_deg)
    a = abs(((theta_deg + 180.0) % 360.0) - 180.0)
    fb = "front" if a < 90.0 else "back"
    if a <= 22.5:
        words = "straight ahead"
    elif a >= 157.5:
        words = "behind"
    elif 67.5 <= a <= 112.5:
        words = f"to the {side}"
    else:
        words = f"{'ahead' if fb == 'front' else 'behind'} and to the {side}"
    return {"side": side, "front_back": fb, "quadrant": quad, "medium": med, "words": words,
            "angle_deg": round(float(theta_deg), 1)}


def in_direction(d: dict[str, Any], asked: str) -> bool:
    """Whether a `describe_direction` reading is in the asked direction: its quadrant, front / back, or left /
    right (not straight ahead or behind)."""
    return asked in (d["quadrant"], d["front_back"]) or (asked == d["side"] and
                                                         d["words"] not in ("straight ahead", "behind"))


def describe_from_camera(T_wc: np.ndarray, point: np.ndarray, back_deg: float = 135.0) -> dict[str, Any]:
    """Direction of a world point `[3]` from a camera `T_wc [4, 4]` (OpenCV axes: x right, z forward), on the
    floor plane: `describe_direction` of the angle plus the horizontal distance (m)."""
    T = np.asarray(T_wc, float)
    fwd = T[:3, 2][:2]
    if np.linalg.norm(fwd) < 1e-6:  # looking straight down: the image's up direction is "forward"
        fwd = -T[:3, 1][:2]
    v = np.asarray(point, float)[:2] - T[:2, 3]
    d = describe_direction(signed_angle_deg(fwd, v), back_deg)
    d["distance_m"] = round(float(np.linalg.norm(v)), 3)
    return d
