"""One piece of furniture detected under two names (a sofa's seat also called a chair) is fused into one instance,
the reason traced; objects on it, beside it or pushed under it stay their own (`map.fuse.named_twice`)."""
from __future__ import annotations

import numpy as np

from mosaicthinker.runtime.infra.trace import StageLog
from mosaicthinker.runtime.map.conf import FusionConfig
from mosaicthinker.runtime.map.fuse import fuse_observations, named_twice
from mosaicthinker.runtime.types import Observation


def _block(g: np.random.Generator, lo: tuple[float, float, float], hi: tuple[float, float, float],
           n: int = 1500) -> np.ndarray:
    """Points on the surface-ish volume of an axis-aligned block (z up), 1 cm noise."""
    p = g.uniform(lo, hi, (n, 3))
    return p + g.normal(0, 0.01, p.shape)


def _obs(name: str, frame: int, pts: np.ndarray, box2d: tuple[float, ...], score: float = 0.8) -> Observation:
    return Observation(name, score, frame, float(frame), pts.astype(np.float32), np.asarray(box2d, np.float32))


def _sofa(g: np.random.Generator) -> np.ndarray:
    return _block(g, (0.0, 0.0, 0.0), (2.0, 0.9, 0.85))


def test_a_sofa_seat_also_called_chair_is_one_sofa():
    g = np.random.default_rng(0)
    sofa_2d = (100, 100, 500, 300)
    obs = [_obs("sofa", f, _sofa(g), sofa_2d) for f in range(4)]
    seat = _block(g, (0.1, 0.05, 0.0), (0.8, 0.85, 0.8), 600)  # the left seat and its back
    obs += [_obs("chair", f, seat, (110, 120, 280, 300), 0.5) for f in (1, 2, 3)]
    # later frames show it again, the detector calling it a chair only (no sofa box there to compare with)
    obs += [_obs("chair", f, seat, (300, 120, 480, 300), 0.5) for f in (5, 6, 7, 8)]
    log = StageLog()
    inst, _ = fuse_observations(obs, FusionConfig(), log)
    assert sorted(o.name for o in inst) == ["sofa"]
    ev = [e for e in log.events if e.get("named_twice")]
    assert ev and "chair" in ev[0]["message"] and "kept as sofa" in ev[0]["message"]
    off, _ = fuse_observations(obs, FusionConfig(named_twice_inside=0.0), StageLog())
    assert sorted(o.name for o in off) == ["chair", "sofa"]  # the rule, not something else, joined them


def test_objects_on_beside_or_under_another_stay():
    g = np.random.default_rng(1)
    sofa = _sofa(g)
    frames = {f: np.array([100, 100, 500, 300.0]) for f in range(4)}
    inner = {f: np.array([150, 120, 250, 200.0]) for f in range(4)}
    cushion = _block(g, (0.2, 0.1, 0.45), (0.6, 0.3, 0.8), 300)  # lies on the seat: not on the floor
    assert named_twice(("pillow", cushion, inner), ("sofa", sofa, frames), 0.8) is None
    beside = _block(g, (2.3, 0.0, 0.0), (2.8, 0.5, 0.9), 500)  # a chair next to the sofa
    assert named_twice(("chair", beside, inner), ("sofa", sofa, frames), 0.8) is None
    table = _block(g, (0.0, 0.0, 0.7), (1.6, 0.8, 0.75), 1200)
    table = np.concatenate([table, _block(g, (0.0, 0.0, 0.0), (0.05, 0.05, 0.75), 100),
                            _block(g, (1.55, 0.75, 0.0), (1.6, 0.8, 0.75), 100)])
    tucked = _block(g, (0.5, 0.3, 0.0), (1.0, 0.75, 0.95), 600)  # its back rises above the table top
    assert named_twice(("chair", tucked, inner), ("table", table, frames), 0.8) is None
    seat = _block(g, (0.1, 0.05, 0.0), (0.8, 0.85, 0.8), 600)
    assert named_twice(("chair", seat, inner), ("sofa", sofa, frames), 0.8) is not None
    # an oven built into a run of cabinets: inside it, on the floor, under its top, but a small part of it
    cabinets = _block(g, (0.0, 0.0, 0.0), (3.6, 0.6, 0.9), 3000)
    oven = _block(g, (1.5, 0.05, 0.1), (2.1, 0.55, 0.8), 400)
    assert named_twice(("oven", oven, inner), ("cabinet", cabinets, frames), 0.8) is None
    # seen apart: never in the same frames as the sofa, so two objects whatever the boxes say
    apart = {f + 10: b for f, b in inner.items()}
    assert named_twice(("chair", seat, apart), ("sofa", sofa, frames), 0.8) is None
    # in the same frames but elsewhere in the image
    elsewhere = {f: np.array([520, 100, 600, 300.0]) for f in range(4)}
    assert named_twice(("chair", seat, elsewhere), ("sofa", sofa, frames), 0.8) is None
