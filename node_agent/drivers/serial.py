"""A radar driver for an M-sequence radar on a serial/USB link (pyserial), driver name ``serial``.

The wire format is :mod:`node_agent.drivers.serial_frames` (``docs/serial-protocol.md``). Per
acquisition the driver sends a TRIGGER carrying a fresh sequence number and waits up to
``timeout`` s for the IR frame that echoes it; IR frames of older triggers (a device that
answered late) are discarded and counted. A port that fails (unplugged adapter, EIO) is
closed and reopened at the next acquisition, at most once per ``reopen_period`` s: the node
agent keeps running and resumes when the device is back.
"""

from __future__ import annotations

import logging
import time
from typing import Any

import serial

from node_agent.drivers.base import Acquisition, DriverError, RadarDriver
from node_agent.drivers.serial_frames import (
    DeviceInfo,
    FrameError,
    FrameParser,
    FrameType,
    decode_info,
    decode_ir,
    encode_frame,
    encode_trigger,
)
from node_agent.tdma import SlotTiming
from protocol import Antenna, RadarInfo

log = logging.getLogger(__name__)

#: Bat-type geometry (one transmitter, two receivers 0.5 m either side), node frame, m.
DEFAULT_ANTENNAS: dict[str, dict[str, Any]] = {
    "tx": {"pos": [0.0, 0.0, 0.0], "tx": True, "rx": False, "boresight": 0.0, "beamwidth": 1.75},
    "rx1": {"pos": [0.0, 0.5, 0.0], "tx": False, "rx": True, "boresight": 0.0, "beamwidth": 1.75},
    "rx2": {"pos": [0.0, -0.5, 0.0], "tx": False, "rx": True, "boresight": 0.0, "beamwidth": 1.75},
}


class SerialDriver(RadarDriver):
    """Acquires impulse responses from a radar on ``port``.

    Parameters
    ----------
    port : device path (``/dev/ttyUSB0``, a pty) or pyserial URL (``loop://``, ``socket://``).
    node : node id, for the ``tx`` name ``"{node}/tx"`` of acquisitions.
    role, pose : the ``node_info`` role and world pose [x, y, z, yaw] (m, rad).
    antennas : name -> {pos, tx, rx, boresight, beamwidth} in the node frame; the receivers,
        in name order, are the device's IR rows. Default: bat-type.
    baudrate : line rate, bit/s (ignored by USB CDC devices and ptys).
    timeout : s to wait for the device's answer (INFO at open, each IR).
    reopen_period : s between attempts to reopen a failed port.
    """

    def __init__(
        self,
        port: str,
        *,
        node: str = "serial",
        role: str = "bat",
        pose: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0),
        antennas: dict[str, dict[str, Any]] | None = None,
        baudrate: int = 3_000_000,
        timeout: float = 0.2,
        reopen_period: float = 1.0,
    ) -> None:
        self.port, self.node, self.role, self.pose = port, node, role, tuple(pose)
        self.baudrate, self.reopen_period = baudrate, reopen_period
        self.antennas = {k: dict(v) for k, v in (antennas or DEFAULT_ANTENNAS).items()}
        self.rx_names = tuple(sorted(n for n, a in self.antennas.items() if a["rx"]))
        tx = [n for n, a in self.antennas.items() if a["tx"]]
        self.tx_name = f"{node}/{tx[0]}" if tx else f"{node}/tx"
        self._serial: Any = None
        self._last_open = -float("inf")
        self._seq = 0
        self.parser = FrameParser()
        self.stale = 0
        self.reopened = 0
        self._timeout = timeout
        self._open()
        self.info = self._request_info()
        if self.info.n_rx != len(self.rx_names):
            self._close_port()
            raise DriverError(
                f"{port}: device has {self.info.n_rx} receivers, config names {len(self.rx_names)}"
            )
        # The longest frame we accept is one IR: a garbage length field beyond it is rejected.
        self.parser.max_payload = 10 + 4 * self.info.n_rx * self.info.n
        super().__init__(n_rx=self.info.n_rx, n=self.info.n, timeout=timeout)

    # -- port ------------------------------------------------------------------------------

    def _open(self) -> None:
        self._last_open = time.monotonic()
        try:
            self._serial = serial.serial_for_url(
                self.port, baudrate=self.baudrate, timeout=0.02, write_timeout=self._timeout
            )
        except (serial.SerialException, OSError, ValueError) as exc:
            self._serial = None
            raise DriverError(f"{self.port}: cannot open: {_first_line(exc)}") from None
        self.parser = FrameParser(self.parser.max_payload)

    def _close_port(self) -> None:
        if self._serial is not None:
            try:
                self._serial.close()
            except (serial.SerialException, OSError):
                pass
            self._serial = None

    def _io_failed(self, exc: BaseException) -> DriverError:
        self._close_port()
        return DriverError(f"{self.port}: device gone: {_first_line(exc)}")

    def _ensure_open(self) -> None:
        if self._serial is not None:
            return
        if time.monotonic() - self._last_open < self.reopen_period:
            raise DriverError(f"{self.port}: device gone; reopening later")
        self._open()
        self.reopened += 1
        log.info("%s: reopened", self.port)

    def _send(self, frame_type: FrameType, payload: bytes = b"") -> int:
        self._seq = (self._seq + 1) & 0xFFFF
        try:
            self._serial.write(encode_frame(frame_type, self._seq, payload))
        except (serial.SerialException, OSError) as exc:
            raise self._io_failed(exc) from None
        return self._seq

    def _wait_for(self, frame_type: FrameType, seq: int) -> bytes:
        """Payload of the next frame of ``frame_type`` echoing ``seq``, within the timeout."""
        deadline = time.monotonic() + self._timeout
        while time.monotonic() < deadline:
            try:
                data = self._serial.read(max(self._serial.in_waiting, 1))
            except (serial.SerialException, OSError) as exc:
                raise self._io_failed(exc) from None
            for f in self.parser.feed(data):
                if f.type == frame_type and f.seq == seq:
                    return f.payload
                self.stale += 1
        raise DriverError(f"{self.port}: no {frame_type.name} within {self._timeout} s")

    def _request_info(self) -> DeviceInfo:
        seq = self._send(FrameType.INFO_REQUEST)
        try:
            return decode_info(self._wait_for(FrameType.INFO, seq))
        except (DriverError, FrameError) as exc:
            self._close_port()
            raise DriverError(f"{self.port}: no valid device description: {exc}") from None

    # -- RadarDriver -----------------------------------------------------------------------

    def describe(self) -> dict[str, Any]:
        i = self.info
        return {
            "role": self.role,
            "pose": tuple(float(v) for v in self.pose),
            "mobile": False,
            "antennas": {name: Antenna(**a) for name, a in self.antennas.items()},
            "radar": RadarInfo(
                fs=i.fs, n=i.n, t0=i.t0, f_low=i.f_low, f_high=i.f_high, rate=i.rate
            ),
        }

    def _acquire_internal(self, slot: SlotTiming) -> Acquisition:
        self._ensure_open()
        seq = self._send(FrameType.TRIGGER, encode_trigger(slot.frame, slot.slot))
        payload = self._wait_for(FrameType.IR, seq)
        try:
            _frame, h = decode_ir(payload)
        except FrameError as exc:
            raise DriverError(f"{self.port}: {exc}") from None
        return Acquisition(t=slot.t, tx=self.tx_name, rx=self.rx_names, h=h)

    def _close_internal(self) -> None:
        self._close_port()


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__
