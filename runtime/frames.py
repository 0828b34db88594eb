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
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterator, Sequence

import numpy as np

from .errors import InputError, path_kind
from .geometry import intrinsics_from_fov, make_pose, worker_threads
from .lru import LRU

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


# Longest image side kept at decode: every model input is <= 1024 px and matching/back-projection gain nothing from
# more, while an 8000x6000 frame is 144 MB (x the frame cache). Larger frames are downscaled (K scaled to match).
MAX_DECODE_SIDE = 1920
MIN_FRAME_SIDE = 16  # below this no feature, box or depth statistic means anything (and OpenCV asserts)


def _read_bytes(path: Path, what: str) -> np.ndarray:
    """File bytes as a uint8 array. Reading through Python, not cv2.imread(str(path)), keeps file names that
    are not valid UTF-8 (undecodable bytes as surrogates) from reaching OpenCV's C++ path handling."""
    if not path.is_file():
        raise InputError(f"{_show(path)}: the {what} file is {path_kind(path)}; give a readable file")
    try:
        return np.frombuffer(path.read_bytes(), np.uint8)
    except OSError as e:
        raise InputError(f"{_show(path)}: cannot read the {what} file ({e.strerror})") from None


def imread_path(path: str | os.PathLike, flags: int | None = None, what: str = "image") -> np.ndarray | None:
    """cv2.imdecode of a file read through Python (path-safe for any file name); None if it does not decode.
    flags: cv2.IMREAD_* (default IMREAD_UNCHANGED). Missing file: InputError."""
    import cv2

    buf = _read_bytes(Path(path), what)
    return cv2.imdecode(buf, cv2.IMREAD_UNCHANGED if flags is None else flags) if buf.size else None


def imwrite_path(path: str | os.PathLike, img: np.ndarray, params: Sequence[int] = ()) -> None:
    """cv2.imencode by the file's extension, checked, then written through Python (path-safe). Raises OSError
    when encoding or writing fails: an image write is never silently skipped."""
    import cv2

    ok, buf = cv2.imencode(Path(path).suffix or ".png", img, list(params))
    if not ok:
        raise OSError(f"cannot encode {Path(path).suffix} image of shape {img.shape} for {_show(path)}")
    Path(path).write_bytes(buf.tobytes())


def _show(path: Path | str) -> str:
    """A path printable on any terminal (undecodable bytes shown as \\xNN)."""
    return os.fsdecode(path).encode("utf-8", "backslashreplace").decode("utf-8") if isinstance(path, (str, Path)) \
        else str(path)


def _imread_rgb(path: Path, notes: list[str] | None = None) -> np.ndarray:
    """Colour image -> [H, W, 3] uint8 RGB. A greyscale file is expanded to 3 channels and noted in `notes`."""
    import cv2

    buf = _read_bytes(path, "image")
    img = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED) if buf.size else None
    if img is None or img.size == 0:
        raise InputError(f"{_show(path)}: cannot decode the image (corrupt, empty or not an image); "
                         f"replace or remove the file")
    if img.dtype != np.uint8:  # 16-bit colour: keep the top 8 bits
        img = (img >> 8).astype(np.uint8) if img.dtype == np.uint16 else np.clip(img, 0, 255).astype(np.uint8)
    if img.ndim == 2 or img.shape[2] == 1:
        if notes is not None and not any(n.startswith("greyscale") for n in notes):
            notes.append(f"greyscale images (first: {_show(path.name)}) converted to 3-channel grey: colour cues "
                         f"are unavailable to the models")
        img = cv2.cvtColor(img.reshape(img.shape[:2]), cv2.COLOR_GRAY2BGR)
    elif img.shape[2] == 4:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2BGR)
    return np.ascontiguousarray(img[:, :, ::-1])


def _imread_depth(path: Path, scale: float, invalid: Sequence[int] = ()) -> np.ndarray:
    """uint16 depth PNG -> [H, W] float32 metres, given `scale` units per metre (1000 for mm, 5000 for TUM)."""
    import cv2

    buf = _read_bytes(path, "depth")
    d = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED) if buf.size else None
    if d is None or d.size == 0:
        raise InputError(f"{_show(path)}: cannot decode the depth image (corrupt or empty); restore or remove it")
    if d.ndim != 2 or d.dtype != np.uint16:
        raise InputError(f"{_show(path)}: depth must be a single-channel uint16 PNG, got {d.dtype} with shape "
                         f"{d.shape}")
    bad = d == 0
    for v in invalid:
        bad |= d == v
    out = d.astype(np.float32) / np.float32(scale)
    out[bad] = 0.0
    return out


