"""Ambiguity-function analysis of sensor placement and tracks (Section 5 of the CoLOR chapter).

Pure numpy: the AF of a UWB MIMO network and its signal x topology x motion factorization
(:mod:`.ambiguity`), resolution and ghost level of one reference point (:mod:`.quality`), maps
over an area (:mod:`.evaluate`) and sensor-site selection (:mod:`.optimize`).
"""

from .ambiguity import (
    SPEED_OF_LIGHT,
    Band,
    FactorMaps,
    NetworkGeometry,
    ambiguity,
    factor_maps,
    grid_points,
)
from .evaluate import AreaEvaluation, evaluate_area, placement_cost, reference_grid
from .optimize import (
    GreedyPlacementOptimizer,
    PlacementResult,
    SiteCandidates,
    compose_network,
    even_selection,
)
from .quality import (
    Area,
    PointQuality,
    assess_point,
    ghost_level,
    mainlobe_widths,
    principal_axes,
)

__all__ = [
    "SPEED_OF_LIGHT",
    "Area",
    "AreaEvaluation",
    "Band",
    "FactorMaps",
    "GreedyPlacementOptimizer",
    "NetworkGeometry",
    "PlacementResult",
    "PointQuality",
    "SiteCandidates",
    "ambiguity",
    "assess_point",
    "compose_network",
    "evaluate_area",
    "even_selection",
    "factor_maps",
    "ghost_level",
    "grid_points",
    "mainlobe_widths",
    "placement_cost",
    "principal_axes",
    "reference_grid",
]
