"""Budget-configuration tests: profile validation, planner arithmetic and monotonicity, provider fallback under a
device profile, re-planning on overrun and the memory guard (runtime/budget/)."""
from __future__ import annotations

import copy
import json
import math
import shutil
import sys

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mosaicthinker.runtime import budget as B
from mosaicthinker.runtime.infra.errors import InputError
from mosaicthinker.runtime.infra.bundle import bundle_hash
from mosaicthinker.runtime.infra.trace import peak_rss_mb, reset_peak_rss
from mosaicthinker.runtime.infra.errors import BudgetError, ProfileError
from mosaicthinker.runtime.infra.trace import Trace, rss_mb

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

import tomli_w

DEVICES = {"cpu-generic", "jetson-agx-orin-64gb", "jetson-orin-nx-16gb", "jetson-orin-nano-8gb", "oneplus-12r",
           "pixel-8gb"}


@pytest.fixture(scope="module")
def shared_bundle(tmp_path_factory, shared_models):
    """The shared real models imported into one fp32 bundle (files copied into a temp folder)."""
    from mosaicthinker.export.onnx_import import import_shared_models

    out = tmp_path_factory.mktemp("shared_bundle")
    import_shared_models(shared_models, out, ["fp32"])
    return out


HAND = {"pairs_per_keyframe": 1.5}  # planner conf of the hand-computed cases


def hand_profile(latency_ms: float = 6000, memory_mb: float = 1000) -> dict:
    """Round numbers so the planner's arithmetic can be checked by hand (no segmenter, embedder or VLM)."""
    est = {"status": "estimated", "source": "hand-made test figure"}
    return {
        "schema": B.PROFILE_SCHEMA,
        "device": {"name": "hand"},
        "budget": {"latency_budget_ms": latency_ms, "memory_budget_mb": memory_mb},
        "runtime": {"providers": ["CPUExecutionProvider"], "intra_op_threads": 1},
        "costs": {
            "process": {"resident_mb": 100, **est},
            "video_decode": {"ms_per_call": 1, **est},
            "dedup": {"ms_per_call": 2, **est},  # includes the decoding the pass does
            "grounding": {"ms_per_call": 0, **est},
            "detector": {"ms_per_call": 10, "load_ms": 100, "resident_mb": 50, **est},
            "depth": {"ms_per_call": 50, "load_ms": 100, "resident_mb": 100, **est},
            "matcher": {"ms_per_call": 20, "ms_per_pair": 10, "load_ms": 100, "resident_mb": 50, **est},
            "geometry": {"ms_per_call": 5, **est},
            "keyframe_state": {"mb_per_call": 10, **est},
        },
    }


def write(tmp_path, data: dict, name: str = "p.toml"):
    p = tmp_path / name
    p.write_bytes(tomli_w.dumps(data).encode())
    return p


# ------------------------------------------------------------------------------------------ profile validation


def test_shipped_profiles_validate():
    names = {p.stem for p in B.list_profiles()}
    assert DEVICES <= names
    for name in DEVICES:
        prof = B.load_profile(name)
        assert prof.providers[-1] == "CPUExecutionProvider"
        assert prof.latency_budget_ms > 0 and prof.memory_budget_mb > 0
        for e in prof.costs.values():  # every figure says where it comes from
            assert (e.status == "measured" and e.date and e.bundle_hash) or (e.status == "estimated" and e.source)
    assert B.load_profile("jetson-orin-nano-8gb").providers[:2] == ["TensorrtExecutionProvider",
                                                                   "CUDAExecutionProvider"]
    phone = B.load_profile("oneplus-12r")
    assert phone.providers == ["QNNExecutionProvider", "NnapiExecutionProvider", "XnnpackExecutionProvider",
                               "CPUExecutionProvider"]
    assert phone.role("detector").int8_kind == "qdq" and phone.role("detector").bundle_variant == "int8-qdq"
    assert B.load_profile("cpu-generic").role("vlm").bundle_variant == "int8-dynamic"


def _mutate(fn):
    d = hand_profile()
    fn(d)
    return d


