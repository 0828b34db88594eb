"""Issue 36's classes as property tests (hypothesis, derandomized, bounded; the campaign in tests/campaign_round4.py
runs them through every command): numbers of any size read from a question or a file, ground truth that is not
there, objects that vanish, maps far from the origin, files checked before work, and killed runs."""
from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fuzz_files import base_map
from mosaicthinker.runtime.cli import main
from mosaicthinker.runtime.geometry import OrientedBox, fit_gravity_box, min_area_rect, polygon_area
from mosaicthinker.runtime.health import map_notes
from mosaicthinker.runtime.infra import jsonio
from mosaicthinker.runtime.infra.errors import InputError
from mosaicthinker.runtime.infra.numbers import check_array, read_number
from mosaicthinker.runtime.map import ObjectInstance, SemanticMap
from mosaicthinker.runtime.query import parse_question
from mosaicthinker.runtime.query.schema import from_json, to_json

FUZZ = settings(max_examples=40, deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])

# a number as typed: 1..1000 digits, maybe a fraction, maybe leading zeros
NUMBER = st.builds(lambda lead, body, frac: lead + body + frac, st.sampled_from(["", "0", "000"]),
                   st.text("0123456789", min_size=1, max_size=1000),
                   st.one_of(st.just(""), st.text("0123456789", min_size=1, max_size=60).map(lambda s: "." + s)))
WORDINGS = ["Is the table within {n} m of the chair?", "Is the chair more than {n} feet from the door?",
            "Is the sofa longer than {n} cm?", "Is the room bigger than {n} square meters?",
            "Are there at least {n} chairs?", "Are there {n} cups?", "Are there more than {n} tables?",
            "If I stand by the sofa facing the tv and turn {n} degrees, is the lamp to my left?"]


@FUZZ
@given(w=st.sampled_from(WORDINGS), n=NUMBER)
def test_a_number_of_any_length_in_a_question_is_read_or_refused_naming_it(w, n):
    """Never an OverflowError; a printed program is one the program reader accepts; a refusal names the
    question's number (exit 2 at the CLI)."""
    try:
        p = parse_question(w.format(n=n))
    except InputError as e:
        assert str(e).startswith("question: ") and ("range" in str(e) or "number" in str(e)), e
        return
    if p.program is not None:
        from_json(to_json(p.program))  # raises ProgramError for a value outside the schema


def test_huge_numbers_through_the_cli(capsys):
    big = "9" * 400
    for q in (f"Is the table more than {big} meters from the chair?", f"Is the sofa longer than {big} cm?",
              f"Is the room bigger than {big} square meters?", "Are there at least " + "1" + "0" * 30 + " chairs?"):
        assert main(["parse", q]) == 2
        err = capsys.readouterr().err
        assert err.startswith("error: question: ") and "out of range" in err and "Traceback" not in err, err


@FUZZ
@given(text=st.one_of(NUMBER, st.sampled_from(["nan", "inf", "-inf", "1e999999", "-1e-999999", "x", ""])),
       lo=st.sampled_from([0.0, 1.0, -math.inf]), hi=st.sampled_from([1000.0, 1e6, math.inf]))
def test_read_number_is_exact_and_never_overflows(text, lo, hi):
    try:
        v = read_number(text, "the value", lo=lo, hi=hi)
    except InputError as e:
        assert str(e).startswith("the value: ")
        return
    assert math.isfinite(v) and lo <= v <= hi


@FUZZ
@given(vals=st.lists(st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-10**30, 10**30)),
                     min_size=1, max_size=16))
def test_check_array_refuses_exactly_the_non_finite_and_out_of_range(vals):
    a = np.asarray([float(v) for v in vals])
    ok = bool(np.isfinite(a).all() and (np.abs(a) <= 1e7).all())
    try:
        check_array(vals, "f.txt", "a matrix", lo=-1e7, hi=1e7)
        assert ok
    except InputError as e:
        assert not ok and str(e).startswith("f.txt: a matrix holds")


