"""The Hugging Face export driver shared by export/hf_*.py.

`GraphSpec` + `export_variants` turn thin torch wrappers into bundle variants with the helpers of
export/common.py: fp32 export + parity against torch, fp16 from a `.half()` copy, int8-dynamic and int8-qdq
from the fp32 graph; every quantised/half component is checked against the fp32 graph on fresh random inputs
and, when it fails, the component stays at fp32 inside that variant and the choice is recorded in the
manifest (`components.<c>.precision` + `fallback_reason`, and the variant's `notes`). Calibration images go
through the runtime's own pre-processing (`runtime.models.preprocess_image`), so int8 sees what the device sees.
"""
from __future__ import annotations

import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from mosaicthinker.runtime.infra.errors import ExportError
from mosaicthinker.runtime.infra.progress import ticked

from . import common as C
from .parity import agreement_check

IMAGENET_MEAN = [0.485, 0.456, 0.406]
IMAGENET_STD = [0.229, 0.224, 0.225]
CLIP_MEAN = [0.48145466, 0.4578275, 0.40821073]
CLIP_STD = [0.26862954, 0.26130258, 0.27577711]


# ------------------------------------------------------------------------------------------------------------
# The export driver

@dataclass
class GraphSpec:
    """One component graph of a role.

    module: a thin torch wrapper with plain-tensor I/O (fp32, eval); example: export example args (use sizes
    >= 2 on dynamic axes: torch.export specialises 0/1); make_inputs(rng) -> fresh feeds for parity (new values
    and, on dynamic axes, new sizes); calibration(): feeds for int8-qdq (defaults to make_inputs draws);
    quantize: False keeps this component at fp32 in int8 variants (e.g. graphs of integer index logic);
    parity_outputs: output indices compared (default all); tol: {precision: (rel, cos)} overrides.
    """

    name: str
    module: Any
    example: tuple
    input_names: list[str]
    output_names: list[str]
    make_inputs: Callable[[np.random.Generator], dict[str, np.ndarray]]
    dynamic_shapes: Any = None
    calibration: Callable[[], list[dict[str, np.ndarray]]] | None = None
    quantize: bool = True
    half: bool = True
    parity_outputs: Sequence[int] | None = None
    tol: dict[str, tuple[float, float]] = field(default_factory=dict)
    meta: dict[str, Any] = field(default_factory=dict)
    # graphs with discrete selections (top-k, argmax, mutual nearest neighbours): near-ties may legitimately
    # flip between runtimes, so besides element-wise parity on `parity_outputs` (the continuous ones) the
    # outputs are compared as sets: agreement(ref_outputs, got_outputs) -> fraction in [0, 1]
    agreement: Callable[[list[np.ndarray], list[np.ndarray]], float] | None = None
    agreement_min: dict[str, float] = field(default_factory=lambda: {"fp32": 0.95, "fp16": 0.8, "int8-dynamic": 0.7,
                                                                     "int8-qdq": 0.7})


class _Half:
    """Wraps a module into an fp16 copy whose graph I/O stays fp32 (the runtime always feeds fp32)."""

    def __new__(cls, module: Any):
        import copy

        import torch

        class HalfWrapper(torch.nn.Module):
            def __init__(self, m: Any):
                super().__init__()
                self.m = copy.deepcopy(m).half()

            def forward(self, *args):
                args = [a.half() if a.is_floating_point() else a for a in args]
                out = self.m(*args)
                out = out if isinstance(out, (tuple, list)) else (out,)
                return tuple(o.float() if o.is_floating_point() else o for o in out)

        return HalfWrapper(module).eval()


def torch_reference(module: Any, input_names: Sequence[str]) -> Callable[[dict], list[np.ndarray]]:
    """feeds -> list of numpy outputs of the torch module (the fp32 parity reference)."""
    import torch

    def run(feeds: dict[str, np.ndarray]) -> list[np.ndarray]:
        with torch.no_grad():
            out = module(*[torch.from_numpy(np.ascontiguousarray(feeds[n])) for n in input_names])
        out = out if isinstance(out, (tuple, list)) else (out,)
        return [o.detach().float().numpy() if o.is_floating_point() else o.detach().numpy() for o in out]

    return run


