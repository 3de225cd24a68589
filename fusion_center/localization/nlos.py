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
