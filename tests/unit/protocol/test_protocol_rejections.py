"""Rejections (PROTOCOL.md, "Encoding"): every bad payload raises one typed ProtocolError with a
specific one-line message; unknown extra fields are kept, ignored and written back."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import msgpack
import numpy as np
import pytest

import protocol
from protocol import DecodeError, ProtocolError, ShapeError, VersionError

GOLDEN = Path(__file__).resolve().parents[2] / "data" / "golden"
MAX_PAYLOAD = 16 * 1024 * 1024  # PROTOCOL.md: "more than 16 MiB" is rejected


def raw(name: str) -> dict[str, Any]:
    """A fresh, mutable copy of a golden message's msgpack map."""
    return msgpack.unpackb((GOLDEN / f"{name}.msgpack").read_bytes())


def pack(m: Any) -> bytes:
    return msgpack.packb(m, use_bin_type=True)


def set_in(m: dict[str, Any], path: tuple[Any, ...], value: Any) -> dict[str, Any]:
    node = m
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = value
    return m


def drop_in(m: dict[str, Any], path: tuple[Any, ...]) -> dict[str, Any]:
    node = m
    for key in path[:-1]:
        node = node[key]
    del node[path[-1]]
    return m


def reject(payload: bytes, error: type[ProtocolError], fragment: str) -> str:
    """Decode ``payload``, expecting exactly ``error`` with ``fragment`` in a one-line message."""
    with pytest.raises(ProtocolError) as info:
        protocol.decode(payload)
    message = str(info.value)
    assert type(info.value) is error, f"{type(info.value).__name__}: {message}"
    assert fragment in message
    assert "\n" not in message and message.strip()
    return message


def name_of(path: tuple[Any, ...]) -> str:
    """The dotted field name the decoder reports: ``slots[0].tx``, ``antennas.tx0.pos``."""
    out = ""
    for key in path:
        out += f"[{key}]" if isinstance(key, int) else (f".{key}" if out else key)
    return out


# --- not msgpack, not a map ----------------------------------------------------------------------


@pytest.mark.parametrize(
    "payload",
    [b"", b"\xc1", b"\x92\x01", b"\x85\xa1v", b"\xdb\xff\xff\xff\xff", pack({"v": 1}) + b"\x00"],
    ids=["empty", "never-used-byte", "short-array", "short-map", "str32-overrun", "trailing"],
)
def test_not_msgpack(payload: bytes) -> None:
    reject(payload, DecodeError, "not msgpack")


@pytest.mark.parametrize(
    ("value", "type_name"),
    [([1, 2], "list"), (1, "int"), ("ir", "str"), (None, "NoneType"), (b"\x80", "bytes")],
)
def test_msgpack_but_not_a_map(value: Any, type_name: str) -> None:
    reject(pack(value), DecodeError, f"message is not a map but {type_name}")


def test_map_with_non_string_keys() -> None:
    reject(pack({1: 1, "kind": "status"}), DecodeError, "map key")


def test_memoryview_and_bytearray_payloads_decode() -> None:
    payload = (GOLDEN / "status.msgpack").read_bytes()
    assert protocol.decode(bytearray(payload)).to_wire() == payload
    assert protocol.decode(memoryview(payload)).to_wire() == payload


# --- missing required fields ---------------------------------------------------------------------