def export_variants(out: str | Path, role: str, graphs: list[GraphSpec], meta: dict[str, Any],
                    precisions: Sequence[str], *, workdir: str | Path | None = None,
                    task_check: Callable[[dict[str, Path], str], dict[str, Any]] | None = None) -> dict[str, Any]:
    """Export `graphs` at each precision and add the variants to the bundle at `out`.

    precisions: variant names (`common.parse_precisions` output; fp32 always first). task_check(files, variant) ->
    {"ok": bool, ...} runs on a whole variant's component files when given (e.g. VLM token agreement); a
    failing fp32 task check fails the export, a failing lower-precision one skips that variant.
    Returns {"variants": {variant: {"components": {c: precision}, "parity": ..., "task": ...}}, "skipped": {...}}.
    """
    precisions = C.parse_precisions(",".join(precisions))
    if "fp32" not in precisions:
        precisions.insert(0, "fp32")
    tmp_ctx = tempfile.TemporaryDirectory(prefix=f"mosaic-export-{role}-") if workdir is None else None
    work = Path(tmp_ctx.name if tmp_ctx else workdir)
    report: dict[str, Any] = {"variants": {}, "skipped": {}}
    try:
        fp32: dict[str, Path] = {}
        par32: dict[str, Any] = {}
        for g in graphs:
            p = C.export_torch(g.module, g.example, work / "fp32" / f"{g.name}.onnx", g.input_names, g.output_names,
                               dynamic_shapes=g.dynamic_shapes, external_data=needs_external_data(g.module))
            par32[g.name] = _parity(g, p, torch_reference(g.module, g.input_names), "fp32", f"{role}/{g.name} vs torch",
                                    require=True)
            fp32[g.name] = p
            par32[g.name]["reference_std"] = _reference_spread(g)
        task = task_check(fp32, "fp32") if task_check else None
        if task is not None and not task.get("ok"):
            raise ExportError(f"{role}: fp32 task check failed: {task}")
        cmeta = {g.name: {**g.meta, "precision": "fp32"} for g in graphs}
        drop_role(out, role)  # a re-export replaces the role: no stale variants of an older model
        C.add_variant_files(out, role, "fp32", fp32, meta=meta, precision="fp32", parity=par32,
                            component_meta=cmeta, default=True, extra={"task_check": task} if task else None)
        report["variants"]["fp32"] = {"components": {g.name: "fp32" for g in graphs}, "parity": par32, "task": task}

        for variant in ticked([p for p in precisions if p != "fp32"], f"export {role}", "variant"):
            files, parity, cmeta, fell_back = {}, {}, {}, []
            for g in graphs:
                res = _lower_precision(g, variant, fp32[g.name], work)
                if res["ok"]:
                    files[g.name] = res["path"]
                    cmeta[g.name] = {**g.meta, "precision": variant}
                else:
                    files[g.name] = fp32[g.name]
                    cmeta[g.name] = {**g.meta, "precision": "fp32", "fallback_reason": res["reason"]}
                    fell_back.append(f"{g.name}: {res['reason']}")
                    C.progress(f"{role}/{variant}/{g.name}: kept at fp32 ({res['reason']})")
                parity[g.name] = res.get("parity")
            if len(fell_back) == len(graphs):
                reason = "; ".join(fell_back)
                C.record_skipped_variant(out, role, variant, f"every component failed: {reason}")
                report["skipped"][variant] = reason
                continue
            task = task_check(files, variant) if task_check else None
            if task is not None and not task.get("ok"):
                C.record_skipped_variant(out, role, variant, f"task check failed: {task}")
                report["skipped"][variant] = f"task check failed: {task}"
                continue
            notes = None
            if fell_back:
                notes = "components kept at fp32 (not converted, or their parity failed): " + "; ".join(fell_back)
            extra = {"task_check": task} if task else None
            C.add_variant_files(out, role, variant, files, meta=meta, precision=variant,
                                target="accelerator" if variant == "int8-qdq" else "cpu", parity=parity,
                                notes=notes, component_meta=cmeta, extra=extra)
            report["variants"][variant] = {"components": {c: m["precision"] for c, m in cmeta.items()},
                                           "parity": parity, "task": task}
    finally:
        if tmp_ctx is not None:
            tmp_ctx.cleanup()
    return report


