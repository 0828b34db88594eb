"""Android target (export/android.py + android/*.sh): .ort artifacts of the real shared models and of a tiny
random-weight SAM, checked here on onnxruntime CPU (no phone, no Android SDK on this machine)."""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("onnx")

from mosaicthinker.export import android as A  # noqa: E402
from mosaicthinker.runtime.infra import bundle as B  # noqa: E402

pytestmark = [pytest.mark.export, pytest.mark.slow]


REPO = Path(__file__).resolve().parents[1]
SCRIPTS = ["common.sh", "push.sh", "profile.sh", "build_ort.sh"]


def _session(path, runtime_opt=False, level=None, save_to=None):
    import onnxruntime as ort

    so = ort.SessionOptions()
    so.intra_op_num_threads = 1
    so.log_severity_level = 3
    if runtime_opt:
        so.add_session_config_entry("session.enable_saved_runtime_optimizations", "1")
    kw = {}
    if level is not None:
        so.graph_optimization_level = level
        so.optimized_model_filepath = str(save_to)
        so.add_session_config_entry("session.qdqisint8allowed", "1")  # what the converter sets for arm
        kw["disabled_optimizers"] = ["NchwcTransformer"]
    return ort.InferenceSession(str(path), so, providers=["CPUExecutionProvider"], **kw)


def _graph_ops(onnx_path, tmp, level):
    """(domain, op type) of the graph onnxruntime builds from `onnx_path` at `level` (saved as ONNX)."""
    import onnx

    out = tmp / f"opt_{Path(onnx_path).stem}_{int(level)}.onnx"
    _session(onnx_path, level=level, save_to=out)
    m = onnx.load(str(out))
    return {(n.domain or "ai.onnx", n.op_type) for n in m.graph.node}


@pytest.fixture(scope="module")
def real_bundle(shared_models, redkitchen, tmp_path_factory):
    """detector (YOLOX-Nano fp32; its SSD variant is not converted), segmenter (DeepLab fp32 + int8-qdq calibrated
    on 7-Scenes frames) and embedder (MobileNet QDQ) from ../shared/models."""
    from mosaicthinker.export.onnx_import import import_shared_models

    out = tmp_path_factory.mktemp("android_real") / "bundle"
    import_shared_models(shared_models, out, ["fp32"], roles=["detector", "embedder"])
    import_shared_models(shared_models, out, ["fp32", "int8-qdq"], roles=["segmenter"], calib=redkitchen)
    summary = A.export_android(out, A.AndroidConfig())
    return out, summary


@pytest.fixture(scope="module")
def tiny_bundle(tmp_path_factory):
    """Tiny random-weight CLIP vision tower (the embedder's real architecture, dynamic batch axis)."""
    from mosaicthinker.export.hf_clip import export_embedder

    out = tmp_path_factory.mktemp("android_tiny") / "bundle"
    export_embedder("tiny", out, ["fp32"])
    summary = A.export_android(out, A.AndroidConfig())
    return out, summary


def _android_variants(root):
    m = json.loads((root / "manifest.json").read_text())
    for role, rm in m["roles"].items():
        for v, vm in rm["variants"].items():
            if vm["target"] == "android":
                yield role, v, vm, rm


def _source_onnx(root, rm, vm):
    src = vm["android"]["source_variant"].split(" ")[0]
    if src in rm["variants"]:
        return {c: root / cm["file"] for c, cm in rm["variants"][src]["components"].items()}, src
    return {c: root / cm["file"] for c, cm in rm["variants"]["fp32"]["components"].items()}, "fp32"


