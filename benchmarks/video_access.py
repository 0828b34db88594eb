"""Random access into an mp4: seconds per frame for random / sorted / sequential access, and equality with
sequential decoding.

    python benchmarks/video_access.py [--frames 900] [--work /tmp/video_access] [--samples 30]

Writes a synthetic 640x480 mp4 (OpenCV mp4v, textured moving pattern) of `--frames` frames at 15 fps into
--work (not the repository), then times `frames.VideoSource`: `--samples` frames in random order, the same
frames in sorted order after `prefetch`, and a full sequential pass. Writes benchmarks/results/video_access.json.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from mosaicthinker.runtime.frames import open_source  # noqa: E402

HERE = Path(__file__).resolve().parent


def write_mp4(path: Path, n: int, size: tuple[int, int] = (640, 480), fps: float = 15.0) -> None:
    W, H = size
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (W, H))
    if not vw.isOpened():
        raise SystemExit("OpenCV cannot write mp4v here")
    tex = cv2.GaussianBlur(np.random.default_rng(0).integers(0, 256, (H, 2 * W, 3), dtype=np.uint8), (7, 7), 0)
    for i in range(n):
        fr = np.ascontiguousarray(np.roll(tex, 2 * i, axis=1)[:, :W])
        cv2.putText(fr, str(i), (20, 80), cv2.FONT_HERSHEY_SIMPLEX, 2.0, (255, 255, 255), 3)
        vw.write(fr)
    vw.release()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=900)
    ap.add_argument("--samples", type=int, default=30)
    ap.add_argument("--work", default="/tmp/video_access")
    ap.add_argument("--out", default=str(HERE / "results" / "video_access.json"))
    a = ap.parse_args(argv)
    work = Path(a.work)
    work.mkdir(parents=True, exist_ok=True)
    p = work / f"clip{a.frames}.mp4"
    if not p.exists():
        write_mp4(p, a.frames)
    t0 = time.perf_counter()
    src = open_source(p, cache_size=64)
    t_open = time.perf_counter() - t0
    pick = np.random.default_rng(1).choice(len(src), a.samples, replace=False).tolist()
    t0 = time.perf_counter()
    rand = {i: src[i].rgb.copy() for i in pick}
    t_rand = (time.perf_counter() - t0) / len(pick)
    src2 = open_source(p, cache_size=64)
    t0 = time.perf_counter()
    src2.prefetch(pick)
    srt = {i: src2[i].rgb for i in sorted(pick)}
    t_sorted = (time.perf_counter() - t0) / len(pick)
    src3 = open_source(p, cache_size=0)
    t0 = time.perf_counter()
    same = 0
    for f in src3:
        if f.index in rand:
            same += int(np.array_equal(f.rgb, rand[f.index]) and np.array_equal(f.rgb, srt[f.index]))
    t_seq = (time.perf_counter() - t0) / len(src3)
    res = {"schema": "mosaicthinker.bench.video_access/1", "command": "python benchmarks/video_access.py "
           + " ".join(argv if argv is not None else sys.argv[1:]), "frames": len(src), "samples": len(pick),
           "open_s": round(t_open, 3), "random_s_per_frame": round(t_rand, 4),
           "sorted_prefetch_s_per_frame": round(t_sorted, 4), "sequential_s_per_frame": round(t_seq, 5),
           "equal_to_sequential": f"{same}/{len(pick)}", "seek_mode": getattr(src, "seek_mode", None),
           "seek_note": getattr(src, "seek_note", None),
           "load_average_1min": os.getloadavg()[0], "date": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(json.dumps(res, indent=1))
    print(json.dumps(res, indent=1))
    return 0 if same == len(pick) else 1


if __name__ == "__main__":
    raise SystemExit(main())
