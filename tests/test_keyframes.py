"""Key-frame selection: kernel update, sigma interpolation, z-score threshold, top-K, baselines, end to end."""
from __future__ import annotations

import math

import numpy as np
import pytest

from mosaicthinker.runtime import keyframes as kf
from mosaicthinker.runtime.errors import InputError
from mosaicthinker.runtime.perception import Detections
from mosaicthinker.runtime.trace import Trace


def table_detector(table: dict[int, dict[str, float]]):
    """detect(frame, names) from a hand-written table frame -> {name: confidence}; counts its calls."""
    calls: list[int] = []

    def detect(frame: int, names: list[str]) -> Detections:
        calls.append(frame)
        hits = [(n, s) for n, s in table.get(frame, {}).items() if n in names]
        return Detections(np.zeros((len(hits), 4)), [s for _, s in hits], [n for n, _ in hits])

    detect.calls = calls  # type: ignore[attr-defined]
    return detect


# ----------------------------------------------------------------------------------------------- scoring


def test_frame_score_weights_targets_and_cues():
    det = Detections(np.zeros((4, 4)), [0.6, 0.9, 0.8, 0.4], ["chair", "chair", "tv", "lamp"])
    w = kf.object_weights(["chair"], ["tv", "chair"])
    assert w == {"chair": 1.0, "tv": 0.5}  # a name that is both counts as a target
    assert kf.frame_score(det, w) == pytest.approx(0.9 + 0.5 * 0.8)
    assert kf.frame_score(Detections.empty(), w) == 0.0
    assert kf.task_names(["a", "b"], ["b", "c"]) == ["a", "b", "c"]


def test_zscores_population_std_and_flat_input():
    z = kf.zscores(np.array([0.0, 0.0, 0.0, 1.0]))
    assert z[-1] == pytest.approx(0.75 / (math.sqrt(3) / 4))  # 1.732: passes 1.5, fails 2
    assert z[0] == pytest.approx(-0.25 / (math.sqrt(3) / 4))
    assert np.all(kf.zscores(np.full(5, 0.7)) == 0.0)


# ------------------------------------------------------------------------------------ sampling distribution


def test_sigma_interpolates_between_one_over_k_and_r_over_k():
    conf = kf.KeyFrameConf()  # r = 3, k = 2
    assert (conf.sigma_min, conf.sigma_max) == (0.5, 1.5)
    assert kf.sigma_from_similarity(0.0, conf) == 0.5
    assert kf.sigma_from_similarity(0.5, conf) == 1.0
    assert kf.sigma_from_similarity(1.0, conf) == 1.5
    assert kf.sigma_from_similarity(1.7, conf) == 1.5  # clipped
    conf2 = kf.KeyFrameConf.merged(r=5, k=4)
    assert kf.sigma_from_similarity(0.25, conf2) == pytest.approx(0.25 + 0.25 * 1.0)


def test_gaussian_kernel_update_exact_values():
    w = np.ones(5)
    out = kf.update_distribution(w, center=2, amplitude=1.0, sigma=1.0)
    e = math.exp
    np.testing.assert_allclose(out, [1 + e(-2), 1 + e(-0.5), 2.0, 1 + e(-0.5), 1 + e(-2)])
    assert np.all(w == 1.0)  # pure
    out2 = kf.update_distribution(out, center=0, amplitude=0.5, sigma=0.5)
    np.testing.assert_allclose(out2 - out, [0.5, 0.5 * e(-2), 0.5 * e(-8), 0.5 * e(-18), 0.5 * e(-32)],
                               rtol=1e-9, atol=1e-15)  # 1 + tiny loses digits in the difference
    # probabilities are renormalised over the frames not yet scored
    p = kf.sampling_probabilities(np.array([1.0, 3.0, 2.0, 2.0]), np.array([False, True, False, False]))
    np.testing.assert_allclose(p, [0.2, 0.0, 0.4, 0.4])


