"""Frame sources: random access by index, with timestamps, over a video, an image folder or an RGB-D folder.

`open_source(path)` detects the layout:
- a video file (anything OpenCV can decode): decoded *sequentially* (seeking in compressed video is slow and
  inexact), decoded frames are kept in a small LRU cache; rotation metadata is honoured;
- a 7-Scenes RGB-D folder: `frame-XXXXXX.color.{jpg,png}`, `.depth.png` (uint16 mm, 0 and 65535 invalid),
  `.pose.txt` (4x4 camera-to-world, metres), `camera-intrinsics.txt` (3x3), optional `gravity-direction.txt`
  and `timestamps.txt` (the synthetic generator writes the same layout);
- a TUM RGB-D folder: `rgb.txt`, `depth.txt`, `groundtruth.txt` (depth scale 5000, i.e. 0.2 mm units);
- a folder of images (sorted by natural order), optional `timestamps.txt` and `camera-intrinsics.txt`.

Intrinsics come from the source when it has them, else from a horizontal field of view (`hfov_deg`, default 60).
A corrupt, empty or unreadable input raises `InputError` naming the file; nothing yields an empty frame.
"""
from __future__ import annotations

import os
import re
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator, Sequence

import numpy as np

from .errors import InputError
from .geometry import intrinsics_from_fov, make_pose

IMAGE_EXTS = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".webp")
VIDEO_EXTS = (".mp4", ".mov", ".avi", ".mkv", ".m4v", ".webm", ".3gp", ".mpg", ".mpeg")
SEVEN_SCENES_K = np.array([[585.0, 0, 320.0], [0, 585.0, 240.0], [0, 0, 1.0]])  # 7-Scenes' published K

# TUM RGB-D published calibrations (ROS default when the sequence name says nothing)
TUM_CALIB = {
    "freiburg1": ((517.3, 516.5, 318.6, 255.3), (0.2624, -0.9531, -0.0054, 0.0026, 1.1633)),
    "freiburg2": ((520.9, 521.0, 325.1, 249.7), (0.2312, -0.7849, -0.0033, -0.0001, 0.9172)),
    "freiburg3": ((535.4, 539.2, 320.1, 247.6), None),
    "default": ((525.0, 525.0, 319.5, 239.5), None),
}


@dataclass
class Frame:
    """One frame. rgb: [H, W, 3] uint8; t: seconds; index: position in its source; depth: [H, W] float32 z-depth
    in metres (0 = invalid) or None; K: [3, 3] float64; pose_gt: [4, 4] float64 camera-to-world or None;
    dist: [k] OpenCV distortion coefficients or None (images are NOT undistorted)."""

    rgb: np.ndarray
    t: float
    index: int
    K: np.ndarray
    depth: np.ndarray | None = None
    pose_gt: np.ndarray | None = None
    dist: np.ndarray | None = None


# ----------------------------------------------------------------------------- readers (errors name the file)


def _imread_rgb(path: Path) -> np.ndarray:
    import cv2

    if not path.is_file():
        raise InputError(f"{path}: image file is missing")
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None or img.size == 0:
        raise InputError(f"{path}: cannot decode the image (corrupt, empty or not an image); "
                         f"replace or remove the file")
    return np.ascontiguousarray(img[:, :, ::-1])


def _imread_depth(path: Path, scale: float, invalid: Sequence[int] = ()) -> np.ndarray:
    """uint16 depth PNG -> [H, W] float32 metres, given `scale` units per metre (1000 for mm, 5000 for TUM)."""
    import cv2

    if not path.is_file():
        raise InputError(f"{path}: depth file is missing")
    d = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if d is None or d.size == 0:
        raise InputError(f"{path}: cannot decode the depth image (corrupt or empty)")
    if d.ndim != 2 or d.dtype != np.uint16:
        raise InputError(f"{path}: depth must be a single-channel uint16 PNG, got {d.dtype} with shape {d.shape}")
    bad = d == 0
    for v in invalid:
        bad |= d == v
    out = d.astype(np.float32) / np.float32(scale)
    out[bad] = 0.0
    return out


