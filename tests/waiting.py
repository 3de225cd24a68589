"""Waiting for a condition in the live (real zenoh, real threads) tests."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable


def wait_for(
    predicate: Callable[[], object], timeout: float, what: str, poll: float = 0.02
) -> float:
    """Wait until ``predicate()`` is true, polling every ``poll`` s; the seconds it took.
    Raises ``AssertionError`` naming ``what`` after ``timeout`` s."""
    t0 = time.monotonic()
    event = threading.Event()  # never set: a sleep that a test's other threads do not delay
    while not predicate():
        if time.monotonic() - t0 > timeout:
            raise AssertionError(f"timed out after {timeout} s waiting for {what}")
        event.wait(poll)
    return time.monotonic() - t0