def test_batch_sizes_spend_exactly_the_budget():
    sizes = kf.batch_sizes(45, 20)
    assert sum(sizes) == 45 and set(sizes) == {2, 3}
    sizes = kf.batch_sizes(7, 20)
    assert sum(sizes) == 7 and max(sizes) == 1 and len(sizes) == 20
    assert kf.batch_sizes(10, 3, batch=4) == [4, 4, 4]
    assert kf.resolve_budget(100, kf.KeyFrameConf()) == 25
    assert kf.resolve_budget(100, kf.KeyFrameConf(budget=500)) == 100


def test_distribution_after_first_iteration_is_the_kernel_update():
    """One frame scored at iteration 1 -> the iteration-2 distribution is exactly uniform + its kernel."""
    m = 9
    table = {f: {"chair": 0.8} for f in range(100, 100 + m)}
    detect = table_detector(table)
    grey = np.full((8, 8, 3), 120, np.uint8)  # identical frames: similarity 1 -> sigma_max
    conf = kf.KeyFrameConf.merged(iterations=2, batch=1, gain=2.0, record_distributions=True, seed=3)
    res = kf.iterative_search(range(100, 100 + m), ["chair"], [], detect, image=lambda f: grey, conf=conf)
    assert len(res.distributions) == 2
    np.testing.assert_allclose(res.distributions[0], np.full(m, 1 / m))
    first = res.order[0] - 100
    w = np.ones(m) + kf.gaussian_kernel(m, first, 2.0 * 0.8 / 1.0, conf.sigma_max)
    w[first] = 0.0
    np.testing.assert_allclose(res.distributions[1], w / w.sum())
    # no images -> sigma_min, and the result says so
    res2 = kf.iterative_search(range(100, 100 + m), ["chair"], [], table_detector(table), conf=conf)
    first = res2.order[0] - 100
    w = np.ones(m) + kf.gaussian_kernel(m, first, 1.6, conf.sigma_min)
    w[first] = 0.0
    np.testing.assert_allclose(res2.distributions[1], w / w.sum())
    assert any("sigma_min" in n for n in res2.notes)


def test_histogram_similarity_bounds():
    a = np.zeros((16, 16, 3), np.uint8)
    b = np.full((16, 16, 3), 255, np.uint8)
    ha, hb = kf.colour_histogram(a), kf.colour_histogram(b)
    assert ha.shape == (512,) and ha.sum() == pytest.approx(1.0)
    assert kf.histogram_similarity(ha, ha) == pytest.approx(1.0)
    assert kf.histogram_similarity(ha, hb) == pytest.approx(0.0)
    half = np.concatenate([a[:8], b[:8]])
    assert kf.histogram_similarity(ha, kf.colour_histogram(half)) == pytest.approx(0.5)
    with pytest.raises(InputError):
        kf.colour_histogram(np.zeros((4, 4), np.uint8))


# ------------------------------------------------------------------------------------ search and baselines


def _peaks_table(m: int, peaks: dict[int, float]) -> dict[int, dict[str, float]]:
    return {f: ({"tv": s} if f in peaks else {}) for f, s in ((f, peaks.get(f, 0.0)) for f in range(m))}


def test_exhaustive_keeps_top_k_positive_and_records_fewer():
    table = _peaks_table(50, {3: 0.9, 10: 0.5, 11: 0.95, 30: 0.7, 44: 0.6})
    det = table_detector(table)
    res = kf.exhaustive_keyframes(range(50), ["tv"], [], det, kf.KeyFrameConf(keyframes=3))
    assert res.chosen.tolist() == [3, 11, 30] and res.frames_scored == 50 and len(det.calls) == 50
    assert res.fraction_scored == 1.0 and not res.notes
    res = kf.exhaustive_keyframes(range(50), ["tv"], [], table_detector(table), kf.KeyFrameConf(keyframes=8))
    assert res.chosen.tolist() == [3, 10, 11, 30, 44]  # zero-score frames are never taken
    assert any("fewer than K: 5 of 8" in n for n in res.notes)


