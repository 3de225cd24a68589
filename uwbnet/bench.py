"""``uwbnet bench NAME``: measured figures, printed as JSON on the last line.

Rates are per core: work divided by the CPU time of this (single-threaded) process, so the
figures do not depend on what else the machine runs. The machine's core count is reported.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from typing import Any

from uwbnet.bench_imaging import bench_imaging
from uwbnet.bench_localization import bench_localization
from uwbnet.bench_objects import bench_objects


def _machine() -> dict[str, Any]:
    return {"cores": os.cpu_count()}


def _foyer_irs(seed: int, n_frames: int) -> tuple[Any, list[Any]]:
    """Realistic ``ir`` messages of one foyer3 node (people walking), and its node_info."""
    from node_agent.tdma import SlotTiming
    from protocol import Ir, NodeInfo
    from sim_nodes.driver import SimulatedDriver
    from sim_nodes.network import SimNetwork
    from sim_nodes.scene import load_scenario

    network = SimNetwork(load_scenario("foyer3"), seed)
    node = sorted(network.node_infos())[0]
    with SimulatedDriver(network, node) as drv:
        info = NodeInfo(src=node, seq=0, t=0.0, **drv.describe())
        irs = []
        for k in range(n_frames):
            slot = SlotTiming(frame=k, slot=0, tx=f"{node}/tx", t=2.0 + 0.02 * k, duration=0.003)
            acq = drv.acquire(slot)
            irs.append(Ir(src=node, seq=k, t=acq.t, tx=acq.tx, rx=acq.rx, slot=0, frame=k, h=acq.h))
    return info, irs


def _rate(fn: Callable[[int], None], min_seconds: float = 3.0) -> tuple[int, float, float]:
    """Call ``fn(i)`` until ``min_seconds`` of CPU time passed; (calls, cpu s, wall s)."""
    n = 0
    c0, w0 = time.process_time(), time.perf_counter()
    while time.process_time() - c0 < min_seconds:
        fn(n)
        n += 1
    return n, time.process_time() - c0, time.perf_counter() - w0


def bench_dsp(seed: int = 0) -> dict[str, Any]:
    """Impulse responses (2 receivers x 4095 samples) per second per core through the whole
    node DSP chain: background subtraction, CFAR, range GM-PHD, association, ellipses.

    The rate is the steady state: the start-up (numba's import and the kernels' compile or
    cache load, reported as ``startup_cpu_s``) and ``warmup_ir`` impulse responses, while
    the background and noise estimates settle, are not counted."""
    info, irs = _foyer_irs(seed, 500)
    c0 = time.process_time()
    from node_agent.core import NodeCore

    core = NodeCore(info)
    core.process(irs[0])
    startup = time.process_time() - c0
    warmup = 50
    for ir in irs[1:warmup]:
        core.process(ir)
    n, cpu, wall = _rate(lambda i: core.process(irs[i % len(irs)]))
    return {
        "bench": "dsp",
        "ir_shape": list(irs[0].h.shape),
        "ir_per_s_per_core": round(n / cpu, 1),
        "us_per_ir": round(1e6 * cpu / n, 1),
        "wall_ir_per_s": round(n / wall, 1),
        "warmup_ir": warmup,
        "startup_cpu_s": round(startup, 3),
        **_machine(),
    }


def bench_sim(seed: int = 0) -> dict[str, Any]:
    """Simulated impulse-response matrices per second per core (foyer3, people walking)."""
    from sim_nodes.network import SimNetwork
    from sim_nodes.scene import load_scenario

    network = SimNetwork(load_scenario("foyer3"), seed)
    nodes = sorted(network.node_infos())
    network.acquire(nodes[0], 0.0)
    n, cpu, wall = _rate(lambda i: network.acquire(nodes[i % len(nodes)], 0.02 * i))
    shape = network.acquire(nodes[0], 0.0)[2].shape
    return {
        "bench": "sim",
        "ir_shape": list(shape),
        "ir_per_s_per_core": round(n / cpu, 1),
        "us_per_ir": round(1e6 * cpu / n, 1),
        "wall_ir_per_s": round(n / wall, 1),
        **_machine(),
    }


def bench_fusion(seed: int = 0) -> dict[str, Any]:
    """GM-PHD update times (6x3, 100x30) and the comparison with Stone Soup's GM-PHD."""
    from uwbnet.bench_fusion import run

    return {"bench": "fusion", **run(seed=seed), **_machine()}


def bench_topology(seed: int = 0) -> dict[str, Any]:
    """Ambiguity function on a 200 x 200 grid over the band (``uwbnet.bench_topology``)."""
    from uwbnet.bench_topology import run

    return {"bench": "topology", **run(seed=seed), **_machine()}


def bench_slam(seed: int = 0) -> dict[str, Any]:
    """Robot acquisitions per second through the UWB SLAM (``uwbnet.bench_slam``)."""
    from uwbnet.bench_slam import run

    return {"bench": "slam", **run(seed=seed), **_machine()}


