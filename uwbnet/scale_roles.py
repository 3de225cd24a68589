"""The processes of ``uwbnet scale``: ``python -m uwbnet.scale_roles ROLE CONFIG_JSON``.

Roles:

* ``hub``: the zenoh router, the TDMA schedule and either the whole fusion center (one
  worker) or the gateway of the cell workers; it also keeps every ``fusion/tracks`` message
  with its arrival time and, when stopped, writes them to ``tracks.jsonl`` (``uwbnet track``
  format plus ``recv``, the arrival time, and ``t_acq``, the acquisition times used).
* ``nodes``: a group of simulated bat-type nodes with their node agents on one zenoh session.
* ``worker``: the fusion worker of one cell (fuses the nodes of its cell plus a margin).

Nodes and workers print ``started`` once initialised (before they wait for the router); each
role prints ``ready`` on stdout once it is up, and stops cleanly on SIGTERM. The scenario is
rebuilt in every process from ``(nodes, people, seed)``
(:func:`sim_nodes.building.building_scenario`); people move deterministically in scenario
time, whose 0 is the schedule's TDMA epoch.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import logging
import math
import os
import sys
import threading
import time
from pathlib import Path
from typing import Any

import zenoh

from protocol import ProtocolError, Tracks, keys
from protocol.transport import session_config
from uwbnet.processes import settle_heap

log = logging.getLogger(__name__)

#: People farther than this from a node are left out of its simulation (m): more than one
#: room away, behind at least one partition, their echoes are far below the noise.
PEOPLE_RANGE = 20.0
#: ``--threads batch``: a node process serves together the slots of its nodes that start within
#: this time (s) of the earliest (half a 20 ms frame: a process's adjacent slots, one frame's).
BATCH_WINDOW = 0.01
#: Fusion worker margin: a cell's worker fuses the nodes within this distance of its cell (m).
CELL_MARGIN = 6.0


def building(cfg: dict[str, Any]) -> Any:
    from sim_nodes.building import building_scenario

    return building_scenario(cfg["nodes"], cfg["people"], cfg["seed"])


def cells(cfg: dict[str, Any]) -> Any:
    from fusion_center.tracking.cells import StripCells
    from sim_nodes.building import building_length

    return StripCells.even(0.0, building_length(cfg["nodes"]), cfg["workers"])


def wall_sight(scenario: Any) -> Any:
    """The GM-PHD's wall-aware detection probability for a building: its walls, taken from
    the building's description (the same every process rebuilds), not from truth."""
    from fusion_center.tracking.walls import WallSightModel

    return WallSightModel([w.start for w in scenario.walls], [w.end for w in scenario.walls])


def _see_walls(fusion: Any, cfg: dict[str, Any]) -> None:
    tracker = fusion.core.tracker
    if hasattr(tracker, "sight"):
        tracker.sight = wall_sight(building(cfg))


def _core(cfg: dict[str, Any]) -> Any:
    """The fusion core's frame assembly, with the run's ``frame_lag`` and ``frame_wait``."""
    from fusion_center.core import FusionCoreConfig

    return FusionCoreConfig(frame_lag=cfg.get("frame_lag", 2), frame_wait=cfg.get("frame_wait", 0))


def _session(cfg: dict[str, Any], *, router: bool = False) -> zenoh.Session:
    if router:
        return zenoh.open(session_config(mode="router", listen=[cfg["listen"]]))
    conf = session_config(mode="client", connect=[cfg["connect"]])
    conf.insert_json5("connect/timeout_ms", "-1")  # wait for the router (DESIGN.md)
    return zenoh.open(conf)


def _ready(what: str) -> None:
    _say(f"ready {what}")


def _say(line: str) -> None:
    """A line on stdout, which the ``uwbnet scale`` orchestrator reads."""
    sys.stdout.write(line + "\n")
    sys.stdout.flush()


