"""Several node agents of one process served by one acquisition thread, in slot order.

A process that runs K simulated nodes (``uwbnet scale``) used to run 2 K threads: each agent's
worker (wait for the slot, acquire, process, encode) and its publisher. Their K acquisitions
fall in K consecutive TDMA slots, so the workers woke one after another and took the GIL from
each other while the previous one was still processing. :class:`SlotOrderGroup` runs the same
per-agent steps (:meth:`NodeAgent.next_slot`, :meth:`NodeAgent.serve`) on one thread, which
waits for the earliest pending slot of its agents and serves them in slot order, and one
publisher thread for all their messages. The messages, counters and status of every agent are
the same as with the agents' own threads.

Measured in ``uwbnet scale --threads process`` on a 2-core machine shared with other work
(issue 11, stop 17 notes): it saved no CPU beyond the noise and lost more
acquisitions than a thread per agent, because one late acquisition delays every later slot of
the process. It is kept as an option for such measurements; the default is a thread per agent.

With ``batch_window`` > 0 (``uwbnet scale --threads batch``) the thread serves the slots of its
agents that fall in one frame together, back to back, and the publisher sends their messages
together: one wake-up of each thread per frame. A process woken from sleep pays for cold caches
(in a plain loop on this machine an acquisition cost about 0.5 ms more after each sleep than
back to back), so this cuts the CPU per acquisition of a simulated node process by about 40 %
with 8 nodes per process (issue 11, stop 18 notes). Before serving a batch the thread
lets the drivers prepare its acquisitions together (``acquire_ahead``: a simulated network
computes them in one batch, bit for bit the same; seventh round).
"""

from __future__ import annotations

import collections
import logging
import threading
import time
from collections.abc import Callable, Sequence

from node_agent.agent import NodeAgent
from node_agent.drivers.base import RadarDriver
from node_agent.tdma import SlotTiming

log = logging.getLogger(__name__)

#: At most this many batches served per wake-up: what is served ahead waits in the agents'
#: outboxes (100 messages, 2 per acquisition with ``ir``), and both a stop and a schedule
#: change take effect only after it (8 batches: at most 160 ms at 50 frames/s).
MAX_BATCHES_PER_WAKE = 8


