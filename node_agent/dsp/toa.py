"""Time-of-arrival (first path) estimation on single impulse responses (Section 4.1).

Every estimator works on the magnitude ``|h|`` of each row of an impulse-response matrix
(the envelope for complex baseband). Thermal noise of standard deviation :math:`\\sigma` (per
component) then has a Rayleigh magnitude (complex) or a half-normal one (real),

.. math::

    F(\\eta) = P(|n| < \\eta) = 1 - \\exp\\left(-\\frac{\\eta^2}{2 \\sigma^2}\\right)
    \\quad \\text{or} \\quad \\operatorname{erf}\\left(\\frac{\\eta}{\\sqrt 2 \\sigma}\\right),

and :math:`\\sigma` is estimated from the impulse response itself (:func:`noise_sigma`), never
from a separate noise measurement: a node must range from what one acquisition gives it.

Every estimator returns a :class:`ToaEstimate`: the delay of the first path in seconds after
sample 0 (add ``t0`` for the time after emission), refined to a fraction of a sample, its
peak signal-to-noise ratio and a quality figure in [0, 1].

Detected first paths are placed on the peak of the pulse whose rising edge crossed the
threshold, refined by a parabola through the log-envelope (exact for a Gaussian pulse): a
crossing of a low threshold on the rising edge of a strong pulse alone would be early by a
good part of the pulse width. That peak is the first local maximum within two pulse widths
(:math:`2 / B`) after the crossing that is resolved from a later, stronger one (the
envelope dips by ``RESOLVE_DIP`` noise sigma between them), else the strongest sample
there (see :func:`_peak_after`).
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.special import erfc, erfcinv, ndtr

from .band_filter import pulse_sigma
from .geometry import RadarParams

FloatArray = npt.NDArray[np.float64]

# median of |n|^2 / sigma^2: 2 ln 2 for complex noise (exponential), the median of a
# chi-square variable with one degree of freedom for real noise
_RAYLEIGH_MEDIAN = 2.0 * math.log(2.0)
_CHI2_1_MEDIAN = 0.454936423119572

#: A path is resolved from a stronger one right after it when the envelope dips between them
#: by more than this many noise sigma (a noise ripple on one pulse's edge rarely does).
RESOLVE_DIP = 4.0

#: ... and when it reaches this fraction of the stronger one (-9 dB): a real system pulse has
#: sidelobes next to its main lobe (a band-limited pulse's first sidelobe is about -13 dB),
#: which must not pass for an earlier path.
RESOLVE_LEVEL = 0.35


@dataclass(frozen=True, slots=True, kw_only=True, eq=False)
class ToaEstimate:
    """First-path estimates of the rows of one impulse-response matrix.

    Attributes
    ----------
    toa : ndarray, float64, shape (n_rows,)
        Delay of the first path after sample 0, s (``index / fs``); NaN where no path
        was detected.
    index : ndarray, float64, shape (n_rows,)
        The same as a fractional sample index.
    snr_db : ndarray, float64, shape (n_rows,)
        Envelope peak of the detected path over the noise :math:`\\sigma`, dB
        (:math:`20 \\log_{10}(A / \\sigma)`).
    quality : ndarray, float64, shape (n_rows,)
        In [0, 1]: for the threshold methods the probability that noise alone stays below
        the detected path over the samples before it, :math:`F(A)^{N}`; for MPD the
        maximised probability of detection of eq. (4).
    sigma : ndarray, float64, shape (n_rows,)
        Estimated noise :math:`\\sigma` of the envelope (units of ``h``).
    """

    toa: FloatArray
    index: FloatArray
    snr_db: FloatArray
    quality: FloatArray
    sigma: FloatArray


def envelope(h: npt.NDArray) -> FloatArray:
    """Magnitude of each row, float64 (rows, n).

    For a real radar this is the rectified signal, not the analytic envelope: the Hilbert
    transform of a baseband pulse has slowly decaying (1/t) tails that would lift the skirts
    of a strong path above a noise threshold; the peak search over a pulse's main lobe
    (:meth:`ToaEstimator._crossing_estimate`) copes with a carrier's oscillation instead.
    """
    return np.abs(np.atleast_2d(h)).astype(np.float64)


def noise_sigma(
    env: FloatArray,
    stop: npt.NDArray[np.intp] | None = None,
    *,
    complex_input: bool = True,
    valid: npt.NDArray[np.bool_] | None = None,
) -> FloatArray:
    """Robust per-row noise :math:`\\sigma` (per component) from the magnitudes themselves.

    .. math:: \\hat\\sigma^2 = \\operatorname{median}(|e_k|^2) / m

    with ``m`` the median of :math:`|n|^2 / \\sigma^2`: :math:`2 \\ln 2` for complex noise,
    0.4549 (chi-square, one degree of freedom) for real noise; over the samples before
    ``stop`` (before the first arrival, where only noise lives) and over the whole row, the
    smaller of the two kept. The median ignores the minority of samples that carry paths;
    the whole-row estimate covers windows whose first arrival comes after a few samples.

    Parameters
    ----------
    env : ndarray, float64, shape (rows, n)
        Magnitudes.
    stop : ndarray, int, shape (rows,), optional
        Per row, the end of the leading noise-only region (exclusive); used when it holds
        at least 32 samples.
    complex_input : bool
        Whether the magnitudes are of complex samples.
    valid : ndarray, bool, shape (rows, n), optional
        Samples that were measured; the others (the zero runs of a recording padded in front
        of, or after, the receiver's window: :func:`measured`) are left out
        of both medians, which they would otherwise pull towards 0, and with them the
        threshold, down to an early false first path. A row without valid samples gets the
        floor.

    Returns
    -------
    ndarray, float64, shape (rows,)
    """
    p = env * env
    if valid is not None and not np.all(valid):
        p = np.where(valid, p, np.nan)
        with np.errstate(all="ignore"):
            empty = ~np.any(valid, axis=1)
            whole = np.nanmedian(np.where(empty[:, None], 0.0, p), axis=1)
    else:
        whole = np.median(p, axis=1)
    if stop is not None:
        cols = np.arange(env.shape[1])
        lead = np.where(cols[None, :] < np.asarray(stop)[:, None], p, np.nan)
        enough = np.count_nonzero(~np.isnan(lead), axis=1) >= 32
        if np.any(enough):
            lead_med = np.nanmedian(lead[enough], axis=1)
            whole[enough] = np.minimum(whole[enough], lead_med)
    sigma = np.sqrt(whole / (_RAYLEIGH_MEDIAN if complex_input else _CHI2_1_MEDIAN))
    # an all-zero row has no noise; a tiny floor keeps SNRs finite
    return np.maximum(sigma, 1e-30)


def _log_noise_cdf(eta: FloatArray, sigma: FloatArray, complex_input: bool) -> FloatArray:
    """:math:`\\ln F(\\eta)` of the noise magnitude, stable for large ``eta``."""
    x = eta / sigma
    if complex_input:
        return np.log1p(-np.exp(-0.5 * x * x))
    return np.log1p(-erfc(x / math.sqrt(2.0)))


def _refine(
    env: FloatArray,
    idx: npt.NDArray[np.intp],
    width: float | None = None,
    sigma: FloatArray | None = None,
) -> FloatArray:
    """Fractional peak position of the pulse whose envelope peaks at sample ``idx``.

    ``width`` None: a parabola through the log-envelope at ``idx - 1 .. idx + 1`` (exact for
    a Gaussian pulse of any width; the offset is clipped to half a sample, the sample being
    a local maximum). ``width`` given (the known envelope sigma of the system pulse, in
    samples): the delay of that Gaussian pulse fitted to the samples within
    ``max(1, ceil(width))`` of ``idx`` by weighted least squares on the log-envelope,
    :math:`\\ln e_k + k^2 / (2 w^2) = c + k \\tau / w^2`, weights :math:`e_k^2` (the
    log of a sample of SNR :math:`e_k / \\sigma` has variance :math:`\\sigma^2 / e_k^2`):
    at high SNR the maximum-likelihood delay of the known pulse (the matched filter's
    peak, interpolated), without the parabola's third unknown (its curvature), which on a
    pulse one or two samples wide costs about half the delay information.
    """
    n = env.shape[1]
    rows = np.arange(env.shape[0])
    i = np.clip(idx, 1, n - 2)
    tiny = 1e-300
    inside = (idx >= 1) & (idx <= n - 2)
    if width is not None and width > 0.0:
        half = max(1, math.ceil(width))
        k = np.arange(-half, half + 1)
        cols = np.clip(i[:, None] + k[None, :], 0, n - 1)
        e = env[rows[:, None], cols]
        w = e * e * (np.abs(cols - i[:, None]) == np.abs(k))  # clipped edges get no weight
        y = np.log(np.maximum(e, tiny)) + k * k / (2.0 * width * width)

        def fit(w: FloatArray, y: FloatArray) -> tuple[FloatArray, FloatArray]:
            sw = w.sum(axis=1)
            kbar = (w * k).sum(axis=1) / sw
            ybar = (w * y).sum(axis=1) / sw
            skk = (w * (k - kbar[:, None]) ** 2).sum(axis=1)
            sky = (w * (k - kbar[:, None]) * (y - ybar[:, None])).sum(axis=1)
            with np.errstate(divide="ignore", invalid="ignore"):
                slope = np.nan_to_num(sky / skk)
            return slope, ybar - slope * kbar

        slope, c0 = fit(w, y)
        if sigma is not None:
            # a later path overlapping the pulse lifts its trailing samples above the model:
            # then only the leading edge and the peak (which the later path touches least)
            model = np.exp(c0[:, None] + slope[:, None] * k - k * k / (2.0 * width * width))
            excess = np.max(np.where(k > 0, e - model, -np.inf), axis=1) > 3.0 * sigma
            if np.any(excess):
                s2, c2 = fit(w[excess] * (k <= 0), y[excess])
                slope[excess], c0[excess] = s2, c2
        with np.errstate(divide="ignore", invalid="ignore"):
            frac = np.nan_to_num(width * width * slope)
        frac = np.clip(frac, -1.0, 1.0)
        return np.where(inside, i + frac, idx.astype(np.float64))
    a = np.log(np.maximum(env[rows, i - 1], tiny))
    b = np.log(np.maximum(env[rows, i], tiny))
    c = np.log(np.maximum(env[rows, i + 1], tiny))
    den = a - 2.0 * b + c
    with np.errstate(divide="ignore", invalid="ignore"):
        frac = np.where(den < 0.0, 0.5 * (a - c) / den, 0.0)
    frac = np.clip(np.nan_to_num(frac), -0.5, 0.5)
    return np.where(inside, i + frac, idx.astype(np.float64))


def _peak_after(
    env: FloatArray,
    start: npt.NDArray[np.intp],
    width: int,
    dip: FloatArray | None = None,
) -> npt.NDArray[np.intp]:
    """Per row, the peak of the pulse whose rising edge crossed the threshold at ``start``.

    Without ``dip``: the strongest envelope sample in ``start .. start + width`` (``width``
    spans a pulse's main lobe). With ``dip`` (rows,): the first local maximum in that span
    that the envelope falls below by more than ``dip`` before the strongest sample and that
    reaches ``RESOLVE_LEVEL`` of it (a path resolved from a stronger one arriving within the
    lobe, not a sidelobe of the system pulse), or any local maximum before the strongest
    sample when that one lies on the rising edge of a later pulse (at the end of the span,
    the envelope still rising), else the strongest sample. A
    reflection arriving a fraction of a pulse width after the direct path and stronger than
    it would otherwise take the first path's place; the dip (a few noise sigma) keeps a
    noise ripple on a rising edge from passing for a path. Only for smooth envelopes
    (complex baseband, real baseband): a real band-pass signal's rectified carrier has a
    local maximum every half carrier period.
    """
    n = env.shape[1]
    idx = np.clip(start[:, None] + np.arange(width + 1)[None, :], 0, n - 1)
    rows = np.arange(env.shape[0])[:, None]
    w = env[rows, idx]
    top = np.argmax(w, axis=1)
    if dip is None:
        return idx[rows[:, 0], top]
    before = env[rows[:, 0], np.maximum(idx[:, 0] - 1, 0)][:, None]
    prev = np.concatenate([before, w[:, :-1]], axis=1)
    nxt = np.concatenate([w[:, 1:], w[:, -1:]], axis=1)
    local = (w >= prev) & (w > nxt)
    cols = np.arange(w.shape[1])[None, :]
    # lowest envelope from each sample up to the strongest one (reverse running minimum)
    upto = np.where(cols <= top[:, None], w, np.inf)
    low = np.minimum.accumulate(upto[:, ::-1], axis=1)[:, ::-1]
    strong = w >= RESOLVE_LEVEL * w[rows[:, 0], top][:, None]
    resolved = local & strong & (cols < top[:, None]) & (w - low > np.asarray(dip)[:, None])
    # the lobe's strongest sample on the rising edge of a later pulse (the envelope still
    # rises past the span): any earlier local maximum is the first path's own peak
    after = env[rows[:, 0], np.minimum(idx[:, -1] + 1, n - 1)]
    rising = (top == w.shape[1] - 1) & (after > w[:, -1])
    resolved |= local & (cols < top[:, None]) & rising[:, None]
    pick = np.where(resolved.any(axis=1), np.argmax(resolved, axis=1), top)
    return idx[rows[:, 0], pick]


class ToaEstimator(ABC):
    """Base of the first-path estimators: configured with the radar, ``estimate(h)``.

    Parameters
    ----------
    radar : RadarParams
        Sampling rate and band: the band sets how many *independent* noise samples a window
        holds, :math:`N_{eff} = N \\min(1, B / f_s)` (an oversampled envelope has correlated
        neighbours, which do not each risk a false alarm).
    search_back : float
        The threshold methods search for the first path only this long (s) before the
        strongest path ("jump back, search forward"): indoors the strongest path arrives
        at most a few tens of ns after the first (room delay spreads are 5-30 ns), and
        every noise sample searched is a chance of a false, early first path. 100 ns
        (30 m of excess path) by default.
    dynamic_range_db : float
        No threshold lies more than this below the strongest path (20 dB): a real system
        pulse has skirts (band-edge ringing, the slow undershoot of the front end's
        high-pass, about -25 dB on the M-sequence radar) that a noise-only threshold would
        take for a first path, and a direct path obstructed by more than that relative to
        the reflections is out of reach anyway.
    """

    def __init__(
        self, radar: RadarParams, search_back: float = 100e-9, dynamic_range_db: float = 20.0
    ) -> None:
        if not search_back > 0.0:
            raise ValueError(f"search_back must be positive, got {search_back}")
        self.radar = radar
        self.search_back = float(search_back)
        self._floor = 10.0 ** (-abs(dynamic_range_db) / 20.0)
        # two pulse widths 1/B: the main lobe of a band-limited pulse
        self._lobe = max(1, math.ceil(2.0 * radar.fs / radar.bandwidth))
        self._bandwidth_ratio = radar.bandwidth / radar.fs
        self._complex = True
        self._independence = min(1.0, self._bandwidth_ratio)
        self._back = max(1, math.ceil(self.search_back * radar.fs))
        self.pulse_width = pulse_sigma(radar, complex_input=True) * radar.fs

    def estimate(self, h: npt.NDArray) -> ToaEstimate:
        """First path of each row of ``h`` (ndarray float32 or complex64, shape (rows, n))."""
        return self.estimate_envelope(
            envelope(h), complex_input=np.iscomplexobj(h), valid=measured(h)
        )

    def estimate_envelope(
        self,
        env: FloatArray,
        *,
        complex_input: bool,
        matched: bool = False,
        valid: npt.NDArray[np.bool_] | None = None,
    ) -> ToaEstimate:
        """First path of each row of magnitudes ``env`` (float64, shape (rows, n)) of real
        or complex samples; ``matched``: the samples went through the band's matched filter
        (:class:`~node_agent.dsp.band_filter.BandMatchedFilter`), which widens the pulse's
        envelope by :math:`\\sqrt 2`; ``valid``: the samples that were measured (see
        :func:`noise_sigma` and :func:`measured`)."""
        self._complex = bool(complex_input)
        # the model pulse's envelope sigma in samples, for the known-pulse peak refinement
        width = pulse_sigma(self.radar, complex_input=complex_input) * self.radar.fs
        self.pulse_width = width * (math.sqrt(2.0) if matched else 1.0)
        # a real signal of bandwidth B has 2 B independent samples per second
        self._independence = min(1.0, (1.0 if complex_input else 2.0) * self._bandwidth_ratio)
        # silent rows (all zero) and samples far above the noise take logs of 0 and exps
        # of large numbers: the limits (-inf, 0, 1) are the right values
        with np.errstate(divide="ignore", over="ignore", under="ignore", invalid="ignore"):
            sigma = _noise(env, self._guard(), complex_input, valid)
            return self._estimate(env, sigma)

    @abstractmethod
    def _estimate(self, env: FloatArray, sigma: FloatArray) -> ToaEstimate:
        """The method on magnitudes ``env`` with noise ``sigma`` (rows,)."""

    def _result(
        self, env: FloatArray, peak: npt.NDArray[np.intp], sigma: FloatArray, quality: FloatArray
    ) -> ToaEstimate:
        smooth = self._complex or self.radar.f_low <= 0.0
        index = _refine(env, peak, self.pulse_width if smooth else None, sigma)
        amp = env[np.arange(env.shape[0]), peak]
        return ToaEstimate(
            toa=index / self.radar.fs,
            index=index,
            snr_db=20.0 * np.log10(np.maximum(amp, 1e-300) / sigma),
            quality=quality,
            sigma=sigma,
        )

    def _noise_quality(self, env: FloatArray, peak: npt.NDArray[np.intp], sigma: FloatArray):
        """:math:`F(A)^{N_{eff}}`: noise alone stays below the path over the searched samples
        before it."""
        amp = env[np.arange(env.shape[0]), peak]
        n_eff = np.maximum(peak - self._search_start(env), 1) * self._independence
        return np.exp(n_eff * _log_noise_cdf(amp, sigma, self._complex))

    def _search_start(self, env: FloatArray) -> npt.NDArray[np.intp]:
        """Per row, the first sample searched: ``search_back`` before the strongest path."""
        return np.maximum(np.argmax(env, axis=1) - self._back, 0)

    def _crossing_estimate(self, env: FloatArray, eta: FloatArray, sigma: FloatArray):
        cols = np.arange(env.shape[1])
        eta = np.maximum(eta, self._floor * env.max(axis=1))
        crossing = (env >= eta[:, None]) & (cols[None, :] >= self._search_start(env)[:, None])
        found = crossing.any(axis=1)
        first = np.where(found, np.argmax(crossing, axis=1), 0)
        smooth = self._complex or self.radar.f_low <= 0.0
        peak = _peak_after(env, first, self._lobe, RESOLVE_DIP * sigma if smooth else None)
        est = self._result(env, peak, sigma, self._noise_quality(env, peak, sigma))
        return _blank(est, ~found)


def _blank(est: ToaEstimate, missing: npt.NDArray[np.bool_]) -> ToaEstimate:
    if not np.any(missing):
        return est
    nan = np.where(missing, np.nan, 1.0)
    return ToaEstimate(
        toa=est.toa * nan,
        index=est.index * nan,
        snr_db=est.snr_db * nan,
        quality=np.where(missing, 0.0, est.quality),
        sigma=est.sigma,
    )


def _noise(
    env: FloatArray,
    guard: int,
    complex_input: bool,
    valid: npt.NDArray[np.bool_] | None = None,
) -> FloatArray:
    """Noise sigma from the samples up to ``guard`` before the strongest path, or the row."""
    stop = np.argmax(env, axis=1) - guard
    return noise_sigma(env, stop, complex_input=complex_input, valid=valid)


#: Shortest zero run at a row's start or end taken for padding: quantised noise has chance
#: runs of a few zeros (at 0.5 LSB, a leading run of 1-5 in about 1 % of the rows), which are
#: noise samples; a receiver window padded into a recording's longer one leaves far more.
MIN_PADDING = 16


def measured(h: npt.NDArray) -> npt.NDArray[np.bool_] | None:
    """Samples of ``h`` (rows, n) that are not padding, or None when none is: a recording may
    pad a shorter receiver window with zeros in front of or after it, which are no noise
    samples. Padding is a run of at least ``MIN_PADDING`` exact zeros at a row's start or end
    (or a row of zeros only). Zeros inside the window are kept: integer-quantised noise is
    exactly 0 in 20-35 % of its samples at 0.5-2 LSB, and leaving those out would raise the
    noise median and the threshold."""
    nz = np.atleast_2d(h) != 0
    n = nz.shape[1]
    if n == 0:
        return None
    any_nz = nz.any(axis=1)
    first = np.where(any_nz, np.argmax(nz, axis=1), n)
    last = np.where(any_nz, n - 1 - np.argmax(nz[:, ::-1], axis=1), -1)
    first = np.where(first >= MIN_PADDING, first, 0)
    last = np.where(n - 1 - last >= MIN_PADDING, last, n - 1)
    cols = np.arange(n)
    valid = (cols >= first[:, None]) & (cols <= last[:, None]) & any_nz[:, None]
    return None if np.all(valid) else valid


class PeakToaEstimator(ToaEstimator):
    """The strongest sample of the envelope, refined by a parabola.

    Unbiased when the direct path is the strongest (LOS); late by the excess delay of the
    strongest reflection when the direct path is attenuated (NLOS).
    """

    def _estimate(self, env: FloatArray, sigma: FloatArray) -> ToaEstimate:
        peak = np.argmax(env, axis=1)
        return self._result(env, peak, sigma, self._noise_quality(env, peak, sigma))

    def _guard(self) -> int:
        # four pulse widths (1 / B) before the strongest path belong to its rising edge
        return max(1, math.ceil(4.0 * self.radar.fs / self.radar.bandwidth))


class ThresholdToaEstimator(PeakToaEstimator):
    """Fixed threshold: the first crossing of a fixed fraction of the envelope's maximum.

    .. math:: \\hat k = \\min\\{k : e_k \\ge \\gamma \\max_j e_j\\}

    then the first local maximum after it. "Fixed" because ``gamma`` does not depend on the
    noise: a first path weaker than ``gamma`` times the strongest one (NLOS) is missed.

    Parameters
    ----------
    radar : RadarParams
    fraction : float
        :math:`\\gamma`, in (0, 1]; 0.5 (-6 dB) by default.
    """

    def __init__(
        self,
        radar: RadarParams,
        fraction: float = 0.5,
        search_back: float = 100e-9,
        dynamic_range_db: float = 20.0,
    ) -> None:
        super().__init__(radar, search_back, dynamic_range_db)
        if not 0.0 < fraction <= 1.0:
            raise ValueError(f"fraction must be in (0, 1], got {fraction}")
        self.fraction = float(fraction)

    def _estimate(self, env: FloatArray, sigma: FloatArray) -> ToaEstimate:
        return self._crossing_estimate(env, self.fraction * env.max(axis=1), sigma)


class AdaptiveThresholdToaEstimator(PeakToaEstimator):
    """Adaptive threshold: a constant false-alarm rate over the whole impulse response.

    The threshold is set on the noise estimated from the impulse response, so that noise
    alone crosses it anywhere in the ``N_eff`` independent samples searched (``search_back``
    before the strongest path) with probability ``pfa``:

    .. math:: F(\\eta)^{N_{eff}} = 1 - P_{fa}

    (:math:`\\eta = \\sigma \\sqrt{-2 \\ln q}` for complex, :math:`\\sigma \\sqrt 2
    \\operatorname{erfc}^{-1}(q)` for real noise, :math:`q = 1 - (1 - P_{fa})^{1/N_{eff}}`).

    Parameters
    ----------
    radar : RadarParams
    pfa : float
        Probability of a false first path per impulse response, 1e-3 by default.
    """

    def __init__(
        self,
        radar: RadarParams,
        pfa: float = 1e-3,
        search_back: float = 100e-9,
        dynamic_range_db: float = 20.0,
    ) -> None:
        super().__init__(radar, search_back, dynamic_range_db)
        if not 0.0 < pfa < 1.0:
            raise ValueError(f"pfa must be in (0, 1), got {pfa}")
        self.pfa = float(pfa)

    def threshold_factor(self, n: int, *, complex_input: bool = True) -> float:
        """:math:`\\eta / \\sigma` for ``n`` samples searched (after :meth:`estimate` set
        the independence of the input's samples)."""
        n_eff = max(n * self._independence, 1.0)
        tail = -math.expm1(math.log1p(-self.pfa) / n_eff)  # per-sample 1 - F(eta)
        if complex_input:
            return math.sqrt(-2.0 * math.log(tail))
        return math.sqrt(2.0) * float(erfcinv(tail))

    def _estimate(self, env: FloatArray, sigma: FloatArray) -> ToaEstimate:
        n = min(self._back, env.shape[1])
        factor = self.threshold_factor(n, complex_input=self._complex)
        return self._crossing_estimate(env, factor * sigma, sigma)


class MpdToaEstimator(PeakToaEstimator):
    """Maximum probability of detection (MPD) of the first path, eq. (4)-(5) of the chapter.

    Our reading of the method: a threshold :math:`\\eta` detects the first path correctly
    when no noise sample before it crosses (the false first paths that make threshold
    ToA early) *and* the first path itself crosses (a miss makes it late). With ``N``
    independent noise samples ahead of a first path of envelope amplitude ``A``,

    .. math::

        P_D(\\eta) = F(\\eta)^{N}\\; P\\left(|A + n| \\ge \\eta\\right)    \\quad (4)

    .. math::

        \\eta^\\ast = \\arg\\max_\\eta P_D(\\eta)                           \\quad (5)

    and the ToA is the first crossing of :math:`\\eta^\\ast` (then the first local maximum,
    sub-sample refined). Noise statistics come from the impulse response itself:
    :math:`\\sigma` from :func:`noise_sigma`, ``N`` the independent samples searched before
    the strongest path (the first path cannot come later; see ``search_back``).

    Beyond the chapter: the first path's amplitude ``A`` is unknown (in NLOS it can be far
    below the strongest path), so eq. (4) is averaged over a log-uniform prior of ``A``
    up to the strongest path's amplitude (every level of
    attenuation equally likely per decade), from ``first_path_floor`` below it (a first path
    through an interior wall, furniture or a body is 5-20 dB weaker than the strongest
    reflection in indoor measurements) but not below :math:`3 \\sigma` (no threshold
    detects a weaker path), with the Gaussian approximation
    :math:`P(|A + n| \\ge \\eta) \\approx \\Phi((A - \\eta) / \\sigma)` (accurate where
    detection matters, :math:`A \\gtrsim 3 \\sigma`). The threshold therefore rises with the
    length of the noise window before the strongest path and, slowly, with its amplitude,
    and stays at a few :math:`\\sigma` whatever the first path's attenuation, which is what
    lets it find weak NLOS first paths that a fraction-of-maximum threshold misses.

    Parameters
    ----------
    radar : RadarParams
    n_thresholds : int
        Grid points of :math:`\\eta` between :math:`\\sigma` and the strongest amplitude.
    n_amplitudes : int
        Grid points of the amplitude prior.
    first_path_floor_db : float
        Weakest first path of the prior relative to the strongest path, dB (-20); also the
        dynamic range of the threshold (see :class:`ToaEstimator`).
    """

    def __init__(
        self,
        radar: RadarParams,
        search_back: float = 100e-9,
        n_thresholds: int = 96,
        n_amplitudes: int = 48,
        first_path_floor_db: float = -20.0,
    ) -> None:
        super().__init__(radar, search_back, dynamic_range_db=abs(first_path_floor_db))
        self.n_thresholds = int(n_thresholds)
        self.n_amplitudes = int(n_amplitudes)

    def detection_probability(
        self, eta: FloatArray, sigma: FloatArray, n_noise: FloatArray, a_max: FloatArray
    ) -> FloatArray:
        """Prior-averaged eq. (4) on thresholds ``eta`` (rows, g); sigma, n_noise, a_max (rows,)."""
        s = sigma[:, None]
        u = np.linspace(0.0, 1.0, self.n_amplitudes)
        # log-uniform amplitude grid from max(3 sigma, a_max * floor) to a_max, shape
        # (rows, n_amplitudes): a path below 3 sigma is not detectable by any threshold
        # (counting it would only reward thresholds inside the noise), and first paths
        # weaker than the floor are not expected (see the class docstring)
        lo = np.maximum(3.0 * sigma, self._floor * a_max)
        ratio = np.maximum(a_max / lo, 1.0)
        amps = lo[:, None] * ratio[:, None] ** u[None, :]
        detect = ndtr((amps[:, None, :] - eta[:, :, None]) / s[:, :, None]).mean(axis=2)
        no_false = np.exp(n_noise[:, None] * _log_noise_cdf(eta, s, self._complex))
        return no_false * detect

    def _estimate(self, env: FloatArray, sigma: FloatArray) -> ToaEstimate:
        strongest = np.argmax(env, axis=1)
        a_max = env.max(axis=1)
        n_noise = np.maximum(strongest - self._search_start(env), 1) * self._independence
        ratio = np.maximum(a_max / sigma, 1.0 + 1e-9)
        g = np.linspace(0.0, 1.0, self.n_thresholds)
        eta = sigma[:, None] * ratio[:, None] ** g[None, :]  # log grid sigma .. a_max
        pd = self.detection_probability(eta, sigma, n_noise, a_max)
        best = np.argmax(pd, axis=1)
        rows = np.arange(env.shape[0])
        est = self._crossing_estimate(env, eta[rows, best], sigma)
        return ToaEstimate(
            toa=est.toa,
            index=est.index,
            snr_db=est.snr_db,
            quality=pd[rows, best],
            sigma=sigma,
        )


ESTIMATORS: dict[str, type[PeakToaEstimator]] = {
    "mpd": MpdToaEstimator,
    "threshold": ThresholdToaEstimator,
    "adaptive": AdaptiveThresholdToaEstimator,
    "peak": PeakToaEstimator,
}
"""Estimator class of each ``uwbnet ranging --method`` name."""


def make_toa_estimator(method: str, radar: RadarParams) -> ToaEstimator:
    """The estimator called ``method`` (``mpd``, ``threshold``, ``adaptive``, ``peak``)."""
    try:
        cls = ESTIMATORS[method]
    except KeyError:
        raise ValueError(f"unknown ToA method {method!r} ({', '.join(ESTIMATORS)})") from None
    return cls(radar)
