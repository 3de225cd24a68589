"""Antenna amplitude patterns for the hybrid channel: omni, horn, measured table (pure numpy).

A pattern maps a direction in the antenna frame (azimuth ``az`` from boresight, counter-
clockwise, and elevation ``el`` above the horizontal, rad) and a frequency (Hz) to a real
amplitude factor ``F`` (1 on boresight, ``|F|^2`` is the gain relative to boresight). The
ray tracer applies it per ray at both ends: ``F_tx`` at the angle of departure and ``F_rx``
at the angle of arrival. All antennas are vertically polarized (see
:mod:`sim_nodes.channel.raytrace`).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt


def direction_angles(
    vec: np.ndarray, yaw: npt.ArrayLike
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Azimuth (from boresight ``yaw``) and elevation of world vectors, rad.

    Parameters
    ----------
    vec : ndarray, shape (..., 3)
        World direction vectors (need not be unit).
    yaw : array_like
        World yaw of the boresight, rad, broadcast against ``vec[..., 0]``.

    Returns
    -------
    az, el : ndarray, float64; az wrapped to [-pi, pi)
    """
    az = np.arctan2(vec[..., 1], vec[..., 0]) - np.asarray(yaw, float)
    az = np.remainder(az + np.pi, 2 * np.pi) - np.pi
    el = np.arctan2(vec[..., 2], np.hypot(vec[..., 0], vec[..., 1]))
    return az, el


class AntennaPattern(ABC):
    """An amplitude pattern ``F(az, el, f)``."""

    @abstractmethod
    def amplitude(self, az: np.ndarray, el: np.ndarray, f: np.ndarray) -> np.ndarray:
        """Amplitude factor, shape ``broadcast(az, el, f)``.

        Parameters
        ----------
        az, el : ndarray, rad
            Direction in the antenna frame.
        f : ndarray, Hz
        """

    @property
    def frequency_dependent(self) -> bool:
        """Whether ``amplitude`` depends on ``f`` (the tracer then evaluates it per knot)."""
        return False


@dataclass(frozen=True, slots=True)
class OmniPattern(AntennaPattern):
    """Isotropic amplitude pattern, ``F = 1``."""

    def amplitude(self, az: np.ndarray, el: np.ndarray, f: np.ndarray) -> np.ndarray:
        return np.ones(np.broadcast_shapes(np.shape(az), np.shape(el), np.shape(f)))


@dataclass(frozen=True, slots=True)
class HornPattern(AntennaPattern):
    """Horn: Gaussian main beam in azimuth and elevation, clipped at a back-lobe floor.

    .. math:: G_{dB} = \\max(-3 [(2 az / \\theta_3(f))^2 + (2 el / \\theta_3(f))^2], G_{floor}),
              \\quad \\theta_3(f) = \\theta_3(f_0) f_0 / f

    The 3 dB beam width of an aperture antenna scales with the wavelength, hence
    ``theta_3 ~ 1/f`` around ``f_0`` (set ``f0 = 0`` for a frequency-independent beam).

    Attributes
    ----------
    beamwidth : float
        3 dB beam width at ``f0``, rad (default 60 degrees).
    f0 : float
        Reference frequency of ``beamwidth``, Hz (default 9 GHz); 0: no scaling.
    floor_db : float
        Back-lobe level, dB.
    """

    beamwidth: float = np.deg2rad(60.0)
    f0: float = 9e9
    floor_db: float = -25.0

    @property
    def frequency_dependent(self) -> bool:
        return self.f0 > 0

    def amplitude(self, az: np.ndarray, el: np.ndarray, f: np.ndarray) -> np.ndarray:
        bw = self.beamwidth * (self.f0 / np.asarray(f, float) if self.f0 > 0 else 1.0)
        g_db = np.maximum(-3.0 * ((2 * az / bw) ** 2 + (2 * el / bw) ** 2), self.floor_db)
        return np.exp(g_db * (np.log(10) / 20))


@dataclass(frozen=True, slots=True)
class TablePattern(AntennaPattern):
    """Measured pattern: gain in dB on an azimuth x elevation grid, bilinear interpolation.

    Azimuth wraps (the grid must span less than 360 degrees without repeating +-180);
    elevation is clamped to the grid. Frequency-independent (one table per antenna).

    Attributes
    ----------
    az : ndarray, float64, shape (A,)
        Increasing azimuths in [-pi, pi), rad.
    el : ndarray, float64, shape (E,)
        Increasing elevations, rad.
    gain_db : ndarray, float64, shape (E, A)
        Gain relative to boresight, dB.
    """

    az: npt.NDArray[np.float64]
    el: npt.NDArray[np.float64]
    gain_db: npt.NDArray[np.float64]

    def amplitude(self, az: np.ndarray, el: np.ndarray, f: np.ndarray) -> np.ndarray:
        shape = np.broadcast_shapes(np.shape(az), np.shape(el), np.shape(f))
        a = np.broadcast_to(np.remainder(np.asarray(az) + np.pi, 2 * np.pi) - np.pi, shape)
        e = np.broadcast_to(np.clip(el, self.el[0], self.el[-1]), shape)
        # Periodic azimuth grid: append the first column at +2 pi.
        az_g = np.concatenate([self.az, self.az[:1] + 2 * np.pi])
        g = np.concatenate([self.gain_db, self.gain_db[:, :1]], axis=1)
        a = np.where(a < az_g[0], a + 2 * np.pi, a)
        i = np.clip(np.searchsorted(az_g, a, side="right") - 1, 0, az_g.size - 2)
        j = np.clip(np.searchsorted(self.el, e, side="right") - 1, 0, max(self.el.size - 2, 0))
        ta = (a - az_g[i]) / (az_g[i + 1] - az_g[i])
        if self.el.size > 1:
            te = (e - self.el[j]) / (self.el[j + 1] - self.el[j])
            j1 = j + 1
        else:
            te, j1 = np.zeros(shape), j
        g_db = (1 - te) * ((1 - ta) * g[j, i] + ta * g[j, i + 1]) + te * (
            (1 - ta) * g[j1, i] + ta * g[j1, i + 1]
        )
        return np.exp(g_db * (np.log(10) / 20))
