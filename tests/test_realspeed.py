"""Issue 14 (real-room speed): repeated work the adapters and the matcher no longer do, and the per-stage
accounting that shows it. Real shared models and 7-Scenes frames; every cached result is compared with a fresh
adapter's."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from mosaicthinker.runtime.trace import Trace


@pytest.fixture(scope="module")
def det_seg_bundle(tmp_path_factory, shared_models) -> Path:
    from mosaicthinker.export.onnx_import import import_shared_models

    out = tmp_path_factory.mktemp("det_seg")
    import_shared_models(shared_models, out, roles=["detector", "segmenter"])
    return out


@pytest.fixture(scope="module")
def kitchen_rgbs(redkitchen) -> list[np.ndarray]:
    from mosaicthinker.runtime.frames import open_source

    src = open_source(redkitchen)
    return [src[i].rgb for i in (40, 120, 200)]


def _same_detections(a, b) -> bool:
    return a.names == b.names and np.array_equal(a.boxes, b.boxes) and np.array_equal(a.scores, b.scores)


def test_the_detector_runs_once_per_image_whatever_names_are_asked(det_seg_bundle, kitchen_rgbs):
    from mosaicthinker.runtime.stages import load_role

    t = Trace()
    det = load_role(det_seg_bundle, "detector", trace=t)
    rgb = kitchen_rgbs[0]
    few = det.detect(rgb, ["chair", "dining table"])
    every = det.detect(rgb, [x for x in dict.fromkeys(det.labels) if x and x.lower() != "n/a"])
    assert t.stages["detector"].calls == 1 and t.stages["detector.overhead"].calls == 2
    fresh = load_role(det_seg_bundle, "detector", trace=Trace())
    assert _same_detections(few, fresh.detect(rgb, ["chair", "dining table"]))
    assert len(every) >= len(few)
    other = rgb.copy()
    other[0, 0, 0] ^= 1  # one changed pixel is another image: the model runs again
    det.detect(other, ["chair"])
    assert t.stages["detector"].calls == 2
    px, _, _ = det.raw(rgb)
    with pytest.raises(ValueError):  # the shared cached arrays cannot be changed by a caller
        px[0, 0] = -1.0


def test_segmenter_class_maps_are_kept_for_several_frames(det_seg_bundle, kitchen_rgbs):
    from mosaicthinker.runtime.stages import load_role

    t = Trace()
    seg = load_role(det_seg_bundle, "segmenter", trace=t)
    fresh = load_role(det_seg_bundle, "segmenter", trace=Trace())
    for _ in range(2):  # refinement's order: an object in every frame, then the next object
        for rgb in kitchen_rgbs:
            for name in ("chair", "dining table"):
                got = seg.class_mask(rgb, name)
                assert np.array_equal(got, fresh.class_mask(rgb, name))
    assert t.stages["segmenter"].calls == len(kitchen_rgbs)  # the one-image cache ran it 12 times
    assert t.stages["segmenter.overhead"].calls == 2 * len(kitchen_rgbs) * 2


def test_prefetched_features_are_the_features_extracted_in_turn(kitchen_rgbs):
    from mosaicthinker.runtime.matching import FeatureMatcher

    ref = FeatureMatcher("sift")
    pre = FeatureMatcher("sift")
    pre.prefetch(list(enumerate(kitchen_rgbs)))
    for k in reversed(range(len(kitchen_rgbs))):  # any order: queued ones are extracted by the caller
        a, b = ref.features(k, kitchen_rgbs[k]), pre.features(k, kitchen_rgbs[k])
        assert np.array_equal(a.uv, b.uv) and np.array_equal(a.desc, b.desc)
    assert pre.extracts == len(kitchen_rgbs) and not pre._pending and pre._pool is None
    m = pre.match_keys(0, kitchen_rgbs[0], 1, kitchen_rgbs[1])
    assert pre.matches_done == 1 and pre.match_seconds > 0 and len(m) > 0


def test_onnxruntime_sessions_do_not_spin_between_runs():
    from mosaicthinker.runtime.providers import SessionConfig, _session_options

    so = _session_options(SessionConfig())
    assert so.get_session_config_entry("session.intra_op.allow_spinning") == "0"
    assert _session_options(SessionConfig(allow_spinning=True)).get_session_config_entry(
        "session.intra_op.allow_spinning") == "1"


def test_frame_decoding_is_counted_once_per_cache_miss(redkitchen):
    from mosaicthinker.runtime.frames import open_source

    src = open_source(redkitchen, cache_size=2)
    n0, s0 = src.loads, src.load_seconds  # opening reads a few frames (sizes, depth units)
    src._cache.clear()
    src[3], src[3], src[4], src[5], src[3]
    assert src.loads - n0 == 4 and src.load_seconds > s0  # 3, 4, 5, then 3 again (evicted)


def test_trace_add_time_books_without_timing():
    t = Trace()
    t.add_time("frames.load", 0.5, 3)
    t.add_time("frames.load", 0.25)
    assert t.stages["frames.load"].seconds == pytest.approx(0.75) and t.stages["frames.load"].calls == 4
