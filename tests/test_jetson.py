"""Jetson target (export/jetson.py): TensorRT EP provider options, optimisation-profile shapes and trtexec
commands generated from a bundle. TensorRT is not installed here, so no engine is built: the generated
settings are checked for form, against the graphs (onnxruntime CPU runs them at the min/opt/max shapes), and
the generated build script is executed with a stand-in `trtexec` that validates its arguments."""
from __future__ import annotations

import json
import os
import shutil
import stat
import subprocess
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("onnx")

from mosaicthinker.export import common as C  # noqa: E402
from mosaicthinker.export import jetson as J  # noqa: E402

pytestmark = [pytest.mark.export]

from mosaicthinker.runtime.infra import bundle as B  # noqa: E402
from mosaicthinker.runtime.infra.errors import ExportError  # noqa: E402


def _dynamic_graph(path: Path) -> Path:
    """A small graph with the dynamic axes of the pipeline's graphs: batch, SAM prompts/points, a VLM decoder's
    token and KV-cache axes (outputs are reductions, so any shape runs)."""
    import onnx
    from onnx import TensorProto, helper

    ins = [helper.make_tensor_value_info("pixel_values", TensorProto.FLOAT, ["batch", 3, 32, 32]),
           helper.make_tensor_value_info("point_coords", TensorProto.FLOAT, ["prompts", "points", 2]),
           helper.make_tensor_value_info("input_ids", TensorProto.INT64, [1, "sequence_length"]),
           helper.make_tensor_value_info("past_key_values.0.key", TensorProto.FLOAT,
                                         [1, 2, "past_sequence_length", 4]),
           helper.make_tensor_value_info("attention_mask", TensorProto.INT64, [1, "total_sequence_length"])]
    nodes, outs = [], []
    for i, inp in enumerate(ins):
        x = inp.name
        if inp.type.tensor_type.elem_type == TensorProto.INT64:
            nodes.append(helper.make_node("Cast", [x], [f"c{i}"], to=TensorProto.FLOAT))
            x = f"c{i}"
        nodes.append(helper.make_node("ReduceSum", [x], [f"o{i}"], keepdims=0))
        outs.append(helper.make_tensor_value_info(f"o{i}", TensorProto.FLOAT, []))
    g = helper.make_graph(nodes, "dyn", ins, outs)
    m = helper.make_model(g, opset_imports=[helper.make_opsetid("", 18)])
    m.ir_version = 9
    onnx.save(m, str(path))
    return path


def _qdq_graph(path: Path, zp_dtype) -> Path:
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    x = helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, 4])
    y = helper.make_tensor_value_info("y", TensorProto.FLOAT, [1, 4])
    init = [numpy_helper.from_array(np.array(0.1, np.float32), "s"),
            numpy_helper.from_array(np.array(0, zp_dtype), "z")]
    nodes = [helper.make_node("QuantizeLinear", ["x", "s", "z"], ["q"]),
             helper.make_node("DequantizeLinear", ["q", "s", "z"], ["y"])]
    m = helper.make_model(helper.make_graph(nodes, "qdq", [x], [y], init),
                          opset_imports=[helper.make_opsetid("", 18)])
    m.ir_version = 9
    onnx.save(m, str(path))
    return path


@pytest.fixture(scope="module")
def bundle(shared_models, tmp_path_factory):
    from mosaicthinker.export.onnx_import import import_shared_models

    tmp = tmp_path_factory.mktemp("jetson")
    out = tmp / "bundle"
    import_shared_models(shared_models, out, ["fp32"], roles=["detector", "segmenter"])
    meta = C.role_meta("smolvlm", preprocessing={"size": [32, 32], "layout": "NCHW"}, semantics={},
                       provenance={"source": "test"}, licence="Apache-2.0", random_weights=True)
    C.add_variant_files(out, "vlm", "fp32", {"decoder": _dynamic_graph(tmp / "dyn.onnx")}, meta=meta,
                        precision="fp32")
    C.add_variant_files(out, "vlm", "int8-qdq", {"decoder": _qdq_graph(tmp / "q.onnx", np.int8)}, meta=meta,
                        precision="int8-qdq", target="accelerator")
    summary = J.export_jetson(out, J.JetsonConfig())
    return out, summary


