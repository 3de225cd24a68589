"""Per-impulse-response ranging: first-path range and LOS/NLOS decision of every row.

The chain of ``uwbnet ranging``: matched filter to the band (when it gains at least
``min_filter_gain_db``), envelope, first path by the chosen ToA estimator
(:mod:`node_agent.dsp.toa`), range :math:`r = c (t_0 + \\hat\\tau)` (the bistatic path length
of the first path, PROTOCOL.md), and the per-link LOS/NLOS decision from the envelope's
shape (:mod:`node_agent.dsp.nlos`). The shape features always use the adaptive-threshold
first path, so the LOS decision does not change with the ranging method.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.signal import hilbert

from .band_filter import BandMatchedFilter
from .geometry import SPEED_OF_LIGHT, RadarParams
from .multipath_toa import MultipathMlToaRefiner
from .nlos import DEFAULT_CLASSIFIER, FEATURES, LogisticNlosClassifier, channel_features
from .toa import (
    AdaptiveThresholdToaEstimator,
    envelope,
    make_toa_estimator,
    measured,
    noise_sigma,
)

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True, slots=True, kw_only=True, eq=False)
class RangingResult:
    """First-path ranges and LOS decisions of the rows of one impulse-response matrix.

    Attributes
    ----------
    range : ndarray, float64, shape (rows,)
        First-path bistatic path length, m; NaN where no path was found.
    toa : ndarray, float64, shape (rows,)
        First-path delay after sample 0, s.
    los : ndarray, bool, shape (rows,)
        LOS decision of each row.
    nlos_probability : ndarray, float64, shape (rows,)
    snr_db : ndarray, float64, shape (rows,)
        First path's envelope over the noise sigma, dB.
    quality : ndarray, float64, shape (rows,)
        The ToA estimator's quality figure in [0, 1].
    features : ndarray, float64, shape (rows, len(nlos.FEATURES))
    """

    range: FloatArray
    toa: FloatArray
    los: npt.NDArray[np.bool_]
    nlos_probability: FloatArray
    snr_db: FloatArray
    quality: FloatArray
    features: FloatArray


def _real_passband(radar: RadarParams) -> bool:
    """Whether the band could be a real signal sampled at ``fs`` without aliasing onto
    itself: it lies within one Nyquist zone :math:`[k f_s / 2, (k + 1) f_s / 2]` (k = 0:
    below fs / 2, as a real radar's band is; k > 0: band-pass undersampling)."""
    half = 0.5 * radar.fs
    return radar.f_high <= (math.floor(radar.f_low / half) + 1) * half


class FirstPathRanger:
    """Range and classify every row of an impulse-response matrix.

    Parameters
    ----------
    radar : RadarParams
        Sampling, window start ``t0``, band and carrier (``node_info.radar``).
    method : str
        ToA estimator: ``mpd``, ``threshold``, ``adaptive``, ``peak``, or ``ml``: the
        adaptive threshold's first path refined by the joint fit of the pulse over a few
        overlapping paths (:class:`~node_agent.dsp.multipath_toa.MultipathMlToaRefiner`).
    classifier : LogisticNlosClassifier
        LOS/NLOS rule; the simulator-trained default when omitted.
    min_filter_gain_db : float or None
        Matched filtering runs when its gain reaches this (dB); None never filters.
    """

    def __init__(
        self,
        radar: RadarParams,
        method: str = "adaptive",
        classifier: LogisticNlosClassifier | None = None,
        min_filter_gain_db: float | None = 1.0,
    ) -> None:
        self.radar = radar
        self.method = method
        self._shape_toa = AdaptiveThresholdToaEstimator(radar)
        self._refiner = MultipathMlToaRefiner(radar) if method == "ml" else None
        self._toa = self._shape_toa if method == "ml" else make_toa_estimator(method, radar)
        self.classifier = classifier if classifier is not None else DEFAULT_CLASSIFIER
        self._min_gain = min_filter_gain_db
        self._filters: dict[bool, BandMatchedFilter | None] = {}
        self._magnitudes: FirstPathRanger | None = None

    def _filter(self, is_complex: bool) -> BandMatchedFilter | None:
        if is_complex not in self._filters:
            band = None
            if self._min_gain is not None:
                band = BandMatchedFilter(self.radar, complex_input=is_complex)
                band = band if band.gain_db >= self._min_gain else None
            self._filters[is_complex] = band
        return self._filters[is_complex]

    def _envelope_ranger(self) -> FirstPathRanger:
        """A ranger of the same settings for the magnitudes of a carrier-less radar: complex
        baseband with the carrier at the band's centre (magnitudes carry no carrier phase,
        so their matched filter is the band's baseband pulse)."""
        if self._magnitudes is None:
            centre = 0.5 * (self.radar.f_low + self.radar.f_high)
            self._magnitudes = FirstPathRanger(
                dataclasses.replace(self.radar, fc=centre),
                self.method,
                self.classifier,
                self._min_gain,
            )
        return self._magnitudes

    def process(self, h: npt.NDArray) -> RangingResult:
        """Range and classify each row of ``h`` (float32 or complex64, shape (rows, n))."""
        if h.ndim != 2 or h.shape[1] != self.radar.n or h.shape[1] < 3:
            raise ValueError(f"h has shape {h.shape}, expected (rows, {self.radar.n})")
        if not np.all(np.isfinite(h)):
            raise ValueError("h holds NaN or Inf")
        if h.shape[0] == 0:
            empty = np.empty(0)
            return RangingResult(
                range=empty,
                toa=empty,
                los=np.empty(0, dtype=bool),
                nlos_probability=empty,
                snr_db=empty,
                quality=empty,
                features=np.empty((0, len(FEATURES))),
            )
        # real rows that are never negative are the magnitudes of complex samples (a noise
        # component is negative half the time): the envelope itself, with Rayleigh noise,
        # detected as complex baseband. Treated as a real passband signal, their band (above
        # fs / 2) aliased to a carrier-dependent frequency and the matched filter with it
        # (accuracy 88 % on channel 2, 93 % on 5). Without a carrier (fc), only when the band
        # cannot be a real signal sampled at fs, and around the band's centre.
        if h.dtype.kind != "c" and bool(np.all(h >= 0)):
            if self.radar.fc > 0.0:
                h = h.astype(np.complex64)
            elif not _real_passband(self.radar):
                return self._envelope_ranger().process(h.astype(np.complex64))
        is_complex = h.dtype.kind == "c"
        band = self._filter(is_complex)
        y = band.apply(h) if band is not None else h
        env = envelope(y)
        matched = band is not None
        # the zero runs padding a window are not noise samples: kept out of the noise estimate
        valid = measured(h)
        est = self._toa.estimate_envelope(
            env, complex_input=is_complex, matched=matched, valid=valid
        )
        toa = est.toa
        if self._refiner is not None:
            toa = self._refine(h, est.index, is_complex, valid) / self.radar.fs
        shape_est = (
            est
            if self.method in ("adaptive", "ml")
            else self._shape_toa.estimate_envelope(
                env, complex_input=is_complex, matched=matched, valid=valid
            )
        )
        # the shape features need the envelope, not a real signal's rectified oscillation:
        # the analytic signal's magnitude, whose noise is Rayleigh with the same sigma
        shape_env = env if is_complex else np.abs(hilbert(y.astype(np.float64), axis=1))
        with np.errstate(divide="ignore", over="ignore", under="ignore", invalid="ignore"):
            feats = channel_features(
                shape_env,
                shape_est.sigma,
                shape_est.index,
                fs=self.radar.fs,
                bandwidth=self.radar.bandwidth,
            )
            p_nlos = self.classifier.nlos_probability(feats)
        return RangingResult(
            range=SPEED_OF_LIGHT * (self.radar.t0 + toa),
            toa=toa,
            los=p_nlos < 0.5,
            nlos_probability=p_nlos,
            snr_db=est.snr_db,
            quality=est.quality,
            features=feats,
        )

    def _refine(
        self,
        h: npt.NDArray,
        index: FloatArray,
        is_complex: bool,
        valid: npt.NDArray[np.bool_] | None,
    ) -> FloatArray:
        """The multipath fit on the unfiltered samples (white noise), with their own noise
        sigma and the adaptive threshold's detection level."""
        assert self._refiner is not None
        est = self._shape_toa
        env = envelope(h)
        guard = max(1, int(np.ceil(4.0 * self.radar.fs / self.radar.bandwidth)))
        stop = np.argmax(env, axis=1) - guard
        sigma = noise_sigma(env, stop, complex_input=is_complex, valid=valid)
        n = min(est._back, h.shape[1])
        factor = est.threshold_factor(n, complex_input=is_complex)
        return self._refiner.refine(h, index, sigma, factor * sigma, est._floor)
