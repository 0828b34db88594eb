"""Procedural indoor rooms: a textured box room and furniture built from textured primitives, drawn from real
VSI-Bench statistics (`stats.py`) and placed without overlaps.

World frame: z up, metres, floor at z = 0, room centred on the origin (x in [-Lx/2, Lx/2], y in [-Ly/2, Ly/2]).
Every object is a composite of boxes and cylinders that exactly fills its oriented box (the ground truth), so the
box in `scene.json` is tight around what is rendered.

What comes from the data and what is a prior (documented, not tuned):
- from `vsibench_stats.json` (ARKitScenes part of VSI-Bench): which categories a room holds (each category present
  with its share of rooms, count from its per-room histogram, redrawn until the total lies in the object level's
  range), every object's dimensions (log-normal fit per category, within the observed min/max), the floor area
  (empirical distribution restricted to the room level's range);
- priors: room aspect ratio U(1, 1.6), ceiling height U(2.5, 2.9) m, the furniture's internal design, which objects
  stand against walls, the tv mounted on a wall, a cooktop (`stove`, 1-23 cm high in the data) standing on a
  counter (`cabinet`), and the extra categories the ARKitScenes part lacks (door, lamp, plant, cabinet, shelf,
  sink) with catalogue-like size ranges (`EXTRA_DIMS`). Extras can be switched off (`extras=False`); they do not
  count towards the object level.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from mosaicthinker.runtime.infra.errors import InputError
from mosaicthinker.runtime.geometry import OrientedBox
from mosaicthinker.host.synth.stats import load_stats, sample_count, sample_dims, sample_quantiles

# ----------------------------------------------------------------------------- configuration

DURATION_LEVELS = {"short": 30.0, "medium": 60.0, "long": 120.0}


@dataclass
class SceneConfig:
    """Knobs of one synthetic scene (the paper's complexity factors: object number, spatial scale, duration)."""

    seed: int = 0
    objects: str = "med"  # low | med | high: terciles of VSI-Bench per-room object counts
    room: str = "medium"  # small | medium | large: terciles of VSI-Bench room areas
    duration: float = 60.0  # seconds of video
    fps: float = 15.0
    width: int = 640
    height: int = 480
    hfov_deg: float = 60.0
    extras: bool = True  # door, lamp, plant, cabinet, shelf, sink (priors, not counted in the object level)
    eye_height: float = 1.5  # camera height (m), +-0.05 per scene
    noise_sigma: float = 2.0  # RGB sensor noise (grey levels)
    stats_path: str | None = None  # statistics JSON or a meta_info.json (default: the checked-in statistics)
    room_dims: tuple[float, float] | None = None  # (Lx, Ly) metres instead of a drawn floor area (a corridor)
    vsibench_objects: bool = True  # False: no objects drawn from the statistics, the extras only (a corridor)

    def validate(self) -> None:
        stats_levels = ("low", "med", "high")
        if self.objects not in stats_levels:
            raise InputError(f"`SceneConfig.objects` must be one of {stats_levels}, got {self.objects!r}",
                             fields=("SceneConfig.objects",))
        if self.room not in ("small", "medium", "large"):
            raise InputError(f"`SceneConfig.room` must be small, medium or large, got {self.room!r}",
                             fields=("SceneConfig.room",))
        if not (self.duration > 0 and self.fps > 0):
            raise InputError(f"`SceneConfig.duration` and `SceneConfig.fps` must be positive (got {self.duration}, "
                             f"{self.fps})", fields=("SceneConfig.duration", "SceneConfig.fps"))
        if self.width < 32 or self.height < 24:
            raise InputError(f"`SceneConfig.size` must be at least 32x24, got {self.width}x{self.height}",
                             fields=("SceneConfig.size",))
        if self.room_dims is not None and min(self.room_dims) < 1.5:
            raise InputError(f"room_dims must be at least 1.5 m each way, got {self.room_dims}")


# ----------------------------------------------------------------------------- primitives


@dataclass
class Prim:
    """A textured solid in an object's local frame (x along the object's width, y towards its front, z up, origin
    at the bottom centre). kind: 'box' | 'cyl' (elliptic prism, axis `axis`); lo, hi: [3] local extents."""

    kind: str
    lo: np.ndarray
    hi: np.ndarray
    mat: str
    color: tuple[float, float, float]
    axis: str = "z"
    sides: int = 12


def _bx(x0, x1, y0, y1, z0, z1, mat, col) -> Prim:
    return Prim("box", np.array([x0, y0, z0], float), np.array([x1, y1, z1], float), mat, tuple(col))


def _cy(x0, x1, y0, y1, z0, z1, mat, col, axis="z", sides=12) -> Prim:
    return Prim("cyl", np.array([x0, y0, z0], float), np.array([x1, y1, z1], float), mat, tuple(col), axis, sides)


PALETTE = {
    "wood": [(0.55, 0.38, 0.22), (0.70, 0.52, 0.33), (0.40, 0.26, 0.16), (0.80, 0.66, 0.46)],
    "fabric": [(0.35, 0.42, 0.58), (0.62, 0.30, 0.28), (0.45, 0.55, 0.40), (0.72, 0.68, 0.60), (0.35, 0.35, 0.38)],
    "metal": [(0.85, 0.86, 0.88), (0.70, 0.72, 0.75), (0.92, 0.92, 0.90)],
    "ceramic": [(0.95, 0.95, 0.93)],
    "dark": [(0.12, 0.12, 0.13)],
    "paint": [(0.90, 0.88, 0.82), (0.75, 0.80, 0.85), (0.82, 0.75, 0.65), (0.60, 0.65, 0.55)],
}


def _pick(rng: np.random.Generator, key: str) -> tuple[float, float, float]:
    p = PALETTE[key]
    return p[int(rng.integers(len(p)))]


# --- furniture designs: (W along x, D along y with the front at +y, H) -> primitives that fill
#     [-W/2, W/2] x [-D/2, D/2] x [0, H]

def _table(W, D, H, rng):
    wood = _pick(rng, "wood")
    t = min(0.04, 0.15 * H)
    lg = max(0.02, min(0.06, 0.1 * W, 0.1 * D))
    p = [_bx(-W / 2, W / 2, -D / 2, D / 2, H - t, H, "wood", wood)]
    for sx in (-1, 1):
        for sy in (-1, 1):
            x = sx * (W / 2 - 0.03 - lg / 2)
            y = sy * (D / 2 - 0.03 - lg / 2)
            p.append(_bx(x - lg / 2, x + lg / 2, y - lg / 2, y + lg / 2, 0, H - t, "wood", wood))
    return p


def _chair(W, D, H, rng):
    wood, fab = _pick(rng, "wood"), _pick(rng, "fabric")
    hs = float(np.clip(0.5 * H, 0.25, 0.55))
    lg = 0.04
    p = [_bx(-W / 2, W / 2, -D / 2, D / 2, hs - 0.05, hs, "fabric", fab),
         _bx(-W / 2, W / 2, -D / 2, -D / 2 + 0.06, hs, H, "wood", wood)]
    for sx in (-1, 1):
        for sy in (-1, 1):
            x, y = sx * (W / 2 - lg / 2), sy * (D / 2 - lg / 2)
            p.append(_bx(x - lg / 2, x + lg / 2, y - lg / 2, y + lg / 2, 0, hs - 0.05, "wood", wood))
    return p


def _stool(W, D, H, rng):
    wood, fab = _pick(rng, "wood"), _pick(rng, "fabric")
    p = [_cy(-W / 2, W / 2, -D / 2, D / 2, H - min(0.06, 0.3 * H), H, "fabric", fab, sides=14)]
    lg = 0.035
    for a in (0.25, 0.75, 1.25, 1.75):
        x, y = 0.62 * W / 2 * math.cos(a * math.pi), 0.62 * D / 2 * math.sin(a * math.pi)
        p.append(_bx(x - lg / 2, x + lg / 2, y - lg / 2, y + lg / 2, 0, H - min(0.06, 0.3 * H), "wood", wood))
    return p


def _sofa(W, D, H, rng):
    fab = _pick(rng, "fabric")
    cush = tuple(min(1.0, c * 1.15) for c in fab)
    aw = min(0.2, 0.12 * W)
    bk = min(0.3, 0.25 * D)
    hb = 0.42 * H
    p = [_bx(-W / 2 + aw, W / 2 - aw, -D / 2 + bk, D / 2, 0, hb, "fabric", fab),
         _bx(-W / 2, W / 2, -D / 2, -D / 2 + bk, 0, H, "fabric", fab),
         _bx(-W / 2, -W / 2 + aw, -D / 2 + bk, D / 2, 0, 0.68 * H, "fabric", fab),
         _bx(W / 2 - aw, W / 2, -D / 2 + bk, D / 2, 0, 0.68 * H, "fabric", fab)]
    n = 3 if W > 1.8 else 2
    xs = np.linspace(-W / 2 + aw, W / 2 - aw, n + 1)
    for i in range(n):
        p.append(_bx(xs[i] + 0.01, xs[i + 1] - 0.01, -D / 2 + bk + 0.01, D / 2 - 0.02, hb, min(hb + 0.12, 0.66 * H),
                     "fabric", cush))
    return p


def _bed(W, D, H, rng):
    """W = width, D = length (head at -y against the wall)."""
    wood, fab = _pick(rng, "wood"), _pick(rng, "fabric")
    hm = min(H, 0.6)
    hf = 0.4 * hm
    p = [_bx(-W / 2, W / 2, -D / 2 + 0.06, D / 2, 0, hf, "wood", wood),
         _bx(-W / 2, W / 2, -D / 2, -D / 2 + 0.06, 0, H, "wood", wood),
         _bx(-W / 2 + 0.03, W / 2 - 0.03, -D / 2 + 0.06, D / 2 - 0.03, hf, hm - 0.03, "fabric", (0.93, 0.93, 0.9)),
         _bx(-W / 2 + 0.02, W / 2 - 0.02, -D / 2 + 0.45 * D, D / 2 - 0.02, hm - 0.03, hm, "fabric", fab)]
    top = min(H, hm + 0.12)
    if top > hm - 0.03 + 0.02:
        n = 2 if W > 1.1 else 1
        xs = np.linspace(-W / 2 + 0.08, W / 2 - 0.08, n + 1)
        for i in range(n):
            p.append(_bx(xs[i] + 0.03, xs[i + 1] - 0.03, -D / 2 + 0.1, -D / 2 + 0.45, hm - 0.03, top, "fabric",
                         (0.97, 0.96, 0.92)))
    return p


def _tv(W, D, H, rng):
    s = min(0.005, D / 4)
    return [_bx(-W / 2, W / 2, -D / 2, D / 2 - s, 0, H, "dark", (0.15, 0.15, 0.16)),
            _bx(-W / 2 + 0.02, W / 2 - 0.02, D / 2 - s, D / 2, 0.02, H - 0.02, "screen", (1, 1, 1))]


def _fridge(W, D, H, rng):
    m = _pick(rng, "metal")
    f = min(0.04, D / 5)
    return [_bx(-W / 2, W / 2, -D / 2, D / 2 - f, 0, H, "metal", m),
            _bx(-W / 2 + 0.01, W / 2 - 0.01, D / 2 - f, D / 2 - f / 2, 0.02, 0.62 * H, "metal", m),
            _bx(-W / 2 + 0.01, W / 2 - 0.01, D / 2 - f, D / 2 - f / 2, 0.63 * H, H - 0.02, "metal", m),
            _bx(W / 2 - 0.09, W / 2 - 0.06, D / 2 - f / 2, D / 2, 0.35 * H, 0.55 * H, "dark", (0.2, 0.2, 0.2)),
            _bx(W / 2 - 0.09, W / 2 - 0.06, D / 2 - f / 2, D / 2, 0.66 * H, 0.8 * H, "dark", (0.2, 0.2, 0.2))]


def _washer(W, D, H, rng):
    m = _pick(rng, "metal")
    f = min(0.04, D / 5)
    r = 0.36 * min(W, H)
    zc = 0.45 * H
    return [_bx(-W / 2, W / 2, -D / 2, D / 2 - f, 0, H, "metal", m),
            _bx(-W / 2 + 0.02, W / 2 - 0.02, D / 2 - f, D / 2 - f / 2, 0.84 * H, 0.96 * H, "dark", (0.3, 0.3, 0.32)),
            _cy(-r, r, D / 2 - f, D / 2, zc - r, zc + r, "dark", (0.25, 0.27, 0.3), axis="y", sides=16)]


def _dishwasher(W, D, H, rng):
    m = _pick(rng, "metal")
    f = min(0.03, D / 5)
    return [_bx(-W / 2, W / 2, -D / 2, D / 2 - f, 0, H, "metal", m),
            _bx(-W / 2 + 0.01, W / 2 - 0.01, D / 2 - f, D / 2 - f / 2, 0.05, H - 0.12, "metal", m),
            _bx(-W / 2 + 0.01, W / 2 - 0.01, D / 2 - f, D / 2 - f / 2, H - 0.11, H - 0.01, "dark", (0.2, 0.2, 0.22)),
            _bx(-0.3 * W, 0.3 * W, D / 2 - f / 2, D / 2, H - 0.2, H - 0.16, "dark", (0.3, 0.3, 0.3))]


def _stove(W, D, H, rng):
    b = min(0.005, H / 3)
    p = [_bx(-W / 2, W / 2, -D / 2, D / 2, 0, H - b, "dark", (0.1, 0.1, 0.11))]
    r = 0.11 * min(W, D)
    for sx in (-1, 1):
        for sy in (-1, 1):
            x, y = sx * W / 4, sy * D / 4
            p.append(_cy(x - r, x + r, y - r, y + r, H - b, H, "metal", (0.45, 0.45, 0.47), sides=12))
    return p


def _toilet(W, D, H, rng):
    """W = width, D = depth (tank at -y against the wall)."""
    c = (0.96, 0.96, 0.95)
    tk = 0.22 * D
    return [_bx(-W / 2, W / 2, -D / 2, -D / 2 + tk, 0.45 * H, H, "ceramic", c),
            _bx(-0.22 * W, 0.22 * W, -D / 2 + tk, D / 2 - 0.3 * D, 0, 0.3 * H, "ceramic", c),
            _cy(-W / 2, W / 2, -D / 2 + tk, D / 2, 0.3 * H, 0.55 * H, "ceramic", c, sides=16),
            _bx(-0.3 * W, 0.3 * W, -D / 2 + 0.05, -D / 2 + tk, 0.3 * H, 0.45 * H, "ceramic", c)]


def _bathtub(W, D, H, rng):
    c = (0.95, 0.95, 0.97)
    t = min(0.08, 0.1 * D)
    return [_bx(-W / 2, W / 2, -D / 2, D / 2, 0, 0.12, "ceramic", c),
            _bx(-W / 2, W / 2, -D / 2, -D / 2 + t, 0.12, H, "ceramic", c),
            _bx(-W / 2, W / 2, D / 2 - t, D / 2, 0.12, H, "ceramic", c),
            _bx(-W / 2, -W / 2 + t, -D / 2 + t, D / 2 - t, 0.12, H, "ceramic", c),
            _bx(W / 2 - t, W / 2, -D / 2 + t, D / 2 - t, 0.12, H, "ceramic", c)]


def _fireplace(W, D, H, rng):
    st = (0.75, 0.70, 0.65)
    return [_bx(-W / 2, W / 2, -D / 2, D / 2 - 0.05, 0, 0.75 * H, "tiles", st),
            _bx(-W / 2, W / 2, -D / 2, D / 2, 0.75 * H, 0.8 * H, "wood", _pick(rng, "wood")),
            _bx(-0.35 * W, 0.35 * W, -D / 2, D / 2 - 0.05, 0.8 * H, H, "tiles", st),
            _bx(-0.25 * W, 0.25 * W, D / 2 - 0.05, D / 2 - 0.04, 0.05, 0.5 * H, "dark", (0.08, 0.07, 0.07))]


def _door(W, D, H, rng):
    col = _pick(rng, "wood")
    fr = (0.92, 0.92, 0.9)
    return [_bx(-W / 2, -W / 2 + 0.06, -D / 2, D / 2, 0, H, "paint", fr),
            _bx(W / 2 - 0.06, W / 2, -D / 2, D / 2, 0, H, "paint", fr),
            _bx(-W / 2 + 0.06, W / 2 - 0.06, -D / 2, D / 2, H - 0.06, H, "paint", fr),
            _bx(-W / 2 + 0.06, W / 2 - 0.06, -D / 2, D / 2 - 0.02, 0, H - 0.06, "wood", col),
            _bx(W / 2 - 0.16, W / 2 - 0.1, D / 2 - 0.02, D / 2, 0.98, 1.04, "metal", (0.6, 0.6, 0.6))]


def _lamp(W, D, H, rng):
    sh = (0.95, 0.9, 0.75)
    return [_cy(-0.3 * W, 0.3 * W, -0.3 * D, 0.3 * D, 0, 0.03, "metal", (0.3, 0.3, 0.3)),
            _cy(-0.02, 0.02, -0.02, 0.02, 0.03, H - 0.35, "metal", (0.3, 0.3, 0.3), sides=8),
            _cy(-W / 2, W / 2, -D / 2, D / 2, H - 0.35, H, "fabric", sh, sides=14)]


def _plant(W, D, H, rng):
    g = (0.25, 0.55, 0.22)
    return [_cy(-0.3 * W, 0.3 * W, -0.3 * D, 0.3 * D, 0, 0.3 * H, "ceramic", (0.7, 0.4, 0.3), sides=12),
            _cy(-W / 2, W / 2, -D / 2, D / 2, 0.3 * H, 0.75 * H, "leaves", g, sides=10),
            _cy(-0.35 * W, 0.35 * W, -0.35 * D, 0.35 * D, 0.75 * H, H, "leaves", g, sides=10)]


def _cabinet(W, D, H, rng, worktop=False):
    col = _pick(rng, "paint" if rng.random() < 0.5 else "wood")
    mat = "wood"
    f = 0.02
    top = H - 0.04 if worktop else H
    p = [_bx(-W / 2, W / 2, -D / 2, D / 2 - f, 0, top, mat, col)]
    n = max(1, int(round(W / 0.5)))
    xs = np.linspace(-W / 2, W / 2, n + 1)
    for i in range(n):
        p.append(_bx(xs[i] + 0.005, xs[i + 1] - 0.005, D / 2 - f, D / 2, 0.08, top - 0.02, mat, col))
    if worktop:
        p.append(_bx(-W / 2, W / 2, -D / 2, D / 2, H - 0.04, H, "tiles", (0.85, 0.85, 0.82)))
    return p


def _counter(W, D, H, rng):
    return _cabinet(W, D, H, rng, worktop=True)


def _shelf(W, D, H, rng):
    col = _pick(rng, "wood")
    t = 0.025
    p = [_bx(-W / 2, -W / 2 + t, -D / 2, D / 2, 0, H, "wood", col),
         _bx(W / 2 - t, W / 2, -D / 2, D / 2, 0, H, "wood", col),
         _bx(-W / 2 + t, W / 2 - t, -D / 2, -D / 2 + 0.01, 0, H, "wood", col)]
    n = max(2, int(H / 0.4))
    zs = np.linspace(0, H - t, n + 1)
    for i, z in enumerate(zs):
        p.append(_bx(-W / 2 + t, W / 2 - t, -D / 2 + 0.01, D / 2, z, z + t, "wood", col))
        if i < n:
            hgt = 0.7 * (zs[i + 1] - z - t)
            p.append(_bx(-W / 2 + t + 0.02, W / 2 - t - 0.05, -D / 2 + 0.03, D / 2 - 0.04, z + t, z + t + hgt,
                         "books", (1, 1, 1)))
    return p


def _sink(W, D, H, rng):
    c = (0.96, 0.96, 0.95)
    return [_cy(-0.15 * W, 0.15 * W, -D / 2, -D / 2 + 0.3 * W, 0, H - 0.18, "ceramic", c, sides=10),
            _bx(-W / 2, W / 2, -D / 2, D / 2, H - 0.18, H, "ceramic", c)]


# category -> (design, placement, front axis): placement 'wall' (back against a wall), 'wallhigh' (mounted),
# 'free', 'table' (around a table), 'counter' (on a counter); front 'short' means the short side faces the room
# (W = long, D = short), 'long' means W = short, D = long (bed, toilet: head/tank at the wall)
DESIGNS: dict[str, tuple[Any, str, str]] = {
    "table": (_table, "free", "short"), "chair": (_chair, "table", "short"), "stool": (_stool, "free", "short"),
    "sofa": (_sofa, "wall", "short"), "bed": (_bed, "wall", "long"), "tv": (_tv, "wallhigh", "short"),
    "refrigerator": (_fridge, "wall", "short"), "washer": (_washer, "wall", "short"),
    "dishwasher": (_dishwasher, "wall", "short"), "stove": (_stove, "counter", "short"),
    "toilet": (_toilet, "wall", "long"), "bathtub": (_bathtub, "wall", "short"),
    "fireplace": (_fireplace, "wall", "short"), "door": (_door, "wall", "short"), "lamp": (_lamp, "free", "short"),
    "plant": (_plant, "free", "short"), "cabinet": (_cabinet, "wall", "short"), "shelf": (_shelf, "wall", "short"),
    "sink": (_sink, "wall", "short"), "counter": (_counter, "wall", "short"),
}

# priors for categories the ARKitScenes part of VSI-Bench lacks: (long, short, height) ranges in metres
EXTRA_DIMS = {"door": ((0.8, 0.95), (0.04, 0.06), (2.0, 2.1)), "lamp": ((0.3, 0.45), (0.3, 0.45), (1.4, 1.7)),
              "plant": ((0.35, 0.6), (0.35, 0.6), (0.6, 1.3)), "cabinet": ((0.6, 1.6), (0.4, 0.6), (0.8, 1.2)),
              "shelf": ((0.6, 1.2), (0.25, 0.4), (1.4, 2.0)), "sink": ((0.45, 0.6), (0.35, 0.5), (0.8, 0.9))}
EXTRA_P = {"lamp": 0.3, "plant": 0.35, "cabinet": 0.3, "shelf": 0.3}


# ----------------------------------------------------------------------------- scene objects


@dataclass
class SynthObject:
    """One object: id (>= 1; 0 is the room), category name, size (W, D, H) in its local frame, placement
    (x, y, z of the bottom centre; yaw about z, radians), primitives, and where its size came from."""

    id: int
    name: str
    size: np.ndarray
    pos: np.ndarray
    yaw: float
    prims: list[Prim]
    source: str  # 'vsibench' | 'prior' | 'support'

    @property
    def R(self) -> np.ndarray:
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])

    def box(self) -> OrientedBox:
        R = self.R
        return OrientedBox(self.pos + np.array([0, 0, self.size[2] / 2]), np.asarray(self.size, float), R.T.copy())

    def footprint(self, margin: float = 0.0) -> np.ndarray:
        """[4, 2] floor corners (counter-clockwise)."""
        w, d = self.size[0] / 2 + margin, self.size[1] / 2 + margin
        loc = np.array([[-w, -d], [w, -d], [w, d], [-w, d]])
        return loc @ self.R[:2, :2].T + self.pos[:2]


