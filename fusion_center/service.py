"""The fusion center process: zenoh subscribers -> :class:`FusionCore` -> publishers.

Holds the TDMA schedule (published on change and served by a queryable), follows node presence
through liveliness tokens, fetches ``node_info`` from the nodes' queryables, and publishes
``tracks`` after every processed frame. Callbacks only enqueue; one worker thread does the rest.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import threading
import time
from collections.abc import Callable
from typing import Any

import zenoh

from fusion_center.core import FusionCore, FusionCoreConfig
from fusion_center.localization.mobile import LocalizerConfig, PoseResult
from fusion_center.offline import make_tracker
from fusion_center.pose_core import PoseCore, poses_message
from fusion_center.tracking.base import TrackerOutput
from protocol import (
    Detections,
    NodeInfo,
    ProtocolError,
    Slot,
    Status,
    TdmaSchedule,
    Track,
    Tracks,
    decode,
    keys,
)
from protocol.errors import KeyExprError
from protocol.transport import FifoChannel, stop_worker

log = logging.getLogger(__name__)


@dataclasses.dataclass(frozen=True, slots=True, kw_only=True)
class FusionConfig:
    """Configuration of the fusion service.

    Parameters
    ----------
    net : network name.
    service_id : id of this service (liveliness token, ``src`` of its messages).
    method : tracking method, ``gmphd`` or ``image``.
    frame_period : TDMA frame period, s (50 impulse responses per second per transmitter).
    flush_after : a frame is processed at the latest this long (s) after its last detection.
    core : frame assembly parameters.
    localization : localization of mobile nodes from their ranging rounds (``poses``).
    """

    net: str = "demo"
    service_id: str = "fusion"
    method: str = "gmphd"
    frame_period: float = 0.02
    flush_after: float = 0.05
    core: FusionCoreConfig = dataclasses.field(default_factory=FusionCoreConfig)
    localization: LocalizerConfig = dataclasses.field(default_factory=LocalizerConfig)


@dataclasses.dataclass(slots=True)
class NodeHealth:
    """What the fusion center knows of one node's health."""

    alive: bool = False
    last_status: Status | None = None
    detections: int = 0
    last_det_t: float = math.nan
    latency_ms: float = math.nan


