"""The typed errors of the wire contract.

Decoders raise only :class:`ProtocolError` subclasses, each with a one-line message that names
the offending field, so a running service can count and log a rejection without a traceback.
"""

from __future__ import annotations


class ProtocolError(ValueError):
    """Base of every error raised while decoding or validating a message or recording."""


class DecodeError(ProtocolError):
    """The payload is not msgpack, is too large, or a field is missing or of the wrong type."""


class VersionError(ProtocolError):
    """The message carries a version ``v`` this decoder does not know."""


class ShapeError(ProtocolError):
    """An array's shape, dtype or data length is inconsistent, or holds forbidden NaN/Inf."""


class KeyExprError(ProtocolError):
    """A zenoh key expression does not follow the uwbnet key layout."""


class RecordingError(ProtocolError):
    """An MCAP recording is unreadable, truncated or corrupt."""
