"""Long synthetic walk-throughs for the key-frame search (issue 17): several rooms, 5-10 minutes, objects in
short stretches.

The paper's key-frame claim is about long videos in which a question's objects appear briefly (LV-Haystack);
the single-room scenes of `generate.py` show most objects for a third of the clip. A long video here is a tour
of `rooms` rooms (each drawn by `scene.generate_scene` with its own seed, room size and object level drawn
from the VSI-Bench terciles) joined by corridors (long narrow empty rooms, 8-14 m x 1.8-2.4 m, walls
and pictures only), the camera walking `room_seconds` through each room and
`corridor_seconds` through each corridor (`trajectory.camera_track`); a cut at each doorway: segments never see
into each other, so an object is visible only while its own room is walked.

Frames are rendered in memory at a small size (default 160x120, `render.Renderer`, about 5 ms a frame) at
`fps` (default 2 frames/s: the rate that redundant-frame removal keeps on the 15 fps scenes, ~150 of 900), so
every frame is a candidate. Per frame and instance the ground truth is that of `scene.json`
(`generate.visibility_entries`: pixels, visible fraction, in-frame share, visibility) plus the instance's
bounding box in the frame.

`long_questions` builds the questions: one per category (targets = [category]) and up to `pairs_per_room`
category pairs of one room (two targets, as distance questions); a question's instances are all instances of its
categories in the whole video, and it is kept only when they are visible (>= `seen_min_pixels`) in fewer than
`max_share` (default 5%) of the frames.

`LongVideoOracle` is the oracle detector on that ground truth: it sees an instance with at least
`seen_min_pixels` visible pixels, misses it with probability `miss_rate`, gives it a confidence that grows with
how much of it is visible (a prior: a real detector is surer of a whole object than of a sliver) times
1 - |N(0, score_noise)|, and adds false positives (a box of a wanted name in a frame that need not show it) with
probability `false_positive_rate` per frame and name, confidence |N(0, 0.3)| clipped to [0.05, 0.9]. Draws are
seeded by (seed, frame, instance or name): asking again gives the same answer, whatever the order.
"""
from __future__ import annotations

import math
import zlib
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.ndimage import find_objects

from mosaicthinker.runtime.infra.errors import InputError
from mosaicthinker.runtime.types import Detections
from mosaicthinker.host.synth.scene import SceneConfig, generate_scene

ROOM_LEVELS = ("small", "medium", "large")
OBJECT_LEVELS = ("low", "med", "high")


@dataclass
class LongVideoConf:
    """One long walk-through. rooms: None -> drawn in [6, 10] from the seed (5.1-8.8 min with the corridors
    between them)."""

    seed: int = 0
    rooms: int | None = None
    room_seconds: float = 25.0
    corridor_seconds: float = 30.0
    fps: float = 2.0
    width: int = 160
    height: int = 120
    noise_sigma: float = 2.0

    def validate(self) -> None:
        if self.rooms is not None and self.rooms < 1:
            raise InputError(f"long video: rooms must be >= 1 (got {self.rooms})")
        if not (self.room_seconds > 0 and self.corridor_seconds >= 0 and self.fps > 0):
            raise InputError(f"long video: need room_seconds > 0, corridor_seconds >= 0, fps > 0 (got "
                             f"{self.room_seconds}, {self.corridor_seconds}, {self.fps})")
        if self.width < 32 or self.height < 24:
            raise InputError(f"long video: size must be at least 32x24 (got {self.width}x{self.height})")

    def n_frames(self) -> int:
        """Frames the video will have (without rendering it): rooms and corridors at `fps`."""
        per = lambda sec: max(1, int(round(sec * self.fps)))  # noqa: E731 (as make_long_video counts)
        n = self.n_rooms()
        return n * per(self.room_seconds) + ((n - 1) * per(self.corridor_seconds) if self.corridor_seconds > 0 else 0)

    def n_rooms(self) -> int:
        if self.rooms is not None:
            return int(self.rooms)
        return int(np.random.default_rng([int(self.seed), 4242]).integers(6, 11))


@dataclass
class LongVideo:
    """A rendered long walk-through. Per frame f (all [N] lists/arrays): room[f] (segment index; `rooms[s]`
    says whether segment s is a room or a corridor); visible[f]: instance id ->
    scene.json row (pixels, fraction, in_frame, visibility); boxes[f]: id -> [4] x0, y0, x1, y1 pixels (x1/y1
    exclusive); rgb: [N, H, W, 3] uint8. names / room_of: id -> category / room index (ids unique over the
    video)."""

    conf: LongVideoConf
    room: np.ndarray
    times: np.ndarray
    visible: list[dict[int, dict[str, float]]]
    boxes: list[dict[int, np.ndarray]]
    names: dict[int, str]
    room_of: dict[int, int]
    rgb: np.ndarray
    rooms: list[dict[str, Any]] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.visible)

    @property
    def size(self) -> tuple[int, int]:
        return self.conf.width, self.conf.height

    @property
    def seen_min_pixels(self) -> int:
        """The scenes' "seen" rule: 0.1% of the image, at least 10 pixels."""
        return max(10, int(math.ceil(0.001 * self.conf.width * self.conf.height)))

    def visibility(self) -> list[dict[int, float]]:
        """Per frame: instance id -> visibility (the table `evaluation.keyframes.score_selection` takes)."""
        return [{i: float(v["visibility"]) for i, v in row.items()} for row in self.visible]


