"""Issue 14 (real-room speed): repeated work the adapters and the matcher no longer do, and the per-stage
accounting that shows it. Real shared models and 7-Scenes frames; every cached result is compared with a fresh
adapter's."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from mosaicthinker.runtime.infra.trace import Trace


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
    from mosaicthinker.runtime.models import load_role

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
    from mosaicthinker.runtime.models import load_role

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


def test_class_maps_and_boxes_outlast_a_k32_run(det_seg_bundle, kitchen_rgbs):
    """Perception segments every key frame, then refinement asks class masks in every key frame again: at K = 32
    the segmenter ran 57 times for 32 frames when it kept 16 maps. Likewise the detector keeps every frame the
    search scored (<= 6 K) for perception. 40 distinct frames (one pixel apart), each model once per frame."""
    from mosaicthinker.runtime.models import load_role

    t = Trace()
    seg = load_role(det_seg_bundle, "segmenter", trace=t)
    det = load_role(det_seg_bundle, "detector", trace=t)
    frames = []
    for k in range(40):
        f = kitchen_rgbs[k % len(kitchen_rgbs)].copy()
        f[0, 0, 0] = k
        frames.append(f)
    first = [seg.class_mask(f, "chair") for f in frames]
    boxes = [det.detect(f, ["chair"]) for f in frames]
    for f, m, b in zip(frames, first, boxes):  # refinement's pass, perception's detections
        assert np.array_equal(seg.class_mask(f, "chair"), m)
        assert _same_detections(det.detect(f, ["chair"]), b)
    assert t.stages["segmenter"].calls == 40 and t.stages["detector"].calls == 40
    fresh = load_role(det_seg_bundle, "segmenter", trace=Trace())
    assert np.array_equal(fresh.class_mask(frames[0], "chair"), first[0])  # the kept map is the model's
    assert first[0].shape == frames[0].shape[:2]


def test_prefetched_features_are_the_features_extracted_in_turn(kitchen_rgbs):
    from mosaicthinker.runtime.align.matching import FeatureMatcher

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
    from mosaicthinker.runtime.infra.providers import SessionConfig, _session_options

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


def test_sift_nearest_neighbours_are_the_exact_ones(kitchen_rgbs):
    """The one-matmul distances (integer SIFT descriptors) against a float64 brute force computed here: the
    same two nearest distances per row, the same nearest column, the same mutual flags; non-integer
    descriptors take the general path and agree to float32 precision."""
    from mosaicthinker.runtime.align.matching import _integer_exact, _knn2_l2, extract_features

    f0, f1 = (extract_features(r) for r in kitchen_rgbs[:2])
    a, b = f0.desc[:700].astype(np.float64), f1.desc[:900].astype(np.float64)
    D = ((a[:, None, :] - b[None, :, :]) ** 2).sum(-1)
    order = np.argsort(D, 1, kind="stable")
    want_d = np.sqrt(np.take_along_axis(D, order[:, :2], 1))
    idx, dd, mutual = _knn2_l2(f0.desc[:700], f1.desc[:900])
    assert _integer_exact(f0.desc, f1.desc, (f0.desc ** 2).sum(1), (f1.desc ** 2).sum(1))
    np.testing.assert_array_equal(dd, want_d)  # bit for bit: integer distances
    unique = want_d[:, 0] < want_d[:, 1]  # no tie for the nearest
    np.testing.assert_array_equal(idx[unique, 0], order[unique, 0])
    col_min = D.min(0)
    np.testing.assert_array_equal(mutual, D[np.arange(len(a)), idx[:, 0]] <= col_min[idx[:, 0]])
    g = np.random.default_rng(1)
    x, y = g.normal(size=(300, 64)).astype(np.float32), g.normal(size=(400, 64)).astype(np.float32)
    assert not _integer_exact(x, y, (x * x).sum(1), (y * y).sum(1))
    _, dd2, _ = _knn2_l2(x, y)
    E = np.sort(((x[:, None, :].astype(np.float64) - y[None]) ** 2).sum(-1), 1)[:, :2]
    np.testing.assert_allclose(dd2, np.sqrt(E), rtol=1e-4)


def test_colour_reads_skip_depth_and_give_the_same_images(redkitchen):
    """`FrameSource.colour`: the colour of the whole frame, no depth or pose decoded; a whole frame read later
    has them, and a cached whole frame serves colour reads too. Redundant-frame removal's gray images are
    those of the whole frames, decoded from the JPEG at half size (`frames.source._gray_file`): on average within half a grey level of the
    full decode's (at most a few levels at edges), and exactly it once the frame is cached."""
    from mosaicthinker.runtime.scan import small_gray
    from mosaicthinker.runtime.frames import open_source

    src, ref = open_source(redkitchen), open_source(redkitchen)
    c = src.colour(30)
    assert c.depth is None and c.pose_gt is None and c.index == 30 and c.t == ref[30].t
    np.testing.assert_array_equal(c.rgb, ref[30].rgb)
    g, full = src.gray(31, 320).astype(int), small_gray(ref[31].rgb, 320).astype(int)
    assert g.shape == full.shape and np.abs(g - full).max() <= 8 and np.abs(g - full).mean() < 0.5
    src[31]
    np.testing.assert_array_equal(src.gray(31, 320), small_gray(ref[31].rgb, 320))
    whole = src[30]
    assert whole.depth is not None and whole.pose_gt is not None
    np.testing.assert_array_equal(whole.depth, ref[30].depth)
    assert src.colour(30) is whole  # the whole frame now serves colour reads


def test_stages_record_cpu_seconds_beside_wall_seconds():
    import time

    t = Trace()
    with t.stage("busy"):
        x = 0
        for i in range(300000):
            x += i
    with t.stage("wait"):
        time.sleep(0.05)
    assert t.stages["busy"].cpu_seconds > 0.005 and t.stages["wait"].cpu_seconds < 0.5 * t.stages["wait"].seconds
    d = t.to_dict()
    assert d["stages"]["busy"]["cpu_seconds"] > 0 and d["cpu_seconds"] >= d["stages"]["busy"]["cpu_seconds"]


def test_sources_without_a_cheaper_colour_read_serve_it_from_the_frame_cache(tmp_path):
    """A video or an image folder decodes the whole frame either way: `colour` goes through the frame cache,
    so the key frames the search read are not decoded (or seeked) again."""
    import cv2

    from mosaicthinker.runtime.frames import open_source

    for k in range(3):
        cv2.imwrite(str(tmp_path / f"{k:03d}.png"), np.full((48, 64, 3), 40 * k, np.uint8))
    src = open_source(tmp_path)
    assert not src.splits_colour
    n0 = src.loads
    c = src.colour(1)
    assert src[1] is c and src.loads == n0 + 1
