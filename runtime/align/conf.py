"""The alignment stage's settings: pairwise edges, the spanning tree, the depth check and recovery (`AlignConf`),
the odometry backbone (`BackboneConf`); one owner each.
Why each default is what it is (the measurements): docs/settings.md."""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from ..infra.config import StageConf
from ..infra.errors import InputError


@dataclass
class AlignConf(StageConf):
    """Defaults of the alignment stage (`AlignConf.merged(overrides)`, see config.StageConf)."""

    conf_name: ClassVar[str] = "alignment config"

    # --- pairwise RGB-D edges (`pairwise.align_pair`)
    threshold_m: float = 0.05          # RANSAC inlier distance for metric depth (m)
    threshold_rel: float = 0.025       # ... for relative depth: fraction of the median depth
    refine_m: float = 0.02             # final least-squares refit on matches this close (m; 0 = off)
    ransac_iterations: int = 1000
    max_matches: int = 400             # matches with valid depth kept per pair, best scores first (0 = all)
    min_inliers: int = 20              # an edge with fewer inliers fails where nothing checks it afterwards
                                       # (`align_frames` on its own: `mosaic eval pose --path frames`, pose table)
    keyframe_min_inliers: int = 12     # ... in `align_keyframes`, whose tree edges the depth check then verifies
    keyframe_edges: bool = False       # set by `align_keyframes` alone: its edges need `keyframe_min_inliers`
    min_inlier_ratio: float = 0.15     # inliers / matches with depth below this = failed edge (random matches)
    max_match_depth_m: float = 10.0    # matches on depth beyond this are ignored (sensor noise)
    edge_radius: int = 3               # a match's depth must be smooth in a (2r+1)^2 window (0 = off) ...
    edge_rel: float = 0.05             # ... i.e. max - min depth there below this fraction of its depth
    icp: bool = False                  # point-to-plane ICP on metric edges (off: it did not lower ATE)
    icp_iterations: int = 30           # projective ICP converges slowly: 10 stopped ~1 cm short on the kitchen
    icp_stride: int = 4
    icp_max_change: tuple[float, float] = (0.10, 5.0)  # (m, deg) larger ICP corrections are rejected
    icp_min_overlap: float = 0.2       # fraction of b's points paired in a, below = ICP rejected
    ransac_seed: int = 0               # each pair draws from its own stream (seed, frame a, frame b)
    threads: int = 0                   # pairs verified concurrently (0 = CPU count capped at 4); same results
    # --- essential-matrix edges (`essential`), "auto": essential on relative depth, else rgbd
    edge: str = "auto"
    essential_px: float | None = None  # Sampson threshold (px); None = the matcher's `keypoint_px` or 1.0
    essential_method: str = "magsac"   # "magsac" | "accurate" | "ransac" | "magsac-prosac" (OpenCV estimators)
    essential_matches: int = 800       # matches kept for the essential matrix, best scores first (0 = all)
    essential_refine: bool = True      # Sampson-error least squares (Huber) on the inliers
    min_parallax_deg: float = 1.0      # triangulated points with a smaller ray angle do not vote on the scale
    min_scale_points: int = 8          # fewer voting points = failed edge
    scale_mode: str = "graph"          # "chain" | "graph" (scales solved over all verified edges) | "shared"
    # --- the spanning tree (`tree`)
    hsv_bins: tuple[int, int, int] = (16, 8, 4)  # colour histograms of the frame similarity
    verify_top: int = 4                # each frame's top-k similar frames are verified; the tree prefers inliers
    verify_neighbours: int | None = None   # ... plus n time neighbours; None = 1 for essential or narrow rgbd
    verify_top_first: int | None = None    # first round's top-k, widened while a frame stays unconnected;
                                           # None = 2 for rgbd edges, `verify_top` for essential ones
    verify_rank: str = "inliers"       # "inliers": verify every candidate; "matches": rank by matches, lazy
    max_attempts: int | None = None    # cap on pairwise alignments Kruskal tries (None = as many as needed)
    # --- the depth check and recovery of the key frames the tree left out (`verify`, `recover`, `stage`)
    verify_depth: bool = True          # metric depth: tree edges whose depth maps contradict each other are cut
    max_free_space_violation: float = 0.02  # share of a frame's points seen in front of the other's surfaces
    whole_image_fallback: bool = True  # key frames unaligned with matches inside boxes: retry on whole images
    relative_box_matching: bool = False    # relative depth: match inside the boxes in the first tree too
    attach_tries: int = 4              # metric depth: each tries its this many nearest aligned frames in time
    bridge_frames: int = 48            # at most this many extra frames to connect unaligned key frames (0 = off)
    bridge_gap_s: float = 0.25         # bridge frames are placed at least this far apart in time
    bridge_rounds: int = 2             # bridge, check, bridge again around edges the check rejected
    bridge_max_gap_s: float = 10.0     # ... only across gaps up to this long (long chains drift)
    revisit_tries: int = 4             # metric depth, out of every chain's reach: (near, far) pairs alike by
                                       # thumbnail tried per key frame (a place the video shows twice; 0 = off)

    @property
    def edge_min_inliers(self) -> int:
        """The inlier minimum every edge solver applies (`pairwise`, `pnp`, `essential`): `keyframe_min_inliers` for
        the key frames' alignment (`keyframe_edges`), else `min_inliers`; never below the solver's own
        `SOLVER_MIN_POINTS`."""
        return self.keyframe_min_inliers if self.keyframe_edges else self.min_inliers

    def validate(self) -> None:
        if self.min_inliers < 1 or self.keyframe_min_inliers < 1:
            raise InputError(f"alignment config: min_inliers and keyframe_min_inliers must be >= 1 (got "
                             f"{self.min_inliers}, {self.keyframe_min_inliers})")
        if self.bridge_frames < 0 or self.revisit_tries < 0:
            raise InputError("alignment config: bridge_frames and revisit_tries must be >= 0")
        if self.attach_tries < 1:
            raise InputError(f"alignment config: attach_tries must be >= 1 (got {self.attach_tries})")
        if not 0 <= self.max_free_space_violation <= 1:
            raise InputError("alignment config: max_free_space_violation must be in [0, 1]")


