"""A small, seeded fuzz run of the protocol decoder in CI (the 1,000,000-input run is
``uwbnet bench fuzz``): mutated golden payloads raise only ProtocolError."""

from __future__ import annotations

from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import protocol
from protocol import ProtocolError

pytestmark = pytest.mark.fuzz

GOLDEN = sorted((Path(__file__).resolve().parents[1] / "data" / "golden").glob("*.msgpack"))
SEEDS = [p.read_bytes() for p in GOLDEN]


@st.composite
def mutated(draw: st.DrawFn) -> bytes:
    data = bytearray(draw(st.sampled_from(SEEDS)))
    for _ in range(draw(st.integers(1, 8))):
        op = draw(st.sampled_from(["flip", "cut", "insert", "splice"]))
        pos = draw(st.integers(0, max(len(data) - 1, 0)))
        if op == "flip" and data:
            data[pos] ^= 1 << draw(st.integers(0, 7))
        elif op == "cut":
            del data[pos : pos + draw(st.integers(1, 64))]
        elif op == "insert":
            data[pos:pos] = draw(st.binary(min_size=1, max_size=16))
        else:
            other = draw(st.sampled_from(SEEDS))
            data[pos:] = other[draw(st.integers(0, len(other))) :]
    return bytes(data)


@settings(
    max_examples=500,
    deadline=None,
    derandomize=True,
    database=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
@given(mutated())
def test_fuzz_decoder_mutated_golden_payloads_raise_only_protocol_errors(payload):
    try:
        protocol.decode(payload)
    except ProtocolError:
        pass
