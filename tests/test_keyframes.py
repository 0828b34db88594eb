"""Key-frame selection: kernel update, sigma interpolation, z-score threshold, top-K, baselines, end to end."""
from __future__ import annotations

import math

import numpy as np
import pytest

from mosaicthinker.runtime import keyframes as kf
from mosaicthinker.runtime.infra.config import StageConf
from mosaicthinker.runtime.keyframes import search as kfs
from mosaicthinker.runtime.scan import colour_histogram
from mosaicthinker.runtime.infra.errors import InputError
from mosaicthinker.runtime.types import Detections
from mosaicthinker.runtime.infra.trace import Trace


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
    assert (kf.KeyFrameConf().sigma_min, kf.KeyFrameConf().sigma_max) == (2.0, 6.0)  # default r = 3, k = 0.5
    conf = kf.KeyFrameConf.merged(k=2.0)  # the paper's r = 3, k = 2
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
    assert kf.batch_sizes(10, 3, batch=4) == [4, 4, 2]  # a fixed batch never spends past the budget
    assert kf.batch_sizes(12, 2, batch=4) == [4, 4]
    assert kf.resolve_budget(100, kf.KeyFrameConf()) == 25
    assert kf.resolve_budget(100, kf.KeyFrameConf(budget=500)) == 100


def test_distribution_after_first_iteration_is_the_kernel_update():
    """The paper's sampling: one frame scored at iteration 1 -> the iteration-2 distribution is exactly uniform +
    its kernel."""
    m = 9
    table = {f: {"chair": 0.8} for f in range(100, 100 + m)}
    detect = table_detector(table)
    grey = np.full((8, 8, 3), 120, np.uint8)  # identical frames: similarity 1 -> sigma_max
    conf = kf.KeyFrameConf.merged(iterations=2, batch=1, gain=2.0, record_distributions=True, seed=3,
                                  sampling="paper", draw="iid")
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
    ha, hb = colour_histogram(a), colour_histogram(b)
    assert ha.shape == (512,) and ha.sum() == pytest.approx(1.0)
    assert kf.histogram_similarity(ha, ha) == pytest.approx(1.0)
    assert kf.histogram_similarity(ha, hb) == pytest.approx(0.0)
    half = np.concatenate([a[:8], b[:8]])
    assert kf.histogram_similarity(ha, colour_histogram(half)) == pytest.approx(0.5)
    with pytest.raises(InputError):
        colour_histogram(np.zeros((4, 4), np.uint8))


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
    res = kf.iterative_search(range(m), ["tv"], [], det, conf=conf, log=tr)
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
    res = kf.iterative_search(range(m), ["tv"], [], table_detector(flat), conf=conf, log=tr)
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
        kf.select_keyframes("bogus", range(5), ["tv"], [], table_detector(table))
    tr = Trace()
    res = kf.iterative_search(range(80), [], [], table_detector(table), conf=conf, log=tr)
    assert res.method == "uniform" and any(e["kind"] == "fallback" for e in tr.events)


# ------------------------------------------------------------------------------------------- evaluation


def test_score_selection_exact():
    from mosaicthinker.host.evaluation.keyframes import score_selection

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
    r = json.loads(buf.getvalue())
    r["_out"] = out
    return r


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


def test_eval_keyframes_out_is_written_as_one_group(small_eval):
    """`--out`: the result through runtime/infra/outputs.py (temp file + rename, run.json complete, same run id) and
    the scene renamed into place only once complete (no partial folder left)."""
    import json

    out = small_eval["_out"]
    saved = json.loads((out / "keyframes.json").read_text())
    run = json.loads((out / "run.json").read_text())
    assert run["status"] == "complete" and run["files"] == ["keyframes.json"]
    assert saved["run_id"] == run["run_id"] == small_eval["run_id"]
    assert saved["methods"] == small_eval["methods"]
    assert not [p.name for p in out.iterdir() if p.name.startswith((".partial-", ".mosaic-tmp."))]
    assert (out / small_eval["scenes"][0]["scene"] / "scene.json").exists()


