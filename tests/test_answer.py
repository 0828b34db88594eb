"""Map reasoner conventions on hand-computed tiny maps, and the question parser on every template."""
from __future__ import annotations

import numpy as np
import pytest

from mosaicthinker.runtime.answer import (Answer, MapReasoner, direction_label, signed_angle_deg, turn_label)
from mosaicthinker.runtime.geometry import OrientedBox, rotation_about
from mosaicthinker.runtime.grounding import (QTYPES, VOCABULARY, canonical_name, parse_question, split_options)
from mosaicthinker.runtime.query.ir import (AppearanceOrder, Count, Direction, Distance, Nearest, Ref, RoomSize,
                                           Size)
from mosaicthinker.runtime.map import ObjectInstance, Room, SemanticMap


def box(c, size=(0.5, 0.5, 0.5), yaw_deg=0.0) -> OrientedBox:
    R = rotation_about([0, 0, 1], np.radians(yaw_deg))
    return OrientedBox(np.asarray(c, float), np.asarray(size, float), R.T)


def make_map(objs, room=None) -> SemanticMap:
    inst = [ObjectInstance(i, name, b, first_seen=t) for i, (name, b, t) in enumerate(objs)]
    return SemanticMap(inst, room)


HARD = "If I am standing by the {a} and facing the {b}, is the {c} to my front-left, front-right, back-left, or " \
       "back-right?\nThe directions refer to the quadrants of a Cartesian plane (if I am standing at the origin " \
       "and facing along the positive y-axis)."
MEDIUM = "If I am standing by the {a} and facing the {b}, is the {c} to my left, right, or back?\nAn object is " \
         "to my back if I would have to turn at least 135 degrees in order to face it."
EASY = "If I am standing by the {a} and facing the {b}, is the {c} to the left or the right of the {b}?"


# ----------------------------------------------------------------------------- direction conventions


def test_signed_angle_and_labels_hand_values():
    f = np.array([0.0, 1.0])  # facing +y, z up: +x is to the right
    assert signed_angle_deg(f, [-1, 0]) == pytest.approx(90)
    assert signed_angle_deg(f, [1, 0]) == pytest.approx(-90)
    assert signed_angle_deg(f, [0, -1]) == pytest.approx(180)
    cases = {(-1, 1): "front-left", (-1, -1): "back-left", (1, -1): "back-right", (1, 1): "front-right"}
    for v, lab in cases.items():
        assert direction_label(signed_angle_deg(f, v), "hard") == lab
    # medium: back from a 135 degree turn on, either side
    assert direction_label(130, "medium") == "left" and direction_label(140, "medium") == "back"
    assert direction_label(-130, "medium") == "right" and direction_label(-140, "medium") == "back"
    assert direction_label(10, "medium") == "left" and direction_label(-10, "medium") == "right"
    assert direction_label(170, "easy") == "left" and direction_label(-170, "easy") == "right"
    assert turn_label(100) == "turn left" and turn_label(-100) == "turn right" and turn_label(-150) == "turn back"
    with pytest.raises(ValueError):
        direction_label(10, "extreme")


def direction_map():
    # standing by the bed at the origin, facing the tv at +y (2 m); objects around
    return make_map([("bed", box([0, 0, 0.3]), 0.0), ("tv", box([0, 2, 1.0]), 1.0),
                     ("chair", box([-1.5, 1.0, 0.4]), 2.0),  # front-left, +56 deg
                     ("sofa", box([-1.0, -2.0, 0.4], (2.0, 0.9, 0.8)), 3.0),  # back-left, +153 deg
                     ("stove", box([1.0, -0.5, 0.4]), 4.0),  # back-right, -117 deg
                     ("toilet", box([2.0, 2.5, 0.4]), 5.0)])  # front-right, -39 deg


@pytest.mark.parametrize("c,hard,medium,easy", [("chair", "front-left", "left", "left"),
                                                ("sofa", "back-left", "back", "left"),
                                                ("stove", "back-right", "right", "right"),
                                                ("toilet", "front-right", "right", "right")])
