"""Propagation channel: wall geometry, image-method paths, people as scatterers (pure numpy).

This first version is the deterministic part of the later hybrid channel: specular wall
reflections (image method, up to order 2), through-wall loss, and people as extended,
fluctuating, mutually shadowing point-scatterer clusters.
"""

from sim_nodes.channel.geometry import (
    Walls,
    antenna_gain,
    mirror,
    segment_intersection,
    segment_point_distance,
    wall_crossings,
    wall_side,
)
from sim_nodes.channel.paths import Antennas, image_paths, scatter_paths
from sim_nodes.channel.people import BodyScatterers, Crowd, Fluctuation, Walker, make_walker

__all__ = [
    "Antennas",
    "BodyScatterers",
    "Crowd",
    "Fluctuation",
    "Walker",
    "Walls",
    "antenna_gain",
    "image_paths",
    "make_walker",
    "mirror",
    "scatter_paths",
    "segment_intersection",
    "segment_point_distance",
    "wall_crossings",
    "wall_side",
]
