"""``uwbnet bench web``: the live web view at 100 sensors and 30 tracks.

A synthetic fusion snapshot (100 sensors around a 40 m x 30 m hall, 30 people walking circles,
100 local estimates per 20 ms frame) feeds the real :class:`WebViewServer` in this process.
Measured:

- with one SSE client in another process: the update rate it receives, bytes per update, and
  the CPU this process spends serving (process CPU time over wall time: fraction of one core),
  with the producer's own CPU per update;
- when Debian's Chromium and Playwright are present, the same page in headless Chromium: the
  update rate the page sees and the frames it draws per second (it stays responsive if both
  keep up), and the serving process's CPU with the browser attached.
"""

from __future__ import annotations

import math
import multiprocessing
import time
from pathlib import Path
from typing import Any

import numpy as np

N_SENSORS = 100
N_TRACKS = 30
SECONDS = 8.0


def _infos(n: int) -> dict[str, Any]:
    from protocol import Antenna, NodeInfo, RadarInfo

    infos = {}
    for k in range(n):
        # Sensors on the hall's perimeter (40 m x 30 m), looking inwards.
        s = k / n * 140.0
        if s < 40:
            x, y, yaw = s, 0.0, math.pi / 2
        elif s < 70:
            x, y, yaw = 40.0, s - 40, math.pi
        elif s < 110:
            x, y, yaw = 110 - s, 30.0, -math.pi / 2
        else:
            x, y, yaw = 0.0, 140 - s, 0.0
        ant = {
            "tx": Antenna(pos=(0, 0, 0), tx=True, rx=False, boresight=0.0, beamwidth=1.75),
            "rx1": Antenna(pos=(0, 0.5, 0), tx=False, rx=True, boresight=0.0, beamwidth=1.75),
        }
        radar = RadarInfo(fs=7e9, n=4095, t0=0.0, f_low=0.0, f_high=3.5e9, rate=50.0)
        nid = f"s{k:03d}"
        infos[nid] = NodeInfo(
            src=nid,
            seq=0,
            t=0.0,
            role="bat",
            pose=(x, y, 1.2, yaw),
            mobile=False,
            antennas=ant,
            radar=radar,
        )
    return infos


class SyntheticFusion:
    """Snapshots of a busy fusion center: 30 tracks on circles, 100 healthy sensors."""

    def __init__(self, seed: int) -> None:
        self.rng = np.random.default_rng(seed)
        self.infos = _infos(N_SENSORS)
        self.centres = self.rng.uniform([5, 5], [35, 25], size=(N_TRACKS, 2))
        self.radii = self.rng.uniform(1.0, 4.0, N_TRACKS)
        self.t0 = time.time()
        self.last = self.t0

    def __call__(self) -> Any:
        from fusion_center.tracking.base import TrackerOutput, TrackEstimate
        from fusion_center.viewer.state import NodeView, ViewInput
        from protocol import Status

        now = time.time()
        t = now - self.t0
        ang = 0.3 * t + np.arange(N_TRACKS)
        xy = self.centres + self.radii[:, None] * np.stack([np.cos(ang), np.sin(ang)], axis=1)
        out = TrackerOutput(
            t=now,
            tracks=tuple(
                TrackEstimate(id=i + 1, x=float(p[0]), y=float(p[1]), vx=0.3, vy=0.0, w=1.0)
                for i, p in enumerate(xy)
            ),
            n_estimate=float(N_TRACKS),
        )
        n_frames = max(1, round((now - self.last) / 0.02))
        self.last = now
        k = N_SENSORS * n_frames
        est = [
            (
                now,
                xy[self.rng.integers(0, N_TRACKS, k)] + self.rng.normal(0, 0.1, (k, 2)),
                np.broadcast_to(np.eye(2) * 0.01, (k, 2, 2)),
            )
        ]
        st = Status(
            src="s",
            seq=0,
            t=now,
            uptime=t,
            acquired=int(50 * t),
            published=int(50 * t),
            dropped=0,
            late_slots=0,
            decode_errors=0,
            cpu=0.05,
        )
        nodes = {
            n: NodeView(alive=True, detections=int(50 * t), latency_ms=2.0, status=st)
            for n in self.infos
        }
        return ViewInput(output=out, nodes=nodes, infos=self.infos, estimates=est)


