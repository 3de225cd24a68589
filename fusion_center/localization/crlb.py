"""Cramér-Rao bounds of ranging and of the position fix (Section 4 of the CoLOR chapter).

Pure numpy. The range bound of a pulse of RMS bandwidth :math:`\\beta` received with energy
to noise density :math:`E/N_0`,

.. math:: \\sigma_r \\ge \\frac{c}{2 \\pi \\beta \\sqrt{2 E / N_0}},

is propagated through the geometry by the Fisher information of the ranges,
:math:`F = \\sum_i u_i u_i^T / \\sigma_i^2` (:math:`u_i` the unit vector from anchor i to the
node), giving the position error bound :math:`\\mathrm{PEB} = \\sqrt{\\mathrm{tr} F^{-1}}`.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from protocol.units import C

FloatArray = npt.NDArray[np.float64]


def rms_bandwidth(f_low: float, f_high: float) -> float:
    """RMS bandwidth (Hz) of a flat spectrum over [f_low, f_high] about its centre: the
    envelope's bandwidth, :math:`B / \\sqrt{12}` (a first-path detector on the envelope does not
    use the carrier phase)."""
    return (f_high - f_low) / math.sqrt(12.0)


def range_crlb(snr_db: float | FloatArray, bandwidth: float) -> FloatArray:
    """Lower bound on the standard deviation of a one-way range, m.

    Parameters
    ----------
    snr_db : float or ndarray
        :math:`E/N_0` of the received pulse, dB.
    bandwidth : float
        RMS bandwidth :math:`\\beta`, Hz (:func:`rms_bandwidth`).
    """
    snr = 10.0 ** (np.asarray(snr_db, float) / 10.0)
    return C / (2.0 * math.pi * bandwidth * np.sqrt(2.0 * snr))


def roundtrip_range_crlb(snr_db: float | FloatArray, bandwidth: float) -> FloatArray:
    """Bound of a round-trip (RTToA) range, m: the mean of two independent one-way
    estimates (the two receptions), i.e. :func:`range_crlb` over :math:`\\sqrt 2`."""
    return range_crlb(snr_db, bandwidth) / math.sqrt(2.0)


def position_crlb(
    position: FloatArray,
    anchors: FloatArray,
    std: FloatArray,
    height_difference: FloatArray | None = None,
) -> FloatArray:
    """Position covariance bound (2 x 2, m²) of an unbiased 2-D fix from ranges.

    Parameters
    ----------
    position : ndarray, shape (2,)
        True position, world x, y, m.
    anchors : ndarray, shape (k, 2)
    std : ndarray, shape (k,)
        Range standard deviation of each anchor, m (its CRLB for the bound).
    height_difference : ndarray, shape (k,), optional
        Known height of each anchor above the node, m: a 3-D range constrains the horizontal
        position only through the horizontal part of its direction.

    Returns
    -------
    ndarray, shape (2, 2)
        :math:`F^{-1}`; infinite where the geometry does not determine the position.
    """
    diff = np.asarray(position, float) - np.asarray(anchors, float)
    dz = np.zeros(diff.shape[0]) if height_difference is None else np.asarray(height_difference)
    dist = np.sqrt(np.sum(diff**2, axis=1) + dz**2)
    u = diff / np.maximum(dist, 1e-9)[:, None]
    fisher = (u / np.asarray(std, float)[:, None] ** 2).T @ u
    if np.linalg.cond(fisher) > 1e12:
        return np.diag([np.inf, np.inf])
    return np.linalg.solve(fisher, np.eye(2))


def position_error_bound(
    position: FloatArray,
    anchors: FloatArray,
    std: FloatArray,
    height_difference: FloatArray | None = None,
) -> float:
    """PEB :math:`\\sqrt{\\mathrm{tr} F^{-1}}`, m: the bound on the position RMSE."""
    return float(np.sqrt(np.trace(position_crlb(position, anchors, std, height_difference))))
