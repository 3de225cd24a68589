"""Circular scans around one object (Section 7): track geometry, echoes, impulse responses.

A bat-type sensor moves on a circle (or part of one) of radius ``radius`` around ``centre``,
stopping every ``step`` (1 degree by default), its boresight toward the centre. Its
polarimetric antennas: a transmitter and a receiver ``baseline`` apart along the track
(transmitter ahead, counter-clockwise), each switchable between vertical (V) and horizontal
(H) polarization, plus the pair rotated by 45 degrees (P = +45, M = -45 degrees).

The echoes come from :func:`sim_nodes.channel.prism.prism_echoes` (faces, wedges, dihedrals,
rough facets, shadowing); :func:`scan_impulse_responses` turns them into the M-sequence
radar's impulse responses (:class:`sim_nodes.radar.MSequenceRadar`), one row per
polarization channel. :func:`geometric_wavefronts` is the fast path of the recognition
benchmark: the echo ranges themselves, with range noise and the radar's resolution (echoes
closer than ``resolution`` merge), without synthesising waveforms. Pure numpy.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from sim_nodes.channel.prism import PrismEchoes, PrismTarget, prism_echoes, rotate_basis
from sim_nodes.radar import C, MSequenceRadar

#: Polarization channels: name -> (basis rotation, rx index, tx index); ``vh`` is
#: transmit H, receive V. ``pp``/``pm``: the 45-degree pair, co- and cross-polar.
CHANNELS: dict[str, tuple[float, int, int]] = {
    "vv": (0.0, 0, 0),
    "hv": (0.0, 1, 0),
    "hh": (0.0, 1, 1),
    "vh": (0.0, 0, 1),
    "pp": (np.pi / 4, 0, 0),
    "pm": (np.pi / 4, 1, 0),
}


@dataclass(frozen=True, slots=True, kw_only=True)
class CircleTrack:
    """Sensor track of a circular scan.

    Attributes
    ----------
    centre : tuple of float
        Circle centre, world x, y, m.
    radius : float
        m.
    start : float
        Angle of the first position from world x, rad (counter-clockwise).
    span : float
        Angle covered, rad (2 pi: full circle, positions do not repeat the start).
    step : float
        Angle between positions, rad.
    baseline : float
        Distance between the transmitter and the receiver, m (along the track).
    height : float
        Antenna height, m.
    """

    centre: tuple[float, float] = (0.0, 0.0)
    radius: float = 1.0
    start: float = 0.0
    span: float = 2 * np.pi
    step: float = np.pi / 180
    baseline: float = 0.1
    height: float = 1.0

    @property
    def closed(self) -> bool:
        """Whether the track is a full circle."""
        return bool(self.span >= 2 * np.pi - 0.5 * self.step)

    @property
    def angles(self) -> npt.NDArray[np.float64]:
        """Angle of each position, rad, shape (P,)."""
        n = round(self.span / self.step) + (0 if self.closed else 1)
        return self.start + self.step * np.arange(n)

    def positions(self) -> npt.NDArray[np.float64]:
        """Sensor positions (midpoint of the antennas), world x, y, m, shape (P, 2)."""
        a = self.angles
        return np.asarray(self.centre) + self.radius * np.column_stack([np.cos(a), np.sin(a)])

    def poses(self) -> npt.NDArray[np.float64]:
        """Sensor poses ``[x, y, z, yaw]`` (yaw toward the centre), shape (P, 4)."""
        p = self.positions()
        yaw = np.mod(self.angles + np.pi + np.pi, 2 * np.pi) - np.pi
        return np.column_stack([p, np.full(len(p), self.height), yaw])

    def antennas(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """World x, y of transmitter and receiver and the boresight, each (P, 2)."""
        a = self.angles
        p = self.positions()
        tangent = np.column_stack([-np.sin(a), np.cos(a)])
        half = 0.5 * self.baseline * tangent
        return p + half, p - half, -np.column_stack([np.cos(a), np.sin(a)])


def scan_echoes(target: PrismTarget, track: CircleTrack, beamwidth: float) -> PrismEchoes:
    """Echoes of ``target`` at every position of ``track``."""
    tx, rx, bs = track.antennas()
    return prism_echoes(target, tx, rx, bs, beamwidth=beamwidth)


def channel_matrix(echoes: PrismEchoes, channel: str) -> npt.NDArray[np.float64]:
    """Amplitude of every echo in one polarization channel, shape (P, E)."""
    angle, i, j = CHANNELS[channel]
    s = rotate_basis(echoes.scattering, angle) if angle else echoes.scattering
    return s[..., i, j]


def scan_impulse_responses(
    echoes: PrismEchoes,
    radar: MSequenceRadar,
    channels: tuple[str, ...],
    rng: np.random.Generator | None,
) -> npt.NDArray[np.float32]:
    """Impulse responses of every position and channel, shape (P, len(channels), n).

    Sample k at ``t0 + k / fs`` after emission; thermal noise from ``rng`` (None: none).
    """
    delays = np.nan_to_num(echoes.length / C, nan=0.0)
    amps = np.stack([channel_matrix(echoes, ch) for ch in channels], axis=1)  # (P, K, E)
    spec = radar.path_spectrum(np.broadcast_to(delays[:, None, :], amps.shape), amps)
    p, k = amps.shape[:2]
    h = radar.impulse_response(spec.reshape(p * k, -1), rng)
    return h.reshape(p, k, -1)


def geometric_wavefronts(
    echoes: PrismEchoes,
    rng: np.random.Generator,
    *,
    range_noise: float = 0.002,
    resolution: float = 0.02,
    dynamic_range_db: float = 30.0,
    max_fronts: int = 6,
) -> npt.NDArray[np.float64]:
    """Wavefronts of each position from the echo geometry (the benchmark's fast path).

    Keeps echoes within ``dynamic_range_db`` of the strongest of the scan (co-polar power
    ``|S_VV|^2 + |S_HH|^2``), merges echoes closer than ``resolution`` (bistatic, m; what a
    super-resolution pulse separation still resolves) into their power-weighted mean, and adds
    Gaussian range noise ``range_noise`` (m).

    Returns
    -------
    ndarray, float64, shape (P, max_fronts)
        Bistatic ranges, ascending per row, NaN-padded.
    """
    power = echoes.scattering[..., 0, 0] ** 2 + echoes.scattering[..., 1, 1] ** 2
    keep = np.isfinite(echoes.length) & (power > power.max() * 10 ** (-dynamic_range_db / 10))
    r = np.where(keep, echoes.length, np.inf)
    order = np.argsort(r, axis=1)
    r = np.take_along_axis(r, order, axis=1)
    w = np.take_along_axis(np.where(keep, power, 0.0), order, axis=1)
    # Merge runs of echoes closer than the resolution (cumulative group labels per row).
    with np.errstate(invalid="ignore"):  # inf - inf in the padding
        gaps = np.diff(r, axis=1) > resolution
    new = np.concatenate([np.ones((len(r), 1), bool), gaps], axis=1)
    new &= np.isfinite(r)
    group = np.cumsum(new, axis=1) - 1
    n_groups = group.max() + 1 if group.size else 0
    rows = np.repeat(np.arange(len(r)), r.shape[1])
    flat = group.ravel()
    fin = np.isfinite(r).ravel() & (flat < max_fronts)
    num = np.zeros((len(r), max(n_groups, max_fronts)))
    den = np.zeros_like(num)
    np.add.at(num, (rows[fin], flat[fin]), (np.where(np.isfinite(r), r, 0.0) * w).ravel()[fin])
    np.add.at(den, (rows[fin], flat[fin]), w.ravel()[fin])
    out = np.where(den > 0, num / np.where(den > 0, den, 1.0), np.nan)[:, :max_fronts]
    return out + rng.normal(0.0, range_noise, out.shape)