class FusionService:
    """The fusion center on an open zenoh ``session``. ``start``/``stop`` are idempotent."""

    def __init__(
        self,
        session: zenoh.Session,
        config: FusionConfig,
        *,
        clock: Callable[[], float] = time.time,
        epoch: float | None = None,
    ) -> None:
        self.session, self.config, self.clock = session, config, clock
        self.core = FusionCore(make_tracker(config.method), config.core)
        self.pose_core = PoseCore(config.localization)
        self.latest_poses: dict[str, PoseResult] = {}
        self.epoch = clock() if epoch is None else epoch
        self._inbox: FifoChannel[tuple[str, str, bytes]] = FifoChannel(8192)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._decl: list[Any] = []
        self._lock = threading.Lock()
        self.health: dict[str, NodeHealth] = {}
        self.latest: TrackerOutput | None = None
        self.decode_errors = 0
        self._schedule: TdmaSchedule | None = None
        self._schedule_bytes = b""
        self._seq = {"tracks": 0, "schedule": 0, "poses": 0}
        self._want_info: set[str] = set()
        self._asked: dict[str, float] = {}

    # -- lifecycle -------------------------------------------------------------------------

    def start(self) -> None:
        if self._thread is not None:
            return
        net, s = self.config.net, self.session
        put = self._inbox.put
        self._pub_tracks = s.declare_publisher(
            keys.fusion_key(net, "tracks"), congestion_control=zenoh.CongestionControl.BLOCK
        )
        self._pub_schedule = s.declare_publisher(
            keys.schedule_key(net), congestion_control=zenoh.CongestionControl.BLOCK
        )
        self._pub_poses = s.declare_publisher(
            keys.fusion_key(net, "poses"), congestion_control=zenoh.CongestionControl.BLOCK
        )
        self._decl += [self._pub_tracks, self._pub_schedule, self._pub_poses]
        for leaf in ("det", "info", "status"):
            self._decl.append(
                s.declare_subscriber(
                    keys.all_nodes_key(net, leaf),
                    lambda sample, leaf=leaf: put((leaf, str(sample.key_expr), _bytes(sample))),
                )
            )
        self._decl.append(
            s.liveliness().declare_subscriber(
                keys.all_alive_key(net),
                lambda sample: put(("alive", str(sample.key_expr), str(sample.kind).encode())),
                history=True,
            )
        )
        self._decl.append(s.declare_queryable(keys.schedule_key(net), self._on_schedule_query))
        self._decl.append(s.liveliness().declare_token(keys.alive_key(net, self.config.service_id)))
        self._publish_schedule()
        self._thread = threading.Thread(target=self._run, name="fusion", daemon=True)
        self._thread.start()
        log.info(
            "fusion center %s started on net %s (%s)",
            self.config.service_id,
            net,
            self.config.method,
        )

    def stop(self) -> None:
        stop_worker(self._stop, self._thread, self._decl)
        self._thread = None

    def _on_schedule_query(self, query: zenoh.Query) -> None:
        if self._schedule_bytes:
            query.reply(keys.schedule_key(self.config.net), self._schedule_bytes)

    # -- state for viewers -----------------------------------------------------------------

    def snapshot(self) -> tuple[TrackerOutput | None, dict[str, NodeHealth]]:
        """The latest tracker output and a copy of the node health table."""
        with self._lock:
            return self.latest, {k: dataclasses.replace(v) for k, v in self.health.items()}

    # -- worker ----------------------------------------------------------------------------

    def _run(self) -> None:
        last_item = time.monotonic()
        while not self._stop.is_set():
            item = self._inbox.get(timeout=self.config.flush_after)
            if item is None:
                if time.monotonic() - last_item >= self.config.flush_after:
                    self._publish(self.core.flush())
                self._fetch_infos()
                continue
            last_item = time.monotonic()
            leaf, key, payload = item
            try:
                self._handle(leaf, key, payload)
            except ProtocolError as exc:
                self.decode_errors += 1
                log.warning("rejected %s: %s", key, exc)
            self._fetch_infos()

    def _handle(self, leaf: str, key: str, payload: bytes) -> None:
        if leaf == "alive":
            self._on_alive(key, payload.decode())
            return
        msg = decode(payload)
        if leaf == "det" and isinstance(msg, Detections):
            if msg.src not in self.core.nodes:
                self._want_info.add(msg.src)
            with self._lock:
                h = self.health.setdefault(msg.src, NodeHealth())
                h.detections += 1
                h.last_det_t = msg.t
                h.latency_ms = (self.clock() - msg.t) * 1e3
            if msg.links is not None:
                self._publish_pose(self.pose_core.add_ranging(msg))
                # anchors ranged before their description arrived: ask their queryables
                self._want_info |= self.pose_core.unknown_anchors
            else:
                self._publish(self.core.add_detections(msg))
        elif leaf == "info" and isinstance(msg, NodeInfo):
            self._add_node(msg)
        elif leaf == "status" and isinstance(msg, Status):
            with self._lock:
                self.health.setdefault(msg.src, NodeHealth()).last_status = msg
        else:
            raise ProtocolError(f"kind {msg.KIND!r} on {key}")

    def _on_alive(self, key: str, kind: str) -> None:
        try:
            node = keys.parse_key(key).node
        except KeyExprError:
            return
        if node is None or node == self.config.service_id:
            return
        alive = kind.endswith("PUT")
        with self._lock:
            self.health.setdefault(node, NodeHealth()).alive = alive
        if alive and node not in self.core.nodes:
            self._want_info.add(node)
        log.info("node %s %s", node, "joined" if alive else "lost")
        self._reschedule()

    def _fetch_infos(self) -> None:
        """Ask the ``node_info`` queryables of nodes whose description is missing.

        Never blocks the worker: replies arrive through a callback into the inbox, like any
        ``info`` sample. A node is asked at most once per second.
        """
        if not self._want_info:
            return
        now = time.monotonic()
        wanted, self._want_info = self._want_info, set()
        put = self._inbox.put
        for node in sorted(wanted):
            if node in self.core.nodes or now - self._asked.get(node, -math.inf) < 1.0:
                continue
            self._asked[node] = now

            def on_reply(reply: zenoh.Reply) -> None:
                if reply.ok is not None:
                    put(("info", str(reply.ok.key_expr), reply.ok.payload.to_bytes()))

            try:
                self.session.get(
                    keys.node_key(self.config.net, node, "info"), on_reply, timeout=1.0
                )
            except zenoh.ZError as exc:
                log.warning("node_info of %s: %s", node, exc)

    def _add_node(self, info: NodeInfo) -> None:
        known = self.core.nodes.get(info.src)
        self.core.add_node(info)
        self.pose_core.add_node(info)
        if known is None or known.antennas != info.antennas:
            self._reschedule()

    def _reschedule(self) -> None:
        """One slot per transmitting antenna of every live node with a known description."""
        with self._lock:
            alive = {n for n, h in self.health.items() if h.alive}
        txs = sorted(
            f"{node}/{name}"
            for node, info in self.core.nodes.items()
            if node in alive
            for name, a in info.antennas.items()
            if a.tx
        )
        old = [s.tx for s in self._schedule.slots] if self._schedule else None
        if txs == old:
            return
        self._publish_schedule(txs)

    def _publish_schedule(self, txs: list[str] | None = None) -> None:
        txs = txs or []
        fp = self.config.frame_period
        dur = fp / max(len(txs), 1)
        sched = TdmaSchedule(
            src=self.config.service_id,
            seq=self._next("schedule"),
            t=self.clock(),
            frame_period=fp,
            epoch=self.epoch,
            slots=tuple(
                Slot(slot=i, tx=tx, start=i * dur, duration=dur) for i, tx in enumerate(txs)
            ),
        )
        self._schedule = sched
        self.core.expected = frozenset(tx.partition("/")[0] for tx in txs)
        self._schedule_bytes = sched.to_wire()
        self._pub_schedule.put(self._schedule_bytes)
        log.info("TDMA schedule: %d slots of %.2f ms", len(txs), dur * 1e3)

    def _publish(self, outputs: list[TrackerOutput]) -> None:
        for out in outputs:
            msg = Tracks(
                src=self.config.service_id,
                seq=self._next("tracks"),
                t=out.t,
                tracks=tuple(
                    Track(id=tr.id, x=tr.x, y=tr.y, vx=tr.vx, vy=tr.vy, cov=tr.cov.tolist(), w=tr.w)
                    for tr in out.tracks
                ),
                n_estimate=out.n_estimate,
            )
            self._pub_tracks.put(msg.to_wire())
            with self._lock:
                self.latest = out

    def _publish_pose(self, result: tuple[str, PoseResult] | None) -> None:
        """Publish the latest pose of every mobile node after one of them was updated."""
        if result is None:
            return
        node, res = result
        with self._lock:
            self.latest_poses[node] = res
            latest = dict(self.latest_poses)
        msg = poses_message(latest, src=self.config.service_id, seq=self._next("poses"), t=res.t)
        self._pub_poses.put(msg.to_wire())

    def _next(self, stream: str) -> int:
        seq = self._seq[stream]
        self._seq[stream] = seq + 1
        return seq


def _bytes(sample: zenoh.Sample) -> bytes:
    return sample.payload.to_bytes()
