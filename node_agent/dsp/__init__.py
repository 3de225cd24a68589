"""Pure numpy DSP of a node: impulse responses -> ranges -> local positions (Section 9).

No I/O, no clocks: time ``t`` is an argument. See :class:`NodeDsp` for the chain.
"""

from .association import RangePairAssociator, pairing_threshold
from .background import ExponentialBackgroundSubtractor
from .cfar import GaussianCfarDetector
from .ellipse import EllipseIntersector, intersect_ellipses, position_covariance
from .geometry import SPEED_OF_LIGHT, RadarParams, SensorGeometry
from .pipeline import DspResult, NodeDsp, NodeDspConfig
from .range_phd import RangeGmPhdFilter

__all__ = [
    "SPEED_OF_LIGHT",
    "DspResult",
    "EllipseIntersector",
    "ExponentialBackgroundSubtractor",
    "GaussianCfarDetector",
    "NodeDsp",
    "NodeDspConfig",
    "RadarParams",
    "RangeGmPhdFilter",
    "RangePairAssociator",
    "SensorGeometry",
    "intersect_ellipses",
    "pairing_threshold",
    "position_covariance",
]
