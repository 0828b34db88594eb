"""box_truth: the box-only answer key. Hand-made boxes with hand-derived answers, an independent brute-force
check of the closest-point distance, and every question of the real VSI-Bench set recomputed from its
meta_info boxes and compared with the benchmark's own ground_truth."""
from __future__ import annotations

import json
import math
import re
from collections import Counter, defaultdict

import numpy as np
import pytest

from mosaicthinker.host.evaluation import box_truth as bt
from mosaicthinker.host.evaluation.box_truth import Box


def _box(cat: str, c, L, yaw_deg: float = 0.0) -> Box:
    a = math.radians(yaw_deg)
    ax = np.array([[math.cos(a), math.sin(a), 0.0], [-math.sin(a), math.cos(a), 0.0], [0.0, 0.0, 1.0]])
    return Box(cat, np.asarray(c, float), np.asarray(L, float), ax)


# ----------------------------------------------------------------------------- hand-made boxes

def test_gap_axis_aligned_and_overlap():
    a = _box("a", [0, 0, 0.5], [1, 1, 1])
    assert bt.box_gap(a, _box("b", [3, 0, 0.5], [1, 1, 1])) == pytest.approx(2.0)  # faces 0.5 .. 2.5
    assert bt.box_gap(a, _box("b", [3, 4, 0.5], [1, 1, 1])) == pytest.approx(math.hypot(2, 3))  # edge to edge
    assert bt.box_gap(a, _box("b", [3, 4, 3.5], [1, 1, 1])) == pytest.approx(math.sqrt(4 + 9 + 4))  # corner
    assert bt.box_gap(a, _box("b", [0.7, 0.2, 0.5], [1, 1, 1])) == 0.0  # overlapping
    assert bt.box_gap(a, _box("b", [0, 0, 0.5], [0.2, 0.2, 0.2])) == 0.0  # inside


def test_gap_rotated_corner_and_crossed_edges():
    # a unit cube rotated 45 deg points its vertical edge at the other's face: edge at x = 3 - sqrt(2)/2
    a = _box("a", [0, 0, 0.5], [1, 1, 1])
    b = _box("b", [3, 0, 0.5], [1, 1, 1], 45)
    assert bt.box_gap(a, b) == pytest.approx(2.5 - math.sqrt(2) / 2)
    # two long bars crossing at right angles one above the other: edge-edge, the gap is the vertical clearance
    lo = _box("lo", [0, 0, 0.05], [4, 0.1, 0.1])
    hi = _box("hi", [0, 0, 1.05], [0.1, 4, 0.1])
    assert bt.box_gap(lo, hi) == pytest.approx(0.9)
    # skew bars: edge-edge interior pair, no vertex involved (rotated 30 deg about z, offset in z)
    hi2 = _box("hi", [0.3, 0.2, 1.05], [0.1, 4, 0.1], 30)
    assert bt.box_gap(lo, hi2) == pytest.approx(0.9)


def _surface_samples(b: Box, n: int) -> np.ndarray:
    rng = np.random.default_rng(0)
    u = rng.uniform(-0.5, 0.5, (n, 3))
    k = rng.integers(0, 3, n)
    u[np.arange(n), k] = rng.choice([-0.5, 0.5], n)
    return b.centroid + (u * b.axes_lengths) @ b.axes


def test_gap_matches_brute_force_on_random_tilted_boxes():
    """An independent upper bound: the closest pair among dense surface samples of both boxes."""
    rng = np.random.default_rng(5)
    for _ in range(12):
        q, _r = np.linalg.qr(rng.normal(size=(3, 3)))
        p, _r = np.linalg.qr(rng.normal(size=(3, 3)))
        a = Box("a", rng.uniform(-1, 1, 3), rng.uniform(0.2, 1.5, 3), q.T)
        b = Box("b", rng.uniform(-1, 1, 3) + [2.0, 0, 0], rng.uniform(0.2, 1.5, 3), p.T)
        exact = bt.box_gap(a, b)
        sa, sb = _surface_samples(a, 4000), _surface_samples(b, 4000)
        brute = min(float(b.distance_to_points(sa).min()), float(a.distance_to_points(sb).min()))
        assert exact <= brute + 1e-9
        assert brute - exact < 0.02, (exact, brute)