def _loadtxt(path: Path, shape: tuple[int, ...] | None = None, what: str = "numbers") -> np.ndarray:
    try:
        a = np.loadtxt(path, dtype=np.float64, ndmin=1)
    except (OSError, ValueError) as e:
        raise InputError(f"{path}: cannot read {what} ({e})") from None
    if shape is not None:
        if a.size != int(np.prod(shape)):
            raise InputError(f"{path}: expected {what} with {int(np.prod(shape))} values {shape}, got {a.size}")
        a = a.reshape(shape)
    if not np.all(np.isfinite(a)):
        raise InputError(f"{path}: {what} contains non-finite values")
    return a


def _natural_key(s: str) -> list[Any]:
    return [int(p) if p.isdigit() else p.lower() for p in re.split(r"(\d+)", s)]


def _read_timestamps(path: Path, n: int, names: Sequence[str] | None = None) -> np.ndarray:
    """`timestamps.txt`: one line per frame, either `t` or `<frame name or number> t` (last field = seconds)."""
    rows: list[tuple[str, float]] = []
    for ln, line in enumerate(path.read_text().splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        parts = line.replace(",", " ").split()
        try:
            rows.append((parts[0] if len(parts) > 1 else "", float(parts[-1])))
        except ValueError:
            raise InputError(f"{path}:{ln}: cannot parse a timestamp from {line!r}") from None
    if len(rows) == n:
        t = np.array([r[1] for r in rows])
    elif names is not None and all(r[0] for r in rows):
        table = {}
        for key, val in rows:
            table[key] = val
            if key.isdigit():
                table[str(int(key))] = val
        t = []
        for nm in names:
            key = nm if nm in table else str(int(re.sub(r"\D", "", nm) or -1))
            if key not in table:
                raise InputError(f"{path}: no timestamp for frame {nm!r}")
            t.append(table[key])
        t = np.array(t)
    else:
        raise InputError(f"{path}: {len(rows)} timestamps for {n} frames")
    if np.any(np.diff(t) < 0):
        raise InputError(f"{path}: timestamps must not decrease with the frame order")
    return t.astype(np.float64)


# ----------------------------------------------------------------------------- base


class FrameSource:
    """Random access to frames. Subclasses set `name`, `timestamps [N] float64`, `K [3, 3]`, `size (W, H)`,
    `dist` and `gravity` and implement `_load(i) -> Frame`.

    `gravity`: unit vector [3] pointing DOWN, expressed in the source's world frame (the frame of `pose_gt`), or
    None when the source gives none. `gravity_camera(i)` expresses it in camera i's frame (needs `pose_gt`).
    """

    name: str = ""
    K: np.ndarray
    size: tuple[int, int]
    timestamps: np.ndarray
    dist: np.ndarray | None = None
    gravity: np.ndarray | None = None
    has_depth: bool = False
    has_pose: bool = False

    def __init__(self, cache_size: int = 32):
        self._cache: OrderedDict[int, Frame] = OrderedDict()
        self._cache_size = int(cache_size)

    def __len__(self) -> int:
        return len(self.timestamps)

    def __getitem__(self, i: int) -> Frame:
        n = len(self)
        i = int(i)
        if i < 0:
            i += n
        if not 0 <= i < n:
            raise IndexError(f"{self.name}: frame {i} out of range (0..{n - 1})")
        if i in self._cache:
            self._cache.move_to_end(i)
            return self._cache[i]
        f = self._load(i)
        self._remember(i, f)
        return f

    def __iter__(self) -> Iterator[Frame]:
        for i in range(len(self)):
            yield self[i]

    def _remember(self, i: int, f: Frame) -> None:
        if self._cache_size <= 0:
            return
        self._cache[i] = f
        self._cache.move_to_end(i)
        while len(self._cache) > self._cache_size:
            self._cache.popitem(last=False)

    def _load(self, i: int) -> Frame:  # pragma: no cover - abstract
        raise NotImplementedError

    def index_of(self, position: int) -> int:
        """Frame index of the frame at `position` (the same for sources; FrameList keeps its frames' indices)."""
        return int(position)

    def prefetch(self, indices: Sequence[int]) -> None:
        """Hint that these frames are needed soon (the video source decodes them in one forward pass)."""

    def gravity_camera(self, i: int) -> np.ndarray | None:
        """Gravity (down) in camera i's frame [3], or None without gravity or ground-truth pose."""
        if self.gravity is None:
            return None
        T = self[i].pose_gt
        if T is None:
            return None
        g = T[:3, :3].T @ self.gravity
        return g / np.linalg.norm(g)  # ground-truth rotations are not exactly orthonormal

    def describe(self) -> dict[str, Any]:
        return {"name": self.name, "kind": type(self).__name__, "frames": len(self), "size": list(self.size),
                "has_depth": self.has_depth, "has_pose": self.has_pose,
                "fx": float(self.K[0, 0]), "fy": float(self.K[1, 1])}


class FrameList(FrameSource):
    """A source over frames already in memory (tests, synthetic data, key-frame subsets)."""

    def __init__(self, frames: Sequence[Frame], name: str = "frames", gravity: np.ndarray | None = None):
        super().__init__(cache_size=0)
        if not frames:
            raise InputError(f"{name}: no frames")
        self.frames = list(frames)
        self.name = name
        self.timestamps = np.array([f.t for f in self.frames], dtype=np.float64)
        self.K = np.asarray(self.frames[0].K, dtype=np.float64)
        H, W = self.frames[0].rgb.shape[:2]
        self.size = (W, H)
        self.gravity = gravity
        self.has_depth = all(f.depth is not None for f in self.frames)
        self.has_pose = all(f.pose_gt is not None for f in self.frames)

    def _load(self, i: int) -> Frame:
        return self.frames[i]

    def index_of(self, position: int) -> int:
        return int(self.frames[position].index)


# ----------------------------------------------------------------------------- RGB-D folders


class SevenScenesSource(FrameSource):
    """7-Scenes layout. Frame numbers may have gaps (e.g. every 2nd frame); without `timestamps.txt`,
    t = frame number / `fps` (7-Scenes records at 30 fps)."""

    def __init__(self, root: Path, fps: float = 30.0, hfov_deg: float | None = None, cache_size: int = 32,
                 depth_scale: float = 1000.0):
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
        ts = self.root / "timestamps.txt"
        self.timestamps = (_read_timestamps(ts, len(colors), self.stems) if ts.exists()
                           else self.numbers.astype(np.float64) / fps)
        first = _imread_rgb(colors[0])
        H, W = first.shape[:2]
        self.size = (W, H)
        kf = self.root / "camera-intrinsics.txt"
        if kf.exists():
            self.K = _loadtxt(kf, (3, 3), "a 3x3 intrinsics matrix")
        elif hfov_deg is not None:
            self.K = intrinsics_from_fov(W, H, hfov_deg)
        else:
            self.K = SEVEN_SCENES_K.copy()
            if (W, H) != (640, 480):
                raise InputError(f"{kf}: missing and the images are {W}x{H}, not 7-Scenes' 640x480; "
                                 f"add camera-intrinsics.txt or pass hfov_deg")
        df = self.root / "distortion.txt"
        self.dist = _loadtxt(df, None, "distortion coefficients") if df.exists() else None
        gf = self.root / "gravity-direction.txt"
        if gf.exists():
            g = _loadtxt(gf, (3,), "a gravity direction")
            if np.linalg.norm(g) < 1e-9:
                raise InputError(f"{gf}: gravity direction is zero")
            self.gravity = g / np.linalg.norm(g)

    def _load(self, i: int) -> Frame:
        rgb = _imread_rgb(self.color_paths[i])
        depth = None
        if self.depth_paths[i].exists():
            depth = _imread_depth(self.depth_paths[i], self.depth_scale, invalid=(65535,))
            if depth.shape != rgb.shape[:2]:
                raise InputError(f"{self.depth_paths[i]}: depth is {depth.shape[::-1]} but the colour image is "
                                 f"{rgb.shape[1::-1]}")
        pose = None
        if self.pose_paths[i].exists():
            pose = _loadtxt(self.pose_paths[i], (4, 4), "a 4x4 camera-to-world pose")
        return Frame(rgb, float(self.timestamps[i]), i, self.K, depth, pose, self.dist)


def _read_tum_list(path: Path) -> list[tuple[float, list[str]]]:
    if not path.is_file():
        raise InputError(f"{path}: missing (TUM RGB-D layout needs rgb.txt, depth.txt, groundtruth.txt)")
    rows = []
    for ln, line in enumerate(path.read_text().splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        parts = line.split()
        try:
            rows.append((float(parts[0]), parts[1:]))
        except (ValueError, IndexError):
            raise InputError(f"{path}:{ln}: cannot parse {line!r}") from None
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

    def __init__(self, root: Path, hfov_deg: float | None = None, max_dt: float = 0.02, cache_size: int = 32):
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
                    v = np.array(v, dtype=np.float64)
                    self.poses[i] = make_pose(_quat_to_R(v[3:]), v[:3])
        self.has_depth = all(p is not None for p in self.depth_paths)
        self.has_pose = all(p is not None for p in self.poses)
        first = _imread_rgb(self.rgb_paths[0])
        H, W = first.shape[:2]
        self.size = (W, H)
        kf = self.root / "camera-intrinsics.txt"
        if kf.exists():
            self.K, self.dist = _loadtxt(kf, (3, 3), "a 3x3 intrinsics matrix"), None
        elif hfov_deg is not None:
            self.K, self.dist = intrinsics_from_fov(W, H, hfov_deg), None
        else:
            key = next((k for k in TUM_CALIB if k in str(self.root).lower()), "default")
            (fx, fy, cx, cy), dist = TUM_CALIB[key]
            self.K = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])
            self.dist = None if dist is None else np.array(dist)

    def _load(self, i: int) -> Frame:
        rgb = _imread_rgb(self.rgb_paths[i])
        dp = self.depth_paths[i]
        depth = None if dp is None else _imread_depth(dp, 5000.0)
        return Frame(rgb, float(self.timestamps[i]), i, self.K, depth, self.poses[i], self.dist)


