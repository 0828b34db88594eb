"""The configuration of a run (`PipelineConfig`): each stage's own typed config (`dedup`, `keyframe`, `alignment`,
`match`, `fusion`, `verify`, `backbone`) and the settings of the wiring and the map's extras, merged with user
overrides."""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, ClassVar, Mapping

from .align import AlignConf, BackboneConf, MatchConf, SfmConf
from .infra.config import StageConf
from .infra.errors import InputError
from .keyframes import KeyFrameConf
from .map import FusionConfig
from .map.conf import ScaleConf
from .map.verify import VerifyConf
from .scan import DedupConf


# typed stage configs of a run: field -> its class (a mapping given for one is merged over the field's default)
_SUB_CONFS: dict[str, type] = {"dedup": DedupConf, "keyframe": KeyFrameConf, "alignment": AlignConf,
                               "match": MatchConf, "fusion": FusionConfig, "verify": VerifyConf,
                               "backbone": BackboneConf, "scale": ScaleConf, "sfm": SfmConf}


@dataclass
class PipelineConfig(StageConf):
    """One config for a run (`PipelineConfig.merged(mapping_or_conf, **overrides)`, unknown keys are an error):
    the stages' own typed configs (a mapping given for one is merged over its default, unknown keys an error) and
    the settings of the wiring and the map's extras. Why each default is what it is: docs/settings.md."""

    conf_name: ClassVar[str] = "pipeline config"

    depth: str = "auto"                  # auto (sensor when the source has it) | sensor | model
    matcher: str = "sift"                # orb | sift | model
    gravity: str = "auto"                # auto (source if it knows gravity, else floor fit) | source | floor
    refine: bool = True                  # occlusion refinement
    first_seen_from_search: bool = True  # first-seen times also from the frames the search scored
    box_prompt_min_share: float = 0.02   # a mask under this share of its box is replaced by a box-prompted one
    # key-frame detections with an instance segmenter in the bundle (`perceive.keyframe_detector`): "merged",
    # "merged_candidates", "instance_segmenter" (one model, one pass) or "detector" (the segmenter left out)
    keyframe_detections: str = "merged"
    grounding_frames: int = 4            # frames (evenly spaced) shown to a VLM that grounds the question
    # floor-standing furniture seen from above reaches down to the floor unless open space was seen under it
    # (`map.extend_to_floor`: support in >= `floor_band_share` of the 10 cm bands, the lowest included); () = off
    floor_standing: tuple[str, ...] = ("table", "chair", "sofa", "couch", "bed", "bench", "desk", "stool",
                                       "refrigerator", "toilet", "cabinet", "shelf", "bookshelf")
    floor_band_share: float = 0.6
    camera_height_m: float = 1.5         # prior when no floor is found
    floor_fit_max_depth_m: float = 6.0   # the floor plane is fitted on key-frame depth nearer than this
    room_trim_percent: float = 0.5       # room extent: depth points beyond this percentile in any direction dropped
    memory_headroom_mb: float = 50.0     # budget's memory guard: no more key frames below this free memory
    dedup: DedupConf = field(default_factory=DedupConf)
    keyframe: KeyFrameConf = field(default_factory=KeyFrameConf)
    alignment: AlignConf = field(default_factory=AlignConf)
    match: MatchConf = field(default_factory=MatchConf)  # OpenCV matchers (ratio per method when unset)
    fusion: FusionConfig = field(default_factory=FusionConfig)
    verify: VerifyConf = field(default_factory=VerifyConf)  # candidate detections verified across views
    backbone: BackboneConf = field(default_factory=BackboneConf)  # metric depth: odometry between key frames
    scale: ScaleConf = field(default_factory=ScaleConf)  # metric scale of maps from model depth (map/scale.py)
    sfm: SfmConf = field(default_factory=SfmConf)  # relative depth: structure from motion over the kept frames

    def __post_init__(self) -> None:
        for name, cls in _SUB_CONFS.items():
            v = getattr(self, name)
            if isinstance(v, Mapping):
                setattr(self, name, _merge_sub(cls, getattr(type(self)(), name), v))
            elif v is None:
                setattr(self, name, getattr(type(self)(), name))

    def validate(self) -> None:
        for name, allowed in (("depth", ("auto", "sensor", "model")), ("gravity", ("auto", "source", "floor")),
                              ("keyframe_detections", ("merged", "merged_candidates", "instance_segmenter",
                                                       "detector"))):
            if getattr(self, name) not in allowed:
                raise InputError(f"pipeline config: {name} must be one of {', '.join(allowed)} "
                                 f"(got {getattr(self, name)!r})")
        if self.grounding_frames < 1:
            raise InputError("pipeline config: grounding_frames must be >= 1")


def _merge_sub(cls: type, base: Any, upd: Mapping[str, Any]) -> Any:
    """A stage config from the pipeline's default for it and a mapping of overrides (unknown keys named). Not
    `cls.merged`: MatchConf.merged fills the per-method ratio, which must stay unset until the method is known."""
    known = {f.name for f in dataclasses.fields(cls)}
    bad = sorted(set(upd) - known)
    if bad:
        raise InputError(f"{cls.conf_name}: unknown key(s) {bad}; known: {sorted(known)}")
    out = dataclasses.replace(base, **dict(upd))
    out.validate()
    return out


default_conf = PipelineConfig()
