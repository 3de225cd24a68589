"""Kirchhoff migration (eq. (17)) and cross-correlated imaging (eq. (18)) of the CoLOR chapter.

Both images are sums over observations ``m`` (one impulse response ``h_m`` of transmitter
``T_m`` at receiver ``R_m``) of samples taken at the bistatic delay of every pixel ``x``:

.. math:: \\tau_m(x) = (|x - T_m| + |x - R_m|) / c

* Kirchhoff migration, eq. (17): :math:`I(x) = \\sum_m w_m(x)\\, h_m(\\tau_m(x))`.
* Cross-correlated imaging, eq. (18): every observation is correlated over the pulse duration
  ``T`` with the observation of a reference receiver ``r(m)`` of the same emission,
  :math:`I(x) = \\sum_m \\int_{-T/2}^{T/2} h_m(\\tau_m(x) + t)\\, h_{r(m)}(\\tau_{r(m)}(x) + t)
  \\, dt`, evaluated with ``taps`` samples spaced ``1/fs``. Echoes that do not come from ``x``
  rarely arrive at both receivers at the matching delays, so the ellipse "smiles" of plain
  migration cancel.

Signals are pre-processed by :func:`prepare_signals` (optional envelope detection, gating of
the direct Tx-Rx coupling). Samples between grid points are linearly interpolated by index
arithmetic (``i = floor(s)``, ``h[i] + (s - i) (h[i+1] - h[i])``) over a chunk of
observations x a tile of pixels at once, float32; distances come from one small matrix
product per chunk (``|x - r|^2 = |x|^2 - 2 x.r + |r|^2``). Observations with the same
geometry (a static network over many frames) are summed before migration (the migration is
linear in ``h``). Pure numpy: the caller may pass a ``map`` (e.g. a thread pool's; numpy
releases the GIL in the kernels) to spread pixel tiles over cores.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from protocol.units import C

F32 = npt.NDArray[np.float32]
Map = Callable[[Callable[[Any], Any], Iterable[Any]], Iterator[Any]]

__all__ = [
    "Grid",
    "Observations",
    "cross_correlated_image",
    "kirchhoff_image",
    "pattern_exponent",
    "prepare_signals",
]


@dataclass(frozen=True, slots=True)
class Grid:
    """A horizontal image plane: pixel (i, j) at (x0 + j dx, y0 + i dy, z), metres."""

    x0: float
    y0: float
    dx: float
    dy: float
    nx: int
    ny: int
    z: float = 1.0

    @classmethod
    def covering(
        cls, x_min: float, x_max: float, y_min: float, y_max: float, nx: int, ny: int, z: float
    ) -> Grid:
        """``nx`` x ``ny`` pixels whose centres span the rectangle (edges included)."""
        dx = (x_max - x_min) / max(nx - 1, 1)
        dy = (y_max - y_min) / max(ny - 1, 1)
        return cls(x_min, y_min, dx, dy, nx, ny, z)

    def xy(self) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        """Pixel centre coordinates along x (nx,) and y (ny,)."""
        return self.x0 + self.dx * np.arange(self.nx), self.y0 + self.dy * np.arange(self.ny)


@dataclass(frozen=True, slots=True, kw_only=True)
class Observations:
    """Impulse responses and their antenna geometry, world frame.

    Attributes
    ----------
    h : ndarray, float32 (M, n) or complex64 (M, n)
        Sample ``k`` at ``t0 + k / fs`` after emission; complex rows are complex baseband
        with carrier ``fc``.
    tx, rx : ndarray, float64, (M, 3)
        Transmitter and receiver antenna positions, m.
    fs, t0 : float
        Sample rate (Hz) and time of sample 0 (s).
    fc : float
        Carrier of complex-baseband rows, Hz (0 for real rows).
    tx_yaw, rx_yaw : ndarray (M,) or None
        Boresight azimuths in the world frame, rad (antenna-pattern weighting).
    tx_beamwidth, rx_beamwidth : ndarray (M,) or None
        3 dB beamwidths, rad (2 pi: omni).
    emission : ndarray, int64 (M,) or None
        Identifier of the emission (transmitter and acquisition) of each row: rows of one
        emission are candidates as reference receivers of each other (eq. (18)).
    """

    h: npt.NDArray[Any]
    tx: npt.NDArray[np.float64]
    rx: npt.NDArray[np.float64]
    fs: float
    t0: float = 0.0
    fc: float = 0.0
    tx_yaw: npt.NDArray[np.float64] | None = None
    rx_yaw: npt.NDArray[np.float64] | None = None
    tx_beamwidth: npt.NDArray[np.float64] | None = None
    rx_beamwidth: npt.NDArray[np.float64] | None = None
    emission: npt.NDArray[np.int64] | None = None

    def __post_init__(self) -> None:
        m = self.h.shape[0]
        if self.h.ndim != 2 or self.tx.shape != (m, 3) or self.rx.shape != (m, 3):
            raise ValueError("h must be (M, n) and tx, rx (M, 3)")

    def __len__(self) -> int:
        return int(self.h.shape[0])

    def take(self, idx: npt.ArrayLike) -> Observations:
        """The observations ``idx`` (an index array or boolean mask)."""

        def sel(a: Any) -> Any:
            return None if a is None else a[idx]

        return Observations(
            h=self.h[idx],
            tx=self.tx[idx],
            rx=self.rx[idx],
            fs=self.fs,
            t0=self.t0,
            fc=self.fc,
            tx_yaw=sel(self.tx_yaw),
            rx_yaw=sel(self.rx_yaw),
            tx_beamwidth=sel(self.tx_beamwidth),
            rx_beamwidth=sel(self.rx_beamwidth),
            emission=sel(self.emission),
        )


def envelope_rows(h: npt.NDArray[Any], block: int = 1024) -> F32:
    """Hilbert envelope ``|h + j H{h}|`` of real rows (``|h|`` of complex rows), float32.

    The analytic signal is formed in the frequency domain (negative frequencies zeroed, positive
    doubled) in blocks of rows, in single precision.
    """
    from scipy import fft

    if np.iscomplexobj(h):
        return np.abs(h).astype(np.float32)
    n = h.shape[-1]
    gain = np.zeros(n, np.float32)
    gain[0] = 1.0
    gain[1 : (n + 1) // 2] = 2.0
    if n % 2 == 0:
        gain[n // 2] = 1.0
    out = np.empty(h.shape, np.float32)
    for a in range(0, h.shape[0], block):
        spec = fft.fft(h[a : a + block].astype(np.float32), axis=-1)
        spec *= gain
        out[a : a + block] = np.abs(fft.ifft(spec, axis=-1, overwrite_x=True))
    return out


def prepare_signals(obs: Observations, *, envelope: bool = True, gate: float = 0.3) -> Any:
    """The signals that are migrated, (M, n): float32, or complex64 for complex baseband.

    Parameters
    ----------
    envelope : bool
        Hilbert envelope (:func:`envelope_rows`) before migration: an incoherent image,
        robust to pose errors and to pixels larger than a quarter wavelength. ``False``: the
        raw samples (eq. (17) as printed; complex rows are then remodulated per pixel, see
        :func:`kirchhoff_image`).
    gate : float
        Samples whose path is shorter than the direct Tx-Rx distance plus ``gate`` metres are
        zeroed: the direct coupling is not an echo of the scene. Negative: no gate.
    """
    h = obs.h
    if envelope:
        sig = envelope_rows(h)
    else:
        sig = h.astype(np.complex64 if np.iscomplexobj(h) else np.float32, copy=True)
    if gate >= 0:
        direct = np.linalg.norm(obs.tx - obs.rx, axis=1) + gate
        k_min = np.ceil((direct / C - obs.t0) * obs.fs).astype(np.int64)
        sig[np.arange(sig.shape[1])[None, :] < k_min[:, None]] = 0
    return sig


def pattern_exponent(beamwidth: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """Exponent ``q`` of the ``cos(theta)^q`` amplitude pattern with the given 3 dB width.

    ``cos(bw/2)^q = 1/sqrt(2)``; 0 (omni) for ``bw >= pi``.
    """
    bw = np.asarray(beamwidth, float)
    with np.errstate(divide="ignore"):
        q = np.log(np.sqrt(0.5)) / np.log(np.cos(np.minimum(bw, np.pi - 1e-9) / 2))
    return np.where(bw >= np.pi, 0.0, q)


# --- the kernel -------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class _Plan:
    """Pixel tiles and the per-observation arrays of one migration."""

    pix: F32  # (5, P): x, y, z (centred), |x|^2, 1
    centre: npt.NDArray[np.float64]
    tiles: list[slice]


def _plan(grid: Grid, tile: int) -> _Plan:
    xs, ys = grid.xy()
    centre = np.array([xs.mean(), ys.mean(), grid.z])
    X, Y = np.meshgrid(xs - centre[0], ys - centre[1])
    x = X.ravel()
    y = Y.ravel()
    z = np.zeros_like(x)
    pix = np.stack([x, y, z, x * x + y * y, np.ones_like(x)]).astype(np.float32)
    p = x.size
    return _Plan(pix, centre, [slice(a, min(a + tile, p)) for a in range(0, p, tile)])


def _dist_rows(pos: npt.NDArray[np.float64], centre: npt.NDArray[np.float64], a: float) -> F32:
    """Rows of the matrix product giving ``(a |x - p|)^2`` for every position ``p``."""
    p = pos - centre
    r2 = np.sum(p * p, axis=1)
    rows = np.stack([-2 * p[:, 0], -2 * p[:, 1], -2 * p[:, 2], np.ones(len(p)), r2], axis=1)
    return (rows * a * a).astype(np.float32)


def _dir_rows(
    pos: npt.NDArray[np.float64], yaw: npt.NDArray[np.float64], centre: npt.NDArray[np.float64]
) -> F32:
    """Rows giving ``(x - p) . b`` for boresight ``b = (cos yaw, sin yaw, 0)``."""
    p = pos - centre
    b = np.stack([np.cos(yaw), np.sin(yaw)], axis=1)
    off = -(p[:, 0] * b[:, 0] + p[:, 1] * b[:, 1])
    z = np.zeros(len(p))
    return np.stack([b[:, 0], b[:, 1], z, z, off], axis=1).astype(np.float32)


def _unique_rows(a: npt.NDArray[np.float64]) -> tuple[npt.NDArray[np.float64], npt.NDArray[Any]]:
    """Unique positions (to 1 um) and the index of each row into them."""
    key = np.round(a * 1e6).astype(np.int64)
    _, first, inv = np.unique(key, axis=0, return_index=True, return_inverse=True)
    return a[first], inv.reshape(-1)


@dataclass(frozen=True, slots=True)
class _Chunk:
    """One chunk of observations ready for the kernel (rows padded: [0, h..., 0, 0])."""

    sig: npt.NDArray[Any]  # padded rows, flattened
    dsig: npt.NDArray[Any]  # differences h[i+1] - h[i] of the padded rows, flattened
    rx_pos: npt.NDArray[np.float64]  # (C, 3) centred, for delay bounds
    tx_pos: npt.NDArray[np.float64]  # (C, 3) centred
    rx_rows: F32  # (C, 5)
    tx_rows: F32  # (U, 5) unique transmitters of the chunk
    tx_idx: npt.NDArray[np.intp]
    offset: F32  # (C, 1) flat index of each row's padded sample 0
    n: int
    weights: tuple[F32, F32, F32, F32, npt.NDArray[np.float32]] | None  # tx/rx dir rows, q's
    phase: float  # 2 pi fc / fs for complex remodulation (0: real)


def _chunks(
    obs: Observations, sig: npt.NDArray[Any], plan: _Plan, chunk: int, pattern: bool
) -> Iterator[_Chunk]:
    a = obs.fs / C
    n = sig.shape[1]
    for c0 in range(0, len(obs), chunk):
        c1 = min(c0 + chunk, len(obs))
        s = sig[c0:c1]
        pad = np.zeros((s.shape[0], n + 3), s.dtype)
        pad[:, 1 : n + 1] = s
        d = np.zeros_like(pad)
        d[:, :-1] = pad[:, 1:] - pad[:, :-1]
        utx, tx_idx = _unique_rows(obs.tx[c0:c1])
        tx_rows = _dist_rows(utx, plan.centre, a)
        weights = None
        if pattern:
            q_t = pattern_exponent(obs.tx_beamwidth[c0:c1])
            q_r = pattern_exponent(obs.rx_beamwidth[c0:c1])
            weights = (
                _dir_rows(obs.tx[c0:c1], obs.tx_yaw[c0:c1], plan.centre),
                _dir_rows(obs.rx[c0:c1], obs.rx_yaw[c0:c1], plan.centre),
                _dist_rows(obs.tx[c0:c1], plan.centre, 1.0),
                _dist_rows(obs.rx[c0:c1], plan.centre, 1.0),
                np.stack([q_t, q_r], axis=1).astype(np.float32),
            )
        yield _Chunk(
            sig=pad.reshape(-1),
            dsig=d.reshape(-1),
            rx_pos=obs.rx[c0:c1] - plan.centre,
            tx_pos=obs.tx[c0:c1] - plan.centre,
            rx_rows=_dist_rows(obs.rx[c0:c1], plan.centre, a),
            tx_rows=tx_rows,
            tx_idx=tx_idx,
            offset=((np.arange(c1 - c0) * (n + 3)).astype(np.float32))[:, None],
            n=n,
            weights=weights,
            phase=2 * math.pi * obs.fc / obs.fs if np.iscomplexobj(sig) else 0.0,
        )


def _sample_index(ch: _Chunk, pix: F32, t0fs: float) -> F32:
    """``s = fs tau_m(x) - fs t0 + 1`` (index into the padded rows), float32 (C, P)."""
    # einsum, not matmul: with 5 inner terms BLAS threading costs more than it saves. Float32
    # rounding of |x|^2 - 2 x.r + |r|^2 can go slightly negative next to an antenna: clamp.
    s = np.einsum("ck,kp->cp", ch.rx_rows, pix)
    st = np.einsum("ck,kp->cp", ch.tx_rows, pix)
    np.maximum(s, 0, out=s)
    np.maximum(st, 0, out=st)
    np.sqrt(s, out=s)
    np.sqrt(st, out=st)
    st += np.float32(1.0 - t0fs)
    if st.shape[0] == 1:
        s += st
    else:
        s += st[ch.tx_idx]
    return s


def _in_range(ch: _Chunk, box: tuple[float, float, float, float], a: float, t0fs: float) -> bool:
    """Whether every pixel of the tile ``box`` (centred x0, x1, y0, y1) maps inside the rows:
    the farthest point of a rectangle from an antenna is a corner, the nearest is clamped."""
    x0, x1, y0, y1 = box
    worst = np.zeros(len(ch.rx_pos))
    best = np.zeros(len(ch.rx_pos))
    for p in (ch.rx_pos, ch.tx_pos):
        fx = np.maximum(np.abs(p[:, 0] - x0), np.abs(p[:, 0] - x1))
        fy = np.maximum(np.abs(p[:, 1] - y0), np.abs(p[:, 1] - y1))
        worst += np.sqrt(fx**2 + fy**2 + p[:, 2] ** 2)
        nx = p[:, 0] - np.clip(p[:, 0], x0, x1)
        ny = p[:, 1] - np.clip(p[:, 1], y0, y1)
        best += np.sqrt(nx**2 + ny**2 + p[:, 2] ** 2)
    return bool(a * worst.max() + 1 - t0fs < ch.n + 0.5 and a * best.min() + 1 - t0fs >= 0.5)


def _interp(ch: _Chunk, s: F32, clip: bool = True) -> Any:
    """Linearly interpolated padded rows at fractional indices ``s`` (consumed)."""
    if clip:
        np.clip(s, 0, ch.n + 1, out=s)
    s += ch.offset  # exact in float32 for chunk x row length < 2^17 (1/128 sample)
    fl = np.floor(s)
    s -= fl  # fraction
    i = fl.astype(np.int32)
    v = ch.dsig.take(i)
    v *= s
    v += ch.sig.take(i)
    return v


def _pattern(ch: _Chunk, pix: F32) -> F32:
    """Amplitude pattern weights ``cos(theta_t)^q_t cos(theta_r)^q_r``, float32 (C, P)."""
    assert ch.weights is not None
    dir_t, dir_r, dist_t, dist_r, q = ch.weights
    w = np.ones((dir_t.shape[0], pix.shape[1]), np.float32)
    for k, (drow, srow) in enumerate(((dir_t, dist_t), (dir_r, dist_r))):
        cos = np.einsum("ck,kp->cp", drow, pix)
        d = np.einsum("ck,kp->cp", srow, pix)
        np.maximum(d, 1e-6, out=d)
        np.sqrt(d, out=d)
        cos /= d
        np.clip(cos, 0, 1, out=cos)
        qk = q[:, k : k + 1]
        np.power(cos, qk, out=cos, where=qk > 0)
        cos[np.broadcast_to(qk <= 0, cos.shape)] = 1.0
        w *= cos
    return w


def _kirchhoff_tile(args: tuple[list[_Chunk], F32, tuple[float, float]]) -> npt.NDArray[Any]:
    chunks, pix, (t0fs, a) = args
    box = (pix[0].min(), pix[0].max(), pix[1].min(), pix[1].max())
    acc: npt.NDArray[Any] | None = None
    for ch in chunks:
        s = _sample_index(ch, pix, t0fs)
        phase = None
        if ch.phase:
            phase = (s - np.float32(1.0 - t0fs)) * np.float32(ch.phase)
        v = _interp(ch, s, clip=not _in_range(ch, box, a, t0fs))
        if phase is not None:
            v = v * (np.cos(phase) + 1j * np.sin(phase)).astype(np.complex64)
        if ch.weights is not None:
            v *= _pattern(ch, pix)
        part = v.sum(axis=0)
        acc = part if acc is None else acc + part
    assert acc is not None
    return acc


def _run_tiles(
    work: Callable[[Any], npt.NDArray[Any]],
    chunks: list[Any],
    plan: _Plan,
    extra: float,
    grid: Grid,
    map_fn: Map | None,
    progress: Callable[[int], None] | None,
) -> npt.NDArray[Any]:
    jobs = [(chunks, np.ascontiguousarray(plan.pix[:, t]), extra) for t in plan.tiles]
    results = (map_fn or map)(work, jobs)
    out: npt.NDArray[Any] | None = None
    for t, r in zip(plan.tiles, results, strict=True):
        if out is None:
            out = np.zeros(grid.nx * grid.ny, r.dtype)
        out[t] = r
        if progress is not None:
            progress(t.stop - t.start)
    assert out is not None
    return out.reshape(grid.ny, grid.nx)


def _merge_same_geometry(obs: Observations, sig: npt.NDArray[Any]) -> tuple[Observations, Any]:
    """Sum the signals of observations with identical geometry (migration is linear)."""
    parts = [obs.tx, obs.rx]
    for a in (obs.tx_yaw, obs.rx_yaw, obs.tx_beamwidth, obs.rx_beamwidth):
        if a is not None:
            parts.append(a[:, None])
    key = np.round(np.concatenate(parts, axis=1) * 1e6).astype(np.int64)
    _, first, inv = np.unique(key, axis=0, return_index=True, return_inverse=True)
    if first.size == len(obs):
        return obs, sig
    summed = np.zeros((first.size, sig.shape[1]), sig.dtype)
    np.add.at(summed, inv.reshape(-1), sig)
    return obs.take(first), summed


def kirchhoff_image(
    obs: Observations,
    grid: Grid,
    *,
    envelope: bool = True,
    gate: float = 0.3,
    pattern: bool = False,
    chunk: int = 16,
    tile: int = 16384,
    map_fn: Map | None = None,
    progress: Callable[[int], None] | None = None,
) -> F32:
    """Kirchhoff migration, eq. (17) of the CoLOR chapter, on ``grid``.

    Parameters
    ----------
    obs : Observations
        Any mix of static and moving transmitters and receivers (positions per row).
    envelope, gate
        Signal pre-processing (:func:`prepare_signals`).
    pattern : bool
        Weight each sample by the ``cos^q`` amplitude patterns of its Tx and Rx antennas
        (``obs.*_yaw`` and ``*_beamwidth`` needed): echoes are not smeared behind a horn.
    chunk, tile : int
        Observations x pixels evaluated at once (memory ``~ 10 chunk tile 4`` bytes per
        worker).
    map_fn : callable, optional
        ``map`` over pixel tiles (a thread pool's ``map`` spreads them over cores).
    progress : callable, optional
        Called with the number of pixels finished.

    Returns
    -------
    ndarray, float32, (ny, nx)
        The image; complex-baseband rows without envelope give its magnitude.
    """
    if pattern and (obs.tx_yaw is None or obs.rx_yaw is None):
        raise ValueError("antenna-pattern weighting needs antenna boresights")
    sig = prepare_signals(obs, envelope=envelope, gate=gate)
    obs2, sig = _merge_same_geometry(obs, sig)
    plan = _plan(grid, tile)
    chunks = list(_chunks(obs2, sig, plan, chunk, pattern))
    extra = (obs.t0 * obs.fs, obs.fs / C)
    img = _run_tiles(_kirchhoff_tile, chunks, plan, extra, grid, map_fn, progress)
    return (np.abs(img) if np.iscomplexobj(img) else img).astype(np.float32)


# --- cross-correlated imaging -----------------------------------------------------------------


def default_references(obs: Observations) -> npt.NDArray[np.intp]:
    """The reference row of every observation: the nearest other receiver of the same emission.

    A nearby receiver sees the same echoes with almost the same waveform, so the correlation
    of eq. (18) is high at true scatterers, while the baseline separates the ellipses of
    off-target echoes. -1 where an emission has a single receiver (those rows are skipped).
    """
    m = len(obs)
    ref = np.full(m, -1, np.intp)
    em = obs.emission if obs.emission is not None else np.zeros(m, np.int64)
    order = np.argsort(em, kind="stable")
    bounds = np.flatnonzero(np.diff(em[order])) + 1
    for group in np.split(order, bounds):
        if group.size < 2:
            continue
        p = obs.rx[group]
        d = np.linalg.norm(p[:, None] - p[None], axis=-1)
        np.fill_diagonal(d, np.inf)
        ref[group] = group[np.argmin(d, axis=1)]
    return ref


def _xcorr_tile(args: tuple[list[tuple[_Chunk, _Chunk]], F32, tuple[float, int]]) -> Any:
    pairs, pix, (t0fs, taps, fs_c) = args
    box = (pix[0].min(), pix[0].max(), pix[1].min(), pix[1].max())
    acc = None
    half = (taps - 1) / 2
    for a, b in pairs:
        sa = _sample_index(a, pix, t0fs)
        sb = _sample_index(b, pix, t0fs)
        # Taps reach half a window beyond the delays: clip unless well inside.
        ok = _in_range(a, box, fs_c, t0fs - half - 1) and _in_range(b, box, fs_c, t0fs - half - 1)
        ok = (
            ok
            and _in_range(a, box, fs_c, t0fs + half + 1)
            and _in_range(b, box, fs_c, t0fs + half + 1)
        )
        part = None
        for k in range(taps):
            off = np.float32(k - half)
            va = _interp(a, sa + off if taps > 1 else sa, clip=not ok)
            vb = _interp(b, sb + off if taps > 1 else sb, clip=not ok)
            va *= vb
            part = va if part is None else part + va
        if a.weights is not None:
            part *= _pattern(a, pix)
        r = part.sum(axis=0)
        acc = r if acc is None else acc + r
    assert acc is not None
    return acc


def cross_correlated_image(
    obs: Observations,
    grid: Grid,
    *,
    references: npt.ArrayLike | None = None,
    duration: float | None = None,
    envelope: bool = True,
    gate: float = 0.3,
    pattern: bool = False,
    symmetric: bool = True,
    chunk: int = 16,
    tile: int = 16384,
    map_fn: Map | None = None,
    progress: Callable[[int], None] | None = None,
) -> F32:
    """Cross-correlated imaging, eq. (18) of the CoLOR chapter, on ``grid``.

    Parameters
    ----------
    references : array_like of int, optional
        Row of the reference receiver of every observation (-1: skip the row); default
        :func:`default_references`.
    duration : float, optional
        Correlation window ``T``, s; default the pulse duration ``1 / bandwidth`` is not known
        here, so one sample period per 0.1 ns (``taps = max(1, round(T fs))``, default
        ``T = 0.1 ns``).
    symmetric : bool
        A pair ``(m, r)`` whose reference is mutual is evaluated once (the integrand is
        symmetric), which halves the work for two-receiver nodes.
    Other parameters as :func:`kirchhoff_image`.
    """
    m = len(obs)
    ref = default_references(obs) if references is None else np.asarray(references, np.intp)
    if ref.shape != (m,) or np.any(ref >= m):
        raise ValueError("references must give one row index (or -1) per observation")
    keep = ref >= 0
    idx = np.flatnonzero(keep)
    if symmetric:
        mutual = ref[ref[idx]] == idx
        idx = idx[~mutual | (idx < ref[idx])]
    if idx.size == 0:
        raise ValueError("no observation has a reference receiver (one receiver per emission)")
    sig = prepare_signals(obs, envelope=envelope, gate=gate)
    taps = max(1, round((duration if duration is not None else 1e-10) * obs.fs))
    plan = _plan(grid, tile)
    ca = list(_chunks(obs.take(idx), sig[idx], plan, chunk, pattern))
    cb = list(_chunks(obs.take(ref[idx]), sig[ref[idx]], plan, chunk, False))
    img = _run_tiles(
        _xcorr_tile,
        list(zip(ca, cb, strict=True)),
        plan,
        (obs.t0 * obs.fs, taps, obs.fs / C),
        grid,
        map_fn,
        progress,
    )
    return np.abs(img).astype(np.float32) if np.iscomplexobj(img) else img.astype(np.float32)
