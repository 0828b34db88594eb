"""The RGB-only alignment of `align_keyframes` (relative depth): structure from motion (`sfm`) over the key frames
and the scan's kept frames between them; each key frame takes its pose from that stream, or stays unaligned with
the reason its registration was rejected."""
from __future__ import annotations

import time
from typing import Callable, Mapping

import numpy as np

from ..frames import FrameSource
from ..infra.trace import StageLog, as_trace
from ..types import Frame
from .backbone import tiny_descriptor
from .conf import SfmConf
from .matching import KeyedMatcher
from .sfm import SfmResult, keyframe_scale, match_stream, reconstruct
from .tree import AlignmentResult


def stream_positions(keys: list[int], grid: list[int], max_frames: int) -> list[int]:
    """The frames SfM runs over, in time order: every key frame, plus the grid's frames (the scan's kept frames)
    between the first and the last key frame, evenly thinned so that at most `max_frames` are used in all."""
    keys = sorted(set(keys))
    inner = sorted(set(g for g in grid if keys[0] < g < keys[-1]) - set(keys))
    room = max(0, max_frames - len(keys))
    if len(inner) > room:
        inner = [inner[int(i)] for i in np.linspace(0, len(inner) - 1, room)] if room else []
    return sorted(set(keys) | set(inner))


def intrinsics_note(source: FrameSource) -> tuple[bool, str]:
    """(K is only a field-of-view prior?, where the intrinsics came from, in words)."""
    where = str(getattr(source, "K_from", "") or "the source")
    if where.startswith("hfov_deg"):
        return True, f"intrinsics from a field-of-view prior ({where})"
    return False, f"intrinsics from {where}"


def hfov_deg(K: np.ndarray) -> float:
    """Horizontal field of view (deg) of K [3, 3], the image's width taken as 2 x its principal point's x."""
    return float(np.degrees(2 * np.arctan2(K[0, 2], K[0, 0])))


def refined_focal(K0: np.ndarray, K1: np.ndarray, bounds: tuple[float, float]) -> tuple[bool, str]:
    """(keep the refined K1?, in words): the adjustment's focal length kept when within `bounds` x the prior
    K0's (a factor outside: the views did not constrain it; the prior stays, said)."""
    f = float(K1[0, 0] / K0[0, 0])
    if bounds[0] <= f <= bounds[1]:
        return True, (f"focal length refined by the bundle adjustment from the prior's {hfov_deg(K0):.1f} deg "
                      f"field of view to {hfov_deg(K1):.1f} deg (x{f:.3f})")
    return False, (f"focal length not refined: the adjustment's x{f:.2f} is outside {bounds[0]}-{bounds[1]} x the "
                   f"prior; the prior's {hfov_deg(K0):.1f} deg field of view kept, poses may bend")


def loop_candidates(keys: list[int], stream: list[int], every: int) -> list[int]:
    """The frames looked at for revisits: every key frame and every `every`-th stream frame (0: key frames only),
    in time order. Pure. (Key frames alone left the real rooms' walks in pieces: docs/rgb-geometry.md.)"""
    return sorted(set(keys) | (set(stream[::every]) if every > 0 else set()))


def loop_pairs(desc: np.ndarray, pos: list[int], n: int, min_gap: int) -> list[tuple[int, int]]:
    """Revisit candidates among the key frames: for each key frame (place descriptors desc [K, D], unit rows; its
    stream position pos [K]) its n most alike key frames more than `min_gap` stream positions away, as position
    pairs (a < b), each once. Pure."""
    if n <= 0 or len(pos) < 3:
        return []
    S = desc @ desc.T
    out: set[tuple[int, int]] = set()
    for i in range(len(pos)):
        far = [j for j in np.argsort(-S[i]) if abs(pos[j] - pos[i]) > min_gap][:n]
        out.update((min(pos[i], pos[j]), max(pos[i], pos[j])) for j in far)
    return sorted(out)


