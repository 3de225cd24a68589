"""``uwbnet bench hub``: the live hub's CPU per received ``detections`` message.

``uwbnet bench scale`` measures the fusion center's work (decode, frame assembly, GM-PHD update)
replayed in one process; the live hub of ``uwbnet scale`` also runs the zenoh router, the
subscriptions' delivery into Python and the fusion thread's wake-ups. This bench measures all
of it, without the simulator's CPU in the way: it starts the hub of ``uwbnet scale``
(``python -m uwbnet.scale_roles hub``: router, TDMA schedule, fusion center with the
building's walls, the ``tracks`` recorder) and, in this process on one client session, plays
N nodes: a liveliness token and a ``node_info`` queryable each, then seeded synthetic
``detections`` (:func:`synthetic_detections`) at 50 Hz, published in groups of 8 at the end of
the group's slots as a ``uwbnet scale`` node process does. It reads the hub's CPU time
(``/proc``, utime + stime, every thread, and split into zenoh's threads and Python's) from the
start of a window of whole frames until the hub has fused the window's last frame, and
divides by the messages published in the window, so the figures do not depend on what else
the machine runs (the latency and drop figures do).
"""

from __future__ import annotations

import json
import math
import os
import shutil
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np

#: TDMA frame period, s; messages published per group (a ``uwbnet scale`` node process).
PERIOD, GROUP = 0.02, 8


def synthetic_detections(
    infos: list[Any],
    frames: int,
    start: np.ndarray,
    velocity: np.ndarray,
    *,
    t0: float = 1.0,
    frame0: int = 0,
    rng: np.random.Generator,
) -> list[bytes]:
    """Wire ``detections`` of the nodes ``infos`` (in slot order) for ``frames`` TDMA frames.

    People start at ``start`` (k, 2) m and walk at ``velocity`` (k, 2) m/s from ``t0`` (s);
    each sensor sees those within 8 m and 60 degrees of its heading with p_D 0.8 and 0.1 m
    noise, plus Poisson clutter (0.3 per scan) in front of it. Frame ``f`` is TDMA frame
    ``frame0 + f`` at ``t0 + f * PERIOD``, slot ``s`` a ``PERIOD / len(infos)`` later each.
    Synthetic, so that the node DSP's changes do not move a reference or a figure.
    """
    from protocol import Detections

    n = len(infos)
    no: dict[str, tuple[float, ...]] = {"rx1": (), "rx2": ()}
    payloads = []
    for f in range(frames):
        for s, info in enumerate(infos):
            t = t0 + f * PERIOD + s * PERIOD / n
            people = start + velocity * (t - t0)
            x, y, _, yaw = info.pose
            d = people - np.array([x, y])
            off = np.abs((np.arctan2(d[:, 1], d[:, 0]) - yaw + math.pi) % (2 * math.pi) - math.pi)
            seen = (np.hypot(d[:, 0], d[:, 1]) < 8.0) & (off < math.radians(60))
            seen &= rng.random(seen.size) < 0.8
            z = people[seen] + rng.normal(0.0, 0.1, (int(seen.sum()), 2))
            k = rng.poisson(0.3)
            r, a = rng.uniform(1.0, 7.0, k), yaw + rng.uniform(-0.8, 0.8, k)
            z = np.concatenate([z, np.stack([x + r * np.cos(a), y + r * np.sin(a)], axis=1)])
            cov = np.broadcast_to(np.eye(2) * 0.01, (z.shape[0], 2, 2))
            det = Detections(
                src=info.src, seq=frame0 + f, t=t, tx=f"{info.src}/tx", frame=frame0 + f,
                ranges=no, amplitudes=no, positions=z, cov=cov,
            )  # fmt: skip
            payloads.append(det.to_wire())
    return payloads


def node_infos(n: int, seed: int = 1) -> list[Any]:
    """The ``node_info`` of every node of the generated ``n``-node building."""
    import msgpack

    from protocol import NodeInfo
    from sim_nodes.building import building_scenario
    from sim_nodes.network import SimNetwork

    infos = []
    for nid, info in SimNetwork(building_scenario(n, 2, seed), seed).node_infos().items():
        wire = {"v": 1, "kind": "node_info", "src": nid, "seq": 0, "t": 0.0, **info}
        infos.append(NodeInfo.from_wire(msgpack.packb(wire)))
    return infos


