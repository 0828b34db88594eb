"""The reliability campaign (tests/campaign.py) in the suite: every class it holds ends with 0 crashes, 0 hangs
and 0 silently wrong answers. The field-damage classes run a stratified subset here (every field path with
campaign.PER_PATH kinds of damage); `python benchmarks/reliability_campaign.py` runs every pair."""
from __future__ import annotations

import pytest

import campaign

FIELD = tuple(campaign.FIELD_CLASSES)


@pytest.mark.slow
@pytest.mark.parametrize("name", FIELD + tuple(campaign.EXTRA_CLASSES))
def test_campaign_class_has_no_crash_hang_or_silent_answer(name, tmp_path):
    recs = campaign.run_all((name,), work=tmp_path, full=False)
    s = campaign.summary(recs)
    assert recs and not s["failures"], s["failures"][:10]