@dataclass
class RoomShape:
    """Rectangular room centred on the origin: size (Lx, Ly) metres, ceiling height."""

    Lx: float
    Ly: float
    height: float

    @property
    def polygon(self) -> np.ndarray:
        x, y = self.Lx / 2, self.Ly / 2
        return np.array([[-x, -y], [x, -y], [x, y], [-x, y]])

    @property
    def area(self) -> float:
        return self.Lx * self.Ly

    def walls(self) -> list[tuple[np.ndarray, np.ndarray, float]]:
        """(midpoint [2], inward normal [2], length) for the 4 walls."""
        x, y = self.Lx / 2, self.Ly / 2
        return [(np.array([0, -y]), np.array([0, 1.0]), self.Lx), (np.array([x, 0]), np.array([-1.0, 0]), self.Ly),
                (np.array([0, y]), np.array([0, -1.0]), self.Lx), (np.array([-x, 0]), np.array([1.0, 0]), self.Ly)]


@dataclass
class Poster:
    """A picture on a wall (room structure, id 0): centre [3], in-plane axes, size (w, h), pattern index."""

    center: np.ndarray
    normal: np.ndarray
    size: tuple[float, float]
    pattern: str


@dataclass
class Scene:
    config: SceneConfig
    room: RoomShape
    objects: list[SynthObject]
    posters: list[Poster]
    dropped: list[dict[str, Any]] = field(default_factory=list)
    composition: dict[str, Any] = field(default_factory=dict)

    def counts(self) -> dict[str, int]:
        out: dict[str, int] = {}
        for o in self.objects:
            out[o.name] = out.get(o.name, 0) + 1
        return out

    def object_bbox(self) -> dict[str, list[dict[str, Any]]]:
        """VSI-Bench meta_info `object_bbox` (category -> boxes), each box with its `instance_id` added."""
        out: dict[str, list[dict[str, Any]]] = {}
        for o in self.objects:
            b = o.box().to_meta()
            b["instance_id"] = o.id
            out.setdefault(o.name, []).append(b)
        return out


