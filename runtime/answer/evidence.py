"""The evidence an answer rests on: the instances it used, their views and fused detections, and the spread
(standard deviation) of the asked quantity over the per-view estimates the map keeps
(`ObjectInstance.views`, from `semantic_map.view_estimates`).

Per question type (its executor picks one):
- counting: the number of the counted instances seen in each view that saw any of them;
- size: the chosen instance's measure (longest side, height, ...) of each view's own box;
- distances: the distance of the two boxes placed at each pair of per-view centres (up to `max_views` views
  of each instance, evenly spread);
- directions: the angle of C standing at A facing B, over combinations of per-view centres.
A map without per-view estimates (built from benchmark boxes, or an older map file) gives std None and says so.
The spread is per-view noise (how much the views of the used instances disagree), not the map's error: a wrong
association (two objects fused as one, one object split) or a wrong pick among several instances is not in it.
So the evidence also lists every question name that matched several instances (`ambiguous`: the ids, the one
used, the rule that picked it and the asked quantity with each of the others) — the answer says so too.
All functions are pure (numpy over the instances given).
"""
from __future__ import annotations

import itertools
from typing import Any, Callable, Sequence

import numpy as np

from ..geometry import OrientedBox, box_distance
from ..map.verify import rests_on
from ..query.vocabulary import plural
from .angles import signed_angle_deg


def _centres(o: Any, max_views: int) -> list[np.ndarray]:
    """Per-view centres [3] of an instance (views with an estimate), at most `max_views`, evenly spread."""
    c = [np.asarray(v["centre"], np.float64) for v in getattr(o, "views", []) if v.get("centre") is not None]
    if len(c) > max_views:
        c = [c[i] for i in np.linspace(0, len(c) - 1, max_views).round().astype(int)]
    return c


def _moved(o: Any, centre: np.ndarray) -> OrientedBox:
    """The fused box of `o` placed at a per-view centre (the view's position, the fused extent)."""
    return OrientedBox(np.asarray(centre, np.float64), np.asarray(o.box.axes_lengths, np.float64),
                       np.asarray(o.box.axes, np.float64))


def count_values(instances: Sequence[Any]) -> list[float]:
    """Per view (frame) that saw any of `instances`: how many of them it saw."""
    per: dict[int, int] = {}
    for o in instances:
        for f in set(o.frames):
            per[int(f)] = per.get(int(f), 0) + 1
    return [float(per[f]) for f in sorted(per)]


def size_values(o: Any, measure: Callable[[Any], float], scale: float = 1.0) -> list[float]:
    """`measure` (a function of an instance-like object with `.box`) of each view's own box, divided by
    `scale` (the question's unit in metres)."""
    out = []
    for v in getattr(o, "views", []):
        if v.get("size") is None:
            continue
        b = OrientedBox(np.asarray(v["centre"], np.float64), np.maximum(np.asarray(v["size"], np.float64), 1e-6),
                        np.asarray(o.box.axes, np.float64))
        out.append(float(measure(_Boxed(b))) / scale)
    return out


class _Boxed:
    """An instance-like view: just a box (what the reasoner's measures read)."""

    def __init__(self, box: OrientedBox):
        self.box = box


def distance_values(x: Any, y: Any, scale: float = 1.0, max_views: int = 12) -> list[float]:
    """Box distance of x and y placed at each pair of their per-view centres, in units of `scale` m."""
    cx, cy = _centres(x, max_views), _centres(y, max_views)
    return [box_distance(_moved(x, a), _moved(y, b)) / scale for a in cx for b in cy]


def angle_values(a: Any, b: Any, c: Any, base_deg: float, max_views: int = 8) -> list[float]:
    """Angle (deg, counter-clockwise) of C's centre standing at A facing B over combinations of per-view
    centres, unwrapped around `base_deg` (the answer's own angle) so the spread is not split at +-180."""
    out = []
    for pa, pb, pc in itertools.product(_centres(a, max_views), _centres(b, max_views), _centres(c, max_views)):
        f = pb[:2] - pa[:2]
        if np.linalg.norm(f) < 1e-9:
            continue
        th = signed_angle_deg(f, pc[:2] - pa[:2])
        out.append(base_deg + ((th - base_deg + 180.0) % 360.0 - 180.0))
    return out