def _check_parity(root, tmp):
    """Every .ort (both styles) loads, runs and matches the graph it came from on a fresh random input."""
    n = 0
    for role, v, vm, rm in _android_variants(root):
        srcs, src_prec = _source_onnx(root, rm, vm)
        for c, cm in vm["components"].items():
            ort_file = root / cm["file"]
            ro_file = root / vm["android"]["components"][c]["runtime_opt"]["file"]
            assert ort_file.suffix == ".ort" and ort_file.is_file() and ro_file.is_file()
            shapes = vm["android"]["components"][c]["fixed_shapes"]
            fixed_src = tmp / f"{role}_{v}_{c}.onnx"
            A.make_fixed(srcs[c], fixed_src, shapes) if shapes else shutil.copyfile(srcs[c], fixed_src)
            feeds = A.random_feeds_factory(fixed_src, rm)(np.random.default_rng(12345 + n))
            ref = _session(fixed_src).run(None, feeds)
            for path, ro in ((ort_file, False), (ro_file, True)):
                got = _session(path, runtime_opt=ro).run(None, feeds)
                assert len(got) == len(ref)
                for g, r in zip(got, ref):
                    assert g.shape == r.shape
                    if v.endswith("fp16") and src_prec == "fp32":  # derived fp16 vs the fp32 graph
                        tol = 3e-2 * max(float(np.abs(r).max()), 1e-6)
                    elif v.endswith("fp16"):
                        tol = 1e-2 * max(float(np.abs(r).max()), 1e-6)
                    elif v.endswith("int8-qdq"):  # arm QDQ fusions may round differently by one step
                        tol = 2e-2 * max(float(np.abs(r).max()), 1e-6)
                    else:
                        tol = 1e-4 * max(float(np.abs(r).max()), 1e-6)
                    assert float(np.abs(g.astype(np.float64) - r.astype(np.float64)).max()) <= tol, \
                        (role, v, c, path.name)
            # the input shapes recorded in the manifest are the .ort's real (static) shapes
            s = _session(ort_file)
            for i, spec in zip(s.get_inputs(), cm["inputs"]):
                assert list(i.shape) == spec["shape"] and all(isinstance(d, int) for d in i.shape)
            n += 1
    return n


def test_real_models_ort_parity(real_bundle, tmp_path):
    root, summary = real_bundle
    B.load_bundle(root, verify=True)  # every new file is hashed in the manifest
    m = json.loads((root / "manifest.json").read_text())
    # the rule, not a count: which quantised variants pass parity depends on the onnxruntime version and CPU
    seg = m["roles"]["segmenter"]
    asked = {"fp32", "int8-qdq"}
    shipped = {v for v, vm in seg["variants"].items() if vm.get("target") != "android"}
    refused = set(seg.get("skipped_variants", {}))
    assert "fp32" in shipped and shipped | refused == asked and not shipped & refused
    for v in shipped - {"fp32"}:
        par = seg["variants"][v]["parity"]["model"]
        assert par["ok"] and par["worst"]["rel"] <= par["tolerance"]["rel"] and par["trials"] >= 8
        assert isinstance(par["seed"], int)  # the exporter drew its seed and recorded it
    for v in refused:
        assert "parity vs fp32 failed" in seg["skipped_variants"][v] and "seed" in seg["skipped_variants"][v]
    # source variants of each role's own model (the detector's ssd-fp32, another model, is not converted)
    n_src = sum(sum(vm.get("target") != "android" and not vm.get("overrides") for vm in rm["variants"].values())
                for rm in m["roles"].values())
    n_ort = _check_parity(root, tmp_path)  # every .ort matches the graph it came from on a fresh input
    roles = summary["roles"]
    assert "android-ort-fp32" in roles["detector"]["variants"]
    assert "android-ort-fp16" in roles["segmenter"]["variants"]  # fp16 derived from fp32, parity ok
    assert n_ort == n_src + 1  # one .ort per shipped source variant, plus the segmenter's derived fp16
    if "int8-qdq" in shipped:
        q = roles["segmenter"]["variants"]["android-ort-int8-qdq"]["components"]["model"]
        assert q["providers"][0] == "QNN"  # QDQ graph in one NNAPI partition: QNN first, then NNAPI
        assert q["nnapi_partitions"] == 1 and "NNAPI" in q["providers"]
    # an already-quantised TFLite graph gets no fp16/int8 copies, and says why; YOLOX-Nano's fp16 copy is derived
    # and refused by its parity; its int8-qdq was not exported
    assert "already" in roles["embedder"]["skipped"]["fp16"] and "already" in roles["embedder"]["skipped"]["int8-qdq"]
    assert "parity" in roles["detector"]["skipped"]["fp16"] or "android-ort-fp16" in roles["detector"]["variants"]
    assert "calibration" in roles["detector"]["skipped"]["int8-qdq"]


