"""Images that improve as impulse responses arrive (the live fusion center's imaging).

Both images of :mod:`~fusion_center.imaging.migration` are sums over observations, so a batch
of new observations is migrated and added to the running image: after all batches the image
equals the offline one of the same observations. Cross-correlated imaging pairs receivers
within a batch (rows of one emission arrive in one ``ir`` message or in one TDMA frame).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from fusion_center.imaging.migration import (
    Grid,
    Map,
    Observations,
    cross_correlated_image,
    default_references,
    kirchhoff_image,
)

METHODS = ("kirchhoff", "xcorr")


@dataclass(frozen=True, slots=True, kw_only=True)
class ImagingConfig:
    """How the running image is formed (see :func:`kirchhoff_image` for the parameters)."""

    method: str = "kirchhoff"
    envelope: bool = True
    gate: float = 0.3
    pattern: bool = False

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise ValueError(f"unknown imaging method {self.method!r} ({', '.join(METHODS)})")


class IncrementalImager:
    """The running sum of eq. (17) or eq. (18) over all observations added so far."""

    def __init__(self, grid: Grid, config: ImagingConfig | None = None) -> None:
        self.grid = grid
        self.config = config or ImagingConfig()
        self.image: npt.NDArray[np.float32] = np.zeros((grid.ny, grid.nx), np.float32)
        #: Observations migrated and observations skipped (xcorr rows without a reference).
        self.added = 0
        self.skipped = 0

    def add(self, obs: Observations, map_fn: Map | None = None) -> None:
        """Migrate ``obs`` and add it to :attr:`image`."""
        if len(obs) == 0:
            return
        cfg = self.config
        kw = {"envelope": cfg.envelope, "gate": cfg.gate, "pattern": cfg.pattern}
        if cfg.method == "kirchhoff":
            self.image += kirchhoff_image(obs, self.grid, map_fn=map_fn, **kw)
            self.added += len(obs)
            return
        ref = default_references(obs)
        n_ref = int(np.sum(ref >= 0))
        self.skipped += len(obs) - n_ref
        if n_ref:
            self.image += cross_correlated_image(
                obs, self.grid, references=ref, map_fn=map_fn, **kw
            )
            self.added += n_ref
