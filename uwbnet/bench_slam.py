"""SLAM benchmark: robot acquisitions per second through the whole mapping chain.

``run(seed) -> dict``: the first ``stops`` stops of room_pillar (120 headings each) are simulated
with the hybrid channel and turned into ``ir`` messages by the robot recorder (not timed); the
:class:`~fusion_center.mapping.EchoSlamMapper` with its default particle count then processes
them (echo extraction, pairing, grouping, RBPF update, one map at the end). Figures:
``acquisitions_per_s`` (wall clock), ``acquisitions_per_cpu_s`` and ``realtime_factor`` against
the robot's acquisition rate (``node_info.radar.rate``; above 1 keeps up), plus the number of
particles and of landmarks per particle at the end.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["run"]


def _robot_messages(seed: int, stops: int) -> tuple[Any, list[Any]]:
    from protocol import Ir, NodeInfo, decode
    from protocol.recording import read_recording
    from sim_nodes.robot_record import write_robot_recording
    from sim_nodes.scene import load_scenario
    from uwbnet.channel_cmd import generate_dataset

    scenario = load_scenario("room_pillar")
    ds, _ = generate_dataset("room_pillar", seed, 1, stops)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "bench.mcap"
        write_robot_recording(scenario, ds, path, seed=seed)
        msgs = [decode(r.payload) for r in read_recording(path)]
    info = next(m for m in msgs if isinstance(m, NodeInfo))
    return info, [m for m in msgs if isinstance(m, Ir)]


def run(seed: int = 0, stops: int = 3) -> dict[str, Any]:
    """Time the SLAM on ``stops`` stops of room_pillar (see the module docstring)."""
    from fusion_center.mapping import EchoSlamMapper
    from uwbnet.map_cmd import robot_geometry

    info, irs = _robot_messages(seed, stops)
    r = info.radar
    mapper = EchoSlamMapper(
        robot_geometry(info, irs[0].rx), fs=r.fs, t0=r.t0, bandwidth=r.f_high - r.f_low
    )
    c0, w0 = time.process_time(), time.perf_counter()
    for m in irs:
        mapper.step(m.t, m.h, m.odom)
    mapper.finish()
    the_map = mapper.map()
    cpu, wall = time.process_time() - c0, time.perf_counter() - w0
    rate = len(irs) / wall
    return {
        "acquisitions": len(irs),
        "particles": mapper.filter.config.n_particles,
        "association": mapper.filter.config.association,
        "acquisitions_per_s": round(rate, 1),
        "acquisitions_per_cpu_s": round(len(irs) / cpu, 1),
        "robot_rate_hz": r.rate,
        "realtime_factor": round(rate / r.rate, 2),
        "landmarks_per_particle": round(float(np.mean(mapper.filter.lm.active.sum(1))), 1),
        "map_walls": len(the_map.walls),
    }
