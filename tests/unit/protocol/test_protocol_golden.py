"""Golden payloads (tests/data/golden, written by hand with msgpack by make_golden.py):
decode each with ``protocol.decode``, check every field, re-encode to identical bytes."""

from __future__ import annotations

import dataclasses
import importlib.util
import math
from pathlib import Path
from typing import Any

import msgpack
import numpy as np
import pytest

import protocol
from protocol import (
    Detections,
    Image,
    Ir,
    NodeInfo,
    Poses,
    Status,
    TdmaSchedule,
    Tracks,
    Truth,
)

DATA = Path(__file__).resolve().parents[2] / "data"
GOLDEN = DATA / "golden"
HEADER = ["v", "kind", "src", "seq", "t"]

#: Field order of each kind as PROTOCOL.md lists it (required, then optional).
CONTRACT_ORDER = {
    "node_info": ["role", "pose", "mobile", "antennas", "radar"],
    "ir": ["tx", "rx", "slot", "frame", "h", "pose"],
    # ``links``: optional, added for node-to-node ranging (docs/localization.md)
    "detections": ["tx", "frame", "ranges", "amplitudes", "positions", "cov", "links"],
    "status": ["uptime", "acquired", "published", "dropped", "late_slots", "decode_errors", "cpu"],
    "tdma_schedule": ["frame_period", "epoch", "slots"],
    "tracks": ["tracks", "n_estimate"],
    "poses": ["poses"],
    "image": ["x0", "y0", "dx", "dy", "method", "img"],
    "truth": ["targets", "nodes"],
}
NESTED_ORDER = {
    protocol.Antenna: ["pos", "tx", "rx", "boresight", "beamwidth"],
    protocol.RadarInfo: ["fs", "n", "t0", "f_low", "f_high", "rate", "fc"],
    protocol.Slot: ["slot", "tx", "start", "duration"],
    protocol.Track: ["id", "x", "y", "vx", "vy", "cov", "w"],
    protocol.PoseEstimate: ["pose", "cov", "los"],
    protocol.Target: ["id", "x", "y", "vx", "vy"],
    protocol.LinkRange: ["range", "std", "los", "snr_db"],
}


