"""Shared fixtures: seeded randomness, free loopback ports, and leak checks.

An autouse fixture fails any test that leaves a zenoh session open or a non-daemon thread
running: a process with an open callback session can hang for minutes at exit (DESIGN.md).
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Sequence
from pathlib import Path

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


class Processes:
    """Child processes of a test: ``uwbnet`` commands, killed (and reaped) at teardown."""

    def __init__(self, tmp_path) -> None:  # type: ignore[no-untyped-def]
        self.tmp_path = tmp_path
        self.procs: list[subprocess.Popen[bytes]] = []

    def uwbnet(self, *args: str, name: str, prefix: Sequence[str] = ()) -> subprocess.Popen[bytes]:
        """Start ``uwbnet ARGS`` (after ``prefix``, e.g. ``ip netns exec NS``); stdout and
        stderr go to ``{tmp_path}/{name}.out|.err``."""
        exe = str(Path(sys.executable).with_name("uwbnet"))
        out = open(self.tmp_path / f"{name}.out", "wb")
        err = open(self.tmp_path / f"{name}.err", "wb")
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        try:
            p = subprocess.Popen([*prefix, exe, *args], stdout=out, stderr=err, env=env)
        finally:
            out.close()
            err.close()
        self.procs.append(p)
        return p

    def stop(self, p: subprocess.Popen[bytes], timeout: float = 15.0) -> int:
        """SIGTERM ``p`` and wait for its exit status (SIGKILL if it does not exit in time)."""
        if p.poll() is None:
            p.send_signal(signal.SIGTERM)
        try:
            return p.wait(timeout)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()
            raise AssertionError(f"{p.args[-3:]} ignored SIGTERM for {timeout} s") from None

    def log(self, name: str) -> str:
        return (self.tmp_path / f"{name}.err").read_text(errors="replace")

    def kill_all(self) -> None:
        for p in self.procs:
            if p.poll() is None:
                p.kill()
        for p in self.procs:
            with contextlib.suppress(subprocess.TimeoutExpired):
                p.wait(10)


@pytest.fixture
def procs(tmp_path):  # type: ignore[no-untyped-def]
    """Start ``uwbnet`` child processes; every one still running is killed at teardown."""
    p = Processes(tmp_path)
    try:
        yield p
    finally:
        p.kill_all()