def run_hub(cfg: dict[str, Any], stop: threading.Event) -> None:
    """Router, schedule, fusion (one worker) or gateway (several), tracks recorder."""
    from fusion_center.gateway import CellGateway
    from fusion_center.service import FusionConfig, FusionService

    received: list[tuple[float, bytes]] = []
    n_nodes = cfg["nodes"]
    with _session(cfg, router=True) as session, contextlib.ExitStack() as stack:
        # Only stamp and keep in the callback: decoding waits until the run is over, so the
        # measurement takes no CPU from the fusion in this process.
        sub = session.declare_subscriber(
            keys.fusion_key(cfg["net"], "tracks"),
            lambda s: received.append((time.time(), s.payload.to_bytes())),
        )
        stack.callback(sub.undeclare)
        single = cfg["workers"] == 1
        # Scenario time 0 (the TDMA epoch) is set now that the hub is up, not when it was
        # launched: the people are where the scenario says when the measurement starts.
        settle_heap()
        epoch = time.time() + 0.5
        fusion = FusionService(
            session, FusionConfig(net=cfg["net"], track=single, core=_core(cfg)), epoch=epoch
        )
        _see_walls(fusion, cfg)
        fusion.start()
        stack.callback(fusion.stop)
        if not single:
            gateway = CellGateway(session, cfg["net"], cells(cfg))
            gateway.start()
            stack.callback(gateway.stop)
        _ready(f"hub {epoch!r}")
        announced = False
        while not stop.wait(0.1):
            sched = fusion.schedule
            if not announced and sched is not None and len(sched.slots) >= n_nodes:
                _say(f"scheduled {len(sched.slots)}")
                announced = True
        # what the fusion core dropped (late: detections whose frame was already fused)
        counters = dataclasses.asdict(fusion.core.counters)
    _write_json(Path(cfg["out"]) / "fusion_counters.json", counters)
    _write_tracks(Path(cfg["out"]) / "tracks.jsonl", received)


def _write_json(path: Path, data: dict[str, Any]) -> None:
    partial = path.with_name(path.name + ".partial")
    partial.write_text(json.dumps(data), encoding="utf-8")
    partial.replace(path)


def _write_tracks(path: Path, received: list[tuple[float, bytes]]) -> None:
    partial = path.with_name(path.name + ".partial")
    with open(partial, "w", encoding="utf-8") as f:
        for recv, payload in received:
            try:
                msg = Tracks.from_wire(payload)
            except ProtocolError as exc:
                log.warning("tracks not written: %s", exc)
                continue
            line = {
                "t": msg.t,
                "recv": recv,
                "tracks": [
                    {"id": tr.id, "x": tr.x, "y": tr.y, "vx": tr.vx, "vy": tr.vy}
                    for tr in msg.tracks
                ],
                "n_estimate": msg.n_estimate,
                "t_acq": msg.extra.get("t_acq", []),
            }
            f.write(json.dumps(line, separators=(",", ":")) + "\n")
    partial.replace(path)


def sim_window(cfg: dict[str, Any], radar: Any) -> int | None:
    """Samples of the simulated radar window ``cfg["ir_window"]`` (m of bistatic range, None:
    the whole period) for ``radar`` (:class:`sim_nodes.radar.RadarConfig`): every sample
    whose range ``c (t0 + k / fs)`` is at most the window, at least one, at most ``n``."""
    from sim_nodes.radar import C

    metres = cfg.get("ir_window")
    if metres is None:
        return None
    # compared before the floor: a huge window (1e308 m) would overflow the integer
    samples = (metres / C - radar.t0) * radar.fs + 1e-9
    if not samples < radar.n:
        return radar.n
    return max(math.floor(samples) + 1, 1)


def agent_config(cfg: dict[str, Any], node: str) -> Any:
    """The node agent configuration of ``node`` in a ``nodes`` process: raw ``ir`` off, and
    the DSP's range window up to ``cfg["max_range"]`` m (None: the whole window)."""
    from node_agent.agent import AgentConfig
    from node_agent.dsp.pipeline import NodeDspConfig

    dsp = NodeDspConfig(max_range=cfg.get("max_range"))
    return AgentConfig(node=node, net=cfg["net"], publish_ir=False, dsp=dsp)


