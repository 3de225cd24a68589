"""Simulated sensor nodes: the stand-in for the M-sequence UWB radar hardware.

* :mod:`sim_nodes.scene`: scenario TOML files (pydantic), ``load_scenario(name_or_path)``.
* :mod:`sim_nodes.radar`: ``MSequenceRadar``: MLBS, system pulse, thermal noise, sampling.
* :mod:`sim_nodes.channel`: walls and image-method paths, people as scatterer clusters.
* :mod:`sim_nodes.network`: ``SimNetwork(scenario, seed)``: ``node_infos()``, ``schedule()``,
  ``acquire(node, t)``, ``truth(t)``.

All of it is pure numpy without I/O or clocks; the simulated driver wraps it.
"""