@settings(FUZZ, max_examples=20)
@given(doc=st.recursive(st.one_of(st.floats(), st.integers(), st.text(max_size=4), st.none()),
                        lambda c: st.one_of(st.lists(c, max_size=4), st.dictionaries(st.text(max_size=3), c,
                                                                                     max_size=4)), max_leaves=20))
def test_every_json_written_is_strict(doc):
    text = jsonio.dumps(doc, indent=1)
    assert jsonio.is_strict(text)
    back = json.loads(text)
    assert back == jsonio.finite_or_none(doc)


# ------------------------------------------------------------------------------------------- maps

def _map(sizes: list[float], offset: np.ndarray = np.zeros(3), yaw: float = 0.3) -> SemanticMap:
    """Four objects; object i's box is sizes[i] long (its other sides 0.6 and 0.9 of it)."""
    c, s = math.cos(yaw), math.sin(yaw)
    R = np.array([[c, s, 0], [-s, c, 0], [0, 0, 1.0]])
    pos = [[0, 0, 0.5], [2.5, 0.5, 0.5], [1.0, 3.0, 0.4], [4.0, 2.0, 0.9]]
    names = ["chair", "chair", "table", "sofa"]
    return SemanticMap([ObjectInstance(i, names[i], OrientedBox(np.array(pos[i], float) + offset, np.maximum(
        np.array([1.0, 0.6, 0.9]) * sizes[i], 5e-324), R)) for i in range(4)], None, [], {})


@FUZZ
@given(k=st.integers(0, 3), e=st.floats(-323.5, 300))
def test_implausible_objects_are_named_in_both_directions(k, e):
    sizes = [0.5, 0.6, 1.2, 2.0]
    sizes[k] = max(10.0 ** e, 5e-324)
    smap = _map(sizes)
    o = smap.instances[k]
    said = " ".join(map_notes(smap))
    if sizes[k] > 30 or sizes[k] < 0.01:  # its longest side
        assert f"{o.name} #{o.id}" in said and ("smaller than 1 cm" in said or "longer than 30 m" in said), said
    else:
        assert not said, said


def test_non_finite_box_named():
    smap = _map([0.5, 0.6, 1.2, 2.0])
    smap.instances[2].box.centroid[0] = np.nan
    assert "table #2" in " ".join(map_notes(smap))


@FUZZ
@given(ox=st.floats(-1e7, 1e7), oy=st.floats(-1e7, 1e7), yaw=st.floats(0, 3.1))
def test_geometry_does_not_depend_on_where_the_map_is(ox, oy, yaw):
    """Room rectangle, area, gravity boxes: the same 10^7 m from the origin as at it (float64 local origin)."""
    rng = np.random.default_rng(0)
    pts = rng.uniform(0, 5, (200, 3)) * [1, 0.6, 0.4]
    c, s = math.cos(yaw), math.sin(yaw)
    pts[:, :2] = pts[:, :2] @ np.array([[c, -s], [s, c]]).T
    off = np.array([ox, oy, 0.0])
    (_, _), (w0, h0), _ = min_area_rect(pts[:, :2])
    (_, _), (w1, h1), _ = min_area_rect(pts[:, :2] + off[:2])
    assert w0 * h0 == pytest.approx(w1 * h1, rel=1e-5, abs=1e-6)
    b0, b1 = fit_gravity_box(pts), fit_gravity_box(pts + off)
    assert np.allclose(np.sort(b0.axes_lengths), np.sort(b1.axes_lengths), rtol=1e-5, atol=1e-6)
    assert np.allclose(b1.centroid - off, b0.centroid, atol=1e-3)
    poly = pts[:6, :2]
    assert polygon_area(poly + off[:2]) == pytest.approx(polygon_area(poly), rel=1e-6, abs=1e-6)


