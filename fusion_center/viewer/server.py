"""The live web view: an aiohttp server on its own thread and event loop in the fusion process.

One static page (``static/index.html``, plain JS, no build step) draws the floor plan, sensors,
tracks and a heat map from Server-Sent Events; a JSON API serves the same documents to scripts:

- ``GET /`` the page; ``GET /static/...`` its files.
- ``GET /api/state`` tracks, nodes and counters; ``GET /api/tracks``, ``/api/nodes``: its parts.
- ``GET /api/scene`` walls and extent; ``GET /api/image`` the heat map (8-bit, base64).
- ``GET /events`` Server-Sent Events: ``scene`` on connect, ``state`` at ``rate`` Hz,
  ``image`` at ``image_rate`` Hz. The browser's EventSource reconnects by itself; the page
  also reconnects when the stream goes quiet.

The fusion loop is never blocked or slowed beyond taking a snapshot: a producer task on the
server's loop asks ``source()`` for a :class:`~fusion_center.viewer.state.ViewInput` (copies
taken under the service's lock), builds and serialises the documents once per tick, and every
client gets the same bytes. A slow client only delays its own stream (it always gets the newest
state, never a backlog).
"""

from __future__ import annotations

import asyncio
import dataclasses
import json
import logging
import threading
import time
from collections.abc import Callable
from importlib import resources
from typing import Any

from aiohttp import web

from fusion_center.viewer.state import LiveViewConfig, LiveViewModel, ViewInput

log = logging.getLogger(__name__)

STATIC = resources.files("fusion_center.viewer") / "static"


@dataclasses.dataclass(frozen=True, slots=True, kw_only=True)
class WebViewConfig:
    """Parameters of the web view server.

    Parameters
    ----------
    port : TCP port (0: any free port, see :attr:`WebViewServer.port`).
    host : address to bind; ``127.0.0.1`` keeps the view on this machine, ``0.0.0.0`` opens it
        to the network (the view has no authentication: put it behind a proxy that has).
    rate : state updates per second pushed to the page.
    image_rate : heat-map updates per second.
    view : what the page shows (tails, rates, image).
    """

    port: int = 8080
    host: str = "127.0.0.1"
    rate: float = 15.0
    image_rate: float = 4.0
    view: LiveViewConfig = dataclasses.field(default_factory=LiveViewConfig)


