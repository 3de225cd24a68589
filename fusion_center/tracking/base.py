"""Data types and the ``Tracker`` role of the fusion center's multi-target tracking.

Pure numpy: no I/O, no clocks; time ``t`` (seconds, network time) is always an argument.

State order everywhere is ``[x, vx, y, vy]`` (world frame, metres and metres per second).
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

__all__ = [
    "SensorScan",
    "TrackEstimate",
    "Tracker",
    "TrackerOutput",
    "constant_velocity_model",
    "in_field_of_view",
]

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True, slots=True, kw_only=True, eq=False)
class SensorScan:
    """Local position estimates one bat-type node extracted from one acquisition.

    Parameters
    ----------
    sensor : str
        Node id of the reporting sensor.
    t : float
        Acquisition time, s (network time).
    positions : ndarray, float64, shape (k, 2)
        Local target position estimates (bistatic ellipse intersection), world x, y, m.
    cov : ndarray, float64, shape (k, 2, 2)
        Covariance of each position estimate, m².
    origin : ndarray, float64, shape (2,)
        Sensor array centre, world x, y, m.
    boresight : float
        Boresight yaw in the world frame, rad.
    beamwidth : float
        Full opening angle of the field of view, rad (``2*pi`` for an omni sensor).
    max_range : float
        Maximum distance from ``origin`` at which the sensor detects a person, m.
    min_range : float
        Distance from ``origin`` within which the sensor detects no one, m: its blind zone
        (a radar window that starts after the emission, ``t0 > 0``).
    """

    sensor: str
    t: float
    positions: FloatArray
    cov: FloatArray
    origin: FloatArray
    boresight: float = 0.0
    beamwidth: float = 2.0 * math.pi
    max_range: float = math.inf
    min_range: float = 0.0

    def __post_init__(self) -> None:
        positions = np.asarray(self.positions, dtype=np.float64).reshape(-1, 2)
        cov = np.asarray(self.cov, dtype=np.float64).reshape(-1, 2, 2)
        origin = np.asarray(self.origin, dtype=np.float64).reshape(2)
        if cov.shape[0] != positions.shape[0]:
            raise ValueError(f"cov has {cov.shape[0]} matrices for {positions.shape[0]} positions")
        object.__setattr__(self, "positions", positions)
        object.__setattr__(self, "cov", cov)
        object.__setattr__(self, "origin", origin)


@dataclass(frozen=True, slots=True, kw_only=True, eq=False)
class TrackEstimate:
    """One labelled target estimate.

    Parameters
    ----------
    id : int
        Track label, stable for a person while tracked.
    x, vx, y, vy : float
        Position (m) and velocity (m/s), world frame.
    cov : ndarray, float64, shape (4, 4)
        State covariance, order ``x, vx, y, vy``.
    w : float
        Weight (GM-PHD: summed component weight of the label) or existence score.
    """

    id: int
    x: float
    vx: float
    y: float
    vy: float
    cov: FloatArray = field(default_factory=lambda: np.eye(4))
    w: float = 1.0


@dataclass(frozen=True, slots=True, kw_only=True, eq=False)
class TrackerOutput:
    """The multi-target estimate at time ``t``.

    Parameters
    ----------
    t : float
        Estimate time, s.
    tracks : tuple of TrackEstimate
        Confirmed tracks, sorted by id.
    n_estimate : float
        Expected number of targets (GM-PHD: total mixture weight).
    acquired : tuple of float
        Acquisition times (s, network time) of the scans this update used; filled in by the
        frame assembly (:class:`fusion_center.core.FusionCore`), empty from a bare tracker.
        End-to-end latency is measured from them.
    """

    t: float
    tracks: tuple[TrackEstimate, ...]
    n_estimate: float
    acquired: tuple[float, ...] = ()

    def ids(self) -> npt.NDArray[np.int64]:
        """Track ids, shape (n,)."""
        return np.array([tr.id for tr in self.tracks], dtype=np.int64)

    def positions(self) -> FloatArray:
        """Track positions, shape (n, 2), world x, y, m."""
        return np.array([(tr.x, tr.y) for tr in self.tracks], dtype=np.float64).reshape(-1, 2)


class Tracker(ABC):
    """A multi-target tracker fed with the sensors' scans of one TDMA frame per step."""

    @abstractmethod
    def step(self, t: float, scans: Sequence[SensorScan]) -> TrackerOutput:
        """Advance to time ``t`` using ``scans`` (each at its own ``scan.t <= t``).

        Parameters
        ----------
        t : float
            Output time, s; non-decreasing between calls.
        scans : sequence of SensorScan
            Scans acquired since the previous step (may be empty).

        Returns
        -------
        TrackerOutput
        """

    @abstractmethod
    def reset(self) -> None:
        """Forget all targets and labels."""


