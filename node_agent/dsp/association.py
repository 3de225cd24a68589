"""Pairing of two receivers' ranges that belong to the same target (eqs. (24)-(25))."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt
from scipy.optimize import linear_sum_assignment

IntArray = npt.NDArray[np.intp]


def pairing_threshold(rx1: npt.ArrayLike, rx2: npt.ArrayLike, margin: float) -> float:
    """The admissible range difference :math:`T_s` of two receivers.

    For any point :math:`p`, the triangle inequality bounds the difference of the two
    bistatic ranges of a common transmitter by the receiver baseline,

    .. math::

        |r_1 - r_2| = \\big| \\|p - rx_1\\| - \\|p - rx_2\\| \\big| \\le \\|rx_1 - rx_2\\|
        \\le T_s = \\|rx_1 - rx_2\\| + \\text{margin}

    (eqs. (24)-(25) of the CoLOR chapter); the margin absorbs range errors.

    Parameters
    ----------
    rx1, rx2 : array_like, shape (2,) or (3,)
        Receiver positions, m.
    margin : float
        Allowance for range errors, m.
    """
    return float(np.linalg.norm(np.asarray(rx1, float) - np.asarray(rx2, float)) + margin)


class RangePairAssociator:
    """Pairs ranges of two receivers by a minimum-cost assignment under eq. (24)-(25).

    Only pairs with :math:`|r_{1,i} - r_{2,j}| \\le T_s` are admissible; the assignment
    pairs as many ranges as possible, each at most once (Hungarian algorithm), at the
    least total cost. Any point of the field of view gives an admissible pair, so the range
    difference itself says little about which pair is right (preferring small differences
    pulls the pairing of two people at similar ranges towards the sensor's axis, where the
    swapped pairing puts two ghosts). What identifies one person's two echoes is that they
    move together and come from one body. The cost of a pair is therefore

    .. math::

        c_{ij} = \\frac{(\\dot r_{1,i} - \\dot r_{2,j})^2}{\\sigma_{\\dot r,1,i}^2 +
        \\sigma_{\\dot r,2,j}^2 + \\sigma_{\\dot r}^2} + \\frac{(\\ln a_{1,i} -
        \\ln a_{2,j})^2}{\\sigma_{\\ln a}^2} + \\frac{|r_{1,i} - r_{2,j}|}{T_s}\\,\\epsilon

    with the range rates :math:`\\dot r` and their variances from the range GM-PHD, and the
    echo amplitudes :math:`a`. :math:`\\sigma_{\\dot r}` allows for the true difference of
    one person's range rates at two receivers, :math:`|v| \\cdot |u_1 - u_2| \\lesssim
    |v|\\, b / d` for a baseline :math:`b` at distance :math:`d` (0.3 m/s at 1.2 m/s, 1 m,
    4 m); :math:`\\sigma_{\\ln a}` the difference of one body's echo strength at two
    receivers (speckle of its scatterers, antenna patterns). The small last term
    (:math:`\\epsilon = 10^{-3}`) only breaks ties, and is the whole cost when rates and
    amplitudes are not given.

    Parameters
    ----------
    threshold : float
        :math:`T_s` in m, see :func:`pairing_threshold`.
    rate_std : float
        :math:`\\sigma_{\\dot r}`, m/s.
    log_amplitude_std : float
        :math:`\\sigma_{\\ln a}` (natural log of the amplitude ratio).
    """

    def __init__(
        self, threshold: float, rate_std: float = 0.3, log_amplitude_std: float = 0.7
    ) -> None:
        if threshold <= 0:
            raise ValueError(f"threshold must be positive, got {threshold}")
        self.threshold = float(threshold)
        self.rate_var = float(rate_std) ** 2
        self.log_amplitude_var = float(log_amplitude_std) ** 2

    def associate(
        self,
        r1: npt.ArrayLike,
        r2: npt.ArrayLike,
        features1: npt.ArrayLike | None = None,
        features2: npt.ArrayLike | None = None,
    ) -> tuple[IntArray, IntArray]:
        """Pair the ranges of receiver 1 with those of receiver 2.

        Parameters
        ----------
        r1 : array_like, float64, shape (k1,)
            Ranges at receiver 1, m.
        r2 : array_like, float64, shape (k2,)
            Ranges at receiver 2, m.
        features1, features2 : array_like, float64, shape (3, k1) and (3, k2), optional
            Rows: range-rate variance (m^2/s^2), range rate (m/s), amplitude (> 0).
            Without them the pairs of least range difference are chosen.

        Returns
        -------
        i1, i2 : ndarray, intp, shape (p,)
            Indices into ``r1`` and ``r2`` of the paired ranges.
        """
        f1 = f2 = None
        if features1 is not None and features2 is not None:
            f1 = np.asarray(features1, dtype=np.float64).T.tolist()
            f2 = np.asarray(features2, dtype=np.float64).T.tolist()
        i1, i2 = self.associate_lists(
            np.asarray(r1, dtype=np.float64).ravel().tolist(),
            np.asarray(r2, dtype=np.float64).ravel().tolist(),
            f1,
            f2,
        )
        return np.array(i1, dtype=np.intp), np.array(i2, dtype=np.intp)

    def associate_lists(
        self,
        r1: Sequence[float],
        r2: Sequence[float],
        features1: Sequence[Sequence[float]] | None = None,
        features2: Sequence[Sequence[float]] | None = None,
    ) -> tuple[list[int], list[int]]:
        """:meth:`associate` on Python lists: a node pairs a few ranges per impulse response,
        where plain float arithmetic costs less than the numpy calls it replaces.

        Parameters
        ----------
        r1, r2 : sequence of float, length k1 and k2
            Ranges at receivers 1 and 2, m.
        features1, features2 : sequence of (rate variance, rate, amplitude), optional
            One triple per range (the columns of :meth:`associate`'s feature rows).

        Returns
        -------
        i1, i2 : list of int
            Indices into ``r1`` and ``r2`` of the paired ranges.
        """
        thr = self.threshold
        pairs = [(i, j) for i, x in enumerate(r1) for j, y in enumerate(r2) if abs(x - y) <= thr]
        if not pairs:
            return [], []
        i1 = [i for i, _ in pairs]
        i2 = [j for _, j in pairs]
        if len(pairs) == len(set(i1)) == len(set(i2)):
            # no range competes for another: the admissible pairs are the assignment
            return i1, i2
        tie = 1e-3 / thr
        cost = [[abs(x - y) * tie for y in r2] for x in r1]
        if features1 is not None and features2 is not None:
            rate_var, amp_var = self.rate_var, self.log_amplitude_var
            # an amplitude of 0 has log -inf: its squared difference is capped below
            log2 = [math.log(a) if a > 0 else -math.inf for _, _, a in features2]
            for row, (v1, d1, a1) in zip(cost, features1, strict=True):
                la = math.log(a1) if a1 > 0 else -math.inf
                for j, ((v2, d2, _), lb) in enumerate(zip(features2, log2, strict=True)):
                    dv, dl = d1 - d2, la - lb
                    row[j] += dv * dv / (v1 + v2 + rate_var)
                    row[j] += min(dl * dl, 1e6) / amp_var
        # inadmissible pairs cost more than any admissible assignment, then get dropped
        big = (max(cost[i][j] for i, j in pairs) + 1.0) * (min(len(r1), len(r2)) + 1.0)
        admissible = set(pairs)
        matrix = [
            [c if (i, j) in admissible else big for j, c in enumerate(row)]
            for i, row in enumerate(cost)
        ]
        rows, cols = linear_sum_assignment(np.array(matrix))
        pairs = [p for p in zip(rows.tolist(), cols.tolist(), strict=True) if p in admissible]
        return [i for i, _ in pairs], [j for _, j in pairs]
