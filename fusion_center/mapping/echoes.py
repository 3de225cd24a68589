"""Echo extraction from a bat-type robot's impulse responses, and Rx1/Rx2 pairing.

The robot's responses hold, besides the landmark echoes, components that turn with the robot:
the direct Tx -> Rx coupling, the floor and the ceiling. They are removed as a background in
the robot frame: the per-sample **median** of the first ``warmup`` responses (a turn on the
spot: a landmark echo occupies each range bin for a few headings only, so the median keeps
just the robot-fixed part). A mean or an exponential average (the node DSP's
:class:`node_agent.dsp.background.ExponentialBackgroundSubtractor`, Section 9.2 of the CoLOR
chapter) keeps smeared copies of the echoes of past headings, whose subtraction leaves
"ghost" echoes that lag behind the robot's turn and pull the SLAM's heading back (measured:
0.5 degrees per 3-degree step on room_pillar); it can still follow a slowly drifting coupling
from there with ``alpha > 0``.

Echoes are local maxima of the analytic envelope above ``threshold`` times the noise
:math:`\\sigma` (:func:`node_agent.dsp.toa.noise_sigma`) and above ``dynamic_db`` below the
strongest echo, at least one pulse apart, refined to sub-sample range by a parabola through
the log-envelope; the ``max_echoes`` strongest per receiver are kept.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.optimize import linear_sum_assignment

from node_agent.dsp.background import ExponentialBackgroundSubtractor
from node_agent.dsp.toa import noise_sigma

FloatArray = npt.NDArray[np.float64]
C = 299792458.0


def analytic_envelope(y: npt.NDArray) -> FloatArray:
    """Magnitude of the analytic signal of real rows (one-sided spectrum, inverse FFT).

    The same as ``abs(scipy.signal.hilbert(y))``, without importing scipy.signal (seconds of
    start-up). Passband impulse responses have no baseband tails to worry about.
    """
    n = y.shape[-1]
    spec = np.fft.fft(y, axis=-1)
    weight = np.zeros(n)
    weight[0] = 1.0
    weight[1 : (n + 1) // 2] = 2.0
    if n % 2 == 0:
        weight[n // 2] = 1.0
    return np.abs(np.fft.ifft(spec * weight, axis=-1))


@dataclass(frozen=True, slots=True, kw_only=True)
class EchoSet:
    """Echoes of one acquisition.

    Attributes
    ----------
    ranges : tuple of ndarray, float64
        Per receiver, bistatic ranges (m), ascending.
    amplitudes : tuple of ndarray, float64
        Per receiver, envelope peak amplitudes (linear).
    """

    ranges: tuple[FloatArray, ...]
    amplitudes: tuple[FloatArray, ...]


class EnvelopePeakEchoExtractor:
    """Multiple echoes per receiver from real or complex impulse responses.

    Parameters
    ----------
    fs : float
        Equivalent sample rate, Hz.
    t0 : float
        Time of sample 0 after emission, s.
    bandwidth : float
        Signal bandwidth, Hz (pulse width ``c / B`` sets the peak separation).
    min_range, max_range : float
        Searched bistatic ranges, m.
    threshold : float
        Peak threshold in noise sigmas.
    dynamic_db : float
        Peaks more than this below the strongest one are ignored, dB.
    max_echoes : int
        Strongest echoes kept per receiver.
    alpha : float
        Forgetting factor of an exponential update of the background after the warm-up
        (0: the warm-up median stays).
    warmup : int
        Responses whose median is the background (0 disables subtraction).
    """

    def __init__(
        self,
        *,
        fs: float,
        t0: float = 0.0,
        bandwidth: float,
        min_range: float = 1.0,
        max_range: float = 12.0,
        threshold: float = 8.0,
        dynamic_db: float = 25.0,
        max_echoes: int = 8,
        alpha: float = 0.0,
        warmup: int = 24,
    ) -> None:
        self.fs = float(fs)
        self.t0 = float(t0)
        self.min_range = float(min_range)
        self.max_range = float(max_range)
        self.threshold = float(threshold)
        self.dynamic = 10 ** (-dynamic_db / 20)
        self.max_echoes = int(max_echoes)
        self.separation = max(1, round(self.fs / bandwidth))  # one pulse width
        self.warmup = int(warmup)
        self._bg = ExponentialBackgroundSubtractor(alpha) if alpha > 0 else None
        self._background: npt.NDArray | None = None
        self._pending: list[npt.NDArray] | None = [] if self.warmup > 0 else None

    def ranges_of(self, n: int) -> FloatArray:
        """Bistatic range of each sample, m."""
        return C * (self.t0 + np.arange(n) / self.fs)

    def push(self, h: npt.NDArray) -> list[EchoSet]:
        """Add one acquisition; return the echo sets now available (oldest first).

        During the warm-up the responses are held back (empty list); the call that completes
        it returns all of them.

        Parameters
        ----------
        h : ndarray, float32 or complex64, shape (n_rx, n)
        """
        if self._pending is not None:
            self._pending.append(np.asarray(h))
            return self.flush() if len(self._pending) >= self.warmup else []
        return [self.extract(self._subtract(h))]

    def _subtract(self, h: npt.NDArray) -> npt.NDArray:
        if self._background is None:
            return h
        if self._bg is not None:
            return self._bg.step(h)
        if h.shape != self._background.shape:
            return h
        return h - self._background

    def flush(self) -> list[EchoSet]:
        """Process the responses held back by the warm-up (also when the stream ends early)."""
        held = self._pending
        if not held:
            return []
        self._pending = None
        if all(x.shape == held[0].shape for x in held):
            stack = np.stack(held)
            if np.iscomplexobj(stack):
                bg = np.median(stack.real, 0) + 1j * np.median(stack.imag, 0)
            else:
                bg = np.median(stack, 0)
            self._background = bg.astype(held[0].dtype)
            if self._bg is not None:
                self._bg.step(self._background)  # initialises the exponential average
        return [self.extract(self._subtract(x)) for x in held]

    def extract(self, y: npt.NDArray) -> EchoSet:
        """Echo ranges and amplitudes of background-free responses ``y`` (n_rx, n)."""
        y = np.atleast_2d(y)
        env = np.abs(y) if np.iscomplexobj(y) else analytic_envelope(y.astype(np.float64))
        n = env.shape[1]
        r = self.ranges_of(n)
        sigma = noise_sigma(env, complex_input=True)
        inside = (r >= self.min_range) & (r <= self.max_range)
        e = np.where(inside[None, :], env, 0.0)
        # local maxima over +-separation samples
        pad = np.pad(e, ((0, 0), (self.separation, self.separation)))
        win = np.lib.stride_tricks.sliding_window_view(pad, 2 * self.separation + 1, axis=1)
        is_max = (e >= win.max(axis=-1)) & (e > 0)
        level = np.maximum(self.threshold * sigma, self.dynamic * e.max(axis=1))
        is_max &= e > level[:, None]
        out_r, out_a = [], []
        for row in range(e.shape[0]):  # n_rx rows: two receivers
            idx = np.flatnonzero(is_max[row])
            idx = idx[np.argsort(e[row, idx])[::-1][: self.max_echoes]]
            idx = np.sort(idx)
            i = np.clip(idx, 1, n - 2)
            a = np.log(np.maximum(env[row, i - 1], 1e-300))
            b = np.log(np.maximum(env[row, i], 1e-300))
            c = np.log(np.maximum(env[row, i + 1], 1e-300))
            den = a - 2 * b + c
            with np.errstate(divide="ignore", invalid="ignore"):
                frac = np.where(den < 0, 0.5 * (a - c) / den, 0.0)
            frac = np.clip(np.nan_to_num(frac), -0.5, 0.5)
            out_r.append(C * (self.t0 + (i + frac) / self.fs))
            out_a.append(env[row, i])
        return EchoSet(ranges=tuple(out_r), amplitudes=tuple(out_a))


def pair_echoes(echoes: EchoSet, max_difference: float = 0.6) -> FloatArray:
    """Pair the echoes of rx1 and rx2 that come from one landmark.

    For a landmark within the horns' beam the two ranges differ by at most about the
    baseline times the sine of the off-boresight angle; pairs are the minimum-cost assignment
    (Hungarian) of ``|r1 - r2| / max_difference + |ln(a1 / a2)| / ln 4`` within the gate
    ``|r1 - r2| <= max_difference``.

    Returns
    -------
    ndarray, float64, shape (m, 2)
        Paired ranges ``(r1, r2)``, m, ordered by ``r1 + r2``.
    """
    r1, r2 = echoes.ranges[0], echoes.ranges[1]
    if r1.size == 0 or r2.size == 0:
        return np.zeros((0, 2))
    a1, a2 = echoes.amplitudes[0], echoes.amplitudes[1]
    dr = np.abs(r1[:, None] - r2[None, :])
    cost = dr / max_difference + np.abs(np.log(a1[:, None] / a2[None, :])) / np.log(4.0)
    cost = np.where(dr <= max_difference, cost, 1e6)
    i, j = linear_sum_assignment(cost)
    keep = cost[i, j] < 1e6
    z = np.stack([r1[i[keep]], r2[j[keep]]], axis=1)
    return z[np.argsort(z.sum(axis=1))]