HEADER = [("v",), ("kind",), ("src",), ("seq",), ("t",)]
#: Required fields of each kind (PROTOCOL.md, "Message kinds"), nested ones included.
REQUIRED: dict[str, list[tuple[Any, ...]]] = {
    "node_info": [
        ("role",),
        ("pose",),
        ("mobile",),
        ("antennas",),
        ("radar",),
        *[("antennas", "tx0", f) for f in ("pos", "tx", "rx", "boresight", "beamwidth")],
        *[("radar", f) for f in ("fs", "n", "t0", "f_low", "f_high", "rate")],
    ],
    "ir": [("tx",), ("rx",), ("slot",), ("frame",), ("h",)],
    "detections": [("tx",), ("frame",), ("ranges",), ("amplitudes",)],
    "status": [
        (f,) for f in ("uptime", "acquired", "published", "dropped", "late_slots", "decode_errors")
    ]
    + [("cpu",)],
    "tdma_schedule": [
        ("frame_period",),
        ("epoch",),
        ("slots",),
        *[("slots", 1, f) for f in ("slot", "tx", "start", "duration")],
    ],
    "tracks": [
        ("tracks",),
        ("n_estimate",),
        *[("tracks", 0, f) for f in ("id", "x", "y", "vx", "vy", "cov", "w")],
    ],
    "poses": [("poses",), *[("poses", "bat2", f) for f in ("pose", "cov", "los")]],
    "image": [(f,) for f in ("x0", "y0", "dx", "dy", "method", "img")],
    "map": [(f,) for f in ("robot", "origin", "walls", "corners", "points")],
    "truth": [
        ("targets",),
        ("nodes",),
        *[("targets", 1, f) for f in ("id", "x", "y", "vx", "vy")],
    ],
}
MISSING_CASES = [
    pytest.param(kind, path, id=f"{kind}-{name_of(path)}")
    for kind, paths in REQUIRED.items()
    for path in [*HEADER, *paths]
]


def test_required_table_covers_every_kind() -> None:
    assert set(REQUIRED) == set(protocol.KINDS)


@pytest.mark.parametrize(("kind", "path"), MISSING_CASES)
def test_missing_required_field(kind: str, path: tuple[Any, ...]) -> None:
    m = drop_in(raw(kind), path)
    reject(pack(m), DecodeError, f"missing required field {name_of(path)!r}")


@pytest.mark.parametrize(
    ("name", "path"),
    [("ir_c8", ("pose",)), ("detections", ("positions",)), ("node_info_dw1000", ("radar", "fc"))],
)
def test_optional_field_may_be_absent(name: str, path: tuple[Any, ...]) -> None:
    m = drop_in(raw(name), path)
    if path == ("positions",):
        del m["cov"]
    msg = protocol.decode(pack(m))
    node: Any = msg
    for key in path:
        node = getattr(node, key)
    assert node is None
    assert msg.to_wire() == pack(m)


# --- wrong types ---------------------------------------------------------------------------------

