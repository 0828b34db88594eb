"""Frame sources (paper: the input video): random access by index, with timestamps, over a video, an image folder or an RGB-D folder.

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

import inspect
import os
from pathlib import Path
from typing import Any

from ..infra.errors import InputError, path_kind
from .folders import ImageFolderSource, SevenScenesSource, TUMSource
from .source import (IMAGE_EXTS, VIDEO_EXTS, FrameList, FrameSource, _show, check_intrinsics, imread_path,
                     imwrite_path, small_gray, world_down)
from .video import FrameObserver, VideoSource

__all__ = ["FrameList", "FrameObserver", "FrameSource", "ImageFolderSource", "SevenScenesSource", "TUMSource",
           "VideoSource", "check_intrinsics", "imread_path", "imwrite_path", "open_source", "small_gray",
           "world_down"]


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
    accepted = inspect.signature(cls.__init__).parameters
    return cls(path, **{k: v for k, v in opts.items() if k in accepted})
