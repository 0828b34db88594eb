"""Input health: degenerate sensor input and implausible magnitudes in a map, said with the answer (a `note:`
line and a trace event), never answered silently.

Pure functions over arrays that return notes (plain sentences); the pipeline records them as "input" events
(`pipeline.ask`, `build_map`), which the printed answer and the JSON result repeat. A check that finds nothing
returns no note, so a healthy input prints nothing extra.

- frames: all-black images; depth that is invalid everywhere (0, NaN, inf) or one constant value (a
  placeholder, not a measurement). `sample_frames` reads a few frames of a source before the work starts, so
  an input that cannot be mapped at all (every sampled frame black) is refused clearly instead of ending in
  "not found" or a misleading "one view" error.
- maps: objects larger than any indoor object or smaller than 1 cm, boxes holding NaN / inf, a room larger than a
  stadium, objects spread over kilometres, a ceiling not above the floor.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from .infra.errors import InputError

BLACK_MAX = 8            # an image whose pixels are all at most this (of 255) is black
MAX_OBJECT_M = 30.0      # no indoor object is longer (the largest: a long table, a wall unit, a bus-sized machine)
MIN_OBJECT_M = 0.01      # nothing a camera maps from a room is under 1 cm on its longest side (a box: points' extent)
MAX_ROOM_M2 = 20_000.0   # a floor larger than a stadium's
MAX_HEIGHT_M = 50.0      # floor to ceiling
MAX_SPREAD_M = 1_000.0   # objects of one indoor map spread over more than a kilometre
SAMPLE_FRAMES = 8


@dataclass
class FrameHealth:
    """Per-frame findings: black image; depth invalid everywhere; depth one constant value (metres)."""

    black: bool
    depth_invalid: bool = False
    depth_constant: float | None = None


def frame_health(rgb: np.ndarray, depth: np.ndarray | None) -> FrameHealth:
    """rgb [H, W, 3] uint8, depth [H, W] float32 metres (0 = invalid) or None."""
    black = bool(rgb.size == 0 or int(rgb.max()) <= BLACK_MAX)
    if depth is None:
        return FrameHealth(black)
    d = np.asarray(depth, np.float32)
    valid = np.isfinite(d) & (d > 0)
    if not valid.any():
        return FrameHealth(black, depth_invalid=True)
    v = d[valid]
    const = float(v[0]) if valid.mean() > 0.5 and float(v.max() - v.min()) < 1e-4 else None
    return FrameHealth(black, depth_constant=const)


def frame_notes(health: Sequence[FrameHealth], what: str = "key frames") -> list[str]:
    """Notes for a set of frames' findings (`what`: how the answer names them)."""
    n = len(health)
    notes = []
    black = sum(h.black for h in health)
    if black:
        notes.append(f"{black} of {n} {what} are black (every pixel <= {BLACK_MAX}/255): nothing can be seen "
                     f"in them; check the camera or the file")
    inv = sum(h.depth_invalid for h in health)
    if inv:
        notes.append(f"the depth of {inv} of {n} {what} is invalid everywhere (0, NaN or infinite): no 3D points "
                     f"from them; check the depth files or use `depth=model`")
    const = [h.depth_constant for h in health if h.depth_constant is not None]
    if const:
        notes.append(f"the depth of {len(const)} of {n} {what} is one constant value ({const[0]:.3g} m): a "
                     f"placeholder, not a measurement; objects are placed on a flat plane")
    return notes


def sample_frames(source: Any, n: int = SAMPLE_FRAMES) -> list[str]:
    """Read up to `n` frames spread over `source` (a FrameSource: len, [i] -> Frame with .rgb) before the work:
    raise InputError when every one is black (nothing could be mapped, and the pipeline would end in a
    misleading "one view" or "not found"); a note when some are (the key frames then avoid them, and the answer
    rests on fewer views). Depth is judged on the key frames (`frame_notes`)."""
    total = len(source)
    if total == 0:
        return []
    idx = np.unique(np.linspace(0, total - 1, min(n, total)).round().astype(int))
    black = sum(frame_health(source[int(i)].rgb, None).black for i in idx)
    if black == len(idx):
        raise InputError(f"{getattr(source, 'name', 'the input')}: all {len(idx)} frames sampled over the input "
                         f"are black (every pixel <= {BLACK_MAX}/255): there is nothing to map; check the camera or "
                         f"the file")
    return frame_notes([FrameHealth(True)] * black + [FrameHealth(False)] * (len(idx) - black),
                       f"frames sampled over the input")


