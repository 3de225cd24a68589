"""The framed binary protocol between a node agent and an M-sequence radar on a serial/USB link.

Pure: bytes in, frames out; no port, no clock. See ``docs/serial-protocol.md``.

Frame layout (little endian)::

    sync     4 B   A5 5A C3 3C
    version  1 B   1
    type     1 B   FrameType
    seq      2 B   u16, the host's trigger sequence echoed in the device's IR
    length   4 B   u32, payload bytes (at most MAX_PAYLOAD)
    payload  length B
    crc      4 B   CRC-32 (zlib/IEEE 802.3) over version .. payload

A receiver that finds a bad version, an oversized length or a CRC mismatch drops the first
sync byte and searches for the next sync word: garbage on the line costs the frames it
overlaps, never the stream.
"""

from __future__ import annotations

import dataclasses
import enum
import struct
import zlib

import numpy as np
import numpy.typing as npt

SYNC = b"\xa5\x5a\xc3\x3c"
VERSION = 1
_HEADER = struct.Struct("<BBHI")  # version, type, seq, length
HEADER_SIZE = len(SYNC) + _HEADER.size
CRC_SIZE = 4
#: Largest payload accepted: 8 receivers x 16384 float32 samples plus the IR header.
MAX_PAYLOAD = 8 * 16384 * 4 + 16

_INFO = struct.Struct("<dddddIHH")  # fs, t0, f_low, f_high, rate, n, n_rx, dtype code
_IR = struct.Struct("<IHI")  # frame, n_rx, n
_TRIGGER = struct.Struct("<IH")  # frame, slot
DTYPE_F32 = 0


class FrameType(enum.IntEnum):
    """Frame types: host -> device requests, device -> host answers."""

    INFO_REQUEST = 0x01
    TRIGGER = 0x02
    INFO = 0x81
    IR = 0x82


class FrameError(ValueError):
    """A frame's payload does not match its type (one-line message)."""


@dataclasses.dataclass(frozen=True, slots=True)
class Frame:
    """One frame: its type, sequence number and payload bytes."""

    type: int
    seq: int
    payload: bytes


@dataclasses.dataclass(frozen=True, slots=True, kw_only=True)
class DeviceInfo:
    """What the radar reports of itself (INFO payload). ``fs`` Hz equivalent sample rate,
    ``t0`` s of sample 0 after emission, band edges ``f_low``/``f_high`` Hz, ``rate`` impulse
    responses per second, ``n`` samples per response, ``n_rx`` receivers."""

    fs: float
    t0: float
    f_low: float
    f_high: float
    rate: float
    n: int
    n_rx: int


def encode_frame(frame_type: int, seq: int, payload: bytes = b"") -> bytes:
    """The bytes of one frame (sync, header, payload, CRC-32)."""
    if len(payload) > MAX_PAYLOAD:
        raise FrameError(f"payload of {len(payload)} B exceeds {MAX_PAYLOAD} B")
    body = _HEADER.pack(VERSION, frame_type, seq & 0xFFFF, len(payload)) + payload
    return SYNC + body + struct.pack("<I", zlib.crc32(body))