WRONG_TYPES = [
    # str for float
    ("status", ("t",), "100.0", "field 't': expected float, got str"),
    ("node_info", ("radar", "fs"), "13e9", "field 'radar.fs': expected float, got str"),
    ("detections", ("ranges", "rx0", 1), "7.5", "field 'ranges.rx0[1]': expected float, got str"),
    ("tracks", ("tracks", 0, "cov", 1, 2), "0", "field 'tracks[0].cov[1][2]': expected float"),
    # float for int
    ("status", ("seq",), 9.0, "field 'seq': expected int, got float"),
    ("ir", ("frame",), 1234.0, "field 'frame': expected int, got float"),
    ("node_info", ("radar", "n"), 16.0, "field 'radar.n': expected int, got float"),
    ("status", ("dropped",), 50.0, "field 'dropped': expected int, got float"),
    # bool for int
    ("ir", ("slot",), True, "field 'slot': expected int, got bool"),
    ("status", ("acquired",), False, "field 'acquired': expected int, got bool"),
    ("tracks", ("tracks", 0, "id"), True, "field 'tracks[0].id': expected int, got bool"),
    ("tdma_schedule", ("slots", 0, "slot"), True, "field 'slots[0].slot': expected int"),
    # bool for float
    ("image", ("dx",), True, "field 'dx': expected float, got bool"),
    # int for bool
    ("node_info", ("mobile",), 0, "field 'mobile': expected bool, got int"),
    ("node_info", ("antennas", "rx0", "rx"), 1, "field 'antennas.rx0.rx': expected bool"),
    ("poses", ("poses", "bat2", "los", "anchor1"), 1, "field 'poses.bat2.los.anchor1'"),
    # other shapes of wrong
    ("status", ("src",), 5, "field 'src': expected str, got int"),
    ("image", ("method",), b"kirchhoff", "field 'method': expected str, got bytes"),
    ("ir", ("rx",), "rx0", "field 'rx': expected a list, got str"),
    ("ir", ("tx",), None, "field 'tx': expected str, got NoneType"),
    ("node_info", ("pose",), [1.0, 2.0, 3.0], "field 'pose': expected 4 numbers, got 3"),
    ("node_info", ("antennas",), [], "field 'antennas': expected a map, got list"),
    ("node_info", ("radar",), [], "field 'radar': expected a map, got list"),
    ("node_info", ("role",), "drone", "field 'role': 'drone' is not one of"),
    ("status", ("seq",), -1, "field 'seq': -1 is below 0"),
    ("tracks", ("tracks", 0, "cov"), [[0.0] * 4] * 3, "field 'tracks[0].cov': expected a 4x4"),
    ("poses", ("poses", "bat2", "cov", 0), [0.0, 0.0], "expected 3 numbers, got 2"),
    ("tdma_schedule", ("slots",), {}, "field 'slots': expected a list, got dict"),
    ("truth", ("nodes",), {"a b": [0.0] * 4}, "field 'nodes': bad key 'a b'"),
    ("truth", ("nodes",), {"bat2\n": [0.0] * 4}, "field 'nodes': bad key 'bat2\\n'"),
    ("ir", ("h",), [[0.0] * 16] * 2, "field 'h': expected an array map, got list"),
    ("ir", ("h", "data"), "abc", "field 'h': data must be binary"),
]


@pytest.mark.parametrize(
    ("name", "path", "value", "fragment"),
    WRONG_TYPES,
    ids=[f"{n}-{name_of(p)}-{type(v).__name__}" for n, p, v, _ in WRONG_TYPES],
)
def test_wrong_type(name: str, path: tuple[Any, ...], value: Any, fragment: str) -> None:
    reject(pack(set_in(raw(name), path, value)), DecodeError, fragment)


def test_int_for_float_is_accepted() -> None:
    """Other tools write 0 for 0.0; the decoder reads it as a float (schema.Float)."""
    msg = protocol.decode(pack(set_in(raw("status"), ("uptime",), 3600)))
    assert isinstance(msg, protocol.Status)
    assert type(msg.uptime) is float and msg.uptime == 3600.0


# --- header: version and kind --------------------------------------------------------------------


@pytest.mark.parametrize("v", [0, 2, 99, -1, 2**64 - 1])
def test_unknown_version(v: int) -> None:
    reject(pack(set_in(raw("status"), ("v",), v)), VersionError, f"unknown version v={v}")


@pytest.mark.parametrize("v", ["1", 1.0, True, None, [1]])
def test_version_of_wrong_type(v: Any) -> None:
    reject(pack(set_in(raw("status"), ("v",), v)), DecodeError, "field 'v'")


@pytest.mark.parametrize("kind", ["foo", "IR", "Status", ""])
def test_unknown_kind(kind: str) -> None:
    reject(pack(set_in(raw("status"), ("kind",), kind)), DecodeError, f"unknown kind {kind!r}")


@pytest.mark.parametrize("kind", [1, None, b"ir"])
def test_kind_of_wrong_type(kind: Any) -> None:
    m = set_in(raw("ir"), ("kind",), kind)
    reject(pack(m), DecodeError, "'kind'")


# --- arrays: shape, length, dtype ----------------------------------------------------------------


def test_array_data_shorter_than_shape() -> None:
    m = raw("ir")
    m["h"]["data"] = m["h"]["data"][:-4]
    reject(pack(m), ShapeError, "field 'h': data has 124 bytes, shape [2, 16] x <f4 needs 128")


def test_array_data_longer_than_shape() -> None:
    m = raw("ir_c8")
    m["h"]["shape"] = [2, 15]
    reject(pack(m), ShapeError, "field 'h': data has 256 bytes, shape [2, 15] x <c8 needs 240")


