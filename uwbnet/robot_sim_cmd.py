"""``uwbnet sim ROBOT_SCENARIO``: a robot scenario's recording (the I/O shell).

The channel data set is computed by :func:`uwbnet.channel_cmd.generate_dataset` (stops split
over worker processes); :func:`sim_nodes.robot_record.write_robot_recording` turns it into
``node_info``, ``ir`` and ``truth`` messages.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Any


def simulate_robot(
    name: str,
    scenario: Any,
    out: Path,
    *,
    seed: int,
    workers: int,
    stops: int | None,
    snr_db: float,
    net: str,
    progress: Callable[[str, int, int], None] | None = None,
) -> dict[str, Any]:
    """Compute the data set of ``scenario`` (a ``[robot]`` scenario, loaded from ``name``, a
    shipped name or TOML path) and write the recording.

    ``progress(stage, done, total)`` reports the stages ``channel`` (once, when the data set is
    ready) and ``writing`` (acquisitions). Returns the figures printed by ``uwbnet sim``.
    """
    from sim_nodes.robot_record import write_robot_recording
    from uwbnet.channel_cmd import generate_dataset

    t0 = time.perf_counter()
    ds, cpu = generate_dataset(name, seed, workers, stops)
    total = int(ds.response.shape[0] * ds.response.shape[1])
    if progress is not None:
        progress("channel", total, total)
    done = 0

    def step(k: int) -> None:
        nonlocal done
        done += k
        if progress is not None:
            progress("writing", done, total)

    n = write_robot_recording(scenario, ds, out, seed=seed, snr_db=snr_db, net=net, progress=step)
    return {
        "out": str(out),
        "messages": n,
        "acquisitions": total,
        "seed": seed,
        "snr_db": snr_db,
        "wall_s": round(time.perf_counter() - t0, 2),
        "channel_cpu_s": round(cpu, 2),
        "workers": workers,
    }