def test_min_keyframes_tops_up_from_scored_frames_spread_out():
    """Nothing stands out (flat scores), so nothing passes; the top-up takes the best scored positive frames,
    first those more than r candidates from one already taken."""
    m = 40
    table = {f: {"tv": 0.5 + 0.01 * (f % 7)} for f in range(m)}
    conf = kf.KeyFrameConf.merged(keyframes=4, min_keyframes=3, budget=m, threshold=5.0, seed=0)
    tr = Trace()
    res = kf.iterative_search(range(m), ["tv"], [], table_detector(table), conf=conf, log=tr)
    assert not res.zscores  # no pass at z >= 5
    ranked = sorted(res.scores, key=lambda f: (-res.scores[f], f))
    exp: list[int] = []
    for f in ranked:  # greedy: best score, more than r = 3 candidates from the ones already taken
        if len(exp) < 3 and all(abs(f - g) > 3 for g in exp):
            exp.append(f)
    assert res.chosen.tolist() == sorted(exp)
    assert any("fewer than K: 0 of 4" in n for n in res.notes) and any("filled 3" in n for n in res.notes)
    deg = [e["message"] for e in tr.events if e["kind"] == "degraded"]
    assert len(deg) == 3 and "content prior is off" in deg[0]  # no images: said, then fewer than K, filled
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
    assert isinstance(conf, StageConf) and conf.to_dict()["topup_gap"] == 5
    res = kf.iterative_search(range(m), ["chair"], ["tv"], detect, conf=conf, image_size=(320, 240))
    # chair's largest view (earliest on ties), then the tv's largest view (40), not the top scores (30 and 40)
    assert res.chosen.tolist() == [0, 40]
    assert any("2 for objects no chosen frame showed well" in n for n in res.notes)
    # without the image size the same top-up goes by score only: 30 and 40 (1.0 > 0.9)
    res2 = kf.iterative_search(range(m), ["chair"], ["tv"], detect, conf=conf)
    assert res2.chosen.tolist() == [30, 40] and any("0 for objects" in n for n in res2.notes)
    with pytest.raises(InputError, match="topup_gap"):
        kf.KeyFrameConf.merged(topup_gap=-1)


# ------------------------------------------------------------------ expected-score sampling (issue 17)


def test_gap_novelty_and_expected_scores_exact():
    nov = kf.gap_novelty(5, np.array([0]), power=1.0)
    d = np.arange(5.0)
    np.testing.assert_allclose(nov, d / d.mean())
    np.testing.assert_allclose(kf.gap_novelty(4, np.array([], np.int64)), np.ones(4))
    # one positive (0.8 at 2) and one zero (at 6), sigma 1, no novelty: Nadaraya-Watson with the mean 0.4 as prior
    m = 8
    e = kf.expected_scores(m, np.array([2, 6]), np.array([0.8, 0.0]), np.array([1.0, 1.0]), novelty=0.0)
    g2, g6 = kf.gaussian_kernel(m, 2, 1.0, 1.0), kf.gaussian_kernel(m, 6, 1.0, 1.0)
    np.testing.assert_allclose(e, (0.4 + 0.8 * g2) / (1 + g2 + g6))
    assert e[2] > e[0] > e[6]  # near the positive > far > near the zero
    # gain 0: kernels off, the prior (mean) everywhere
    np.testing.assert_allclose(kf.expected_scores(m, np.array([2]), np.array([0.8]), np.array([1.0]), gain=0.0),
                               np.full(m, 0.8))


def test_sequential_draw_spreads_a_batch_over_the_gaps():
    """Before anything is scored, a sequential batch of 4 from 100 candidates spreads out (each pick counts as
    explored for the next): its closest pair is on average much farther apart than the paper's iid draw's."""
    def min_gap(draw: str, seed: int) -> int:
        st = kfs._Search(100, kf.KeyFrameConf.merged(draw=draw, novelty=4.0), 1.0)
        picks, _ = st.draw(4, np.random.default_rng(seed))
        assert len(set(picks.tolist())) == 4
        return int(np.diff(np.sort(picks)).min())

    seq = np.mean([min_gap("sequential", s) for s in range(30)])
    iid = np.mean([min_gap("iid", s) for s in range(30)])
    assert seq >= 12 and seq >= 1.5 * iid


