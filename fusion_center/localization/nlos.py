"""NLOS identification of anchors from the variance of their ranges (eq. (6) of the CoLOR chapter).

Under LOS a node's range to an anchor scatters with the known LOS variance
:math:`\\sigma_{LOS}^2`; an obstructed direct path is weak, so its first-path ToA jumps between
the direct path and later multipath and the range varies much more. Over a window of N
ranges, the mean squared deviation from a smooth fit (the mean for a static node, a
low-order polynomial in time for a moving one),

.. math:: \\mathrm{MSE} = \\frac{1}{N} \\sum_{k=1}^{N} (r_k - \\hat r(t_k))^2,

is compared with the known LOS variance: NLOS is decided when
:math:`N \\, \\mathrm{MSE} / \\sigma_{LOS}^2 > \\chi^2_{N-p-1}(1 - \\alpha)`, so that the false
alarm probability of a LOS anchor is :math:`\\alpha` by construction (Gaussian LOS errors). The
test runs per anchor, so it says which anchors are NLOS, not only that one exists.

"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.stats import chi2

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True, slots=True, kw_only=True)
class MseNlosTest:
    """The per-anchor MSE hypothesis test of eq. (6).

    Parameters
    ----------
    los_std : float
        Known standard deviation of a LOS range, m (calibrated on LOS links).
    false_alarm : float
        Probability :math:`\\alpha` of calling a LOS anchor NLOS.
    order : int
        Degree of the polynomial fitted over the window: 0 for a static node (the
        chapter's setting), 1 or 2 for a moving one.
    min_samples : int
        Below this many ranges the anchor is not tested (reported LOS).
    clip : float
        Residuals are clipped at this many ``los_std`` (0, the default: the chapter's MSE).
    """

    los_std: float = 0.03
    false_alarm: float = 0.01
    order: int = 2
    min_samples: int = 8
    clip: float = 0.0

    def statistic(self, t: FloatArray, ranges: FloatArray) -> tuple[float, int]:
        """``(N MSE / sigma_LOS^2, degrees of freedom)`` of one anchor's window.

        Parameters
        ----------
        t : ndarray, shape (N,)
            Times of the ranges, s.
        ranges : ndarray, shape (N,)
            Ranges, m.
        """
        t = np.asarray(t, float)
        r = np.asarray(ranges, float)
        ok = np.isfinite(t) & np.isfinite(r)
        t, r = t[ok], r[ok]
        order = min(self.order, max(t.size - 2, 0))
        dof = t.size - order - 1
        if t.size < self.min_samples or dof < 1:
            return 0.0, 0
        tc = t - t.mean()
        scale = max(float(np.ptp(tc)), 1e-9)
        basis = np.vander(tc / scale, order + 1)
        coef, *_ = np.linalg.lstsq(basis, r, rcond=None)
        res = (r - basis @ coef) / self.los_std
        if self.clip > 0:
            res = np.clip(res, -self.clip, self.clip)
        return float(np.sum(res**2)), dof

    def is_nlos(self, t: FloatArray, ranges: FloatArray) -> bool:
        """Eq. (6) decision for one anchor's window of ranges."""
        stat, dof = self.statistic(t, ranges)
        return dof >= 1 and stat > self.threshold(dof)

    def decide(self, t: FloatArray, ranges: FloatArray) -> npt.NDArray[np.bool_]:
        """Eq. (6) decisions of several anchors ranged at the same times (True: NLOS).

        Parameters
        ----------
        t : ndarray, shape (N,)
        ranges : ndarray, shape (N, k)
            One column per anchor, all finite.
        """
        t = np.asarray(t, float)
        r = np.asarray(ranges, float).reshape(t.size, -1)
        order = min(self.order, max(t.size - 2, 0))
        dof = t.size - order - 1
        if t.size < self.min_samples or dof < 1:
            return np.zeros(r.shape[1], bool)
        tc = t - t.mean()
        basis = np.vander(tc / max(float(np.ptp(tc)), 1e-9), order + 1)
        coef, *_ = np.linalg.lstsq(basis, r, rcond=None)
        res = (r - basis @ coef) / self.los_std
        if self.clip > 0:
            res = np.clip(res, -self.clip, self.clip)
        return np.sum(res**2, axis=0) > self.threshold(dof)

    def threshold(self, dof: int) -> float:
        """The test's threshold on ``N MSE / sigma_LOS^2`` for ``dof`` degrees of freedom."""
        return _chi2_quantile(1.0 - self.false_alarm, dof)


@functools.lru_cache(maxsize=1024)
def _chi2_quantile(p: float, dof: int) -> float:
    return float(chi2.ppf(p, dof))


@dataclass(frozen=True, slots=True, kw_only=True)
class EvidenceNlosTest:
    """Eq. (6) combined with the impulse responses' own NLOS evidence by a sum of
    log-likelihood ratios (beyond the chapter).

    The eq. (6) test sees an obstructed direct path only through the scatter of its ranges,
    so it needs a channel that changes during the window (a static node in a still room
    looks LOS). Each ranging round also carries two per-link cues that do not need a
    changing channel:

    * **first-path power against the path loss of the range**:
      :math:`\\Delta_k = \\mathrm{SNR}_k + 20 \\log_{10} r_k - \\mathrm{SNR}_{1m}`, dB. Free
      space makes the first path's amplitude fall as :math:`1/r`, so a LOS link has
      :math:`\\Delta \\approx 0` (scattered by the multipath that overlaps the first path,
      ``power_los_std``); a wall or body in the direct path takes its transmission loss off
      (``power_nlos_mean`` below, wide ``power_nlos_std``). The link budget
      :math:`\\mathrm{SNR}_{1m}` is ``link_budget_db`` or, when None, calibrated from the
      links themselves: an obstruction can only weaken the direct path, so the anchor with
      the strongest median :math:`\\mathrm{SNR} + 20 \\log_{10} r` over its window is taken as
      LOS (right whenever at least one anchor is LOS; with all anchors obstructed the
      localization fails anyway).
    * **the per-impulse-response shape classifier** (:mod:`node_agent.dsp.nlos`: first path
      against the strongest, rise time, excess delay, kurtosis), whose decision arrives as
      ``los`` of the link with detection probability ``flag_detection`` and false-alarm
      probability ``flag_false_alarm``.

    Per anchor over the window of N rounds,

    .. math::

        \\Lambda = \\underbrace{\\max\\left(\\tfrac{T}{2}(1 - \\kappa^{-1})
        - \\tfrac{d}{2} \\ln \\kappa, 0\\right)}_{\\text{eq. (6)}}
        + \\sum_k \\operatorname{clip}_{\\pm c}\\left(\\ln
        \\frac{\\mathcal N(\\Delta_k; \\mu_N, \\sigma_N)}
        {\\mathcal N(\\Delta_k; 0, \\sigma_L)}\\right)
        + \\sum_k \\ln \\frac{P(f_k \\mid \\mathrm{NLOS})}{P(f_k \\mid \\mathrm{LOS})}

    with :math:`T = N \\mathrm{MSE} / \\sigma_{LOS}^2` (residuals clipped at ``range_clip``)
    and :math:`d` the statistic and degrees of freedom of eq. (6) (:class:`MseNlosTest`):
    its first term is the exact log-likelihood ratio of :math:`T \\sim \\chi^2_d` (LOS)
    against :math:`T \\sim \\kappa \\chi^2_d` (NLOS ranges scatter with :math:`\\kappa` times
    the LOS variance), so eq. (6) alone is the threshold test on it. It counts one-sided:
    steady ranges are no evidence of LOS, since an obstructed link whose channel does not
    change (a static node in a still room) ranges just as steadily. The per-round power
    terms are clipped at ``clip_llr`` so that one faded round (a LOS first path cancelled
    by an overlapping reflection) cannot decide. NLOS when :math:`\\Lambda >`
    ``threshold``. Rounds without an SNR (NaN) add no power term.

    The distribution parameters were measured by ``python -m uwbnet.nlos_link_training``
    on ``lab_nlos`` and ``lab_los`` runs with seeds 101-103, disjoint from the evaluation
    seeds (1-5); docs/localization.md.

    Parameters
    ----------
    mse : MseNlosTest
        The eq. (6) test (its statistic, window handling and ``los_std``).
    kappa : float
        NLOS over LOS range variance of the eq. (6) likelihood ratio.
    link_budget_db : float or None
        First-path SNR of a LOS link at 1 m, dB; None: calibrated from the links.
    power_los_std, power_nlos_mean, power_nlos_std : float
        :math:`\\sigma_L`, :math:`\\mu_N`, :math:`\\sigma_N` of :math:`\\Delta`, dB.
    flag_detection, flag_false_alarm : float
        Per-impulse-response classifier's NLOS detection and false-alarm probabilities.
    clip_llr : float
        :math:`c`, bound of one round's power term.
    range_clip : float
        Range residuals enter :math:`T` clipped at this many ``los_std``: a range further
        off the smooth fit is one gross error (a noise crossing taken for the first path,
        a missed first path), whose evidence is bounded like one round's power term.
    threshold : float
        Decision threshold on :math:`\\Lambda` (0: equal priors and costs).
    """

    mse: MseNlosTest = MseNlosTest()
    kappa: float = 5.0
    link_budget_db: float | None = None
    power_los_std: float = 2.0
    power_nlos_mean: float = -11.0
    power_nlos_std: float = 5.0
    flag_detection: float = 0.65
    flag_false_alarm: float = 0.06
    clip_llr: float = 4.0
    range_clip: float = 5.0
    threshold: float = 0.0

    def power_residual(self, snr_db: FloatArray, ranges: FloatArray, budget: float) -> FloatArray:
        """:math:`\\Delta = \\mathrm{SNR} + 20 \\log_{10} r - \\mathrm{SNR}_{1m}`, dB."""
        r = np.maximum(np.asarray(ranges, float), 1e-3)
        return np.asarray(snr_db, float) + 20.0 * np.log10(r) - budget

    def calibrate(self, snr_db: Sequence[FloatArray], ranges: Sequence[FloatArray]) -> float:
        """The link budget, dB: ``link_budget_db``, or the strongest anchor's median
        :math:`\\mathrm{SNR} + 20 \\log_{10} r` over its window (one array of SNRs, dB, and
        one of ranges, m, per anchor; NaN SNRs ignored); NaN when nothing is known."""
        if self.link_budget_db is not None:
            return float(self.link_budget_db)
        medians = [float("nan")]
        for s, r in zip(snr_db, ranges, strict=True):
            lvl = self.power_residual(s, r, 0.0)
            lvl = lvl[np.isfinite(lvl)]
            if lvl.size >= self.mse.min_samples:
                medians.append(float(np.median(lvl)))
        return float(np.nanmax(medians)) if len(medians) > 1 else float("nan")

    def llr(
        self,
        t: FloatArray,
        ranges: FloatArray,
        snr_db: FloatArray,
        flags: npt.NDArray[np.bool_],
        budget: float,
    ) -> FloatArray:
        """:math:`\\Lambda` of several anchors ranged at the same times.

        Parameters
        ----------
        t : ndarray, shape (N,)
            Times, s.
        ranges, snr_db : ndarray, shape (N, k)
            Ranges (m, finite) and first-path SNRs (dB, NaN when unknown) per anchor.
        flags : ndarray, bool, shape (N, k)
            Per-impulse-response NLOS decisions (``not los``).
        budget : float
            Link budget, dB (:meth:`calibrate`); NaN: no power terms.
        """
        t = np.asarray(t, float)
        r = np.asarray(ranges, float).reshape(t.size, -1)
        k = r.shape[1]
        out = np.zeros(k)
        m = self.mse
        order = min(m.order, max(t.size - 2, 0))
        dof = t.size - order - 1
        if t.size < m.min_samples or dof < 1:
            return out
        tc = t - t.mean()
        basis = np.vander(tc / max(float(np.ptp(tc)), 1e-9), order + 1)
        coef, *_ = np.linalg.lstsq(basis, r, rcond=None)
        res = (r - basis @ coef) / m.los_std
        clip = min(m.clip, self.range_clip) if m.clip > 0 else self.range_clip
        stat = np.sum(np.clip(res, -clip, clip) ** 2, axis=0)
        kappa = max(self.kappa, 1.0 + 1e-9)
        # one-sided: steady ranges are no evidence of LOS (a frozen NLOS channel is steady)
        out += np.maximum(0.5 * stat * (1.0 - 1.0 / kappa) - 0.5 * dof * np.log(kappa), 0.0)
        if np.isfinite(budget):
            d = self.power_residual(np.asarray(snr_db, float).reshape(r.shape), r, budget)
            sl, sn, mu = self.power_los_std, self.power_nlos_std, self.power_nlos_mean
            term = np.log(sl / sn) - 0.5 * ((d - mu) / sn) ** 2 + 0.5 * (d / sl) ** 2
            term = np.clip(term, -self.clip_llr, self.clip_llr)
            out += np.sum(np.where(np.isfinite(term), term, 0.0), axis=0)
        pd, pf = self.flag_detection, self.flag_false_alarm
        f = np.asarray(flags, bool).reshape(r.shape)
        n_flag = f.sum(axis=0)
        out += n_flag * np.log(pd / pf) + (t.size - n_flag) * np.log((1.0 - pd) / (1.0 - pf))
        return out

    def decide(
        self,
        t: FloatArray,
        ranges: FloatArray,
        snr_db: FloatArray,
        flags: npt.NDArray[np.bool_],
        budget: float,
    ) -> npt.NDArray[np.bool_]:
        """NLOS decisions (True: NLOS) of anchors ranged at the same times, see :meth:`llr`."""
        return self.llr(t, ranges, snr_db, flags, budget) > self.threshold
