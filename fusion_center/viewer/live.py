"""Glue between a running :class:`~fusion_center.service.FusionService` and the web view.

:class:`FusionViewSource` hands the web server snapshots of the service (copies taken under
the service's lock) plus the latest ``image`` and ``poses`` messages of the network, which it
receives through its own zenoh subscribers (callbacks only store the bytes; decoding happens on
the web server's thread). :func:`start_web_view` wires both and returns a stop function.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

import zenoh

from fusion_center.service import FusionService
from fusion_center.viewer.server import WebViewConfig, WebViewServer
from fusion_center.viewer.state import NodeView, ViewInput
from protocol import Image, Poses, ProtocolError, keys

log = logging.getLogger(__name__)


class FusionViewSource:
    """Snapshots of ``service`` for the web view; ``start()``/``stop()`` declare and undeclare
    the subscribers to ``fusion/image`` and ``fusion/poses``."""

    def __init__(self, service: FusionService) -> None:
        self.service = service
        self._latest: dict[str, bytes] = {}
        self._decoded: dict[str, tuple[bytes, Any]] = {}
        self._subs: list[Any] = []

    def start(self) -> None:
        if self._subs:
            return
        net, s = self.service.config.net, self.service.session
        for leaf in ("image", "poses"):
            self._subs.append(
                s.declare_subscriber(
                    keys.fusion_key(net, leaf),
                    lambda sample, leaf=leaf: self._latest.__setitem__(
                        leaf, sample.payload.to_bytes()
                    ),
                )
            )

    def stop(self) -> None:
        while self._subs:
            sub = self._subs.pop()
            try:
                sub.undeclare()
            except zenoh.ZError:
                pass  # the session is already closing

    def _message(self, leaf: str, cls: Any) -> Any:
        raw = self._latest.get(leaf)
        if raw is None:
            return None
        cached = self._decoded.get(leaf)
        if cached is not None and cached[0] is raw:
            return cached[1]
        try:
            msg = cls.from_wire(raw)
        except ProtocolError as exc:
            log.warning("web view: %s rejected: %s", leaf, exc)
            msg = None
        self._decoded[leaf] = (raw, msg)
        return msg

    def __call__(self) -> ViewInput:
        svc = self.service
        out, health = svc.snapshot()
        estimates = []
        q = svc.recent_estimates
        while q:
            try:
                estimates.append(q.popleft())
            except IndexError:
                break
        c = svc.core.counters
        return ViewInput(
            output=out,
            nodes={
                k: NodeView(
                    alive=h.alive,
                    detections=h.detections,
                    latency_ms=h.latency_ms,
                    status=h.last_status,
                )
                for k, h in health.items()
            },
            infos=svc.node_infos(),
            estimates=estimates,
            image=self._message("image", Image),
            poses=self._message("poses", Poses),
            counters={
                "method": svc.config.method,
                "updates": c.updates,
                "late": c.late,
                "duplicates": c.duplicates,
                "decode_errors": svc.decode_errors,
            },
        )


def start_web_view(
    service: FusionService, config: WebViewConfig, walls: list[list[float]] | None = None
) -> tuple[WebViewServer, Callable[[], None]]:
    """Serve the live view of ``service``; returns the server and its stop function (call it
    before the service's session closes)."""
    source = FusionViewSource(service)
    source.start()
    server = WebViewServer(source, walls, config, clock=service.clock)
    try:
        server.start()
    except BaseException:
        source.stop()
        raise

    def stop() -> None:
        server.stop()
        source.stop()

    return server, stop
