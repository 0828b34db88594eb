"""Runtime adapters: one small class per model role over onnxruntime sessions (numpy only, never torch).

`load_role(bundle_or_dir, role, variant=None, providers=None, threads=None, trace=None)` reads the role's
manifest entry, hash-checks the variant's files, creates one session per component through
`runtime.providers.create_session` (provider fallback recorded in the trace), warns loudly when the role has
random weights, and returns the adapter class registered for the manifest's `arch` in `ARCHS`.

Interfaces (shapes as in ARCHITECTURE.md):
- depth:     `.predict(rgb [H,W,3] uint8) -> [H,W] float32`, `.semantics` in metric_m|relative|relative_inverse
- segmenter: `.segment(rgb, boxes [N,4] | None, names, points=None) -> masks [N,H,W] bool`
- detector:  `.detect(rgb, names) -> perception.Detections` (names it cannot detect in `.undetectable`)
- embedder:  `.embed(rgb) -> [D] float32`, L2-normalised
- matcher:   `.match(rgb0, rgb1, boxes0=None, boxes1=None) -> types.Matches`
- vlm:       see the VLM adapter (H6)

Adding an architecture: write `runtime/models/<module>.py` with a `RoleModel` subclass and add ONE line to
`ARCHS` ("arch": "module:Class"); the class receives a `RoleSpec` (manifest metadata + component paths) and the
created sessions.
"""
from __future__ import annotations

import hashlib
import importlib
import os
import time
from contextlib import contextmanager
from typing import Any, Callable, Iterator, Sequence

import numpy as np

from ..infra.bundle import Bundle, RoleSpec, load_bundle
from ..infra.errors import BundleError, InputError
from ..infra.file_schemas import image_input_problem
from ..infra.lru import LRU
from ..infra.trace import Trace
from ..infra.providers import create_session, files_mb

# arch (manifest roles.<role>.arch) -> "module:Class" inside mosaicthinker.runtime.models
ARCHS: dict[str, str] = {
    "pydnet": "depth:DepthModel",            # relative monocular depth, single NHWC graph
    "depth_generic": "depth:DepthModel",     # any single-graph depth model described by its preprocessing
    "ssd_tflite": "detector:ClosedSetDetector",  # TFLite SSD with in-graph NMS (boxes, classes, scores, count)
    "yolox": "yolo:YoloxDetector",               # YOLOX raw anchors: grid decoding + NMS in the adapter
    "ultralytics_e2e": "yolo:UltralyticsDetector",  # Ultralytics nms=True export: boxes (+ mask coefficients)
    "deeplab": "segmenter:SemanticSegmenter",    # per-pixel class logits
    "mobilenet_embedding": "embedder:Embedder",  # pooled CNN features
    "embedding_generic": "embedder:Embedder",
    "xfeat": "matcher:TwoStageMatcher",      # XFeat extractor + mutual-NN matcher (contract B in matcher.py)
    "pair_matcher": "matcher:PairMatcher",   # any graph following the pair contract
    "two_stage_matcher": "matcher:TwoStageMatcher",  # extractor + matcher components
    # Hugging Face architectures (export/hf_*.py)
    "depth-anything-v2": "depth:DepthModel",                # relative inverse depth
    "depth-anything-v2-metric-indoor": "depth:DepthModel",  # metres
    "sam": "sam:SamSegmenter",                # image encoder + prompt decoder
    "slimsam": "sam:SamSegmenter",
    "owlv2": "owlv2:OwlV2Detector",           # image branch + text branch (embeddings cached per name)
    "clip": "embedder:Embedder",              # CLIP vision tower + projection, L2-normalised in graph
    "siglip": "embedder:Embedder",            # SigLIP pooled vision embedding
    "superpoint_lightglue": "matcher:TwoStageMatcher",  # SuperPoint top-K extractor + LightGlue matcher
    "efficientloftr": "matcher:PairMatcher",  # pair graph
    "smolvlm": "vlm:VLM",                     # vision + embed + decoder-with-KV-cache
    "internvl": "vlm:VLM",
    "qwen2_5_vl": "vlm_genai:GenAIVLM",       # ONNX Runtime GenAI package (decoder, embedding, vision)
    "qwen3_vl": "vlm:Qwen3VL",                # own graphs: vision with DeepStack, M-RoPE decoder
    "minilm-reader": "reader:QuestionReader",  # the trained question reader (query/reader.py runs it)
}


