"""Numbers of any length are read, refused as not understood, or refused as out of range (bad input, exit 2)
by the rules (the trained reader's side is in test_query_reader.py): never a crash, never a program the
program reader (`schema.from_json`) rejects."""
from __future__ import annotations

import pytest

from mosaicthinker.runtime.infra.errors import InputError
from mosaicthinker.runtime.query.parse import parse_question
from mosaicthinker.runtime.query.schema import from_json, to_json

BIG = "9" * 400
QUESTIONS = [f"is the sofa longer than {BIG} m?", f"is the sofa within {BIG} metres of the table?",
             f"is the room bigger than {BIG} square meters?", "are there " + "1" + "0" * 30 + " chairs?",
             f"how many chairs are there? {BIG}", f"is the sofa {BIG} cm long?", f"chair #{BIG} how big?",
             f"how far is chair {BIG} from the table?", "is the room bigger than 1e400 square meters?",
             f"is the tv more than {BIG}.5 feet from the bed?"]


@pytest.mark.parametrize("q", QUESTIONS, ids=range(len(QUESTIONS)))
def test_a_huge_number_is_read_within_the_schema_or_refused(q):
    try:
        pq = parse_question(q, None, reader=None, readers="rules")
    except InputError as e:  # out of range where it is read (infra/numbers): the field and its range said
        assert str(e).startswith("question:") and "out of range" in str(e) and "ask" in str(e)
        return
    if pq.program is not None:
        assert from_json(to_json(pq.program)) == pq.program
    else:
        assert pq.notes  # the refusal says what was not understood


def test_numbers_within_the_bounds_still_read():
    pq = parse_question("is the sofa longer than 2 m?", None, reader=None, readers="rules")
    assert pq.node.threshold_mm == 2000
    pq = parse_question("are there two chairs?", None, reader=None, readers="rules")
    assert pq.node.count.n == 2
