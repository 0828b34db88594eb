"""The reliability campaign of issue 29 (tests/campaign.py), every case, counted per class and outcome.

    python benchmarks/reliability_campaign.py [--classes map,manifest,...] [--stratified] [--label after] [--seed N]
                                              [--out benchmarks/results/reliability_campaign.json]

Field-damage classes run every (field path x damage) pair (`--stratified`: the suite's subset). The result is
merged into the JSON under `--label` (e.g. "before" for a run of older code through PYTHONPATH, "after"), with
the command, date, load and the cases that crashed, hung or answered silently wrong.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))


def main() -> None:
    import campaign
    import mosaicthinker.runtime as rt

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--classes", default="", help="comma-separated class names (default: all): "
                    + ", ".join({**campaign.FIELD_CLASSES, **campaign.EXTRA_CLASSES}))
    ap.add_argument("--stratified", action="store_true", help="the test suite's subset of field damage")
    ap.add_argument("--label", default="after")
    ap.add_argument("--seed", type=int, default=0, help="seed of the generated classes (issue 36's: question "
                    "numbers, ground truth, far maps ...); another seed draws held-out variants")
    ap.add_argument("--out", default=str(REPO / "benchmarks" / "results" / "reliability_campaign.json"))
    a = ap.parse_args()
    only = tuple(c for c in a.classes.split(",") if c) or None
    os.environ["MOSAIC_CAMPAIGN_SEED"] = str(a.seed)
    load0, t0 = os.getloadavg()[0], time.time()
    recs = campaign.run_all(only, full=not a.stratified)
    s = campaign.summary(recs)
    res = {"command": "python " + " ".join(sys.argv), "date": time.strftime("%Y-%m-%d %H:%M"),
           "code": str(Path(rt.__file__).resolve().parent), "seconds": round(time.time() - t0, 1),
           "seed": a.seed, "load_start": round(load0, 2), "load_end": round(os.getloadavg()[0], 2),
           "cpus": os.cpu_count(), **s}
    out = Path(a.out)
    doc = json.loads(out.read_text()) if out.is_file() else {}
    doc[a.label] = res
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(doc, indent=1) + "\n")
    print(json.dumps({"cases": s["cases"], "total": s["total"]}, indent=1))
    for f in s["failures"][:30]:
        print(f)


if __name__ == "__main__":
    main()
