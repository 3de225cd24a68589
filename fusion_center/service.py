"""The fusion center process: zenoh subscribers -> :class:`FusionCore` -> publishers.

Holds the TDMA schedule (published on change and served by a queryable), follows node presence
through liveliness tokens, fetches ``node_info`` from the nodes' queryables, and publishes
``tracks`` after every processed frame. One worker thread does the work: ``detections``,
``node_info`` and ``status`` samples wait in zenoh's own ring channels (no Python callback per
message) and the worker takes all that arrived at each of its wake-ups, every ``poll_period``
(issue 11, stop 21 notes; docs/capacity.md); the rare control inputs (liveliness, replies of
``node_info`` queries) come through callbacks that only enqueue. Within one wake-up the inputs
are handled by kind (control, ``node_info``, ``status``, ``detections``), not in arrival order:
an updated ``node_info`` may apply to detections that came up to ``poll_period`` before it.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any

import numpy as np
import zenoh

from fusion_center.core import FusionCore, FusionCoreConfig
from fusion_center.image_runtime import ImagingRuntime, LiveImagingConfig
from fusion_center.localization.mobile import LocalizerConfig, PoseResult
from fusion_center.offline import make_tracker
from fusion_center.pose_core import PoseCore, poses_message
from fusion_center.tracking.base import TrackerOutput
from protocol import (
    Detections,
    Ir,
    NodeInfo,
    Poses,
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
from protocol.transport import FifoChannel, RingChannel, stop_worker

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
    poll_period : the worker wakes this often (s) and takes every sample that arrived since
        (zenoh's channels, drained without a Python callback or a thread wake-up per message).
        Adds up to this much latency; 5 ms is a quarter of a TDMA frame.
    channel_capacity : samples a zenoh channel holds for the worker; when it is full (the
        worker that far behind) the oldest are dropped: a ring, never blocking zenoh's
        network thread (a blocking FIFO there stalled the whole router and, after zenoh's
        5 s block timeout, closed the nodes' links). Lost detections are counted per node
        from the gaps in their ``seq`` (``NodeHealth.missing``).
    core : frame assembly parameters.
    localization : localization of mobile nodes from their ranging rounds (``poses``).
    imaging : live imaging of the nodes' ``ir`` (off unless ``imaging.rate > 0``), in its own
        thread, published on ``fusion/image``.
    nodes : fuse only these nodes (subscribing to their keys alone: a fusion worker of one
        cell, :mod:`fusion_center.gateway`); None: every node of the network.
    schedule : own the TDMA schedule (publish it, serve its queryable). Exactly one service
        of a network does; the cell workers of a sharded fusion center do not.
    track : run the tracker at all (False: a schedule-only service).
    tracks_key : where ``tracks`` go (default ``uwbnet/{net}/fusion/tracks``).
    """

    net: str = "demo"
    service_id: str = "fusion"
    method: str = "gmphd"
    frame_period: float = 0.02
    flush_after: float = 0.05
    poll_period: float = 0.005
    channel_capacity: int = 8192
    core: FusionCoreConfig = dataclasses.field(default_factory=FusionCoreConfig)
    localization: LocalizerConfig = dataclasses.field(default_factory=LocalizerConfig)
    imaging: LiveImagingConfig = dataclasses.field(default_factory=LiveImagingConfig)
    nodes: tuple[str, ...] | None = None
    schedule: bool = True
    track: bool = True
    tracks_key: str | None = None

    def __post_init__(self) -> None:
        if not (0.0 < self.poll_period <= 1.0):
            raise ValueError(f"poll_period must be in (0, 1] s, not {self.poll_period}")
        if self.channel_capacity < 1:
            raise ValueError(f"channel_capacity must be >= 1, not {self.channel_capacity}")