def map_notes(smap: Any) -> list[str]:
    """Implausible magnitudes of a SemanticMap (instances with oriented boxes, an optional room): the answer is
    computed from them as given, and says so."""
    notes = []
    inst = smap.instances
    if inst:
        C, L, _ = smap.box_arrays() if hasattr(smap, "box_arrays") else (
            np.array([o.box.centroid for o in inst], np.float64).reshape(-1, 3),
            np.array([o.box.axes_lengths for o in inst], np.float64).reshape(-1, 3), None)
        finite = np.isfinite(C).all(1) & np.isfinite(L).all(1)
        if not finite.all():
            notes.append(f"implausible objects in the map: {_names(inst, np.flatnonzero(~finite))} hold NaN or "
                         f"infinity in their box; answers cannot place them: check the map")
        longest = np.where(finite, L.max(1, initial=0.0), np.nan)
        with np.errstate(invalid="ignore"):
            big, tiny = np.flatnonzero(longest > MAX_OBJECT_M), np.flatnonzero(longest < MIN_OBJECT_M)
        if len(big):
            big = big[np.argsort(-longest[big])]
            notes.append(f"implausible sizes in the map: {len(big)} object(s) longer than {MAX_OBJECT_M:g} m: "
                         f"{_names(inst, big, longest, 'long')} (larger than any indoor object); answers use them "
                         f"as given: check the map")
        if len(tiny):
            tiny = tiny[np.argsort(longest[tiny])]
            notes.append(f"implausible sizes in the map: {len(tiny)} object(s) smaller than {MIN_OBJECT_M * 100:g} "
                         f"cm on every side: {_names(inst, tiny, longest, 'long')} (smaller than anything a camera "
                         f"maps; vanishing boxes); answers use them as given: check the map")
        C = C[finite] if finite.any() else np.zeros((1, 3))
        spread = float((C.max(0) - C.min(0))[:2].max())
        if spread > MAX_SPREAD_M:
            notes.append(f"implausible extent: the objects of the map spread over {_m(spread)} (more than "
                         f"{_m(MAX_SPREAD_M)}; one indoor space is far smaller); answers use them as given")
    room = getattr(smap, "room", None)
    if room is not None:
        area = float(room.area())
        if area > MAX_ROOM_M2:
            notes.append(f"implausible room: its floor is {area:,.0f} m^2 (larger than a stadium, "
                         f"{MAX_ROOM_M2:,.0f} m^2); answers use it as given")
        h = float(room.ceiling_z - room.floor_z)
        if h > MAX_HEIGHT_M:
            notes.append(f"implausible room: {_m(h)} from floor to ceiling; answers use it as given")
        if len(np.asarray(room.polygon).reshape(-1, 2)) < 3:
            notes.append("the room's floor outline has fewer than 3 corners: its area is 0")
    return notes


def _m(x: float) -> str:
    return f"{x / 1000:,.1f} km" if x >= 10_000 else f"{x:,.1f} m" if x >= 0.1 else f"{x:.3g} m"


def _names(inst: Sequence[Any], idx: np.ndarray, size: np.ndarray | None = None, word: str = "") -> str:
    """'sofa #3 (1,000.0 km long), chair #0 ... and 4 more': up to three objects by name and id."""
    parts = [f"{inst[int(k)].name} #{inst[int(k)].id}" + (f" ({_m(float(size[k]))} {word})" if size is not None
                                                            else "") for k in idx[:3]]
    return ", ".join(parts) + (f" and {len(idx) - 3} more" if len(idx) > 3 else "")
