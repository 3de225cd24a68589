"""The runtime over real zenoh sessions on loopback: simulated node agents and the fusion center.

Every node and the fusion center have their own session (peer mode, scouting off, one listening
hub on a free port), as separate hosts would.
"""

from __future__ import annotations

import contextlib
import itertools
import time

import msgpack
import pytest
import zenoh

from fusion_center.service import FusionConfig, FusionService
from node_agent.agent import AgentConfig, NodeAgent
from protocol import NodeInfo, Status, TdmaSchedule, Tracks, keys
from protocol.transport import FifoChannel, session_config
from sim_nodes.driver import SimulatedDriver
from sim_nodes.network import SimNetwork
from sim_nodes.scene import load_scenario
from tests.waiting import wait_for as _wait_for

pytestmark = pytest.mark.integration

NET = "itest"


@pytest.fixture
def network() -> SimNetwork:
    return SimNetwork(load_scenario("foyer3"), seed=7)


@contextlib.contextmanager
def running_network(hub: str, network: SimNetwork, nodes: list[str]):  # type: ignore[no-untyped-def]
    """Fusion center and node agents for ``nodes``; yields (fusion, agents, observer session)."""
    start = time.time() + 0.3
    with contextlib.ExitStack() as stack:
        fs = stack.enter_context(zenoh.open(session_config(listen=[hub])))
        fusion = FusionService(fs, FusionConfig(net=NET), epoch=start)
        fusion.start()
        stack.callback(fusion.stop)
        observer = stack.enter_context(zenoh.open(session_config(connect=[hub])))
        agents = {}
        for node in nodes:
            s = stack.enter_context(zenoh.open(session_config(connect=[hub])))
            drv = stack.enter_context(SimulatedDriver(network, node, start=start))
            agent = NodeAgent(s, drv, AgentConfig(node=node, net=NET))
            agent.start()
            stack.callback(agent.stop)
            agents[node] = (agent, s)
        yield fusion, agents, observer


def test_nodes_and_fusion_exchange_schedule_detections_tracks_status(hub_endpoint, network):
    nodes = sorted(network.node_infos())[:3]
    got: FifoChannel[tuple[str, bytes]] = FifoChannel(100000)
    with running_network(hub_endpoint, network, nodes) as (fusion, agents, observer):
        sub = observer.declare_subscriber(
            keys.all_key(NET), lambda s: got.put((str(s.key_expr), s.payload.to_bytes()))
        )
        try:
            _wait_for(lambda: fusion.core.counters.updates >= 50, 15.0, "50 fusion updates")
            _wait_for(
                lambda: all(h.last_status is not None for h in fusion.snapshot()[1].values()),
                5.0,
                "status of every node",
            )
            # A node whose slot came through the 1 Hz schedule retry starts a little later.
            _wait_for(
                lambda: all(a.counters["acquired"] > 10 for a, _ in agents.values()),
                5.0,
                "10 acquisitions at every node",
            )
            # node_info served by each node's queryable, on its own concrete key.
            replies = list(observer.get(keys.all_nodes_key(NET, "info"), timeout=2.0))
            infos = [NodeInfo.from_wire(r.ok.payload.to_bytes()) for r in replies if r.ok]
            assert sorted(i.src for i in infos) == nodes
            assert {str(r.ok.key_expr) for r in replies if r.ok} == {
                keys.node_key(NET, n, "info") for n in nodes
            }
            # the schedule queryable answers late joiners
            sched_replies = list(observer.get(keys.schedule_key(NET), timeout=2.0))
            sched = TdmaSchedule.from_wire(sched_replies[0].ok.payload.to_bytes())
            assert sorted(s.tx for s in sched.slots) == sorted(f"{n}/tx" for n in nodes)
        finally:
            sub.undeclare()
    kinds: dict[str, int] = {}
    for key, _payload in got.drain():
        kind = keys.parse_key(key).kind or "alive"
        kinds[kind] = kinds.get(kind, 0) + 1
    assert kinds.get("ir", 0) >= 50
    assert kinds.get("detections", 0) >= 50
    assert kinds.get("tracks", 0) >= 10
    assert kinds.get("status", 0) >= len(nodes)
    for agent, _ in agents.values():
        assert agent.counters["acquired"] > 10
        assert agent.counters["dsp_errors"] == 0


@pytest.mark.faults
def test_fusion_notices_a_lost_node_within_one_second_and_keeps_tracking(hub_endpoint, network):
    nodes = sorted(network.node_infos())[:3]
    with running_network(hub_endpoint, network, nodes) as (fusion, agents, _observer):
        _wait_for(lambda: fusion.core.counters.updates >= 20, 15.0, "fusion updates")
        victim = nodes[0]
        agent, session = agents[victim]
        agent.stop()
        lost_at = time.monotonic()
        session.close()  # the process is gone: its liveliness token vanishes
        _wait_for(lambda: not fusion.snapshot()[1][victim].alive, 1.0, "loss of the node")
        assert time.monotonic() - lost_at < 1.0
        _wait_for(lambda: fusion.core.expected == frozenset(nodes[1:]), 2.0, "schedule without it")
        before = fusion.core.counters.updates
        _wait_for(lambda: fusion.core.counters.updates > before + 20, 5.0, "more updates")


def test_malformed_messages_are_counted_not_fatal(hub_endpoint, network):
    nodes = sorted(network.node_infos())[:1]
    with running_network(hub_endpoint, network, nodes) as (fusion, _agents, observer):
        _wait_for(lambda: fusion.core.counters.updates >= 5, 15.0, "fusion updates")
        bad_key = keys.node_key(NET, "intruder", "det")
        observer.put(bad_key, b"\xc1 not msgpack")
        observer.put(bad_key, msgpack.packb({"v": 1, "kind": "detections", "src": "x"}))
        observer.put(bad_key, msgpack.packb({"v": 9, "kind": "detections"}))
        _wait_for(lambda: fusion.decode_errors >= 3, 5.0, "three rejections")
        before = fusion.core.counters.updates
        _wait_for(lambda: fusion.core.counters.updates > before + 10, 5.0, "fusion still running")


def test_tracks_and_status_messages_decode(hub_endpoint, network):
    nodes = sorted(network.node_infos())
    tracks: FifoChannel[bytes] = FifoChannel(10000)
    status: FifoChannel[bytes] = FifoChannel(10000)
    with running_network(hub_endpoint, network, nodes) as (_fusion, _agents, observer):
        s1 = observer.declare_subscriber(
            keys.fusion_key(NET, "tracks"), lambda s: tracks.put(s.payload.to_bytes())
        )
        s2 = observer.declare_subscriber(
            keys.all_nodes_key(NET, "status"), lambda s: status.put(s.payload.to_bytes())
        )
        try:
            _wait_for(lambda: len(status) >= len(nodes), 5.0, "status messages")
            _wait_for(lambda: len(tracks) >= 100, 15.0, "tracks messages")
        finally:
            s1.undeclare()
            s2.undeclare()
    msgs = [Tracks.from_wire(b) for b in tracks.drain()]
    seqs = [m.seq for m in msgs]
    assert seqs == sorted(seqs)
    assert all(m.t >= prev.t for prev, m in itertools.pairwise(msgs))
    st = [Status.from_wire(b) for b in status.drain()]
    assert {s.src for s in st} == set(nodes)
    assert all(s.acquired >= 0 and 0.0 <= s.cpu < 2.0 for s in st)
