"""``uwbnet channel ...``: channel-model figures, plots and data sets (the I/O shell).

The computations live in :mod:`sim_nodes.channel` (pure), :mod:`sim_nodes.propagation` and
:mod:`sim_nodes.study`; this module parallelises, prints and writes files.
"""

from __future__ import annotations

import multiprocessing
import os
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np


def _dataset_worker(args: tuple[str, int, list[int]]) -> tuple[list[int], Any, float]:
    import time

    from sim_nodes.propagation import hybrid_channel, robot_dataset
    from sim_nodes.scene import load_scenario

    cpu0 = time.process_time()
    name, seed, stops = args
    scenario = load_scenario(name)
    # Every worker draws the same realization from the seed: results do not depend on the
    # number of workers.
    channel = hybrid_channel(scenario, np.random.default_rng(seed))
    ds = robot_dataset(scenario, channel, stops=stops)
    return stops, ds, time.process_time() - cpu0


def generate_dataset(
    scenario: str, seed: int, workers: int, n_stops: int | None = None
) -> tuple[Any, float]:
    """The robot data set of a scenario, stops split over ``workers`` processes.

    Returns the :class:`~sim_nodes.propagation.RobotDataset` and the CPU seconds the workers
    spent (imports included): with the machine to itself, wall time is about CPU / workers.
    """
    from sim_nodes.propagation import RobotDataset
    from sim_nodes.scene import load_scenario

    sc = load_scenario(scenario)
    if sc.robot is None:
        raise ValueError(f"{sc.name}: no [robot] in this scenario (a data set needs one)")
    total = len(sc.robot.stops) if n_stops is None else min(n_stops, len(sc.robot.stops))
    # Interleave stops over workers (neighbouring stops cost about the same).
    jobs = [(scenario, seed, list(range(w, total, workers))) for w in range(workers)]
    jobs = [j for j in jobs if j[2]]
    if len(jobs) == 1:
        results = [_dataset_worker(jobs[0])]
    else:
        ctx = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(max_workers=len(jobs), mp_context=ctx) as pool:
            results = list(pool.map(_dataset_worker, jobs))
    first = results[0][1]
    n_h, _, n_f = first.response.shape[1:]
    resp = np.zeros((total, n_h, 2, n_f), np.complex64)
    n_paths = np.zeros((total, n_h, 2), np.int64)
    heads = np.zeros((total, n_h))
    for stops, ds, _ in results:
        resp[stops] = ds.response
        n_paths[stops] = ds.n_paths
        heads[stops] = ds.headings
    cpu = sum(r[2] for r in results)
    return RobotDataset(
        frequencies=first.frequencies,
        stops=np.array(sc.robot.stops[:total], float),
        headings=heads,
        response=resp,
        n_paths=n_paths,
    ), cpu


def write_dataset(ds: Any, out: Path) -> None:
    """Save a data set as ``.npz`` (written to ``out.partial``, then renamed)."""
    part = out.with_name(out.name + ".partial")
    with open(part, "wb") as fh:
        np.savez(
            fh,
            frequencies=ds.frequencies,
            stops=ds.stops,
            headings=ds.headings,
            response=ds.response,
            n_paths=ds.n_paths,
        )
    os.replace(part, out)


def write_paths_csv(paths: Any, names: tuple[str, ...], out: Path) -> None:
    """The path list as CSV: one row per path (written to ``.partial``, then renamed)."""
    from sim_nodes.channel.raytrace import DIFFRACTED

    kinds = ("los", "reflected", "diffracted", "scattered")
    mid = paths.knots.size // 2
    part = out.with_name(out.name + ".partial")
    with open(part, "w", encoding="utf-8") as fh:
        fh.write(
            "kind,order,delay_ns,amp_re,amp_im,amp_db,aod_az_deg,aod_el_deg,"
            "aoa_az_deg,aoa_el_deg,crossings,interactions\n"
        )
        for i in range(paths.count):
            a = paths.amplitude[i, mid]
            faces = [int(f) for f in paths.faces[i] if f >= 0]
            if paths.kind[i] == DIFFRACTED:
                where = f"wedge {faces[0]}"
            else:
                where = " > ".join(names[f] for f in faces[: int(paths.order[i])])
            aod, aoa = np.degrees(paths.aod[i]), np.degrees(paths.aoa[i])
            fh.write(
                f"{kinds[paths.kind[i]]},{paths.order[i]},{paths.delay[i] * 1e9:.4f},"
                f"{a.real:.6e},{a.imag:.6e},{20 * np.log10(max(abs(a), 1e-300)):.2f},"
                f"{aod[0]:.2f},{aod[1]:.2f},{aoa[0]:.2f},{aoa[1]:.2f},"
                f"{paths.n_transmissions[i]},{where}\n"
            )
    os.replace(part, out)


