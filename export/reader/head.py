"""The reader's trained head over the frozen encoder: one pre-norm transformer layer (written out in matmuls so
that it exports to plain ONNX), a kind classifier on [CLS] and a BIO tagger on every word piece; and the full
graph (encoder + head + the encoder's mean-pooled sentence embedding) that `mosaic export reader` writes.

The encoder stays frozen: its sentence embedding is then all-MiniLM-L6-v2's own, which names-by-meaning uses.
"""
from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from mosaicthinker.runtime.infra import jsonio
from mosaicthinker.runtime.query.reader_spec import KINDS, SPEC_VERSION, TAGS


@dataclass(frozen=True)
class HeadConfig:
    dim: int = 384
    heads: int = 6
    ffn: int = 768
    dropout: float = 0.1


class Head(nn.Module):
    """[B, T, D] encoder states + [B, T] mask -> kind logits [B, K], tag logits [B, T, L]."""

    def __init__(self, conf: HeadConfig = HeadConfig()):
        super().__init__()
        d = conf.dim
        self.conf = conf
        self.ln1, self.ln2, self.ln3 = nn.LayerNorm(d), nn.LayerNorm(d), nn.LayerNorm(d)
        self.qkv, self.proj = nn.Linear(d, 3 * d), nn.Linear(d, d)
        self.ff1, self.ff2 = nn.Linear(d, conf.ffn), nn.Linear(conf.ffn, d)
        self.drop = nn.Dropout(conf.dropout)
        self.kind = nn.Linear(d, len(KINDS))
        self.tag = nn.Linear(d, len(TAGS))

    def forward(self, x: torch.Tensor, mask: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        b, t, d = x.shape
        h = self.conf.heads
        q, k, v = self.qkv(self.ln1(x)).reshape(b, t, 3, h, d // h).permute(2, 0, 3, 1, 4)
        att = (q @ k.transpose(-1, -2)) / float(np.sqrt(d // h))
        att = att + (1.0 - mask[:, None, None, :].to(att.dtype)) * -1e4  # padding never attended
        y = (att.softmax(-1) @ v).transpose(1, 2).reshape(b, t, d)
        x = x + self.drop(self.proj(y))
        x = x + self.drop(self.ff2(torch.nn.functional.gelu(self.ff1(self.ln2(x)))))
        z = self.ln3(x)
        return self.kind(z[:, 0]), self.tag(z)


class Reader(nn.Module):
    """input_ids, attention_mask [B, T] int64 -> kind_logits [B, K], tag_logits [B, T, L], embedding [B, D]."""

    def __init__(self, encoder: nn.Module, head: Head):
        super().__init__()
        self.encoder, self.head = encoder, head

    def forward(self, input_ids: torch.Tensor, attention_mask: torch.Tensor):
        states = self.encoder(input_ids=input_ids, attention_mask=attention_mask).last_hidden_state
        kind, tag = self.head(states, attention_mask)
        m = attention_mask[..., None].to(states.dtype)
        emb = (states * m).sum(1) / m.sum(1).clamp(min=1.0)
        emb = emb / emb.norm(dim=-1, keepdim=True).clamp(min=1e-9)
        return kind, tag, emb


def save_head(head: Head, folder: Path, info: dict[str, Any]) -> Path:
    """The head as float16 arrays (`head.npz`, small enough to commit) and `head.json` (kinds, tags, config,
    training figures). Written atomically."""
    folder.mkdir(parents=True, exist_ok=True)
    arrays = {k: v.detach().cpu().numpy().astype(np.float16) for k, v in head.state_dict().items()}
    tmp = folder / "head.npz.tmp.npz"
    np.savez_compressed(tmp, **arrays)
    tmp.replace(folder / "head.npz")
    meta = {"spec": SPEC_VERSION, "kinds": list(KINDS), "tags": list(TAGS), "config": asdict(head.conf), **info}
    tj = folder / "head.json.tmp"
    tj.write_text(jsonio.dumps(meta, indent=1, sort_keys=True) + "\n")
    tj.replace(folder / "head.json")
    return folder / "head.npz"


def load_head(folder: Path) -> tuple[Head, dict[str, Any]]:
    meta = json.loads((folder / "head.json").read_text())
    if meta.get("spec") != SPEC_VERSION or meta.get("kinds") != list(KINDS) or meta.get("tags") != list(TAGS):
        raise ValueError(f"{folder}/head.json: trained for another reader spec ({meta.get('spec')}); retrain it")
    head = Head(HeadConfig(**meta["config"]))
    with np.load(folder / "head.npz") as z:
        head.load_state_dict({k: torch.from_numpy(z[k].astype(np.float32)) for k in z.files})
    head.eval()
    return head, meta
