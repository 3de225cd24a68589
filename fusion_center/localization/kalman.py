"""Kalman filters for range tracking and location tracking (Section 4 of the CoLOR chapter).

Both use filterpy's linear :class:`~filterpy.kalman.KalmanFilter` with a nearly-constant-
velocity model (white acceleration of spectral density ``q``, m²/s³): per anchor on
``[range, range rate]``, and on the position ``[x, vx, y, vy]`` (world frame, the state order of
:mod:`fusion_center.tracking`) with the snapshot fixes and their covariances as measurements.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from filterpy.kalman import KalmanFilter

FloatArray = npt.NDArray[np.float64]


def _cv_1d(dt: float, q: float) -> tuple[FloatArray, FloatArray]:
    """Transition and process noise of one nearly-constant-velocity axis."""
    f = np.array([[1.0, dt], [0.0, 1.0]])
    qm = q * np.array([[dt**3 / 3.0, dt**2 / 2.0], [dt**2 / 2.0, dt]])
    return f, qm


class RangeKalmanTracker:
    """Tracks one node-to-anchor range: state ``[r, dr/dt]`` (m, m/s).

    Parameters
    ----------
    q : float
        Acceleration noise spectral density of the range, m²/s³.
    """

    def __init__(self, q: float = 0.5) -> None:
        self.q = q
        self._kf: KalmanFilter | None = None
        self._t = 0.0

    def step(self, t: float, measured: float, std: float) -> tuple[float, float]:
        """Predict to ``t`` and update with one range; returns ``(range, std)``, m."""
        if self._kf is None:
            kf = KalmanFilter(dim_x=2, dim_z=1)
            kf.x = np.array([measured, 0.0])
            kf.P = np.diag([std**2, 4.0])
            kf.H = np.array([[1.0, 0.0]])
            self._kf, self._t = kf, t
            return measured, std
        kf = self._kf
        dt = max(t - self._t, 0.0)
        kf.F, kf.Q = _cv_1d(dt, self.q)
        kf.predict()
        kf.update(np.array([measured]), R=np.array([[std**2]]))
        self._t = t
        return float(kf.x[0]), float(np.sqrt(kf.P[0, 0]))


class PositionKalmanTracker:
    """Tracks a mobile node's horizontal position: state ``[x, vx, y, vy]``.

    Parameters
    ----------
    q : float
        Acceleration noise spectral density per axis, m²/s³.
    """

    def __init__(self, q: float = 0.5) -> None:
        self.q = q
        self._kf: KalmanFilter | None = None
        self._t = 0.0

    @property
    def initialised(self) -> bool:
        return self._kf is not None

    def predict(
        self, t: float, q: float | None = None, fading: float = 1.0
    ) -> tuple[FloatArray, FloatArray] | None:
        """Predicted ``(state, cov)`` at ``t`` without changing the filter (None before the
        first fix); ``q`` overrides the acceleration noise density of this prediction and
        ``fading`` (>= 1) multiplies the propagated covariance (fading memory)."""
        if self._kf is None:
            return None
        f, qm = self._transition(max(t - self._t, 0.0), q)
        return f @ self._kf.x, fading * (f @ self._kf.P @ f.T) + qm

    def _transition(self, dt: float, q: float | None = None) -> tuple[FloatArray, FloatArray]:
        f1, q1 = _cv_1d(dt, self.q if q is None else q)
        f, qm = np.zeros((4, 4)), np.zeros((4, 4))
        f[:2, :2] = f[2:, 2:] = f1
        qm[:2, :2] = qm[2:, 2:] = q1
        return f, qm

    def step(
        self,
        t: float,
        position: FloatArray | None,
        cov: FloatArray | None,
        q: float | None = None,
        fading: float = 1.0,
    ):
        """Predict to ``t`` and update with a fix (``position`` (2,), ``cov`` (2, 2)) if given;
        ``q`` overrides the acceleration noise density of this step (a manoeuvre) and
        ``fading`` (>= 1) multiplies the propagated covariance (filterpy's fading memory,
        ``alpha`` squared).

        Returns
        -------
        state : ndarray, shape (4,)
            ``[x, vx, y, vy]``.
        cov : ndarray, shape (4, 4)
        """
        h = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]])
        if self._kf is None:
            if position is None or cov is None:
                raise ValueError("the first step needs a fix")
            kf = KalmanFilter(dim_x=4, dim_z=2)
            kf.x = np.array([position[0], 0.0, position[1], 0.0])
            kf.P = np.diag([cov[0, 0], 1.0, cov[1, 1], 1.0])
            kf.P[0, 2] = kf.P[2, 0] = cov[0, 1]
            kf.H = h
            self._kf, self._t = kf, t
            return kf.x.copy(), kf.P.copy()
        kf = self._kf
        kf.F, kf.Q = self._transition(max(t - self._t, 0.0), q)
        kf.alpha = float(np.sqrt(max(fading, 1.0)))
        kf.predict()
        kf.alpha = 1.0
        if position is not None and cov is not None:
            kf.update(np.asarray(position, float), R=np.asarray(cov, float))
        self._t = t
        return kf.x.copy(), kf.P.copy()
