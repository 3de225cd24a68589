"""Low-complexity fused-image tracker (Section 9.1 of the CoLOR chapter).

Each sensor contributes only its closest target (the local estimate nearest to the sensor,
the one that is not shadowed). The estimates are accumulated into a fused image with a
forgetting factor, eq. (23) of the CoLOR chapter:

.. math::

    I_k(x, y) = \\lambda\\, I_{k-1}(x, y)
    + \\sum_{s} \\mathcal N\\big((x, y);\\ p_s, \\Sigma_s\\big)

Targets are the local maxima of ``I_k`` above a threshold; a Kalman nearest-neighbour track
manager labels them and estimates their velocities.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import maximum_filter
from scipy.optimize import linear_sum_assignment

from .base import (
    FloatArray,
    SensorScan,
    Tracker,
    TrackerOutput,
    TrackEstimate,
    constant_velocity_model,
)

__all__ = ["FusedImageConfig", "FusedImageTracker", "add_gaussians"]


@dataclass(frozen=True, slots=True, kw_only=True)
class FusedImageConfig:
    """Parameters of :class:`FusedImageTracker`; each is declared once here.

    Attributes
    ----------
    bounds : tuple of 4 floats or None
        Image extent ``(x_min, x_max, y_min, y_max)``, m; ``None``: from the first scans'
        sensors, ``origin ± max_range`` (sensors with an infinite range need ``bounds``).
    resolution : float
        Pixel size, m.
    forgetting : float
        Forgetting factor ``λ`` of eq. (23) per step, ``0 <= λ < 1``.
    window_sigmas : float
        Each Gaussian is evaluated on a window of ± this many standard deviations.
    threshold : float
        Minimum image value of a target peak, 1/m² (one estimate with σ = 0.1 m peaks at
        15.9 /m²; a steadily seen target reaches about ``1 / (1 - λ)`` times that).
    relative_threshold : float
        Peaks below this fraction of the image maximum are ignored as well.
    extent_std : float
        Standard deviation (m) of a person's scattering centres about the body centre, added
        to each estimate's covariance (the node's covariance covers ranging only).
    peak_separation : float
        Two peaks closer than this (m) are one person: the local-maximum window half-width.
    accel_psd : float
        Acceleration noise PSD of the track manager's constant-velocity Kalman filter, m²/s³.
    measurement_std : float
        Standard deviation of a peak position, m, in the track manager.
    gate : float
        Association distance between a track's predicted position and a peak, m.
    confirm_hits : int
        Associated peaks before a new track is reported.
    max_misses : int
        Consecutive steps without a peak before a track is deleted.
    """

    bounds: tuple[float, float, float, float] | None = None
    resolution: float = 0.05
    forgetting: float = 0.8
    window_sigmas: float = 3.0
    threshold: float = 2.0
    relative_threshold: float = 0.2
    extent_std: float = 0.2
    peak_separation: float = 0.4
    accel_psd: float = 0.5
    measurement_std: float = 0.1
    gate: float = 1.0
    confirm_hits: int = 3
    max_misses: int = 10


class FusedImageTracker(Tracker):
    """Fused image with forgetting factor plus Kalman nearest-neighbour labelling.

    Parameters
    ----------
    config : FusedImageConfig, optional
    """

    def __init__(self, config: FusedImageConfig | None = None) -> None:
        self.config = config or FusedImageConfig()
        self.reset()

    def reset(self) -> None:
        self._image: FloatArray | None = None
        self._x0 = self._y0 = 0.0
        self._t: float | None = None
        self._m = np.zeros((0, 4))
        self._P = np.zeros((0, 4, 4))
        self._ids = np.zeros(0, dtype=np.int64)
        self._hits = np.zeros(0, dtype=np.int64)
        self._misses = np.zeros(0, dtype=np.int64)
        self._next_id = 1

    @property
    def image(self) -> tuple[FloatArray, float, float, float]:
        """The fused image ``(img (ny, nx), x0, y0, resolution)``; pixel ``[i, j]`` is centred
        at ``(x0 + j*res, y0 + i*res)``."""
        if self._image is None:
            raise RuntimeError("no scan processed yet")
        return self._image, self._x0, self._y0, self.config.resolution

    def _grid(self, scans: Sequence[SensorScan]) -> None:
        cfg = self.config
        if cfg.bounds is not None:
            x_min, x_max, y_min, y_max = cfg.bounds
        else:
            if not scans:
                return
            lo = np.min([s.origin - s.max_range for s in scans], axis=0)
            hi = np.max([s.origin + s.max_range for s in scans], axis=0)
            if not (np.isfinite(lo).all() and np.isfinite(hi).all()):
                raise ValueError("bounds must be configured for sensors with infinite range")
            x_min, y_min = lo
            x_max, y_max = hi
        nx = math.ceil((x_max - x_min) / cfg.resolution) + 1
        ny = math.ceil((y_max - y_min) / cfg.resolution) + 1
        self._image = np.zeros((ny, nx))
        self._x0, self._y0 = float(x_min), float(y_min)

    @staticmethod
    def closest_estimates(scans: Sequence[SensorScan]) -> tuple[FloatArray, FloatArray]:
        """Each sensor's local estimate nearest to the sensor.

        Returns
        -------
        positions : ndarray, float64, shape (s, 2)
        cov : ndarray, float64, shape (s, 2, 2)
            For the ``s`` scans with at least one estimate.
        """
        picks = [
            (s.positions[k], s.cov[k])
            for s in scans
            if s.positions.shape[0]
            for k in [int(np.argmin(((s.positions - s.origin) ** 2).sum(axis=1)))]
        ]
        if not picks:
            return np.zeros((0, 2)), np.zeros((0, 2, 2))
        return np.array([p for p, _ in picks]), np.array([c for _, c in picks])

    def _accumulate(self, p: FloatArray, cov: FloatArray) -> None:
        """Eq. (23): ``I ← λ I + Σ_s N(·; p_s, Σ_s)``, on a window around each estimate."""
        cfg = self.config
        assert self._image is not None
        self._image *= cfg.forgetting
        add_gaussians(self._image, self._x0, self._y0, cfg.resolution, p, cov, cfg.window_sigmas)

    def _peaks(self) -> FloatArray:
        """Local maxima above threshold, refined by the 3x3 centroid, (n, 2) world x, y."""
        cfg = self.config
        img = self._image
        assert img is not None
        level = max(cfg.threshold, cfg.relative_threshold * float(img.max()))
        size = 2 * max(1, round(cfg.peak_separation / cfg.resolution)) + 1
        is_peak = (img == maximum_filter(img, size=size, mode="constant")) & (img >= level)
        i, j = np.nonzero(is_peak)
        if i.size == 0:
            return np.zeros((0, 2))
        pad = np.pad(img, 1)
        off = np.array([-1, 0, 1])
        win = pad[(i + 1)[:, None, None] + off[None, :, None], (j + 1)[:, None, None] + off]
        tot = win.sum(axis=(1, 2))
        di = (win.sum(axis=2) @ off) / tot
        dj = (win.sum(axis=1) @ off) / tot
        res = cfg.resolution
        return np.stack([self._x0 + (j + dj) * res, self._y0 + (i + di) * res], axis=1)

    def _manage(self, dt: float, peaks: FloatArray) -> None:
        """Kalman nearest-neighbour track manager (vectorised over tracks)."""
        cfg = self.config
        if dt > 0.0 and self._m.shape[0]:
            F, Q = constant_velocity_model(dt, cfg.accel_psd)
            self._m = self._m @ F.T
            self._P = F @ self._P @ F.T + Q
        n_tr = self._m.shape[0]
        matched_tr = np.zeros(n_tr, dtype=bool)
        matched_pk = np.zeros(peaks.shape[0], dtype=bool)
        if n_tr and peaks.shape[0]:
            d = np.linalg.norm(self._m[:, None, ::2] - peaks[None, :, :], axis=2)
            r, c = linear_sum_assignment(d)
            ok = d[r, c] <= cfg.gate
            r, c = r[ok], c[ok]
            if r.size:
                R = np.eye(2) * cfg.measurement_std**2
                Pm = self._P[r]
                S = Pm[:, ::2, ::2] + R
                PHt = Pm[:, :, ::2]
                # K = P H^T S^-1 via a batched solve of S K^T = H P.
                K = np.linalg.solve(S, PHt.transpose(0, 2, 1)).transpose(0, 2, 1)
                nu = peaks[c] - self._m[r][:, ::2]
                self._m[r] = self._m[r] + (K @ nu[:, :, None])[:, :, 0]
                self._P[r] = Pm - K @ PHt.transpose(0, 2, 1)
                matched_tr[r] = True
                matched_pk[c] = True
        self._hits = self._hits + matched_tr
        self._misses = np.where(matched_tr, 0, self._misses + 1)
        keep = self._misses <= cfg.max_misses
        new = peaks[~matched_pk]
        n_new = new.shape[0]
        m_new = np.zeros((n_new, 4))
        m_new[:, ::2] = new
        P_new = np.broadcast_to(
            np.diag([cfg.measurement_std**2, 1.0, cfg.measurement_std**2, 1.0]), (n_new, 4, 4)
        )
        self._m = np.concatenate([self._m[keep], m_new])
        self._P = np.concatenate([self._P[keep], P_new])
        self._ids = np.concatenate(
            [self._ids[keep], np.arange(self._next_id, self._next_id + n_new)]
        )
        self._next_id += n_new
        self._hits = np.concatenate([self._hits[keep], np.ones(n_new, dtype=np.int64)])
        self._misses = np.concatenate([self._misses[keep], np.zeros(n_new, dtype=np.int64)])

    def step(self, t: float, scans: Sequence[SensorScan]) -> TrackerOutput:
        """Accumulate this frame's closest estimates, extract peaks, update the tracks.

        Parameters
        ----------
        t : float
            Output time, s.
        scans : sequence of SensorScan

        Returns
        -------
        TrackerOutput
            Confirmed tracks that had a peak in one of the last three steps (``w`` is 1);
            ``n_estimate`` is the number of peaks.
        """
        if self._image is None:
            self._grid(scans)
            if self._image is None:
                return TrackerOutput(t=t, tracks=(), n_estimate=0.0)
        p, cov = self.closest_estimates(scans)
        self._accumulate(p, cov + self.config.extent_std**2 * np.eye(2))
        peaks = self._peaks()
        dt = 0.0 if self._t is None else t - self._t
        self._t = t
        self._manage(dt, peaks)
        show = (self._hits >= self.config.confirm_hits) & (self._misses <= 2)
        tracks = tuple(
            TrackEstimate(id=int(i), x=m[0], vx=m[1], y=m[2], vy=m[3], cov=P, w=1.0)
            for i, m, P in zip(
                self._ids[show].tolist(), self._m[show].tolist(), self._P[show], strict=True
            )
        )
        return TrackerOutput(t=t, tracks=tracks, n_estimate=float(peaks.shape[0]))


def add_gaussians(
    img: FloatArray,
    x0: float,
    y0: float,
    resolution: float,
    p: FloatArray,
    cov: FloatArray,
    window_sigmas: float = 3.0,
    weights: FloatArray | None = None,
) -> None:
    """Add the sum term of eq. (23) of the CoLOR chapter to ``img`` in place.

    .. math:: I(x, y) \\mathrel{+}= \\sum_s \\mathcal N\\big((x, y);\\ p_s, \\Sigma_s\\big)

    Each Gaussian is evaluated on a square window of ``± window_sigmas`` standard deviations.

    Parameters
    ----------
    img : ndarray, float64, shape (ny, nx)
        Image, 1/m²; pixel ``[i, j]`` is centred at ``(x0 + j*resolution, y0 + i*resolution)``.
    x0, y0, resolution : float
        Grid origin and pixel size, m (world frame).
    p : ndarray, float64, shape (s, 2)
        Estimates, world x, y, m.
    cov : ndarray, float64, shape (s, 2, 2)
        Their covariances, m².
    window_sigmas : float
    weights : ndarray, float64, shape (s,), optional
        Factor on each Gaussian (e.g. the forgetting an estimate has already undergone).
    """
    if p.shape[0] == 0:
        return
    res = resolution
    sig = np.sqrt(np.maximum(cov[:, 0, 0], cov[:, 1, 1]))
    half = math.ceil(window_sigmas * float(sig.max()) / res)
    offs = np.arange(-half, half + 1)
    ci = np.rint((p[:, 1] - y0) / res).astype(np.int64)  # row (y)
    cj = np.rint((p[:, 0] - x0) / res).astype(np.int64)  # column (x)
    rows = ci[:, None, None] + offs[None, :, None]  # (s, w, 1)
    cols = cj[:, None, None] + offs[None, None, :]  # (s, 1, w)
    dx = x0 + cols * res - p[:, 0, None, None]
    dy = y0 + rows * res - p[:, 1, None, None]
    a, b, d = cov[:, 0, 0, None, None], cov[:, 0, 1, None, None], cov[:, 1, 1, None, None]
    det = a * d - b * b
    maha = (d * dx * dx - 2.0 * b * dx * dy + a * dy * dy) / det
    vals = np.exp(-0.5 * maha) / (2.0 * math.pi * np.sqrt(det))
    if weights is not None:
        vals = vals * weights[:, None, None]
    rows, cols = np.broadcast_arrays(rows, cols)
    ok = (rows >= 0) & (rows < img.shape[0]) & (cols >= 0) & (cols < img.shape[1])
    np.add.at(img, (rows[ok], cols[ok]), vals[ok])
