"""Channel parameters: path loss, mean delay, RMS delay spread, azimuth spread, angular PDP.

Pure numpy on transfer functions (``1/d``-scaled, from
:func:`sim_nodes.channel.synth.frequency_response`) and path lists. Delay parameters are
computed from the band-limited power delay profile ``P(tau) = |h(tau)|^2`` (Hann-windowed
inverse FFT of the transfer function), as from a measurement, so coherent sums of
unresolved scatterers count as they would in the radar.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from sim_nodes.channel.antenna import AntennaPattern
from sim_nodes.channel.raytrace import PathSet
from sim_nodes.channel.synth import frequency_response, friis_amplitude, impulse_response


def path_loss_db(h_f: np.ndarray, f: np.ndarray) -> npt.NDArray[np.float64]:
    """Band-averaged path loss, dB (positive), of transfer functions (..., K).

    .. math:: PL = -10 \\log_{10} \\frac{1}{K} \\sum_k |H(f_k)\\, c / (4 \\pi f_k)|^2

    (for a single free-space path of length d this is the Friis loss
    ``20 log10(4 pi d f / c)`` averaged in power over the band).
    """
    p = np.mean(np.abs(h_f * friis_amplitude(f)) ** 2, axis=-1)
    return -10 * np.log10(np.maximum(p, 1e-300))


def power_delay_profile(
    h_f: np.ndarray, df: float
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """``|h(tau)|^2`` and the delays, s, of transfer functions (..., K) with step ``df``."""
    h, tau = impulse_response(h_f, df)
    return np.abs(h.astype(np.complex128)) ** 2, tau


def delay_moments(
    pdp: np.ndarray, tau: np.ndarray, threshold_db: float = 30.0
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Mean delay and RMS delay spread of power delay profiles, s.

    .. math:: \\bar\\tau = \\frac{\\sum P \\tau}{\\sum P}, \\quad
              \\sigma_\\tau = \\sqrt{\\frac{\\sum P (\\tau - \\bar\\tau)^2}{\\sum P}}

    Samples more than ``threshold_db`` below each profile's peak are ignored (sidelobes and
    the numerical floor of the synthesis), as in measurement practice.

    Parameters
    ----------
    pdp : ndarray, shape (..., K)
    tau : ndarray, shape (K,), s
    """
    peak = pdp.max(axis=-1, keepdims=True)
    p = np.where(pdp >= peak * 10 ** (-threshold_db / 10), pdp, 0.0)
    total = np.maximum(p.sum(axis=-1), 1e-300)
    mean = (p * tau).sum(axis=-1) / total
    var = (p * (tau - mean[..., None]) ** 2).sum(axis=-1) / total
    return mean, np.sqrt(np.maximum(var, 0.0))


def azimuth_spread(paths: PathSet, n_rx: int, knot: int | None = None) -> npt.NDArray[np.float64]:
    """RMS azimuth spread of arrival per receiver, rad (power-weighted, circular).

    .. math:: \\sigma_\\phi = \\sqrt{\\frac{\\sum_i P_i\\, \\mathrm{wrap}(\\phi_i - \\bar\\phi)^2}
              {\\sum_i P_i}}, \\quad \\bar\\phi = \\arg \\sum_i P_i e^{j \\phi_i}

    with ``P_i = |a_i|^2`` at the middle amplitude knot (or ``knot``).
    """
    b = paths.knots.size // 2 if knot is None else knot
    power = np.abs(paths.amplitude[:, b]) ** 2
    phi = paths.aoa[:, 0]
    vec = np.zeros(n_rx, complex)
    np.add.at(vec, paths.rx, power * np.exp(1j * phi))
    mean = np.angle(vec)
    dev = np.remainder(phi - mean[paths.rx] + np.pi, 2 * np.pi) - np.pi
    num = np.bincount(paths.rx, weights=power * dev**2, minlength=n_rx)
    den = np.maximum(np.bincount(paths.rx, weights=power, minlength=n_rx), 1e-300)
    return np.sqrt(num / den)


def angular_pdp(
    paths: PathSet,
    receiver: int,
    headings: np.ndarray,
    pattern: AntennaPattern,
    f0: float,
    df: float,
    n_freq: int,
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Angle-dependent PDP of a directive antenna rotated at one receiver (Fig. 8/14 style).

    The paths must have been traced with an omnidirectional receiver; each heading weights
    them by ``pattern`` at their arrival azimuth relative to the heading, and
    ``|h(tau)|^2`` is computed per heading.

    Returns
    -------
    pdp : ndarray, float64, shape (H, K)
    tau : ndarray, float64, shape (K,), s
    """
    sel = paths.select(paths.rx == receiver)
    n_h = headings.size
    rel = sel.aoa[None, :, 0] - headings[:, None]  # (H, P)
    gain = pattern.amplitude(rel[..., None], sel.aoa[None, :, 1, None], sel.knots)  # (H, P, B)
    rot = PathSet(
        rx=np.repeat(np.arange(n_h), sel.count),
        delay=np.tile(sel.delay, n_h),
        amplitude=(sel.amplitude[None] * gain).reshape(n_h * sel.count, -1),
        knots=sel.knots,
        kind=np.tile(sel.kind, n_h),
        order=np.tile(sel.order, n_h),
        faces=np.tile(sel.faces, (n_h, 1)),
        aod=np.tile(sel.aod, (n_h, 1)),
        aoa=np.tile(sel.aoa, (n_h, 1)),
        n_transmissions=np.tile(sel.n_transmissions, n_h),
    )
    h_f = frequency_response(rot, n_h, f0, df, n_freq)
    return power_delay_profile(h_f, df)
