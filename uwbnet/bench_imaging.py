"""``uwbnet bench imaging``: speed and memory of Kirchhoff migration (eq. (17)).

* ``updates_per_s_per_core``: pixel x impulse-response-row updates per CPU second (one row is
  one Tx/Rx pair; a room_pillar acquisition has two), single thread, 400 x 400 grid.
* ``room_pillar_s``: wall time of the 400 x 400 image of the room_pillar geometry (78 stops x
  120 headings = 9,360 acquisitions, 18,720 rows of n = 3,240 samples, fs = 32.4 GHz) on two
  threads. The signals are synthetic noise of the recorded size (the kernel's cost does not
  depend on their content), so the bench does not wait a minute for the channel simulation.
* ``peak_mem_mb``: peak resident memory of the process (imports, signals and kernel).
* ``speedup_vs_straightforward``: CPU time per update of the straightforward implementation
  (one observation at a time, :func:`numpy.interp`,
  :mod:`fusion_center.imaging.reference`) over this one, on the same rows.
"""

from __future__ import annotations

import math
import os
import resource
import time
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numpy as np


def _room_pillar_observations(seed: int) -> Any:
    from fusion_center.imaging import Observations
    from sim_nodes.scene import load_scenario

    rb = load_scenario("room_pillar").robot
    stops = np.array(rb.stops, float)
    heads = np.arange(rb.n_headings) * rb.heading_step
    sx = np.repeat(stops[:, 0], heads.size)
    sy = np.repeat(stops[:, 1], heads.size)
    hh = np.tile(heads, len(stops))
    tx = np.stack([sx, sy, np.full_like(sx, rb.height)], axis=1)
    rows_tx, rows_rx, em = [], [], []
    for side in (0.5, -0.5):
        off = side * rb.baseline
        rows_rx.append(np.stack([sx - np.sin(hh) * off, sy + np.cos(hh) * off, tx[:, 2]], axis=1))
        rows_tx.append(tx)
        em.append(np.arange(len(sx)))
    n, fs = 3240, 32.4e9
    rng = np.random.default_rng(seed)
    m = 2 * len(sx)
    return Observations(
        h=rng.standard_normal((m, n), dtype=np.float32),
        tx=np.concatenate(rows_tx),
        rx=np.concatenate(rows_rx),
        fs=fs,
        emission=np.concatenate(em),
    )


def bench_imaging(seed: int = 0) -> dict[str, Any]:
    from fusion_center.imaging import Grid, kirchhoff_image
    from fusion_center.imaging.reference import straightforward_kirchhoff

    obs = _room_pillar_observations(seed)
    grid = Grid.covering(-0.25, 9.25, -0.25, 8.25, 400, 400, 1.0)
    # Single-thread rates on slices of rows, after a warm-up call (imports, FFT plans).
    small = Grid.covering(0.0, 1.0, 0.0, 1.0, 8, 8, 1.0)
    kirchhoff_image(obs.take(np.arange(4)), small)
    straightforward_kirchhoff(obs.take(np.arange(4)), small)
    # Contiguous rows, as a recording delivers them (consecutive rows share a transmitter).
    part = obs.take(np.arange(512))
    c0 = time.process_time()
    kirchhoff_image(part, grid)
    cpu_fast = time.process_time() - c0
    updates = len(part) * grid.nx * grid.ny
    few = obs.take(np.arange(32))
    c0 = time.process_time()
    straightforward_kirchhoff(few, grid)
    cpu_slow = time.process_time() - c0
    ns_fast = cpu_fast / updates
    ns_slow = cpu_slow / (len(few) * grid.nx * grid.ny)
    # The whole image on two threads.
    t0 = time.perf_counter()
    c0 = time.process_time()
    with ThreadPoolExecutor(max_workers=2) as pool:
        img = kirchhoff_image(obs, grid, map_fn=pool.map)
    wall = time.perf_counter() - t0
    cpu = time.process_time() - c0
    assert math.isfinite(float(img.sum()))
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    load = os.getloadavg()[0]
    return {
        "updates_per_s_per_core": round(1 / ns_fast),
        "room_pillar_s": round(wall, 2),
        "room_pillar_cpu_s": round(cpu, 2),
        "room_pillar_rows": len(obs),
        "room_pillar_updates": len(obs) * grid.nx * grid.ny,
        "peak_mem_mb": round(peak, 1),
        "speedup_vs_straightforward": round(ns_slow / ns_fast, 1),
        "straightforward_updates_per_s": round(1 / ns_slow),
        "load_avg_1min": round(load, 2),
        "cores": os.cpu_count(),
    }
