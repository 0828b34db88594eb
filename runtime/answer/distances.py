"""Executors of distances and which-is-closest (closest points of the solid boxes, nearest instances)."""
from __future__ import annotations

from typing import Any

from ..geometry import point_box_distance
from ..query.ir import UNIT_M, Distance, Nearest, Ref
from ..query.vocabulary import plural
from . import evidence as ev
from .spatial import BoxSet, closest_pair, nearest_values
from .context import Ctx
from .result import Unsupported


def distance(node: Distance, ctx: Ctx) -> tuple[Any, str]:
    if node.b is None:
        return _camera_distance(node, ctx)
    a, b, unit = node.a, node.b, node.unit
    inst = ctx.require([a, b])
    if a.name == b.name:
        return _pair_distance(ctx, a, inst[a.name], unit)
    d, x, y = closest_pair(inst[a.name], inst[b.name])
    v = d / UNIT_M[unit]
    ctx.spread = ("per-view-pair distance", ev.distance_values(x, y, UNIT_M[unit]), unit)
    for r, own, other, used in ((a, inst[a.name], inst[b.name], x), (b, inst[b.name], inst[a.name], y)):
        if len(own) > 1:
            near = nearest_values(own, other, ctx.conf.n_alternatives)
            ctx.choice(r, own, used, "the nearest", {own[i].id: near[i] / UNIT_M[unit] for i in sorted(near)}, unit)
    expl = f"closest points of {ctx.one(a)} #{x.id} and {ctx.one(b)} #{y.id}: {v:.3f} {unit}"
    cond = node.within
    if cond is not None:  # "is the sofa within 2 m of the tv?": yes or no, the distance said
        t = cond.threshold_mm / 1000.0
        yes = {"<": d < t, "<=": d <= t, ">": d > t, ">=": d >= t}[cond.op]
        return ({"text": f"{'yes' if yes else 'no'} ({v:.{2 if unit in ('m', 'ft') else 0}f} {unit})",
                 "answer": yes, "distance": round(v, 3), "unit": unit}, f"{expl} (asked: {cond.text})")
    return v, expl


def _camera_distance(node: Distance, ctx: Ctx) -> tuple[Any, str]:
    """"How far am I from the tv?": the last camera's centre to the object's box (closest point; the nearest
    instance), the viewer being where the video ended."""
    cam = ctx.viewer("'how far am I' needs", "how far two objects are apart")[:3, 3]
    a, unit = node.a, node.unit
    inst = ctx.instances(a)
    dist = {o.id: point_box_distance(cam, o.box) for o in inst}
    far = node.pick == "farthest"
    o = (max if far else min)(inst, key=lambda x: dist[x.id])
    ctx.choice(a, inst, o, f"the {'farthest from' if far else 'nearest to'} the camera",
               {i: d / UNIT_M[unit] for i, d in dist.items()}, unit)
    v = dist[o.id] / UNIT_M[unit]
    expl = (f"from the last camera position (where the video ended) to the closest point of {a.words} "
            f"#{o.id}: {v:.3f} {unit}")
    if node.pick is not None:  # "what's the closest chair to me?": that chair, and how far
        return {"text": f"{a.words} #{o.id}, {v:.1f} {unit} away", "object": o.name, "instance": int(o.id),
                "distance": round(v, 3), "unit": unit}, expl
    return v, expl


def _pair_distance(ctx: Ctx, ref: Ref, inst: list[Any], unit: str) -> tuple[Any, str]:
    """"The distance between the two chairs": two instances of one name; with more, the nearest two (said as
    ambiguous); with fewer, unsupported."""
    name = ref.name
    if len(inst) < 2:  # (the map's name: the phrase may say "two")
        raise Unsupported(f"the map holds {len(inst)} {name if len(inst) == 1 else plural(name)}: no two to "
                          f"measure between")
    d, x, y = closest_pair(inst, inst)
    v = d / UNIT_M[unit]
    ctx.used = [x, y]
    if len(inst) > 2:
        ctx.choice(ref, inst, x, f"the nearest two (#{x.id} and #{y.id})")
    return v, f"closest points of {name} #{x.id} and #{y.id}: {v:.3f} {unit}"