def _room() -> list[Box]:
    # stand at the sofa (origin) facing the tv (+y): lamp at (-2, 1) is front-left/left, bed at (1, -3)
    # back-right/back (turn 161.6 deg), desk at (2, 0.5) front-right/right; two chairs
    return [_box("sofa", [0, 0, 0.4], [2.0, 0.9, 0.8]), _box("tv", [0, 4, 1.0], [1.2, 0.1, 0.7]),
            _box("lamp", [-2, 1, 0.8], [0.3, 0.3, 1.6]), _box("bed", [1, -3, 0.3], [2.0, 1.6, 0.6], 90),
            _box("desk", [2, 0.5, 0.4], [1.4, 0.7, 0.8]), _box("chair", [3, 2, 0.45], [0.5, 0.5, 0.9]),
            _box("chair", [-3, -2, 0.45], [0.5, 0.5, 0.9])]


def test_truth_functions_by_hand():
    b = _room()
    assert bt.count(b, "chair") == 2 and bt.count(b, "piano") == 0
    assert bt.longest_side_cm(b, "sofa") == 200 and bt.longest_side_cm(b, "lamp") == 160
    # sofa x in [-1, 1], y in [-0.45, 0.45]; desk x in [1.3, 2.7]: gap 0.3 along x
    assert bt.abs_distance_m(b, "sofa", "desk") == pytest.approx(0.3)
    # bed rotated 90 deg: y in [-4, -2]; sofa bottom y = -0.45 -> 1.55
    assert bt.abs_distance_m(b, "sofa", "bed") == pytest.approx(1.55)
    assert bt.closest_of(b, "sofa", ["bed", "desk", "tv"]) == "desk"
    assert bt.nearest_of_all(b, "sofa") == "desk" and bt.nearest_of_all(b, "tv") == "chair"  # hypot(2.15, 1.7) m
    # nearest chair instance counts: chair (3, 2) to desk: x 2.75 - 2.7 = 0.05, y 1.75 - 0.85 = 0.9
    assert bt.abs_distance_m(b, "desk", "chair") == pytest.approx(math.hypot(0.05, 0.9))
    assert bt.direction(b, "sofa", "tv", "lamp", "easy") == "left"
    assert bt.direction(b, "sofa", "tv", "desk", "easy") == "right"
    assert bt.direction(b, "sofa", "tv", "lamp", "hard") == "front-left"
    assert bt.direction(b, "sofa", "tv", "bed", "hard") == "back-right"
    assert bt.direction(b, "sofa", "tv", "desk", "hard") == "front-right"
    assert bt.direction(b, "sofa", "tv", "bed", "medium") == "back"
    assert bt.direction(b, "sofa", "tv", "lamp", "medium") == "left"
    assert bt.direction_angle(b, "sofa", "tv", "lamp") == pytest.approx(math.degrees(math.atan2(2, 1)))
    with pytest.raises(ValueError):  # a position must be a single instance
        bt.direction(b, "chair", "tv", "lamp", "easy")
    # route: sofa -> tv (north), then to the desk (2, 0.5) from (0, 4): move (2, -3.5), a right turn of
    # 90 + atan2(3.5, 2) = 150.3 deg -> back; then desk -> lamp: move (-4, 0.5), turn -126.9 deg -> right
    turns = bt.route_turn_angles(b, "sofa", "tv", ["tv", "desk", "lamp"])
    assert turns[0] == pytest.approx(0.0)
    assert turns[1] == pytest.approx(-(90 + math.degrees(math.atan2(3.5, 2))))
    assert bt.route_turns(b, "sofa", "tv", ["tv", "desk", "lamp"])[1:] == ["Turn Back", "Turn Right"]


# ----------------------------------------------------------------------------- the real benchmark

_PAT = {
    "object_counting": r"How many (.+?)\(s\) are in this room",
    "object_size_estimation": r"\(length, width, or height\) of the (.+?), measured",
    "object_abs_distance": r"distance between the (.+?) and the (.+?) \(in meters\)",
    "object_rel_distance": r"which of these objects \((.+?)\) is the closest to the (.+?)\?",
    "object_rel_direction": r"standing by the (.+?) and facing the (.+?), is the (.+?) to ",
}


def _option(options: list[str], word: str) -> str | None:
    return next((o[0] for o in options if o[3:].strip().lower() == word.lower()), None)


