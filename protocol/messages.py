"""The message kinds of the uwbnet wire contract v1 (PROTOCOL.md), one dataclass each.

Every message is one msgpack map with string keys. ``to_wire()`` encodes, ``decode()`` (or
``Kind.from_wire()``) decodes and validates; decoders raise only :class:`ProtocolError`
subclasses. Unknown extra fields are kept in ``extra`` and written back on re-encoding, so a
message decoded and re-encoded keeps its bytes when its keys came in our order.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from typing import Any, ClassVar, Self

import msgpack
import numpy as np
import numpy.typing as npt

from protocol.errors import DecodeError, ProtocolError, VersionError
from protocol.schema import (
    ID_RE,
    Array,
    Bool,
    Float,
    Int,
    ListOf,
    MapOf,
    Matrix,
    Nested,
    Str,
    Vec,
    decode_fields,
    encode_fields,
    optional,
    wire,
)

#: The contract version this module writes.
VERSION = 1
#: Largest payload a decoder accepts (PROTOCOL.md, "Encoding").
MAX_PAYLOAD = 16 * 1024 * 1024

ROLES = ("anchor", "bat", "robot", "illuminator", "observer")

_frozen = dataclasses.dataclass(frozen=True, slots=True, kw_only=True)


def _no_extra() -> dict[str, Any]:
    return {}


@_frozen
class Message:
    """The header every message carries: ``v``, ``kind``, ``src``, ``seq``, ``t``.

    ``t`` is float64 seconds of network time; ``seq`` counts +1 per message per publisher.
    """

    KIND: ClassVar[str] = ""

    src: str = wire(Str())
    seq: int = wire(Int(minimum=0))
    t: float = wire(Float())
    v: int = VERSION
    extra: Mapping[str, Any] = dataclasses.field(default_factory=_no_extra, compare=False)

    def to_map(self) -> dict[str, Any]:
        """The msgpack map of this message: header first, then fields, then kept extras."""
        body = encode_fields(self)
        head = {"v": self.v, "kind": self.KIND}
        return head | body

    def to_wire(self) -> bytes:
        """Encode to the msgpack bytes that travel on the wire."""
        return msgpack.packb(self.to_map(), use_bin_type=True)

    @classmethod
    def from_wire(cls, payload: bytes | bytearray | memoryview) -> Self:
        """Decode ``payload`` and check it is of this kind."""
        msg = decode(payload)
        if not isinstance(msg, cls):
            raise DecodeError(f"expected kind {cls.KIND!r}, got {msg.KIND!r}")
        return msg


# --- node_info -------------------------------------------------------------------------------


@_frozen
class Antenna:
    """One antenna of a node: position in the node frame (m), roles, boresight yaw in the node
    frame (rad) and 3 dB beamwidth (rad; 2*pi for omni)."""

    pos: tuple[float, float, float] = wire(Vec(3))
    tx: bool = wire(Bool())
    rx: bool = wire(Bool())
    boresight: float = wire(Float())
    beamwidth: float = wire(Float())
    extra: Mapping[str, Any] = dataclasses.field(default_factory=_no_extra, compare=False)


@_frozen
class RadarInfo:
    """Sampling of a node's impulse responses: sample k is at ``t0 + k/fs`` after emission."""

    fs: float = wire(Float())
    n: int = wire(Int(minimum=1))
    t0: float = wire(Float())
    f_low: float = wire(Float())
    f_high: float = wire(Float())
    rate: float = wire(Float())
    fc: float | None = optional(Float())
    extra: Mapping[str, Any] = dataclasses.field(default_factory=_no_extra, compare=False)


@_frozen
class NodeInfo(Message):
    """A node's description: role, world pose [x, y, z, yaw], antennas and radar sampling."""

    KIND: ClassVar[str] = "node_info"

    role: str = wire(Str(choices=ROLES))
    pose: tuple[float, float, float, float] = wire(Vec(4))
    mobile: bool = wire(Bool())
    antennas: Mapping[str, Antenna] = wire(MapOf(Nested(Antenna)))
    radar: RadarInfo = wire(Nested(RadarInfo))


# --- ir, detections, status ------------------------------------------------------------------


