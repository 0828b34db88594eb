"""Executors of directions (standing at A facing B), left of / behind as the viewer sees it, where an object is,
routes and the order of first appearance."""
from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from ..query.ir import AppearanceOrder, Direction, Forward, Route, ViewDirection, Where
from ..query.vocabulary import name_key, plural
from . import evidence as ev
from .angles import (describe_direction, describe_from_camera, direction_label, in_direction, signed_angle_deg,
                     turn_label)
from .boxes import view_relation
from .context import Ctx
from .spatial import k_nearest
from .result import Unsupported


def _angle(node: Direction, ctx: Ctx) -> tuple[float, str]:
    inst = ctx.require([node.stand, node.face, node.target])
    others = lambda *rs: [o.center for r in rs for o in inst[r.name]]  # noqa: E731
    A, na = ctx.pick_unique(node.stand, others(node.face, node.target))
    B, nb = ctx.pick_unique(node.face, [A.center])
    C, nc = ctx.pick_unique(node.target, [A.center, B.center])
    f = B.center[:2] - A.center[:2]
    if np.linalg.norm(f) < 1e-9:
        raise Unsupported(f"standing by {node.stand.words} and facing {node.face.words}: same position")
    th = signed_angle_deg(f, C.center[:2] - A.center[:2])
    ctx.spread = ("per-view angle", ev.angle_values(A, B, C, th), "deg")
    by_order = (f"; where I stand read as the {node.stand.words}: the object named before what I face (no place "
                f"word such as 'at' or 'by')") if node.stand_by_order else ""
    return th, (f"at {node.stand.words} facing {node.face.words}: {node.target.words} at {th:+.1f} deg "
                f"(counter-clockwise){na}{nb}{nc}{by_order}")


def _back_deg(node: Direction, ctx: Ctx) -> float:
    return float(node.back_deg) if node.back_deg is not None else ctx.conf.back_deg


def direction(node: Direction, ctx: Ctx) -> tuple[Any, str]:
    if node.granularity != "free":
        th, expl = _angle(node, ctx)
        lab = direction_label(th, node.granularity, _back_deg(node, ctx))
        return lab, f"{expl} -> {lab}"
    asked = list(node.asked)
    if node.candidates:
        return _direction_choice(node, ctx, asked)
    th, expl = _angle(node, ctx)
    d = describe_direction(th, _back_deg(node, ctx))
    if len(asked) == 1:
        hit = in_direction(d, asked[0])
        shown = d["words"]
        if asked[0] in ("front", "back") and shown in ("to the left", "to the right"):  # 67-113 deg: say the
            shown = f"{'ahead' if d['front_back'] == 'front' else 'behind'} and {shown}"  # half it is in
        d["text"] = ("yes" if hit else "no") + f" ({shown})"
        d["asked"], d["answer"] = asked[0], hit
    else:
        d["text"] = d["words"]
    return d, f"{expl} -> {d['words']}"


def _direction_choice(node: Direction, ctx: Ctx, asked: list[str]) -> tuple[Any, str]:
    """"Standing by A facing B, what's on my right: the C or the D?" -> the candidates in that direction."""
    if len(asked) != 1:
        raise Unsupported("several objects and several directions: ask 'is the C on my left?' per object")
    where: dict[str, dict[str, Any]] = {}
    expls = []
    for c in node.candidates:
        th, e = _angle(replace(node, target=c, candidates=()), ctx)
        where[c.name] = describe_direction(th, _back_deg(node, ctx))
        expls.append(e)
    words = {c.name: c.words for c in node.candidates}
    hits = [n for n, d in where.items() if in_direction(d, asked[0])]
    text = " and ".join(words[n] for n in hits) if hits else "none of them"
    return {"text": text, "matches": hits, "asked": asked[0], "directions": where}, "; ".join(expls)


