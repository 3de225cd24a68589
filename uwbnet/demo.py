"""``uwbnet demo``: the whole network on one machine, in real time, over real zenoh sessions.

Simulated nodes, one node agent per node and the fusion center each get their own zenoh
session (peer mode on loopback, as separate hosts would), all in this process. The live view is
a terminal table of tracks and per-node health; the run ends after ``duration`` or on Ctrl-C
and prints a summary with the tracking error against the simulator's truth.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import math
import multiprocessing
import threading
import time
from typing import Any

import numpy as np
import zenoh
from rich.console import Console, Group
from rich.live import Live
from rich.table import Table

from fusion_center.image_runtime import LiveImagingConfig
from fusion_center.recorder import NetworkRecorder
from fusion_center.service import FusionConfig, FusionService, NodeHealth
from fusion_center.tracking.base import TrackerOutput
from fusion_center.tracking.metrics import ospa
from node_agent.agent import AgentConfig, NodeAgent
from protocol import keys
from protocol.transport import free_tcp_port, session_config
from sim_nodes.driver import SimulatedDriver
from sim_nodes.network import SimNetwork
from sim_nodes.record import truth_message
from sim_nodes.scene import Scenario
from uwbnet.processes import settle_heap

log = logging.getLogger(__name__)


@dataclasses.dataclass(frozen=True, slots=True, kw_only=True)
class DemoConfig:
    """Parameters of a demo run (``uwbnet demo --help``)."""

    scenario: Scenario
    duration: float = math.inf
    seed: int = 1
    net: str = "demo"
    method: str = "gmphd"
    record: str | None = None
    publish_ir: bool = True
    web: int | None = None
    web_host: str = "127.0.0.1"
    #: Live images per second of the fusion center (0: off; fusion_center.image_runtime).
    image_rate: float = 0.0


@dataclasses.dataclass(slots=True)
class DemoScore:
    """Running tracking error of the demo against the simulator's truth (after 2 s)."""

    updates: int = 0
    ospa_sum: float = 0.0
    count_ok: int = 0

    def add(self, out: TrackerOutput, truth_xy: np.ndarray) -> float:
        d = ospa(out.positions(), truth_xy, c=1.0, p=2)
        self.updates += 1
        self.ospa_sum += d
        self.count_ok += int(len(out.tracks) == len(truth_xy))
        return d

    def as_dict(self) -> dict[str, Any]:
        n = max(self.updates, 1)
        return {
            "updates_scored": self.updates,
            "ospa_mean": round(self.ospa_sum / n, 4),
            "card_correct_fraction": round(self.count_ok / n, 4),
        }


def truth_loop(
    session: zenoh.Session, network: SimNetwork, net: str, start: float, stop: threading.Event
) -> None:
    """Publish the simulator's truth at 50 Hz (simulation only, PROTOCOL.md ``truth``)."""
    pub = session.declare_publisher(keys.truth_key(net))
    seq = 0
    try:
        while not stop.wait(0.02):
            t = time.time()
            msg = truth_message(network, t - start, seq)
            pub.put(dataclasses.replace(msg, t=t).to_wire())
            seq += 1
    finally:
        pub.undeclare()


def _run_nodes(
    scenario: Scenario,
    seed: int,
    net: str,
    hub: str,
    clock: Any,
    publish_ir: bool,
    ready: Any,
    stop: Any,
) -> None:
    """The simulated nodes' process: one zenoh session and node agent per node, and the
    simulator's truth publisher. Runs until ``stop`` is set (or Ctrl-C).

    ``clock`` is the :class:`_NodesClock` hand-shake: the process first loads everything that
    costs seconds of CPU (imports, the simulator, numba's kernels, the zenoh sessions), says so
    through ``clock.loaded``, and only then learns the TDMA epoch, so that a slow start-up (a
    cold numba cache, a busy machine) cannot eat into the first frames.
    """
    from node_agent.dsp import kernels  # noqa: F401  (compiles or loads the DSP kernels)

    network = SimNetwork(scenario, seed)
    truth_stop = threading.Event()
    try:
        with contextlib.ExitStack() as stack:
            sim_session = stack.enter_context(zenoh.open(session_config(connect=[hub])))
            nodes = sorted(network.node_infos())
            sessions = [
                stack.enter_context(zenoh.open(session_config(connect=[hub]))) for _ in nodes
            ]
            clock.loaded.set()
            while not clock.go.wait(0.2):
                if stop.is_set():
                    return
            start = clock.epoch.value
            truth_thread = threading.Thread(
                target=truth_loop, args=(sim_session, network, net, start, truth_stop)
            )
            truth_thread.start()
            stack.callback(truth_thread.join, 2.0)
            stack.callback(truth_stop.set)
            agents = [
                NodeAgent(
                    session,
                    stack.enter_context(SimulatedDriver(network, node, start=start)),
                    AgentConfig(node=node, net=net, publish_ir=publish_ir),
                )
                for node, session in zip(nodes, sessions, strict=True)
            ]
            settle_heap()  # start-up is over, and no slot has run yet
            for agent in agents:
                agent.start()
                stack.callback(agent.stop)
            ready.set()
            while not stop.wait(0.2):
                pass
    except KeyboardInterrupt:
        pass  # the parent stops us through ``stop``; Ctrl-C reaches both processes