@_frozen
class Ir(Message):
    """One acquisition: impulse responses of transmitter ``tx`` at this node's receivers ``rx``.

    ``h`` is ``(len(rx), n)``, ``<f4`` real or ``<c8`` complex baseband, sample k at
    ``t0 + k/fs`` after emission (``node_info.radar``). Optional ``pose`` (mobile nodes) and
    ``odom`` (odometry increment since the previous acquisition, docs/mapping.md).
    """

    KIND: ClassVar[str] = "ir"

    tx: str = wire(Str())
    rx: tuple[str, ...] = wire(ListOf(Str()))
    slot: int = wire(Int())
    frame: int = wire(Int())
    h: npt.NDArray[Any] = wire(Array(("<f4", "<c8"), ndim=2))
    pose: tuple[float, float, float, float] | None = optional(Vec(4))
    #: Optional odometry of a mobile node: ``(dx, dy, dyaw)`` driven since its previous
    #: acquisition, in the node frame of that acquisition (m, m, rad), as its wheels measured
    #: it (slip included). Used by the SLAM of :mod:`fusion_center.mapping`.
    odom: tuple[float, float, float] | None = optional(Vec(3))

    def __post_init__(self) -> None:
        if self.h.shape[0] != len(self.rx):
            raise_shape(f"field 'h': {self.h.shape[0]} rows for {len(self.rx)} receivers")


@_frozen
class LinkRange:
    """One node-to-node range (optional ``detections.links``, docs/localization.md): the
    first-path length of the direct link between this node and anchor ``{id}``, m, from a
    round-trip ToA exchange (clock offsets cancel), its standard deviation, m, the per-impulse-
    response LOS decision and the received SNR, dB."""

    range: float = wire(Float())
    std: float = wire(Float())
    los: bool = wire(Bool())
    snr_db: float = wire(Float())
    extra: Mapping[str, Any] = dataclasses.field(default_factory=_no_extra, compare=False)


@_frozen
class Detections(Message):
    """Ranges (bistatic path lengths, m) per receiver and optional world x, y position estimates
    with covariances, extracted from one acquisition."""

    KIND: ClassVar[str] = "detections"

    tx: str = wire(Str())
    frame: int = wire(Int())
    ranges: Mapping[str, tuple[float, ...]] = wire(MapOf(Vec(None)))
    amplitudes: Mapping[str, tuple[float, ...]] = wire(MapOf(Vec(None)))
    positions: npt.NDArray[np.float64] | None = optional(Array(("<f8",), ndim=2))
    cov: npt.NDArray[np.float64] | None = optional(Array(("<f8",), ndim=3))
    links: Mapping[str, LinkRange] | None = optional(MapOf(Nested(LinkRange), ID_RE))

    def __post_init__(self) -> None:
        for rx, r in self.ranges.items():
            a = self.amplitudes.get(rx)
            if a is None or len(a) != len(r):
                raise_shape(f"field 'amplitudes.{rx}': length differs from 'ranges.{rx}'")
        if self.positions is not None:
            if self.positions.shape[1:] != (2,):
                raise_shape(f"field 'positions': shape {list(self.positions.shape)} is not [k, 2]")
            k = self.positions.shape[0]
            if self.cov is not None and self.cov.shape != (k, 2, 2):
                raise_shape(f"field 'cov': shape {list(self.cov.shape)} is not [{k}, 2, 2]")


@_frozen
class Status(Message):
    """Health counters of a node agent, published at 1 Hz."""

    KIND: ClassVar[str] = "status"

    uptime: float = wire(Float())
    acquired: int = wire(Int(minimum=0))
    published: int = wire(Int(minimum=0))
    dropped: int = wire(Int(minimum=0))
    late_slots: int = wire(Int(minimum=0))
    decode_errors: int = wire(Int(minimum=0))
    cpu: float = wire(Float())


# --- tdma_schedule ---------------------------------------------------------------------------


@_frozen
class Slot:
    """One TDMA slot: index, transmitter ``"{node}/{antenna}"``, offset in the frame, duration."""

    slot: int = wire(Int(minimum=0))
    tx: str = wire(Str())
    start: float = wire(Float())
    duration: float = wire(Float())
    extra: Mapping[str, Any] = dataclasses.field(default_factory=_no_extra, compare=False)


@_frozen
class TdmaSchedule(Message):
    """The TDMA frame: period (s), epoch (network time of frame 0 start) and slots."""

    KIND: ClassVar[str] = "tdma_schedule"

    frame_period: float = wire(Float())
    epoch: float = wire(Float())
    slots: tuple[Slot, ...] = wire(ListOf(Nested(Slot)))

    def __post_init__(self) -> None:
        if self.frame_period <= 0:
            raise DecodeError("field 'frame_period': must be positive")


# --- fusion outputs --------------------------------------------------------------------------


@_frozen
class Track:
    """One tracked target: stable ``id``, state x, vx, y, vy (m, m/s), 4x4 covariance in the
    state order x, vx, y, vy, and weight or existence probability ``w``."""

    id: int = wire(Int())
    x: float = wire(Float())
    y: float = wire(Float())
    vx: float = wire(Float())
    vy: float = wire(Float())
    cov: tuple[tuple[float, ...], ...] = wire(Matrix(4))
    w: float = wire(Float())
    extra: Mapping[str, Any] = dataclasses.field(default_factory=_no_extra, compare=False)