def _threads(pid: int) -> Counter[str]:
    """CPU ticks (utime + stime) of every thread of ``pid``, summed by thread name."""
    ticks: Counter[str] = Counter()
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            stat = (task / "stat").read_text()
        except OSError:
            continue
        name = stat[stat.index("(") + 1 : stat.rindex(")")]
        fields = stat.rsplit(")", 1)[1].split()
        ticks[name] += int(fields[11]) + int(fields[12])
    return ticks


def _wait_line(proc: subprocess.Popen[str], prefix: str, timeout: float) -> str:
    assert proc.stdout is not None
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        if not line:
            break
        if line.startswith(prefix):
            return line.strip()
    raise RuntimeError(f"the hub did not say {prefix!r} within {timeout:.0f} s")


def run_one(n: int, seconds: float = 8.0, warmup: float = 2.0, seed: int = 1) -> dict[str, Any]:
    """Play ``n`` nodes for ``warmup + seconds`` against a live hub; the hub's figures."""
    import zenoh

    from protocol import keys
    from protocol.transport import free_tcp_port, session_config

    net, port = "benchhub", free_tcp_port()
    infos = node_infos(n, seed)
    out = Path(tempfile.mkdtemp(prefix="uwbnet-benchhub."))
    cfg = {
        "net": net, "nodes": n, "people": 2, "seed": seed, "workers": 1,
        "listen": f"tcp/127.0.0.1:{port}", "out": str(out),
    }  # fmt: skip
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")
    root = str(Path(__file__).resolve().parents[1])
    env["PYTHONPATH"] = os.pathsep.join(p for p in (root, env.get("PYTHONPATH")) if p)
    err = open(out / "hub.err", "w", encoding="utf-8")
    hub = subprocess.Popen(
        [sys.executable, "-P", "-m", "uwbnet.scale_roles", "hub", json.dumps(cfg)],
        stdout=subprocess.PIPE, stderr=err, text=True, env=env,
    )  # fmt: skip
    err.close()
    conf = session_config(mode="client", connect=[f"tcp/127.0.0.1:{port}"])
    conf.insert_json5("connect/timeout_ms", "-1")
    try:
        epoch = float(_wait_line(hub, "ready", 60.0).split()[-1])
        with zenoh.open(conf) as session:
            decl = []
            for info in infos:
                wire = info.to_wire()
                key = keys.node_key(net, info.src, "info")
                decl.append(session.declare_queryable(key, lambda q, k=key, w=wire: q.reply(k, w)))
                decl.append(session.liveliness().declare_token(keys.alive_key(net, info.src)))
                session.put(key, wire)
            _wait_line(hub, "scheduled", 60.0)
            figures = _play(session, hub.pid, net, infos, epoch, seconds, warmup, seed)
            for d in decl:
                d.undeclare()
    finally:
        hub.terminate()
        try:
            hub.wait(30.0)
        except subprocess.TimeoutExpired:
            hub.kill()
            hub.wait(5.0)
    try:
        figures |= _outcome(out, figures.pop("window"), n)
    finally:
        shutil.rmtree(out, ignore_errors=True)
    return {"nodes": n, **figures}


