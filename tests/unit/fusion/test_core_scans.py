"""FusionCore gives each scan its sensor's blind zone from node_info when asked, and drops
position estimates beyond the sensor's range when its range gate is on (pure)."""

from __future__ import annotations

import dataclasses

import msgpack
import numpy as np
import pytest

from fusion_center.core import FusionCore, FusionCoreConfig
from fusion_center.tracking.base import TrackerOutput
from node_agent.core import radar_params
from protocol import Detections, NodeInfo
from sim_nodes.network import SimNetwork


def _empty(src: str, t: float) -> Detections:
    no = {"rx1": (), "rx2": ()}
    return Detections(src=src, seq=0, t=t, tx=f"{src}/tx", frame=0, ranges=no, amplitudes=no)


class ScanRecorder:
    def __init__(self) -> None:
        self.scans: list = []

    def step(self, t, scans):  # type: ignore[no-untyped-def]
        self.scans.extend(scans)
        return TrackerOutput(t=t, tracks=(), n_estimate=0.0)

    def reset(self) -> None:
        pass


@pytest.mark.parametrize("blind_zone", [False, True])
def test_scans_carry_the_blind_zone(blind_zone: bool) -> None:
    rec = ScanRecorder()
    core = FusionCore(rec, FusionCoreConfig(blind_zone=blind_zone, window_guard=1.0))  # type: ignore[arg-type]
    infos = {}
    for nid, info in SimNetwork("foyer3", seed=1).node_infos().items():
        wire = {"v": 1, "kind": "node_info", "src": nid, "seq": 0, "t": 0.0, **info}
        msg = NodeInfo.from_wire(msgpack.packb(wire))
        # a cropped window: 20 ns after the emission (6 m of bistatic path)
        infos[nid] = msg = dataclasses.replace(msg, radar=dataclasses.replace(msg.radar, t0=20e-9))
        core.add_node(msg)
    core.expected = frozenset({"bat1", "bat2"})
    core.add_detections(_empty("bat1", 0.00))
    core.add_detections(_empty("bat2", 0.01))
    assert len(rec.scans) == 2
    for scan in rec.scans:
        radar = radar_params(infos[scan.sensor])
        want = (radar.measurable(1.0)[0] / 2.0) if blind_zone else 0.0
        assert scan.min_range == pytest.approx(want)
        if blind_zone:
            assert scan.min_range > 3.0  # half of 6 m plus half a pulse width


@pytest.mark.parametrize("range_gate", [False, True])
def test_estimates_beyond_max_range_are_dropped(range_gate: bool) -> None:
    rec = ScanRecorder()
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
