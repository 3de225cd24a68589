"""Multistatic imaging (Section 8 of the CoLOR chapter), pure numpy.

* :mod:`~fusion_center.imaging.migration`: Kirchhoff migration (eq. (17)) and
  cross-correlated imaging (eq. (18)) for any mix of static and moving Tx/Rx;
* :mod:`~fusion_center.imaging.incremental`: the same, accumulated as impulse responses arrive;
* :mod:`~fusion_center.imaging.quality`: peak position errors and an artefact measure;
* :mod:`~fusion_center.imaging.stationary`: time-shift and accumulation (eq. (19)) and the
  matched-filter detector (eq. (21)-(22)) of stationary targets (Section 8.2).

The moving-target image of Section 9.1 (eq. (23)) is
:class:`fusion_center.tracking.fused_image.FusedImageTracker`.
"""

from fusion_center.imaging.migration import (
    Grid,
    Observations,
    cross_correlated_image,
    default_references,
    kirchhoff_image,
    prepare_signals,
)

__all__ = [
    "Grid",
    "Observations",
    "cross_correlated_image",
    "default_references",
    "kirchhoff_image",
    "prepare_signals",
]
