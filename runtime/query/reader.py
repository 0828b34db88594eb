"""The trained reader at run time: all-MiniLM-L6-v2 + a kind head and a role tagger, int8 ONNX, run with
onnxruntime and tokenizers (no torch). `ModelReader.read(question)` -> `Reading` (the kind, word spans with their
roles, and the reader's confidence in each); `embed(texts)` -> the encoder's sentence embeddings (names by meaning).

Where it comes from: a bundle's `reader` role (`mosaic export reader`), or a folder holding `model.onnx`,
`tokenizer.json` and `reader.json`; `MOSAIC_READER` names one for processes that are given no bundle
(`default_reader`). The programs are composed from a `Reading` by `query.compose`.
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..infra.bundle import Bundle, load_bundle
from ..infra.errors import BundleError
from .reader_spec import KINDS, MAX_TOKENS, SPEC_VERSION, TAGS


@dataclass(frozen=True)
class Span:
    """Words of the question with one role: text as written, the character range, the reader's confidence (the
    least probability of its word pieces' tags)."""

    role: str
    text: str
    start: int
    end: int
    confidence: float


@dataclass
class Reading:
    """What the reader read: kind (one of `KINDS`) and its probability, the spans in question order, and whether
    the question was longer than the reader reads (`truncated`: refused by the composer)."""

    kind: str
    kind_confidence: float
    spans: list[Span] = field(default_factory=list)
    truncated: bool = False
    runner_up: tuple[str, float] = ("", 0.0)

    def of(self, role: str) -> list[Span]:
        return [s for s in self.spans if s.role == role]


def _softmax(x: np.ndarray) -> np.ndarray:
    e = np.exp(x - x.max(-1, keepdims=True))
    return e / e.sum(-1, keepdims=True)


# each tag's partner of the same role (B-X <-> I-X; "O" has none)
_PAIR = [TAGS.index(("I-" if t.startswith("B-") else "B-") + t[2:]) if t != "O" else -1 for t in TAGS]


def decode_spans(text: str, offsets: list[tuple[int, int]], probs: np.ndarray) -> list[Span]:
    """BIO tags of word pieces -> spans. offsets: [T] character ranges (special tokens (0, 0)); probs: [T, L]
    tag probabilities. A word (pieces with no gap between letters) takes its first piece's tag, as in training;
    a word continues a span when its tag is I- of the span's role. A span's confidence: its words' least
    probability of the span's role."""
    words: list[list[Any]] = []  # [start, end, tag id, prob]
    for (a, b), row in zip(offsets, probs):
        if a == b:
            continue
        if words and a == words[-1][1] and text[a - 1:a].isalnum() and text[a:a + 1].isalnum():
            words[-1][1] = b  # a later piece of the same word
            continue
        t = int(row.argmax())  # confidence: the probability of the role (B- and I- together), not of one tag
        words.append([a, b, t, float(row[t] + (row[_PAIR[t]] if _PAIR[t] >= 0 else 0.0))])
    spans: list[Span] = []
    cur: list[Any] | None = None  # [role, start, end, min prob]
    for a, b, t, p in words:
        tag = TAGS[t]
        if tag == "O":
            cur = _close(spans, cur, text)
        elif cur is not None and tag == "I-" + cur[0]:
            cur[2], cur[3] = b, min(cur[3], p)
        else:
            _close(spans, cur, text)
            cur = [tag[2:], a, b, p]
    _close(spans, cur, text)
    return spans


def _close(spans: list[Span], cur: list[Any] | None, text: str) -> None:
    if cur is not None:
        spans.append(Span(cur[0], text[cur[1]:cur[2]], cur[1], cur[2], round(cur[3], 4)))
    return None