def test_operator_config_covers_every_operator(real_bundle, tmp_path):
    import onnxruntime as ort

    root, _ = real_bundle
    cfg = root / A.OPS_CONFIG
    ops = A.config_op_types(A.read_operator_config(cfg))
    m = json.loads((root / "manifest.json").read_text())
    assert m["android"]["required_operators"]["file"] == A.OPS_CONFIG
    assert "--include_ops_by_config" in m["android"]["build_command"]
    for role, v, vm, rm in _android_variants(root):
        srcs, _ = _source_onnx(root, rm, vm)
        for c, cm in vm["components"].items():
            shapes = vm["android"]["components"][c]["fixed_shapes"]
            src = tmp_path / f"{role}_{v}_{c}.onnx"
            A.make_fixed(srcs[c], src, shapes) if shapes else shutil.copyfile(srcs[c], src)
            if v.endswith("fp16") and vm["android"]["source_variant"].startswith("fp16 (derived"):
                from mosaicthinker.export.common import to_fp16

                to_fp16(src, src)
                A.make_fixed(src, src, {})  # the same topological clean-up the export applies
            # Fixed style = the ALL-level graph; Runtime style keeps the BASIC-level graph
            for level in (ort.GraphOptimizationLevel.ORT_ENABLE_ALL, ort.GraphOptimizationLevel.ORT_ENABLE_BASIC):
                missing = _graph_ops(src, tmp_path, level) - ops
                assert not missing, f"{role}/{v}/{c}: operators {missing} missing from {cfg}"


def test_usability_reports(real_bundle):
    root, summary = real_bundle
    m = json.loads((root / "manifest.json").read_text())
    seen = 0
    for role, v, vm, rm in _android_variants(root):
        for c, info in vm["android"]["components"].items():
            rep = json.loads((root / info["usability"]["file"]).read_text())
            text = (root / info["usability_text"]["file"]).read_text()
            assert "Checking NNAPI" in text and "CoreML" in text
            n = rep["nnapi"]["partitions"]
            assert isinstance(n, int) and n == info["nnapi"]["partitions"]
            assert 0 <= rep["nnapi"]["supported_nodes"] <= rep["nnapi"]["nodes"]
            flagged = any(f.startswith("nnapi_many_partitions") for f in info["flags"])
            assert flagged == (n > 2)
            if flagged:
                assert "NNAPI" not in info["providers"]
            assert "XNNPACK and QNN" in rep["not_checked"]
            seen += 1
    # the bundle-wide summary lists every component
    assert len(m["android"]["usability_summary"]) == seen
    assert "not checked" in m["android"]["not_checked"]
    # DeepLab fp32 and YOLOX-Nano (decoding and NMS outside the graph) are one NNAPI partition each
    by = {(u["role"], u["variant"]): u for u in m["android"]["usability_summary"]}
    assert by[("segmenter", "android-ort-fp32")]["nnapi_partitions"] == 1
    assert by[("detector", "android-ort-fp32")]["nnapi_partitions"] == 1


def test_tiny_clip_fixed_shapes_and_parity(tiny_bundle, tmp_path):
    root, summary = tiny_bundle
    B.load_bundle(root, verify=True)
    m = json.loads((root / "manifest.json").read_text())
    rm = m["roles"]["embedder"]
    assert rm["variants"]["fp32"]["components"]["model"]["inputs"][0]["dynamic_axes"]  # batch is dynamic in the export
    size = rm["preprocessing"]["size"]
    for v in ("android-ort-fp32", "android-ort-fp16"):  # fp16 derived from fp32 (parity-checked)
        info = rm["variants"][v]["android"]["components"]["model"]
        assert info["fixed_shapes"]["pixel_values"] == [1, 3, *size] and not info["dynamic_left"]
    assert _check_parity(root, tmp_path) == 2
    assert rm["random_weights"] is True


