"""Frame sources over folders: 7-Scenes RGB-D (`frame-XXXXXX.color/depth/pose`, the synthetic generator's layout
too), TUM RGB-D (`rgb.txt`, `depth.txt`, `groundtruth.txt`) and plain image folders (natural order, optional
`timestamps.txt` and `camera-intrinsics.txt`)."""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from ..geometry import intrinsics_from_fov, make_pose
from ..infra.errors import InputError, read_text
from ..infra.numbers import check_array, read_number
from ..types import Frame
from .source import (IMAGE_EXTS, MAX_DECODE_SIDE, FrameSource, _downscale, _imread_depth, _imread_rgb, _loadtxt,
                     _natural_key, _read_timestamps, _show, check_depth_units, check_gravity, check_pose)

SEVEN_SCENES_K = np.array([[585.0, 0, 320.0], [0, 585.0, 240.0], [0, 0, 1.0]])  # 7-Scenes' published K


# TUM RGB-D published calibrations (ROS default when the sequence name says nothing)
TUM_CALIB = {
    "freiburg1": ((517.3, 516.5, 318.6, 255.3), (0.2624, -0.9531, -0.0054, 0.0026, 1.1633)),
    "freiburg2": ((520.9, 521.0, 325.1, 249.7), (0.2312, -0.7849, -0.0033, -0.0001, 0.9172)),
    "freiburg3": ((535.4, 539.2, 320.1, 247.6), None),
    "default": ((525.0, 525.0, 319.5, 239.5), None),
}


