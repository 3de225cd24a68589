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
(docs/capacity.md, stop 17, item 17): it saved no CPU beyond the noise and lost more
acquisitions than a thread per agent, because one late acquisition delays every later slot of
the process. It is kept as an option for such measurements; the default is a thread per agent.
"""

from __future__ import annotations

import collections
import logging
import threading
import time
from collections.abc import Callable, Sequence

from node_agent.agent import NodeAgent

log = logging.getLogger(__name__)


class SlotOrderGroup:
    """Runs the acquisitions of ``agents`` on one thread in the order of their slots.

    Parameters
    ----------
    agents : node agents on one zenoh session, not started (``start`` declares them with
        ``threads=False``).
    clock : network time in seconds (the agents' clock).

    ``start()`` and ``stop()`` are idempotent; ``stop`` joins the threads and stops the agents.
    """

    def __init__(
        self, agents: Sequence[NodeAgent], *, clock: Callable[[], float] = time.time
    ) -> None:
        if not agents:
            raise ValueError("a SlotOrderGroup needs at least one agent")
        self.agents = list(agents)
        self.clock = clock
        self._stop = threading.Event()
        # (agent, messages) in the order of the acquisitions: the publisher thread sends them
        # in slot order, as they were acquired
        self._order: collections.deque[tuple[NodeAgent, int]] = collections.deque()
        self._queued = threading.Event()
        self._threads: list[threading.Thread] = []

    def start(self) -> None:
        """Declare every agent and start the acquisition and publisher threads."""
        if self._threads:
            return
        for agent in self.agents:
            agent.start(threads=False)
        name = f"group-{self.agents[0].config.node}"
        self._threads = [
            threading.Thread(target=self._publish_loop, name=f"{name}-pub", daemon=True),
            threading.Thread(target=self._run, name=name, daemon=True),
        ]
        for thread in self._threads:
            thread.start()

    def stop(self) -> None:
        """Stop the threads, publish what is queued, and stop (undeclare) every agent."""
        self._stop.set()
        self._queued.set()
        # the acquisition thread first: what its last slot queues is then in the publisher's
        # final flush
        for thread in reversed(self._threads):
            thread.join(timeout=5.0)
        self._threads = []
        for agent in self.agents:
            agent.stop()

    def _run(self) -> None:
        while not self._stop.is_set():
            first: tuple[float, int] | None = None
            for i, agent in enumerate(self.agents):
                slot = agent.next_slot()
                if slot is not None and (first is None or slot.t < first[0]):
                    first = (slot.t, i)
            if first is None:
                self._stop.wait(0.05)
                continue
            wait = first[0] - self.clock()
            if wait > 0 and self._stop.wait(wait):
                break
            agent = self.agents[first[1]]
            slot = agent.next_slot()
            if slot is None:  # a new schedule took the slot away while we waited
                continue
            if slot.t > self.clock():
                continue  # the new schedule moved it later: wait again
            self._order.append((agent, agent.serve(slot)))
            self._queued.set()

    def _publish_loop(self) -> None:
        while not self._stop.is_set():
            self._queued.wait(0.1)
            self._queued.clear()
            while self._order:
                agent, count = self._order.popleft()
                agent.publish_pending(count)
        for agent in self.agents:
            agent.publish_pending()
