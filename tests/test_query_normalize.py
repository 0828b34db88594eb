"""The parser's normalisers, one by one (unicode, units and cue synonyms, numbers in words, clauses, cue scores),
and a property over whole questions: the clauses of a stance question say the same in any order. (The spelling
corrector, texting shorthand and the phrase tables written for wording sets 8-10 retired with issue 35: a
misspelt word is the trained reader's, docs/query.md.)"""
from __future__ import annotations

import itertools
import json
from pathlib import Path

import pytest

from mosaicthinker.runtime.query import cues
from mosaicthinker.runtime.query.normalize import _number_words, normalize, synonyms, unicode_ascii
from mosaicthinker.runtime.query.parse import parse_question
from mosaicthinker.runtime.query.rules.clauses import read_clauses
from mosaicthinker.runtime.query.rules.tokens import tokens
from mosaicthinker.runtime.query.vocabulary import NAME_SYNONYMS, name_key

REPO = Path(__file__).resolve().parents[1]


# ----------------------------------------------------------------------------- the normalisers, one by one

def test_unicode_punctuation_becomes_ascii_and_lower_case():
    assert unicode_ascii("The TV\u2019s height \u2014 in m\u00b2\u2026") == "the tv's height - in m2 ..."
    assert unicode_ascii("\u201cquoted\u201d\u00a0word") == '"quoted" word'


@pytest.mark.parametrize("text, want", [
    ("how big is it in m2?", "how big is it in square meters?"), ("area in sq ft", "area in square feet"),
    ("whats the square footage", "whats the square feet"), ("m^2 please", "square meters please"),
    ("in sq. m", "in square meters"), ("so what's the tally?", "so what's the count?"),
    ("which has the smallest gap to the tv", "which has the closest to the tv"),
    ("what is it at its longest", "what is it at its longest dimension"),
    ("nearest neighbour of the tv", "nearest to the tv"), ("the bed is dead ahead", "the bed is straight ahead")])
def test_phrase_synonyms_give_the_parsers_own_words(text, want):
    assert synonyms(text) == want


def test_a_unit_word_inside_another_word_is_left_alone():
    assert synonyms("the smart tv") == "the smart tv" and synonyms("a sqm") == "a square meters"


@pytest.mark.parametrize("text, want", [
    ("two and a half metres", "2.5 metres"), ("twenty-five cm", "25 cm"), ("a couple of metres away", "2 metres away"),
    ("a dozen chairs", "12 chairs"), ("half a dozen cups", "6 cups"), ("two chairs", "two chairs"),
    ("one of them", "one of them"), ("three feet", "3 feet")])
def test_numbers_in_words_before_a_unit_become_digits(text, want):
    assert _number_words(text) == want


def _known(phrase: str) -> bool:
    return name_key(phrase) in NAME_SYNONYMS


@pytest.mark.parametrize("text, want, note", [
    ("is it true that the sofa is closer to the tv than the bed?", "is the sofa closer to the tv than the bed ?",
     "lead-in"),
    ("can you tell me how many chairs there are?", "how many chairs there are ?", "lead-in"),
    ("honestly I need help: how far is the bed from the tv?", "how far is the bed from the tv ?", "left out"),
    ("the fridge - how long is it?", "how long is the fridge ?", "read as the fridge"),
    ("the tv... how far is that from the bed?", "how far is the tv from the bed ?", "read as the tv"),
    ("you're standing at the stove. which is nearest to you, the bed or the tv?",
     "i am standing at the stove . which is nearest to me , the bed or the tv ?", "asker")])
def test_clauses_that_are_not_the_question_are_set_aside(text, want, note):
    toks, notes = read_clauses(tokens(text), _known)
    assert " ".join(toks) == want and any(note in n for n in notes)


def test_a_clause_with_a_unit_or_a_cue_is_never_left_out():
    toks, notes = read_clauses(tokens("how long is the bed, in feet, please"), _known)
    assert "feet" in toks and notes == ["left out 'please' (no object and nothing asked)"]


def test_cue_scores_pick_a_kind_and_refuse_ties_and_nothing():
    assert cues.kind_of("if you went around counting the tvs what number".split())[0] == "count"
    assert cues.kind_of("the bed and the tv".split()) == (None, "no cue word of any question kind")
    kind, why = cues.kind_of("distance left".split())  # 2 and 2
    assert kind is None and "tie" in why


# ----------------------------------------------------------------------------- properties over whole questions

STANDS = ["standing by the {a}", "I'm at the {a}", "with my back to the {a}"]
FACES = ["facing the {b}", "looking at the {b}", "with the {b} in front of me"]


@pytest.mark.parametrize("a, b, c", [("sofa", "tv", "lamp"), ("bed", "door", "chair")])
def test_the_clauses_of_a_stance_question_say_the_same_in_any_order(a, b, c):
    """Where I stand, what I face and the question, in every order of the three clauses and every pair of
    wordings: one program (the stance, the target, and the side asked)."""
    seen = set()
    for stand, face in itertools.product(STANDS, FACES):
        parts = [stand.format(a=a), face.format(b=b), f"is the {c} to my left or right?"]
        for order in itertools.permutations(parts):
            q = ", ".join(order)
            pq = parse_question(q)
            assert pq.program is not None, (q, pq.notes)
            node = pq.node
            seen.add((node.stand.name, node.face.name, node.target.name))
    assert seen == {(a if a != "tv" else "tv", b, c)}