def _parse_shapes(s: str) -> dict[str, list[int]]:
    out = {}
    for item in s.split(","):
        name, dims = item.rsplit(":", 1)
        out[name] = [int(d) for d in dims.split("x")]
    return out


def test_profile_shapes_cover_dynamic_inputs_and_run(bundle):
    import onnxruntime as ort

    root, _ = bundle
    m = json.loads((root / "manifest.json").read_text())
    comp = m["roles"]["vlm"]["variants"]["fp32"]["components"]["decoder"]
    jc = m["roles"]["vlm"]["variants"]["fp32"]["jetson"]["components"]["decoder"]
    trt_name, opts = jc["providers"][0]
    assert [p[0] for p in jc["providers"]] == ["TensorrtExecutionProvider", "CUDAExecutionProvider",
                                               "CPUExecutionProvider"]
    dyn_inputs = {i["name"] for i in comp["inputs"] if i["dynamic_axes"]}
    prof = {k: _parse_shapes(opts[f"trt_profile_{k}_shapes"]) for k in ("min", "opt", "max")}
    assert set(prof["min"]) == set(prof["opt"]) == set(prof["max"]) == dyn_inputs  # TensorRT needs all of them
    assert prof == jc["trt_profile_shapes"]
    sess = ort.InferenceSession(str(root / comp["file"]), providers=["CPUExecutionProvider"])
    for k in ("min", "opt", "max"):
        for name in dyn_inputs:
            assert all(a <= b for a, b in zip(prof["min"][name], prof[k][name]))
            assert all(a <= b for a, b in zip(prof[k][name], prof["max"][name]))
        feeds = {i.name: np.ones(prof[k][i.name], np.float32 if "float" in i.type else np.int64)
                 for i in sess.get_inputs()}
        sess.run(None, feeds)  # every profile shape is a valid input of the graph
    assert prof["min"]["past_key_values.0.key"][2] == 0  # the prefill call has an empty cache
    conf = J.JetsonConfig()
    assert prof["opt"]["past_key_values.0.key"][2] == conf.past_range[1]
    assert prof["max"]["attention_mask"][1] == conf.past_range[2] + conf.seq_range[2]  # total = past + new
    assert prof["min"]["pixel_values"] == [1, 3, 32, 32] and prof["max"]["pixel_values"][0] == conf.max_batch
    assert prof["opt"]["point_coords"] == [conf.prompts_range[1], conf.points_range[1], 2]


def test_provider_options_by_precision(bundle):
    root, _ = bundle
    m = json.loads((root / "manifest.json").read_text())
    seg = m["roles"]["segmenter"]["variants"]["fp32"]["jetson"]["components"]["model"]
    o = seg["providers"][0][1]
    assert o["trt_engine_cache_enable"] is True and o["trt_engine_cache_path"] == "/cache/trt/segmenter/fp32"
    assert o["trt_dump_ep_context_model"] is True and o["trt_ep_context_file_path"].endswith("model_ctx.onnx")
    assert o["trt_fp16_enable"] is False and o["trt_int8_enable"] is False
    assert "trt_profile_min_shapes" not in o  # DeepLab is fully static: no profile
    o16 = seg["providers_fp16_engine"][0][1]
    assert o16["trt_fp16_enable"] is True and o16["trt_engine_cache_path"] != o["trt_engine_cache_path"]
    q = m["roles"]["vlm"]["variants"]["int8-qdq"]["jetson"]["components"]["decoder"]
    oq = q["providers"][0][1]
    assert oq["trt_int8_enable"] is True and "trt_int8_calibration_table_name" not in oq
    assert q["qdq"]["trt_int8_compatible"] is True and not q["warnings"]
    assert "--int8" in q["trtexec"] and not any(a.startswith("--calib") for a in q["trtexec"])
    # the TFLite SSD (the detector's ssd-fp32 variant) carries uint8 asymmetric Q/DQ: TensorRT cannot take it,
    # and the manifest says so
    det = m["roles"]["detector"]["variants"]["ssd-fp32"]["jetson"]["components"]["model"]
    assert det["qdq"]["qdq"] and not det["qdq"]["trt_int8_compatible"]
    assert det["warnings"] and "symmetric int8" in det["warnings"][0]
    # ... so neither the provider options nor the build script ask TensorRT for int8 on it
    assert det["providers"][0][1]["trt_int8_enable"] is False and det["trtexec"] is None
    script = (root / J.SCRIPT).read_text()
    assert "detector/ssd-fp32/model: no engine" in script
    assert all("--int8" not in ln for ln in script.splitlines() if "/detector/" in ln)
    assert m["jetson"]["provider_chain"][0] == "TensorrtExecutionProvider"
    assert "not installed" in m["jetson"]["not_run"]
    B.load_bundle(root, verify=True)


