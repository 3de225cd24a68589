"""Faults over real zenoh sessions on loopback: a node lost and re-admitted without restarting
the fusion center, node agents re-attaching to a restarted router, and a stuck consumer that
must not slow acquisition."""

from __future__ import annotations

import contextlib
import threading
import time

import pytest
import zenoh

from fusion_center.service import FusionConfig, FusionService
from node_agent.agent import AgentConfig, NodeAgent
from protocol import keys
from protocol.transport import session_config
from sim_nodes.driver import SimulatedDriver
from sim_nodes.network import SimNetwork
from sim_nodes.scene import load_scenario
from tests.waiting import wait_for

pytestmark = [pytest.mark.integration, pytest.mark.faults]

NET = "ftest"


def _wait_for(predicate, timeout: float, what: str) -> float:  # type: ignore[no-untyped-def]
    """Wait until ``predicate()``; returns the seconds it took."""
    return wait_for(predicate, timeout, what, poll=0.005)


@pytest.fixture(scope="module")
def network() -> SimNetwork:
    return SimNetwork(load_scenario("foyer3"), seed=11)


class _Node:
    """A node agent with its own session, started and stopped as a process would be."""

    def __init__(self, network, node, hub, start, *, mode="peer", publish_ir=False):  # type: ignore[no-untyped-def]
        self.session = zenoh.open(session_config(mode=mode, connect=[hub], lease_ms=1000))
        self.driver = SimulatedDriver(network, node, start=start)
        self.agent = NodeAgent(
            self.session, self.driver, AgentConfig(node=node, net=NET, publish_ir=publish_ir)
        )
        self.agent.start()

    def kill(self) -> None:
        self.agent.stop()
        self.driver.close()
        self.session.close()


def test_lost_node_noticed_within_1s_tracking_continues_and_it_is_readmitted(hub_endpoint, network):
    nodes = ["bat1", "bat2", "bat3"]
    start = time.time() + 0.3
    with contextlib.ExitStack() as stack:
        fs = stack.enter_context(zenoh.open(session_config(listen=[hub_endpoint])))
        fusion = FusionService(fs, FusionConfig(net=NET), epoch=start)
        fusion.start()
        stack.callback(fusion.stop)
        running = {n: _Node(network, n, hub_endpoint, start) for n in nodes}
        stack.callback(lambda: [n.kill() for n in running.values()])
        _wait_for(lambda: fusion.core.expected == frozenset(nodes), 10.0, "all nodes scheduled")
        _wait_for(lambda: fusion.core.counters.updates >= 50, 15.0, "fusion updates")

        running.pop("bat1").kill()
        noticed = _wait_for(lambda: not fusion.snapshot()[1]["bat1"].alive, 1.0, "loss of bat1")
        _wait_for(lambda: fusion.core.expected == frozenset(nodes[1:]), 1.0, "slot freed")
        before = fusion.core.counters.updates
        _wait_for(lambda: fusion.core.counters.updates > before + 25, 5.0, "tracking without it")

        dets = fusion.snapshot()[1]["bat1"].detections
        t0 = time.monotonic()
        running["bat1"] = _Node(network, "bat1", hub_endpoint, start)
        _wait_for(lambda: fusion.core.expected == frozenset(nodes), 5.0, "bat1 rescheduled")
        _wait_for(lambda: fusion.snapshot()[1]["bat1"].detections > dets + 10, 5.0, "its data")
        readmitted = time.monotonic() - t0
        assert fusion.core.counters.duplicates == 0  # its seq restarted at 0: not a duplicate
        print(f"\nnotice lost node: {noticed * 1e3:.0f} ms; re-admit: {readmitted * 1e3:.0f} ms")


def test_node_agents_reattach_to_a_restarted_router(hub_endpoint, network):
    start = time.time() + 0.3
    node = None
    try:
        for generation in range(2):
            # The fusion center is the router; the second one replaces the first on its port.
            with zenoh.open(
                session_config(mode="router", listen=[hub_endpoint], lease_ms=1000)
            ) as rs:
                fusion = FusionService(rs, FusionConfig(net=NET), epoch=start)
                fusion.start()
                if node is None:
                    node = _Node(network, "bat2", hub_endpoint, start, mode="client")
                try:
                    took = _wait_for(
                        lambda f=fusion: (
                            (h := f.snapshot()[1].get("bat2")) is not None and h.detections > 20
                        ),
                        15.0,
                        f"detections at router generation {generation}",
                    )
                finally:
                    fusion.stop()
            if generation == 1:
                print(f"\nnode re-attached and delivering after {took:.2f} s")
    finally:
        if node is not None:
            node.kill()


def test_a_stuck_consumer_never_slows_acquisition(hub_endpoint, network):
    start = time.time() + 0.3
    release = threading.Event()
    with contextlib.ExitStack() as stack:
        fs = stack.enter_context(zenoh.open(session_config(listen=[hub_endpoint])))
        fusion = FusionService(fs, FusionConfig(net=NET), epoch=start)
        fusion.start()
        stack.callback(fusion.stop)
        node = _Node(network, "bat3", hub_endpoint, start, publish_ir=True)
        stack.callback(node.kill)
        _wait_for(lambda: node.agent.counters["acquired"] > 20, 10.0, "acquisitions")
        # A consumer whose callback hangs (against zenoh's rules, as a buggy viewer might):
        # its session stops reading, so the link to it backs up.
        stuck = stack.enter_context(zenoh.open(session_config(connect=[hub_endpoint])))
        sub = stuck.declare_subscriber(keys.all_key(NET), lambda s: release.wait(10.0))
        stack.callback(sub.undeclare)
        stack.callback(release.set)  # runs first: the callback returns before undeclare
        threading.Event().wait(0.5)
        a0, t0 = node.agent.counters["acquired"], time.monotonic()
        threading.Event().wait(4.0)
        rate = (node.agent.counters["acquired"] - a0) / (time.monotonic() - t0)
        release.set()
        # What the stuck link held up is reported, not hidden.
        status = fusion.snapshot()[1]["bat3"].last_status
        assert status is not None and "queue_dropped" in status.extra
        # One transmitter, 50 frames per second.
        assert rate > 40.0, f"acquisition slowed to {rate:.1f} Hz by a stuck consumer"
        print(f"\nacquisition with a stuck consumer: {rate:.1f} Hz")
