"""VSI-Bench ground truth from oriented 3D boxes only (the checker, independent of the map reasoner).

This module is the answer key for generated questions (synthetic scenes, the real-room benchmark). It shares no
code with `runtime/answer.py` (the reasoner under test) nor with `runtime/geometry.py`: its geometry is its own
small numpy code, so a bug in the reasoner's geometry cannot make both agree. It is checked against the real
benchmark's own answers (tests/test_box_truth.py: every question of the shared VSI-Bench set recomputed from its
meta_info boxes).

Boxes are VSI-Bench meta_info `object_bbox` entries: centroid, axesLengths (full lengths, m), normalizedAxes
(row-major 3x3, rows = the box axes), z up. Definitions (the benchmark's):
- counting: number of boxes of the category;
- size: longest box side in cm, rounded to an integer (the largest instance when there are several);
- absolute distance: distance between the closest points of the two solid boxes (m), over instance pairs;
- relative distance: the candidate whose closest instance is nearest (closest points) to the target
  (`nearest_of_all`: among every other category);
- directions, on the floor plane, standing at the centre of the `stand` box facing the centre of the `face` box,
  θ = counter-clockwise angle (left positive) of the `obj` centre: easy "left" for 0 < θ < 180 else "right";
  medium "back" when the turn is at least 135° (135 <= θ <= 225), else left/right; hard the quadrants
  front-left [0, 90), back-left [90, 180), back-right [180, 270), front-right [270, 360);
- route: from the start centre heading to the facing centre, each waypoint's turn is back (|turn| >= 135°),
  left (turn > 0) or right;
- room size: the meta entry's `room_size` (m², 1 decimal) when it has one.

Closest points (`box_gap`): two solid boxes overlap iff no separating axis exists among the 15 candidates (3 + 3
face normals, 9 edge cross products); then the gap is 0. Otherwise some closest pair has a vertex of one box on
it, or lies in the interiors of one edge of each box (a face-face or edge-face closest pair can always be slid
to a vertex or an edge-edge pair without changing the distance). So the gap is exactly the minimum of the 16
vertex-to-solid-box distances (clamping in the box frame) and of the 144 edge-pair line distances whose
closest points fall inside both edges — no sampling, no optimiser, exact up to float rounding.

`generate_questions` writes questions in the benchmark's wording and schema from one meta entry; objects that
stand for a position are categories with exactly one box; boundary margins are explicit (`Margins`) and every
rule's removals are counted per type.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Any

import numpy as np

# ----------------------------------------------------------------------------- boxes

_SIGNS = np.array(list(itertools.product((-1.0, 1.0), repeat=3)))  # [8, 3], corner i <-> signs i
_EDGES = np.array([(i, j) for i in range(8) for j in range(i + 1, 8)
                   if np.sum(_SIGNS[i] != _SIGNS[j]) == 1])  # [12, 2], corners differing in one sign


@dataclass
class Box:
    """One annotated object: category, centroid [3], axes_lengths [3] (full, m), axes [3, 3] (rows = unit axes)."""

    category: str
    centroid: np.ndarray
    axes_lengths: np.ndarray
    axes: np.ndarray

    @classmethod
    def from_meta(cls, d: dict[str, Any], category: str = "") -> "Box":
        """From a meta_info `object_bbox` entry (`centroid`, `axesLengths`, `normalizedAxes` row-major 3x3)."""
        return cls(category, np.asarray(d["centroid"], float).reshape(3),
                   np.asarray(d["axesLengths"], float).reshape(3),
                   np.asarray(d["normalizedAxes"], float).reshape(3, 3))

    def corners(self) -> np.ndarray:
        """[8, 3] corners; corner i has the half-length signs `_SIGNS[i]`."""
        return self.centroid + (_SIGNS * (self.axes_lengths / 2.0)) @ self.axes

    def distance_to_points(self, pts: np.ndarray) -> np.ndarray:
        """Distance [N] of points [N, 3] to the solid box (0 inside)."""
        local = (np.asarray(pts, float) - self.centroid) @ self.axes.T
        out = np.maximum(np.abs(local) - self.axes_lengths / 2.0, 0.0)
        return np.sqrt((out ** 2).sum(1))


def room_boxes(meta_entry: dict[str, Any]) -> list[Box]:
    """Every box of a meta_info scene entry (`object_bbox`: {category: [box, ...]})."""
    return [Box.from_meta(b, cat) for cat, bs in meta_entry["object_bbox"].items() for b in bs]


def _of(boxes: list[Box], cat: str) -> list[Box]:
    got = [b for b in boxes if b.category == cat]
    if not got:
        raise KeyError(f"no box of category {cat!r}")
    return got


def _one(boxes: list[Box], cat: str) -> Box:
    got = _of(boxes, cat)
    if len(got) != 1:
        raise ValueError(f"{cat!r} stands for a position but has {len(got)} boxes")
    return got[0]


# ----------------------------------------------------------------------------- closest points

def _separated(a: Box, b: Box, eps: float = 1e-12) -> bool:
    """Separating-axis test over the 15 candidate axes, projecting all corners."""
    ca, cb = a.corners(), b.corners()
    cand = list(a.axes) + list(b.axes) + [np.cross(u, v) for u in a.axes for v in b.axes]
    for n in cand:
        if n @ n < eps:  # parallel edges: covered by the face normals
            continue
        pa, pb = ca @ n, cb @ n
        if pa.max() < pb.min() or pb.max() < pa.min():
            return True
    return False


def _edge_pairs_gap(a: Box, b: Box) -> float:
    """Smallest distance between an edge of a and an edge of b whose closest points lie inside both edges."""
    ca, cb = a.corners(), b.corners()
    p0, d1 = ca[_EDGES[:, 0]][:, None], (ca[_EDGES[:, 1]] - ca[_EDGES[:, 0]])[:, None]  # [12, 1, 3]
    q0, d2 = cb[_EDGES[:, 0]][None], (cb[_EDGES[:, 1]] - cb[_EDGES[:, 0]])[None]  # [1, 12, 3]
    r = p0 - q0
    aa, ee = (d1 * d1).sum(-1), (d2 * d2).sum(-1)
    bb, cc, ff = (d1 * d2).sum(-1), (d1 * r).sum(-1), (d2 * r).sum(-1)
    den = aa * ee - bb * bb
    ok = den > 1e-12 * np.maximum(aa * ee, 1e-30)  # non-parallel, non-degenerate edges
    den = np.where(ok, den, 1.0)
    s = (bb * ff - cc * ee) / den
    t = (aa * ff - bb * cc) / den
    ok &= (s >= 0) & (s <= 1) & (t >= 0) & (t <= 1)
    if not ok.any():
        return np.inf
    gap = np.linalg.norm(p0 + s[..., None] * d1 - (q0 + t[..., None] * d2), axis=-1)
    return float(gap[ok].min())


def box_gap(a: Box, b: Box) -> float:
    """Exact distance (m) between the closest points of two solid oriented boxes; 0 when they overlap."""
    if not _separated(a, b):
        return 0.0
    vert = min(float(b.distance_to_points(a.corners()).min()), float(a.distance_to_points(b.corners()).min()))
    return min(vert, _edge_pairs_gap(a, b))


def _gap(boxes: list[Box], a: str, b: str) -> float:
    return min(box_gap(x, y) for x in _of(boxes, a) for y in _of(boxes, b) if x is not y)


# ----------------------------------------------------------------------------- truth functions

def count(boxes: list[Box], cat: str) -> int:
    return sum(b.category == cat for b in boxes)


def longest_side_cm(boxes: list[Box], cat: str) -> int:
    return int(round(100.0 * max(float(b.axes_lengths.max()) for b in _of(boxes, cat))))


def abs_distance_m(boxes: list[Box], a: str, b: str) -> float:
    """Closest-point distance (m, unrounded) between categories a and b (nearest instance pair)."""
    return _gap(boxes, a, b)


def candidate_distances(boxes: list[Box], target: str, candidates: list[str]) -> dict[str, float]:
    return {c: _gap(boxes, target, c) for c in candidates}


def closest_of(boxes: list[Box], target: str, candidates: list[str]) -> str:
    d = candidate_distances(boxes, target, candidates)
    return min(candidates, key=lambda c: d[c])


def nearest_of_all(boxes: list[Box], target: str) -> str:
    """The category (other than target's) whose nearest box is closest to any box of target (closest points)."""
    others = sorted({b.category for b in boxes} - {target})
    return closest_of(boxes, target, others)


def _bearing(p: np.ndarray, q: np.ndarray) -> float:
    """Heading (deg) of q seen from p on the floor plane, counter-clockwise from +x."""
    return float(np.degrees(np.arctan2(q[1] - p[1], q[0] - p[0])))


def direction_angle(boxes: list[Box], stand: str, face: str, obj: str) -> float:
    """θ in [0, 360): counter-clockwise angle of obj's centre from the facing direction stand -> face."""
    s, f, o = (_one(boxes, n).centroid for n in (stand, face, obj))
    return (_bearing(s, o) - _bearing(s, f)) % 360.0


DIRECTION_WORDS = {"easy": ("left", "right"), "medium": ("left", "right", "back"),
                   "hard": ("front-left", "front-right", "back-left", "back-right")}
DIRECTION_BOUNDS = {"easy": (0.0, 180.0), "medium": (0.0, 135.0, 225.0), "hard": (0.0, 90.0, 180.0, 270.0)}


def direction_word(theta: float, level: str) -> str:
    th = theta % 360.0
    if level == "easy":
        return "left" if 0.0 < th < 180.0 else "right"
    if level == "medium":
        return "back" if 135.0 <= th <= 225.0 else ("left" if th < 180.0 else "right")
    if level == "hard":
        return ("front-left", "back-left", "back-right", "front-right")[int(th // 90.0) % 4]
    raise ValueError(f"direction level {level!r}: expected easy, medium or hard")


def direction(boxes: list[Box], stand: str, face: str, obj: str, level: str) -> str:
    return direction_word(direction_angle(boxes, stand, face, obj), level)


def turn_word(turn_deg: float) -> str:
    """'Turn Back' / 'Turn Left' / 'Turn Right' for a signed heading change (counter-clockwise +, (-180, 180])."""
    return "Turn Back" if abs(turn_deg) >= 135.0 else ("Turn Left" if turn_deg > 0 else "Turn Right")


def route_turn_angles(boxes: list[Box], start: str, face: str, waypoints: list[str]) -> list[float]:
    """Signed turn (deg) before each forward move: start at start's centre heading to face's centre; moving to
    a waypoint's centre sets the heading along the move. The first waypoint is usually `face` itself."""
    pos = _one(boxes, start).centroid
    heading = _bearing(pos, _one(boxes, face).centroid)
    out = []
    for w in waypoints:
        nxt = _one(boxes, w).centroid
        move = _bearing(pos, nxt)
        out.append((move - heading + 180.0) % 360.0 - 180.0)
        pos, heading = nxt, move
    return out


def route_turns(boxes: list[Box], start: str, face: str, waypoints: list[str]) -> list[str]:
    return [turn_word(t) for t in route_turn_angles(boxes, start, face, waypoints)]


def room_size_m2(meta_entry: dict[str, Any]) -> float | None:
    v = meta_entry.get("room_size")
    return None if v is None else float(v)


# ----------------------------------------------------------------------------- question generation

Q_COUNT = "How many {a}(s) are in this room?"
Q_SIZE = ("What is the length of the longest dimension (length, width, or height) of the {a}, measured in "
          "centimeters?")
Q_ROOM = ("What is the size of this room (in square meters)? \nIf multiple rooms are shown, estimate the size of "
          "the combined space.")
Q_ABS = ("Measuring from the closest point of each object, what is the distance between the {a} and the {b} "
         "(in meters)?")
Q_REL = "Measuring from the closest point of each object, which of these objects ({cands}) is the closest to the {a}?"
Q_DIR = {"easy": "If I am standing by the {a} and facing the {b}, is the {c} to the left or the right of the {b}?",
         "medium": ("If I am standing by the {a} and facing the {b}, is the {c} to my left, right, or back?\nAn "
                    "object is to my back if I would have to turn at least 135 degrees in order to face it."),
         "hard": ("If I am standing by the {a} and facing the {b}, is the {c} to my front-left, front-right, "
                  "back-left, or back-right?\nThe directions refer to the quadrants of a Cartesian plane (if I am "
                  "standing at the origin and facing along the positive y-axis).")}
Q_ROUTE = ("You are a robot beginning at the {a} facing the {b}. You want to navigate to the {d}. You will perform "
           "the following actions (Note: for each [please fill in], choose either 'turn back,' 'turn left,' or "
           "'turn right.'): {steps}. You have reached the final destination.")
TURN_WORDS = ("Turn Back", "Turn Left", "Turn Right")

BOX_QTYPES = ("object_counting", "object_size_estimation", "room_size_estimation", "object_abs_distance",
              "object_rel_distance", "object_rel_direction_easy", "object_rel_direction_medium",
              "object_rel_direction_hard", "route_planning")


@dataclass
class Margins:
    """Boundary-margin rules: a candidate question whose truth sits this close to a decision boundary is not
    asked (the benchmark avoids ambiguous cases too); each rule's removals are counted per type."""

    angle_deg: float = 15.0  # direction θ at least this far from every boundary of its level (0/180, 0/135/225, 0/90/180/270)
    turn_deg: float = 20.0  # route turns at least this far from 0 and ±135
    rel_dist_m: float = 0.15  # relative distance: runner-up at least this much farther than the closest
    min_sep_m: float = 0.3  # direction/route: positions at least this far apart on the floor (defines the angle)
    pool: int = 400  # combinatorial types: at most this many random candidates are examined


def _letters(opts: list[str]) -> list[str]:
    return [f"{chr(65 + i)}. {o}" for i, o in enumerate(opts)]


def _mc(rng: np.random.Generator, truth: str, choices: list[str]) -> tuple[list[str], str]:
    """Options (shuffled, as the benchmark's) and the letter of the truth."""
    opts = [str(choices[int(i)]) for i in rng.permutation(len(choices))]
    return _letters(opts), chr(65 + opts.index(truth))


class _Gen:
    """Collects candidates per type, applies the margin rules, keeps up to `per_type` survivors."""

    def __init__(self, boxes: list[Box], rng: np.random.Generator, margins: Margins):
        self.boxes, self.rng, self.m = boxes, rng, margins
        cats = sorted({b.category for b in boxes})
        self.cats = cats
        self.unique = [c for c in cats if count(boxes, c) == 1]
        self.removed: dict[str, dict[str, int]] = {}
        self.kept: dict[str, list[dict[str, Any]]] = {}
        self._gaps: dict[tuple[str, str], float] = {}

    def gap(self, a: str, b: str) -> float:
        k = (min(a, b), max(a, b))
        if k not in self._gaps:
            self._gaps[k] = _gap(self.boxes, a, b)
        return self._gaps[k]

    def sample(self, items: list[Any]) -> list[Any]:
        order = self.rng.permutation(len(items))[: self.m.pool] if items else []
        return [items[int(i)] for i in order]

    def run(self, qtype: str, cands: list[Any], make) -> None:
        """`make(c)` -> a record dict, or the name of the margin rule that removes the candidate."""
        rem = {"candidates": len(cands)}
        kept = []
        for c in cands:
            r = make(c)
            if isinstance(r, str):
                rem[r] = rem.get(r, 0) + 1
            else:
                kept.append({"question_type": qtype, **r})
        rem["kept"] = len(kept)
        self.removed[qtype], self.kept[qtype] = rem, kept

    def far(self, *names: str) -> bool:
        c = [_one(self.boxes, n).centroid[:2] for n in names]
        return all(np.linalg.norm(c[i] - c[0]) >= self.m.min_sep_m for i in range(1, len(c)))


def _clear(theta: float, bounds: tuple[float, ...], margin: float) -> bool:
    return all(min((theta - b) % 360.0, (b - theta) % 360.0) >= margin for b in bounds)


def _numeric_types(g: _Gen, meta_entry: dict[str, Any]) -> None:
    b = g.boxes
    g.run("object_counting", [c for c in g.cats if count(b, c) >= 2],  # as the benchmark: 2 or more
          lambda c: {"question": Q_COUNT.format(a=c), "options": None, "ground_truth": str(count(b, c)),
                     "categories": [c]})
    g.run("object_size_estimation", list(g.unique),
          lambda c: {"question": Q_SIZE.format(a=c), "options": None, "ground_truth": str(longest_side_cm(b, c)),
                     "categories": [c]})
    area = room_size_m2(meta_entry)
    g.run("room_size_estimation", [] if area is None else [area],
          lambda a: {"question": Q_ROOM, "options": None, "ground_truth": f"{round(a, 1):.1f}", "categories": []})
    pairs = [tuple(p[int(i)] for i in g.rng.permutation(2)) for p in itertools.combinations(g.unique, 2)]
    g.run("object_abs_distance", g.sample(pairs),
          lambda p: {"question": Q_ABS.format(a=p[0], b=p[1]), "options": None,
                     "ground_truth": f"{round(g.gap(*p), 1):.1f}", "categories": list(p)})


def _rel_distance(g: _Gen) -> None:
    pool: dict[tuple[str, frozenset], tuple[str, list[str]]] = {}
    for t in g.unique:  # a few random 4-candidate sets per target (all sets explode combinatorially)
        others = [c for c in g.cats if c != t]
        for _ in range(min(8, len(others)) if len(others) >= 4 else 0):
            cands = [others[int(i)] for i in g.rng.permutation(len(others))[:4]]
            pool.setdefault((t, frozenset(cands)), (t, cands))

    def make(tc: tuple[str, list[str]]) -> dict[str, Any] | str:
        t, cands = tc
        d = sorted(g.gap(t, c) for c in cands)
        if d[1] - d[0] < g.m.rel_dist_m:
            return "rel_dist_margin"
        best = min(cands, key=lambda c: g.gap(t, c))
        return {"question": Q_REL.format(cands=", ".join(cands), a=t), "options": _letters(cands),
                "ground_truth": chr(65 + cands.index(best)), "categories": cands + [t]}
    g.run("object_rel_distance", g.sample(list(pool.values())), make)


def _directions(g: _Gen) -> None:
    triples = g.sample(list(itertools.permutations(g.unique, 3)))
    for level in ("easy", "medium", "hard"):
        def make(abc: tuple[str, str, str], level: str = level) -> dict[str, Any] | str:
            a, b, c = abc
            if not g.far(a, b, c):
                return "min_separation"
            th = direction_angle(g.boxes, a, b, c)
            if not _clear(th, DIRECTION_BOUNDS[level], g.m.angle_deg):
                return "angle_margin"
            opts, letter = _mc(g.rng, direction_word(th, level), list(DIRECTION_WORDS[level]))
            return {"question": Q_DIR[level].format(a=a, b=b, c=c), "options": opts, "ground_truth": letter,
                    "categories": [a, b, c]}
        g.run(f"object_rel_direction_{level}", triples, make)


def _route(g: _Gen) -> None:
    """Benchmark form: go forward to the facing object, then a turn before each further waypoint."""
    paths = g.sample([p for n in (3, 4) for p in itertools.permutations(g.unique, n)])

    def make(path: tuple[str, ...]) -> dict[str, Any] | str:
        a, b, *rest = path
        if not all(g.far(x, y) for x, y in zip(path, path[1:])):
            return "min_separation"
        turns = route_turn_angles(g.boxes, a, b, [b] + rest)[1:]
        if not all(_clear(t % 360.0, (0.0, 135.0, 225.0), g.m.turn_deg) for t in turns):
            return "turn_margin"
        steps = [f"Go forward until the {b}"]
        for w in rest:
            steps += ["[please fill in]", f"Go forward until the {w}"]
        truth = ", ".join(turn_word(t) for t in turns)
        alts = [", ".join(p) for p in itertools.product(TURN_WORDS, repeat=len(turns)) if ", ".join(p) != truth]
        pick = [alts[int(i)] for i in g.rng.permutation(len(alts))[:3]]
        opts, letter = _mc(g.rng, truth, pick + [truth])
        text = " ".join(f"{i + 1}. {s}" for i, s in enumerate(steps))
        return {"question": Q_ROUTE.format(a=a, b=b, d=rest[-1], steps=text), "options": opts,
                "ground_truth": letter, "categories": list(path)}
    g.run("route_planning", paths, make)


def generate_questions(meta_entry: dict[str, Any], scene_name: str, rng: np.random.Generator | int = 0,
                       per_type: int | dict[str, int] = 3, margins: Margins | dict | None = None
                       ) -> tuple[list[dict[str, Any]], dict[str, dict[str, int]]]:
    """Questions of every box-answerable VSI-Bench type for one meta entry -> (records, removed).

    records: VSI-Bench questions.jsonl schema (id, dataset, scene_name, question_type, question, options or None,
    ground_truth) plus `categories` (the categories the question names). removed: per type, `candidates`
    examined, `kept` after the margin rules, and the count removed by each rule (angle_margin, turn_margin,
    rel_dist_margin, min_separation); up to `per_type` of the kept ones (random) become questions.
    """
    rng = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(int(rng))
    m = margins if isinstance(margins, Margins) else Margins(**(margins or {}))
    g = _Gen(room_boxes(meta_entry), rng, m)
    _numeric_types(g, meta_entry)
    _rel_distance(g)
    _directions(g)
    _route(g)
    out: list[dict[str, Any]] = []
    for qtype in BOX_QTYPES:
        n = per_type.get(qtype, 0) if isinstance(per_type, dict) else int(per_type)
        kept = g.kept.get(qtype, [])
        for k in rng.permutation(len(kept))[:n]:
            out.append({"id": len(out), "dataset": meta_entry.get("dataset", "unknown"), "scene_name": scene_name,
                        **kept[int(k)]})
        g.removed[qtype]["asked"] = min(n, len(kept))
    return out, g.removed