# the fewest matches each edge solver can estimate from at all (the math's minimum, not a setting: an edge's minimum
# is `AlignConf.edge_min_inliers`, checked above these): Umeyama (3 points), PnP (6), the essential matrix (the
# 8-point algorithm), and the least-squares refit of a 3D-3D edge on its tight inliers
SOLVER_MIN_POINTS = {"3d-3d": 3, "pnp": 6, "essential": 8, "refit": 6}

# expected error of one edge by method (metres, degrees): the median error of each method against the ground truth
# on adjacent frames of the shared rooms (docs/real-rooms.md, "pairwise edges"); the pose graph's sigmas
EDGE_SIGMA = {"3d-3d": (0.02, 0.6), "pnp": (0.025, 0.6), "essential": (0.06, 1.5)}
ICP_SIGMA = (0.008, 0.3)   # an edge ICP refined (`backbone.icp_refined`), whatever method placed it first


@dataclass
class BackboneConf(StageConf):
    """Defaults of the odometry backbone (`backbone.align_backbone`): metric depth, after the key frames' tree and
    its depth check. `PipelineConfig.backbone`; `BackboneConf.merged(overrides)`."""

    conf_name: ClassVar[str] = "backbone config"

    odometry: bool = True           # off: the paper's recovery alone (`stage.align_rest_metric`: attach, bridges)
    max_frames: int = 160           # frames the walks may load in one alignment (each costs one feature extraction)
    methods: tuple[str, ...] = ("3d-3d", "pnp")  # pairwise edge methods, in order of preference
    # the essential matrix verifies many wrong edges over a baseline: only between neighbouring frames of a walk,
    # as the last resort where neither end has depth enough
    adjacent_essential: bool = True
    pnp_px: float | None = None     # reprojection threshold (px); None: 1.5 x the matcher's keypoint noise
    first_jump: int = 4             # a walk's first jump (grid frames); later jumps follow the last success
    max_jump: int = 4               # ... never more than this many grid frames (the goal itself is tried first)
    loops: bool = True              # verified key-frame pairs beyond the tree join the graph (depth-checked)
    part_revisits: int = 6          # a part the walks could not join: this many of its most alike frame pairs with
                                    # the root's part (by appearance) tried with whole-image edges (0 = off)
    walk_matcher: str = "pipeline"  # the walks' features: "orb" (OpenCV, cheaper) or "pipeline" (the run's matcher)
    walk_keypoints: int = 1000      # ... ORB keypoints per frame
    walk_all: bool = True           # walk between EVERY two key frames next in time, not only between parts: a
                                    # path independent of the tree's long edges, so the graph can outvote a wrong one
    closures: int = 12              # loop closures: pairs of posed frames far apart in the graph but predicted to
                                    # overlap (by their poses and depth) tried as edges (0 = off)
    closure_hops: int = 4           # ... "far apart": more than this many edges between them in the tree
    edge_icp: bool = False          # the walks' edges refined by point-to-plane ICP on the two frames' depth after
                                    # the depth check (`backbone.icp_refined`, AlignConf's icp_* settings). Off: it
                                    # helps one room and hurts two (docs/real-rooms.md, "ICP on the walks")
    graph: bool = True              # refine the poses over every edge (`graph.refine`); off: the spanning tree
    robust: float = 3.0             # the graph's loss scale (in sigmas)

    def validate(self) -> None:
        bad = [m for m in self.methods if m not in EDGE_SIGMA]
        if bad or not self.methods:
            raise InputError(f"backbone config: methods must be a non-empty subset of {sorted(EDGE_SIGMA)}, got "
                             f"{list(self.methods)}")
        if self.walk_matcher not in ("orb", "pipeline"):
            raise InputError(f"backbone config: walk_matcher must be orb or pipeline, got {self.walk_matcher!r}")
        if self.max_frames < 0 or self.first_jump < 1 or self.robust <= 0 or self.part_revisits < 0:
            raise InputError("backbone config: max_frames >= 0, first_jump >= 1, robust > 0 and part_revisits >= 0 "
                             "are required")


