"""VLM adapter: images + prompt -> text, greedy decoding over separate vision / embedding / decoder graphs.

Graphs (export/hf_vlm.py writes them; all numpy I/O):
- vision:  `pixel_values [N, 3, S, S] float32` -> `image_features [N, T, H] float32` (T tokens per image,
           after the family's connector/projector).
- embed:   `input_ids [1, L] int64` -> `inputs_embeds [1, L, H] float32`.
- decoder: `inputs_embeds [1, L, H]`, `attention_mask [1, P+L] int64`, `position_ids [1, L] int64`,
           `past_key_i`, `past_value_i [1, KV, P, D] float32` (i < layers) -> `logits [1, L, V]`,
           `present_key_i`, `present_value_i [1, KV, P+L, D]`.  P = 0 on the first (prefill) call.

Decoding: the chat template of the model family (`TEMPLATES`) wraps the prompt; every image becomes
`image_seq_len` image tokens whose embeddings are replaced by the vision features (in order); then one
prefill call and one call per new token, feeding the previous step's present key/values back as past
(greedy argmax, stops at the family's stop tokens or `max_new_tokens`). Each image is resized to S x S
(no tiling: SmolVLM's and InternVL's multi-tile splitting is not reproduced; that only costs detail).
Tokenizer: `tokenizer.json` from the bundle, through the `tokenizers` library (no transformers).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, ClassVar, Sequence

import numpy as np

from ..infra.config import StageConf
from ..infra.errors import BundleError, InputError
from . import RoleModel, preprocess_image

@dataclass
class VLMConfig(StageConf):
    """How the VLM is asked. max_new_tokens: reply length limit; retries: extra attempts (with a stricter format
    reminder) when the reply cannot be parsed."""

    max_new_tokens: int = 16
    retries: int = 1

    conf_name: ClassVar[str] = "vlm config"

    def validate(self) -> None:
        if not (1 <= self.max_new_tokens <= 4096 and 0 <= self.retries <= 5):
            raise InputError(f"vlm config: need 1 <= max_new_tokens <= 4096 and 0 <= retries <= 5 (got "
                             f"{self.max_new_tokens}, {self.retries})")


# family -> chat template pieces. {content} = images then text; {image_tokens} = the image token repeated.
TEMPLATES: dict[str, dict[str, Any]] = {
    "smolvlm": {  # Idefics3 / SmolVLM (global image only, no tile grid)
        "prompt": "<|im_start|>User:{content}<end_of_utterance>\nAssistant:",
        "image": "<fake_token_around_image><global-img>{image_tokens}<fake_token_around_image>",
        "image_token": "<image>",
        "stop": ["<end_of_utterance>", "<|im_end|>", "</s>"],
    },
    "internvl": {  # InternVL 2.5 / 3 (Qwen2 chat format)
        "prompt": "<|im_start|>user\n{content}<|im_end|>\n<|im_start|>assistant\n",
        "image": "<img>{image_tokens}</img>\n",
        "image_token": "<IMG_CONTEXT>",
        "stop": ["<|im_end|>", "<|endoftext|>"],
    },
    "qwen3_vl": {  # Qwen3-VL (Qwen chat format; the image is one fixed-grid block of merged patches)
        "prompt": "<|im_start|>user\n{content}<|im_end|>\n<|im_start|>assistant\n",
        "image": "<|vision_start|>{image_tokens}<|vision_end|>",
        "image_token": "<|image_pad|>",
        "stop": ["<|im_end|>", "<|endoftext|>"],
    },
}


def build_prompt(family: str, prompt: str, n_images: int, image_seq_len: int) -> str:
    """The chat-templated text with every image expanded into `image_seq_len` image tokens."""
    if family not in TEMPLATES:
        raise BundleError(f"VLM family {family!r} has no chat template (known: {sorted(TEMPLATES)})")
    t = TEMPLATES[family]
    img = t["image"].format(image_tokens=t["image_token"] * image_seq_len)
    return t["prompt"].format(content=img * n_images + prompt)


@dataclass
class VLMConf:
    max_new_tokens: int = 64


def greedy(logits: np.ndarray, advance: Callable[[int], np.ndarray], max_new_tokens: int,
           stop_ids: Sequence[int]) -> list[int]:
    """Greedy decoding: argmax of `logits [1, T, V]`'s last row, then `advance(token) -> next logits`, until a stop
    token (included as the last id) or `max_new_tokens`. One loop for every decoder that keeps its own KV cache."""
    out: list[int] = []
    for _ in range(max_new_tokens):
        nxt = int(np.argmax(logits[0, -1]))
        out.append(nxt)
        if nxt in stop_ids:
            break
        logits = advance(nxt)
    return out


class GreedyDecoder:
    """The decoding loop over three runners (`.run(feeds) -> list of arrays` in graph output order)."""

    def __init__(self, vision: Any, embed: Any, decoder: Any, cfg: dict[str, Any]):
        self.vision, self.embed, self.decoder = vision, embed, decoder
        self.layers = int(cfg["num_layers"])
        self.kv_heads = int(cfg["num_kv_heads"])
        self.head_dim = int(cfg["head_dim"])
        self.image_token_id = int(cfg["image_token_id"])

    def image_features(self, pixel_values: np.ndarray) -> np.ndarray:
        """pixel_values [N, 3, S, S] -> [N, T, H]."""
        return np.asarray(self.vision.run({"pixel_values": pixel_values})[0], np.float32)

    def prefill_embeds(self, ids: Sequence[int], feats: np.ndarray | None) -> np.ndarray:
        """Token embeddings [1, L, H] with image-token rows replaced by the image features (in order)."""
        ids_a = np.asarray(ids, np.int64)[None]
        emb = np.asarray(self.embed.run({"input_ids": ids_a})[0], np.float32).copy()
        pos = np.flatnonzero(ids_a[0] == self.image_token_id)
        n_feat = 0 if feats is None else feats.shape[0] * feats.shape[1]
        if len(pos) != n_feat:
            raise InputError(f"prompt has {len(pos)} image tokens but the images give {n_feat} features")
        if n_feat:
            emb[0, pos] = feats.reshape(n_feat, -1)
        return emb

    def step(self, embeds: np.ndarray, past: list[np.ndarray], past_len: int) -> tuple[np.ndarray, list[np.ndarray]]:
        """One decoder call: embeds [1, L, H] after `past_len` cached tokens -> (logits [1, L, V], presents)."""
        L = embeds.shape[1]
        feeds = {"inputs_embeds": embeds, "attention_mask": np.ones((1, past_len + L), np.int64),
                 "position_ids": np.arange(past_len, past_len + L, dtype=np.int64)[None]}
        for i in range(self.layers):
            feeds[f"past_key_{i}"] = past[2 * i]
            feeds[f"past_value_{i}"] = past[2 * i + 1]
        out = self.decoder.run(feeds)
        return np.asarray(out[0]), list(out[1:])

    def empty_past(self) -> list[np.ndarray]:
        z = np.zeros((1, self.kv_heads, 0, self.head_dim), np.float32)
        return [z] * (2 * self.layers)

    def generate_ids(self, ids: Sequence[int], feats: np.ndarray | None, max_new_tokens: int,
                     stop_ids: Sequence[int]) -> list[int]:
        """Greedy new token ids (the stop token, when reached, is included as the last id)."""
        emb = self.prefill_embeds(ids, feats)
        logits, past = self.step(emb, self.empty_past(), 0)
        state = {"past": past, "n": len(ids)}

        def advance(nxt: int) -> np.ndarray:
            out, state["past"] = self.step(self.embed_token(nxt), state["past"], state["n"])
            state["n"] += 1
            return out

        return greedy(logits, advance, max_new_tokens, stop_ids)

    def embed_token(self, token: int) -> np.ndarray:
        """[1, 1, H] embedding of one token id."""
        return np.asarray(self.embed.run({"input_ids": np.array([[token]], np.int64)})[0], np.float32)

    def generate_ids_nocache(self, ids: Sequence[int], feats: np.ndarray | None, max_new_tokens: int,
                             stop_ids: Sequence[int]) -> list[int]:
        """The same greedy decoding re-running the whole sequence each step (no KV cache): the reference for
        the cache-consistency check (must give the same ids as `generate_ids`)."""
        seq, out = list(ids), []
        for _ in range(max_new_tokens):
            logits, _ = self.step(self.prefill_embeds(seq, feats), self.empty_past(), 0)
            nxt = int(np.argmax(logits[0, -1]))
            out.append(nxt)
            if nxt in stop_ids:
                break
            seq.append(nxt)
        return out


def load_tokenizer(path: str) -> Any:
    from tokenizers import Tokenizer

    return Tokenizer.from_file(str(path))


class VLM(RoleModel):
    """`generate(images: list of rgb [H, W, 3] uint8, prompt: str) -> str` (greedy, KV cache)."""

    role = "vlm"

    def __init__(self, spec, sessions, trace, conf: VLMConf | None = None):
        super().__init__(spec, sessions, trace)
        cfg = spec.config
        for k in ("family", "num_layers", "num_kv_heads", "head_dim", "image_token_id", "image_seq_len"):
            if k not in cfg:
                raise BundleError(f"{spec.bundle.manifest_path}: roles.vlm.config.{k} is missing")
        self.family = cfg["family"]
        self.conf = conf or VLMConf(max_new_tokens=int(cfg.get("max_new_tokens", 64)))
        tok_ref = spec.meta.get("tokenizer") or {}
        tok_path = spec.bundle.file(tok_ref, "roles.vlm.tokenizer")
        self.tokenizer = load_tokenizer(str(tok_path))
        self.core = GreedyDecoder(self.session("vision"), self.session("embed"), self.session("decoder"), cfg)
        stops = cfg.get("stop_tokens") or TEMPLATES[self.family]["stop"]
        self.stop_ids = sorted({i for i in (self.tokenizer.token_to_id(t) for t in stops) if i is not None})
        if not self.stop_ids:
            raise BundleError(f"{tok_path}: none of the stop tokens {stops} is in the tokenizer")

    def encode(self, images: Sequence[np.ndarray], prompt: str) -> tuple[list[int], np.ndarray | None]:
        text = build_prompt(self.family, prompt, len(images), int(self.spec.config["image_seq_len"]))
        ids = self.tokenizer.encode(text, add_special_tokens=False).ids
        if not images:
            return ids, None
        px = np.concatenate([preprocess_image(im, self.spec.preprocessing) for im in images], axis=0)
        with self.trace.stage("vlm.vision"):
            feats = self.core.image_features(px)
        return ids, feats

    def generate_ids(self, images: Sequence[np.ndarray], prompt: str, max_new_tokens: int | None = None) -> list[int]:
        ids, feats = self.encode(images, prompt)
        with self.trace.stage("vlm.decode"):
            return self.core.generate_ids(ids, feats, max_new_tokens or self.conf.max_new_tokens, self.stop_ids)

    def generate(self, images: Sequence[np.ndarray], prompt: str, max_new_tokens: int | None = None) -> str:
        """images: list of rgb [H, W, 3] uint8 (may be empty); prompt: the user's text -> the answer text."""
        out = self.generate_ids(images, prompt, max_new_tokens)
        return self.tokenizer.decode([t for t in out if t not in self.stop_ids], skip_special_tokens=True)


