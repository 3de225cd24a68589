"""A serial M-sequence radar emulated on a pseudo-terminal, for tests and bench-top runs.

:class:`PtyRadarEmulator` opens a pty pair, keeps the master side and serves the protocol of
:mod:`node_agent.drivers.serial_frames` from a thread: it answers INFO_REQUEST with its
description and every TRIGGER with an IR frame computed by ``source(frame, slot)``. The slave
side is a real tty device (``emulator.port``, or a stable symlink ``link``) that
:class:`~node_agent.drivers.serial.SerialDriver` opens like a USB adapter.

Faults a field link shows can be injected: garbage bytes before answers, corrupted CRCs,
silence (a hung device), and unplugging (the master side is closed, so the driver's reads
fail with EIO) followed by plugging back in on a fresh pty behind the same symlink.
"""

from __future__ import annotations

import contextlib
import os
import select
import threading
import tty
from collections.abc import Callable
from pathlib import Path
from types import TracebackType
from typing import Self

import numpy as np
import numpy.typing as npt

from node_agent.drivers.serial_frames import (
    DeviceInfo,
    FrameError,
    FrameParser,
    FrameType,
    decode_trigger,
    encode_frame,
    encode_info,
    encode_ir,
)

Source = Callable[[int, int], npt.NDArray[np.float32]]


def noise_source(info: DeviceInfo, seed: int = 0) -> Source:
    """A source of Gaussian noise plus one echo at sample n/4, float32 (n_rx, n)."""
    rng = np.random.default_rng(seed)

    def source(frame: int, slot: int) -> npt.NDArray[np.float32]:
        h = rng.normal(0.0, 0.01, (info.n_rx, info.n)).astype(np.float32)
        h[:, info.n // 4] += 1.0
        return h

    return source


class PtyRadarEmulator:
    """An emulated radar on a pty. A context manager; :meth:`close` is idempotent.

    Parameters
    ----------
    info : what the device reports (INFO).
    source : ``(frame, slot) -> h`` float32 (n_rx, n) for each TRIGGER; default noise.
    link : optional path of a symlink to the current pty (kept across :meth:`replug`).
    seed : seed of the injected garbage.

    Attributes set by tests: ``garbage`` bytes of noise sent before each answer,
    ``corrupt_every`` (corrupt the CRC of every k-th IR, 0: never), ``silent`` (answer
    nothing), ``delay`` (s before each IR).
    """

    def __init__(
        self,
        info: DeviceInfo,
        source: Source | None = None,
        *,
        link: str | os.PathLike[str] | None = None,
        seed: int = 0,
    ) -> None:
        self.info = info
        self.source = source or noise_source(info, seed)
        self.link = Path(link) if link is not None else None
        self._rng = np.random.default_rng(seed)
        self.garbage = 0
        self.corrupt_every = 0
        self.silent = False
        self.delay = 0.0
        self.triggers = 0
        self.answered = 0
        self._master = -1
        self._slave = -1
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._plug()

    @property
    def port(self) -> str:
        """The device path to open: the symlink if any, else the pty's slave path."""
        return str(self.link) if self.link is not None else self._slave_name

    def _plug(self) -> None:
        self._master, self._slave = os.openpty()
        # Raw mode: no echo, no line editing, no CR/LF translation of binary frames.
        tty.setraw(self._slave)
        self._slave_name = os.ttyname(self._slave)
        if self.link is not None:
            tmp = self.link.with_name(self.link.name + ".new")
            tmp.unlink(missing_ok=True)
            tmp.symlink_to(self._slave_name)
            tmp.replace(self.link)
        self._stop = threading.Event()
        self._thread = threading.Thread(
            target=self._serve, args=(self._master, self._stop), name="pty-radar", daemon=True
        )
        self._thread.start()

    def unplug(self) -> None:
        """Pull the cable: stop answering and close both pty ends (reads then fail)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(2.0)
            self._thread = None
        for fd in (self._master, self._slave):
            if fd >= 0:
                with contextlib.suppress(OSError):
                    os.close(fd)
        self._master = self._slave = -1

    def replug(self) -> None:
        """Plug back in: a fresh pty behind the same symlink (needs ``link``)."""
        self.unplug()
        self._plug()

    def close(self) -> None:
        """Unplug and remove the symlink. Idempotent."""
        self.unplug()
        if self.link is not None:
            self.link.unlink(missing_ok=True)

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    # -- device ----------------------------------------------------------------------------

    def _write(self, fd: int, data: bytes) -> None:
        if self.garbage:
            os.write(fd, self._rng.integers(0, 256, self.garbage, dtype=np.uint8).tobytes())
        view = memoryview(data)
        while view:
            _, ready, _ = select.select([], [fd], [], 0.5)
            if ready:
                view = view[os.write(fd, view) :]
            elif self._stop.is_set():
                return

    def _serve(self, fd: int, stop: threading.Event) -> None:
        parser = FrameParser()
        while not stop.is_set():
            try:
                ready, _, _ = select.select([fd], [], [], 0.05)
                if not ready:
                    continue
                data = os.read(fd, 65536)
            except OSError:
                return
            for f in parser.feed(data):
                if self.silent:
                    continue
                try:
                    if f.type == FrameType.INFO_REQUEST:
                        self._write(fd, encode_frame(FrameType.INFO, f.seq, encode_info(self.info)))
                    elif f.type == FrameType.TRIGGER:
                        self.triggers += 1
                        frame, slot = decode_trigger(f.payload)
                        if self.delay and stop.wait(self.delay):
                            return
                        out = bytearray(
                            encode_frame(
                                FrameType.IR, f.seq, encode_ir(frame, self.source(frame, slot))
                            )
                        )
                        if self.corrupt_every and self.triggers % self.corrupt_every == 0:
                            out[-1] ^= 0xFF
                        self._write(fd, bytes(out))
                        self.answered += 1
                except (OSError, FrameError):
                    continue