def test_fixed_shape_plan_rules():
    role = {"preprocessing": {"size": [48, 64], "layout": "NHWC"}, "config": {"top_k": 256}}
    inputs = [{"name": "image", "shape": [0, 0, 0, 3], "dtype": "uint8",
               "dynamic_axes": {"0": "batch", "1": "height", "2": "width"}},
              {"name": "input_ids", "shape": [0, 0], "dtype": "int64",
               "dynamic_axes": {"0": "batch", "1": "sequence_length"}},
              {"name": "keypoints", "shape": [1, 0, 2], "dtype": "float32", "dynamic_axes": {"1": "num_keypoints"}},
              {"name": "past_key_values.0.key", "shape": [1, 2, 0, 8], "dtype": "float32",
               "dynamic_axes": {"2": "past_sequence_length"}},
              {"name": "point_coords", "shape": [0, 0, 2], "dtype": "float32",
               "dynamic_axes": {"0": "prompts", "1": "points"}},
              {"name": "weird", "shape": [1, 0], "dtype": "float32", "dynamic_axes": {"1": "zzz"}}]
    shapes, left = A.fixed_shape_plan(inputs, role, "model", A.AndroidConfig(text_len=12))
    assert shapes["image"] == [1, 48, 64, 3]
    assert shapes["input_ids"] == [1, 12]
    assert shapes["keypoints"] == [1, 256, 2]
    assert shapes["point_coords"] == [4, 4, 2]  # SAM prompts x points (pad with label -1)
    assert "past_key_values.0.key" not in shapes and "KV-cache" in left["past_key_values.0.key[2]"]
    assert "--fix zzz=VALUE" in left["weird[1]"]
    shapes, left = A.fixed_shape_plan(inputs[-1:], role, "model", A.AndroidConfig(overrides={"zzz": 5}))
    assert shapes == {"weird": [1, 5]} and not left
    providers, why = A.recommended_providers({"nnapi": {"partitions": 1, "supported_pct": 99.0}}, "fp32", True,
                                             A.AndroidConfig())
    assert providers == ["XNNPACK", "CPU"]


def test_operator_config_roundtrip(tmp_path):
    p = tmp_path / "a.config"
    p.write_text("# c\nai.onnx;13;Conv,Relu\ncom.microsoft;1;FusedConv\n")
    ops = A.read_operator_config(p)
    ops[("ai.onnx", 13)].add("Add")
    q = A.write_operator_config(tmp_path / "b.config", ops, ["x.ort"])
    assert A.read_operator_config(q) == ops
    (tmp_path / "bad.config").write_text("ai.onnx;x;Conv\n")
    with pytest.raises(Exception, match="malformed"):
        A.read_operator_config(tmp_path / "bad.config")


# ------------------------------------------------------------------------------------------------ scripts

@pytest.mark.parametrize("script", SCRIPTS)
def test_script_syntax(script, shellcheck):
    path = REPO / "android" / script
    assert path.is_file()
    subprocess.run(["bash", "-n", str(path)], check=True)
    r = subprocess.run([shellcheck, "-x", "-P", str(REPO), str(path)], capture_output=True, text=True, cwd=REPO)
    assert r.returncode == 0, r.stdout + r.stderr


def _run(args, env_over=None, **kw):
    base = os.environ if env_over is None else env_over
    env = {**base, "PYTHON": sys.executable,
           "PATH": base.get("PATH", "") + os.pathsep + str(Path(sys.executable).parent)}
    return subprocess.run(["bash", *map(str, args)], capture_output=True, text=True, env=env, **kw)


def test_push_and_profile_dry_run(real_bundle, tmp_path):
    root, _ = real_bundle
    perf = tmp_path / "onnxruntime_perf_test"
    perf.write_text("stub")
    r = _run([REPO / "android/push.sh", "--dry-run", "--serial", "ABC", "--perf-test", perf, root])
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    assert all(ln.startswith("adb -s ABC ") for ln in lines)
    pushed = [ln for ln in lines if " push " in ln and ln.split()[4].endswith(".ort")]
    n_comp = sum(len(vm["components"]) for _, _, vm, _ in _android_variants(root))
    assert n_comp >= 4 and len(pushed) == 2 * n_comp  # Fixed + Runtime style per component
    assert any("onnxruntime_perf_test" in ln for ln in lines)

    out = tmp_path / "prof"
    r = _run([REPO / "android/profile.sh", "--dry-run", "--providers", "cpu,nnapi,qnn", "--runs", "7",
              "--out", out, root])
    assert r.returncode == 0, r.stderr
    runs = [ln for ln in r.stdout.splitlines() if "onnxruntime_perf_test" in ln]
    assert len(runs) == 3 * n_comp
    assert all("-m times -r 7" in ln and " -I " in ln for ln in runs)
    assert all("with_runtime_opt.ort" in ln and "enable_saved_runtime_optimizations|1" in ln
               for ln in runs if "-e nnapi" in ln or "-e qnn" in ln)
    assert all("with_runtime_opt" not in ln for ln in runs if "-e cpu" in ln)
    assert r.stdout.splitlines()[-1].startswith("adb pull ")
    assert (out / "raw").is_dir()


