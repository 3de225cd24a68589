"""Non-coherent multi-frame integration before detection, for echoes too weak for one frame."""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
from scipy.special import gammainccinv

FloatArray = npt.NDArray[np.float64]
_EMPTY = (np.empty(0), np.empty(0), np.empty(0, dtype=np.intp))


def integration_frames(pulse_width: float, rate: float, range_rate: float, max_frames: int) -> int:
    """Frames over which a walker's echo stays within one pulse width, at most ``max_frames``.

    A person whose bistatic range changes at ``range_rate`` (m/s) moves by
    ``range_rate / rate`` (m) per frame; summing more frames than fit in one pulse width
    (``c / bandwidth``, m) smears the echo over several range bins and loses more than the
    integration gains. 1 (no integration) when the frame rate is unknown (``rate <= 0``).
    """
    if rate <= 0.0 or range_rate <= 0.0 or max_frames <= 1:
        return 1
    return int(min(max_frames, max(1, math.floor(pulse_width * rate / range_rate))))


class NoncoherentIntegrator:
    """Neyman-Pearson detection on the echo power summed over the last ``frames`` frames.

    A far person's echo is a few noise standard deviations high in each frame (the bistatic
    spreading :math:`1 / (d_1 d_2)`), below the single-frame threshold of
    :class:`~node_agent.dsp.cfar.GaussianCfarDetector` in about half the frames, but it stays
    in the same range bins for several frames. Each background-subtracted sample's power is
    normalised by the noise power the CFAR tracks for its bin (``noise_power``, the expected
    :math:`|y_k|^2` without a target), and the last :math:`N` frames are summed:

    .. math::

        T_k = \\sum_{i=0}^{N-1} \\frac{|y_{k}^{(n-i)}|^2}{E_0 |y_k|^2}

    Without a target and with independent noise from frame to frame, :math:`T_k` is a sum
    of :math:`N` unit-mean exponential variables (complex baseband), a :math:`\\Gamma(N, 1)`
    variable, or of :math:`N` :math:`\\chi^2_1` variables (real samples),
    :math:`\\Gamma(N/2, 2)`. The Neyman-Pearson test at false-alarm probability
    :math:`P_{fa}` per sample compares :math:`T_k` with the Gamma quantile
    :math:`\\theta\\, P^{-1}(a, 1 - P_{fa})` (Richards, *Fundamentals of Radar Signal
    Processing*, 2nd ed., Sec. 6.3: non-coherent integration, the square-law detector).
    Crossings are reduced to local maxima of :math:`T_k` at least one pulse width apart,
    refined to sub-sample range by a parabola through :math:`\\sqrt{T}`, in the compiled
    kernel :func:`node_agent.dsp.kernels.integrated_peaks`.

    Beyond the CoLOR chapter, whose CFAR decides per frame; the node keeps the chapter's
    single-frame detections and adds these (:class:`~node_agent.dsp.pipeline.NodeDsp`).

    Parameters
    ----------
    frames : int
        :math:`N`, frames summed (see :func:`integration_frames`).
    pfa : float
        False-alarm probability per range sample.
    ranges : ndarray, float64, shape (m,)
        Range of each column of the window, m, uniformly spaced.
    pulse_width : float
        Range extent of one pulse, m; peaks closer than this merge.
    complex_input : bool
        True for complex baseband samples.
    """

    def __init__(
        self,
        frames: int,
        pfa: float,
        *,
        ranges: FloatArray,
        pulse_width: float,
        complex_input: bool,
    ) -> None:
        if frames < 1:
            raise ValueError(f"frames must be >= 1, got {frames}")
        if not 0.0 < pfa < 0.5:
            raise ValueError(f"pfa must be in (0, 0.5), got {pfa}")
        self.frames = int(frames)
        self.complex_input = bool(complex_input)
        self._ranges = np.asarray(ranges, dtype=np.float64)
        m = self._ranges.size
        self._step = float(self._ranges[1] - self._ranges[0]) if m > 1 else 1.0
        # Gamma(shape, scale) quantile of the sum of N normalised powers without a target
        shape, scale = (self.frames, 1.0) if self.complex_input else (0.5 * self.frames, 2.0)
        self.threshold = float(gammainccinv(shape, pfa) * scale)
        self._half = max(1, round(pulse_width / abs(self._step)))
        # imported here: numba's import and the kernel's (cached) compile are paid only by
        # nodes that integrate
        from . import kernels

        self._kernel = kernels.integrated_peaks
        self.reset()

    def reset(self) -> None:
        """Forget the frames summed so far."""
        self._buf: npt.NDArray[np.float32] | None = None
        self._padded = np.zeros((0, 0), dtype=np.float32)
        self._next = 0
        self._count = 0

    def step(
        self,
        y: npt.NDArray,
        noise_power: npt.NDArray[np.float32],
        searched: npt.NDArray[np.bool_],
    ) -> tuple[FloatArray, FloatArray, npt.NDArray[np.intp]]:
        """Add one frame; detect on the sum of the last ``frames`` frames.

        Parameters
        ----------
        y : ndarray, float32 or complex64, shape (n_rx, m)
            Background-subtracted impulse responses over the ``ranges`` window.
        noise_power : ndarray, float32, shape (n_rx, m)
            Expected :math:`|y_k|^2` of each bin without a target.
        searched : ndarray, bool, shape (n_rx, m)
            Bins searched for echoes (the CFAR's range limits).

        Returns
        -------
        ranges, amplitudes : ndarray, float64, shape (k,)
            Detected bistatic ranges (m) and the echoes' RMS amplitude over the summed frames
            (input units), sorted by (receiver, range). Empty until ``frames`` frames are in.
        rows : ndarray, intp, shape (k,)
            Receiver of each detection.
        """
        n_rx, m = y.shape
        half = self._half
        if self._buf is None or self._buf.shape[1:] != (n_rx, m):
            self._buf = np.zeros((self.frames, n_rx, m), dtype=np.float32)
            # the running sum lives inside a zero-padded array, so that a crossing's
            # neighbourhood (flat index + offsets) needs no clipping at the window's edges
            self._padded = np.zeros((n_rx, m + 2 * half), dtype=np.float32)
            self._next = self._count = 0
        total = self._padded[:, half : half + m]
        p = self._buf[self._next]
        # running sum: the oldest frame out, the new one in (a handful of array passes,
        # whatever N); recomputed from the buffer once per 64 frames against float drift
        total -= p
        if self.complex_input:
            np.multiply(y.real, y.real, out=p)
            p += y.imag * y.imag
        else:
            np.multiply(y, y, out=p)
        p /= noise_power
        total += p
        self._next = (self._next + 1) % self.frames
        self._count += 1
        if self._count % 64 == 0:
            self._buf.sum(axis=0, dtype=np.float32, out=total)
        if self._count < self.frames or m == 0:
            return _EMPTY
        return self._kernel(
            self._padded,
            searched,
            noise_power,
            self.threshold,
            half,
            self.frames,
            self._ranges,
            self._step,
        )


