"""Per key frame perception cost: the detector (YOLOX-Nano) + the instance segmenter (YOLO11n-seg: detections with
one mask each) + their merge, on real 640x480 kitchen frames, through the runtime adapters (pre/post-processing and
mask decoding included), each frame new to the models (no cache hit).

    python benchmarks/perception_keyframe.py --bundle B [--frames 24] [--threads 2] [--variants fp32]
                                             [--results benchmarks/results/perception_keyframe.json]

Reports per configuration the median / p90 wall ms per key frame and the CPU ms (process time: on a shared machine
wall time grows with the other jobs, CPU time much less), the load average before and after, and how many
detections and masks a frame gave. B: `mosaic export shared-models` (YOLOX-Nano detector, YOLO11n-seg instance
segmenter). Configurations: detector alone, instance segmenter alone ("one model, one pass"), both merged (what
`perception_from_bundle` gives key frames by default).
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("MOSAIC_SHARED", REPO.parent / "shared"))
DATA = SHARED / "data" / "7scenes-redkitchen"
OUT = REPO / "benchmarks" / "results" / "perception_keyframe.json"


def frames(n: int) -> list[np.ndarray]:
    import cv2

    files = sorted(DATA.glob("frame-*.color.jpg"))
    pick = [files[int(i)] for i in np.linspace(0, len(files) - 1, n).round()]
    return [cv2.cvtColor(cv2.imread(str(f)), cv2.COLOR_BGR2RGB) for f in pick]


def run(bundle: Path, n: int, threads: int, det_variant: str | None, seg_variant: str | None) -> dict:
    from mosaicthinker.runtime.perceive import keyframe_detector
    from mosaicthinker.runtime.models import load_role
    from mosaicthinker.runtime.infra.trace import Trace

    tr = Trace()
    det = load_role(bundle, "detector", det_variant, threads=threads, trace=tr)
    seg = load_role(bundle, "instance_segmenter", seg_variant, threads=threads, trace=tr)
    names = list(dict.fromkeys(det.labels))
    imgs = frames(n + 1)
    det.detect(imgs[-1], names)  # warm-up: first runs allocate
    seg.detect(imgs[-1], names, masks=True)

    def detector(rgb):
        return det.detect(rgb, names, min_score=det.conf.floor)

    def segmenter(rgb):
        return seg.detect(rgb, names, min_score=seg.conf.floor, masks=True)

    merged = keyframe_detector(det, seg, {}, "merged")  # what perception_from_bundle gives key frames

    def both(rgb):
        return merged(type("F", (), {"rgb": rgb})(), names)

    out = {}
    for c, (name, fn) in enumerate((("detector", detector), ("instance_segmenter", segmenter), ("merged", both))):
        wall, cpu, counts = [], [], []
        for k, rgb in enumerate(imgs[:n]):
            rgb = rgb.copy()
            rgb[0, :2] = [[c, k, 255], [255, k, c]]  # a corner marker: new to every result cache
            c0, t0 = time.process_time(), time.perf_counter()
            d = fn(rgb)
            wall.append((time.perf_counter() - t0) * 1000)
            cpu.append((time.process_time() - c0) * 1000)
            counts.append((len(d), 0 if d.masks is None else int(sum(m.any() for m in d.masks))))
        out[name] = {"wall_ms_p50": round(float(np.median(wall)), 1),
                     "wall_ms_p90": round(float(np.percentile(wall, 90)), 1),
                     "cpu_ms_p50": round(float(np.median(cpu)), 1),
                     "detections_mean": round(float(np.mean([c[0] for c in counts])), 1),
                     "masks_mean": round(float(np.mean([c[1] for c in counts])), 1)}
    return {"detector": det.describe(), "instance_segmenter": seg.describe(), "configs": out}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--bundle", type=Path, required=True)
    ap.add_argument("--frames", type=int, default=24)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--detector-variant", default=None)
    ap.add_argument("--segmenter-variant", default=None)
    ap.add_argument("--results", type=Path, default=OUT)
    a = ap.parse_args(argv)
    load0 = os.getloadavg()
    res = run(a.bundle, a.frames, a.threads, a.detector_variant, a.segmenter_variant)
    doc = {"schema": "mosaicthinker.bench.perception_keyframe/1", "cmd": " ".join(sys.argv),
           "date": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), "frames": a.frames, "threads": a.threads,
           "image": "640x480 7-Scenes redkitchen frames, evenly spaced", "load_avg_before": load0,
           "load_avg_after": os.getloadavg(), "cpus": os.cpu_count(), **res}
    a.results.parent.mkdir(parents=True, exist_ok=True)
    a.results.write_text(json.dumps(doc, indent=1) + "\n")
    print(json.dumps(doc, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
