"""Monocular depth adapter and the scale/shift recovery that makes relative depth metric-consistent.

Trace: the graph run is timed as stage ``depth.model`` (pre/post-processing excluded), so that a caller's own
``depth`` stage around `predict` is not double-counted.

`DepthModel.predict(rgb [H, W, 3] uint8) -> [H, W] float32` returns the model's map resized to the input size
with the manifest's semantics (`.semantics`):
- ``metric_m``: z-depth in metres (0 = invalid);
- ``relative``: an unknown affine function of depth, z ~ s * d + t (larger = farther), e.g. PyDNet++;
- ``relative_inverse``: affine in inverse depth (disparity-like, larger = nearer), 1/z ~ s * d + t, e.g.
  Depth-Anything's relative head.

Scale/shift recovery (pure functions; pick by what the caller has):
1. `fit_to_sensor(pred, sensor)`: least squares (s, t) against sensor depth on the pixels where the sensor is
   valid, with two rounds of trimming residuals above 2.5 x MAD. Best available, needs an RGB-D sensor (or a
   sparse one: ToF, LiDAR). Limit: the fit is per frame, so it hides the model's temporal inconsistency.
2. `fit_to_points(pred, uv, z)`: the same fit against sparse metric depths z [N] at pixels uv [N, 2] -- the
   depths of cross-frame matched 3D points (e.g. triangulated, or from an already-metric neighbour frame
   transformed into this camera with the pair's pose). Needs >= 8 well-spread points; with few points prefer
   `shift=False` (scale only).
3. `scale_from_prior(pred, median_m)`: scale-only, so that the median of the map equals a documented prior
   (default 2.0 m, typical for handheld indoor video; or `camera_height_prior` from a floor-plane fit and a
   known camera height). Gives a consistent but not exact scale: errors of +-30-50 % across rooms are
   normal; use only when nothing else exists.
Without any of these, alignment estimates Sim(3) per frame pair (`alignment.py`, with_scale), which chains
relative scales through the pose graph -- the scale then drifts along the chain; ATE is reported after a
Sim(3) trajectory alignment.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..infra.errors import InputError
from . import RoleModel, preprocess_image
from ..geometry import ScaleShift, fit_scale_shift, robust_line_fit, sample_depth
from ..planes import fit_floor_plane

_fit = robust_line_fit  # the names benchmarks import
_fit_pairs = fit_scale_shift

SEMANTICS = ("metric_m", "relative", "relative_inverse")


@dataclass
class DepthConf:
    """output: index of the graph output to use (PyDNet++ has 3 scales; the first is the finest)."""

    output: int = 0
    min_depth_m: float = 0.05   # after metric conversion, smaller values are set invalid (0)
    max_depth_m: float = 20.0


def fit_to_points(pred: np.ndarray, uv: np.ndarray, z: np.ndarray, semantics: str = "relative",
                  shift: bool = True) -> ScaleShift:
    """Fit (s, t) so that pred at pixels uv [N, 2] (x, y) maps to metric depths z [N] (metres, > 0)."""
    _check_semantics(semantics)
    uv = np.asarray(uv, np.float32).reshape(-1, 2)
    z = np.asarray(z, np.float64).reshape(-1)
    d = sample_depth(pred.astype(np.float32), uv).astype(np.float64)
    ok = np.isfinite(d) & np.isfinite(z) & (z > 0)
    return fit_scale_shift(d[ok], z[ok], semantics, shift, "points")


def fit_to_sensor(pred: np.ndarray, sensor: np.ndarray, semantics: str = "relative", shift: bool = True,
                  stride: int = 4, max_depth_m: float = 10.0) -> ScaleShift:
    """Fit (s, t) of pred [H, W] against sensor depth [H', W'] metres (0 = invalid), on a pixel grid."""
    import cv2

    _check_semantics(semantics)
    if sensor.shape != pred.shape:
        pred = cv2.resize(pred.astype(np.float32), (sensor.shape[1], sensor.shape[0]), interpolation=cv2.INTER_LINEAR)
    p = pred[::stride, ::stride].astype(np.float64).ravel()
    z = sensor[::stride, ::stride].astype(np.float64).ravel()
    ok = (z > 0) & (z < max_depth_m) & np.isfinite(p)
    return fit_scale_shift(p[ok], z[ok], semantics, shift, "sensor")


def scale_from_prior(pred: np.ndarray, median_m: float = 2.0, semantics: str = "relative") -> ScaleShift:
    """Scale-only recovery from a scene-depth prior: the median of the valid map becomes `median_m` metres."""
    _check_semantics(semantics)
    v = pred[np.isfinite(pred) & (pred > 0)]
    if v.size == 0:
        raise InputError("depth scale recovery (prior): the map has no positive values")
    med = float(np.median(v))
    if semantics == "relative_inverse":
        return ScaleShift(1.0 / (median_m * med), 0.0, int(v.size), 0.0, semantics, f"prior median {median_m} m")
    return ScaleShift(median_m / med, 0.0, int(v.size), 0.0, "relative", f"prior median {median_m} m")


def camera_height_prior(points: np.ndarray, height_m: float, up_hint: np.ndarray | None = None,
                        iterations: int = 200, threshold: float = 0.02, rng: int = 0,
                        max_tilt_deg: float = 25.8) -> float:
    """Scale factor from a known camera height: the floor plane of camera points [N, 3] (up to scale), found by
    the map's floor fit (`planes.fit_floor_plane`, the one floor RANSAC); returns
    height_m / distance(camera, plane). up_hint [3] (camera frame, e.g. gravity from an IMU, default -y: OpenCV
    cameras look roughly horizontal) selects planes below the camera, within `max_tilt_deg` of horizontal;
    `threshold` is relative to the points' median range (they have no unit yet). Limit: needs visible floor."""
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    if len(pts) < 50:
        raise InputError("camera-height prior: fewer than 50 points")
    up = np.asarray(up_hint if up_hint is not None else [0.0, -1.0, 0.0], np.float64)
    scale_ref = float(np.median(np.linalg.norm(pts, axis=1)))
    fit = fit_floor_plane(pts, -up / np.linalg.norm(up), max_tilt_deg=max_tilt_deg,
                          threshold=threshold * scale_ref, iterations=iterations, rng=rng)
    if fit is None or fit[1] <= 0 or fit[2] < 30:  # d > 0: the plane lies below the camera
        raise InputError("camera-height prior: no floor plane found below the camera")
    return float(height_m / fit[1])


