"""Topology benchmark: the ambiguity function on a 200 x 200 grid over the band.

``run(seed) -> dict`` (JSON-serialisable figures, times in ms of CPU and wall):

* ``af_200x200_ms_{foyer3,room_pillar}``: the exact AF across the band (closed-form band
  kernel, one value per link and pixel) of one reference point on a 200 x 200 grid over the
  scenario's area; ``links_*`` the links summed, ``Mpix_links_per_s_*`` the throughput;
* ``factors_200x200x64_ms_foyer3``: the per-frequency signal, motion and topology factors on
  the same grid at 64 frequencies (the exact spherical factors);
* ``point_ms_foyer3``: one reference point assessed (3 dB widths along the principal axes and
  the worst ghost over the 200 x 200 grid with refinement);
* ``area_8x6_s_foyer3``: the deployment's maps at 8 x 6 reference points.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np

from fusion_center.topology import Band, assess_point, evaluate_area, factor_maps
from fusion_center.topology import ambiguity as ambiguity_fn
from sim_nodes.scene import load_scenario
from uwbnet.topology_cmd import scenario_area, scenario_band, scenario_geometry

__all__ = ["run"]


def _timed(fn: Callable[[], Any], repeat: int) -> tuple[float, float]:
    """Best CPU and wall time of ``repeat`` calls, ms."""
    cpu, wall = [], []
    for _ in range(repeat):
        c0, w0 = time.process_time(), time.perf_counter()
        fn()
        cpu.append(time.process_time() - c0)
        wall.append(time.perf_counter() - w0)
    return 1e3 * min(cpu), 1e3 * min(wall)


def run(seed: int = 0) -> dict[str, Any]:
    """The figures above; ``seed`` picks the reference point inside the area."""
    rng = np.random.default_rng(seed)
    out: dict[str, Any] = {}
    for name in ("foyer3", "room_pillar"):
        sc = load_scenario(name)
        band, area, net = scenario_band(sc), scenario_area(sc, 200, 200), scenario_geometry(sc)
        ref = np.array(
            [
                rng.uniform(area.x_min + 1, area.x_max - 1),
                rng.uniform(area.y_min + 1, area.y_max - 1),
            ]
        )
        pts = area.points()
        cpu, wall = _timed(lambda: ambiguity_fn(net, band, ref, pts), 3)  # noqa: B023
        out[f"af_200x200_ms_{name}"] = round(cpu, 1)
        out[f"af_200x200_wall_ms_{name}"] = round(wall, 1)
        out[f"links_{name}"] = net.n_links
        out[f"Mpix_links_per_s_{name}"] = round(len(pts) * net.n_links / cpu / 1e3, 1)
        if name == "foyer3":
            freqs = Band(f_low=band.f_low, f_high=band.f_high).frequencies(64)
            cpu, wall = _timed(lambda: factor_maps(net, ref, pts, freqs, far_field=False), 1)  # noqa: B023
            out["factors_200x200x64_ms_foyer3"] = round(cpu, 1)
            cpu, _ = _timed(lambda: assess_point(net, band, ref, area), 3)  # noqa: B023
            out["point_ms_foyer3"] = round(cpu, 1)
            c0, w0 = time.process_time(), time.perf_counter()
            ev = evaluate_area(net, band, area, (8, 6))
            out["area_8x6_s_foyer3"] = round(time.process_time() - c0, 2)
            out["area_8x6_wall_s_foyer3"] = round(time.perf_counter() - w0, 2)
            out.update({f"foyer3_{k}": v for k, v in ev.summary().items()})
    return out
