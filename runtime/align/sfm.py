"""RGB-only poses: incremental structure from motion over a stream of frames (the key frames and the scan's kept
frames between them), with OpenCV and scipy only (runs on the device profiles' ARM CPUs; pycolmap, which has no
aarch64 wheel, is only the host-side oracle in `benchmarks/sfm_oracle.py`).

1. matches between each stream frame and its next `match_window` frames (the pipeline's matcher), verified by an
   essential matrix (MAGSAC); the inliers chained into tracks (one keypoint per frame and track);
2. two-view start: the pair near the chain's start with the most inliers and enough parallax;
3. each next frame registered by PnP (RANSAC, then Levenberg-Marquardt) on its tracks' triangulated points, and
   REJECTED when it disagrees with its neighbours: too few inliers or too small a share, or an implausible jump
   (a rotation or a camera move no neighbour could make); `max_misses` rejections in a row end the chain and a
   new one starts (the frames stay out, each with its reason);
4. new tracks triangulated (two views, parallax and reprojection checked), a local bundle adjustment every few
   frames and a global one per chain (`bundle_adjust`), observations that stay off by more than
   `max_reproj_px` dropped.
The result is in the reconstruction's own units: `sfm_keyframe_poses` expresses the key frames in the root key
frame's camera, each carrying its relative depth's scale (Sim(3)), as the relative-depth pipeline expects.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np

from ..geometry import ransac_transform
from .bundle_adjust import bundle_adjust, project
from .conf import SfmConf

PairMatches = Callable[[int, int], "tuple[np.ndarray, np.ndarray]"]  # positions (a, b) -> uv_a, uv_b [M, 2]


@dataclass
class Tracks:
    """Feature tracks over F stream frames: per frame p, `tid[p]` [n_p] track ids and `uv[p]` [n_p, 2] pixels
    (a track is seen at most once per frame); `n`: number of tracks; `pairs`: {(a, b): (R [3, 3], t [3],
    inliers)} the essential-matrix relative pose of every verified pair (camera b from camera a, unit t)."""

    tid: list[np.ndarray]
    uv: list[np.ndarray]
    n: int
    pairs: dict[tuple[int, int], tuple[np.ndarray, np.ndarray, int]] = field(default_factory=dict)


def verify_pair(uv0: np.ndarray, uv1: np.ndarray, K: np.ndarray, px: float
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Essential matrix between two views of one camera K. uv0, uv1: [M, 2] -> (inlier mask [M] bool, R [3, 3],
    t [3]: camera 1 from camera 0, |t| = 1), or None when it cannot be estimated."""
    import cv2

    if len(uv0) < 8:
        return None
    E, mask = cv2.findEssentialMat(uv0.astype(np.float64), uv1.astype(np.float64), K, cv2.USAC_MAGSAC, 0.999, px)
    if E is None or E.shape != (3, 3):
        return None
    n, R, t, mask2 = cv2.recoverPose(E, uv0.astype(np.float64), uv1.astype(np.float64), K, mask=mask.copy())
    inl = mask.ravel() > 0
    return inl, R, t.ravel()


def build_tracks(n_frames: int, matched: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]]) -> Tracks:
    """Chain pairwise inlier matches into tracks. matched: {(a, b): (uv_a [M, 2], uv_b [M, 2])} over frame
    positions; a keypoint is its pixel (a matcher gives a frame's keypoints the same coordinates in every pair).
    Pairs are joined nearest in time first; a match that would make a track see one frame twice (two points
    mixed by a wrong match) is not joined."""
    keys: list[list[np.ndarray]] = [[] for _ in range(n_frames)]
    for (a, b), (ua, ub) in matched.items():
        keys[a].append(_key(ua))
        keys[b].append(_key(ub))
    uniq = [np.unique(np.concatenate(k)) if k else np.zeros(0, np.int64) for k in keys]
    off = np.concatenate([[0], np.cumsum([len(u) for u in uniq])]).astype(int)
    N = int(off[-1])
    frame_of = np.repeat(np.arange(n_frames), [len(u) for u in uniq])
    parent = list(range(N))
    mask = [1 << int(f) for f in frame_of]  # frames each component sees (bit set)

    def find(x: int) -> int:
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    for (a, b) in sorted(matched, key=lambda ab: (ab[1] - ab[0], ab)):
        ua, ub = matched[(a, b)]
        na = (off[a] + np.searchsorted(uniq[a], _key(ua))).tolist()
        nb = (off[b] + np.searchsorted(uniq[b], _key(ub))).tolist()
        for x, y in zip(na, nb):
            rx, ry = find(x), find(y)
            if rx != ry and not mask[rx] & mask[ry]:
                parent[ry] = rx
                mask[rx] |= mask[ry]
    label = np.array([find(x) for x in range(N)], np.int64) if N else np.zeros(0, np.int64)
    size = np.bincount(label, minlength=N) if N else np.zeros(0, int)
    keep = size[label] >= 2 if N else np.zeros(0, bool)
    good = np.unique(label[keep])
    new_id = -np.ones(max(N, 1), np.int64)
    new_id[good] = np.arange(len(good))
    tid, uv = [], []
    for p in range(n_frames):
        sl = slice(off[p], off[p + 1])
        k = keep[sl]
        tid.append(new_id[label[sl]][k])
        uv.append(_unkey(uniq[p])[k])
    return Tracks(tid, uv, len(good))


