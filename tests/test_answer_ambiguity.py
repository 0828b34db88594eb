"""An answer whose object name matches several instances says so (answer text, JSON evidence, printed line), and
its evidence says what the per-view spread is (per-view noise, not the map's error)."""
from __future__ import annotations

import numpy as np

from mosaicthinker.runtime.answer import evidence as ev
from mosaicthinker.runtime.answer import MapReasoner
from mosaicthinker.runtime.map import SemanticMap
from test_grounding_nl import ask


def _box(c, size):
    c, size = np.asarray(c, float), np.asarray(size, float)
    return {"centroid": c.tolist(), "axesLengths": size.tolist(), "normalizedAxes": np.eye(3).ravel().tolist(),
            "min": (c - size / 2).tolist(), "max": (c + size / 2).tolist()}


def _map():
    # table x in [-0.5, 0.5]; two screens at its height side by side on the wall: gaps 1.0 m (x from 1.5) and 2.0 m (x from 2.5)
    meta = {"object_bbox": {"table": [_box([0, 0, 0.4], [1.0, 0.8, 0.8])],
                            "tv": [_box([3.0, 0, 0.4], [1.0, 0.1, 0.6]), _box([2.0, 0, 0.4], [1.0, 0.1, 0.6])]}}
    return SemanticMap.from_meta_info(meta, "two screens")


def test_distance_to_one_of_two_tvs_names_the_ambiguity_and_the_alternative():
    a = MapReasoner(_map()).answer("how far is the table from the tv")
    assert a.ok and a.text == "1.0"
    amb = a.evidence["ambiguous"]
    assert len(amb) == 1 and amb[0]["name"] == "tv" and len(amb[0]["instances"]) == 2
    tv_ids = {o.id: o for o in _map().instances if o.name == "tv"}
    near = min(tv_ids, key=lambda i: tv_ids[i].center[0])
    assert amb[0]["used"] == near and amb[0]["rule"] == "the nearest"
    far = [i for i in amb[0]["instances"] if i != near][0]
    assert abs(amb[0]["alternatives"][far] - 2.0) < 1e-6  # the other screen's gap, 1.5 m .. 2.5 m further
    assert "2 tvs in the map" in a.explanation and f"used #{near}" in a.explanation
    printed = ev.line(a.evidence)
    assert "AMBIGUOUS" in printed and "not the map's error" not in printed  # boxes only: no per-view spread
    assert a.evidence["spread_is"].startswith("per-view noise")


def test_unique_names_are_not_ambiguous():
    a = MapReasoner(_map()).answer("How many tv(s) are in this room?")
    assert a.ok and a.text == "2" and a.evidence["ambiguous"] == []
    assert "in the map (" not in a.explanation


def test_a_plural_question_names_the_instances_singular_and_counts_them_in_the_plural():
    """"How far are the chairs from the desk?" printed "3 chairs(s) in the map ... (chairs #2: 1.51 m)": the
    question's plural words reached the ambiguity text, which appended "(s)"."""
    for q, many, one in (("how far are the chairs from the desk?", "3 chairs", "chair"),
                         ("how far is the chair from the desk?", "3 chairs", "chair"),
                         ("how tall are the office chairs?", "2 office chairs", "office chair")):
        a = ask(q)
        assert a.ok and f"{many} in the map (" in a.explanation and "(s)" not in a.explanation, a.explanation
        assert f"{one} #{a.evidence['ambiguous'][0]['instances'][1]}: " in a.explanation, a.explanation
        assert a.evidence["ambiguous"][0]["name"] == one


def test_plural_is_the_inverse_of_singular_over_the_vocabulary():
    from mosaicthinker.runtime.grounding import NAME_SYNONYMS, name_key, plural

    assert [plural(w) for w in ("shelf", "bench", "box", "tv", "battery", "person", "glass", "office chair",
                                "drawers")] == ["shelves", "benches", "boxes", "tvs", "batteries", "people",
                                                "glasses", "office chairs", "drawers"]
    names = set(NAME_SYNONYMS) | set(NAME_SYNONYMS.values())
    odd = {"stair", "drape"}  # `singular` keeps "stairs", "drapes" as they are (names in their own right)
    assert [n for n in names - odd if name_key(plural(n)) != name_key(n)] == []