def _check_semantics(semantics: str) -> None:
    if semantics not in SEMANTICS:
        raise InputError(f"depth semantics {semantics!r}: expected one of {SEMANTICS}")


class DepthModel(RoleModel):
    """Single-graph depth model (PyDNet++, Depth-Anything-like): rgb -> [H, W] float32 in `.semantics` units.

    Manifest: preprocessing (size, layout, scale/mean/std), semantics.depth, config.output (output index).
    Output layouts accepted: [1, h, w], [1, h, w, 1], [1, 1, h, w].
    """

    role = "depth"

    def __init__(self, spec, sessions, trace, conf: DepthConf | None = None):
        super().__init__(spec, sessions, trace)
        cfg = {k: v for k, v in spec.config.items() if k in DepthConf.__dataclass_fields__}
        self.conf = conf or DepthConf(**cfg)
        self.semantics: str = spec.semantics.get("depth", "relative")
        _check_semantics(self.semantics)
        sess = self.session()
        self._input = sess.input_names[0]

    def predict_raw(self, rgb: np.ndarray) -> np.ndarray:
        """Model output at the model's resolution, [h, w] float32."""
        x = preprocess_image(rgb, self.spec.preprocessing)
        # "depth.model" (the graph alone), not "depth": callers time their whole depth step as "depth", and
        # a nested stage of the same name was counted twice in the trace's per-stage totals
        with self._stage("depth.model"):
            out = self.session().run({self._input: x})[self.conf.output]
        out = np.asarray(out, np.float32)
        return np.squeeze(out)

    def predict(self, rgb: np.ndarray) -> np.ndarray:
        """rgb [H, W, 3] uint8 -> [H, W] float32 in `.semantics` units (bilinear resize to the input size)."""
        with self._overhead("depth.model"):
            return self._predict(rgb)

    def _predict(self, rgb: np.ndarray) -> np.ndarray:
        import cv2

        d = self.predict_raw(rgb)
        if d.shape != rgb.shape[:2]:
            d = cv2.resize(d, (rgb.shape[1], rgb.shape[0]), interpolation=cv2.INTER_LINEAR)
        if self.semantics == "metric_m":
            d = np.where((d >= self.conf.min_depth_m) & (d <= self.conf.max_depth_m), d, 0.0).astype(np.float32)
        return d

    def predict_metric(self, rgb: np.ndarray, sensor: np.ndarray | None = None,
                       prior_median_m: float = 2.0) -> tuple[np.ndarray, ScaleShift | None]:
        """Metric depth [H, W] float32: as-is for metric models, else fitted to `sensor` when given, else the
        median prior (recorded in the trace as a "degraded" event because its scale is only a guess)."""
        with self._overhead("depth.model"):
            return self._predict_metric(rgb, sensor, prior_median_m)

    def _predict_metric(self, rgb: np.ndarray, sensor: np.ndarray | None, prior_median_m: float
                        ) -> tuple[np.ndarray, ScaleShift | None]:
        pred = self.predict(rgb)
        if self.semantics == "metric_m":
            return pred, None
        if sensor is not None:
            ss = fit_to_sensor(pred, sensor, self.semantics)
        else:
            ss = scale_from_prior(pred, prior_median_m, self.semantics)
            if not getattr(self, "_prior_noted", False):
                self._prior_noted = True
                self.trace.event("degraded", f"{self.name}: relative depth scaled by a prior (median "
                             f"{prior_median_m} m) per frame; the map's metric scale is set afterwards from what it shows "
                             f"(see the scale note)", stage="depth")
        return ss.apply(pred, self.conf.min_depth_m, self.conf.max_depth_m), ss