class OrtRunner:
    """Adapts a plain onnxruntime.InferenceSession to the `.run(feeds) -> list` interface used above."""

    def __init__(self, sess: Any):
        self.sess = sess

    def run(self, feeds: dict[str, np.ndarray], outputs: Sequence[str] | None = None) -> list[np.ndarray]:
        return self.sess.run(outputs, feeds)



# ------------------------------------------------------------------------------------------------ Qwen3-VL
# Qwen3-VL (export/hf_qwen3_vl.py): the vision graph also emits DeepStack features, and the decoder takes 3-D
# M-RoPE positions and those features scattered to the image rows:
# - vision:  `pixel_values [P, 3*T*p*p]` -> `image_features [P/m^2, H]`, `deepstack_features [K, P/m^2, H]`
# - decoder: `inputs_embeds [1, L, H]`, `attention_mask [1, P+L]`, `position_ids [3, 1, L]`,
#            `deepstack [K, 1, L, H]`, `past_key_i / past_value_i` -> `logits`, `present_key_i / present_value_i`

def qwen_patches(chw: np.ndarray, patch: int, merge: int, temporal: int) -> np.ndarray:
    """[3, S, S] normalised image -> [(S/p)^2, 3*T*p*p] patches in merge-unit order (Qwen2-VL's image
    processor layout: the frame repeated T times, patches of one merge unit adjacent)."""
    c, h, w = chw.shape
    gh, gw = h // patch, w // patch
    x = np.broadcast_to(chw[None], (temporal, c, h, w))
    x = x.reshape(temporal, c, gh // merge, merge, patch, gw // merge, merge, patch)
    x = x.transpose(2, 5, 3, 6, 1, 0, 4, 7)
    return np.ascontiguousarray(x.reshape(gh * gw, c * temporal * patch * patch), dtype=np.float32)


def mrope_positions(ids: Sequence[int], image_token_id: int, grid_hw: tuple[int, int]) -> tuple[np.ndarray, int]:
    """M-RoPE position ids [3, 1, L] (t, h, w) for one prompt, each run of image tokens one merged grid of
    `grid_hw` = (rows, cols): text advances all three by one; an image block starting at s holds (s, s+r, s+c)
    and the text after it resumes at s + max(rows, cols). Returns (positions, next position)."""
    ids_a = np.asarray(ids, np.int64)
    pos = np.zeros((3, ids_a.size), np.int64)
    i, cur, rows, cols = 0, 0, int(grid_hw[0]), int(grid_hw[1])
    while i < ids_a.size:
        if ids_a[i] != image_token_id:
            pos[:, i] = cur
            i, cur = i + 1, cur + 1
            continue
        n = rows * cols
        if not np.all(ids_a[i:i + n] == image_token_id):
            raise InputError(f"an image block at token {i} is shorter than its {rows}x{cols} grid")
        r, c = np.divmod(np.arange(n), cols)
        pos[0, i:i + n], pos[1, i:i + n], pos[2, i:i + n] = cur, cur + r, cur + c
        i, cur = i + n, cur + max(rows, cols)
    return pos[:, None], cur


class MRopeDecoder(GreedyDecoder):
    """The greedy loop for decoders with 3-D M-RoPE positions and DeepStack inputs (Qwen3-VL)."""

    def __init__(self, vision: Any, embed: Any, decoder: Any, cfg: dict[str, Any]):
        super().__init__(vision, embed, decoder, cfg)
        self.grid = tuple(int(g) for g in cfg["merged_grid"])
        self.deepstack = int(cfg["deepstack_layers"])
        self.hidden = int(cfg["hidden_size"])

    def image_features(self, pixel_values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """pixel_values [P, 3*T*p*p] of one image -> (features [T, H], deepstack [K, T, H])."""
        feats, deep = self.vision.run({"pixel_values": pixel_values})[:2]
        return np.asarray(feats, np.float32), np.asarray(deep, np.float32)

    def step3(self, embeds: np.ndarray, pos: np.ndarray, deep: np.ndarray, past: list[np.ndarray],
              past_len: int) -> tuple[np.ndarray, list[np.ndarray]]:
        L = embeds.shape[1]
        feeds = {"inputs_embeds": embeds, "attention_mask": np.ones((1, past_len + L), np.int64),
                 "position_ids": pos, "deepstack": deep}
        for i in range(self.layers):
            feeds[f"past_key_{i}"], feeds[f"past_value_{i}"] = past[2 * i], past[2 * i + 1]
        out = self.decoder.run(feeds)
        return np.asarray(out[0]), list(out[1:])

    def prefill(self, ids: Sequence[int], image: tuple[np.ndarray, np.ndarray] | None):
        """-> (logits, presents, next position) after the whole prompt (image rows: features + DeepStack)."""
        feats, deep = image if image is not None else (None, None)
        emb = self.prefill_embeds(ids, None if feats is None else feats[None])
        dense = np.zeros((self.deepstack, 1, len(ids), emb.shape[2]), np.float32)
        if deep is not None:
            dense[:, 0, np.flatnonzero(np.asarray(ids) == self.image_token_id)] = deep
        pos, nxt = mrope_positions(ids, self.image_token_id, self.grid)
        logits, past = self.step3(emb, pos, dense, self.empty_past(), 0)
        return logits, past, nxt

    def generate_ids(self, ids: Sequence[int], image: tuple[np.ndarray, np.ndarray] | None, max_new_tokens: int,
                     stop_ids: Sequence[int]) -> list[int]:
        logits, past, cur = self.prefill(ids, image)
        zeros = np.zeros((self.deepstack, 1, 1, self.hidden), np.float32)  # DeepStack feeds image rows only
        state = {"past": past, "n": len(ids), "cur": cur}

        def advance(nxt: int) -> np.ndarray:
            pos = np.full((3, 1, 1), state["cur"], np.int64)
            out, state["past"] = self.step3(self.embed_token(nxt), pos, zeros, state["past"], state["n"])
            state["n"] += 1
            state["cur"] += 1
            return out

        return greedy(logits, advance, max_new_tokens, stop_ids)


class Qwen3VL(VLM):
    """Qwen3-VL over the project's own graphs: one fixed-grid image (S x S), DeepStack, M-RoPE."""

    def __init__(self, spec, sessions, trace, conf: VLMConf | None = None):
        super().__init__(spec, sessions, trace, conf)
        for k in ("merged_grid", "deepstack_layers", "hidden_size", "patch_size", "merge_size", "temporal_patch_size"):
            if k not in spec.config:
                raise BundleError(f"{spec.bundle.manifest_path}: roles.vlm.config.{k} is missing")
        self.core = MRopeDecoder(self.session("vision"), self.session("embed"), self.session("decoder"), spec.config)

    def encode(self, images: Sequence[np.ndarray], prompt: str):
        if len(images) > 1:
            raise InputError("the Qwen3-VL graphs take one image per prompt (the map image); got "
                             f"{len(images)}")
        ids, image = super().encode([], prompt)[0], None
        if images:
            c = self.spec.config
            ids = self.tokenizer.encode(build_prompt(self.family, prompt, 1, int(c["image_seq_len"])),
                                        add_special_tokens=False).ids
            chw = preprocess_image(images[0], self.spec.preprocessing)[0]
            px = qwen_patches(chw, int(c["patch_size"]), int(c["merge_size"]), int(c["temporal_patch_size"]))
            with self.trace.stage("vlm.vision"):
                image = self.core.image_features(px)
        return ids, image