# protobuf's hard limit is 2 GiB per file; weights past this go to `<graph>.onnx.data` beside the graph
EXTERNAL_DATA_BYTES = 1 << 30


def needs_external_data(module: Any) -> bool:
    """Whether a torch module's weights (parameters + buffers) are too big for one protobuf file."""
    n = sum(t.numel() * t.element_size() for t in list(module.parameters()) + list(module.buffers()))
    return n > EXTERNAL_DATA_BYTES


def _strip_value_info(src: Path, dst: Path) -> Path:
    """A copy of the graph without the exporter's intermediate `value_info` shapes: onnxruntime's quantiser
    re-infers shapes and rejects some that the dynamo exporter recorded (seen: CLIP's projection, 'Inferred
    shape and existing shape differ'). Same numerics; the quantisers start from this copy."""
    import onnx

    model = onnx.load(str(src))
    model.graph.ClearField("value_info")
    big = _has_external_data(src)  # an external-data source is past the protobuf limit once loaded
    onnx.save(model, str(dst), save_as_external_data=big, location=dst.name + ".data" if big else None)
    return dst


def _has_external_data(path: Path) -> bool:
    from mosaicthinker.host import bundle_write as B

    return bool(B.external_data_locations(path))


def drop_role(out: str | Path, role: str) -> None:
    from mosaicthinker.host import bundle_write as B

    if (Path(out) / B.MANIFEST).is_file():
        manifest = B.read_manifest(out)
        if manifest["roles"].pop(role, None) is not None:
            C.progress(f"{role}: replacing the role's previous variants in {out}")
            B.write_manifest(out, manifest)


def _reference_spread(g: GraphSpec) -> list[float]:
    """Std of each float reference output on one fresh input: a constant output (e.g. a random net whose
    ReLU head is all zero) would make any parity figure vacuous, so it fails the export."""
    outs = torch_reference(g.module, g.input_names)(g.make_inputs(np.random.default_rng(7)))
    idx = g.parity_outputs if g.parity_outputs else range(len(outs))
    spread = [float(np.std(outs[i])) for i in idx if np.issubdtype(outs[i].dtype, np.floating) and outs[i].size > 1]
    if spread and max(spread) == 0.0:
        raise ExportError(f"{g.name}: every float output is constant on random inputs; the parity check would "
                          f"be vacuous (a random-weight model with a dead head?)")
    return spread