@pytest.mark.parametrize(
    ("name", "field", "shape", "fragment"),
    [
        ("ir", "h", [32], "field 'h': expected 2 dimensions, got shape [32]"),
        ("ir", "h", [1, 2, 16], "field 'h': expected 2 dimensions"),
        ("image", "img", [6], "field 'img': expected 2 dimensions"),
        ("detections", "positions", [4], "field 'positions': expected 2 dimensions"),
        ("detections", "cov", [2, 4], "field 'cov': expected 3 dimensions"),
        ("ir", "h", [-2, -16], "field 'h': shape must be a list of non-negative ints"),
        ("ir", "h", [2.0, 16], "field 'h': shape must be a list of non-negative ints"),
        ("ir", "h", [True, 16], "field 'h': shape must be a list of non-negative ints"),
        ("ir", "h", "2x16", "field 'h': shape must be a list of non-negative ints"),
    ],
)
def test_array_bad_shape(name: str, field: str, shape: Any, fragment: str) -> None:
    reject(pack(set_in(raw(name), (field, "shape"), shape)), ShapeError, fragment)


@pytest.mark.parametrize(
    ("name", "field", "dtype", "fragment"),
    [
        ("ir", "h", "<f8", "field 'h': dtype <f8 not allowed here"),
        ("ir", "h", "<i4", "field 'h': dtype <i4 not allowed here"),
        ("image", "img", "<u2", "field 'img': dtype <u2 not allowed here"),
        ("detections", "positions", "<f4", "field 'positions': dtype <f4 not allowed here"),
        ("ir", "h", ">f4", "field 'h': unknown dtype '>f4'"),
        ("ir", "h", "float32", "field 'h': unknown dtype 'float32'"),
        ("ir", "h", None, "field 'h': unknown dtype None"),
    ],
)
def test_array_bad_dtype(name: str, field: str, dtype: Any, fragment: str) -> None:
    reject(pack(set_in(raw(name), (field, "dtype"), dtype)), ShapeError, fragment)


def test_detections_positions_not_k_by_2() -> None:
    m = raw("detections")
    m["positions"] = {"dtype": "<f8", "shape": [2, 3], "data": bytes(48)}
    reject(pack(m), ShapeError, "field 'positions': shape [2, 3] is not [k, 2]")


def test_detections_cov_not_k_by_2_by_2() -> None:
    m = raw("detections")
    m["cov"] = {"dtype": "<f8", "shape": [1, 2, 2], "data": bytes(32)}
    reject(pack(m), ShapeError, "field 'cov': shape [1, 2, 2] is not [2, 2, 2]")


@pytest.mark.parametrize(
    ("shape", "data"),
    [([2**62, 4], b""), ([2**32, 2**32], b""), ([2**64 - 1, 16], bytes(128))],
    ids=["wraps-to-zero", "wraps-to-zero-2", "uint64-max"],
)
def test_huge_shape_is_a_length_mismatch(shape: list[int], data: bytes) -> None:
    """Regression: the byte count was computed in int64 and wrapped, so a huge shape with empty
    data passed the length check and numpy's reshape error escaped with an untyped message."""
    m = set_in(raw("ir"), ("h",), {"dtype": "<f4", "shape": shape, "data": data})
    needs = shape[0] * shape[1] * 4
    reject(pack(m), ShapeError, f"data has {len(data)} bytes, shape {shape} x <f4 needs {needs}")


def test_empty_array_with_a_dimension_numpy_cannot_hold() -> None:
    m = set_in(raw("ir"), ("h",), {"dtype": "<f4", "shape": [0, 2**64 - 1], "data": b""})
    m["rx"] = []
    with pytest.raises(ProtocolError) as info:
        protocol.decode(pack(m))
    assert "\n" not in str(info.value)


