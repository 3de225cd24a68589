"""FusionCore drops position estimates beyond a sensor's max_range when asked (pure)."""

from __future__ import annotations

import msgpack
import numpy as np
import pytest

from fusion_center.core import FusionCore, FusionCoreConfig
from fusion_center.tracking.base import TrackerOutput
from protocol import Detections, NodeInfo
from sim_nodes.network import SimNetwork


class ScanLog:
    """A tracker stand-in that keeps the scans it is given."""

    def __init__(self) -> None:
        self.scans: list = []

    def step(self, t, scans):  # type: ignore[no-untyped-def]
        self.scans.extend(scans)
        return TrackerOutput(t=t, tracks=(), n_estimate=0.0)

    def reset(self) -> None:
        pass


@pytest.mark.parametrize("range_gate", [False, True])
def test_estimates_beyond_max_range_are_dropped(range_gate: bool) -> None:
    rec = ScanLog()
    core = FusionCore(rec, FusionCoreConfig(range_gate=range_gate, max_range=10.0))  # type: ignore[arg-type]
    for nid, info in SimNetwork("foyer3", seed=1).node_infos().items():
        wire = {"v": 1, "kind": "node_info", "src": nid, "seq": 0, "t": 0.0, **info}
        core.add_node(NodeInfo.from_wire(msgpack.packb(wire)))
    core.expected = frozenset({"bat1"})
    x, y = core.nodes["bat1"].pose[:2]
    # 3 m and 40 m east of the sensor (an echo by a wall, placed far outside the hall)
    positions = np.array([[x + 3.0, y], [x + 40.0, y]])
    cov = np.broadcast_to(np.eye(2) * 0.01, (2, 2, 2))
    no = {"rx1": (), "rx2": ()}
    core.add_detections(
        Detections(
            src="bat1", seq=0, t=0.0, tx="bat1/tx", frame=0, ranges=no, amplitudes=no,
            positions=positions, cov=cov,
        )
    )  # fmt: skip
    (scan,) = rec.scans
    assert scan.max_range == 10.0
    want = positions[:1] if range_gate else positions
    np.testing.assert_allclose(scan.positions, want, atol=0.5)
    assert scan.cov.shape == (want.shape[0], 2, 2)
    assert core.counters.beyond_range == (1 if range_gate else 0)
