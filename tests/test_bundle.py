"""Bundle schema: writing, verify/show, and the refusals (tampered file, escaping paths, unknown schema, missing
file or field). Bundles are built in tmp_path with a tiny hand-made ONNX graph (no model download)."""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from mosaicthinker.host import bundle_write as BW
from mosaicthinker.runtime.infra import bundle as B
from mosaicthinker.runtime.infra.errors import BundleError, ExportError

onnx = pytest.importorskip("onnx")  # the export extra (CI installs it)

pytestmark = [pytest.mark.export]



def _tiny_graph(path: Path, scale: float = 2.0) -> Path:
    """y = x * scale, x: [1, 4] float32 (dynamic batch)."""
    from onnx import TensorProto as T
    from onnx import helper as h

    w = h.make_tensor("w", T.FLOAT, [1], [scale])
    g = h.make_graph([h.make_node("Mul", ["x", "w"], ["y"])], "tiny",
                     [h.make_tensor_value_info("x", T.FLOAT, ["batch", 4])],
                     [h.make_tensor_value_info("y", T.FLOAT, ["batch", 4])], [w])
    m = h.make_model(g, opset_imports=[h.make_opsetid("", 18)])
    m.ir_version = 9
    onnx.save(m, str(path))
    return path


def _meta(random_weights: bool = False) -> dict:
    from mosaicthinker.export.common import role_meta

    return role_meta("embedding_generic", preprocessing={}, semantics={"dim": 4},
                     provenance={"source": "test:tiny"}, licence="Apache-2.0", random_weights=random_weights)


@pytest.fixture()
def tiny_bundle(tmp_path: Path) -> Path:
    from mosaicthinker.export.common import add_variant_files

    out = tmp_path / "bundle"
    g = _tiny_graph(tmp_path / "g.onnx")
    add_variant_files(out, "embedder", "fp32", {"model": g}, meta=_meta(), precision="fp32",
                      parity={"model": {"ok": True}})
    return out


def test_written_manifest_has_schema_io_and_reserved_fields(tiny_bundle: Path):
    m = json.loads((tiny_bundle / "manifest.json").read_text())
    assert m["schema"] == B.SCHEMA
    role = m["roles"]["embedder"]
    assert role["licence"] == "Apache-2.0" and role["random_weights"] is False
    assert "android" in role and "jetson" in role and "android" in m and "jetson" in m
    comp = role["variants"]["fp32"]["components"]["model"]
    assert comp["file"] == "embedder/fp32/model.onnx"
    assert comp["sha256"] == B.sha256_file(tiny_bundle / comp["file"])
    assert comp["opset"] == 18
    assert comp["inputs"][0]["name"] == "x" and comp["inputs"][0]["dynamic_axes"] == {"0": "batch"}
    assert comp["outputs"][0]["dtype"] == "float32"
    assert "android" in role["variants"]["fp32"] and "jetson" in role["variants"]["fp32"]
    b = B.load_bundle(tiny_bundle)
    assert b.verify()["files"] == 1
    spec = b.spec("embedder")
    assert spec.variant == "fp32" and spec.component("model").path.is_file()


def test_tampered_file_is_refused(tiny_bundle: Path):
    f = tiny_bundle / "embedder" / "fp32" / "model.onnx"
    data = bytearray(f.read_bytes())
    data[-1] ^= 0xFF
    f.write_bytes(bytes(data))
    with pytest.raises(BundleError, match=r"model\.onnx: sha256 mismatch"):
        B.load_bundle(tiny_bundle)
    from mosaicthinker.runtime.models import load_role

    with pytest.raises(BundleError, match="sha256 mismatch"):
        load_role(tiny_bundle, "embedder")


@pytest.mark.parametrize("bad", ["/etc/passwd", "../outside.onnx", "embedder/../../outside.onnx", "C:/x.onnx"])
def test_escaping_paths_are_refused(tiny_bundle: Path, bad: str):
    mp = tiny_bundle / "manifest.json"
    m = json.loads(mp.read_text())
    m["roles"]["embedder"]["variants"]["fp32"]["components"]["model"]["file"] = bad
    mp.write_text(json.dumps(m))
    with pytest.raises(BundleError, match="components.model.file"):
        B.load_bundle(tiny_bundle)