class SevenScenesSource(FrameSource):
    """7-Scenes layout. Frame numbers may have gaps (e.g. every 2nd frame); without `timestamps.txt`,
    t = frame number / `fps` (7-Scenes records at 30 fps)."""

    def __init__(self, root: Path, fps: float = 30.0, hfov_deg: float | None = None, cache_size: int = 32,
                 depth_scale: float = 1000.0, max_side: int = MAX_DECODE_SIDE):
        super().__init__(cache_size)
        self.root = Path(root)
        self.name = self.root.name
        colors = sorted(self.root.glob("frame-*.color.*"), key=lambda p: _natural_key(p.name))
        colors = [p for p in colors if p.suffix.lower() in IMAGE_EXTS]
        if not colors:
            raise InputError(f"{self.root}: no frame-XXXXXX.color.jpg files (7-Scenes layout)")
        self.color_paths = colors
        self.stems = [p.name.split(".color.")[0] for p in colors]
        self.numbers = np.array([int(re.sub(r"\D", "", s)) for s in self.stems])
        self.depth_paths = [self.root / f"{s}.depth.png" for s in self.stems]
        self.pose_paths = [self.root / f"{s}.pose.txt" for s in self.stems]
        self.has_depth = all(p.exists() for p in self.depth_paths)
        self.has_pose = all(p.exists() for p in self.pose_paths)
        self.depth_scale = depth_scale
        self._note_missing([p for p in self.depth_paths if not p.exists()], "depth", "those frames take model "
                           "depth, the others sensor depth (mixed depth sources)")
        self._note_missing([p for p in self.pose_paths if not p.exists()], "pose", "ground-truth poses are unused")
        ts = self.root / "timestamps.txt"
        self.timestamps = (_read_timestamps(ts, len(colors), self.stems) if ts.exists()
                           else self.numbers.astype(np.float64) / fps)
        first = _imread_rgb(colors[0], self.notes)
        self._set_size(first, _show(colors[0]), max_side)
        W, H = self.orig_size
        kf = self.root / "camera-intrinsics.txt"
        if kf.exists():
            self._set_K(_loadtxt(kf, (3, 3), "a 3x3 intrinsics matrix"), _show(kf))
        elif hfov_deg is not None:
            self._set_K(intrinsics_from_fov(W, H, hfov_deg), f"hfov_deg={hfov_deg}")
        else:
            if (W, H) != (640, 480):
                raise InputError(f"{_show(kf)}: missing and the images are {W}x{H}, not 7-Scenes' 640x480; "
                                 f"add camera-intrinsics.txt or pass hfov_deg")
            self._set_K(SEVEN_SCENES_K.copy(), "7-Scenes intrinsics")
        first_depth = next((p for p in self.depth_paths if p.exists()), None)
        if first_depth is not None:
            check_depth_units(_imread_depth(first_depth, depth_scale, (65535,)), first_depth, depth_scale)
        df = self.root / "distortion.txt"
        self.dist = _loadtxt(df, None, "distortion coefficients") if df.exists() else None
        gf = self.root / "gravity-direction.txt"
        if gf.exists():
            g = _loadtxt(gf, (3,), "a gravity direction")
            if np.linalg.norm(g) < 1e-9:
                raise InputError(f"{_show(gf)}: gravity direction is zero")
            self.gravity = g / np.linalg.norm(g)
            check_gravity(self, _show(gf))

    def _note_missing(self, missing: list[Path], what: str, effect: str) -> None:
        n = len(self.color_paths)
        if 0 < len(missing) < n:
            names = ", ".join(_show(p.name) for p in missing[:3]) + (" ..." if len(missing) > 3 else "")
            self.notes.append(f"{len(missing)} of {n} frames have no {what} file ({names}): {effect}")

    splits_colour = True

    def _load_colour(self, i: int) -> Frame:
        rgb = _downscale(_imread_rgb(self.color_paths[i], self.notes), self.scale)
        return Frame(rgb, float(self.timestamps[i]), i, self.K, None, None, self.dist)

    def _load(self, i: int) -> Frame:
        rgb = _imread_rgb(self.color_paths[i], self.notes)
        depth = None
        if self.depth_paths[i].exists():
            depth = _imread_depth(self.depth_paths[i], self.depth_scale, invalid=(65535,))
            if depth.shape != rgb.shape[:2]:
                raise InputError(f"{_show(self.depth_paths[i])}: depth is {depth.shape[::-1]} but the colour image "
                                 f"is {rgb.shape[1::-1]}")
            depth = _downscale(depth, self.scale, nearest=True)  # nearest: never blend across depth edges
        rgb = _downscale(rgb, self.scale)
        pose = self._pose(i)
        return Frame(rgb, float(self.timestamps[i]), i, self.K, depth, pose, self.dist)

    def _colour_path(self, position: int) -> Path | None:
        return self.color_paths[self._position(position)]

    def _pose(self, i: int) -> np.ndarray | None:
        """Frame i's ground-truth pose [4, 4], or None without a pose file or where the file marks a tracking
        failure (ScanNet writes -inf: no ground truth for that frame, not bad input; `untracked_frames`)."""
        if not self.pose_paths[i].exists():
            return None
        T = _loadtxt(self.pose_paths[i], (4, 4), "a 4x4 camera-to-world pose", allow_nonfinite=True)
        if not np.isfinite(T).all():
            self.untracked_frames()  # every pose file non-finite is bad input, not N tracking failures
            return None
        return check_pose(check_array(T, _show(self.pose_paths[i]), "a 4x4 camera-to-world pose", lo=-1e7, hi=1e7),
                          _show(self.pose_paths[i]))

    def untracked_frames(self) -> list[int]:
        """Positions whose pose file holds a non-finite pose (a tracking failure), read once and cached; said in
        `notes`. Every pose file non-finite is not a tracking failure but files without ground truth: InputError."""
        if getattr(self, "_untracked", None) is None:
            have = [(i, p) for i, p in enumerate(self.pose_paths) if p.exists()]
            bad = [i for i, p in have if not np.isfinite(
                _loadtxt(p, (4, 4), "a 4x4 camera-to-world pose", allow_nonfinite=True)).all()]
            if have and len(bad) == len(have):
                raise InputError(f"{_show(self.root)}: every one of the {len(have)} pose files holds NaN or infinity "
                                 f"(e.g. {_show(have[0][1].name)}): no ground-truth pose to use; fix the pose files "
                                 f"or remove them (a tracking failure marks a few frames, not all)")
            if bad:
                names = ", ".join(_show(self.pose_paths[i].name) for i in bad[:3]) + (" ..." if len(bad) > 3 else "")
                self.notes.append(f"{len(bad)} of {len(have)} pose files hold non-finite values ({names}): a "
                                  f"tracking failure (as ScanNet writes -inf); those frames have no ground truth "
                                  f"and are not scored")
            self._untracked = bad
        return list(self._untracked)