def test_needle_search_beats_random_scoring():
    """Short object stretches (6 candidates each) in 600: at 10% scored, the expected-score search (coarse to
    fine) finds more stretches than the paper's iid sampling with the kernels off (random scoring), averaged
    over seeds."""
    m, starts = 600, (37, 151, 260, 333, 452, 540)
    peaks = {f: 0.5 + 0.08 * (3 - abs(f - s - 2.5)) for s in starts for f in range(s, s + 6)}
    table = _peaks_table(m, peaks)

    def found(over: dict) -> float:
        hits = []
        for seed in range(8):
            res = kf.iterative_search(range(m), ["tv"], [], table_detector(table),
                                      conf=kf.KeyFrameConf.merged({"keyframes": 6, "budget_fraction": 0.1,
                                                                   "seed": seed, **over}))
            hits.append(sum(any(s <= f < s + 6 for f in res.order) for s in starts))
        return float(np.mean(hits))

    paper_k, rand = found({"k": 2.0}), found({"sampling": "paper", "draw": "iid", "gain": 0.0})
    assert paper_k >= rand + 1.0 and paper_k >= 3.5  # a perfect 1-in-10 grid expects 3.6 of 6
    # the default's wider kernels (k = 0.5, chosen on the long videos' content axis) still beat random scoring
    # here on the plain index axis, by less (measured 2.9 vs 2.4): a zero-score frame's sigma_max = 6 explains
    # away more of its neighbourhood than these 6-candidate stretches allow
    assert found({}) > rand + 0.25


def test_raw_threshold_mode_and_validation():
    table = _peaks_table(40, {5: 0.9, 6: 0.6, 20: 1.0})
    conf = kf.KeyFrameConf.merged(keyframes=4, budget=40, threshold=0.8, threshold_mode="raw")
    res = kf.iterative_search(range(40), ["tv"], [], table_detector(table), conf=conf)
    assert sorted(res.zscores) == [5, 20] and res.chosen.tolist() == [5, 20]
    assert res.zscores[20] == pytest.approx(1.0)  # the raw score is what passed
    for bad in ({"threshold_mode": "zz"}, {"sampling": "x"}, {"draw": "x"}, {"prior_weight": 0}):
        with pytest.raises(InputError):
            kf.KeyFrameConf.merged(bad)


def test_budget_beyond_the_candidates_is_said():
    """The planner's scored-frame count exceeds the candidates (as on the kitchen: 125 for 50): all are scored,
    a note and a "budget" trace event say so."""
    table = _peaks_table(50, {10: 0.9})
    tr = Trace()
    res = kf.iterative_search(range(50), ["tv"], [], table_detector(table),
                              conf=kf.KeyFrameConf(keyframes=4, budget=125), log=tr)
    assert res.frames_scored == 50
    assert any("candidates ran out before the budget: 125" in n for n in res.notes)
    ev = [e for e in tr.events if e["kind"] == "budget"]
    assert len(ev) == 1 and ev[0]["budget"] == 125 and ev[0]["candidates"] == 50
    res = kf.iterative_search(range(50), ["tv"], [], table_detector(table), conf=kf.KeyFrameConf(budget=20))
    assert not any("ran out" in n for n in res.notes)


def test_random_baseline_scores_nothing_and_is_seeded():
    a = kf.select_keyframes("random", range(100), ["tv"], [], table_detector({}),
                            conf=kf.KeyFrameConf(keyframes=8, seed=3))
    b = kf.random_keyframes(range(100), kf.KeyFrameConf(keyframes=8, seed=3))
    assert a.chosen.tolist() == b.chosen.tolist() and len(a.chosen) == 8 and a.frames_scored == 0
    assert a.chosen.tolist() == sorted(set(a.chosen.tolist()))


# ------------------------------------------------------------------------------ long videos (issue 17)


@pytest.fixture(scope="module")
def tiny_long_video():
    from mosaicthinker.host.synth.longvideo import LongVideoConf, make_long_video

    return make_long_video(LongVideoConf(seed=3, rooms=2, room_seconds=6, corridor_seconds=4, fps=2, width=64,
                                         height=48))


def test_long_video_segments_and_ground_truth(tiny_long_video):
    v = tiny_long_video
    assert len(v) == 12 + 8 + 12 and [s["kind"] for s in v.rooms] == ["room", "corridor", "room"]
    assert v.rgb.shape == (32, 48, 64, 3) and v.room.tolist() == [0] * 12 + [1] * 8 + [2] * 12
    assert all(not row for row in v.visible[12:20])  # an empty corridor shows no object
    for f, row in enumerate(v.visible):  # objects are seen only in their own room; boxes inside the image
        for i, r in row.items():
            assert v.room_of[i] == v.room[f] and 0 <= r["visibility"] <= 1
            x0, y0, x1, y1 = v.boxes[f][i]
            assert 0 <= x0 < x1 <= 64 and 0 <= y0 < y1 <= 48


