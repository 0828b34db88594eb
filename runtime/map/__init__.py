"""The sparse global semantic map (paper: iterative construction), one module per job:

model   SemanticMap, ObjectInstance, Room: the map, its JSON schema and checks
conf    FusionConfig: every setting of lifting and fusion
lift    a key frame's detections -> camera-frame points (masks or box depth layers) -> the world
cluster connected components, voxel down-sampling, outlier removal
verify  candidate detections verified across views (kept when another key frame agrees, or confident)
fuse    observations of one object -> one instance with an oriented box
floor   gravity and the floor plane (z up, origin on the floor)
extent  floor-standing objects down to the floor, the room extent, first-seen times
refine  occlusion refinement (re-prompting the segmenter where an instance should be visible)
"""
from .cluster import components, largest_components, remove_outliers, voxel_downsample
from .conf import FusionConfig, default_fusion_conf
from .extent import (band_visibility, extend_to_floor, first_seen_from_detections, floor_decision, floor_support,
                     hull_candidates, room_extent)
from ..planes import fit_floor_plane, sharpen_normal  # the one floor fit, below every stage
from .floor import gravity_from_frames, gravity_world_transform
from .fuse import footprint_overlap, fuse_frames, fuse_observations, same_frame_redundant, view_estimates
from .lift import (box_depth_mask, box_layer, duplicate_names, lift_camera, lift_detections, lift_observations,
                   place, world_points)
from .model import (MAP_SCHEMA, MAX_MAP_BYTES, MAX_MAP_OBJECTS, ObjectInstance, Room, SemanticMap, room_from_boxes,
                    validate_map_dict)
from .refine import expected_visible, refine
from .verify import Verification, VerifyConf, annotate_views, rests_on, verify_observations

__all__ = [
    "components", "largest_components", "remove_outliers", "voxel_downsample", "FusionConfig", "default_fusion_conf",
    "band_visibility", "extend_to_floor", "first_seen_from_detections", "floor_decision", "floor_support",
    "hull_candidates", "room_extent", "fit_floor_plane", "gravity_from_frames", "gravity_world_transform",
    "sharpen_normal", "footprint_overlap", "fuse_frames", "fuse_observations", "same_frame_redundant",
    "view_estimates", "box_depth_mask", "box_layer", "duplicate_names", "lift_camera", "lift_detections",
    "lift_observations", "place",
    "world_points", "MAP_SCHEMA", "MAX_MAP_BYTES", "MAX_MAP_OBJECTS", "ObjectInstance", "Room", "SemanticMap",
    "room_from_boxes", "validate_map_dict", "expected_visible", "refine", "Verification", "VerifyConf",
    "annotate_views", "rests_on", "verify_observations",
]