class RoleModel:
    """Base adapter: holds the role spec, its sessions and the trace; subclasses add the role's method."""

    role: str = ""

    def __init__(self, spec: RoleSpec, sessions: dict[str, Any], trace: Trace):
        self.spec = spec
        self.sessions = sessions
        self.trace = trace

    @property
    def name(self) -> str:
        return f"{self.spec.role}:{self.spec.arch}/{self.spec.variant}"

    def session(self, component: str | None = None) -> Any:
        """The session of `component` (default: the only one)."""
        if component is None:
            if len(self.sessions) != 1:
                raise BundleError(f"{self.name}: several components {sorted(self.sessions)}; name one")
            return next(iter(self.sessions.values()))
        if component not in self.sessions:
            raise BundleError(f"{self.name}: no component {component!r} (has {sorted(self.sessions)})")
        return self.sessions[component]

    @contextmanager
    def _stage(self, name: str, component: str | None = None) -> Iterator[Any]:
        """trace.stage(name) that also records the provider the component's session runs on."""
        with self.trace.stage(name) as rec:
            rec.provider = getattr(self.session(component), "provider", None)
            yield rec

    @contextmanager
    def _overhead(self, *model_stages: str) -> Iterator[None]:
        """Times one adapter call and books what is not a graph run (the seconds `model_stages` gained inside it:
        pre- and post-processing, cache look-ups) as stage `<role>.overhead` (role: the first model stage's
        prefix), next to the model's own stages: the trace shows the adapter's cost beside the model's."""
        if getattr(self, "_in_call", False):  # a nested adapter call (predict inside predict_metric): the outer books
            yield
            return
        st = self.trace.stages

        def inner() -> float:
            return sum(st[n].seconds for n in model_stages if n in st)

        inner0, t0 = inner(), time.perf_counter()
        self._in_call = True
        try:
            yield
        finally:
            self._in_call = False
            total = time.perf_counter() - t0
            self.trace.add_time(f"{model_stages[0].split('.')[0]}.overhead", max(0.0, total - (inner() - inner0)))

    def providers_used(self) -> dict[str, str | None]:
        return {c: getattr(s, "provider", None) for c, s in self.sessions.items()}

    def describe(self) -> dict[str, Any]:
        return {"role": self.spec.role, "arch": self.spec.arch, "variant": self.spec.variant,
                "model": self.spec.meta.get("name"), "random_weights": self.spec.random_weights,
                "providers": self.providers_used(), "licence": self.spec.meta.get("licence"),
                "source": self.spec.meta.get("provenance", {}).get("source")}


def resolve_arch(arch: str) -> type:
    if arch not in ARCHS:
        raise BundleError(f"manifest arch {arch!r} has no runtime adapter (known: {sorted(ARCHS)})")
    mod, cls = ARCHS[arch].split(":")
    module = importlib.import_module(f"{__name__}.{mod}")
    return getattr(module, cls)


def check_archs(bundle: Bundle, roles: Sequence[str] | None = None) -> None:
    """Every role's `arch` (and every variant's own, under `overrides`) names an adapter of that role (`ARCHS` and
    the adapter's `role`, or `roles` where one model serves several): a depth graph labelled with a segmenter's
    arch would load and crash on first use."""
    for role in roles if roles is not None else bundle.roles:
        meta = bundle.role_meta(role)
        archs = {f"roles.{role}.arch": meta["arch"]}
        for vname, vm in meta["variants"].items():
            if "arch" in (vm.get("overrides") or {}):
                archs[f"roles.{role}.variants.{vname}.overrides.arch"] = vm["overrides"]["arch"]
        for field_, arch in archs.items():
            where = f"{bundle.manifest_path}: {field_}"
            if arch not in ARCHS:
                raise BundleError(f"{where} is {arch!r}, which has no runtime adapter (known: "
                                  f"{', '.join(sorted(ARCHS))}); fix the manifest or re-export the role")
            cls = resolve_arch(arch)
            if role not in getattr(cls, "roles", (cls.role,)):
                raise BundleError(f"{where} is {arch!r}, an architecture of the {cls.role} role, not of {role}; fix "
                                  f"the manifest or re-export the role")


def load_role(bundle_or_dir: Bundle | str | os.PathLike, role: str, variant: str | None = None,
              providers: Sequence[Any] | str | None = None, threads: int | None = None,
              trace: Trace | None = None) -> RoleModel:
    """Load one role of a bundle as its runtime adapter.

    providers: ordered preference (short names ok: "cuda,cpu"); threads: intra-op threads per session;
    variant: e.g. "fp32", "int8-dynamic" (default: the role's default_variant). The component files are
    sha256-checked before any session is created.
    """
    trace = trace if trace is not None else Trace()
    b = load_bundle(bundle_or_dir, verify=False)
    spec = b.spec(role, variant, verify=True)
    check_archs(b, [role])
    cls = resolve_arch(spec.arch)
    if spec.random_weights:
        trace.note_random_weights(f"{role}:{spec.arch} ({b.root})")
    sessions = {}
    if spec.variant_meta.get("genai"):  # an ONNX Runtime GenAI package: GenAI creates its own sessions
        trace.decide(f"model.{role}", {"arch": spec.arch, "variant": spec.variant, "bundle": str(b.root),
                                       "random_weights": spec.random_weights, "runtime": "onnxruntime-genai"})
        return cls(spec, sessions, trace, threads=threads)
    for cname, comp in spec.components.items():
        if comp.format not in ("onnx", "ort"):
            raise BundleError(f"{b.manifest_path}: roles.{role}.variants.{spec.variant}.components.{cname}.format "
                              f"is {comp.format!r}; the runtime loads onnx or ort")
        stage = role if len(spec.components) == 1 else f"{role}.{cname}"
        # the graph and its external data: the floor of the memory guard's size estimate for the session
        extra = [b.root / e["file"] for e in comp.meta.get("extra_files", []) if isinstance(e.get("file"), str)]
        sessions[cname] = create_session(comp.path, stage, providers, threads=threads, trace=trace,
                                         model_mb=files_mb(comp.path, extra))
        check_image_input(spec, cname, sessions[cname])
    trace.decide(f"model.{role}", {"arch": spec.arch, "variant": spec.variant, "bundle": str(b.root),
                                   "random_weights": spec.random_weights})
    try:
        return cls(spec, sessions, trace)
    except (KeyError, TypeError, ValueError, IndexError) as e:  # a manifest entry its adapter cannot use
        raise BundleError(f"{b.manifest_path}: roles.{role}: the {spec.arch} adapter cannot use this entry "
                          f"({type(e).__name__}: {e}); fix the manifest or re-export the role") from e


