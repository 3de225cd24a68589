"""The fast ``detections`` decoder (the fusion center's hot path) decodes exactly what the generic
field walk decodes, to an equal message, and leaves every rejection to it."""

from __future__ import annotations

import copy
from typing import Any

import msgpack
import numpy as np
import pytest

import protocol
from protocol import DecodeError, Detections, ProtocolError
from protocol.messages import _detections_fast
from protocol.schema import decode_fields


def _node_message() -> dict[str, Any]:
    """A ``detections`` map as a node writes it: two estimates, covariances, an unknown key."""
    det = Detections(
        src="n007",
        seq=41,
        t=12.345,
        tx="n007/tx",
        frame=617,
        ranges={"rx1": (3.5, 7.25), "rx2": (3.4, 7.3)},
        amplitudes={"rx1": (0.5, 0.25), "rx2": (0.4, 0.2)},
        positions=np.array([[1.0, 2.0], [3.5, -1.25]]),
        cov=np.array([np.eye(2) * 0.01, np.eye(2) * 0.04]),
        extra={"x_note": [1, 2]},
    )
    return msgpack.unpackb(det.to_wire())


def _empty_message() -> dict[str, Any]:
    m = _node_message()
    m["ranges"], m["amplitudes"] = {"rx1": [], "rx2": []}, {"rx1": [], "rx2": []}
    m["positions"] = {"dtype": "<f8", "shape": [0, 2], "data": b""}
    m["cov"] = {"dtype": "<f8", "shape": [0, 2, 2], "data": b""}
    return m


def _generic(m: dict[str, Any]) -> Any:
    """What the generic decoder gives: the message, or the error's type and text."""
    body = {k: v for k, v in m.items() if k not in ("v", "kind")}
    try:
        return decode_fields(Detections, body)
    except ProtocolError as exc:
        return type(exc), str(exc)
    except (TypeError, ValueError, IndexError) as exc:  # as protocol.decode types them
        return DecodeError, f"detections: {exc}".splitlines()[0]


def _decoded(m: dict[str, Any]) -> Any:
    try:
        return protocol.decode(msgpack.packb(m, use_bin_type=True))
    except ProtocolError as exc:
        return type(exc), str(exc)


def _assert_same(a: Any, b: Any) -> None:
    if isinstance(a, tuple) or isinstance(b, tuple):
        assert a == b
        return
    for name in ("src", "seq", "t", "tx", "frame", "ranges", "amplitudes", "links", "extra"):
        assert getattr(a, name) == getattr(b, name), name
        assert type(getattr(a, name)) is type(getattr(b, name)), name
    for name in ("positions", "cov"):
        x, y = getattr(a, name), getattr(b, name)
        assert (x is None) == (y is None), name
        if x is not None:
            assert x.dtype == y.dtype and x.shape == y.shape and np.array_equal(x, y), name
            assert not x.flags.writeable, f"{name} must be read-only like every decoded array"


def _set(m: dict[str, Any], path: tuple[Any, ...], value: Any) -> dict[str, Any]:
    m = copy.deepcopy(m)
    node = m
    for key in path[:-1]:
        node = node[key]
    if value is _DROP:
        del node[path[-1]]
    else:
        node[path[-1]] = value
    return m


_DROP = object()
_NAN8 = np.array([np.nan, 0.0]).tobytes()

#: Variants of a node's message: valid in other forms, or bad in the ways PROTOCOL.md rejects.
VARIANTS = [
    ((), None),
    (("t",), 12),  # an int for a float: valid, generic path
    (("t",), float("nan")),
    (("t",), "1.0"),
    (("seq",), -1),
    (("seq",), True),
    (("seq",), 1.0),
    (("frame",), None),
    (("src",), 7),
    (("tx",), _DROP),
    (("ranges",), _DROP),
    (("ranges",), [1.0]),
    (("ranges", "rx1"), [1.0, float("inf")]),
    (("ranges", "rx1"), [1.0, 2]),
    (("ranges", "rx1"), (1.0, 2.0)),
    (("ranges", "rx1"), [1.0]),  # length differs from amplitudes
    (("amplitudes", "rx2"), [0.4, "x"]),
    (("positions",), None),
    (("positions",), _DROP),
    (("positions",), [1.0, 2.0]),
    (("positions", "dtype"), "<f4"),
    (("positions", "shape"), [2, 2, 1]),
    (("positions", "shape"), [2, True]),
    (("positions", "shape"), (2, 2)),
    # zero bytes, but a shape numpy cannot make: a typed error, not numpy's ValueError
    (("positions", "shape"), [0, 2**63]),
    (("positions", "shape"), [0, 2**62]),
    (("cov", "shape"), [0, 2**62, 2]),
    (("positions", "data"), b"\x00" * 8),
    (("positions", "data"), _NAN8 * 2),
    (("positions", "data"), "text"),
    (("positions", "extra_key"), 1),
    (("cov",), None),
    (("cov", "shape"), [1, 2, 2]),
    (("cov", "data"), np.array([np.inf] * 8).tobytes()),
    (("links",), None),
    (("links",), {"a1": {"range": 1.0, "std": 0.1, "los": True, "snr_db": 20.0}}),
    (("links",), {"a 1": {}}),
    (("x_more",), {"k": 1}),
]


@pytest.mark.parametrize("base", [_node_message, _empty_message], ids=["estimates", "empty"])
@pytest.mark.parametrize(("path", "value"), VARIANTS, ids=[str(v) for v in VARIANTS])
def test_decode_equals_the_generic_walk(base: Any, path: tuple[Any, ...], value: Any) -> None:
    m = base() if not path else _set(base(), path, value)
    _assert_same(_decoded(m), _generic(m))


@pytest.mark.parametrize("base", [_node_message, _empty_message], ids=["estimates", "empty"])
def test_a_nodes_message_takes_the_fast_path(base: Any) -> None:
    m = base()
    fast = _detections_fast(m)
    assert fast is not None
    _assert_same(fast, _generic(m))


def test_the_fast_path_leaves_bad_messages_to_the_generic_one() -> None:
    """No bad message is accepted, whatever path it takes."""
    for path, value in VARIANTS:
        if not path:
            continue
        m = _set(_node_message(), path, value)
        expected = _generic(m)
        if isinstance(expected, tuple):
            # either handed on, or rejected by the message's own shape checks, alike
            try:
                fast = _detections_fast(m)
            except ProtocolError as exc:
                fast = type(exc), str(exc)
                assert fast == expected, (path, value)
            else:
                assert fast is None, (path, value)
