"""The fusion center takes its inputs from zenoh's channels in batches (one wake-up every
``poll_period``, docs/capacity.md; issue 11, stop 21 notes), over real zenoh sessions: every
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
from tests.waiting import wait_for as _wait_for
from uwbnet.bench_hub import node_infos, synthetic_detections

pytestmark = pytest.mark.integration

NET = "draintest"


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


def test_a_worker_far_behind_drops_its_oldest_and_never_stalls_the_router() -> None:
    """The fusion center runs in the network's router (``uwbnet scale``, ``uwbnet fusion``):
    its channels must never block zenoh's network thread. A worker that takes its inputs only
    once a second from channels of 4 samples, flooded by detections, loses the oldest
    (counted per node from the ``seq`` gaps) while unrelated traffic between two other
    clients is still routed. (A blocking FIFO channel routed 0 of 20 there.)"""
    from protocol.transport import free_tcp_port

    port = free_tcp_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    infos = node_infos(2)
    payloads = synthetic_detections(
        infos, 300, np.array([[5.0, 4.0]]), np.array([[0.5, 0.0]]),
        t0=time.time() - 6.0, rng=np.random.default_rng(4),
    )  # fmt: skip
    with contextlib.ExitStack() as stack:
        router = stack.enter_context(zenoh.open(session_config(mode="router", listen=[endpoint])))
        cfg = FusionConfig(net=NET, poll_period=1.0, channel_capacity=4)
        fusion = FusionService(router, cfg)
        fusion.start()
        stack.callback(fusion.stop)

        def client() -> zenoh.Session:
            return stack.enter_context(
                zenoh.open(session_config(mode="client", connect=[endpoint]))
            )

        node, b, c = client(), client(), client()
        for info in infos:
            node.put(keys.node_key(NET, info.src, "info"), info.to_wire())
        _wait_for(lambda: len(fusion.node_infos()) == len(infos), 10.0, "node_info")
        routed: dict[int, float] = {}
        c.declare_subscriber(
            f"{NET}/viewer/x", lambda s: routed.setdefault(int(s.payload.to_bytes()), time.time())
        )
        time.sleep(0.3)
        pubs = [
            node.declare_publisher(
                keys.node_key(NET, i.src, "det"), congestion_control=zenoh.CongestionControl.BLOCK
            )
            for i in infos
        ]
        for k in range(len(infos)):  # the first frame, taken: the seq marks to count from
            pubs[k].put(payloads[k])
        _wait_for(lambda: len(fusion.snapshot()[1]) == len(infos), 5.0, "the first frame")
        done = threading.Event()

        def flood() -> None:
            for k, payload in enumerate(payloads[len(infos) :], start=len(infos)):
                pubs[k % len(infos)].put(payload)
                if k % 20 == 19:
                    time.sleep(0.005)
            done.set()

        flooder = threading.Thread(target=flood, daemon=True)
        flooder.start()
        time.sleep(0.2)
        sent = {}
        for k in range(20):  # while the flood fills the worker's channels
            sent[k] = time.time()
            b.put(f"{NET}/viewer/x", str(k).encode())
            time.sleep(0.02)
        _wait_for(lambda: len(routed) == 20, 3.0, "the unrelated samples routed")
        # at once, not at the worker's next wake-up (up to 1 s with a blocking channel)
        delays = [routed[k] - sent[k] for k in sent]
        assert max(delays) < 0.5, delays
        assert done.wait(10.0), "the flooding node was blocked"
        time.sleep(2.2)  # the worker's next wake-ups
        health = fusion.snapshot()[1]
    taken = sum(h.detections for h in health.values())
    missing = sum(h.missing for h in health.values())
    assert missing > 0, health  # the oldest were dropped, and counted
    assert taken + missing <= len(payloads), (taken, missing)
    assert fusion.handler_errors == 0