def test_long_questions_keep_rare_objects_only(tiny_long_video):
    from mosaicthinker.host.synth.longvideo import long_questions

    v = tiny_long_video
    qs, skipped = long_questions(v, max_share=0.3)
    px = v.seen_min_pixels
    for q in qs:
        share = np.mean([any(row.get(i, {}).get("pixels", 0) >= px for i in q["instances"]) for row in v.visible])
        assert share == pytest.approx(q["share"], abs=1e-4) and share < 0.3
        assert {v.names[i] for i in q["instances"]} == set(q["targets"])
    everything, _ = long_questions(v, max_share=1.01)
    singles = {q["targets"][0]: q["share"] for q in everything if q["qtype"] == "single"}
    kept = {q["targets"][0] for q in qs if q["qtype"] == "single"}
    assert kept == {n for n, sh in singles.items() if sh < 0.3} and skipped["too visible"] >= len(singles) - len(kept)


def test_long_video_oracle_misses_and_false_positives(tiny_long_video):
    from mosaicthinker.host.synth.longvideo import LongVideoOracle

    v = tiny_long_video
    names = sorted(set(v.names.values()))
    perfect = LongVideoOracle(v, miss_rate=0.0, score_noise=0.0, false_positive_rate=0.0)
    for f in (0, 5, 25):
        d = perfect.detect(f, names)
        want = {i for i, r in v.visible[f].items() if r["pixels"] >= v.seen_min_pixels}
        assert set(d.instance_ids.tolist()) == want
    blind = LongVideoOracle(v, miss_rate=1.0, false_positive_rate=1.0, seed=1)
    d = blind.detect(3, ["chair"])
    assert d.names == ["chair"] and d.instance_ids.tolist() == [-1] and 0.05 <= d.scores[0] <= 0.9
    noisy = LongVideoOracle(v, seed=2)
    a, b = noisy.detect(7, names), noisy.detect(7, names[::-1])  # same draws whatever the order asked
    assert sorted(zip(a.names, a.scores.tolist())) == sorted(zip(b.names, b.scores.tolist()))
    with pytest.raises(InputError):
        LongVideoOracle(v, false_positive_rate=2.0)


def test_evaluate_long_video_records(tiny_long_video):
    from mosaicthinker.host.evaluation.keyframes import evaluate_long_video, summarise
    from mosaicthinker.host.synth.longvideo import LongVideoOracle, long_questions

    v = tiny_long_video
    qs, _ = long_questions(v, max_share=0.5)
    assert qs
    conf = kf.KeyFrameConf(keyframes=3, budget_fraction=0.25, min_keyframes=3)
    methods = {m: (m, conf) for m in kf.METHODS}
    recs = evaluate_long_video(v, qs, LongVideoOracle(v, miss_rate=0.0, false_positive_rate=0.0).detect, methods)
    assert len(recs) == len(qs) * len(methods)
    s = summarise(recs, list(methods))
    assert s["exhaustive"]["all"]["found"] == 1.0 and s["exhaustive"]["all"]["scored_candidates"] == 1.0
    assert s["iterative"]["all"]["scored_candidates"] == pytest.approx(0.25, abs=0.02)
    assert s["uniform"]["all"]["scored_candidates"] == 0.0
    # a repeat runs the same questions with other search seeds (the design spread), repeat 0 is the plain run
    from mosaicthinker.host.evaluation.keyframes import search_seed

    assert search_seed(3, 7) == 3007 and search_seed(3, 7, 2) == 2_003_007
    rep = evaluate_long_video(v, qs, LongVideoOracle(v, miss_rate=0.0, false_positive_rate=0.0).detect,
                              {"random": ("random", conf)}, repeat=1)
    assert {r["repeat"] for r in rep} == {1} and {r["repeat"] for r in recs} == {0}


# ------------------------------------------------------------------------------ content prior (issue 17)