def spread(values: Sequence[float]) -> dict[str, Any]:
    """{"std", "n", "min", "max"} of per-view values (std None with fewer than 2)."""
    v = np.asarray(list(values), np.float64)
    if not len(v):
        return {"std": None, "n": 0, "min": None, "max": None}
    return {"std": round(float(v.std()), 4) if len(v) >= 2 else None, "n": int(len(v)),
            "min": round(float(v.min()), 4), "max": round(float(v.max()), 4)}


SPREAD_IS = "per-view noise of the used instances, not the map's error (wrong associations or picks are not in it)"


def build(instances: Sequence[Any], quantity: str | None = None, values: Sequence[float] | None = None,
          unit: str | None = None, ambiguous: Sequence[dict[str, Any]] = ()) -> dict[str, Any]:
    """The evidence dict of an answer: instances used (id, name, views, fused detections), views (distinct
    frames), detections (fused, in all), the spread of the asked quantity (None when the question type has
    no per-view estimate, e.g. the room's area) and what that spread measures (`spread_is`), and the question
    names that matched several instances (`ambiguous`, see the module doc)."""
    seen: dict[int, Any] = {}
    for o in instances:
        seen.setdefault(int(o.id), o)
    # rests_on: key frames its detections were fused from or agreed with (map.verify), the views it stands on
    rows = [{"id": i, "name": o.name, "views": len(set(o.frames)), "detections": len(getattr(o, "views", [])),
             "rests_on": rests_on(o)} for i, o in seen.items()]
    frames = {int(f) for o in seen.values() for f in o.frames}
    ev: dict[str, Any] = {"instances": rows, "views": len(frames), "detections": sum(r["detections"] for r in rows),
                          "quantity": quantity, "unit": unit, **spread(values or []),
                          "spread_is": SPREAD_IS if quantity is not None else None, "ambiguous": list(ambiguous)}
    if quantity is not None and seen and not any(getattr(o, "views", []) for o in seen.values()):
        ev["note"] = "the map holds no per-view estimates (built from boxes, or an older map file)"
    return ev


def ambiguity_text(a: dict[str, Any]) -> str:
    """`2 tvs in the map (#0 #2); used #0, the nearest (tv #2: 0.84 m)` (`a["name"]`: singular, one instance's)."""
    alt = {int(k): v for k, v in (a.get("alternatives") or {}).items() if int(k) != a["used"]}
    u = f" {a['unit']}" if a.get("unit") else ""
    others = ", ".join(f"{a['name']} #{k}: {_fmt(v)}{u}" for k, v in alt.items())
    n = a.get("n_instances", len(a["instances"]))
    more = f" and {n - len(a['instances'])} more" if n > len(a["instances"]) else ""
    return (f"{n} {a['name'] if n == 1 else plural(a['name'])} in the map "
            f"({' '.join('#' + str(i) for i in a['instances'])}{more}); used #{a['used']}, {a['rule']}"
            + (f" ({others})" if others else ""))


def line(ev: dict[str, Any] | None, max_ids: int = 8) -> str:
    """One printed line: `evidence: chair #1 #4, 9 views, 12 fused detections; per-view count std 0.47 (n=9)`."""
    if not ev:
        return ""
    rows = ev.get("instances", [])
    names: dict[str, list[str]] = {}
    for r in rows[:max_ids]:  # an instance's views (map.verify.rests_on) when the map recorded them
        names.setdefault(r["name"], []).append(f"#{r['id']}" + (f" ({r['rests_on']} views)" if r.get("rests_on")
                                                                 else ""))
    objs = "; ".join(f"{n} {' '.join(ids)}" for n, ids in names.items()) or "no instances"
    if len(rows) > max_ids:
        objs += f" (+{len(rows) - max_ids} more)"
    s = f"evidence: {objs}, {ev.get('views', 0)} view(s), {ev.get('detections', 0)} fused detection(s)"
    if ev.get("quantity"):
        u = f" {ev['unit']}" if ev.get("unit") else ""
        std = ev.get("std")
        s += (f"; {ev['quantity']} std {_fmt(std)}{u} (n={ev.get('n', 0)}), per-view noise, not the map's error"
              if std is not None
              else f"; {ev['quantity']}: no spread ({ev.get('note') or str(ev.get('n', 0)) + ' per-view value(s)'})")
    for a in ev.get("ambiguous") or []:
        s += f"; AMBIGUOUS: {ambiguity_text(a)}"
    return s


def _fmt(x: float) -> str:
    return f"{x:.2f}" if abs(x) < 100 else f"{x:.0f}"
