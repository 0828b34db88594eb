"""The map stage's settings: lifting detections to points and fusing them into instances, and the metric scale
of maps built without a depth sensor (one owner)."""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from ..infra.config import StageConf
from ..infra.errors import InputError


@dataclass
class FusionConfig(StageConf):
    """Defaults chosen for metric indoor depth; all overridable (`FusionConfig.merged(mapping_or_conf,
    **overrides)`: unknown keys are an error)."""

    conf_name: ClassVar[str] = "fusion config"

    pixel_stride: int = 2               # pixel stride when lifting masks (speed; masks are dense)
    erode_px: int = 2             # shrink masks so depth edges (object/background) do not bleed in
    max_depth_m: float = 8.0      # ignore far, noisy depth
    min_points: int = 25          # an observation with fewer 3D points is dropped
    max_points: int = 4000        # per observation, random subsample (memory bound)
    voxel_m: float = 0.04         # instance point clouds are voxel-downsampled at this size
    merge_radius_m: float = 0.12  # a point "overlaps" an instance if an instance point is this close
    merge_overlap: float = 0.2    # ... and this share of the observation's points overlaps
    merge_centre_m: float = 0.6   # or the centres are this close relative to the instance's size (see below)
    outlier_mad: float = 6.0      # radial outlier removal: keep points within median + k * MAD of the centre
    outlier_radius_m: float = 0.1  # density outlier removal: >= outlier_neighbors other points within this
    outlier_neighbors: int = 2
    component_link_m: float = 0.05  # per observation: keep its largest connected part (0 = off) ...
    component_share: float = 0.5    # ... and parts with at least this share of its points
    merge_footprint: bool = True  # after fusion, merge same-name instances whose floor footprints overlap
    min_instance_points: int = 40
    duplicate_iou: float = 0.7    # one frame's boxes of two names this alike are one object named twice (0 = off)
    same_frame_share: float = 0.5  # one frame's same-name box whose points lie on another's: group/duplicate (0 = off)
    subsample_seed: int = 0  # the stream of each frame's point subsampling (seed + frame)
    named_twice_inside: float = 0.8  # an instance this much inside another name's box, seen with it: one object (0 = off)
    anchor: bool = True           # relative depth + triangulated points: each detection scaled to its own points
    anchor_cell_px: int = 4       # ... map points count as inside a detection in its footprint's cells of this size
    anchor_min_points: int = 5    # ... fewer agreeing points: the frame's depth factor stays
    anchor_inlier_log: float = 0.15  # ... points this far (log depth ratio) from their median are not on it

    def validate(self) -> None:
        if self.pixel_stride < 1 or self.erode_px < 0 or self.min_points < 1 or self.max_points < self.min_points:
            raise InputError(f"fusion config: need pixel_stride >= 1, erode_px >= 0, 1 <= min_points <= max_points "
                             f"(got {self.pixel_stride}, {self.erode_px}, {self.min_points}, {self.max_points})")
        for name in ("max_depth_m", "voxel_m", "merge_radius_m", "merge_centre_m", "outlier_mad", "outlier_radius_m"):
            if getattr(self, name) <= 0:
                raise InputError(f"fusion config: {name} must be > 0 (got {getattr(self, name)})")
        if not 0 <= self.merge_overlap <= 1:
            raise InputError(f"fusion config: merge_overlap must be in [0, 1] (got {self.merge_overlap})")


default_fusion_conf = FusionConfig()


@dataclass
class ScaleConf(StageConf):
    """Metric scale of a map built without a depth sensor (`map.scale.estimate_scale`). Priors fixed before any
    evaluation room was looked at: the camera height from the literature range of hand-held / head-worn cameras
    (standing adults' eye height 1.5-1.75 m, phones held at chest-to-eye height: about 1.1-1.7 m), the object
    sizes from VSI-Bench's ARKitScenes boxes (`size_priors.json`). Heights and bins are in rough metres: the map
    is first normalised so that its median point depth is `rough_depth_m` (only thresholds depend on it)."""

    conf_name: ClassVar[str] = "scale config"

    apply: bool = True               # rescale a map built from model depth by the estimate (False: state it only)
    height_prior_m: float = 1.40    # median camera height above the floor (hand-held / head-worn)
    height_prior_sd: float = 0.11   # its spread, log units (1.1-1.7 m is about +-2 sd)
    floor_sd: float = 0.05           # the floor layer's own height error, log units of the camera height
    object_meas_sd: float = 0.20     # a fused box's size error (partial views, mask bleed), log units
    max_prior_sd: float = 0.35       # box dimensions whose category spread is wider than this are not used
    objects_min_sd: float = 0.15     # floor of the object cue's sd: one room's boxes share their bias (partial views
                                     # behind furniture, mask bleed), which does not average out over its objects
    stated_z: float = 1.645          # the answer's +-% is this many sd (1.645: a 90 % range)
    depth_model_sd: float = 0.10     # a metric depth model's scale error per room, log units
    reject_k: float = 2.5            # a vote this many sd from the weighted median is an outlier
    rough_depth_m: float = 2.0       # the normalisation's median depth (thresholds only)
    floor_bin_m: float = 0.04        # height layers of the floor search
    floor_min_share: float = 0.01    # a floor layer holds >= this share of the points (and >= floor_min_points)
    floor_min_points: int = 30
    floor_peak_ratio: float = 2.0    # ... and >= this x the median layer within +-0.3 m (a surface, not a wall)
    floor_clearance_m: float = 0.5   # the floor lies this far below the 90th-percentile camera height
    fallback_median_m: float = 2.0   # no cue: the old prior (median depth), said as a guess
    min_sparse_points: int = 500     # triangulated points enough to fit the floor to (else the depth model's)

    def validate(self) -> None:
        for name in ("height_prior_m", "height_prior_sd", "object_meas_sd", "max_prior_sd", "depth_model_sd", "stated_z",
                     "reject_k", "rough_depth_m", "floor_bin_m", "fallback_median_m"):
            if getattr(self, name) <= 0:
                raise InputError(f"scale config: {name} must be > 0 (got {getattr(self, name)})")
        if not 0 <= self.floor_min_share < 1:
            raise InputError(f"scale config: floor_min_share must be in [0, 1) (got {self.floor_min_share})")


default_scale_conf = ScaleConf()