def test_symlink_escape_is_refused(tiny_bundle: Path, tmp_path: Path):
    outside = tmp_path / "outside.onnx"
    shutil.copyfile(tiny_bundle / "embedder" / "fp32" / "model.onnx", outside)
    link = tiny_bundle / "embedder" / "fp32" / "link.onnx"
    os.symlink(outside, link)
    mp = tiny_bundle / "manifest.json"
    m = json.loads(mp.read_text())
    m["roles"]["embedder"]["variants"]["fp32"]["components"]["model"]["file"] = "embedder/fp32/link.onnx"
    mp.write_text(json.dumps(m))
    with pytest.raises(BundleError, match="symlink escape"):
        B.load_bundle(tiny_bundle)


def test_unknown_schema_missing_field_and_missing_file(tiny_bundle: Path):
    mp = tiny_bundle / "manifest.json"
    good = mp.read_text()
    m = json.loads(good)
    m["schema"] = "mosaicthinker.bundle/99"
    mp.write_text(json.dumps(m))
    with pytest.raises(BundleError, match="unknown schema version 'mosaicthinker.bundle/99'"):
        B.load_bundle(tiny_bundle)
    m = json.loads(good)
    del m["roles"]["embedder"]["licence"]
    mp.write_text(json.dumps(m))
    with pytest.raises(BundleError, match=r"roles\.embedder\.licence is missing"):
        B.load_bundle(tiny_bundle)
    mp.write_text(good)
    (tiny_bundle / "embedder" / "fp32" / "model.onnx").unlink()
    with pytest.raises(BundleError, match="is missing"):
        B.load_bundle(tiny_bundle)
    with pytest.raises(BundleError, match="manifest.json is missing"):
        B.load_bundle(tiny_bundle / "embedder")


def test_reserved_target_files_are_verified_too(tiny_bundle: Path):
    """Android/Jetson additions ({file, sha256} anywhere in the manifest) are hash-checked without a schema change."""
    mp = tiny_bundle / "manifest.json"
    m = json.loads(mp.read_text())
    extra = tiny_bundle / "embedder" / "android" / "model.ort"
    extra.parent.mkdir(parents=True)
    extra.write_bytes(b"not really an ort file")
    m["roles"]["embedder"]["variants"]["fp32"]["android"] = {
        "ort": {"file": "embedder/android/model.ort", "sha256": B.sha256_file(extra)}}
    mp.write_text(json.dumps(m))
    assert B.load_bundle(tiny_bundle).verify()["files"] == 2
    extra.write_bytes(b"changed")
    with pytest.raises(BundleError, match=r"variants\.fp32\.android\.ort"):
        B.load_bundle(tiny_bundle)


