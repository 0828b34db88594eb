"""A video as a frame source: decoded sequentially with OpenCV after one opening scan (timestamps, frame count),
seeks verified against that scan; an observer (the scan stage's redundant-frame removal) may see the frames as the
opening scan decodes them, so the video is decoded once."""
from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Callable, Protocol, Sequence

import cv2
import numpy as np

from ..geometry import intrinsics_from_fov, worker_threads
from ..infra.errors import InputError
from ..types import Frame
from .source import MAX_DECODE_SIDE, MIN_FRAME_SIDE, FrameSource, _downscale, _show, small_gray


def _small_gray_bgr(bgr: np.ndarray, width: int, scale: float = 1.0) -> np.ndarray:
    """Gray [h, w] uint8 of a decoded BGR frame, downscaled like the colour frame, then to at most `width`."""
    g = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
    return small_gray(_downscale(g, scale) if scale != 1.0 else g, width)


class FrameObserver(Protocol):
    """Sees a video's frames while its opening scan decodes them (e.g. `scan.OnlineDedup` in a worker): `wants(t)`
    for every frame in order, `push(index, gray or None, bgr)` for the frames it wants, `finish()` its result."""

    def wants(self, t: float) -> bool: ...
    def push(self, index: int, gray: np.ndarray | None, bgr: np.ndarray | None = None) -> Any: ...
    def finish(self) -> Any: ...


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

    sequential = True   # frames decode forward only (the scan keeps its time sampling: times are measured)
    seek_min: int = 48  # forward jumps longer than this seek instead of decoding every frame in between
    # FFmpeg threads of the opening scan (None: the cores less one: the observer's worker has its own)
    scan_decoder_threads: int | None = None

    def __init__(self, path: Path, hfov_deg: float = 60.0, K: np.ndarray | None = None,
                 dist: np.ndarray | None = None, cache_size: int = 64, max_frames: int | None = None,
                 max_side: int = MAX_DECODE_SIDE, observer: Callable[[], FrameObserver] | None = None,
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
        od = observer() if observer is not None else None
        try:
            while max_frames is None or len(ts) < max_frames:
                if not cap.grab():
                    break
                ms = cap.get(self._cv2.CAP_PROP_POS_MSEC)
                ts.append(ms / 1000.0 if ms > 0 or not ts else (len(ts) / fps if fps > 0 else float(len(ts))))
                if progress is not None and len(ts) % 32 == 0:  # frames decoded so far (a progress bar)
                    progress(len(ts))
                if od is not None and od.wants(ts[-1]):  # the observer (the scan stage's removal) wants it
                    ok, bgr = cap.retrieve()
                    if not ok or bgr is None or min(bgr.shape[:2]) < MIN_FRAME_SIDE:  # _set_size says why below
                        od.finish()
                        od = None
                    else:
                        # the gray copy is made by the observer's worker: this thread is the scan's bottleneck
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
        # what the observer made of the frames it saw: void when the timestamps it sampled by were replaced or the
        # frames it saw are not the ones this source serves (downscaled)
        self.observed = od if self.timestamp_source == "container" and self.scale == 1.0 else None

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