@dataclasses.dataclass(frozen=True, slots=True)
class _NodesClock:
    """Start-up hand-shake with the nodes' process: ``loaded`` (set by the nodes), then
    ``epoch`` (wall-clock TDMA epoch, s) and ``go`` (set by the demo)."""

    loaded: Any
    go: Any
    epoch: Any


def _table(
    out: TrackerOutput | None,
    health: dict[str, NodeHealth],
    truth: list[dict[str, Any]],
    elapsed: float,
    score: DemoScore,
) -> Group:
    tracks = Table(title=f"uwbnet demo  t = {elapsed:6.1f} s", expand=False)
    for col in ("id", "x [m]", "y [m]", "vx [m/s]", "vy [m/s]", "w"):
        tracks.add_column(col, justify="right")
    if out is not None:
        for tr in out.tracks:
            tracks.add_row(
                str(tr.id),
                f"{tr.x:6.2f}",
                f"{tr.y:6.2f}",
                f"{tr.vx:5.2f}",
                f"{tr.vy:5.2f}",
                f"{tr.w:4.2f}",
            )
    s = score.as_dict()
    tracks.caption = (
        f"{len(out.tracks) if out else 0} tracks / {len(truth)} people | "
        f"OSPA {s['ospa_mean']:.2f} m | count ok {100 * s['card_correct_fraction']:.0f} %"
    )
    nodes = Table(title="nodes")
    for col in ("node", "alive", "acquired", "late", "drops", "det/s", "latency ms", "cpu %"):
        nodes.add_column(col, justify="right")
    for node, h in sorted(health.items()):
        st = h.last_status
        rate = h.detections / elapsed if elapsed > 0 else 0.0
        nodes.add_row(
            node,
            "yes" if h.alive else "[red]LOST[/red]",
            str(st.acquired) if st else "-",
            str(st.late_slots) if st else "-",
            str(st.dropped) if st else "-",
            f"{rate:5.1f}",
            f"{h.latency_ms:5.1f}" if math.isfinite(h.latency_ms) else "-",
            f"{100 * st.cpu:4.1f}" if st else "-",
        )
    return Group(tracks, nodes)


def _wait_for_nodes(event: Any, proc: Any, timeout: float, what: str) -> None:
    """Wait for the nodes' process to set ``event``; a one-line error if it exits or times out."""
    deadline = time.monotonic() + timeout
    while not event.wait(0.2):
        if not proc.is_alive():
            raise RuntimeError(
                f"the simulated nodes' process exited (code {proc.exitcode}) before it could {what}"
            )
        if time.monotonic() > deadline:
            raise RuntimeError(f"the simulated nodes did not {what} within {timeout:.0f} s")


