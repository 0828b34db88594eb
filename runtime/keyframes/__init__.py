"""Key-frame selection (paper: key frame selection, the iterative temporal search), one module per job:

conf       KeyFrameConf (every setting of the stage)
count      the key-frame count K, resolved in one place: flag, budget, config, plan, floor, reserve, budget cut
signals    cheap per-candidate signals: edge density, view change, colour-histogram similarity
score      frame scores, kernels, the expected-score distribution, stretches and climbs
search     the iterative search, its top-up, the coverage spread, `select_keyframes`
baselines  uniform, random and exhaustive key frames
"""
from .baselines import exhaustive_keyframes, random_keyframes, uniform_keyframes
from .conf import METHODS, KeyFrameConf, scored_budget
from .count import (KeyFrameBudget, KeyFramePlan, coverage_reserve, cut_keyframes, finish_keyframes, plan_keyframes,
                    requested_keyframes)
from .score import (KeyFrameResult, batch_sizes, climb_steps, expected_scores, frame_score, gap_novelty,
                    gaussian_kernel, kernel_matrix, object_weights, resolve_budget, sampling_probabilities,
                    sigma_from_similarity, stretches, task_names, top_k, top_k_stretches, update_distribution,
                    zscores)
from .search import cut_by_border, iterative_search, reduce_keyframes, select_keyframes, spread_keyframes
from .signals import content_axis, edge_density, grey_thumbnail, histogram_similarity, view_change

__all__ = [
    "exhaustive_keyframes", "random_keyframes", "uniform_keyframes", "METHODS", "KeyFrameBudget", "KeyFrameConf",
    "KeyFramePlan", "coverage_reserve", "cut_keyframes", "finish_keyframes", "plan_keyframes", "requested_keyframes",
    "scored_budget", "KeyFrameResult", "batch_sizes",
    "climb_steps", "expected_scores", "frame_score", "gap_novelty", "gaussian_kernel", "kernel_matrix",
    "object_weights", "resolve_budget", "sampling_probabilities", "sigma_from_similarity", "stretches", "task_names",
    "top_k", "top_k_stretches", "update_distribution", "zscores", "cut_by_border", "iterative_search",
    "reduce_keyframes", "select_keyframes", "spread_keyframes", "content_axis", "edge_density", "grey_thumbnail",
    "histogram_similarity", "view_change",
]
