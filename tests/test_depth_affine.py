"""Per-frame affine fit of relative depth to triangulated essential-edge points (`essential_depth_affine`)."""
import numpy as np

from mosaicthinker.runtime.alignment import PairResult, essential_depth_affine


def _scene(s_true: float, t_true: float, sigma: float):
    """Frame 0 (root) and frame 1, centres 0.4 apart; frame 1's relative depth d = (z - t) / s / sigma, with
    pose scale sigma (global units per unit of its depth): the fit must give z / sigma (frame 1's units)."""
    rng = np.random.default_rng(0)
    H, W = 240, 320
    v, u = np.mgrid[0:H, 0:W]
    z1 = 1.0 + 3.0 * u / W + 0.5 * v / H                        # true depth in frame 1, global units
    d1 = ((z1 - t_true) / s_true) / sigma                       # relative depth, frame 1's units
    uv = np.stack([rng.uniform(5, W - 5, 200), rng.uniform(5, H - 5, 200)], 1)
    zt = z1[np.round(uv[:, 1]).astype(int), np.round(uv[:, 0]).astype(int)]
    base = 0.4                                                  # camera centres 0.4 apart
    P0, P1 = np.eye(4), np.eye(4)
    P1[:3, :3] *= sigma
    P1[:3, 3] = [base, 0, 0]
    tri = (uv, zt / base, uv, zt / base)                       # z at unit baseline (frame 0's side unused)
    # the edge's baseline in each frame's depth units: 0.4 in frame 0's (global), 0.4 / sigma in frame 1's
    r = PairResult(np.eye(4), True, 200, 200, 200, 0.0, 0.0, scale_a=base, scale_b=base / sigma, tri=tri)
    return {0: P0, 1: P1}, {(0, 1): r}, d1, z1


def test_affine_recovers_scale_and_shift():
    poses, edges, d1, z1 = _scene(s_true=0.5, t_true=0.8, sigma=2.0)
    fits = essential_depth_affine(poses, edges, {1: d1})
    z_fit = fits[1].apply(d1) * 2.0                             # back to global units through the pose scale
    assert np.median(np.abs(z_fit - z1) / z1) < 1e-3
    # a scale-only fit of the same data is off at the near and far ends (the shift is real)
    s_only = float(np.median(z1 / (d1 * 2.0)))
    assert np.median(np.abs(s_only * d1 * 2.0 - z1) / z1) > 0.05


def test_too_few_points_left_out():
    poses, edges, d1, _ = _scene(0.5, 0.8, 1.0)
    r = edges[(0, 1)]
    r.tri = tuple(a[:10] for a in r.tri)
    assert essential_depth_affine(poses, edges, {1: d1}) == {}
