"""Frequency responses and impulse responses from path lists (pure numpy).

A path list ``(tau_i, a_i(f))`` has the transfer function

.. math:: H(f) = \\sum_i a_i(f)\\, e^{-j 2 \\pi f \\tau_i},

with ``a_i(f)`` linearly interpolated between the amplitude knots of the
:class:`~sim_nodes.channel.raytrace.PathSet` (constant outside them), evaluated on a
uniform frequency grid by a non-uniform FFT (:func:`frequency_response`).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from scipy import fft as scipy_fft
from scipy import sparse

from sim_nodes.channel.raytrace import PathSet
from sim_nodes.radar import C

_SPREAD = 6  # half-width of the Gaussian spreading kernel, grid points (about 1e-6)


def knot_weights(knots: np.ndarray, f: np.ndarray) -> npt.NDArray[np.float64]:
    """Linear-interpolation weights ``phi_b(f)`` of the amplitude knots, shape (B, K)."""
    knots = np.asarray(knots, float)
    f = np.asarray(f, float)
    if knots.size == 1:
        return np.ones((1, f.size))
    eye = np.eye(knots.size)
    return np.stack([np.interp(f, knots, eye[b]) for b in range(knots.size)])


def frequency_response(
    paths: PathSet,
    n_rx: int,
    f0: float,
    df: float,
    n_freq: int,
    *,
    delay_offset: float = 0.0,
) -> npt.NDArray[np.complex64]:
    """Transfer function of every receiver on the grid ``f_k = f0 + k df``.

    .. math:: H_r(f_k) = \\sum_{i: rx_i = r} a_i(f_k)\\, e^{-j 2 \\pi f_k (\\tau_i - t_0)}

    Computed by a type-1 non-uniform FFT with Gaussian gridding (Greengard and Lee 2004):
    with ``x_i = 2 pi df (tau_i - t_0) mod 2 pi`` and ``k = k' + K_0`` the sum is
    ``sum_i c_i e^{-j k' x_i}`` with ``c_i = a_i e^{-j 2 pi (f_0 + K_0 df)(tau_i - t_0)}``.
    Each ``c_i`` is spread onto a 2x oversampled periodic grid with the Gaussian
    ``exp(-(x - x_i)^2 / (4 tau))`` over 12 neighbours, the grid is FFT'd, and the Gaussian
    is divided out (``sqrt(pi / tau) exp(k'^2 tau)``): relative error about 1e-6 of the
    largest term, cost ``O(P + K log K)`` per receiver instead of ``O(P K)``, so tens of
    thousands of scatterer paths stay cheap. Amplitude knots are synthesised separately
    and blended with their interpolation weights.

    Parameters
    ----------
    paths : PathSet
    n_rx : int
        Number of receivers R (rows of the result).
    f0, df : float
        First frequency and step, Hz.
    n_freq : int
        Number of frequencies K.
    delay_offset : float
        ``t_0``, s, subtracted from every delay (the radar's time of sample 0).

    Returns
    -------
    ndarray, complex64, shape (R, K)
        ``1/d``-scaled (multiply by ``c / (4 pi f)`` for the physical Friis amplitude).
    """
    out = np.zeros((n_rx, n_freq), np.complex64)
    if paths.count == 0:
        return out
    k0 = n_freq // 2
    n_grid = 2 * _next_fast(n_freq)
    half = _SPREAD
    tau_g = np.pi * half / (n_freq**2 * 2 * 1.5)
    # Paths grouped by receiver: the spreading then writes within one receiver's grid.
    order = np.argsort(paths.rx, kind="stable")
    rx_sorted = paths.rx[order]
    tau = paths.delay[order] - delay_offset
    cyc = tau * df
    x = 2 * np.pi * (cyc - np.floor(cyc))  # in [0, 2 pi)
    turns = tau * (f0 + k0 * df)
    turns -= np.rint(turns)
    phase = (-2 * np.pi) * turns
    rot = np.empty(turns.size, np.complex64)
    rot.real = np.cos(phase)
    rot.imag = np.sin(phase)
    c = paths.amplitude.astype(np.complex64)[order] * rot[:, None]  # (P, B)
    # Gaussian spreading onto grid points m0 - half + 1 .. m0 + half, with the factorisation
    # exp(-(e - l h)^2 / 4 tau) = exp(-e^2 / 4 tau) q^l exp(-(l h)^2 / 4 tau), q = exp(e h / 2 tau)
    # (e = x - m0 h): two exponentials per path and products instead of 2 half exponentials.
    h = 2 * np.pi / n_grid
    m0 = np.floor(x / h).astype(np.int32)
    e = x - m0 * h
    offs = np.arange(-half + 1, half + 1)
    q = np.exp(e * (h / (2 * tau_g))).astype(np.float32)
    w = np.empty((x.size, offs.size), np.float32)
    w[:, half - 1] = np.exp(-(e * e) / (4 * tau_g))  # l = 0
    for j in range(half, offs.size):  # l = 1 .. half: 2 half products, not per-path work
        w[:, j] = w[:, j - 1] * q
    q_inv = 1.0 / q
    for j in range(half - 2, -1, -1):  # l = -1 .. -(half - 1)
        w[:, j] = w[:, j + 1] * q_inv
    w *= np.exp(-((offs * h) ** 2) / (4 * tau_g)).astype(np.float32)
    # An extended grid (half - 1 cells before, half after) avoids a modulo per weight; the
    # overhangs are folded back (periodic grid) after spreading.
    n_ext = n_grid + 2 * half - 1
    cell = m0[:, None] + np.arange(2 * half, dtype=np.int32)  # index into the extended grid
    flat = (rx_sorted.astype(np.int32)[:, None] * n_ext + cell).reshape(-1)
    # Spreading as one sparse (grid x path) matrix applied to all knots at once: column i
    # holds path i's 2 half Gaussian weights (already in CSC order, no sorting needed).
    spread = sparse.csc_matrix(
        (w.reshape(-1), flat, np.arange(0, w.size + 1, 2 * half, dtype=np.int32)),
        shape=(n_rx * n_ext, paths.count),
    )
    # Real weights times (re, im) pairs: a real sparse product on the float32 view of c,
    # about 4x faster than letting scipy promote the weights to complex.
    ext = np.ascontiguousarray(spread @ c.view(np.float32), np.float32).view(np.complex64)
    ext = ext.reshape(n_rx, n_ext, -1)
    g = ext[:, half - 1 : half - 1 + n_grid].copy()
    g[:, n_grid - half + 1 :] += ext[:, : half - 1]
    g[:, :half] += ext[:, half - 1 + n_grid :]
    g = np.ascontiguousarray(g.transpose(0, 2, 1))  # (R, B, grid)
    spec = scipy_fft.fft(g, axis=-1)  # (R, B, grid), complex64 kept
    weights = knot_weights(paths.knots, f0 + df * np.arange(n_freq))  # (B, K)
    kp = np.arange(n_freq) - k0
    deconv = np.sqrt(np.pi / tau_g) * np.exp(kp.astype(float) ** 2 * tau_g) / n_grid
    # FFT bin k' >= 0 is k', k' < 0 is n_grid + k'.
    sel = spec[:, :, np.remainder(kp, n_grid)]  # (R, B, K)
    out[:] = np.einsum("rbk,bk->rk", sel, (weights * deconv).astype(np.float32))
    return out


def _next_fast(n: int) -> int:
    """Smallest 2^a 3^b 5^c >= n (fast FFT length)."""
    best = 2 * n
    for a in range(int(np.log2(n)) + 2):
        for b in range(int(np.log(n) / np.log(3)) + 2):
            v = 2**a * 3**b
            while v < n:
                v *= 5
            best = min(best, v)
    return best


def impulse_response(
    h_f: np.ndarray, df: float, window: str | None = "hann"
) -> tuple[npt.NDArray[np.complex64], npt.NDArray[np.float64]]:
    """Complex (baseband-equivalent) impulse response of a band-limited transfer function.

    .. math:: h[n] = \\frac{1}{K} \\sum_k w_k H(f_k) e^{j 2 \\pi k n / K},
              \\quad \\tau_n = n / (K \\Delta f)

    Parameters
    ----------
    h_f : ndarray, complex, shape (..., K)
    df : float
        Frequency step, Hz.
    window : {"hann", None}
        Spectral window against delay sidelobes.

    Returns
    -------
    h : ndarray, complex64, shape (..., K)
    tau : ndarray, float64, shape (K,), s (period ``1 / df``)
    """
    k = h_f.shape[-1]
    w = np.hanning(k) if window == "hann" else np.ones(k)
    h = np.fft.ifft(h_f * w, axis=-1).astype(np.complex64)
    return h, np.arange(k) / (k * df)


def friis_amplitude(f: npt.ArrayLike) -> np.ndarray:
    """``c / (4 pi f)``: turns a ``1/d``-scaled transfer function into the Friis one."""
    return C / (4 * np.pi * np.asarray(f, float))
