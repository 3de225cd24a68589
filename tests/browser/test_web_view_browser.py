"""The live web view in a real browser: Debian's headless Chromium driven by Playwright.

A fusion center with ``[web]`` in its config (``uwbnet fusion``) and the foyer3 sensors as two
``uwbnet simnode`` processes (bat1-bat5, and bat6 alone so that it can be killed) run as real
processes over zenoh on loopback. The page must show the three walking people as moving tracks
and mark bat6 lost after its process is killed. Screenshots are kept as test artefacts (their
paths are printed; ``UWBNET_ARTIFACTS=DIR`` keeps them outside pytest's tmp dir).
"""

from __future__ import annotations

import math
import os
import signal
import threading
import time
from pathlib import Path

import pytest

from tests.browser.chromium import browser_page

pytestmark = [pytest.mark.browser, pytest.mark.integration, pytest.mark.slow]

NET = "webtest"


def _wait_log(procs, name: str, text: str, timeout: float) -> None:  # type: ignore[no-untyped-def]
    deadline = time.monotonic() + timeout
    while text not in procs.log(name):
        if time.monotonic() > deadline:
            raise AssertionError(f"{name}: no {text!r} after {timeout} s:\n{procs.log(name)}")
        threading.Event().wait(0.05)


def _artefact(tmp_path: Path, name: str) -> Path:
    base = os.environ.get("UWBNET_ARTIFACTS")
    d = Path(base) if base else tmp_path
    d.mkdir(parents=True, exist_ok=True)
    return d / name


def _tracks(page) -> dict[int, tuple[float, float]]:  # type: ignore[no-untyped-def]
    st = page.evaluate("window.uwbnetView.state")
    return {t["id"]: (t["x"], t["y"]) for t in st["tracks"]}


def test_page_shows_foyer3_tracks_moving_and_marks_a_killed_node_lost(
    procs, tmp_path, hub_endpoint
):
    from protocol.transport import free_tcp_port

    port = free_tcp_port()
    client = f'[zenoh]\nmode = "client"\nconnect = ["{hub_endpoint}"]\nlease = "1 s"\n'
    (tmp_path / "fusion.toml").write_text(
        f'net = "{NET}"\n[web]\nport = {port}\nscenario = "foyer3"\n'
        f'[zenoh]\nmode = "router"\nlisten = ["{hub_endpoint}"]\nlease = "1 s"\n'
    )
    for name, nodes in (("sim", '["bat1", "bat2", "bat3", "bat4", "bat5"]'), ("sim6", '["bat6"]')):
        (tmp_path / f"{name}.toml").write_text(
            f'net = "{NET}"\nscenario = "foyer3"\nseed = 2\nnodes = {nodes}\n{client}'
        )
    procs.uwbnet("-v", "fusion", "--config", str(tmp_path / "fusion.toml"), name="fusion")
    _wait_log(procs, "fusion", "live web view on", 20.0)
    procs.uwbnet("-v", "simnode", "--config", str(tmp_path / "sim.toml"), name="sim")
    sim6 = procs.uwbnet("-v", "simnode", "--config", str(tmp_path / "sim6.toml"), name="sim6")

    with browser_page(tmp_path) as page:
        page.goto(f"http://127.0.0.1:{port}/")
        # Three people walk in the foyer: three confirmed tracks within the warm-up.
        try:
            page.wait_for_function(
                "window.uwbnetView.state && window.uwbnetView.state.tracks.length >= 3",
                timeout=60_000,
            )
        except Exception:
            state = page.evaluate("window.uwbnetView.state")
            raise AssertionError(f"no 3 tracks on the page in 60 s; last state {state}") from None
        assert page.locator("#conn").get_attribute("data-state") == "live"
        # Update rate seen by the page: >= 10 Hz.
        n0, t0 = page.evaluate("window.uwbnetView.updates"), time.monotonic()
        page.wait_for_timeout(2000)
        rate = (page.evaluate("window.uwbnetView.updates") - n0) / (time.monotonic() - t0)
        print(f"page update rate: {rate:.1f} Hz")
        assert rate >= 10.0
        # Three tracks moving: the same three ids 1 s apart, each well over 0.4 m further on
        # (people walk at about 1.3 m/s). Where two people cross, a track may briefly drop,
        # so a few one-second windows are tried.
        before, deadline, moved = _tracks(page), time.monotonic() + 20.0, []
        while len(moved) < 3 and time.monotonic() < deadline:
            page.wait_for_timeout(1000)
            after = _tracks(page)
            moved = [i for i in set(before) & set(after) if math.dist(before[i], after[i]) > 0.4]
            before = after
        assert len(moved) >= 3, f"tracks before {before}, after {after}"
        assert page.locator("#tracks tbody tr").count() >= 3
        walls = page.evaluate("window.uwbnetView.scene.walls.length")
        assert walls >= 4
        assert page.evaluate("window.uwbnetView.image && window.uwbnetView.image.max") > 0
        page.wait_for_selector('#nodes tr[data-node="bat6"][data-state="alive"]')
        alive = page.locator('#nodes tr[data-state="alive"]').count()
        assert alive == 6, page.locator("#nodes").inner_text()
        shot = _artefact(tmp_path, "webview-foyer3.png")
        page.screenshot(path=str(shot))
        print(f"screenshot: {shot}")

        # Kill bat6's process: its liveliness token goes, the page marks it lost.
        sim6.send_signal(signal.SIGKILL)
        sim6.wait(10)
        page.wait_for_selector('#nodes tr[data-node="bat6"][data-state="lost"]', timeout=10_000)
        assert page.locator('#nodes tr[data-state="alive"]').count() == 5
        shot = _artefact(tmp_path, "webview-foyer3-bat6-lost.png")
        page.screenshot(path=str(shot))
        print(f"screenshot: {shot}")

    for name in ("sim", "fusion"):
        p = next(p for p in procs.procs if str(tmp_path / f"{name}.toml") in p.args)
        assert procs.stop(p) == 0, procs.log(name)
    assert "Traceback" not in procs.log("fusion") + procs.log("sim")


def test_page_reconnects_by_itself_after_the_server_restarts(tmp_path):
    """The fusion center restarts: the page says so and picks the stream up again, unaided."""
    from fusion_center.viewer.server import WebViewConfig, WebViewServer
    from uwbnet.bench_web import SyntheticFusion

    server = WebViewServer(SyntheticFusion(3), config=WebViewConfig(port=0))
    server.start()
    port = server.port
    try:
        with browser_page(tmp_path) as page:
            page.goto(server.url)
            page.wait_for_function("window.uwbnetView.updates > 5")
            # 100 sensors and 30 tracks on the page (the tables fill at the first draw).
            page.wait_for_function(
                "document.querySelectorAll('#nodes tbody tr').length > 0", timeout=5_000
            )
            assert page.locator("#nodes tbody tr").count() == 100
            assert page.evaluate("window.uwbnetView.state.tracks.length") == 30
            server.stop()
            page.wait_for_selector('#conn[data-state="reconnecting"]', timeout=10_000)
            n = page.evaluate("window.uwbnetView.updates")
            server = WebViewServer(SyntheticFusion(3), config=WebViewConfig(port=port))
            server.start()
            page.wait_for_function(f"window.uwbnetView.updates > {n + 10}", timeout=15_000)
            assert page.locator("#conn").get_attribute("data-state") == "live"
            shot = _artefact(tmp_path, "webview-100-sensors-30-tracks.png")
            page.screenshot(path=str(shot))
            print(f"screenshot: {shot}")
    finally:
        server.stop()
