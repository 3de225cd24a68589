"""The node agent process: driver -> DSP -> zenoh publishers, status and liveliness.

A thin shell: timing comes from the published TDMA schedule, processing from
:class:`node_agent.core.NodeCore`, and every zenoh declaration is held for the agent's lifetime
and undeclared by :meth:`NodeAgent.stop`. Callbacks only enqueue (zenoh's rule).
"""

from __future__ import annotations

import bisect
import dataclasses
import logging
import math
import threading
import time
from collections.abc import Callable
from typing import Any

import zenoh

from node_agent.core import NodeConfigError, NodeCore, detections_message
from node_agent.drivers.base import DriverError, RadarDriver
from node_agent.dsp.pipeline import NodeDspConfig
from node_agent.tdma import SlotTiming, next_slot
from protocol import Ir, NodeInfo, ProtocolError, Status, TdmaSchedule, keys
from protocol.transport import RingChannel, stop_worker

log = logging.getLogger(__name__)

#: Seconds between schedule queries of a node that has one (see :meth:`NodeAgent.next_slot`).
SCHEDULE_REFRESH = 5.0

#: Upper edges (ms) of the bins of the acquisition lateness histogram in ``status.extra``
#: (``lateness_ms``: counts per bin, the last bin open-ended): how long after its slot start an
#: acquisition began. More than a frame late means the next slot is skipped.
LATENESS_EDGES_MS = (1.0, 2.0, 5.0, 10.0, 20.0, 40.0)


@dataclasses.dataclass(frozen=True, slots=True, kw_only=True)
class AgentConfig:
    """Configuration of one node agent.

    Parameters
    ----------
    node : node id ([A-Za-z0-9_-]+).
    net : network name of the key expressions.
    publish_ir : publish raw impulse responses on ``.../ir`` (for imaging and recording).
    status_period : seconds between ``status`` messages.
    outbox : messages queued for the publisher thread before the oldest are dropped
        (100: one second of ``ir`` and ``detections`` at 50 Hz).
    dsp : node DSP configuration.
    """

    node: str
    net: str = "demo"
    publish_ir: bool = True
    status_period: float = 1.0
    outbox: int = 100
    dsp: NodeDspConfig = dataclasses.field(default_factory=NodeDspConfig)


