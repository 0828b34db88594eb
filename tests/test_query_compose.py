"""The trained reader's composer: kind + role spans -> a program of ir.py, or a refusal that says what was not read
(no model needed: readings are written here as the reader would return them)."""
from __future__ import annotations

import numpy as np
import pytest

from mosaicthinker.runtime.query.compose import ComposeConfig, clean_phrase, compose, unit_of
from mosaicthinker.runtime.query.ir import Count, Direction, Distance, Nearest, Route, Size, Turn
from mosaicthinker.runtime.query.names import NameResolver
from mosaicthinker.runtime.query.reader import Reading, Span, decode_spans
from mosaicthinker.runtime.query.reader_spec import TAGS


def reading(q: str, kind: str, roles: list[tuple[str, str]], p: float = 0.99, sure: float = 0.98) -> Reading:
    """A reading of q: each (role, words) found in q in order."""
    spans, at = [], 0
    for role, words in roles:
        i = q.index(words, at)
        spans.append(Span(role, words, i, i + len(words), sure))
        at = i + len(words)
    return Reading(kind, p, spans, False, ("other", 0.0))


RES = NameResolver(None, ())


def test_count_of_two_objects_and_no_room_word():
    q = "how many chairs and tables are there in this lounge?"
    node, notes = compose(reading(q, "count", [("OBJ", "chairs"), ("OBJ", "tables")]), q, None, RES)
    assert isinstance(node, Count) and [r.name for r in node.objects] == ["chair", "table"]


def test_size_unit_and_dimension_from_the_words():
    q = "the wardrobe, how tall is it in inches?"
    node, _ = compose(reading(q, "size", [("OBJ", "wardrobe"), ("UNIT", "inches")]), q, None, RES)
    assert isinstance(node, Size) and node.dimension == "height" and node.unit == "in"
    q = "longest side of the sofa in millimetres"
    node, _ = compose(reading(q, "size", [("OBJ", "sofa"), ("UNIT", "millimetres")]), q, None, RES)
    assert node.dimension == "longest" and node.unit == "mm" and node.object.name == "sofa"


def test_distance_needs_exactly_two_objects():
    q = "how far is the bed from the door in feet"
    node, _ = compose(reading(q, "distance", [("OBJ", "bed"), ("OBJ", "door"), ("UNIT", "feet")]), q, None, RES)
    assert isinstance(node, Distance) and (node.a.name, node.b.name, node.unit) == ("bed", "door", "ft")
    node, notes = compose(reading(q, "distance", [("OBJ", "bed")]), q, None, RES)
    assert node is None and "the two objects" in notes[-1]


def test_nearest_takes_candidates_from_the_options_when_the_question_lists_none():
    q = "which one is closest to the fridge?"
    node, _ = compose(reading(q, "closest", [("REF", "fridge")]), q, ["A. sink", "B. stove", "C. table"], RES)
    assert isinstance(node, Nearest) and node.origin.name == "refrigerator"
    assert [c.name for c in node.candidates] == ["sink", "stove", "table"] and node.extreme == "closest"


@pytest.mark.parametrize("options,level", [(["A. left", "B. right"], "easy"),
                                           (["A. left", "B. right", "C. back"], "medium"),
                                           (["A. front-left", "B. front-right", "C. back-left", "D. back-right"],
                                            "hard"), (None, "free")])
def test_direction_granularity_from_the_options(options, level):
    q = "i'm at the sofa looking at the tv. where is the lamp?"
    r = reading(q, "direction", [("STAND", "sofa"), ("FACE", "tv"), ("OBJ", "lamp")])
    node, _ = compose(r, q, options, RES)
    assert isinstance(node, Direction) and node.granularity == level
    assert (node.stand.name, node.face.name, node.target.name) == ("sofa", "tv", "lamp")


def test_route_steps_in_order_with_a_turn_between_waypoints():
    q = "from the bed facing the door, get to the sink: walk to the table, then the sink"
    r = reading(q, "route", [("START", "bed"), ("FACE", "door"), ("GOAL", "sink"), ("WAY", "table"),
                             ("GOAL", "sink")])
    node, _ = compose(r, q, None, RES)
    assert isinstance(node, Route) and node.destination.name == "sink"
    assert [type(s).__name__ for s in node.steps] == ["Forward", "Turn", "Forward"]
    assert isinstance(node.steps[1], Turn)


def test_refusals_say_what_was_not_understood():
    q = "how many chairs are on the table?"
    node, notes = compose(reading(q, "count", [("OBJ", "chairs"), ("LOC", "table")]), q, None, RES)
    assert node is None and "'table'" in notes[0] and "a place" in notes[0]  # a confident stray role: refused
    node, notes = compose(reading(q, "count", [("OBJ", "chairs")], p=0.6), q, None, RES)
    assert node is None and "what is asked" in notes[0]  # an unsure kind
    node, notes = compose(reading(q, "count", [("OBJ", "chairs")], sure=0.4), q, None, RES)
    assert node is None and "'chairs'" in notes[0]  # an unsure span
    node, notes = compose(reading(q, "other", []), q, None, RES)
    assert node is None and "no program" in notes[0]
    r = reading(q, "count", [("OBJ", "chairs")])
    r.truncated = True
    assert compose(r, q, None, RES)[0] is None


