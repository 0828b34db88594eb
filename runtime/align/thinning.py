"""Thinning a sequence by measured overlap, not by an assumed frame rate.

Redundant-frame removal first samples the frames uniformly in time (`DedupConf.sample_fps`: a 30 fps video shows
nearly the same view in ten consecutive frames). A frame folder without timestamps only has frame numbers, so its
times are assumed (number / 30 fps), and a sequence that was recorded sparsely (ScanNet's even subsample, a
HoloLens walk-through) loses the frames that consecutive views need to overlap: the lounge moves ~0.8 m and
~40 degrees between its 3 fps samples. `overlap_sampled` keeps the time sampling where it is harmless and
measures where it is not: between two consecutive sampled frames that share less than `min_overlap` of their
tracked keypoints, the frame halfway is sampled too, recursively, down to adjacent frames. The kept frames are
then what later stages can chain through (the odometry backbone walks the removal's kept frames).
"""
from __future__ import annotations

from typing import Any, Callable, Iterator, Sequence


def overlap_sampled(sampled: Sequence[int], load: Callable[[int], Any], overlap: Callable[[Any, Any], float],
                    min_overlap: float) -> Iterator[tuple[int, Any, bool]]:
    """Positions to compare, in order, as (position, item, inserted): every position of `sampled` (sorted) plus,
    between two consecutive ones whose `overlap(item_a, item_b)` is below `min_overlap`, the position halfway,
    recursively (a pair of adjacent positions is never split). load(position) -> item (e.g. a small gray image
    and its keypoints), called once per yielded position; overlap(a, b) -> share of a's keypoints tracked in b.
    Pure apart from the two callables; `min_overlap` <= 0 yields `sampled` unchanged."""
    if not sampled:
        return
    prev = (int(sampled[0]), load(int(sampled[0])))
    yield prev[0], prev[1], False
    for p in sampled[1:]:
        cur = (int(p), load(int(p)))
        if min_overlap > 0:
            yield from _between(prev, cur, load, overlap, min_overlap)
        yield cur[0], cur[1], False
        prev = cur


def _between(a: tuple[int, Any], b: tuple[int, Any], load: Callable[[int], Any],
             overlap: Callable[[Any, Any], float], min_overlap: float) -> Iterator[tuple[int, Any, bool]]:
    """The positions strictly between a and b (each (position, item)) the rule inserts, in order."""
    if b[0] - a[0] <= 1 or overlap(a[1], b[1]) >= min_overlap:
        return
    m = (a[0] + b[0]) // 2
    mid = (m, load(m))
    yield from _between(a, mid, load, overlap, min_overlap)
    yield m, mid[1], True
    yield from _between(mid, b, load, overlap, min_overlap)