def _sse_client(url: str, seconds: float, result: Any) -> None:
    """Read ``/events`` for ``seconds``; put (state events, bytes, wall s) in ``result``."""
    import http.client
    from urllib.parse import urlparse

    u = urlparse(url)
    conn = http.client.HTTPConnection(u.hostname, u.port, timeout=10)
    conn.request("GET", "/events")
    resp = conn.getresponse()
    n = size = 0
    t0 = time.monotonic()
    while time.monotonic() - t0 < seconds:
        line = resp.readline()
        if not line:
            break
        size += len(line)
        if line.startswith(b"event: state"):
            n += 1
    result.put((n, size, time.monotonic() - t0))
    conn.close()


def _serving_cpu(fn: Any) -> tuple[Any, float, float]:
    c0, w0 = time.process_time(), time.monotonic()
    r = fn()
    return r, time.process_time() - c0, time.monotonic() - w0


def bench_web(seed: int = 0) -> dict[str, Any]:
    from fusion_center.viewer.server import WebViewConfig, WebViewServer
    from fusion_center.viewer.state import floor_plan  # noqa: F401  (import cost outside)

    src = SyntheticFusion(seed)
    walls = [[0, 0, 40, 0], [40, 0, 40, 30], [40, 30, 0, 30], [0, 30, 0, 0], [20, 0, 20, 12]]
    server = WebViewServer(src, walls, WebViewConfig(port=0))
    server.start()
    result: dict[str, Any] = {"sensors": N_SENSORS, "tracks": N_TRACKS, "target_rate_hz": 15.0}
    try:
        ctx = multiprocessing.get_context("spawn")
        q = ctx.Queue()
        p = ctx.Process(target=_sse_client, args=(server.url, SECONDS, q))
        p.start()
        time.sleep(1.0)  # client start-up (spawn) is not the server's cost
        ticks0, prod0 = server.ticks, server.produce_cpu
        (_, cpu, wall) = _serving_cpu(lambda: time.sleep(SECONDS - 1.5))
        ticks = server.ticks - ticks0
        n, size, cwall = q.get(timeout=30)
        p.join(10)
        result.update(
            sse_rate_hz=round(n / cwall, 2),
            bytes_per_update=round(size / max(n, 1)),
            serving_cpu_core_fraction=round(cpu / wall, 4),
            producer_ms_per_update=round(1e3 * (server.produce_cpu - prod0) / max(ticks, 1), 3),
        )
        result.update(_browser(server.url))
    finally:
        server.stop()
    result["cores"] = multiprocessing.cpu_count()
    return result


def _browser(url: str) -> dict[str, Any]:
    """Page-side figures in headless Chromium; empty with a reason when it is not available."""
    chromium = Path("/usr/bin/chromium")
    if not chromium.exists():
        return {"browser": "skipped: no /usr/bin/chromium"}
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        return {"browser": "skipped: playwright not installed"}
    import tempfile

    flags = [
        "--no-sandbox",
        "--disable-gpu",
        "--disable-quic",
        "--no-first-run",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
    ]
    with tempfile.TemporaryDirectory() as profile, sync_playwright() as pw:
        ctx = pw.chromium.launch_persistent_context(
            profile,
            executable_path=str(chromium),
            headless=True,
            args=["--headless", *flags],
            viewport={"width": 1400, "height": 800},
        )
        try:
            page = ctx.pages[0] if ctx.pages else ctx.new_page()
            page.goto(url)
            page.wait_for_function("window.uwbnetView.updates > 5", timeout=20_000)
            u0, f0 = page.evaluate("[window.uwbnetView.updates, window.uwbnetView.frames]")
            (_, cpu, wall) = _serving_cpu(lambda: page.wait_for_timeout(SECONDS * 1000))
            u1, f1 = page.evaluate("[window.uwbnetView.updates, window.uwbnetView.frames]")
            shown = page.evaluate(
                "[window.uwbnetView.state.tracks.length, window.uwbnetView.state.nodes.length]"
            )
        finally:
            ctx.close()
    return {
        "browser_rate_hz": round((u1 - u0) / wall, 2),
        "browser_frames_per_s": round((f1 - f0) / wall, 2),
        "browser_tracks_nodes_shown": shown,
        # Includes this process's Playwright client, which is not part of serving.
        "serving_cpu_core_fraction_with_browser": round(cpu / wall, 4),
    }
