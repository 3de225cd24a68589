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


def multipath_delay_bound(
    delays: FloatArray,
    amplitudes: npt.NDArray,
    *,
    noise_sigma: float,
    fs: float,
    n: int,
    first_index: float,
    pulse_sigma: float,
    offset_frequency: float = 0.0,
    real_output: bool = True,
    neighbourhood: float = 1e-9,
) -> tuple[float, float]:
    """Delay bounds of the first path (s) without and with the paths that overlap it.

    Beyond the chapter, after Shen and Win ("Fundamental limits of wideband localization -
    Part I", IEEE Trans. Inf. Theory 56(10), 2010): the *equivalent Fisher information*
    (EFI) of the first path's delay :math:`\\tau_0` when the other paths' delays and
    amplitudes are unknown too (nuisance parameters),

    .. math::

        J_e(\\tau_0) = J_{\\tau_0 \\tau_0} - J_{\\tau_0 \\psi} J_{\\psi \\psi}^{+}
        J_{\\psi \\tau_0}, \\qquad J = D^T D / \\sigma^2,

    with :math:`D` the Jacobian of the noise-free samples with respect to all parameters
    (:math:`\\psi`: the first path's amplitude and every other path within
    ``neighbourhood`` of it: farther paths do not overlap the pulse and leave :math:`J_e`
    unchanged) and white noise of :math:`\\sigma` per sample and component. The bound is
    :math:`J_e^{-1/2}`; where a path nearly coincides with the first one it grows without
    limit (the two are not separable by any unbiased estimator), and it equals the
    single-path bound (the first path's amplitude the only nuisance) when nothing overlaps.

    The model is that of :func:`sim_nodes.channel.stochastic.render`: every path a copy of
    the Gaussian-envelope pulse ``exp(-t^2 / (2 pulse_sigma^2)) exp(2j pi f_off t)``
    delayed by its delay and scaled by its complex amplitude (the real part of it for a
    real radar).

    Parameters
    ----------
    delays : ndarray, shape (P,)
        Path delays, s; the first entry is the first (direct) path.
    amplitudes : ndarray, complex, shape (P,)
    noise_sigma : float
        Noise standard deviation per sample (and per component for complex samples).
    fs : float
        Sample rate, Hz.
    n : int
        Samples in the window.
    first_index : float
        Fractional sample index of delay ``delays[0]``.
    pulse_sigma : float
        Envelope sigma of the pulse, s.
    offset_frequency : float
        ``f_off``: the band centre for a real passband radar, the centre minus the carrier
        for complex baseband, 0 for a real baseband radar, Hz.
    real_output : bool
        Whether the samples are real (the real part of the complex model).
    neighbourhood : float
        Paths within this delay of the first one are nuisance parameters, s.

    Returns
    -------
    single, multipath : float
        :math:`\\sqrt{1 / J}` with only the first path's amplitude unknown, and with the
        overlapping paths unknown too, s (inf where the information vanishes).
    """
    d = np.asarray(delays, float)
    a = np.asarray(amplitudes, complex)
    t = (np.arange(n) - first_index) / fs + d[0]
    near = np.flatnonzero(np.abs(d - d[0]) <= neighbourhood)  # includes the first path
    cols = []
    for k in near:
        dt = t - d[k]
        q = np.exp(-0.5 * (dt / pulse_sigma) ** 2 + 2j * math.pi * offset_frequency * dt)
        dq = q * (-dt / pulse_sigma**2 + 2j * math.pi * offset_frequency)
        cols += [-a[k] * dq, q, 1j * q]  # d/dtau, d/dRe a, d/dIm a
    jac = np.stack(cols, axis=1)
    jac = jac.real if real_output else np.concatenate([jac.real, jac.imag])
    # unit columns: the delay and amplitude columns differ by orders of magnitude, and the
    # pseudo-inverse's cut-off is relative (a vanishing column, such as the imaginary
    # amplitude of a real baseband pulse, stays zero and drops out)
    scale = np.linalg.norm(jac, axis=0)
    scale[scale == 0.0] = 1.0
    fisher = (jac / scale).T @ (jac / scale) / noise_sigma**2

    def efi(idx: list[int]) -> float:
        rest = fisher[np.ix_(idx, idx)]
        cross = fisher[0, idx]
        return (
            float(fisher[0, 0] - cross @ np.linalg.pinv(rest, rcond=1e-9) @ cross) * scale[0] ** 2
        )

    single = efi([1, 2])
    multi = efi(list(range(1, len(cols))))

    def bound(j: float) -> float:
        return 1.0 / math.sqrt(j) if j > 0.0 else math.inf

    return bound(single), bound(multi)
