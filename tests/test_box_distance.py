"""Box-to-box closest points without scipy (the question path's distance): checked against an optimality
certificate, not against another solver. For disjoint convex sets the closest pair (p, q) is optimal exactly when
the plane through p orthogonal to q - p has all of box a on one side and all of box b beyond the parallel plane
through q; overlapping boxes must share the returned point."""
from __future__ import annotations

import subprocess
import sys

import numpy as np

from mosaicthinker.runtime.geometry import OrientedBox, box_closest_points, rotation_about


def _random_box(rng: np.random.Generator) -> OrientedBox:
    lengths = rng.uniform(0.0, 2.0, 3)
    lengths[rng.random(3) < 0.15] = 0.0  # flat and degenerate boxes too
    return OrientedBox(rng.uniform(-2, 2, 3), lengths, rotation_about(rng.normal(size=3), rng.uniform(0, 2 * np.pi)))


def test_closest_points_are_certified_optimal():
    rng = np.random.default_rng(7)
    n_apart = 0
    for _ in range(1500):
        a, b = _random_box(rng), _random_box(rng)
        d, p, q = box_closest_points(a, b)
        assert a.contains(p[None], 1e-7)[0] and b.contains(q[None], 1e-7)[0]
        assert abs(np.linalg.norm(p - q) - d) < 1e-9
        if d > 1e-9:
            n_apart += 1
            n = (q - p) / d
            assert (a.corners() @ n).max() <= p @ n + 1e-7  # a lies behind p's plane
            assert (b.corners() @ n).min() >= q @ n - 1e-7  # b lies beyond q's plane
    assert n_apart > 500  # both cases exercised


def test_parallel_faces_and_crossing_boxes():
    a = OrientedBox(np.zeros(3), np.array([2.0, 2.0, 2.0]), np.eye(3))
    above = OrientedBox(np.array([0.3, -0.2, 3.0]), np.array([1.0, 1.0, 1.0]), np.eye(3))
    assert box_closest_points(a, above)[0] == 1.5  # face to face
    bar = OrientedBox(np.zeros(3), np.array([10.0, 0.2, 0.2]), rotation_about([0, 0, 1], 0.3).T)  # no corner inside
    d, p, q = box_closest_points(a, bar)
    assert d == 0.0 and a.contains(p[None], 1e-9)[0] and bar.contains(p[None], 1e-9)[0]


def test_a_distance_question_imports_no_scipy(tmp_path):
    from mosaicthinker.runtime.map import ObjectInstance, SemanticMap

    m = tmp_path / "m.json"
    SemanticMap([ObjectInstance(0, "chair", OrientedBox(np.zeros(3), np.ones(3), np.eye(3))),
                 ObjectInstance(1, "table", OrientedBox(np.array([3.0, 0, 0]), np.ones(3), np.eye(3)))],
                None, [(0.0, np.eye(4))], {}).save(m)
    code = (f"import sys; from mosaicthinker.runtime import pipeline; "
            f"r = pipeline.ask({str(m)!r}, 'What is the distance between the chair and the table (in meters)?', "
            f"request=pipeline.AskRequest(render_image=False)); "
            f"print(r.answer.text, any(k.split('.')[0] == 'scipy' for k in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["2.0", "False"]