def _load_maker() -> Any:
    spec = importlib.util.spec_from_file_location("uwbnet_make_golden", DATA / "make_golden.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


MAKER = _load_maker()
NAMES = sorted(MAKER.payloads())


def golden(name: str) -> bytes:
    return (GOLDEN / f"{name}.msgpack").read_bytes()


def wire_fields(cls: type) -> list[str]:
    return [f.name for f in dataclasses.fields(cls) if "wire" in f.metadata]


def assert_matches_raw(value: Any, raw: Any, where: str) -> None:
    """``value`` (decoded by protocol) holds exactly what the raw msgpack ``raw`` says."""
    if dataclasses.is_dataclass(value):
        assert isinstance(raw, dict), where
        names = wire_fields(type(value))
        assert set(raw) <= set(names) | {"v", "kind"}, f"{where}: unexpected keys"
        for name in names:
            if name in raw:
                assert_matches_raw(getattr(value, name), raw[name], f"{where}.{name}")
            else:
                assert getattr(value, name) is None, f"{where}.{name} should be absent"
        assert dict(value.extra) == {}, f"{where}: no extras in golden files"
    elif isinstance(value, np.ndarray):
        assert set(raw) == {"dtype", "shape", "data"}, where
        assert value.dtype == np.dtype(raw["dtype"]), where
        assert list(value.shape) == raw["shape"], where
        assert value.tobytes() == raw["data"], where
    elif isinstance(raw, dict):
        assert set(value) == set(raw), where
        for k in raw:
            assert_matches_raw(value[k], raw[k], f"{where}.{k}")
    elif isinstance(raw, list):
        assert isinstance(value, tuple), f"{where}: lists decode to tuples"
        assert len(value) == len(raw), where
        for i, (a, b) in enumerate(zip(value, raw, strict=True)):
            assert_matches_raw(a, b, f"{where}[{i}]")
    else:
        assert type(value) is type(raw), f"{where}: {type(value)} vs {type(raw)}"
        assert value == raw, where


def test_golden_files_are_what_the_script_writes() -> None:
    for name, payload in MAKER.payloads().items():
        assert golden(name) == payload, f"{name}.msgpack is stale: run tests/data/make_golden.py"
    kinds = {msgpack.unpackb(golden(n))["kind"] for n in NAMES}
    assert kinds == set(protocol.KINDS), "one golden file per message kind"


@pytest.mark.parametrize("name", NAMES)
def test_golden_key_order_is_the_contract_order(name: str) -> None:
    raw = msgpack.unpackb(golden(name))
    keys = list(raw)
    assert keys[:5] == HEADER
    order = CONTRACT_ORDER[raw["kind"]]
    assert keys[5:] == [k for k in order if k in raw]


@pytest.mark.parametrize("kind", sorted(CONTRACT_ORDER))
def test_dataclass_field_order_is_the_contract_order(kind: str) -> None:
    cls = protocol.KINDS[kind]
    assert wire_fields(cls) == ["src", "seq", "t", *CONTRACT_ORDER[kind]]


@pytest.mark.parametrize("cls", list(NESTED_ORDER), ids=lambda c: c.__name__)
def test_nested_field_order_is_the_contract_order(cls: type) -> None:
    assert wire_fields(cls) == NESTED_ORDER[cls]


@pytest.mark.parametrize("name", NAMES)
def test_golden_decodes_to_every_field_and_reencodes_identically(name: str) -> None:
    payload = golden(name)
    raw = msgpack.unpackb(payload)
    msg = protocol.decode(payload)
    assert type(msg) is protocol.KINDS[raw["kind"]]
    assert msg.KIND == raw["kind"]
    assert msg.v == 1
    assert_matches_raw(msg, raw, name)
    assert msg.to_wire() == payload
    assert type(msg).from_wire(payload).to_wire() == payload


def test_golden_node_info_values() -> None:
    msg = protocol.decode(golden("node_info"))
    assert isinstance(msg, NodeInfo)
    assert (msg.src, msg.seq, msg.t) == ("anchor1", 0, 100.0)
    assert msg.role == "anchor" and msg.mobile is False
    assert msg.pose == (1.5, -2.25, 1.1, math.pi / 4)
    assert list(msg.antennas) == ["tx0", "rx0", "rx1"]
    tx0 = msg.antennas["tx0"]
    assert tx0.pos == (0.0, 0.1, 0.0) and tx0.tx is True and tx0.rx is False
    assert tx0.boresight == 0.0 and tx0.beamwidth == math.pi / 2
    assert msg.antennas["rx1"].boresight == 0.5
    r = msg.radar
    assert (r.fs, r.n, r.t0, r.f_low, r.f_high, r.rate) == (
        13.312e9,
        16,
        -1.5e-9,
        3.5e9,
        10e9,
        100.0,
    )
    assert r.fc is None

    dw = protocol.decode(golden("node_info_dw1000"))
    assert isinstance(dw, NodeInfo)
    assert dw.role == "bat" and dw.mobile is True
    assert dw.radar.fc == 6.4896e9
    assert dw.antennas["a"].beamwidth == 2 * math.pi


def test_golden_ir_values() -> None:
    msg = protocol.decode(golden("ir"))
    assert isinstance(msg, Ir)
    assert (msg.src, msg.seq, msg.t) == ("anchor1", 42, 100.5)
    assert (msg.tx, msg.rx, msg.slot, msg.frame) == ("anchor1/tx0", ("rx0", "rx1"), 2, 1234)
    assert msg.h.dtype == np.dtype("<f4") and msg.h.shape == (2, 16)
    k = np.arange(16)
    np.testing.assert_array_equal(msg.h[0], 0.25 * k - 2.0)
    np.testing.assert_array_equal(msg.h[1], np.where(k % 2, -0.5, 0.5) * k)
    assert msg.pose is None

    c8 = protocol.decode(golden("ir_c8"))
    assert isinstance(c8, Ir)
    assert c8.h.dtype == np.dtype("<c8") and c8.h.shape == (2, 16)
    np.testing.assert_array_equal(c8.h[0], 0.5 * k - 0.25j * k)
    np.testing.assert_array_equal(c8.h[1], (1.0 - 0.125 * k) + 0.0625j * k)
    assert c8.pose == (2.0, 3.0, 0.3, 1.25)


def test_golden_detections_values() -> None:
    msg = protocol.decode(golden("detections"))
    assert isinstance(msg, Detections)
    assert (msg.tx, msg.frame) == ("anchor1/tx0", 1234)
    assert msg.ranges == {"rx0": (3.25, 7.5), "rx1": (4.125,)}
    assert msg.amplitudes == {"rx0": (0.75, 0.125), "rx1": (0.5,)}
    assert msg.positions is not None and msg.cov is not None
    assert msg.positions.dtype == np.dtype("<f8") and msg.cov.dtype == np.dtype("<f8")
    np.testing.assert_array_equal(msg.positions, [[1.0, 2.0], [-3.5, 4.25]])
    np.testing.assert_array_equal(
        msg.cov, [[[0.01, 0.002], [0.002, 0.04]], [[0.09, 0.0], [0.0, 0.16]]]
    )


def test_golden_status_values() -> None:
    msg = protocol.decode(golden("status"))
    assert isinstance(msg, Status)
    assert (msg.src, msg.seq, msg.t) == ("anchor1", 9, 110.0)
    assert msg.uptime == 3600.5 and msg.cpu == 0.375
    counters = (msg.acquired, msg.published, msg.dropped, msg.late_slots, msg.decode_errors)
    assert counters == (360050, 360000, 50, 3, 1)


def test_golden_tdma_schedule_values() -> None:
    msg = protocol.decode(golden("tdma_schedule"))
    assert isinstance(msg, TdmaSchedule)
    assert (msg.frame_period, msg.epoch) == (0.02, 98.0)
    assert [(s.slot, s.tx, s.start, s.duration) for s in msg.slots] == [
        (0, "anchor1/tx0", 0.0, 0.005),
        (1, "bat2/a", 0.005, 0.005),
    ]


def test_golden_tracks_values() -> None:
    msg = protocol.decode(golden("tracks"))
    assert isinstance(msg, Tracks)
    assert msg.n_estimate == 1.05
    (track,) = msg.tracks
    assert (track.id, track.x, track.y, track.vx, track.vy, track.w) == (
        17,
        4.5,
        3.25,
        0.5,
        -0.25,
        0.95,
    )
    assert track.cov[0] == (0.04, 0.01, 0.0, 0.0)
    assert track.cov[3] == (0.0, 0.0, 0.01, 0.09)


def test_golden_poses_values() -> None:
    msg = protocol.decode(golden("poses"))
    assert isinstance(msg, Poses)
    est = msg.poses["bat2"]
    assert est.pose == (2.0, 3.0, 0.3, 1.25)
    assert est.cov == ((0.01, 0.0, 0.0), (0.0, 0.01, 0.0), (0.0, 0.0, 0.0025))
    assert est.los == {"anchor1": True, "anchor3": False}


def test_golden_image_values() -> None:
    msg = protocol.decode(golden("image"))
    assert isinstance(msg, Image)
    assert (msg.x0, msg.y0, msg.dx, msg.dy, msg.method) == (-1.0, 0.5, 0.25, 0.5, "kirchhoff")
    assert msg.img.dtype == np.dtype("<f4")
    np.testing.assert_array_equal(msg.img, [[0.0, 0.5, 1.0], [0.25, 0.75, 0.125]])


def test_golden_truth_values() -> None:
    msg = protocol.decode(golden("truth"))
    assert isinstance(msg, Truth)
    assert [(g.id, g.x, g.y, g.vx, g.vy) for g in msg.targets] == [
        (1, 4.5, 3.25, 0.5, -0.25),
        (2, -1.0, 6.0, 0.0, 1.0),
    ]
    assert msg.nodes == {"bat2": (2.0, 3.0, 0.3, 1.25)}


def test_from_wire_rejects_another_kind() -> None:
    with pytest.raises(protocol.DecodeError, match="expected kind 'ir', got 'status'"):
        Ir.from_wire(golden("status"))


def test_detections_links_round_trip_and_reject_a_bad_anchor_id() -> None:
    link = protocol.LinkRange(range=3.5, std=0.01, los=False, snr_db=12.0)
    det = Detections(
        src="tag", seq=1, t=2.0, tx="tag/ant", frame=7, ranges={}, amplitudes={},
        links={"rx1": link},
    )  # fmt: skip
    back = protocol.decode(det.to_wire())
    assert isinstance(back, Detections) and back.links == {"rx1": link}
    raw = msgpack.unpackb(det.to_wire())
    raw["links"] = {"bad id!": raw["links"]["rx1"]}
    with pytest.raises(protocol.ProtocolError):
        protocol.decode(msgpack.packb(raw, use_bin_type=True))
    raw["links"] = {"rx1": {"range": 1.0, "std": 0.1, "los": "yes", "snr_db": 3.0}}
    with pytest.raises(protocol.ProtocolError):
        protocol.decode(msgpack.packb(raw, use_bin_type=True))