def run_demo(config: DemoConfig, console: Console | None = None) -> dict[str, Any]:
    """Run the demo; returns its summary (also printed). Stops cleanly on KeyboardInterrupt."""
    console = console or Console()
    network = SimNetwork(config.scenario, config.seed)
    hub = f"tcp/127.0.0.1:{free_tcp_port()}"
    score = DemoScore()
    summary: dict[str, Any] = {}
    with contextlib.ExitStack() as stack:
        fusion_session = stack.enter_context(zenoh.open(session_config(listen=[hub])))
        # The nodes run in their own process (spawned: zenoh sessions do not survive fork),
        # as on separate hosts, and so that the fusion center has a core of its own.
        ctx = multiprocessing.get_context("spawn")
        ready, stop_nodes = ctx.Event(), ctx.Event()
        clock = _NodesClock(ctx.Event(), ctx.Event(), ctx.Value("d", 0.0))
        recording = config.publish_ir or bool(config.record)
        nodes_proc = ctx.Process(
            target=_run_nodes,
            args=(
                config.scenario,
                config.seed,
                config.net,
                hub,
                clock,
                recording,
                ready,
                stop_nodes,
            ),
            name="uwbnet-nodes",
        )
        nodes_proc.start()
        stack.callback(nodes_proc.join, 10.0)
        stack.callback(stop_nodes.set)
        # A cold numba cache costs the nodes' process several seconds of compiling.
        _wait_for_nodes(clock.loaded, nodes_proc, 120.0, "load")
        # Network time is wall-clock time; scenario time 0 is the TDMA epoch, a little ahead so
        # that every node has joined before the first frame.
        start = time.time() + 1.0
        fusion = FusionService(
            fusion_session,
            FusionConfig(
                net=config.net,
                method=config.method,
                imaging=LiveImagingConfig(rate=config.image_rate),
            ),
            epoch=start,
        )
        fusion.start()
        stack.callback(fusion.stop)
        web_url = ""
        if config.web is not None:
            from fusion_center.viewer.live import start_web_view
            from fusion_center.viewer.server import WebViewConfig
            from fusion_center.viewer.state import floor_plan

            server, stop_web = start_web_view(
                fusion,
                WebViewConfig(port=config.web, host=config.web_host),
                floor_plan(config.scenario),
            )
            stack.callback(stop_web)
            web_url = server.url
        recorder = None
        if config.record:
            rec_session = stack.enter_context(zenoh.open(session_config(connect=[hub])))
            from fusion_center.viewer.state import floor_plan

            recorder = NetworkRecorder(
                rec_session, config.net, config.record, walls=floor_plan(config.scenario)
            )
            recorder.start()
            stack.callback(recorder.stop)
        settle_heap()
        clock.epoch.value = start
        clock.go.set()
        n_nodes = len(network.node_infos())
        _wait_for_nodes(ready, nodes_proc, 30.0, "start")
        console.print(
            f"uwbnet demo: scenario {config.scenario.name}, {n_nodes} nodes, fusion "
            f"{config.method}, zenoh peers on {hub}"
            + (f", recording {config.record}" if config.record else "")
            + (f", live view {web_url}" if web_url else "")
        )
        last_scored = None
        live_ctx = (
            Live(console=console, refresh_per_second=4, transient=False)
            if console.is_terminal
            else contextlib.nullcontext()
        )
        try:
            with live_ctx as live:
                next_line = time.time()
                while True:
                    now = time.time()
                    elapsed = now - start
                    if elapsed >= config.duration:
                        break
                    out, health = fusion.snapshot()
                    truth = network.truth(max(elapsed, 0.0))
                    if out is not None and out is not last_scored and out.t - start > 2.0:
                        txy = np.array([(p["x"], p["y"]) for p in network.truth(out.t - start)])
                        score.add(out, txy.reshape(-1, 2))
                        last_scored = out
                    if live is not None:
                        live.update(_table(out, health, truth, elapsed, score))
                    elif now >= next_line:
                        next_line = now + 2.0
                        n_tr = len(out.tracks) if out else 0
                        console.print(
                            f"t={elapsed:6.1f} s  tracks={n_tr}  people={len(truth)}  "
                            f"ospa_mean={score.as_dict()['ospa_mean']:.3f} m"
                        )
                    time.sleep(0.05)
        except KeyboardInterrupt:
            console.print("interrupted: stopping")
        out, health = fusion.snapshot()
        summary = {
            "scenario": config.scenario.name,
            "duration_s": round(time.time() - start, 2),
            "nodes": n_nodes,
            "fusion_updates": fusion.core.counters.updates,
            "late_detections": fusion.core.counters.late,
            "estimates_beyond_range": fusion.core.counters.beyond_range,
            "decode_errors": fusion.decode_errors,
            "handler_errors": fusion.handler_errors,
            "missing_detections": sum(h.missing for h in health.values()),
            "acquired": sum(h.last_status.acquired for h in health.values() if h.last_status),
            "late_slots": sum(h.last_status.late_slots for h in health.values() if h.last_status),
            "final_tracks": len(out.tracks) if out else 0,
            "latency_ms_max": round(max((h.latency_ms for h in health.values()), default=0), 1),
            **score.as_dict(),
        }
        if recorder is not None:
            summary["recorded_dropped"] = recorder.dropped
        if fusion.imaging is not None:
            c = fusion.imaging.counters
            summary |= {"image_steps": c.steps, "image_rows": c.rows, "image_rejected": c.rejected}
    # The recording is complete only once the exit stack has closed it.
    if config.record:
        summary["recording"] = config.record
    return summary
