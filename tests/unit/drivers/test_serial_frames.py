"""The serial frame protocol: encoding, parsing, resynchronisation (pure, no port)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from node_agent.drivers.serial_frames import (
    SYNC,
    DeviceInfo,
    FrameError,
    FrameParser,
    FrameType,
    decode_info,
    decode_ir,
    decode_trigger,
    encode_frame,
    encode_info,
    encode_ir,
    encode_trigger,
)

INFO = DeviceInfo(fs=7e9, t0=0.0, f_low=0.0, f_high=3.5e9, rate=50.0, n=64, n_rx=2)


def test_payloads_round_trip(rng):
    assert decode_info(encode_info(INFO)) == INFO
    assert decode_trigger(encode_trigger(70000, 3)) == (70000, 3)
    h = rng.normal(size=(2, 64)).astype(np.float32)
    frame, back = decode_ir(encode_ir(9, h))
    assert frame == 9 and back.dtype == np.float32 and np.array_equal(back, h)


def test_frame_layout_is_sync_header_payload_crc():
    b = encode_frame(FrameType.TRIGGER, 0x1234, b"\x01\x02")
    assert b[:4] == SYNC and b[4] == 1 and b[5] == FrameType.TRIGGER
    assert b[6:8] == b"\x34\x12" and b[8:12] == b"\x02\x00\x00\x00" and len(b) == 12 + 2 + 4


def test_parser_resynchronises_after_garbage_and_split_reads(rng):
    frames = [
        encode_frame(FrameType.IR, i, encode_ir(i, np.full((2, 8), i, np.float32)))
        for i in range(20)
    ]
    stream = bytearray()
    for f in frames:
        stream += rng.integers(0, 256, int(rng.integers(0, 40)), dtype=np.uint8).tobytes()
        stream += SYNC[:3]  # a partial sync word right before the real one
        stream += f
    parser = FrameParser()
    got = []
    pos = 0
    while pos < len(stream):
        step = int(rng.integers(1, 50))
        got += parser.feed(bytes(stream[pos : pos + step]))
        pos += step
    assert [f.seq for f in got] == list(range(20))
    assert parser.garbage_bytes > 0


def test_corrupt_crc_costs_only_that_frame():
    a = encode_frame(FrameType.IR, 1, b"a" * 10)
    b = bytearray(encode_frame(FrameType.IR, 2, b"b" * 10))
    b[-1] ^= 1
    c = encode_frame(FrameType.IR, 3, b"c" * 10)
    parser = FrameParser()
    got = parser.feed(a + bytes(b) + c)
    assert [f.seq for f in got] == [1, 3] and parser.crc_errors == 1


def test_an_oversized_length_field_is_rejected_at_once():
    parser = FrameParser(max_payload=100)
    bogus = SYNC + bytes([1, FrameType.IR, 0, 0]) + (10**6).to_bytes(4, "little")
    good = encode_frame(FrameType.IR, 5, b"x" * 10)
    assert [f.seq for f in parser.feed(bogus + good)] == [5]
    assert parser.bad_headers == 1


@pytest.mark.parametrize(
    ("call", "payload", "message"),
    [
        (decode_info, b"\x00" * 3, "INFO payload of 3 B"),
        (decode_ir, b"\x00" * 3, "shorter than its header"),
        (decode_ir, encode_ir(1, np.zeros((2, 4), np.float32))[:-1], "does not hold 2 x 4"),
        (decode_trigger, b"", "TRIGGER payload of 0 B"),
    ],
)
def test_malformed_payloads_raise_frame_error(call, payload, message):
    with pytest.raises(FrameError, match=message):
        call(payload)


@pytest.mark.fuzz
@settings(max_examples=300, deadline=None, derandomize=True)
@given(st.binary(max_size=400), st.integers(1, 64))
def test_fuzz_parser_never_raises_and_keeps_frames_after_noise(noise, step):
    good = encode_frame(FrameType.IR, 7, b"payload")
    parser = FrameParser(max_payload=1000)
    stream = noise + good
    got = []
    for i in range(0, len(stream), step):
        got += parser.feed(stream[i : i + step])
    assert any(f.seq == 7 and f.payload == b"payload" for f in got)
    assert len(parser._buf) < 1000 + 20
