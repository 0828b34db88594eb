"""Questions of every VSI-Bench type from a synthetic scene's ground truth, answered by the map reasoner.

`generate_questions(scene_meta, seed)` builds the ground-truth `SemanticMap` (the true boxes, the true room
polygon, first-seen times from the rendered video), writes questions in the benchmark's own wording, and takes the
answer from `answer.MapReasoner`. Independently of the reasoner, each question's geometry is computed here too
(centres, angles, closest-point distances): a question whose answer would sit within a margin of a decision
boundary is not asked (as the benchmark avoids ambiguous cases), and a question where this computation and the
reasoner disagree is dropped and counted (`disagreements`; tests require none).

Objects that stand for a position (direction, route, distance questions) are categories with exactly one instance,
as in VSI-Bench. Records follow the schema of VSI-Bench's questions.jsonl (id, dataset="synthetic", scene_name,
question_type, question, options, ground_truth) plus `instances`: the ids of the question's object instances
(targets and cues; all instances of a counted category).
"""
from __future__ import annotations

import itertools
import math
from typing import Any

import numpy as np

from ..geometry import OrientedBox, box_distance
from ..semantic_map import ObjectInstance, Room, SemanticMap

Q_COUNT = "How many {a}(s) are in this room?"
Q_SIZE = ("What is the length of the longest dimension (length, width, or height) of the {a}, measured in "
          "centimeters?")
Q_ROOM = ("What is the size of this room (in square meters)? \nIf multiple rooms are shown, estimate the size of "
          "the combined space.")
Q_ABS = ("Measuring from the closest point of each object, what is the distance between the {a} and the {b} "
         "(in meters)?")
Q_REL = "Measuring from the closest point of each object, which of these objects ({cands}) is the closest to the {a}?"
Q_EASY = "If I am standing by the {a} and facing the {b}, is the {c} to the left or the right of the {b}?"
Q_MEDIUM = ("If I am standing by the {a} and facing the {b}, is the {c} to my left, right, or back?\nAn object is "
            "to my back if I would have to turn at least 135 degrees in order to face it.")
Q_HARD = ("If I am standing by the {a} and facing the {b}, is the {c} to my front-left, front-right, back-left, or "
          "back-right?\nThe directions refer to the quadrants of a Cartesian plane (if I am standing at the origin "
          "and facing along the positive y-axis).")
Q_ORDER = "What will be the first-time appearance order of the following categories in the video: {cats}?"
Q_ROUTE = ("You are a robot beginning at the {a} facing the {b}. You want to navigate to the {d}. You will perform "
           "the following actions (Note: for each [please fill in], choose either 'turn back,' 'turn left,' or "
           "'turn right.'): {steps} You have reached the final destination.")

LIMITS = {"object_counting": 3, "object_size_estimation": 3, "room_size_estimation": 1, "object_abs_distance": 3,
          "object_rel_distance": 2, "object_rel_direction_easy": 2, "object_rel_direction_medium": 2,
          "object_rel_direction_hard": 2, "obj_appearance_order": 2, "route_planning": 2}
ANGLE_MARGIN = 15.0  # degrees away from any direction boundary
DIST_MARGIN = 0.15  # metres between the closest and the runner-up candidate
ORDER_GAP = 1.0  # seconds between consecutive first appearances


def ground_truth_map(meta: dict[str, Any]) -> SemanticMap:
    """The scene's exact map: every instance's true box and first-seen time, the true room polygon."""
    inst = [ObjectInstance(int(o["id"]), o["name"], OrientedBox.from_meta(o["box"]), o.get("first_seen"))
            for o in meta["instances"]]
    r = meta["room"]
    room = Room(np.asarray(r["polygon"], float), float(r["floor_z"]), float(r["ceiling_z"]), "ground_truth")
    return SemanticMap(inst, room, [], {"source": "synthetic_ground_truth", "scene_name": meta.get("scene_name"),
                                        "dataset": "synthetic"})


