"""Real indoor-scene statistics from VSI-Bench's `meta_info.json` (ARKitScenes rooms), used to draw synthetic scenes.

The statistics are fixed before any tuning: `compute_stats(meta_info)` reads the benchmark's own per-room boxes and
keeps, per category, the share of rooms that hold it, the histogram of its count per room, and a log-normal fit
of its box dimensions (horizontal long side, horizontal short side, height) with the observed min/max; over rooms,
the empirical quantiles of the floor area (`room_size`) and of the total object count. The complexity levels
(low/med/high object number, small/medium/large rooms) are the terciles of those two distributions.

The result is checked in as `vsibench_stats.json` (so `mosaic synth` works without ../shared) and is reproducible:

    python -m mosaicthinker.host.synth.stats --meta ../shared/data/vsibench/meta_info.json \
        --out host/synth/vsibench_stats.json

(tests/test_synth.py recomputes it from ../shared and compares).
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np

from mosaicthinker.runtime.infra import jsonio
from mosaicthinker.runtime.infra.errors import InputError

STATS_PATH = Path(__file__).with_name("vsibench_stats.json")
STATS_SCHEMA = "mosaicthinker.synth.vsibench_stats/1"
QUANTILES = np.linspace(0.0, 1.0, 21)


def box_dims(box: dict[str, Any]) -> np.ndarray:
    """meta_info box -> [3] (horizontal long, horizontal short, height) in metres. The height is the length along
    the box axis closest to vertical (rows of `normalizedAxes` are the axes)."""
    axes = np.asarray(box["normalizedAxes"], dtype=np.float64).reshape(3, 3)
    lengths = np.asarray(box["axesLengths"], dtype=np.float64).reshape(3)
    k = int(np.argmax(np.abs(axes[:, 2])))
    h = lengths[k]
    horiz = np.sort(np.delete(lengths, k))[::-1]
    return np.array([horiz[0], horiz[1], h])


def compute_stats(meta: dict[str, Any], source: str = "meta_info.json") -> dict[str, Any]:
    """Statistics of a VSI-Bench meta_info dict (scene -> room_size, object_bbox ...). Pure function of its input."""
    cats: dict[str, dict[str, Any]] = {}
    room_sizes, totals = [], []
    scenes = sorted(meta)
    for name in scenes:
        s = meta[name]
        if "object_bbox" not in s or "room_size" not in s:
            raise InputError(f"{source}: scene {name} lacks `object_bbox` or `room_size`")
        room_sizes.append(float(s["room_size"]))
        n = 0
        for cat, boxes in s["object_bbox"].items():
            c = cats.setdefault(cat, {"rooms": 0, "counts": [], "dims": []})
            c["rooms"] += 1
            c["counts"].append(len(boxes))
            c["dims"] += [box_dims(b) for b in boxes]
            n += len(boxes)
        totals.append(n)
    out_cats = {}
    for cat in sorted(cats):
        c = cats[cat]
        d = np.array(c["dims"])
        logd = np.log(np.maximum(d, 1e-3))
        cov = np.cov(logd.T) if len(d) > 1 else np.zeros((3, 3))
        hist: dict[str, int] = {}
        for k in c["counts"]:
            hist[str(k)] = hist.get(str(k), 0) + 1
        out_cats[cat] = {
            "rooms": c["rooms"], "p_room": c["rooms"] / len(scenes), "instances": int(len(d)),
            "count_hist": dict(sorted(hist.items(), key=lambda kv: int(kv[0]))),
            "log_mean": logd.mean(0).round(6).tolist(), "log_cov": np.round(cov, 6).tolist(),
            "dims_min": d.min(0).round(4).tolist(), "dims_max": d.max(0).round(4).tolist(),
            "dims_median": np.median(d, 0).round(4).tolist()}
    rs, tt = np.array(room_sizes), np.array(totals, dtype=np.float64)
    return {
        "schema": STATS_SCHEMA, "source": source, "scenes": len(scenes),
        "dims_order": ["horizontal_long", "horizontal_short", "height"],
        "room_size_quantiles": np.quantile(rs, QUANTILES).round(4).tolist(),
        "object_total_quantiles": np.quantile(tt, QUANTILES).round(4).tolist(),
        "levels": {
            "room": {"small": [float(rs.min()), float(np.quantile(rs, 1 / 3))],
                     "medium": [float(np.quantile(rs, 1 / 3)), float(np.quantile(rs, 2 / 3))],
                     "large": [float(np.quantile(rs, 2 / 3)), float(rs.max())]},
            # object totals are integers: low = 1..q1, med = q1+1..q2, high = q2+1..max
            "objects": {"low": [int(tt.min()), int(np.floor(np.quantile(tt, 1 / 3)))],
                        "med": [int(np.floor(np.quantile(tt, 1 / 3))) + 1, int(np.floor(np.quantile(tt, 2 / 3)))],
                        "high": [int(np.floor(np.quantile(tt, 2 / 3))) + 1, int(tt.max())]},
        },
        "categories": out_cats,
    }


def load_meta_info(path: str | Path) -> dict[str, Any]:
    p = Path(path)
    try:
        return json.loads(p.read_text())
    except (OSError, json.JSONDecodeError) as e:
        raise InputError(f"{p}: cannot read VSI-Bench meta_info ({e})") from None


def load_stats(path: str | Path | None = None) -> dict[str, Any]:
    """The checked-in statistics (default) or a JSON written by this module, or a meta_info.json (computed)."""
    p = Path(path) if path is not None else STATS_PATH
    try:
        d = json.loads(p.read_text())
    except (OSError, json.JSONDecodeError) as e:
        raise InputError(f"{p}: cannot read scene statistics ({e}); regenerate with "
                         f"`python -m mosaicthinker.host.synth.stats --meta META --out {p}`") from None
    if d.get("schema") == STATS_SCHEMA:
        return d
    if all(isinstance(v, dict) and "object_bbox" in v for v in d.values()):
        return compute_stats(d, p.name)
    raise InputError(f"{p}: neither scene statistics (schema {STATS_SCHEMA}) nor a VSI-Bench meta_info.json")


# ----------------------------------------------------------------------------- sampling


def sample_quantiles(q: list[float], rng: np.random.Generator, lo: float | None = None,
                     hi: float | None = None) -> float:
    """Inverse-CDF draw from an empirical distribution given by its quantiles at `QUANTILES`, restricted to
    [lo, hi] (the level's range)."""
    qv = np.asarray(q, dtype=np.float64)
    ps = QUANTILES
    p_lo = 0.0 if lo is None else float(np.interp(lo, qv, ps))
    p_hi = 1.0 if hi is None else float(np.interp(hi, qv, ps))
    return float(np.interp(rng.uniform(p_lo, p_hi), ps, qv))


def sample_dims(cat_stats: dict[str, Any], rng: np.random.Generator) -> np.ndarray:
    """[3] (long, short, height) metres from the category's log-normal fit, redrawn until inside the observed
    [min, max] per dimension (clipped after 50 tries), long >= short kept."""
    mu = np.asarray(cat_stats["log_mean"])
    cov = np.asarray(cat_stats["log_cov"])
    lo, hi = np.asarray(cat_stats["dims_min"]), np.asarray(cat_stats["dims_max"])
    d = np.exp(mu)
    for _ in range(50):
        if not np.any(cov):
            break
        try:
            d = np.exp(rng.multivariate_normal(mu, cov, method="cholesky"))
        except np.linalg.LinAlgError:  # singular fit (few instances): eigen-decomposition copes
            d = np.exp(rng.multivariate_normal(mu, cov, method="eigh"))
        if np.all(d >= lo) and np.all(d <= hi):
            break
    d = np.clip(d, lo, hi)
    if d[1] > d[0]:
        d[0], d[1] = d[1], d[0]
    return d


def sample_count(cat_stats: dict[str, Any], rng: np.random.Generator) -> int:
    """Count per room given the category is present, from its histogram."""
    ks = np.array([int(k) for k in cat_stats["count_hist"]])
    w = np.array(list(cat_stats["count_hist"].values()), dtype=np.float64)
    return int(rng.choice(ks, p=w / w.sum()))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="derive synthetic-scene statistics from VSI-Bench meta_info.json")
    ap.add_argument("--meta", required=True, help="path to meta_info.json")
    ap.add_argument("--out", default=str(STATS_PATH))
    a = ap.parse_args(argv)
    stats = compute_stats(load_meta_info(a.meta), Path(a.meta).name)
    Path(a.out).write_text(jsonio.dumps(stats, indent=1) + "\n")
    print(f"wrote {a.out}: {stats['scenes']} scenes, {len(stats['categories'])} categories")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
