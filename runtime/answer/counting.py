"""Executors of counts, is-there questions, more-or-fewer and lists (what is where)."""
from __future__ import annotations

from collections import Counter
from typing import Any, Iterable, Iterator

import numpy as np

from ..query.ir import (Count, CountCompare, Described, Exists, List, NearestTo, Ref, Relation, SeenSide, StanceSide,
                        Superlative, ViewerSide)
from ..query.vocabulary import plural
from . import evidence as ev
from .angles import describe_direction, describe_from_camera, in_direction, signed_angle_deg
from .boxes import aabb_gaps, half_extents, relation_holds, view_relation
from .context import Ctx, is_everything
from .result import Unsupported

# a side of a viewer or of an object, in words ("what is to the left of the desk?")
SIDE_WORDS = {"left": "to the left of", "right": "to the right of", "front": "in front of", "back": "behind"}


def located(ctx: Ctx, ref: Ref, where: Relation) -> tuple[list[Any], list[Any], str]:
    """(instances of `ref` (every object but the reference's category for "*") that are `where.relation` an
    instance of `where.object`, the candidates, the rule in words)."""
    refs = ctx.instances(where.object)
    rel = where.relation
    pairs = [(r, None) for r in refs]
    if rel == "between":  # "between the desk and the couch": any instance of each
        pairs = [(r, q) for r in refs for q in ctx.instances(where.object2) if q is not r]
    if ref.name == "*":
        own = {id(o) for w in (where.object, where.object2) if w is not None for o in ctx.find(w)}
        cands = [o for o in ctx.map.instances if id(o) not in own]
    else:
        ctx.missing([ref])
        cands = ctx.select(ref, ctx.find(ref))
    keep = [o for o in cands if any(relation_holds(o, r, rel, ctx.conf, q) for r, q in _pairs_near(o, pairs, rel, ctx)
                                    if r is not o and q is not o)]
    if where.negate:  # "cups not on the table": the candidates the relation does not hold for
        keep = [o for o in cands if not any(o is k for k in keep)]
    ctx.used += keep  # the evidence: the reference and what was counted, not every candidate
    rule = {"on": f"bottom within {ctx.conf.on_gap_m * 100:.0f} cm of its top, centre over it",
            "near": f"closest points within {ctx.conf.near_m:.2f} m", "in": "centre inside its box",
            "under": "centre within its footprint, below its top",
            "above": "over its footprint, bottom at or above its top",
            "between": "centre inside the top-view hull of their footprints"}[rel]
    ids = " ".join(f"#{o.id}" for o in keep)
    neg = "not " if where.negate else ""
    place = f"the {where.object.words}" + (f" and the {where.object2.words}" if rel == "between" else "")
    return keep, cands, f"{neg}{rel} {place} ({rule}){': ' + ids if ids else ''}"


class _Near:
    """The reference boxes of a location in a 2D KD-tree (xy centres): a candidate is tested only against those
    whose footprint can hold its centre or, for "near", whose box can be within `near_m` of its box."""

    def __init__(self, pairs: list[tuple[Any, Any]], rel: str, conf: Any):
        from scipy.spatial import cKDTree

        self.pairs, self.rel = pairs, rel
        c, e = half_extents([r for r, _ in pairs])
        self.c, self.e = c, e
        self.tree = cKDTree(c[:, :2])
        dims = slice(0, 3) if rel == "near" else slice(0, 2)  # near: whole boxes; else a footprint holds a centre
        self.reach = float(np.linalg.norm(e[:, dims], axis=1).max())
        self.margin = conf.near_m if rel == "near" else 0.0

    def around(self, o: Any) -> Iterator[tuple[Any, Any]]:
        """The pairs that can hold for `o`: its nearest few first (usually enough), then the rest in reach."""
        co, eo = half_extents([o])
        ro = float(np.linalg.norm(eo[0])) if self.rel == "near" else 0.0
        xy, reach = np.asarray(o.center, float)[:2], self.reach + self.margin + ro
        seen: set[int] = set()
        _, first = self.tree.query(xy, k=min(8, len(self.pairs)))
        for stage in (sorted(int(i) for i in np.atleast_1d(first)), sorted(self.tree.query_ball_point(xy, reach))):
            idx = [i for i in stage if i not in seen and float(np.linalg.norm(self.c[i, :2] - xy)) <= reach]
            seen.update(idx)
            if self.rel == "near" and idx:  # boxes whose bounds are farther than near_m cannot be near
                idx = [i for i, g in zip(idx, aabb_gaps(co[0], eo[0], self.c[idx], self.e[idx]))
                       if g <= self.margin + 1e-9]
            yield from (self.pairs[i] for i in idx)


