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
# columns of a component row: weight, covariance entries (prr, prv, pvv), mean (range,
# range rate), amplitude, channel; pvv to channel are contiguous so that an estimate is a
# slice of a row
_W, _PRR, _PRV, _PVV, _R, _V, _AMP, _CH = range(8)
_NCOL = 8
# channel c lives on the stretch [c * _CH_SPAN, (c + 1) * _CH_SPAN) of one range axis:
# innovations across channels are ~1e6 m, so their likelihood is exactly 0 and their
# components never merge, with no channel masks (float64 keeps 1e-10 m resolution there)
_CH_SPAN = 1.0e6
# Kalman covariance update (prr, prv, pvv) -= gain[_GAIN_COLS] * row[_COV_COLS]
_GAIN_COLS = np.array([0, 0, 1])
_COV_COLS = np.array([_PRR, _PRV, _PRV])
# moment-matching spread (w e_r e_r, w e_r e_v, w e_v e_v) = (w e)[:, left] * e[:, right]
_SPREAD_LEFT = np.array([0, 0, 1])
_SPREAD_RIGHT = np.array([0, 1, 1])
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
        self._channel_edges = np.arange(self.n_channels + 1) - 0.5
        # survivors' missed-detection row scale: w *= 1 - pD, every other column kept
        self._miss_scale = np.ones(_NCOL)
        self._miss_scale[_W] = 1.0 - self.pd
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
        # one row per component (columns _W.._CH); a single array keeps the number of
        # numpy calls per step small, whatever the number of channels
        self._x = np.empty((0, _NCOL))
        self._dt = -1.0
        self._transition = np.eye(_NCOL)
        self._noise = np.zeros(_NCOL)

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
        self._predict(dt)
        z, za, zc = self._cluster(ranges, amplitudes, channels)
        self._update(z, za, zc)
        self._prune_merge()
        return self._extract()

    def _predict(self, dt: float) -> None:
        x = self._x
        if x.shape[0] == 0 or dt == 0.0:
            return
        if abs(dt - self._dt) > 1e-6:
            # x_row @ transition: range += dt * rate, (prr, prv, pvv) of F P F^T, w *= pS;
            # then + noise (Q and nothing else); rebuilt only when the step changes by more
            # than 1 us (timestamps jitter; 1 us moves a walker by a micrometre)
            f = np.eye(_NCOL)
            f[_W, _W] = self.ps
            f[_V, _R] = dt
            f[_PRV, _PRR] = 2.0 * dt
            f[_PVV, _PRR] = dt * dt
            f[_PVV, _PRV] = dt
            q = self.q
            noise = np.zeros(_NCOL)
            noise[_PRR : _PVV + 1] = (q * dt**3 / 3.0, 0.5 * q * dt * dt, q * dt)
            self._dt, self._transition, self._noise = dt, f, noise
        x = x @ self._transition
        x += self._noise
        self._x = x

    def _cluster(
        self, r: FloatArray, a: FloatArray, ch: npt.NDArray[np.intp]
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Merge the detections of an extended echo into one measurement per cluster.

        Returns the measurements on the channel-offset range axis, their amplitudes and
        channels (as float).
        """
        if r.size == 0:
            return r, a, r
        key = ch * _CH_SPAN  # float64 from the integer channels, without a separate cast
        key += r
        # a cluster starts after a gap wider than cluster_gap; a dozen detections per
        # impulse response: one list pass costs less than the numpy calls it replaces
        kl = key.tolist()
        gap = self.cluster_gap
        first = [i for i in range(1, len(kl)) if kl[i] - kl[i - 1] > gap]
        if len(first) == len(kl) - 1:  # no extended echo: every detection is a measurement
            return key, a, ch
        starts = np.array([0, *first], dtype=np.intp)
        # power-weighted centre: the strongest scatterers of a body dominate its range
        p = a * a
        z = np.add.reduceat(p * key, starts) / np.add.reduceat(p, starts)
        return z, np.maximum.reduceat(a, starts), ch[starts]

    def _update(self, z: FloatArray, za: FloatArray, zc: FloatArray) -> None:
        x = self._x
        m = z.size
        if m == 0:
            x[:, _W] *= 1.0 - self.pd
            return
        n = x.shape[0]
        k = n
        out = None
        if n:
            s = x[:, _PRR] + self.range_var  # innovation variance, (J,)
            innov = z - x[:, _R, None]  # (J, M); exactly 0 likelihood across channels
            lik = innov * innov
            lik *= (-0.5 / s)[:, None]
            np.exp(lik, out=lik)
            # pD w_j N(z; m_j, s_j), normalised over components and clutter
            lik *= (x[:, _W] * (self.pd / _SQRT_2PI) / np.sqrt(s))[:, None]
            den = np.add.reduce(lik, 0)
            den += self.kappa
            lik /= den
            # keep only the (component, measurement) hypotheses that matter
            jj, mm = (lik > self.prune_threshold).nonzero()
            k = n + jj.size
            # one allocation for survivors, updated hypotheses and births
            out = np.empty((k + m, _NCOL))
            np.multiply(x, self._miss_scale, out=out[:n])  # w *= 1 - pD, the rest kept
            hyp = out[n:k]
            x.take(jj, axis=0, out=hyp)
            # gain (k_r, k_v) = P H^T / s and posterior covariance P - K H P
            gain = hyp[:, _PRR : _PRV + 1] / s.take(jj)[:, None]
            # (prr, prv, pvv) -= (k_r prr, k_r prv, k_v prv)
            hyp[:, _PRR : _PVV + 1] -= gain[:, _GAIN_COLS] * hyp[:, _COV_COLS]
            hyp[:, _R : _V + 1] += gain * innov[jj, mm][:, None]
            hyp[:, _W] = lik[jj, mm]
            hyp[:, _AMP] = za.take(mm)
            # 1 - (explained share of each measurement) is kappa / den
            explained = den
        else:
            out = np.empty((m, _NCOL))
        # adaptive birth at the measurements the mixture does not explain yet
        b = out[k:]
        b[:] = self._birth_row
        if n:
            np.divide(self.birth_weight * self.kappa, explained, out=b[:, _W])
        b[:, _R] = z
        b[:, _AMP] = za
        b[:, _CH] = zc
        self._x = out

    def _prune_merge(self) -> None:
        """Prune light components, merge neighbours in range, cap; leaves rows sorted."""
        x = self._x
        x = x.compress(x[:, _W] > self.prune_threshold, axis=0)
        n = x.shape[0]
        if n > 1:
            # sorting the channel-offset range sorts by (channel, range)
            x = x.take(x[:, _R].argsort(), axis=0)
            w = x[:, _W]
            # squared Mahalanobis distance between neighbours in range, with the 2x2
            # covariance of the heavier one written out (no matrix inverse); merging
            # runs of neighbours keeps the work linear in the number of components
            dr, dv = (x[1:, _R : _V + 1] - x[:-1, _R : _V + 1]).T
            cov = np.where(
                (w[1:] >= w[:-1])[:, None], x[1:, _PRR : _PVV + 1], x[:-1, _PRR : _PVV + 1]
            )
            prr, prv, pvv = cov.T
            # d^T adj(P) d <= gate * det(P)
            d2 = (pvv * dr - 2.0 * prv * dv) * dr + prr * dv * dv
            first = np.empty(n, dtype=bool)
            first[0] = True
            # not joined to the previous row: a NaN distance starts a group too
            np.less_equal(d2, self.merge_threshold * (prr * pvv - prv * prv), out=first[1:])
            np.logical_not(first[1:], out=first[1:])
            starts = first.nonzero()[0]
            if starts.size < n:
                group = np.add.accumulate(first) - 1
                ws = np.add.reduceat(w, starts)
                # moment matching: weighted means of every column, plus the spread
                merged = np.add.reduceat(x * w[:, None], starts, axis=0) / ws[:, None]
                e = x[:, _R : _V + 1] - merged[group, _R : _V + 1]
                # (w e_r e_r, w e_r e_v, w e_v e_v)
                spread = (e * w[:, None])[:, _SPREAD_LEFT] * e[:, _SPREAD_RIGHT]
                merged[:, _PRR : _PVV + 1] += np.add.reduceat(spread, starts, axis=0) / ws[:, None]
                merged[:, _W] = ws
                # members share a channel; rint undoes the rounding of the weighted mean
                np.rint(merged[:, _CH], out=merged[:, _CH])
                x = merged
        if x.shape[0] > self.max_components:
            top = np.argpartition(x[:, _W], -self.max_components)[-self.max_components :]
            x = x[np.sort(top)]  # keep the (channel, range) order
        self._x = x

    def _extract(self) -> FloatArray:
        x = self._x
        e = x.compress(x[:, _W] > 0.5, axis=0)
        w = e[:, _W]
        if np.count_nonzero(w >= 1.5):
            # a weight near 2 means two unresolved targets at that range
            e = np.repeat(e, np.rint(w).astype(np.intp), axis=0)
        est = e[:, _PVV:]  # a copy's slice: (rate variance, range, rate, amplitude, channel)
        est[:, 1] -= est[:, 4] * _CH_SPAN
        return est
