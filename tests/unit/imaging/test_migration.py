"""Kirchhoff migration and cross-correlated imaging on point targets (fusion_center.imaging)."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

from fusion_center.imaging import (
    Grid,
    Observations,
    cross_correlated_image,
    default_references,
    kirchhoff_image,
)
from fusion_center.imaging.quality import artefact_ratio, peak_errors, surface_errors
from fusion_center.imaging.reference import straightforward_kirchhoff
from tests.unit.imaging.synth import FS, anchor_network, responses

TARGETS = np.array([[2.0, 3.0, 1.0], [4.3, 1.7, 1.0]])
GRID = Grid.covering(0.0, 6.0, 0.0, 5.0, 121, 101, 1.0)


def test_kirchhoff_agrees_with_the_straightforward_implementation() -> None:
    obs = anchor_network(TARGETS)
    fast = kirchhoff_image(obs, GRID, chunk=5, tile=777)  # ragged chunks and tiles
    slow = straightforward_kirchhoff(obs, GRID)
    assert np.allclose(fast, slow, rtol=2e-3, atol=2e-3 * np.abs(slow).max())
    raw = kirchhoff_image(obs, GRID, envelope=False)
    assert np.allclose(
        raw, straightforward_kirchhoff(obs, GRID, envelope=False), atol=2e-3 * np.abs(raw).max()
    )


@pytest.mark.parametrize("method", [kirchhoff_image, cross_correlated_image])
def test_static_network_locates_point_targets(method) -> None:
    obs = anchor_network(TARGETS)
    with ThreadPoolExecutor(2) as pool:
        img = method(obs, GRID, map_fn=pool.map)
    assert img.shape == (GRID.ny, GRID.nx) and img.dtype == np.float32
    err = peak_errors(img, GRID, TARGETS[:, :2], radius=0.6)
    assert np.all(err < 0.05), err


def test_moving_transceiver_images_a_target_and_xcorr_has_fewer_artefacts() -> None:
    # A bat-type robot (Tx, two Rx 0.4 m apart) driving along y = 0.5, facing +y.
    xs = np.linspace(0.5, 5.5, 41)
    tx = np.stack([xs, np.full_like(xs, 0.5), np.ones_like(xs)], axis=1)
    side = np.array([0.2, 0.0, 0.0])
    rx = np.concatenate([tx + side, tx - side])
    txx = np.concatenate([tx, tx])
    obs = Observations(
        h=responses(txx, rx, TARGETS, noise=2e-4, seed=1),
        tx=txx,
        rx=rx,
        fs=FS,
        emission=np.concatenate([np.arange(41), np.arange(41)]),
    )
    k = kirchhoff_image(obs, GRID)
    x = cross_correlated_image(obs, GRID)
    for img in (k, x):
        assert np.all(peak_errors(img, GRID, TARGETS[:, :2], radius=0.6) < 0.05)
    # Artefacts: energy farther than 0.25 m from the targets (tiny squares around them).
    boxes = [[(p[0] - 0.01, p[1]), (p[0] + 0.01, p[1])] for p in TARGETS]
    assert artefact_ratio(x, GRID, boxes) < artefact_ratio(k, GRID, boxes)


def test_default_references_pair_nearest_receivers_of_one_emission() -> None:
    obs = anchor_network(TARGETS)
    ref = default_references(obs)
    assert np.all(obs.emission[ref] == obs.emission) and np.all(ref != np.arange(len(obs)))
    single = Observations(h=obs.h[:1], tx=obs.tx[:1], rx=obs.rx[:1], fs=FS)
    assert default_references(single)[0] == -1
    with pytest.raises(ValueError, match="no observation has a reference"):
        cross_correlated_image(single, GRID)


def test_antenna_pattern_weighting_suppresses_echoes_behind_the_antennas() -> None:
    # One monostatic-like pair at the centre facing +x; a target in front at (4, 2.5).
    tx = np.array([[3.0, 2.5, 1.0]])
    rx = np.array([[3.0, 2.6, 1.0]])
    tgt = np.array([[4.0, 2.5, 1.0]])
    obs = Observations(
        h=responses(tx, rx, tgt),
        tx=tx,
        rx=rx,
        fs=FS,
        tx_yaw=np.zeros(1),
        rx_yaw=np.zeros(1),
        tx_beamwidth=np.full(1, np.radians(60)),
        rx_beamwidth=np.full(1, np.radians(60)),
    )
    plain = kirchhoff_image(obs, GRID, gate=0.05)
    weighted = kirchhoff_image(obs, GRID, gate=0.05, pattern=True)
    front, back = (GRID.ny // 2, 80), (GRID.ny // 2, 40)  # x = 4.0 and x = 2.0
    assert plain[back] == pytest.approx(plain[front], rel=0.2)  # the ellipse is symmetric
    assert weighted[front] > 0.9 * plain[front] and weighted[back] < 1e-3 * plain[back]


def test_surface_errors_measure_distance_to_outlines() -> None:
    img = np.zeros((GRID.ny, GRID.nx), np.float32)
    img[50, 60] = 1.0  # (3.0, 2.5)
    square = [(3.05, 2.0), (4.0, 2.0), (4.0, 3.0), (3.05, 3.0), (3.05, 2.0)]
    assert surface_errors(img, GRID, [square])[0] == pytest.approx(0.05, abs=1e-9)
