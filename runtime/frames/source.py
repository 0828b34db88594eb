"""The frame source every stage reads (`FrameSource`: random access by index, timestamps, K, optional depth,
poses and gravity), its readers (errors name the file) and the checks of what a source gives."""
from __future__ import annotations

import os
import re
import time
from pathlib import Path
from typing import Any, Iterator, Sequence

import cv2
import numpy as np

from ..infra.errors import InputError, path_kind, read_text
from ..infra.lru import LRU
from ..infra.numbers import check_array, read_number
from ..types import Frame

IMAGE_EXTS = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".webp")
VIDEO_EXTS = (".mp4", ".mov", ".avi", ".mkv", ".m4v", ".webm", ".3gp", ".mpg", ".mpeg")


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
    buf = _read_bytes(Path(path), what)
    return cv2.imdecode(buf, cv2.IMREAD_UNCHANGED if flags is None else flags) if buf.size else None


def imwrite_path(path: str | os.PathLike, img: np.ndarray, params: Sequence[int] = ()) -> None:
    """cv2.imencode by the file's extension, checked, then written through Python (path-safe). Raises OSError
    when encoding or writing fails: an image write is never silently skipped."""
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


def world_down(source: "FrameSource", n: int = 48) -> tuple[np.ndarray, str] | None:
    """The direction of gravity (DOWN, unit [3]) in the world of a source's ground-truth poses, and how it was
    found: the source's own (`gravity-direction.txt`), else from the poses: the mean image-down axis (camera +y)
    of up to `n` cameras spread over the sequence - people hold cameras upright - snapped to the nearest world
    axis when within 10 degrees of it (a tracker's world usually has one axis vertical: z in ScanNet, y in a
    HoloLens or ARKit world). None without poses. For evaluation and annotation (top-down pictures in the world of
    the ground truth); the pipeline finds its floor itself."""
    if source.gravity is not None:
        return np.asarray(source.gravity, float), "gravity-direction.txt"
    bad = set(source.untracked_frames())
    idx = [int(i) for i in np.unique(np.linspace(0, len(source) - 1, min(n, len(source))).round()) if int(i) not in bad]
    downs = [T[:3, 1] for T in (source[i].pose_gt for i in idx) if T is not None]
    if not downs:
        return None
    d = np.mean(downs, 0)
    d /= max(float(np.linalg.norm(d)), 1e-12)
    k = int(np.argmax(np.abs(d)))
    if abs(d[k]) >= np.cos(np.radians(10.0)):
        axis = np.zeros(3)
        axis[k] = np.sign(d[k])
        return axis, f"world {'xyz'[k]} axis (cameras' mean down, {np.degrees(np.arccos(abs(d[k]))):.1f} deg off it)"
    return d, "cameras' mean down"


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


def _loadtxt(path: Path, shape: tuple[int, ...] | None = None, what: str = "numbers",
             allow_nonfinite: bool = False) -> np.ndarray:
    try:
        a = np.loadtxt(path, dtype=np.float64, ndmin=1)
    except (OSError, ValueError) as e:
        raise InputError(f"{path}: cannot read {what} ({e})") from None
    if shape is not None:
        if a.size != int(np.prod(shape)):
            raise InputError(f"{path}: expected {what} with {int(np.prod(shape))} values {shape}, got {a.size}")
        a = a.reshape(shape)
    if not allow_nonfinite:  # the one check of every number read (finite; within ±1e7: no indoor value is larger)
        check_array(a, _show(path), what, lo=-1e7, hi=1e7, fix="fix or replace the file")
    return a


def _natural_key(s: str) -> list[Any]:
    return [int(p) if p.isdigit() else p.lower() for p in re.split(r"(\d+)", s)]