# ----------------------------------------------------------------------------- each failure class, in new words

@pytest.mark.parametrize("q, qtype, names", [
    ("Is it true that the sofa is closer to the tv than the bed?", "object_rel_distance", ["sofa", "bed", "tv"]),
    ("Can you tell me how many chairs there are?", "object_counting", ["chair"]),
    ("I'd like to know how far the fridge is from the sink", "object_abs_distance", ["refrigerator", "sink"]),
    ("Do you know whether there is a lamp in the room?", "object_existence", ["lamp"]),
    ("hey, quick question - how tall is the wardrobe?", "object_size_estimation", ["wardrobe"]),
    ("whats the distance between the couch and the telly in feet", "object_abs_distance", ["sofa", "tv"]),
    ("the bookcase: how wide is it?", "object_size_estimation", ["bookshelf"]),
    ("so the fridge... how far is that from the oven?", "object_abs_distance", ["refrigerator", "oven"]),
    ("roughly what's the floor space of this flat in sq ft", "room_size_estimation", []),
    ("tally up the cushions for me", "object_counting", ["cushion"]),
    ("which is further from the toilet, the bath or the sink?", "object_rel_distance", ["bathtub", "sink", "toilet"]),
    ("with my back to the tv and the sofa in front of me, is the lamp on my left?", "object_rel_direction_medium",
     ["lamp", "tv", "sofa"]),
    ("I'm trying to figure out if the couch fits through the doorway: how long is it?", "object_size_estimation",
     ["sofa"]),
    ("if you walked around counting the lamps, what would you get?", "object_counting", ["lamp"]),
])
def test_each_failure_class_in_words_the_parser_was_not_written_for(q, qtype, names):
    """Typos, unknown cue words, clauses that are no object, lead-ins, topics and colloquial names, in wordings
    written for this test (not the development set's): the program's type and objects."""
    pq = parse_question(q)
    assert pq.program is not None, pq.notes
    assert pq.qtype == qtype and sorted(pq.objects) == sorted(names), (pq.qtype, pq.objects)


def test_hyphenated_names_are_read_as_the_vocabulary_writes_them():
    from mosaicthinker.runtime.query.normalize import compounds
    assert compounds("the dish-washer by the night-stands, front-left") == "the dishwasher by the nightstands, front-left"
    assert compounds("the tv-to-bed distance") == "the tv-to-bed distance"


OPENERS = ["", "honestly, ", "quick q - ", "can you tell me ", "I'd like to know ", "hey, so "]
CLOSERS = ["?", ", please?", "? thanks", " - just curious", "?? cheers"]
PHRASINGS = {
    "object_abs_distance": ["how far is the {a} from the {b}", "what's the distance between the {a} and the {b}",
                            "the {a} and the {b}: how far apart", "from the {b}, how far is the {a}",
                            "how much space is there between the {a} and the {b}", "the gap from the {a} to the {b}"],
    "object_counting": ["how many {a}s are there", "what's the number of {a}s", "count the {a}s",
                        "the {a}s in this room: how many", "tally up the {a}s"],
    "object_size_estimation": ["how big is the {a}", "what's the longest side of the {a}", "the {a}: how long is it",
                               "what does the {a} measure at its longest", "the size of the {a}"],
}


@pytest.mark.parametrize("qtype", sorted(PHRASINGS))
def test_every_opener_and_closer_with_every_phrasing_reads_the_same(qtype):
    """Openers (lead-ins, fillers) x phrasings x closers, two object pairs: one type and the same objects each
    time (6 x 5-6 x 5 x 2 questions per type)."""
    wrong = []
    for (a, b), pre, ph, post in itertools.product([("sofa", "tv"), ("bed", "wardrobe")], OPENERS, PHRASINGS[qtype],
                                                   CLOSERS):
        q = pre + ph.format(a=a, b=b) + post
        pq = parse_question(q)
        want = {a, b} if "{b}" in ph else {a}
        if pq.qtype != qtype or set(pq.objects) != want:
            wrong.append((q, pq.describe()[:120]))
    assert not wrong, (len(wrong), wrong[:4])


@pytest.mark.parametrize("q, unit", [("how far is the desk from the bed, mm?", "mm"),
                                     ("how far is the sofa from the tv, ft?", "ft"),
                                     ("the lamp and the desk: distance. cm", "cm")])
def test_a_unit_said_alone_is_read(q, unit):
    """"cm", "mm", "ft" anywhere are the unit (no other word means them): never a distance in metres."""
    pq = parse_question(q, names=("desk", "bed", "sofa", "tv", "lamp"))
    assert pq.program is not None and pq.node.KIND == "distance" and pq.node.unit == unit, pq.describe()
