"""`eval scene` says where the answer score went without changing it: questions that name a category the map
lacks, and the score of the answered ones."""
from __future__ import annotations

import pytest

from mosaicthinker.host.evaluation.scene import why_wrong


def test_why_wrong_counts_missing_names_and_scores_only_the_answered():
    recs = [{"status": "ok", "score": 1.0, "missing": []},
            {"status": "ok", "score": 0.2, "missing": []},
            {"status": "not_found", "score": 0.0, "missing": ["sink", "keyboard"]},
            {"status": "not_found", "score": 0.0, "missing": ["sink"]},
            {"status": "unsupported", "score": 0.0, "missing": []}]
    w = why_wrong(recs)
    assert w["not_in_map"] == 2 and w["missing_names"] == {"sink": 2, "keyboard": 1}
    assert w["answered"] == 2 and w["answered_score"] == pytest.approx(0.6)
    assert why_wrong([]) == {"not_in_map": 0, "missing_names": {}, "answered": 0, "answered_score": None}
