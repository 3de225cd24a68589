"""Wiener deconvolution of impulse responses against a reference pulse (eq. (15)).

The radar's impulse response is the channel convolved with the system pulse ``p`` (the
reference: a measured calibration echo, or the band's model pulse). Dividing the spectra
would blow up the noise where ``P`` is small; the Wiener filter weighs each frequency by its
signal-to-noise ratio:

.. math::

    \\hat X(f) = \\frac{Y(f)\\, P^*(f)}{|P(f)|^2 + \\lambda}, \\qquad
    \\lambda = \\frac{\\max_f |P(f)|^2}{\\mathrm{SNR}},

eq. (15) of the CoLOR chapter, with ``lambda`` the noise-to-signal power ratio (a constant
for white noise). The output is sharper than the impulse response (its pulse is the band's
Wiener-equalised pulse), which is what the wavefront extraction and the pulse separation
want. Pure numpy.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt


class WienerDeconvolver:
    """Wiener deconvolution against one reference pulse, eq. (15) of the CoLOR chapter.

    Parameters
    ----------
    reference : array_like, float, shape (L,)
        The reference pulse, its time origin at sample ``centre``.
    n : int
        Length of the impulse responses to deconvolve (samples).
    snr_db : float
        Signal-to-noise power ratio that sets the regulariser ``lambda``, dB.
    centre : int or None
        Sample of the reference's time origin (default: its peak), so the output keeps the
        impulse response's time axis.
    """

    def __init__(
        self, reference: npt.ArrayLike, n: int, snr_db: float = 30.0, centre: int | None = None
    ) -> None:
        ref = np.asarray(reference, float)
        if ref.ndim != 1 or not 0 < len(ref) <= n:
            raise ValueError(f"reference must be 1-D and at most n = {n} samples long")
        if centre is None:
            centre = int(np.argmax(np.abs(ref)))
        padded = np.zeros(n)
        padded[: len(ref)] = ref
        padded = np.roll(padded, -centre)  # time origin at sample 0
        spec = np.fft.rfft(padded)
        power = np.abs(spec) ** 2
        lam = power.max() * 10 ** (-snr_db / 10)
        self.n = n
        #: The Wiener filter ``P^* / (|P|^2 + lambda)``, shape (n // 2 + 1,).
        self.filter = np.conj(spec) / (power + lam)

    def apply(self, h: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """Deconvolved impulse responses, same shape (..., n) and time axis as ``h``."""
        x = np.asarray(h, float)
        if x.shape[-1] != self.n:
            raise ValueError(f"impulse responses have {x.shape[-1]} samples, expected {self.n}")
        return np.fft.irfft(np.fft.rfft(x, axis=-1) * self.filter, self.n, axis=-1)
