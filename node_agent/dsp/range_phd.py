"""Per-receiver range GM-PHD filter (Section 9.2.1 of the CoLOR chapter).

Cleans the CFAR detections of each receiver: clutter is suppressed, the several
detections of one extended person are merged, and short detection gaps are bridged.
The state of a component is ``[range, range_rate]`` (bistatic, m and m/s).
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]
# columns of a component row: weight, covariance entries (prr, prv, pvv), mean (range,
# range rate), amplitude, channel (node_agent.dsp.kernels works on these rows)
_W, _PRR, _PRV, _PVV, _R, _V, _AMP, _CH = range(8)
_NCOL = 8
# channel c lives on the stretch [c * _CH_SPAN, (c + 1) * _CH_SPAN) of one range axis:
# innovations across channels are ~1e6 m, so their likelihood is exactly 0 and their
# components never merge, with no channel masks (float64 keeps 1e-10 m resolution there)
_CH_SPAN = 1.0e6
ESTIMATE_COLUMNS = ("range_rate_var", "range", "range_rate", "amplitude", "channel")
"""Columns of the estimate rows returned by :meth:`RangeGmPhdFilter.step_detections`."""


class RangeGmPhdFilter:
    """Gaussian-mixture PHD filter on bistatic range, one independent mixture per receiver.

    Prediction (constant velocity, white-acceleration noise of spectral density ``q``):

    .. math::

        m^- = F m, \\quad P^- = F P F^T + Q, \\quad F = \\begin{bmatrix}1 & \\Delta t\\\\
        0 & 1\\end{bmatrix}, \\quad Q = q \\begin{bmatrix}\\Delta t^3/3 & \\Delta t^2/2\\\\
        \\Delta t^2/2 & \\Delta t\\end{bmatrix}, \\quad w^- = p_S w

    Update with measurements :math:`z` (one per cluster of detections closer than
    ``cluster_gap``, the amplitude-weighted centre of an extended echo):

    .. math::

        w_{j}(z) = \\frac{p_D w_j \\mathcal{N}(z; m_{r,j}, S_j)}
        {\\kappa + p_D \\sum_l w_l \\mathcal{N}(z; m_{r,l}, S_l)}, \\qquad
        w_j^{miss} = (1 - p_D) w_j

    as in Section 9.2.1 of the CoLOR chapter (Vo and Ma's GM-PHD). Births are placed at the
    measurements, weighted by how little the existing mixture explains them. Components
    are pruned, merged (runs of range neighbours within the squared Mahalanobis distance
    ``merge_threshold`` of each other, moment-matched) and capped.
    Estimates are the means of components with weight above 0.5, repeated
    ``round(weight)`` times. One cycle is one call of the compiled kernel
    :func:`node_agent.dsp.kernels.range_phd_step`.

    Parameters
    ----------
    n_channels : int
        Number of receivers filtered (independent mixtures, processed in one pass).
    range_std : float
        Measurement standard deviation of a range, m.
    process_noise : float
        Acceleration spectral density ``q`` of the range, m^2/s^3.
    detection_probability : float
        :math:`p_D`.
    survival_probability : float
        :math:`p_S` per step.
    clutter_intensity : float
        :math:`\\kappa`, expected false measurements per metre of range per step.
    birth_weight : float
        Weight of a birth at an unexplained measurement.
    birth_rate_std : float
        Standard deviation of a birth's range rate, m/s.
    cluster_gap : float
        Detections of one receiver closer than this (m) form one measurement.
    prune_threshold, merge_threshold : float
        Weight below which components are dropped; squared Mahalanobis merge gate.
    max_components : int
        Cap on the number of components over all channels.
    """

    def __init__(
        self,
        *,
        n_channels: int = 1,
        range_std: float = 0.05,
        process_noise: float = 2.0,
        detection_probability: float = 0.8,
        survival_probability: float = 0.99,
        clutter_intensity: float = 0.01,
        birth_weight: float = 0.1,
        birth_rate_std: float = 2.0,
        cluster_gap: float = 0.4,
        prune_threshold: float = 1e-3,
        merge_threshold: float = 4.0,
        max_components: int = 60,
    ) -> None:
        self.n_channels = int(n_channels)
        self.range_var = float(range_std) ** 2
        self.q = float(process_noise)
        self.pd = float(detection_probability)
        self.ps = float(survival_probability)
        self.kappa = float(clutter_intensity)
        self.birth_weight = float(birth_weight)
        self.birth_rate_var = float(birth_rate_std) ** 2
        self.cluster_gap = float(cluster_gap)
        self.prune_threshold = float(prune_threshold)
        self.merge_threshold = float(merge_threshold)
        self.max_components = int(max_components)
        self._channel_edges = np.arange(self.n_channels + 1) - 0.5
        # imported here, not at the top: numba's import and the kernel's (cached) compile
        # are paid only by processes that filter ranges, not by every user of node_agent.dsp
        from . import kernels

        self._kernel = kernels.range_phd_step
        par = np.empty(kernels.N_PARAMS)
        par[kernels.P_PD] = self.pd
        par[kernels.P_RANGE_VAR] = self.range_var
        par[kernels.P_KAPPA] = self.kappa
        par[kernels.P_BIRTH_WEIGHT] = self.birth_weight
        par[kernels.P_BIRTH_RATE_VAR] = self.birth_rate_var
        par[kernels.P_CLUSTER_GAP] = self.cluster_gap
        par[kernels.P_PRUNE] = self.prune_threshold
        par[kernels.P_MERGE] = self.merge_threshold
        par[kernels.P_MAX_COMPONENTS] = self.max_components
        par[kernels.P_CH_SPAN] = _CH_SPAN
        self._par = par
        self._no_prediction = np.zeros(kernels.N_TRANSITION)
        self.reset()

    def reset(self) -> None:
        """Empty the mixture."""
        self._t: float | None = None
        # one row per component (columns _W.._CH); a single array keeps the number of
        # numpy calls per step small, whatever the number of channels
        self._x = np.empty((0, _NCOL))
        self._dt = -1.0
        self._transition = self._no_prediction

    @property
    def expected_count(self) -> FloatArray:
        """Expected number of targets per channel (sum of weights), shape (n_channels,)."""
        x = self._x
        return np.bincount(x[:, _CH].astype(np.intp), weights=x[:, _W], minlength=self.n_channels)

    def step(
        self, t: float, ranges: npt.ArrayLike, amplitudes: npt.ArrayLike
    ) -> tuple[FloatArray, FloatArray]:
        """One predict-update-extract cycle of a single-receiver filter.

        Parameters
        ----------
        t : float
            Time of the impulse response, s.
        ranges : array_like, float64, shape (k,)
            CFAR detections, bistatic range in m.
        amplitudes : array_like, float64, shape (k,)
            Their amplitudes.

        Returns
        -------
        ranges, amplitudes : ndarray, float64, shape (l,)
            Estimated target ranges (m, ascending) and their amplitudes.
        """
        if self.n_channels != 1:
            raise ValueError("step() is for one channel; use step_channels()")
        r, a = self.step_channels(t, (ranges,), (amplitudes,))
        return r[0], a[0]

    def step_channels(
        self,
        t: float,
        ranges: Sequence[npt.ArrayLike],
        amplitudes: Sequence[npt.ArrayLike],
    ) -> tuple[tuple[FloatArray, ...], tuple[FloatArray, ...]]:
        """One cycle for all receivers at once (independent mixtures, one numpy pass).

        Parameters
        ----------
        t : float
            Time, s.
        ranges, amplitudes : sequence of n_channels array_like, float64, shape (k_i,)
            Per receiver, CFAR detections (m) and their amplitudes.

        Returns
        -------
        ranges, amplitudes : tuple of n_channels ndarray, float64, shape (l_i,)
            Per receiver, estimated target ranges (m, ascending) and amplitudes.
        """
        if len(ranges) != self.n_channels or len(amplitudes) != self.n_channels:
            raise ValueError(f"expected {self.n_channels} channels, got {len(ranges)}")
        rs = [np.asarray(r, dtype=np.float64).ravel() for r in ranges]
        r = np.concatenate(rs)
        a = np.concatenate([np.asarray(x, dtype=np.float64).ravel() for x in amplitudes])
        ch = np.repeat(np.arange(self.n_channels), [x.size for x in rs])
        order = np.lexsort((r, ch))
        est = self.step_detections(t, r[order], a[order], ch[order])
        spans = self.channel_spans(est)
        return (
            tuple(est[i:j, 1] for i, j in spans),
            tuple(est[i:j, 3] for i, j in spans),
        )

    def channel_spans(self, estimates: FloatArray) -> list[tuple[int, int]]:
        """Row ranges ``[(start, stop), ...]`` of each channel in :meth:`step_detections` rows."""
        bounds = np.searchsorted(estimates[:, 4], self._channel_edges)
        return list(itertools.pairwise(bounds.tolist()))

    def step_detections(
        self,
        t: float,
        ranges: FloatArray,
        amplitudes: FloatArray,
        channels: npt.NDArray[np.intp],
    ) -> FloatArray:
        """One cycle on the detections of all channels, given as flat sorted arrays.

        Parameters
        ----------
        t : float
            Time, s.
        ranges, amplitudes : ndarray, float64, shape (k,)
            CFAR detections (m) and their amplitudes, sorted by (channel, range).
        channels : ndarray, int, shape (k,)
            Channel of each detection.

        Returns
        -------
        ndarray, float64, shape (l, 5)
            Estimates sorted by (channel, range), columns :data:`ESTIMATE_COLUMNS`:
            variance of the range rate (m^2/s^2), range (m), range rate (m/s),
            amplitude, channel (as float).
        """
        dt = 0.0 if self._t is None else max(float(t) - self._t, 0.0)
        self._t = float(t)
        transition = self._no_prediction
        if dt != 0.0 and self._x.shape[0]:
            if abs(dt - self._dt) > 1e-6:
                # rebuilt only when the step changes by more than 1 us (timestamps jitter;
                # 1 us moves a walker by a micrometre)
                self._dt, self._transition = dt, self._prediction(dt)
            transition = self._transition
        if channels.dtype != np.intp:  # the kernel is compiled for one signature
            channels = channels.astype(np.intp)
        self._x, est = self._kernel(self._x, transition, ranges, amplitudes, channels, self._par)
        return est

    def _prediction(self, dt: float) -> FloatArray:
        """The kernel's prediction vector: ``x @ F + Q`` written out for step ``dt`` (s)."""
        from . import kernels

        v = np.empty(kernels.N_TRANSITION)
        q = self.q
        v[kernels.T_PS] = self.ps
        v[kernels.T_DT] = dt
        v[kernels.T_2DT] = 2.0 * dt
        v[kernels.T_DT2] = dt * dt
        v[kernels.T_QRR] = q * dt**3 / 3.0
        v[kernels.T_QRV] = 0.5 * q * dt * dt
        v[kernels.T_QVV] = q * dt
        return v
