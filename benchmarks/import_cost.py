"""Import and bundle-load cost of the device runtime (issue 11: <= 0.5 s and <= 80 MB RSS).

    python benchmarks/import_cost.py [--bundle B] [--runs 7] [--out benchmarks/results/import_cost.json]

Each case runs in --runs fresh interpreter processes (nothing cached in the process; the OS file cache is warm
after the first run, as on a device that has started the app before). In each process the clock starts after
the interpreter is up and stops after the step:

- `import`: `import mosaicthinker.runtime`;
- `import+load`: that, then `load_bundle(BUNDLE, verify=False)` (manifest read and schema-checked);
- `import+load+verify`: that with `verify=True` (every artifact's sha256, external data, unlisted files);
- `import+load+verify+pipeline` (information, not the target): that plus `mosaicthinker.runtime.ask`, i.e. the
  pipeline module and what it imports at module level before a first question.

RSS is the process's resident set (VmRSS) after the step, and its increase over the bare interpreter (measured
in the same process before the import). The figures are medians over the runs; the machine's load average is
recorded, since on a shared machine timings are inflated.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
TARGET_S, TARGET_MB = 0.5, 80.0

_CHILD = r"""
import time, json
def rss_mb():
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
base = rss_mb()
t0 = time.perf_counter()
import mosaicthinker.runtime as R
step = {step!r}
if step != "import":
    R.load_bundle({bundle!r}, verify=(step != "import+load"))
if step == "import+load+verify+pipeline":
    R.ask  # the pipeline module and what it imports at module level (numpy, OpenCV, ...)
dt = time.perf_counter() - t0
import sys
print(json.dumps({{"seconds": dt, "rss_mb": rss_mb(), "rss_increase_mb": rss_mb() - base,
                   "modules": len(sys.modules)}}))
"""

STEPS = ("import", "import+load", "import+load+verify", "import+load+verify+pipeline")
TARGETED = STEPS[:3]  # the target; the last case is for information (what a first question imports)


def run_case(step: str, bundle: str, runs: int) -> dict[str, Any]:
    rows = []
    for _ in range(runs):
        t0 = time.perf_counter()
        out = subprocess.run([sys.executable, "-c", _CHILD.format(step=step, bundle=bundle)], capture_output=True,
                             text=True, timeout=120, check=True)
        row = json.loads(out.stdout.strip().splitlines()[-1])
        row["process_seconds"] = time.perf_counter() - t0  # interpreter start included
        rows.append(row)
    med = {k: round(statistics.median(r[k] for r in rows), 3)
           for k in ("seconds", "rss_mb", "rss_increase_mb", "process_seconds", "modules")}
    return {"step": step, "runs": len(rows), "median": med,
            "max_seconds": round(max(r["seconds"] for r in rows), 3),
            "meets_target": (med["seconds"] <= TARGET_S and med["rss_mb"] <= TARGET_MB) if step in TARGETED
            else None,
            "all": [{k: round(v, 3) for k, v in r.items()} for r in rows]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--bundle", default=os.environ.get("MOSAIC_BUNDLE"), required="MOSAIC_BUNDLE" not in os.environ,
                    help="an exported bundle (default: $MOSAIC_BUNDLE)")
    ap.add_argument("--runs", type=int, default=7, help="fresh processes per case (median reported; >= 5)")
    ap.add_argument("--out", default=str(REPO / "benchmarks" / "results" / "import_cost.json"))
    a = ap.parse_args()
    if a.runs < 5:
        ap.error("--runs must be >= 5 (the figure is a median)")
    res: dict[str, Any] = {"schema": "mosaicthinker.bench.import_cost/1", "command": " ".join(sys.argv),
                           "bundle": a.bundle, "python": sys.version.split()[0], "cores": os.cpu_count(),
                           "targets": {"seconds": TARGET_S, "rss_mb": TARGET_MB},
                           "loadavg_start": [round(x, 2) for x in os.getloadavg()]}
    res["cases"] = {s: run_case(s, a.bundle, a.runs) for s in STEPS}
    res["loadavg_end"] = [round(x, 2) for x in os.getloadavg()]
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(json.dumps(res, indent=1) + "\n")
    for s, c in res["cases"].items():
        m = c["median"]
        print(f"{s:<20} median {m['seconds']:.3f} s (max {c['max_seconds']:.3f}), RSS {m['rss_mb']:.1f} MB "
              f"(+{m['rss_increase_mb']:.1f} over the interpreter), process {m['process_seconds']:.2f} s: "
              + ("(information, no target)" if c["meets_target"] is None else
                 f"{'meets' if c['meets_target'] else 'MISSES'} <= {TARGET_S} s / {TARGET_MB:.0f} MB"))
    print(f"load average {res['loadavg_start']} -> {res['loadavg_end']} on {os.cpu_count()} cores")


if __name__ == "__main__":
    main()
