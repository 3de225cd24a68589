"""Shared fixtures: seeded randomness, free loopback ports, and leak checks.

An autouse fixture fails any test that leaves a zenoh session open or a non-daemon thread
running: a process with an open callback session can hang for minutes at exit (DESIGN.md).
"""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
import zenoh

_open_sessions: list[zenoh.Session] = []
_real_open = zenoh.open


def _tracking_open(*args, **kwargs):  # type: ignore[no-untyped-def]
    session = _real_open(*args, **kwargs)
    _open_sessions.append(session)
    return session


zenoh.open = _tracking_open


@pytest.fixture(autouse=True)
def _no_leaks():  # type: ignore[no-untyped-def]
    threads_before = set(threading.enumerate())
    yield
    leaked = [s for s in _open_sessions if not s.is_closed()]
    _open_sessions.clear()
    for s in leaked:
        s.close()
    deadline = time.monotonic() + 2.0
    extra: list[threading.Thread] = []
    while time.monotonic() < deadline:
        extra = [
            t
            for t in threading.enumerate()
            if t not in threads_before and t.is_alive() and not t.name.startswith("pydevd")
        ]
        if not extra:
            break
        time.sleep(0.05)
    assert not leaked, f"test leaked {len(leaked)} open zenoh session(s)"
    assert not extra, f"test leaked threads: {[t.name for t in extra]}"


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(12345)


@pytest.fixture
def hub_endpoint() -> str:
    """A loopback endpoint on a free port for the listening peer of a test."""
    from protocol.transport import free_tcp_port

    return f"tcp/127.0.0.1:{free_tcp_port()}"
