"""The live view's model and server with a synthetic fusion snapshot (no zenoh, no browser):
JSON API, SSE stream at the configured rate, tails, node states, the eq. (23) heat map, and a
clean stop."""

from __future__ import annotations

import base64
import json
import time
import urllib.request

import numpy as np
import pytest

from fusion_center.tracking.base import TrackerOutput, TrackEstimate
from fusion_center.viewer.server import WebViewConfig, WebViewServer
from fusion_center.viewer.state import LiveViewModel, NodeView, ViewInput
from uwbnet.bench_web import SyntheticFusion, _infos


def _snap(t: float, xs: list[float], alive: dict[str, bool], est=()) -> ViewInput:
    infos = _infos(4)
    out = TrackerOutput(
        t=t,
        tracks=tuple(TrackEstimate(id=i, x=x, y=5.0, vx=1.0, vy=0.0) for i, x in enumerate(xs)),
        n_estimate=len(xs),
    )
    nodes = {n: NodeView(alive=alive.get(n, True), detections=int(50 * t)) for n in infos}
    return ViewInput(output=out, nodes=nodes, infos=infos, estimates=est)


def test_model_tails_rates_states_and_moving_target_image() -> None:
    m = LiveViewModel([[0, 0, 40, 0]])
    for k in range(31):
        t = 0.1 * k
        est = [(t, np.array([[10.0 + t, 5.0]]), np.eye(2)[None] * 0.01)]
        doc = m.update(t, _snap(t, [1.0 + t, 20.0], {"s002": k < 20}, est))
    tr = {d["id"]: d for d in doc["tracks"]}
    # Tail: one point per 0.2 s over the last 3 s, ending at the current position.
    assert 13 <= len(tr[0]["tail"]) <= 17 and tr[0]["tail"][-1] == [4.0, 5.0]
    assert tr[0]["tail"][0][0] >= 0.9  # nothing older than 3 s
    nodes = {n["id"]: n for n in doc["nodes"]}
    assert nodes["s002"]["state"] == "lost" and nodes["s002"]["latency_ms"] is None
    assert nodes["s001"]["state"] == "alive"
    assert nodes["s001"]["rate"] == pytest.approx(50.0, abs=1.0)
    img = m.image(3.0, _snap(3.0, [], {}))
    assert img is not None and img["method"] == "eq23"
    q = np.frombuffer(base64.b64decode(img["data"]), np.uint8).reshape(img["ny"], img["nx"])
    i, j = np.unravel_index(int(np.argmax(q)), q.shape)
    # The newest estimates (x = 13 m, y = 5 m) dominate under the forgetting factor.
    assert (
        abs(img["x0"] + j * img["dx"] - 13.0) < 0.5 and abs(img["y0"] + i * img["dy"] - 5.0) < 0.5
    )
    # A track that is gone loses its tail.
    doc = m.update(3.1, _snap(3.1, [], {}))
    assert doc["tracks"] == [] and m._tails == {}


def _get(url: str) -> object:
    with urllib.request.urlopen(url, timeout=5) as r:
        return json.loads(r.read())


def test_server_api_and_sse_stream_then_clean_stop() -> None:
    server = WebViewServer(SyntheticFusion(1), [[0, 0, 40, 0]], WebViewConfig(port=0, rate=20))
    server.start()
    try:
        base = server.url
        assert len(_get(base + "api/tracks")["tracks"]) == 30
        assert len(_get(base + "api/nodes")["nodes"]) == 100
        assert _get(base + "api/scene")["walls"] == [[0, 0, 40, 0]]
        with urllib.request.urlopen(base, timeout=5) as r:
            assert b"<canvas" in r.read()
        with urllib.request.urlopen(base + "static/view.js", timeout=5) as r:
            assert b"EventSource" in r.read()
        events: dict[str, int] = {}
        t0 = time.monotonic()
        with urllib.request.urlopen(base + "events", timeout=5) as r:
            while time.monotonic() - t0 < 1.5:
                line = r.readline()
                if line.startswith(b"event: "):
                    name = line[7:].strip().decode()
                    events[name] = events.get(name, 0) + 1
                elif line.startswith(b"data: "):
                    json.loads(line[6:])
        rate = events["state"] / (time.monotonic() - t0)
        assert 15 <= rate <= 25, events
        assert events["scene"] >= 1 and events["image"] >= 3
        assert _get(base + "api/image")["method"] == "eq23"
    finally:
        server.stop()
    server.stop()  # idempotent
    with pytest.raises(OSError):
        urllib.request.urlopen(server.url + "api/state", timeout=2)


def test_a_port_in_use_is_an_oserror_not_a_hang() -> None:
    a = WebViewServer(SyntheticFusion(1), config=WebViewConfig(port=0))
    a.start()
    try:
        b = WebViewServer(SyntheticFusion(1), config=WebViewConfig(port=a.port))
        with pytest.raises(OSError):
            b.start()
    finally:
        a.stop()


def test_fusion_config_web_section(tmp_path) -> None:
    from uwbnet.config import ConfigError, FusionFile, load_config

    good = tmp_path / "f.toml"
    good.write_text('[web]\nport = 0\nscenario = "foyer3"\n')
    cfg = load_config(FusionFile, good, env={})
    assert cfg.web is not None and cfg.web.port == 0 and cfg.web.rate == 15.0
    assert load_config(FusionFile, None, env={}).web is None
    bad = tmp_path / "b.toml"
    bad.write_text("[web]\nport = 70000\n")
    with pytest.raises(ConfigError, match=r"web\.port"):
        load_config(FusionFile, bad, env={})
