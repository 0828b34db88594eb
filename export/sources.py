"""Model sources of the Hugging Face exporters: `hf:ID[@REV]`, `dir:PATH`, `tiny`, `tiny:ARCH`.

Its own module (not export/hf_common.py) so the export driver does not depend on the tiny builders, which
import the architecture modules (export/hf_qwen_vl.py) that use the driver: no import circle.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

from mosaicthinker.runtime.infra.errors import ExportError


def load_source(source: str, role: str, hf_class: Any, *, tiny_kwargs: dict | None = None) -> tuple[Any, dict]:
    """The torch model for `hf:ID[@REV]`, `dir:PATH`, `tiny` or `tiny:ARCH`, and its provenance.

    hf_class: the transformers class to call `from_pretrained` on (real checkpoints; needs the hub or a local
    folder). Returns (model in eval mode, {"source", "arch"?, "random_weights"}).
    """
    from . import tiny

    if source == "tiny" or source.startswith("tiny:"):
        arch = tiny.resolve(role, source)
        return tiny.build(arch, **(tiny_kwargs or {})), {"source": f"tiny:{arch}", "arch": arch,
                                                       "random_weights": True, "seed": tiny.SEED}
    if source.startswith("hf:"):
        ident, _, rev = source[3:].partition("@")
        kw = {"revision": rev} if rev else {}
    elif source.startswith("dir:"):
        ident, kw = source[4:], {}
        if not Path(ident).is_dir():
            raise ExportError(f"--source {source}: folder {ident} does not exist")
    else:
        raise ExportError(f"--source {source}: expected hf:ID, dir:PATH, tiny or tiny:ARCH for the {role} role")
    try:
        model = hf_class.from_pretrained(ident, **kw)
    except Exception as e:  # noqa: BLE001  (hub/network/format errors all end here)
        raise ExportError(f"--source {source}: could not load {hf_class.__name__} ({type(e).__name__}: "
                          f"{str(e)[:300]}); model hubs need network access, else pass dir:PATH of a local "
                          f"checkpoint") from e
    model.eval()
    marker = Path(ident) / "RANDOM_WEIGHTS.json" if source.startswith("dir:") else None
    if marker is not None and marker.is_file():  # a random-weight checkpoint of a real config (benchmarks)
        import json

        return model, {"source": source, "random_weights": True, "random": json.loads(marker.read_text())}
    return model, {"source": source, "random_weights": False}
