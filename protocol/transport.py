"""Zenoh sessions and the queues between zenoh callbacks and worker threads.

A zenoh callback only enqueues and never blocks or calls zenoh (zenoh's rule; deadlocks
follow otherwise). High-rate streams go through a :class:`RingChannel` that drops the oldest
item and counts the drop; control traffic through a :class:`FifoChannel` that counts
rejections when full. Both are thin ``collections.deque``/``threading.Condition`` pairs: zenoh's
own ``handlers.RingChannel`` does not count what it drops, which ``status`` must report.
"""

from __future__ import annotations

import collections
import json
import socket
import threading
import time
from collections.abc import Sequence
from typing import Any, Generic, TypeVar

import zenoh

T = TypeVar("T")


def session_config(
    *,
    mode: str = "peer",
    listen: Sequence[str] = (),
    connect: Sequence[str] = (),
    multicast_scouting: bool = False,
    shared_memory: bool = False,
    timestamping: bool = True,
    lease_ms: int | None = None,
    config_file: str | None = None,
) -> zenoh.Config:
    """Build a zenoh configuration.

    In peer mode on one machine every session listens on its own loopback port (``tcp/127.0.0.1:0``
    when ``listen`` is empty) so that gossip scouting can build a full mesh: without it, two peers
    that both only connect to a third cannot query each other. Multicast scouting is off by
    default: tests and the demo must not reach beyond the addresses they name.
    """
    conf = zenoh.Config.from_file(config_file) if config_file else zenoh.Config()
    if mode not in ("peer", "client", "router"):
        raise ValueError(f"zenoh mode must be peer, client or router, not {mode!r}")
    conf.insert_json5("mode", json.dumps(mode))
    if not listen and mode != "client":
        listen = ["tcp/127.0.0.1:0"]
    if listen:
        conf.insert_json5("listen/endpoints", json.dumps(list(listen)))
    if connect:
        conf.insert_json5("connect/endpoints", json.dumps(list(connect)))
    if not config_file:
        conf.insert_json5("scouting/multicast/enabled", json.dumps(multicast_scouting))
        conf.insert_json5("transport/shared_memory/enabled", json.dumps(shared_memory))
        conf.insert_json5("timestamping/enabled", json.dumps(timestamping))
    if lease_ms is not None:
        conf.insert_json5("transport/link/tx/lease", json.dumps(lease_ms))
    return conf


def stop_worker(
    stop: threading.Event, thread: threading.Thread | None, declarations: list[Any]
) -> None:
    """Stop a service's worker thread and undeclare its zenoh entities, newest first.

    Idempotent: ``declarations`` is emptied. An entity whose session is already closing is
    skipped (zenoh raises ``ZError`` for it).
    """
    stop.set()
    if thread is not None:
        thread.join(timeout=5.0)
    for d in reversed(declarations):
        try:
            d.undeclare()
        except zenoh.ZError:
            pass
    declarations.clear()


def free_tcp_port() -> int:
    """A currently free TCP port on 127.0.0.1 (for a listening endpoint)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class _Channel(Generic[T]):
    def __init__(self, capacity: int) -> None:
        if capacity < 1:
            raise ValueError("capacity must be >= 1")
        self.capacity = capacity
        self._items: collections.deque[T] = collections.deque()
        self._cond = threading.Condition()
        self.dropped = 0
        self.received = 0

    def get(self, timeout: float | None = None) -> T | None:
        """Take the oldest item, waiting up to ``timeout`` s; None if none came."""
        deadline = None if timeout is None else time.monotonic() + timeout
        with self._cond:
            while not self._items:
                remaining = None if deadline is None else deadline - time.monotonic()
                if remaining is not None and remaining <= 0:
                    return None
                self._cond.wait(remaining)
            return self._items.popleft()

    def get_before(self, index: int) -> T | None:
        """Take the oldest item if it was the ``k``-th put with ``k < index`` (counting from
        0 over the channel's life), else None; never waits. Items dropped when the channel
        was full keep their numbers, so a reader that marked "up to put ``index``" never
        takes a later put in their place."""
        with self._cond:
            if not self._items or self.received - len(self._items) >= index:
                return None
            return self._items.popleft()

    def drain(self) -> list[T]:
        """Take every queued item without waiting."""
        with self._cond:
            items = list(self._items)
            self._items.clear()
            return items

    def __len__(self) -> int:
        return len(self._items)


class RingChannel(_Channel[T]):
    """Bounded queue that drops the oldest item when full (and counts it): for ``ir``."""

    def put(self, item: T) -> None:
        with self._cond:
            self.received += 1
            if len(self._items) >= self.capacity:
                self._items.popleft()
                self.dropped += 1
            self._items.append(item)
            self._cond.notify()


class FifoChannel(_Channel[T]):
    """Bounded FIFO that rejects (and counts) a new item when full; never blocks the caller."""

    def put(self, item: T) -> None:
        with self._cond:
            self.received += 1
            if len(self._items) >= self.capacity:
                self.dropped += 1
                return
            self._items.append(item)
            self._cond.notify()