@pytest.mark.parametrize("mutate, needle", [
    (lambda d: d["budget"].update(latency_budget_s=5), "wrong unit"),
    (lambda d: d["budget"].update(memory_budget_gb=1), "'memory_budget_mb'"),
    (lambda d: d["costs"]["detector"].update(s_per_call=1), "wrong unit"),
    (lambda d: d["budget"].update(colour="red"), "unknown key 'colour'"),
    (lambda d: d.update(extras={}), "unknown key 'extras'"),
    (lambda d: d["costs"].update(teleport={"ms_per_call": 1, "status": "estimated", "source": "x"}),
     "unknown cost item"),
    (lambda d: d["budget"].update(latency_budget_ms=-5), "negative"),
    (lambda d: d["costs"]["depth"].update(ms_per_call=-1.0), "negative"),
    (lambda d: d["budget"].update(latency_budget_ms="5 s"), "must be a number"),
    (lambda d: d["budget"].pop("memory_budget_mb"), "budget.memory_budget_mb is missing"),
    (lambda d: d["costs"].pop("geometry"), "missing cost table [costs.geometry]"),
    (lambda d: d["costs"]["depth"].pop("resident_mb"), "missing field 'resident_mb'"),
    (lambda d: d["costs"]["depth"].update(status="measured"), "needs 'date'"),
    (lambda d: d["costs"]["depth"].pop("source"), "needs 'source'"),
    (lambda d: d["runtime"].update(providers=["CUDAExecutionProvider"]), "must end with 'CPUExecutionProvider'"),
    (lambda d: d["runtime"].update(providers=["WarpDriveProvider", "CPUExecutionProvider"]),
     "must be a known execution provider"),
    (lambda d: d.update(schema="mosaicthinker.profile/9"), "schema"),
    (lambda d: d.update(roles={"depth": {"precision": "int8"}}), "int8_kind"),
    (lambda d: d.update(roles={"depth": {"precision": "int8", "int8_kind": "dynamic",
                                         "providers": ["QNNExecutionProvider", "CPUExecutionProvider"]}}),
     "runs on CPU only"),
    (lambda d: d.update(roles={"depth": {"precision": "fp8"}}), "precision"),
    (lambda d: d.update(roles={"ears": {"precision": "fp32"}}), "unknown role"),
    (lambda d: d["runtime"].update(core_affinity=[-1]), "core_affinity"),
])
def test_bad_profiles_are_refused_with_the_field_named(tmp_path, mutate, needle):
    path = write(tmp_path, _mutate(mutate), "bad.toml")
    with pytest.raises(ProfileError) as e:
        B.load_profile(path)
    assert needle in str(e.value)
    assert "bad.toml" in str(e.value)


def test_bad_toml_and_missing_file(tmp_path):
    p = tmp_path / "broken.toml"
    p.write_text("[budget\nlatency_budget_ms = 5")
    with pytest.raises(ProfileError, match="not valid TOML"):
        B.load_profile(p)
    with pytest.raises(ProfileError, match="no such profile"):
        B.load_profile(tmp_path / "nope.toml")


# --------------------------------------------------------------------------------------------------- planner