class WebViewServer:
    """Serves the live view of ``source()`` snapshots. ``start()``/``stop()`` are idempotent.

    Parameters
    ----------
    source : returns the current :class:`ViewInput`; called on the server's thread at ``rate``.
    walls : floor-plan segments ``[x1, y1, x2, y2]``, m.
    config : WebViewConfig
    clock : network time, s.
    """

    def __init__(
        self,
        source: Callable[[], ViewInput],
        walls: list[list[float]] | None = None,
        config: WebViewConfig | None = None,
        *,
        clock: Callable[[], float] = time.time,
    ) -> None:
        self.source, self.config, self.clock = source, config or WebViewConfig(), clock
        self.model = LiveViewModel(walls or [], self.config.view)
        self.port = self.config.port
        self._thread: threading.Thread | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._stopping: asyncio.Event | None = None
        self._changed: asyncio.Condition | None = None
        self._state: dict[str, Any] = {"tracks": [], "nodes": [], "seq": 0}
        self._state_bytes = b""
        self._image: dict[str, Any] | None = None
        self._image_bytes = b""
        self._scene: dict[str, Any] = self.model.scene({})
        self._scene_bytes = b""
        #: Ticks produced and the CPU time (s, thread time) the producer spent on them.
        self.ticks = 0
        self.produce_cpu = 0.0
        self.clients = 0

    # -- lifecycle -------------------------------------------------------------------------

    def start(self, timeout: float = 10.0) -> None:
        """Bind the port and start serving; raises OSError if the port cannot be bound."""
        if self._thread is not None:
            return
        self._ready.clear()
        self._thread = threading.Thread(target=self._run, name="webview", daemon=True)
        self._thread.start()
        if not self._ready.wait(timeout):
            raise RuntimeError("web view did not start")
        if self._error is not None:
            self._thread.join()
            self._thread = None
            err, self._error = self._error, None
            raise err
        log.info("web view on http://%s:%d/", self.config.host, self.port)

    def stop(self) -> None:
        """Close every stream and the listening socket; wait for the thread. Idempotent."""
        if self._thread is None:
            return
        loop, stopping = self._loop, self._stopping
        if loop is not None and stopping is not None and not loop.is_closed():
            loop.call_soon_threadsafe(stopping.set)
        self._thread.join(timeout=10.0)
        self._thread = None

    @property
    def url(self) -> str:
        return f"http://{self.config.host}:{self.port}/"

    def _run(self) -> None:
        loop = asyncio.new_event_loop()
        self._loop = loop
        try:
            loop.run_until_complete(self._serve())
        except BaseException as exc:  # reported to start(); the thread must not die silently
            if not self._ready.is_set():
                self._error = exc
                self._ready.set()
            else:
                log.exception("web view stopped")
        finally:
            loop.close()

    async def _serve(self) -> None:
        self._stopping = asyncio.Event()
        self._changed = asyncio.Condition()
        app = web.Application()
        app.router.add_get("/", self._index)
        app.router.add_get("/api/state", self._api("state"))
        app.router.add_get("/api/tracks", self._api("tracks"))
        app.router.add_get("/api/nodes", self._api("nodes"))
        app.router.add_get("/api/scene", self._api("scene"))
        app.router.add_get("/api/image", self._api("image"))
        app.router.add_get("/events", self._events)
        app.router.add_static("/static/", str(STATIC))
        runner = web.AppRunner(app, handle_signals=False, access_log=None, shutdown_timeout=1.0)
        await runner.setup()
        try:
            site = web.TCPSite(runner, self.config.host, self.config.port, reuse_address=True)
            await site.start()
            if runner.addresses:
                self.port = int(runner.addresses[0][1])
            self._produce_once()
            self._ready.set()
            producer = asyncio.create_task(self._producer())
            await self._stopping.wait()
            producer.cancel()
            async with self._changed:
                self._changed.notify_all()  # streams see _stopping and end
        finally:
            await runner.cleanup()

    # -- producer --------------------------------------------------------------------------

    async def _producer(self) -> None:
        period = 1.0 / self.config.rate
        image_every = max(1, round(self.config.rate / self.config.image_rate))
        next_t = time.monotonic()
        assert self._changed is not None
        while True:
            next_t += period
            await asyncio.sleep(max(0.0, next_t - time.monotonic()))
            if time.monotonic() - next_t > 1.0:
                next_t = time.monotonic()  # fell behind (suspended): do not burst
            try:
                self._produce_once(image=self.ticks % image_every == 0)
            except Exception:  # a bad snapshot must not end the view
                log.exception("web view update failed")
            async with self._changed:
                self._changed.notify_all()

    def _produce_once(self, *, image: bool = True) -> None:
        c0 = time.thread_time()
        snap = self.source()
        now = self.clock()
        self._state = self.model.update(now, snap)
        self._state_bytes = _sse("state", self._state)
        scene = self.model.scene(snap.infos)
        if scene != self._scene or not self._scene_bytes:
            self._scene = scene
            self._scene_bytes = _sse("scene", scene)
        if image:
            doc = self.model.image(now, snap)
            if doc is not None:
                self._image = doc
                self._image_bytes = _sse("image", doc)
        self.ticks += 1
        self.produce_cpu += time.thread_time() - c0

    # -- handlers --------------------------------------------------------------------------

    async def _index(self, request: web.Request) -> web.StreamResponse:
        return web.FileResponse(str(STATIC / "index.html"))

    def _api(self, what: str) -> Callable[[web.Request], Any]:
        async def handler(request: web.Request) -> web.Response:
            if what == "state":
                doc: Any = self._state
            elif what == "scene":
                doc = self._scene
            elif what == "image":
                doc = self._image
                if doc is None:
                    return web.json_response({"error": "no image yet"}, status=404)
            else:
                doc = {"t": self._state.get("t"), what: self._state.get(what, [])}
            return web.json_response(doc, dumps=_dumps)

        return handler

    async def _events(self, request: web.Request) -> web.StreamResponse:
        assert self._changed is not None and self._stopping is not None
        resp = web.StreamResponse(
            headers={
                "Content-Type": "text/event-stream",
                "Cache-Control": "no-cache",
                "X-Accel-Buffering": "no",
            }
        )
        await resp.prepare(request)
        self.clients += 1
        try:
            await resp.write(b"retry: 1000\n\n" + self._scene_bytes + self._image_bytes)
            sent_scene, sent_image, sent_state = self._scene_bytes, self._image_bytes, b""
            while not self._stopping.is_set():
                if self._state_bytes is sent_state:
                    async with self._changed:
                        await self._changed.wait()
                    continue
                chunk = self._state_bytes
                sent_state = chunk
                if self._scene_bytes is not sent_scene:
                    sent_scene = self._scene_bytes
                    chunk = sent_scene + chunk
                if self._image_bytes is not sent_image:
                    sent_image = self._image_bytes
                    chunk += sent_image
                await resp.write(chunk)
        except (ConnectionResetError, asyncio.CancelledError):
            pass
        finally:
            self.clients -= 1
        return resp


def _dumps(doc: Any) -> str:
    return json.dumps(doc, separators=(",", ":"))


def _sse(event: str, doc: Any) -> bytes:
    return f"event: {event}\ndata: {_dumps(doc)}\n\n".encode()