def integrated_peaks_reference(
    padded: npt.NDArray[np.float32],
    searched: npt.NDArray[np.bool_],
    noise_power: npt.NDArray[np.float32],
    threshold: float,
    half: int,
    frames: int,
    ranges: FloatArray,
    step: float,
) -> tuple[FloatArray, FloatArray, npt.NDArray[np.intp]]:
    """The numpy form of :func:`node_agent.dsp.kernels.integrated_peaks` (the reference of
    its test): peaks of the padded sums ``padded`` above ``threshold``."""
    m = searched.shape[1]
    total = padded[:, half : half + m]
    idx = np.flatnonzero(total > threshold)
    idx = idx[searched.ravel()[idx]]
    if idx.size == 0:
        return _EMPTY
    # a crossing is a peak when it is the first maximum within one pulse width of its row
    rows, cols = np.divmod(idx, m)
    flat = rows * (m + 2 * half) + cols + half
    nb = padded.ravel()[flat[:, None] + np.arange(-half, half + 1)]
    peak = nb.argmax(axis=1) == half
    rows, cols, nb = rows[peak], cols[peak], nb[peak]
    env = np.sqrt(np.maximum(nb[:, half - 1 : half + 2], 0.0).astype(np.float64))
    a_m, a_0, a_p = env.T
    den = a_m - 2.0 * a_0 + a_p
    frac = 0.5 * step * (a_m - a_p) / np.minimum(den, -1e-300)
    amp = np.sqrt(nb[:, half].astype(np.float64) / frames * noise_power[rows, cols])
    return ranges[cols] + frac, amp, rows.astype(np.intp)


def merge_detections(
    single: tuple[FloatArray, FloatArray, npt.NDArray[np.intp]],
    integrated: tuple[FloatArray, FloatArray, npt.NDArray[np.intp]],
    pulse_width: float,
) -> tuple[FloatArray, FloatArray, npt.NDArray[np.intp]]:
    """The single-frame detections plus the integrated ones farther than one pulse width from
    any single-frame detection of their receiver, sorted by (receiver, range)."""
    r1, a1, c1 = single
    r2, a2, c2 = integrated
    if r2.size == 0:
        return single
    if r1.size:
        # one sorted axis for all receivers: receiver c at offset c * span
        span = 2.0 * (max(float(r1.max()), float(r2.max())) + pulse_width) + 1.0
        k1 = c1 * span + r1
        k2 = c2 * span + r2
        pos = np.searchsorted(k1, k2)
        left = np.abs(k2 - k1[np.maximum(pos - 1, 0)])
        right = np.abs(k1[np.minimum(pos, k1.size - 1)] - k2)
        new = np.minimum(left, right) >= pulse_width
        r2, a2, c2 = r2[new], a2[new], c2[new]
        if r2.size == 0:
            return single
    r = np.concatenate((r1, r2))
    a = np.concatenate((a1, a2))
    c = np.concatenate((c1, c2)).astype(np.intp)
    order = np.lexsort((r, c))
    return r[order], a[order], c[order]
