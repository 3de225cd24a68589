"""The radar driver interface: one ``acquire(slot)`` for simulated, serial and replayed radars.

Modelled on python-can's ``BusABC``: the public method lives in the base and owns counters,
timing and shape checks; back-ends implement ``_acquire_internal``.
"""

from __future__ import annotations

import abc
import dataclasses
import time
import warnings
from collections.abc import Sequence
from types import TracebackType
from typing import Any, Self

import numpy as np
import numpy.typing as npt

from node_agent.tdma import SlotTiming


class DriverError(RuntimeError):
    """A driver could not acquire (device gone, timeout, bad frame); one-line message."""


@dataclasses.dataclass(frozen=True, slots=True, kw_only=True)
class Acquisition:
    """One acquisition: impulse responses ``h`` (n_rx, n) of transmitter ``tx`` at receivers
    ``rx``, acquired at network time ``t`` (s); ``pose`` [x, y, z, yaw] for mobile nodes."""

    t: float
    tx: str
    rx: tuple[str, ...]
    h: npt.NDArray[Any]
    pose: tuple[float, float, float, float] | None = None


class RadarDriver(abc.ABC):
    """Base of all radar drivers. A context manager; :meth:`close` is idempotent.

    Parameters
    ----------
    n_rx, n : the impulse-response matrix shape every acquisition must have.
    timeout : an acquisition slower than this (s) counts as late.
    """

    def __init__(self, *, n_rx: int, n: int, timeout: float = 0.1) -> None:
        self.n_rx, self.n, self.timeout = n_rx, n, timeout
        self.acquired = 0
        self.errors = 0
        self.late = 0
        self._closed = False

    @abc.abstractmethod
    def describe(self) -> dict[str, Any]:
        """The ``node_info`` fields (role, pose, mobile, antennas, radar) of this radar."""

    @abc.abstractmethod
    def _acquire_internal(self, slot: SlotTiming) -> Acquisition:
        """Acquire one impulse-response matrix in ``slot`` (back-end specific)."""

    def acquire(self, slot: SlotTiming) -> Acquisition:
        """Acquire in ``slot``; checks shape and finiteness, counts acquisitions and errors.

        Raises
        ------
        DriverError
            On a closed driver or a malformed acquisition (counted in ``errors``).
        """
        if self._closed:
            raise DriverError("driver is closed")
        start = time.monotonic()
        try:
            acq = self._acquire_internal(slot)
        except DriverError:
            self.errors += 1
            raise
        if time.monotonic() - start > self.timeout:
            self.late += 1
        h = acq.h
        if h.shape != (self.n_rx, self.n):
            self.errors += 1
            raise DriverError(f"acquisition shape {h.shape} != ({self.n_rx}, {self.n})")
        if not np.isfinite(h).all():
            self.errors += 1
            raise DriverError("acquisition contains NaN or Inf")
        self.acquired += 1
        return acq

    @classmethod  # noqa: B027 - optional hook, empty by default
    def acquire_ahead(cls, batch: Sequence[tuple[RadarDriver, SlotTiming]]) -> None:
        """Prepare the acquisitions of ``batch`` (drivers of this class, their slots) in one
        go before they are acquired one by one with :meth:`acquire`; the default does
        nothing. A simulated driver computes them together (a
        :class:`node_agent.group.SlotOrderGroup` serving a batch of slots); a radar, which
        acquires in real time, keeps the default."""

    def close(self) -> None:
        """Release the device. Idempotent."""
        if not self._closed:
            self._closed = True
            self._close_internal()

    def _close_internal(self) -> None:  # noqa: B027 - optional hook, empty by default
        """Back-end specific release; default does nothing."""

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def __del__(self) -> None:
        if not getattr(self, "_closed", True):
            warnings.warn(f"{type(self).__name__} was never closed", ResourceWarning, stacklevel=1)