def _angle(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> float:
    """Counter-clockwise angle (deg, [0, 360)) of c seen from a, from the direction a -> b (floor plane)."""
    f, g = b[:2] - a[:2], c[:2] - a[:2]
    return math.degrees(math.atan2(f[0] * g[1] - f[1] * g[0], f @ g)) % 360.0


def _away(theta: float, boundaries: list[float], margin: float = ANGLE_MARGIN) -> bool:
    return all(min(abs(theta - b) % 360.0, 360.0 - abs(theta - b) % 360.0) >= margin for b in boundaries)


def _letters(opts: list[str]) -> list[str]:
    return [f"{chr(65 + i)}. {o}" for i, o in enumerate(opts)]


def generate_questions(meta: dict[str, Any], seed: int = 0) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """-> (question records, report {type: count or reason, 'disagreements': n})."""
    from ..answer import MapReasoner

    rng = np.random.default_rng([int(seed), 2718])
    smap = ground_truth_map(meta)
    reasoner = MapReasoner(smap)
    by: dict[str, list[ObjectInstance]] = {}
    for o in smap.instances:
        by.setdefault(o.name, []).append(o)
    unique = sorted(n for n, v in by.items() if len(v) == 1)
    cen = {n: by[n][0].center for n in unique}
    out: list[dict[str, Any]] = []
    report: dict[str, Any] = {"disagreements": 0, "dropped": []}

    def ask(qtype: str, q: str, opts: list[str] | None, expect: Any, names: list[str]) -> bool:
        ans = reasoner.answer(q, opts)
        if ans.status != "ok":
            report["dropped"].append({"type": qtype, "question": q, "why": ans.text})
            return False
        if expect is not None and str(ans.text) != str(expect):
            report["disagreements"] += 1
            report["dropped"].append({"type": qtype, "question": q, "why": f"reasoner {ans.text} != {expect}"})
            return False
        ids = sorted({o.id for n in names for o in by.get(n, [])})
        out.append({"id": len(out), "dataset": "synthetic", "scene_name": meta.get("scene_name"),
                    "question_type": qtype, "question": q, "options": opts, "ground_truth": str(ans.text),
                    "instances": ids})
        return True

    def take(qtype: str, cands: list[Any], fn) -> None:
        n = 0
        order = rng.permutation(len(cands)) if cands else []
        for k in order:
            if n >= LIMITS[qtype]:
                break
            n += bool(fn(cands[int(k)]))
        report[qtype] = n

    names = sorted(by)
    # counting: categories with several instances (as the benchmark)
    take("object_counting", [n for n in names if len(by[n]) >= 2],
         lambda n: ask("object_counting", Q_COUNT.format(a=n), None, str(len(by[n])), [n]))
    take("object_size_estimation", unique,
         lambda n: ask("object_size_estimation", Q_SIZE.format(a=n), None,
                       str(int(round(100 * float(np.max(by[n][0].box.axes_lengths))))), [n]))
    area = float(meta["room_size"])
    take("room_size_estimation", [0],
         lambda _: ask("room_size_estimation", Q_ROOM, None, f"{round(area, 1):.1f}", []))
    take("object_abs_distance", list(itertools.combinations(unique, 2)),
         lambda ab: ask("object_abs_distance", Q_ABS.format(a=ab[0], b=ab[1]), None,
                        f"{round(box_distance(by[ab[0]][0].box, by[ab[1]][0].box), 1):.1f}", list(ab)))

    def rel_distance(ref: str) -> bool:
        others = [n for n in names if n != ref]
        if len(others) < 3:
            return False
        cands = [others[int(i)] for i in rng.permutation(len(others))[:4]]
        d = {c: min(box_distance(by[ref][0].box, o.box) for o in by[c]) for c in cands}
        srt = sorted(d.values())
        if srt[1] - srt[0] < DIST_MARGIN:
            return False
        best = min(d, key=d.get)
        return ask("object_rel_distance", Q_REL.format(cands=", ".join(cands), a=ref), _letters(cands),
                   chr(65 + cands.index(best)), cands + [ref])
    take("object_rel_distance", unique, rel_distance)

    triples = [t for t in itertools.permutations(unique, 3)]

    def direction(level: str, abc: tuple[str, str, str]) -> bool:
        a, b, c = abc
        if np.linalg.norm(cen[b][:2] - cen[a][:2]) < 0.3 or np.linalg.norm(cen[c][:2] - cen[a][:2]) < 0.3:
            return False
        th = _angle(cen[a], cen[b], cen[c])
        if level == "easy":
            if not _away(th, [0, 180]):
                return False
            word = "left" if th < 180 else "right"
            opts = ["left", "right"]
            q = Q_EASY.format(a=a, b=b, c=c)
        elif level == "medium":
            if not _away(th, [0, 135, 225]):
                return False
            word = "back" if 135 <= th <= 225 else ("left" if th < 180 else "right")
            opts = list(rng.permutation(["left", "right", "back"]))
            q = Q_MEDIUM.format(a=a, b=b, c=c)
        else:
            if not _away(th, [0, 90, 180, 270]):
                return False
            word = ("front-left", "back-left", "back-right", "front-right")[int(th // 90)]
            opts = list(rng.permutation(["front-left", "front-right", "back-left", "back-right"]))
            q = Q_HARD.format(a=a, b=b, c=c)
        opts = [str(o) for o in opts]
        return ask(f"object_rel_direction_{level}", q, _letters(opts), chr(65 + opts.index(word)), [a, b, c])
    for level in ("easy", "medium", "hard"):
        take(f"object_rel_direction_{level}", triples, lambda abc, lv=level: direction(lv, abc))

    # appearance order: categories first seen at well-separated times
    first = {n: min((o.first_seen for o in by[n] if o.first_seen is not None), default=None) for n in names}
    seen = sorted((t, n) for n, t in first.items() if t is not None)

    def order(cats: tuple[str, ...]) -> bool:
        ts = sorted(first[c] for c in cats)
        if min(np.diff(ts)) < ORDER_GAP:
            return False
        cats = [cats[int(i)] for i in rng.permutation(len(cats))]
        truth = sorted(cats, key=lambda c: first[c])
        perms = [list(p) for p in itertools.permutations(cats) if list(p) != truth]
        pick = [perms[int(i)] for i in rng.permutation(len(perms))[:3]]
        opts = pick + [truth]
        opts = [opts[int(i)] for i in rng.permutation(len(opts))]
        texts = [", ".join(p) for p in opts]
        return ask("obj_appearance_order", Q_ORDER.format(cats=", ".join(cats)), _letters(texts),
                   chr(65 + opts.index(truth)), list(cats))
    combos = []
    for k in (4, 3):  # four categories where their first appearances are separated, else three
        ck = [c for c in itertools.combinations([n for _, n in seen], k)
              if min(np.diff(sorted(first[x] for x in c))) >= ORDER_GAP]
        combos += [ck[int(i)] for i in rng.permutation(len(ck))[:100]]
    take("obj_appearance_order", combos, order)

    # route planning: start A facing B, waypoints, destination; every turn clear of the boundaries
    def route(path: tuple[str, ...]) -> bool:
        a, b, *rest = path
        if len(rest) < 1:
            return False
        pos, heading = cen[a][:2], cen[b][:2] - cen[a][:2]
        if np.linalg.norm(heading) < 0.3:
            return False
        turns = []
        steps = []
        for w in rest:
            move = cen[w][:2] - pos
            if np.linalg.norm(move) < 0.5:
                return False
            th = math.degrees(math.atan2(heading[0] * move[1] - heading[1] * move[0], heading @ move))
            if not _away(th % 360.0, [0, 135, 225], 20.0):
                return False
            turns.append("Turn Back" if abs(th) >= 135 else ("Turn Left" if th > 0 else "Turn Right"))
            steps += ["[please fill in]", f"Go forward until the {w}."]
            pos, heading = cen[w][:2], move
        text = " ".join(f"{i + 1}. {s}" for i, s in enumerate(steps))
        q = Q_ROUTE.format(a=a, b=b, d=rest[-1], steps=text)
        truth = ", ".join(turns)
        words = ["Turn Back", "Turn Left", "Turn Right"]
        alts = [", ".join(p) for p in itertools.product(words, repeat=len(turns)) if ", ".join(p) != truth]
        opts = [alts[int(i)] for i in rng.permutation(len(alts))[:3]] + [truth]
        opts = [opts[int(i)] for i in rng.permutation(len(opts))]
        return ask("route_planning", q, _letters(opts), chr(65 + opts.index(truth)), list(path))
    paths = [p for n in (3, 4) for p in itertools.permutations(unique, n)]
    if len(paths) > 300:
        paths = [paths[int(i)] for i in rng.permutation(len(paths))[:300]]
    take("route_planning", paths, route)
    return out, report