@_frozen
class Tracks(Message):
    """The fusion center's current multi-target estimate."""

    KIND: ClassVar[str] = "tracks"

    tracks: tuple[Track, ...] = wire(ListOf(Nested(Track)))
    n_estimate: float = wire(Float())


@_frozen
class PoseEstimate:
    """Estimated pose [x, y, z, yaw] of a mobile node, 3x3 covariance over x, y, yaw, and the
    per-anchor line-of-sight decision."""

    pose: tuple[float, float, float, float] = wire(Vec(4))
    cov: tuple[tuple[float, ...], ...] = wire(Matrix(3))
    los: Mapping[str, bool] = wire(MapOf(Bool()))
    extra: Mapping[str, Any] = dataclasses.field(default_factory=_no_extra, compare=False)


@_frozen
class Poses(Message):
    """Estimated poses of the mobile nodes."""

    KIND: ClassVar[str] = "poses"

    poses: Mapping[str, PoseEstimate] = wire(MapOf(Nested(PoseEstimate)))


@_frozen
class Image(Message):
    """An imaging result on a grid: pixel (i, j) is at (x0 + j*dx, y0 + i*dy)."""

    KIND: ClassVar[str] = "image"

    x0: float = wire(Float())
    y0: float = wire(Float())
    dx: float = wire(Float())
    dy: float = wire(Float())
    method: str = wire(Str())
    img: npt.NDArray[np.float32] = wire(Array(("<f4",), ndim=2))


@_frozen
class Map(Message):
    """A SLAM map of a robot (fusion_center.mapping): wall segments ``[x1, y1, x2, y2]``,
    corners and point scatterers ``[x, y]`` (m) in the world frame, where the robot's first
    pose ``origin`` ([x, y, z, yaw], world) anchors the map (docs/mapping.md)."""

    KIND: ClassVar[str] = "map"

    robot: str = wire(Str())
    origin: tuple[float, float, float, float] = wire(Vec(4))
    walls: npt.NDArray[np.float64] = wire(Array(("<f8",), ndim=2))
    corners: npt.NDArray[np.float64] = wire(Array(("<f8",), ndim=2))
    points: npt.NDArray[np.float64] = wire(Array(("<f8",), ndim=2))

    def __post_init__(self) -> None:
        for name, cols in (("walls", 4), ("corners", 2), ("points", 2)):
            a = getattr(self, name)
            if a.shape[1:] != (cols,):
                raise_shape(f"field {name!r}: shape {list(a.shape)} is not [k, {cols}]")


@_frozen
class Target:
    """A true target state (simulation only)."""

    id: int = wire(Int())
    x: float = wire(Float())
    y: float = wire(Float())
    vx: float = wire(Float())
    vy: float = wire(Float())
    extra: Mapping[str, Any] = dataclasses.field(default_factory=_no_extra, compare=False)


@_frozen
class Truth(Message):
    """Ground truth of targets and mobile nodes (simulator only)."""

    KIND: ClassVar[str] = "truth"

    targets: tuple[Target, ...] = wire(ListOf(Nested(Target)))
    nodes: Mapping[str, tuple[float, float, float, float]] = wire(MapOf(Vec(4), ID_RE))


#: kind -> message class.
KINDS: dict[str, type[Message]] = {
    cls.KIND: cls
    for cls in (NodeInfo, Ir, Detections, Status, TdmaSchedule, Tracks, Poses, Image, Map, Truth)
}


def raise_shape(message: str) -> None:
    """Raise :class:`~protocol.errors.ShapeError` (used in ``__post_init__`` checks)."""
    from protocol.errors import ShapeError

    raise ShapeError(message)


def unpack(payload: bytes | bytearray | memoryview) -> dict[str, Any]:
    """Unpack a payload into its msgpack map, checking size, map type and version only."""
    if len(payload) > MAX_PAYLOAD:
        raise DecodeError(f"payload of {len(payload)} bytes exceeds {MAX_PAYLOAD}")
    try:
        m = msgpack.unpackb(payload, raw=False, use_list=True, strict_map_key=True)
    except Exception as exc:  # msgpack raises several unrelated types for bad bytes
        raise DecodeError(f"not msgpack: {type(exc).__name__}: {exc}".splitlines()[0]) from None
    if not isinstance(m, dict):
        raise DecodeError(f"message is not a map but {type(m).__name__}")
    v = m.get("v")
    if isinstance(v, bool) or not isinstance(v, int):
        raise DecodeError("missing required field 'v'" if v is None else "field 'v': not an int")
    if v != VERSION:
        raise VersionError(f"unknown version v={v}")
    return m