@dataclass
class SfmConf(StageConf):
    """Defaults of the RGB-only structure from motion (`sfm`, `rgb_stage.align_rest_sfm`): relative depth, over the
    key frames and the scan's kept frames between them. `PipelineConfig.sfm`; `SfmConf.merged(overrides)`."""

    conf_name: ClassVar[str] = "sfm config"

    sfm_on: bool = True            # off: the essential-matrix tree and bridge rounds (`stage.align_rest_relative`)
    stream_frames: int = 320           # stream frames (key frames always in; the scan's kept frames evenly thinned)
    match_window: int = 3           # each stream frame matched with its next this many (tracks over 3+ views)
    loop_pairs: int = 2             # each loop candidate also matched with its n most alike candidates far in time (0 = off)
    loop_every: int = 4             # loop candidates: the key frames and every n-th stream frame (0: key frames only)
    pair_matches: int = 1000         # matches kept per pair, best scores first
    pair_px: float = 1.5       # a pair's essential-matrix inlier threshold (px)
    min_pair_inliers: int = 30      # fewer verified matches: the pair adds nothing to the tracks
    init_window: int = 8            # a chain's start pair is looked for among this many frames from its start
    init_min_parallax_deg: float = 2.0   # ... with at least this median triangulation angle
    min_tri_parallax_deg: float = 2.0    # a point triangulated with a smaller ray angle is not kept (yet): 1 deg let
                                         # near-biased points in and the scale collapsed along a walk
    max_reproj_px: float = 4.0      # observations off by more after an adjustment are dropped
    register_px: float = 4.0             # PnP RANSAC reprojection threshold (px)
    pnp_iterations: int = 500
    min_pnp_inliers: int = 20       # a registration with fewer PnP inliers is rejected ...
    min_pnp_ratio: float = 0.3      # ... or with a smaller share of its 2D-3D matches
    two_view_points: int = 8        # too few for PnP: the pair's essential matrix, scaled by this many shared points
    max_step_rot_deg: float = 30.0  # ... or rotating more than this per stream step from its neighbour ...
    max_step_depth: float = 1.0     # ... or moving more than this x its median scene depth per stream step
    max_misses: int = 3             # this many rejections in a row end a chain (a new one starts after)
    merge_min_points: int = 20      # chains are joined by a Sim(3) on at least this many shared points ...
    merge_min_share: float = 0.5    # ... this share of them inliers ...
    merge_rel: float = 0.03         # ... within this fraction of the points' spread
    relocalize_rounds: int = 4      # frames outside the largest chain re-tried against its whole map, rounds at most
    local_ba_every: int = 5         # a local adjustment after this many registrations ...
    local_ba_window: int = 12       # ... over the last this many cameras
    local_ba_iterations: int = 10
    ba_iterations: int = 30         # the global adjustment's Levenberg-Marquardt iterations at most
    ba_loss: str = "huber"          # robust loss: "huber" or "linear" (plain least squares)
    ba_scale_px: float = 2.0        # ... its scale (px)
    refine_focal: bool = True       # K from a field-of-view prior: the global adjustments refine the focal length ...
    focal_bounds: tuple[float, float] = (0.67, 1.5)  # ... kept within this factor of the prior's (else the prior, said)
    rng_seed: int = 0               # OpenCV's RANSAC generator, set before matching and mapping (reproducible)
    scale_points: int = 10      # a key frame's depth scale needs this many triangulated points with depth

    def validate(self) -> None:
        if self.match_window < 1 or self.max_misses < 1 or self.min_pnp_inliers < 4:
            raise InputError("sfm config: match_window >= 1, max_misses >= 1 and min_pnp_inliers >= 4 are required")
        if self.ba_loss not in ("linear", "huber"):
            raise InputError(f"sfm config: ba_loss must be huber or linear, got {self.ba_loss!r}")