def test_plan_arithmetic_by_hand():
    # 100 s at 10 fps = 1000 frames -> 500 candidates. fixed = loads 300 + video pass 1000 x 2 = 2300 ms.
    # per scored frame = decode 1 + detector 10 = 11 ms; per key frame = decode 1 + depth 50 + features 20
    # + 1.5 pairs x 10 + geometry 5 = 91 ms; the search scores at least 4 frames per key frame.
    # latency: 2300 + 4k x 11 + 91k <= 6000 -> k <= 27.4 -> K = 27 (memory 100 + 200 + 270 <= 1000 fits).
    # S = max(4 x 27, min(ceil(0.25 x 500) = 125, floor((6000 - 2300 - 27 x 91) / 11) = 113)) = 113.
    p = B.plan(B.parse_profile(hand_profile(6000, 1000)), 100, 10, conf=HAND)
    assert (p.total_frames, p.candidates) == (1000, 500)
    assert sum(p.fixed_ms.values()) == pytest.approx(2300)
    assert sum(p.per_keyframe_ms.values()) == pytest.approx(91)
    assert p.keyframes == 27 and p.limited_by == "latency"
    assert p.scored_frames == 113
    assert (p.iterations, p.batch_size) == (20, 6)
    assert p.total_ms == pytest.approx(2300 + 113 * 11 + 27 * 91)
    assert p.total_memory_mb == pytest.approx(100 + 200 + 270)
    d = p.to_dict()
    assert d["keyframes"] == 27 and d["scored_frames"] == 113 and d["session_policy"] == "all_resident"
    assert any("K = 27" in line for line in d["arithmetic"])
    json.dumps(d)

    # memory-bound: all resident 100 + 200 + 10k <= 400 gives k <= 10; one session at a time (stage-major)
    # 100 + max(100) + 10k <= 400 gives k <= 20, so the planner loads them one at a time: K = 20, and the search
    # gets its target min(ceil(0.25 x 500) = 125, 6 per key frame x 20 = 120) = 120 (6000 - 2300 - 20 x 91 =
    # 1880 ms leaves room for 170).
    p = B.plan(B.parse_profile(hand_profile(6000, 400)), 100, 10, conf=HAND)
    assert (p.keyframes, p.limited_by, p.scored_frames) == (20, "memory", 120)
    assert p.session_policy == "one_at_a_time" and p.total_memory_mb == pytest.approx(100 + 100 + 200)

    # 100 + 100 + 10k <= 250 -> K = 5
    p = B.plan(B.parse_profile(hand_profile(6000, 250)), 100, 10, conf=HAND)
    assert (p.session_policy, p.keyframes) == ("one_at_a_time", 5)

    # plenty of budget: K hits keyframes_max
    p = B.plan(B.parse_profile(hand_profile(60000, 5000)), 100, 10, conf=HAND)
    assert p.keyframes == 32 and p.limited_by.startswith("keyframes_max")


def test_paper_example_one_second_at_40_ms_per_scored_frame_gives_25_frames():
    """The paper's own example: with 1 s for the search and 40 ms to score a frame, the search scores 25 frames."""
    prof = hand_profile(1000, 1000)
    for name, c in prof["costs"].items():  # everything free except scoring a frame with the detector
        for k in ("ms_per_call", "ms_per_pair", "load_ms"):
            if k in c:
                c[k] = 0
    prof["costs"]["detector"]["ms_per_call"] = 40
    p = B.plan(B.parse_profile(prof), 100, 10, conf=HAND)
    assert p.scored_frames == 25 and p.search_ms == pytest.approx(1000)


def test_plan_nothing_fits_says_which_budget_and_by_how_much():
    # K = 2: 2300 + 8 x 11 + 2 x 91 = 2570 ms > 2000 ms -> fails by 570 ms
    with pytest.raises(BudgetError, match=r"latency budget 2,000 ms fails by 570 ms"):
        B.plan(B.parse_profile(hand_profile(2000, 1000)), 100, 10, conf=HAND)
    # memory: even one session at a time needs 100 + 100 + 2 x 10 = 220 MB > 150 MB -> fails by 70 MB
    with pytest.raises(BudgetError, match=r"memory budget 150 MB fails by 70.0 MB") as e:
        B.plan(B.parse_profile(hand_profile(60000, 150)), 100, 10, conf=HAND)
    assert "latency" not in str(e.value)


@settings(max_examples=40, deadline=None)
@given(l1=st.floats(1000, 120000), dl=st.floats(0, 60000), m1=st.floats(100, 3000), dm=st.floats(0, 2000),
       dur=st.floats(5, 900), fps=st.sampled_from([5.0, 10.0, 15.0, 30.0]))
def test_more_budget_never_gives_fewer_keyframes(l1, dl, m1, dm, dur, fps):
    base = B.load_profile("cpu-generic")

    def k(lat, mem):
        prof = copy.copy(base)
        prof.latency_budget_ms, prof.memory_budget_mb = lat, mem
        try:
            return B.plan(prof, dur, fps).keyframes
        except BudgetError:
            return 0

    assert k(l1, m1) <= k(l1 + dl, m1) <= k(l1 + dl, m1 + dm)
    assert k(l1, m1) <= k(l1, m1 + dm)