def decode(payload: bytes | bytearray | memoryview) -> Message:
    """Decode any v1 message, dispatching on ``kind``.

    Raises
    ------
    DecodeError, VersionError, ShapeError
        Never anything else: every failure is a :class:`~protocol.errors.ProtocolError`.
    """
    m = unpack(payload)
    kind = m.get("kind")
    if not isinstance(kind, str):
        raise DecodeError("missing required field 'kind'" if kind is None else "bad 'kind'")
    cls = KINDS.get(kind)
    if cls is None:
        raise DecodeError(f"unknown kind {kind!r}")
    try:
        if cls is Detections:
            fast = _detections_fast(m)
            if fast is not None:
                return fast
        body = {k: val for k, val in m.items() if k not in ("v", "kind")}
        return decode_fields(cls, body)
    except ProtocolError:
        raise
    except (TypeError, ValueError, IndexError) as exc:  # defensive: never leak other types
        raise DecodeError(f"{kind}: {exc}".splitlines()[0]) from None


#: The keys a ``detections`` map may carry that are not kept in ``extra``.
_DETECTIONS_KEYS = frozenset(
    ("v", "kind", "src", "seq", "t", "tx", "frame", "ranges", "amplitudes", "positions", "cov")
)


def _float_lists(value: Any) -> dict[str, tuple[float, ...]] | None:
    """``ranges`` / ``amplitudes`` of a well-formed message (str keys, lists of finite
    floats), or None for anything else."""
    if type(value) is not dict:
        return None
    out = {}
    for k, v in value.items():
        if type(k) is not str or type(v) is not list:
            return None
        if not (all(type(x) is float for x in v) and all(map(math.isfinite, v))):
            return None
        out[k] = tuple(v)
    return out


def _read_only_empty(shape: tuple[int, ...]) -> npt.NDArray[np.float64]:
    a = np.zeros(shape)
    a.flags.writeable = False
    return a


#: Shared empty ``positions`` and ``cov`` (read-only, as every decoded array is).
_EMPTY_F8 = {(0, 2): _read_only_empty((0, 2)), (0, 2, 2): _read_only_empty((0, 2, 2))}


def _f8_array(obj: Any, ndim: int) -> npt.NDArray[np.float64] | None:
    """A well-formed ``<f8`` wire array of ``ndim`` dimensions, or None for anything else."""
    if type(obj) is not dict or len(obj) != 3 or obj.get("dtype") != "<f8":
        return None
    shape, data = obj.get("shape"), obj.get("data")
    if type(shape) is not list or len(shape) != ndim or type(data) is not bytes:
        return None
    if not all(type(s) is int and s >= 0 for s in shape):
        return None
    size = math.prod(shape)
    if len(data) != 8 * size:
        return None
    if not size and (empty := _EMPTY_F8.get(tuple(shape))) is not None:
        return empty  # most messages: no position estimate
    arr = np.frombuffer(data, dtype=np.float64).reshape(shape)
    if arr.size and not np.isfinite(arr).all():
        return None
    return arr


def _detections_fast(m: dict[str, Any]) -> Detections | None:
    """Decode the usual, well-formed ``detections`` map (the fusion center gets one per node per
    frame) without the generic per-field walk of :func:`~protocol.schema.decode_fields`.

    Every check of PROTOCOL.md is applied, but in the narrow form every node writes (floats
    that are Python floats, no ``links``, arrays with exactly their three keys); anything else
    returns None and goes the generic way, which accepts the other valid forms and raises the
    precise error. So this path only ever decodes what the generic one decodes, to an equal
    message (tests/unit/protocol/test_protocol_fast_decode.py)."""
    src, seq, t, tx, frame = m.get("src"), m.get("seq"), m.get("t"), m.get("tx"), m.get("frame")
    if not (type(src) is str and type(tx) is str and type(seq) is int and type(frame) is int):
        return None
    if seq < 0 or type(t) is not float or not math.isfinite(t) or "links" in m:
        return None
    ranges, amplitudes = _float_lists(m.get("ranges")), _float_lists(m.get("amplitudes"))
    if ranges is None or amplitudes is None:
        return None
    positions = cov = None
    if (p := m.get("positions")) is not None and (positions := _f8_array(p, 2)) is None:
        return None
    if (c := m.get("cov")) is not None and (cov := _f8_array(c, 3)) is None:
        return None
    extra = {k: v for k, v in m.items() if k not in _DETECTIONS_KEYS}
    return Detections(
        src=src,
        seq=seq,
        t=t,
        tx=tx,
        frame=frame,
        ranges=ranges,
        amplitudes=amplitudes,
        positions=positions,
        cov=cov,
        extra=extra,
    )
