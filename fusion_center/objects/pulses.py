"""Separation of overlapping echoes: Dynamic Correlation Method, CLEAN, matched filter.

Two echoes closer than the range resolution (``c / B`` of path, about two samples at a
3.5 GHz band) merge into one peak of the matched-filter output. The **Dynamic Correlation
Method** (DCM, Section 7.4 of the CoLOR chapter) correlates the signal with *two* shifted
reference pulses at once: for every pair of delays ``(tau_1, tau_2)`` on a fine grid it
computes the energy of the signal's least-squares projection onto ``{p(t - tau_1),
p(t - tau_2)}``,

.. math::

    M(\\tau_1, \\tau_2) = \\frac{E (c_1^2 + c_2^2) - 2 R_{12} c_1 c_2}{E^2 - R_{12}^2},
    \\quad c_i = \\langle y, p_{\\tau_i} \\rangle,\\;
    R_{12} = \\langle p_{\\tau_1}, p_{\\tau_2} \\rangle,\\; E = \\|p\\|^2,

(the 2-D correlation matrix), takes its maximum, and ends adaptively: the pair is accepted
only if it explains significantly more energy than the best single pulse (a test against the
noise variance), the fitted pulses are subtracted, and the search repeats on the residual
until its peak falls below ``threshold`` times the noise level. **CLEAN** subtracts one pulse
at a time at the matched-filter maximum; the **matched-filter peak picker** reports the local
maxima of the correlation. All three work on a grid ``upsample`` times finer than the
samples (band-limited interpolation by zero padding of the spectrum). Pure numpy.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True, slots=True, kw_only=True)
class Pulses:
    """Separated pulses of one signal: delays (samples, fractional) and amplitudes."""

    delays: FloatArray
    amplitudes: FloatArray


class _Correlator:
    """Correlation ``c(tau) = <y, p_tau>`` and autocorrelation ``R(d)`` on a fine grid."""

    def __init__(self, reference: npt.ArrayLike, n: int, upsample: int, centre: int | None):
        ref = np.asarray(reference, float)
        centre = int(np.argmax(np.abs(ref))) if centre is None else centre
        padded = np.zeros(n)
        padded[: len(ref)] = ref
        self.spec = np.fft.rfft(np.roll(padded, -centre))
        self.n, self.up = n, upsample
        self.energy = float(np.sum(ref**2))
        #: R(m / upsample samples), circular, shape (n * upsample,)
        self.auto = np.fft.irfft(np.abs(self.spec) ** 2, n * upsample) * upsample

    def correlate(self, y: FloatArray) -> FloatArray:
        return np.fft.irfft(np.fft.rfft(y) * np.conj(self.spec), self.n * self.up) * self.up

    def pulse(self, delay: float) -> FloatArray:
        f = np.arange(len(self.spec))
        return np.fft.irfft(self.spec * np.exp(-2j * np.pi * f * delay / self.n), self.n)


class DynamicCorrelationSeparator:
    """Pulse separation by the Dynamic Correlation Method (Section 7.4 of the CoLOR chapter).

    Parameters
    ----------
    reference : array_like, float, shape (L,)
        Reference pulse; its time origin at ``centre`` (default: its peak).
    n : int
        Samples per signal.
    upsample : int
        Fine-grid factor of the delay search.
    window : float
        Half width of the pair search around the strongest correlation peak, samples.
    threshold : float
        Stop when the residual correlation peak is below ``threshold`` noise standard
        deviations of the correlation.
    max_pulses : int
        Upper bound on the pulses returned.
    min_ratio : float
        Smallest amplitude ratio of an accepted pair (weaker: a single off-grid pulse).
    """

    def __init__(
        self,
        reference: npt.ArrayLike,
        n: int,
        *,
        upsample: int = 8,
        window: float = 4.0,
        threshold: float = 6.0,
        max_pulses: int = 6,
        min_ratio: float = 0.2,
        centre: int | None = None,
    ) -> None:
        self._c = _Correlator(reference, n, upsample, centre)
        self.min_ratio = min_ratio
        self.window = window
        self.threshold = threshold
        self.max_pulses = max_pulses

    def separate(self, y: npt.ArrayLike, noise_std: float) -> Pulses:
        """Delays (samples) and amplitudes of the pulses in ``y`` (n,), noise std ``noise_std``."""
        c = self._c
        resid = np.asarray(y, float).copy()
        e = c.energy
        floor = self.threshold * noise_std * np.sqrt(e)
        delays: list[float] = []
        amps: list[float] = []
        half = int(self.window * c.up)
        k = np.arange(-half, half + 1)
        diff = k[:, None] - k[None, :]
        r12 = c.auto[np.mod(diff, len(c.auto))]
        det = e * e - r12**2
        valid = det > 1e-3 * e * e  # pairs far enough apart to be distinguishable
        while len(delays) < self.max_pulses:
            corr = c.correlate(resid)
            m0 = int(np.argmax(np.abs(corr)))
            if abs(corr[m0]) < floor:
                break
            idx = np.mod(m0 + k, len(corr))
            c1 = corr[idx]
            with np.errstate(invalid="ignore", divide="ignore"):
                energy2 = np.where(
                    valid,
                    (e * (c1[:, None] ** 2 + c1[None, :] ** 2) - 2 * r12 * np.outer(c1, c1)) / det,
                    -np.inf,
                )
            i, j = np.unravel_index(int(np.argmax(energy2)), energy2.shape)
            single = c1[half] ** 2 / e
            # Adaptive termination of the pair: accept the second pulse only if the energy it
            # adds beats the noise (a chi-square-like margin of threshold^2 / 2 noise powers).
            a = np.linalg.solve(
                np.array([[e, r12[i, j]], [r12[i, j], e]]), np.array([c1[i], c1[j]])
            )
            # A single pulse between two grid points is also fitted better by a strong and a
            # weak opposite pulse (a derivative): a real second pulse must carry a share
            # of the energy (min_ratio) as well as beat the noise.
            weak = min(abs(a[0]), abs(a[1])) < self.min_ratio * max(abs(a[0]), abs(a[1]))
            if not weak and energy2[i, j] - single > 0.5 * self.threshold**2 * noise_std**2:
                found = [((m0 + k[i]) / c.up, a[0]), ((m0 + k[j]) / c.up, a[1])]
            else:
                found = [(m0 / c.up, c1[half] / e)]
            for d, a_ in found:
                delays.append(d)
                amps.append(a_)
                resid -= a_ * c.pulse(d)
        order = np.argsort(delays)
        return Pulses(delays=np.asarray(delays)[order], amplitudes=np.asarray(amps)[order])


class _CorrelatingSeparator:
    """What CLEAN and the peak picker share: the upsampled correlator with the reference
    pulse, the detection threshold (noise deviations) and the most pulses reported."""

    def __init__(
        self,
        reference: npt.ArrayLike,
        n: int,
        *,
        upsample: int = 8,
        threshold: float = 6.0,
        max_pulses: int = 6,
        centre: int | None = None,
    ) -> None:
        self._c = _Correlator(reference, n, upsample, centre)
        self.threshold = threshold
        self.max_pulses = max_pulses


class CleanSeparator(_CorrelatingSeparator):
    """CLEAN: subtract one reference pulse at the correlation maximum until only noise is left.

    Parameters as :class:`DynamicCorrelationSeparator`.
    """

    def separate(self, y: npt.ArrayLike, noise_std: float) -> Pulses:
        """Delays (samples) and amplitudes of the pulses in ``y`` (n,)."""
        c = self._c
        resid = np.asarray(y, float).copy()
        floor = self.threshold * noise_std * np.sqrt(c.energy)
        delays, amps = [], []
        for _ in range(self.max_pulses):
            corr = c.correlate(resid)
            m0 = int(np.argmax(np.abs(corr)))
            if abs(corr[m0]) < floor:
                break
            a = corr[m0] / c.energy
            delays.append(m0 / c.up)
            amps.append(a)
            resid -= a * c.pulse(m0 / c.up)
        order = np.argsort(delays)
        return Pulses(delays=np.asarray(delays)[order], amplitudes=np.asarray(amps)[order])


class MatchedFilterPeakPicker(_CorrelatingSeparator):
    """Local maxima of the matched-filter output above ``threshold`` noise deviations.

    Parameters as :class:`DynamicCorrelationSeparator`.
    """

    def separate(self, y: npt.ArrayLike, noise_std: float) -> Pulses:
        """Delays (samples) and amplitudes of the correlation peaks of ``y`` (n,)."""
        c = self._c
        corr = c.correlate(np.asarray(y, float))
        mag = np.abs(corr)
        peak = (mag > np.roll(mag, 1)) & (mag >= np.roll(mag, -1))
        peak &= mag > self.threshold * noise_std * np.sqrt(c.energy)
        idx = np.flatnonzero(peak)
        idx = idx[np.argsort(-mag[idx])][: self.max_pulses]
        idx = np.sort(idx)
        return Pulses(delays=idx / c.up, amplitudes=corr[idx] / c.energy)