def test_script_argument_errors(real_bundle, tmp_path):
    root, _ = real_bundle
    r = _run([REPO / "android/profile.sh", "--dry-run", "--providers", "gpu", root])
    assert r.returncode == 2 and "unknown provider" in r.stderr
    r = _run([REPO / "android/profile.sh", "--dry-run", "--runs", "0", root])
    assert r.returncode == 2 and "--runs" in r.stderr
    r = _run([REPO / "android/push.sh", "--dry-run", tmp_path])
    assert r.returncode == 2 and "manifest.json" in r.stderr
    r = _run([REPO / "android/push.sh", "--bogus", root])
    assert r.returncode == 2 and "unknown option" in r.stderr
    r = _run([REPO / "android/build_ort.sh", "--dry-run", "--ort-src", "/src/onnxruntime", "--qnn", root])
    assert r.returncode == 0, r.stderr
    line = r.stdout.splitlines()[-1]
    assert f"--include_ops_by_config {(root / A.OPS_CONFIG).resolve()}" in line
    assert "--minimal_build extended" in line and "--use_qnn" in line and "--use_nnapi" in line


def test_build_ort_expands_sdk_paths(real_bundle, tmp_path):
    """The SDK/NDK paths are the environment's when set; unset, the line keeps "$NAME" for the shell that runs
    it (never a quoted '$NAME' that would be passed literally) and a note says what to set."""
    root, _ = real_bundle
    cmd = [REPO / "android/build_ort.sh", "--dry-run", "--ort-src", "/src/onnxruntime", root]
    env = {k: v for k, v in os.environ.items() if k not in ("ANDROID_HOME", "ANDROID_NDK_HOME")}
    r = _run(cmd, env_over={**env, "ANDROID_HOME": str(tmp_path / "sdk"), "ANDROID_NDK_HOME": str(tmp_path / "ndk")})
    line = r.stdout.splitlines()[-1]
    assert r.returncode == 0 and f"--android_sdk_path {tmp_path / 'sdk'}" in line
    assert f"--android_ndk_path {tmp_path / 'ndk'}" in line and "note:" not in r.stderr
    r = _run(cmd, env_over=env)
    line = r.stdout.splitlines()[-1]
    assert r.returncode == 0 and "'$ANDROID_HOME'" not in line and '--android_sdk_path "$ANDROID_HOME"' in line
    assert "ANDROID_HOME is not set" in r.stderr and "ANDROID_NDK_HOME is not set" in r.stderr


def test_push_dry_run_needs_no_binaries(real_bundle, tmp_path):
    """--dry-run lists the pushes of binaries not built yet (with a note); a real run refuses them."""
    root, _ = real_bundle
    missing = tmp_path / "build" / "onnxruntime_perf_test"
    r = _run([REPO / "android/push.sh", "--dry-run", "--perf-test", missing, root])
    assert r.returncode == 0, r.stderr
    assert any(f"push {missing} " in ln for ln in r.stdout.splitlines()) and "not found here" in r.stderr
    r = _run([REPO / "android/push.sh", "--perf-test", missing, root], env_over={**os.environ, "ADB": "true"})
    assert r.returncode == 2 and "no such file" in r.stderr


