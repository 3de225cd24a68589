"""Propagation channel (pure numpy).

Two static-channel models and the people:

* ``image2d`` (:mod:`~sim_nodes.channel.paths`, :mod:`~sim_nodes.channel.geometry`): vertical
  walls, specular reflections up to order 2 with scalar reflection factors, through-wall loss;
* ``hybrid`` (Section 3 of the CoLOR chapter): 3-D ray tracing in a :class:`Room`
  (:mod:`~sim_nodes.channel.raytrace`: image method to order 5, Fresnel reflection,
  transmission, wedge diffraction, antenna patterns) plus the stochastic scatterer clusters
  of eq. (1)-(3) (:mod:`~sim_nodes.channel.hybrid`), synthesised on any frequency grid
  (:mod:`~sim_nodes.channel.synth`) and analysed by :mod:`~sim_nodes.channel.params`;
* people as extended, fluctuating, mutually shadowing point-scatterer clusters
  (:mod:`~sim_nodes.channel.people`).
"""

from sim_nodes.channel.antenna import HornPattern, OmniPattern, TablePattern
from sim_nodes.channel.geometry import (
    Walls,
    antenna_gain,
    mirror,
    segment_intersection,
    segment_point_distance,
    wall_crossings,
    wall_side,
)
from sim_nodes.channel.hybrid import HybridChannel, HybridConfig
from sim_nodes.channel.materials import Material
from sim_nodes.channel.paths import Antennas, image_paths, scatter_paths
from sim_nodes.channel.people import BodyScatterers, Crowd, Fluctuation, Walker, make_walker
from sim_nodes.channel.raytrace import AntennaArray, PathSet, trace
from sim_nodes.channel.room import Room
from sim_nodes.channel.synth import frequency_response, impulse_response

__all__ = [
    "AntennaArray",
    "Antennas",
    "BodyScatterers",
    "Crowd",
    "Fluctuation",
    "HornPattern",
    "HybridChannel",
    "HybridConfig",
    "Material",
    "OmniPattern",
    "PathSet",
    "Room",
    "TablePattern",
    "Walker",
    "Walls",
    "antenna_gain",
    "frequency_response",
    "image_paths",
    "impulse_response",
    "make_walker",
    "mirror",
    "scatter_paths",
    "segment_intersection",
    "segment_point_distance",
    "trace",
    "wall_crossings",
    "wall_side",
]