def test_trtexec_commands_match_provider_options(bundle):
    root, _ = bundle
    m = json.loads((root / "manifest.json").read_text())
    jc = m["roles"]["vlm"]["variants"]["fp32"]["jetson"]["components"]["decoder"]
    argv, opts = jc["trtexec"], jc["providers"][0][1]
    flags = dict(a[2:].split("=", 1) for a in argv[1:] if "=" in a)
    assert argv[0] == "trtexec"
    assert flags["onnx"] == "/bundle/" + m["roles"]["vlm"]["variants"]["fp32"]["components"]["decoder"]["file"]
    for k in ("min", "opt", "max"):
        assert _parse_shapes(flags[f"{k}Shapes"]) == _parse_shapes(opts[f"trt_profile_{k}_shapes"])
    assert flags["memPoolSize"] == "workspace:2048M"
    assert "--fp16" not in argv and "--int8" not in argv


def test_build_script_runs_with_stand_in_trtexec(bundle, tmp_path, shellcheck):
    root, _ = bundle
    script = root / J.SCRIPT
    subprocess.run(["bash", "-n", str(script)], check=True)
    r = subprocess.run([shellcheck, str(script)], capture_output=True, text=True)
    assert r.returncode == 0, r.stdout
    fake = tmp_path / "bin" / "trtexec"
    fake.parent.mkdir()
    # stand-in: checks the ONNX path exists and the shape flags are well formed, then "writes" the engine
    fake.write_text('#!/usr/bin/env bash\nset -e\nfor a in "$@"; do case "$a" in\n'
                    '  --onnx=*) test -f "${a#--onnx=}" || { echo "missing ${a#--onnx=}" >&2; exit 3; } ;;\n'
                    '  --saveEngine=*) engine="${a#--saveEngine=}" ;;\n'
                    '  --minShapes=*|--optShapes=*|--maxShapes=*) [[ "${a#*=}" =~ ^([A-Za-z0-9_.]+:[0-9x]+,?)+$ ]]'
                    ' || { echo "bad $a" >&2; exit 4; } ;;\nesac; done\necho "$*" > "$engine"\n')
    fake.chmod(fake.stat().st_mode | stat.S_IEXEC)
    cache = tmp_path / "cache"
    env = {**os.environ, "PATH": f"{fake.parent}{os.pathsep}{os.environ['PATH']}", "BUNDLE": str(root),
           "CACHE": str(cache)}
    r = subprocess.run(["bash", str(script)], capture_output=True, text=True, env=env)
    assert r.returncode == 0, r.stderr
    engines = sorted(p.relative_to(cache).as_posix() for p in cache.rglob("*.engine"))
    assert "vlm/fp32/decoder.engine" in engines and "segmenter/fp32-trtfp16/model.engine" in engines
    assert "detector/ssd-fp32/model.engine" not in engines and "vlm/int8-qdq/decoder.engine" in engines
    assert "detector/fp32/model.engine" in engines  # YOLOX-Nano, float: TensorRT takes it