def view_direction(node: ViewDirection, ctx: Ctx) -> tuple[Any, str]:
    """"Is A to the left of B?" as the viewer sees them: from the last camera, looking at B, A's bearing left or
    right of B's, and in front of / behind B by its distance along that line."""
    T = ctx.viewer("'left of' and 'behind' need", "'standing by the X facing the Y, is the Z on my left?'")
    a, b, asked = node.object, node.reference, node.asked
    inst = ctx.require([a, b])
    B, nb = ctx.pick_unique(b, [o.center for o in inst[a.name]])
    A, na = ctx.pick_unique(a, [B.center])
    side, fb, th, along = view_relation(A, B, T)
    yes = asked == side if asked in ("left", "right") else asked == fb
    words = (f"seen from the last camera view: the {a.words} is {abs(th):.0f} deg to the {side} of the "
             f"{b.words} and {abs(along):.1f} m {'behind' if fb == 'back' else 'in front of'} it{na}{nb}")
    return {"text": "yes" if yes else "no", "answer": yes, "side": side, "front_back": fb,
            "angle_deg": round(th, 1), "behind_m": round(along, 3)}, words


def where(node: Where, ctx: Ctx) -> tuple[Any, str]:
    """Where an object is: its nearest other objects (closest points) and, when the map has a camera track, its
    direction from the last camera; several instances: each of them (the first four by id)."""
    ref = node.object
    inst = ctx.instances(ref)
    rel = node.relative_to
    refs = {id(x) for x in ctx.instances(rel)} - {id(x) for x in inst} if rel is not None else set()
    if rel is not None and not refs:
        raise Unsupported(f"'{ref.words}' relative to itself")
    each = [_where_one(ctx, o, inst, refs) for o in sorted(inst, key=lambda x: x.id)[:4]]
    if len(inst) == 1:
        verb = "are" if name_key(ref.words) != ref.words.lower() else "is"  # "the office chairs are"
        words = each[0].pop("words")
        text = f"the {ref.words} {verb} " + (", ".join(words) if words else "the only object in the map")
        return {**each[0], "text": text}, text
    many = ref.words if name_key(ref.words) != ref.words.lower() else plural(ref.words)
    text = f"{len(inst)} {many}: " + "; ".join(f"#{v['instance']} " + ", ".join(v.pop("words")) for v in each)
    if len(inst) > len(each):
        text += f"; and {len(inst) - len(each)} more"
    return {"text": text, "object": inst[0].name, "n_instances": len(inst), "instances": each}, text


def _where_one(ctx: Ctx, o: Any, own: list[Any], refs: set[int]) -> dict[str, Any]:
    """One instance's place: its `n_landmarks` nearest other objects (those in `refs` first: "relative to the
    desk") and its direction from the last camera; "words" is the text of each."""
    bs = ctx.index.boxes
    allow = np.ones(len(bs), bool)
    allow[[bs.pos[id(x)] for x in own if id(x) in bs.pos]] = False
    if refs:  # the reference's nearest instance, then the nearest others
        is_ref = np.zeros(len(bs), bool)
        is_ref[[bs.pos[i] for i in (id(x) for x in bs.inst) if i in refs]] = True
        found = k_nearest(o, bs, 1, allow & is_ref) + k_nearest(o, bs, ctx.conf.n_landmarks, allow & ~is_ref)
    else:
        found = k_nearest(o, bs, ctx.conf.n_landmarks, allow)
    near = [(d, bs.inst[j]) for d, j in found]
    marks = [{"object": x.name, "instance": int(x.id), "distance_m": round(float(d), 3)}
             for d, x in near[:ctx.conf.n_landmarks]]
    value: dict[str, Any] = {"object": o.name, "instance": int(o.id), "centre": np.round(o.center, 3).tolist(),
                             "landmarks": marks}
    words = [f"touching the {m['object']}" if m["distance_m"] < 0.05 else
             f"{m['distance_m']:.1f} m from the {m['object']}" for m in marks]
    if ctx.map.cameras:
        cam = describe_from_camera(ctx.map.cameras[-1][1], o.center, ctx.conf.back_deg)
        value["camera"] = cam
        of = "" if cam["words"] == "behind" else " of"  # "behind the last camera view", not "behind of"
        words.insert(0, f"{cam['words']}{of} the last camera view, {cam['distance_m']:.1f} m away")
    value["words"] = words
    return value


def room_centre(smap: Any) -> np.ndarray:
    """[2] the centroid of the map's floor outline (its room, else the hull of its boxes)."""
    poly = np.asarray(smap.extent().polygon, float)
    x, y = poly[:, 0], poly[:, 1]
    cross = x * np.roll(y, -1) - np.roll(x, -1) * y
    area = cross.sum() / 2.0
    if abs(area) < 1e-9:
        return poly.mean(0)
    return np.array([((x + np.roll(x, -1)) * cross).sum(), ((y + np.roll(y, -1)) * cross).sum()]) / (6.0 * area)


