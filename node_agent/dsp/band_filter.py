"""Matched filtering of impulse responses to the radar's declared band.

A radar whose sampling is wider than its band (an oversampled complex baseband, as
DW1000-class transceivers deliver, or a band-pass radar sampled well above twice its top
frequency) leaves noise outside the band that a detector need not see. Correlating with
the expected pulse is the matched filter: for white noise it maximises the peak
signal-to-noise ratio of an echo, by the pulse's effective width in samples,

.. math::

    G = \\frac{\\sum_k |s_k|^2}{\\max_k |s_k|^2}.

The pulse is not published in ``node_info``, only its band, so the model is the standard
UWB convention: a Gaussian spectrum centred on the band, 10 dB down at its edges (the
FCC's -10 dB bandwidth). This goes beyond the chapter, whose M-sequence radar delivers the
correlation (already matched) output at 7 GHz, where the filter changes nothing: it is
used only when ``G`` is worth it (``min_gain_db``).
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
from scipy.signal import oaconvolve

from .geometry import RadarParams

# exp(-f^2 / (2 sigma_f^2)) is 10 dB down in power (amplitude 10^(-1/2)) at f = EDGE * sigma_f
_EDGE = math.sqrt(math.log(10.0))


def pulse_sigma(radar: RadarParams, *, complex_input: bool) -> float:
    """Envelope sigma (s) of the band's model pulse (:func:`band_pulse`): a Gaussian
    spectrum 10 dB down at the band edges, :math:`\\sigma_t = \\sqrt{\\ln 10} / (2 \\pi
    B_{1/2})` with :math:`B_{1/2}` half the band (``f_high`` for a real baseband radar, a
    low-pass from 0 Hz)."""
    if complex_input or radar.f_low > 0.0:
        half_band = 0.5 * radar.bandwidth
    else:
        half_band = radar.f_high
    return _EDGE / (2.0 * math.pi * half_band)


def band_pulse(radar: RadarParams, *, complex_input: bool) -> npt.NDArray:
    """Model pulse of the band, sampled at ``radar.fs``, peak 1, truncated at 4 sigma.

    Gaussian envelope with :math:`\\sigma_t = 1 / (2 \\pi \\sigma_f)`, :math:`\\sigma_f`
    such that the spectrum is 10 dB down at the band edges, modulated to the band centre:
    ``cos(2 pi f0 t)`` for real impulse responses (``f0 = 0`` for a baseband radar whose
    band starts at 0 Hz: then the Gaussian low-pass spans ``[0, f_high]``), or
    ``exp(2j pi (f0 - fc) t)`` for complex baseband around the carrier ``fc``.

    Returns
    -------
    ndarray, float64 (real input) or complex128 (complex input), shape (2 K + 1,)
        The pulse at sample offsets ``-K..K``.
    """
    sigma_t = pulse_sigma(radar, complex_input=complex_input)
    f0 = 0.5 * (radar.f_low + radar.f_high) if complex_input or radar.f_low > 0.0 else 0.0
    k = math.ceil(4.0 * sigma_t * radar.fs)
    t = np.arange(-k, k + 1) / radar.fs
    env = np.exp(-0.5 * (t / sigma_t) ** 2)
    if complex_input:
        return env * np.exp(2j * math.pi * (f0 - radar.fc) * t)
    return env * np.cos(2.0 * math.pi * f0 * t)


def matched_gain(pulse: npt.NDArray) -> float:
    """Peak SNR gain of the matched filter for white noise, :math:`\\sum |s|^2 / \\max |s|^2`."""
    p = np.abs(pulse) ** 2
    return float(p.sum() / p.max())


class BandMatchedFilter:
    """Correlate each impulse response with the band's model pulse (unit-energy kernel).

    The kernel has unit energy, so white noise keeps its variance and an echo matching
    the pulse gains :func:`matched_gain` in peak power. The model pulse is symmetric
    (conjugate-symmetric for complex baseband), so the correlation is a convolution with
    the pulse itself and it shifts no echo in range.

    Parameters
    ----------
    radar : RadarParams
        Sampling and band, from ``node_info.radar``.
    complex_input : bool
        True for complex-baseband impulse responses.
    """

    def __init__(self, radar: RadarParams, *, complex_input: bool) -> None:
        pulse = band_pulse(radar, complex_input=complex_input)
        self.gain = matched_gain(pulse)
        self.complex_input = bool(complex_input)
        kernel = np.conj(pulse[::-1])
        kernel /= np.sqrt(np.sum(np.abs(kernel) ** 2))
        self._kernel = kernel[None, :].astype(np.complex64 if complex_input else np.float32)

    @property
    def gain_db(self) -> float:
        """Matched-filter gain in dB."""
        return 10.0 * math.log10(self.gain)

    def apply(self, y: npt.NDArray) -> npt.NDArray:
        """Filtered impulse responses, same shape and dtype as ``y`` (n_rx, m).

        Overlap-add convolution: the kernel is a few to a few tens of samples long.
        """
        out = oaconvolve(y, self._kernel, mode="same", axes=1)
        return out.astype(y.dtype, copy=False)