def check_depth_units(depth: np.ndarray, path: Path, scale: float) -> None:
    """Refuse depth whose values cannot be metres after dividing by `scale` (indoor scenes: 0.1..20 m median).
    Depth saved in metres or centimetres into a millimetre PNG would otherwise give a 1000x smaller room."""
    v = depth[depth > 0]
    if v.size < 0.01 * depth.size:
        return  # too little valid depth to judge (checked on the next file with depth)
    med = float(np.median(v))
    if not 0.1 <= med <= 20.0:
        raw = med * scale
        guess = "metres" if raw < 30 else ("centimetres" if raw < 3000 else "sub-millimetre units")
        raise InputError(f"{_show(path)}: median depth {med:.3g} m after dividing the stored values (median "
                         f"{raw:.0f}) by {scale:g}; the file seems to hold {guess}, not 1/{scale:g} m units. "
                         f"Convert the depth PNGs to {'millimetres' if scale == 1000 else f'1/{scale:g} m'}")


def check_intrinsics(K: np.ndarray, size: tuple[int, int], where: str) -> np.ndarray:
    """A plausible pinhole K for an image of `size` (W, H): finite, fx, fy > 0 (a negative focal length mirrors
    the map, zero gives NaN geometry), field of view 5..175 degrees, principal point inside the image."""
    K = np.asarray(K, dtype=np.float64)
    W, H = size
    if K.shape != (3, 3) or not np.isfinite(K).all():
        raise InputError(f"{where}: intrinsics must be a finite 3x3 matrix")
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    if fx <= 0 or fy <= 0:
        raise InputError(f"{where}: focal lengths fx={fx:g}, fy={fy:g} must be positive (in pixels); fix the "
                         f"intrinsics (a negative value mirrors the scene, zero makes geometry undefined)")
    fov = np.degrees(2 * np.arctan(W / (2 * fx)))
    if not 5.0 <= fov <= 175.0 or not 0.2 <= fx / fy <= 5.0:
        raise InputError(f"{where}: fx={fx:g}, fy={fy:g} px give a {fov:.1f} degree horizontal field of view for "
                         f"{W}x{H} images; check the units (pixels) and that K matches this image size")
    if not (0 <= cx <= W and 0 <= cy <= H) or not np.allclose(K[2], [0, 0, 1]):
        raise InputError(f"{where}: principal point ({cx:g}, {cy:g}) is outside the {W}x{H} image or the last row "
                         f"is not [0 0 1]; check that K matches this image size")
    return K


def check_pose(T: np.ndarray, where: str) -> np.ndarray:
    """A rigid camera-to-world pose [4, 4]: rotation orthonormal with det +1, last row [0 0 0 1]. All-zero or
    scaled matrices (invalid ground truth) are refused here instead of failing later in fusion."""
    R = T[:3, :3]
    if (not np.allclose(T[3], [0, 0, 0, 1]) or abs(np.linalg.det(R) - 1) > 0.05
            or np.abs(R @ R.T - np.eye(3)).max() > 0.05):
        raise InputError(f"{where}: not a rigid camera-to-world pose (rotation must be orthonormal, det +1, last "
                         f"row 0 0 0 1); fix or remove the pose file")
    return T


def check_gravity(source: "FrameSource", where: str, max_deg: float = 75.0) -> None:
    """The source's gravity (down, world frame) seen from its cameras must point roughly along camera +y
    (image down): a handheld or robot video is seldom tilted by more than `max_deg` on median. A flipped or
    wrong-axis vector would stand the map on its side."""
    if source.gravity is None or not source.has_pose or len(source) == 0:
        return
    idx = np.unique(np.linspace(0, len(source) - 1, min(len(source), 24)).round().astype(int))
    ang = []
    for i in idx:
        g = source.gravity_camera(int(i))
        if g is not None:
            ang.append(np.degrees(np.arccos(np.clip(g[1], -1.0, 1.0))))
    if ang and float(np.median(ang)) > max_deg:
        raise InputError(f"{where}: gravity points {np.median(ang):.0f} degrees away from the cameras' down axis "
                         f"(median over {len(ang)} frames; a video is rarely tilted over {max_deg:.0f}); it must "
                         f"point DOWN in the pose frame: check its sign and axes, or delete it to use a floor fit")


