"""Alignment of the key frames (paper: cross-frame and multi-frame alignment), one module per job:

conf      AlignConf: every setting of the stage
matching  feature matchers (OpenCV ORB/SIFT, the bundle's model) behind one `KeyedMatcher` protocol
pairwise  RGB-D edges: matches lifted to 3D, RANSAC SE(3) / Sim(3)
essential essential-matrix edges for relative depth, per-frame scales solved over the graph
tree      frame similarity, maximum spanning tree, poses composed to the root (`align_frames`)
verify    the depth check of tree edges
recover   whole-image edges, bridge frames, revisits; what placed each key frame (`Fates`)
pnp       sensor-depth edges that need depth at one end only: 3D-3D, then PnP, then the essential matrix
odometry  walks between two key frames over the scan's kept frames
graph     pose-graph edges, spanning-tree composition, robust (Cauchy) refinement
backbone  after the tree's depth check: walks, place revisits, loop closures, one pose graph (`BackboneConf`)
sfm       RGB only: tracks, two-view start, PnP registration with jump rejection, triangulation (`SfmConf`)
bundle_adjust  cameras and points by scipy least squares (sparse Jacobian, robust loss)
rgb_stage relative depth: key frames posed by SfM over the scan's kept frames (`align_keyframes_sfm`)
stage     `align_keyframes`: the stage as `build_map` runs it
"""
from .backbone import align_backbone, align_rest_backbone, tiny_descriptor
from .conf import EDGE_SIGMA, AlignConf, BackboneConf, SfmConf
from .essential import align_pair_essential, essential_edge, essential_frame_scales, essential_pose, refine_essential
from .matching import FeatureMatcher, KeyedMatcher, MatchConf, Matcher, Matches, make_matcher
from .graph import Edge, GraphReport, rigid_part, spanning_poses
from .odometry import OrbWalker, Walk, walk
from .pnp import EdgeResult, essential_metric_pair, pnp_pair, rgbd_edge
from .pairwise import PairResult, align_pair, depth_smooth, depth_valid, pose_change
from .recover import (BlockPairs, Fates, attach_frames, bridge_attach, bridge_chain, bridge_realign, chain_jumps,
                      revisit_attach, revisit_pairs, thumb_histograms)
from .rgb_stage import align_keyframes_sfm
from .stage import align_keyframes, align_rest_metric, align_rest_relative
from .tree import (AlignmentResult, align_frames, candidate_pairs, choose_root, color_histograms, compose_tree,
                   maximum_spanning_tree, refine_with_inliers, root_in_largest, similarity_matrix)
from .verify import depth_consistency, edge_ok, verify_tree

__all__ = [
    "align_backbone", "align_rest_backbone", "tiny_descriptor", "EDGE_SIGMA", "BackboneConf", "Edge", "GraphReport",
    "rigid_part", "spanning_poses", "OrbWalker", "Walk", "walk", "EdgeResult", "essential_metric_pair", "pnp_pair",
    "rgbd_edge", "AlignConf", "align_pair_essential", "essential_edge", "essential_frame_scales", "essential_pose",
    "refine_essential", "FeatureMatcher", "KeyedMatcher", "MatchConf", "Matcher", "Matches", "make_matcher",
    "PairResult", "align_pair", "depth_smooth", "depth_valid", "pose_change", "BlockPairs", "Fates",
    "attach_frames", "bridge_attach", "bridge_chain", "bridge_realign", "chain_jumps", "revisit_attach",
    "revisit_pairs", "thumb_histograms", "align_keyframes", "align_rest_metric", "align_rest_relative",
    "AlignmentResult", "align_frames", "candidate_pairs", "choose_root", "color_histograms", "compose_tree",
    "maximum_spanning_tree", "refine_with_inliers", "root_in_largest", "similarity_matrix", "depth_consistency",
    "edge_ok", "verify_tree", "SfmConf", "align_keyframes_sfm",
]