def test_a_stricter_config_refuses_more():
    q = "how many chairs?"
    r = reading(q, "count", [("OBJ", "chairs")], p=0.9)
    assert compose(r, q, None, RES)[0] is not None
    assert compose(r, q, None, RES, ComposeConfig(kind_min=0.95))[0] is None


def test_phrases_and_units():
    assert clean_phrase("the sofa's") == "sofa" and clean_phrase("my coat rack,") == "coat rack"
    spans = [Span("UNIT", "centimetres", 0, 11, 0.9)]
    assert unit_of(spans, "m") == "cm" and unit_of([], "m") == "m"
    assert unit_of([Span("UNIT", "ft", 0, 2, 0.9)], "m") == "ft"


def test_decode_spans_joins_word_pieces_and_bio_tags():
    text = "how far is the coat rack from the sofa"
    words = [(0, 3), (4, 7), (8, 10), (11, 14), (15, 19), (20, 24), (25, 29), (30, 33), (34, 38)]
    tags = ["O", "O", "O", "O", "B-OBJ", "I-OBJ", "O", "O", "B-OBJ"]
    offsets = [(0, 0)] + words + [(0, 0)]
    probs = np.full((len(offsets), len(TAGS)), 0.001)
    for i, t in enumerate(["O"] + tags + ["O"]):
        probs[i, TAGS.index(t)] = 0.95
    spans = decode_spans(text, offsets, probs)
    assert [(s.role, s.text) for s in spans] == [("OBJ", "coat rack"), ("OBJ", "sofa")]
    assert all(abs(s.confidence - 0.951) < 1e-3 for s in spans)  # the role's probability: B- plus I-


def test_names_known_by_the_map_resolve_as_written_and_unknown_ones_stay():
    res = NameResolver(None, ["coat hanger"])
    ref, notes = res("coat hangers", True)
    assert ref.name == "coat hanger" and not notes
    ref, _ = res("zither")
    assert ref.name == "zither" and not ref.known


@pytest.mark.parametrize("q,level", [("from the bed facing the door, is the lamp on my left or my right?", "easy"),
                                     ("at the bed facing the door: the lamp, left, right or behind me?", "medium"),
                                     ("my back is to the bed and i face the door; is the lamp left or right?", "easy"),
                                     ("at the bed facing the door, which quadrant is the lamp in?", "hard"),
                                     ("at the bed facing the door, where is the lamp?", "free")])
def test_direction_granularity_from_the_choices_the_question_lists(q, level):
    stand = q.index("bed")
    r = Reading("direction", 0.99, [Span("STAND", "bed", stand, stand + 3, 0.98),
                                    Span("FACE", "door", q.index("door"), q.index("door") + 4, 0.98),
                                    Span("OBJ", "lamp", q.index("lamp"), q.index("lamp") + 4, 0.98)])
    assert compose(r, q, None, RES)[0].granularity == level


def test_a_name_said_twice_in_one_role_is_one_span_and_two_names_refuse():
    q = "which is closest to the bed: lamp or desk? measure from the bed"
    node, _ = compose(reading(q, "closest", [("REF", "bed"), ("CAND", "lamp"), ("CAND", "desk"), ("REF", "bed")]),
                      q, None, RES)
    assert isinstance(node, Nearest) and node.origin.name == "bed" and len(node.candidates) == 2
    q = "which is closest to the bed: lamp or desk? measure from the sofa"
    node, notes = compose(reading(q, "closest", [("REF", "bed"), ("CAND", "lamp"), ("CAND", "desk"),
                                                 ("REF", "sofa")]), q, None, RES)
    assert node is None and "bed, sofa" in notes[-1]


def test_a_name_said_again_in_its_role_counts_its_surest_mention():
    q = "at the desk, facing the door: is the lamp left or right of the door?"
    spans = [Span("STAND", "desk", 7, 11, 0.95), Span("FACE", "door", 24, 28, 0.55), Span("OBJ", "lamp", 33, 37, 0.97),
             Span("FACE", "door", q.rindex("door"), q.rindex("door") + 4, 0.9)]
    node, notes = compose(Reading("direction", 0.99, spans, False, ("other", 0.0)), q, None, RES)
    assert isinstance(node, Direction) and node.face.name == "door", notes
    spans[3] = Span("FACE", "door", q.rindex("door"), q.rindex("door") + 4, 0.5)  # never sure: refused
    node, notes = compose(Reading("direction", 0.99, spans, False, ("other", 0.0)), q, None, RES)
    assert node is None and "'door'" in notes[0]
