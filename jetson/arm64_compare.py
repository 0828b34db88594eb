"""The verdict of jetson/arm64_check.sh: the aarch64 run's demo and ask against the x86 run's.

python jetson/arm64_compare.py --out OUT --start EPOCH_S [--x86-ref FILE]

Reads OUT/{x86,arm64}/{demo,ask}.json (the `--json` outputs) and OUT/arm64/*/trace.json (`host.machine`, what the
mosaic process itself reported), or the x86 side from FILE (an earlier OUT/arm64_check.json, for --native runs on
a device). Writes OUT/arm64_check.json atomically and prints the summary as the last line of stdout; exit 0 when
the targets are met (machine aarch64, demo mean score >= 0.9, every answer equal to x86's), 1 otherwise.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path
from typing import Any

MIN_DEMO_SCORE = 0.9
RUNTIME_DISTS = ("numpy", "scipy", "opencv-python-headless", "onnxruntime", "pillow", "psutil", "tokenizers",
                 "tqdm", "tomli_w")


def answers(side_dir: Path) -> dict[str, Any]:
    """{demo_score, demo: [[type, answer], ...], ask: {status, answer, value}, machine} of one side's run."""
    demo = json.loads((side_dir / "demo.json").read_text())
    ask = json.loads((side_dir / "ask.json").read_text())
    machines = {json.loads(t.read_text()).get("host", {}).get("machine")
                for t in (side_dir / "demo" / "trace.json", side_dir / "ask" / "trace.json") if t.is_file()}
    return {"machine": machines.pop() if len(machines) == 1 else sorted(map(str, machines)),
            "demo_score": demo.get("mean_score"), "demo": [[q["type"], q["answer"]] for q in demo["questions"]],
            "ask": {k: ask.get(k) for k in ("status", "answer", "value")},
            "seconds": {"demo": demo.get("seconds"), "ask": ask.get("seconds")}}


def wheel_tags(folder: Path) -> dict[str, str]:
    """{distribution: wheel file name} of the aarch64 wheels pip downloaded."""
    out = {}
    for w in sorted(folder.glob("*.whl")) if folder.is_dir() else []:
        out[w.name.split("-")[0].lower().replace("_", "-")] = w.name
    return out


def installed_tags() -> dict[str, str]:
    """{distribution: its WHEEL tags} of this (x86) interpreter's runtime dependencies."""
    from importlib import metadata

    out = {}
    for name in RUNTIME_DISTS:
        try:
            d = metadata.distribution(name)
        except metadata.PackageNotFoundError:
            continue
        tags = [ln.split(":", 1)[1].strip() for ln in (d.read_text("WHEEL") or "").splitlines()
                if ln.startswith("Tag:")]
        out[name.replace("_", "-")] = f"{d.version} {','.join(tags)}"
    return out


def verdict(x86: dict[str, Any], arm: dict[str, Any]) -> dict[str, Any]:
    equal = x86["demo"] == arm["demo"] and x86["ask"] == arm["ask"]
    return {"machine": arm["machine"], "demo_score": arm["demo_score"], "ask_status": arm["ask"]["status"],
            "answers_equal_x86": bool(equal)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--start", type=float, required=True, help="the check's start (seconds since the epoch)")
    ap.add_argument("--x86-ref", type=Path, help="an earlier arm64_check.json whose x86 side to compare with")
    a = ap.parse_args(argv)
    x86 = json.loads(a.x86_ref.read_text())["x86"] if a.x86_ref else answers(a.out / "x86")
    arm = answers(a.out / "arm64")
    summary = {**verdict(x86, arm), "seconds": round(time.time() - a.start, 1)}
    ok = (summary["machine"] == "aarch64" and (summary["demo_score"] or 0) >= MIN_DEMO_SCORE
          and summary["answers_equal_x86"])
    report = {"schema": "mosaicthinker.arm64_check/1", "summary": summary, "targets_met": ok,
              "min_demo_score": MIN_DEMO_SCORE, "x86": x86, "arm64": arm,
              "wheels": {"aarch64": wheel_tags(a.out / "wheels-arm64"),
                         "x86_installed": installed_tags() if not a.x86_ref else None},
              "when": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}
    tmp = a.out / f"arm64_check.json.tmp-{os.getpid()}"
    tmp.write_text(json.dumps(report, indent=2) + "\n")
    os.replace(tmp, a.out / "arm64_check.json")
    print(json.dumps(summary))
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