def _lower_precision(g: GraphSpec, variant: str, fp32_path: Path, work: Path) -> dict[str, Any]:
    """One component at fp16 / int8-*: converted, then checked against the fp32 graph on fresh inputs."""
    dst = work / variant / f"{g.name}.onnx"
    dst.parent.mkdir(parents=True, exist_ok=True)
    rel, cos = g.tol.get(variant, (None, None))
    if variant == "int4":
        return {"ok": False, "reason": "int4 (MatMulNBits) is built only for GenAI VLM decoders (Qwen2.5-VL)"}
    if variant == "fp16":
        if not g.half:
            return {"ok": False, "reason": "fp16 disabled for this component (numerically unsafe in half)"}
        try:
            # the half wrapper takes *args: name-keyed dynamic shapes become one positional tuple
            ds = g.dynamic_shapes
            if isinstance(ds, dict):
                ds = (tuple(ds.get(n) for n in g.input_names),)
            elif isinstance(ds, (tuple, list)):  # positional, possibly with a nested *args tuple: flatten
                flat: list = []
                for d in ds:
                    flat.extend(d) if isinstance(d, (tuple, list)) else flat.append(d)
                ds = (tuple(flat),)
            C.export_torch(_Half(g.module), g.example, dst, g.input_names, g.output_names, dynamic_shapes=ds)
        except ExportError as e:
            return {"ok": False, "reason": f".half() export failed: {str(e)[:200]}"}
        ref = C.ort_session(fp32_path)
        par = _parity(g, dst, lambda feeds: C.ort_run(ref, feeds), "fp16", f"{g.name} fp16 vs fp32", require=False)
        if par["ok"]:
            return {"ok": True, "path": dst, "parity": par}
        return {"ok": False, "parity": par, "reason": f"fp16 parity vs fp32 failed: rel {par['worst']['rel']:.3g}, "
                                                      f"cosine {par['worst']['cosine']:.4f}"}
    if not g.quantize:
        return {"ok": False, "reason": "int8 disabled for this component (integer/index logic or tiny graph)"}
    fp32_path = _strip_value_info(fp32_path, work / variant / f"{g.name}.src.onnx")
    calib = g.calibration() if (variant == "int8-qdq" and g.calibration) else (
        [g.make_inputs(np.random.default_rng(1000 + i)) for i in range(8)] if variant == "int8-qdq" else ())
    if g.parity_outputs is not None and len(g.parity_outputs) == 0:
        # discrete outputs only: quantise, then judge by set agreement with the fp32 graph
        try:
            if variant == "int8-dynamic":
                C.quantize_int8_dynamic(fp32_path, dst)
            else:
                C.quantize_int8_qdq(fp32_path, dst, calib)
        except Exception as e:  # noqa: BLE001
            return {"ok": False, "reason": f"{variant} conversion failed: {type(e).__name__}: {str(e)[:200]}"}
        ref = C.ort_session(fp32_path)
        par = _parity(g, dst, lambda feeds: C.ort_run(ref, feeds), variant, f"{g.name} {variant} vs fp32",
                      require=False)
        if par["ok"]:
            return {"ok": True, "path": dst, "parity": par}
        dst.unlink(missing_ok=True)
        return {"ok": False, "parity": par, "reason": f"{variant} set agreement vs fp32 "
                                                      f"{par['agreement']['worst']:.3f} < {par['agreement']['min']}"}
    task = None
    if g.agreement is not None:
        ref = C.ort_session(fp32_path)

        def task(path: Path) -> dict[str, Any]:
            return _agreement(g, path, lambda feeds: C.ort_run(ref, feeds), variant, require=False)

    res = C.quantize_variant(fp32_path, dst, variant, make_inputs=g.make_inputs, calibration=calib,
                             outputs=g.parity_outputs, rel_tol=rel, cos_min=cos, task_check=task)
    return res


def _parity(g: GraphSpec, path: Path, reference: Callable, precision: str, label: str, *,
            require: bool) -> dict[str, Any]:
    """Element-wise parity (common.parity_check) on the continuous outputs, plus set agreement for graphs
    with discrete selections. Raises ExportError when require and either fails."""
    rel, cos = g.tol.get(precision, (None, None))
    if g.parity_outputs is not None and len(g.parity_outputs) == 0:
        par: dict[str, Any] = {"ok": True, "precision": precision, "elementwise": "none (discrete outputs only)"}
    else:
        try:
            par = C.parity_check(path, reference, g.make_inputs, precision=precision, outputs=g.parity_outputs,
                                 rel_tol=rel, cos_min=cos, require=require, label=label)
        except ExportError:
            raise
        except Exception as e:  # noqa: BLE001  the graph cannot even run the fresh inputs
            msg = (f"parity check: {path.name} failed to run on fresh inputs ({type(e).__name__}: {str(e)[:300]}); "
                   f"an axis was probably specialised to the export example (declare it dynamic)")
            if require:
                raise ExportError(msg) from e
            return {"ok": False, "precision": precision, "error": msg,
                    "worst": {"rel": float("inf"), "cosine": 0.0, "max_abs": float("inf")}}
    if g.agreement is not None:
        agr = _agreement(g, path, reference, precision, require=require)
        par = {**par, "agreement": agr, "ok": bool(par["ok"] and agr["ok"])}
    return par


