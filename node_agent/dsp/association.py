"""Pairing of two receivers' ranges that belong to the same target (eqs. (24)-(25))."""

from __future__ import annotations

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

    Among the admissible pairs :math:`|r_{1,i} - r_{2,j}| \\le T_s` the assignment
    minimising :math:`\\sum |r_{1,i} - r_{2,j}|` is chosen (Hungarian algorithm), so each
    range is used at most once.

    Parameters
    ----------
    threshold : float
        :math:`T_s` in m, see :func:`pairing_threshold`.
    """

    def __init__(self, threshold: float) -> None:
        if threshold <= 0:
            raise ValueError(f"threshold must be positive, got {threshold}")
        self.threshold = float(threshold)

    def associate(self, r1: npt.ArrayLike, r2: npt.ArrayLike) -> tuple[IntArray, IntArray]:
        """Pair the ranges of receiver 1 with those of receiver 2.

        Parameters
        ----------
        r1 : array_like, float64, shape (k1,)
            Ranges at receiver 1, m.
        r2 : array_like, float64, shape (k2,)
            Ranges at receiver 2, m.

        Returns
        -------
        i1, i2 : ndarray, intp, shape (p,)
            Indices into ``r1`` and ``r2`` of the paired ranges.
        """
        a = np.asarray(r1, dtype=np.float64).ravel()
        b = np.asarray(r2, dtype=np.float64).ravel()
        if a.size == 0 or b.size == 0:
            return np.empty(0, dtype=np.intp), np.empty(0, dtype=np.intp)
        cost = np.abs(a[:, None] - b[None, :])
        admissible = cost <= self.threshold
        if not admissible.any():
            return np.empty(0, dtype=np.intp), np.empty(0, dtype=np.intp)
        rows_ok = admissible.sum(axis=1)
        if rows_ok.max() <= 1 and admissible.sum(axis=0).max() <= 1:
            # no range competes for another: the admissible pairs are the assignment
            i1, i2 = admissible.nonzero()
            return i1.astype(np.intp), i2.astype(np.intp)
        # inadmissible pairs cost more than any admissible assignment, then get dropped
        big = self.threshold * (min(a.size, b.size) + 1.0)
        i1, i2 = linear_sum_assignment(np.where(admissible, cost, big))
        ok = admissible[i1, i2]
        return i1[ok].astype(np.intp), i2[ok].astype(np.intp)
