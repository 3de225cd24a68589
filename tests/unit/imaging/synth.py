"""Synthetic multistatic impulse responses of point targets (free space), for imaging tests."""

from __future__ import annotations

import numpy as np

from fusion_center.imaging import Observations
from protocol.units import C

FS = 20e9
N = 1200
F0, BW = 6.0e9, 4.0e9


def pulse(t: np.ndarray) -> np.ndarray:
    """A Gaussian-modulated cosine (F0, about BW wide), unit peak."""
    sigma = 1.0 / (np.pi * BW / 2.355)
    return np.exp(-0.5 * (t / sigma) ** 2) * np.cos(2 * np.pi * F0 * t)


def responses(
    tx: np.ndarray, rx: np.ndarray, targets: np.ndarray, *, noise: float = 0.0, seed: int = 0
) -> np.ndarray:
    """Real impulse responses (M, N) at FS: one echo per target, 1/(d_t d_r) amplitude."""
    t = np.arange(N) / FS
    h = np.zeros((len(tx), N))
    for p in targets:
        dt = np.linalg.norm(tx - p, axis=1)
        dr = np.linalg.norm(rx - p, axis=1)
        h += pulse(t[None, :] - ((dt + dr) / C)[:, None]) / (dt * dr)[:, None]
    h += np.random.default_rng(seed).normal(0, noise, h.shape)
    return h.astype(np.float32)


def anchor_network(targets: np.ndarray, z: float = 1.0, seed: int = 0) -> Observations:
    """Four static nodes at a 6 m square's corners; each transmits, all four receive."""
    nodes = np.array([[0.0, 0.0, z], [6.0, 0.0, z], [6.0, 5.0, z], [0.0, 5.0, z]])
    ti, ri = np.meshgrid(np.arange(4), np.arange(4), indexing="ij")
    tx, rx = nodes[ti.ravel()], nodes[ri.ravel()]
    return Observations(
        h=responses(tx, rx, targets, seed=seed),
        tx=tx,
        rx=rx,
        fs=FS,
        emission=ti.ravel().astype(np.int64),
    )
