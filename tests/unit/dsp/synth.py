"""Synthetic impulse responses from known geometry, for simulate-then-recover tests."""

from __future__ import annotations

import numpy as np

from node_agent.dsp import SPEED_OF_LIGHT, RadarParams, SensorGeometry

M_SEQUENCE = RadarParams(fs=7e9, n=4095, t0=0.0, f_low=0.0, f_high=3.5e9)


def bat_geometry(x: float = 0.0, y: float = 0.0, yaw: float = 0.0) -> SensorGeometry:
    """A bat-type node: Tx at the origin, Rx at +-0.5 m left, horns of 100 deg."""
    return SensorGeometry.from_pose(
        [x, y, 1.0, yaw],
        tx=[0.0, 0.0, 0.0],
        rx=[[0.0, 0.5, 0.0], [0.0, -0.5, 0.0]],
        rx_names=("rx1", "rx2"),
        boresight=0.0,
        beamwidth=np.deg2rad(100.0),
    )


def pulse(t: np.ndarray, radar: RadarParams) -> np.ndarray:
    """Ricker wavelet whose spectrum fills the radar band (peak at 0.4 * f_high)."""
    a = (np.pi * 0.4 * radar.f_high * t) ** 2
    return (1.0 - 2.0 * a) * np.exp(-a)


def bistatic_ranges(points: np.ndarray, geometry: SensorGeometry) -> np.ndarray:
    """Bistatic range of world x, y points (at antenna height) per receiver, (n_rx, k)."""
    p = np.column_stack((points, np.full(len(points), geometry.tx[2])))
    d_tx = np.linalg.norm(p - geometry.tx, axis=1)
    d_rx = np.linalg.norm(p[None, :, :] - geometry.rx[:, None, :], axis=2)
    return d_tx[None, :] + d_rx


def synth_ir(
    radar: RadarParams,
    ranges: np.ndarray,
    amplitudes: np.ndarray,
    rng: np.random.Generator,
    noise_std: float = 0.01,
) -> np.ndarray:
    """Impulse responses with band-limited pulses at given ranges, plus white noise.

    ranges, amplitudes: (n_rx, k). Returns float32 (n_rx, n).
    """
    ranges = np.atleast_2d(ranges)
    amplitudes = np.broadcast_to(amplitudes, ranges.shape)
    tk = radar.t0 + np.arange(radar.n) / radar.fs
    h = np.zeros((ranges.shape[0], radar.n))
    for i in range(ranges.shape[0]):  # a handful of rows; samples are vectorized
        delay = ranges[i] / SPEED_OF_LIGHT
        h[i] = pulse(tk[:, None] - delay[None, :], radar) @ amplitudes[i]
    h += noise_std * rng.standard_normal(h.shape)
    return h.astype(np.float32)


def static_scene(geometry: SensorGeometry) -> tuple[np.ndarray, np.ndarray]:
    """Direct coupling (strong) plus four wall echoes, (n_rx, 5) ranges and amplitudes."""
    direct = geometry.direct_ranges()[:, None]
    walls = np.array([6.0, 9.5, 14.0, 21.0])
    r = np.hstack((direct, np.broadcast_to(walls, (geometry.n_rx, 4))))
    a = np.broadcast_to(np.array([5.0, 0.8, 0.6, 0.5, 0.4]), r.shape)
    return r, a


def body_offsets(rng: np.random.Generator, k: int = 5) -> np.ndarray:
    """Scattering points of a body of about 0.3 m, relative to its centre, (k, 2).

    The first point is the torso at the centre; the others (limbs) are weaker.
    """
    ang = rng.uniform(0, 2 * np.pi, k)
    rad = 0.15 * np.sqrt(rng.uniform(0, 1, k))
    rad[0] = 0.0
    return np.column_stack((rad * np.cos(ang), rad * np.sin(ang)))


def scene_ir(
    radar: RadarParams,
    geometry: SensorGeometry,
    people: list[tuple[np.ndarray, np.ndarray]],
    rng: np.random.Generator,
    noise_std: float = 0.01,
    person_amp: float = 0.1,
) -> np.ndarray:
    """Coupling + walls + extended people + noise, (n_rx, n) float32.

    people: (centre (2,), body offsets (k, 2)) per person, world m. Each scattering
    point's amplitude fluctuates from frame to frame (a walking body).
    """
    r_static, a_static = static_scene(geometry)
    rs, amps = [r_static], [a_static]
    for centre, offsets in people:
        r = bistatic_ranges(np.asarray(centre, float) + offsets, geometry)
        rs.append(r)
        strength = rng.uniform(0.5, 1.0, r.shape[1])
        strength[1:] *= 0.4  # limbs
        amps.append(person_amp * strength * np.ones_like(r))
    return synth_ir(radar, np.hstack(rs), np.hstack(amps), rng, noise_std)
