"""Physical constants and unit conversions of the contract (SI everywhere, PROTOCOL.md)."""

from __future__ import annotations

#: Speed of light in vacuum, m/s (PROTOCOL.md, "Units and frames").
C = 299792458.0

#: Nanoseconds per second, for MCAP ``log_time``/``publish_time``.
NS_PER_S = 1_000_000_000


def seconds_to_ns(t: float) -> int:
    """Convert network time in seconds to the integer nanoseconds MCAP stores."""
    return max(0, round(t * NS_PER_S))
