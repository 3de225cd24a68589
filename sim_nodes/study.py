"""The chapter's channel-model study (Section 3, Fig. 12) on a scenario: a table of figures.

The transmitter stands at the robot's first stop and omnidirectional receivers at the other
stops (``office.toml``). The deterministic paths are traced once (up to the scenario's
reflection order); every row then adds one realization of the scatterer clusters with its
own (a, p, N, scatter order) and reports, averaged over the receivers and realizations:
received power (band-averaged ``|H c / 4 pi f|^2``, dB), mean delay and RMS delay spread
(from the Hann-windowed PDP, 30 dB threshold) and the azimuth spread of arrival.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from sim_nodes.channel.antenna import OmniPattern
from sim_nodes.channel.hybrid import draw_clusters, scatterer_paths
from sim_nodes.channel.params import (
    azimuth_spread,
    delay_moments,
    path_loss_db,
    power_delay_profile,
)
from sim_nodes.channel.raytrace import AntennaArray, PathSet, face_visibility, trace
from sim_nodes.channel.synth import frequency_response
from sim_nodes.propagation import channel_band, hybrid_config, room_from_scenario
from sim_nodes.scene import Scenario

#: Rows of the study: (label, overrides of the scenario's hybrid configuration or None for
#: pure ray tracing).
STUDY_ROWS: list[tuple[str, dict | None]] = [
    ("ray tracing only", None),
    ("hybrid (defaults)", {}),
    ("a = 0.1", {"a": 0.1}),
    ("a = 0.4", {"a": 0.4}),
    ("N = 4", {"n_scatterers": 4}),
    ("N = 64", {"n_scatterers": 64}),
    ("scatterers to order 1", {"scatter_order": 1}),
    ("scatterers to order 2", {"scatter_order": 2}),
    ("scatterers to order 3", {"scatter_order": 3}),
    ("scatterers to order 4", {"scatter_order": 4}),
    ("scatterers to order 5", {"scatter_order": 5}),
]


def channel_study(
    scenario: Scenario,
    seed: int = 0,
    *,
    realizations: int = 3,
    rows: list[tuple[str, dict | None]] | None = None,
    max_receivers: int | None = None,
) -> list[dict]:
    """Figures of each study row (see module docstring), one dict per row."""
    if scenario.robot is None or len(scenario.robot.stops) < 2:
        raise ValueError(f"{scenario.name}: the study needs a [robot] with at least 2 stops")
    rows = STUDY_ROWS if rows is None else rows
    base = hybrid_config(scenario)
    room = room_from_scenario(scenario)
    h = scenario.robot.height
    stops = np.array(scenario.robot.stops, float)
    rx_xy = stops[1:] if max_receivers is None else stops[1 : 1 + max_receivers]
    tx = AntennaArray(position=np.array([[*stops[0], h]]), yaw=np.zeros(1), pattern=OmniPattern())
    rx = AntennaArray(
        position=np.concatenate([rx_xy, np.full((len(rx_xy), 1), h)], axis=1),
        yaw=np.zeros(len(rx_xy)),
        pattern=OmniPattern(),
    )
    n_rx = len(rx_xy)
    det, geom = trace(
        room,
        tx,
        rx,
        base.knots,
        max_order=base.max_order,
        diffraction=base.diffraction,
        diffraction_strength=base.diffraction_strength,
        sees=face_visibility(room),
    )
    f_lo, f_hi = channel_band(scenario)
    df = scenario.channel.frequency_step or 6.25e6
    n_freq = math.floor((f_hi - f_lo) / df + 1e-9) + 1
    f = f_lo + df * np.arange(n_freq)
    seeds = np.random.SeedSequence(seed).spawn(realizations)
    out = []
    for label, override in rows:
        figs = []
        for child in seeds if override is not None else seeds[:1]:
            if override is None:
                paths = det
            else:
                cfg = dataclasses.replace(base, **override)
                clusters = draw_clusters(
                    cfg.n_table, cfg.n_scatterers, cfg.radius, np.random.default_rng(child)
                )
                paths = PathSet.concat(
                    [det, scatterer_paths(room, det, geom, clusters, cfg)], det.knots
                )
            h_f = frequency_response(paths, n_rx, f_lo, df, n_freq)
            pdp, tau = power_delay_profile(h_f, df)
            mean, spread = delay_moments(pdp, tau)
            figs.append(
                (
                    -path_loss_db(h_f, f),
                    mean * 1e9,
                    spread * 1e9,
                    np.degrees(azimuth_spread(paths, n_rx)),
                    paths.count / n_rx,
                )
            )
        arr = np.array([[np.mean(x) for x in fig] for fig in figs])
        cfg = dataclasses.replace(base, **override) if override is not None else None
        out.append(
            {
                "model": label,
                "a": cfg.a if cfg else None,
                "p": cfg.p if cfg else None,
                "N": cfg.n_scatterers if cfg else 0,
                "scatter_order": cfg.scatter_order if cfg else 0,
                "power_db": round(float(arr[:, 0].mean()), 2),
                "mean_delay_ns": round(float(arr[:, 1].mean()), 2),
                "rms_delay_spread_ns": round(float(arr[:, 2].mean()), 2),
                "azimuth_spread_deg": round(float(arr[:, 3].mean()), 1),
                "paths_per_rx": round(float(arr[:, 4].mean()), 1),
            }
        )
    return out
