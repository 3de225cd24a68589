"""Measurement-space data association: Kalman grouping of echo tracks (Section 6.3).

While the robot turns in small steps, an echo's pair of ranges ``(r1, r2)`` moves smoothly
from one acquisition to the next. A constant-velocity Kalman filter per echo track (state
``r1, r2, dr1, dr2`` per acquisition) with global-nearest-neighbour assignment (Hungarian,
chi-square gate) groups the pairs of consecutive acquisitions. Each pair gets the id of its
track; the SLAM filter associates a whole group with one landmark (the association is
sampled once per particle, when the group's first pair reaches the filter), and groups that
never reach ``confirm`` pairs are dropped as clutter. This is the second association method
of Section 6.3 of the CoLOR chapter; the first (state space) is in
:mod:`fusion_center.mapping.rbpf`.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from scipy.optimize import linear_sum_assignment

FloatArray = npt.NDArray[np.float64]

_F = np.block([[np.eye(2), np.eye(2)], [np.zeros((2, 2)), np.eye(2)]])
_H = np.hstack([np.eye(2), np.zeros((2, 2))])


class KalmanEchoGrouper:
    """Groups pairs of ranges across consecutive acquisitions.

    Parameters
    ----------
    range_sigma : float
        Measurement noise of one range, m.
    accel_sigma : float
        Process noise on the range rate, m per acquisition squared.
    gate : float
        Chi-square gate on the 2-D innovation (9.21: 99 %).
    max_misses : int
        Consecutive acquisitions without a pair after which a track ends.
    """

    def __init__(
        self,
        *,
        range_sigma: float = 0.02,
        accel_sigma: float = 0.03,
        gate: float = 9.21,
        max_misses: int = 2,
    ) -> None:
        self.r = range_sigma**2 * np.eye(2)
        g = np.vstack([0.5 * np.eye(2), np.eye(2)])
        self.q = accel_sigma**2 * g @ g.T
        self.gate = float(gate)
        self.max_misses = int(max_misses)
        self._x = np.zeros((0, 4))
        self._p = np.zeros((0, 4, 4))
        self._id = np.zeros(0, np.int64)
        self._miss = np.zeros(0, np.int64)
        self._next = 0
        #: hits per group id
        self.hits: dict[int, int] = {}

    def reset(self) -> None:
        """End every track (e.g. after the robot drove to a new stop)."""
        self._x = np.zeros((0, 4))
        self._p = np.zeros((0, 4, 4))
        self._id = np.zeros(0, np.int64)
        self._miss = np.zeros(0, np.int64)

    def step(self, z: FloatArray) -> npt.NDArray[np.int64]:
        """Assign this acquisition's pairs to tracks; return their group ids.

        Parameters
        ----------
        z : ndarray, shape (m, 2)
            Pairs ``(r1, r2)``, m.

        Returns
        -------
        ndarray, int64, shape (m,)
            Group id of each pair (a new id starts a new track).
        """
        x = self._x @ _F.T
        p = _F @ self._p @ _F.T + self.q
        ids = np.full(z.shape[0], -1, np.int64)
        matched_t = np.zeros(x.shape[0], bool)
        if x.shape[0] and z.shape[0]:
            s = _H @ p @ _H.T + self.r  # (t, 2, 2)
            nu = z[None, :, :] - x[:, None, :2]  # (t, m, 2)
            d2 = np.einsum("tmi,tij,tmj->tm", nu, np.linalg.inv(s), nu)
            cost = np.where(d2 <= self.gate, d2, 1e9)
            ti, mi = linear_sum_assignment(cost)
            ok = cost[ti, mi] < 1e9
            ti, mi = ti[ok], mi[ok]
            k = p[ti] @ _H.T @ np.linalg.inv(s[ti])  # (k, 4, 2)
            x[ti] = x[ti] + np.einsum("kij,kj->ki", k, nu[ti, mi])
            p[ti] = (np.eye(4) - k @ _H) @ p[ti]
            ids[mi] = self._id[ti]
            matched_t[ti] = True
        miss = np.where(matched_t, 0, self._miss + 1)
        keep = miss <= self.max_misses
        new = np.flatnonzero(ids < 0)
        new_ids = self._next + np.arange(new.size)
        self._next += new.size
        ids[new] = new_ids
        p0 = np.diag([self.r[0, 0], self.r[1, 1], 0.05**2, 0.05**2])
        self._x = np.vstack([x[keep], np.hstack([z[new], np.zeros((new.size, 2))])])
        self._p = np.concatenate([p[keep], np.broadcast_to(p0, (new.size, 4, 4))])
        self._id = np.concatenate([self._id[keep], new_ids])
        self._miss = np.concatenate([miss[keep], np.zeros(new.size, np.int64)])
        for g in ids.tolist():
            self.hits[g] = self.hits.get(g, 0) + 1
        return ids
