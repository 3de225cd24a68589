"""Record a live network to MCAP (PROTOCOL.md, "Recordings").

Subscribes to ``uwbnet/{net}/**`` and writes every payload unchanged. A node's ``node_info`` is
written before its first ``ir`` (or detections, status): when the recorder joined after the node
announced itself, the description is fetched from the node's queryable first.
"""

from __future__ import annotations

import logging
import math
import os
import threading
import time
from typing import Any

import zenoh

from protocol import ProtocolError, decode, keys
from protocol.errors import KeyExprError
from protocol.messages import unpack
from protocol.recording import RecordingWriter
from protocol.transport import FifoChannel

log = logging.getLogger(__name__)

#: Kinds that have a Foxglove view on a ``/viz`` channel.
_VIZ_KINDS = frozenset({"node_info", "tracks", "truth", "image"})


class NetworkRecorder:
    """Writes the traffic of network ``net`` seen by ``session`` into ``path``.

    ``start()``/``stop()`` are idempotent; ``stop()`` drains the queue and closes the file.
    Messages that are not valid uwbnet messages are counted in ``rejected``; messages the
    queue could not hold are counted in ``dropped`` (the queue is sized for seconds of ``ir``).

    Unless ``viz`` is off, Foxglove ``/viz/...`` JSON channels are written beside them
    (:mod:`fusion_center.viewer.foxglove`), with ``walls`` as the floor plan.

    Crash safety: every ``flush_period`` seconds the chunk in progress is ended and handed to
    the OS, so a recorder killed by SIGKILL leaves ``NAME.partial`` readable up to its last
    flush (at most ``flush_period`` s lost); ``uwbnet recover`` turns it into a complete MCAP.
    """

    def __init__(
        self,
        session: zenoh.Session,
        net: str,
        path: str | os.PathLike[str],
        *,
        flush_period: float = 1.0,
        walls: list[list[float]] | None = None,
        viz: bool = True,
    ) -> None:
        from fusion_center.viewer.foxglove import FoxgloveScene

        self.session, self.net, self.flush_period = session, net, flush_period
        #: Foxglove ``/viz`` channels written beside the contract's (None: off).
        self.viz = FoxgloveScene(walls or []) if viz else None
        self.writer = RecordingWriter(path)
        self._inbox: FifoChannel[tuple[str, bytes]] = FifoChannel(20000)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._sub: Any = None
        self._has_info: set[str] = set()
        self._asked: dict[str, float] = {}
        self.rejected = 0

    @property
    def dropped(self) -> int:
        return self._inbox.dropped

    def start(self) -> None:
        if self._thread is not None:
            return
        put = self._inbox.put
        self._sub = self.session.declare_subscriber(
            keys.all_key(self.net),
            lambda s: put((str(s.key_expr), s.payload.to_bytes())),
        )
        self._thread = threading.Thread(target=self._run, name="recorder", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Stop, write what is queued, and close the recording. Idempotent."""
        if self._sub is not None:
            self._sub.undeclare()
            self._sub = None
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=30.0)
            self._thread = None
        for key, payload in self._inbox.drain():
            self._write(key, payload, fetch=False)
        self.writer.close()

    def _run(self) -> None:
        last_flush = time.monotonic()
        while not self._stop.is_set():
            item = self._inbox.get(timeout=0.1)
            if item is not None:
                self._write(*item, fetch=True)
            if time.monotonic() - last_flush >= self.flush_period:
                last_flush = time.monotonic()
                self.writer.flush()

    def _write(self, key: str, payload: bytes, *, fetch: bool) -> None:
        try:
            parsed = keys.parse_key(key)
            m = unpack(payload)
        except (KeyExprError, ProtocolError) as exc:
            self.rejected += 1
            log.warning("not recorded: %s: %s", key, exc)
            return
        t = m.get("t")
        if parsed.kind is None or not isinstance(t, float | int):
            self.rejected += 1
            return
        if parsed.kind == "node_info" and parsed.node:
            self._has_info.add(parsed.node)
        elif parsed.node and parsed.node not in self._has_info:
            # A node first seen by its ir, detections or status: its description comes first
            # (asked at most once a second, the query blocks this worker for up to 1 s).
            now = time.monotonic()
            if fetch and now - self._asked.get(parsed.node, -math.inf) >= 1.0:
                self._asked[parsed.node] = now
                self._fetch_info(parsed.node)
            if parsed.kind == "ir" and parsed.node not in self._has_info:
                self.rejected += 1
                return
        self.writer.write(key, parsed.kind, payload, float(t))
        if self.viz is not None and parsed.kind in _VIZ_KINDS:
            self._write_viz(key, payload)

    def _write_viz(self, key: str, payload: bytes) -> None:
        from fusion_center.viewer.foxglove import dumps, foxglove_schema

        assert self.viz is not None
        try:
            msg = decode(payload)
            docs = self.viz.on_message(msg)
        except (ProtocolError, ValueError) as exc:
            log.warning("no viewer message for %s: %s", key, exc)
            return
        for topic, schema, doc in docs:
            self.writer.write_json(topic, schema, foxglove_schema(schema), dumps(doc), msg.t)

    def _fetch_info(self, node: str) -> None:
        key = keys.node_key(self.net, node, "info")
        try:
            for reply in self.session.get(key, timeout=1.0):
                if reply.ok is not None:
                    self._write(key, reply.ok.payload.to_bytes(), fetch=False)
        except zenoh.ZError as exc:
            log.warning("node_info of %s: %s", node, exc)