def recompute(meta: dict, q: dict) -> str:
    """The benchmark question's answer from its scene's boxes (raises KeyError for an unannotated object)."""
    t, text, opts = q["question_type"], q["question"], q["options"]
    boxes = bt.room_boxes(meta)
    g = re.search(_PAT.get("object_rel_direction" if t.startswith("object_rel_direction") else t, "^$"), text)
    g = g.groups() if g else ()
    if t == "object_counting":
        return str(bt.count(boxes, g[0]))
    if t == "object_size_estimation":
        return str(bt.longest_side_cm(boxes, g[0]))
    if t == "room_size_estimation":
        return f"{round(bt.room_size_m2(meta), 1):.1f}"
    if t == "object_abs_distance":
        return f"{round(bt.abs_distance_m(boxes, *g), 1):.1f}"
    if t == "object_rel_distance":
        return _option(opts, bt.closest_of(boxes, g[1], g[0].split(", ")))
    if t.startswith("object_rel_direction"):
        return _option(opts, bt.direction(boxes, *g, t.rsplit("_", 1)[1]))
    raise KeyError(t)


def _mra(pred: float, gt: float) -> float:
    """VSI-Bench's Mean Relative Accuracy over θ in 0.50, 0.55, ..., 0.95."""
    return float(np.mean([abs(pred - gt) / gt <= 1 - th for th in np.linspace(0.5, 0.95, 10)]))


@pytest.fixture(scope="module")
def benchmark(vsibench_dir):
    meta = json.loads((vsibench_dir / "meta_info.json").read_text())
    qs = [json.loads(line) for line in (vsibench_dir / "questions.jsonl").read_text().splitlines()]
    per: dict[str, Counter] = defaultdict(Counter)
    wrong: list[tuple] = []
    for q in qs:
        t = q["question_type"]
        if t == "route_planning":  # human-written routes (waypoints not in the boxes): not box-answerable
            continue
        try:
            mine = recompute(meta[q["scene_name"]], q)
        except (KeyError, ValueError) as e:
            per[t]["error"] += 1
            wrong.append((q["id"], t, f"{type(e).__name__}: {e}", q["ground_truth"]))
            continue
        ok = mine == q["ground_truth"]
        if t == "object_abs_distance":
            per[t]["mra_sum"] += _mra(float(mine), float(q["ground_truth"]))
        if t == "object_abs_distance" and not ok:  # a rounding step apart is counted separately
            ok = "within_0.1" if abs(float(mine) - float(q["ground_truth"])) <= 0.1 + 1e-9 else False
        per[t]["n"] += 1
        per[t][ok if isinstance(ok, str) else ("agree" if ok else "disagree")] += 1
        if ok is not True:
            wrong.append((q["id"], t, mine, q["ground_truth"]))
    return per, wrong


def test_benchmark_answers_recomputed_from_boxes(benchmark):
    """Exact agreement for counting, size, room size and the multiple-choice types (the one known miss: the
    benchmark counts 5 of a category its own box list holds 2 of). Absolute distance: the benchmark's values sit
    a few cm above the exact box gap (median +0.045 m: it measured on the objects' points, not their boxes), so
    it is checked to 0.1 m and by the benchmark's MRA."""
    per, wrong = benchmark
    print({t: dict(c) for t, c in per.items()})
    print([w for w in wrong if w[1] != "object_abs_distance" or abs(float(w[2]) - float(w[3])) > 0.1 + 1e-9])
    assert set(per) == set(bt.BOX_QTYPES) - {"route_planning"}
    assert not any(c["error"] for c in per.values())
    for t, c in per.items():
        if t != "object_abs_distance":
            assert c["agree"] / c["n"] >= 0.99, (t, c)
    c = per["object_abs_distance"]
    assert (c["agree"] + c["within_0.1"]) / c["n"] >= 0.95, c
    assert c["mra_sum"] / c["n"] >= 0.95, c


# ----------------------------------------------------------------------------- generated questions

def _templates(vsibench_dir) -> dict[str, set[str]]:
    """The benchmark's wording per type with object names blanked."""
    meta = json.loads((vsibench_dir / "meta_info.json").read_text())
    out: dict[str, set[str]] = defaultdict(set)
    for line in (vsibench_dir / "questions.jsonl").read_text().splitlines():
        q = json.loads(line)
        names = sorted(meta[q["scene_name"]]["object_bbox"], key=len, reverse=True)
        out[q["question_type"]].add(_blank(q["question"], names))
    return out


def _blank(text: str, names: list[str]) -> str:
    for n in sorted(names, key=len, reverse=True):
        text = re.sub(rf"\b{re.escape(n)}\b", "<o>", text)
    return re.sub(r"\(<o>(, <o>)*\)", "(<list>)", text)


