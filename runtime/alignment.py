"""Cross-frame and multi-frame alignment (paper: "Cross-frame alignment", "Multi-frame alignment").

Pairwise (`AlignConf.edge`):
- "rgbd" (metric depth): feature matches lifted to 3D with each frame's depth, then `geometry.ransac_transform`
  (SE(3); Sim(3) per edge when forced on relative depth). The best `max_matches` matches by score are used;
  RANSAC rejects most outlier samples by a lossless distance pre-test before any SVD.
- "essential" (relative, non-metric depth; chosen by "auto" when `with_scale=True`): `align_pair_essential` -
  5-point essential matrix (OpenCV USAC_MAGSAC) for rotation + translation direction; the depth only sets the
  translation length (median of predicted / unit-baseline triangulated depth over inliers with parallax). The
  per-frame depth scales are then solved over all verified edges (`essential_frame_scales`, scale_mode "graph")
  so the tree composes in one global scale (the root frame's depth unit). Measured on 7-Scenes (PyDNet++ +
  XFeat, K=32 evenly spaced): ATE 0.08 m against 0.53 m for rgbd Sim(3) edges on the same frames.

Multi-frame (strategy "mst"):
1. frame-similarity matrix S [K, K]: cosine similarity of per-frame embeddings when given, otherwise the
   correlation of colour histograms (HSV, 16 hue x 8 saturation x 4 value bins, OpenCV's HISTCMP_CORREL);
2. root = frame with the largest total similarity;
3. geometric refinement of S (`verify_top`, default 4): each frame's most similar frames are aligned pairwise
   (plus its time neighbour): for rgbd edges the 2 most similar first, widened by one per round up to 4 only
   while the verified pairs leave a frame unconnected (`verify_top_first`); essential edges all 4 at once. A
   verified pair weighs 1 + its RANSAC inlier count, a failed pair is removed, untried pairs keep their
   similarity (< 1, so they rank after every verified pair).
   Measured on 7-Scenes: colour histograms alone pick wide-baseline pairs whose few inliers give 10-25 cm
   errors (ATE 0.11 m at K=32 instead of 0.05);
4. maximum spanning tree by Kruskal over these weights. An edge that would join two components and has not
   been aligned yet is aligned then; when an alignment fails (too few inliers or too low an inlier ratio) the
   edge is dropped and Kruskal moves on to the next-best edge (failed-edge handling);
5. the pose of every frame = composition of the pairwise transforms along its unique tree path to the root,
   expressed in the root camera's frame. Frames outside the root's component are reported as unaligned and
   get no pose.

Strategy "sequential" is the paper's naive baseline: frames in time order, chained t -> t+1; a failed link
keeps the previous pose (those frames are listed in `guessed`).
"""
from __future__ import annotations

import time
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from typing import Any, Callable, ClassVar, Mapping, Protocol, Sequence

import numpy as np

from .config import StageConf
from .errors import AlignmentError, InputError
from .geometry import (backproject_pixels, icp_point_to_plane, ransac_transform, rotation_angle_deg, sample_depth,
                       transform, transform_scale, umeyama, worker_threads)
from .matching import KeyedMatcher, Matches, make_matcher
from .trace import as_trace


@dataclass
class AlignConf(StageConf):
    """Defaults of the alignment stage (`AlignConf.merged(overrides)`, see config.StageConf)."""

    conf_name: ClassVar[str] = "alignment config"

    threshold_m: float = 0.05          # RANSAC inlier distance for metric depth (m)
    threshold_rel: float = 0.025       # ... for relative depth (with_scale): fraction of the median depth
    refine_m: float = 0.02             # final least-squares refit on matches within this distance (m; for
                                       # relative depth scaled like threshold_rel); 0 = off
    iterations: int = 1000
    max_matches: int = 400             # matches with valid depth kept per pair, best scores first (0 = all)
    min_inliers: int = 20              # fewer inliers = failed edge
    min_inlier_ratio: float = 0.15     # inliers / matches with depth, below = failed edge (random matches)
    max_depth_m: float = 10.0          # ignore depth beyond this (sensor noise)
    edge_radius: int = 3               # a match's depth must be smooth in a (2r+1)^2 window (0 = off) ...
    edge_rel: float = 0.05             # ... i.e. max - min depth there below this fraction of its depth
    hist_bins: tuple[int, int, int] = (16, 8, 4)
    icp: bool = False                  # refine metric edges by point-to-plane ICP on the two depth maps (off:
                                       # on 7-Scenes it did not lower ATE and costs ~0.1 s per edge; ICP
                                       # started AT the ground truth moves 1-5 cm, i.e. GT noise dominates)
    icp_iterations: int = 10
    icp_stride: int = 4
    icp_max_change: tuple[float, float] = (0.10, 5.0)  # (m, deg) larger ICP corrections are rejected
    icp_min_overlap: float = 0.2       # fraction of b's points paired in a, below = ICP rejected
    verify_top: int = 4                # geometric refinement: each frame's top-k similar frames are aligned first
                                       # and the tree prefers edges with more inliers (0 = order by S only).
                                       # Measured: 3 keeps SIFT's accuracy with 63 instead of 80 pairs at K=32,
                                       # but ORB's tree then takes wrong edges (uniform K=64 ATE 0.16 vs 0.05 m),
                                       # and essential edges get worse (0.13 vs 0.08 m)
    verify_neighbours: int | None = None  # ... plus each frame's n time neighbours; None = 1 for essential edges
                                       # (their inlier counts favour short, ill-conditioned baselines: measured
                                       # ATE 0.12 -> 0.08 m at K=32) and 1 for rgbd edges when they start
                                       # narrow (`verify_top_first`), else 0
    verify_top_first: int | None = None  # candidates start at each frame's top-k (+ time neighbours) and widen by
                                       # one frame per round up to `verify_top` only while the verified pairs
                                       # leave some frame unconnected; None = 2 for rgbd edges (a failed pair
                                       # costs a full RANSAC: 49 instead of 80 pairs at K=32, see
                                       # docs/performance.md), `verify_top` for essential edges (their ATE
                                       # needs every candidate: 0.12 vs 0.075 m with 2)
    verify_rank: str = "inliers"       # how the candidates are ranked: "inliers" = each is verified first and
                                       # weighs 1 + its inlier count; "matches" = weighs 1 + its count of matches
                                       # with depth in both frames (RANSAC's input) and is verified only when
                                       # Kruskal takes it (lazy: ~K pairs instead of ~2.5K). Measured on 7-Scenes
                                       # (benchmarks/pose_table.py, sensor depth), "matches" vs "inliers": SIFT
                                       # uniform K=16/32/64 ATE 0.047/0.048/0.050 vs 0.049/0.049/0.048 m, random
                                       # K=16 median 0.058 vs 0.053; ORB uniform K=32 0.090 vs 0.070, random K=16
                                       # 0.107 vs 0.085; XFeat essential edges 0.127 vs 0.071 (their graph scales
                                       # need every candidate): worse where it counts, so not the default
    max_attempts: int | None = None    # cap on pairwise alignments tried by Kruskal (None = as many as needed)
    seed: int = 0                      # RANSAC seed; each rgbd pair draws from its own stream (seed, frame a,
                                       # frame b), so a pair's result does not depend on which pairs ran before
    threads: int = 0                   # pairwise verifications run concurrently on this many threads (OpenCV and
                                       # numpy release the GIL); 0 = os.cpu_count() capped at 4, 1 = in the
                                       # caller's thread. The same results whatever the count (tested)
    # edge type: "rgbd" = 3D-3D RANSAC on depth-lifted matches (SE(3) metric / Sim(3) relative); "essential" =
    # 5-point essential matrix for rotation + translation direction, the depth only sets the translation
    # length (`align_pair_essential`); "auto" = essential when depth is relative (with_scale), else rgbd
    edge: str = "auto"
    essential_px: float | None = None  # essential-matrix RANSAC threshold (pixels, Sampson distance); None =
                                       # the matcher's `keypoint_px` (keypoint localisation noise) or 1.0.
                                       # Measured on 7-Scenes: SIFT best at 1 px (ATE 0.03 vs 0.11 m at 2 px),
                                       # XFeat at 2 px (0.09 vs 0.14 m at 1 px)
    essential_method: str = "magsac"   # OpenCV robust estimator: "magsac" (USAC_MAGSAC, local optimisation),
                                       # "accurate" (USAC_ACCURATE) or "ransac" (classic RANSAC; measured worse)
    essential_matches: int = 800       # matches kept for the essential matrix, best scores first (0 = all)
    essential_refine: bool = True      # Sampson-error least squares (Huber) on the inliers after RANSAC
                                       # (measured on 7-Scenes + XFeat: ATE lower in 4 of 5 subsets, ~20 ms/edge)
    min_parallax_deg: float = 1.0      # triangulated points with a smaller ray angle do not vote on the scale
    min_scale_points: int = 8          # fewer voting points = failed edge
    scale_mode: str = "graph"          # "chain": each frame's relative depth has its own scale, the edge carries
                                       # the ratio (Sim(3) edge; scale composes along the tree); "graph": the same,
                                       # but the per-frame scales are solved over ALL verified edges
                                       # (`essential_frame_scales`) before composing; "shared": one scale for
                                       # every frame's depth (rigid edge, baseline = geometric mean)



@dataclass
class PairResult:
    """Pairwise alignment of frames a, b. T_ab [4, 4]: pose of camera b in camera a's frame (maps b-camera points
    to a-camera points; a similarity when estimated with scale)."""

    T_ab: np.ndarray
    ok: bool
    n_matches: int
    n_valid: int          # matches with valid depth in both frames
    n_inliers: int
    residual_m: float
    seconds: float
    reason: str = ""
    icp: str = ""         # "" (not tried), "applied", or why it was rejected
    icp_rms_m: float = float("nan")
    scale_a: float = float("nan")  # essential edges: baseline length in frame a's / b's depth units
    scale_b: float = float("nan")

    def to_dict(self) -> dict[str, Any]:
        return {"ok": self.ok, "matches": self.n_matches, "valid": self.n_valid, "inliers": self.n_inliers,
                "residual": round(float(self.residual_m), 5) if np.isfinite(self.residual_m) else None,
                "scale": round(transform_scale(self.T_ab), 5), "seconds": round(self.seconds, 5),
                "reason": self.reason, "icp": self.icp,
                "icp_rms": None if not np.isfinite(self.icp_rms_m) else round(float(self.icp_rms_m), 5)}


