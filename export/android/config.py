"""Options of the Android step: `AndroidConfig`, its flags (`mosaic export --target android`) and the fixed
texts written into the manifest."""
from __future__ import annotations

import argparse
from dataclasses import dataclass, field

from mosaicthinker.runtime.infra.errors import ExportError

from ..formats import target_format

FORMAT = target_format("android")
SOURCE_PRECISIONS = FORMAT.precisions
STYLES = ("Fixed", "Runtime")
VARIANT_PREFIX = FORMAT.variant.replace("<p>", "")
OPS_CONFIG = "android/required_operators.config"
NOT_CHECKED = ("XNNPACK and QNN operator coverage is not checked by onnxruntime's mobile usability checker (NNAPI "
               "and CoreML only): `mosaic bundle verify B --target android` reads it from their EPs' op tables (an "
               "upper bound). Profile on the phone (android/profile.sh) to see what each provider actually takes.")
PHONE_RUNS = ("The phone runs the per-model graphs (.ort) through ONNX Runtime Mobile (Java/Kotlin or C/C++ "
              "API, or onnxruntime_perf_test for profiling); the Python pipeline itself is not shipped to the "
              "phone. See android/README.md for the Python-on-Android options that exist and why they are not "
              "used.")



@dataclass
class AndroidConfig:
    """Options of the Android step (defaults are the ones the tests and README use)."""

    precisions: tuple[str, ...] = SOURCE_PRECISIONS      # source variants to convert (when present / makeable)
    make_fp16: bool = True                               # derive fp16 from fp32 when the bundle lacks it
    styles: tuple[str, ...] = STYLES                     # ORT optimisation styles to write
    target_platform: str = "arm"                         # convert_onnx_models_to_ort --target_platform
    batch: int = 1
    text_len: int = 16                                   # detector text branch: tokens per name
    max_prompts: int = 4                                 # segmenter prompts (boxes) per call
    max_points: int = 4                                  # points per prompt (pad with label -1)
    max_queries: int = 8                                 # open-vocabulary detector: object names per text call
    kv_window: int = 256                                 # VLM decoder fixed cache slots W (0: no window variant)
    prefill_len: int = 64                                # VLM decoder prompt chunk P of the window prefill graph
    nnapi_max_partitions: int = 2                        # more -> flagged (onnxruntime's checker says NO > 2)
    parity_trials: int = 2
    roles: tuple[str, ...] | None = None                 # None: every role in the bundle
    overrides: dict[str, int] = field(default_factory=dict)  # dim_param -> value (--fix NAME=VALUE)



def add_arguments(parser: argparse.ArgumentParser) -> None:
    g = parser.add_argument_group("android target")
    g.add_argument("--android-precisions", default=",".join(SOURCE_PRECISIONS),
                   help="source variants to convert to .ort (default: fp32,fp16,int8-qdq)")
    g.add_argument("--android-roles", default=None, help="comma-separated roles (default: all in the bundle)")
    g.add_argument("--fix", action="append", default=[], metavar="DIM=VALUE",
                   help="fix a named dynamic axis (repeatable), e.g. --fix num_points=5")
    g.add_argument("--nnapi-max-partitions", type=int, default=2)
    g.add_argument("--no-derive-fp16", action="store_true", help="do not make fp16 from fp32 when missing")
    g.add_argument("--kv-window", type=int, default=256,
                   help="VLM decoder: KV-cache slots of the fixed-window variant (0 = none; default 256)")
    g.add_argument("--prefill-len", type=int, default=64,
                   help="VLM decoder: prompt positions per fixed-window prefill call (default 64)")


def config_from_args(args: argparse.Namespace) -> AndroidConfig:
    over = {}
    for item in getattr(args, "fix", []) or []:
        if "=" not in item:
            raise ExportError(f"--fix {item!r}: expected DIM=VALUE")
        k, v = item.split("=", 1)
        try:
            over[k.strip()] = int(v)
        except ValueError as e:
            raise ExportError(f"--fix {item!r}: VALUE must be an integer") from e
        if over[k.strip()] <= 0:
            raise ExportError(f"--fix {item!r}: VALUE must be > 0")
    precs = tuple(p.strip() for p in getattr(args, "android_precisions", ",".join(SOURCE_PRECISIONS)).split(",") if p.strip())
    bad = [p for p in precs if p not in SOURCE_PRECISIONS]
    if bad:
        raise ExportError(f"--android-precisions: unknown {bad} (use {', '.join(SOURCE_PRECISIONS)})")
    roles = getattr(args, "android_roles", None)
    kvw, pre = int(getattr(args, "kv_window", 256)), int(getattr(args, "prefill_len", 64))
    if kvw < 0 or pre < 1 or (kvw and pre >= kvw):
        raise ExportError(f"--kv-window {kvw} / --prefill-len {pre}: need 0 (off) or window > prefill >= 1")
    return AndroidConfig(precisions=precs, overrides=over, make_fp16=not getattr(args, "no_derive_fp16", False),
                         kv_window=kvw, prefill_len=pre,
                         nnapi_max_partitions=int(getattr(args, "nnapi_max_partitions", 2)),
                         roles=tuple(r.strip() for r in roles.split(",")) if roles else None)