def test_room_size_of_a_map_translated_by_a_million_metres(tmp_path, capsys):
    d = base_map()
    d.pop("room")
    answers = []
    for off in (0.0, 1e6, -3.3e6):
        m = json.loads(json.dumps(d))
        for o in m["instances"]:
            for k in ("centroid", "min", "max"):
                if k in o["box"]:
                    o["box"][k][0] += off
                    o["box"][k][1] += off
        for cam in m["cameras"]:
            cam["T_wc"][0][3] += off
        (tmp_path / "m.json").write_text(json.dumps(m))
        assert main(["ask", str(tmp_path / "m.json"), "How big is the room (in square meters)?", "--json"]) == 0
        answers.append(json.loads(capsys.readouterr().out)["answer"])
    assert answers[0] == answers[1] == answers[2], answers


# ------------------------------------------------------------------------------------------- files, ground truth

def _rgbd(tmp: Path, n: int = 6) -> Path:
    from test_bad_inputs import rgbd_folder

    return rgbd_folder(tmp, n=n)


@settings(max_examples=12, deadline=None, derandomize=True, database=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(bad=st.sets(st.integers(0, 5), min_size=1, max_size=6), v=st.sampled_from([np.nan, np.inf, -np.inf]))
def test_non_finite_pose_files_are_listed_or_refused(tmp_path_factory, bad, v):
    from mosaicthinker.runtime.frames import open_source

    d = _rgbd(tmp_path_factory.mktemp("p"))
    for i in bad:
        np.savetxt(d / f"frame-{i:06d}.pose.txt", np.full((4, 4), v))
    src = open_source(d)
    if len(bad) == 6:
        with pytest.raises(InputError, match="every one of the 6 pose files holds NaN or infinity"):
            src.untracked_frames()
        return
    assert src.untracked_frames() == sorted(bad)
    assert any(f"{len(bad)} of 6 pose files hold non-finite" in n for n in src.notes)
    assert all(src[i].pose_gt is None for i in bad)


@settings(max_examples=15, deadline=None, derandomize=True, database=None)
@given(hit=st.sets(st.sampled_from([("chair", 0), ("chair", 1), ("table", 0)]), min_size=0, max_size=3),
       part=st.sampled_from(["centroid", "axesLengths"]), v=st.sampled_from([math.nan, math.inf, -1.0, 0.0]))
def test_gt_boxes_with_parts_not_there_are_named_or_refused(tmp_path_factory, hit, part, v):
    from mosaicthinker.host.evaluation.scene import load_gt_boxes

    if part == "centroid" and v in (-1.0, 0.0):
        v = math.nan  # a centre may be anywhere
    boxes = {"chair": [{"centroid": [0, 0, 0.5], "axesLengths": [0.5, 0.5, 1]},
                       {"centroid": [1, 1, 0.5], "axesLengths": [0.5, 0.5, 1]}],
             "table": [{"centroid": [2, 0, 0.4], "axesLengths": [1, 1, 0.8]}]}
    for c, j in hit:
        boxes[c][j][part][1] = v
    f = tmp_path_factory.mktemp("g") / "gt_boxes.json"
    f.write_text(json.dumps({"axis_align_matrix": np.eye(4).tolist(), "object_bbox": boxes}))
    if len(hit) == 3:
        with pytest.raises(InputError, match="nothing is left to score"):
            load_gt_boxes(f)
        return
    _, scene, _ = load_gt_boxes(f)
    assert sorted(d.split(" (")[0] for d in scene["not_scored"]) == sorted(f"{c} #{j}" for c, j in hit)
    assert sum(map(len, scene["object_bbox"].values())) == 3 - len(hit)


@pytest.mark.parametrize("damage", ["nan", "utf8", "scaled"])
def test_eval_scene_refuses_bad_ground_truth_and_output_before_work(tmp_path, capsys, damage):
    d = _rgbd(tmp_path, n=3)
    m = np.eye(4)
    if damage == "nan":
        m[1, 3] = np.nan
    if damage == "scaled":
        m[:3, :3] *= 2
    text = json.dumps({"axis_align_matrix": m.tolist(), "object_bbox": {}}).encode()
    (d / "gt_boxes.json").write_bytes(text.replace(b"{", b"{\xff", 1) if damage == "utf8" else text)
    # no bundle at all: the refusal comes before anything is loaded or aligned
    assert main(["eval", "scene", "--data", str(d), "--bundle", str(tmp_path / "none")]) == 2
    err = capsys.readouterr().err
    assert "gt_boxes.json" in err and ("axis_align_matrix" in err or "UTF-8" in err), err
    (tmp_path / "f").write_text("x")
    assert main(["eval", "scene", "--data", str(d), "--bundle", str(tmp_path / "none"), "--out",
                 str(tmp_path / "f" / "o")]) == 2
    assert "--out" in capsys.readouterr().err


def test_non_utf8_annotation_is_refused_naming_it(tmp_path, capsys):
    d = _rgbd(tmp_path, n=3)
    a = tmp_path / "ann.json"
    a.write_bytes(b'{"schema": "mosaicthinker.scene_annotation/1", "scene": "caf\xe9"}')
    assert main(["eval", "scene", "--data", str(d), "--bundle", str(tmp_path / "none"), "--annotations",
                 str(a)]) == 2
    err = capsys.readouterr().err
    assert "ann.json" in err and "not UTF-8" in err, err


# ------------------------------------------------------------------------------------------- killed runs

@pytest.mark.parametrize("status", ["running", "interrupted", "failed"])
def test_a_folder_left_by_an_unfinished_run_says_so(tmp_path, capsys, status):
    m = tmp_path / "m.json"
    m.write_text(json.dumps(base_map()))
    out = tmp_path / "o"
    assert main(["ask", str(m), "How many chairs?", "--out", str(out)]) == 0
    capsys.readouterr()
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()  # a pid that is gone, as after SIGKILL
    rec = json.loads((out / "run.json").read_text())
    rec.update(status=status, pid=dead.pid, run_id="20261208T000000Z-deadbeef",
               **({"reason": "interrupted by SIGTERM"} if status != "running" else {}))
    (out / "run.json").write_text(json.dumps(rec))
    if status == "running":  # SIGKILL leaves the lock too
        (out / ".mosaic.lock").write_text(json.dumps({"pid": dead.pid, "host": os.uname().nodename,
                                                      "run_id": rec["run_id"], "started": 0}))
    assert main(["ask", str(out / "map.json"), "How many chairs?"]) == 0
    said = capsys.readouterr().out
    assert "did not finish" in said and "20261208T000000Z-deadbeef" in said, said
    assert main(["ask", str(m), "How many chairs?", "--out", str(out)]) == 0
    assert "did not finish" in capsys.readouterr().out
    assert main(["ask", str(out / "map.json"), "How many chairs?"]) == 0  # that run finished: nothing to say
    assert "did not finish" not in capsys.readouterr().out


def test_vsibench_result_files_are_checked_before_scoring(tmp_path, capsys):
    (tmp_path / "f").write_text("x")
    q, m = tmp_path / "q.jsonl", tmp_path / "m.json"
    q.write_text('{"scene_name": "s", "question_type": "object_counting", "question": "How many chair(s)?", '
                 '"ground_truth": 1}\n')
    m.write_text("{]")  # would be refused when read: the result file must be refused first
    for flag, bad in (("--result", tmp_path / "f" / "r.json"), ("--disagreements", tmp_path)):
        assert main(["eval", "vsibench", "--questions", str(q), "--meta", str(m), flag, str(bad)]) == 2
        err = capsys.readouterr().err
        assert err.startswith(f"error: {flag} ") and str(bad) in err, err
