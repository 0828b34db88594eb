"""Key-frame baselines in the search's terms: K evenly spaced candidates, K random ones, or every candidate
scored and the top K kept."""
from __future__ import annotations

from typing import Callable, Sequence

import numpy as np

from ..types import Detections
from .conf import KeyFrameConf
from .score import KeyFrameResult, _check_candidates, frame_score, object_weights, task_names, top_k

DetectFn = Callable[[int, list[str]], Detections]


def uniform_keyframes(candidates: Sequence[int], conf: KeyFrameConf | None = None) -> KeyFrameResult:
    """Baseline: K candidates evenly spaced in candidate order (centres of K equal bins); nothing is scored."""
    conf = conf or KeyFrameConf()
    c = _check_candidates(candidates)
    k = min(conf.keyframes, len(c))
    pos = np.unique(np.floor((np.arange(k) + 0.5) * len(c) / k).astype(np.int64))
    notes = [f"only {len(c)} candidates for {conf.keyframes} key frames"] if len(c) < conf.keyframes else []
    return KeyFrameResult("uniform", c[pos], {}, [], 0, len(c), conf.keyframes, notes=notes)


def random_keyframes(candidates: Sequence[int], conf: KeyFrameConf | None = None) -> KeyFrameResult:
    """Baseline: K candidates drawn at random (seed `conf.seed`, without replacement); nothing is scored."""
    conf = conf or KeyFrameConf()
    c = _check_candidates(candidates)
    k = min(conf.keyframes, len(c))
    pick = np.sort(np.random.default_rng([int(conf.seed), 5]).choice(len(c), size=k, replace=False))
    notes = [f"only {len(c)} candidates for {conf.keyframes} key frames"] if len(c) < conf.keyframes else []
    return KeyFrameResult("random", c[pick], {}, [], 0, len(c), conf.keyframes, notes=notes)


def exhaustive_keyframes(candidates: Sequence[int], targets: Sequence[str], cues: Sequence[str],
                         detect: DetectFn, conf: KeyFrameConf | None = None) -> KeyFrameResult:
    """Baseline: score every candidate, keep the top K among those with a positive score."""
    conf = conf or KeyFrameConf()
    c = _check_candidates(candidates)
    weights = object_weights(targets, cues, conf)
    names = task_names(targets, cues)
    scores = {int(f): frame_score(detect(int(f), names), weights) for f in c}
    positive = [f for f in scores if scores[f] > 0]
    chosen = top_k(positive, scores, conf.keyframes)
    notes = []
    if len(chosen) < conf.keyframes:
        notes.append(f"fewer than K: {len(chosen)} of {conf.keyframes} key frames (only {len(positive)} "
                     f"candidates with a positive score)")
    return KeyFrameResult("exhaustive", chosen, scores, [int(f) for f in c], len(c), len(c), conf.keyframes,
                          notes=notes)