# ----------------------------------------------------------------------------- collision


def _overlap2d(a: np.ndarray, b: np.ndarray) -> bool:
    """Separating-axis test for two convex polygons [k, 2]."""
    for poly in (a, b):
        for i in range(len(poly)):
            e = poly[(i + 1) % len(poly)] - poly[i]
            n = np.array([-e[1], e[0]])
            pa, pb = a @ n, b @ n
            if pa.max() <= pb.min() or pb.max() <= pa.min():
                return False
    return True


class _Layout:
    def __init__(self, room: RoomShape, gap: float = 0.05):
        self.room = room
        self.gap = gap
        self.items: list[tuple[np.ndarray, float, float]] = []  # footprint, z0, z1

    def fits(self, o: SynthObject) -> bool:
        fp = o.footprint()
        x, y = self.room.Lx / 2 - 0.005, self.room.Ly / 2 - 0.005
        if np.any(np.abs(fp[:, 0]) > x) or np.any(np.abs(fp[:, 1]) > y):
            return False
        z0, z1 = o.pos[2], o.pos[2] + o.size[2]
        fpm = o.footprint(self.gap / 2)
        for f, a0, a1 in self.items:
            if a0 < z1 and z0 < a1 and _overlap2d(fpm, f):
                return False
        return True

    def add(self, o: SynthObject, extra: np.ndarray | None = None) -> None:
        self.items.append((o.footprint(self.gap / 2), o.pos[2], o.pos[2] + o.size[2]))
        if extra is not None:  # keep-out zone (e.g. in front of a door), full height
            self.items.append((extra, 0.0, 10.0))