def _route_start(node: Route, ctx: Ctx, first: Any) -> tuple[Any, np.ndarray, str]:
    """(start instance, heading [2], how): beginning at the start facing the facing object; "at the tv facing the
    tv" stands at it and faces it from the room (heading from the room's centre to it: objects face the room)."""
    start = ctx.select(node.start, ctx.find(node.start))
    if node.start.name == node.face.name:
        near = first.center[:2] if first is not None else room_centre(ctx.map)
        a = min(start, key=lambda o: float(np.linalg.norm(o.center[:2] - near)))
        ctx.choice(node.start, start, a, "the one nearest the first waypoint")
        heading = a.center[:2] - room_centre(ctx.map)
        if np.linalg.norm(heading) < 1e-6:
            raise Unsupported(f"beginning at the {node.start.words} facing it: it stands at the room's centre, so "
                              f"which way it faces is unknown")
        return a, heading, (f"at the {node.start.words} facing it from the room (heading from the room's centre "
                            f"to it); ")
    face_all = ctx.find(node.face)
    face = ctx.select(node.face, face_all, viewer_xy=start[0].center[:2]) if len(start) == 1 else face_all
    pairs = [(a, b) for a in start for b in (face if len(start) == 1 else  # "facing the closest sofa": from there
                                             ctx.select(node.face, face_all, viewer_xy=a.center[:2])) if a is not b]
    if not pairs:
        raise Unsupported(f"beginning at {node.start.name} facing the same {node.face.name}: heading unknown")
    a, b = min(pairs, key=lambda ab: float(np.linalg.norm(ab[0].center[:2] - ab[1].center[:2])))
    ctx.choice(node.start, start, a, f"the one nearest the {node.face.words}")
    ctx.choice(node.face, face, b, f"the one nearest the {node.start.words}")
    return a, b.center[:2] - a.center[:2], ""


def route(node: Route, ctx: Ctx) -> tuple[Any, str]:
    """Start at the start's centre heading to the facing object's centre; "go forward until X" moves to X's
    centre (its instance nearest the previous waypoint, after X's own selectors) and sets the heading along the
    move; each turn is the heading change towards the next waypoint: back when |turn| >= back_deg, else left /
    right by its sign."""
    forwards = [s.to for s in node.steps if isinstance(s, Forward)]
    ctx.require([node.start, node.face, *forwards], select=False)
    first = ctx.find(forwards[0])[0] if forwards else None
    a, heading, how = _route_start(node, ctx, first)
    ctx.used.append(a)
    pos = a.center[:2].copy()
    turns, log = [], []
    pending = False
    for s in node.steps:
        if not isinstance(s, Forward):
            pending = True
            continue
        cands = ctx.select(s.to, ctx.find(s.to), viewer_xy=pos)
        tgt = min(cands, key=lambda o: float(np.linalg.norm(o.center[:2] - pos)))
        ctx.choice(s.to, ctx.find(s.to), tgt, "the one nearest the previous waypoint")
        ctx.used.append(tgt)
        move = tgt.center[:2] - pos
        if np.linalg.norm(move) < 1e-6:
            if pending:
                raise Unsupported(f"turn towards {s.to.name}: already there")
            continue
        if pending:
            th = signed_angle_deg(heading, move)
            turns.append(turn_label(th, ctx.conf.back_deg))
            log.append(f"{turns[-1]} ({th:+.0f} deg) to {s.to.name}")
            pending = False
        pos, heading = tgt.center[:2].copy(), move
    if pending:
        raise Unsupported("a turn without a following waypoint")
    return [t.title() for t in turns], how + "; ".join(log)


def appearance_order(node: AppearanceOrder, ctx: Ctx) -> tuple[Any, str]:
    cats = node.categories
    inst = ctx.require(list(cats))
    first = {}
    for c in cats:
        ts = [o.first_seen for o in inst[c.name] if o.first_seen is not None]
        if not ts:
            raise Unsupported(f"the map has no first-seen time for {c.name} (built without video)")
        first[c.name] = min(ts)
    order = sorted(dict.fromkeys(c.name for c in cats), key=lambda c: first[c])
    return order, "first seen: " + ", ".join(f"{c} {first[c]:.2f} s" for c in order)