def _read_timestamps(path: Path, n: int, names: Sequence[str] | None = None) -> np.ndarray:
    """`timestamps.txt`: one line per frame, either `t` or `<frame name or number> t` (last field = seconds)."""
    rows: list[tuple[str, float]] = []
    for ln, line in enumerate(read_text(path, "timestamps").splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        parts = line.replace(",", " ").split()
        rows.append((parts[0] if len(parts) > 1 else "", read_number(
            parts[-1], f"{_show(path)}:{ln}: the timestamp", lo=-1e11, hi=1e11, unit="s", fix="fix that line")))
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


def _small_gray(rgb: np.ndarray, width: int) -> np.ndarray:
    g = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2GRAY) if rgb.ndim == 3 else rgb
    if g.shape[1] > width:
        g = cv2.resize(g, (width, max(1, round(g.shape[0] * width / g.shape[1]))), interpolation=cv2.INTER_AREA)
    return g


def small_gray(rgb: np.ndarray, width: int, bgr: bool = False) -> np.ndarray:
    """Gray image [h, w] uint8 at most `width` wide (INTER_AREA) of an RGB (or BGR) image [H, W, 3]."""
    if rgb.ndim == 3:
        rgb = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_BGR2GRAY if bgr else cv2.COLOR_RGB2GRAY)
    return _small_gray(rgb, width)


def _gray_file(path: Path, width: int) -> np.ndarray:
    """Gray [h, w] uint8, at most `width` wide, of an image file, decoded at the largest JPEG reduction (1/2, 1/4,
    1/8) that is still at least `width` wide: the redundant-frame removal reads every compared frame this way
    (a full decode, colour conversion and copy cost ~3x more). A file that does not decode: `_imread_rgb`'s error."""
    buf = _read_bytes(path, "image")
    g = None
    head = _image_width(buf)
    for flag, f in ((cv2.IMREAD_REDUCED_GRAYSCALE_8, 8), (cv2.IMREAD_REDUCED_GRAYSCALE_4, 4),
                    (cv2.IMREAD_REDUCED_GRAYSCALE_2, 2), (cv2.IMREAD_GRAYSCALE, 1)):
        if head is not None and head // f < width and f > 1:
            continue
        g = cv2.imdecode(buf, flag) if buf.size else None
        break
    if g is None or g.size == 0 or (head is None and g.shape[1] < width and g.shape[1] * 2 <= width):
        return small_gray(_imread_rgb(path), width)
    return small_gray(g, width)


def _image_width(buf: np.ndarray) -> int | None:
    """The width stored in a JPEG's or PNG's header (None when not found: the caller decodes in full)."""
    b = buf.tobytes()[:65536]
    if b[:8] == b"\x89PNG\r\n\x1a\n" and len(b) >= 24:
        return int.from_bytes(b[16:20], "big")
    i = 2
    while b[:2] == b"\xff\xd8" and i + 9 < len(b):
        if b[i] != 0xFF:
            return None
        marker, seg = b[i + 1], int.from_bytes(b[i + 2:i + 4], "big")
        if marker in (0xC0, 0xC1, 0xC2):
            return int.from_bytes(b[i + 7:i + 9], "big")
        i += 2 + seg
    return None


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
    sequential: bool = False     # frames decode forward only (a video: going back re-opens the file)

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
        path = self._colour_path(position)
        if path is not None and self._position(position) not in self._cache:
            return _gray_file(path, width)
        return small_gray(self.colour(position).rgb, width)

    def _colour_path(self, position: int) -> Path | None:
        """The image file of the frame at `position`, when the source reads one file per frame (a cheaper gray
        read decodes it at a reduced size: `_gray_file`)."""
        return None

    def prefetch(self, indices: Sequence[int]) -> None:
        """Hint that these frames are needed soon (the video source decodes them in one forward pass)."""

    def untracked_frames(self) -> list[int]:
        """Positions of frames whose ground-truth pose marks a tracking failure (none for most sources)."""
        return []

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
        """Check K against the decoded size, then scale it to the delivered size; `K_from` says where K came from."""
        self.K = _scale_K(check_intrinsics(K, self.orig_size, where), self.scale)
        self.K_from = where


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