def nearest(node: Nearest, ctx: Ctx) -> tuple[Any, str]:
    if node.origin is None:
        return _viewer_nearest(node, ctx)
    if node.among_everything:
        return _nearest_of_all(node, ctx)
    ref, cands = node.origin, node.candidates
    inst = ctx.require([ref, *cands])
    if len(cands) == 1 and cands[0].name != ref.name and not ctx.options and not node.yesno:
        return _which_instance(ctx, cands[0], ref, inst, node.extreme == "farthest")
    ref_set = BoxSet(inst[ref.name])
    pairs = {c.name: closest_pair(inst[c.name], ref_set) for c in cands if c.name != ref.name}
    dists = {c: p[0] for c, p in pairs.items()}
    if not dists:
        raise Unsupported("no candidate other than the reference object itself")
    pick = (min if node.extreme == "closest" else max)(dists, key=dists.get)
    by_name = {c.name: c for c in cands}
    for c in [ref.name] + list(pairs):
        if c == ref.name:
            ctx.choice(ref, inst[ref.name], pairs[pick][2], f"the one nearest the {by_name[pick].words}")
        elif len(inst[c]) > 1:
            near = nearest_values(inst[c], ref_set, ctx.conf.n_alternatives)
            ctx.choice(by_name[c], inst[c], pairs[c][1], "the nearest", {inst[c][i].id: near[i] for i in sorted(near)},
                       "m")
    ctx.spread = (f"per-view-pair distance of {by_name[pick].words}",
                  ev.distance_values(pairs[pick][1], pairs[pick][2]), "m")
    expl = f"closest-point distances to {ref.words}: " + ", ".join(
        f"{by_name[c].words} {d:.2f} m" for c, d in dists.items())
    if node.yesno:  # "is the tv closer to the table than the cup?": the first candidate wins?
        yes = pick == cands[0].name and len(set(dists.values())) > 1
        return {"text": "yes" if yes else "no", "object": pick, "distances_m": {
            by_name[c].words: round(d, 3) for c, d in dists.items()}}, expl
    return pick, expl


def _viewer_nearest(node: Nearest, ctx: Ctx) -> tuple[Any, str]:
    """"Am I closer to the desk or the sofa?": the candidates' distances from the last camera (where the video
    ended; the nearest instance of each)."""
    cam = ctx.viewer("'closer to me' needs", "which object is closer to another object")[:3, 3]
    inst = ctx.require(list(node.candidates))
    dists = {c: min(point_box_distance(cam, o.box) for o in v) for c, v in inst.items()}
    pick = (max if node.extreme == "farthest" else min)(dists, key=dists.get)
    by_name = {c.name: c for c in node.candidates}
    return pick, "from the last camera position (where the video ended): " + ", ".join(
        f"{by_name[c].words} {d:.2f} m" for c, d in dists.items())


def _which_instance(ctx: Ctx, cand: Ref, ref: Ref, inst: dict[str, list[Any]], far: bool) -> tuple[Any, str]:
    """"Which chair is closest to (farthest from) the tv?": the chair instance by its closest-point distance to
    the tv (the nearest tv to it), not the category name."""
    own, ref_set = inst[cand.name], BoxSet(inst[ref.name])
    per = nearest_values(own, ref_set, 6, largest=far)  # position in own -> distance, best first
    if not per:
        raise Unsupported("no candidate other than the reference object itself")
    o = own[next(iter(per))]
    d, j = ref_set.nearest(o)
    r = ref_set.inst[j]  # which instance is the question, not an ambiguity: only the reference's is one
    ctx.choice(ref, inst[ref.name], r, f"the one nearest {ctx.one(cand)} #{o.id}")
    ctx.spread = (f"per-view-pair distance of {ctx.one(cand)} #{o.id}", ev.distance_values(o, r), "m")
    expl = f"closest-point distances to {ref.words}: " + ", ".join(
        f"{ctx.one(cand)} #{own[i].id} {v:.2f} m" for i, v in per.items())
    return {"text": f"{ctx.one(cand)} #{o.id}", "object": o.name, "instance": int(o.id),
            "distance_m": round(d, 3)}, expl


def _nearest_of_all(node: Nearest, ctx: Ctx) -> tuple[Any, str]:
    """Nearest (farthest) object among everything in the map, other than the reference's own category."""
    ref = node.origin
    rinst = ctx.instances(ref)
    own = {id(o) for o in ctx.find(ref)}
    own |= {id(o) for r in node.exclude for o in ctx.find(r)}  # "..., apart from the bin"
    dist: dict[str, tuple[float, Any]] = {}
    rset = BoxSet(rinst)
    for key, inst in ctx.index.by_key.items():
        others = [o for o in inst if id(o) not in own]
        if others:
            d, o, _ = closest_pair(others, rset)
            dist[key] = (d, o)
    if not dist:
        raise Unsupported(f"the map holds nothing but {ref.words}")
    far = node.extreme == "farthest"
    key = (max if far else min)(dist, key=lambda k: dist[k][0])
    d, o = dist[key]
    ranked = sorted(dist, key=lambda k: dist[k][0], reverse=far)[:4]
    value: Any = {"text": o.name, "object": o.name, "instance": int(o.id), "distance_m": round(d, 3)}
    if ctx.options:
        value = o.name
    return value, f"{'farthest' if far else 'nearest'} to {ref.words}: " + ", ".join(
        f"{k} {dist[k][0]:.2f} m" for k in ranked)