def test_runtime_takes_the_provider_chain(bundle):
    """runtime/infra/providers.py accepts the manifest's [name, options] chain; here (no GPU) it ends on CPU and
    records why."""
    from mosaicthinker.runtime.infra.providers import create_session
    from mosaicthinker.runtime.infra.trace import Trace

    root, _ = bundle
    m = json.loads((root / "manifest.json").read_text())
    v = m["roles"]["segmenter"]["variants"]["fp32"]
    tr = Trace()
    s = create_session(root / v["components"]["model"]["file"], "segmenter",
                       v["jetson"]["components"]["model"]["providers"], trace=tr, threads=1)
    out = s.run({"sub_7": np.zeros((1, 257, 257, 3), np.float32)})
    assert out[0].shape == (1, 257, 257, 21)
    d = tr.to_dict()
    assert "TensorrtExecutionProvider" in json.dumps(d)
    assert tr.providers["segmenter"]["used"] == "CPUExecutionProvider"


def test_axis_rules_and_errors():
    role = {"preprocessing": {"size": [8, 8], "layout": "NCHW"}, "arch": "x", "config": {}}
    inp = [{"name": "feat", "shape": [1, 0], "dtype": "float32", "dynamic_axes": {"1": "mystery"}}]
    with pytest.raises(ExportError, match="--axis mystery=MIN:OPT:MAX"):
        J.profile_shapes(inp, role, J.JetsonConfig())
    prof = J.profile_shapes(inp, role, J.JetsonConfig(overrides={"mystery": (2, 5, 9)}))
    assert prof == {"min": {"feat": [1, 2]}, "opt": {"feat": [1, 5]}, "max": {"feat": [1, 9]}}
    with pytest.raises(ExportError, match="min <= opt <= max"):
        J.profile_shapes(inp, role, J.JetsonConfig(overrides={"mystery": (5, 2, 9)}))
    assert J.shape_string({"a": [1, 3], "b": [2]}) == "a:1x3,b:2"
    with pytest.raises(ExportError, match="cannot express"):
        J.shape_string({"a,b": [1]})
    import argparse

    args = argparse.Namespace(axis=["mystery=1:2:3"], trt_cache="/c", trt_workspace_mb=512, dla_core=0,
                              jetson_roles=None)
    conf = J.config_from_args(args)
    assert conf.overrides == {"mystery": (1, 2, 3)} and conf.dla_core == 0
    o = J.trt_provider_options("r", "fp16", "m", "fp16", {"min": {}}, conf)
    assert o["trt_dla_enable"] is True and o["trt_max_workspace_size"] == 512 * 2**20
    assert "--useDLACore=0" in J.trtexec_command("r/fp16/m.onnx", "r", "fp16", "m", "fp16", {"min": {}}, conf)
    with pytest.raises(ExportError, match="NAME=MIN:OPT:MAX"):
        J.config_from_args(argparse.Namespace(axis=["x=1:2"]))


