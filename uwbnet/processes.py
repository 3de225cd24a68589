"""The processes of a field deployment: ``run(config, stop) -> int`` for each command.

Each holds its zenoh session and declarations in a ``with`` and returns when ``stop`` is set
(SIGTERM or SIGINT through :func:`stop_on_signals`), after closing everything. Opening a
session is retried once a second until it succeeds or the process is stopped, so a node
started before its router waits for it instead of failing; once open, zenoh itself re-attaches
a client whose link or router went away.
"""

from __future__ import annotations

import contextlib
import gc
import json
import logging
import math
import os
import re
import signal
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import zenoh

from protocol import ProtocolError, Tracks, keys
from protocol.recording import read_recording
from protocol.transport import FifoChannel
from uwbnet.config import (
    ConfigError,
    FusionFile,
    NodeFile,
    RecordFile,
    SimNodeFile,
    zenoh_config,
)

log = logging.getLogger(__name__)


@contextlib.contextmanager
def stop_on_signals() -> Iterator[threading.Event]:
    """An event set by SIGTERM or SIGINT while the block runs (previous handlers restored)."""
    stop = threading.Event()
    previous = {}

    def handler(signum: int, frame: Any) -> None:
        log.info("signal %d: stopping", signum)
        stop.set()

    for sig in (signal.SIGTERM, signal.SIGINT):
        previous[sig] = signal.signal(sig, handler)
    try:
        yield stop
    finally:
        for sig, h in previous.items():
            signal.signal(sig, h)


def open_session(
    make_config: Callable[[], zenoh.Config], stop: threading.Event, what: str
) -> zenoh.Session | None:
    """Open a zenoh session; None if stopped first.

    A router that cannot be reached yet is waited for (retried every second); any other
    failure (a listening endpoint that cannot be opened, a bad TLS setup) is a
    :class:`ConfigError`: retrying would not fix it.
    """
    warned = False
    while not stop.is_set():
        try:
            return zenoh.open(make_config())
        except zenoh.ZError as exc:
            # zenoh appends " at /path/to/source.rs:line." to its messages.
            detail = re.sub(r"\s+at /\S+\.rs:\d+\.?", "", str(exc).splitlines()[0]).strip()
            if "Unable to connect" not in detail:
                raise ConfigError(f"{what}: zenoh: {detail}") from None
            if not warned:
                log.warning("%s: cannot join the network yet (%s); retrying", what, detail)
                warned = True
            stop.wait(1.0)
    return None


def settle_heap() -> None:
    """Collect once, then move every object alive now into the permanent generation.

    Call it when a real-time process has finished starting (imports, compiled kernels, the
    scene, sessions). Python's cyclic collector otherwise makes a full (generation 2) pass
    over that start-up heap some seconds into the run: 60-80 ms of CPU in whichever thread
    allocates, measured in every node process and the hub of ``uwbnet scale`` (gc callbacks
    and per-slot thread times; stop-17 note of issue 11), which drops 4-6 frames of that
    process's slots. Frozen objects are never scanned again, so later full passes cover only
    what the run itself allocates (``gc.freeze``, Python >= 3.7).
    """
    gc.collect()
    gc.freeze()


def _wait(stop: threading.Event, duration: float = math.inf) -> None:
    deadline = time.monotonic() + duration
    while not stop.wait(min(0.2, max(deadline - time.monotonic(), 0.0))):
        if time.monotonic() >= deadline:
            return


# --- node ------------------------------------------------------------------------------------


def run_node(cfg: NodeFile, stop: threading.Event) -> int:
    """One node agent on the driver of ``cfg.driver``; returns the exit status."""
    from node_agent.agent import AgentConfig, NodeAgent
    from node_agent.drivers import get_driver_class

    log.info("node config: %s", cfg.model_dump_json())
    driver_cls = get_driver_class(cfg.driver.name)
    options = dict(cfg.driver.options)
    if cfg.driver.name == "serial":
        options.setdefault("node", cfg.node)
        options.setdefault("role", cfg.describe.role)
        options.setdefault("pose", tuple(cfg.describe.pose))
    try:
        driver = driver_cls(**options)
    except TypeError as exc:
        from node_agent.drivers import DriverError

        raise DriverError(f"driver.options: {exc}") from None
    with driver:
        session = open_session(lambda: zenoh_config(cfg.zenoh, cfg.net), stop, cfg.node)
        if session is None:
            return 0
        with session:
            agent = NodeAgent(
                session,
                driver,
                AgentConfig(
                    node=cfg.node,
                    net=cfg.net,
                    publish_ir=cfg.publish_ir,
                    status_period=cfg.status_period,
                ),
            )
            settle_heap()
            agent.start()
            try:
                _wait(stop)
            finally:
                agent.stop()
    return 0


# --- simulated nodes -------------------------------------------------------------------------