# ----------------------------------------------------------------------------- generation


def _draw_composition(stats: dict[str, Any], level: str, rng: np.random.Generator) -> dict[str, int]:
    lo, hi = stats["levels"]["objects"][level]
    cats = stats["categories"]
    for _ in range(10000):
        comp = {}
        for name in sorted(cats):
            if rng.random() < cats[name]["p_room"]:
                comp[name] = sample_count(cats[name], rng)
        if lo <= sum(comp.values()) <= hi:
            return comp
    raise InputError(f"cannot draw a composition with {lo}..{hi} objects from the statistics")


def generate_scene(conf: SceneConfig) -> Scene:
    """Draw a room and its objects from the statistics, deterministically from `conf.seed`."""
    conf.validate()
    stats = load_stats(conf.stats_path)
    rng = np.random.default_rng([int(conf.seed), 7919])
    if conf.room_dims is None:
        lo, hi = stats["levels"]["room"][conf.room]
        area = sample_quantiles(stats["room_size_quantiles"], rng, lo, hi)
        aspect = rng.uniform(1.0, 1.6)
        Lx = math.sqrt(area * aspect)
    else:
        Lx, Ly = (float(d) for d in conf.room_dims)
        area, aspect = Lx * Ly, Lx / Ly
    room = RoomShape(Lx, area / Lx, float(rng.uniform(2.5, 2.9)))
    comp = _draw_composition(stats, conf.objects, rng) if conf.vsibench_objects else {}
    # ordered request list: (name, size (long, short, height), source)
    req: list[tuple[str, np.ndarray, str]] = []
    for name in sorted(comp):
        for _ in range(comp[name]):
            req.append((name, sample_dims(stats["categories"][name], rng), "vsibench"))
    if any(n == "stove" for n, _, _ in req):  # cooktops stand on a counter
        st = max((d for n, d, _ in req if n == "stove"), key=lambda d: d[0])
        req.append(("counter", np.array([st[0] + rng.uniform(0.5, 1.2), max(0.55, st[1] + 0.05),
                                         rng.uniform(0.86, 0.92)]), "support"))
    if conf.extras:
        def prior(n):
            r = EXTRA_DIMS[n]
            d = np.array([rng.uniform(*r[0]), rng.uniform(*r[1]), rng.uniform(*r[2])])
            if n in ("lamp", "plant"):
                d[1] = d[0]
            return d
        req.append(("door", prior("door"), "prior"))
        for n in sorted(EXTRA_P):
            if rng.random() < EXTRA_P[n]:
                req.append((n, prior(n), "prior"))
        if any(n in ("toilet", "bathtub") for n, _, _ in req) and rng.random() < 0.7:
            req.append(("sink", prior("sink"), "prior"))
    order = {"door": 0, "bed": 1, "bathtub": 1, "counter": 1, "sofa": 2, "refrigerator": 2, "fireplace": 2,
             "shelf": 3, "cabinet": 3, "washer": 3, "dishwasher": 3, "toilet": 3, "sink": 4, "tv": 5, "table": 6,
             "stove": 7, "chair": 8, "stool": 8, "lamp": 9, "plant": 9}
    # the door first (a room has one), then the drawn objects, the optional extras last (they yield space)
    req.sort(key=lambda r: (r[2] == "prior" and r[0] != "door", order.get(r[0], 5), -float(r[1][0])))
    layout = _Layout(room)
    objects: list[SynthObject] = []
    dropped: list[dict[str, Any]] = []
    for name, dims, source in req:
        o = _place(name, dims, source, len(objects) + 1, room, layout, objects, rng)
        if o is None:
            dropped.append({"name": name, "size": dims.round(3).tolist(), "reason": "no free place"})
            continue
        objects.append(o)
    # the counter is a cabinet to the question vocabulary
    for o in objects:
        if o.name == "counter":
            o.name = "cabinet"
    posters = _posters(room, rng, objects)
    return Scene(conf, room, objects, posters, dropped,
                 {"requested": comp, "room_area_drawn": area, "aspect": aspect})