def bench_fuzz(seed: int = 0) -> dict[str, Any]:
    """Fuzz the protocol decoder and the serial frame parser with atheris (``uwbnet.fuzz``),
    ``UWBNET_FUZZ_RUNS`` inputs each (default 500000): inputs run, crashes, hangs."""
    import os
    import re
    import subprocess
    import sys
    import time

    runs = int(os.environ.get("UWBNET_FUZZ_RUNS", "500000"))
    out: dict[str, Any] = {"bench": "fuzz", "runs_requested_each": runs}
    total = 0
    for target in ("decoder", "serial"):
        t0 = time.perf_counter()
        r = subprocess.run(
            [
                sys.executable,
                "-m",
                "uwbnet.fuzz",
                target,
                "--runs",
                str(runs),
                "--seed",
                str(seed + 1),
            ],
            capture_output=True,
            text=True,
        )
        if "No module named 'atheris'" in r.stderr:
            raise RuntimeError("bench fuzz needs atheris: pip install 'uwbnet[fuzz]'")
        done = re.findall(r"Done (\d+) runs", r.stderr)
        n = int(done[-1]) if done else 0
        total += n
        out[target] = {
            "inputs": n,
            "crashes": int(r.returncode != 0 and "timeout" not in r.stderr.lower()),
            "hangs": int("ERROR: libFuzzer: timeout" in r.stderr),
            "exit_status": r.returncode,
            "seconds": round(time.perf_counter() - t0, 1),
        }
    out["inputs_total"] = total
    return {**out, **_machine()}


def bench_channel(seed: int = 0) -> dict[str, Any]:
    """Hybrid channel on room_pillar: one Tx/Rx pair (order 3, scatterers, 1,425 frequencies,
    impulse response) per second per core, paths per second, and the wall time of the whole
    room_pillar data set (9,360 acquisitions x 2 receivers) on 2 worker processes."""
    import numpy as np

    from sim_nodes.channel.raytrace import AntennaArray
    from sim_nodes.channel.synth import frequency_response, impulse_response
    from sim_nodes.propagation import channel_band, hybrid_channel, robot_arrays
    from sim_nodes.scene import load_scenario
    from uwbnet.channel_cmd import generate_dataset

    sc = load_scenario("room_pillar")
    channel = hybrid_channel(sc, np.random.default_rng(seed))
    f_lo, f_hi = channel_band(sc)
    df = sc.channel.frequency_step or 6.25e6
    n_f = int((f_hi - f_lo) / df + 1e-9) + 1
    rng = np.random.default_rng(seed)
    arrays = [robot_arrays(sc, s) for s in range(len(sc.robot.stops))]
    counts = {"paths": 0, "deterministic": 0}

    def one(i: int) -> None:
        tx, rx, heads = arrays[i % len(arrays)]
        h = int(rng.integers(heads.size))
        rx1 = AntennaArray(
            position=rx.position[2 * h : 2 * h + 1], yaw=heads[h : h + 1], pattern=rx.pattern
        )
        paths = channel.paths(tx, rx1, tx_yaw=heads[h : h + 1])
        impulse_response(frequency_response(paths, 1, f_lo, df, n_f), df)
        counts["paths"] += paths.count
        counts["deterministic"] += int(np.sum(paths.kind != 3))

    n, cpu, _wall = _rate(one)
    load_before = os.getloadavg()[0]  # other work on the machine slows the wall time
    t0 = time.perf_counter()
    ds, cpu_s = generate_dataset("room_pillar", seed, workers=2)
    room_pillar_s = time.perf_counter() - t0
    return {
        "bench": "channel",
        "scenario": "room_pillar",
        "pair_frequencies": n_f,
        "paths_per_pair": round(counts["paths"] / n, 1),
        "deterministic_paths_per_pair": round(counts["deterministic"] / n, 1),
        "paths_per_s": round(counts["paths"] / cpu, 1),
        "ir_per_s_per_core": round(n / cpu, 2),
        "room_pillar_acquisitions": int(ds.response.shape[0] * ds.response.shape[1]),
        "room_pillar_receivers": 2,
        "room_pillar_workers": 2,
        "room_pillar_s": round(room_pillar_s, 2),
        # CPU of the workers: about the wall time x 2 on an otherwise idle 2-core machine.
        "room_pillar_cpu_s": round(cpu_s, 2),
        "load_average_1min_before": round(load_before, 2),
        **_machine(),
    }


def bench_scale(seed: int = 1) -> dict[str, Any]:
    """CPU per acquisition of simulation, node DSP and fusion (one center / 4 cells) in
    generated buildings of 12, 48 and 100 nodes (``uwbnet.bench_scale``)."""
    from uwbnet.bench_scale import run

    return {"bench": "scale", **run(seed=seed), **_machine()}


def bench_hub(seed: int = 1) -> dict[str, Any]:
    """The live hub's CPU per received ``detections`` message at 48 and 100 played nodes
    (``uwbnet.bench_hub``)."""
    from uwbnet.bench_hub import run

    return {"bench": "hub", **run(seed=seed), **_machine()}


def bench_web(seed: int = 0) -> dict[str, Any]:
    """The live web view at 100 sensors / 30 tracks (``uwbnet/bench_web.py``)."""
    from uwbnet.bench_web import bench_web as run

    return run(seed)


BENCHES: dict[str, Callable[..., dict[str, Any]]] = {
    "channel": bench_channel,
    "objects": bench_objects,
    "dsp": bench_dsp,
    "fuzz": bench_fuzz,
    "fusion": bench_fusion,
    "hub": bench_hub,
    "localization": bench_localization,
    "imaging": bench_imaging,
    "scale": bench_scale,
    "sim": bench_sim,
    "web": bench_web,
    "topology": bench_topology,
    "slam": bench_slam,
}

__all__ = ["BENCHES"]
