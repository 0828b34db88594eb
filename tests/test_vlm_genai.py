"""Qwen2.5-VL packaged for ONNX Runtime GenAI (pinned 0.18.0): a tiny random Qwen2.5-VL (real vocabulary size and
special-token ids) goes through `mosaic export vlm` (GenAI model builder decoder + the project's vision and
embedding graphs); the standard GenAI API must load the package as it is and generate from an image + prompt,
fp32 token for token equal to transformers' greedy generate on the same processor inputs; the manifest lists
every package file with its sha256; the runtime's VLM adapter drives the package with the same answer parsing."""
from __future__ import annotations


import numpy as np
import pytest

pytest.importorskip("torch")
pytest.importorskip("transformers")
og = pytest.importorskip("onnxruntime_genai")

pytestmark = [pytest.mark.export, pytest.mark.slow]
IMAGE = 224  # grid 16 x 16 patches -> 2 x 2 attention windows (window 112 px), 64 image tokens


@pytest.fixture(scope="module")
def qwen_bundle(tmp_path_factory):
    from mosaicthinker.export import cli
    from mosaicthinker.runtime.cli import build_parser

    out = tmp_path_factory.mktemp("qwen") / "b"
    args = build_parser(("export",), cli).parse_args(  # the command's own parser: every flag has its default
        ["vlm", "--source", "tiny:qwen2_5_vl", "--precision", "fp32,int4", "--set", f"image_size={IMAGE}",
         "--set", "check_tokens=6", "--out", str(out)])
    return out, cli.run(args)


