"""Radar parameters and sensor geometry shared by the node DSP chain.

Conventions follow ``docs/interfaces.md``: sample ``k`` of an impulse response lies at
time ``t0 + k / fs`` after the emission, and its *range* is the bistatic path length
Tx -> object -> Rx, ``r = c * (t0 + k / fs)``. World frame x east, y north, yaw
counter-clockwise from world x.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

SPEED_OF_LIGHT = 299792458.0
"""Propagation speed c in m/s (PROTOCOL.md)."""

FloatArray = npt.NDArray[np.float64]


#: Pulse widths at either end of an impulse response's window in which no echo is measured
#: (:meth:`RadarParams.measurable`). 0 (off) by default: one pulse width removes the false
#: bearings of echoes cut at a cropped window's start, but on the outside proxy recordings the
#: tracker then lost more people near the sensors than it gained (docs/blind_zone.md).
WINDOW_GUARD = 0.0


@dataclass(frozen=True, slots=True, kw_only=True)
class RadarParams:
    """Sampling and band of one radar, as published in ``node_info.radar``.

    Parameters
    ----------
    fs : float
        Equivalent sample rate in Hz (7e9 for the M-sequence radar).
    n : int
        Samples per impulse response.
    t0 : float
        Time of sample 0 after the transmitter's emission, s.
    f_low, f_high : float
        Band edges in Hz (0 and 3.5e9 for the baseband M-sequence radar).
    fc : float
        Carrier in Hz of complex-baseband impulse responses, 0 for real ones.
    rate : float
        Impulse responses per second of one link (``node_info.radar.rate``), Hz; 0 unknown.
    """

    fs: float
    n: int
    t0: float
    f_low: float
    f_high: float
    fc: float = 0.0
    rate: float = 0.0

    def __post_init__(self) -> None:
        if not (self.fs > 0 and self.n > 0 and self.f_high > self.f_low >= 0):
            raise ValueError(
                f"invalid radar parameters fs={self.fs} n={self.n} "
                f"band=[{self.f_low}, {self.f_high}]"
            )

    @property
    def bandwidth(self) -> float:
        """Occupied bandwidth ``f_high - f_low`` in Hz."""
        return self.f_high - self.f_low

    @property
    def range_step(self) -> float:
        """Range spacing of two samples, ``c / fs`` in m (4.28 cm at 7 GHz)."""
        return SPEED_OF_LIGHT / self.fs

    @property
    def pulse_range_width(self) -> float:
        """Range extent of one band-limited pulse, ``c / bandwidth`` in m (8.6 cm at 3.5 GHz)."""
        return SPEED_OF_LIGHT / self.bandwidth

    def measurable(self, guard: float = WINDOW_GUARD) -> tuple[float, float]:
        """Shortest and longest bistatic range (m) whose echo lies whole in the window.

        ``guard`` pulse widths (:attr:`pulse_range_width`) in from each end of the window
        :math:`[c t_0, c (t_0 + (n - 1) / f_s)]`: an echo nearer the window's edge is cut,
        and its range estimate sticks to the edge. The node searches only this interval
        (``NodeDspConfig.window_guard``) and the fusion centre takes the sensor as blind
        outside it.
        """
        edge = guard * self.pulse_range_width
        start = SPEED_OF_LIGHT * self.t0
        end = SPEED_OF_LIGHT * (self.t0 + (self.n - 1) / self.fs)
        return start + edge, end - edge

    def ranges(self) -> FloatArray:
        """Range axis of the impulse response.

        Returns
        -------
        ndarray, float64, shape (n,)
            Bistatic range of each sample in m, :math:`r_k = c (t_0 + k / f_s)`.
        """
        return SPEED_OF_LIGHT * (self.t0 + np.arange(self.n, dtype=np.float64) / self.fs)

    def index_of_range(self, r: float) -> float:
        """Fractional sample index of range ``r`` (m), inverse of :meth:`ranges`."""
        return (r / SPEED_OF_LIGHT - self.t0) * self.fs


def _yaw_rotation(yaw: float) -> FloatArray:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


@dataclass(frozen=True, slots=True, kw_only=True, eq=False)
class SensorGeometry:
    """Antenna positions of one node in the world frame.

    Parameters
    ----------
    tx : ndarray, float64, shape (3,)
        Transmitter position, world frame, m.
    rx : ndarray, float64, shape (n_rx, 3)
        Receiver positions, world frame, m, one row per impulse-response row.
    rx_names : tuple of str
        Antenna names, one per receiver row.
    boresight : float
        World yaw of the antennas' main beam, rad.
    beamwidth : float
        Full 3 dB beamwidth, rad; ``2*pi`` for omnidirectional antennas.
    """

    tx: FloatArray
    rx: FloatArray
    rx_names: tuple[str, ...] = field(default=())
    boresight: float = 0.0
    beamwidth: float = 2.0 * np.pi
    _centre: FloatArray = field(init=False, repr=False)
    _boresight_dir: tuple[float, float] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        tx = np.asarray(self.tx, dtype=np.float64).reshape(3)
        rx = np.asarray(self.rx, dtype=np.float64)
        if rx.ndim != 2 or rx.shape[1] != 3 or rx.shape[0] < 1:
            raise ValueError(f"rx must have shape (n_rx, 3), got {rx.shape}")
        names = tuple(self.rx_names) or tuple(f"rx{i + 1}" for i in range(rx.shape[0]))
        if len(names) != rx.shape[0]:
            raise ValueError(f"{len(names)} rx_names for {rx.shape[0]} receivers")
        tx.flags.writeable = False
        rx.flags.writeable = False
        # frozen dataclass: bypass the frozen __setattr__ once, to normalise the inputs
        object.__setattr__(self, "tx", tx)
        object.__setattr__(self, "rx", rx)
        object.__setattr__(self, "rx_names", names)
        # derived once: the field-of-view test runs per impulse response
        centre = np.vstack([tx[None, :2], rx[:, :2]]).mean(axis=0)
        centre.flags.writeable = False
        object.__setattr__(self, "_centre", centre)
        direction = (float(np.cos(self.boresight)), float(np.sin(self.boresight)))
        object.__setattr__(self, "_boresight_dir", direction)

    @classmethod
    def from_pose(
        cls,
        pose: npt.ArrayLike,
        *,
        tx: npt.ArrayLike,
        rx: npt.ArrayLike,
        rx_names: tuple[str, ...] = (),
        boresight: float = 0.0,
        beamwidth: float = 2.0 * np.pi,
    ) -> SensorGeometry:
        """Build the world geometry from antenna positions in the node frame.

        Parameters
        ----------
        pose : array_like, shape (4,)
            Node pose ``[x, y, z, yaw]`` in the world frame (m, rad).
        tx : array_like, shape (3,)
            Transmitter in the node frame (x forward, y left, z up), m.
        rx : array_like, shape (n_rx, 3)
            Receivers in the node frame, m.
        boresight : float
            Beam yaw in the node frame, rad (0 = forward).
        beamwidth : float
            Full beamwidth, rad.
        """
        x, y, z, yaw = np.asarray(pose, dtype=np.float64).reshape(4)
        rot = _yaw_rotation(yaw)
        offset = np.array([x, y, z])
        return cls(
            tx=rot @ np.asarray(tx, dtype=np.float64).reshape(3) + offset,
            rx=np.asarray(rx, dtype=np.float64).reshape(-1, 3) @ rot.T + offset,
            rx_names=rx_names,
            boresight=float(yaw + boresight),
            beamwidth=float(beamwidth),
        )

    @property
    def n_rx(self) -> int:
        """Number of receivers."""
        return int(self.rx.shape[0])

    @property
    def centre(self) -> FloatArray:
        """Array centre in world x, y (m), mean of all antenna positions, shape (2,)."""
        return self._centre

    def direct_ranges(self) -> FloatArray:
        """Direct-path (coupling) range Tx -> Rx of each receiver, m, shape (n_rx,)."""
        return np.linalg.norm(self.rx - self.tx, axis=1)

    def in_field_of_view(self, points: npt.ArrayLike, margin: float = 0.0) -> npt.NDArray[np.bool_]:
        """Whether world points lie inside the antennas' beam, seen from the array centre.

        Parameters
        ----------
        points : array_like, float64, shape (k, 2)
            World x, y, m.
        margin : float
            Angle added to the half beamwidth, rad.

        Returns
        -------
        ndarray, bool, shape (k,)
            ``|wrap(atan2(p - centre) - boresight)| <= beamwidth / 2 + margin``;
            all True for omnidirectional antennas.
        """
        p = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        half = 0.5 * self.beamwidth + margin
        if half >= np.pi:
            return np.ones(p.shape[0], dtype=bool)
        d = p - self._centre
        # cos(bearing - boresight) >= cos(half): dot products instead of angles
        c, s = self._boresight_dir
        along = d[:, 0] * c + d[:, 1] * s
        return along >= np.sqrt(d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1]) * np.cos(half)
