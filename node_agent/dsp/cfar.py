"""Gaussian adaptive-threshold (CFAR) detection of echoes (Section 9.2 of the CoLOR chapter)."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from scipy.ndimage import maximum_filter1d
from scipy.special import erfcinv

FloatArray = npt.NDArray[np.float64]

# median of a chi-square variable with one degree of freedom: turns the median of
# squared Gaussian samples into their variance, robust to the few echoes present
_CHI2_1_MEDIAN = 0.454936423119572


class GaussianCfarDetector:
    """Neyman-Pearson detector with a Gaussian adaptive threshold per range bin.

    After background subtraction, the sample :math:`y_k` of range bin ``k`` is modelled
    under "no target" as Gaussian with mean :math:`\\mu_k` and variance :math:`\\sigma_k^2`,
    both tracked over time by exponential averaging (so residuals of imperfectly removed
    clutter raise the threshold locally). For a false-alarm probability :math:`P_{fa}` per
    sample the Neyman-Pearson test on the Gaussian tail is

    .. math::

        |y_k - \\mu_k| > \\sigma_k \\sqrt{2}\\, \\operatorname{erfc}^{-1}(P_{fa})

    (two-sided, real signals), or :math:`|y_k| - \\mu_k > \\sigma_k \\sqrt{2}\\,
    \\operatorname{erfc}^{-1}(2 P_{fa})` on magnitudes (complex baseband). Threshold
    crossings are reduced to local maxima of :math:`|y_k - \\mu_k|` at least one pulse
    width (:math:`\\approx c / B`) apart, refined to sub-sample range by a parabola.

    Parameters
    ----------
    pfa : float
        False-alarm probability per range sample.
    ranges : ndarray, float64, shape (m,)
        Range of each column of the input window, m, uniformly spaced.
    pulse_width : float
        Range extent of one pulse, m (``c / bandwidth``); peaks closer than this merge.
    min_range : float or ndarray, shape (n_rx,)
        Per-receiver shortest range searched, m (direct path + guard: coupling residuals).
    max_range : float
        Longest range searched, m.
    alpha : float
        Forgetting factor of the noise mean/variance averages.
    complex_input : bool
        True when the input is complex baseband (the test runs on magnitudes).
    """

    def __init__(
        self,
        pfa: float,
        *,
        ranges: FloatArray,
        pulse_width: float,
        min_range: float | FloatArray = 0.0,
        max_range: float = np.inf,
        alpha: float = 0.05,
        complex_input: bool = False,
    ) -> None:
        if not 0.0 < pfa < 0.5:
            raise ValueError(f"pfa must be in (0, 0.5), got {pfa}")
        self.pfa = float(pfa)
        self.alpha = float(alpha)
        self.complex_input = bool(complex_input)
        self._ranges = np.asarray(ranges, dtype=np.float64)
        m = self._ranges.size
        self._step = float(self._ranges[1] - self._ranges[0]) if m > 1 else 1.0
        # Gaussian tail quantile, computed once: two-sided on real samples, one-sided on
        # magnitudes; squared because the test runs on squared deviations (no sqrt per bin)
        tail = self.pfa if not self.complex_input else 2.0 * self.pfa
        self.threshold_factor = float(np.sqrt(2.0) * erfcinv(tail))
        k2 = self.threshold_factor**2
        min_r = np.atleast_1d(np.asarray(min_range, dtype=np.float64))[:, None]
        valid = (self._ranges[None, :] >= min_r) & (self._ranges[None, :] <= max_range)
        # an infinite factor switches a bin off without a separate mask operation
        self._k2 = np.where(valid, k2, np.inf).astype(np.float32)
        self._half = max(1, round(pulse_width / abs(self._step)))
        self._mean: npt.NDArray[np.float32] | None = None
        self._var: npt.NDArray[np.float32] | None = None
        self._floor = np.float32(0.0)

    def reset(self) -> None:
        """Forget the noise statistics."""
        self._mean = None
        self._var = None

    def step(self, y: npt.NDArray) -> tuple[tuple[FloatArray, ...], tuple[FloatArray, ...]]:
        """Detect echoes in one background-subtracted impulse-response matrix.

        Parameters
        ----------
        y : ndarray, float32 or complex64, shape (n_rx, m)
            Background-subtracted impulse responses over the ``ranges`` window.

        Returns
        -------
        ranges : tuple of ndarray, float64, shape (k_i,)
            Per receiver, the detected bistatic ranges in m, ascending.
        amplitudes : tuple of ndarray, float64, shape (k_i,)
            Per receiver, the peak deviation :math:`|y_k - \\mu_k|` (input units).
        """
        n_rx = y.shape[0]
        if self._k2.shape[0] == 1 and n_rx > 1:
            self._k2 = np.repeat(self._k2, n_rx, axis=0)
        if self.complex_input:
            s = np.abs(y).astype(np.float32, copy=False)
        else:
            s = y.astype(np.float32, copy=False)
        empty = tuple(np.empty(0) for _ in range(n_rx))
        if self._var is None:
            # initialise from a robust noise-floor estimate of this frame; an all-zero
            # frame (the background subtractor's first output) carries no information
            mean = np.median(s, axis=1, keepdims=True) if self.complex_input else 0.0
            d0 = s - mean
            var0 = np.median(d0 * d0, axis=1, keepdims=True) / _CHI2_1_MEDIAN
            if not np.all(var0 > 0):
                return empty, empty
            self._floor = np.float32(1e-6 * float(np.min(var0)))
            self._var = np.repeat(var0, s.shape[1], axis=1).astype(np.float32)
            if self.complex_input:
                self._mean = np.repeat(mean, s.shape[1], axis=1).astype(np.float32)
        var = self._var
        if self._mean is not None:
            d = s - self._mean
            self._mean += self.alpha * d
            d2 = d * d
            d2[d < 0] = 0.0  # magnitudes below the mean are never echoes (one-sided)
        else:
            d2 = s * s
        limit = self._k2 * var
        crossing = d2 > limit
        peaks = crossing & (d2 >= maximum_filter1d(d2, 2 * self._half + 1, axis=1))
        # statistics after the test; clipping at the threshold keeps echoes from
        # inflating the variance of their own bins, while clutter residuals still raise it
        np.minimum(d2, np.where(crossing, limit, d2), out=limit)
        var += self.alpha * (limit - var)
        np.maximum(var, self._floor, out=var)

        rows, cols = np.nonzero(peaks)
        if rows.size == 0:
            return empty, empty
        m = s.shape[1]
        amp = np.sqrt(d2[rows, cols].astype(np.float64))
        a_m = np.sqrt(d2[rows, np.maximum(cols - 1, 0)].astype(np.float64))
        a_p = np.sqrt(d2[rows, np.minimum(cols + 1, m - 1)].astype(np.float64))
        # parabola through the envelope around the peak: sub-sample delay
        den = a_m - 2.0 * amp + a_p
        frac = np.where(den < 0, 0.5 * (a_m - a_p) / np.where(den < 0, den, -1.0), 0.0)
        r = self._ranges[cols] + np.clip(frac, -0.5, 0.5) * self._step
        splits = np.searchsorted(rows, np.arange(1, n_rx))
        return tuple(np.split(r, splits)), tuple(np.split(amp, splits))