def align_pair(m: Matches, depth_a: np.ndarray, K_a: np.ndarray, depth_b: np.ndarray, K_b: np.ndarray,
               conf: AlignConf | None = None, with_scale: bool = False,
               rng: np.random.Generator | int | None = 0, dist_a: np.ndarray | None = None,
               dist_b: np.ndarray | None = None) -> PairResult:
    """Matches (uv0 in a, uv1 in b) -> 3D points via each frame's depth ([H, W] float32, 0 = invalid) and
    intrinsics K [3, 3] -> RANSAC transform T_ab (b camera -> a camera). dist_a/dist_b: OpenCV distortion
    coefficients; when given, the pixels are undistorted before back-projection (depth is read at the raw pixel)."""
    conf = conf or AlignConf()
    t0 = time.perf_counter()
    za = sample_depth(depth_a, m.uv0)
    zb = sample_depth(depth_b, m.uv1)
    ok = depth_valid(m, depth_a, depth_b, conf, with_scale, za, zb)
    if conf.edge_radius > 0:  # keypoints sit on corners, often on depth edges: their depth is unreliable
        q = np.flatnonzero(ok)
        ok[q] = depth_smooth(depth_a, m.uv0[q], conf.edge_radius, conf.edge_rel) & \
            depth_smooth(depth_b, m.uv1[q], conf.edge_radius, conf.edge_rel)
    if conf.max_matches and ok.sum() > conf.max_matches:  # keep the most distinctive matches (RANSAC cost ~ N)
        q = np.flatnonzero(ok)
        ok[:] = False
        ok[q[np.argsort(-m.scores[q], kind="stable")[:conf.max_matches]]] = True
    nv = int(ok.sum())
    if nv < max(3, conf.min_inliers):
        return PairResult(np.eye(4), False, len(m), nv, 0, float("inf"), time.perf_counter() - t0,
                          f"only {nv} matches with valid depth (need {conf.min_inliers})")
    pa = backproject_pixels(_undistort(m.uv0[ok], K_a, dist_a), za[ok], K_a)
    pb = backproject_pixels(_undistort(m.uv1[ok], K_b, dist_b), zb[ok], K_b)
    thr = conf.threshold_m if not with_scale else conf.threshold_rel * float(np.median(za[ok]))
    # only a model with >= w_min inliers could be accepted: enough iterations to find one with 99.9%
    # confidence (fewer than `iterations` for small match sets; failed pairs are the common, costly case)
    w_min = min(1.0, max(conf.min_inliers / nv, conf.min_inlier_ratio))
    its = conf.iterations if w_min >= 1.0 else \
        min(conf.iterations, int(np.ceil(np.log(1e-3) / np.log(max(1e-12, 1.0 - w_min**3)))) + 1)
    r = ransac_transform(pb, pa, threshold=thr, iterations=its, with_scale=with_scale,
                         min_inliers=conf.min_inliers, rng=rng)
    reason = ""
    good = r.ok
    if good and conf.refine_m > 0:  # accept with the loose threshold, estimate from the tight inliers
        thr2 = conf.refine_m * (1.0 if not with_scale else thr / conf.threshold_m)
        T = r.T
        for _ in range(2):
            sel = np.linalg.norm(transform(T, pb) - pa, axis=1) < thr2
            if sel.sum() < max(6, conf.min_inliers // 2):
                break
            T = umeyama(pb[sel], pa[sel], with_scale)
        r.T = T
    if not r.ok:
        reason = f"{r.n_inliers} inliers (need {conf.min_inliers})"
    elif r.n_inliers < conf.min_inlier_ratio * nv:
        good, reason = False, f"inlier ratio {r.n_inliers / nv:.2f} below {conf.min_inlier_ratio}"
    T, icp, icp_rms = r.T, "", float("nan")
    if good and conf.icp and not with_scale:
        T2, icp_rms, _n, overlap = icp_point_to_plane(depth_a, K_a, depth_b, K_b, r.T, conf.icp_iterations,
                                                      conf.icp_stride)
        dt, dr = pose_change(r.T, T2)
        if overlap < conf.icp_min_overlap:
            icp = f"rejected: overlap {overlap:.2f} < {conf.icp_min_overlap}"
        elif dt > conf.icp_max_change[0] or dr > conf.icp_max_change[1]:
            icp = f"rejected: moved {dt:.3f} m / {dr:.1f} deg from the RANSAC pose"
        else:
            T, icp = T2, "applied"
    return PairResult(T, good, len(m), nv, r.n_inliers, r.residual, time.perf_counter() - t0, reason, icp, icp_rms)


def depth_valid(m: Matches, depth_a: np.ndarray, depth_b: np.ndarray, conf: AlignConf, with_scale: bool,
                za: np.ndarray | None = None, zb: np.ndarray | None = None) -> np.ndarray:
    """[M] bool: matches with depth > 0 at both ends (and below `max_depth_m` for metric depth); za, zb: the
    sampled depths when already known."""
    za = sample_depth(depth_a, m.uv0) if za is None else za
    zb = sample_depth(depth_b, m.uv1) if zb is None else zb
    lim = conf.max_depth_m if not with_scale else np.inf
    return (za > 0) & (zb > 0) & (za < lim) & (zb < lim)


def align_pair_essential(m: Matches, depth_a: np.ndarray, K_a: np.ndarray, depth_b: np.ndarray, K_b: np.ndarray,
                         conf: AlignConf | None = None, dist_a: np.ndarray | None = None,
                         dist_b: np.ndarray | None = None) -> PairResult:
    """Pairwise alignment for relative (non-metric) depth: the 5-point essential matrix (OpenCV, RANSAC) gives
    the rotation and the translation direction; the depth maps ([H, W], any consistent-per-frame unit, 0 =
    invalid) only set the translation length.

    Scale: the essential inliers are triangulated with a unit baseline; for points whose two rays meet at more
    than `min_parallax_deg`, the predicted depth over the triangulated depth is the baseline length in that
    frame's depth units; the median over the points gives s_a (frame a) and s_b (frame b). Returned T_ab (b camera
    -> a camera) is the similarity [(s_a / s_b) R_ba, s_a t_ba] in a's depth units (`scale_mode` "chain"), so
    composing edges along the tree keeps one global scale (the root's); "shared" assumes every frame's depth has
    the same unit and returns the rigid [R_ba, sqrt(s_a s_b) t_ba].
    Failed edges: too few matches or essential inliers, a degenerate essential matrix, or too few points with
    parallax and depth to fix the scale (pure rotation / tiny baseline).
    = `essential_edge(essential_pose(...), ..., refine=conf.essential_refine)`."""
    conf = conf or AlignConf()
    pose = essential_pose(m, K_a, K_b, conf, dist_a, dist_b)
    if isinstance(pose, PairResult):
        return pose
    return essential_edge(pose, depth_a, depth_b, conf, conf.essential_refine)


@dataclass
class EssentialPose:
    """The RANSAC part of an essential edge: normalised (xa, xb [M, 2]) and pixel (uva, uvb [M, 2]) coordinates
    of the matches used, the cheirality inliers inl [M] bool, the relative pose x_b = R x_a + t (|t| = 1), the
    Sampson threshold in normalised units, the pair's match count, seconds spent."""

    xa: np.ndarray
    xb: np.ndarray
    uva: np.ndarray
    uvb: np.ndarray
    inl: np.ndarray
    R: np.ndarray
    t: np.ndarray
    thr: float
    n_matches: int
    seconds: float


def essential_pose(m: Matches, K_a: np.ndarray, K_b: np.ndarray, conf: AlignConf,
                   dist_a: np.ndarray | None = None, dist_b: np.ndarray | None = None) -> EssentialPose | PairResult:
    """Essential matrix (`_find_essential`) + cheirality (cv2.recoverPose on its inliers) of one pair; a failed
    PairResult when there are too few matches or inliers (see `align_pair_essential`)."""
    import cv2

    t0 = time.perf_counter()
    n = len(m)

    def fail(why: str, nv: int = 0, ninl: int = 0) -> PairResult:
        return PairResult(np.eye(4), False, n, nv, ninl, float("inf"), time.perf_counter() - t0, why)

    if n < max(8, conf.min_inliers):
        return fail(f"only {n} matches (need {max(8, conf.min_inliers)})")
    sel = np.arange(n)
    if conf.essential_matches and n > conf.essential_matches:
        sel = np.argsort(-m.scores, kind="stable")[:conf.essential_matches]
    elif conf.essential_method == "magsac-prosac":  # PROSAC samples the best scores first
        sel = np.argsort(-m.scores, kind="stable")
    uva, uvb = m.uv0[sel].astype(np.float64), m.uv1[sel].astype(np.float64)
    xa = cv2.undistortPoints(uva.reshape(-1, 1, 2), K_a, None if dist_a is None else np.asarray(dist_a, float))
    xb = cv2.undistortPoints(uvb.reshape(-1, 1, 2), K_b, None if dist_b is None else np.asarray(dist_b, float))
    xa, xb = xa.reshape(-1, 2), xb.reshape(-1, 2)
    f = 0.25 * (K_a[0, 0] + K_a[1, 1] + K_b[0, 0] + K_b[1, 1])
    px = conf.essential_px if conf.essential_px is not None else 1.0
    E, mask = _find_essential(xa, xb, px / f, conf.essential_method)
    if E is None or E.shape[0] < 3:
        return fail("no essential matrix", len(sel))
    q0 = np.flatnonzero(mask.ravel())  # cheirality test on the RANSAC inliers only (same result, less work)
    _n, R, t, m2 = cv2.recoverPose(E[:3], xa[q0], xb[q0], np.eye(3))
    inl = np.zeros(len(sel), bool)
    inl[q0[m2.ravel() > 0]] = True
    ninl = int(inl.sum())
    if ninl < conf.min_inliers:
        return fail(f"{ninl} essential inliers (need {conf.min_inliers})", len(sel), ninl)
    if ninl < conf.min_inlier_ratio * len(sel):
        return fail(f"essential inlier ratio {ninl / len(sel):.2f} below {conf.min_inlier_ratio}", len(sel), ninl)
    t = t.reshape(3) / max(np.linalg.norm(t), 1e-12)  # x_b = R x_a + t, |t| = 1
    return EssentialPose(xa, xb, uva, uvb, inl, R, t, px / f, n, time.perf_counter() - t0)


def essential_edge(pose: EssentialPose, depth_a: np.ndarray, depth_b: np.ndarray, conf: AlignConf,
                   refine: bool) -> PairResult:
    """The rest of an essential edge from its RANSAC pose: the Sampson refinement (when `refine`), then the
    translation length from the depth maps (see `align_pair_essential`). Same inliers either way."""
    import cv2

    t0 = time.perf_counter()
    R, t, inl, xa, xb = pose.R, pose.t, pose.inl, pose.xa, pose.xb
    ninl = int(inl.sum())

    def fail(why: str, nv: int = 0) -> PairResult:
        return PairResult(np.eye(4), False, pose.n_matches, nv, ninl, float("inf"),
                          pose.seconds + time.perf_counter() - t0, why)

    if refine:  # on at most 200 inliers, evenly picked (cost ~ points x iterations)
        q = np.flatnonzero(inl)
        q = q[np.linspace(0, len(q) - 1, min(len(q), 200)).astype(int)]
        R, t = refine_essential(R, t, xa[q], xb[q], pose.thr)
    Xh = cv2.triangulatePoints(np.eye(3, 4), np.hstack([R, t[:, None]]), xa[inl].T, xb[inl].T)
    with np.errstate(divide="ignore", invalid="ignore"):
        X = (Xh[:3] / Xh[3]).T  # [M, 3] in camera a, unit baseline
    Xb = X @ R.T + t
    cb = -R.T @ t  # centre of b in a
    ra, rb = X, X - cb
    cosang = np.sum(ra * rb, 1) / np.maximum(np.linalg.norm(ra, axis=1) * np.linalg.norm(rb, axis=1), 1e-12)
    par = np.degrees(np.arccos(np.clip(cosang, -1, 1)))
    da = sample_depth(depth_a, pose.uva[inl])
    db = sample_depth(depth_b, pose.uvb[inl])
    ok = np.isfinite(X).all(1) & (X[:, 2] > 0) & (Xb[:, 2] > 0) & (par >= conf.min_parallax_deg) & (da > 0) & (db > 0)
    nv = int(ok.sum())
    if nv < conf.min_scale_points:
        return fail(f"{nv} inliers with parallax >= {conf.min_parallax_deg} deg and depth (need "
                    f"{conf.min_scale_points}): baseline too small to fix the scale", nv)
    la = np.log(da[ok] / X[ok, 2])  # log baseline length in a's / b's depth units, per point
    lb = np.log(db[ok] / Xb[ok, 2])
    s_a, s_b = float(np.exp(np.median(la))), float(np.exp(np.median(lb)))
    spread = float(np.median(np.abs(la - np.log(s_a))))  # robust log-scale spread (residual)
    T = np.eye(4)
    if conf.scale_mode == "shared":
        T[:3, :3] = R.T
        T[:3, 3] = -np.sqrt(s_a * s_b) * (R.T @ t)
    else:
        T[:3, :3] = (s_a / s_b) * R.T
        T[:3, 3] = -s_a * (R.T @ t)
    return PairResult(T, True, pose.n_matches, nv, ninl, spread, pose.seconds + time.perf_counter() - t0,
                      scale_a=s_a, scale_b=s_b)


def _find_essential(xa: np.ndarray, xb: np.ndarray, thr: float, method: str) -> tuple[Any, Any]:
    """Robust essential matrix of normalised correspondences xa, xb [N, 2] -> (E, mask). "magsac":
    cv2.USAC_MAGSAC; "accurate": cv2.USAC_ACCURATE; "ransac": cv2.RANSAC; "magsac-prosac": MAGSAC++ scoring and
    sigma consensus with PROSAC sampling over the score order (xa, xb best first) - measured on 7-Scenes + XFeat
    K=32: 22% less CPU for the edges but ATE 0.089 m against 0.065-0.085 m for "magsac" over 5 match orders, so
    not the default."""
    import cv2

    if method == "magsac-prosac":
        p = cv2.UsacParams()
        p.confidence, p.maxIterations, p.threshold = 0.999, 1000, thr
        p.sampler, p.score, p.loMethod = cv2.SAMPLING_PROSAC, cv2.SCORE_METHOD_MAGSAC, cv2.LOCAL_OPTIM_SIGMA
        I3, z = np.eye(3), np.zeros(5)
        return cv2.findEssentialMat(xa, xb, I3, I3, z, z, params=p)
    flag = {"magsac": cv2.USAC_MAGSAC, "accurate": cv2.USAC_ACCURATE, "ransac": cv2.RANSAC}.get(method)
    if flag is None:
        raise InputError(f"alignment config: essential_method must be 'magsac', 'accurate', 'ransac' or "
                         f"'magsac-prosac', got {method!r}")
    return cv2.findEssentialMat(xa, xb, np.eye(3), method=flag, prob=0.999, threshold=thr)


def refine_essential(R: np.ndarray, t: np.ndarray, xa: np.ndarray, xb: np.ndarray, scale: float,
                     iterations: int = 20) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares refinement of a relative pose (x_b = R x_a + t, |t| = 1) on inlier correspondences in
    normalised coordinates xa, xb [N, 2]: Sampson error, Huber loss at `scale`, rotation as a rotation vector
    update and t on the unit sphere (2 tangent directions). Returns (R [3, 3], t [3]).

    Levenberg-Marquardt with Huber IRLS weights (the minimum of scipy's least_squares(loss="huber") on the same
    residuals); the Jacobian by forward differences, all 6 residual vectors in one batched evaluation (was
    scipy's trf with one Python call per difference: ~50 ms a pair, now ~1 ms)."""
    ha = np.hstack([xa, np.ones((len(xa), 1))])
    hb = np.hstack([xb, np.ones((len(xb), 1))])
    u = np.cross(t, [1.0, 0, 0] if abs(t[0]) < 0.9 else [0, 1.0, 0])
    u /= np.linalg.norm(u)
    v = np.cross(t, u)
    p = np.zeros(5)
    r = _sampson_batch(R, t, u, v, p[None], ha, hb)[0]
    cost = _huber_cost(r, scale)
    lam, eps = 1e-3, 1e-7
    for _ in range(iterations):
        P = np.vstack([p, p + eps * np.eye(5)])
        rr = _sampson_batch(R, t, u, v, P, ha, hb)          # [6, N]
        J = (rr[1:] - rr[0]).T / eps                        # [N, 5]
        a = np.abs(rr[0])
        w = np.where(a <= scale, 1.0, scale / np.maximum(a, 1e-300))  # Huber IRLS weights
        A = J.T @ (J * w[:, None])
        g = J.T @ (w * rr[0])
        improved = False
        for _ in range(6):
            step = np.linalg.solve(A + lam * np.diag(np.diag(A) + 1e-12), -g)
            r_new = _sampson_batch(R, t, u, v, (p + step)[None], ha, hb)[0]
            c_new = _huber_cost(r_new, scale)
            if c_new < cost:
                gain = cost - c_new
                p, cost, lam, improved = p + step, c_new, max(lam / 3, 1e-9), True
                break
            lam *= 4
        if not improved or gain < 1e-8 * cost:  # converged (scipy's ftol default)
            break
    return _pose_update(R, t, u, v, p[None])


def _huber_cost(r: np.ndarray, scale: float) -> float:
    a = np.abs(r)
    return float(np.sum(np.where(a <= scale, 0.5 * r * r, scale * a - 0.5 * scale * scale)))


def _pose_update(R: np.ndarray, t: np.ndarray, u: np.ndarray, v: np.ndarray, P: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Parameter rows P [B, 5] (rotation vector, two tangent steps of t) -> R [B, 3, 3], t [B, 3] (one row: unbatched)."""
    w = P[:, :3]
    ang = np.linalg.norm(w, axis=1)
    k = w / np.where(ang > 1e-12, ang, 1.0)[:, None]
    Kx = np.zeros((len(P), 3, 3))
    Kx[:, 0, 1], Kx[:, 0, 2], Kx[:, 1, 2] = -k[:, 2], k[:, 1], -k[:, 0]
    Kx -= Kx.transpose(0, 2, 1)
    s, c = np.sin(ang)[:, None, None], (1 - np.cos(ang))[:, None, None]
    Rn = (np.eye(3) + s * Kx + c * (Kx @ Kx)) @ R
    tn = t + P[:, 3:4] * u + P[:, 4:5] * v
    tn /= np.linalg.norm(tn, axis=1, keepdims=True)
    if len(P) == 1:
        return Rn[0], tn[0]
    return Rn, tn


def _sampson_batch(R: np.ndarray, t: np.ndarray, u: np.ndarray, v: np.ndarray, P: np.ndarray, ha: np.ndarray,
                   hb: np.ndarray) -> np.ndarray:
    """Signed Sampson errors [B, N] of homogeneous correspondences ha, hb [N, 3] for the poses of P [B, 5]."""
    B = len(P)
    Rn, tn = _pose_update(R, t, u, v, P)
    Rn, tn = Rn.reshape(B, 3, 3), tn.reshape(B, 3)
    tx = np.zeros((B, 3, 3))
    tx[:, 0, 1], tx[:, 0, 2], tx[:, 1, 2] = -tn[:, 2], tn[:, 1], -tn[:, 0]
    tx -= tx.transpose(0, 2, 1)
    E = tx @ Rn                                                   # [B, 3, 3]
    Ea = (ha @ E.reshape(3 * B, 3).T).reshape(len(ha), B, 3)      # E x_a, one GEMM for the batch
    Eb = (hb @ E.transpose(1, 0, 2).reshape(3, 3 * B)).reshape(len(hb), B, 3)  # E^T x_b
    num = np.einsum("nj,nbj->bn", hb, Ea)
    den = np.sqrt(Ea[..., 0]**2 + Ea[..., 1]**2 + Eb[..., 0]**2 + Eb[..., 1]**2).T + 1e-12
    return num / den


def essential_frame_scales(n: int, root: int, edges: Mapping[tuple[int, int], PairResult],
                           rounds: int = 3) -> np.ndarray:
    """Per-frame depth scales sigma [n] (global units per unit of frame k's relative depth, sigma[root] = 1) from
    every verified essential edge (a, b) -> PairResult with scale_a/scale_b (the pair's baseline in a's and b's
    depth units): the baseline is one length, so sigma_a * scale_a = sigma_b * scale_b. Solved in log space by
    least squares over all verified edges (a graph, not only the tree: each frame's scale is averaged over its
    edges instead of inheriting the errors of one path), re-weighted (Huber, 0.1 in log units) `rounds` times.
    Frames without a verified edge keep 1."""
    rows = [(a, b, np.log(r.scale_b) - np.log(r.scale_a), float(r.n_inliers))
            for (a, b), r in edges.items() if r.ok and r.scale_a > 0 and r.scale_b > 0]
    ls = np.zeros(n)
    if not rows:
        return np.ones(n)
    A = np.zeros((len(rows) + 1, n))
    y = np.zeros(len(rows) + 1)
    w0 = np.ones(len(rows) + 1)
    for k, (a, b, d, ninl) in enumerate(rows):  # log sigma_a - log sigma_b = log scale_b - log scale_a
        A[k, a], A[k, b], y[k] = 1.0, -1.0, d
        w0[k] = np.sqrt(ninl)
    A[-1, root], w0[-1] = 1.0, 1e3  # gauge: sigma_root = 1
    w = w0.copy()
    for _ in range(max(1, rounds)):
        ls = np.linalg.lstsq(A * w[:, None], y * w, rcond=None)[0]
        r = np.abs(A @ ls - y)
        w = w0 * np.where(r > 0.1, 0.1 / np.maximum(r, 1e-12), 1.0) ** 0.5
        w[-1] = w0[-1]
    return np.exp(ls)


def _undistort(uv: np.ndarray, K: np.ndarray, dist: np.ndarray | None) -> np.ndarray:
    if dist is None or not np.any(dist):
        return uv
    import cv2

    pts = np.asarray(uv, np.float64).reshape(-1, 1, 2)
    return cv2.undistortPoints(pts, K, np.asarray(dist, np.float64), P=K).reshape(-1, 2)


def depth_smooth(depth: np.ndarray, uv: np.ndarray, radius: int = 3, rel: float = 0.05) -> np.ndarray:
    """For pixels uv [N, 2]: True where every depth in the (2r+1)^2 window is valid and max - min < rel * depth
    (not on a depth discontinuity, where a slightly misplaced sample jumps to the background) -> [N] bool."""
    H, W = depth.shape
    if len(uv) == 0:
        return np.zeros(0, bool)
    u = np.round(uv[:, 0]).astype(int)
    v = np.round(uv[:, 1]).astype(int)
    o = np.arange(-radius, radius + 1)
    uu = np.clip(u[:, None, None] + o[None, None, :], 0, W - 1)
    vv = np.clip(v[:, None, None] + o[None, :, None], 0, H - 1)
    win = depth[vv, uu].reshape(len(uv), -1)
    lo, hi = win.min(1), win.max(1)
    return (lo > 0) & np.isfinite(hi) & (hi - lo < rel * hi)


# ----------------------------------------------------------------------------- similarity, root, spanning tree


def color_histograms(rgbs: Sequence[np.ndarray], bins: tuple[int, int, int] = (16, 8, 4),
                     threads: int = 1) -> np.ndarray:
    """HSV histograms of images [H, W, 3] uint8 RGB -> [K, prod(bins)] float64 (each sums to 1); the images on
    `threads` threads (OpenCV releases the GIL; the same histograms in the same order)."""
    import cv2

    def one(rgb: np.ndarray) -> np.ndarray:
        small = cv2.resize(rgb, (160, max(1, round(160 * rgb.shape[0] / rgb.shape[1]))),
                           interpolation=cv2.INTER_AREA)
        hsv = cv2.cvtColor(small, cv2.COLOR_RGB2HSV)
        h = cv2.calcHist([hsv], [0, 1, 2], None, list(bins), [0, 180, 0, 256, 0, 256]).ravel()
        return h / max(h.sum(), 1e-12)

    if threads <= 1 or len(rgbs) < 2:
        return np.array([one(rgb) for rgb in rgbs], dtype=np.float64)
    with ThreadPoolExecutor(min(threads, len(rgbs))) as ex:
        return np.array(list(ex.map(one, rgbs)), dtype=np.float64)


def similarity_matrix(rgbs: Sequence[np.ndarray] | None = None, embeddings: np.ndarray | None = None,
                      bins: tuple[int, int, int] = (16, 8, 4), threads: int = 1) -> tuple[np.ndarray, str]:
    """Frame similarity S [K, K] (diagonal 0) and what it is: 'embedding_cosine' for embeddings [K, D],
    else 'color_hist_correlation' (Pearson correlation of HSV histograms, as cv2.HISTCMP_CORREL; histograms on
    `threads` threads)."""
    if embeddings is not None:
        E = np.asarray(embeddings, dtype=np.float64)
        E = E / np.maximum(np.linalg.norm(E, axis=1, keepdims=True), 1e-12)
        S, kind = E @ E.T, "embedding_cosine"
    else:
        if rgbs is None:
            raise AlignmentError("similarity_matrix needs images or embeddings")
        H = color_histograms(rgbs, bins, threads)
        H = H - H.mean(1, keepdims=True)
        H = H / np.maximum(np.linalg.norm(H, axis=1, keepdims=True), 1e-12)
        S, kind = H @ H.T, "color_hist_correlation"
    S = S.copy()
    np.fill_diagonal(S, 0.0)
    return S, kind


def choose_root(S: np.ndarray) -> int:
    """Row with the largest total similarity (ties -> the earliest frame)."""
    return int(np.argmax(S.sum(1)))


def root_in_largest(S: np.ndarray, tree: Sequence[tuple[int, int]], root: int) -> int:
    """`root` if its tree component is the largest (ties keep it), else the `choose_root` row of the largest
    component of the verified forest: a split tree keeps the most key frames aligned, not the most similar
    frame's few (the map is built from the root's component only)."""
    dsu = _DSU(len(S))
    for i, j in tree:
        dsu.union(i, j)
    comp = np.array([dsu.find(i) for i in range(len(S))])
    sizes = np.bincount(comp, minlength=len(S))
    if sizes[comp[root]] >= sizes.max():
        return root
    members = np.flatnonzero(comp == int(np.argmax(sizes)))
    return int(members[np.argmax(S[np.ix_(members, members)].sum(1))])


class _DSU:
    def __init__(self, n: int):
        self.p = list(range(n))

    def find(self, x: int) -> int:
        while self.p[x] != x:
            self.p[x] = self.p[self.p[x]]
            x = self.p[x]
        return x

    def union(self, a: int, b: int) -> bool:
        ra, rb = self.find(a), self.find(b)
        if ra == rb:
            return False
        self.p[rb] = ra
        return True


def maximum_spanning_tree(S: np.ndarray, verify=None, max_attempts: int | None = None
                          ) -> tuple[list[tuple[int, int]], list[tuple[int, int]]]:
    """Kruskal on weights S [K, K] (symmetric; only i < j used), heaviest first.

    verify(i, j) -> bool is called for every edge that would join two components; a False edge is skipped and
    the next-best edge tried (failed-edge handling). Returns (tree edges, failed edges), each as (i, j), i < j.
    The result is a maximum spanning forest when the verified graph is disconnected."""
    K = len(S)
    iu, ju = np.triu_indices(K, 1)
    order = np.argsort(-S[iu, ju], kind="stable")
    dsu = _DSU(K)
    tree: list[tuple[int, int]] = []
    failed: list[tuple[int, int]] = []
    for e in order:
        i, j = int(iu[e]), int(ju[e])
        if dsu.find(i) == dsu.find(j):
            continue
        if max_attempts is not None and len(tree) + len(failed) >= max_attempts:
            break
        if verify is not None and not verify(i, j):
            failed.append((i, j))
            continue
        dsu.union(i, j)
        tree.append((i, j))
        if len(tree) == K - 1:
            break
    return tree, failed


def candidate_pairs(S: np.ndarray, top: int, extra: Sequence[tuple[int, int]] = ()) -> list[tuple[int, int]]:
    """The pairs `refine_with_inliers` verifies, as sorted (i, j), i < j: every frame's `top` most similar
    frames (by S [K, K]) plus the `extra` pairs."""
    K = len(S)
    cand = {(min(i, j), max(i, j)) for i, j in extra if i != j}
    for i in range(K):
        for j in np.argsort(-S[i])[:min(top, K - 1)]:
            if int(j) != i:
                cand.add((min(i, int(j)), max(i, int(j))))
    return sorted(cand)


def refine_with_inliers(S: np.ndarray, verify, inliers, top: int,
                        extra: Sequence[tuple[int, int]] = ()) -> np.ndarray:
    """Edge weights refined by geometric verification: every frame's `top` most similar frames (by S [K, K])
    are aligned, plus the `extra` pairs (e.g. time neighbours); a verified pair weighs 1 + its inlier count, a
    failed one -1 (never used), an untried one keeps its similarity (in [-1, 1], so verified edges come first and
    untried ones are the next-best fallbacks). verify(i, j) -> bool, inliers(i, j) -> int (after verify).
    Returns W [K, K]."""
    W = np.array(S, dtype=np.float64)
    for i, j in candidate_pairs(S, top, extra):
        W[i, j] = W[j, i] = (1.0 + inliers(i, j)) if verify(i, j) else -1.0
    return W


def compose_tree(root: int, edges: Sequence[tuple[int, int]], T: Mapping[tuple[int, int], np.ndarray]
                 ) -> tuple[dict[int, np.ndarray], dict[int, int]]:
    """Global poses along tree paths. T[(i, j)] = pose of j in i's camera frame (the reverse direction is
    derived). Returns ({node: pose [4, 4] in root's camera frame}, {node: parent}) for the root's component."""
    from .geometry import invert

    adj: dict[int, list[int]] = {}
    for i, j in edges:
        adj.setdefault(i, []).append(j)
        adj.setdefault(j, []).append(i)
    poses = {root: np.eye(4)}
    parent = {root: -1}
    q = deque([root])
    while q:
        p = q.popleft()
        for c in adj.get(p, []):
            if c in poses:
                continue
            T_pc = T[(p, c)] if (p, c) in T else invert(T[(c, p)])
            poses[c] = poses[p] @ T_pc
            parent[c] = p
            q.append(c)
    return poses, parent


# ----------------------------------------------------------------------------- multi-frame


@dataclass
class AlignmentResult:
    """poses: {frame index: T [4, 4] camera -> root camera frame}; root: frame index; edges: tree edges (or
    sequential links) as (frame index, frame index); unaligned: frame indices with no pose; guessed: frame
    indices whose pose was guessed (sequential baseline: a failed link keeps the previous pose);
    edge_stats: {(a, b): PairResult} for every pair tried."""

    poses: dict[int, np.ndarray]
    root: int
    edges: list[tuple[int, int]]
    unaligned: list[int]
    strategy: str
    guessed: list[int] = field(default_factory=list)
    edge_stats: dict[tuple[int, int], PairResult] = field(default_factory=dict)
    similarity: np.ndarray | None = None
    similarity_kind: str = ""
    with_scale: bool = False
    seconds: dict[str, float] = field(default_factory=dict)
    edge: str = "rgbd"    # pairwise edge type used: "rgbd" (3D-3D RANSAC) or "essential" (see AlignConf.edge)
    # tree edges the depth check rejected (`verify_tree`): later rounds never use them again
    rejected_edges: list[tuple[int, int]] = field(default_factory=list)
    # pairs already tried with whole-image matches (`attach_frames`): a pair that failed inside object boxes
    # is not one of them (few boxes give few matches; the whole image may still align it)
    whole_tried: set[frozenset] = field(default_factory=set)
    # what became of each key frame in the end (`align_keyframes`): the step that gave its final pose, or
    # "unaligned"; the steps' own trace events are the history, this is the state
    fates: dict[int, str] = field(default_factory=dict)
    # frames whose pose the last `verify_tree` only re-expressed in a new root's frame (their fate stays)
    rebased: list[int] = field(default_factory=list)

    @property
    def aligned(self) -> list[int]:
        return [i for i in self.poses if i not in set(self.guessed)]

    def to_dict(self) -> dict[str, Any]:
        return {"strategy": self.strategy, "root": self.root, "edges": [list(e) for e in self.edges],
                "aligned": len(self.aligned), "unaligned": list(self.unaligned), "guessed": list(self.guessed),
                "similarity": self.similarity_kind, "with_scale": self.with_scale, "edge": self.edge,
                "pairs_tried": len(self.edge_stats), "pairs_failed": sum(not r.ok for r in self.edge_stats.values()),
                "fates": {str(i): f for i, f in self.fates.items()},
                "edge_stats": {f"{a}-{b}": r.to_dict() for (a, b), r in self.edge_stats.items()},
                "seconds": {k: round(v, 4) for k, v in self.seconds.items()}}


def _as_list(x: Any, frames: Sequence[Any], what: str) -> list[Any]:
    if x is None:
        return [None] * len(frames)
    if isinstance(x, Mapping):
        return [x.get(f.index) for f in frames]
    x = list(x)
    if len(x) != len(frames):
        raise InputError(f"{what}: {len(x)} entries for {len(frames)} frames")
    return x


def _check_frames(frames: list[Any], strategy: str, conf: AlignConf) -> None:
    """Input errors of `align_frames`, named."""
    if strategy not in ("mst", "sequential"):
        raise InputError(f"strategy must be 'mst' or 'sequential', got {strategy!r}")
    if len(frames) < 2:
        raise AlignmentError(f"need at least 2 frames to align, got {len(frames)}")
    for f in frames:
        if f.depth is None:
            raise AlignmentError(f"frame {f.index} has no depth: alignment needs sensor or model depth per frame")
    idx = [int(f.index) for f in frames]
    if len(set(idx)) != len(idx):
        raise InputError("align_frames: frame indices must be unique")
    if conf.edge not in ("auto", "rgbd", "essential"):
        raise InputError(f"alignment config: edge must be 'auto', 'rgbd' or 'essential', got {conf.edge!r}")
    if conf.verify_rank not in ("inliers", "matches"):
        raise InputError(f"alignment config: verify_rank must be 'inliers' or 'matches', got "
                         f"{conf.verify_rank!r}")
    if not isinstance(conf.threads, int) or conf.threads < 0:
        raise InputError(f"alignment config: threads must be an integer >= 0 (0 = the CPU count), got "
                         f"{conf.threads!r}")
    if conf.scale_mode not in ("chain", "graph", "shared"):
        raise InputError(f"alignment config: scale_mode must be 'chain', 'graph' or 'shared', got "
                         f"{conf.scale_mode!r}")


class _PairVerifier:
    """Pairwise alignment of frames by position (a, b), each pair aligned once: the PairResult per frame-index
    pair (`stats`), the transforms of the verified pairs by position (`Tpair`), match and RANSAC seconds."""

    def __init__(self, frames: list[Any], m: KeyedMatcher, edge: str, conf: AlignConf, with_scale: bool,
                 boxes: list[Any]):
        self.frames, self.m, self.edge, self.conf, self.with_scale, self.boxes = frames, m, edge, conf, with_scale, boxes
        self.stats: dict[tuple[int, int], PairResult] = {}
        self.Tpair: dict[tuple[int, int], np.ndarray] = {}
        self.secs = {"match": 0.0, "ransac": 0.0}
        self.threads = worker_threads(conf.threads)
        self._ready: dict[tuple[int, int], tuple[PairResult, EssentialPose | None]] = {}  # `prefetch`ed results
        self._ready_refine: dict[tuple[int, int], PairResult] = {}
        self.ok_cache: dict[tuple[int, int], bool] = {}
        self.n_inl: dict[tuple[int, int], int] = {}
        self._matches: dict[tuple[int, int], Matches] = {}
        # essential edges: refinement deferred to the edges the tree takes (`refine_edge`); the RANSAC poses kept
        self.defer_refine = False
        self._poses: dict[tuple[int, int], EssentialPose] = {}
        self.refined: set[tuple[int, int]] = set()

    def match(self, a: int, b: int) -> Matches:
        """The pair's matches, computed once (ranking by match count and verifying read the same ones)."""
        if (a, b) not in self._matches:
            fa, fb = self.frames[a], self.frames[b]
            t0 = time.perf_counter()
            self._matches[(a, b)] = self.m.match_keys(fa.index, fa.rgb, fb.index, fb.rgb, self.boxes[a], self.boxes[b])
            self.secs["match"] += time.perf_counter() - t0
        return self._matches[(a, b)]

    def n_depth_matches(self, a: int, b: int) -> int:
        """Matches with valid depth in both frames: what RANSAC could use, an upper bound of its inliers."""
        a, b = min(a, b), max(a, b)
        m = self.match(a, b)
        return int(depth_valid(m, self.frames[a].depth, self.frames[b].depth, self.conf, self.with_scale).sum())

    def verify(self, a: int, b: int) -> bool:
        """Align frames at positions a, b (a result `prefetch` computed is taken, not recomputed) and record it."""
        ready = self._ready.pop((a, b), None)
        r, pose = ready if ready is not None else self._solve(a, b, self.match(a, b))
        self.secs["ransac"] += r.seconds
        self.stats[(self.frames[a].index, self.frames[b].index)] = r
        if pose is not None:
            self._poses[(a, b)] = pose
            if self.conf.essential_refine and not self.defer_refine:
                self.refined.add((a, b))
        if r.ok:
            self.Tpair[(a, b)] = r.T_ab
        return r.ok

    def _solve(self, a: int, b: int, mt: Matches) -> tuple[PairResult, EssentialPose | None]:
        """One pair's alignment from its matches; touches no shared state (runs in worker threads). rgbd RANSAC
        draws from the pair's own stream (seed, frame a, frame b); OpenCV's USAC seeds each call itself."""
        fa, fb = self.frames[a], self.frames[b]
        da, db = getattr(fa, "dist", None), getattr(fb, "dist", None)
        if self.edge == "essential":
            pose = essential_pose(mt, fa.K, fb.K, self.conf, da, db)
            if isinstance(pose, PairResult):
                return pose, None
            refine = self.conf.essential_refine and not self.defer_refine
            return essential_edge(pose, fa.depth, fb.depth, self.conf, refine), pose
        rng = np.random.default_rng((self.conf.seed, int(fa.index), int(fb.index)))
        return align_pair(mt, fa.depth, fa.K, fb.depth, fb.K, self.conf, self.with_scale, rng, da, db), None

    def prefetch(self, pairs: Sequence[tuple[int, int]]) -> None:
        """Align the given (a, b) pairs not aligned yet concurrently on `threads` threads; `verify` then records
        them in whatever order it is called, so the state is exactly that of aligning them one by one. Matches
        are computed here first, in order, in this thread (a matcher need not be thread-safe)."""
        todo = list(dict.fromkeys(p for p in pairs if p not in self._ready and p not in self._done()))
        if self.threads <= 1 or len(todo) < 2:
            return
        jobs = [(a, b, self.match(a, b)) for a, b in todo]
        with ThreadPoolExecutor(min(self.threads, len(jobs))) as ex:
            for (a, b, _m), res in zip(jobs, ex.map(lambda j: self._solve(*j), jobs)):
                self._ready[(a, b)] = res

    def _done(self) -> set[tuple[int, int]]:
        pos = {int(f.index): k for k, f in enumerate(self.frames)}
        return {(pos[i], pos[j]) for i, j in self.stats}

    def verify_cached(self, a: int, b: int) -> bool:
        a, b = min(a, b), max(a, b)
        if (a, b) not in self.ok_cache:
            self.ok_cache[(a, b)] = self.verify(a, b)
            self.n_inl[(a, b)] = (self.stats[(self.frames[a].index, self.frames[b].index)].n_inliers
                                  if self.ok_cache[(a, b)] else 0)
        return self.ok_cache[(a, b)]

    def prefetch_refine(self, edges: Sequence[tuple[int, int]]) -> None:
        """The deferred refinements of verified essential edges (a < b), computed concurrently (see `prefetch`);
        `refine_edge` takes them."""
        todo = [e for e in edges if e not in self.refined and e in self._poses and e not in self._ready_refine]
        if self.threads <= 1 or len(todo) < 2 or not self.conf.essential_refine:
            return
        def run(e: tuple[int, int]) -> PairResult:
            fa, fb = self.frames[e[0]], self.frames[e[1]]
            return essential_edge(self._poses[e], fa.depth, fb.depth, self.conf, True)
        with ThreadPoolExecutor(min(self.threads, len(todo))) as ex:
            self._ready_refine.update(zip(todo, ex.map(run, todo)))

    def refine_edge(self, a: int, b: int) -> bool:
        """A verified essential edge (a < b) with the refinement deferred: refine it now (same inliers; the pose
        and its baseline scales change). False when the refined pose no longer fixes the scale."""
        if (a, b) in self.refined or not self.conf.essential_refine:
            return self.ok_cache.get((a, b), False)
        fa, fb = self.frames[a], self.frames[b]
        r = self._ready_refine.pop((a, b), None) or essential_edge(self._poses[(a, b)], fa.depth, fb.depth,
                                                                    self.conf, True)
        self.secs["ransac"] += r.seconds - self._poses[(a, b)].seconds
        self.stats[(fa.index, fb.index)] = r
        self.refined.add((a, b))
        if r.ok:
            self.Tpair[(a, b)] = r.T_ab
        else:
            self.Tpair.pop((a, b), None)
        self.ok_cache[(a, b)] = r.ok
        return r.ok

    def inliers(self, a: int, b: int) -> int:
        self.verify_cached(a, b)
        return self.n_inl[(min(a, b), max(a, b))]


def _time_order(frames: list[Any]) -> list[int]:
    return sorted(range(len(frames)), key=lambda k: (frames[k].t, int(frames[k].index)))


def _candidate_widths(conf: AlignConf, edge: str) -> tuple[int, int]:
    """(first round's top-k, time neighbours) of the candidate pairs for this edge type (AlignConf defaults)."""
    narrow = edge == "rgbd" and conf.verify_rank == "inliers"  # (the lazy ranking verifies ~K pairs anyway)
    top = conf.verify_top_first if conf.verify_top_first is not None else (
        min(2, conf.verify_top) if narrow else conf.verify_top)
    top = max(1, min(top, conf.verify_top))
    n_nb = conf.verify_neighbours if conf.verify_neighbours is not None else int(
        edge == "essential" or top < conf.verify_top)
    return top, n_nb


def _widening_weights(S: np.ndarray, pv: _PairVerifier, top: int, max_top: int,
                      extra: Sequence[tuple[int, int]]) -> np.ndarray:
    """`refine_with_inliers` over each frame's `top` most similar frames (+ `extra`), widened by one frame per
    round up to `max_top` while the verified pairs do not connect every frame: a frame whose first candidates
    all failed gets more before the tree falls back to unverified similarity edges."""
    while True:
        pv.prefetch(candidate_pairs(S, top, extra))
        W = refine_with_inliers(S, pv.verify_cached, pv.inliers, top, extra)
        if top >= max_top or _connected(len(S), [e for e, ok in pv.ok_cache.items() if ok]):
            return W
        top += 1


def _connected(n: int, edges: Sequence[tuple[int, int]]) -> bool:
    """Whether the undirected graph on n nodes with these edges is connected."""
    dsu, parts = _DSU(n), n
    for a, b in edges:
        parts -= dsu.union(a, b)
    return parts <= 1


def _align_mst(frames: list[Any], pv: _PairVerifier, embeddings: np.ndarray | None
               ) -> tuple[int, dict[int, np.ndarray], list[tuple[int, int]], np.ndarray, str]:
    """Similarity matrix, root, geometric refinement, Kruskal, composition (module docstring, steps 1-5).
    Returns (root position, poses by frame index, tree edges by frame index, S, similarity kind)."""
    conf, idx = pv.conf, [int(f.index) for f in frames]
    t0 = time.perf_counter()
    S, kind = similarity_matrix([f.rgb for f in frames] if embeddings is None else None, embeddings, conf.hist_bins,
                                pv.threads)
    pv.secs["similarity"] = time.perf_counter() - t0
    root = choose_root(S)
    t0 = time.perf_counter()
    W = S
    if conf.verify_top > 0:
        top, n_nb = _candidate_widths(conf, pv.edge)
        order = _time_order(frames)
        nb = [(order[p], order[p + d]) for d in range(1, n_nb + 1) for p in range(len(order) - d)]
        if conf.verify_rank == "inliers":
            # ranking and the scale graph need every candidate's inliers and scales, not its refined pose
            pv.defer_refine = pv.edge == "essential"
            W = _widening_weights(S, pv, top, conf.verify_top, nb)
        else:  # lazy: ranked by match count, verified by Kruskal only when it takes the edge
            W = refine_with_inliers(S, lambda i, j: True, pv.n_depth_matches, conf.verify_top, nb)
    tree, _failed = maximum_spanning_tree(W, pv.verify_cached, conf.max_attempts)
    while pv.defer_refine:  # the tree's edges refined; one that fails then is dropped and the tree re-grown
        pv.prefetch_refine(tree)
        bad = [e for e in tree if not pv.refine_edge(*e)]
        if not bad:
            break
        for i, j in bad:
            W[i, j] = W[j, i] = -1.0
        tree, _failed = maximum_spanning_tree(W, pv.verify_cached, conf.max_attempts)
    pv.secs["tree"] = time.perf_counter() - t0
    root = root_in_largest(S, tree, root)
    if pv.edge == "essential" and conf.scale_mode == "graph":
        _rescale_essential(pv.Tpair, tree, pv.stats, idx, root)
    local, _parent = compose_tree(root, tree, pv.Tpair)
    return root, {idx[k]: T for k, T in local.items()}, [(idx[i], idx[j]) for i, j in tree], S, kind


def _align_sequential(frames: list[Any], pv: _PairVerifier
                      ) -> tuple[int, dict[int, np.ndarray], list[tuple[int, int]], list[int]]:
    """The naive baseline: t -> t+1 links; a failed link keeps the previous pose (listed as guessed)."""
    idx = [int(f.index) for f in frames]
    order = _time_order(frames)
    root = order[0]
    poses = {idx[root]: np.eye(4)}
    edges, guessed = [], []
    pv.prefetch(list(zip(order[:-1], order[1:])))
    prev = root
    for k in order[1:]:
        if pv.verify(prev, k):
            poses[idx[k]] = poses[idx[prev]] @ pv.Tpair[(prev, k)]
            edges.append((idx[prev], idx[k]))
        else:  # naive baseline: keep the previous pose
            poses[idx[k]] = poses[idx[prev]].copy()
            guessed.append(idx[k])
        prev = k
    return root, poses, edges, guessed


def _record_alignment(trace: Any, res: AlignmentResult, n: int, step: bool = False) -> None:
    """Decisions and the unaligned frames of one `align_frames` call: a final state ("degraded") for a caller
    that stops there, history (kind "alignment") for a first round that later steps continue (`step`)."""
    t = as_trace(trace)
    t.decide("alignment.strategy", res.strategy)
    t.decide("alignment.edge", res.edge)
    t.decide("alignment.similarity", res.similarity_kind or "time_order")
    t.decide("alignment.root", res.root)
    if res.unaligned:
        t.event("alignment" if step else "degraded",
                f"{'first round: ' if step else ''}{len(res.unaligned)} of {n} frames could not be aligned "
                f"(no verified edge to the root's tree)", frames=res.unaligned, stage="alignment")
    if res.guessed:
        t.event("degraded", f"sequential chaining: {len(res.guessed)} failed links kept the previous pose",
                frames=res.guessed)


def align_frames(frames: Sequence[Any], matcher: Any = "sift", strategy: str = "mst",
                 conf: AlignConf | Mapping[str, Any] | None = None, embeddings: np.ndarray | None = None,
                 boxes: Sequence[np.ndarray | None] | Mapping[int, np.ndarray] | None = None,
                 with_scale: bool = False, trace: Any = None, step: bool = False) -> AlignmentResult:
    """Align frames (objects with .rgb [H, W, 3], .depth [H, W] metres (or relative depth with with_scale),
    .K [3, 3], .index) into the root camera's frame.

    matcher: 'sift' | 'orb' | a `matching.Matcher` (features are cached per frame when it is a `KeyedMatcher`);
    strategy: 'mst' | 'sequential'; embeddings: [K, D] for the similarity matrix (else colour histograms);
    boxes: per-frame [N, 4] boxes to restrict matching (list in frame order or {frame index: boxes});
    with_scale: estimate Sim(3) per edge (relative, non-metric depth); step: a first round that later steps
    continue (its unaligned frames are recorded as history, not as the final state).
    """
    conf = AlignConf.merged(conf)
    frames = list(frames)
    _check_frames(frames, strategy, conf)
    idx = [int(f.index) for f in frames]
    edge = conf.edge if conf.edge != "auto" else ("essential" if with_scale else "rgbd")
    m = make_matcher(matcher)
    if edge == "essential" and conf.essential_px is None:
        conf = replace(conf, essential_px=float(getattr(m, "keypoint_px", 1.0)))
    pv = _PairVerifier(frames, m, edge, conf, with_scale, _as_list(boxes, frames, "boxes"))
    extract0 = getattr(m, "extract_seconds", 0.0)
    t_all = time.perf_counter()
    S, kind, guessed = None, "", []
    if strategy == "mst":
        root, poses, edges, S, kind = _align_mst(frames, pv, embeddings)
    else:
        root, poses, edges, guessed = _align_sequential(frames, pv)
    secs = pv.secs
    secs["total"] = time.perf_counter() - t_all
    secs["extract"] = getattr(m, "extract_seconds", 0.0) - extract0
    secs["match"] -= secs["extract"]  # match time excluding feature extraction
    unaligned = [i for i in idx if i not in poses]
    res = AlignmentResult(poses, idx[root], edges, unaligned, strategy, guessed, pv.stats, S, kind, with_scale, secs,
                          edge)
    _record_alignment(trace, res, len(idx), step)
    return res


def _rescale_essential(Tpair: dict[tuple[int, int], np.ndarray], tree: Sequence[tuple[int, int]],
                       stats: Mapping[tuple[int, int], PairResult], idx: Sequence[int], root: int) -> None:
    """Rewrite the tree's essential edges with per-frame scales solved over all verified edges: T_ab =
    [(sigma_b / sigma_a) R_ab, (L_ab / sigma_a) d_ab], L_ab = geometric mean of sigma_a scale_a and sigma_b scale_b
    (the baseline in global units), d_ab the unit translation direction; composing gives pose_k = [sigma_k R_k,
    c_k], which maps frame k's depth points into the root frame (in the root's depth units)."""
    pos = {int(f): k for k, f in enumerate(idx)}
    by_pos = {(pos[a], pos[b]): r for (a, b), r in stats.items()}
    sig = essential_frame_scales(len(idx), root, by_pos)
    for a, b in tree:
        r = by_pos[(a, b)]
        T = Tpair[(a, b)]
        R = T[:3, :3] / transform_scale(T)
        d = T[:3, 3] / max(np.linalg.norm(T[:3, 3]), 1e-12)
        L = np.sqrt(sig[a] * r.scale_a * sig[b] * r.scale_b)
        Tn = np.eye(4)
        Tn[:3, :3] = (sig[b] / sig[a]) * R
        Tn[:3, 3] = (L / sig[a]) * d
        Tpair[(a, b)] = Tn


def pose_change(T_a: np.ndarray, T_b: np.ndarray) -> tuple[float, float]:
    """(translation m, rotation deg) between two poses [4, 4] (camera centres, relative rotation)."""
    d = np.linalg.norm(T_a[:3, 3] - T_b[:3, 3])
    Ra = T_a[:3, :3] / transform_scale(T_a)
    Rb = T_b[:3, :3] / transform_scale(T_b)
    return float(d), rotation_angle_deg(Ra.T @ Rb)


# ----------------------------------------------------------------------------- the pipeline's alignment policy
# box matches -> whole image -> bridge rounds -> depth verification (paper: multi-frame alignment, plus what real
# clips needed: key frames far apart in time share no view). `align_keyframes` is the entry point.


class AlignPolicy(Protocol):
    """The pipeline settings the policy reads (`pipeline.PipelineConfig` has them; see its comments)."""

    alignment: AlignConf
    whole_image_fallback: bool
    relative_box_matching: bool
    bridge_frames: int
    bridge_gap_s: float
    bridge_rounds: int
    bridge_max_gap_s: float
    revisit_tries: int
    verify_depth: bool
    max_free_space_violation: float
    attach_tries: int


WithDepth = Callable[[Any], Any]   # a source frame -> the same frame with the depth the run uses (sensor or model)


def depth_consistency(fa: Any, fb: Any, T_ab: np.ndarray, stride: int = 8) -> tuple[float, float, float]:
    """How well frame b's depth agrees with frame a's under T_ab (b camera -> a camera).

    Returns (overlap: share of b's points that land on valid depth in a, consistent: share of those within
    5 cm + 3% of a's depth, violation: share of those lying clearly in FRONT of a's observed surface, i.e. in
    space a sees as empty). A wrong transform puts points in free space; a right one only at occlusion edges."""
    from .geometry import backproject

    p, _ = backproject(fb.depth, fb.K, stride=stride)
    if len(p) == 0:
        return 0.0, 0.0, 0.0
    q = transform(T_ab, p)
    z = q[:, 2]
    zs = np.maximum(z, 1e-6)
    uv = np.stack([fa.K[0, 0] * q[:, 0] / zs + fa.K[0, 2], fa.K[1, 1] * q[:, 1] / zs + fa.K[1, 2]], 1)
    zo = sample_depth(fa.depth, uv)
    ins = (z > 0.1) & (zo > 0)
    n = max(int(ins.sum()), 1)
    cons = ins & (np.abs(z - zo) < 0.05 + 0.03 * zo)
    viol = ins & (z < zo - (0.10 + 0.05 * zo))
    return float(ins.mean()), float(cons.sum() / n), float(viol.sum() / n)


def _edge_ok(fa: Any, fb: Any, T_ab: np.ndarray, max_violation: float) -> bool:
    """The depth check of one edge, both ways: neither frame puts more than `max_violation` of its points into
    space the other sees as empty."""
    from .geometry import invert

    return max(depth_consistency(fa, fb, T_ab)[2], depth_consistency(fb, fa, invert(T_ab))[2]) <= max_violation


def _reattach(al: AlignmentResult, poses: dict[int, np.ndarray], dropped: list[int], ok: Callable[..., bool]
              ) -> list[int]:
    """Re-attach dropped frames through other pairs alignment verified that pass `ok`; mutates poses."""
    from .geometry import invert

    reattached = []
    changed = True
    while changed:
        changed = False
        for (a, b), r in al.edge_stats.items():
            if not r.ok:
                continue
            for x, y, T in ((a, b, r.T_ab), (b, a, invert(r.T_ab))):  # T: pose of y in x's camera
                if x in poses and y not in poses and y in dropped and ok(x, y, T):
                    poses[y] = poses[x] @ T
                    reattached.append(y)
                    changed = True
    return reattached


def verify_tree(al: AlignmentResult, frames: dict[int, Any], conf: AlignPolicy, trace: Any = None
                ) -> AlignmentResult:
    """Check every tree edge with `depth_consistency` in both directions; an edge that puts more than
    `max_free_space_violation` of the points into observed free space is cut. The largest part of the cut tree
    stays aligned (the root's part on a tie; else the root moves to the part's frame nearest the old root and
    the poses are re-expressed in it), the other parts are re-attached through other verified pairs (from the
    pairs alignment already tried) that pass the same check, if any; the rest become unaligned. Recorded in the
    trace; the cut edges are kept in `al.rejected_edges` so that a later round does not use them again."""
    from .geometry import invert

    def ok(a: int, b: int, T_ab: np.ndarray) -> bool:
        if a not in frames or b not in frames:
            return True  # frames without kept depth are not checked
        return _edge_ok(frames[a], frames[b], T_ab, conf.max_free_space_violation)

    poses = dict(al.poses)
    order = _tree_order(al.root, al.edges, poses)
    bad: list[tuple[int, int]] = list(al.rejected_edges)
    part = {al.root: al.root}
    for p, c in order:  # breadth-first from the root: each edge (parent, child) once
        if ok(p, c, invert(poses[p]) @ poses[c]):
            part[c] = part[p]
        else:
            bad.append((p, c))
            part[c] = c  # a new part, headed by the frame nearest the root
    al.rejected_edges = bad
    sizes: dict[int, int] = {}
    for h in part.values():
        sizes[h] = sizes.get(h, 0) + 1
    head = max(sizes, key=lambda h: (sizes[h], h == al.root))  # ties: the root's part, then the nearest
    dropped = [i for i in poses if part.get(i) != head]
    if not dropped:
        return al
    moved = head != al.root
    if moved:  # the root's own part was the smaller: the map keeps the most key frames
        T = invert(poses[head])
        poses = {i: T @ P for i, P in poses.items()}
        al.root = head
        al.rebased = [i for i in poses if i not in dropped]
    for i in dropped:
        poses.pop(i)
    reattached = _reattach(al, poses, dropped, ok)
    lost = [i for i in dropped if i not in poses]
    as_trace(trace).event("alignment", f"depth check rejected tree edge(s) {bad}: {len(dropped)} frame(s) "
                          f"detached" + (f" (the larger part kept, rooted at frame {head})" if moved else "") +
                          f", {len(reattached)} re-attached through other verified pairs, {len(lost)} left unaligned",
                          stage="alignment", rejected=[list(e) for e in bad], unaligned=lost, root=al.root)
    al.poses = poses
    al.unaligned = sorted(set(al.unaligned) | set(lost))
    return al


def _tree_order(root: int, edges: Sequence[tuple[int, int]], poses: Mapping[int, Any]) -> list[tuple[int, int]]:
    """The tree's edges (parent, child) in breadth-first order from `root`, over frames with a pose."""
    adj: dict[int, list[int]] = {}
    for a, b in edges:
        adj.setdefault(a, []).append(b)
        adj.setdefault(b, []).append(a)
    seen, queue, out = {root}, deque([root]), []
    while queue:
        p = queue.popleft()
        for c in adj.get(p, []):
            if c not in seen and c in poses:
                seen.add(c)
                out.append((p, c))
                queue.append(c)
    return out


def attach_frames(al: AlignmentResult, frames: dict[int, Any], todo: Sequence[int], matcher: KeyedMatcher,
                  conf: AlignPolicy, tries: int | None = None) -> list[int]:
    """Attach frames without a pose to the tree one edge at a time, metric depth only: each frame in `todo` is
    matched (whole image, cached features) to its `tries` (default `conf.attach_tries`) nearest aligned frames
    in time, the first edge that passes RANSAC and the depth check (`max_free_space_violation` both ways) gives
    its pose; repeated while frames get attached (a new one can host the next). Costs <= tries pairs per frame,
    against a full re-alignment's all-pairs search. Mutates al (poses, edges, unaligned, edge_stats); returns
    the attached."""
    tries = conf.attach_tries if tries is None else tries
    aconf = AlignConf.merged(conf.alignment)
    rng = np.random.default_rng(aconf.seed)
    # not al.edge_stats: those pairs failed with matches inside the boxes only (the trial's 0-of-13 attached)
    tried = al.whole_tried | set(frozenset(e) for e in al.rejected_edges)
    attached: list[int] = []
    changed = True
    while changed:
        changed = False
        for u in [int(i) for i in todo if int(i) not in al.poses and int(i) in frames]:
            fu = frames[u]
            near = sorted((a for a in al.poses if a in frames and frozenset((a, u)) not in tried),
                          key=lambda a: (abs(float(frames[a].t) - float(fu.t)), a))[:tries]
            for a in near:
                tried.add(frozenset((a, u)))
                if _try_edge(al, frames, a, u, matcher, conf, aconf, rng):
                    attached.append(u)
                    changed = True
                    break
    al.unaligned = [i for i in al.unaligned if i not in al.poses]
    return attached


def _try_edge(al: AlignmentResult, frames: Mapping[int, Any], a: int, u: int, matcher: KeyedMatcher,
              conf: AlignPolicy, aconf: AlignConf, rng: np.random.Generator) -> bool:
    """One whole-image edge from aligned frame a to frame u: RANSAC, then the depth check both ways; on success
    u gets its pose through a. Recorded in al (whole_tried, edge_stats, and poses + edges on success)."""
    al.whole_tried.add(frozenset((a, u)))
    fa, fu = frames[a], frames[u]
    mt = matcher.match_keys(a, fa.rgb, u, fu.rgb, None, None)
    r = align_pair(mt, fa.depth, fa.K, fu.depth, fu.K, aconf, False, rng, getattr(fa, "dist", None),
                   getattr(fu, "dist", None))
    al.edge_stats[(a, u)] = r
    if not r.ok or not _edge_ok(fa, fu, r.T_ab, conf.max_free_space_violation):
        return False
    al.poses[u] = al.poses[a] @ r.T_ab
    al.edges.append((a, u))
    return True


class BlockPairs:
    """Matcher wrapper that returns no matches for the given frame pairs (edges the depth check rejected), so a
    new alignment round cannot choose them again; everything else goes to the wrapped matcher."""

    def __init__(self, matcher: KeyedMatcher, pairs: Sequence[tuple[int, int]]):
        self.m = matcher
        self.pairs = {frozenset(p) for p in pairs}

    def match_keys(self, k0: Any, rgb0: np.ndarray, k1: Any, rgb1: np.ndarray, boxes0: Any = None,
                   boxes1: Any = None) -> Matches:
        if frozenset((k0, k1)) in self.pairs:
            return Matches.empty()
        return self.m.match_keys(k0, rgb0, k1, rgb1, boxes0, boxes1)

    def match(self, rgb0: np.ndarray, rgb1: np.ndarray, boxes0: Any = None, boxes1: Any = None) -> Matches:
        return self.m.match(rgb0, rgb1, boxes0, boxes1)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.m, name)


def _bridge_frames(al: AlignmentResult, have: set[int], prev: Mapping[int, Any], cands: list[int], source: Any,
                   conf: AlignPolicy) -> list[int]:
    """Candidate frames (at most `bridge_gap_s` apart, `bridge_frames` in all) between each unaligned key frame
    and its nearest aligned key frame in time, across gaps up to `bridge_max_gap_s`; earlier rounds' kept."""
    times = {i: float(source.timestamps[i]) for i in cands}
    extra: list[int] = []
    for u in sorted(al.unaligned, key=lambda u: min(abs(u - a) for a in al.poses)):
        a = min(al.poses, key=lambda j: abs(j - u))
        lo, hi = sorted((u, a))
        if abs(float(source.timestamps[hi]) - float(source.timestamps[lo])) > conf.bridge_max_gap_s:
            continue  # a long chain of bridges drifts: better unaligned (reported) than misplaced
        between = [c for c in cands if lo < c < hi and c not in have and c not in extra and c not in prev]
        last = float(source.timestamps[lo])
        for c in between:
            if times[c] - last >= conf.bridge_gap_s:
                extra.append(c)
                last = times[c]
        if len(extra) >= conf.bridge_frames:
            break
    return sorted(set(extra[:conf.bridge_frames]) | set(prev))


def bridge_realign(al: AlignmentResult, frames: list[Any], boxes: dict[int, Any], cands: list[int], source: Any,
                   matcher: KeyedMatcher, with_depth: WithDepth, with_scale: bool, conf: AlignPolicy, trace: Any,
                   previous: Sequence[Any] = ()) -> tuple[AlignmentResult, list[Any]]:
    """Relative depth: key frames far apart in time often share no view, so the tree falls apart into
    components. Connect each unaligned key frame to its nearest aligned key frame in time through intermediate
    candidate frames (`_bridge_frames`; used for poses only, never detected) and align again. Key frames still
    unaligned afterwards stay unaligned (recorded). Returns (alignment, the bridge frames used)."""
    trace = as_trace(trace)
    have = {f.index for f in frames}
    prev = {f.index: f for f in previous}  # bridges of an earlier round are kept (their depth is loaded)
    extra = _bridge_frames(al, have, prev, cands, source, conf)
    if not set(extra) - set(prev):
        return al, []
    bf = [prev[i] if i in prev else with_depth(source[i]) for i in extra]
    with trace.stage("alignment"):
        al2 = align_frames(frames + bf, matcher, "mst", conf.alignment, None,
                           {**boxes, **{i: None for i in extra}}, with_scale=with_scale, trace=None)
    before = len(al.unaligned)
    al2.unaligned = [i for i in al2.unaligned if i in have]
    al2.rejected_edges = list(al.rejected_edges)
    trace.event("alignment", f"{before} key frame(s) had no verified edge to the tree; {len(extra)} bridge "
                f"frames between them "
                f"and their neighbours in time left {len(al2.unaligned)} unaligned", stage="alignment",
                bridges=extra, unaligned=al2.unaligned)
    if len(al2.poses) and sum(i in have for i in al2.poses) >= sum(i in have for i in al.poses):
        return al2, bf
    return al, []


def _whole_image_realign(al: AlignmentResult, frames: list[Any], boxes: dict[int, Any], emb: Any,
                         matcher: KeyedMatcher, with_scale: bool, conf: AlignPolicy, trace: Any
                         ) -> tuple[AlignmentResult, dict[int, Any]]:
    """Too few matches inside the task objects' boxes (small or few objects): match whole images instead;
    the better tree is kept. Returns (alignment, the boxes it used)."""
    with trace.stage("alignment"):
        al2 = align_frames(frames, matcher, "mst", conf.alignment, emb, None, with_scale=with_scale, trace=None)
    trace.event("alignment", f"alignment inside object boxes left {len(al.unaligned)} of {len(frames)} key "
                f"frames "
                f"unaligned; whole-image matching left {len(al2.unaligned)}", stage="alignment",
                boxes_unaligned=list(al.unaligned), whole_unaligned=list(al2.unaligned))
    if len(al2.unaligned) < len(al.unaligned):
        return al2, {i: None for i in boxes}
    return al, boxes


class Fates:
    """What became of each key frame: the step that gave it its current pose, or "unaligned" (`after` is called
    once per step; a step that leaves a frame's pose object as it was leaves its fate too)."""

    def __init__(self, keys: Sequence[int]):
        self.keys = sorted(int(i) for i in keys)
        self.how: dict[int, str] = {}
        self.steps: list[str] = []   # in the order they ran (the summary's order)
        self._poses: dict[int, Any] = {}

    def after(self, al: AlignmentResult, step: str) -> None:
        if step not in self.steps:
            self.steps.append(step)
        for i in self.keys:
            T = al.poses.get(i)
            if T is None:
                self.how[i] = "unaligned"
            elif self._poses.get(i) is not T and i not in al.rebased:
                self.how[i] = step
            self._poses[i] = T
        al.rebased = []

    def summary(self) -> str:
        """"12 of 16 key frames aligned (9 box-matched tree, 3 through bridge frames)"."""
        n = len(self.keys)
        got_by = [self.how.get(i, "unaligned") for i in self.keys]
        counts = {k: got_by.count(k) for k in self.steps if k != "unaligned" and k in got_by}
        got = sum(counts.values())
        return f"{got} of {n} key frames aligned" + (f" ({', '.join(f'{c} {k}' for k, c in counts.items())})"
                                                    if counts else "")


def align_rest_relative(al: AlignmentResult, frames: list[Any], boxes: dict[int, Any], emb: Any,
                        matcher: KeyedMatcher, source: Any, with_depth: WithDepth, with_scale: bool,
                        conf: AlignPolicy, trace: Any, over_budget: Callable[[list[int]], bool],
                        fates: Fates | None = None) -> tuple[AlignmentResult, list[Any]]:
    """Relative depth (no depth check): the box-matched tree's unaligned frames get a whole-image re-alignment,
    then bridge rounds (`bridge_realign`) while they buy aligned key frames. Returns (alignment, bridge frames
    used)."""
    trace = as_trace(trace)
    fates = fates or Fates([f.index for f in frames])
    if al.unaligned and conf.whole_image_fallback and any(b is not None for b in boxes.values()):
        al, boxes = _whole_image_realign(al, frames, boxes, emb, matcher, with_scale, conf, trace)
        fates.after(al, "whole-image tree")
    used: list[Any] = []
    keys = {f.index for f in frames}
    al.unaligned = [i for i in al.unaligned if i in keys]
    for _ in range(conf.bridge_rounds):
        if not al.unaligned or conf.bridge_frames <= 0 or over_budget(al.unaligned):
            break
        blocked = BlockPairs(matcher, al.rejected_edges)  # never re-use a rejected edge
        # bridge frames come from the whole video (consecutive frames match best), not only dedup's candidates
        al_b, bridges = bridge_realign(al, frames, boxes, list(range(len(source))), source, blocked, with_depth,
                                       with_scale, conf, trace, used)
        if not bridges:
            break
        al_b.unaligned = [i for i in al_b.unaligned if i in keys]  # bridges are not counted: only key frames
        if len(al_b.unaligned) >= len(al.unaligned):
            # another round only pays where it buys aligned key frames: keep the better tree and stop
            trace.event("alignment", f"bridge round left {len(al_b.unaligned)} key frame(s) unaligned (before: "
                        f"{len(al.unaligned)}): kept the tree without it, no further rounds", stage="alignment")
            break
        al, used = al_b, bridges
        fates.after(al, "tree with bridge frames")
    return al, used


def align_rest_metric(al: AlignmentResult, frames: list[Any], matcher: KeyedMatcher, source: Any,
                      with_depth: WithDepth, conf: AlignPolicy, trace: Any,
                      over_budget: Callable[[list[int]], bool], fates: Fates | None = None,
                      thumbs: Mapping[int, np.ndarray] | None = None) -> list[Any]:
    """Metric depth after the box-matched tree: depth-check its edges, attach what it left out by whole-image
    edges, then bridge what is still out (in time, then by appearance with `thumbs`: `bridge_attach`). Returns
    the bridge frames used."""
    trace = as_trace(trace)
    fates = fates or Fates([f.index for f in frames])
    with trace.stage("alignment.verify"):
        al = verify_tree(al, {f.index: f for f in frames}, conf, trace)
    fates.after(al, "re-attached after the depth check")
    keys = {f.index for f in frames}
    al.unaligned = [i for i in al.unaligned if i in keys]
    if al.unaligned and conf.whole_image_fallback:
        before = list(al.unaligned)
        with trace.stage("alignment"):
            got = attach_frames(al, {f.index: f for f in frames}, before, matcher, conf)
        trace.event("alignment", f"box-matched tree left {len(before)} of {len(frames)} key frames unaligned; "
                    f"whole-image edges attached {len(got)}, {len(al.unaligned)} left", stage="alignment",
                    boxes_unaligned=before, attached=got)
        fates.after(al, "whole-image edge")
    if not al.unaligned or conf.bridge_frames <= 0 or conf.bridge_rounds <= 0 or over_budget(al.unaligned):
        return []
    with trace.stage("alignment"):
        used = bridge_attach(al, frames, source, matcher, with_depth, conf, trace, thumbs, fates)
    fates.after(al, "through bridge frames")
    return used


def bridge_attach(al: AlignmentResult, frames: list[Any], source: Any, matcher: KeyedMatcher, with_depth: WithDepth,
                  conf: AlignPolicy, trace: Any = None, thumbs: Mapping[int, np.ndarray] | None = None,
                  fates: Fates | None = None) -> list[Any]:
    """Metric depth: connect each unaligned key frame through a chain of video frames (at least `bridge_gap_s`
    apart, `bridge_frames` in all) walked from its nearest aligned key frame in time towards it (`bridge_chain`),
    one `attach_frames` edge per step, loading a frame only when the chain reaches it and stopping as soon as the
    key frame itself attaches: no re-alignment of the whole set, so a round that cannot buy an aligned frame costs
    only its failed steps. Gaps over `bridge_max_gap_s` are not bridged (long chains drift): key frames that far
    from every aligned one then get bridges found by appearance (`revisit_attach`, with `thumbs`: small gray
    images of the video's frames, e.g. dedup's) from what is left of the same `bridge_frames` budget. Returns
    the bridge frames used (poses only, never detected); recorded."""
    pool = {f.index: f for f in frames}
    keys = set(pool)
    used: list[Any] = []
    budget = conf.bridge_frames
    n0 = len(al.unaligned)
    failed: dict[tuple[int, int], int] = {}  # (anchor, direction) -> the key frame its chain got stuck before
    skipped: list[int] = []
    for u in sorted(al.unaligned, key=lambda u: min((abs(u - a) for a in al.poses if a in keys), default=0)):
        if budget <= 0 or u in al.poses:
            continue
        anchors = [a for a in al.poses if a in keys]
        if not anchors:
            break
        # the nearest aligned key frame on each side in time, the nearer first (a chain can fail on one side)
        sides = [max((j for j in anchors if j < u), default=None), min((j for j in anchors if j > u), default=None)]
        for a in sorted((j for j in sides if j is not None), key=lambda j: abs(j - u)):
            if u in al.poses or abs(float(source.timestamps[u]) - float(source.timestamps[a])) > conf.bridge_max_gap_s:
                continue
            d = int(np.sign(u - a))
            if (a, d) in failed and d * (u - failed[(a, d)]) > 0:
                # a nearer key frame across the same gap from the same anchor was not reached: a chain to this
                # one, beyond it, must cross the same frames, so it would spend the budget without buying one
                skipped.append(u)
                continue
            budget, chain = bridge_chain(al, pool, a, u, source, matcher, with_depth, conf, budget)
            used += chain
            end = chain[-1].index if chain else a
            if u not in al.poses and abs(float(source.timestamps[u]) - float(source.timestamps[end])) \
                    >= 2 * conf.bridge_gap_s:  # stuck inside the gap (not merely u itself failing at its end)
                failed.setdefault((a, d), u)  # the nearest such key frame (they come nearest first)
    al.unaligned = [i for i in al.unaligned if i not in al.poses]
    as_trace(trace).event("alignment", f"bridging: {conf.bridge_frames - budget} video frame(s) tried, "
                          f"{len(used)} attached as "
                          f"bridges, {n0 - len(al.unaligned)} of {n0} key frame(s) aligned through them; "
                          f"{len(al.unaligned)} key frame(s) left unaligned"
                          + (f" ({len(set(skipped))} not tried: behind a gap a chain did not cross)" if skipped
                             else ""), stage="alignment", bridges=[f.index for f in used],
                          unaligned=list(al.unaligned), skipped=sorted(set(skipped)))
    if thumbs and conf.revisit_tries > 0 and al.unaligned and budget > 0:
        if fates is not None:
            fates.after(al, "through bridge frames")
        budget, more = revisit_attach(al, pool, keys, source, matcher, with_depth, conf, thumbs, budget, trace)
        used += more
        if fates is not None:
            fates.after(al, "through bridges found by appearance")
    return used


def thumb_histograms(thumbs: Mapping[int, np.ndarray], bins: int = 32) -> dict[int, np.ndarray]:
    """Gray-level histograms of small gray images, zero-mean and unit-norm, so that a dot product is their
    Pearson correlation (like `similarity_matrix`'s colour histograms; dedup's thumbnails are gray). Pure.
    Chosen over zero-mean NCC of blurred thumbnails and gradient-orientation grids by how often the most alike
    frame far away in time overlaps (synthetic seeds 7 and 8, docs/performance.md)."""
    out = {}
    for i, g in thumbs.items():
        h = np.histogram(np.asarray(g), bins, (0, 256))[0].astype(np.float64)
        h -= h.mean()
        out[int(i)] = h / max(float(np.linalg.norm(h)), 1e-12)
    return out


def revisit_pairs(u: int, aligned: Sequence[int], hist: Mapping[int, np.ndarray], times: Any, max_gap_s: float,
                  skip: set[frozenset[int]], n: int) -> list[tuple[int, int]]:
    """Up to n (c, a) pairs to connect unaligned frame u through a place the video shows twice: c a frame
    with a histogram (u itself included) within `max_gap_s` of u in time and not in `aligned`, a an aligned
    frame more than `max_gap_s` away from u (nearer ones are the time chains' work); each c with the a it is
    most alike, the most alike pairs first, pairs in `skip` (tried) left out. Pure."""
    tu = float(times[u])
    far = [a for a in aligned if a in hist and abs(float(times[a]) - tu) > max_gap_s]
    near = [c for c in hist if c not in aligned and abs(float(times[c]) - tu) <= max_gap_s]
    if not far or not near:
        return []
    sim = np.array([hist[c] for c in near]) @ np.array([hist[a] for a in far]).T
    best = []
    for i, c in enumerate(near):
        order = [j for j in np.argsort(-sim[i], kind="stable") if frozenset((far[j], c)) not in skip]
        if order:
            best.append((-float(sim[i, order[0]]), abs(float(times[c]) - tu), c, far[order[0]]))
    return [(c, a) for _, _, c, a in sorted(best)[:n]]


def revisit_attach(al: AlignmentResult, pool: dict[int, Any], keys: set[int], source: Any, matcher: KeyedMatcher,
                   with_depth: WithDepth, conf: AlignPolicy, thumbs: Mapping[int, np.ndarray], budget: int,
                   trace: Any = None) -> tuple[int, list[Any]]:
    """Bridges found by appearance, metric depth: a long video comes back to places (people walk back), so a
    key frame with no aligned key frame within `bridge_max_gap_s` in time (out of the time chains' reach) may
    still be near (in time) a view of an aligned frame's place. Key frames with an aligned key frame that near
    are left to the time chains (where those failed, a chain from a revisit must cross the same frames near the
    key frame). For each unaligned key frame u out of reach, its `revisit_tries` (c, a) pairs
    (`revisit_pairs`: c near u in time, a aligned far from it, alike by thumbnail histogram) are tried as
    whole-image edges a -> c (RANSAC + the depth check both ways); an attached c is chained to u in time
    (`bridge_chain`). Once u is aligned, the unaligned key frames it has verified pairs with come along
    (`_reattach`, depth-checked), e.g. the rest of a part the depth check cut off. Loads at most `budget`
    frames. Mutates al and pool; returns (budget left, the bridge frames used); recorded."""
    aconf = AlignConf.merged(conf.alignment)
    rng = np.random.default_rng(aconf.seed)
    ts, gap = source.timestamps, conf.bridge_max_gap_s
    todo = [u for u in sorted(al.unaligned) if u not in al.poses and not any(
        a in al.poses and abs(float(ts[a]) - float(ts[u])) <= gap for a in keys)]
    if not todo:
        return budget, []
    hist = thumb_histograms(thumbs)
    n0, tried, used, gained = len(al.unaligned), 0, [], []

    def ok(a: int, b: int, T_ab: np.ndarray) -> bool:
        return a in pool and b in pool and _edge_ok(pool[a], pool[b], T_ab, conf.max_free_space_violation)

    for u in todo:
        if budget <= 0:
            break
        if u in al.poses:
            continue
        for c, a in revisit_pairs(u, list(al.poses), hist, ts, gap, al.whole_tried, conf.revisit_tries):
            if u in al.poses:
                break
            if c in al.poses:
                continue  # attached by an earlier chain of this loop
            if c not in pool:
                if budget <= 0:
                    break
                pool[c] = with_depth(source[c])
                budget -= 1
            tried += 1
            if not _try_edge(al, pool, a, c, matcher, conf, aconf, rng):
                continue
            if c != u:
                used.append(pool[c])
                budget, chain = bridge_chain(al, pool, c, u, source, matcher, with_depth, conf, budget)
                used += chain
        if u in al.poses:
            gained.append(u)
            gained += _reattach(al, al.poses, [i for i in al.unaligned if i in keys and i not in al.poses], ok)
    al.unaligned = [i for i in al.unaligned if i not in al.poses]
    as_trace(trace).event("alignment", f"bridges found by appearance: {len(todo)} key frame(s) more than {gap:g} s "
                          f"from every aligned one, {tried} pair(s) tried, {len(used)} frame(s) attached as "
                          f"bridges, {n0 - len(al.unaligned)} of {n0} key frame(s) aligned through them; "
                          f"{len(al.unaligned)} left unaligned", stage="alignment", out_of_reach=todo,
                          bridges=[f.index for f in used], aligned=gained, unaligned=list(al.unaligned))
    return budget, used


def chain_jumps(gap: float, min_gap: float) -> list[float]:
    """The jump schedule of one `bridge_chain` step over a `gap` (s) to the key frame: halve the gap down to
    `min_gap` (`bridge_gap_s`), then walk at 2, 3, ... x `min_gap` (slow camera motion costs few bridge frames,
    fast motion the dense chain). Pure; a fixed schedule, so a step always ends."""
    halving = [gap / 2 ** k for k in range(1, 32) if gap / 2 ** k >= min_gap]
    walking = [min_gap * k for k in range(2, int(gap / min_gap))]
    return halving + walking


def bridge_chain(al: AlignmentResult, pool: dict[int, Any], a: int, u: int, source: Any, matcher: KeyedMatcher,
                 with_depth: WithDepth, conf: AlignPolicy, budget: int) -> tuple[int, list[Any]]:
    """Walk from aligned frame a towards unaligned key frame u: each step first tries u itself, then jumps
    (`chain_jumps`) to the frame halfway between the chain's end and u, halving the jump on a failed attach
    down to `bridge_gap_s`, then walking on at that spacing. Returns (budget left, the bridge frames
    attached)."""
    ts = source.timestamps
    end, used = a, []
    while budget > 0 and u not in al.poses:
        if attach_frames(al, pool, [u], matcher, conf, tries=1):
            break
        gap = abs(float(ts[u]) - float(ts[end]))
        if gap < 2 * conf.bridge_gap_s or abs(u - end) < 2:
            break  # no room for a bridge frame (in time, or no frame at all between: sparse frames far apart)
        step, moved = (1 if u > end else -1), False
        for jump in chain_jumps(gap, conf.bridge_gap_s):  # a blurred frame is skipped
            if budget <= 0 or moved:
                break
            c = min(range(end + step, u, step), key=lambda i: abs(abs(float(ts[i]) - float(ts[end])) - jump))
            if c in pool:
                continue
            pool[c] = with_depth(source[c])
            budget -= 1
            if attach_frames(al, pool, [c], matcher, conf, tries=1):
                end, moved = c, True
                used.append(pool[c])
        if not moved:
            break  # no bridge frame attached at any jump: give up on u (reported by the caller)
    return budget, used


def align_keyframes(frames: list[Any], matcher: KeyedMatcher, boxes: dict[int, Any], emb: np.ndarray | None,
                    source: Any, with_depth: WithDepth, with_scale: bool, conf: AlignPolicy, trace: Any,
                    over_budget: Callable[[list[int]], bool] = lambda unaligned: False,
                    thumbs: Mapping[int, np.ndarray] | None = None) -> tuple[AlignmentResult, list[Any]]:
    """The key frames' alignment: matches restricted to object boxes (the paper's trick; with relative depth
    only when `relative_box_matching`), MST over frame similarity; then, with metric depth and `verify_depth`,
    every tree edge depth-checked and the frames left out attached one edge at a time (`align_rest_metric`),
    else a whole-image re-alignment and bridge rounds (`align_rest_relative`). `over_budget(unaligned)` says
    (and records) when bridge rounds are skipped. `thumbs` (frame -> small gray image, e.g. dedup's) lets
    metric bridging look for places the video revisits. Returns (alignment over the key frames only, the bridge frames used)."""
    trace = as_trace(trace)
    if with_scale and not conf.relative_box_matching:  # essential edges: whole images from the first tree
        boxes = {i: None for i in boxes}
    with trace.stage("alignment"):
        al = align_frames(frames, matcher, "mst", conf.alignment, emb, boxes, with_scale=with_scale, trace=trace,
                          step=True)
    keys = {f.index for f in frames}
    fates = Fates(keys)
    fates.after(al, "box-matched tree" if any(b is not None for b in boxes.values()) else "whole-image tree")
    if conf.verify_depth and not with_scale:  # metric depth: one edge at a time onto the verified tree (cheap)
        used = align_rest_metric(al, frames, matcher, source, with_depth, conf, trace, over_budget, fates, thumbs)
    else:
        al, used = align_rest_relative(al, frames, boxes, emb, matcher, source, with_depth, with_scale, conf, trace,
                                       over_budget, fates)
    al.unaligned = [i for i in al.unaligned if i in keys]
    _record_fates(trace, al, fates)
    return al, used


def _record_fates(trace: Any, al: AlignmentResult, fates: Fates) -> None:
    """The final state after every step, once: per key frame in `al.fates` and the trace decision
    `alignment.frames`; one count in an event the printed answer repeats ("degraded" when frames stay out)."""
    for i in fates.keys:  # every step recorded its frames; a frame no step placed has no pose
        if i not in al.poses:
            fates.how[i] = "unaligned"
    al.fates = {i: fates.how.get(i, "unaligned") for i in fates.keys}
    trace.decide("alignment.frames", {str(i): f for i, f in al.fates.items()})
    trace.decide("alignment.root", al.root)  # the depth check may have moved it to the larger part
    out = sorted(i for i in fates.keys if al.fates[i] == "unaligned")
    msg = f"alignment: {fates.summary()}"
    if out:
        msg += f"; {len(out)} unaligned, left out of the map: {out}"
    trace.event("degraded" if out else "alignment", msg, stage="alignment", unaligned=out,
                fates={str(i): f for i, f in al.fates.items()})