def _make(name, dims, source, oid, rng) -> SynthObject:
    design, _, front = DESIGNS[name]
    L, S, H = (float(v) for v in dims)
    W, D = (L, S) if front == "short" else (S, L)
    return SynthObject(oid, name, np.array([W, D, H]), np.zeros(3), 0.0, design(W, D, H, rng), source)


def _place(name, dims, source, oid, room, layout, objects, rng) -> SynthObject | None:
    o = _make(name, dims, source, oid, rng)
    W, D, H = o.size
    how = DESIGNS[name][1]
    walls = room.walls()
    for attempt in range(200):
        keepout = None
        if how in ("wall", "wallhigh"):
            mid, n, length = walls[int(rng.integers(4))]
            if W > length - 0.1:
                continue
            t = np.array([n[1], -n[0]])  # along the wall
            s = rng.uniform(-(length - W) / 2 + 0.05, (length - W) / 2 - 0.05)
            back = 0.006 if name in ("tv", "door") else rng.uniform(0.01, 0.05)
            c = mid + t * s + n * (back + D / 2)
            o.yaw = math.atan2(n[1], n[0]) - math.pi / 2  # local +y (front) along the inward normal
            z = 0.0
            if how == "wallhigh":
                z = float(rng.uniform(0.75, min(1.25, room.height - H - 0.1)))
            o.pos = np.array([c[0], c[1], z])
            if name == "door":
                keepout = np.array([c + t * W / 2 * 1.1, c - t * W / 2 * 1.1, c - t * W / 2 * 1.1 + n * 0.9,
                                    c + t * W / 2 * 1.1 + n * 0.9])
        elif how == "counter":
            counters = [q for q in objects if q.name == "counter"]
            if not counters:
                return None
            q = counters[0]
            ox = rng.uniform(-(q.size[0] - W) / 2, (q.size[0] - W) / 2) if q.size[0] > W else 0.0
            oy = (q.size[1] - D) / 2 - 0.02 if q.size[1] > D else 0.0
            o.yaw = q.yaw
            o.pos = np.array([*(q.pos[:2] + q.R[:2, :2] @ np.array([ox, -oy])), q.size[2]])
        elif how == "table" and attempt < 120 and any(q.name == "table" for q in objects):
            tables = [q for q in objects if q.name == "table"]
            q = tables[int(rng.integers(len(tables)))]
            side = int(rng.integers(4))
            ang = q.yaw + side * math.pi / 2
            half = q.size[1] / 2 if side % 2 == 0 else q.size[0] / 2
            along = q.size[0] if side % 2 == 0 else q.size[1]
            dirn = np.array([math.cos(ang - math.pi / 2), math.sin(ang - math.pi / 2)])  # outward from the table
            tang = np.array([-dirn[1], dirn[0]])
            c = q.pos[:2] + dirn * (half + D / 2 + rng.uniform(0.06, 0.2)) + tang * rng.uniform(-0.35, 0.35) * along
            o.yaw = math.atan2(-dirn[1], -dirn[0]) - math.pi / 2  # front faces the table
            o.pos = np.array([c[0], c[1], 0.0])
        else:
            m = 0.1
            x = rng.uniform(-room.Lx / 2 + W / 2 + m, room.Lx / 2 - W / 2 - m) if room.Lx > W + 2 * m else 0.0
            y = rng.uniform(-room.Ly / 2 + D / 2 + m, room.Ly / 2 - D / 2 - m) if room.Ly > D + 2 * m else 0.0
            o.yaw = float(rng.integers(4) * math.pi / 2 + rng.normal(0, math.radians(8)))
            o.pos = np.array([x, y, 0.0])
        if how == "counter" or layout.fits(o):
            if how != "counter":
                layout.add(o, keepout)
            return o
    return None