_ORT_DTYPES = {"tensor(float)": "float32", "tensor(float16)": "float16", "tensor(uint8)": "uint8"}


def check_image_input(spec: RoleSpec, cname: str, sess: Any) -> None:
    """The manifest's `preprocessing` (size, layout, dtype) must fit the graph's image input, or every run
    would fail inside the provider with a message that names neither (`file_schemas.image_input_problem`)."""
    ins = [(i.name, list(i.shape or []), _ORT_DTYPES.get(i.type, i.type)) for i in sess.get_inputs()]
    bad = image_input_problem(spec.preprocessing, ins)
    if bad is not None:
        raise BundleError(f"{spec.bundle.manifest_path}: roles.{spec.role}.preprocessing.{bad[0]} {bad[1]} "
                          f"(graph {spec.components[cname].path.name})")


# ---------------------------------------------------------------------------------------------------------------
# Per-image result cache (one home for the adapters' "same frame, same answer")


class ImageLRU(LRU):
    """Results keyed by an image's full content (shape, dtype, every byte), least recently used dropped past
    `size` images: a frame shown to a model twice (the key-frame search detects it, alignment wants its boxes of
    every label; refinement asks one class mask per object) runs the model once. The key is a 128-bit BLAKE2
    digest of the bytes (~1 ms for 640x480): any changed pixel is a new key. `hits` counts the runs saved."""

    @staticmethod
    def key(rgb: np.ndarray) -> bytes:
        a = np.ascontiguousarray(rgb)
        h = hashlib.blake2b(f"{a.shape}{a.dtype.str}".encode(), digest_size=16)
        h.update(a.data)
        return h.digest()

    def cached(self, rgb: np.ndarray, compute: Callable[[np.ndarray], Any]) -> Any:
        """`compute(rgb)` once per image content: the cached value on a hit, else computed, its arrays (one, or
        a tuple of them) made read-only (every later call on the image shares them) and cached."""
        key = self.key(rgb)
        hit = self.get(key)
        if hit is not None:
            return hit
        out = compute(rgb)
        for a in out if isinstance(out, tuple) else (out,):
            a.setflags(write=False)
        return self.put(key, out)


# ---------------------------------------------------------------------------------------------------------------
# Shared image pre-processing driven by the manifest's `preprocessing` block

def preprocess_image(rgb: np.ndarray, pp: dict[str, Any]) -> np.ndarray:
    """rgb [H, W, 3] uint8 -> [1, h, w, 3] (NHWC) or [1, 3, h, w] (NCHW) in the manifest's dtype.

    pp keys: size [h, w] (resize, bilinear; absent = keep), channel_order RGB|BGR, dtype float32|float16|uint8,
    scale (multiplied first), mean/std (per channel, after scale), layout NHWC|NCHW.
    """
    import cv2

    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
        raise InputError(f"expected an RGB image [H, W, 3] uint8, got {rgb.shape} {rgb.dtype}")
    img = rgb
    size = pp.get("size")
    if size:
        h, w = int(size[0]), int(size[1])
        if img.shape[:2] != (h, w):
            interp = cv2.INTER_AREA if h < img.shape[0] and w < img.shape[1] else cv2.INTER_LINEAR
            img = cv2.resize(img, (w, h), interpolation=interp)
    if pp.get("channel_order", "RGB").upper() == "BGR":
        img = img[..., ::-1]
    dtype = np.dtype(pp.get("dtype", "float32"))
    if dtype == np.uint8:
        x = np.ascontiguousarray(img)
    else:
        x = img.astype(np.float32)
        if pp.get("scale") is not None:
            x = x * np.float32(pp["scale"])
        if pp.get("mean") is not None:
            x = x - np.asarray(pp["mean"], np.float32)
        if pp.get("std") is not None:
            x = x / np.asarray(pp["std"], np.float32)
        x = x.astype(dtype)
    if pp.get("layout", "NHWC").upper() == "NCHW":
        x = x.transpose(2, 0, 1)
    return np.ascontiguousarray(x[None])
