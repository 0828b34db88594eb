"""RGB-only key-frame poses on the real rooms (issue 38): `mosaic eval pose --depth model --path ask` (structure
from motion over the key frames and the scan's kept frames, `align.rgb_stage`) per room, with the accounting of
`real_rooms.pose_row` (registered share, ATE after SE(3) and Sim(3), the Sim(3)'s scale, what was lost where),
beside the same rooms' pycolmap oracle (`sfm_oracle.py`) when `--oracle`.

    python benchmarks/rgb_poses.py --bundle BUNDLE [--keyframes 32] [--oracle] \
        [--rooms 7scenes-redkitchen,scannet-scene0000_00,hololens-lounge] [--out benchmarks/results/rgb_poses.json]
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from real_rooms import SHARED, pose_row  # noqa: E402
from mosaicthinker.runtime.infra import jsonio  # noqa: E402
from mosaicthinker.runtime.infra.outputs import write_file_atomic  # noqa: E402

TARGETS = {"registered_share": 0.9, "ate_sim3_m": 0.10, "ate_sim3_kitchen_m": 0.06}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--bundle", default=os.environ.get("MOSAIC_BUNDLE"),
                    help="the bundle to evaluate with (default: $MOSAIC_BUNDLE)")
    ap.add_argument("--keyframes", type=int, default=32)
    ap.add_argument("--rooms", default="7scenes-redkitchen,scannet-scene0000_00,hololens-lounge")
    ap.add_argument("--oracle", action="store_true", help="also pycolmap's global mapper over the same frames")
    ap.add_argument("--out", default=str(Path(__file__).resolve().parent / "results" / "rgb_poses.json"))
    a = ap.parse_args()
    if not a.bundle:
        print("error: no bundle: pass --bundle DIR or set MOSAIC_BUNDLE (a bundle with a depth model and a matcher)",
              file=sys.stderr)
        return 2
    if not (Path(a.bundle) / "manifest.json").is_file():
        print(f"error: --bundle {a.bundle}: no manifest.json there; pass an exported bundle directory", file=sys.stderr)
        return 2
    rows = {}
    for name in a.rooms.split(","):
        room = SHARED / "data" / name
        load = os.getloadavg()[0]
        row = pose_row(room, Path(a.bundle), "model", a.keyframes, "ask")
        row["load_before"] = round(load, 2)
        if row.get("of"):
            row["registered_share"] = round(row["aligned"] / row["of"], 3)
        if a.oracle:
            from sfm_oracle import oracle

            row["oracle"] = oracle(str(room), a.keyframes, 0, 3)
        rows[name] = row
        print(name, {k: row.get(k) for k in ("aligned", "of", "ate_sim3_m", "ate_se3_m", "sim3_scale", "seconds")},
              file=sys.stderr)
    res = {"date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()), "keyframes": a.keyframes,
           "bundle": a.bundle, "targets": TARGETS, "machine": f"{os.cpu_count()} CPUs, shared", "rooms": rows}
    write_file_atomic(a.out, jsonio.dumps(res, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