def fetch_epoch(session: zenoh.Session, net: str, stop: threading.Event) -> float | None:
    """The TDMA epoch (network s) of the fusion center's schedule, asked once a second."""
    from protocol import TdmaSchedule

    while not stop.is_set():
        try:
            for reply in session.get(keys.schedule_key(net), timeout=1.0):
                if reply.ok is not None:
                    try:
                        return TdmaSchedule.from_wire(reply.ok.payload.to_bytes()).epoch
                    except ProtocolError as exc:
                        log.warning("schedule rejected: %s", exc)
        except zenoh.ZError as exc:
            log.debug("schedule query: %s", exc)
        stop.wait(1.0)
    return None


def run_simnode(cfg: SimNodeFile, stop: threading.Event) -> int:
    """Simulated nodes of a scenario, with one node agent each, on one zenoh session."""
    from node_agent.agent import AgentConfig, NodeAgent
    from sim_nodes.driver import SimulatedDriver
    from sim_nodes.network import SimNetwork
    from sim_nodes.scene import load_scenario
    from uwbnet.demo import truth_loop

    log.info("simnode config: %s", cfg.model_dump_json())
    network = SimNetwork(load_scenario(cfg.scenario), cfg.seed)
    nodes = cfg.nodes or network.node_ids
    unknown = sorted(set(nodes) - set(network.node_ids))
    if unknown:
        raise ConfigError(f"nodes: {unknown[0]!r} is not a node of scenario {cfg.scenario}")
    session = open_session(lambda: zenoh_config(cfg.zenoh, cfg.net), stop, "simnode")
    if session is None:
        return 0
    with session, contextlib.ExitStack() as stack:
        epoch = fetch_epoch(session, cfg.net, stop)
        if epoch is None:
            return 0
        log.info("scenario time 0 = TDMA epoch %.3f", epoch)
        if cfg.truth:
            truth_stop = threading.Event()
            t = threading.Thread(
                target=truth_loop,
                args=(session, network, cfg.net, epoch, truth_stop),
                name="truth",
            )
            t.start()
            stack.callback(t.join, 2.0)
            stack.callback(truth_stop.set)
        agents = [
            NodeAgent(
                session,
                stack.enter_context(SimulatedDriver(network, node, start=epoch)),
                AgentConfig(
                    node=node,
                    net=cfg.net,
                    publish_ir=cfg.publish_ir,
                    status_period=cfg.status_period,
                ),
            )
            for node in nodes
        ]
        settle_heap()  # before the slots run, not in one of them
        for agent in agents:
            agent.start()
            stack.callback(agent.stop)
        _wait(stop)
    return 0


# --- fusion ----------------------------------------------------------------------------------


def _tracks_line(msg: Tracks) -> str:
    """One JSONL record (``uwbnet track`` format) of a ``tracks`` message."""
    return json.dumps(
        {
            "t": round(msg.t, 6),
            "tracks": [
                {
                    "id": tr.id,
                    "x": round(tr.x, 4),
                    "y": round(tr.y, 4),
                    "vx": round(tr.vx, 4),
                    "vy": round(tr.vy, 4),
                }
                for tr in msg.tracks
            ],
            "n_estimate": round(msg.n_estimate, 4),
        },
        separators=(",", ":"),
    )


def _write_tracks(f: Any, inbox: FifoChannel[bytes]) -> None:
    for payload in inbox.drain():
        try:
            f.write(_tracks_line(Tracks.from_wire(payload)) + "\n")
        except ProtocolError as exc:
            log.warning("tracks not written: %s", exc)
    f.flush()


def run_fusion(cfg: FusionFile, stop: threading.Event) -> int:
    """The fusion center (the network's router in ``router`` mode)."""
    from fusion_center.image_runtime import LiveImagingConfig
    from fusion_center.imaging.incremental import ImagingConfig
    from fusion_center.service import FusionConfig, FusionService

    log.info("fusion config: %s", cfg.model_dump_json())
    jsonl = Path(cfg.tracks_jsonl) if cfg.tracks_jsonl else None
    if jsonl is not None and not jsonl.parent.exists():
        raise ConfigError(f"tracks_jsonl: directory does not exist: {jsonl.parent}")
    session = open_session(lambda: zenoh_config(cfg.zenoh, cfg.net), stop, "fusion")
    if session is None:
        return 0
    with session, contextlib.ExitStack() as stack:
        fusion = FusionService(
            session,
            FusionConfig(
                net=cfg.net,
                service_id=cfg.service_id,
                method=cfg.method,
                frame_period=cfg.frame_period,
                imaging=LiveImagingConfig(
                    rate=cfg.image_rate, imaging=ImagingConfig(method=cfg.image_method)
                ),
            ),
        )
        if jsonl is not None:
            inbox: FifoChannel[bytes] = FifoChannel(100000)
            partial = jsonl.with_name(jsonl.name + ".partial")
            # Exit order (LIFO): stop the service, undeclare, write what is queued, close, rename.
            stack.callback(os.replace, partial, jsonl)
            f = stack.enter_context(open(partial, "w", encoding="utf-8"))
            stack.callback(_write_tracks, f, inbox)
            sub = session.declare_subscriber(
                keys.fusion_key(cfg.net, "tracks"), lambda s: inbox.put(s.payload.to_bytes())
            )
            stack.callback(sub.undeclare)
        fusion.start()
        stack.callback(fusion.stop)
        if cfg.web is not None:
            stack.callback(_start_web(fusion, cfg))
        if cfg.mapping:
            from fusion_center.mapping_service import MappingConfig, MappingService

            mapping = MappingService(session, MappingConfig(net=cfg.net, service_id=cfg.service_id))
            mapping.start()
            stack.callback(mapping.stop)
        settle_heap()
        while not stop.wait(0.2):
            if jsonl is not None:
                _write_tracks(f, inbox)
    return 0