@dataclasses.dataclass(slots=True)
class NodeHealth:
    """What the fusion center knows of one node's health."""

    alive: bool = False
    last_status: Status | None = None
    detections: int = 0
    last_det_t: float = math.nan
    latency_ms: float = math.nan
    #: detections messages never received: gaps in the node's ``seq`` (dropped in transit
    #: or by a full channel of a worker that fell behind)
    missing: int = 0


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
        #: Control inputs (liveliness changes, ``node_info`` replies): callbacks enqueue here.
        self._inbox: FifoChannel[tuple[str, str, bytes]] = FifoChannel(8192)
        #: (leaf, subscriber with a zenoh channel) drained by the worker, ``info`` first.
        self._channels: list[tuple[str, Any]] = []
        #: Detections per node since the last health update: [count, latest t, seq gaps].
        self._det_batch: dict[str, list[Any]] = {}
        #: the last detections ``seq`` seen per node
        self._det_seq: dict[str, int] = {}
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._decl: list[Any] = []
        self._lock = threading.Lock()
        self.health: dict[str, NodeHealth] = {}
        self.latest: TrackerOutput | None = None
        self.decode_errors = 0
        #: messages whose handling raised something other than a protocol error (logged)
        self.handler_errors = 0
        self.rejected_poses = 0
        self._schedule: TdmaSchedule | None = None
        self._schedule_bytes = b""
        self._seq = {"tracks": 0, "schedule": 0, "poses": 0}
        self._want_info: set[str] = set()
        self._asked: dict[str, float] = {}
        #: Recent local position estimates ``(t, positions (k, 2), cov (k, 2, 2))`` for viewers
        #: (the web view's moving-target image); bounded, the oldest fall off unread.
        self.recent_estimates: deque[tuple[float, Any, Any]] = deque(maxlen=4096)
        #: Live imaging (None when off): its runtime, ``ir`` ring and thread.
        self.imaging: ImagingRuntime | None = None
        self._ir_inbox: RingChannel[bytes] = RingChannel(1024)
        self._img_thread: threading.Thread | None = None
        self._img_lock = threading.Lock()

    # -- lifecycle -------------------------------------------------------------------------

    def start(self) -> None:
        if self._thread is not None:
            return
        net, s = self.config.net, self.session
        put = self._inbox.put
        cfg = self.config
        self._pub_tracks = s.declare_publisher(
            cfg.tracks_key or keys.fusion_key(net, "tracks"),
            congestion_control=zenoh.CongestionControl.BLOCK,
        )
        self._pub_poses = s.declare_publisher(
            keys.fusion_key(net, "poses"), congestion_control=zenoh.CongestionControl.BLOCK
        )
        self._decl += [self._pub_tracks, self._pub_poses]
        if cfg.schedule:
            self._pub_schedule = s.declare_publisher(
                keys.schedule_key(net), congestion_control=zenoh.CongestionControl.BLOCK
            )
            self._decl.append(self._pub_schedule)
        if cfg.nodes is not None:
            # A cell worker: its nodes' frames are complete when all of them reported.
            self.core.expected = frozenset(cfg.nodes)
        leaves = ("info", "status", "det") if cfg.track else ("info", "status")
        for leaf in leaves:
            if cfg.nodes is None:
                exprs = [keys.all_nodes_key(net, leaf)]
            else:
                exprs = [keys.node_key(net, node, leaf) for node in cfg.nodes]
            for expr in exprs:
                # zenoh's channel: its network thread queues the sample without Python's lock
                # and the worker takes them in batches; a Python callback costs a thread
                # wake-up, the lock and a queue per message (issue 11, stop 21 notes)
                sub = s.declare_subscriber(expr, zenoh.handlers.RingChannel(cfg.channel_capacity))
                self._decl.append(sub)
                self._channels.append((leaf, sub))
        self._decl.append(
            s.liveliness().declare_subscriber(
                keys.all_alive_key(net),
                lambda sample: put(("alive", str(sample.key_expr), str(sample.kind).encode())),
                history=True,
            )
        )
        if cfg.schedule:
            self._decl.append(s.declare_queryable(keys.schedule_key(net), self._on_schedule_query))
        self._decl.append(s.liveliness().declare_token(keys.alive_key(net, self.config.service_id)))
        if cfg.schedule:
            self._publish_schedule()
        if self.config.imaging.rate > 0:
            self._start_imaging()
        self._thread = threading.Thread(target=self._run, name="fusion", daemon=True)
        self._thread.start()
        log.info(
            "fusion center %s started on net %s (%s)",
            self.config.service_id,
            net,
            self.config.method,
        )

    def stop(self) -> None:
        if self._img_thread is not None:
            self._stop.set()
            self._img_thread.join(timeout=10.0)
            self._img_thread = None
        stop_worker(self._stop, self._thread, self._decl)
        self._thread = None

    # -- live imaging ----------------------------------------------------------------------

    def _start_imaging(self) -> None:
        net, s = self.config.net, self.session
        self.imaging = ImagingRuntime(self.config.imaging, self.config.service_id)
        self._pub_image = s.declare_publisher(keys.fusion_key(net, "image"))
        self._decl.append(self._pub_image)
        put = self._ir_inbox.put
        self._decl.append(
            s.declare_subscriber(keys.all_nodes_key(net, "ir"), lambda smp: put(_bytes(smp)))
        )
        # Mobile nodes whose ir carry no pose are placed by the latest ``poses``: this
        # service's own localization or another service's (the mapping of a robot).
        self._decl.append(
            s.declare_subscriber(keys.fusion_key(net, "poses"), lambda smp: put(_bytes(smp)))
        )
        self._img_thread = threading.Thread(target=self._run_imaging, name="imaging", daemon=True)
        self._img_thread.start()

    def _run_imaging(self) -> None:
        """Decode ``ir`` and ``poses`` as they arrive, migrate and publish at ``imaging.rate``."""
        assert self.imaging is not None
        period = 1.0 / self.config.imaging.rate
        next_t = time.monotonic() + period
        while not self._stop.is_set():
            payload = self._ir_inbox.get(timeout=max(0.0, min(period, next_t - time.monotonic())))
            if payload is not None:
                try:
                    msg = decode(payload)
                    if isinstance(msg, Ir):
                        with self._img_lock:
                            self.imaging.add_ir(msg)
                    elif isinstance(msg, Poses):
                        with self._img_lock:
                            self.imaging.add_poses(msg)
                    else:
                        raise ProtocolError(f"kind {msg.KIND!r} on an ir or poses key")
                except ProtocolError as exc:
                    self.decode_errors += 1
                    log.warning("rejected imaging input: %s", exc)
            if time.monotonic() >= next_t:
                next_t = time.monotonic() + period
                with self._img_lock:
                    image = self.imaging.step(self.clock())
                if image is not None:
                    self._pub_image.put(image.to_wire())

    def _on_schedule_query(self, query: zenoh.Query) -> None:
        if self._schedule_bytes:
            query.reply(keys.schedule_key(self.config.net), self._schedule_bytes)

    # -- state for viewers -----------------------------------------------------------------

    @property
    def schedule(self) -> TdmaSchedule | None:
        """The TDMA schedule this service published last (None before the first)."""
        return self._schedule

    def snapshot(self) -> tuple[TrackerOutput | None, dict[str, NodeHealth]]:
        """The latest tracker output and a copy of the node health table."""
        with self._lock:
            return self.latest, {k: dataclasses.replace(v) for k, v in self.health.items()}

    def node_infos(self) -> dict[str, NodeInfo]:
        """A copy of the known node descriptions (safe to call from another thread)."""
        return dict(self.core.nodes)

    # -- worker ----------------------------------------------------------------------------

    def _run(self) -> None:
        period, flush_after = self.config.poll_period, self.config.flush_after
        last_item = next_wake = time.monotonic()
        while not self._stop.is_set():
            now = time.monotonic()
            try:
                taken = self._drain()
                now = time.monotonic()
                if taken:
                    last_item = now
                elif now - last_item >= flush_after:
                    self._publish(self.core.flush())
                    last_item = now
                self._fetch_infos()
            except Exception:  # a bug costs one wake-up, not the worker (inputs would pile up)
                self.handler_errors += 1
                log.exception("fusion worker wake-up failed")
            next_wake = max(next_wake + period, now)
            delay = next_wake - time.monotonic()
            if delay > 0.0:
                time.sleep(delay)

    def _drain(self) -> int:
        """Handle every input that arrived since the last wake-up; how many there were."""
        taken = 0
        t_drain = self.clock()  # detections' latency: until taken, not until the batch is done
        if len(self._inbox):
            for leaf, key, payload in self._inbox.drain():
                taken += 1
                self._guarded(leaf, key, payload)
        # at most a full channel's worth per leaf, so that a flood cannot starve the rest
        limit = self.config.channel_capacity
        for leaf, sub in self._channels:
            for _ in range(limit):
                sample = sub.try_recv()
                if sample is None:
                    break
                taken += 1
                self._guarded(leaf, sample, None)
        if self._det_batch:
            self._note_detections(t_drain)
        return taken

    def _guarded(self, leaf: str, key: Any, payload: bytes | None) -> None:
        """``_handle`` one input (a zenoh sample when ``payload`` is None), counting and
        logging what it rejects or fails on."""
        try:
            if payload is None:
                payload = key.payload.to_bytes()
            self._handle(leaf, key, payload)
        except ProtocolError as exc:
            self.decode_errors += 1
            log.warning("rejected %s: %s", _key(key), exc)
        except Exception:  # a bug must cost one message, not the fusion thread
            self.handler_errors += 1
            log.exception("failed on %s", _key(key))

    def _note_detections(self, now: float) -> None:
        """Node health from the detections of one wake-up: counts, latest ``t``, the latency
        (ms from acquisition to the wake-up that took the message) and the ``seq`` gaps."""
        batch, self._det_batch = self._det_batch, {}
        with self._lock:
            for src, (count, t, gaps) in batch.items():
                h = self.health.get(src)
                if h is None:
                    h = self.health[src] = NodeHealth()
                h.detections += count
                h.last_det_t = t
                h.latency_ms = (now - t) * 1e3
                h.missing += gaps

    def _handle(self, leaf: str, key: Any, payload: bytes) -> None:
        if leaf == "alive":
            self._on_alive(key, payload.decode())
            return
        msg = decode(payload)
        if leaf == "det" and isinstance(msg, Detections):
            if msg.src not in self.core.nodes:
                self._want_info.add(msg.src)
            last = self._det_seq.get(msg.src)
            # a gap in seq: messages lost; a restarted node begins at 0 again (no gap), and
            # a late duplicate or reordered message does not move the mark back
            gap = msg.seq - last - 1 if last is not None and msg.seq > last + 1 else 0
            if last is None or msg.seq > last or msg.seq == 0:
                self._det_seq[msg.src] = msg.seq
            seen = self._det_batch.get(msg.src)
            if seen is None:
                self._det_batch[msg.src] = [1, msg.t, gap]
            else:
                seen[0] += 1
                seen[1] = msg.t
                seen[2] += gap
            if msg.links is not None:
                self._publish_pose(self.pose_core.add_ranging(msg))
                # anchors ranged before their description arrived: ask their queryables
                self._want_info |= self.pose_core.unknown_anchors
            else:
                if msg.positions is not None and msg.positions.shape[0]:
                    self.recent_estimates.append((msg.t, msg.positions, msg.cov))
                self._publish(self.core.add_detections(msg))
        elif leaf == "info" and isinstance(msg, NodeInfo):
            self._add_node(msg)
        elif leaf == "status" and isinstance(msg, Status):
            with self._lock:
                self.health.setdefault(msg.src, NodeHealth()).last_status = msg
        else:
            raise ProtocolError(f"kind {msg.KIND!r} on {_key(key)}")

    def _on_alive(self, key: str, kind: str) -> None:
        try:
            node = keys.parse_key(key).node
        except KeyExprError:
            return
        if node is None or node == self.config.service_id:
            return
        if self.config.nodes is not None and node not in self.config.nodes:
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
        if self.imaging is not None:
            with self._img_lock:
                self.imaging.add_info(info)
        if known is None or known.antennas != info.antennas:
            self._reschedule()

    def _reschedule(self) -> None:
        """One slot per transmitting antenna of every live node with a known description."""
        if not self.config.schedule:
            return
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
            msg = tracks_message(out, src=self.config.service_id, seq=self._next("tracks"))
            self._pub_tracks.put(msg.to_wire())
            with self._lock:
                self.latest = out

    def _publish_pose(self, result: tuple[str, PoseResult] | None) -> None:
        """Publish the latest pose of every mobile node after one of them was updated."""
        if result is None:
            return
        node, res = result
        if not (np.isfinite(res.pose).all() and np.isfinite(res.cov).all()):
            # one bad pose must not sit in latest_poses and spoil every later message
            self.rejected_poses += 1
            log.warning("pose of %s at t=%.3f not published: not finite", node, res.t)
            return
        with self._lock:
            self.latest_poses[node] = res
            latest = dict(self.latest_poses)
        msg = poses_message(latest, src=self.config.service_id, seq=self._next("poses"), t=res.t)
        self._pub_poses.put(msg.to_wire())

    def _next(self, stream: str) -> int:
        seq = self._seq[stream]
        self._seq[stream] = seq + 1
        return seq


def tracks_message(out: TrackerOutput, *, src: str, seq: int) -> Tracks:
    """The ``tracks`` message of a tracker output, with the optional field ``t_acq``: the
    acquisition times of the detections the update used (end-to-end latency)."""
    return Tracks(
        src=src,
        seq=seq,
        t=out.t,
        tracks=tuple(
            Track(
                id=tr.id,
                x=tr.x,
                y=tr.y,
                vx=tr.vx,
                vy=tr.vy,
                cov=np.asarray(tr.cov).tolist(),
                w=tr.w,
            )
            for tr in out.tracks
        ),
        n_estimate=out.n_estimate,
        extra={"t_acq": list(out.acquired)},
    )


def _bytes(sample: zenoh.Sample) -> bytes:
    return sample.payload.to_bytes()


def _key(key: Any) -> str:
    """The key expression of an input: a string, or a zenoh sample's."""
    return key if isinstance(key, str) else str(key.key_expr)