def test_uniform_baseline_is_evenly_spaced_and_scores_nothing():
    res = kf.uniform_keyframes(np.arange(0, 200, 2), kf.KeyFrameConf(keyframes=4))
    assert res.chosen.tolist() == [24, 74, 124, 174] and res.frames_scored == 0
    res = kf.uniform_keyframes([5, 6, 7], kf.KeyFrameConf(keyframes=8))
    assert res.chosen.tolist() == [5, 6, 7] and res.notes


def test_iterative_threshold_topk_and_fewer_than_k():
    """A synthetic score sequence: two object segments in 200 candidates, the rest empty."""
    m = 200
    rng = np.random.default_rng(0)
    peaks = {f: float(0.7 + 0.3 * rng.random()) for f in list(range(40, 52)) + list(range(140, 150))}
    table = _peaks_table(m, peaks)
    det = table_detector(table)
    conf = kf.KeyFrameConf.merged(keyframes=4, budget=60, seed=1)
    tr = Trace()
    res = kf.iterative_search(range(m), ["tv"], [], det, conf=conf, trace=tr)
    assert res.frames_scored == 60 == len(det.calls) == len(set(res.order))
    assert len(res.chosen) == 4 and set(res.chosen.tolist()) <= set(peaks)
    assert any("kept the top 4" in n for n in res.notes)
    passed = sorted(res.zscores, key=lambda f: (-res.scores[f], f))
    assert sorted(passed[:4]) == res.chosen.tolist()  # top-K by score among the passes
    assert all(z >= 1.5 for z in res.zscores.values())
    assert tr.decisions["keyframes.frames_scored"] == 60

    # the kernels concentrate the sampling on the object segments (gain 0 = plain random sampling)
    grey = np.full((8, 8, 3), 120, np.uint8)

    def hits(gain: float) -> float:
        runs = [kf.iterative_search(range(m), ["tv"], [], table_detector(table), image=lambda f: grey,
                                    conf=kf.KeyFrameConf(keyframes=4, budget=60, seed=s, gain=gain))
                for s in range(5)]
        return float(np.mean([sum(f in peaks for f in r.order) for r in runs]))

    assert hits(10.0) >= 1.8 * hits(0.0)

    # every candidate shows the object with the same score: nothing stands out, fewer than K (zero) returned
    flat = {f: {"tv": 0.8} for f in range(m)}
    tr = Trace()
    res = kf.iterative_search(range(m), ["tv"], [], table_detector(flat), conf=conf, trace=tr)
    assert len(res.chosen) == 0 and any("fewer than K: 0 of 4" in n for n in res.notes)
    assert any(e["kind"] == "degraded" for e in tr.events)


def test_iterative_is_deterministic_and_validates():
    table = _peaks_table(80, {f: 0.9 for f in range(20, 26)})
    conf = kf.KeyFrameConf(keyframes=3, seed=7)
    a = kf.iterative_search(range(80), ["tv"], [], table_detector(table), conf=conf)
    b = kf.iterative_search(range(80), ["tv"], [], table_detector(table), conf=conf)
    assert a.order == b.order and a.chosen.tolist() == b.chosen.tolist()
    with pytest.raises(InputError, match="unknown key"):
        kf.KeyFrameConf.merged({"treshold": 2})
    with pytest.raises(InputError, match="no candidate"):
        kf.iterative_search([], ["tv"], [], table_detector(table))
    with pytest.raises(InputError, match="unknown method"):
        kf.select_keyframes("random", range(5), ["tv"], [], table_detector(table))
    tr = Trace()
    res = kf.iterative_search(range(80), [], [], table_detector(table), conf=conf, trace=tr)
    assert res.method == "uniform" and any(e["kind"] == "fallback" for e in tr.events)


# ------------------------------------------------------------------------------------------- evaluation


