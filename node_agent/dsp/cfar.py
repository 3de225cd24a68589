"""Gaussian adaptive-threshold (CFAR) detection of echoes (Section 9.2 of the CoLOR chapter)."""

from __future__ import annotations

import itertools

import numpy as np
import numpy.typing as npt
from scipy.special import erfcinv

FloatArray = npt.NDArray[np.float64]

# median of a chi-square variable with one degree of freedom: turns the median of
# squared Gaussian samples into their variance, robust to the few echoes present
_CHI2_1_MEDIAN = 0.454936423119572
_EMPTY = (np.empty(0), np.empty(0), np.empty(0, dtype=np.intp))


class GaussianCfarDetector:
    """Neyman-Pearson detector with a Gaussian adaptive threshold per range bin.

    After background subtraction, the sample :math:`y_k` of range bin ``k`` is modelled
    under "no target" as Gaussian with mean :math:`\\mu_k` and variance :math:`\\sigma_k^2`,
    both tracked over time by exponential averaging (so residuals of imperfectly removed
    clutter raise the threshold locally). For real signals :math:`\\mu_k = 0`: the
    background subtraction already removes the exponential mean. For a false-alarm
    probability :math:`P_{fa}` per sample the Neyman-Pearson test on the Gaussian tail is

    .. math::

        |y_k - \\mu_k| > \\sigma_k \\sqrt{2}\\, \\operatorname{erfc}^{-1}(P_{fa})

    (two-sided, real signals), or :math:`|y_k| - \\mu_k > \\sigma_k \\sqrt{2}\\,
    \\operatorname{erfc}^{-1}(2 P_{fa})` on magnitudes (complex baseband). Threshold
    crossings are reduced to local maxima of :math:`|y_k - \\mu_k|` at least one pulse
    width (:math:`\\approx c / B`) apart, refined to sub-sample range by a parabola.
    Real samples go through the compiled kernel
    :func:`node_agent.dsp.kernels.cfar_detect_real` in one pass; complex baseband through
    numpy.

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
    censor : float
        Fraction of ``alpha`` at which bins that cross the threshold update their
        statistics.
    clip_sigma : float
        Squared deviations enter the variance average clipped at ``clip_sigma**2``
        times the variance: echoes below the threshold then raise it only slowly
        (the clipping biases a Gaussian variance by under 3 % at 3 sigma).
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
        censor: float = 0.1,
        clip_sigma: float = 3.0,
    ) -> None:
        if not 0.0 < pfa < 0.5:
            raise ValueError(f"pfa must be in (0, 0.5), got {pfa}")
        self.pfa = float(pfa)
        self.alpha = float(alpha)
        self.censor = float(censor)
        self._clip2 = np.float32(clip_sigma**2)
        self._alpha_noise = np.float32(self.alpha)
        self._alpha_crossing = np.float32(self.alpha * self.censor)
        self.complex_input = bool(complex_input)
        self._ranges = np.asarray(ranges, dtype=np.float64)
        m = self._ranges.size
        self._step = float(self._ranges[1] - self._ranges[0]) if m > 1 else 1.0
        # Gaussian tail quantile, computed once: two-sided on real samples, one-sided on
        # magnitudes; squared because the test runs on squared deviations (no sqrt per bin)
        tail = self.pfa if not self.complex_input else 2.0 * self.pfa
        self.threshold_factor = float(np.sqrt(2.0) * erfcinv(tail))
        self._max_range = float(max_range)
        self._half = max(1, round(pulse_width / abs(self._step)))
        self._offsets = np.arange(-self._half, self._half + 1)
        # Every per-bin array lives in a padded layout: ``half`` columns on each side of the
        # window that never cross the threshold, so that a crossing's neighbourhood
        # (flat index + offsets) needs no clipping at the window's edges.
        self._width = m + 2 * self._half
        # range of each padded column (padding columns never cross: their value is unused)
        self._padded_ranges = (
            np.pad(self._ranges, self._half, mode="edge") if m else np.zeros(self._width)
        )
        self.set_min_range(min_range)
        self._rate = np.empty(0, dtype=np.float32)
        self._mean: npt.NDArray[np.float32] | None = None
        self._var: npt.NDArray[np.float32] | None = None
        self._floor = np.empty(0, dtype=np.float32)
        # imported here: numba's import and the kernel's (cached) compile are paid only by
        # processes that detect
        from . import kernels

        self._kernel = kernels.cfar_detect_real
        self._fused = kernels.background_cfar_real
        self._rates = np.array(
            [self._clip2, self._alpha_noise, self._alpha_crossing], dtype=np.float32
        )

    def set_min_range(self, min_range: float | FloatArray) -> None:
        """Change the per-receiver shortest searched range, m (geometry change)."""
        min_r = np.atleast_1d(np.asarray(min_range, dtype=np.float64))[:, None]
        valid = (self._ranges[None, :] >= min_r) & (self._ranges[None, :] <= self._max_range)
        # an infinite factor switches a bin off without a separate mask operation; the
        # padding columns are off
        k2 = np.full((valid.shape[0], self._width), np.inf, dtype=np.float32)
        k2[:, self._half : self._width - self._half] = np.where(
            valid, self.threshold_factor**2, np.inf
        )
        self._k2 = k2
        # the bins searched, (rows, m): rows 1 until the first frame tells n_rx
        self._searched = np.isfinite(k2[:, self._half : self._width - self._half])

    def reset(self) -> None:
        """Forget the noise statistics."""
        self._mean = None
        self._var = None

    def noise_power(self) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.bool_]] | None:
        """The expected power :math:`E_0 |y_k|^2` of each bin without a target, and the bins
        searched, both shape (n_rx, m), after the last :meth:`detect`; None before the
        statistics exist.

        Real samples: the tracked variance :math:`\\sigma_k^2`. Complex baseband: the
        magnitude's tracked variance plus its squared mean, :math:`\\sigma_k^2 + \\mu_k^2`.
        """
        if self._var is None:
            return None
        half, width = self._half, self._width
        power = self._var[:, half : width - half]
        if self._mean is not None:
            mean = self._mean[:, half : width - half]
            power = power + mean * mean
        searched = self._searched
        if searched.shape != power.shape:
            searched = self._searched = np.ascontiguousarray(np.broadcast_to(searched, power.shape))
        return power, searched

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
        r, amp, rows = self.detect(y)
        bounds = np.searchsorted(rows, np.arange(y.shape[0] + 1)).tolist()
        spans = list(itertools.pairwise(bounds))
        return tuple(r[a:b] for a, b in spans), tuple(amp[a:b] for a, b in spans)

    def detect(self, y: npt.NDArray) -> tuple[FloatArray, FloatArray, npt.NDArray[np.intp]]:
        """:meth:`step` with the detections of all receivers in flat arrays.

        Returns
        -------
        ranges, amplitudes : ndarray, float64, shape (k,)
            Detected bistatic ranges (m) and peak deviations, sorted by (receiver, range).
        rows : ndarray, intp, shape (k,)
            Receiver (row of ``y``) of each detection.
        """
        n_rx, m = y.shape
        if m == 0:  # the searched window is empty (guard beyond the window)
            return _EMPTY
        if self._k2.shape[0] == 1 and n_rx > 1:
            self._k2 = np.repeat(self._k2, n_rx, axis=0)
        if self.complex_input:
            s = np.abs(y).astype(np.float32, copy=False)
        else:
            s = y.astype(np.float32, copy=False)
        half, width = self._half, self._width
        if self._var is None:
            if not self._initialise(s):
                return _EMPTY
        var = self._var
        if self._mean is None:
            # real samples: the whole frame in one compiled pass, the same arithmetic as
            # the numpy form below (node_agent.dsp.kernels.cfar_detect_real)
            return self._kernel(
                s, var, self._k2, self._floor, self._padded_ranges, self._rates, half, self._step
            )
        # complex baseband: magnitudes against their tracked mean, in numpy.
        # Padded squared deviations: the padding columns stay 0 and never cross
        stat = self._stat
        inner = stat[:, half : width - half]
        d = s - self._mean[:, half : width - half]
        self._mean[:, half : width - half] += self.alpha * d
        np.multiply(d, d, out=inner)
        # magnitudes below the mean are never echoes: one-sided test
        d2 = self._d2
        np.copyto(d2[:, half : width - half], inner)
        d2[:, half : width - half][d <= 0] = 0.0
        limit = np.multiply(self._k2, var, out=self._limit)
        crossing = d2 > limit
        # crossings are sparse: the peak search and the censoring mask work on their flat
        # indices only (nonzero of a raveled mask is several times faster than 2-D), with a
        # (k, 2*half+1) neighbourhood gathered around each; the padding keeps it in its row
        idx = crossing.ravel().nonzero()[0]
        flat_nb = idx[:, None] + self._offsets
        # statistics after the test, clipped, and censored: bins within a pulse width
        # of a crossing update only at the slow rate, so a passing person
        # does not mask itself, while clutter residuals that keep crossing still raise
        # their local threshold
        rate = self._rate
        rate.fill(self._alpha_noise)
        rate.ravel()[flat_nb] = self._alpha_crossing
        np.multiply(var, self._clip2, out=limit)
        np.minimum(stat, limit, out=limit)
        limit -= var
        limit *= rate
        var += limit
        np.maximum(var, self._floor, out=var)
        if idx.size == 0:
            return _EMPTY

        nb = d2.ravel()[flat_nb]  # (k, 2*half+1)
        # a crossing is a peak when it is the maximum within one pulse width, and the
        # first of equal maxima (a flat top gives one peak, not two a sample apart):
        # argmax returns the first maximum, so both tests are argmax == centre
        is_peak = nb.argmax(1) == half
        rows, cols = np.divmod(idx.compress(is_peak), width)
        env = np.sqrt(nb.compress(is_peak, axis=0)[:, half - 1 : half + 2], dtype=np.float64)
        a_m, amp, a_p = env.T
        # parabola through the envelope around the peak: sub-sample delay. The centre is
        # the neighbourhood's maximum, so den <= -|a_m - a_p| and |frac| <= 1/2; a flat
        # top (den = 0, a_m = a_p) gives frac = 0
        den = a_m - 2.0 * amp + a_p
        frac = (a_m - a_p) / np.minimum(den, -1e-300)
        frac *= 0.5 * self._step
        return self._padded_ranges[cols] + frac, amp, rows

    def detect_subtracting(
        self, h: npt.NDArray, background: npt.NDArray, alpha: float, out: npt.NDArray
    ) -> tuple[FloatArray, FloatArray, npt.NDArray[np.intp]] | None:
        """Background subtraction and :meth:`detect` in one compiled call, for real samples.

        The same bits as ``detect(subtractor.step(h, out=out))`` of an
        :class:`~node_agent.dsp.background.ExponentialBackgroundSubtractor` whose
        background is ``background`` (:meth:`~ExponentialBackgroundSubtractor.state_for`)
        and forgetting factor ``alpha``
        (:func:`node_agent.dsp.kernels.background_cfar_real`), at about 15-20 us less per
        impulse response (issue 11, stop 20 notes).

        Parameters
        ----------
        h : ndarray, float32, shape (n_rx, m)
            Impulse responses over the ``ranges`` window.
        background : ndarray, float32, shape (n_rx, m)
            The background to subtract; updated in place.
        alpha : float
            The background's forgetting factor.
        out : ndarray, float32, shape (n_rx, m)
            Receives the background-subtracted frame.

        Returns
        -------
        As :meth:`detect`; None, with nothing changed, where the single call does not
        apply (complex input, no noise statistics yet, an empty window): then subtract and
        :meth:`detect` separately.
        """
        n_rx, m = h.shape
        if self.complex_input or self._var is None or m == 0 or h.dtype != np.float32:
            return None
        if self._k2.shape[0] == 1 and n_rx > 1:
            self._k2 = np.repeat(self._k2, n_rx, axis=0)
        if self._var.shape[0] != n_rx or background.shape != h.shape or out.shape != h.shape:
            return None
        # the compiled signatures take C-ordered background and output (a driver may hand
        # over a transposed or broadcast frame: that layout must fall back, not raise)
        if not (background.flags.c_contiguous and out.flags.c_contiguous):
            return None
        if h.flags.f_contiguous and not h.flags.c_contiguous:
            # numba finds a Fortran-ordered frame ambiguous between the writable and the
            # read-only signature; a row-major copy is rare and exact
            h = np.ascontiguousarray(h)
        return self._fused(
            h,
            background,
            np.float32(alpha),
            out,
            self._var,
            self._k2,
            self._floor,
            self._padded_ranges,
            self._rates,
            self._half,
            self._step,
        )

    def _initialise(self, s: npt.NDArray[np.float32]) -> bool:
        """Noise statistics from a robust noise-floor estimate of the frame ``s``.

        Returns False for an all-zero frame (the background subtractor's first output),
        which carries no information; the statistics stay unset.
        """
        mean = np.median(s, axis=1, keepdims=True) if self.complex_input else 0.0
        d0 = s - mean
        var0 = np.median(d0 * d0, axis=1, keepdims=True) / _CHI2_1_MEDIAN
        if not np.any(var0 > 0):
            return False
        # a silent receiver row (all zeros) gets the floor and stays silent
        var0 = np.maximum(var0, 1e-6 * float(np.max(var0)))
        shape = (s.shape[0], self._width)
        self._var = np.repeat(var0, shape[1], axis=1).astype(np.float32)
        # an array floor: a ufunc with a scalar operand pays a dtype resolution
        self._floor = np.full(shape, 1e-6 * float(np.min(var0)), dtype=np.float32)
        if self.complex_input:  # buffers of the numpy form (real samples use the kernel)
            self._rate = np.empty(shape, dtype=np.float32)
            self._limit = np.empty(shape, dtype=np.float32)
            self._stat = np.zeros(shape, dtype=np.float32)
            self._mean = np.repeat(mean, shape[1], axis=1).astype(np.float32)
            self._d2 = np.zeros(shape, dtype=np.float32)
        return True