# ----------------------------------------------------------------------------- plain images and video


class ImageFolderSource(FrameSource):
    """A folder of images in natural sort order; t from `timestamps.txt` or index / `fps`."""

    def __init__(self, root: Path, fps: float = 30.0, hfov_deg: float = 60.0, K: np.ndarray | None = None,
                 cache_size: int = 32):
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
        first = _imread_rgb(paths[0])
        H, W = first.shape[:2]
        self.size = (W, H)
        kf = self.root / "camera-intrinsics.txt"
        if K is not None:
            self.K = np.asarray(K, dtype=np.float64)
        elif kf.exists():
            self.K = _loadtxt(kf, (3, 3), "a 3x3 intrinsics matrix")
        else:
            self.K = intrinsics_from_fov(W, H, hfov_deg)

    def _load(self, i: int) -> Frame:
        rgb = _imread_rgb(self.paths[i])
        if rgb.shape[1::-1] != self.size:
            raise InputError(f"{self.paths[i]}: image is {rgb.shape[1]}x{rgb.shape[0]}, the folder's first image "
                             f"is {self.size[0]}x{self.size[1]}; all frames must have one size")
        return Frame(rgb, float(self.timestamps[i]), i, self.K)


class VideoSource(FrameSource):
    """A video decoded sequentially with OpenCV.

    Opening scans the file once (grab only, no colour conversion) to count frames and read their timestamps,
    because container frame counts are unreliable. Access decodes forward from the current position. A backward
    access, or a jump more than `seek_min` frames ahead, seeks (CAP_PROP_POS_FRAMES: FFmpeg jumps to the
    preceding key frame and decodes forward) and then checks the seek: the decoder's position and the frame's
    timestamp must equal the ones recorded by the scan. A seek that lands elsewhere (inexact seeking in some
    containers/codecs, or timestamps rebuilt from the nominal rate) switches the source to the exact slow path
    for good: reopen and decode forward from frame 0 (recorded in `seek_mode`, "verified" or "sequential").
    Decoded frames stay in an LRU cache (`cache_size` frames); `prefetch(indices)` decodes a set of frames in one
    forward pass. Rotation metadata is applied by OpenCV (CAP_PROP_ORIENTATION_AUTO) and recorded in
    `rotation_deg`.
    """

    seek_min: int = 48  # forward jumps longer than this seek instead of decoding every frame in between

    def __init__(self, path: Path, hfov_deg: float = 60.0, K: np.ndarray | None = None,
                 dist: np.ndarray | None = None, cache_size: int = 64, max_frames: int | None = None):
        super().__init__(cache_size)
        self.path = Path(path)
        self.name = self.path.stem
        if not self.path.is_file():
            raise InputError(f"{self.path}: video file not found")
        if self.path.stat().st_size == 0:
            raise InputError(f"{self.path}: video file is empty")
        cap = self._open()
        self.rotation_deg = int(cap.get(self._cv2.CAP_PROP_ORIENTATION_META) or 0)
        fps = cap.get(self._cv2.CAP_PROP_FPS) or 0.0
        ts: list[float] = []
        while max_frames is None or len(ts) < max_frames:
            if not cap.grab():
                break
            ms = cap.get(self._cv2.CAP_PROP_POS_MSEC)
            ts.append(ms / 1000.0 if ms > 0 or not ts else (len(ts) / fps if fps > 0 else float(len(ts))))
        cap.release()
        if not ts:
            raise InputError(f"{self.path}: no decodable video frames (corrupt file or unsupported codec)")
        t = np.array(ts, dtype=np.float64)
        if np.any(np.diff(t) <= 0):  # broken container timestamps: fall back to the nominal rate
            t = np.arange(len(ts), dtype=np.float64) / (fps if fps > 0 else 30.0)
            self.timestamp_source = "nominal_fps"
        else:
            self.timestamp_source = "container"
        self.timestamps = t
        # seeking is verified against the scan's container timestamps; without them only sequential decoding
        # is exact
        self.seek_mode = "verified" if self.timestamp_source == "container" else "sequential"
        self.seek_note = "" if self.seek_mode == "verified" else "no container timestamps to verify seeks"
        self._cap = None
        self._pos = 0  # index of the next frame `grab()` returns
        first = self._decode(0)
        H, W = first.shape[:2]
        self.size = (W, H)
        self.K = np.asarray(K, dtype=np.float64) if K is not None else intrinsics_from_fov(W, H, hfov_deg)
        self.dist = None if dist is None else np.asarray(dist, dtype=np.float64)

    @property
    def _cv2(self):
        import cv2

        return cv2

    def _open(self):
        cv2 = self._cv2
        cap = cv2.VideoCapture(str(self.path))
        if not cap.isOpened():
            raise InputError(f"{self.path}: OpenCV cannot open this video (corrupt file or unsupported format)")
        cap.set(cv2.CAP_PROP_ORIENTATION_AUTO, 1)
        return cap

    def _seek(self, i: int) -> bool:
        """Seek so that the next read returns frame i; False (and the capture reopened at 0) if inexact."""
        cv2 = self._cv2
        if self._cap is None:
            self._cap, self._pos = self._open(), 0
        if (self._cap.set(cv2.CAP_PROP_POS_FRAMES, float(i))
                and int(round(self._cap.get(cv2.CAP_PROP_POS_FRAMES))) == i):
            self._pos = i
            return True
        self._seek_failed(f"position {self._cap.get(cv2.CAP_PROP_POS_FRAMES)} after seeking to frame {i}")
        return False

    def _seek_failed(self, why: str) -> None:
        self.seek_mode = "sequential"
        self.seek_note = why
        if self._cap is not None:
            self._cap.release()
        self._cap, self._pos = self._open(), 0

    def _decode(self, i: int) -> np.ndarray:
        seek = (self.seek_mode == "verified" and self._cap is not None
                and (i < self._pos or i - self._pos > self.seek_min))
        if seek and self._seek(i):
            ok, bgr = self._cap.read()
            ms = self._cap.get(self._cv2.CAP_PROP_POS_MSEC)
            if ok and bgr is not None and abs(ms / 1000.0 - self.timestamps[i]) < 1e-3:
                self._pos = i + 1
                return np.ascontiguousarray(bgr[:, :, ::-1])
            self._seek_failed(f"frame {i}: timestamp {ms / 1000.0:.4f} s after seeking, scan gave "
                              f"{self.timestamps[i]:.4f} s")
        if self._cap is None or i < self._pos:
            if self._cap is not None:
                self._cap.release()
            self._cap, self._pos = self._open(), 0
        while self._pos < i:
            if not self._cap.grab():
                raise InputError(f"{self.path}: decoding stopped at frame {self._pos} of {len(self)}")
            self._pos += 1
        ok, bgr = self._cap.read()
        if not ok or bgr is None:
            raise InputError(f"{self.path}: cannot decode frame {i}")
        self._pos += 1
        return np.ascontiguousarray(bgr[:, :, ::-1])

    def _load(self, i: int) -> Frame:
        return Frame(self._decode(i), float(self.timestamps[i]), i, self.K, dist=self.dist)

    def prefetch(self, indices: Sequence[int]) -> None:
        """Decode these frames in one forward pass (at most `cache_size` of them, the earliest: more would evict
        the first before they are used; the rest are then reached by forward decoding anyway)."""
        want = sorted(set(int(i) for i in indices if 0 <= int(i) < len(self)))
        for i in want[:max(0, self._cache_size)]:
            if i not in self._cache:
                self._remember(i, self._load(i))

    def __del__(self) -> None:
        if getattr(self, "_cap", None) is not None:
            self._cap.release()