# Output format of onnxruntime_perf_test -s (onnxruntime/test/perftest/performance_runner.cc), as profile.sh
# stores it with the appended exit code. Numbers here are made up: the test checks the parsing and the report.
PERF_OK = """Session creation time cost: 0.0508382 s
First inference time cost: 31 ms
Total inference time cost: 1.9918 s
Total inference requests: 100
Average inference time cost total: 19.918 ms
Total inference run time: 1.99202 s
Number of inferences per second: 50.2002
Avg CPU usage: 12 %
Peak working set size: 109531136 bytes
Min Latency: 0.0197812 s
Max Latency: 0.0202704 s
P50 Latency: 0.0199047 s
P90 Latency: 0.0200251 s
P95 Latency: 0.0201534 s
P99 Latency: 0.0202704 s
P999 Latency: 0.0202704 s
exit_code: 0
"""
PERF_FAIL = "Error: NNAPI execution provider is not available in this build\nexit_code: 1\n"


def test_perf_report_in_profile_schema(real_bundle, tmp_path):
    import importlib.util

    from mosaicthinker.runtime.commands.profile import REPORT_SCHEMA

    spec = importlib.util.spec_from_file_location("perf_report", REPO / "android" / "perf_report.py")
    pr = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(pr)
    r = pr.parse_perf_output(PERF_OK)
    assert r["ok"] and r["p50_s"] == pytest.approx(0.0199047) and r["total_requests"] == 100
    assert r["average_ms"] == pytest.approx(19.918) and r["peak_working_set_bytes"] == 109531136
    bad = pr.parse_perf_output(PERF_FAIL)
    assert not bad["ok"] and "not available" in bad["error"]

    root, _ = real_bundle
    raw = tmp_path / "raw"
    raw.mkdir()
    (raw / "device.txt").write_text("model=TEST-PHONE\nsoc=SM8550\nandroid=14\n")
    (raw / "segmenter__android-ort-fp32__model__cpu.txt").write_text(PERF_OK)
    (raw / "segmenter__android-ort-fp32__model__nnapi.txt").write_text(PERF_FAIL)
    out = tmp_path / "report"
    assert pr.main(["--bundle", str(root), "--raw", str(raw), "--out", str(out)]) == 0
    rep = json.loads((out / "report.json").read_text())
    assert rep["schema"] == REPORT_SCHEMA and rep["machine"]["device"] == "TEST-PHONE"
    v = rep["roles"]["segmenter"]["variants"]
    c = v["android-ort-fp32@cpu"]["components"]["model"]
    assert c["latency_ms"]["p50"] == pytest.approx(19.905, abs=1e-3) and c["load_ms"] == pytest.approx(50.84, 0.01)
    assert c["provider"] == "CPUExecutionProvider" and c["peak_rss_increase_mb"] == pytest.approx(104.5, abs=0.1)
    assert "error" in v["android-ort-fp32@nnapi"]["components"]["model"] and rep["fallbacks"]
    for f in ("report.md", "latency.png", "memory.png"):
        assert (out / f).stat().st_size > 0
    assert "android-ort-fp32@cpu" in (out / "report.md").read_text()


# ------------------------------------------------------------------------------------------------ VLM decoder

