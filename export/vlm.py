"""`mosaic export vlm`: one entry that picks the VLM exporter per source family (registered in export/cli.py).

Qwen2.5-VL goes to the ONNX Runtime GenAI packager (export/hf_qwen_vl.py); Qwen3-VL to the project's own graphs
(export/hf_qwen3_vl.py: GenAI 0.18.0 has no DeepStack input); SmolVLM / InternVL to export/hf_vlm.py. It sits
above the three so none of them imports another's dispatcher."""
from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

from . import hf_qwen3_vl, hf_qwen_vl, hf_vlm


def export_role(role: str, source: str, precisions: Sequence[str], out: str | Path, *, calib: str | None = None,
                options: dict[str, str] | None = None, **kw: Any) -> dict[str, Any]:
    """`mosaic export vlm --source hf:ID|dir:PATH|tiny[:ARCH]`."""
    if hf_qwen3_vl.is_qwen3_source(source):
        return hf_qwen3_vl.export_role(role, source, precisions, out, options=options)
    if hf_qwen_vl.is_qwen_source(source):
        return hf_qwen_vl.export_role(role, source, precisions, out, options=options)
    return hf_vlm.export_role(role, source, precisions, out, calib=calib, options=options, **kw)
