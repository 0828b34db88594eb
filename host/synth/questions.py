"""Questions of every VSI-Bench type from a synthetic scene's ground truth; answers from the boxes, not the reasoner.

`generate_questions(scene_meta, seed)` takes every box-answerable type from `evaluation.box_truth` (the answer
key that shares no code with the map reasoner, also used for real rooms): the benchmark's wording and option
shapes, ground truth from the true oriented boxes, and explicit boundary-margin rules (`box_truth.Margins`)
whose removals are counted per type. Appearance order comes from the rendered video's first-seen times (a
category's earliest instance), with its own rule: consecutive first appearances at least `ORDER_GAP` apart.
Nothing is dropped because the reasoner answers it differently: the e2e "GT map" figure measures the reasoner.

Objects that stand for a position (direction, route, distance questions) are categories with exactly one instance,
as in VSI-Bench. Records follow the schema of VSI-Bench's questions.jsonl (id, dataset="synthetic", scene_name,
question_type, question, options, ground_truth) plus `instances`: the ids of the question's object instances
(targets and cues; all instances of a counted category).

`ground_truth_map(meta)` is the scene's exact `SemanticMap` (the e2e "GT map" mode answers from it).
"""
from __future__ import annotations

import itertools
from dataclasses import asdict
from typing import Any

import numpy as np

from mosaicthinker.host.evaluation import box_truth
from mosaicthinker.runtime.geometry import OrientedBox
from mosaicthinker.runtime.map import ObjectInstance, Room, SemanticMap

Q_ORDER = "What will be the first-time appearance order of the following categories in the video: {cats}?"

LIMITS = {"object_counting": 3, "object_size_estimation": 3, "room_size_estimation": 1, "object_abs_distance": 3,
          "object_rel_distance": 2, "object_rel_direction_easy": 2, "object_rel_direction_medium": 2,
          "object_rel_direction_hard": 2, "obj_appearance_order": 2, "route_planning": 2}
ORDER_GAP = 1.0  # seconds between consecutive first appearances


def ground_truth_map(meta: dict[str, Any]) -> SemanticMap:
    """The scene's exact map: every instance's true box and first-seen time, the true room polygon."""
    inst = [ObjectInstance(int(o["id"]), o["name"], OrientedBox.from_meta(o["box"]), o.get("first_seen"))
            for o in meta["instances"]]
    r = meta["room"]
    room = Room(np.asarray(r["polygon"], float), float(r["floor_z"]), float(r["ceiling_z"]), "ground_truth")
    return SemanticMap(inst, room, [], {"source": "synthetic_ground_truth", "scene_name": meta.get("scene_name"),
                                        "dataset": "synthetic"})


def _appearance_order(meta: dict[str, Any], rng: np.random.Generator, n: int, pool: int
                      ) -> tuple[list[dict[str, Any]], dict[str, int]]:
    """Four (else three) categories in the order of their first appearance; rule `order_gap`."""
    first: dict[str, float] = {}
    for o in meta["instances"]:
        if o.get("first_seen") is not None:
            first[o["name"]] = min(first.get(o["name"], np.inf), float(o["first_seen"]))
    combos = [c for k in (4, 3) for c in itertools.combinations(sorted(first), k)]
    cands = [combos[int(i)] for i in rng.permutation(len(combos))[:pool]] if combos else []
    rem = {"candidates": len(cands), "order_gap": 0}
    kept = []
    for c in cands:
        if min(np.diff(sorted(first[x] for x in c))) < ORDER_GAP:
            rem["order_gap"] += 1
            continue
        cats = [c[int(i)] for i in rng.permutation(len(c))]
        truth = ", ".join(sorted(cats, key=lambda x: first[x]))
        perms = [", ".join(p) for p in itertools.permutations(cats) if ", ".join(p) != truth]
        opts = [perms[int(i)] for i in rng.permutation(len(perms))[:3]] + [truth]
        opts = [opts[int(i)] for i in rng.permutation(len(opts))]
        kept.append({"question_type": "obj_appearance_order", "question": Q_ORDER.format(cats=", ".join(cats)),
                     "options": [f"{chr(65 + i)}. {o}" for i, o in enumerate(opts)],
                     "ground_truth": chr(65 + opts.index(truth)), "categories": cats})
    rem["kept"] = len(kept)
    pick = [kept[int(i)] for i in rng.permutation(len(kept))[:n]]
    rem["asked"] = len(pick)
    return pick, rem


def generate_questions(meta: dict[str, Any], seed: int = 0, margins: box_truth.Margins | dict | None = None,
                       per_type: dict[str, int] | None = None) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """-> (question records, report {'removed': {type: {candidates, kept, asked, <rule>: n}}, 'margins': ...,
    'order_gap_s': ...}). Ground truth from the boxes (`box_truth`), never from the map reasoner."""
    rng = np.random.default_rng([int(seed), 2718])
    m = margins if isinstance(margins, box_truth.Margins) else box_truth.Margins(**(margins or {}))
    limits = {**LIMITS, **(per_type or {})}
    qs, removed = box_truth.generate_questions(meta, meta.get("scene_name"), rng, per_type=limits, margins=m)
    order, removed["obj_appearance_order"] = _appearance_order(meta, rng, limits["obj_appearance_order"], m.pool)
    ids: dict[str, list[int]] = {}
    for o in meta["instances"]:
        ids.setdefault(o["name"], []).append(int(o["id"]))
    out = []
    for q in qs + order:
        out.append({"id": len(out), "dataset": "synthetic", "scene_name": meta.get("scene_name"),
                    **{k: q[k] for k in ("question_type", "question", "options", "ground_truth")},
                    "instances": sorted({i for c in q["categories"] for i in ids.get(c, [])})})
    return out, {"removed": removed, "margins": asdict(m), "order_gap_s": ORDER_GAP}