def _toy_decoder(path: Path, *, use_position_ids: bool = True, hidden: int = 16, d: int = 8, vocab: int = 24,
                 max_pos: int = 512) -> Path:
    """A one-layer, one-head attention decoder with the KV-cache I/O of export/hf_vlm.py (inputs_embeds,
    attention_mask, position_ids, past_key_0/past_value_0 -> logits, present_key_0/present_value_0), causal +
    padding mask and learned position embeddings. use_position_ids=False derives positions from the cache
    length instead (past .. past+s-1), as graphs without a position input do: the fixed window then breaks."""
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    rng = np.random.default_rng(0)
    w = {n: (rng.standard_normal(s) * 0.3).astype(np.float32) for n, s in
         {"Wq": (hidden, d), "Wk": (hidden, d), "Wv": (hidden, d), "Wo": (d, vocab), "PE": (max_pos, d)}.items()}
    init = [numpy_helper.from_array(v, k) for k, v in w.items()]
    init += [numpy_helper.from_array(np.array(v, dt), n) for n, v, dt in
             [("one_i", [1], np.int64), ("zero_i", [0], np.int64), ("ax1", [1], np.int64),
              ("scale", 1 / np.sqrt(d), np.float32), ("neg", -1e9, np.float32), ("onef", 1.0, np.float32),
              ("step", 1, np.int64)]]
    N = helper.make_node
    nodes = [N("Shape", ["inputs_embeds"], ["sh_x"]), N("Gather", ["sh_x", "one_i"], ["s"], axis=0),
             N("Shape", ["attention_mask"], ["sh_m"]), N("Gather", ["sh_m", "one_i"], ["t"], axis=0),
             N("Sub", ["t", "s"], ["past_len"]), N("Concat", ["s", "t"], ["st"], axis=0),
             N("ConstantOfShape", ["st"], ["ones"], value=helper.make_tensor("v", TensorProto.FLOAT, [1], [1.0])),
             N("Squeeze", ["past_len", "zero_i"], ["k0"]), N("Trilu", ["ones", "k0"], ["causal"], upper=0),
             N("Cast", ["attention_mask"], ["mf"], to=TensorProto.FLOAT), N("Unsqueeze", ["mf", "ax1"], ["mf3"]),
             N("Mul", ["causal", "mf3"], ["allowed"]), N("Sub", ["onef", "allowed"], ["blocked"]),
             N("Mul", ["blocked", "neg"], ["bias"])]
    if use_position_ids:
        nodes.append(N("Gather", ["PE", "position_ids"], ["pe"], axis=0))
    else:
        nodes += [N("Squeeze", ["t", "zero_i"], ["t0"]), N("Range", ["k0", "t0", "step"], ["rng_pos"]),
                  N("Gather", ["PE", "rng_pos"], ["pe"], axis=0)]
    nodes += [N("MatMul", ["inputs_embeds", "Wq"], ["q0"]), N("Add", ["q0", "pe"], ["q"]),
              N("MatMul", ["inputs_embeds", "Wk"], ["k1"]), N("Add", ["k1", "pe"], ["k2"]),
              N("MatMul", ["inputs_embeds", "Wv"], ["v1"]),
              N("Unsqueeze", ["k2", "ax1"], ["k3"]), N("Unsqueeze", ["v1", "ax1"], ["v3"]),
              N("Concat", ["past_key_0", "k3"], ["present_key_0"], axis=2),
              N("Concat", ["past_value_0", "v3"], ["present_value_0"], axis=2),
              N("Squeeze", ["present_key_0", "ax1"], ["K"]), N("Squeeze", ["present_value_0", "ax1"], ["V"]),
              N("Transpose", ["K"], ["KT"], perm=[0, 2, 1]), N("MatMul", ["q", "KT"], ["sc0"]),
              N("Mul", ["sc0", "scale"], ["sc1"]), N("Add", ["sc1", "bias"], ["sc"]),
              N("Softmax", ["sc"], ["p"], axis=-1), N("MatMul", ["p", "V"], ["o"]),
              N("MatMul", ["o", "Wo"], ["logits"])]
    f = TensorProto.FLOAT
    ins = [helper.make_tensor_value_info("inputs_embeds", f, [1, "seq", hidden]),
           helper.make_tensor_value_info("attention_mask", TensorProto.INT64, [1, "total"]),
           helper.make_tensor_value_info("position_ids", TensorProto.INT64, [1, "seq"]),
           helper.make_tensor_value_info("past_key_0", f, [1, 1, "past", d]),
           helper.make_tensor_value_info("past_value_0", f, [1, 1, "past", d])]
    outs = [helper.make_tensor_value_info("logits", f, [1, "seq", vocab]),
            helper.make_tensor_value_info("present_key_0", f, [1, 1, "total", d]),
            helper.make_tensor_value_info("present_value_0", f, [1, 1, "total", d])]
    m = helper.make_model(helper.make_graph(nodes, "toy_decoder", ins, outs, init),
                          opset_imports=[helper.make_opsetid("", 18)])
    m.ir_version = 9
    onnx.checker.check_model(m)
    onnx.save(m, str(path))
    return path


def _vlm_bundle(tmp, use_position_ids):
    from mosaicthinker.export import common as C

    meta = C.role_meta("smolvlm", preprocessing={"size": [32, 32], "layout": "NCHW"}, semantics={},
                       provenance={"source": "test toy decoder"}, licence="Apache-2.0", random_weights=True,
                       config={"family": "smolvlm"})
    out = tmp / "bundle"
    C.add_variant_files(out, "vlm", "fp32", {"decoder": _toy_decoder(tmp / "dec.onnx",
                                                                      use_position_ids=use_position_ids)},
                        meta=meta, precision="fp32")
    return out


