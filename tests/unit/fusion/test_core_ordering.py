"""FusionCore against duplicated, reordered, late and restarted-node detections (pure)."""

from __future__ import annotations

import numpy as np
import pytest

from fusion_center.core import FusionCore
from fusion_center.offline import make_tracker
from protocol import Detections, NodeInfo
from sim_nodes.network import SimNetwork

pytestmark = pytest.mark.faults


@pytest.fixture
def core() -> FusionCore:
    net = SimNetwork("foyer3", seed=1)
    c = FusionCore(make_tracker("gmphd"))
    for nid, info in net.node_infos().items():
        c.add_node(NodeInfo.from_wire(_info_wire(nid, info)))
    c.expected = frozenset({"bat1", "bat2"})
    return c


def _info_wire(nid, info):  # type: ignore[no-untyped-def]
    import msgpack

    return msgpack.packb({"v": 1, "kind": "node_info", "src": nid, "seq": 0, "t": 0.0, **info})


def _det(src: str, seq: int, frame: int, t: float) -> Detections:
    return Detections(
        src=src,
        seq=seq,
        t=t,
        tx=f"{src}/tx",
        frame=frame,
        ranges={"rx1": (), "rx2": ()},
        amplitudes={"rx1": (), "rx2": ()},
        positions=np.zeros((0, 2)),
        cov=np.zeros((0, 2, 2)),
    )


def test_duplicates_and_reordered_messages_are_counted_and_dropped(core):
    assert core.add_detections(_det("bat1", 0, 0, 0.00)) == []
    assert core.add_detections(_det("bat1", 0, 0, 0.00)) == []  # duplicate
    assert core.counters.duplicates == 1
    out = core.add_detections(_det("bat2", 0, 0, 0.01))  # frame 0 complete
    assert len(out) == 1 and core.counters.updates == 1
    core.add_detections(_det("bat1", 2, 2, 0.04))
    core.add_detections(_det("bat1", 1, 1, 0.02))  # arrives after seq 2: reordered, dropped
    assert core.counters.duplicates == 2
    # a late message for a frame already processed
    core.add_detections(_det("bat2", 5, 0, 0.05))
    assert core.counters.late == 1


def test_a_restarted_node_is_accepted_although_its_seq_starts_again(core):
    for i in range(5):
        core.add_detections(_det("bat1", 100 + i, i, 0.02 * i))
        core.add_detections(_det("bat2", i, i, 0.02 * i + 0.01))
    updates = core.counters.updates
    core.add_detections(_det("bat1", 0, 6, 0.12))  # seq 0 again, later time
    core.add_detections(_det("bat2", 6, 6, 0.13))
    assert core.counters.duplicates == 0
    assert core.counters.updates == updates + 1  # frame 6, with both nodes
    assert core.counters.detections == 12
