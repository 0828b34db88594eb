"""The files of `mosaic profile --out DIR` (host side): report.json, report.md and Pillow bar charts.

The measurements and the Markdown text live in `runtime/commands/profile.py`; here they become files, written as one
group through `runtime/infra/outputs.py` (folder checked and locked, every file staged in a temp file and renamed,
the run id in each, a failed image encode raised, never skipped).
"""
from __future__ import annotations

import os
from typing import Any

import numpy as np

from mosaicthinker.runtime.infra.errors import OutputError
from mosaicthinker.runtime.infra.outputs import write_group
from mosaicthinker.runtime.commands.profile import render, report_rows
from mosaicthinker.runtime.infra.trace import Trace, jsonable

_DEFAULT_LEGEND = "bars: p50, whisker: p90"


def _font(size: int) -> Any:
    from PIL import ImageFont

    for name in ("DejaVuSans.ttf", "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf"):
        try:
            return ImageFont.truetype(name, size)
        except OSError:
            continue
    return ImageFont.load_default()


def bar_chart(title: str, labels: list[str], values: list[float], whiskers: list[float] | None = None,
              unit: str = "ms", marks: list[bool] | None = None, legend: str = _DEFAULT_LEGEND) -> np.ndarray:
    """Horizontal bar chart as RGB [H, W, 3] uint8 (Pillow): one bar per label, optional p90 whisker, '*' marks
    random weights; NaN values are drawn as "error"."""
    from PIL import Image, ImageDraw

    n = max(len(labels), 1)
    W, row, left, top = 900, 26, 260, 50
    H = top + n * row + 40
    img = Image.new("RGB", (W, H), "white")
    d = ImageDraw.Draw(img)
    f, fs = _font(14), _font(12)
    d.text((10, 12), title, fill="black", font=_font(16))
    vmax = max([v for v in values + (whiskers or []) if v == v] + [1e-9])
    scale = (W - left - 90) / vmax
    for i, (lab, v) in enumerate(zip(labels, values)):
        y = top + i * row
        mark = marks[i] if marks else False
        d.text((10, y + 4), (lab + (" *" if mark else ""))[:34], fill="black", font=fs)
        if v != v:  # nan: error
            d.text((left, y + 4), "error", fill=(180, 0, 0), font=fs)
            continue
        colour = (200, 90, 60) if mark else (60, 110, 190)
        d.rectangle([left, y + 4, left + max(1, int(v * scale)), y + row - 6], fill=colour)
        if whiskers and whiskers[i] == whiskers[i]:
            x = left + int(whiskers[i] * scale)
            d.line([left + int(v * scale), y + row // 2, x, y + row // 2], fill="black", width=1)
            d.line([x, y + 7, x, y + row - 9], fill="black", width=1)
        d.text((left + max(1, int(max(v, whiskers[i] if whiskers else v) * scale)) + 6, y + 4),
               f"{v:.1f} {unit}", fill="black", font=fs)
    foot = legend if (whiskers or legend != _DEFAULT_LEGEND) else ""
    if marks and any(marks):
        foot += ("; " if foot else "") + "* random weights (timings real, outputs not)"
    d.text((10, H - 24), foot, fill=(90, 90, 90), font=f)
    return np.asarray(img, dtype=np.uint8)


def report_items(report: dict[str, Any]) -> list[tuple[str, str, Any]]:
    """The report's files as `outputs.save_run` items: (key, file name, dict | text | RGB image)."""
    nan = float("nan")
    rows = report_rows(report)
    cpu = report.get("cpu_side", {})
    lat_rows = rows + [{"name": f"cpu: {k}", "p50": v["latency_ms"]["p50"], "p90": v["latency_ms"]["p90"],
                        "random": False} for k, v in cpu.items() if "latency_ms" in v]
    for k, v in cpu.items():
        if "ms_per_frame" in v:
            lat_rows.append({"name": f"cpu: {k} / frame", "p50": v["ms_per_frame"], "p90": nan, "random": False})
    items: list[tuple[str, str, Any]] = [("report.json", "report.json", jsonable(report)),
                                         ("report.md", "report.md", render(report))]
    stages = (report.get("pipeline") or {}).get("stages", {})
    if stages:  # totals of one question, on their own scale (seconds, not ms per call)
        items.append(("pipeline.png", "pipeline.png", bar_chart(
            f"one question, time per stage: {report['pipeline'].get('question')}", list(stages),
            [st["seconds"] for st in stages.values()], None, "s",
            legend="nested stages overlap (e.g. detect contains detector)")))
    items.append(("latency.png", "latency.png", bar_chart(
        f"latency per model / stage (bundle {report['bundle_hash']})", [r["name"] for r in lat_rows],
        [r.get("p50", nan) for r in lat_rows], [r.get("p90", nan) for r in lat_rows], "ms",
        [r["random"] for r in lat_rows])))
    items.append(("memory.png", "memory.png", bar_chart(
        f"resident memory per model (bundle {report['bundle_hash']})", [r["name"] for r in rows],
        [r.get("mem", nan) for r in rows], [r.get("peak", nan) for r in rows], "MB", [r["random"] for r in rows],
        legend="bars: RSS increase after load + runs, whisker: peak increase")))
    return items


def save_report(report: dict[str, Any], out: str | os.PathLike, trace: Trace | None = None) -> dict[str, Any]:
    """Write the report files into `out` as one group; records `files`, `run_id` (and `write_error` +
    `exit_code` when the write failed, so the caller still prints the report) in `report`. Returns `report`."""
    return write_group(out, report_items(report), report, trace)


def write_report(report: dict[str, Any], out: str | os.PathLike) -> dict[str, str]:
    """report.json, report.md, latency.png, memory.png (and pipeline.png after a full question) into `out`;
    returns {file name: path}. Raises OutputError when the files could not be written."""
    res = write_group(out, report_items(report), {})
    if res.get("write_error"):
        raise OutputError(res["write_error"].removeprefix("error: "))
    return {name: path for name, path in res["files"].items()}

