"""The network ambiguity function, its factorization and its resolution/ghost measures."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import brentq

from fusion_center.topology import (
    SPEED_OF_LIGHT,
    Area,
    Band,
    NetworkGeometry,
    ambiguity,
    assess_point,
    factor_maps,
    ghost_level,
    mainlobe_widths,
    principal_axes,
)

BAND = Band(f_low=3.5e9, f_high=10.5e9)


def _linear(offset: float = 0.0, n: int = 21) -> NetworkGeometry:
    tx = np.column_stack([np.linspace(1.0, 9.0, n), np.full(n, 5.0)])
    rx = np.array([[0.5, 5.0 - offset], [3.0, 5.0 - offset], [9.5, 5.0 - offset]])
    return NetworkGeometry(transmitters=tx, receivers=rx)


def _brute_force(net: NetworkGeometry, p0, pts, freqs) -> np.ndarray:
    """Per-frequency AF by the definition: sum over every link, (F, P)."""
    ti, ri = net.link_indices()

    def d(p):
        return np.linalg.norm(p - net.transmitters[ti], axis=-1) + np.linalg.norm(
            p - net.receivers[ri], axis=-1
        )

    dd = np.array([d(p) for p in pts]) - d(np.asarray(p0))  # (P, L)
    k = 2 * np.pi * np.asarray(freqs) / SPEED_OF_LIGHT
    return np.exp(1j * k[:, None, None] * dd[None]).mean(axis=2)


def test_af_is_one_at_the_reference_and_at_most_one_elsewhere():
    net = _linear(0.3)
    rng = np.random.default_rng(1)
    pts = np.vstack([[5.0, 7.0], rng.uniform(0, 10, (500, 2))])
    chi = ambiguity(net, BAND, (5.0, 7.0), pts)
    assert abs(chi[0] - 1.0) < 1e-6
    assert np.all(np.abs(chi) <= 1.0 + 1e-6)
    assert np.abs(chi[1:]).max() < 0.9


def test_fast_kernel_matches_the_closed_form_band_kernel():
    net = NetworkGeometry(transmitters=[[0.0, 0.0]], receivers=[[1.0, 0.0]])
    rng = np.random.default_rng(2)
    pts = rng.uniform(-3, 3, (300, 2))
    p0 = np.array([0.4, 1.5])
    tau = (
        np.linalg.norm(pts - [0, 0], axis=1)
        + np.linalg.norm(pts - [1, 0], axis=1)
        - (np.linalg.norm(p0) + np.linalg.norm(p0 - [1, 0]))
    ) / SPEED_OF_LIGHT
    np.testing.assert_allclose(ambiguity(net, BAND, p0, pts), BAND.kernel(tau), atol=2e-3)


def test_exact_factors_multiply_to_the_link_sum_per_frequency():
    net = _linear(0.4, n=7)
    rng = np.random.default_rng(3)
    pts = rng.uniform(0, 10, (40, 2))
    freqs = [3.7e9, 6e9, 9.9e9]
    fm = factor_maps(net, (5.0, 7.0), pts, freqs, far_field=False)
    np.testing.assert_allclose(
        fm.per_frequency(), _brute_force(net, (5.0, 7.0), pts, freqs), atol=1e-9
    )


def test_factors_across_a_dense_band_approach_the_continuous_band_af():
    net = _linear(0.4, n=9)
    p0 = np.array([5.0, 7.0])
    pts = p0 + np.random.default_rng(4).uniform(-0.3, 0.3, (200, 2))
    fm = factor_maps(net, p0, pts, BAND.frequencies(400), far_field=False)
    np.testing.assert_allclose(fm.across_band(), ambiguity(net, BAND, p0, pts), atol=5e-3)


def test_far_field_factors_match_the_exact_ones_near_a_far_reference():
    # Antennas 50-100 m away: within 5 cm of p0 the plane-wave phase error is tiny.
    tx = np.array([[-60.0, 0.0], [-50.0, 30.0], [0.0, -80.0]])
    rx = np.array([[70.0, 10.0], [20.0, 90.0]])
    net = NetworkGeometry(transmitters=tx, receivers=rx)
    p0 = np.array([1.0, 2.0])
    pts = p0 + np.random.default_rng(5).uniform(-0.05, 0.05, (100, 2))
    exact = factor_maps(net, p0, pts, [8e9], far_field=False)
    far = factor_maps(net, p0, pts, [8e9], far_field=True)
    np.testing.assert_allclose(far.motion, exact.motion, atol=0.02)
    np.testing.assert_allclose(far.topology, exact.topology, atol=0.02)


def test_factorization_needs_a_fully_linked_network():
    net = NetworkGeometry(transmitters=[[0, 0], [1, 0]], receivers=[[0, 1]], links=[[0, 0]])
    with pytest.raises(ValueError, match="factorises"):
        factor_maps(net, (0.0, 3.0), [[0.0, 3.1]], [5e9])


def test_monostatic_range_width_is_the_band_sinc_width():
    # One co-located Tx/Rx far away: along the line of sight chi = sinc(2 B Delta / c) e^(..),
    # so the 3 dB width is 2 * x / (2 B / c) with sinc(x) = 10^(-3/20).
    net = NetworkGeometry(transmitters=[[-1000.0, 0.0]], receivers=[[-1000.0, 0.0]])
    x = brentq(lambda v: np.sinc(v) - 10 ** (-3 / 20), 0.01, 0.99)
    expected = 2 * x * SPEED_OF_LIGHT / (2 * BAND.bandwidth)
    widths, _ = mainlobe_widths(net, BAND, (0.0, 0.0), np.array([[1.0, 0.0], [0.0, 1.0]]))
    assert widths[0] == pytest.approx(expected, rel=0.01)


def test_resolution_is_finer_along_the_direction_the_look_direction_rotates():
    # A broadside track below p0: the look direction rotates in x; one narrow band.
    narrow = Band(f_low=6.97e9, f_high=7.03e9)
    tx = np.column_stack([np.linspace(2.0, 8.0, 31), np.full(31, 5.0)])
    net = NetworkGeometry(transmitters=tx, receivers=[[5.0, 1.0]])
    w, _ = mainlobe_widths(net, narrow, (5.0, 8.0), np.eye(2))
    assert w[0] < 0.5 * w[1]
    axes, _ = principal_axes(net, narrow, (5.0, 8.0))
    assert abs(axes[0] @ [0.0, 1.0]) > 0.99  # the wide axis is y


def test_linear_track_ghost_at_the_mirror_and_its_suppression():
    p0, mirror = np.array([5.0, 7.0]), np.array([[5.0, 3.0]])
    on_line = abs(ambiguity(_linear(0.0), BAND, p0, mirror)[0])
    off_line = abs(ambiguity(_linear(1.0), BAND, p0, mirror)[0])
    rng = np.random.default_rng(0)
    irregular = _linear(0.0)
    tx = irregular.transmitters.copy()
    tx[:, 1] += rng.uniform(-0.6, 0.6, len(tx))
    irr = abs(
        ambiguity(
            NetworkGeometry(transmitters=tx, receivers=irregular.receivers), BAND, p0, mirror
        )[0]
    )
    assert on_line == pytest.approx(1.0, abs=1e-4)
    assert 20 * math.log10(off_line) < -20
    assert 20 * math.log10(irr) < -20


def test_ghost_search_finds_the_mirror_ghost():
    net = _linear(0.0)
    area = Area(x_min=0, y_min=0, x_max=10, y_max=10, nx=80, ny=80)
    q = assess_point(net, BAND, (5.0, 7.0), area)
    assert q.ghost_db > -0.5
    np.testing.assert_allclose(q.ghost_position, [5.0, 3.0], atol=0.03)
    # The same network with receivers off the line: the ghost drops.
    q2 = assess_point(_linear(1.0), BAND, (5.0, 7.0), area)
    assert q2.ghost_db < -6


def test_ghost_level_excludes_the_main_lobe():
    net = _linear(1.0)
    area = Area(x_min=4.9, y_min=6.9, x_max=5.1, y_max=7.1, nx=41, ny=41)
    widths, axes = mainlobe_widths(net, BAND, (5.0, 7.0))
    db, where, image = ghost_level(net, BAND, (5.0, 7.0), area, widths, axes)
    assert image.shape == (41, 41) and image.max() == pytest.approx(1.0, abs=1e-3)
    assert db < -1.0
    local = (where - [5.0, 7.0]) @ axes.T
    assert np.sum((local / (2.0 * widths)) ** 2) > 1.0


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"transmitters": np.zeros((0, 2)), "receivers": [[0, 0]]}, "at least one"),
        ({"transmitters": [[np.nan, 0]], "receivers": [[0, 0]]}, "finite"),
        ({"transmitters": [[0, 0]], "receivers": [[1, 0]], "links": [[0, 1]]}, "out of range"),
    ],
)
def test_bad_geometry_is_rejected(kwargs, message):
    with pytest.raises(ValueError, match=message):
        NetworkGeometry(**kwargs)


def test_bad_band_is_rejected():
    with pytest.raises(ValueError, match="f_low < f_high"):
        Band(f_low=5e9, f_high=4e9)
