"""Fixtures for the simulated-node tests: golden data, a free-space radar, test geometry."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from sim_nodes.channel import Antennas, Walls
from sim_nodes.radar import MSequenceRadar, RadarConfig

DATA = Path(__file__).resolve().parents[2] / "data"


@pytest.fixture(scope="session")
def golden_mlbs() -> np.ndarray:
    return np.load(DATA / "mlbs12_ilmsens.npy")


@pytest.fixture(scope="session")
def golden_reference() -> dict[str, np.ndarray]:
    with np.load(DATA / "m12_ov1_reference.npz") as z:
        return {k: z[k] for k in z.files}


@pytest.fixture(scope="session")
def radar() -> MSequenceRadar:
    return MSequenceRadar(RadarConfig())


def omni(*positions: tuple[float, float, float]) -> Antennas:
    """Omnidirectional antennas at the given world positions."""
    n = len(positions)
    return Antennas(
        position=np.array(positions, float),
        boresight=np.zeros(n),
        beamwidth=np.full(n, 2 * np.pi),
    )


def one_wall(
    start: tuple[float, float],
    end: tuple[float, float],
    reflection: float = -0.5,
    loss_db: float = 10.0,
) -> Walls:
    return Walls(
        start=np.array([start], float),
        end=np.array([end], float),
        height=np.array([3.0]),
        reflection=np.array([reflection]),
        transmission=np.array([10 ** (-loss_db / 20)]),
    )


def peak(h: np.ndarray, up: int = 16) -> tuple[float, float]:
    """Fractional index and value of the largest |h| by exact band-limited interpolation.

    The impulse response is periodic and band-limited below fs/2, so zero-padding its
    spectrum interpolates it exactly.
    """
    n = h.shape[-1]
    spec = np.fft.rfft(h.astype(float))
    fine = np.fft.irfft(spec, n=n * up) * up
    k = int(np.argmax(np.abs(fine)))
    return k / up, float(fine[k])
