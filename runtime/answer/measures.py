"""Executors of sizes, size comparisons and the room's size."""
from __future__ import annotations

from typing import Any

import numpy as np

from ..geometry import min_area_rect
from ..query.ir import COMPARATIVES, EVERYTHING, SUPERLATIVES, UNIT_M, Ref, RoomSize, Size, SizeCompare, everything
from . import evidence as ev
from .boxes import MEASURE_WORDS, measure
from .context import Ctx
from .result import UNIT_WORDS, Unsupported


def size(node: Size, ctx: Ctx) -> tuple[Any, str]:
    ref = node.object
    inst = ctx.instances(ref)
    dim, unit = node.dimension, node.unit
    if dim == "all":  # width x depth x height of the largest instance (as furniture is sold)
        o = max(inst, key=lambda x: measure(x, "longest"))
        if len(inst) > 1:
            ctx.choice(ref, inst, o, "the largest", {x.id: measure(x, "longest") / UNIT_M[unit] for x in inst}, unit)
        ctx.used = [o]
        d = {k: round(measure(o, k) / UNIT_M[unit], 1) for k in ("width", "depth", "height")}
        text = f"{d['width']:g} x {d['depth']:g} x {d['height']:g} {unit}"
        return {"text": text, **d, "unit": unit}, f"box width x depth x height of {ctx.one(ref)} #{o.id}: {text}"
    if dim == "elevation":
        return _elevation(ctx, ref, inst, unit)
    scale = 1.0 if dim == "volume" else UNIT_M[unit]  # volume: m^3
    sizes = [measure(o, dim) / scale for o in inst]
    i = int(np.argmax(sizes))
    ctx.spread = (f"per-view {'longest side' if dim == 'longest' else dim}",
                  ev.size_values(inst[i], lambda o: measure(o, dim), scale), unit)
    note = "" if len(inst) == 1 else f" (largest of {len(inst)} instances)"
    ctx.choice(ref, inst, inst[i], "the largest", {o.id: v for o, v in zip(inst, sizes)}, unit)
    what = "longest box dimension" if dim == "longest" else f"box {dim}"
    shown = f"{sizes[i]:.2f} m^3" if dim == "volume" else f"{sizes[i]:.1f} {unit}"
    return sizes[i], f"{what} of {ctx.one(ref)} #{inst[i].id}: {shown}{note}"


def _elevation(ctx: Ctx, ref: Ref, inst: list[Any], unit: str) -> tuple[Any, str]:
    """"How high above the floor is the lamp?": its box bottom over the map's floor (the room's floor height,
    else the lowest box bottom); several instances: the highest, the others listed."""
    floor, source = ctx.map.floor_z()
    lift = {o.id: (measure(o, "bottom") - floor) / UNIT_M[unit] for o in inst}
    o = max(inst, key=lambda x: lift[x.id])
    ctx.choice(ref, inst, o, "the highest", lift, unit)
    ctx.used = [o]
    d = {"m": 2, "ft": 2, "in": 1}.get(unit, 0)
    return round(lift[o.id], 2), (f"bottom of {ctx.one(ref)} #{o.id} above the floor ({source}): "
                                  f"{lift[o.id]:.{d}f} {unit}")


def size_compare(node: SizeCompare, ctx: Ctx) -> tuple[Any, str]:
    """The object with the largest (smallest) box measure among the candidates, or among every object of the
    map; a category with several instances counts by its extreme one (recorded as ambiguity)."""
    key, pick = SUPERLATIVES[node.measure]
    cands, unit = node.candidates, "m3" if key == "volume" else "m"
    every = any(everything(c) for c in cands)
    if node.form == "threshold":  # "is the couch longer than 2 m?"
        return _size_against(ctx, node, cands[0], key, pick)
    if not every and len(cands) == 1:  # "which chair is the tallest?": one of its instances
        inst = ctx.instances(cands[0])
        o = pick(inst, key=lambda x: measure(x, key))
        ranked = sorted(inst, key=lambda x: measure(x, key), reverse=pick is max)[:6]
        return ({"text": f"{ctx.one(cands[0])} #{o.id}", "object": o.name, "instance": int(o.id),
                 "value": round(measure(o, key), 3)},
                f"{MEASURE_WORDS[key]}: " + ", ".join(f"#{x.id} {measure(x, key):.2f} {unit}" for x in ranked))
    refs = {c.name: c for c in cands}
    groups = {k: list(v) for k, v in ctx.index.by_key.items()} if every else ctx.require(list(cands))
    best = {n: pick(inst, key=lambda o: measure(o, key)) for n, inst in groups.items() if inst}
    if len(best) < 2:
        raise Unsupported("fewer than two objects to compare")
    vals = {n: measure(o, key) for n, o in best.items()}
    win = pick(vals, key=vals.get)
    word = (lambda n: n) if every else (lambda n: refs[n].words)
    one = (lambda n: n) if every else (lambda n: ctx.one(refs[n]))
    if every:
        ctx.used.append(best[win])
    else:
        for n, inst in groups.items():
            ctx.choice(refs[n], inst, best[n], f"the {node.measure}", {o.id: measure(o, key) for o in inst}, unit)
    ranked = sorted(vals, key=vals.get, reverse=pick is max)[:6]
    expl = f"{MEASURE_WORDS[key]}: " + ", ".join(f"{one(n)} #{best[n].id} {vals[n]:.2f} {unit}" for n in ranked)
    if node.form == "difference":
        return _size_difference(node, vals, key), expl
    if node.form == "yesno":
        a = cands[0].name
        yes = win == a and vals[cands[0].name] != vals[cands[1].name]
        return {"text": "yes" if yes else "no", "answer": yes, "values_m": vals}, expl
    if every and not ctx.options:
        o = best[win]
        text = o.name
        if node.with_value:  # "how tall is the tallest object?": which, and how tall
            text += f", {vals[win]:.2f} m^3" if key == "volume" else f", {vals[win] * 100:.0f} cm"
        return {"text": text, "object": o.name, "instance": int(o.id), "value": round(vals[win], 3)}, expl
    tied = [n for n in vals if n != win and abs(vals[n] - vals[win]) <= 0.005 * abs(vals[win])]  # within 0.5%
    if tied and not ctx.options:  # "which is longer, the couch or the whiteboard?" when both are 2.00 m
        names = " and the ".join(word(n) for n in [win] + tied)
        return {"text": f"equal: the {names} ({vals[win]:.2f} {unit})", "equal": [win] + tied}, expl
    return win, expl