def _segments(conf: LongVideoConf) -> list[tuple[str, SceneConfig, float]]:
    """(kind, scene config, seconds) per segment: room, corridor, room, ..., room."""
    rng = np.random.default_rng([int(conf.seed), 77])
    common = dict(fps=conf.fps, width=conf.width, height=conf.height, noise_sigma=conf.noise_sigma)
    out = []
    n = conf.n_rooms()
    for r in range(n):
        out.append(("room", SceneConfig(seed=int(conf.seed) * 1000 + 2 * r, objects=OBJECT_LEVELS[int(rng.integers(3))],
                                        room=ROOM_LEVELS[int(rng.integers(3))], duration=conf.room_seconds,
                                        **common), conf.room_seconds))
        if r < n - 1 and conf.corridor_seconds > 0:
            dims = (float(rng.uniform(8.0, 14.0)), float(rng.uniform(1.8, 2.4)))
            out.append(("corridor", SceneConfig(seed=int(conf.seed) * 1000 + 2 * r + 1, room_dims=dims,
                                                vsibench_objects=False, extras=False, duration=conf.corridor_seconds, **common),
                        conf.corridor_seconds))
    return out


def _frame_boxes(inst: np.ndarray, offset: int) -> dict[int, np.ndarray]:
    """Bounding boxes of every instance id in an [H, W] instance buffer (0 = room), ids shifted by `offset`."""
    out = {}
    for k, sl in enumerate(find_objects(inst), start=1):
        if sl is not None:
            out[k + offset] = np.array([sl[1].start, sl[0].start, sl[1].stop, sl[0].stop], np.float32)
    return out


def make_long_video(conf: LongVideoConf | None = None) -> LongVideo:
    """Generate and render a long walk-through (deterministic in `conf`)."""
    from mosaicthinker.runtime.geometry import intrinsics_from_fov
    from mosaicthinker.host.synth.generate import in_frame_fraction, visibility_entries
    from mosaicthinker.host.synth.render import Renderer
    from mosaicthinker.host.synth.trajectory import camera_track

    conf = conf or LongVideoConf()
    conf.validate()
    K = intrinsics_from_fov(conf.width, conf.height, 60.0)
    room_idx, times, visible, boxes, rgbs, rooms = [], [], [], [], [], []
    names: dict[int, str] = {}
    room_of: dict[int, int] = {}
    offset, t0 = 0, 0.0
    for r, (kind, sconf, seconds) in enumerate(_segments(conf)):
        sc = generate_scene(sconf)
        n = max(1, int(round(seconds * conf.fps)))
        t, poses = camera_track(sc, n, conf.fps)
        ren = Renderer(sc, K, conf.width, conf.height, conf.noise_sigma)
        for i, T_wc in enumerate(poses):
            res = ren.render(T_wc, frame_seed=i)
            rows = visibility_entries(res.visible, res.covered, in_frame_fraction(sc, K, T_wc, ren.W, ren.H))
            visible.append({int(v["id"]) + offset: v for v in rows})
            boxes.append(_frame_boxes(res.instances, offset))
            rgbs.append(res.rgb)
        for o in sc.objects:
            names[o.id + offset] = o.name
            room_of[o.id + offset] = r
        rooms.append({"kind": kind, "seed": sconf.seed, "room": sconf.room if kind == "room" else None,
                      "objects": sconf.objects if kind == "room" else None, "area_m2": round(sc.room.area, 2),
                      "instances": len(sc.objects), "frames": n})
        room_idx += [r] * n
        times.append(t0 + t)
        t0 += n / conf.fps
        offset += max([o.id for o in sc.objects], default=0)
    return LongVideo(conf, np.array(room_idx), np.concatenate(times), visible, boxes, names, room_of,
                     np.stack(rgbs), rooms)


# ------------------------------------------------------------------------------------------------ questions


def _share(video: LongVideo, ids: set[int]) -> float:
    px = video.seen_min_pixels
    return float(np.mean([any(row.get(i, {}).get("pixels", 0) >= px for i in ids) for row in video.visible]))


