"""Object-size priors for metric scale (`runtime/map/scale.py`): per category and per box dimension (horizontal long,
horizontal short, height; `stats.box_dims`), the median and the spread (1.4826 x MAD of the log, floored at 0.03) of
real oriented boxes, from VSI-Bench's `meta_info.json` (150 ARKitScenes rooms, none of them an evaluation room here).
Categories with fewer than `--min-instances` boxes are left out. Regenerate the checked-in table with:

    python -m mosaicthinker.host.synth.size_priors --meta ../shared/data/vsibench/meta_info.json \
        --out runtime/map/size_priors.json
"""
from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import numpy as np

from mosaicthinker.runtime.infra import jsonio
from mosaicthinker.runtime.infra.errors import InputError
from mosaicthinker.runtime.infra.outputs import write_file_atomic

from .stats import box_dims, load_meta_info

PRIORS_SCHEMA = "mosaicthinker.size_priors/1"


def size_priors(meta: dict[str, Any], min_instances: int = 10, source: str = "meta_info.json") -> dict[str, Any]:
    """The priors table of a meta_info dict (scene -> object_bbox: category -> boxes). Pure function."""
    dims: dict[str, list[np.ndarray]] = {}
    for name in sorted(meta):
        boxes = meta[name].get("object_bbox")
        if not isinstance(boxes, dict):
            raise InputError(f"{source}: scene {name} lacks `object_bbox`")
        for cat, bs in boxes.items():
            dims.setdefault(cat, []).extend(box_dims(b) for b in bs)
    cats = {}
    for cat in sorted(dims):
        d = np.log(np.maximum(np.array(dims[cat]), 1e-3))
        if len(d) < min_instances:
            continue
        med = np.median(d, 0)
        sd = np.maximum(1.4826 * np.median(np.abs(d - med), 0), 0.03)
        cats[cat] = {"n": int(len(d)), "median_m": np.round(np.exp(med), 4).tolist(), "log_sd": np.round(sd, 4).tolist()}
    return {"schema": PRIORS_SCHEMA, "source": source, "scenes": len(meta),
            "dims_order": ["horizontal_long", "horizontal_short", "height"], "categories": cats}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--meta", required=True, help="VSI-Bench meta_info.json")
    ap.add_argument("--out", required=True, help="where the table goes (runtime/map/size_priors.json)")
    ap.add_argument("--min-instances", type=int, default=10)
    a = ap.parse_args(argv)
    table = size_priors(load_meta_info(a.meta), a.min_instances, Path(a.meta).name)
    write_file_atomic(Path(a.out), jsonio.dumps(table, indent=1) + "\n")
    print(f"wrote {a.out}: {len(table['categories'])} categories from {table['scenes']} rooms")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