class ModelReader:
    """One onnxruntime session over the reader graph (input_ids, attention_mask -> kind_logits, tag_logits,
    embedding) and its tokenizer. name: how the answers name it ("model")."""

    name = "model"

    def __init__(self, model: str | os.PathLike, tokenizer: str | os.PathLike, meta: dict[str, Any]):
        import onnxruntime as ort
        from tokenizers import Tokenizer

        if meta.get("spec") != SPEC_VERSION or list(meta.get("kinds", [])) != list(KINDS) \
                or list(meta.get("tags", [])) != list(TAGS):
            raise BundleError(f"{model}: a reader for another spec ({meta.get('spec')}, kinds {meta.get('kinds')});"
                              f" re-export it with `mosaic export reader`")
        so = ort.SessionOptions()
        so.intra_op_num_threads = int(meta.get("threads", 1))
        so.inter_op_num_threads = 1
        self.session = ort.InferenceSession(str(model), so, providers=["CPUExecutionProvider"])
        self.tokenizer = Tokenizer.from_file(str(tokenizer))
        self.tokenizer.no_padding()
        self.tokenizer.no_truncation()
        self.meta = meta
        self.random_weights = bool(meta.get("random_weights", False))
        self._emb: dict[str, np.ndarray] = {}

    def _run(self, texts: list[str]) -> tuple[list[Any], np.ndarray, np.ndarray, np.ndarray]:
        encs = [self.tokenizer.encode(t) for t in texts]
        t = min(MAX_TOKENS, max(len(e.ids) for e in encs))
        ids = np.zeros((len(encs), t), np.int64)
        mask = np.zeros((len(encs), t), np.int64)
        for i, e in enumerate(encs):
            n = min(len(e.ids), t)
            ids[i, :n], mask[i, :n] = e.ids[:n], 1
            if len(e.ids) > t:  # cut: keep [SEP] at the end so the encoder reads a whole input
                ids[i, t - 1] = e.ids[-1]
        kind, tag, emb = self.session.run(None, {"input_ids": ids, "attention_mask": mask})
        return encs, kind, tag, emb

    def read(self, question: str) -> Reading:
        """The kind and the role spans of one question (`MAX_TOKENS` word pieces at most: truncated beyond)."""
        encs, kind, tag, _ = self._run([question])
        e = encs[0]
        pk = _softmax(kind[0].astype(np.float64))
        order = np.argsort(-pk)
        n = min(len(e.ids), MAX_TOKENS)
        spans = decode_spans(question, list(e.offsets[:n]), _softmax(tag[0, :n].astype(np.float64)))
        return Reading(KINDS[order[0]], round(float(pk[order[0]]), 4), spans, len(e.ids) > MAX_TOKENS,
                       (KINDS[order[1]], round(float(pk[order[1]]), 4)))

    def embed(self, texts: list[str]) -> np.ndarray:
        """[N, D] unit sentence embeddings of short texts (object names), cached per text."""
        todo = [t for t in dict.fromkeys(texts) if t not in self._emb]
        for s in range(0, len(todo), 32):
            chunk = todo[s:s + 32]
            _, _, _, emb = self._run(chunk)
            for t, v in zip(chunk, emb):
                self._emb[t] = v.astype(np.float32)
        return np.stack([self._emb[t] for t in texts]) if texts else np.zeros((0, 384), np.float32)


def load_reader(source: str | os.PathLike | Any, variant: str | None = None) -> ModelReader:
    """A reader from a bundle (its `reader` role) or a folder with model.onnx + tokenizer.json + reader.json."""
    if not isinstance(source, Bundle):
        p = Path(source)
        if (p / "reader.json").is_file():
            meta = json.loads((p / "reader.json").read_text())
            return ModelReader(p / "model.onnx", p / "tokenizer.json", meta)
        source = load_bundle(p, verify=False)
    spec = source.spec("reader", variant)  # checks the reader's own files' sha256
    meta = dict(spec.meta.get("config") or {})
    meta["random_weights"] = spec.random_weights
    tok = source.file(spec.meta.get("tokenizer"), "roles.reader.tokenizer")
    return ModelReader(spec.component("model").path, tok, meta)


_DEFAULT: dict[str, ModelReader | None] = {}


def default_reader() -> ModelReader | None:
    """The reader `MOSAIC_READER` names (a bundle or a reader folder), loaded once; None when unset."""
    src = os.environ.get("MOSAIC_READER", "").strip()
    if not src:
        return None
    if src not in _DEFAULT:
        _DEFAULT[src] = load_reader(src)
    return _DEFAULT[src]