class SlotOrderGroup:
    """Runs the acquisitions of ``agents`` on one thread in the order of their slots.

    Parameters
    ----------
    agents : node agents on one zenoh session, not started (``start`` declares them with
        ``threads=False``).
    clock : network time in seconds (the agents' clock).
    batch_window : 0 (default): each slot is served at its start. > 0 (s): the pending slots
        that start within ``batch_window`` of the earliest are served together, in slot
        order, when the earliest starts, and their messages are published together once the
        last of them has started: one wake-up of each thread per batch instead of one per
        slot (a simulated node process: a woken process pays for cold caches, about 0.2-0.5
        ms per wake-up on this machine, issue 11, stop 18 notes). For simulated
        drivers only, whose acquisition for slot time ``t`` may run before ``t`` (the scene
        at every slot time is known in advance); a radar acquires in real time. Every
        message carries its own slot's acquisition time, and none is published before its
        slot has started.
    acquire_ahead : with ``batch_window`` > 0, the drivers of a batch prepare its
        acquisitions together before they are served (:meth:`RadarDriver.acquire_ahead`: a
        simulated network computes them in one batch: the same impulse responses, the
        simulator at about a quarter less CPU, issue 11, stop 19 notes). False: one
        by one.
    catch_up : with ``batch_window`` > 0, a slot whose start passed less than this (s) ago
        when the thread looks for the next slots is still served, late, with its own
        acquisition time (``NodeAgent.catch_up``); 0 (default): such slots are skipped. A
        process that waited for a core otherwise loses the slots of all its nodes
        (issue 11, stop 19 notes).
    pipeline : with ``batch_window`` > 0 and one batch per wake-up: 0 (default) runs an
        acquisition thread and a publisher thread, each woken once per batch. > 0 (s): one
        thread does both, pipelined: it wakes when the batch served last is due (its last
        slot start), publishes its messages, and then at once serves the next batch if
        that batch's first slot is at most ``pipeline`` s away (one frame period: the next
        frame's batch, served ahead of its slots), then sleeps until that batch is due. One wake-up
        per frame for the whole process instead of two, the same messages at the same
        times (none before its slot), each acquisition computed up to ``pipeline`` s before
        its slot (issue 11, stop 22 notes).

    ``start()`` and ``stop()`` are idempotent; ``stop`` joins the threads and stops the agents.
    """

    def __init__(
        self,
        agents: Sequence[NodeAgent],
        *,
        clock: Callable[[], float] = time.time,
        batch_window: float = 0.0,
        acquire_ahead: bool = True,
        catch_up: float = 0.0,
        batches_per_wake: int = 1,
        pipeline: float = 0.0,
    ) -> None:
        if not agents:
            raise ValueError("a SlotOrderGroup needs at least one agent")
        if not batch_window >= 0.0:
            raise ValueError(f"batch_window must be >= 0 s, not {batch_window}")
        self.agents = list(agents)
        self.clock = clock
        self.batch_window = batch_window
        self.acquire_ahead = acquire_ahead
        self.errors = 0  # unexpected failures of a slot's service (logged)
        if not 0.0 <= catch_up <= 1.0:
            raise ValueError(f"catch_up must be 0 to 1 s, not {catch_up}")
        if catch_up and not batch_window:
            raise ValueError("catch_up needs batch_window > 0 (simulated drivers)")
        if not 1 <= batches_per_wake <= MAX_BATCHES_PER_WAKE or int(batches_per_wake) != (
            batches_per_wake
        ):
            raise ValueError(
                f"batches_per_wake must be an integer from 1 to {MAX_BATCHES_PER_WAKE},"
                f" not {batches_per_wake}"
            )
        if batches_per_wake > 1 and not batch_window:
            raise ValueError("batches_per_wake > 1 needs batch_window > 0 (simulated drivers)")
        self.batches_per_wake = int(batches_per_wake)
        if not 0.0 <= pipeline <= 1.0:
            raise ValueError(f"pipeline must be 0 to 1 s, not {pipeline}")
        if pipeline and (not batch_window or batches_per_wake > 1):
            raise ValueError(
                "pipeline needs batch_window > 0 (simulated drivers) and one batch per wake-up"
            )
        self.pipeline = pipeline
        for agent in self.agents:
            agent.catch_up = catch_up
        self._stop = threading.Event()
        # (release time, agent, the agent's put count after the slot) in the order of the
        # acquisitions: the publisher thread sends the messages up to that count (see
        # publish_pending) in slot order, as they were acquired, not before their release
        self._order: collections.deque[tuple[float, NodeAgent, int]] = collections.deque()
        self._queued = threading.Event()
        # set once the acquisition thread has ended: the publisher's final flush
        self._flushing = threading.Event()
        self._threads: list[threading.Thread] = []

    def start(self) -> None:
        """Declare every agent and start the acquisition and publisher threads."""
        if self._threads:
            return
        for agent in self.agents:
            agent.start(threads=False)
        name = f"group-{self.agents[0].config.node}"
        if self.pipeline:
            # one thread: no publisher (the acquisition thread publishes and flushes)
            self._threads = [
                threading.Thread(target=self._run_pipelined, name=name, daemon=True),
            ]
        else:
            self._threads = [
                threading.Thread(target=self._publish_loop, name=f"{name}-pub", daemon=True),
                threading.Thread(target=self._run, name=name, daemon=True),
            ]
        for thread in self._threads:
            thread.start()

    def stop(self) -> None:
        """Stop the threads, publish what is queued, and stop (undeclare) every agent."""
        self._stop.set()
        if len(self._threads) == 2:
            publisher, acquisition = self._threads
        else:  # pipelined (one thread, which flushes at its end) or never started
            publisher, acquisition = None, (self._threads or [None])[0]
        # the acquisition thread first: a batch it is serving ends and queues its messages,
        # and only then does the publisher make its final flush
        if acquisition is not None:
            acquisition.join(timeout=5.0)
        self._flushing.set()
        self._queued.set()
        if publisher is not None:
            publisher.join(timeout=5.0)
        self._threads = []
        for agent in self.agents:
            agent.stop()

    def _run(self) -> None:
        while not self._stop.is_set():
            upcoming = self._next_batch()
            if upcoming is None:
                self._stop.wait(0.05)
                continue
            # the batch: the earliest slot and those starting within the window after it
            batch, first, last = upcoming
            wait = first - self.clock()
            if wait > 0 and self._stop.wait(wait):
                break
            try:
                if self.batch_window == 0.0:
                    self._serve_one(self.agents[batch[0]])
                else:
                    self._serve_batch([self.agents[i] for i in batch], first, last)
                    for _ in range(self.batches_per_wake - 1):
                        # the next batch at once, ahead of its slots (released at its last)
                        ahead = self._next_batch()
                        if ahead is None or self._stop.is_set():
                            break
                        batch, first, last = ahead
                        self._serve_batch([self.agents[i] for i in batch], first, last)
            except Exception:
                self._failed(batch, last)

    def _run_pipelined(self) -> None:
        while not self._stop.is_set():
            self._publish_due()
            upcoming = self._next_batch()
            # the next batch once the last one has left (publish frame f, then compute
            # f + 1), ahead of its slots: queued, released at its last slot
            if (
                upcoming is not None
                and not self._order
                and upcoming[1] - self.clock() <= self.pipeline
            ):
                batch, first, last = upcoming
                try:
                    self._serve_batch([self.agents[i] for i in batch], first, last)
                except Exception:
                    self._failed(batch, last)
                continue  # what fell due while serving leaves at once
            # asleep until the batch served last is due, else until the next one comes
            # within reach
            if self._order:
                wait = self._order[0][0] - self.clock()
            elif upcoming is not None:
                wait = upcoming[1] - self.pipeline - self.clock()
            else:
                wait = 0.05
            if wait > 0:
                self._stop.wait(wait)
        # the final flush: everything queued, none before its release
        self._publish_released(None)
        for agent in self.agents:
            agent.publish_pending()

    def _publish_due(self) -> None:
        """Publish, in order, the queued messages whose release time has come."""
        now = self.clock()
        while self._order and self._order[0][0] <= now:
            _, agent, mark = self._order.popleft()
            agent.publish_pending(mark)

    def _failed(self, batch: list[int], last: float) -> None:
        # one thread serves every node of the process: an unexpected error in one slot must
        # not end them all; counted and logged, those slots given up (not retried in a
        # loop), the next ones served
        self.errors += 1
        if self.errors <= 10 or self.errors % 1000 == 0:  # not 50 tracebacks a second
            log.exception("slot service failed (%d so far)", self.errors)
        for i in batch:
            self.agents[i].skip_until(last)

    def _next_batch(self) -> tuple[list[int], float, float] | None:
        """The agents (indices) of the next batch, its first and last slot start; None if no
        agent has a slot."""
        pending = []
        for i, agent in enumerate(self.agents):
            slot = agent.next_slot()
            if slot is not None:
                pending.append((slot.t, i))
        if not pending:
            return None
        pending.sort()
        first = pending[0][0]
        batch = [i for t, i in pending if t <= first + self.batch_window]
        return batch, first, pending[len(batch) - 1][0]

    def _serve_one(self, agent: NodeAgent) -> None:
        slot = agent.next_slot()
        if slot is None:  # a new schedule took the slot away while we waited
            return
        if slot.t > self.clock():
            return  # the new schedule moved it later: wait again
        agent.serve(slot)
        self._order.append((0.0, agent, agent.queued_total))
        self._queued.set()

    def _serve_batch(self, agents: list[NodeAgent], first: float, last: float) -> None:
        late = max(self.clock() - first, 0.0)  # a batch served ahead is not late
        batch = []
        for agent in agents:
            slot = agent.next_slot()
            if slot is None or slot.t > last:
                continue  # a new schedule took the slot away or moved it out of the batch
            batch.append((agent, slot))
        if self.acquire_ahead and len(batch) > 1:
            self._acquire_ahead(batch)
        for agent, slot in batch:
            agent.serve(slot, late=late)
            self._order.append((last, agent, agent.queued_total))
        self._queued.set()  # one wake-up of the publisher per batch

    def _acquire_ahead(self, batch: list[tuple[NodeAgent, SlotTiming]]) -> None:
        """Let each driver class prepare its drivers' acquisitions of the batch together
        (:meth:`RadarDriver.acquire_ahead`); their CPU time is shared out over the agents'
        ``status.cpu``. A failure leaves each slot to its own acquisition."""
        by_class: dict[type[RadarDriver], list[tuple[RadarDriver, SlotTiming]]] = {}
        for agent, slot in batch:
            by_class.setdefault(type(agent.driver), []).append((agent.driver, slot))
        cpu0 = time.thread_time()
        for cls, items in by_class.items():
            try:
                cls.acquire_ahead(items)
            except Exception as exc:  # an optimisation: never let it stop the process's nodes
                # (a failure part-way may have advanced a simulated node's random stream,
                # so its next impulse responses differ from the per-slot path's)
                log.warning("acquisitions of a batch not prepared together: %r", exc)
        share = (time.thread_time() - cpu0) / len(batch)
        for agent, _ in batch:
            agent.add_cpu(share)

    def _publish_loop(self) -> None:
        while not self._flushing.is_set():
            self._queued.wait(0.1)
            self._queued.clear()
            self._publish_released(self._flushing)
        # the final flush: everything the acquisition thread queued, still none before its
        # release (a batch's last slot start, at most one batch window away)
        self._publish_released(None)
        for agent in self.agents:
            agent.publish_pending()

    def _publish_released(self, stop: threading.Event | None) -> None:
        """Publish the queued messages in order, each once its release time has come; with
        ``stop`` set, return early (what is left goes in the final flush)."""
        while self._order and not (stop is not None and stop.is_set()):
            release, agent, mark = self._order[0]
            hold = release - self.clock()
            if hold > 0:
                if stop is not None:
                    if stop.wait(hold):
                        return
                else:
                    # bounded: a release is at most batches_per_wake frames away
                    time.sleep(min(hold, 1.0))
            self._order.popleft()
            agent.publish_pending(mark)