POSTER_PATTERNS = ("poster0", "poster1", "poster2", "poster3")


def _posters(room: RoomShape, rng: np.random.Generator, objects: list[SynthObject]) -> list[Poster]:
    """1-2 pictures per wall, 1 cm off the wall, not overlapping each other or an object's box."""
    out: list[Poster] = []
    boxes = [o.box().aabb() for o in objects]
    for k, (mid, n, length) in enumerate(room.walls()):
        placed: list[tuple[np.ndarray, np.ndarray]] = []
        for _ in range(int(rng.integers(1, 3))):
            w, h = rng.uniform(0.4, 1.0), rng.uniform(0.35, 0.8)
            t = np.array([n[1], -n[0]])
            s = rng.uniform(-(length - w) / 2 + 0.1, (length - w) / 2 - 0.1)
            c = np.array([*(mid + t * s + n * 0.01), rng.uniform(1.3, min(2.0, room.height - h / 2 - 0.1))])
            half = (np.abs(np.array([t[0], t[1], 0.0])) * w / 2 + np.array([0, 0, h / 2])
                    + np.abs(np.array([n[0], n[1], 0.0])) * 0.02)
            lo, hi = c - half, c + half
            if any(np.all(lo < b1) and np.all(b0 < hi) for b0, b1 in boxes + placed):
                continue
            placed.append((lo, hi))
            out.append(Poster(c, np.array([n[0], n[1], 0.0]), (w, h),
                              POSTER_PATTERNS[int(rng.integers(len(POSTER_PATTERNS)))]))
    return out


def config_dict(conf: SceneConfig) -> dict[str, Any]:
    return asdict(conf)