def test_relative_direction_on_a_hand_made_map(c, hard, medium, easy):
    r = MapReasoner(direction_map())
    a = r.answer(HARD.format(a="bed", b="tv", c=c), ["A. front-left", "B. front-right", "C. back-left",
                                                     "D. back-right"])
    assert a.status == "ok" and a.value == hard and a.text == "ABCD"[["front-left", "front-right", "back-left",
                                                                      "back-right"].index(hard)]
    a = r.answer(MEDIUM.format(a="bed", b="tv", c=c), ["A. right", "B. back", "C. left"])
    assert a.value == medium and a.text == {"right": "A", "back": "B", "left": "C"}[medium]
    a = r.answer(EASY.format(a="bed", b="tv", c=c), ["A. left", "B. right"])
    assert a.value == easy and a.text == ("A" if easy == "left" else "B")


def test_relative_direction_uses_box_centres_and_synonyms():
    # synonyms in the question resolve to the map's names; the sofa's long box does not change the answer
    r = MapReasoner(direction_map())
    a = r.answer(HARD.format(a="bed", b="television", c="couch"),
                 ["A. back-left", "B. front-left", "C. front-right", "D. back-right"])
    assert a.ok and a.text == "A"


# ----------------------------------------------------------------------------- numbers


def numbers_map():
    return make_map([("chair", box([0, 0, 0.45], (0.5, 0.55, 0.9)), 1.0),
                     ("chair", box([3, 0, 0.45], (0.5, 0.55, 0.9), 30), 2.0),
                     ("table", box([0, 2.0, 0.4], (1.6, 0.8, 0.8)), 0.5),
                     ("sofa", box([5.0, 5.0, 0.4], (2.1, 0.9, 0.8), 90), None)],
                    Room(np.array([[-1, -1], [6, -1], [6, 6], [-1, 6.0]]), 0.0, 2.5, "test"))


def test_counting_size_room_and_distance():
    r = MapReasoner(numbers_map())
    a = r.answer("How many chair(s) are in this room?")
    assert (a.status, a.text, a.value) == ("ok", "2", 2)
    a = r.answer("What is the length of the longest dimension (length, width, or height) of the table, "
                 "measured in centimeters?")
    assert a.text == "160" and a.value == pytest.approx(160)
    a = r.answer("What is the size of this room (in square meters)? \nIf multiple rooms are shown, estimate the "
                 "size of the combined space.")
    assert a.text == "49.0" and a.value == pytest.approx(49.0)
    # closest points: chair #0 spans y in [-0.275, 0.275], table y in [1.6, 2.4] -> 1.325 m
    a = r.answer("Measuring from the closest point of each object, what is the distance between the chair and "
                 "the table (in meters)?")
    assert a.value == pytest.approx(1.325) and a.text == "1.3"
    # several instances: the closest pair counts
    a = r.answer("Measuring from the closest point of each object, what is the distance between the sofa and "
                 "the chair (in meters)?")
    c1 = make_map([("chair", box([3, 0, 0.45], (0.5, 0.55, 0.9), 30), None),
                   ("sofa", box([5.0, 5.0, 0.4], (2.1, 0.9, 0.8), 90), None)])
    assert a.value == pytest.approx(MapReasoner(c1).answer(
        "Measuring from the closest point of each object, what is the distance between the sofa and the chair "
        "(in meters)?").value)


def test_relative_distance_closest_and_farthest():
    r = MapReasoner(numbers_map())
    q = "Measuring from the closest point of each object, which of these objects ({}) is the {} to the table?"
    opts = ["A. chair", "B. sofa"]
    a = r.answer(q.format("chair, sofa", "closest"), opts)
    assert a.ok and (a.text, a.value) == ("A", "chair")
    a = r.answer(q.format("chair, sofa", "farthest"), opts)
    assert a.ok and (a.text, a.value) == ("B", "sofa")


def test_numeric_question_with_options_picks_the_nearest():
    a = MapReasoner(numbers_map()).answer("How many chair(s) are in this room?", ["A. 5", "B. 2", "C. 3"])
    assert a.ok and a.text == "B"
    a = MapReasoner(numbers_map()).answer("What is the length of the longest dimension (length, width, or height) "
                                          "of the table, measured in centimeters?", ["A. 90 cm", "B. 155 cm"])
    assert a.ok and a.text == "B" and a.value == pytest.approx(160)


