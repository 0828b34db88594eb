"""OWLv2 open-vocabulary detector: image branch and text branch as separate graphs, so a new object name
costs one text pass (the runtime caches the text embedding per name) and a frame costs one image pass.

Components (runtime adapter: runtime/models/owlv2.py):
- image: `pixel_values [B, 3, S, S] float32` (padded to a square bottom/right with grey 0.5, resized to S,
  CLIP mean/std) -> `class_embeds [B, P, D]` (unit norm), `logit_shift [B, P, 1]`, `logit_scale [B, P, 1]`
  (ELU + 1 applied), `pred_boxes [B, P, 4]` (cx, cy, w, h in [0, 1] of the padded square), `objectness [B, P]`
  (logits). P = (S / patch)^2 patch tokens.
- text: `input_ids [Q, L] int64`, `attention_mask [Q, L] int64` (L = the text tower's 16 positions;
  start token, name tokens, end token, pad 0) -> `text_embeds [Q, D]` (unit norm).
Score of name q at patch p: sigmoid((class_embeds[p] . text_embeds[q] + shift[p]) * scale[p]) (the class head
of `Owlv2ForObjectDetection`, split at the dot product).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

import numpy as np

from mosaicthinker.runtime.infra.errors import ExportError

from . import common as C
from .hf_common import CLIP_MEAN, CLIP_STD, GraphSpec, export_variants, run_exporter, word_level_tokenizer, write_tokenizer
from .sources import load_source

HF_DEFAULTS = {"owlv2": "google/owlv2-base-patch16-ensemble"}
TINY_WORDS = ("a photo of the chair table sofa bed tv door window sink fridge lamp plant oven microwave "
               "toilet car person cup bottle bowl book clock vase laptop keyboard mouse phone bag bench "
               "stool desk shelf cabinet counter pillow rug picture mirror").split()


def build_tiny_tokenizer(path: str | Path, vocab_size: int) -> Path:
    """WordLevel tokenizer.json for the tiny OWLv2: pad 0, [UNK] 1, words, start = vocab-2, end = vocab-1
    (the text tower pools at argmax(input_ids), i.e. at the end token, as with CLIP's vocabulary)."""
    vocab = {"!": 0, "[UNK]": 1}
    for w in TINY_WORDS:
        vocab.setdefault(w, len(vocab))
    if len(vocab) > vocab_size - 2:
        raise ExportError("tiny OWLv2 tokenizer vocabulary exceeds the tiny model's vocab size")
    vocab["<|startoftext|>"] = vocab_size - 2
    vocab["<|endoftext|>"] = vocab_size - 1
    return word_level_tokenizer(vocab, ["<|startoftext|>", "<|endoftext|>"], path)


def image_wrapper(model: Any):
    import torch

    class Owlv2Image(torch.nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.m = model

        def forward(self, pixel_values):
            fmap = self.m.image_embedder(pixel_values=pixel_values)[0]
            b, h, w, d = fmap.shape
            feats = fmap.reshape(b, h * w, d)
            cls = self.m.class_head.dense0(feats)
            cls = cls / (torch.linalg.norm(cls, dim=-1, keepdim=True) + 1e-6)
            shift = self.m.class_head.logit_shift(feats)
            scale = self.m.class_head.elu(self.m.class_head.logit_scale(feats)) + 1
            boxes = self.m.box_predictor(feats, fmap)
            obj = self.m.objectness_predictor(feats)
            return cls, shift, scale, boxes, obj

    return Owlv2Image().eval()


def text_wrapper(model: Any):
    import torch

    class Owlv2Text(torch.nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.text = model.owlv2.text_model
            self.proj = model.owlv2.text_projection

        def forward(self, input_ids, attention_mask):
            pooled = self.text(input_ids=input_ids, attention_mask=attention_mask).pooler_output
            e = self.proj(pooled)
            return e / (torch.linalg.norm(e, dim=-1, keepdim=True) + 1e-6)

    return Owlv2Text().eval()


def export_detector(source: str, out: str | Path, precisions: Sequence[str], *,
                    calibration_frames: list[np.ndarray] | None = None, **_: Any) -> dict[str, Any]:
    """Add the detector role (OWLv2, image + text graphs, tokenizer.json) to the bundle at `out`."""
    import torch
    from transformers import Owlv2ForObjectDetection

    model, prov = load_source(source, "detector", Owlv2ForObjectDetection)
    vc, tc = model.config.vision_config, model.config.text_config
    S, L, V = int(vc.image_size), int(tc.max_position_embeddings), int(tc.vocab_size)
    out = Path(out)
    tok = write_tokenizer(out, "detector", source, prov["random_weights"], lambda p: build_tiny_tokenizer(p, V))
    img, txt = image_wrapper(model), text_wrapper(model)
    Bd = torch.export.Dim("batch", min=1, max=8)
    Qd = torch.export.Dim("queries", min=1, max=256)

    def img_inputs(rng):
        return {"pixel_values": rng.standard_normal((int(rng.integers(1, 3)), 3, S, S)).astype(np.float32)}

    def txt_inputs(rng):
        q = int(rng.integers(1, 6))
        ids = np.zeros((q, L), np.int64)
        mask = np.zeros((q, L), np.int64)
        for i in range(q):
            n = int(rng.integers(1, L - 2))
            ids[i, 0] = V - 2
            ids[i, 1:n + 1] = rng.integers(1, V - 2, size=n)
            ids[i, n + 1] = V - 1
            mask[i, :n + 2] = 1
        return {"input_ids": ids, "attention_mask": mask}

    ex_t = txt_inputs(np.random.default_rng(0))
    ex_t = {k: np.concatenate([v, v[:1]])[:max(2, len(v))] for k, v in ex_t.items()}
    pre = {"size": [S, S], "layout": "NCHW", "channel_order": "RGB", "dtype": "float32", "scale": 1 / 255,
           "mean": CLIP_MEAN, "std": CLIP_STD, "resize": "pad_square_then_resize", "pad_value": 0.5,
           "keep_aspect": True}

    def calib():
        from mosaicthinker.runtime.models.owlv2 import owl_preprocess

        return [{"pixel_values": owl_preprocess(f, pre)[0]} for f in calibration_frames]

    graphs = [
        GraphSpec("image", img, (torch.randn(2, 3, S, S),), ["pixel_values"],
                  ["class_embeds", "logit_shift", "logit_scale", "pred_boxes", "objectness"], img_inputs,
                  dynamic_shapes={"pixel_values": {0: Bd}}, calibration=calib if calibration_frames else None),
        GraphSpec("text", txt, (torch.from_numpy(ex_t["input_ids"]), torch.from_numpy(ex_t["attention_mask"])),
                  ["input_ids", "attention_mask"], ["text_embeds"], txt_inputs,
                  dynamic_shapes={"input_ids": {0: Qd}, "attention_mask": {0: Qd}}),
    ]
    from mosaicthinker.runtime.infra.bundle import sha256_file

    meta = C.role_meta("owlv2", preprocessing=pre, semantics={"vocabulary": "open"}, provenance=prov,
                       licence="Apache-2.0", random_weights=prov["random_weights"],
                       config={"text_length": L, "start_token": "<|startoftext|>", "end_token": "<|endoftext|>",
                               "pad_id": 0, "query_template": "a photo of a {}", "score_threshold": 0.1,
                               "nms_iou": 0.3, "max_per_name": 10},
                       tokenizer={"file": "detector/tokenizer.json", "sha256": sha256_file(tok)})
    return export_variants(out, "detector", graphs, meta, precisions)


def export_role(role: str, source: str, precisions: Sequence[str], out: str | Path, *, calib: str | None = None,
                options: dict[str, str] | None = None, **_: Any) -> dict[str, Any]:
    """`mosaic export detector --source hf:ID|dir:PATH|tiny[:ARCH]` (registered in export/cli.py)."""
    return run_exporter(export_detector, source, precisions, out, calib=calib, options=options)