def test_vlm_decoder_fixed_window_variant(tmp_path):
    root = _vlm_bundle(tmp_path, use_position_ids=True)
    conf = A.AndroidConfig(kv_window=16, prefill_len=4, make_fp16=False)
    summary = A.export_android(root, conf)
    comps = summary["roles"]["vlm"]["variants"]["android-ort-fp32"]["components"]
    dec = comps["decoder"]
    assert dec["dynamic_left"] and dec["providers"] == ["XNNPACK", "CPU"]  # growing cache: CPU/XNNPACK
    chk = dec["kv_window_check"]
    assert chk["ok"] and chk["max_rel"] < 1e-5 and chk["steps"] == 7
    m = json.loads((root / "manifest.json").read_text())
    vm = m["roles"]["vlm"]["variants"]["android-ort-fp32"]
    step = vm["android"]["components"]["decoder_kvwindow_step"]
    assert step["fixed_shapes"]["past_key_0"] == [1, 1, 16, 8] and step["fixed_shapes"]["attention_mask"] == [1, 17]
    assert vm["android"]["components"]["decoder_kvwindow_prefill"]["fixed_shapes"]["inputs_embeds"] == [1, 4, 16]
    assert "RIGHT" in step["kv_window"]["protocol"]
    # the fixed-window .ort graphs run the protocol: one prefill + steps give the dynamic graph's logits
    sess = {n: _session(root / vm["components"][n]["file"]) for n in ("decoder", "decoder_kvwindow_step")}
    rng = np.random.default_rng(3)
    x = rng.standard_normal((1, 4, 16)).astype(np.float32)
    ref = sess["decoder"].run(None, {"inputs_embeds": x, "attention_mask": np.ones((1, 4), np.int64),
                                     "position_ids": np.arange(4)[None],
                                     "past_key_0": np.zeros((1, 1, 0, 8), np.float32),
                                     "past_value_0": np.zeros((1, 1, 0, 8), np.float32)})[0]
    cache = [np.zeros((1, 1, 16, 8), np.float32)] * 2
    mask = np.zeros(16, np.int64)
    for t in range(4):  # token by token through the step graph
        lg, k, v = sess["decoder_kvwindow_step"].run(None, {
            "inputs_embeds": x[:, t:t + 1], "attention_mask": np.concatenate([mask, [1]])[None],
            "position_ids": np.array([[t]]), "past_key_0": cache[0], "past_value_0": cache[1]})
        cache, mask = [k[:, :, 1:], v[:, :, 1:]], np.concatenate([mask, [1]])[1:]
        np.testing.assert_allclose(lg[0, 0], ref[0, t], rtol=1e-4, atol=1e-5)
    B.load_bundle(root, verify=True)


def test_vlm_decoder_without_position_input_stays_cpu_only(tmp_path):
    root = _vlm_bundle(tmp_path, use_position_ids=False)
    summary = A.export_android(root, A.AndroidConfig(kv_window=16, prefill_len=4, make_fp16=False))
    comps = summary["roles"]["vlm"]["variants"]["android-ort-fp32"]["components"]
    assert set(comps) == {"decoder"}  # no window variant shipped
    assert not comps["decoder"]["kv_window_check"]["ok"] and comps["decoder"]["kv_window_check"]["max_rel"] > 1e-2
    assert comps["decoder"]["providers"] == ["XNNPACK", "CPU"]


def test_export_target_step_honours_android_roles(real_bundle, tmp_path):
    """`mosaic export ... --target android --android-roles embedder` converts only the embedder, not every role
    just exported."""
    import argparse

    root, _ = real_bundle
    copy = tmp_path / "bundle"
    shutil.copytree(root, copy)
    res = A.target_step(copy, ["detector", "segmenter", "embedder"], argparse.Namespace(android_roles="embedder"))
    assert sorted(res["roles"]) == ["embedder"]
    with pytest.raises(Exception, match="nope"):
        A.target_step(copy, ["embedder"], argparse.Namespace(android_roles="nope"))