def test_score_selection_exact():
    from mosaicthinker.runtime.evaluation.keyframes import score_selection

    vis = [{1: 0.5}, {1: 0.1, 2: 0.3}, {}, {3: 0.9}, {2: 0.25, 3: 0.2}]
    sc = score_selection([0, 1, 2], {1, 2}, vis)  # frame 1 shows 2 (0.3); frame 2 shows nothing
    assert (sc.precision, sc.recall) == (pytest.approx(2 / 3), 1.0)
    assert sc.f1 == pytest.approx(2 * (2 / 3) / (2 / 3 + 1))
    sc = score_selection([3], {1, 2}, vis)
    assert (sc.precision, sc.recall, sc.f1) == (0.0, 0.0, 0.0)
    sc = score_selection([], {1}, vis)
    assert (sc.precision, sc.recall, sc.chosen) == (0.0, 0.0, 0)
    sc = score_selection([1], {1}, vis, min_visible=0.1)
    assert (sc.precision, sc.recall) == (1.0, 1.0)


@pytest.fixture(scope="module")
def small_eval(tmp_path_factory):
    """One small generated scene (96x72, 40 s at 5 fps) through `mosaic eval keyframes`."""
    import json

    from mosaicthinker.runtime.cli import main

    out = tmp_path_factory.mktemp("kf")
    import contextlib
    import io

    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        rc = main(["eval", "keyframes", "--scenes", "1", "--seed", "0", "--duration", "40", "--fps", "5",
                   "--size", "96x72", "--keyframes", "6", "--out", str(out), "--json",
                   "--variant", 'topup={"min_keyframes": 6}'])
    assert rc == 0
    return json.loads(buf.getvalue())


def test_end_to_end_keyframes_on_a_small_scene(small_eval):
    r = small_eval
    assert r["schema"] == "mosaicthinker.eval.keyframes/1"
    scene = r["scenes"][0]
    assert scene["frames"] == 200 and scene["candidates"] < scene["frames"]
    assert scene["candidates_from"].startswith("dedup")
    m = {k: v["all"] for k, v in r["methods"].items()}
    assert m["iterative"]["questions"] >= 10
    # the search scores a quarter of the candidates, the exhaustive baseline all of them
    assert m["iterative"]["scored_candidates"] <= 0.30 and m["exhaustive"]["scored_candidates"] == 1.0
    assert m["uniform"]["scored_candidates"] == 0.0
    # accuracy: the frames it picks show the question's objects, and (topped up to K) they cover them
    assert m["iterative"]["precision"] >= 0.7
    assert m["exhaustive"]["f1"] >= 0.8
    assert m["topup"]["f1"] >= 0.8 and m["topup"]["f1"] > m["uniform"]["f1"] + 0.1


def test_min_keyframes_tops_up_from_scored_frames_spread_out():
    """Nothing stands out (flat scores), so nothing passes; the top-up takes the best scored positive frames,
    first those more than r candidates from one already taken."""
    m = 40
    table = {f: {"tv": 0.5 + 0.01 * (f % 7)} for f in range(m)}
    conf = kf.KeyFrameConf.merged(keyframes=4, min_keyframes=3, budget=m, threshold=5.0, seed=0)
    tr = Trace()
    res = kf.iterative_search(range(m), ["tv"], [], table_detector(table), conf=conf, trace=tr)
    assert not res.zscores  # no pass at z >= 5
    ranked = sorted(res.scores, key=lambda f: (-res.scores[f], f))
    exp: list[int] = []
    for f in ranked:  # greedy: best score, more than r = 3 candidates from the ones already taken
        if len(exp) < 3 and all(abs(f - g) > 3 for g in exp):
            exp.append(f)
    assert res.chosen.tolist() == sorted(exp)
    assert any("fewer than K: 0 of 4" in n for n in res.notes) and any("filled 3" in n for n in res.notes)
    assert sum(e["kind"] == "degraded" for e in tr.events) == 2
    with pytest.raises(InputError, match="min_keyframes"):
        kf.KeyFrameConf.merged(keyframes=4, min_keyframes=5)


