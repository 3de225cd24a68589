"""Cooperative localization of mobile nodes against anchors (Section 4 of the CoLOR chapter).

Pure numpy: snapshot estimators (:mod:`.estimators`), the eq. (6) NLOS test (:mod:`.nlos`),
Kalman filters (:mod:`.kalman`), Cramér-Rao bounds (:mod:`.crlb`) and the per-node
localizer that combines them (:mod:`.mobile`).
"""

from .crlb import (
    multipath_delay_bound,
    position_crlb,
    position_error_bound,
    range_crlb,
    rms_bandwidth,
)
from .estimators import (
    LOCATORS,
    ApproximateMlLocator,
    LinearLeastSquaresLocator,
    Locator,
    PositionFix,
    TaylorSeriesLocator,
)
from .kalman import PositionKalmanTracker, RangeKalmanTracker
from .mobile import LocalizerConfig, PoseResult, RangingLocalizer
from .nlos import EvidenceNlosTest, MseNlosTest

__all__ = [
    "LOCATORS",
    "ApproximateMlLocator",
    "EvidenceNlosTest",
    "LinearLeastSquaresLocator",
    "LocalizerConfig",
    "Locator",
    "MseNlosTest",
    "PoseResult",
    "PositionFix",
    "PositionKalmanTracker",
    "RangeKalmanTracker",
    "RangingLocalizer",
    "TaylorSeriesLocator",
    "multipath_delay_bound",
    "position_crlb",
    "position_error_bound",
    "range_crlb",
    "rms_bandwidth",
]
