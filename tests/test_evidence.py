"""Evidence per answer: per-view estimates kept in the map by fusion, the reasoner's evidence (instances, views,
fused detections, spread of the asked quantity over the views), and how `mosaic ask` prints it."""
from __future__ import annotations

import json

import numpy as np
import pytest

from mosaicthinker.runtime.answer import evidence
from mosaicthinker.runtime.answer import MapReasoner
from mosaicthinker.runtime.commands import ask as ask_cmd
from mosaicthinker.runtime.geometry import OrientedBox
from mosaicthinker.runtime.map import SemanticMap, fuse_observations
from mosaicthinker.runtime.types import Observation


def _box_points(c, size, n=600, seed=0) -> np.ndarray:
    g = np.random.default_rng(seed)
    return np.asarray(c, float) + (g.random((n, 3)) - 0.5) * np.asarray(size, float)


def _obs(name, c, size, frame, seed=0) -> Observation:
    return Observation(name, 0.9, frame, float(frame), _box_points(c, size, seed=seed), np.zeros(4, np.float32))


def _map(extra_shift=0.0) -> SemanticMap:
    """A table seen in 3 views (its centre moves by +-extra_shift in x between views), two chairs in 2 views."""
    obs = [_obs("table", [0.0 + s, 0, 0.4], [1.6, 0.8, 0.8], f, f) for f, s in
           zip((0, 1, 2), (-extra_shift, 0.0, extra_shift))]
    obs += [_obs("chair", [2.0, 0, 0.45], [0.45, 0.45, 0.9], f, 10 + f) for f in (0, 1)]
    obs += [_obs("chair", [-2.0, 0, 0.45], [0.45, 0.45, 0.9], f, 20 + f) for f in (1, 2)]
    inst, _ = fuse_observations(obs)
    return SemanticMap(inst)


def test_fusion_keeps_one_per_view_estimate_per_detection_and_saves_it():
    m = _map()
    table = m.by_name("table")[0]
    assert [v["frame"] for v in table.views] == [0, 1, 2]
    for v in table.views:
        assert np.allclose(v["centre"], [0, 0, 0.4], atol=0.05)
        assert max(v["size"]) == pytest.approx(1.6, abs=0.1)
    back = SemanticMap.from_dict(json.loads(json.dumps(m.to_dict())))
    assert back.by_name("table")[0].views == table.views


def test_evidence_of_each_quantity_matches_the_per_view_values():
    m = _map(extra_shift=0.1)
    r = MapReasoner(m)
    a = r.answer("How many chair(s) are in this room?")
    e = a.evidence
    assert a.text == "2" and e["quantity"] == "per-view count"
    assert sorted(x["id"] for x in e["instances"]) == sorted(o.id for o in m.by_name("chair"))
    assert e["views"] == 3 and e["detections"] == 4
    assert e["n"] == 3 and e["std"] == pytest.approx(np.std([1, 2, 1]), abs=1e-3)  # views 0, 1, 2 see 1, 2, 1

    a = r.answer("What is the length of the longest dimension (length, width, or height) of the table, measured "
                 "in centimeters?")
    e = a.evidence
    longest = [max(v["size"]) * 100 for v in m.by_name("table")[0].views]
    assert e["unit"] == "cm" and e["n"] == 3 and e["std"] == pytest.approx(np.std(longest), abs=0.01)

    a = r.answer("Measuring from the closest point of each object, what is the distance between the table and "
                 "the chair (in meters)?")
    e = a.evidence
    assert e["quantity"] == "per-view-pair distance" and e["n"] == 6  # 3 table views x 2 chair views
    assert e["std"] == pytest.approx(0.1 * np.sqrt(2 / 3), abs=0.02)  # table centre at -0.1, 0, 0.1 m in x
    assert evidence.line(e).startswith("evidence: ")


def test_evidence_without_per_view_estimates_says_so():
    m = SemanticMap.from_meta_info({"object_bbox": {"table": [OrientedBox(np.zeros(3), np.ones(3), np.eye(3))
                                                               .to_meta()]}, "room_size": 10.0})
    e = MapReasoner(m).answer("How many table(s) are in this room?").evidence
    assert e["std"] is None and e["n"] == 0 and "no per-view estimates" in e["note"]
    assert "no spread" in evidence.line(e)


def test_direction_spread_is_zero_for_still_views_and_positive_for_moving_ones():
    q = ("If I am standing by the chair and facing the table, is the sofa to the left or the right of the table? "
         "Options: A. left B. right")

    def build(shift):
        obs = [_obs("chair", [0, -2, 0.4], [0.4, 0.4, 0.8], f, f) for f in (0, 1)]
        obs += [_obs("table", [0, 0, 0.4], [0.8, 0.8, 0.8], f, 10 + f) for f in (0, 1)]
        obs += [_obs("sofa", [1.0, -1.0 + s, 0.4], [0.8, 0.8, 0.8], f, 20 + f) for f, s in ((0, -shift), (1, shift))]
        return SemanticMap(fuse_observations(obs)[0])

    still = MapReasoner(build(0.0)).answer(q)
    moving = MapReasoner(build(0.3)).answer(q)
    assert still.text == moving.text == "right"
    assert still.evidence["quantity"] == "per-view angle" and still.evidence["std"] < 2.0
    assert moving.evidence["std"] > still.evidence["std"] + 2.0


def test_ask_prints_evidence_what_ran_and_undetectable():
    r = {"answer": "2", "explanation": "2 instance(s) of chair in the map", "warnings": [],
         "evidence": {"instances": [{"id": 1, "name": "chair", "views": 2, "detections": 2}], "views": 2,
                      "detections": 2, "quantity": "per-view count", "unit": None, "std": 0.5, "n": 2},
         "ran": {"depth": "sensor", "matcher": "xfeat fp32", "models": {"detector": "ssd_tflite fp32"}},
         "undetectable": ["cabinet"]}
    out = ask_cmd.render(r)
    assert "evidence: chair #1, 2 view(s), 2 fused detection(s); per-view count std 0.50 (n=2)" in out
    assert "ran: depth sensor; matcher xfeat fp32; detector ssd_tflite fp32" in out
    assert "cannot detect" in out and "cabinet" in out


def test_mosaic_ask_on_a_saved_map_returns_and_prints_the_evidence(tmp_path, capsys):
    from mosaicthinker.runtime import cli

    path = tmp_path / "map.json"
    _map().save(path)
    assert cli.main(["ask", str(path), "How many chairs are there?", "--json"]) == 0
    r = json.loads(capsys.readouterr().out)
    assert r["answer"] == "2" and r["evidence"]["detections"] == 4 and r["evidence"]["n"] == 3
    assert r["ran"] is None  # a saved map: no perception ran
    assert cli.main(["ask", str(path), "How many chairs are there?"]) == 0
    assert "evidence: chair #" in capsys.readouterr().out