def _read_tum_list(path: Path) -> list[tuple[float, list[str]]]:
    if not path.is_file():
        raise InputError(f"{path}: missing (TUM RGB-D layout needs rgb.txt, depth.txt, groundtruth.txt)")
    rows = []
    for ln, line in enumerate(read_text(path, "TUM list").splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        parts = line.split()
        rows.append((read_number(parts[0], f"{_show(path)}:{ln}: the timestamp", lo=0, hi=1e11, unit="s",
                                 fix="fix or drop that line"), parts[1:]))
    if not rows:
        raise InputError(f"{path}: no entries")
    return rows


def _quat_to_R(q: np.ndarray) -> np.ndarray:
    x, y, z, w = q / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def _nearest(ts: np.ndarray, t: float, max_dt: float) -> int | None:
    j = int(np.searchsorted(ts, t))
    best = None
    for k in (j - 1, j):
        if 0 <= k < len(ts) and abs(ts[k] - t) <= max_dt and (best is None or abs(ts[k] - t) < abs(ts[best] - t)):
            best = k
    return best


class TUMSource(FrameSource):
    """TUM RGB-D layout. Depth and ground truth are associated to each RGB frame by nearest timestamp
    (within `max_dt` s, as TUM's associate.py); unmatched ones are None. Ground truth is converted from
    TUM's `tx ty tz qx qy qz qw` to a 4x4 camera-to-world pose."""

    def __init__(self, root: Path, hfov_deg: float | None = None, max_dt: float = 0.02, cache_size: int = 32,
                 max_side: int = MAX_DECODE_SIDE):
        super().__init__(cache_size)
        self.root = Path(root)
        self.name = self.root.name
        rgb = _read_tum_list(self.root / "rgb.txt")
        self.timestamps = np.array([r[0] for r in rgb])
        self.rgb_paths = [self.root / r[1][0] for r in rgb]
        self.depth_paths: list[Path | None] = [None] * len(rgb)
        if (self.root / "depth.txt").exists():
            dl = _read_tum_list(self.root / "depth.txt")
            dts = np.array([r[0] for r in dl])
            for i, t in enumerate(self.timestamps):
                k = _nearest(dts, t, max_dt)
                self.depth_paths[i] = None if k is None else self.root / dl[k][1][0]
        self.poses: list[np.ndarray | None] = [None] * len(rgb)
        gt = self.root / "groundtruth.txt"
        if gt.exists():
            gl = _read_tum_list(gt)
            gts = np.array([r[0] for r in gl])
            for i, t in enumerate(self.timestamps):
                k = _nearest(gts, t, max_dt)
                if k is not None:
                    v = gl[k][1]
                    if len(v) != 7:
                        raise InputError(f"{gt}: expected 'timestamp tx ty tz qx qy qz qw', got {len(v) + 1} fields")
                    try:
                        v = np.array(v, dtype=np.float64)
                    except ValueError:
                        raise InputError(f"{_show(gt)}: the pose at t={gts[k]} is not 7 numbers; fix or drop that "
                                         f"line") from None
                    v = check_array(v, f"{_show(gt)}: the pose at t={gts[k]}", "the line", lo=-1e7, hi=1e7,
                                    fix="fix or drop that line")
                    if not 0.5 < np.linalg.norm(v[3:]) < 2.0:
                        raise InputError(f"{_show(gt)}: pose at t={gts[k]} is not finite or its quaternion is not "
                                         f"unit length; fix or drop that line")
                    self.poses[i] = make_pose(_quat_to_R(v[3:]), v[:3])
        self.has_depth = all(p is not None for p in self.depth_paths)
        self.has_pose = all(p is not None for p in self.poses)
        n_no_depth = sum(p is None for p in self.depth_paths)
        if 0 < n_no_depth < len(rgb):
            self.notes.append(f"{n_no_depth} of {len(rgb)} RGB frames have no depth within {max_dt} s in depth.txt: "
                              f"those frames take model depth, the others sensor depth (mixed depth sources)")
        first = _imread_rgb(self.rgb_paths[0], self.notes)
        self._set_size(first, _show(self.rgb_paths[0]), max_side)
        W, H = self.orig_size
        kf = self.root / "camera-intrinsics.txt"
        if kf.exists():
            self._set_K(_loadtxt(kf, (3, 3), "a 3x3 intrinsics matrix"), _show(kf))
            self.dist = None
        elif hfov_deg is not None:
            self._set_K(intrinsics_from_fov(W, H, hfov_deg), f"hfov_deg={hfov_deg}")
            self.dist = None
        else:
            key = next((k for k in TUM_CALIB if k in str(self.root).lower()), "default")
            if (W, H) != (640, 480):
                raise InputError(f"{_show(kf)}: missing and the images are {W}x{H}, not TUM's 640x480 (the "
                                 f"published calibrations are for that size); add camera-intrinsics.txt")
            (fx, fy, cx, cy), dist = TUM_CALIB[key]
            self._set_K(np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]]), f"TUM calibration {key}")
            self.dist = None if dist is None else np.array(dist)
        first_depth = next((p for p in self.depth_paths if p is not None), None)
        if first_depth is not None:
            check_depth_units(_imread_depth(first_depth, 5000.0), first_depth, 5000.0)

    splits_colour = True

    def _load_colour(self, i: int) -> Frame:
        rgb = _downscale(_imread_rgb(self.rgb_paths[i], self.notes), self.scale)
        return Frame(rgb, float(self.timestamps[i]), i, self.K, None, None, self.dist)

    def _load(self, i: int) -> Frame:
        rgb = _downscale(_imread_rgb(self.rgb_paths[i], self.notes), self.scale)
        dp = self.depth_paths[i]
        depth = None if dp is None else _downscale(_imread_depth(dp, 5000.0), self.scale, nearest=True)
        return Frame(rgb, float(self.timestamps[i]), i, self.K, depth, self.poses[i], self.dist)


