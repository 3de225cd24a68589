"""Synthetic channel impulse responses with known first paths, for the ToA tests.

Paths are Gaussian pulses whose spectrum is 10 dB down at the band edges (the model pulse of
:func:`node_agent.dsp.band_filter.band_pulse`), on the carrier for complex baseband; noise is
white Gaussian noise through the same band (a receiver's noise is band-limited), scaled so
that its per-component standard deviation is ``sigma``. SNR is the strongest path's
envelope amplitude over ``sigma``, in dB.
"""

from __future__ import annotations

import numpy as np
from scipy.signal import oaconvolve

from node_agent.dsp.band_filter import band_pulse
from node_agent.dsp.geometry import RadarParams

DW1000 = RadarParams(fs=998.4e6, n=1016, t0=0.0, f_low=6.2396e9, f_high=6.7396e9, fc=6.4896e9)
"""A DW1000-class complex-baseband CIR: channel 5, 500 MHz, about 1 ns sampling."""

M_SEQUENCE = RadarParams(fs=7e9, n=4095, t0=0.0, f_low=0.0, f_high=3.5e9)
"""The chapter's real baseband M-sequence radar."""

PASSBAND = RadarParams(fs=7e9, n=2048, t0=0.0, f_low=3.5e9, f_high=6.5e9, fc=5.0e9)
"""A 3 GHz wide complex-baseband radar at 7 GHz sampling (neither of the above)."""


def synth_cir(
    radar: RadarParams,
    delays: np.ndarray,
    amplitudes: np.ndarray,
    snr_db: float,
    rng: np.random.Generator,
    *,
    rows: int = 1,
    complex_input: bool = True,
) -> np.ndarray:
    """Impulse responses (rows, n): paths at ``delays`` (s after sample 0), amplitudes, noise.

    ``delays``/``amplitudes`` are 1-D (the same channel on every row) or (rows, k).
    Returns complex64 or float32.
    """
    delays = np.broadcast_to(np.atleast_2d(delays), (rows, np.shape(delays)[-1]))
    amps = np.broadcast_to(np.atleast_2d(amplitudes), delays.shape)
    pulse = band_pulse(radar, complex_input=complex_input)
    k = (pulse.size - 1) // 2
    t = np.arange(radar.n) / radar.fs
    # the pulse model of band_pulse, evaluated at arbitrary delays (rows, k, n): a few paths
    half = 0.5 * radar.bandwidth if (complex_input or radar.f_low > 0) else radar.f_high
    f0 = 0.5 * (radar.f_low + radar.f_high) if (complex_input or radar.f_low > 0) else 0.0
    sigma_t = np.sqrt(np.log(10.0)) / (2 * np.pi * half)
    dt = t[None, None, :] - delays[:, :, None]
    env = np.exp(-0.5 * (dt / sigma_t) ** 2)
    if complex_input:
        # carrier phase of each path: exp(-2j pi fc tau)
        wave = env * np.exp(2j * np.pi * (f0 - radar.fc) * dt)
        wave *= np.exp(-2j * np.pi * radar.fc * delays)[:, :, None]
    else:
        wave = env * np.cos(2 * np.pi * f0 * dt)
    h = np.einsum("rk,rkn->rn", amps, wave)
    sigma = float(np.max(np.abs(amps))) * 10 ** (-snr_db / 20)
    kernel = pulse / np.sqrt(np.sum(np.abs(pulse) ** 2))
    if complex_input:
        w = rng.standard_normal((rows, radar.n + 2 * k)) + 1j * rng.standard_normal(
            (rows, radar.n + 2 * k)
        )
        noise = oaconvolve(w, kernel[None, :], mode="valid", axes=1)
        return (h + sigma * noise).astype(np.complex64)
    w = rng.standard_normal((rows, radar.n + 2 * k))
    noise = oaconvolve(w, kernel[None, :], mode="valid", axes=1)
    return (h.real + sigma * noise).astype(np.float32)