def test_empty_arrays_are_valid() -> None:
    m = set_in(raw("ir"), ("h",), {"dtype": "<f4", "shape": [0, 16], "data": b""})
    m["rx"] = []
    msg = protocol.decode(pack(m))
    assert isinstance(msg, protocol.Ir) and msg.h.shape == (0, 16)
    assert msg.to_wire() == pack(m)


# --- NaN and Inf ---------------------------------------------------------------------------------

NON_FINITE_FLOATS = [
    ("status", ("t",), float("nan"), "field 't': NaN or Inf not allowed"),
    ("status", ("cpu",), float("inf"), "field 'cpu': NaN or Inf not allowed"),
    ("node_info", ("radar", "fs"), float("inf"), "field 'radar.fs': NaN or Inf not allowed"),
    ("node_info", ("pose", 3), float("-inf"), "field 'pose[3]': NaN or Inf not allowed"),
    ("ir_c8", ("pose", 0), float("nan"), "field 'pose[0]': NaN or Inf not allowed"),
    ("detections", ("ranges", "rx1", 0), float("nan"), "field 'ranges.rx1[0]': NaN"),
    ("tracks", ("tracks", 0, "cov", 2, 2), float("nan"), "field 'tracks[0].cov[2][2]': NaN"),
    ("truth", ("targets", 1, "vy"), float("inf"), "field 'targets[1].vy': NaN or Inf"),
    ("image", ("dx",), float("nan"), "field 'dx': NaN or Inf not allowed"),
]


@pytest.mark.parametrize(
    ("name", "path", "value", "fragment"),
    NON_FINITE_FLOATS,
    ids=[f"{n}-{name_of(p)}-{v}" for n, p, v, _ in NON_FINITE_FLOATS],
)
def test_non_finite_float_field(
    name: str, path: tuple[Any, ...], value: float, fragment: str
) -> None:
    reject(pack(set_in(raw(name), path, value)), DecodeError, fragment)


@pytest.mark.parametrize(
    ("name", "field", "index", "value"),
    [
        ("ir", "h", (1, 5), np.nan),
        ("ir", "h", (0, 0), -np.inf),
        ("ir_c8", "h", (1, 15), complex(0.0, np.inf)),
        ("ir_c8", "h", (0, 3), complex(np.nan, 0.0)),
        ("image", "img", (1, 2), np.inf),
        ("detections", "positions", (0, 1), np.nan),
        ("detections", "cov", (1, 1, 1), np.inf),
    ],
)
def test_non_finite_array_element(
    name: str, field: str, index: tuple[int, ...], value: complex
) -> None:
    m = raw(name)
    arr = np.frombuffer(m[field]["data"], dtype=m[field]["dtype"]).reshape(m[field]["shape"])
    arr = arr.copy()
    arr[index] = value
    m[field]["data"] = arr.tobytes()
    reject(pack(m), ShapeError, f"field {field!r}: contains NaN or Inf")


# --- cross-field consistency ---------------------------------------------------------------------


@pytest.mark.parametrize("rx", [["rx0", "rx1", "rx2"], ["rx0"], []])
def test_ir_rows_differ_from_receivers(rx: list[str]) -> None:
    m = set_in(raw("ir"), ("rx",), rx)
    reject(pack(m), ShapeError, f"field 'h': 2 rows for {len(rx)} receivers")


@pytest.mark.parametrize(
    ("amplitudes", "bad"),
    [
        ({"rx0": [0.75], "rx1": [0.5]}, "rx0"),
        ({"rx0": [0.75, 0.125], "rx1": [0.5, 0.5]}, "rx1"),
        ({"rx0": [0.75, 0.125], "rx1": []}, "rx1"),
        ({"rx0": [0.75, 0.125]}, "rx1"),
    ],
)
def test_detections_amplitudes_length_differs(amplitudes: dict[str, Any], bad: str) -> None:
    m = set_in(raw("detections"), ("amplitudes",), amplitudes)
    reject(pack(m), ShapeError, f"field 'amplitudes.{bad}': length differs from 'ranges.{bad}'")


