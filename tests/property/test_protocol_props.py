"""Property tests of the wire contract: random valid messages of every kind round trip exactly;
random bytes and mutations of valid payloads raise only ProtocolError."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

import msgpack
import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

import protocol
from protocol import (
    Antenna,
    Detections,
    Image,
    Ir,
    Map,
    NodeInfo,
    PoseEstimate,
    Poses,
    ProtocolError,
    RadarInfo,
    Slot,
    Status,
    Target,
    TdmaSchedule,
    Track,
    Tracks,
    Truth,
)

GOLDEN = Path(__file__).resolve().parents[1] / "data" / "golden"
GOLDEN_PAYLOADS = {p.stem: p.read_bytes() for p in sorted(GOLDEN.glob("*.msgpack"))}

# Seeded (derandomize) and modest: the machine is shared.
SETTINGS = settings(
    max_examples=200,
    deadline=None,
    derandomize=True,
    database=None,
    suppress_health_check=[HealthCheck.too_slow],
)

ids = st.from_regex(r"[A-Za-z0-9_-]{1,8}", fullmatch=True)
names = st.text(max_size=8)
finite = st.floats(allow_nan=False, allow_infinity=False)
uint = st.integers(0, 2**64 - 1)
sint = st.integers(-(2**63), 2**63 - 1)
vec3 = st.tuples(finite, finite, finite)
vec4 = st.tuples(finite, finite, finite, finite)


def matrix(n: int) -> st.SearchStrategy[tuple[tuple[float, ...], ...]]:
    return st.tuples(*[st.tuples(*[finite] * n)] * n)


def header() -> dict[str, st.SearchStrategy[Any]]:
    return {"src": ids, "seq": uint, "t": finite}


def finite_array(dtype: str, shape: Any) -> st.SearchStrategy[np.ndarray]:
    return hnp.arrays(
        np.dtype(dtype), shape, elements={"allow_nan": False, "allow_infinity": False}
    )


antennas = st.builds(
    Antenna, pos=vec3, tx=st.booleans(), rx=st.booleans(), boresight=finite, beamwidth=finite
)
radars = st.builds(
    RadarInfo,
    fs=finite,
    n=st.integers(1, 2**32),
    t0=finite,
    f_low=finite,
    f_high=finite,
    rate=finite,
    fc=st.none() | finite,
)
node_infos = st.builds(
    NodeInfo,
    **header(),
    role=st.sampled_from(["anchor", "bat", "robot", "illuminator", "observer"]),
    pose=vec4,
    mobile=st.booleans(),
    antennas=st.dictionaries(names, antennas, max_size=3),
    radar=radars,
)


@st.composite
def irs(draw: st.DrawFn) -> Ir:
    rx = draw(st.lists(names, max_size=3))
    n = draw(st.integers(0, 24))
    h = draw(finite_array(draw(st.sampled_from(["<f4", "<c8"])), (len(rx), n)))
    return Ir(
        **draw(st.fixed_dictionaries(header())),
        tx=draw(names),
        rx=tuple(rx),
        slot=draw(sint),
        frame=draw(sint),
        h=h,
        pose=draw(st.none() | vec4),
    )


@st.composite
def detections(draw: st.DrawFn) -> Detections:
    ranges = draw(st.dictionaries(names, st.lists(finite, max_size=4).map(tuple), max_size=3))
    amplitudes = {
        rx: tuple(draw(st.lists(finite, min_size=len(r), max_size=len(r))))
        for rx, r in ranges.items()
    }
    positions = cov = None
    if draw(st.booleans()):
        k = draw(st.integers(0, 4))
        positions = draw(finite_array("<f8", (k, 2)))
        cov = draw(st.none() | finite_array("<f8", (k, 2, 2)))
    return Detections(
        **draw(st.fixed_dictionaries(header())),
        tx=draw(names),
        frame=draw(sint),
        ranges=ranges,
        amplitudes=amplitudes,
        positions=positions,
        cov=cov,
    )


counter = st.integers(0, 2**64 - 1)
statuses = st.builds(
    Status,
    **header(),
    uptime=finite,
    acquired=counter,
    published=counter,
    dropped=counter,
    late_slots=counter,
    decode_errors=counter,
    cpu=finite,
)
slots = st.builds(Slot, slot=st.integers(0, 2**32), tx=names, start=finite, duration=finite)
schedules = st.builds(
    TdmaSchedule,
    **header(),
    frame_period=st.floats(min_value=1e-9, max_value=1e9),
    epoch=finite,
    slots=st.lists(slots, max_size=4).map(tuple),
)
tracks = st.builds(
    Tracks,
    **header(),
    tracks=st.lists(
        st.builds(
            Track, id=sint, x=finite, y=finite, vx=finite, vy=finite, cov=matrix(4), w=finite
        ),
        max_size=3,
    ).map(tuple),
    n_estimate=finite,
)
poses = st.builds(
    Poses,
    **header(),
    poses=st.dictionaries(
        ids,
        st.builds(PoseEstimate, pose=vec4, cov=matrix(3), los=st.dictionaries(ids, st.booleans())),
        max_size=3,
    ),
)
images = st.builds(
    Image,
    **header(),
    x0=finite,
    y0=finite,
    dx=finite,
    dy=finite,
    method=names,
    img=finite_array("<f4", st.tuples(st.integers(0, 6), st.integers(0, 6))),
)
maps = st.builds(
    Map,
    **header(),
    robot=ids,
    origin=vec4,
    walls=finite_array("<f8", st.tuples(st.integers(0, 4), st.just(4))),
    corners=finite_array("<f8", st.tuples(st.integers(0, 4), st.just(2))),
    points=finite_array("<f8", st.tuples(st.integers(0, 4), st.just(2))),
)
truths = st.builds(
    Truth,
    **header(),
    targets=st.lists(
        st.builds(Target, id=sint, x=finite, y=finite, vx=finite, vy=finite), max_size=3
    ).map(tuple),
    nodes=st.dictionaries(ids, vec4, max_size=3),
)

STRATEGIES = {
    "node_info": node_infos,
    "ir": irs(),
    "detections": detections(),
    "status": statuses,
    "tdma_schedule": schedules,
    "tracks": tracks,
    "poses": poses,
    "image": images,
    "map": maps,
    "truth": truths,
}
messages = st.one_of(*STRATEGIES.values())


def assert_same(a: Any, b: Any, where: str = "msg") -> None:
    """Deep equality that compares arrays by dtype, shape and values (dataclass ``==`` cannot)."""
    if dataclasses.is_dataclass(a):
        assert type(a) is type(b), where
        for f in dataclasses.fields(a):
            assert_same(getattr(a, f.name), getattr(b, f.name), f"{where}.{f.name}")
    elif isinstance(a, np.ndarray):
        assert isinstance(b, np.ndarray), where
        assert a.dtype == b.dtype and a.shape == b.shape, where
        np.testing.assert_array_equal(a, b, err_msg=where)
    elif isinstance(a, dict):
        assert isinstance(b, dict) and list(a) == list(b), where
        for k in a:
            assert_same(a[k], b[k], f"{where}.{k}")
    elif isinstance(a, tuple | list):
        assert isinstance(b, tuple) and len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            assert_same(x, y, f"{where}[{i}]")
    elif isinstance(a, float):
        assert type(b) is float and (a == b or (math.isnan(a) and math.isnan(b))), where
    else:
        assert type(a) is type(b) and a == b, where


def test_every_kind_has_a_strategy() -> None:
    assert set(STRATEGIES) == set(protocol.KINDS)


@SETTINGS
@given(msg=messages)
def test_round_trip(msg: protocol.Message) -> None:
    payload = msg.to_wire()
    raw = msgpack.unpackb(payload)
    assert list(raw)[:5] == ["v", "kind", "src", "seq", "t"]
    assert raw["v"] == 1 and raw["kind"] == msg.KIND
    back = protocol.decode(payload)
    assert_same(msg, back)
    assert back.to_wire() == payload
    assert type(msg).from_wire(payload).to_wire() == payload


def _must_be_protocol_error(payload: bytes) -> None:
    try:
        msg = protocol.decode(payload)
    except ProtocolError as exc:
        message = str(exc)
        assert message and "\n" not in message
    else:  # a mutation may still be a valid message: then it must re-encode and decode again
        assert isinstance(msg, protocol.Message)
        protocol.decode(msg.to_wire())


@SETTINGS
@given(payload=st.binary(max_size=512))
def test_random_bytes_raise_only_protocol_error(payload: bytes) -> None:
    _must_be_protocol_error(payload)


@SETTINGS
@given(name=st.sampled_from(sorted(GOLDEN_PAYLOADS)), data=st.data())
def test_truncations_raise_only_protocol_error(name: str, data: st.DataObject) -> None:
    payload = GOLDEN_PAYLOADS[name]
    cut = data.draw(st.integers(0, len(payload) - 1))
    _must_be_protocol_error(payload[:cut])


@SETTINGS
@given(
    name=st.sampled_from(sorted(GOLDEN_PAYLOADS)),
    flips=st.lists(st.tuples(st.integers(0, 10_000), st.integers(1, 255)), min_size=1, max_size=4),
)
def test_byte_flips_raise_only_protocol_error(name: str, flips: list[tuple[int, int]]) -> None:
    payload = bytearray(GOLDEN_PAYLOADS[name])
    for pos, mask in flips:
        payload[pos % len(payload)] ^= mask
    _must_be_protocol_error(bytes(payload))


msgpack_values = st.recursive(
    st.none()
    | st.booleans()
    | st.integers(-(2**63), 2**64 - 1)
    | st.floats()
    | st.text(max_size=6)
    | st.binary(max_size=16),
    lambda inner: (
        st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=6), inner, max_size=4)
    ),
    max_leaves=12,
)


def _paths(node: Any, prefix: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    out = [prefix] if prefix else []
    if isinstance(node, dict):
        for k, v in node.items():
            out += _paths(v, (*prefix, k))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            out += _paths(v, (*prefix, i))
    return out


@SETTINGS
@given(name=st.sampled_from(sorted(GOLDEN_PAYLOADS)), data=st.data())
def test_field_mutations_raise_only_protocol_error(name: str, data: st.DataObject) -> None:
    """Replace any value (header, field, nested, array dtype/shape/data) with any msgpack value."""
    m = msgpack.unpackb(GOLDEN_PAYLOADS[name])
    for _ in range(data.draw(st.integers(1, 3))):
        path = data.draw(st.sampled_from(_paths(m)))
        node = m
        for key in path[:-1]:
            node = node[key]
        if isinstance(node, dict) and data.draw(st.booleans()):
            del node[path[-1]]
        else:
            node[path[-1]] = data.draw(msgpack_values)
        if not _paths(m):
            break
    _must_be_protocol_error(msgpack.packb(m, use_bin_type=True))


@SETTINGS
@given(
    shape=st.lists(st.integers(0, 2**64 - 1), min_size=0, max_size=3),
    dtype=st.sampled_from(["<f4", "<f8", "<c8", "<i4", "<u2", "|u1", ">f4"]),
    data=st.binary(max_size=64),
)
def test_array_maps_raise_only_protocol_error(shape: list[int], dtype: str, data: bytes) -> None:
    for name, field in [("ir", "h"), ("image", "img"), ("detections", "cov")]:
        m = msgpack.unpackb(GOLDEN_PAYLOADS[name])
        m[field] = {"dtype": dtype, "shape": shape, "data": data}
        _must_be_protocol_error(msgpack.packb(m, use_bin_type=True))
