"""M-sequence UWB radar model: sequence, system pulse, thermal noise, sampling.

The radar transmits a periodic maximum-length binary sequence (MLBS) of
``n = 2**order - 1`` chips clocked at ``fs`` and samples the received signal at one
sample per chip (the equivalent sample rate of the CoLOR radar is its 7 GHz clock).
The impulse response is the periodic correlation of the received signal with the
sequence. Everything here is pure numpy: no files, no clocks.

Frequency-domain synthesis
--------------------------
A channel of point paths ``(a_i, tau_i)`` has the spectrum, on the DFT grid
``f_k = k fs / n`` of the periodic radar,

.. math::

    C_k = \\sum_i a_i \\exp(-j 2 \\pi f_k (\\tau_i - t_0)),

and the impulse response the radar delivers is

.. math::

    h[m] = \\mathrm{irfft}(G_k C_k + V_k)[m], \\quad
    G_k = \\mathrm{sinc}^2(f_k / f_s)\\, B(f_k) / g_0,

with sample ``m`` at ``t0 + m / fs`` after emission. ``sinc^2`` is the spectrum of the
chip-triangle autocorrelation, ``B`` the receiver band (front-end high-pass and the
anti-alias low-pass to ``f_high``, zero phase: the calibrated reference plane removes the
system group delay) and ``g_0`` normalises the system pulse to a peak of 1 for a delay
on the sample grid. Because ``G`` is band-limited below ``fs / 2`` the sampled pulse is
alias-free and sub-sample delays are exact; delays wrap modulo the period ``n / fs``
exactly as in the periodic radar. ``V_k`` is the thermal noise after correlation,
see :meth:`MSequenceRadar.noise_spectrum`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import numpy.typing as npt

C = 299792458.0
"""Speed of light, m/s (PROTOCOL.md)."""

#: Feedback taps of the Ilmsens 12-stage MLBS: b[k] = b[k-1] ^ b[k-5] ^ b[k-8] ^ b[k-12],
#: i.e. the feedback polynomial 1 + x + x^5 + x^8 + x^12 (sim_nodes/data/README.md).
ILMSENS_TAPS_12 = (1, 5, 8, 12)

#: The first 12 chips (as bits) of the Ilmsens sequence: with this register state the
#: LFSR reproduces the shipped sequence without a cyclic shift.
ILMSENS_SEED_12 = (1, 1, 1, 1, 1, 0, 1, 0, 0, 0, 1, 0)


@lru_cache(maxsize=8)
def _mlbs_cached(taps: tuple[int, ...], seed: tuple[int, ...]) -> bytes:
    order = max(taps)
    n = 2**order - 1
    bits = bytearray(n)
    bits[:order] = bytes(seed)
    # A linear recurrence is inherently sequential (b[k] needs b[k-1]); it runs once per
    # (taps, seed) and is cached, so this 4095-step loop is the shift register's clock,
    # not per-sample work in the acquisition path.
    for k in range(order, n):
        v = 0
        for tap in taps:
            v ^= bits[k - tap]
        bits[k] = v
    return bytes(bits)


def mlbs(
    taps: tuple[int, ...] = ILMSENS_TAPS_12,
    seed: tuple[int, ...] = ILMSENS_SEED_12,
) -> npt.NDArray[np.int8]:
    """Generate a maximum-length binary sequence with a Fibonacci LFSR.

    Parameters
    ----------
    taps : tuple of int
        Feedback lags; the register obeys ``b[k] = XOR_j b[k - taps_j]``. The largest tap is
        the order ``r``; the default is the Ilmsens polynomial ``1 + x + x^5 + x^8 + x^12``.
    seed : tuple of int
        The first ``r`` bits (not all zero). The default reproduces the Ilmsens sequence
        exactly; any other non-zero seed gives a cyclic shift of it.

    Returns
    -------
    ndarray, int8, shape (2**r - 1,)
        Chips ``s = 2 b - 1`` in {-1, +1}.
    """
    order = max(taps)
    if len(seed) != order or not any(seed):
        raise ValueError(f"seed must be {order} bits, not all zero")
    bits = np.frombuffer(_mlbs_cached(tuple(taps), tuple(int(b) & 1 for b in seed)), np.uint8)
    return (2 * bits.astype(np.int8) - 1).astype(np.int8)


#: Samples beyond a window that :meth:`MSequenceRadar.window_noise`'s periodic grid adds:
#: the noise's autocorrelation is below 1e-4 of its peak beyond lag 70.
WINDOW_NOISE_GUARD = 128


@dataclass(frozen=True, slots=True, kw_only=True)
class RadarConfig:
    """Parameters of the simulated M-sequence radar (SI units).

    Attributes
    ----------
    fs : float
        Equivalent sample rate = chip clock, Hz.
    n : int
        Samples per impulse response = chips per period (4095 for 12 stages).
    t0 : float
        Time of sample 0 after the transmitter's emission, s.
    f_low, f_high : float
        Published band edges, Hz (baseband: 0 and fs / 2).
    rate : float
        Impulse responses per second per transmitter.
    highpass : float
        Corner of the front-end/antenna high-pass, Hz (horns do not radiate near DC).
    rolloff : float
        Width of the raised-cosine anti-alias taper below ``f_high``, as a fraction of it.
    snr_db : float
        SNR of the reference target, dB: peak of its echo in the impulse response over the
        standard deviation of the noise in the impulse response (after correlation).
    snr_reference_distance : float
        The reference target's distance from Tx and from Rx, m (monostatic, on boresight).
    snr_reference_rcs : float
        The reference target's radar cross-section, m^2.
    noise : bool
        Add thermal noise.
    """

    fs: float = 7e9
    n: int = 4095
    t0: float = 0.0
    f_low: float = 0.0
    f_high: float = 3.5e9
    rate: float = 50.0
    highpass: float = 1.5e8
    rolloff: float = 0.2
    snr_db: float = 40.0
    snr_reference_distance: float = 5.0
    snr_reference_rcs: float = 1.0
    noise: bool = True


def scatter_amplitude(rcs: npt.ArrayLike, d1: npt.ArrayLike, d2: npt.ArrayLike) -> np.ndarray:
    """Amplitude of a point scatterer relative to a unit-gain 1/d free-space link.

    .. math:: a = \\sqrt{\\sigma / (4\\pi)} / (d_1 d_2)

    (the bistatic radar equation in amplitude; the direct path of length ``d`` is ``1/d``).

    Parameters
    ----------
    rcs : array_like
        Radar cross-section sigma, m^2.
    d1, d2 : array_like
        Distances Tx -> scatterer and scatterer -> Rx, m.
    """
    return np.sqrt(np.asarray(rcs, float) / (4 * np.pi)) / (np.asarray(d1) * np.asarray(d2))


class MSequenceRadar:
    """The M-sequence radar: turns path lists into sampled, noisy impulse responses.

    Parameters
    ----------
    config : RadarConfig
        Radar parameters; ``config.n`` must be ``2**12 - 1`` (the Ilmsens sequence).
    """

    def __init__(self, config: RadarConfig | None = None) -> None:
        cfg = config or RadarConfig()
        if cfg.n != 2**12 - 1:
            raise ValueError(f"radar.n must be 4095 (12-stage M-sequence), got {cfg.n}")
        if not 0 <= cfg.f_low < cfg.f_high <= cfg.fs / 2:
            raise ValueError("radar band must satisfy 0 <= f_low < f_high <= fs/2")
        self.config = cfg
        self.sequence = mlbs()
        n = cfg.n
        self.n_bins = n // 2 + 1
        #: DFT frequencies f_k = k fs / n, Hz, shape (n_bins,).
        self.frequencies = np.arange(self.n_bins) * (cfg.fs / n)
        f = self.frequencies
        band = self.band(f)
        #: Receiver band magnitude B_k, shape (n_bins,).
        self.receiver_band = band
        g = np.sinc(f / cfg.fs) ** 2 * band
        g0 = (g[0] + 2 * g[1:].sum()) / n  # pulse value at zero delay (n odd: no Nyquist bin)
        #: System transfer G_k (zero phase, peak-normalised pulse), shape (n_bins,).
        self.system_response = g / g0
        spec = np.fft.rfft(self.sequence.astype(float))
        ref = np.zeros(self.n_bins, complex)
        # Ilmsens phase-only reference conj(exp(j angle S_k)), DC = 0; scaled by
        # 1/sqrt(n+1) = 1/|S_k| so a unit path gives G_k exactly.
        ref[1:] = np.conj(spec[1:]) / np.abs(spec[1:]) / np.sqrt(n + 1)
        #: Correlation reference R_k, shape (n_bins,), complex.
        self.reference_spectrum = ref
        self._sequence_spectrum = spec
        self.reference_amplitude = float(
            scatter_amplitude(
                cfg.snr_reference_rcs, cfg.snr_reference_distance, cfg.snr_reference_distance
            )
        )
        #: Noise std in the impulse response (after correlation): reference peak / SNR.
        self.noise_std = self.reference_amplitude * 10 ** (-cfg.snr_db / 20)
        # Receive-domain (per-sample, before correlation) noise std giving noise_std after
        # correlation: var_out = sigma_r^2 sum_k |B_k|^2 |S_k|^2 |R_k|^2 / n^2 over the full
        # spectrum = sigma_r^2 * 2 sum_{k>=1} B_k^2 / (n (n+1)).
        full = 2 * np.sum(band[1:] ** 2)
        #: Thermal noise std per received sample, before correlation (same scale as h).
        self.receive_noise_std = self.noise_std * np.sqrt(n * (n + 1) / full)
        # Per-bin std of the real and imaginary parts of V_k (see noise_spectrum).
        self._noise_scale = (band * self.receive_noise_std * np.sqrt(n / 2 / (n + 1))).astype(
            np.float32
        )
        self._system_response32 = self.system_response.astype(np.float32)
        # Split the n_bins phase ramp into (n_hi x n_lo) blocks: k = n_lo * m + l.
        self._n_lo = int(np.ceil(np.sqrt(self.n_bins)))
        n_hi = int(np.ceil(self.n_bins / self._n_lo))
        self._block_index = np.concatenate(
            [np.arange(self._n_lo), self._n_lo * np.arange(n_hi)]
        ).astype(float)
        self._window_grids: dict[int, tuple[int, npt.NDArray[np.float32]]] = {}

    def band(self, f: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        """Receiver band magnitude ``B(f)`` at frequencies ``f`` (Hz, ascending from 0)."""
        cfg = self.config
        # Receiver band B(f): smooth 4th-order high-pass (antenna/front end) and a
        # raised-cosine anti-alias taper ending at f_high (keeps pulse ringing short).
        hp = (f / cfg.highpass) ** 4 / (1 + (f / cfg.highpass) ** 4) if cfg.highpass > 0 else 1.0
        f_pass = cfg.f_high * (1 - cfg.rolloff)
        x = np.clip((f - f_pass) / max(cfg.f_high - f_pass, 1e-30), 0.0, 1.0)
        lp = 0.5 * (1 + np.cos(np.pi * x))
        band = np.asarray(hp * lp, float)
        band[f < cfg.f_low] = 0.0
        band[0] = 0.0  # the phase-only reference has no DC bin (Ilmsens), nor has the front end
        return band

    @property
    def delays(self) -> npt.NDArray[np.float64]:
        """Sample times ``t0 + k / fs`` after emission, s, shape (n,)."""
        return self.config.t0 + np.arange(self.config.n) / self.config.fs

    @property
    def ranges(self) -> npt.NDArray[np.float64]:
        """Bistatic range of each sample ``c (t0 + k / fs)``, m, shape (n,)."""
        return C * self.delays

    def path_spectrum(self, delays: npt.ArrayLike, amplitudes: npt.ArrayLike) -> np.ndarray:
        """Spectrum of a sum of delayed impulses on the radar's DFT grid.

        .. math:: C_k = \\sum_i a_i \\exp(-j 2 \\pi k \\Delta f (\\tau_i - t_0)),
                  \\quad \\Delta f = f_s / n

        Evaluated exactly but cheaply: with ``k = L m + l`` the phase factorises into
        ``w^l (w^L)^m``, so only ``(L + M) P`` phase factors and one batched matrix
        product are needed instead of ``n_bins P`` complex exponentials. Phases are
        reduced modulo one cycle in float64 before the float32 sine/cosine, so the
        result is accurate to float32 precision (about 1e-14 s of delay at 3.5 GHz).

        Parameters
        ----------
        delays : array_like, float, shape (..., P)
            Path delays tau_i after emission, s.
        amplitudes : array_like, float, shape (..., P)
            Path amplitudes a_i (dimensionless, 1/d scale).

        Returns
        -------
        ndarray, complex64, shape (..., n_bins)
        """
        lo, hi = self._phase_factors(np.asarray(delays, float), np.asarray(amplitudes, np.float32))
        out = hi @ np.swapaxes(lo, -1, -2)  # (..., M, L): bin k = L m + l
        return out.reshape(*out.shape[:-2], -1)[..., : self.n_bins]

    def _phase_factors(
        self, delays: npt.NDArray[np.float64], amplitudes: npt.NDArray[np.float32]
    ) -> tuple[np.ndarray, np.ndarray]:
        """The factors of :meth:`path_spectrum`: ``w^l`` (l < L), shape (..., L, P), and
        ``a_i (w^L)^m`` (m < M), shape (..., M, P), complex64, elementwise over the paths."""
        cfg = self.config
        cycles = (delays - cfg.t0) * (cfg.fs / cfg.n)  # (..., P)
        # Phase cycles of w^l (l < L) and of (w^L)^m (m < M), stacked on one axis.
        turns = cycles[..., None, :] * self._block_index[:, None]  # (..., L + M, P)
        turns -= np.rint(turns)
        phase = (turns * (-2 * np.pi)).astype(np.float32)
        w = np.empty(phase.shape, np.complex64)
        w.real = np.cos(phase)
        w.imag = np.sin(phase)
        return w[..., : self._n_lo, :], w[..., self._n_lo :, :] * amplitudes[..., None, :]

    def path_spectra(self, paths: Sequence[tuple[np.ndarray, np.ndarray]]) -> list[np.ndarray]:
        """:meth:`path_spectrum` of several acquisitions at once: ``out[i]`` is bit for bit
        ``path_spectrum(*paths[i])``.

        The phase factors and their amplitude weighting are elementwise, so they run once
        over the paths of all acquisitions side by side (one numpy call per step instead
        of one per acquisition); only the matrix product is per acquisition.

        Parameters
        ----------
        paths : sequence of ``(delays, amplitudes)``, float, each shape (n_rx, P_i), the
            same n_rx

        Returns
        -------
        list of ndarray, complex64, shape (n_rx, n_bins)
        """
        if not paths:
            return []
        delays = np.concatenate([np.asarray(d, float) for d, _ in paths], axis=-1)
        amps = np.concatenate([np.asarray(a, np.float32) for _, a in paths], axis=-1)
        # the factors of path_spectrum, elementwise over all paths side by side
        lo, hi = self._phase_factors(delays, amps)
        out = []
        end = 0
        for d, _ in paths:
            start, end = end, end + np.shape(d)[-1]
            spec = hi[..., start:end] @ np.swapaxes(lo[..., start:end], -1, -2)
            out.append(spec.reshape(*spec.shape[:-2], -1)[..., : self.n_bins])
        return out

    def noise_spectrum(self, rng: np.random.Generator, n_rx: int) -> np.ndarray:
        """Thermal noise after correlation, as received before correlation.

        White Gaussian noise ``w[m] ~ N(0, sigma_r^2)`` enters each receiver before the
        anti-alias filter, is sampled and correlated with the sequence:

        .. math:: V_k = B_k\\, W_k\\, R_k, \\quad W_k = \\mathrm{rfft}(w)_k

        The ``W_k`` (k >= 1) of white noise are independent circular complex Gaussians with
        ``E|W_k|^2 = n sigma_r^2``, and the phase-only ``R_k`` has constant magnitude
        ``1/sqrt(n+1)``; a circular Gaussian times a fixed phase is the same Gaussian. So
        ``V_k`` is drawn directly as ``B_k sigma_r sqrt(n / (n+1)) CN(0, 1)``, which is
        equal in distribution to correlating explicit receive-domain noise (checked in the
        tests against :meth:`correlate`) and saves one FFT per receiver. The correlation
        gain of the n chips makes the output noise std ``sigma_r / sqrt(n)`` (times the
        band factor): see :attr:`noise_std`.

        Returns
        -------
        ndarray, complex64, shape (n_rx, n_bins)
        """
        v = np.zeros((n_rx, self.n_bins), np.complex64)
        self._add_noise(v, rng)
        return v

    def _add_noise(self, spec: np.ndarray, rng: np.random.Generator) -> None:
        """Add the thermal noise ``V_k`` of :meth:`noise_spectrum` to ``spec`` in place.

        The circular complex Gaussians are drawn by the Box-Muller transform (Box & Muller
        1958), ``r e^{j theta}`` with ``r = sqrt(-2 ln(1 - u_1))`` and ``theta = 2 pi u_2``
        for uniform ``u`` in float32: real and imaginary parts are independent N(0, 1),
        exactly as two ``standard_normal`` draws, at 2.5x less CPU here than numpy's float32
        ziggurat (the noise was a third of the simulator's time per acquisition). The
        float32 uniforms bound ``r`` at 5.8 (a Rayleigh tail of 6e-8 per bin).
        """
        self._add_noise_uniforms(spec, rng.random((2, *spec.shape), dtype=np.float32))

    def _add_noise_uniforms(self, spec: np.ndarray, u: npt.NDArray[np.float32]) -> None:
        """The Box-Muller transform of :meth:`_add_noise` from its uniforms ``u``, shape
        ``(2, *spec.shape)``, float32 (elementwise: the same values whatever the batch)."""
        r = np.log1p(-u[0])
        r *= -2.0
        np.sqrt(r, out=r)
        r *= self._noise_scale
        theta = u[1]
        theta *= np.float32(2 * np.pi)
        spec.real += r * np.cos(theta)
        spec.imag += r * np.sin(theta)

    def impulse_response(
        self, channel_spectrum: np.ndarray, rng: np.random.Generator | None = None
    ) -> npt.NDArray[np.float32]:
        """Sampled impulse responses the radar delivers for a channel spectrum.

        .. math:: h = \\mathrm{irfft}(G_k C_k + V_k)

        Parameters
        ----------
        channel_spectrum : ndarray, complex, shape (n_rx, n_bins)
            ``C_k`` from :meth:`path_spectrum` (sums of several allowed).
        rng : numpy.random.Generator or None
            Source of thermal noise; ``None`` (or ``config.noise`` false) gives no noise.

        Returns
        -------
        h : ndarray, float32, shape (n_rx, n)
            Sample m at time ``t0 + m / fs`` after emission.
        """
        spec = np.asarray(channel_spectrum, np.complex64) * self._system_response32
        if rng is not None and self.config.noise:
            self._add_noise(spec, rng)
        return np.fft.irfft(spec, n=self.config.n, axis=-1).astype(np.float32, copy=False)

    def impulse_responses(
        self, channel_spectra: np.ndarray, rngs: Sequence[np.random.Generator]
    ) -> npt.NDArray[np.float32]:
        """:meth:`impulse_response` of several acquisitions at once, each with its own noise
        source: ``h[i]`` is bit for bit ``impulse_response(channel_spectra[i], rngs[i])``.

        Each generator draws the same uniforms as in :meth:`impulse_response`; the system
        response, the Box-Muller transform and the inverse FFT, elementwise or per row, run
        once over the batch (one numpy call per step instead of one per acquisition: with
        8 acquisitions the simulator costs about a quarter less, issue 11, stop 19
        notes).

        Parameters
        ----------
        channel_spectra : ndarray, complex, shape (k, n_rx, n_bins)
        rngs : k generators (``config.noise`` false: unused)

        Returns
        -------
        h : ndarray, float32, shape (k, n_rx, n)
        """
        spec = np.asarray(channel_spectra, np.complex64) * self._system_response32
        if len(rngs) != spec.shape[0]:
            raise ValueError(f"{spec.shape[0]} spectra but {len(rngs)} generators")
        if self.config.noise and spec.size:
            u = np.empty((2, *spec.shape), np.float32)
            for i, rng in enumerate(rngs):
                u[:, i] = rng.random((2, *spec.shape[1:]), dtype=np.float32)
            self._add_noise_uniforms(spec, u)
        return np.fft.irfft(spec, n=self.config.n, axis=-1).astype(np.float32, copy=False)

    def window_grid(self, length: int) -> tuple[int, npt.NDArray[np.float32]]:
        """The grid of :meth:`window_noise` for the first ``length`` samples: its period
        ``m`` (an FFT-friendly length at least ``length + WINDOW_NOISE_GUARD``) and the
        per-bin std of the real and imaginary parts, shape (m // 2 + 1,), float32."""
        if not 1 <= length <= self.config.n:
            raise ValueError(f"window must be 1 to {self.config.n} samples, not {length}")
        cached = self._window_grids.get(length)
        if cached is not None:
            return cached
        from scipy.fft import next_fast_len

        cfg = self.config
        m = min(next_fast_len(length + WINDOW_NOISE_GUARD, real=True), cfg.n)
        if m == cfg.n:  # no shorter grid: the radar's own
            grid = (m, self._noise_scale)
        else:
            band = self.band(np.arange(m // 2 + 1) * (cfg.fs / m))
            if m % 2 == 0:
                band[-1] = 0.0  # the Nyquist bin is real: its noise would have half the power
            # var(irfft(V)) = (4 s^2 / m^2) sum_k B_k^2 for V_k = s B_k (a + j b), a, b
            # ~ N(0, 1): s is chosen to give the impulse response's noise_std
            s = self.noise_std * m / (2 * np.sqrt(np.sum(band[1:] ** 2)))
            grid = (m, (band * s).astype(np.float32))
        self._window_grids[length] = grid
        return grid

    def window_noise(
        self, rngs: Sequence[np.random.Generator], n_rx: int, length: int
    ) -> npt.NDArray[np.float32]:
        """Thermal noise of the first ``length`` samples of the impulse responses of
        ``len(rngs)`` acquisitions (one generator each), shape (k, n_rx, length), float32.

        The noise :meth:`noise_spectrum` adds is stationary Gaussian noise of spectrum
        ``B_k^2`` (std :attr:`noise_std`), whose autocorrelation falls below 1e-4 of its
        peak within 70 samples. Here it is synthesised on a shorter periodic grid of ``m``
        samples (:meth:`window_grid`, at least ``length + WINDOW_NOISE_GUARD``) with the
        same band, Box-Muller draws and scale, and cut to ``length``: the same std and,
        within the window, the same correlation up to the grid's period (lags beyond
        ``m - length`` alias, where the correlation is below 1e-4). For a radar window
        much shorter than the period (``uwbnet scale``'s range window, docs/capacity.md,
        ``--ir-window``) this draws and transforms a fraction of the bins; the realisations
        differ from :meth:`impulse_response`'s.
        """
        m, scale = self.window_grid(length)
        k = len(rngs)
        u = np.empty((2, k, n_rx, scale.size), np.float32)
        for i, rng in enumerate(rngs):
            u[:, i] = rng.random((2, n_rx, scale.size), dtype=np.float32)
        r = np.log1p(-u[0])
        r *= -2.0
        np.sqrt(r, out=r)
        r *= scale
        theta = u[1]
        theta *= np.float32(2 * np.pi)
        spec = np.empty((k, n_rx, scale.size), np.complex64)
        spec.real = r * np.cos(theta)
        spec.imag = r * np.sin(theta)
        return np.fft.irfft(spec, n=m, axis=-1)[..., :length].astype(np.float32, copy=False)

    def echo_responses(self, channel_spectra: np.ndarray) -> npt.NDArray[np.float32]:
        """Noise-free impulse responses ``irfft(G_k C_k)`` of spectra of shape
        (..., n_bins), float32 (..., n)."""
        spec = np.asarray(channel_spectra, np.complex64) * self._system_response32
        return np.fft.irfft(spec, n=self.config.n, axis=-1).astype(np.float32, copy=False)

    def receive(
        self, channel_spectrum: np.ndarray, rng: np.random.Generator | None = None
    ) -> np.ndarray:
        """Received periodic signal (one period, one sample per chip), before correlation.

        The explicit form of the measurement, for checking :meth:`impulse_response`:

        .. math:: r = \\mathrm{irfft}(S_k G_k C_k + B_k\\, \\mathrm{rfft}(w)_k),
                  \\quad w[m] \\sim N(0, \\sigma_r^2)

        with ``S_k`` the sequence spectrum and ``w`` the thermal noise (if ``rng``).

        Returns
        -------
        ndarray, float64, shape (n_rx, n)
        """
        spec = channel_spectrum * self.system_response * self._sequence_spectrum
        if rng is not None:
            w = rng.standard_normal((*spec.shape[:-1], self.config.n)) * self.receive_noise_std
            spec = spec + np.fft.rfft(w, axis=-1) * self.receiver_band
        return np.fft.irfft(spec, n=self.config.n, axis=-1)

    def correlate(self, received: npt.ArrayLike) -> npt.NDArray[np.float32]:
        """Impulse response from a received period by phase-only correlation (Ilmsens).

        .. math:: h = \\mathrm{irfft}(\\mathrm{rfft}(r)_k R_k),
                  \\quad R_k = \\overline{S_k} / (|S_k| \\sqrt{n+1}),\\; R_0 = 0

        Parameters
        ----------
        received : array_like, float, shape (..., n)

        Returns
        -------
        ndarray, float32, shape (..., n)
        """
        spec = np.fft.rfft(np.asarray(received, float), axis=-1) * self.reference_spectrum
        return np.fft.irfft(spec, n=self.config.n, axis=-1).astype(np.float32)