class FrameParser:
    """Incremental frame parser with resynchronisation.

    Feed it whatever the port returned; it yields complete, CRC-checked frames and keeps the
    rest. Counters: ``frames`` accepted, ``crc_errors``, ``bad_headers`` (version or length)
    and ``garbage_bytes`` skipped while searching for a sync word. The buffer never holds
    more than one maximal frame.

    ``max_payload`` bounds the length field: a receiver that knows its largest frame sets it
    so that a garbage header claiming a huge length is rejected at once instead of holding
    the frames behind it until that many bytes have arrived.
    """

    def __init__(self, max_payload: int = MAX_PAYLOAD) -> None:
        self.max_payload = max_payload
        self._buf = bytearray()
        self.frames = 0
        self.crc_errors = 0
        self.bad_headers = 0
        self.garbage_bytes = 0

    def feed(self, data: bytes) -> list[Frame]:
        """Add received bytes; return the frames they complete, in order."""
        self._buf += data
        out: list[Frame] = []
        buf = self._buf
        while True:
            start = buf.find(SYNC)
            if start < 0:
                # Keep a tail that may be the start of a sync word split across reads.
                keep = len(SYNC) - 1
                drop = max(len(buf) - keep, 0)
                self.garbage_bytes += drop
                del buf[:drop]
                break
            if start:
                self.garbage_bytes += start
                del buf[:start]
            if len(buf) < HEADER_SIZE:
                break
            version, ftype, seq, length = _HEADER.unpack_from(buf, len(SYNC))
            if version != VERSION or length > self.max_payload:
                self.bad_headers += 1
                self.garbage_bytes += 1
                del buf[:1]
                continue
            end = HEADER_SIZE + length + CRC_SIZE
            if len(buf) < end:
                break
            body = bytes(buf[len(SYNC) : HEADER_SIZE + length])
            (crc,) = struct.unpack_from("<I", buf, HEADER_SIZE + length)
            if zlib.crc32(body) != crc:
                self.crc_errors += 1
                self.garbage_bytes += 1
                del buf[:1]
                continue
            out.append(Frame(ftype, seq, body[_HEADER.size :]))
            self.frames += 1
            del buf[:end]
        return out


def encode_info(info: DeviceInfo) -> bytes:
    """INFO payload."""
    return _INFO.pack(
        info.fs, info.t0, info.f_low, info.f_high, info.rate, info.n, info.n_rx, DTYPE_F32
    )


def decode_info(payload: bytes) -> DeviceInfo:
    """DeviceInfo of an INFO payload; FrameError if malformed or implausible."""
    if len(payload) != _INFO.size:
        raise FrameError(f"INFO payload of {len(payload)} B, expected {_INFO.size}")
    fs, t0, f_low, f_high, rate, n, n_rx, dtype = _INFO.unpack(payload)
    values = np.array([fs, t0, f_low, f_high, rate])
    if not np.isfinite(values).all() or fs <= 0 or rate <= 0 or not 0 <= f_low < f_high:
        raise FrameError("INFO with non-finite or inconsistent radar parameters")
    if dtype != DTYPE_F32 or n < 1 or n_rx < 1:
        raise FrameError(f"INFO with unsupported sample type {dtype} or empty shape")
    return DeviceInfo(fs=fs, t0=t0, f_low=f_low, f_high=f_high, rate=rate, n=n, n_rx=n_rx)


def encode_trigger(frame: int, slot: int) -> bytes:
    """TRIGGER payload: acquire now, for TDMA ``frame`` and ``slot``."""
    return _TRIGGER.pack(frame & 0xFFFFFFFF, slot & 0xFFFF)


def decode_trigger(payload: bytes) -> tuple[int, int]:
    """(frame, slot) of a TRIGGER payload."""
    if len(payload) != _TRIGGER.size:
        raise FrameError(f"TRIGGER payload of {len(payload)} B, expected {_TRIGGER.size}")
    frame, slot = _TRIGGER.unpack(payload)
    return int(frame), int(slot)


def encode_ir(frame: int, h: npt.NDArray[np.float32]) -> bytes:
    """IR payload: ``h`` float32 (n_rx, n), C order, little endian."""
    n_rx, n = h.shape
    return _IR.pack(frame & 0xFFFFFFFF, n_rx, n) + np.ascontiguousarray(h, "<f4").tobytes()


def decode_ir(payload: bytes) -> tuple[int, npt.NDArray[np.float32]]:
    """(frame, h) of an IR payload; ``h`` float32 (n_rx, n). FrameError if the length does
    not match the shape."""
    if len(payload) < _IR.size:
        raise FrameError(f"IR payload of {len(payload)} B is shorter than its header")
    frame, n_rx, n = _IR.unpack_from(payload)
    if len(payload) != _IR.size + 4 * n_rx * n:
        raise FrameError(f"IR payload of {len(payload)} B does not hold {n_rx} x {n} float32")
    h = np.frombuffer(payload, "<f4", offset=_IR.size).reshape(n_rx, n)
    return int(frame), h.astype(np.float32)