def test_edge_density_and_content_axis_exact():
    flat = np.full((48, 64, 3), 128, np.uint8)
    assert kf.edge_density(flat) == 0.0
    bars = flat.copy()
    bars[:, ::8] = 255  # vertical lines: edges on both sides of each
    assert 0.1 < kf.edge_density(bars) <= 1.0
    np.testing.assert_allclose(kf.content_axis(np.full(5, 0.3)), np.arange(5.0))  # flat: the index
    # steps d/mean + floor = [2.1, 0.1, 0.1, 2.1]; neighbour distances [1.1, 0.1, 1.1] rescaled to span 3
    np.testing.assert_allclose(kf.content_axis(np.array([0.2, 0.0, 0.0, 0.2]), floor=0.1),
                               np.array([0.0, 1.1, 1.2, 2.3]) * 3 / 2.3)
    assert kf.content_axis(np.zeros(4)).tolist() == [0.0, 1.0, 2.0, 3.0]  # nothing anywhere: the index
    # distances along the axis: two empty candidates between two views sit next to each other
    x = kf.content_axis(np.array([0.2, 0.0, 0.0, 0.2]), floor=0.1)
    np.testing.assert_allclose(kf.gap_novelty(4, np.array([0]), power=1.0, axis=x), x / x.mean())
    with pytest.raises(InputError, match="content_floor"):
        kf.KeyFrameConf.merged(content_floor=0)


def test_view_change_and_the_change_weighted_axis_exact():
    """view_change: mean |difference| of mean-free grey copies to each neighbour, averaged (ends: one); an
    exposure change alone is no change. content_axis with it: steps density x change / their mean + floor."""
    a = np.zeros((24, 32), np.float32)
    b = a.copy()
    b[:, :16] = 2.0  # minus its mean (1): +-1 everywhere, |a - b| = 1
    np.testing.assert_allclose(kf.view_change([kf.grey_thumbnail(g, 32) for g in (a, a, b, b)]),
                               [0.0, 0.5, 0.5, 0.0])
    bright = np.full((48, 64, 3), 200, np.uint8)
    dark = np.full((48, 64, 3), 50, np.uint8)
    assert kf.view_change([kf.grey_thumbnail(x) for x in (dark, bright, dark)]).tolist() == [0.0, 0.0, 0.0]
    assert kf.grey_thumbnail(bright).shape == (24, 32) and abs(float(kf.grey_thumbnail(bright).mean())) < 1e-6
    # equal densities, change [1, 1, 0, 0] -> steps [2, 2, 0, 0] + 0.1; distances [2.1, 1.1, 0.1] -> span 3
    np.testing.assert_allclose(kf.content_axis(np.full(4, 0.3), 0.1, np.array([1.0, 1.0, 0.0, 0.0])),
                               np.array([0.0, 2.1, 3.2, 3.3]) * 3 / 3.3)
    flat = kf.content_axis(np.array([0.2, 0.0, 0.0, 0.2]), 0.1)  # no change anywhere / power 0: density alone
    np.testing.assert_allclose(kf.content_axis(np.array([0.2, 0.0, 0.0, 0.2]), 0.1, np.zeros(4)), flat)
    np.testing.assert_allclose(kf.content_axis(np.array([0.2, 0.0, 0.0, 0.2]), 0.1, np.arange(4.0), 0.0), flat)
    # given edge densities and grey images (the pipeline: dedup's 64-px uint8 thumbnails) no frame is read; the
    # store keeps them as compared, so a second search gets the same axis
    def no_read(f):
        raise AssertionError(f"frame {f} read")

    rng = np.random.default_rng(3)
    dedup = {f: rng.integers(0, 256, (48, 64), dtype=np.uint8) for f in range(6)}
    store = dict(dedup)
    conf = kf.KeyFrameConf.merged(change_power=1.0)  # measured, off by default
    x1 = kfs._content_axis(np.arange(6), no_read, conf, [], None, {f: 0.1 for f in range(6)}, store)
    assert all(g.dtype == np.float32 and g.shape == (24, 32) for g in store.values())
    x2 = kfs._content_axis(np.arange(6), no_read, conf, [], None, {f: 0.1 for f in range(6)}, store)
    want = kf.content_axis(np.full(6, 0.1), conf.content_floor,
                           kf.view_change([kf.grey_thumbnail(dedup[f]) for f in range(6)]))
    np.testing.assert_allclose(x1, want)
    np.testing.assert_allclose(x2, want)
    # the densities themselves come from the thumbnails when none are given (the pipeline passes none): no read
    dens: dict[int, float] = {}
    x3 = kfs._content_axis(np.arange(6), no_read, kf.KeyFrameConf(), [], None, dens, dict(dedup))
    assert dens == {f: kf.edge_density(dedup[f], 64) for f in range(6)} and x3 is not None
    reads = []
    kfs._content_axis(np.arange(2), lambda f: reads.append(f) or dedup[f], kf.KeyFrameConf(), [], None, {},
                     {0: dedup[0][:, :32]})  # too narrow a copy, and none for frame 1: both read
    assert reads == [0, 1]
    for bad in ({"change_power": -1}, {"change_size": 1}):
        with pytest.raises(InputError, match="change_"):
            kf.KeyFrameConf.merged(bad)