def test_generated_questions_on_benchmark_rooms(vsibench_dir):
    """Generated from real rooms: the benchmark's wording, option shapes, and answers that the truth functions
    give; every removal is accounted for; kept directions are clear of the boundaries by the margin."""
    meta = json.loads((vsibench_dir / "meta_info.json").read_text())
    tmpl = _templates(vsibench_dir)
    m = bt.Margins()
    types = Counter()
    for name in list(meta)[:12]:
        qs, removed = bt.generate_questions(meta[name], name, rng=7, per_type=2, margins=m)
        boxes = bt.room_boxes(meta[name])
        for t, r in removed.items():
            assert r["candidates"] == r["kept"] + sum(v for k, v in r.items() if k not in ("candidates", "kept",
                                                                                             "asked"))
        for q in qs:
            t = q["question_type"]
            types[t] += 1
            assert q["scene_name"] == name and q["dataset"] == "arkitscenes"
            if t != "route_planning":  # the benchmark's routes are hand-written prose
                assert _blank(q["question"], list(meta[name]["object_bbox"])) in tmpl[t], q["question"]
                assert recompute(meta[name], q) == q["ground_truth"]
            if t.startswith("object_rel_direction"):
                th = bt.direction_angle(boxes, *q["categories"])
                bounds = bt.DIRECTION_BOUNDS[t.rsplit("_", 1)[1]]
                assert min(min((th - b) % 360, (b - th) % 360) for b in bounds) >= m.angle_deg
                assert sorted(o[3:] for o in q["options"]) == sorted(bt.DIRECTION_WORDS[t.rsplit("_", 1)[1]])
    assert set(types) == set(bt.BOX_QTYPES), types


def test_margin_rules_remove_and_count():
    b = _room()
    meta = {"object_bbox": {}, "room_size": 20.04}
    for x in b:
        meta["object_bbox"].setdefault(x.category, []).append(
            {"centroid": x.centroid.tolist(), "axesLengths": x.axes_lengths.tolist(),
             "normalizedAxes": x.axes.reshape(-1).tolist()})
    qs, removed = bt.generate_questions(meta, "hand", rng=1, per_type=50, margins={"angle_deg": 30.0})
    # sofa -> tv facing +y: lamp at 63.4 deg is kept for easy (>= 30 from 0 and 180) ...
    easy = {tuple(q["categories"]) for q in qs if q["question_type"] == "object_rel_direction_easy"}
    assert ("sofa", "tv", "lamp") in easy
    # ... but not for hard (26.6 deg from the 90 deg boundary)
    hard = {tuple(q["categories"]) for q in qs if q["question_type"] == "object_rel_direction_hard"}
    assert ("sofa", "tv", "lamp") not in hard and removed["object_rel_direction_hard"]["angle_margin"] >= 1
    # 5 unique categories (sofa, tv, lamp, bed, desk): 60 ordered triples examined per level
    assert removed["object_rel_direction_easy"]["candidates"] == 60
    assert [q["ground_truth"] for q in qs if q["question_type"] == "room_size_estimation"] == ["20.0"]
    assert [q["ground_truth"] for q in qs if q["question_type"] == "object_counting"] == ["2"]


@pytest.mark.slow
def test_map_reasoner_against_the_box_key_on_benchmark_rooms(vsibench_dir):
    """The reasoner under test, on the exact map of every benchmark room, against this independent key."""
    from mosaicthinker.runtime.answer import MapReasoner
    from mosaicthinker.runtime.map import SemanticMap

    meta = json.loads((vsibench_dir / "meta_info.json").read_text())
    per: dict[str, list[bool]] = defaultdict(list)
    for name, entry in meta.items():
        qs, _ = bt.generate_questions(entry, name, rng=11, per_type=1)
        reasoner = MapReasoner(SemanticMap.from_meta_info(entry, name))
        for q in qs:
            if q["question_type"] == "room_size_estimation":  # the box-only map has no room scan: a lower bound
                continue
            per[q["question_type"]].append(reasoner.answer(q["question"], q["options"]).text == q["ground_truth"])
    assert set(per) == set(bt.BOX_QTYPES) - {"room_size_estimation"}
    for t, ok in per.items():
        assert len(ok) >= 25 and np.mean(ok) >= 0.99, (t, len(ok), np.mean(ok))
