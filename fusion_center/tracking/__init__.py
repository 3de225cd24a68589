"""Multi-target tracking at the fusion center: pure numpy, time as an argument."""

from .base import (
    SensorScan,
    Tracker,
    TrackerOutput,
    TrackEstimate,
    constant_velocity_model,
    in_field_of_view,
)
from .fused_image import FusedImageConfig, FusedImageTracker
from .gmphd import GmPhdConfig, GmPhdTracker, merge_components
from .metrics import evaluate, gospa, ospa

__all__ = [
    "FusedImageConfig",
    "FusedImageTracker",
    "GmPhdConfig",
    "GmPhdTracker",
    "SensorScan",
    "TrackEstimate",
    "Tracker",
    "TrackerOutput",
    "constant_velocity_model",
    "evaluate",
    "gospa",
    "in_field_of_view",
    "merge_components",
    "ospa",
]