def _pairs_near(o: Any, pairs: list[tuple[Any, Any]], rel: str, ctx: Ctx) -> Iterable[tuple[Any, Any]]:
    """The (reference, second reference) pairs of a location that can hold for instance `o` (all of them for
    "between": its hull of two footprints is not culled here); the caller stops at the first that holds."""
    if rel == "between" or len(pairs) < 16:
        return pairs
    near = ctx.cache.get(("near", id(pairs)))
    if near is None:
        near = ctx.cache[("near", id(pairs))] = _Near(pairs, rel, ctx.conf)
    return near.around(o)


def selector_phrase(ref: Ref) -> str:
    """The question's words for a selected instance ("biggest chairs", "red chair", "near the door")."""
    for s in ref.select:
        if isinstance(s, Described):
            return s.phrase
    sup = [s.word for s in ref.select if isinstance(s, Superlative)]
    if sup:
        return " ".join(sup + [ref.words])
    near = [s.name for s in ref.select if isinstance(s, NearestTo)]
    return "near the " + near[0] if near else ref.words


def count(node: Count, ctx: Ctx) -> tuple[Any, str]:
    first = node.objects[0]
    if node.where is not None:
        keep, cands, how = located(ctx, first, node.where)
        what = "object(s)" if first.name == "*" else first.words
        return len(keep), f"{len(keep)} of {len(cands)} {what} {how}"
    if len(node.objects) > 1:  # one count per object; a name the map lacks counts 0
        inst = {r.name: (r, ctx.find(r)) for r in node.objects}
        ctx.used += [o for _, v in inst.values() for o in v]
        counts = {r.words: len(v) for r, v in inst.values()}
        text = ", ".join(f"{len(v)} {n if len(v) == 1 else plural(n)}" for n, (_, v) in inst.items())
        return {"text": text, "counts": counts}, "; ".join(f"{n}: {k} in the map" for n, k in counts.items())
    if first.select and not is_everything(first):
        raise Unsupported(f"counting only some {first.words} ('{selector_phrase(first)}') is not supported; ask how many "
                          f"{first.words} there are")
    if is_everything(first):
        everything = list(ctx.map.instances)
        ctx.used += everything  # the evidence: every instance counted
        by = Counter(o.name for o in everything)
        parts = ", ".join(f"{k} {name if k == 1 else plural(name)}" for name, k in by.most_common())
        return len(everything), f"{len(everything)} object(s) in the map" + (f": {parts}" if parts else "")
    inst = ctx.instances(first)
    ctx.spread = ("per-view count", ev.count_values(inst), None)
    return len(inst), f"{len(inst)} instance(s) of {first.words} in the map"


def count_compare(node: CountCompare, ctx: Ctx) -> tuple[Any, str]:
    """More (fewer) of a than of b: instance counts in the map (a name the map lacks counts 0, said so, as an
    is-there question says "no"); yes/no, the name with more (fewer), or the difference."""
    a, b = node.a, node.b
    ia, ib = ctx.find(a), ctx.find(b)
    ctx.used += ia + ib
    na, nb = len(ia), len(ib)
    expl = "; ".join(f"{r.words}: {n} in the map" for r, n in ((a, na), (b, nb)))
    more = node.compare == "more"
    counts = {a.words: na, b.words: nb}
    if node.form == "difference":
        d = (na - nb) if more else (nb - na)
        word = "more" if more else "fewer"
        text = str(d) if d >= 0 else f"none: {-d} {'fewer' if more else 'more'}, not {word}"
        return {"text": text, "difference": d, "counts": counts}, expl
    if node.form == "which":
        if na == nb:
            return {"text": f"neither: {na} each", "counts": counts}, expl
        return (a.name if (na > nb) == more else b.name), expl
    yes = na > nb if more else na < nb
    return {"text": "yes" if yes else "no", "counts": counts}, expl


def _count_holds(node: Exists, found: dict[str, int]) -> tuple[bool, str]:
    """Is-there with a number ("are there two chairs?": exactly 2; "more than one"): (holds, the rule in words);
    without one, whether any was found."""
    c = node.count
    if c is None:
        return any(found.values()), ""
    n = sum(found.values())
    holds = {"==": n == c.n, ">": n > c.n, ">=": n >= c.n, "<": n < c.n, "<=": n <= c.n}[c.op]
    return holds, f" (asked: {c.op} {c.n})"


