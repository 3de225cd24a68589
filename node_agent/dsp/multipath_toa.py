"""First-path delay by a joint maximum-likelihood fit of the known pulse over a few paths.

Beyond the chapter (whose ToA estimators, :mod:`node_agent.dsp.toa`, detect and refine one
pulse): a reflection arriving within one or two pulse widths of the direct path overlaps it
and pulls a single-pulse estimate late or early. Here the samples around the detected first
path are modelled as a sum of ``P`` copies of the band's model pulse
(:func:`node_agent.dsp.band_filter.band_pulse`: Gaussian envelope, modulated for a
passband or complex-baseband radar) with unknown delays and complex amplitudes,

.. math:: y_k = \\mathrm{Re}\\left[\\sum_{p=1}^{P} a_p\\, q(t_k - \\tau_p)\\right] + n_k
    \\quad (\\text{the real part only for a real radar}),

and fitted by least squares, which is maximum likelihood in white Gaussian noise. The
amplitudes are linear and solved in closed form for given delays (variable projection,
Golub and Pereyra); the delays by :func:`scipy.optimize.least_squares`. Paths are added one
at a time in the manner of SAGE / matching pursuit (Fleury et al., 1999): each new path
starts at the strongest correlation of the residual with the pulse and at a few offsets
around the first path (where an overlapping reflection hides), all delays are refitted
jointly, and it is kept when it lowers the residual by more than ``min_gain`` noise
variances (a penalised-likelihood order selection; a true path of amplitude :math:`A`
lowers it by about :math:`(A / \\sigma)^2` times the pulse's energy in samples).

The first path is the earliest fitted path that a detector could have seen: at least the
adaptive threshold's ``factor`` noise sigma and within the estimator's dynamic range of the
strongest fitted path. Its error approaches the multipath-aware bound
(:func:`fusion_center.localization.crlb.multipath_delay_bound`) where the paths are
separable; paths that nearly coincide cannot be separated by any estimator and are merged.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
from scipy.optimize import least_squares

from .band_filter import pulse_sigma
from .geometry import RadarParams

FloatArray = npt.NDArray[np.float64]


class MultipathMlToaRefiner:
    """Refine coarse first-path indices by the joint fit of the module docstring.

    Parameters
    ----------
    radar : RadarParams
        Sampling, band and carrier: the pulse model.
    max_paths : int
        Most paths fitted around the first path.
    min_gain : float
        A path is kept when it lowers the residual by more than this many noise
        variances (per component).
    before, after : float
        The fit window: this many pulse sigmas (envelope) before the coarse first path and
        after it, plus two samples each side.
    """

    def __init__(
        self,
        radar: RadarParams,
        max_paths: int = 3,
        min_gain: float = 25.0,
        before: float = 5.0,
        after: float = 10.0,
    ) -> None:
        if max_paths < 1:
            raise ValueError(f"max_paths must be at least 1, got {max_paths}")
        self.radar = radar
        self.max_paths = int(max_paths)
        self.min_gain = float(min_gain)
        self.before = float(before)
        self.after = float(after)

    def _pulse(self, complex_input: bool) -> tuple[float, float]:
        """Envelope sigma (samples) and modulation frequency (cycles per sample)."""
        r = self.radar
        sig = pulse_sigma(r, complex_input=complex_input) * r.fs
        if complex_input:
            f_off = 0.5 * (r.f_low + r.f_high) - r.fc
        elif r.f_low > 0.0:
            f_off = 0.5 * (r.f_low + r.f_high)
        else:
            f_off = 0.0
        return sig, f_off / r.fs

    def refine(
        self,
        h: npt.NDArray,
        coarse: FloatArray,
        sigma: FloatArray,
        threshold: FloatArray,
        floor: float,
    ) -> FloatArray:
        """First-path fractional sample index of each row.

        Parameters
        ----------
        h : ndarray, float32/float64 or complex, shape (rows, n)
            The impulse responses (not matched-filtered: the noise must be white).
        coarse : ndarray, shape (rows,)
            Detected first-path indices (NaN: none; kept NaN).
        sigma : ndarray, shape (rows,)
            Noise sigma per sample and component of ``h``.
        threshold : ndarray, shape (rows,)
            Least amplitude of a first path (the detector's threshold), units of ``h``.
        floor : float
            Least amplitude of a first path relative to the strongest fitted one.

        Returns
        -------
        ndarray, float64, shape (rows,)
            Refined indices; the coarse one where the fit finds no path.
        """
        complex_input = np.iscomplexobj(h)
        sig, f_off = self._pulse(complex_input)
        out = np.array(coarse, dtype=np.float64)
        for r in np.flatnonzero(np.isfinite(out)):  # a few small fits per impulse response
            out[r] = self._row(np.asarray(h[r]), out[r], sigma[r], threshold[r], floor, sig, f_off)
        return out

    def _row(
        self,
        y: npt.NDArray,
        k0: float,
        sigma: float,
        threshold: float,
        floor: float,
        sig: float,
        f_off: float,
    ) -> float:
        n = y.size
        lo = max(0, math.floor(k0 - self.before * sig) - 2)
        hi = min(n, math.ceil(k0 + self.after * sig) + 3)
        if hi - lo < 4:
            return k0
        k = np.arange(lo, hi, dtype=np.float64)
        real = not np.iscomplexobj(y)
        yw = y[lo:hi].astype(np.complex128)

        def basis(taus: FloatArray) -> npt.NDArray:
            dt = k[:, None] - np.asarray(taus)[None, :]
            return np.exp(-0.5 * (dt / sig) ** 2 + 2j * math.pi * f_off * dt)

        def design(taus: FloatArray) -> npt.NDArray:
            b = basis(taus)
            if real:  # real amplitude and quadrature per path: Re(a q) = a_r Re q - a_i Im q
                return np.concatenate([b.real, -b.imag], axis=1)
            return b

        def residual(taus: FloatArray) -> FloatArray:
            d = design(taus)
            target = yw.real if real else yw
            coef, *_ = np.linalg.lstsq(d, target, rcond=1e-10)
            res = target - d @ coef
            return res if real else np.concatenate([res.real, res.imag])

        def amplitudes(taus: FloatArray) -> FloatArray:
            d = design(taus)
            target = yw.real if real else yw
            coef, *_ = np.linalg.lstsq(d, target, rcond=1e-10)
            if real:
                p = len(taus)
                return np.abs(coef[:p] + 1j * coef[p:])
            return np.abs(coef)

        def fit(start: list[float]) -> tuple[FloatArray, float] | None:
            sol = least_squares(residual, np.asarray(start), method="lm", xtol=1e-6)
            taus = np.sort(sol.x)
            if taus[0] < lo - 1.0 or taus[-1] > hi:
                return None  # a path fled the window: not a fit of these samples
            if taus.size > 1 and np.min(np.diff(taus)) < 0.3 * sig:
                return None  # two paths on top of each other: ill-conditioned, not a path
            return taus, float(np.sum(sol.fun**2))

        grid = np.arange(lo, hi - 1, 0.125)
        gb = basis(grid)
        gnorm = np.sum(np.abs(gb) ** 2, axis=0)
        best = fit([k0])
        if best is None:
            return k0
        taus, rss = best
        var = sigma * sigma
        # one pulse explains the window within the noise (chi-square, 3 sigma): done
        dof = k.size * (1 if real else 2)
        if rss / var < dof + 3.0 * math.sqrt(2.0 * dof):
            return float(taus[0])
        while taus.size < self.max_paths:
            res = residual(taus)
            res_c = res if real else res[: k.size] + 1j * res[k.size :]
            corr = np.abs(np.conj(gb).T @ res_c) ** 2 / gnorm
            first = float(taus[0])
            starts = [float(grid[np.argmax(corr)])]
            starts += [first + f * sig for f in (-1.0, 1.0)]
            trials = [fit([*taus, s]) for s in starts]
            trials = [t for t in trials if t is not None]
            if not trials:
                break
            new_taus, new_rss = min(trials, key=lambda t: t[1])
            if (rss - new_rss) / var < self.min_gain:
                break
            taus, rss = new_taus, new_rss
        amp = amplitudes(taus)
        ok = (amp >= threshold) & (amp >= floor * amp.max()) & (taus >= lo) & (taus < hi)
        return float(taus[np.argmax(ok)]) if ok.any() else k0