def _pan_and_linger(m: int = 600):
    """Every view equally busy (the same random texture, shifted): the first half pans (each candidate a new
    shift), the second lingers (one shift for 30 candidates at a time). Two-candidate object stretches every 25
    candidates of the panning half only. Returns (images, table, stretch starts)."""
    tex = np.random.default_rng(5).integers(0, 256, (48, 200, 3), dtype=np.uint8)
    imgs = {f: np.ascontiguousarray(tex[:, (f % 130) if f < m // 2 else 3 * (f // 30):][:, :64]) for f in range(m)}
    starts = list(range(7, m // 2, 25))
    return imgs, _peaks_table(m, {f: 0.9 for s in starts for f in (s, s + 1)}), starts


def test_view_change_spends_the_detector_where_the_views_change():
    """Edge density is the same everywhere, so only the view change tells the panning half (every candidate
    new, objects in view for 2 candidates) from the lingering half (one view for 30 candidates): with it the
    search scores more of the panning half and finds more of its short stretches at 10% scored, averaged over
    seeds; the thumbnails are made once and reused by the next search; the budget is spent exactly."""
    imgs, table, starts = _pan_and_linger()

    def run(power: float) -> tuple[float, float]:
        hits, share, thumbs = [], [], {}
        for seed in range(6):
            conf = kf.KeyFrameConf.merged(keyframes=6, budget=60, seed=seed, change_power=power)
            res = kf.iterative_search(range(600), ["tv"], [], table_detector(table), imgs.__getitem__, conf,
                                      thumbs=thumbs)
            assert res.frames_scored == 60 == len(set(res.order))
            hits.append(sum(any(f in (s, s + 1) for f in res.order) for s in starts))
            share.append(np.mean(np.array(res.order) < 300))
        assert len(thumbs) == (600 if power > 0 else 0)
        return float(np.mean(hits)), float(np.mean(share))

    (on, on_share), (off, off_share) = run(1.0), run(0.0)
    assert on_share >= off_share + 0.2 and on >= off + 1.5  # 12 stretches; a 1-in-10 grid in time expects 2.4


def _walk(m: int = 600, seg: int = 50):
    """Rooms (textured images) and empty corridors (flat grey), `seg` candidates each; a 4-candidate object
    stretch in every room at a seeded place. Returns (images, table, stretches)."""
    rng = np.random.default_rng(11)
    tex = [rng.integers(0, 256, (48, 64, 3), dtype=np.uint8) for _ in range(8)]
    imgs, starts = {}, []
    for f in range(m):
        room = (f // seg) % 2 == 0
        imgs[f] = tex[f % 8] if room else np.full((48, 64, 3), 100, np.uint8)
    for r0 in range(0, m, 2 * seg):
        starts.append(r0 + int(rng.integers(0, seg - 4)))
    table = _peaks_table(m, {f: 0.9 for s in starts for f in range(s, s + 4)})
    return imgs, table, starts


def test_content_prior_spends_the_detector_where_the_views_show_something():
    """Half of the candidates are empty views: measured along the content axis the search explores the rooms
    and finds more object stretches at 10% scored than the same search evenly in time, averaged over seeds;
    it spends exactly the budget either way."""
    imgs, table, starts = _walk()

    def found(prior: bool) -> float:
        hits = []
        for seed in range(6):
            conf = kf.KeyFrameConf.merged(keyframes=6, budget=60, seed=seed, content_prior=prior)
            res = kf.iterative_search(range(600), ["tv"], [], table_detector(table), imgs.__getitem__, conf)
            assert res.frames_scored == 60 == len(set(res.order))
            hits.append(sum(any(s <= f < s + 4 for f in res.order) for s in starts))
        return float(np.mean(hits))

    on, off = found(True), found(False)
    assert on >= off + 1.0 and on >= 4.5  # 6 stretches; evenly in time a 1-in-10 grid expects 2.4


def test_first_grid_is_even_along_the_axis_and_the_budget_is_spent_exactly():
    """grid_share: the first iteration scores that share of the budget as an even grid (one per cell of the
    axis); grid points that fall on one candidate are owed to the next batch, so the total is the budget."""
    imgs, table, _ = _walk()
    conf = kf.KeyFrameConf.merged(keyframes=6, budget=60, grid_share=0.5, iterations=10, seed=2)
    res = kf.iterative_search(range(600), ["tv"], [], table_detector(table), imgs.__getitem__, conf)
    assert res.frames_scored == 60 == len(set(res.order))
    first = sorted(res.order[:30])
    # the rooms (textured) hold nearly all of the axis: the grid lands in them, not in the empty corridors
    assert sum((f // 50) % 2 == 0 for f in first) >= 28
    st = kfs._Search(100, kf.KeyFrameConf(), 1.0)  # no axis: an even grid over the index
    picks, _ = st.grid(10, np.random.default_rng(0))
    assert len(picks) == 10 and set(np.diff(np.sort(picks)).tolist()) <= {9, 10, 11}
    with pytest.raises(InputError, match="grid_share"):
        kf.KeyFrameConf.merged(grid_share=1.5)


def test_stretches_split_at_zero_scored_frames():
    """Positive frames belong to one stretch until a scored zero-score frame separates them (unscored gaps do
    not); zero-score frames get no stretch."""
    pos = [40, 3, 5, 9, 12, 30, 31, 50]
    sc = [0.7, 0.4, 0.9, 0.0, 0.5, 0.6, 0.0, 0.2]
    # in candidate order: 3+ 5+ | 9 zero | 12+ 30+ | 31 zero | 40+ 50+
    assert kf.stretches(pos, sc) == {3: 0, 5: 0, 12: 1, 30: 1, 40: 2, 50: 2}
    assert kf.stretches([], []) == {}


def test_top_k_stretches_takes_the_best_of_each_stretch_first():
    """Six high frames of one stretch and a weaker one elsewhere: top-3 by score alone takes three of the first
    stretch; by stretch it takes the other stretch's best too."""
    scores = {10: 0.95, 11: 0.9, 12: 0.92, 13: 0.93, 14: 0.91, 15: 0.9, 80: 0.5, 81: 0.45}
    stretch = {f: 0 for f in range(10, 16)} | {80: 1, 81: 1}
    assert kf.top_k(list(scores), scores, 3).tolist() == [10, 12, 13]
    assert kf.top_k_stretches(list(scores), scores, 3, stretch).tolist() == [10, 13, 80]
    assert kf.top_k_stretches(list(scores), scores, 1, stretch).tolist() == [10]


def test_stretch_selection_keeps_a_second_object_the_score_ranking_drops():
    """Exhaustive budget, K = 4: object A is seen well in eight frames, object B weaker in three, far away.
    The default selection (one frame per stretch first) shows B; ranking by score alone (`stretch_first`
    off) fills K from A."""
    m = 120
    table = {f: {"chair": 0.9 + 0.001 * f} for f in range(20, 28)} | {f: {"chair": 0.5} for f in (90, 91, 92)}
    for over, shows_b in (({}, True), ({"stretch_first": False}, False)):
        res = kf.iterative_search(range(m), ["chair"], [], table_detector(table),
                                  conf=kf.KeyFrameConf.merged({"keyframes": 4, "budget": m, "min_keyframes": 4,
                                                               **over}))
        assert len(res.chosen) == 4
        assert any(f >= 90 for f in res.chosen) == shows_b
    # the stretch rule orders the top-up, it does not shrink it: without the relaxed pass (the pipeline's
    # setting) the spaced frames of a stretch already used still fill up to K
    res = kf.iterative_search(range(m), ["chair"], [], table_detector(table),
                              conf=kf.KeyFrameConf.merged({"keyframes": 6, "budget": m, "min_keyframes": 6,
                                                           "threshold": 5.0, "topup_relax": False,
                                                           "topup_gap": 2}))
    assert len(res.chosen) == 6 and any(f >= 90 for f in res.chosen)


def test_greedy_draw_without_hits_is_an_even_coarse_to_fine_grid():
    """No detection anywhere: the greedy draws are farthest-point picks along the axis, so after any number of
    picks the widest unscored gap is at most twice an even grid's (random first pick: a random offset)."""
    m = 400
    for seed in (0, 1, 2):
        st = kfs._Search(m, kf.KeyFrameConf.merged(seed=seed), 1.0)
        rng = np.random.default_rng(seed)
        for n in (8, 8, 16, 8):
            picks, _ = st.draw(n, rng)
            for p in picks:
                st.add(int(p), 0.0, st.conf.sigma_max)
            edges = np.concatenate([[-1], np.sort(st.pos), [m]])
            assert np.diff(edges).max() <= 2 * math.ceil(m / len(st.pos)) + 1
    assert len({int(kfs._Search(m, kf.KeyFrameConf.merged(seed=s), 1.0).draw(1, np.random.default_rng(s))[0][0])
                for s in range(6)}) > 1


def test_climb_steps_lead_to_the_best_frames_neighbours_until_it_is_a_local_maximum():
    """Two stretches: the first's best frame (12) has an unscored neighbour on each side, the second's (41) has
    both neighbours scored (settled); a best frame whose box is whole (not in `cut`) does not climb."""
    scored = np.zeros(60, bool)
    pos, sc = [10, 12, 20, 40, 41, 42], [0.3, 0.6, 0.0, 0.5, 0.8, 0.4]
    scored[pos] = True
    assert kf.climb_steps(pos, sc, scored) == {0: [11, 13], 1: []}
    assert kf.climb_steps(pos, sc, scored, cut={41}) == {0: [], 1: []}
    assert kf.climb_steps(pos, sc, scored, cut={12}) == {0: [11, 13], 1: []}
    # at the ends of the candidates only the inner neighbour exists
    edge = np.zeros(5, bool)
    edge[[0, 2, 4]] = True
    assert kf.climb_steps([0, 2, 4], [0.5, 0.0, 0.7], edge) == {0: [1], 1: [3]}


def test_cut_by_border_looks_at_the_best_box_of_each_task_object():
    det = Detections(np.array([[0, 10, 30, 40], [50, 20, 90, 60], [100, 100, 159, 110]]), [0.4, 0.9, 0.8],
                     ["chair", "chair", "tv"])
    assert not kf.cut_by_border(det, ["chair"], (160, 120))     # the best chair box is inside the image
    assert kf.cut_by_border(det, ["tv"], (160, 120))            # the tv box reaches the right border
    assert kf.cut_by_border(det, ["chair", "tv"], (160, 120))
    assert not kf.cut_by_border(det, ["lamp"], (160, 120))
    assert not kf.cut_by_border(det, ["tv"], None)              # no image size: no evidence, no climbing


def _sliver_detector(m: int, peak: int, half: int, W: int = 160, H: int = 120):
    """One object seen in candidates peak-half .. peak+half: a box cut by the left border and a low score away
    from the peak, whole and confident at the peak (as a camera turning past it)."""
    def detect(frame: int, names: list[str]) -> Detections:
        d = abs(frame - peak)
        if d > half or "chair" not in names:
            return Detections.empty()
        box = [0, 40, 40, 80] if d > 0 else [40, 40, 100, 90]
        return Detections(np.array([box]), [0.9 - 0.5 * d / half], ["chair"])
    return detect


def test_climbing_a_cut_view_reaches_the_whole_view():
    """A hit whose box is cut by the border climbs to its neighbours until the best frame is a local maximum:
    with the climb steps the search scores the peak (whole) view in every seed; without them it misses it in some
    (the grid and the kernels alone come near it, not always onto it: 5 of 8 when written)."""
    m, peak = 300, 151
    found = {True: 0, False: 0}
    for climb in (True, False):
        for seed in range(8):
            conf = kf.KeyFrameConf.merged({"budget": 30, "iterations": 15, "climb": climb, "seed": seed,
                                           "content_prior": False})
            res = kf.iterative_search(range(m), ["chair"], [], _sliver_detector(m, peak, 8), conf=conf,
                                      image_size=(160, 120))
            found[climb] += peak in res.scores
    assert found[True] == 8 and found[False] <= 6, found
    with pytest.raises(InputError, match="climb_share"):
        kf.KeyFrameConf.merged(climb_share=1.5)


def test_no_climbing_while_hits_are_common():
    """More stretches than `climb_share` of the scored frames: the batch takes no climb steps (every pick is an
    exploration pick); at most that share: the cut stretch's neighbours come first."""
    for scores, climbs in (([0.6, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0], [19, 21]), ([0.6, 0.5, 0.0, 0.0], [])):
        st = kfs._Search(100, kf.KeyFrameConf.merged(climb_share=0.15), 1.0)
        for p, s in zip((20, 60, 5, 35, 50, 70, 80, 95), scores):
            st.add(p, s, st.conf.sigma_max)
        assert st.climbs() == climbs
        picks, _ = st.draw(3, np.random.default_rng(0))
        assert picks[:len(climbs)].tolist() == climbs and len(picks) == 3
