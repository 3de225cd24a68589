"""``uwbnet bench NAME``: measured figures, printed as JSON on the last line.

Rates are per core: work divided by the CPU time of this (single-threaded) process, so the
figures do not depend on what else the machine runs. The machine's core count is reported.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from typing import Any


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
    node DSP chain: background subtraction, CFAR, range GM-PHD, association, ellipses."""
    from node_agent.core import NodeCore

    info, irs = _foyer_irs(seed, 500)
    core = NodeCore(info)
    for ir in irs[:50]:  # warm-up: background and noise estimates settle
        core.process(ir)
    n, cpu, wall = _rate(lambda i: core.process(irs[i % len(irs)]))
    return {
        "bench": "dsp",
        "ir_shape": list(irs[0].h.shape),
        "ir_per_s_per_core": round(n / cpu, 1),
        "us_per_ir": round(1e6 * cpu / n, 1),
        "wall_ir_per_s": round(n / wall, 1),
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


BENCHES: dict[str, Callable[..., dict[str, Any]]] = {
    "dsp": bench_dsp,
    "fuzz": bench_fuzz,
    "fusion": bench_fusion,
    "sim": bench_sim,
}

__all__ = ["BENCHES"]