def align_keyframes_sfm(frames: list[Frame], matcher: KeyedMatcher, source: FrameSource, conf: SfmConf,
                        log: StageLog | None, thumbs: Mapping[int, np.ndarray] | None = None,
                        describe: Callable[[np.ndarray], np.ndarray] | None = None,
                        ) -> tuple[AlignmentResult, list[int], SfmResult]:
    """Key frames `frames` (with relative depth) posed by SfM over the stream (`stream_positions` of the scan's
    kept frames, the keys of `thumbs`; else every frame of `source`). Poses: camera -> root key frame's camera,
    each carrying its depth's scale (Sim(3): the rotation part times s_i / s_root, s = reconstruction depth /
    relative depth at its points), so the root's depth units are the map's. Returns (alignment over the key
    frames, the other frames used, the SfM result)."""
    log = as_trace(log)
    t0 = time.perf_counter()
    keys = sorted(f.index for f in frames)
    by_index = {f.index: f for f in frames}
    grid = sorted(int(i) for i in thumbs) if thumbs else list(range(len(source)))
    stream = stream_positions(keys, grid, conf.stream_frames)
    K = np.asarray(frames[0].K, np.float64)
    prior, how = intrinsics_note(source)
    refine = prior and conf.refine_focal
    if prior and not refine:
        log.event("degraded", f"alignment: {how}, not refined (sfm.refine_focal off): poses may bend",
                  stage="alignment")
    elif not prior:
        log.event("alignment", f"alignment: {how}", stage="alignment")
    rgb_cache: dict[int, np.ndarray] = {}
    cap = conf.pair_matches

    def rgb(i: int) -> np.ndarray:
        if i in by_index:
            return by_index[i].rgb
        if i not in rgb_cache:
            if len(rgb_cache) > conf.match_window + 2:  # matching walks forward: keep a short window decoded
                rgb_cache.pop(min(rgb_cache))
            rgb_cache[i] = source[i].rgb
        return rgb_cache[i]

    def match(a: int, b: int) -> tuple[np.ndarray, np.ndarray]:
        ia, ib = stream[a], stream[b]
        m = matcher.match_keys(ia, rgb(ia), ib, rgb(ib))
        o = np.argsort(-m.scores)[:cap] if cap else np.arange(len(m))
        return m.uv0[o], m.uv1[o]

    extra: list[tuple[int, int]] = []
    if conf.loop_pairs > 0:  # places the walk shows twice: frames alike by appearance, far apart in time
        at = {i: p for p, i in enumerate(stream)}
        cand = loop_candidates(keys, stream, conf.loop_every)
        d = np.array([np.asarray((describe or tiny_descriptor)(rgb(i) if i in by_index else source[i].rgb),
                                 np.float64).ravel() for i in cand])
        d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
        extra = loop_pairs(d, [at[i] for i in cand], conf.loop_pairs, 2 * conf.match_window)
    with log.stage("alignment.sfm_match"):
        tracks = match_stream(len(stream), match, K, conf, extra)
    t1 = time.perf_counter()
    with log.stage("alignment.sfm_map"):
        res = reconstruct(tracks, K, conf, refine)
    if refine:  # the key frames take the refined K (the map back-projects with it), or the prior stays: said
        keep, words = refined_focal(K, res.K, conf.focal_bounds)
        if keep:
            for f in frames:
                f.K = res.K.copy()
        else:
            res.K = K
        log.event("degraded", f"alignment: {how}; {words}", stage="alignment", hfov_prior_deg=hfov_deg(K),
                  hfov_deg=hfov_deg(res.K))
    res.seconds = {"sfm_match": t1 - t0, "sfm_map": time.perf_counter() - t1}
    al = _keyframe_result(res, stream, by_index, conf, log)
    al.seconds.update(res.seconds)
    used = [stream[p] for p in res.model_of if res.model_of[p] == 0 and stream[p] not in by_index]
    return al, sorted(used), res


def _keyframe_result(res: SfmResult, stream: list[int], by_index: dict[int, Frame], conf: SfmConf,
                     log: StageLog) -> AlignmentResult:
    """The largest chain's key frames as an `AlignmentResult` (module doc of `align_keyframes_sfm`); the rest
    unaligned with their reasons (trace event)."""
    pos = {i: p for p, i in enumerate(stream)}
    keys = sorted(by_index)
    why: dict[int, str] = {}
    poses: dict[int, np.ndarray] = {}
    scales: dict[int, float] = {}
    m = res.models[0] if res.models else None
    for i in keys:
        p = pos[i]
        if m is None or p not in m.poses:
            if p in res.model_of:
                why[i] = f"registered in a separate chain ({res.model_of[p] + 1} of {len(res.models)}): no track " \
                         f"links it to the largest"
            else:
                why[i] = res.why.get(p, "not registered")
            continue
        R, t = m.poses[p]
        tid, uv = res.tracks.tid[p], res.tracks.uv[p]
        ok = ~np.isnan(m.X[tid, 0]) & ~m.outlier.get(p, np.zeros(len(tid), bool))
        d = by_index[i].depth
        s = keyframe_scale(R, t, m.X[tid[ok]], uv[ok], d, conf.scale_points) if d is not None else None
        if s is None:
            why[i] = f"registered, but fewer than {conf.scale_points} of its triangulated points have depth"
            continue
        scales[i] = s
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R.T, -R.T @ t
        poses[i] = T
    root = max(poses, key=lambda i: int((~np.isnan(m.X[res.tracks.tid[pos[i]], 0])).sum())) if poses else keys[0]
    out: dict[int, np.ndarray] = {}
    if not poses:  # nothing related: the root key frame is still its own frame (the map holds what it sees)
        out[root] = np.eye(4)
        why.pop(root, None)
    else:
        Ti_root = np.linalg.inv(poses[root])
        for i, T in poses.items():
            rel = Ti_root @ T
            rel[:3, 3] /= scales[root]
            rel[:3, :3] *= scales[i] / scales[root]
            out[i] = rel
    unaligned = [i for i in keys if i not in out]
    al = AlignmentResult(out, root, [], unaligned, "sfm", with_scale=True, edge="sfm")
    if poses:  # the points in the root camera's frame and units: what the metric scale fits the floor to
        R, t = m.poses[pos[root]]
        X = m.X[np.isfinite(m.X).all(1)]
        al.points = (X @ R.T + t) / scales[root]
    al.fates = {i: ("structure from motion" if i in out else "unaligned") for i in keys}
    n_reg = len(m.poses) if m else 0
    msg = (f"structure from motion over {len(stream)} frames ({len(keys)} key frames): {n_reg} registered in the "
           f"largest of {len(res.models)} chain(s), {len(out)} of {len(keys)} key frames posed")
    if unaligned:
        msg += "; unaligned: " + "; ".join(f"{i}: {why[i]}" for i in unaligned)
    log.event("alignment", msg, stage="alignment", unaligned={str(i): why[i] for i in unaligned},
              chains=[len(mm.poses) for mm in res.models], stream_frames=len(stream),
              joined=res.joined)
    if unaligned:  # the answer says why frames could not be related (never a pose kept because a solver gave one)
        kinds: dict[str, int] = {}
        for i in unaligned:
            k = why[i].split(":")[0].split(" (")[0]
            kinds[k] = kinds.get(k, 0) + 1
        log.event("degraded", f"structure from motion could not relate {len(unaligned)} of {len(keys)} key frames "
                  f"to the others (" + ", ".join(f"{n}: {k}" for k, n in kinds.items()) + ")", stage="alignment")
    return al
