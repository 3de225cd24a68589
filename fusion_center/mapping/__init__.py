"""UWB SLAM of a bat-type robot: walls, corners and point scatterers (Section 6 of the CoLOR
chapter). Pure numpy; see docs/mapping.md."""

from fusion_center.mapping.features import LandmarkSet, SlamMap, build_map
from fusion_center.mapping.pipeline import EchoSlamMapper, MapperConfig, MapperOutput
from fusion_center.mapping.rbpf import PoseEstimate2D, RbpfSlam, SlamConfig

__all__ = [
    "EchoSlamMapper",
    "LandmarkSet",
    "MapperConfig",
    "MapperOutput",
    "PoseEstimate2D",
    "RbpfSlam",
    "SlamConfig",
    "SlamMap",
    "build_map",
]