def test_cli_verify_and_show(tiny_bundle: Path):
    cmd = [sys.executable, "-m", "mosaicthinker.runtime.cli"]
    out = subprocess.run(cmd + ["bundle", "verify", str(tiny_bundle), "--json"], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    res = json.loads(out.stdout)
    assert res["ok"] and res["files"] == 1 and res["roles"] == {"embedder": ["fp32"]}
    out = subprocess.run(cmd + ["bundle", "show", str(tiny_bundle)], capture_output=True, text=True)
    assert out.returncode == 0 and "[embedder] arch=embedding_generic" in out.stdout and "x[batch,4]" in out.stdout
    (tiny_bundle / "embedder" / "fp32" / "model.onnx").write_bytes(b"tampered")
    out = subprocess.run(cmd + ["bundle", "verify", str(tiny_bundle)], capture_output=True, text=True)
    assert out.returncode == 2 and "sha256 mismatch" in out.stderr


def test_random_weights_warn_loudly(tmp_path: Path):
    from mosaicthinker.export.common import add_variant_files
    from mosaicthinker.runtime.models import load_role
    from mosaicthinker.runtime.infra.trace import Trace

    out = tmp_path / "b"
    add_variant_files(out, "embedder", "fp32", {"model": _tiny_graph(tmp_path / "g.onnx")},
                      meta=_meta(random_weights=True), precision="fp32")
    tr = Trace()
    with pytest.warns(RuntimeWarning, match="RANDOM weights"):
        emb = load_role(out, "embedder", trace=tr)
    assert tr.random_weights_used and any(e["kind"] == "random_weights" for e in tr.events)
    v = emb.session().run({"x": np.ones((1, 4), np.float32)})[0]
    assert np.allclose(v, 2.0)


def test_onnx_import_with_sidecar_and_precisions(tmp_path: Path):
    """`mosaic export ROLE --source onnx:PATH --meta FILE` imports, converts fp16/int8-dynamic with parity."""
    from mosaicthinker.runtime.cli import main

    g = _tiny_graph(tmp_path / "g.onnx", scale=3.0)
    side = tmp_path / "meta.json"
    side.write_text(json.dumps({"arch": "embedding_generic", "licence": "MIT", "preprocessing": {},
                                "semantics": {"dim": 4}}))
    out = tmp_path / "b"
    args = ["export", "embedder", "--source", f"onnx:{g}", "--meta", str(side), "--precision", "fp32,fp16",
            "--out", str(out), "--json"]
    assert main(args) == 2  # the sidecar does not say whether the weights are real: refused
    assert not (out / "manifest.json").exists()
    rc = main(args + ["--real-weights"])
    assert rc == 0
    b = B.load_bundle(out)
    role = b.role_meta("embedder")
    assert sorted(role["variants"]) == ["fp16", "fp32"]
    assert role["provenance"]["sha256"] == B.sha256_file(g)
    assert role["variants"]["fp16"]["parity"]["model"]["ok"]
    assert role["variants"]["fp16"]["parity"]["model"]["inputs"] == "fresh random"
    with pytest.raises(BundleError, match="no variant 'int8-qdq'"):
        b.spec("embedder", "int8-qdq")


def test_failing_parity_fails_the_export(tmp_path: Path):
    from mosaicthinker.export.common import parity_check, parse_precisions

    g = _tiny_graph(tmp_path / "g.onnx", scale=2.0)
    mk = lambda rng: {"x": rng.random((1, 4), dtype=np.float32)}  # noqa: E731
    ok = parity_check(g, lambda f: [f["x"] * 2.0], mk)
    assert ok["ok"] and ok["worst"]["rel"] < 1e-6 and ok["seed"] != parity_check(g, lambda f: [f["x"] * 2], mk)["seed"]
    with pytest.raises(ExportError, match="parity check failed"):
        parity_check(g, lambda f: [f["x"] * 2.1], mk)
    assert parse_precisions("fp16,int8") == ["fp32", "fp16", "int8-dynamic", "int8-qdq"]
    with pytest.raises(ExportError, match="unknown precision"):
        parse_precisions("int3")


def test_export_output_is_a_table_of_shipped_and_refused_with_library_noise_hidden(tmp_path: Path, capsys):
    """`mosaic export` prints one row per variant (shipped / REFUSED and why, long reasons wrapped at spaces,
    never cut); the quantiser's root-logger warnings are hidden and counted, our own lines stay."""
    from mosaicthinker.export.cli import render
    from mosaicthinker.runtime.cli import main

    code = ("import logging, warnings\n"
            "from mosaicthinker.export.cli import library_noise_hidden\n"
            "counts = {}\n"
            "with library_noise_hidden(counts):\n"
            "    logging.basicConfig()\n"
            "    for _ in range(3):\n"
            "        logging.warning(\"Expected bias 'conv/bias_dequant' to be an initializer\")\n"
            "    warnings.warn_explicit('a library warning', UserWarning, '/x/site-packages/torchvision/io.py', 1)\n"
            "    warnings.warn('our own warning', RuntimeWarning)\n"
            "logging.warning('after the export')\n"
            "print(counts)\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "{'log': 3, 'warnings': 1}"
    assert "Expected bias" not in r.stderr and "a library warning" not in r.stderr
    assert "our own warning" in r.stderr and "after the export" in r.stderr  # only hidden inside

    long_reason = "parity vs fp32 failed: " + " ".join(f"word{i}" for i in range(60))
    text = render({"bundle": "B", "roles": {"detector": {
        "variants": {"fp32": {"ok": True, "copied": True},
                     "int8-qdq": {"worst": {"rel": 0.05, "cosine": 0.999}, "tolerance": {"rel": 0.15}}},
        "skipped": {"fp16": long_reason}}}, "bundle_roles": {"detector": ["fp32", "int8-qdq"]},
        "library_messages_hidden": {"log": 3}})
    rows = text.splitlines()
    assert rows[1].split() == ["role", "variant", "result", "parity", "/", "why"]
    assert rows[2].split()[:3] == ["detector", "fp32", "shipped"] and "rel 0.05 (tol 0.15)" in rows[3]
    refused = rows[4:][:[i for i, r in enumerate(rows[4:]) if "bundle now has" in r][0]]
    assert refused[0].split()[:3] == ["detector", "fp16", "REFUSED"]
    assert " ".join(" ".join(refused).split()[3:]) == long_reason  # all of it, wrapped only at spaces
    assert "3 library log line(s)" in rows[-1]

    # the real command: a refused variant (int8 of a one-Mul graph has nothing to quantise -> parity fails or it
    # is shipped; either way a row) and no root-logger noise on stderr
    g = _tiny_graph(tmp_path / "g.onnx", scale=3.0)
    side = tmp_path / "meta.json"
    side.write_text(json.dumps({"arch": "embedding_generic", "licence": "MIT", "preprocessing": {},
                                "semantics": {"dim": 4}, "random_weights": True}))
    rc = main(["export", "embedder", "--source", f"onnx:{g}", "--meta", str(side), "--precision", "fp32,fp16",
               "--out", str(tmp_path / "b")])
    out = capsys.readouterr()
    assert rc == 0 and "WARNING:root" not in out.err
    assert [r.split()[:3] for r in out.out.splitlines()[2:4]] == [["embedder", "fp32", "shipped"],
                                                                  ["embedder", "fp16", "shipped"]]


def test_bundle_show_never_cuts_parity_or_notes(tiny_bundle: Path):
    from mosaicthinker.export.common import record_skipped_variant

    m = B.read_manifest(tiny_bundle)
    vm = m["roles"]["embedder"]["variants"]["fp32"]
    vm["parity"] = {"model": {"ok": True, "worst": {"rel": 0.0123, "cosine": 0.99987}, "tolerance": {"rel": 0.02},
                              "outputs": [{"name": f"output_{i}", "rel": 0.01} for i in range(40)]}}
    vm["notes"] = " ".join(f"note{i}" for i in range(80))
    BW.write_manifest(tiny_bundle, m)
    record_skipped_variant(tiny_bundle, "embedder", "int8-qdq", " ".join(f"why{i}" for i in range(70)))
    r = subprocess.run([sys.executable, "-m", "mosaicthinker.runtime.cli", "bundle", "show", str(tiny_bundle)],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    words = r.stdout.split()
    assert "rel 0.0123 (tol 0.02), cosine 0.9999" in " ".join(words)
    assert all(f"note{i}" in words for i in range(80)) and all(f"why{i}" in words for i in range(70))
    assert "NOT shipped:" in r.stdout and max(len(ln) for ln in r.stdout.splitlines()) < 140


def test_the_documented_onnx_sidecar_example_imports(tmp_path: Path, shared_models: Path, capsys):
    """The sidecar JSON of docs/bundle-and-adapters.md imports the real embedding model as documented."""
    import re

    from mosaicthinker.runtime.cli import main

    doc = (Path(__file__).resolve().parents[1] / "docs" / "bundle-and-adapters.md").read_text()
    sec = doc[doc.index("### The `onnx:` metadata sidecar"):]
    side = tmp_path / "embedder.mosaic.json"
    side.write_text(re.search(r"```json\n(.*?)```", sec, re.S).group(1))
    model = shared_models / "mobilenet-v1-embedding" / "mobilenet_v1_embedding.onnx"
    rc = main(["export", "embedder", "--source", f"onnx:{model}", "--meta", str(side), "--precision", "fp32",
               "--out", str(tmp_path / "B")])
    assert rc == 0
    role = B.load_bundle(tmp_path / "B").role_meta("embedder")
    assert role["arch"] == "mobilenet_embedding" and role["semantics"]["dim"] == 1024
    assert role["provenance"]["sha256"] == B.sha256_file(model) and "already int8" in role["variants"]["fp32"]["notes"]
    bad = json.loads(side.read_text())
    del bad["semantics"]
    side.write_text(json.dumps(bad))
    capsys.readouterr()
    rc = main(["export", "embedder", "--source", f"onnx:{model}", "--meta", str(side), "--out", str(tmp_path / "C")])
    err = capsys.readouterr().err
    assert rc == 2 and err.startswith("error:") and str(side) in err and "'semantics'" in err
