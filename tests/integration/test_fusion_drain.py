"""The fusion center takes its inputs from zenoh's channels in batches (one wake-up every
``poll_period``, docs/capacity.md "Ninth round, hub side"), over real zenoh sessions: every
detection of a burst is fused and counted in the node's health, and bad messages are still
counted and logged, not fatal."""

from __future__ import annotations

import contextlib
import threading
import time

import msgpack
import numpy as np
import pytest
import zenoh

from fusion_center.service import FusionConfig, FusionService
from protocol import Status, decode, keys
from protocol.transport import session_config
from uwbnet.bench_hub import node_infos, synthetic_detections

pytestmark = pytest.mark.integration

NET = "draintest"


def _wait_for(predicate, timeout: float, what: str) -> None:  # type: ignore[no-untyped-def]
    deadline = time.monotonic() + timeout
    event = threading.Event()
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout} s waiting for {what}")
        event.wait(0.02)


def test_a_burst_of_detections_is_fused_and_bad_messages_are_counted(hub_endpoint) -> None:
    infos = node_infos(4)
    frames = 40
    start, velocity = np.array([[5.0, 4.0]]), np.array([[0.5, 0.0]])
    # acquired during the last second (0.8 s of frames), published now as one burst
    payloads = synthetic_detections(
        infos, frames, start, velocity, t0=time.time() - 1.0, rng=np.random.default_rng(3)
    )
    with contextlib.ExitStack() as stack:
        fs = stack.enter_context(zenoh.open(session_config(listen=[hub_endpoint])))
        # a long poll period: the whole burst waits in the channel for one wake-up
        fusion = FusionService(fs, FusionConfig(net=NET, poll_period=0.2))
        fusion.start()
        stack.callback(fusion.stop)
        peer = stack.enter_context(zenoh.open(session_config(connect=[hub_endpoint])))
        for info in infos:
            peer.put(keys.node_key(NET, info.src, "info"), info.to_wire())
        _wait_for(lambda: len(fusion.node_infos()) == len(infos), 10.0, "node_info")
        pubs = [peer.declare_publisher(keys.node_key(NET, i.src, "det")) for i in infos]
        for k, payload in enumerate(payloads):
            pubs[k % len(infos)].put(payload)
        bad = keys.node_key(NET, infos[0].src, "det")
        peer.put(bad, b"\xc1 not msgpack")
        peer.put(bad, msgpack.packb({"v": 1, "kind": "detections", "src": "x"}))
        status = Status(
            src=infos[0].src, seq=0, t=time.time(), uptime=1.0, acquired=1, published=1,
            dropped=0, late_slots=0, decode_errors=0, cpu=0.1,
        )  # fmt: skip
        peer.put(bad, status.to_wire())  # a valid message of the wrong kind for the key
        _wait_for(lambda: fusion.decode_errors >= 3, 10.0, "three rejections")
        _wait_for(lambda: fusion.core.counters.detections == len(payloads), 10.0, "detections")
        # the last frames are fused once the stream has been quiet for flush_after
        _wait_for(lambda: fusion.core.counters.updates == frames, 10.0, "every frame fused")
        _, health = fusion.snapshot()
        for p in pubs:
            p.undeclare()
    assert fusion.decode_errors == 3 and fusion.handler_errors == 0
    assert fusion.core.counters.late == 0 and fusion.core.counters.duplicates == 0
    last = {d.src: d.t for d in map(decode, payloads)}  # each node's latest acquisition
    assert set(health) == set(last)
    for src, t in last.items():
        assert health[src].detections == frames
        assert health[src].last_det_t == t
        assert 0.0 <= health[src].latency_ms < 60_000.0


def test_the_poll_period_and_channel_capacity_are_checked() -> None:
    with pytest.raises(ValueError, match="poll_period"):
        FusionConfig(poll_period=0.0)
    with pytest.raises(ValueError, match="poll_period"):
        FusionConfig(poll_period=float("nan"))
    with pytest.raises(ValueError, match="channel_capacity"):
        FusionConfig(channel_capacity=0)
