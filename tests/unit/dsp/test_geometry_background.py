import numpy as np
import pytest

from node_agent.dsp import SPEED_OF_LIGHT, ExponentialBackgroundSubtractor, RadarParams

from .synth import bat_geometry


def test_range_axis_uses_t0_and_fs():
    radar = RadarParams(fs=5e9, n=100, t0=20e-9, f_low=3e9, f_high=5e9)
    r = radar.ranges()
    assert r.shape == (100,) and r.dtype == np.float64
    assert r[0] == pytest.approx(SPEED_OF_LIGHT * 20e-9)
    assert r[7] == pytest.approx(SPEED_OF_LIGHT * (20e-9 + 7 / 5e9))
    assert radar.bandwidth == 2e9
    assert radar.index_of_range(r[42]) == pytest.approx(42)


def test_bat_geometry_from_pose_and_field_of_view():
    g = bat_geometry(2.0, -1.0, 2.0)
    # rx1 is 0.5 m to the node's left: yaw 2.0 rotates (0, 0.5) to 0.5 (-sin, cos)
    np.testing.assert_allclose(g.rx[0, :2], [2.0 - 0.5 * np.sin(2.0), -1.0 + 0.5 * np.cos(2.0)])
    np.testing.assert_allclose(g.direct_ranges(), [0.5, 0.5])
    ahead = g.centre + 3.0 * np.array([np.cos(2.0), np.sin(2.0)])
    behind = g.centre - 3.0 * np.array([np.cos(2.0), np.sin(2.0)])
    side = g.centre + 3.0 * np.array([np.cos(2.0 + 1.2), np.sin(2.0 + 1.2)])
    np.testing.assert_array_equal(g.in_field_of_view([ahead, behind, side]), [True, False, False])


def test_background_removes_static_and_keeps_moving(rng):
    n = 500
    static = rng.standard_normal((2, n)).astype(np.float32)
    bg = ExponentialBackgroundSubtractor(alpha=0.1)
    assert not np.any(bg.step(static))  # first call initialises
    for _ in range(5):
        y = bg.step(static)
    assert np.max(np.abs(y)) < 1e-6
    moving = static.copy()
    moving[:, 300] += 1.0
    y = bg.step(moving)
    assert y[0, 300] == pytest.approx(1.0, abs=1e-5)
    # the exponential average absorbs a fraction alpha of the new echo
    y = bg.step(static)
    assert y[0, 300] == pytest.approx(-0.1, abs=1e-5)