def test_appearance_order_from_first_seen():
    r = MapReasoner(numbers_map())
    q = "What will be the first-time appearance order of the following categories in the video: chair, table?"
    a = r.answer(q, ["A. chair, table", "B. table, chair"])
    assert a.ok and a.text == "B" and a.value == ["table", "chair"]
    a = r.answer("What will be the first-time appearance order of the following categories in the video: "
                 "chair, sofa?", ["A. chair, sofa", "B. sofa, chair"])
    assert a.status == "unsupported" and "first-seen" in a.explanation


# ----------------------------------------------------------------------------- route planning


ROUTE = ("You are a robot beginning at the bed facing the tv. You want to navigate to the toilet. You will perform "
         "the following actions (Note: for each [please fill in], choose either 'turn back,' 'turn left,' or "
         "'turn right.'): 1. Go forward until the tv 2. [please fill in] 3. Go forward until the stove 4. "
         "[please fill in] 5. Go forward until the toilet. You have reached the final destination.")


def test_route_planning_hand_case():
    # bed (0,0) -> tv (0,2) heading +y; stove at (2,2): turn right; toilet at (2,4): from heading +x, turn left
    m = make_map([("bed", box([0, 0, 0.3]), None), ("tv", box([0, 2, 1]), None), ("stove", box([2, 2, 0.4]), None),
                  ("toilet", box([2, 4, 0.4]), None)])
    opts = ["A. Turn Back, Turn Left", "B. Turn Left, Turn Left", "C. Turn Right, Turn Left",
            "D. Turn Right, Turn Right"]
    a = MapReasoner(m).answer(ROUTE, opts)
    assert a.ok and a.text == "C" and a.value == ["Turn Right", "Turn Left"]
    # going back the way it came is "turn back"
    m2 = make_map([("bed", box([0, 0, 0.3]), None), ("tv", box([0, 2, 1]), None), ("stove", box([0.3, -1, 0.4]), None),
                   ("toilet", box([-2, -1, 0.4]), None)])
    assert MapReasoner(m2).answer(ROUTE, opts).value == ["Turn Back", "Turn Right"]


# ----------------------------------------------------------------------------- not found / unsupported


def test_missing_objects_are_reported_never_guessed():
    r = MapReasoner(numbers_map())
    a = r.answer("How many piano(s) are in this room?")
    assert a.status == "not_found" and a.missing == ["piano"] and a.value == 0 and "not found" in a.text
    a = r.answer(HARD.format(a="chair", b="bed", c="tv"), ["A. front-left", "B. front-right", "C. back-left",
                                                          "D. back-right"])
    assert a.status == "not_found" and a.missing == ["bed", "tv"] and a.text.startswith("not found")
    a = r.answer("Measuring from the closest point of each object, what is the distance between the chair and the "
                 "grand zither (in meters)?")
    assert a.status == "not_found" and a.missing == ["grand zither"]
    assert a.parsed is not None and a.parsed.unknown == ["grand zither"]
    a = r.answer(ROUTE, ["A. Turn Left, Turn Left"])
    assert a.status == "not_found" and set(a.missing) == {"bed", "tv", "stove", "toilet"}


def test_unrecognised_question_is_unsupported():
    a = MapReasoner(numbers_map()).answer("What colour is the sofa?")
    assert isinstance(a, Answer) and a.status == "unsupported" and a.qtype is None
    d = a.to_dict()
    assert d["status"] == "unsupported" and d["parsed"]["qtype"] is None


def test_empty_map_room_size_unsupported():
    a = MapReasoner(SemanticMap()).answer("What is the size of this room (in square meters)?")
    assert a.status == "unsupported"


# ----------------------------------------------------------------------------- grounding