class ImageFolderSource(FrameSource):
    """A folder of images in natural sort order; t from `timestamps.txt` or index / `fps`."""

    def __init__(self, root: Path, fps: float = 30.0, hfov_deg: float = 60.0, K: np.ndarray | None = None,
                 cache_size: int = 32, max_side: int = MAX_DECODE_SIDE):
        super().__init__(cache_size)
        self.root = Path(root)
        self.name = self.root.name
        paths = sorted((p for p in self.root.iterdir() if p.suffix.lower() in IMAGE_EXTS and p.is_file()),
                       key=lambda p: _natural_key(p.name))
        if not paths:
            raise InputError(f"{self.root}: no images ({', '.join(IMAGE_EXTS)}) in this folder")
        self.paths = paths
        ts = self.root / "timestamps.txt"
        self.timestamps = (_read_timestamps(ts, len(paths), [p.stem for p in paths]) if ts.exists()
                           else np.arange(len(paths), dtype=np.float64) / fps)
        first = _imread_rgb(paths[0], self.notes)
        self._set_size(first, _show(paths[0]), max_side)
        W, H = self.orig_size
        kf = self.root / "camera-intrinsics.txt"
        if K is not None:
            self._set_K(K, "K")
        elif kf.exists():
            self._set_K(_loadtxt(kf, (3, 3), "a 3x3 intrinsics matrix"), _show(kf))
        else:
            self._set_K(intrinsics_from_fov(W, H, hfov_deg), f"hfov_deg={hfov_deg}")

    def _colour_path(self, position: int) -> Path | None:
        return self.paths[self._position(position)]

    def _load(self, i: int) -> Frame:
        rgb = _imread_rgb(self.paths[i], self.notes)
        if rgb.shape[1::-1] != self.orig_size:
            raise InputError(f"{_show(self.paths[i])}: image is {rgb.shape[1]}x{rgb.shape[0]}, the folder's first "
                             f"image is {self.orig_size[0]}x{self.orig_size[1]}; all frames must have one size")
        return Frame(_downscale(rgb, self.scale), float(self.timestamps[i]), i, self.K)