_Q = 8.0  # keypoint pixels are identified to 1/8 px


def _key(uv: np.ndarray) -> np.ndarray:
    q = np.round(np.asarray(uv, np.float64) * _Q).astype(np.int64)
    return q[:, 0] * 1_000_000 + q[:, 1]


def _unkey(k: np.ndarray) -> np.ndarray:
    return np.stack([k // 1_000_000, k % 1_000_000], 1).astype(np.float64) / _Q


def triangulate(K: np.ndarray, R0: np.ndarray, t0: np.ndarray, R1: np.ndarray, t1: np.ndarray, uv0: np.ndarray,
                uv1: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two-view DLT in normalised coordinates. Cameras x = R X + t; uv0, uv1: [M, 2] -> (X [M, 3],
    parallax angle [M] deg)."""
    Ki = np.linalg.inv(K)
    n0 = (np.c_[uv0, np.ones(len(uv0))] @ Ki.T)
    n1 = (np.c_[uv1, np.ones(len(uv1))] @ Ki.T)
    P0, P1 = np.c_[R0, t0], np.c_[R1, t1]
    A = np.stack([n0[:, :1] * P0[2] - P0[0], n0[:, 1:2] * P0[2] - P0[1],
                  n1[:, :1] * P1[2] - P1[0], n1[:, 1:2] * P1[2] - P1[1]], 1)
    Xh = np.linalg.svd(A)[2][:, -1]
    X = Xh[:, :3] / np.where(np.abs(Xh[:, 3:]) > 1e-12, Xh[:, 3:], 1e-12)
    c0, c1 = -R0.T @ t0, -R1.T @ t1
    r0, r1 = X - c0, X - c1
    cos = np.sum(r0 * r1, 1) / np.maximum(np.linalg.norm(r0, axis=1) * np.linalg.norm(r1, axis=1), 1e-12)
    return X, np.degrees(np.arccos(np.clip(cos, -1, 1)))


@dataclass
class Reconstruction:
    """One chain of registered frames. poses: {position: (R [3, 3], t [3])} world -> camera; X: [T, 3] track
    points (NaN until triangulated); outlier: per frame [n_p] bool observations
    dropped by the reprojection check."""

    poses: dict[int, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    X: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    outlier: dict[int, np.ndarray] = field(default_factory=dict)


@dataclass
class SfmResult:
    """models: the chains, largest first; model_of: {position: model number}; why: {position: why it is not
    registered}; K: the intrinsics used."""

    models: list[Reconstruction]
    model_of: dict[int, int]
    why: dict[int, str]
    K: np.ndarray
    tracks: Tracks
    seconds: dict[str, float] = field(default_factory=dict)
    rejected: list[tuple[int, str]] = field(default_factory=list)  # (position, why) every rejected registration
    joined: list[str] = field(default_factory=list)  # chains joined by shared points (`merge_chains`)


def _rot_deg(Ra: np.ndarray, Rb: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(Ra.T @ Rb) - 1) / 2, -1, 1))))


class _Mapper:
    """Incremental mapping over tracks (module doc, steps 2-4)."""

    def __init__(self, tracks: Tracks, K: np.ndarray, conf: SfmConf, refine_focal: bool = False):
        self.t, self.K, self.c = tracks, K.astype(np.float64), conf
        self.refine_focal = refine_focal  # global adjustments refine the focal length (K from a prior)
        self.F = len(tracks.tid)
        self.why: dict[int, str] = {}
        self.history: list[tuple[int, str]] = []  # every rejection, also of frames a later chain registered

    # --- one chain
    def init(self, start: int, stop: int) -> Reconstruction | None:
        """Two-view start in positions [start, stop): a frame a near `start` and a later b (up to `init_window`
        ahead) whose shared tracks give an essential matrix; the pair with the most triangulated points of at least
        `init_min_parallax_deg` median parallax wins (the nearest a that has one)."""
        c = self.c
        for a in range(start, min(stop, start + c.init_window)):
            best = None
            for b in range(a + 1, min(stop, a + 1 + c.init_window)):
                common, ia, ib = np.intersect1d(self.t.tid[a], self.t.tid[b], return_indices=True)
                if len(common) < c.min_pair_inliers:
                    continue
                v = verify_pair(self.t.uv[a][ia], self.t.uv[b][ib], self.K, c.pair_px)
                if v is None or v[0].sum() < c.min_pair_inliers:
                    continue
                m = Reconstruction(poses={a: (np.eye(3), np.zeros(3)), b: (v[1], v[2])},
                                   X=np.full((self.t.n, 3), np.nan))
                got = self.triangulate_new(m, b)
                if got >= c.min_pnp_inliers and self._last_parallax >= c.init_min_parallax_deg and \
                        (best is None or got > best[0]):
                    best = (got, m)
            if best is not None:
                return best[1]
        return None

    def triangulate_new(self, m: Reconstruction, p: int) -> int:
        """Triangulate p's tracks without a point from p and the registered frame farthest in the stream that
        sees them (more baseline); checks parallax, depth and reprojection. Returns points added."""
        c, tid, uv = self.c, self.t.tid[p], self.t.uv[p]
        todo = np.isnan(m.X[tid, 0])
        self._last_parallax = 0.0
        if not todo.any():
            return 0
        Rp, tp = m.poses[p]
        added, angs = 0, []
        others = sorted(m.poses, key=lambda q: -abs(q - p))
        for q in others:
            if q == p or not todo.any():
                continue
            common, ip, iq = np.intersect1d(tid[todo], self.t.tid[q], return_indices=True)
            if len(common) == 0:
                continue
            idx_p = np.flatnonzero(todo)[ip]
            Rq, tq = m.poses[q]
            X, ang = triangulate(self.K, Rp, tp, Rq, tq, uv[idx_p], self.t.uv[q][iq])
            ok = (ang >= c.min_tri_parallax_deg) & self._good(X, Rp, tp, uv[idx_p]) & \
                self._good(X, Rq, tq, self.t.uv[q][iq])
            angs.append(ang[ok])
            m.X[common[ok]] = X[ok]
            todo[idx_p[ok]] = False
            added += int(ok.sum())
        if angs and sum(len(a) for a in angs):
            self._last_parallax = float(np.median(np.concatenate(angs)))
        return added

    def _good(self, X: np.ndarray, R: np.ndarray, t: np.ndarray, uv: np.ndarray) -> np.ndarray:
        x = X @ R.T + t
        e = project(np.zeros_like(X), np.zeros_like(X), x, self.K)
        return (x[:, 2] > 1e-6) & (np.linalg.norm(e - uv, axis=1) < self.c.max_reproj_px)

    def register(self, m: Reconstruction, p: int, near: int) -> str | None:
        """Position p placed by PnP on its triangulated tracks, else (too few of them) by the essential matrix of
        the verified pair with the registered neighbour `near`, its scale from the points both see; either way
        checked against `near` (a jump is rejected). Returns None when registered, else why not."""
        got = self._pnp(m, p, near)
        if isinstance(got, str):
            edge = self._two_view(m, p, near)
            if isinstance(edge, str):
                return f"{got}; {edge}"
            got = edge
        R, t, depth = got
        Rn, tn = m.poses[near]
        c = self.c
        rot = _rot_deg(R, Rn)
        move = np.linalg.norm(-R.T @ t + Rn.T @ tn)
        if rot > c.max_step_rot_deg * max(1, abs(p - near)):
            return f"jump: {rot:.0f} deg from frame position {near} (> {c.max_step_rot_deg:.0f} deg a step)"
        if not depth > 0 or move > c.max_step_depth * depth * max(1, abs(p - near)):
            return (f"jump: moved {move / max(depth, 1e-9):.2f} x the scene depth from frame position {near} "
                    f"(> {c.max_step_depth})")
        m.poses[p] = (R, t)
        return None

    def _pnp(self, m: Reconstruction, p: int, near: int) -> tuple[np.ndarray, np.ndarray, float] | str:
        """(R, t, median depth of the inliers) by PnP RANSAC + Levenberg-Marquardt, or why not."""
        import cv2

        c, tid, uv = self.c, self.t.tid[p], self.t.uv[p]
        has = ~np.isnan(m.X[tid, 0]) if len(tid) else np.zeros(0, bool)
        n3d = int(has.sum())
        if n3d < c.min_pnp_inliers:
            return f"{n3d} matches with triangulated points (< {c.min_pnp_inliers})"
        X, u = m.X[tid[has]], uv[has]
        try:
            ok, rv, tv, inl = cv2.solvePnPRansac(X, u, self.K, None, iterationsCount=c.pnp_iterations,
                                                 reprojectionError=c.register_px, confidence=0.999,
                                                 flags=cv2.SOLVEPNP_SQPNP)
        except cv2.error as e:  # SQPnP asserts on degenerate samples (e.g. collapsed points): a failed PnP
            return f"PnP: degenerate ({str(e).strip().splitlines()[-1][:60]})"
        if not ok or inl is None or len(inl) < c.min_pnp_inliers:
            return f"PnP: {0 if inl is None else len(inl)} inliers of {n3d} (< {c.min_pnp_inliers})"
        inl = inl.ravel()
        if len(inl) < c.min_pnp_ratio * n3d:
            return f"PnP: {len(inl)} inliers of {n3d} ({len(inl) / n3d:.0%} < {c.min_pnp_ratio:.0%})"
        rv, tv = cv2.solvePnPRefineLM(X[inl], u[inl], self.K, None, rv, tv)
        R, t = cv2.Rodrigues(rv)[0], tv.ravel()
        return R, t, float(np.median((X[inl] @ R.T + t)[:, 2]))

    def _two_view(self, m: Reconstruction, p: int, near: int) -> tuple[np.ndarray, np.ndarray, float] | str:
        """(R, t, median depth) from the verified pair (near, p): its relative rotation and direction, the length
        from the points near's chain holds that the pair also sees (their depth in near / their depth
        triangulated with a unit baseline, median of at least `two_view_points`), or why not."""
        c = self.c
        key = (min(near, p), max(near, p))
        if key not in self.t.pairs:
            return "no verified pair with its neighbour"
        Rr, tr, _ = self.t.pairs[key]
        if key[0] == p:  # the pair gives camera b from camera a: invert for (near -> p)
            Rr, tr = Rr.T, -Rr.T @ tr
        common, ip, iq = np.intersect1d(self.t.tid[p], self.t.tid[near], return_indices=True)
        held = ~np.isnan(m.X[common, 0])
        if held.sum() < c.two_view_points:
            return f"two-view: {int(held.sum())} shared points to scale it (< {c.two_view_points})"
        Rn, tn = m.poses[near]
        Xu, ang = triangulate(self.K, np.eye(3), np.zeros(3), Rr, tr, self.t.uv[near][iq[held]],
                              self.t.uv[p][ip[held]])
        zq = (m.X[common[held]] @ Rn.T + tn)[:, 2]
        good = (Xu[:, 2] > 0) & (zq > 0) & (ang > c.min_tri_parallax_deg)
        if good.sum() < c.two_view_points:
            return f"two-view: {int(good.sum())} shared points with parallax (< {c.two_view_points})"
        s = float(np.median(zq[good] / Xu[good, 2]))
        R, t = Rr @ Rn, Rr @ tn + s * tr
        return R, t, float(np.median(zq[good]))

    def adjust(self, m: Reconstruction, free: Sequence[int], iterations: int, focal: bool = False) -> None:
        """Bundle adjustment with the cameras `free` free (the rest of the chain fixed), then observations off by
        more than `max_reproj_px` dropped and points left with fewer than 2 views removed; `focal`: the focal
        length refined too (K's fx, fy by one factor, kept in `self.K`)."""
        c = self.c
        cams = sorted(m.poses)
        row = {p: i for i, p in enumerate(cams)}
        free_set = set(free)
        obs_c, obs_t, obs_uv, obs_ref = [], [], [], []
        pts_free = set()
        for p in free:
            tid = self.t.tid[p]
            ok = ~np.isnan(m.X[tid, 0]) & ~m.outlier.get(p, np.zeros(len(tid), bool))
            pts_free.update(tid[ok].tolist())
        if not pts_free:
            return
        pts = np.array(sorted(pts_free))
        for p in cams:
            tid = self.t.tid[p]
            ok = ~m.outlier.get(p, np.zeros(len(tid), bool)) & np.isin(tid, pts)
            obs_c.append(np.full(int(ok.sum()), row[p]))
            obs_t.append(np.searchsorted(pts, tid[ok]))
            obs_uv.append(self.t.uv[p][ok])
            obs_ref.append((p, np.flatnonzero(ok)))
        cam, pt, uv = np.concatenate(obs_c), np.concatenate(obs_t), np.concatenate(obs_uv)
        rv = np.array([_rvec(m.poses[p][0]) for p in cams])
        tv = np.array([m.poses[p][1] for p in cams])
        K = self.K
        res = bundle_adjust(rv, tv, m.X[pts], cam, pt, uv, K, np.array([p in free_set for p in cams]),
                            c.ba_loss, c.ba_scale_px, iterations, focal)
        if focal:
            K = self.K = K @ np.diag([res.focal, res.focal, 1.0])
        for p in free:
            m.poses[p] = (_rmat(res.rvecs[row[p]]), res.tvecs[row[p]])
        m.X[pts] = res.X
        e = np.linalg.norm(project(res.rvecs[cam], res.tvecs[cam], res.X[pt], K) - uv, axis=1)
        i = 0
        for p, where in obs_ref:
            bad = e[i:i + len(where)] > c.max_reproj_px
            i += len(where)
            o = m.outlier.setdefault(p, np.zeros(len(self.t.tid[p]), bool))
            o[where[bad]] = True
        views = np.zeros(self.t.n, int)
        for p in cams:
            tid = self.t.tid[p]
            np.add.at(views, tid[~m.outlier.get(p, np.zeros(len(tid), bool))], 1)
        m.X[views < 2] = np.nan

    def chain(self, start: int) -> tuple[Reconstruction | None, int]:
        """One chain from `start`: start pair, forward registration until `max_misses` in a row, then backward
        down to `start`, a global adjustment, one more try for the frames it skipped. Returns (chain or None,
        the first position after it)."""
        c = self.c
        m = self.init(start, self.F)
        if m is None:
            self.why[start] = "no frame pair near it with enough matches and parallax to start a chain"
            return None, start + 1
        a, b = sorted(m.poses)
        self.adjust(m, [b], c.ba_iterations)
        last, misses, since = b, 0, 0
        for p in range(a + 1, self.F):
            if p == b:
                continue
            near = max(q for q in m.poses if q < p)
            why = self.register(m, p, near)
            if why:
                self.why[p] = why
                self.history.append((p, why))
                misses += 1
                if misses >= c.max_misses:
                    break
                continue
            misses, last = 0, p
            self.why.pop(p, None)
            self.triangulate_new(m, p)
            since += 1
            if since >= c.local_ba_every:
                since = 0
                window = sorted(m.poses)[-c.local_ba_window:]
                self.adjust(m, [q for q in window if q != min(m.poses)], c.local_ba_iterations)
        end = last + 1
        misses = 0
        for p in range(a - 1, start - 1, -1):
            why = self.register(m, p, min(m.poses))
            if why:
                self.why[p] = why
                misses += 1
                if misses >= c.max_misses:
                    break
                continue
            misses = 0
            self.why.pop(p, None)
            self.triangulate_new(m, p)
        self._global(m)
        for p in range(start, end):  # frames the chain skipped, once more against the adjusted chain
            if p in m.poses or p not in self.why or not any(q < p for q in m.poses) and not any(q > p for q in m.poses):
                continue
            near = min(m.poses, key=lambda q: abs(q - p))
            if self.register(m, p, near) is None:
                self.why.pop(p)
                self.triangulate_new(m, p)
        self._global(m)
        return m, end

    def relocalize(self, m: Reconstruction) -> list[int]:
        """Frames outside chain m (rejected, or in a smaller chain) re-tried against m's whole map: PnP on every
        track of theirs m has triangulated (loop pairs and wider matches link them), most such points first, each
        checked against its nearest registered frame in time like any registration; rounds until none is added
        (at most `relocalize_rounds`), a global adjustment after each. Returns the frames added."""
        c, added = self.c, []
        tried: dict[int, int] = {}  # frame -> points it had when it last failed (re-tried only with more)
        for _ in range(c.relocalize_rounds):
            got = []
            for p in self._candidates(m, tried):
                near = min(m.poses, key=lambda q: (abs(q - p), q))
                why = self.register(m, p, near)
                if why:
                    tried[p] = self._n3d(m, p)
                    self.why[p] = f"{why} (re-tried against the map)"
                    continue
                self.why.pop(p, None)
                self.triangulate_new(m, p)
                got.append(p)
            if not got:
                break
            added += got
            self._global(m, c.local_ba_iterations)
        return added

    def _n3d(self, m: Reconstruction, p: int) -> int:
        tid = self.t.tid[p]
        return int((~np.isnan(m.X[tid, 0])).sum()) if len(tid) else 0

    def _candidates(self, m: Reconstruction, tried: dict[int, int]) -> list[int]:
        """Frames outside m with at least `min_pnp_inliers` tracks m has triangulated (more than when they last
        failed), most first."""
        n = {p: self._n3d(m, p) for p in range(self.F) if p not in m.poses}
        ok = [p for p, k in n.items() if k >= self.c.min_pnp_inliers and k > tried.get(p, 0)]
        return sorted(ok, key=lambda p: (-n[p], p))

    def _global(self, m: Reconstruction, iterations: int | None = None) -> None:
        first = min(m.poses)
        self.adjust(m, [q for q in sorted(m.poses) if q != first], iterations or self.c.ba_iterations,
                    self.refine_focal)


def _rvec(R: np.ndarray) -> np.ndarray:
    import cv2

    return cv2.Rodrigues(np.asarray(R, np.float64))[0].ravel()


def _rmat(r: np.ndarray) -> np.ndarray:
    import cv2

    return cv2.Rodrigues(np.asarray(r, np.float64).reshape(3, 1))[0]


def merge_chains(models: list[Reconstruction], conf: SfmConf) -> tuple[list[Reconstruction], list[str]]:
    """Join chains that share triangulated tracks: a Sim(3) from the points both hold (RANSAC, inliers within
    `merge_rel` of their spread) takes the smaller chain into the larger one's frame; the shared tracks keep the
    larger chain's points. Returns (chains, largest first; what was joined, in words)."""
    models = sorted(models, key=lambda m: -len(m.poses))
    said: list[str] = []
    merged = True
    while merged and len(models) > 1:
        merged = False
        for j in range(1, len(models)):
            A, B = models[0], models[j]
            both = np.flatnonzero(~np.isnan(A.X[:, 0]) & ~np.isnan(B.X[:, 0]))
            if len(both) < conf.merge_min_points:
                continue
            spread = float(np.median(np.linalg.norm(A.X[both] - np.median(A.X[both], 0), axis=1)))
            r = ransac_transform(B.X[both], A.X[both], conf.merge_rel * spread, 500, True,
                                 min_inliers=conf.merge_min_points)
            if not r.ok or r.n_inliers < conf.merge_min_share * len(both):
                continue
            S = r.T
            s = float(np.cbrt(np.linalg.det(S[:3, :3])))
            Rw, tw = S[:3, :3] / s, S[:3, 3]
            for p, (Rb, tb) in B.poses.items():
                A.poses[p] = (Rb @ Rw.T, s * tb - Rb @ Rw.T @ tw)
            new = ~np.isnan(B.X[:, 0]) & np.isnan(A.X[:, 0])
            A.X[new] = B.X[new] @ (s * Rw).T + tw
            for p, o in B.outlier.items():
                A.outlier[p] = o
            said.append(f"joined a chain of {len(B.poses)} frames by {r.n_inliers} of {len(both)} shared points")
            models.pop(j)
            merged = True
            break
    return models, said


def _without(m: Reconstruction, frames: set[int]) -> Reconstruction:
    """Chain m less `frames` (registered elsewhere)."""
    return Reconstruction({p: v for p, v in m.poses.items() if p not in frames}, m.X,
                          {p: v for p, v in m.outlier.items() if p not in frames})


def reconstruct(tracks: Tracks, K: np.ndarray, conf: SfmConf | None = None, refine_focal: bool = False
                ) -> SfmResult:
    """Chains of registered frames over `tracks` (module doc); every frame not in the largest chain keeps why.
    `refine_focal` (K from a field-of-view prior): every global adjustment refines the focal length; the
    result's K is the one found."""
    import cv2

    conf = SfmConf.merged(conf)
    cv2.setRNGSeed(conf.rng_seed)  # OpenCV's RANSAC draws from its global generator: the same answer every run
    mp = _Mapper(tracks, K, conf, refine_focal)
    models, start = [], 0
    while start < mp.F - 1:
        m, start = mp.chain(start)
        if m is not None and len(m.poses) >= 2:
            models.append(m)
    models, joined = merge_chains(models, conf)
    if joined:
        mp._global(models[0])
    if models and conf.relocalize_rounds > 0:
        got = mp.relocalize(models[0])
        if got:
            joined.append(f"re-localized {len(got)} frames against the largest chain's map")
            models = [models[0]] + [_without(mm, set(got)) for mm in models[1:]]
            models = [models[0]] + sorted([mm for mm in models[1:] if len(mm.poses) >= 2], key=lambda mm: -len(mm.poses))
            mp._global(models[0])
    model_of = {p: i for i, m in enumerate(models) for p in m.poses}
    for p in range(mp.F):
        if p not in model_of:
            mp.why.setdefault(p, "no chain reached it")
    why = {p: w for p, w in mp.why.items() if p not in model_of}
    return SfmResult(models, model_of, why, mp.K, tracks, rejected=mp.history, joined=joined)


def match_stream(n: int, match: PairMatches, K: np.ndarray, conf: SfmConf,
                 extra_pairs: Sequence[tuple[int, int]] = ()) -> Tracks:
    """Match each stream position with its next `match_window` (and `extra_pairs`), verify each pair by an
    essential matrix, chain the inliers into tracks."""
    import cv2

    cv2.setRNGSeed(conf.rng_seed)
    matched, pairs = {}, {}
    todo = [(a, b) for a in range(n) for b in range(a + 1, min(n, a + 1 + conf.match_window))]
    for a, b in list(todo) + [tuple(sorted(p)) for p in extra_pairs if tuple(sorted(p)) not in set(todo)]:
        ua, ub = match(a, b)
        if len(ua) < conf.min_pair_inliers:
            continue
        v = verify_pair(ua, ub, K, conf.pair_px)
        if v is None or v[0].sum() < conf.min_pair_inliers:
            continue
        inl, R, t = v
        matched[(a, b)] = (ua[inl], ub[inl])
        pairs[(a, b)] = (R, t, int(inl.sum()))
    tr = build_tracks(n, matched)
    tr.pairs = pairs
    return tr


def keyframe_scale(R: np.ndarray, t: np.ndarray, X: np.ndarray, uv: np.ndarray, depth: np.ndarray,
                   min_points: int = 10) -> float | None:
    """The factor from a frame's relative depth [H, W] to the reconstruction's units: the median over its
    triangulated points X [M, 3] seen at uv [M, 2] of (their depth in the camera) / (relative depth there);
    None with fewer than `min_points` valid pairs."""
    H, W = depth.shape
    z = (X @ R.T + t)[:, 2]
    x = np.clip(np.round(uv[:, 0]).astype(int), 0, W - 1)
    y = np.clip(np.round(uv[:, 1]).astype(int), 0, H - 1)
    d = depth[y, x]
    ok = (d > 0) & (z > 0) & np.isfinite(d)
    return float(np.median(z[ok] / d[ok])) if ok.sum() >= min_points else None

