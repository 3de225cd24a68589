"""Channel geometry: spreading loss, wall images, visibility, through-wall loss, shadowing."""

from __future__ import annotations

import numpy as np
import pytest

from sim_nodes.channel import Walls, image_paths, scatter_paths
from sim_nodes.channel.geometry import antenna_gain
from sim_nodes.radar import C, MSequenceRadar

from .conftest import omni, one_wall, peak


def test_scatter_amplitude_scales_as_one_over_d1_d2(radar: MSequenceRadar) -> None:
    tx, rx = omni((0.0, 0.0, 1.0)), omni((0.0, 0.5, 1.0))
    values = []
    for x in (3.0, 6.0):
        point = np.array([[x, 0.25, 1.0]])
        delays, amps = scatter_paths(tx, rx, point, np.array([1.0]), Walls.empty())
        h = radar.impulse_response(radar.path_spectrum(delays, amps))
        _, value = peak(h[0])
        d1 = np.linalg.norm(point[0] - tx.position[0])
        d2 = np.linalg.norm(point[0] - rx.position[0])
        values.append((abs(value), d1 * d2))
    (a_near, p_near), (a_far, p_far) = values
    assert a_near / a_far == pytest.approx(p_far / p_near, rel=0.05)
    assert a_near / a_far > 3.5  # about 4: a test that would catch 1/d or 1/d^4


def test_first_order_wall_image_has_the_mirror_geometry_delay(radar: MSequenceRadar) -> None:
    tx, rx = omni((1.0, 2.0, 1.2)), omni((1.0, 1.0, 1.2))
    wall = one_wall((5.0, -10.0), (5.0, 10.0), reflection=-0.6)
    delays, amps = image_paths(tx, rx, wall, max_order=1)
    image = np.array([9.0, 2.0, 1.2])  # tx mirrored in x = 5
    expected = np.linalg.norm(image - rx.position[0]) / C
    first = delays[0, 1:][amps[0, 1:] != 0]
    assert first.shape == (1,)
    assert first[0] == pytest.approx(expected, rel=1e-12)
    assert amps[0, 1] == pytest.approx(-0.6 / (C * expected), rel=1e-9)
    # The IR shows the echo at the mirror range.
    h = radar.impulse_response(radar.path_spectrum(delays, amps))
    k = np.argmax(np.abs(h[0, 100:])) + 100  # skip the direct coupling at 1 m
    assert abs(C * k / 7e9 - C * expected) <= C / 7e9 / 2


def test_reflection_point_off_the_wall_segment_gives_no_path() -> None:
    tx, rx = omni((1.0, 2.0, 1.2)), omni((1.0, 1.0, 1.2))
    short = one_wall((5.0, 5.0), (5.0, 8.0))  # specular point would be at y = 1.5
    _, amps = image_paths(tx, rx, short, max_order=2)
    assert np.count_nonzero(amps[0]) == 1  # the direct path only


def test_second_order_corner_path_has_double_mirror_length() -> None:
    tx, rx = omni((2.0, 2.0, 1.0)), omni((3.0, 1.0, 1.0))
    walls = Walls(
        start=np.array([[0.0, 0.0], [0.0, 0.0]]),
        end=np.array([[10.0, 0.0], [0.0, 10.0]]),
        height=np.array([3.0, 3.0]),
        reflection=np.array([-0.5, -0.5]),
        transmission=np.array([0.1, 0.1]),
    )
    delays, amps = image_paths(tx, rx, walls, max_order=2)
    valid = delays[0][amps[0] != 0] * C
    corner_image = np.array([-2.0, -2.0, 1.0])
    expected = np.linalg.norm(corner_image - rx.position[0])
    # Both sequences share the image (-2, -2), but only one has both reflection points
    # on the walls (the last bounce at y = 0, x = 4/3): a corner gives one double bounce.
    assert np.sum(np.isclose(valid, expected, rtol=1e-12)) == 1
    assert valid.size == 4  # direct + 2 first order + 1 second order


def test_path_through_a_wall_is_attenuated_by_its_loss() -> None:
    tx, rx = omni((0.0, 0.0, 1.0)), omni((0.0, 0.5, 1.0))
    point = np.array([[6.0, 0.0, 1.0]])
    _, free = scatter_paths(tx, rx, point, np.array([1.0]), Walls.empty())
    wall = one_wall((3.0, -5.0), (3.0, 5.0), loss_db=8.0)
    _, through = scatter_paths(tx, rx, point, np.array([1.0]), wall)
    assert through[0, 0] / free[0, 0] == pytest.approx(10 ** (-16 / 20), rel=1e-9)  # both legs


def test_crossing_a_slow_wall_adds_its_excess_delay_on_both_legs() -> None:
    tx, rx = omni((0.0, 0.0, 1.0)), omni((0.0, 0.5, 1.0))
    point = np.array([[6.0, 0.0, 1.0]])
    free, _ = scatter_paths(tx, rx, point, np.array([1.0]), Walls.empty())
    plain = one_wall((3.0, -5.0), (3.0, 5.0))
    brick = Walls(
        start=plain.start,
        end=plain.end,
        height=plain.height,
        reflection=plain.reflection,
        transmission=plain.transmission,
        excess=np.array([0.24 * (np.sqrt(4.0) - 1)]),  # 24 cm of eps_r = 4
    )
    same, _ = scatter_paths(tx, rx, point, np.array([1.0]), plain)
    slow, _ = scatter_paths(tx, rx, point, np.array([1.0]), brick)
    assert same[0, 0] == free[0, 0]
    assert C * (slow[0, 0] - free[0, 0]) == pytest.approx(0.48, rel=1e-9)


def test_a_person_behind_another_is_shadowed() -> None:
    tx, rx = omni((0.0, 0.0, 1.2)), omni((0.0, 0.5, 1.2))
    points = np.array([[3.0, 0.2, 1.2], [6.0, 0.4, 1.2]])  # person 0 in front of person 1
    centres = points[:, :2]
    kwargs = {"owner": np.array([0, 1]), "blocker_radius": np.array([0.25, 0.25])}
    _, alone = scatter_paths(
        tx,
        rx,
        points[1:],
        np.ones(1),
        Walls.empty(),
        blockers=centres[1:],
        **{"owner": np.array([0]), "blocker_radius": np.array([0.25])},
    )
    _, both = scatter_paths(
        tx, rx, points, np.ones(2), Walls.empty(), blockers=centres, shadow_db=18.0, **kwargs
    )
    assert both[0, 1] / alone[0, 0] == pytest.approx(10 ** (-36 / 20), rel=1e-6)
    # The person in front is not shadowed by the one behind.
    _, front = scatter_paths(tx, rx, points[:1], np.ones(1), Walls.empty())
    assert both[0, 0] == pytest.approx(front[0, 0], rel=1e-12)


def test_antenna_pattern_is_3db_at_half_beamwidth_and_omni_is_flat() -> None:
    bw = np.deg2rad(100)
    dirs = np.array([[1.0, 0.0], [np.cos(bw / 2), np.sin(bw / 2)], [-1.0, 0.0]])
    g = antenna_gain(dirs, 0.0, bw)
    assert g[0] == pytest.approx(1.0)
    assert 20 * np.log10(g[1]) == pytest.approx(-3.0, abs=1e-9)
    assert 20 * np.log10(g[2]) == pytest.approx(-25.0)
    np.testing.assert_allclose(antenna_gain(dirs, 0.0, 2 * np.pi), 1.0)