def test_prefetch_hook_sorted_batches_same_result():
    """The search hands each iteration's frames (+-r neighbours) to prefetch in time order before it reads them;
    the hook changes the decoding order only, never the selection."""
    cands = list(range(0, 400, 4))
    table = {f: {"chair": 0.9} for f in (40, 44, 48, 200, 204, 360)}
    rng = np.random.default_rng(0)
    imgs = {f: rng.integers(0, 256, (8, 8, 3), dtype=np.uint8) for f in cands}
    conf = kf.KeyFrameConf.merged(keyframes=4, iterations=5, budget=40)
    calls: list[list[int]] = []
    read: list[int] = []

    def image(f: int) -> np.ndarray:
        read.append(f)
        return imgs[f]

    a = kf.iterative_search(cands, ["chair"], [], table_detector(table), image, conf)
    b = kf.iterative_search(cands, ["chair"], [], table_detector(table), image, conf,
                            prefetch=lambda idx: calls.append(list(idx)))
    assert a.chosen.tolist() == b.chosen.tolist() and a.order == b.order
    assert len(calls) == len(kf.batch_sizes(40, 5)) and all(c == sorted(set(c)) for c in calls)
    scored = set(b.order)
    assert scored <= set().union(*map(set, calls))  # every scored frame was announced before it was read

    class Src:  # image callables with a .prefetch (e.g. a bound method's owner) are used by default
        def __init__(self):
            self.calls = 0

        def __call__(self, f: int) -> np.ndarray:
            return imgs[f]

        def prefetch(self, idx) -> None:
            self.calls += 1

    s = Src()
    c = kf.iterative_search(cands, ["chair"], [], table_detector(table), s, conf)
    assert s.calls == len(calls) and c.chosen.tolist() == a.chosen.tolist()


def test_min_keyframes_topup_covers_objects_first():
    """With the image size known, the top-up first adds, for each object no chosen frame shows well, the scored
    frame with its largest box — before better-scoring frames — then goes by score; the conf is the shared
    StageConf."""
    m = 60
    table = {f: {"chair": 0.9} for f in range(0, m, 2)}          # chair everywhere, big boxes
    table.update({f: {"chair": 0.9, "tv": 0.2} for f in (30, 40)})  # tv: low score, box 12% at 40, 1% at 30
    big, tv40, tv30 = (0, 0, 200, 200), (0, 0, 120, 100), (0, 0, 10, 10)

    def detect(frame: int, names: list[str]) -> Detections:
        hits = [(n, s) for n, s in table.get(frame, {}).items() if n in names]
        boxes = [big if n == "chair" else (tv40 if frame == 40 else tv30) for n, _ in hits]
        return Detections(np.array(boxes, np.float32).reshape(-1, 4), [s for _, s in hits], [n for n, _ in hits])

    conf = kf.KeyFrameConf.merged({"keyframes": 2, "budget": m, "threshold": 5.0}, min_keyframes=2, topup_gap=5,
                                  topup_relax=False)
    assert isinstance(conf, kf.StageConf) and conf.to_dict()["topup_gap"] == 5
    res = kf.iterative_search(range(m), ["chair"], ["tv"], detect, conf=conf, image_size=(320, 240))
    # chair's largest view (earliest on ties), then the tv's largest view (40), not the top scores (30 and 40)
    assert res.chosen.tolist() == [0, 40]
    assert any("2 for objects no chosen frame showed well" in n for n in res.notes)
    # without the image size the same top-up goes by score only: 30 and 40 (1.0 > 0.9)
    res2 = kf.iterative_search(range(m), ["chair"], ["tv"], detect, conf=conf)
    assert res2.chosen.tolist() == [30, 40] and any("0 for objects" in n for n in res2.notes)
    with pytest.raises(InputError, match="topup_gap"):
        kf.KeyFrameConf.merged(topup_gap=-1)