def _play(
    session: Any,
    pid: int,
    net: str,
    infos: list[Any],
    epoch: float,
    seconds: float,
    warmup: float,
    seed: int,
) -> dict[str, Any]:
    import msgpack

    from protocol import keys
    from sim_nodes.building import building_length

    n = len(infos)
    frames = round((warmup + seconds) / PERIOD)
    rng = np.random.default_rng(seed)
    length = building_length(n)
    people = max(2, n // 12)
    start = np.stack([rng.uniform(1.0, length - 1.0, people), rng.uniform(1.5, 6.5, people)], 1)
    velocity = rng.uniform(-1.0, 1.0, (people, 2))
    f0 = math.ceil((time.time() + 1.5 - epoch) / PERIOD)
    payloads = synthetic_detections(
        infos, frames, start, velocity, t0=epoch + f0 * PERIOD, frame0=f0, rng=rng
    )
    pubs = [session.declare_publisher(keys.node_key(net, i.src, "det")) for i in infos]
    # the latest acquisition the hub has fused: the CPU is read once it caught up
    fused = [-math.inf]
    sub = session.declare_subscriber(
        keys.fusion_key(net, "tracks"),
        lambda smp: fused.__setitem__(
            0, max(fused[0], *msgpack.unpackb(smp.payload.to_bytes())["t_acq"], -math.inf)
        ),
    )
    last_t = epoch + (f0 + frames - 1) * PERIOD + (n - 1) * PERIOD / n
    w_frame = round(warmup / PERIOD)
    cpu0: Counter[str] = Counter()
    clk = os.sysconf("SC_CLK_TCK")
    for f in range(frames):
        if f == w_frame:
            cpu0, t_w0 = _threads(pid), time.monotonic()
        for g in range(0, n, GROUP):
            last = min(g + GROUP, n)
            due = epoch + (f0 + f) * PERIOD + last * PERIOD / n
            wait = due - time.time()
            if wait > 0:
                time.sleep(wait)
            for s in range(g, last):
                pubs[s].put(payloads[f * n + s])
    wall = time.monotonic() - t_w0
    caught_up = time.monotonic() + 10.0
    while fused[0] < last_t - 1e-6 and time.monotonic() < caught_up:
        time.sleep(PERIOD)
    cpu1 = _threads(pid)
    sub.undeclare()
    for p in pubs:
        p.undeclare()
    msgs = (frames - w_frame) * n
    used = {k: (cpu1[k] - cpu0.get(k, 0)) / clk for k in cpu1}
    zenoh_s = sum(v for k, v in used.items() if not k.startswith("python"))
    python_s = sum(v for k, v in used.items() if k.startswith("python"))
    return {
        # not N x 50 when this process lagged behind the frames (a loaded machine)
        "messages_per_s": round(msgs / wall, 1),
        "hub_cpu": round((zenoh_s + python_s) / wall, 3),
        "hub_us_per_msg": round(1e6 * (zenoh_s + python_s) / msgs, 1),
        "zenoh_threads_us_per_msg": round(1e6 * zenoh_s / msgs, 1),
        "python_threads_us_per_msg": round(1e6 * python_s / msgs, 1),
        "window": (epoch + (f0 + w_frame) * PERIOD, epoch + (f0 + frames) * PERIOD),
        "load_avg": [round(x, 2) for x in os.getloadavg()],
    }


def _outcome(out: Path, window: tuple[float, float], n: int) -> dict[str, Any]:
    """Latency, drops and the fusion core's counters of a run, from the hub's files."""
    w0, w1 = window
    lat, fused = [], set()
    with open(out / "tracks.jsonl", encoding="utf-8") as f:
        for line in f:
            rec = json.loads(line)
            t = np.asarray(rec["t_acq"], dtype=np.float64)
            t = t[(t >= w0 - 1e-6) & (t < w1 - 1e-6)]
            lat.append(rec["recv"] - t)
            fused.update(np.round(t, 6).tolist())
    ms = np.concatenate(lat) * 1e3 if lat else np.zeros(0)
    counters = json.loads((out / "fusion_counters.json").read_text())
    expected = n * round((w1 - w0) / PERIOD)
    return {
        "p50_latency_ms": round(float(np.percentile(ms, 50)), 2) if ms.size else None,
        "p99_latency_ms": round(float(np.percentile(ms, 99)), 2) if ms.size else None,
        "drop_rate": round(1.0 - len(fused) / expected, 5),
        "late_detections": counters.get("late"),
    }


def run(sizes: tuple[int, ...] = (48, 100), seconds: float = 8.0, seed: int = 1) -> dict[str, Any]:
    """The figures of every size, one live hub each."""
    out = {str(n): run_one(n, seconds=seconds, seed=seed) for n in sizes}
    return {"sizes": out}
