"""The depth check of tree edges (metric depth): a wrong transform puts one frame's points into space the other
sees as empty; a right one only at occlusion edges. Cut edges split the tree; the larger part stays aligned."""
from __future__ import annotations

from collections import deque
from typing import Callable, Mapping, Sequence

import numpy as np

from ..geometry import backproject, invert, sample_depth, transform
from ..infra.trace import StageLog, as_trace
from ..types import Frame
from .conf import AlignConf
from .tree import AlignmentResult


def depth_consistency(fa: Frame, fb: Frame, T_ab: np.ndarray, stride: int = 8) -> tuple[float, float, float]:
    """How well frame b's depth agrees with frame a's under T_ab (b camera -> a camera).

    Returns (overlap: share of b's points that land on valid depth in a, consistent: share of those within
    5 cm + 3% of a's depth, violation: share of those lying clearly in FRONT of a's observed surface, i.e. in
    space a sees as empty). A wrong transform puts points in free space; a right one only at occlusion edges."""
    p, _ = backproject(fb.depth, fb.K, stride=stride)
    if len(p) == 0:
        return 0.0, 0.0, 0.0
    q = transform(T_ab, p)
    z = q[:, 2]
    zs = np.maximum(z, 1e-6)
    uv = np.stack([fa.K[0, 0] * q[:, 0] / zs + fa.K[0, 2], fa.K[1, 1] * q[:, 1] / zs + fa.K[1, 2]], 1)
    zo = sample_depth(fa.depth, uv)
    ins = (z > 0.1) & (zo > 0)
    n = max(int(ins.sum()), 1)
    cons = ins & (np.abs(z - zo) < 0.05 + 0.03 * zo)
    viol = ins & (z < zo - (0.10 + 0.05 * zo))
    return float(ins.mean()), float(cons.sum() / n), float(viol.sum() / n)


def edge_ok(fa: Frame, fb: Frame, T_ab: np.ndarray, max_violation: float) -> bool:
    """The depth check of one edge, both ways: neither frame puts more than `max_violation` of its points into
    space the other sees as empty."""
    return max(depth_consistency(fa, fb, T_ab)[2], depth_consistency(fb, fa, invert(T_ab))[2]) <= max_violation


def reattach(al: AlignmentResult, poses: dict[int, np.ndarray], dropped: list[int], ok: Callable[..., bool]
              ) -> list[int]:
    """Re-attach dropped frames through other pairs alignment verified that pass `ok`; mutates poses."""
    reattached = []
    changed = True
    while changed:
        changed = False
        for (a, b), r in al.edge_stats.items():
            if not r.ok:
                continue
            for x, y, T in ((a, b, r.T_ab), (b, a, invert(r.T_ab))):  # T: pose of y in x's camera
                if x in poses and y not in poses and y in dropped and ok(x, y, T):
                    poses[y] = poses[x] @ T
                    reattached.append(y)
                    changed = True
    return reattached


def verify_tree(al: AlignmentResult, frames: dict[int, Frame], conf: AlignConf, log: StageLog | None = None
                ) -> AlignmentResult:
    """Check every tree edge with `depth_consistency` in both directions; an edge that puts more than
    `max_free_space_violation` of the points into observed free space is cut. The largest part of the cut tree
    stays aligned (the root's part on a tie; else the root moves to the part's frame nearest the old root and
    the poses are re-expressed in it), the other parts are re-attached through other verified pairs (from the
    pairs alignment already tried) that pass the same check, if any; the rest become unaligned. Recorded in the
    trace; the cut edges are kept in `al.rejected_edges` so that a later round does not use them again."""
    def ok(a: int, b: int, T_ab: np.ndarray) -> bool:
        if a not in frames or b not in frames:
            return True  # frames without kept depth are not checked
        return edge_ok(frames[a], frames[b], T_ab, conf.max_free_space_violation)

    poses = dict(al.poses)
    order = _tree_order(al.root, al.edges, poses)
    bad: list[tuple[int, int]] = list(al.rejected_edges)
    part = {al.root: al.root}
    for p, c in order:  # breadth-first from the root: each edge (parent, child) once
        if ok(p, c, invert(poses[p]) @ poses[c]):
            part[c] = part[p]
        else:
            bad.append((p, c))
            part[c] = c  # a new part, headed by the frame nearest the root
    al.rejected_edges = bad
    sizes: dict[int, int] = {}
    for h in part.values():
        sizes[h] = sizes.get(h, 0) + 1
    head = max(sizes, key=lambda h: (sizes[h], h == al.root))  # ties: the root's part, then the nearest
    dropped = [i for i in poses if part.get(i) != head]
    if not dropped:
        return al
    moved = head != al.root
    if moved:  # the root's own part was the smaller: the map keeps the most key frames
        T = invert(poses[head])
        poses = {i: T @ P for i, P in poses.items()}
        al.root = head
        al.rebased = [i for i in poses if i not in dropped]
    for i in dropped:
        poses.pop(i)
    reattached = reattach(al, poses, dropped, ok)
    lost = [i for i in dropped if i not in poses]
    as_trace(log).event("alignment", f"depth check rejected tree edge(s) {bad}: {len(dropped)} frame(s) "
                          f"detached" + (f" (the larger part kept, rooted at frame {head})" if moved else "") +
                          f", {len(reattached)} re-attached through other verified pairs, {len(lost)} left unaligned",
                          stage="alignment", rejected=[list(e) for e in bad], unaligned=lost, root=al.root)
    al.poses = poses
    al.unaligned = sorted(set(al.unaligned) | set(lost))
    return al


def _tree_order(root: int, edges: Sequence[tuple[int, int]], poses: Mapping[int, np.ndarray]) -> list[tuple[int, int]]:
    """The tree's edges (parent, child) in breadth-first order from `root`, over frames with a pose."""
    adj: dict[int, list[int]] = {}
    for a, b in edges:
        adj.setdefault(a, []).append(b)
        adj.setdefault(b, []).append(a)
    seen, queue, out = {root}, deque([root]), []
    while queue:
        p = queue.popleft()
        for c in adj.get(p, []):
            if c not in seen and c in poses:
                seen.add(c)
                out.append((p, c))
                queue.append(c)
    return out