def test_vocabulary_covers_benchmark_and_common_objects():
    for c in ("chair", "table", "sofa", "tv", "stool", "bed", "toilet", "stove", "bathtub", "washer", "refrigerator",
              "fireplace", "dishwasher", "lamp", "plant", "cabinet", "shelf", "door", "sink"):
        assert c in VOCABULARY and canonical_name(c) == c
    pairs = {"couch": "sofa", "television": "tv", "monitor": "monitor", "dining table": "table", "potted plant": "plant",
             "fridge": "refrigerator", "washing machine": "washer", "bath tub": "bathtub", "Sofas": "sofa",
             "chair(s)": "chair", "the stool by the piano": "stool", "kitchen sink": "sink", "bookshelves": "bookshelf",
             "edge of the bed": "bed", "3-seater sofa": "sofa", "tv_monitor": "tv"}
    for s, c in pairs.items():
        assert canonical_name(s) == c, s
    assert canonical_name("grand zither") is None and canonical_name("") is None
    # only true synonyms: related objects keep their own names, unknown heads name nothing
    for s, c in {"computer tower": None, "ceiling light": None, "power strip": None, "desk": "desk",
                 "freezer": "freezer", "radiator": "radiator", "cushion": "cushion", "phone": "telephone",
                 "trash cans": "trash bin", "garbage bin": "trash bin", "the kitchen's sink": "sink"}.items():
        assert canonical_name(s) == c, s


def test_parse_every_template():
    R = Ref
    cases = {
        "How many table(s) are in this room?": ("object_counting", ["table"], [], Count((R("table"),))),
        "What is the length of the longest dimension (length, width, or height) of the couch, measured in "
        "centimeters?": ("object_size_estimation", ["sofa"], [], Size(R("sofa", "couch"))),
        "What is the size of this room (in square meters)? \nIf multiple rooms are shown, estimate the size of the "
        "combined space.": ("room_size_estimation", [], [], RoomSize()),
        "Measuring from the closest point of each object, what is the distance between the sofa and the stove (in "
        "meters)?": ("object_abs_distance", ["sofa", "stove"], [], Distance(R("sofa"), R("stove"))),
        "Measuring from the closest point of each object, which of these objects (chair, stool, stove, sofa) is the "
        "closest to the tv?": ("object_rel_distance", ["chair", "stool", "stove", "sofa"], ["tv"],
                               Nearest(R("tv"), (R("chair"), R("stool"), R("stove"), R("sofa")), "closest")),
        HARD.format(a="stove", b="sofa", c="tv"): ("object_rel_direction_hard", ["tv"], ["stove", "sofa"],
                                                   Direction(R("stove"), R("sofa"), R("tv"), "hard")),
        MEDIUM.format(a="stove", b="sofa", c="tv"): ("object_rel_direction_medium", ["tv"], ["stove", "sofa"],
                                                     Direction(R("stove"), R("sofa"), R("tv"), "medium")),
        EASY.format(a="stove", b="sofa", c="tv"): ("object_rel_direction_easy", ["tv"], ["stove", "sofa"],
                                                   Direction(R("stove"), R("sofa"), R("tv"), "easy", R("sofa"))),
        "What will be the first-time appearance order of the following categories in the video: chair, tv, fridge, "
        "sofa?": ("obj_appearance_order", ["chair", "tv", "refrigerator", "sofa"], [],
                  AppearanceOrder((R("chair"), R("tv"), R("refrigerator", "fridge"), R("sofa")))),
    }
    for q, (qt, targets, cues, node) in cases.items():
        p = parse_question(q)
        assert (p.qtype, p.targets, p.cues, p.node, p.unknown) == (qt, targets, cues, node, []), q
    p = parse_question(ROUTE)
    assert p.qtype == "route_planning" and p.targets == ["toilet"] and p.cues == ["bed", "tv", "stove"]
    assert [type(s).__name__ for s in p.node.steps] == ["Forward", "Turn", "Forward", "Turn", "Forward"]
    assert {q.split("_")[0] for q in QTYPES} >= {"object", "room", "route", "obj"}


def test_parse_unknown_names_and_non_templates():
    p = parse_question("How many grand zither(s) are in this room?")
    assert p.qtype == "object_counting" and p.unknown == ["grand zither"] and p.targets == ["grand zither"]
    p = parse_question("You are a robot beginning at the door and facing into the room. You want to navigate to "
                       "the window. You will perform the following actions: 1. [please fill in] 2. Go forward "
                       "until the window. You have reached the final destination.")
    assert p.qtype == "route_planning" and p.unknown == ["room"] and p.node.face.name == "room"
    p = parse_question("Describe the kitchen.")
    assert p.qtype is None and p.targets == [] and p.unknown == []


def test_split_options():
    assert split_options(["A. left", "B. right"]) == [("A", "left"), ("B", "right")]
    assert split_options(["left", "right"]) == [("A", "left"), ("B", "right")]
    assert split_options(None) == []