def long_questions(video: LongVideo, max_share: float = 0.05, min_visible: float = 0.2, pairs_per_room: int = 3,
                   seed: int = 0) -> tuple[list[dict[str, Any]], dict[str, int]]:
    """Questions as {id, qtype ("single" | "pair"), targets, cues, instances, share}; returns (kept, skipped
    counts). Only instances that reach `min_visible` somewhere count; a question needs one and a visible share
    (frames showing any of its instances) below `max_share`."""
    vis = video.visibility()
    eligible = {i for row in vis for i, v in row.items() if v >= min_visible}
    by_name: dict[str, set[int]] = {}
    for i, n in video.names.items():
        if i in eligible:
            by_name.setdefault(n, set()).add(i)
    cands: list[tuple[str, list[str]]] = [("single", [n]) for n in sorted(by_name)]
    rng = np.random.default_rng([int(seed), 31])
    for r in (r for r, seg in enumerate(video.rooms) if seg["kind"] == "room"):
        here = sorted({video.names[i] for i in eligible if video.room_of[i] == r})
        here = [n for n in here if _share(video, by_name[n]) < max_share / 2]  # pairs of rare categories
        pairs = [(a, b) for k, a in enumerate(here) for b in here[k + 1:]]
        for j in rng.permutation(len(pairs))[:pairs_per_room]:
            cands.append(("pair", list(pairs[int(j)])))
    out, skipped, seen = [], {"too visible": 0, "duplicate": 0}, set()
    for qtype, targets in cands:
        key = tuple(sorted(targets))
        if key in seen:
            skipped["duplicate"] += 1
            continue
        seen.add(key)
        ids = set().union(*(by_name[n] for n in targets))
        share = _share(video, ids)
        if share >= max_share:
            skipped["too visible"] += 1
            continue
        out.append({"id": len(out), "qtype": qtype, "targets": targets, "cues": [], "instances": sorted(ids),
                    "share": round(share, 4)})
    return out, skipped


# ------------------------------------------------------------------------------------------------ detector


class LongVideoOracle:
    """Oracle detector on a `LongVideo`'s ground truth with misses, visibility-dependent confidence and false
    positives (module doc). detect(frame, names) -> Detections (boxes [N, 4] pixels, instance_ids [N], -1 for a
    false positive)."""

    def __init__(self, video: LongVideo, miss_rate: float = 0.1, score_noise: float = 0.1,
                 false_positive_rate: float = 0.02, seed: int = 0, full_confidence_at: float = 0.5):
        for nm, v in (("miss_rate", miss_rate), ("false_positive_rate", false_positive_rate)):
            if not 0.0 <= v <= 1.0:
                raise InputError(f"long-video oracle: {nm} must be in [0, 1], got {v}")
        if score_noise < 0 or full_confidence_at <= 0:
            raise InputError("long-video oracle: need score_noise >= 0 and full_confidence_at > 0")
        from mosaicthinker.runtime.grounding import canonical_name

        self.video, self.seed = video, int(seed)
        self.miss_rate, self.score_noise, self.fp_rate = float(miss_rate), float(score_noise), float(false_positive_rate)
        self.full_at = float(full_confidence_at)
        self._canon = canonical_name
        self._key = {i: (canonical_name(n) or n.lower()) for i, n in video.names.items()}

    def _score(self, rng: np.random.Generator, visibility: float) -> float:
        base = 1.0 - abs(rng.normal(0.0, self.score_noise)) if self.score_noise > 0 else 1.0
        return float(np.clip(base * (0.4 + 0.6 * min(1.0, visibility / self.full_at)), 0.05, 1.0))

    def _false_positive(self, f: int, key: str) -> tuple[np.ndarray, float] | None:
        rng = np.random.default_rng([self.seed, int(f), zlib.crc32(key.encode()), 7])
        if rng.random() >= self.fp_rate:
            return None
        W, H = self.video.size
        w, h = rng.uniform(0.1, 0.35) * W, rng.uniform(0.1, 0.35) * H
        x, y = rng.uniform(0, W - w), rng.uniform(0, H - h)
        return np.array([x, y, x + w, y + h], np.float32), float(np.clip(abs(rng.normal(0, 0.3)), 0.05, 0.9))

    def detect(self, frame_index: int, names: list[str]) -> Detections:
        f = int(frame_index)
        if not 0 <= f < len(self.video):
            raise IndexError(f"long video: frame {f} out of range (0..{len(self.video) - 1})")
        want: dict[str, list[str]] = {}
        for n in names:
            want.setdefault(self._canon(n) or n.strip().lower(), []).append(n)
        boxes, scores, out_names, inst = [], [], [], []
        for k, row in self.video.visible[f].items():
            if row["pixels"] < self.video.seen_min_pixels or self._key.get(k) not in want:
                continue
            rng = np.random.default_rng([self.seed, f, int(k)])
            if rng.random() < self.miss_rate:
                continue
            s = self._score(rng, float(row["visibility"]))
            for n in want[self._key[k]]:
                boxes.append(self.video.boxes[f][k]), scores.append(s), out_names.append(n), inst.append(k)
        for key, ns in want.items():
            fp = self._false_positive(f, key)
            if fp is not None:
                for n in ns:
                    boxes.append(fp[0]), scores.append(fp[1]), out_names.append(n), inst.append(-1)
        if not out_names:
            return Detections.empty()
        return Detections(np.array(boxes, np.float32), np.array(scores, np.float32), out_names,
                          instance_ids=np.array(inst, np.int64))