# --- size limit ----------------------------------------------------------------------------------


def _padded_status(total: int) -> bytes:
    """A valid status payload of exactly ``total`` bytes, padded by an extra binary field."""
    m = raw("status")
    m["pad"] = b"x" * 70_000  # bin32 from here on: header size no longer depends on length
    overhead = len(pack(m)) - 70_000
    m["pad"] = b"x" * (total - overhead)
    payload = pack(m)
    assert len(payload) == total
    return payload


def test_payload_of_16_mib_is_accepted() -> None:
    payload = _padded_status(MAX_PAYLOAD)
    msg = protocol.decode(payload)
    assert len(msg.extra["pad"]) > MAX_PAYLOAD - 200
    assert msg.to_wire() == payload


def test_payload_over_16_mib_is_rejected() -> None:
    reject(_padded_status(MAX_PAYLOAD + 1), DecodeError, f"exceeds {MAX_PAYLOAD}")


def test_huge_ir_is_rejected_before_unpacking() -> None:
    n = 2**21 + 1  # 2 rows x n x 4 bytes: just over 16 MiB of samples
    m = raw("ir")
    m["h"] = {"dtype": "<f4", "shape": [2, n], "data": bytes(8 * n)}
    payload = pack(m)
    reject(payload, DecodeError, f"payload of {len(payload)} bytes exceeds {MAX_PAYLOAD}")


# --- unknown extra fields ------------------------------------------------------------------------


def test_extra_fields_are_kept_ignored_and_written_back() -> None:
    m = raw("status")
    m["temperature"] = 41.5
    m["x_note"] = {"firmware": "1.2.3", "blob": b"\x00\x01", "list": [1, "a", None]}
    payload = pack(m)
    msg = protocol.decode(payload)
    assert dict(msg.extra) == {
        "temperature": 41.5,
        "x_note": {"firmware": "1.2.3", "blob": b"\x00\x01", "list": [1, "a", None]},
    }
    assert msg == protocol.decode((GOLDEN / "status.msgpack").read_bytes())  # ignored
    assert msg.to_wire() == payload


def test_nested_extra_fields_are_kept_and_written_back() -> None:
    m = raw("node_info")
    m["antennas"]["tx0"]["gain_db"] = 3.0
    m["radar"]["chip"] = "m-sequence"
    m["zone"] = "lab"
    payload = pack(m)
    msg = protocol.decode(payload)
    assert isinstance(msg, protocol.NodeInfo)
    assert dict(msg.antennas["tx0"].extra) == {"gain_db": 3.0}
    assert dict(msg.radar.extra) == {"chip": "m-sequence"}
    assert dict(msg.extra) == {"zone": "lab"}
    assert msg.to_wire() == payload

    t = raw("tdma_schedule")
    t["slots"][1]["power"] = 7
    t_payload = pack(t)
    sched = protocol.decode(t_payload)
    assert isinstance(sched, protocol.TdmaSchedule)
    assert dict(sched.slots[1].extra) == {"power": 7}
    assert sched.to_wire() == t_payload


def test_extra_fields_are_not_validated() -> None:
    m = raw("ir")
    m["h2"] = {"dtype": "bogus", "shape": "x", "data": 1}
    m["nan"] = float("nan")
    msg = protocol.decode(pack(m))
    assert set(msg.extra) == {"h2", "nan"}


def test_extra_field_in_the_middle_moves_after_the_known_fields() -> None:
    m = raw("status")
    reordered = {k: m[k] for k in ["v", "kind", "src", "seq", "t"]}
    reordered["x_first"] = 1
    reordered |= {k: val for k, val in m.items() if k not in reordered}
    msg = protocol.decode(pack(reordered))
    assert dict(msg.extra) == {"x_first": 1}
    again = msgpack.unpackb(msg.to_wire())
    assert list(again) == [*m, "x_first"]
    assert dict(protocol.decode(msg.to_wire()).extra) == {"x_first": 1}
