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
_SQRT_2PI = np.sqrt(2.0 * np.pi)
_W, _R, _V, _PRR, _PRV, _PVV, _AMP, _CH = range(8)
_NCOL = 8
_SPREAD_A = np.array([0, 0, 1])  # index pairs giving (er*er, er*ev, ev*ev)
_SPREAD_B = np.array([0, 1, 1])


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
    ``round(weight)`` times.

    Parameters
    ----------
    n_channels : int
        Number of receivers filtered (independent mixtures, processed in one vectorized pass).
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
        self._birth_row = np.zeros((1, _NCOL))
        self._birth_row[0, [_W, _PRR, _PVV]] = (
            self.birth_weight,
            self.range_var,
            self.birth_rate_var,
        )
        self.reset()

    def reset(self) -> None:
        """Empty the mixture."""
        self._t: float | None = None
        # one row per component: columns _W.._CH (weight, range and range-rate means,
        # covariance entries prr, prv, pvv, amplitude, channel); a single array keeps
        # the number of numpy calls per step small
        self._x = np.empty((0, _NCOL))

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
        dt = 0.0 if self._t is None else max(float(t) - self._t, 0.0)
        self._t = float(t)
        self._predict(dt)
        z, za, zc = self._cluster(ranges, amplitudes)
        self._update(z, za, zc)
        self._prune_merge()
        return self._extract()

    def _predict(self, dt: float) -> None:
        x = self._x
        if x.shape[0] == 0 or dt == 0.0:
            return
        q = self.q
        # mean: F m; covariance entries (prr, prv, pvv) of F P F^T + Q, as one matmul
        x[:, _R : _V + 1] = x[:, _R : _V + 1] @ np.array([[1.0, 0.0], [dt, 1.0]])
        cov_map = np.array([[1.0, 0.0, 0.0], [2.0 * dt, 1.0, 0.0], [dt * dt, dt, 1.0]])
        x[:, _PRR : _PVV + 1] = x[:, _PRR : _PVV + 1] @ cov_map + np.array(
            [q * dt**3 / 3.0, 0.5 * q * dt * dt, q * dt]
        )
        x[:, _W] *= self.ps

    def _cluster(
        self, ranges: Sequence[npt.ArrayLike], amplitudes: Sequence[npt.ArrayLike]
    ) -> tuple[FloatArray, FloatArray, npt.NDArray[np.intp]]:
        """Merge the detections of an extended echo into one measurement per cluster."""
        rs = [np.asarray(r, dtype=np.float64).ravel() for r in ranges]
        counts = [r.size for r in rs]
        if sum(counts) == 0:
            return np.empty(0), np.empty(0), np.empty(0, dtype=np.intp)
        r = np.concatenate(rs)
        a = np.concatenate([np.asarray(x, dtype=np.float64).ravel() for x in amplitudes])
        ch = np.repeat(np.arange(self.n_channels), counts)
        order = np.lexsort((r, ch))
        r, a, ch = r[order], a[order], ch[order]
        new = np.empty(r.size, dtype=bool)
        new[0] = True
        new[1:] = ((r[1:] - r[:-1]) > self.cluster_gap) | (ch[1:] != ch[:-1])
        starts = np.flatnonzero(new)
        # power-weighted centre: the strongest scatterers of a body dominate its range
        p = a * a
        psum = np.add.reduceat(p, starts)
        z = np.add.reduceat(p * r, starts) / psum
        return z, np.maximum.reduceat(a, starts), ch[starts]

    def _update(self, z: FloatArray, za: FloatArray, zc: npt.NDArray[np.intp]) -> None:
        x = self._x
        if z.size == 0:
            x[:, _W] *= 1.0 - self.pd
            return
        explained = np.zeros(z.size)
        parts = [x]
        if x.shape[0]:
            prr, prv = x[:, _PRR], x[:, _PRV]
            s = prr + self.range_var  # innovation variance, (J,)
            innov = z[None, :] - x[:, _R : _R + 1]  # (J, M)
            # pD w_j N(z; m_j, s_j), zero across receivers
            coef = x[:, _W] * (self.pd / _SQRT_2PI) / np.sqrt(s)
            num = np.exp(innov * innov * (-0.5 / s)[:, None])
            num *= coef[:, None] * (x[:, _CH : _CH + 1] == zc[None, :])
            wu = num / (self.kappa + num.sum(axis=0))
            explained = wu.sum(axis=0)
            # keep only the (component, measurement) hypotheses that matter
            jj, mm = np.nonzero(wu > self.prune_threshold)
            k0, k1 = prr / s, prv / s
            inn = innov[jj, mm]
            y = x[jj]
            kj0, kj1 = k0[jj], k1[jj]
            y[:, _W] = wu[jj, mm]
            y[:, _R] += kj0 * inn
            y[:, _V] += kj1 * inn
            y[:, _PVV] -= kj1 * y[:, _PRV]
            y[:, _PRR : _PRV + 1] *= (1.0 - kj0)[:, None]
            y[:, _AMP] = za[mm]
            x[:, _W] *= 1.0 - self.pd
            parts.append(y)
        # adaptive birth at the measurements the mixture does not explain yet
        b = np.repeat(self._birth_row, z.size, axis=0)
        b[:, _W] *= np.maximum(1.0 - explained, 0.0)  # explained >= 0
        b[:, _R] = z
        b[:, _AMP] = za
        b[:, _CH] = zc
        parts.append(b)
        self._x = np.concatenate(parts)

    def _prune_merge(self) -> None:
        """Prune light components, merge neighbours in range, cap; leaves rows sorted."""
        x = self._x
        x = x[x[:, _W] > self.prune_threshold]
        n = x.shape[0]
        if n > 1:
            x = x[np.lexsort((x[:, _R], x[:, _CH]))]
            w = x[:, _W]
            # squared Mahalanobis distance between neighbours in range, with the 2x2
            # covariance of the heavier one written out (no matrix inverse); merging
            # runs of neighbours keeps the work linear in the number of components
            dr = x[1:, _R] - x[:-1, _R]
            dv = x[1:, _V] - x[:-1, _V]
            heavy = np.where((w[1:] >= w[:-1])[:, None], x[1:], x[:-1])
            prr, prv, pvv = heavy[:, _PRR], heavy[:, _PRV], heavy[:, _PVV]
            d2 = pvv * dr * dr - 2.0 * prv * dr * dv + prr * dv * dv
            join = d2 <= self.merge_threshold * (prr * pvv - prv * prv)
            join &= x[1:, _CH] == x[:-1, _CH]
            if join.any():
                starts = np.flatnonzero(np.concatenate(([True], ~join)))
                counts = np.diff(np.append(starts, n))
                ws = np.add.reduceat(w, starts)
                # moment matching: weighted means of every column, plus the spread
                merged = np.add.reduceat(x * w[:, None], starts, axis=0) / ws[:, None]
                e = x[:, _R : _V + 1] - np.repeat(merged[:, _R : _V + 1], counts, axis=0)
                spread = e[:, _SPREAD_A] * e[:, _SPREAD_B] * w[:, None]
                merged[:, _PRR : _PVV + 1] += np.add.reduceat(spread, starts, axis=0) / ws[:, None]
                merged[:, _W] = ws
                # members share a channel; rint undoes the rounding of the weighted mean
                np.rint(merged[:, _CH], out=merged[:, _CH])
                x = merged
        if x.shape[0] > self.max_components:
            top = np.argpartition(x[:, _W], -self.max_components)[-self.max_components :]
            x = x[np.sort(top)]  # keep the (channel, range) order
        self._x = x

    def _extract(self) -> tuple[tuple[FloatArray, ...], tuple[FloatArray, ...]]:
        x = self._x
        sel = np.flatnonzero(x[:, _W] > 0.5)
        # a weight near 2 means two unresolved targets at that range
        reps = np.maximum(np.rint(x[sel, _W]), 1).astype(np.intp)
        e = x[np.repeat(sel, reps)]  # rows are sorted by (channel, range)
        bounds = np.searchsorted(e[:, _CH], np.arange(self.n_channels + 1) - 0.5).tolist()
        spans = list(itertools.pairwise(bounds))
        r, amp = e[:, _R], e[:, _AMP]
        return tuple(r[a:b] for a, b in spans), tuple(amp[a:b] for a, b in spans)