# ----------------------------------------------------------------------------- detection


def open_source(path: str | os.PathLike, **opts: Any) -> FrameSource:
    """Open a video file, 7-Scenes folder, TUM RGB-D folder or image folder (detected from the contents).

    opts go to the source class (e.g. `hfov_deg`, `fps`, `K`, `cache_size`, `max_frames`)."""
    p = Path(path)
    opts = {k: v for k, v in opts.items() if v is not None}
    if not p.exists():
        raise InputError(f"{p}: no such file or folder")
    if p.is_file():
        if p.suffix.lower() in IMAGE_EXTS:
            raise InputError(f"{p}: a single image is not a frame source; give its folder")
        return _make(VideoSource, p, opts)
    if not os.access(p, os.R_OK | os.X_OK):
        raise InputError(f"{p}: folder is not readable")
    if (p / "rgb.txt").exists():
        return _make(TUMSource, p, opts)
    if any(p.glob("frame-*.color.*")):
        return _make(SevenScenesSource, p, opts)
    if any(q.suffix.lower() in IMAGE_EXTS for q in p.iterdir()):
        return _make(ImageFolderSource, p, opts)
    vids = [q for q in p.iterdir() if q.suffix.lower() in VIDEO_EXTS]
    if len(vids) == 1:
        return _make(VideoSource, vids[0], opts)
    raise InputError(f"{p}: not a video, image folder, 7-Scenes folder (frame-XXXXXX.color.jpg) or TUM folder "
                     f"(rgb.txt)")


def _make(cls: type, path: Path, opts: dict[str, Any]) -> FrameSource:
    """Options that do not apply to the detected kind (e.g. `fps` for a video, which has its own timestamps)
    are not passed on."""
    import inspect

    accepted = inspect.signature(cls.__init__).parameters
    return cls(path, **{k: v for k, v in opts.items() if k in accepted})
