"""Maps of resolution and ghost level of a deployment over an area (Section 5).

Pure numpy. A deployment (:class:`~fusion_center.topology.ambiguity.NetworkGeometry`) is
assessed at a grid of reference points; at each, the AF gives the 3 dB main-lobe widths along
its principal axes and the worst ghost over the whole area (:func:`assess_point`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from .ambiguity import Band, NetworkGeometry
from .quality import Area, PointQuality, assess_point

__all__ = ["AreaEvaluation", "evaluate_area", "placement_cost", "reference_grid"]

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True, slots=True, kw_only=True, eq=False)
class AreaEvaluation:
    """Resolution and ghost maps over the reference points of an area.

    Attributes
    ----------
    x, y : ndarray, shape (mx,), (my,)
        Reference point coordinates, m.
    widths : ndarray, shape (my, mx, 2)
        3 dB main-lobe widths along the principal axes (wider first), m.
    ghost_db : ndarray, shape (my, mx)
        Worst ghost over the area for each reference point, dB re peak.
    points : list of PointQuality
        The per-point results, row-major.
    """

    x: FloatArray
    y: FloatArray
    widths: FloatArray
    ghost_db: FloatArray
    points: list[PointQuality]

    @property
    def resolution(self) -> FloatArray:
        """Mean main-lobe width per reference point, m, shape (my, mx)."""
        return self.widths.mean(axis=-1)

    @property
    def mean_resolution(self) -> float:
        """Mean main-lobe width over the area, m."""
        return float(self.resolution.mean())

    @property
    def worst_resolution(self) -> float:
        """Largest main-lobe width over the area, m."""
        return float(self.widths.max())

    @property
    def worst_ghost_db(self) -> float:
        """Highest peak-to-ghost level over the area, dB re peak."""
        return float(self.ghost_db.max())

    def summary(self) -> dict[str, float]:
        """The headline numbers (``resolution_m`` = mean main-lobe width, ``ghost_db`` =
        worst ghost), rounded for reports."""
        return {
            "resolution_m": round(self.mean_resolution, 4),
            "worst_width_m": round(self.worst_resolution, 4),
            "ghost_db": round(self.worst_ghost_db, 2),
            "mean_ghost_db": round(float(self.ghost_db.mean()), 2),
        }


def reference_grid(area: Area, mx: int, my: int) -> tuple[FloatArray, FloatArray]:
    """``mx`` by ``my`` reference points at the centres of equal cells of the area, m."""
    x = area.x_min + (area.x_max - area.x_min) * (np.arange(mx) + 0.5) / mx
    y = area.y_min + (area.y_max - area.y_min) * (np.arange(my) + 0.5) / my
    return x, y


def evaluate_area(
    geometry: NetworkGeometry,
    band: Band,
    area: Area,
    references: tuple[int, int] = (8, 6),
    *,
    mainlobe_factor: float = 2.0,
    refine: int = 6,
) -> AreaEvaluation:
    """Resolution and ghost level at a grid of reference points over ``area``.

    Parameters
    ----------
    geometry : NetworkGeometry
    band : Band
    area : Area
        The area and the grid the ghosts are searched on.
    references : (mx, my)
        Reference points along x and y (cell centres).

    Returns
    -------
    AreaEvaluation
    """
    mx, my = references
    if mx < 1 or my < 1:
        raise ValueError("need at least one reference point")
    x, y = reference_grid(area, mx, my)
    pts = [
        assess_point(geometry, band, (xi, yi), area, mainlobe_factor=mainlobe_factor, refine=refine)
        for yi in y
        for xi in x
    ]
    widths = np.array([p.widths for p in pts]).reshape(my, mx, 2)
    ghost = np.array([p.ghost_db for p in pts]).reshape(my, mx)
    return AreaEvaluation(x=x, y=y, widths=widths, ghost_db=ghost, points=pts)


def placement_cost(evaluation: AreaEvaluation, resolution_scale: float = 1.0) -> float:
    """The optimizer's objective: worst ghost (dB) plus resolution in dB of length.

    .. math:: J = \\max_p G(p) + 20 \\log_{10}(\\bar w / w_0)

    so halving the mean main-lobe width is worth as much as lowering the worst ghost by 6 dB
    (both halve an amplitude). ``w_0 = resolution_scale`` (m) only shifts ``J``.
    """
    return evaluation.worst_ghost_db + 20.0 * np.log10(
        max(evaluation.mean_resolution, 1e-9) / resolution_scale
    )