def test_container_recipe_and_run_script(bundle, shellcheck):
    repo = Path(__file__).resolve().parents[1]
    run = repo / "jetson" / "run.sh"
    subprocess.run(["bash", "-n", str(run)], check=True)
    r = subprocess.run([shellcheck, str(run)], capture_output=True, text=True)
    assert r.returncode == 0, r.stdout
    root, _ = bundle
    r = subprocess.run(["bash", str(run), "--dry-run", "--cache", "/tmp/trt", str(root), "--", "profile",
                        "--bundle", "/bundle"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    line = r.stdout.strip()
    assert line.startswith("docker run --rm --runtime nvidia") and f"{root.resolve()}:/bundle:ro" in line
    assert "/tmp/trt:/cache" in line and line.endswith("profile --bundle /bundle")
    r = subprocess.run(["bash", str(run), "--dry-run", "--build-engines", str(root)], capture_output=True,
                       text=True)
    assert r.returncode == 0 and "/bundle/jetson/build_engines.sh" in r.stdout
    r = subprocess.run(["bash", str(run), "--dry-run", str(root / "nope")], capture_output=True, text=True)
    assert r.returncode == 2 and "manifest.json" in r.stderr
    # the container's cache and bundle mounts are the paths the provider options point at
    m = json.loads((root / "manifest.json").read_text())
    assert m["jetson"]["cache_dir"] == "/cache/trt" and m["jetson"]["bundle_dir"] == "/bundle"
    docker = (repo / "jetson" / "Dockerfile").read_text()
    assert "FROM ${L4T_JETPACK}" in docker and "l4t-jetpack:r36" in docker
    code = "\n".join(ln for ln in docker.splitlines() if not ln.lstrip().startswith("#"))
    assert "onnxruntime-gpu" in code and "TensorrtExecutionProvider" in code and "torch" not in code
    assert "pip install ." in code and "[export]" not in code  # runtime only


def test_kv_cache_axis_is_not_mistaken_for_an_image_axis():
    """A one-head KV cache [1, 1, past, d] has the 4-D shape of a 1-channel image: its past axis must get the
    KV-cache range, not the image size (one axis classifier serves the Android and Jetson steps)."""
    from mosaicthinker.export import common as C

    meta = {"arch": "smolvlm", "preprocessing": {"size": [32, 32], "layout": "NCHW"}, "config": {}}
    inp = {"name": "past_key_0", "shape": [1, 1, 0, 8], "dtype": "float32", "dynamic_axes": {"2": "past"}}
    assert C.axis_kind("past", inp, 2, meta) == "past"
    img = {"name": "pixel_values", "shape": [1, 3, 32, 32], "dtype": "float32", "dynamic_axes": {"2": "h"}}
    assert C.axis_kind("h", img, 2, meta) == "image"


def test_export_target_step_honours_jetson_roles_and_says_what_it_wrote(bundle, tmp_path, capsys):
    import argparse

    root, _ = bundle
    copy = tmp_path / "bundle"
    shutil.copytree(root, copy)
    res = J.target_step(copy, ["detector", "segmenter", "vlm"], argparse.Namespace(jetson_roles="segmenter"))
    assert sorted(res["roles"]) == ["segmenter"]
    err = capsys.readouterr().err
    assert "jetson settings written into" in err and "segmenter/fp32/model: trtexec" in err and J.SCRIPT in err
    res = J.target_step(copy, ["segmenter", "vlm"], argparse.Namespace())  # no --jetson-roles: the exported ones
    assert sorted(res["roles"]) == ["segmenter", "vlm"]


def test_one_target_entry_runs_the_step_on_an_existing_bundle(bundle, tmp_path):
    """`mosaic export --target jetson --out B` without a ROLE: the step alone, on every role of B (the one
    entry that replaced `python -m mosaicthinker.export.jetson B`)."""
    import sys

    root, _ = bundle
    copy = tmp_path / "bundle"
    shutil.copytree(root, copy)
    (copy / J.SCRIPT).unlink()
    m = json.loads((copy / "manifest.json").read_text())
    for rm in m["roles"].values():
        rm.pop("jetson", None)
        for vm in rm["variants"].values():
            vm.pop("jetson", None)
    m.pop("jetson", None)
    (copy / "manifest.json").write_text(json.dumps(m))
    exe = Path(sys.executable).with_name("mosaic")
    r = subprocess.run([str(exe), "export", "--target", "jetson", "--out", str(copy), "--json"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    res = json.loads(r.stdout)
    assert res["roles"] == {} and sorted(res["targets"]["jetson"]["roles"]) == ["detector", "segmenter", "vlm"]
    m2 = json.loads((copy / "manifest.json").read_text())
    assert (copy / J.SCRIPT).is_file() and m2["jetson"]["build_engines"]["file"] == J.SCRIPT
    assert all("jetson" in m2["roles"][r] for r in ("detector", "segmenter", "vlm"))
    bad = subprocess.run([str(exe), "export", "--target", "tpu", "--out", str(copy)], capture_output=True,
                         text=True, timeout=300)
    assert bad.returncode != 0 and "--target tpu" in bad.stderr