class NodeAgent:
    """Acquires in this node's TDMA slots, processes, and publishes ``ir``, ``detections``,
    ``status``, ``node_info`` and a liveliness token on an open zenoh ``session``.

    ``clock`` returns network time in seconds. ``start()`` and ``stop()`` are idempotent; ``stop``
    waits for the worker thread.
    """

    def __init__(
        self,
        session: zenoh.Session,
        driver: RadarDriver,
        config: AgentConfig,
        *,
        clock: Callable[[], float] = time.time,
    ) -> None:
        self.session, self.driver, self.config, self.clock = session, driver, config, clock
        desc = driver.describe()
        self.info = NodeInfo(src=config.node, seq=0, t=clock(), **desc)
        self._info_bytes = self.info.to_wire()
        self.tx = next(
            (f"{config.node}/{name}" for name, a in self.info.antennas.items() if a.tx), None
        )
        self.core = NodeCore(self.info, config.dsp)
        # the newest schedules: while many nodes join, one is published per join, faster than
        # a busy worker takes them; a FIFO that rejects the newest when full left nodes on a
        # stale schedule for good (two nodes in one slot: 56-node scale runs lost 1/56)
        self._schedule_in: RingChannel[bytes] = RingChannel(16)
        # Acquisition never waits for the network: messages go through a bounded queue to a
        # publisher thread; when a stuck link or consumer backs it up, the oldest are dropped
        # and counted (``status.dropped``, ``extra.queue_dropped``).
        self._outbox: RingChannel[tuple[Any, bytes]] = RingChannel(config.outbox)
        self._pub_thread: threading.Thread | None = None
        self._schedule: TdmaSchedule | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._decl: list[Any] = []
        self._seq = {"ir": 0, "det": 0, "status": 0}
        self.counters = {
            "acquired": 0,
            "published": 0,
            "dropped": 0,
            "late_slots": 0,
            "decode_errors": 0,
            "dsp_errors": 0,
            "driver_errors": 0,
        }
        self._started_at = 0.0
        self._started = False
        # slot state of the worker (NodeAgent._run or a SlotOrderGroup's thread)
        self._pending: SlotTiming | None = None
        self._last_frame: int | None = None
        self._served_t = -math.inf
        #: How long after its start a slot may still be served (s): 0 skips every slot whose
        #: start has passed when the next one is looked up. A SlotOrderGroup serving
        #: simulated drivers sets it (the scene at a past slot time is known): a process that
        #: waited for a core then serves those slots late instead of losing them.
        self.catch_up = 0.0
        self._last_query = 0.0
        # CPU time (s) of this agent's acquisitions, and (cpu, monotonic) at the last status
        self._cpu_used = 0.0
        self._status_mark = (0.0, 0.0)
        self._lateness = [0] * (len(LATENESS_EDGES_MS) + 1)

    # -- lifecycle -------------------------------------------------------------------------

    def start(self, *, threads: bool = True) -> None:
        """Declare publishers, queryable, subscriber and token, and start the worker.

        With ``threads=False`` the agent only declares: an :class:`node_agent.group.SlotOrderGroup`
        runs its acquisitions and publishing on the group's threads.
        """
        if self._started:
            return
        self._started = True
        net, node = self.config.net, self.config.node
        s = self.session
        self._pub_ir = s.declare_publisher(
            keys.node_key(net, node, "ir"), congestion_control=zenoh.CongestionControl.DROP
        )
        self._pub_det = s.declare_publisher(
            keys.node_key(net, node, "det"), congestion_control=zenoh.CongestionControl.BLOCK
        )
        self._pub_status = s.declare_publisher(keys.node_key(net, node, "status"))
        info_key = keys.node_key(net, node, "info")
        self._decl += [self._pub_ir, self._pub_det, self._pub_status]
        self._decl.append(s.declare_queryable(info_key, self._on_info_query))
        self._decl.append(
            s.declare_subscriber(
                keys.schedule_key(net), lambda sample: self._schedule_in.put(_payload(sample))
            )
        )
        self._decl.append(s.liveliness().declare_token(keys.alive_key(net, node)))
        s.put(info_key, self._info_bytes)
        self._started_at = time.monotonic()
        self._status_mark = (self._cpu_used, self._started_at)
        if threads:
            self._thread = threading.Thread(target=self._run, name=f"agent-{node}", daemon=True)
            self._pub_thread = threading.Thread(
                target=self._publish_loop, name=f"agent-{node}-pub", daemon=True
            )
            self._pub_thread.start()
            self._thread.start()
        log.info("node agent %s started on net %s (tx %s)", node, net, self.tx)

    def stop(self) -> None:
        """Stop the workers and undeclare everything. Idempotent."""
        self._stop.set()
        if self._pub_thread is not None:
            self._pub_thread.join(timeout=5.0)
            self._pub_thread = None
        stop_worker(self._stop, self._thread, self._decl)
        self._thread = None

    def _publish_loop(self) -> None:
        while not self._stop.is_set():
            item = self._outbox.get(timeout=0.1)
            if item is not None:
                self._put(*item)

    def publish_pending(self, until: int | None = None) -> None:
        """Publish now, without waiting, the queued messages put before the ``until``-th put
        of the agent's life (all if None): the publisher thread of a
        :class:`node_agent.group.SlotOrderGroup`, which marks each served slot by
        :attr:`queued_total` after it. Marked by put number, not counted: when the outbox
        overflowed (its oldest dropped, counted), a later slot's message is never taken in a
        dropped one's place and sent before its own slot."""
        while True:
            item = (
                self._outbox.get(timeout=0.0) if until is None else self._outbox.get_before(until)
            )
            if item is None:
                return
            self._put(*item)

    @property
    def queued_total(self) -> int:
        """Messages put in the outbox over the agent's life (published, queued or dropped)."""
        return self._outbox.received

    def _put(self, publisher: Any, payload: bytes) -> None:
        try:
            publisher.put(payload)
        except zenoh.ZError as exc:
            log.debug("publish failed: %s", exc)
            return
        self.counters["published"] += 1

    def _on_info_query(self, query: zenoh.Query) -> None:
        # Reply on our own concrete key, not on the query's wildcard.
        query.reply(keys.node_key(self.config.net, self.config.node, "info"), self._info_bytes)

    # -- worker ----------------------------------------------------------------------------

    def _take_schedule(self) -> bool:
        """Take the newest of the schedules received; True if it replaced ours. A schedule is
        newer with a higher ``seq``, a later ``t`` (its service restarted) or from another
        service; a query's late reply with an older one must not undo a published change."""
        taken = False
        for payload in self._schedule_in.drain():
            try:
                sched = TdmaSchedule.from_wire(payload)
            except ProtocolError as exc:
                self.counters["decode_errors"] += 1
                log.warning("node %s: rejected schedule: %s", self.config.node, exc)
                continue
            cur = self._schedule
            if cur is None or sched.src != cur.src or sched.seq > cur.seq or sched.t > cur.t:
                self._schedule = sched
                taken = True
        return taken

    def _query_schedule(self) -> None:
        # The replies arrive on zenoh's thread and only enqueue: the asking thread (which may
        # serve other agents' slots, node_agent.group) never waits for the network.
        def on_reply(reply: zenoh.Reply) -> None:
            if reply.ok is not None:
                self._schedule_in.put(reply.ok.payload.to_bytes())

        try:
            self.session.get(keys.schedule_key(self.config.net), handler=on_reply, timeout=1.0)
        except zenoh.ZError as exc:
            log.debug("schedule query failed: %s", exc)

    def next_slot(self) -> SlotTiming | None:
        """This node's next TDMA slot (the one still to be served), or None when there is no
        schedule or we are not (yet) in it; then the schedule is queried (1 Hz): the update
        that adds us may have been published before our subscriber was matched."""
        if self._take_schedule():
            self._pending = None
        if self._pending is None and self._schedule is not None and self.tx is not None:
            # after the slot served last: a batch (node_agent.group) may serve a slot before
            # its start, and that slot must not come round again
            after = max(self.clock() - self.catch_up, self._served_t + 1e-6)
            slot = next_slot(self._schedule, self.tx, after)
            # and in a later frame: a schedule change can move this node's slot later in
            # the frame just served (a node sorted before it joined), and a batch serving
            # ahead or a catch-up would then acquire that frame twice
            while slot is not None and self._last_frame is not None:
                if slot.frame > self._last_frame:
                    break
                slot = next_slot(self._schedule, self.tx, slot.t + 1e-6)
            self._pending = slot
        # not in a schedule: ask every second; in one: every SCHEDULE_REFRESH s, in case a
        # change was published before our subscriber was matched
        since = time.monotonic() - self._last_query
        if since > (1.0 if self._pending is None else SCHEDULE_REFRESH):
            self._last_query = time.monotonic()
            self._query_schedule()
        return self._pending

    def skip_until(self, t: float) -> None:
        """Give up the slots starting up to ``t`` (s, node clock) unserved, e.g. after their
        service failed: they are not tried again, and count as ``dropped`` once a later
        slot is served."""
        self._pending = None
        self._served_t = max(self._served_t, t)

    def serve(self, slot: SlotTiming, *, late: float | None = None) -> int:
        """Acquire, process and queue the messages of ``slot`` (its start has come), and send
        ``status`` when due. Called from one thread at a time. Returns the number of messages
        queued for publishing.

        ``late`` is how long after it was due the worker began serving (s): by default now
        minus the slot's start; a :class:`node_agent.group.SlotOrderGroup` that serves a batch
        of slots together gives the batch's lateness. ``late_slots`` and the
        ``lateness_ms`` histogram count it."""
        self._pending = None
        self._served_t = slot.t
        queued = self._outbox.received
        if self._last_frame is not None and slot.frame > self._last_frame + 1:
            # The worker fell behind: these frames' slots passed without an acquisition.
            self.counters["dropped"] += slot.frame - self._last_frame - 1
        self._last_frame = slot.frame
        if late is None:
            late = self.clock() - slot.t
        if late > slot.duration:
            self.counters["late_slots"] += 1
        self._lateness[bisect.bisect_left(LATENESS_EDGES_MS, late * 1e3)] += 1
        cpu0 = time.thread_time()
        self._acquire_and_publish(slot)
        self._cpu_used += time.thread_time() - cpu0
        now = time.monotonic()
        if now - self._status_mark[1] >= self.config.status_period:
            cpu = (self._cpu_used - self._status_mark[0]) / max(now - self._status_mark[1], 1e-9)
            self._status_mark = (self._cpu_used, now)
            self._publish_status(cpu)
        return self._outbox.received - queued

    def add_cpu(self, seconds: float) -> None:
        """Count CPU time spent for this agent's acquisitions outside :meth:`serve` (its
        share of a batch simulated ahead, node_agent.group) in ``status.cpu``."""
        self._cpu_used += seconds

    def _run(self) -> None:
        while not self._stop.is_set():
            slot = self.next_slot()
            if slot is None:
                self._stop.wait(0.05)
                continue
            wait = slot.t - self.clock()
            if wait > 0 and self._stop.wait(wait):
                break
            self.serve(slot)

    def _acquire_and_publish(self, slot: SlotTiming) -> None:
        try:
            acq = self.driver.acquire(slot)
        except DriverError as exc:
            self.counters["driver_errors"] += 1
            log.warning("node %s: acquisition failed: %s", self.config.node, exc)
            return
        self.counters["acquired"] += 1
        ir = Ir(
            src=self.config.node,
            seq=self._next("ir"),
            t=acq.t,
            tx=acq.tx,
            rx=acq.rx,
            slot=slot.slot,
            frame=slot.frame,
            h=acq.h,
            pose=acq.pose,
        )
        if self.config.publish_ir:
            self._outbox.put((self._pub_ir, ir.to_wire()))
        try:
            result = self.core.process(ir)
        except (NodeConfigError, ValueError) as exc:
            self.counters["dsp_errors"] += 1
            log.warning("node %s: processing failed: %s", self.config.node, exc)
            return
        except Exception:  # a DSP bug must cost one acquisition, not the node
            self.counters["dsp_errors"] += 1
            log.exception("node %s: processing failed unexpectedly", self.config.node)
            return
        det = detections_message(ir, result, src=self.config.node, seq=self._next("det"))
        self._outbox.put((self._pub_det, det.to_wire()))

    def _publish_status(self, cpu: float) -> None:
        c = self.counters
        status = Status(
            src=self.config.node,
            seq=self._next("status"),
            t=self.clock(),
            uptime=time.monotonic() - self._started_at,
            acquired=c["acquired"],
            published=c["published"],
            dropped=c["dropped"] + self._outbox.dropped,
            late_slots=c["late_slots"],
            decode_errors=c["decode_errors"],
            cpu=cpu,
            extra={
                "dsp_errors": c["dsp_errors"],
                "driver_errors": c["driver_errors"],
                "queue_dropped": self._outbox.dropped,
                "missed_frames": c["dropped"],
                "lateness_ms": list(self._lateness),
                "lateness_edges_ms": list(LATENESS_EDGES_MS),
            },
        )
        self._pub_status.put(status.to_wire())

    def _next(self, stream: str) -> int:
        seq = self._seq[stream]
        self._seq[stream] = seq + 1
        return seq


def _payload(sample: zenoh.Sample) -> bytes:
    return sample.payload.to_bytes()