def test_cli_result_and_manifest(qwen_bundle):
    from mosaicthinker.runtime.infra.bundle import load_bundle, sha256_file

    out, res = qwen_bundle
    assert res["bundle_roles"]["vlm"] == ["fp32", "int4"]
    rm = load_bundle(out).role_meta("vlm")
    assert rm["arch"] == "qwen2_5_vl" and rm["random_weights"] is True and rm["default_variant"] == "int4"
    for v in ("fp32", "int4"):
        vm = rm["variants"][v]
        pkg = out / vm["genai"]["package"]
        listed = {f["file"]: f["sha256"] for f in vm["genai"]["files"]}
        on_disk = {p.relative_to(out).as_posix() for p in pkg.rglob("*") if p.is_file()}
        assert set(listed) == on_disk  # every file, external data included
        assert all(sha256_file(out / f) == h for f, h in listed.items())
        assert any(f.endswith("decoder/model.onnx.data") for f in listed)
        assert vm["components"]["decoder"]["extra_files"][0]["file"].endswith("model.onnx.data")
    chk = rm["variants"]["fp32"]["task_check"]
    assert chk["ok"] and chk["token_agreement_vs_transformers"] == 1.0 and chk["logits_rel_err_vs_transformers"] < 1e-3
    assert chk["image_grid_thw"] == [1, IMAGE // 14, IMAGE // 14]
    assert chk["prompt_tokens"] > (IMAGE // 28) ** 2  # the image expanded to its merged-patch tokens
    assert 0 <= rm["variants"]["int4"]["task_check"]["kl_vs_fp32"] < 1.0


def test_int4_package_ships_int8_vision_and_embedding(qwen_bundle):
    """The int4 package's vision graph is int8 (the default vision_quant=dynamic: per-channel int8 weights,
    MatMulInteger) and its embedding table int8 (4x smaller than fp32), each with parity on fresh inputs vs fp32,
    and the int8 side alone (fp32 decoder) barely moves the next-token distribution."""
    import onnx

    from mosaicthinker.runtime.infra.bundle import load_bundle

    out, _ = qwen_bundle
    rm = load_bundle(out).role_meta("vlm")
    v4, v32 = rm["variants"]["int4"], rm["variants"]["fp32"]
    assert v4["genai"]["component_precision"] == {"decoder": "int4", "vision": "int8", "embedding": "int8"}
    assert v32["genai"]["component_precision"] == {"decoder": "fp32", "vision": "fp32", "embedding": "fp32"}
    vis = onnx.load(str(out / "vlm" / "int4" / "vision" / "model.onnx"), load_external_data=False)
    consts = {t.name for t in vis.graph.initializer}
    assert sum(n.op_type == "MatMulInteger" for n in vis.graph.node) >= 5 * 2 + 2  # 5 Linear per block + merger
    assert not any(n.op_type == "Gemm" or (n.op_type == "MatMul" and n.input[1] in consts) for n in vis.graph.node)
    emb = onnx.load(str(out / "vlm" / "int4" / "embedding" / "model.onnx"))
    dtypes = {t.data_type for t in emb.graph.initializer if len(t.dims) == 2 and t.dims[0] == 151936}
    assert dtypes == {onnx.TensorProto.INT8, onnx.TensorProto.FLOAT}  # int8 rows + fp32 block scales
    size = lambda v: sum((out / "vlm" / v / "embedding" / f).stat().st_size for f in ("model.onnx", "model.onnx.data"))
    assert size("int4") < 0.3 * size("fp32")
    for c in ("vision", "embedding"):
        par = v4["parity"][c]
        assert par["ok"] and par["inputs"] == "fresh random" and par["precision"] == "int8-dynamic"
        assert 0 < par["worst"]["rel"] < 0.15 and par["worst"]["cosine"] > 0.99
    side = v4["task_check"]["side_only"]
    assert 0 <= side["kl_vs_fp32"] < 1e-2


def test_tampered_package_file_is_refused(qwen_bundle, tmp_path):
    import shutil

    from mosaicthinker.runtime.infra.bundle import load_bundle
    from mosaicthinker.runtime.infra.errors import BundleError

    out, _ = qwen_bundle
    copy = tmp_path / "b"
    shutil.copytree(out, copy)
    p = copy / "vlm" / "int4" / "processor_config.json"
    p.write_text(p.read_text().replace('"width": 224', '"width": 448'))
    with pytest.raises(BundleError, match="sha256"):
        load_bundle(copy)


def test_standard_genai_api_generates_from_image_and_prompt(qwen_bundle, tmp_path):
    import cv2

    out, _ = qwen_bundle
    pkg = out / "vlm" / "int4"
    img = np.zeros((180, 260, 3), np.uint8)
    cv2.rectangle(img, (20, 30), (120, 150), (0, 0, 255), -1)
    cv2.imwrite(str(tmp_path / "m.png"), img)
    model = og.Model(str(pkg))
    proc = model.create_multimodal_processor()
    text = "<|im_start|>user\n<|vision_start|><|image_pad|><|vision_end|>Where is the box?<|im_end|>\n<|im_start|>assistant\n"
    inputs = proc(text, images=og.Images.open(str(tmp_path / "m.png")))
    ids = inputs["input_ids"].as_numpy().reshape(-1)
    assert int((ids == 151655).sum()) == (IMAGE // 28) ** 2
    assert inputs["pixel_values"].as_numpy().shape == ((IMAGE // 14) ** 2, 3 * 2 * 14 * 14)
    params = og.GeneratorParams(model)
    params.set_search_options(do_sample=False, max_length=ids.size + 5)
    gen = og.Generator(model, params)
    gen.set_inputs(inputs)
    new = []
    while len(new) < 5 and not gen.is_done():
        gen.generate_next_token()
        new.append(int(gen.get_next_tokens()[0]))
    assert len(new) == 5 and all(0 <= t < 151936 for t in new)


def test_runtime_adapter_drives_the_package(qwen_bundle, tmp_path):
    from mosaicthinker.export.hf_qwen_vl import genai_generate
    from mosaicthinker.runtime.answer import answer_with_vlm
    from mosaicthinker.runtime.models import load_role
    from mosaicthinker.runtime.models.vlm_genai import GenAIVLM
    from mosaicthinker.runtime.infra.trace import Trace

    out, _ = qwen_bundle
    trace = Trace()
    vlm = load_role(out, "vlm", variant="fp32", threads=2, trace=trace)
    assert isinstance(vlm, GenAIVLM) and vlm.sessions == {}
    rgb = np.full((200, 300, 3), 255, np.uint8)
    rgb[40:120, 50:170] = (200, 30, 30)
    ids = vlm.generate_ids([rgb], "How many chairs are there?", max_new_tokens=6)
    import cv2

    cv2.imwrite(str(tmp_path / "x.png"), rgb[..., ::-1])
    ref = genai_generate(out / "vlm" / "fp32", str(tmp_path / "x.png"), "How many chairs are there?", 6)["ids"]
    assert ids == ref  # the adapter feeds GenAI exactly what the export check fed it
    assert {"vlm.prefill", "vlm.decode"} <= set(trace.stages) and trace.decisions["vlm.genai"]["new_tokens"] == 6
    assert trace.random_weights_used  # random weights flagged
    ans = answer_with_vlm(vlm, "How many chairs?", None, "How many chairs?", [rgb], trace=trace)
    assert ans.status in ("ok", "unsupported")  # a random model's reply is parsed or reported, never invented
    if ans.status != "ok":
        assert any(e.get("kind") == "degraded" for e in trace.events)
    text_only = vlm.generate([], "Hello", max_new_tokens=3)
    assert isinstance(text_only, str)


def test_vlm_grounding_emits_a_schema_valid_program_for_200_questions(qwen_bundle):
    """Constrained decoding (LLGuidance with the program's JSON schema, query/vlm.py): the random-weight Qwen2.5-VL
    still emits a valid program for each of 200 questions of the repo's wording sets, and every raw reply also
    passes an independent JSON-schema validator (tests/test_query_golden.py), not only the product's reader."""
    import json

    from mosaicthinker.runtime.infra.bundle import load_bundle
    from mosaicthinker.runtime.query.schema import json_schema
    from mosaicthinker.runtime.query.vlm import ground_with_vlm
    from mosaicthinker.runtime.models import load_role
    from mosaicthinker.runtime.infra.trace import Trace
    from test_query_golden import validate, wording_sets

    out, _ = qwen_bundle
    from mosaicthinker.runtime.query.ir import SCHEMA_VERSION

    rm = load_bundle(out).role_meta("vlm")
    assert rm["variants"][rm["default_variant"]]["genai"]["guidance"] == {"json_schema": SCHEMA_VERSION}
    with pytest.warns(RuntimeWarning, match="RANDOM"):
        vlm = load_role(load_bundle(out), "vlm", trace=Trace())
    every = [q for qs in wording_sets().values() for q in qs]
    qs = every[::max(1, len(every) // 200)][:200]
    schema = json_schema("ask", profile="vlm")
    bad, kinds = [], set()
    for q in qs:
        t = Trace()
        pq = ground_with_vlm(vlm, q["question"], q.get("options"), [], t)
        reply = t.decisions.get("grounding.vlm_reply", "")
        errs = validate(json.loads(reply), schema) if pq.how == "vlm" else ["refused"]
        if errs:
            bad.append((q["question"][:60], pq.notes[-1:], errs[:2], reply[:80]))
        kinds.add(pq.qtype)
    assert len(qs) == 200 and not bad, bad[:3]