def link_figures(
    scenario_name: str, seed: int, stop: int, plot: Path | None, paths_csv: Path | None = None
) -> dict[str, Any]:
    """Channel parameters of one link, pure ray tracing vs hybrid, and optional plots.

    For a robot scenario: the robot's Tx and rx1 at ``stop``, heading 0, plus the angular PDP
    of its horn turned through all headings at rx1's position (omni-traced). For a node
    scenario: node number ``stop``'s Tx and rx1.
    """
    from sim_nodes.channel.antenna import HornPattern, OmniPattern
    from sim_nodes.channel.params import (
        angular_pdp,
        azimuth_spread,
        delay_moments,
        path_loss_db,
        power_delay_profile,
    )
    from sim_nodes.channel.raytrace import AntennaArray
    from sim_nodes.channel.synth import frequency_response
    from sim_nodes.propagation import channel_band, hybrid_channel, robot_arrays
    from sim_nodes.scene import load_scenario

    sc = load_scenario(scenario_name)
    channel = hybrid_channel(sc, np.random.default_rng(seed))
    if sc.robot is not None:
        if not 0 <= stop < len(sc.robot.stops):
            raise ValueError(f"--stop must be in 0..{len(sc.robot.stops) - 1}")
        tx, rx, _ = robot_arrays(sc, stop)
        tx1 = AntennaArray(position=tx.position, yaw=tx.yaw, pattern=tx.pattern)
        rx1 = AntennaArray(position=rx.position[:1], yaw=rx.yaw[:1], pattern=rx.pattern)
        # The rotating directive antenna of the angular PDP: the robot's horn, or the default
        # 60-degree horn if the robot is omnidirectional.
        horn = tx.pattern if isinstance(tx.pattern, HornPattern) else HornPattern()
    else:
        if not 0 <= stop < len(sc.nodes):
            raise ValueError(f"--stop (node number) must be in 0..{len(sc.nodes) - 1}")
        from sim_nodes.network import BAT_BEAMWIDTH, _build_node

        node = _build_node(sc.nodes[stop])
        horn = HornPattern(beamwidth=BAT_BEAMWIDTH, f0=0.0)
        tx1 = AntennaArray(position=node.tx.position, yaw=node.tx.boresight, pattern=horn)
        rx1 = AntennaArray(position=node.rx.position[:1], yaw=node.rx.boresight[:1], pattern=horn)
    f_lo, f_hi = channel_band(sc)
    df = sc.channel.frequency_step or 6.25e6
    n_f = int((f_hi - f_lo) / df + 1e-9) + 1
    f = f_lo + df * np.arange(n_f)
    out: dict[str, Any] = {"scenario": sc.name, "stop": stop, "seed": seed}
    curves = {}
    for label, scat in (("ray_tracing", False), ("hybrid", True)):
        paths = channel.paths(tx1, rx1, scatterers=scat)
        h_f = frequency_response(paths, 1, f_lo, df, n_f)
        pdp, tau = power_delay_profile(h_f, df)
        mean, spread = delay_moments(pdp, tau)
        omni_rx = AntennaArray(position=rx1.position, yaw=rx1.yaw, pattern=OmniPattern())
        omni_paths = channel.paths(tx1, omni_rx, scatterers=scat)
        out[label] = {
            "paths": paths.count,
            "path_loss_db": round(float(path_loss_db(h_f, f)[0]), 2),
            "mean_delay_ns": round(float(mean[0]) * 1e9, 2),
            "rms_delay_spread_ns": round(float(spread[0]) * 1e9, 2),
            "azimuth_spread_deg": round(float(np.degrees(azimuth_spread(omni_paths, 1)[0])), 1),
        }
        curves[label] = (tau, pdp[0], omni_paths)
        if scat and paths_csv is not None:
            write_paths_csv(paths, channel.room.names, paths_csv)
            out["paths_csv"] = str(paths_csv)
    if plot is not None:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        headings = np.radians(np.arange(0, 360, 3.0))
        fig, axes = plt.subplots(1, 3, figsize=(15, 4.5))
        for label, (tau, pdp, _) in curves.items():
            axes[0].plot(tau * 1e9, 10 * np.log10(pdp / pdp.max() + 1e-12), label=label, lw=0.8)
        axes[0].set(xlabel="delay (ns)", ylabel="PDP (dB re peak)", ylim=(-60, 3), xlim=(0, 120))
        axes[0].legend()
        for ax, label in zip(axes[1:], curves, strict=True):
            apdp, tau = angular_pdp(curves[label][2], 0, headings, horn, f_lo, df, n_f)
            db = 10 * np.log10(apdp / apdp.max() + 1e-12)
            ax.imshow(
                db,
                aspect="auto",
                origin="lower",
                extent=(0, tau[-1] * 1e9, 0, 360),
                vmin=-50,
                vmax=0,
                cmap="viridis",
            )
            ax.set(xlabel="delay (ns)", ylabel="antenna heading (deg)", xlim=(0, 120))
            ax.set_title(f"angular PDP, {label}")
        fig.tight_layout()
        part = plot.with_name(plot.stem + ".partial" + plot.suffix)
        fig.savefig(part, dpi=110)
        plt.close(fig)
        os.replace(part, plot)
        out["plot"] = str(plot)
    return out