def _start_web(fusion: Any, cfg: FusionFile) -> Callable[[], None]:
    """Start the ``[web]`` live view of ``fusion``; returns its stop function."""
    from fusion_center.viewer.live import start_web_view
    from fusion_center.viewer.server import WebViewConfig
    from fusion_center.viewer.state import floor_plan

    assert cfg.web is not None
    walls = None
    if cfg.web.scenario:
        from sim_nodes.scene import ScenarioError, load_scenario

        try:
            walls = floor_plan(load_scenario(cfg.web.scenario))
        except ScenarioError as exc:
            raise ConfigError(f"web.scenario: {exc}") from None
    try:
        server, stop_web = start_web_view(
            fusion, WebViewConfig(port=cfg.web.port, host=cfg.web.host, rate=cfg.web.rate), walls
        )
    except OSError as exc:
        raise ConfigError(
            f"web: cannot serve on {cfg.web.host}:{cfg.web.port}: {exc.strerror}"
        ) from None
    log.info("live web view on %s", server.url)
    return stop_web


# --- record and replay -----------------------------------------------------------------------


def run_record(
    cfg: RecordFile,
    out: Path,
    stop: threading.Event,
    duration: float,
    walls: list[list[float]] | None = None,
) -> dict[str, Any]:
    """Record network ``cfg.net`` into ``out`` until stopped or ``duration`` s have passed
    (with Foxglove ``/viz`` channels, ``walls`` as their floor plan)."""
    from fusion_center.recorder import NetworkRecorder

    session = open_session(lambda: zenoh_config(cfg.zenoh, cfg.net), stop, "record")
    if session is None:
        return {"out": None, "messages": 0}
    with session:
        recorder = NetworkRecorder(session, cfg.net, out, walls=walls)
        recorder.start()
        log.info("recording network %s to %s", cfg.net, out)
        try:
            _wait(stop, duration)
        finally:
            recorder.stop()
    return {
        "out": str(out),
        "messages": recorder.writer.count,
        "rejected": recorder.rejected,
        "dropped": recorder.dropped,
    }


def run_replay(
    cfg: RecordFile, path: Path, stop: threading.Event, rate: float, wait_subscriber: float = 2.0
) -> dict[str, Any]:
    """Republish the payloads of a recording, unchanged, on their topics.

    ``rate`` is the speed-up over the recording's own timing (1: real time, ``inf``: as fast
    as the network takes them). ``node_info`` is also served from queryables, as the nodes
    themselves would. Publishers use BLOCK congestion control: a replay loses nothing. Before
    the first message, up to ``wait_subscriber`` s are given for a subscriber (a recorder, the
    fusion center) to become reachable: zenoh drops what nobody has subscribed to yet.
    """
    session = open_session(lambda: zenoh_config(cfg.zenoh, cfg.net), stop, "replay")
    if session is None:
        return {"published": 0}
    published = 0
    infos: dict[str, bytes] = {}
    with session, contextlib.ExitStack() as stack:
        pubs: dict[str, Any] = {}

        def publisher(topic: str) -> Any:
            pub = pubs.get(topic)
            if pub is None:
                pub = session.declare_publisher(
                    topic, congestion_control=zenoh.CongestionControl.BLOCK
                )
                pubs[topic] = pub
                stack.callback(pub.undeclare)
            return pub

        t0_rec: float | None = None
        t0_wall = time.monotonic()
        for rec in read_recording(path):
            if stop.is_set():
                break
            if t0_rec is None:
                t0_rec = rec.t
            if math.isfinite(rate):
                wait = (rec.t - t0_rec) / rate - (time.monotonic() - t0_wall)
                if wait > 0 and stop.wait(wait):
                    break
            if rec.kind == "node_info" and rec.topic not in infos:
                infos[rec.topic] = rec.payload

                def reply(query: zenoh.Query, topic: str = rec.topic) -> None:
                    query.reply(topic, infos[topic])

                q = session.declare_queryable(rec.topic, reply)
                stack.callback(q.undeclare)
            elif rec.kind == "node_info":
                infos[rec.topic] = rec.payload
            pub = publisher(rec.topic)
            if published == 0:
                deadline = time.monotonic() + wait_subscriber
                while not pub.matching_status.matching and time.monotonic() < deadline:
                    stop.wait(0.02)
                t0_wall = time.monotonic()
            pub.put(rec.payload)
            published += 1
    return {"published": published, "topics": len(pubs)}