def _agreement(g: GraphSpec, path: Path, reference: Callable, precision: str, *, require: bool,
               trials: int | None = None) -> dict[str, Any]:
    return agreement_check(path, reference, g.make_inputs, g.agreement, g.agreement_min.get(precision, 0.9),
                           precision=precision, trials=trials, require=require, label=g.name)


def run_exporter(fn: Callable[..., dict], source: str, precisions: Sequence[str], out: str | Path, *,
                 calib: str | None = None, options: dict[str, str] | None = None) -> dict[str, Any]:
    """The `mosaic export` entry (export/cli.py signature) around an `export_<role>(source, out, precisions,
    **kw)` function: --set KEY=VALUE become keyword arguments (ints/floats parsed), --calib frames are
    read for int8-qdq calibration."""
    kw: dict[str, Any] = {}
    for k, v in (options or {}).items():
        try:
            kw[k] = int(v)
        except ValueError:
            try:
                kw[k] = float(v)
            except ValueError:
                kw[k] = v
    if calib:
        kw["calibration_frames"] = C.calibration_frames(calib)
    rep = fn(source, out, precisions, **kw)
    return {"variants": {v: {c: (r["parity"][c] or {}).get("worst") if r.get("parity") else None
                             for c in r["components"]} for v, r in rep["variants"].items()},
            "components": {v: r["components"] for v, r in rep["variants"].items()},
            "task": {v: _brief_task(r.get("task")) for v, r in rep["variants"].items() if r.get("task")},
            "skipped": rep["skipped"]}


def _brief_task(task: dict[str, Any] | None) -> dict[str, Any] | None:
    return None if task is None else {k: v for k, v in task.items() if k != "runs"}


def _image_calibration(frames: list[np.ndarray] | None, pre: dict[str, Any],
                       name: str) -> Callable[[], list[dict[str, np.ndarray]]] | None:
    """int8-qdq calibration feeds from real frames (None -> the driver's random draws)."""
    from mosaicthinker.runtime.models import preprocess_image

    if not frames:
        return None
    return lambda: [{name: preprocess_image(f, pre)} for f in frames]


def word_level_tokenizer(vocab: dict[str, int], specials: Sequence[str], path: str | Path) -> Path:
    """Write a whitespace WordLevel `tokenizer.json` (tiny test models): `vocab` token -> id with an "[UNK]"
    entry; `specials` are added as special tokens (never split, not normalised)."""
    from tokenizers import AddedToken, Tokenizer, models, pre_tokenizers

    tok = Tokenizer(models.WordLevel(vocab, unk_token="[UNK]"))
    tok.pre_tokenizer = pre_tokenizers.Whitespace()
    tok.add_special_tokens([AddedToken(t, special=True, normalized=False) for t in specials])
    path = Path(path)
    tok.save(str(path))
    return path


def save_hf_tokenizer(source: str, dst: Path) -> None:
    """tokenizer.json of a real checkpoint (`hf:ID[@rev]` or `dir:PATH`; the fast tokenizer saved by
    transformers)."""
    from transformers import AutoTokenizer

    ident = source[3:].partition("@")[0] if source.startswith("hf:") else source[4:]
    tok = AutoTokenizer.from_pretrained(ident)
    with tempfile.TemporaryDirectory() as d:
        tok.save_pretrained(d)
        src = Path(d) / "tokenizer.json"
        if not src.is_file():
            raise ExportError(f"--source {source}: the tokenizer has no tokenizer.json (needs a fast tokenizer)")
        dst.write_bytes(src.read_bytes())


def write_tokenizer(out: str | Path, role: str, source: str, random_weights: bool,
                    build_tiny: Callable[[Path], Path]) -> Path:
    """`OUT/ROLE/tokenizer.json`: built by `build_tiny(path)` for a random-weight test model, else the real
    checkpoint's own tokenizer (`save_hf_tokenizer`)."""
    dst = Path(out) / role / "tokenizer.json"
    dst.parent.mkdir(parents=True, exist_ok=True)
    if random_weights:
        build_tiny(dst)
    else:
        save_hf_tokenizer(source, dst)
    return dst
