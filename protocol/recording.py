"""MCAP recordings of the contract (PROTOCOL.md, "Recordings").

Each key expression is a channel whose topic is the key, ``message_encoding`` is ``msgpack`` and
whose schema is ``uwbnet.{kind}`` (a JSON schema of the map). ``log_time`` and ``publish_time``
are ``t`` in nanoseconds, and the payload is exactly the bytes that travelled on the wire.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import os
from collections.abc import Callable, Iterator
from pathlib import Path
from types import TracebackType
from typing import IO, Protocol, Self

from mcap.writer import CompressionType, Writer

from protocol.errors import KeyExprError, ProtocolError, RecordingError
from protocol.keys import parse_key
from protocol.messages import KINDS, Message, decode
from protocol.units import seconds_to_ns

_log = logging.getLogger(__name__)

SCHEMA_PREFIX = "uwbnet."
VIZ_PREFIX = "/viz/"


def json_schema(kind: str) -> bytes:
    """A JSON schema of the map of ``kind``: its type and required fields."""
    cls = KINDS.get(kind)
    required = ["v", "kind", "src", "seq", "t"]
    if cls is not None:
        required += [
            f.name
            for f in dataclasses.fields(cls)
            if "wire" in f.metadata and not f.metadata.get("optional") and f.name not in required
        ]
    schema = {"title": SCHEMA_PREFIX + kind, "type": "object", "required": required}
    return json.dumps(schema, separators=(",", ":")).encode()


class RecordingWriter:
    """Write an MCAP recording; the file appears under its name only when closed cleanly.

    Messages go to ``{path}.partial``; :meth:`close` finishes the MCAP summary and renames it, so
    an interrupted run never leaves a file that looks complete. Use as a context manager: an
    exception inside the block removes the partial file.
    """

    def __init__(self, path: str | os.PathLike[str], *, library: str = "uwbnet") -> None:
        self.path = Path(path)
        self._partial = self.path.with_name(self.path.name + ".partial")
        try:
            self._file: IO[bytes] | None = open(self._partial, "wb")
        except OSError as exc:
            raise RecordingError(f"cannot write {self.path}: {exc.strerror}") from None
        self._writer = Writer(self._file, compression=CompressionType.NONE)
        self._writer.start(profile="", library=library)
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self.count = 0

    def _channel(self, topic: str, kind: str) -> int:
        channel = self._channels.get(topic)
        if channel is None:
            schema = self._schemas.get(kind)
            if schema is None:
                schema = self._writer.register_schema(
                    name=SCHEMA_PREFIX + kind, encoding="jsonschema", data=json_schema(kind)
                )
                self._schemas[kind] = schema
            channel = self._writer.register_channel(
                topic=topic, message_encoding="msgpack", schema_id=schema
            )
            self._channels[topic] = channel
        return channel

    def write(
        self, topic: str, kind: str, payload: bytes, t: float, *, log_time: int | None = None
    ) -> None:
        """Append one payload (bytes as on the wire) at network time ``t`` (s), or exactly at
        ``log_time`` (ns) when given (copying a recording)."""
        if self._file is None:
            raise RecordingError(f"{self.path}: recording already closed")
        ns = seconds_to_ns(t) if log_time is None else log_time
        self._writer.add_message(
            channel_id=self._channel(topic, kind), log_time=ns, publish_time=ns, data=payload
        )
        self.count += 1

    def write_json(
        self, topic: str, schema_name: str, schema: bytes, data: bytes, t: float
    ) -> None:
        """Append a JSON document on a viewer channel (``/viz/...``, message encoding ``json``,
        schema ``schema_name`` given as JSON schema ``schema``) at network time ``t`` (s)."""
        if self._file is None:
            raise RecordingError(f"{self.path}: recording already closed")
        if not topic.startswith(VIZ_PREFIX):
            raise RecordingError(f"viewer channel {topic!r} is not under {VIZ_PREFIX}")
        channel = self._channels.get(topic)
        if channel is None:
            key = "json:" + schema_name
            schema_id = self._schemas.get(key)
            if schema_id is None:
                schema_id = self._writer.register_schema(
                    name=schema_name, encoding="jsonschema", data=schema
                )
                self._schemas[key] = schema_id
            channel = self._writer.register_channel(
                topic=topic, message_encoding="json", schema_id=schema_id
            )
            self._channels[topic] = channel
        ns = seconds_to_ns(t)
        self._writer.add_message(channel_id=channel, log_time=ns, publish_time=ns, data=data)

    def write_message(self, topic: str, msg: Message) -> bytes:
        """Encode ``msg``, append it on ``topic`` and return the bytes written."""
        payload = msg.to_wire()
        self.write(topic, msg.KIND, payload, msg.t)
        return payload

    def flush(self) -> None:
        """End the chunk in progress and hand everything written so far to the OS.

        What was flushed survives a SIGKILL of this process (the kernel holds it); the file is
        still ``.partial`` and needs :func:`recover_recording` to become a complete MCAP.
        """
        if self._file is None:
            return
        self._writer.flush()

    def close(self) -> None:
        """Finish the MCAP, flush it to disk and move it to its final name. Idempotent."""
        if self._file is None:
            return
        self._writer.finish()
        self._file.flush()
        os.fsync(self._file.fileno())
        self._file.close()
        self._file = None
        os.replace(self._partial, self.path)

    def abort(self) -> None:
        """Drop the recording: close and remove the partial file. Idempotent."""
        if self._file is not None:
            self._file.close()
            self._file = None
        self._partial.unlink(missing_ok=True)

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()


@dataclasses.dataclass(frozen=True, slots=True, kw_only=True)
class RecordedMessage:
    """One message of a recording: its topic, kind (from the schema name), time and payload."""

    topic: str
    kind: str | None
    log_time: int
    payload: bytes

    @property
    def t(self) -> float:
        return self.log_time / 1e9

    @property
    def message_kind(self) -> str | None:
        """The message kind: from the channel's schema, else from the topic's key expression
        (recordings from other tools may carry no schema); None when neither tells."""
        if self.kind is not None:
            return self.kind
        try:
            return parse_key(self.topic).kind
        except KeyExprError:
            return None


def read_recording(path: str | os.PathLike[str]) -> Iterator[RecordedMessage]:
    """Yield the contract's messages of an MCAP recording in file order.

    ``/viz/...`` channels and channels not encoded as msgpack are skipped. A missing, corrupt or
    truncated file raises :class:`RecordingError` with a one-line message (after yielding the
    messages before the damage, so a caller may keep or drop them).
    """
    from mcap.reader import NonSeekingReader

    path = Path(path)
    try:
        f = open(path, "rb")
    except OSError as exc:
        raise RecordingError(f"cannot read {path}: {exc.strerror}") from None
    with f:
        try:
            # Read linearly, checking chunk CRCs: the summary section (channels, indexes) has
            # no CRC the reader checks, so a flipped byte there could silently drop or
            # re-route messages; schemas and channels inside the chunks are covered.
            reader = NonSeekingReader(f, validate_crcs=True)
            for schema, channel, message in reader.iter_messages(log_time_order=False):
                if channel.topic.startswith(VIZ_PREFIX) or channel.message_encoding != "msgpack":
                    continue
                kind = None
                if schema is not None and schema.name.startswith(SCHEMA_PREFIX):
                    kind = schema.name[len(SCHEMA_PREFIX) :]
                yield RecordedMessage(
                    topic=channel.topic,
                    kind=kind,
                    log_time=message.log_time,
                    payload=bytes(message.data),
                )
        except RecordingError:
            raise
        except Exception as exc:  # mcap raises struct, zlib, EOF and its own errors alike
            detail = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            raise RecordingError(f"{path}: corrupt or truncated MCAP ({detail})") from None


class ReadCounts(Protocol):
    """The counters :func:`decoded_messages` keeps (an offline pass's stats)."""

    messages: int
    rejected: int


def decoded_messages(
    path: str | os.PathLike[str],
    kinds: tuple[str, ...],
    counts: ReadCounts,
    progress: Callable[[int], None] | None = None,
) -> Iterator[Message]:
    """The messages of ``kinds`` in recording ``path``, decoded, in log order.

    Every record counts in ``counts.messages`` (and its payload size goes to ``progress``);
    a record of one of ``kinds`` that does not decode is counted in ``counts.rejected``,
    logged and skipped: an offline pass never stops on one bad message.
    """
    for rec in read_recording(path):
        counts.messages += 1
        if progress is not None:
            progress(len(rec.payload))
        if rec.message_kind not in kinds:
            continue
        try:
            msg = decode(rec.payload)
        except ProtocolError as exc:
            counts.rejected += 1
            _log.warning("%s: message rejected: %s", rec.topic, exc)
            continue
        yield msg


def recover_recording(
    partial: str | os.PathLike[str], out: str | os.PathLike[str]
) -> tuple[int, str | None]:
    """Copy the readable messages of an interrupted recording into a complete MCAP.

    A recorder killed without a chance to close (SIGKILL, power cut) leaves ``NAME.partial``:
    the MCAP header and every chunk it flushed, then perhaps a torn chunk. Messages up to the
    damage are rewritten, unchanged, to ``out``.

    Returns
    -------
    count : messages recovered.
    damage : the one-line reason reading stopped, or None if the input was complete.
    """
    damage = None
    count = 0
    with RecordingWriter(out, library="uwbnet recover") as writer:
        try:
            for rec in read_recording(partial):
                writer.write(
                    rec.topic, rec.kind or "unknown", rec.payload, rec.t, log_time=rec.log_time
                )
                count += 1
        except RecordingError as exc:
            if count == 0 and "cannot read" in str(exc):
                raise
            damage = str(exc)
    return count, damage
