"""VLM adapter over an ONNX Runtime GenAI package (Qwen2.5-VL; export/hf_qwen_vl.py writes it).

The bundle's variant names its package folder (`variants.<v>.genai.package`: genai_config.json,
processor_config.json, tokenizer, decoder/embedding/vision graphs, every file sha256-listed in the manifest).
GenAI owns the whole loop: its processor turns the image into patches and expands the image tokens, its
Generator runs vision, embedding merge, M-RoPE positions, prefill and greedy decode with the KV cache. Same
`generate(images, prompt, max_new_tokens) -> str` interface as the project's own loop (runtime/models/vlm.py),
so the answerer's parsing does not change.

`onnxruntime_genai` is the optional `vlm` extra, imported only here, only when such a bundle is loaded.
Trace stages: `vlm.prefill` (vision + embedding + prefill: one GenAI call, the API does not split them) and
`vlm.decode` (the remaining tokens; tokens/s in the record's detail).
"""
from __future__ import annotations

import os
import tempfile
import time
from typing import Any, Sequence

import numpy as np

from ..infra import jsonio
from ..infra.errors import BundleError
from . import RoleModel

PINNED_GENAI = "0.18.0"


def import_genai() -> Any:
    try:
        import onnxruntime_genai as og
    except ImportError as e:
        raise BundleError("this bundle's vlm is an ONNX Runtime GenAI package: install the optional runtime extra "
                          "(pip install 'mosaicthinker[vlm]', onnxruntime-genai==0.18.0)") from e
    return og


def chat_text(prompt: str, n_images: int) -> str:
    """Qwen2.5-VL chat template, one user turn; GenAI's processor expands each <|image_pad|> to the image's tokens."""
    img = "<|vision_start|><|image_pad|><|vision_end|>" * n_images
    return (f"<|im_start|>system\nYou are a helpful assistant.<|im_end|>\n<|im_start|>user\n{img}{prompt}<|im_end|>\n"
            f"<|im_start|>assistant\n")


class GenAIVLM(RoleModel):
    """`generate(images: list of rgb [H, W, 3] uint8, prompt: str) -> str` through onnxruntime-genai (greedy)."""

    role = "vlm"

    def __init__(self, spec, sessions, trace, conf: Any = None, threads: int | None = None):
        super().__init__(spec, sessions, trace)
        og = import_genai()
        genai = spec.variant_meta.get("genai") or {}
        if not genai.get("package"):
            raise BundleError(f"{spec.bundle.manifest_path}: roles.vlm.variants.{spec.variant}.genai.package missing")
        self.pkg = spec.bundle.root / genai["package"]
        if og.__version__ != genai.get("version", PINNED_GENAI):
            trace.event("degraded", f"onnxruntime-genai {og.__version__} loads a package built for "
                                    f"{genai.get('version')}; results may differ", stage="vlm")
        cfg = og.Config(str(self.pkg))
        cfg.clear_providers()  # CPU; GPU providers are set by the profile on devices that have them
        if threads:
            so = {"intra_op_num_threads": int(threads), "inter_op_num_threads": 1}
            cfg.overlay(jsonio.dumps({"model": {c: {"session_options": so} for c in ("decoder", "embedding",
                                                                                   "vision")}}))
        self.og = og
        self.model = og.Model(cfg)
        self.processor = self.model.create_multimodal_processor()
        self.tokenizer = og.Tokenizer(self.model)
        self.max_new_tokens = int(spec.config.get("max_new_tokens", 64))
        self.query_schema = (genai.get("guidance") or {}).get("json_schema")  # recorded at export (None: older)
        self.specials = tuple(spec.config.get("stop_tokens") or ("<|im_end|>", "<|endoftext|>"))
        self.last: dict[str, Any] = {}

    def providers_used(self) -> dict[str, str | None]:
        return {"genai": "CPUExecutionProvider"}

    def _images(self, images: Sequence[np.ndarray], tmp: str) -> Any:
        import cv2

        if not images:
            return None
        paths = []
        for i, im in enumerate(images):
            p = os.path.join(tmp, f"image{i}.png")
            cv2.imwrite(p, np.ascontiguousarray(im[..., ::-1]))  # RGB -> BGR for OpenCV
            paths.append(p)
        return self.og.Images.open(*paths)

    supports_guidance = True  # constrained decoding (LLGuidance): `guidance=("json_schema" | "lark_grammar" | "regex", text)`

    def generate_ids(self, images: Sequence[np.ndarray], prompt: str, max_new_tokens: int | None = None,
                     guidance: tuple[str, str] | None = None) -> list[int]:
        """Greedy new token ids (the end-of-turn token, when reached, is the last id); `guidance`: decode under a
        grammar (GenAI's `GeneratorParams.set_guidance`)."""
        n_new = int(max_new_tokens or self.max_new_tokens)
        with tempfile.TemporaryDirectory(prefix="mosaic-vlm-") as tmp:
            inputs = self.processor(chat_text(prompt, len(images)), images=self._images(images, tmp))
            n_prompt = int(inputs["input_ids"].as_numpy().size)
            params = self.og.GeneratorParams(self.model)
            params.set_search_options(do_sample=False, top_k=1, max_length=n_prompt + n_new)
            if guidance is not None:
                params.set_guidance(*guidance)
            gen = self.og.Generator(self.model, params)
            ids: list[int] = []
            t0, c0 = time.perf_counter(), time.process_time()  # CPU seconds too: other jobs move them less than wall
            with self.trace.stage("vlm.prefill"):
                gen.set_inputs(inputs)
                gen.generate_next_token()
                ids.append(int(gen.get_next_tokens()[0]))
            t1, c1 = time.perf_counter(), time.process_time()
            with self.trace.stage("vlm.decode"):
                while len(ids) < n_new and not gen.is_done():
                    gen.generate_next_token()
                    ids.append(int(gen.get_next_tokens()[0]))
            t2, c2 = time.perf_counter(), time.process_time()
            del gen
        self.last = {"prompt_tokens": n_prompt, "images": len(images), "new_tokens": len(ids),
                     "prefill_s": round(t1 - t0, 4), "decode_s": round(t2 - t1, 4),
                     "prefill_cpu_s": round(c1 - c0, 4), "decode_cpu_s": round(c2 - c1, 4),
                     "decode_tokens_per_s": round((len(ids) - 1) / (t2 - t1), 2) if len(ids) > 1 and t2 > t1 else None}
        self.trace.decide("vlm.genai", self.last)
        return ids

    def generate(self, images: Sequence[np.ndarray], prompt: str, max_new_tokens: int | None = None,
                 guidance: tuple[str, str] | None = None) -> str:
        """images: list of rgb [H, W, 3] uint8 (may be empty); prompt: the user's text -> the answer text."""
        text = self.tokenizer.decode(np.asarray(self.generate_ids(images, prompt, max_new_tokens, guidance), np.int32))
        for s in self.specials:
            text = text.replace(s, "")
        return text.strip()
