"""Host-side oracle for the RGB-only poses (issue 38): pycolmap's global mapper (GLOMAP) over the SAME frames the
runtime's structure from motion uses (K key frames, uniform, plus the scan's kept frames between them,
`align.rgb_stage.stream_positions`), COLMAP's SIFT, sequential matching, the source's intrinsics; the key frames'
ATE after Sim(3) against the ground truth. pycolmap has no aarch64 wheel: it is never a runtime dependency.

    python benchmarks/sfm_oracle.py --data ../shared/data/7scenes-redkitchen --keyframes 32 \
        --out benchmarks/results/sfm_oracle_kitchen.json
"""
from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from mosaicthinker.runtime.infra import jsonio
from mosaicthinker.runtime.infra.outputs import write_file_atomic


def oracle(data: str, k: int, stream_frames: int, overlap: int) -> dict:
    import cv2
    import pycolmap

    from mosaicthinker.host.evaluation.pose import ate_fields, pick_frames
    from mosaicthinker.runtime.align.conf import SfmConf
    from mosaicthinker.runtime.align.rgb_stage import stream_positions
    from mosaicthinker.runtime.conf import PipelineConfig
    from mosaicthinker.runtime.frames import open_source
    from mosaicthinker.runtime.scan import remove_redundant

    src = open_source(data)
    keys = pick_frames(len(src), k, "uniform")
    t0 = time.perf_counter()
    scan = remove_redundant(src, PipelineConfig().dedup)
    stream = stream_positions(keys, sorted(int(i) for i in scan.thumbs), stream_frames or SfmConf().stream_frames)
    t_scan = time.perf_counter() - t0
    with tempfile.TemporaryDirectory(prefix="sfm-oracle-") as tmp:
        img = Path(tmp) / "images"
        img.mkdir()
        for i in stream:  # numbered so that COLMAP's sequential order is the stream's
            cv2.imwrite(str(img / f"{i:06d}.png"), cv2.cvtColor(src[i].rgb, cv2.COLOR_RGB2BGR))
        K = src.K
        ro = pycolmap.ImageReaderOptions()
        ro.camera_model = "PINHOLE"
        ro.camera_params = f"{K[0, 0]},{K[1, 1]},{K[0, 2]},{K[1, 2]}"
        db = str(Path(tmp) / "db.db")
        t1 = time.perf_counter()
        pycolmap.extract_features(db, str(img), camera_mode=pycolmap.CameraMode.SINGLE, reader_options=ro,
                                  device=pycolmap.Device.cpu)
        t2 = time.perf_counter()
        po = pycolmap.SequentialPairingOptions()
        po.overlap = overlap
        pycolmap.match_sequential(db, pairing_options=po, device=pycolmap.Device.cpu)
        t3 = time.perf_counter()
        out = Path(tmp) / "sparse"
        out.mkdir()
        recs = pycolmap.global_mapping(db, str(img), str(out))
        t4 = time.perf_counter()
        best = max(recs.values(), key=lambda r: r.num_reg_images()) if recs else None
        poses = {}
        if best is not None:
            for im in best.images.values():
                if im.has_pose:
                    T = np.eye(4)
                    T[:3, :] = im.cam_from_world().inverse().matrix()
                    poses[int(Path(im.name).stem)] = T
    ev = [i for i in keys if i in poses and src[i].pose_gt is not None]
    scores = ate_fields(np.array([poses[i] for i in ev]), np.array([src[i].pose_gt for i in ev]), True)
    return {"data": data, "keyframes": k, "stream_frames": len(stream), "registered_stream": len(poses),
            "keyframes_registered": len(ev), "reconstructions": len(recs), **scores,
            "seconds": {"scan": round(t_scan, 2), "extract": round(t2 - t1, 2), "match": round(t3 - t2, 2),
                        "map": round(t4 - t3, 2)},
            "pycolmap": pycolmap.__version__, "load": os.getloadavg()[0]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", required=True)
    ap.add_argument("--keyframes", type=int, default=32)
    ap.add_argument("--stream-frames", type=int, default=0, help="0: SfmConf's stream_frames")
    ap.add_argument("--overlap", type=int, default=3, help="sequential matching: each frame with its next n")
    ap.add_argument("--out", default=None)
    a = ap.parse_args()
    r = oracle(a.data, a.keyframes, a.stream_frames, a.overlap)
    text = jsonio.dumps(r, indent=1) + "\n"  # a non-finite figure (nothing registered) is written as null
    if a.out:
        write_file_atomic(a.out, text)
    print(text)


if __name__ == "__main__":
    main()