def _fit_size(W: int, H: int, where: str, max_side: int) -> float:
    """Scale factor (<= 1) that brings the longest side to `max_side`; refuses frames too small to use."""
    if min(W, H) < MIN_FRAME_SIDE:
        raise InputError(f"{where}: frames are {W}x{H} px; at least {MIN_FRAME_SIDE}x{MIN_FRAME_SIDE} is needed")
    return min(1.0, max_side / float(max(W, H)))


def _downscale(img: np.ndarray, s: float, nearest: bool = False) -> np.ndarray:
    import cv2

    if s >= 1.0:
        return img
    h, w = img.shape[:2]
    size = (max(1, int(round(w * s))), max(1, int(round(h * s))))
    return cv2.resize(img, size, interpolation=cv2.INTER_NEAREST if nearest else cv2.INTER_AREA)


def _scale_K(K: np.ndarray, s: float) -> np.ndarray:
    if s >= 1.0:
        return K
    K = np.array(K, dtype=np.float64)
    K[:2] *= s
    return K


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
    load_seconds: float = 0.0   # class defaults: a subclass that skips __init__ still counts
    loads: int = 0
    splits_colour: bool = False  # `_load_colour` reads less than `_load` (depth and pose are separate files)

    def __init__(self, cache_size: int = 32):
        self._cache = LRU(cache_size)
        self._cache_size = int(cache_size)
        self._colour = LRU(max(1, self._cache_size // 2) if cache_size > 0 else 0)  # frames without depth, pose
        # what the reader had to degrade (greyscale, missing depth, partial decode, downscaling): the pipeline
        # records each as a `degraded` trace event, which the answer prints as a note
        self.notes: list[str] = []
        # decoding cost (every `_load`, cache misses only): the pipeline books it as trace stage "frames.load"
        self.load_seconds = 0.0
        self.loads = 0

    def __len__(self) -> int:
        return len(self.timestamps)

    def _position(self, i: int) -> int:
        n = len(self)
        i = int(i)
        if i < 0:
            i += n
        if not 0 <= i < n:
            raise IndexError(f"{self.name}: frame {i} out of range (0..{n - 1})")
        return i

    def colour(self, i: int) -> Frame:
        """Frame i for a reader of its colour only (redundant-frame removal, the key-frame search's detections
        and histograms): the cached whole frame when there is one, else the frame without depth and pose
        (`_load_colour`: a 7-Scenes frame's depth PNG costs more to decode than its JPEG, and the search scores
        3x the frames that get used), kept in a colour cache of half the frame cache's size. Sources without a
        cheaper colour read (`splits_colour` False: a video decodes the frame either way) give the whole frame,
        through the frame cache."""
        if not self.splits_colour:
            return self[i]
        i = self._position(i)
        f = self._cache.get(i)
        f = self._colour.get(i) if f is None else f
        return f if f is not None else self._colour.put(i, self._timed_load(i, self._load_colour))

    def _load_colour(self, i: int) -> Frame:
        """Frame i without depth and pose; sources that decode those separately override this."""
        return self._load(i)

    def __getitem__(self, i: int) -> Frame:
        i = self._position(i)
        f = self._cache.get(i)
        if f is None:
            f = self._timed_load(i)
            self._remember(i, f)
        return f

    def _timed_load(self, i: int, load: Any = None) -> Frame:
        t0 = time.perf_counter()
        try:
            return (load or self._load)(i)
        finally:
            self.load_seconds += time.perf_counter() - t0
            self.loads += 1

    def __iter__(self) -> Iterator[Frame]:
        for i in range(len(self)):
            yield self[i]

    def _remember(self, i: int, f: Frame) -> None:
        self._colour.pop(i, None)
        self._cache.put(i, f)

    def _load(self, i: int) -> Frame:  # pragma: no cover - abstract
        raise NotImplementedError

    def index_of(self, position: int) -> int:
        """Frame index of the frame at `position` (the same for sources; FrameList keeps its frames' indices)."""
        return int(position)

    def gray(self, position: int, width: int) -> np.ndarray:
        """Gray image [h, w] uint8, at most `width` wide, of the frame at `position` (redundant-frame removal;
        sources that can decode it more cheaply than the colour frame override this)."""
        from .dedup import small_gray

        return small_gray(self.colour(position).rgb, width)

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
                "fx": float(self.K[0, 0]), "fy": float(self.K[1, 1]), "notes": list(self.notes)}

    def _set_size(self, first: np.ndarray, where: str, max_side: int) -> None:
        """Record the decoded size (`orig_size`) and the size frames are delivered at (`size`, after the
        decode-time downscale `scale`), noting a downscale."""
        H, W = first.shape[:2]
        self.orig_size = (W, H)
        self.scale = _fit_size(W, H, where, max_side)
        self.size = (W, H) if self.scale >= 1 else _downscale(first, self.scale).shape[1::-1]
        if self.scale < 1:
            self.notes.append(f"{W}x{H} frames downscaled to {self.size[0]}x{self.size[1]} at decode (intrinsics "
                              f"scaled to match; the models need no more)")

    def _set_K(self, K: np.ndarray, where: str) -> None:
        """Check K against the decoded size, then scale it to the delivered size."""
        self.K = _scale_K(check_intrinsics(K, self.orig_size, where), self.scale)


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
        pose = None
        if self.pose_paths[i].exists():
            pose = check_pose(_loadtxt(self.pose_paths[i], (4, 4), "a 4x4 camera-to-world pose"),
                              _show(self.pose_paths[i]))
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
                    v = np.array(v, dtype=np.float64)
                    if not np.isfinite(v).all() or not 0.5 < np.linalg.norm(v[3:]) < 2.0:
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


# ----------------------------------------------------------------------------- plain images and video


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

    def _load(self, i: int) -> Frame:
        rgb = _imread_rgb(self.paths[i], self.notes)
        if rgb.shape[1::-1] != self.orig_size:
            raise InputError(f"{_show(self.paths[i])}: image is {rgb.shape[1]}x{rgb.shape[0]}, the folder's first "
                             f"image is {self.orig_size[0]}x{self.orig_size[1]}; all frames must have one size")
        return Frame(_downscale(rgb, self.scale), float(self.timestamps[i]), i, self.K)


def _small_gray_bgr(bgr: np.ndarray, width: int, scale: float = 1.0) -> np.ndarray:
    """Gray [h, w] uint8 of a decoded BGR frame, downscaled like the colour frame, then to at most `width`."""
    import cv2

    from .dedup import small_gray

    g = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
    return small_gray(_downscale(g, scale) if scale != 1.0 else g, width)


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
    `rotation_deg`. `progress(n)` is called with the frames the scan has decoded so far, every 32 (a bar).
    """

    seek_min: int = 48  # forward jumps longer than this seek instead of decoding every frame in between
    # FFmpeg decoder threads of the opening scan (None: `worker_threads()` less one, at least 1: the
    # redundant-frame removal's worker has a core of its own). On two cores FFmpeg's own choice (one thread
    # per core, competing with that worker) cost ~1 s more wall and ~1.5 s more CPU on the 600 s clip than one
    # decoder thread: docs/performance.md, "the scan's CPU" and "round 4"
    scan_decoder_threads: int | None = None

    def __init__(self, path: Path, hfov_deg: float = 60.0, K: np.ndarray | None = None,
                 dist: np.ndarray | None = None, cache_size: int = 64, max_frames: int | None = None,
                 max_side: int = MAX_DECODE_SIDE, dedup: Any = "default",
                 progress: Callable[[int], None] | None = None):
        super().__init__(cache_size)
        self.path = Path(path)
        self.name = self.path.stem
        if not self.path.is_file():
            raise InputError(f"{_show(self.path)}: video file not found")
        if self.path.stat().st_size == 0:
            raise InputError(f"{_show(self.path)}: video file is empty")
        self._cv_path = self._opencv_path(self.path)
        cap = self._open(self.scan_decoder_threads or max(1, worker_threads() - 1))
        self.rotation_deg = int(cap.get(self._cv2.CAP_PROP_ORIENTATION_META) or 0)
        fps = cap.get(self._cv2.CAP_PROP_FPS) or 0.0
        self.container_frames = int(cap.get(self._cv2.CAP_PROP_FRAME_COUNT) or 0)
        ts: list[float] = []
        od = self._start_online_dedup(dedup)
        try:
            while max_frames is None or len(ts) < max_frames:
                if not cap.grab():
                    break
                ms = cap.get(self._cv2.CAP_PROP_POS_MSEC)
                ts.append(ms / 1000.0 if ms > 0 or not ts else (len(ts) / fps if fps > 0 else float(len(ts))))
                if progress is not None and len(ts) % 32 == 0:  # frames decoded so far (a progress bar)
                    progress(len(ts))
                if od is not None and od.wants(ts[-1]):  # online redundant-frame removal: this frame is sampled
                    ok, bgr = cap.retrieve()
                    if not ok or bgr is None or min(bgr.shape[:2]) < MIN_FRAME_SIDE:  # _set_size says why below
                        od.finish()
                        od = None
                    else:
                        # the gray copy is made by the removal's worker: this thread is the scan's bottleneck
                        od.push(len(ts) - 1, None, bgr)
        finally:
            od = od.finish() if od is not None else None
        cap.release()
        if not ts:
            raise InputError(f"{_show(self.path)}: no decodable video frames (corrupt file or unsupported codec)")
        self.decoded_frames = len(ts)
        if max_frames is None and self.container_frames > len(ts) + 1:  # the header promised more: truncated
            self.notes.append(f"partial video: decoded {len(ts)} of the {self.container_frames} frames the "
                              f"container announces (truncated or corrupt file); the answer covers the first "
                              f"{len(ts) / fps if fps > 0 else len(ts):.1f} {'s' if fps > 0 else 'frames'} only")
        t = np.array(ts, dtype=np.float64)
        if np.any(np.diff(t) <= 0):  # broken container timestamps: fall back to the nominal rate
            t = np.arange(len(ts), dtype=np.float64) / (fps if fps > 0 else 30.0)
            self.timestamp_source = "nominal_fps"
        else:
            self.timestamp_source = "container"
        self.timestamps = t
        # the online removal sampled by the container timestamps: void if they were replaced
        self._online = od if od is not None and self.timestamp_source == "container" else None
        # seeking is verified against the scan's container timestamps; without them only sequential decoding
        # is exact
        self.seek_mode = "verified" if self.timestamp_source == "container" else "sequential"
        self.seek_note = "" if self.seek_mode == "verified" else "no container timestamps to verify seeks"
        self._cap = None
        self._pos = 0  # index of the next frame `grab()` returns
        self.scale = 1.0
        first = self._decode(0)
        self._set_size(first, _show(self.path), max_side)
        W, H = self.orig_size
        self._set_K(K if K is not None else intrinsics_from_fov(W, H, hfov_deg), "K" if K is not None else
                    f"hfov_deg={hfov_deg}")
        self.dist = None if dist is None else np.asarray(dist, dtype=np.float64)

    @staticmethod
    def _start_online_dedup(dedup: Any) -> Any:
        """dedup: "default" (DedupConf defaults), a DedupConf / mapping, or None (no removal while scanning)."""
        if dedup is None:
            return None
        from .dedup import BackgroundDedup, OnlineDedup

        return BackgroundDedup(OnlineDedup(None if isinstance(dedup, str) and dedup == "default" else dedup))

    @property
    def deduped_while_decoding(self) -> bool:
        """Whether the opening scan removed redundant frames as it decoded (`online_dedup` has the result)."""
        return getattr(self, "_online", None) is not None

    def online_dedup(self, conf: Any) -> Any:
        """The redundant-frame removal made while the opening scan decoded the video (`dedup.OnlineDedup`), as
        a DedupResult, when it ran with the same config `conf` (a DedupConf); else None (remove_redundant then
        decodes the sampled frames again)."""
        od = getattr(self, "_online", None)
        if od is None or od.conf != conf or self.scale != 1.0:  # the scan saw the frames before downscaling
            return None
        return od.result(len(self), self.index_of)

    def gray(self, position: int, width: int) -> np.ndarray:
        """Gray image of a frame, decoded without the RGB copy and without entering the frame cache."""
        if position in self._cache:
            return super().gray(position, width)
        return _small_gray_bgr(self._decode_bgr(position), width, self.scale)

    def _opencv_path(self, path: Path) -> str:
        """A path OpenCV can open: the file itself, or (for a name that is not valid UTF-8, which OpenCV's
        C++ side mishandles) a symlink with a plain name in a private temp folder."""
        s = os.fsdecode(path)
        try:
            s.encode("utf-8")
            return s
        except UnicodeEncodeError:
            import atexit
            import shutil
            import tempfile

            d = tempfile.mkdtemp(prefix="mosaic_video_")
            atexit.register(shutil.rmtree, d, True)
            link = os.path.join(d, "video" + "".join(c for c in path.suffix if c.isascii()))
            os.symlink(os.path.abspath(path), link)
            return link

    @property
    def _cv2(self):
        import cv2

        return cv2

    def _open(self, threads: int | None = None):
        cv2 = self._cv2
        cap = cv2.VideoCapture(self._cv_path, cv2.CAP_ANY, [cv2.CAP_PROP_N_THREADS, threads]) if threads else None
        if cap is None or not cap.isOpened():  # no thread count asked, or a backend that does not take one:
            cap = cv2.VideoCapture(self._cv_path)  # the same frames, decoded with the backend's own threads
        if not cap.isOpened():
            raise InputError(f"{_show(self.path)}: OpenCV cannot open this video (corrupt file or unsupported "
                             f"format)")
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
        return _downscale(np.ascontiguousarray(self._decode_bgr(i)[:, :, ::-1]), self.scale)

    def _decode_bgr(self, i: int) -> np.ndarray:
        """Frame i as decoded (BGR, original size)."""
        seek = (self.seek_mode == "verified" and self._cap is not None
                and (i < self._pos or i - self._pos > self.seek_min))
        if seek and self._seek(i):
            ok, bgr = self._cap.read()
            ms = self._cap.get(self._cv2.CAP_PROP_POS_MSEC)
            if ok and bgr is not None and abs(ms / 1000.0 - self.timestamps[i]) < 1e-3:
                self._pos = i + 1
                return bgr
            self._seek_failed(f"frame {i}: timestamp {ms / 1000.0:.4f} s after seeking, scan gave "
                              f"{self.timestamps[i]:.4f} s")
        if self._cap is None or i < self._pos:
            if self._cap is not None:
                self._cap.release()
            self._cap, self._pos = self._open(), 0
        while self._pos < i:
            if not self._cap.grab():
                raise InputError(f"{_show(self.path)}: decoding stopped at frame {self._pos} of {len(self)}")
            self._pos += 1
        ok, bgr = self._cap.read()
        if not ok or bgr is None:
            raise InputError(f"{_show(self.path)}: cannot decode frame {i}")
        self._pos += 1
        return bgr

    def _load(self, i: int) -> Frame:
        return Frame(self._decode(i), float(self.timestamps[i]), i, self.K, dist=self.dist)

    def prefetch(self, indices: Sequence[int]) -> None:
        """Decode these frames in one forward pass (at most `cache_size` of them, the earliest: more would evict
        the first before they are used; the rest are then reached by forward decoding anyway)."""
        want = sorted(set(int(i) for i in indices if 0 <= int(i) < len(self)))
        for i in want[:max(0, self._cache_size)]:
            if i not in self._cache:
                self._remember(i, self._timed_load(i))

    def __del__(self) -> None:
        if getattr(self, "_cap", None) is not None:
            self._cap.release()


# ----------------------------------------------------------------------------- detection


def open_source(path: str | os.PathLike, **opts: Any) -> FrameSource:
    """Open a video file, 7-Scenes folder, TUM RGB-D folder or image folder (detected from the contents).

    opts go to the source class (e.g. `hfov_deg`, `fps`, `K`, `cache_size`, `max_frames`)."""
    p = Path(path)
    opts = {k: v for k, v in opts.items() if v is not None}
    kind = path_kind(p)
    if kind not in ("a file", "a folder"):  # a FIFO would block the first read; a loop is not "missing"
        raise InputError(f"{_show(p)}: {'no such file or folder' if kind == 'missing' else kind}; give a video "
                         f"file or a folder of frames")
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