def constant_velocity_model(dt: float, accel_psd: float) -> tuple[FloatArray, FloatArray]:
    """Transition and process-noise matrices of the 2-D constant-velocity model.

    Continuous white-acceleration noise of power spectral density ``q`` on each axis
    (Bar-Shalom, Li & Kirubarajan 2001, Sec. 6.2.2):

    .. math::

        F = \\begin{bmatrix} 1 & \\Delta t \\\\ 0 & 1 \\end{bmatrix}^{\\oplus 2},\\qquad
        Q = q \\begin{bmatrix} \\Delta t^3/3 & \\Delta t^2/2 \\\\
        \\Delta t^2/2 & \\Delta t \\end{bmatrix}^{\\oplus 2}

    Parameters
    ----------
    dt : float
        Time step, s.
    accel_psd : float
        ``q``, m²/s³.

    Returns
    -------
    F, Q : ndarray, float64, shape (4, 4)
        State order ``x, vx, y, vy``.
    """
    f1 = np.array([[1.0, dt], [0.0, 1.0]])
    q1 = accel_psd * np.array([[dt**3 / 3.0, dt**2 / 2.0], [dt**2 / 2.0, dt]])
    F = np.zeros((4, 4))
    Q = np.zeros((4, 4))
    F[:2, :2] = F[2:, 2:] = f1
    Q[:2, :2] = Q[2:, 2:] = q1
    return F, Q


def in_field_of_view(
    scan: SensorScan, xy: FloatArray, margin: float = 0.0
) -> npt.NDArray[np.bool_]:
    """Whether points lie inside a sensor's field of view and range.

    Parameters
    ----------
    scan : SensorScan
        Provides ``origin``, ``boresight``, ``beamwidth``, ``max_range`` and ``min_range``.
    xy : ndarray, float64, shape (n, 2)
        World positions, m.
    margin : float
        Widen the field of view by this distance, m, at the range limit and at the sector
        edges (a point within ``margin`` of the sector counts as inside).

    Returns
    -------
    ndarray, bool, shape (n,)
        ``min_range <= |p - o| <= max_range + margin`` and
        ``|wrap(atan2(p - o) - boresight)| <= beamwidth / 2 + asin(min(1, margin / |p - o|))``.
    """
    d = xy - scan.origin
    r2 = np.einsum("ij,ij->i", d, d)
    inside = r2 <= (scan.max_range + margin) ** 2
    if scan.min_range > 0.0:  # the blind zone: no margin, a point near it may be unseen
        inside &= r2 >= scan.min_range**2
    if scan.beamwidth < 2.0 * math.pi:
        bearing = np.arctan2(d[:, 1], d[:, 0]) - scan.boresight
        off = np.abs((bearing + math.pi) % (2.0 * math.pi) - math.pi)
        half = 0.5 * scan.beamwidth
        if margin > 0.0:
            with np.errstate(divide="ignore"):
                half = half + np.arcsin(np.minimum(1.0, margin / np.sqrt(r2)))
        inside &= off <= half
    return inside