def run_nodes(cfg: dict[str, Any], stop: threading.Event) -> None:
    """Simulated nodes ``cfg["ids"]`` with their node agents (raw ``ir`` off)."""
    from node_agent.agent import NodeAgent
    from node_agent.group import SlotOrderGroup
    from sim_nodes.driver import SimulatedDriver
    from sim_nodes.network import SimNetwork
    from uwbnet.processes import fetch_epoch

    scenario = building(cfg)
    network = SimNetwork(
        scenario,
        cfg["seed"],
        people_range=PEOPLE_RANGE,
        window=sim_window(cfg, scenario.radar.config()),
    )
    _say("started")
    with _session(cfg) as session, contextlib.ExitStack() as stack:
        epoch = fetch_epoch(session, cfg["net"], stop)
        if epoch is None:
            return
        agents = []
        for node in cfg["ids"]:
            driver = stack.enter_context(SimulatedDriver(network, node, start=epoch))
            agents.append(NodeAgent(session, driver, agent_config(cfg, node)))
        # start-up is over (imports, kernels, scene, DSP state): its heap never needs scanning
        # again; collected before the slots run, not in one of them
        settle_heap()
        threads = cfg.get("threads", "agent")
        if threads in ("process", "batch"):
            # one acquisition thread serves the agents in slot order (no GIL hand-offs
            # between K workers whose slots follow each other); "batch": one wake-up per frame
            # for all of them, back to back (issue 11, stop 18 notes)
            batch = threads == "batch"
            group = SlotOrderGroup(
                agents,
                batch_window=BATCH_WINDOW if batch else 0,
                catch_up=cfg.get("catch_up", 0.0) if batch else 0.0,
                batches_per_wake=cfg.get("batches_per_wake", 1) if batch else 1,
                pipeline=cfg.get("pipeline", 0.0) if batch else 0.0,
            )
            group.start()
            stack.callback(group.stop)
        else:
            for agent in agents:
                agent.start()
                stack.callback(agent.stop)
        _ready(f"nodes {len(cfg['ids'])}")
        while not stop.wait(0.2):
            pass


def run_worker(cfg: dict[str, Any], stop: threading.Event) -> None:
    """The fusion worker of cell ``cfg["cell"]``."""
    from fusion_center.service import FusionConfig, FusionService

    cell = cfg["cell"]
    _say("started")
    with _session(cfg) as session:
        fusion = FusionService(
            session,
            FusionConfig(
                net=cfg["net"],
                service_id=f"fusion-cell{cell}",
                nodes=tuple(cfg["ids"]),
                schedule=False,
                tracks_key=keys.cell_tracks_key(cfg["net"], cell),
                core=_core(cfg),
            ),
        )
        _see_walls(fusion, cfg)
        settle_heap()
        fusion.start()
        try:
            _ready(f"worker {cell}")
            while not stop.wait(0.2):
                pass
        finally:
            fusion.stop()


ROLES = {"hub": run_hub, "nodes": run_nodes, "worker": run_worker}


def main(argv: list[str]) -> int:
    from uwbnet.processes import stop_on_signals

    logging.basicConfig(
        level=logging.WARNING, format="%(asctime)s %(levelname)s %(name)s: %(message)s"
    )
    role, cfg = argv[0], json.loads(argv[1])
    if cfg.get("rt_priority"):
        # Before any thread exists, so that zenoh's and ours inherit it: on a machine shared
        # with other work the TDMA slots otherwise wait 10-30 ms behind other processes' time
        # slices (issue 11, stop 17 notes).
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(cfg["rt_priority"]))
    with stop_on_signals() as stop:
        ROLES[role](cfg, stop)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