def exists(node: Exists, ctx: Ctx) -> tuple[Any, str]:
    if node.where is not None:  # "is there a cup on the table?": a missing cup is "no", a missing table not found
        ctx.missing([node.where.object])
        found, parts = {}, []
        for r in node.objects:
            keep, _, how = located(ctx, r, node.where) if r.name == "*" or ctx.find(r) else ([], [], "in the map")
            what = "object(s)" if r.name == "*" else r.words
            found[what] = len(keep)
            parts.append(f"{what}: {len(keep)} {how}")
        yes, asked = _count_holds(node, found)
        return {"text": "yes" if yes else "no", "exists": yes, "counts": found}, "; ".join(parts) + asked
    for r in node.objects:
        if r.select:
            raise Unsupported(f"'is there a {r.words} ...' with a condition is not supported; ask whether there is "
                              f"a {r.words} at all")
    ctx.used += [o for r in node.objects for o in ctx.find(r)]  # the evidence: what was found
    found = {r.words: len(ctx.find(r)) for r in node.objects}
    yes = all(found.values()) if node.all else any(found.values())
    if node.count is not None:
        yes, asked = _count_holds(node, found)
        return {"text": "yes" if yes else "no", "exists": yes, "counts": found}, "; ".join(
            f"{k}: {v} in the map" for k, v in found.items()) + asked
    hints = {r.words: ctx.index.hints(r.words, ctx.conf.n_hints) for r in node.objects if not found[r.words]}
    expl = "; ".join(f"{k}: {v} in the map" for k, v in found.items())
    if any(hints.values()):  # a name the map may hold in other words ("desk lamp": the map's lamp)
        expl += "; similar names in the map: " + "; ".join(f"{k} -> {', '.join(v)}" for k, v in hints.items() if v)
    return {"text": "yes" if yes else "no", "exists": yes, "counts": found}, expl


def _on_my_side(ctx: Ctx, side: str) -> tuple[list[Any], str]:
    """Every object on that side (left | right | front | back) of the viewer: the last camera (where the video
    ended), as `describe_from_camera` reads their centres; left/right exclude straight ahead and behind."""
    words = SIDE_WORDS[side]
    T = ctx.viewer(f"'{words} me' needs", "'standing by the X facing the Y, is the Z on my left?'")
    inst = [o for o in ctx.map.instances if in_direction(describe_from_camera(T, o.center, ctx.conf.back_deg), side)]
    return inst, f"{words} the last camera view (where the video ended)"


def _seen_beside(ctx: Ctx, reference: Ref, asked: str) -> tuple[list[Any], str]:
    """Every other object to the left / right of, in front of / behind `reference` as seen from the last camera
    (`boxes.view_relation`)."""
    T = ctx.viewer("'left of' and 'behind' need", "'standing by the X facing the Y, what is on my left?'")
    refs = ctx.instances(reference)
    B, nb = ctx.pick_unique(reference, [])
    inst = []
    for o in ctx.map.instances:
        if any(o is r for r in refs):
            continue
        side, fb, _, _ = view_relation(o, B, T)
        if (side if asked in ("left", "right") else fb) == asked:
            inst.append(o)
    return inst, f"{SIDE_WORDS[asked]} the {reference.words} #{B.id} seen from the last camera view{nb}"


def _on_side_of(ctx: Ctx, position: Ref, facing: Ref, side: str) -> tuple[list[Any], str]:
    """Every other object on that side of someone standing at `position` facing `facing` (box centres, the
    same readings as a direction question: left / right exclude straight ahead and behind)."""
    A, na = ctx.pick_unique(position, [o.center for o in ctx.instances(facing)])
    B, nb = ctx.pick_unique(facing, [A.center])
    f = B.center[:2] - A.center[:2]
    if np.linalg.norm(f) < 1e-9:
        raise Unsupported(f"standing by {position.words} and facing {facing.words}: same position")
    inst = [o for o in ctx.map.instances if o is not A and o is not B and in_direction(
        describe_direction(signed_angle_deg(f, o.center[:2] - A.center[:2]), ctx.conf.back_deg), side)]
    return inst, f"{SIDE_WORDS[side]} someone at the {position.words} facing the {facing.words}{na}{nb}"


def list_objects(node: List, ctx: Ctx) -> tuple[Any, str]:
    how = ""
    r = node.region
    if isinstance(r, ViewerSide):  # "what is to my left?"
        inst, how = _on_my_side(ctx, r.side)
    elif isinstance(r, SeenSide):  # "what is to the left of the couch?", as the viewer sees it
        inst, how = _seen_beside(ctx, r.reference, r.side)
    elif isinstance(r, StanceSide):  # "standing at the desk facing the door, what is on my left?"
        inst, how = _on_side_of(ctx, r.stand, r.face, r.side)
    elif isinstance(r, Relation):  # "what's on the table?": every object there
        inst, _, how = located(ctx, Ref("*"), r)
    elif node.objects:
        ctx.missing(list(node.objects))
        inst = [o for x in node.objects for o in ctx.find(x)]
    else:
        inst = list(ctx.map.instances)
    if not isinstance(r, Relation):  # the evidence: what was listed (`located` records its own)
        ctx.used += inst
    counts = dict(Counter(o.name for o in inst))  # in order of first appearance, as the JSON lists them
    text = ", ".join(f"{c} {n if c == 1 else plural(n)}" for n, c in sorted(counts.items())) or "nothing"
    value = {"text": text, "counts": counts,
             "instances": [{"object": o.name, "instance": int(o.id), "centre": np.round(o.center, 3).tolist()}
                           for o in inst]}
    return value, f"{len(inst)} object(s) {how or 'in the map'}: {text}"
