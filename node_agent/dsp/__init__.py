"""Pure numpy DSP of a node: impulse responses -> ranges -> local positions (Section 9).

No I/O, no clocks: time ``t`` is an argument. See :class:`NodeDsp` for the chain.
"""

from .association import RangePairAssociator, pairing_threshold
from .background import ExponentialBackgroundSubtractor
from .cfar import GaussianCfarDetector
from .ellipse import EllipseIntersector, intersect_ellipses, position_covariance
from .geometry import SPEED_OF_LIGHT, RadarParams, SensorGeometry
from .nlos import DEFAULT_CLASSIFIER, LogisticNlosClassifier, channel_features
from .pipeline import DspResult, NodeDsp, NodeDspConfig
from .range_phd import RangeGmPhdFilter
from .ranging import FirstPathRanger, RangingResult
from .toa import (
    AdaptiveThresholdToaEstimator,
    MpdToaEstimator,
    PeakToaEstimator,
    ThresholdToaEstimator,
    ToaEstimate,
    ToaEstimator,
    make_toa_estimator,
)

__all__ = [
    "DEFAULT_CLASSIFIER",
    "SPEED_OF_LIGHT",
    "AdaptiveThresholdToaEstimator",
    "DspResult",
    "EllipseIntersector",
    "ExponentialBackgroundSubtractor",
    "FirstPathRanger",
    "GaussianCfarDetector",
    "LogisticNlosClassifier",
    "MpdToaEstimator",
    "NodeDsp",
    "NodeDspConfig",
    "PeakToaEstimator",
    "RadarParams",
    "RangeGmPhdFilter",
    "RangePairAssociator",
    "RangingResult",
    "SensorGeometry",
    "ThresholdToaEstimator",
    "ToaEstimate",
    "ToaEstimator",
    "channel_features",
    "intersect_ellipses",
    "make_toa_estimator",
    "pairing_threshold",
    "position_covariance",
]