@pytest.mark.export
def test_plan_with_bundle_drops_missing_roles_and_reads_sizes(shared_bundle):
    p = B.plan("cpu-generic", 60, 15, bundle=shared_bundle)
    d = p.to_dict()
    assert "vlm" not in d["providers"] and any("no vlm" in n for n in d["notes"])
    assert d["resolutions"]["depth"] == [640, 448] and d["resolutions"]["detector"] == [416, 416]  # YOLOX-Nano
    assert d["bundle_hash"] == bundle_hash(shared_bundle) and len(d["bundle_hash"]) == 16
    assert d["stages"]["answer"]["planned_ms"] == 0


def test_mosaic_plan_cli(capsys, tmp_path):
    from mosaicthinker.runtime.cli import main

    assert main(["plan", "--profile", "jetson-orin-nx-16gb", "--duration", "60", "--fps", "15", "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["schema"] == B.PLAN_SCHEMA and d["keyframes"] >= 2 and d["scored_frames"] >= d["keyframes"]
    assert d["providers"]["depth"]["device"] == "TensorrtExecutionProvider"
    assert d["providers"]["depth"]["here"] == "CPUExecutionProvider"
    assert main(["plan", "--profile", "cpu-generic", "--duration", "60", "--fps", "15"]) == 0
    out = capsys.readouterr().out
    assert "key frames K" in out and "arithmetic:" in out
    tiny = write(tmp_path, hand_profile(500, 1000), "tiny.toml")
    assert main(["plan", "--profile", str(tiny), "--duration", "60", "--fps", "15"]) == 2
    assert "latency budget" in capsys.readouterr().err


def test_mosaic_plan_video(capsys, redkitchen):
    from mosaicthinker.runtime.cli import main

    assert main(["plan", "--profile", "cpu-generic", "--video", str(redkitchen), "--fps", "30", "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["video"]["frames"] == len([p for p in redkitchen.glob("frame-*.color.*")])


# ------------------------------------------------------------------------------------------------ providers


def test_profile_provider_chain_falls_back_to_cpu_with_reasons(shared_models):
    from mosaicthinker.runtime.infra.providers import create_session

    prof = B.load_profile("jetson-orin-nano-8gb")
    trace = Trace()
    opts = prof.session_options("embedder")
    s = create_session(shared_models / "mobilenet-v1-embedding" / "mobilenet_v1_embedding.onnx", "embedder",
                       opts["providers"], threads=opts["intra_op_threads"], trace=trace)
    assert s.provider == "CPUExecutionProvider"
    fb = trace.fallbacks()
    requested = {e.get("requested") for e in fb}
    assert {"TensorrtExecutionProvider", "CUDAExecutionProvider"} <= requested
    assert all("not available" in e["message"] for e in fb if e.get("requested") != "CPUExecutionProvider")
    assert trace.providers["embedder"]["used"] == "CPUExecutionProvider"
    out = s.run({s.input_names[0]: np.zeros((1, 224, 224, 3), np.uint8)})
    assert out[0].size == 1024


# ------------------------------------------------------------------------------------------------- run time


class FakeClock:
    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


def test_overrun_replans_remaining_stages():
    p = B.plan(B.parse_profile(hand_profile(6000, 1000)), 100, 10, conf=HAND)  # K = 27, S = 113
    clock, trace = FakeClock(), Trace()
    ctl = B.BudgetController(p, trace, clock=clock, rss=lambda: 0.0)
    # on-plan stage: no re-plan
    ctl.start_stage("load")
    clock.t += 0.3
    assert ctl.end_stage("load") is False and not ctl.reduced
    # the video pass takes 3.5 s instead of 2 s: 1.5 s behind, remaining stages must shrink
    ctl.start_stage("frames")
    clock.t += 3.5
    assert ctl.end_stage("frames") is True
    assert ctl.reduced and ctl.keyframes < p.keyframes and ctl.scored_frames < p.scored_frames
    assert ctl.batch_size <= p.batch_size
    ev = [e for e in trace.events if e["kind"] == "replan"]
    assert ev and "reduced plan" in ev[0]["message"] and ev[0]["keyframes"] == ctl.keyframes
    assert trace.decisions["budget.reduced_plan"] is True
    # what is left now fits the time left (scaled by the observed slowdown)
    slow = ev[0]["slowdown"]
    rest = sum(p.stage_ms(n, ctl.keyframes, ctl.scored_frames) for n in ("grounding", "keyframes", "perception",
                                                                         "alignment", "answer"))
    assert slow * rest <= ctl.remaining_ms() + 1e-6
    assert ctl.summary()["reduced_plan"] is True
    assert ctl.allow_keyframes(p.keyframes) == ctl.keyframes


def test_tiny_budget_overruns_to_the_minimum_and_says_so():
    p = B.plan(B.parse_profile(hand_profile(6000, 1000)), 100, 10, conf=HAND)
    clock, trace = FakeClock(), Trace()
    ctl = B.BudgetController(p, trace, clock=clock, rss=lambda: 0.0)
    with ctl.stage("load"):
        clock.t += 7.0  # the whole budget gone in the first stage
    assert ctl.reduced and ctl.keyframes == p.conf.keyframes_min
    assert "will overrun" in trace.events[-1]["message"]
    assert trace.stages["load"].calls == 1


def test_memory_guard_releases_idle_sessions_then_refuses():
    p = B.plan(B.parse_profile(hand_profile(60000, 5000)), 100, 10, conf=HAND)
    p.memory_budget_mb = rss_mb() + 60.0  # deliberately tiny headroom
    trace = Trace()
    ctl = B.BudgetController(p, trace)
    held = {"big": np.ones(100 * 2**20 // 8)}  # ~100 MB, touched, so it is resident

    def release():
        held.pop("big", None)

    ctl.register_session("depth", 100.0, release)
    assert ctl.headroom_mb() < 0
    ctl.start_stage("perception")  # the depth session is idle here (registered outside this stage)
    assert ctl.check_headroom(20.0, "load the segmenter") is True
    assert "big" not in held
    assert any(e["kind"] == "memory_guard" and e.get("session") == "depth" for e in trace.events)
    assert not ctl.reduced
    assert ctl.check_headroom(10_000.0, "load a 10 GB model") is False
    assert ctl.reduced and "memory guard" in ctl.reasons[-1]
    # key frames: 10 MB each in the hand profile; headroom ~60 MB -> far fewer than the 32 planned
    k = ctl.allow_keyframes(32)
    assert 0 <= k < 10
    ctl.end_stage("perception")
    assert ctl.summary()["stages"]["perception"]["peak_rss_mb"] > 0


def test_peak_rss_reset_and_read():
    import mmap

    reset_peak_rss()
    before = peak_rss_mb()
    # fresh anonymous pages: a numpy array may reuse heap memory an earlier test freed and that stayed resident
    # (the test then failed in some orders of the suite)
    with mmap.mmap(-1, 64 * 2**20) as m:
        np.frombuffer(m, np.uint8)[::4096] = 1  # touch every page
        assert peak_rss_mb() >= before + 50


# ---------------------------------------------------------------------------------------- update-profile


def test_update_profile_costs_round_trip(tmp_path):
    dst = tmp_path / "cpu.toml"
    shutil.copy(B.resolve_profile_path("cpu-generic"), dst)
    B.update_profile_costs(dst, {"detector": {"ms_per_call": 12.5, "load_ms": 80.0}}, bundle_hash_="abcd1234abcd1234",
                           date="2026-11-22", providers={"detector": "CPUExecutionProvider"})
    prof = B.load_profile(dst)
    e = prof.cost("detector")
    assert (e.status, e.date, e.bundle_hash, e.ms_per_call, e.load_ms) == ("measured", "2026-11-22",
                                                                           "abcd1234abcd1234", 12.5, 80.0)
    assert e.source is None and "resident_mb kept" in e.note
    assert prof.cost("depth").status in ("estimated", "measured")
    with open(dst, "rb") as f:
        assert tomllib.load(f)["costs"]["detector"]["provider"] == "CPUExecutionProvider"
    with pytest.raises(ProfileError):
        B.update_profile_costs(dst, {"detector": {"ms_per_call": -1.0}}, bundle_hash_="x")
    assert B.load_profile(dst).cost("detector").ms_per_call == 12.5  # the invalid update was not written


def test_stage_aliases_and_candidates_after_dedup():
    p = B.plan(B.parse_profile(hand_profile(6000, 1000)), 100, 10, conf=HAND)  # K = 27, S = 113 from 500 estimated
    clock, trace = FakeClock(), Trace()
    ctl = B.BudgetController(p, trace, clock=clock, rss=lambda: 0.0)
    assert ctl.share_ms("dedup") == ctl.share_ms("frames") == pytest.approx(2000)
    with ctl.stage("dedup"):  # the trace keeps the pipeline's name, the controller books it on "frames"
        clock.t += 1.0
    assert "dedup" in trace.stages and "frames" in ctl.done and not ctl.reduced
    ctl.update_candidates(20)  # dedup kept only 20 frames
    assert (ctl.keyframes, ctl.scored_frames) == (20, 20) and ctl.batch_size == 1
    assert trace.decisions["budget.candidates"] == 20


@pytest.mark.export
def test_profile_variant_in_bundle(shared_bundle):
    trace = Trace()
    assert B.load_profile("cpu-generic").variant_in("depth", shared_bundle, trace) == "fp32"
    # no fp16 depth in this bundle: the nearest precision it has runs, and the trace says so
    assert B.load_profile("jetson-orin-nano-8gb").variant_in("depth", shared_bundle, trace) == "fp32"
    assert any(e["kind"] == "degraded" and e.get("requested") == "fp16" and e.get("used") == "fp32"
               for e in trace.events)


def test_nearest_variant_by_precision():
    have = {"fp32": {"precision": "fp32"}, "android-ort-int8-qdq": {"precision": "int8-qdq"},
            "int8-dynamic": {"precision": "int8-dynamic"}}
    assert B.nearest_variant("fp32", have) == "fp32"
    assert B.nearest_variant("int8-qdq", have) == "android-ort-int8-qdq"  # same precision, another target
    assert B.nearest_variant("fp16", {"fp32": {"precision": "fp32"}, "int8-qdq": {"precision": "int8-qdq"}}) == "fp32"
    assert B.nearest_variant("int8-qdq", {"fp32": {"precision": "fp32"}, "fp16": {"precision": "fp16"}}) == "fp16"
    assert B.nearest_variant("custom", have) is None


@pytest.mark.export
def test_phone_profile_runs_the_shared_bundle_on_its_nearest_variants(shared_bundle):
    """`--profile pixel-8gb` on a bundle without int8-qdq variants: planned and loaded on the nearest ones, loudly
    (it used to fail with "role 'detector' has no variant 'int8-qdq'")."""
    from mosaicthinker.runtime.pipeline import perception_from_bundle

    prof = B.load_profile("pixel-8gb")
    plan = B.plan(prof, 60, 15, bundle=shared_bundle)
    assert all(p["variant"] == "fp32" for p in plan.to_dict()["providers"].values())
    assert any("nearest" in n for n in plan.notes)
    trace = Trace()
    perc = perception_from_bundle(shared_bundle, trace=trace, profile=prof)
    assert perc is not None
    used = [e for e in trace.events if e["kind"] == "degraded" and e.get("used") == "fp32"]
    assert used and all("int8-qdq" in e["message"] or "fp16" in e["message"] for e in used)


def test_online_video_pass_is_not_in_the_question_latency():
    # fixed = loads 300 only; 300 + 4k x 11 + 91k <= 2000 -> k <= 12.6 -> K = 12 (question mode: nothing fits)
    prof = B.parse_profile(hand_profile(2000, 1000))
    with pytest.raises(BudgetError, match="--online"):
        B.plan(prof, 100, 10, conf=HAND)
    p = B.plan(prof, 100, 10, conf={**HAND, "video_pass": "online"})
    assert p.fixed_ms["video_pass"] == 0 and p.keyframes == 12
    assert not any("cannot keep up" in n for n in p.notes)  # 2 ms per frame at 10 fps: x0.02 real time
    slow = B.parse_profile(_mutate(lambda d: d["costs"]["dedup"].update(ms_per_call=150)))
    assert any("cannot keep up" in n for n in B.plan(slow, 100, 10, conf={**HAND, "video_pass": "online"}).notes)


def test_controller_for_a_frame_source(redkitchen):
    from mosaicthinker.runtime.frames import open_source

    src = open_source(redkitchen, fps=30)
    duration, fps = B.clip_of(src)
    assert duration * fps == pytest.approx(len(src))
    trace = Trace()
    ctl = B.controller_for("cpu-generic", src, trace, conf={"use_vlm": False})
    assert ctl.plan.total_frames == len(src) and 2 <= ctl.keyframes <= 32
    assert trace.decisions["budget.plan"]["keyframes"] == ctl.keyframes


def test_plan_with_paper_model_costs(tmp_path):
    """[paper_costs.*] replace the model costs under --models paper; a profile without them says so."""
    import tomllib

    from mosaicthinker.runtime.budget import MODEL_SETS, load_profile, plan, resolve_profile_path
    from mosaicthinker.runtime.infra.errors import ProfileError

    src = resolve_profile_path("cpu-generic")
    data = tomllib.loads(src.read_text())
    data.pop("paper_costs", None)
    base = tmp_path / "p.toml"
    import tomli_w

    base.write_text(tomli_w.dumps(data))
    with pytest.raises(ProfileError, match="paper_costs"):
        plan(base, 60, 30, models="paper")
    vlm = dict(data["costs"]["vlm"])
    data["paper_costs"] = {"vlm": {**vlm, "ms_per_token": vlm["ms_per_token"] * 3, "status": "estimated",
                                   "source": "test"}}
    base.write_text(tomli_w.dumps(data))
    shared, paper = plan(base, 60, 30, models="shared"), plan(base, 60, 30, models="paper")
    assert paper.total_ms > shared.total_ms and MODEL_SETS == ("shared", "paper")
    assert load_profile(base).with_models("paper").cost("vlm").ms_per_token == vlm["ms_per_token"] * 3


@pytest.mark.export
def test_a_variant_name_the_bundle_lacks_entirely_runs_its_default_loudly(shared_bundle):
    prof = B.load_profile("cpu-generic")
    prof.roles["depth"].variant = "custom-build"  # no precision to match: the bundle's default runs
    trace = Trace()
    assert prof.variant_in("depth", shared_bundle, trace) is None
    ev = [e for e in trace.events if e["kind"] == "degraded" and e.get("requested") == "custom-build"]
    assert ev and ev[0]["used"] == "fp32" and "default variant 'fp32'" in ev[0]["message"]


def test_scored_budget_does_not_grow_with_duration():
    # issue 14: at the same K the search's scored-frame target is capped per key frame, so a 10x longer clip
    # (10x the candidates) does not score 10x the frames; without the cap it would follow scored_fraction.
    prof = B.parse_profile(hand_profile(10**9, 10**6))
    short = B.plan(prof, 60, 10, conf={**HAND, "keyframes_max": 8})
    long = B.plan(prof, 600, 10, conf={**HAND, "keyframes_max": 8})
    assert short.keyframes == long.keyframes == 8
    assert long.candidates == 10 * short.candidates
    assert long.scored_frames == short.scored_frames == 6 * 8
    free = B.plan(prof, 600, 10, conf={**HAND, "keyframes_max": 8, "plan_max_scored_per_keyframe": None})
    assert free.scored_frames == math.ceil(0.25 * free.candidates) > 6 * 8
    with pytest.raises(InputError, match="plan_max_scored_per_keyframe"):
        B.plan(prof, 60, 10, conf={**HAND, "plan_max_scored_per_keyframe": 1})