def _size_against(ctx: Ctx, node: SizeCompare, ref: Ref, key: str, pick: Any) -> tuple[Any, str]:
    """Yes / no: the object's box measure beyond (`pick` max: above, min: below) a length; with several
    instances the one most in that direction (said as ambiguous)."""
    inst = ctx.require([ref])[ref.name]
    o = pick(inst, key=lambda x: measure(x, key))
    v, thr = measure(o, key), node.threshold_mm / 1000.0
    ctx.choice(ref, inst, o, f"the {node.measure}", {x.id: measure(x, key) for x in inst}, "m")
    ctx.used = [o]
    yes = v > thr if pick is max else v < thr
    return ({"text": "yes" if yes else "no", "answer": yes, "value_m": round(v, 3)},
            f"{MEASURE_WORDS[key]} of {ctx.one(ref)} #{o.id}: {v:.2f} m against {node.threshold_text}"
            + ("" if node.threshold_text.endswith(" m") else f" ({thr:.2f} m)"))


def _size_difference(node: SizeCompare, vals: dict[str, float], key: str) -> dict[str, Any]:
    """"How much taller (shorter) is A than B?": how far A's measure exceeds (falls short of) B's (m^3 for
    volume, else the asked length unit); a negative difference is said with the opposite comparative, or,
    where the vocabulary has none (longer), with B as the subject."""
    a, b = node.candidates[0], node.candidates[1]
    _, pick = SUPERLATIVES[node.measure]
    word = next(w for w, sup in COMPARATIVES.items() if sup == node.measure)
    d = (vals[a.name] - vals[b.name]) * (1 if pick is max else -1)
    unit = "m3" if key == "volume" else (node.unit or "cm")
    v = d if key == "volume" else d / UNIT_M[unit]
    shown = f"{abs(v):.2f} m^3" if key == "volume" else \
        f"{abs(v):.{0 if unit in ('cm', 'mm') else 2}f} {UNIT_WORDS[unit]}"
    other = next((c for c, sup in COMPARATIVES.items() if SUPERLATIVES[sup] == (key, min if pick is max else max)),
                 None)
    text = shown if d >= 0 else f"none: the {a.words} is {shown} {other}" if other else \
        f"none: the {b.words} is {shown} {word}"
    return {"text": text, "difference": round(v, 4), "unit": unit}


def room_size(node: RoomSize, ctx: Ctx) -> tuple[Any, str]:
    """The floor area of the map's room extent. A map with a floor extent (built from video: the observed floor,
    the camera track) measures that outline; a map of object boxes alone measures the smallest rectangle around
    the boxes (rooms are rectangles with furniture along the walls; the room's sides are that rectangle's too),
    said in the answer as a lower bound."""
    room = ctx.map.extent()
    if room is None:
        raise Unsupported("the map has no room extent and no objects")
    src = room.source
    if node.measure != "area":
        return _room_sides(ctx, node, src)
    if src.startswith("object_boxes"):  # boxes only: the smallest rectangle around them, a lower bound
        (_, _), (w, h), _ = min_area_rect(room.polygon)
        area, what = float(w * h), ("smallest rectangle around the object boxes (the map has no floor extent: a "
                                    "lower bound, the floor between the furniture and the walls is not seen)")
    else:
        area, what = float(room.area()), f"floor outline of the map's room extent ({src})"
    unit = node.unit
    if unit == "ft2":
        area = area / 0.3048 ** 2
    expl = f"area of the {what}: {area:.2f} {unit}"
    if node.than is not None:  # "is the room bigger than 20 square meters?"
        thr = node.than.threshold_cm2 / 1e4 / (0.3048 ** 2 if unit == "ft2" else 1.0)
        yes = area > thr if node.than.op == ">" else area < thr
        return {"text": f"{'yes' if yes else 'no'} ({area:.1f} {unit})", "answer": yes, "area": round(area, 2),
                "unit": unit}, f"{expl} (asked: {node.than.op} {node.than.text})"
    return area, expl


def _room_sides(ctx: Ctx, node: RoomSize, src: str) -> tuple[Any, str]:
    """"How long / wide is the room?": the sides of the smallest rectangle around the room's floor outline
    (length the longer)."""
    (_, _), (w, h), _ = min_area_rect(ctx.map.extent().polygon)
    unit = node.unit
    length, width = max(w, h) / UNIT_M[unit], min(w, h) / UNIT_M[unit]
    how = f"sides of the smallest rectangle around the map's room extent ({src})"
    if node.measure == "all":
        text = f"{length:.1f} x {width:.1f} {unit}"
        return {"text": text, "length": round(length, 2), "width": round(width, 2), "unit": unit}, f"{how}: {text}"
    v = length if node.measure == "length" else width
    return {"text": f"{v:.1f} {unit}", node.measure: round(v, 2), "unit": unit}, \
        f"{how}: {length:.2f} x {width:.2f} {unit}"


__all__ = ["size", "size_compare", "room_size", "EVERYTHING"]
