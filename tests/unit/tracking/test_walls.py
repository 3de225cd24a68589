"""Wall-aware detection probability of the GM-PHD (fusion_center.tracking.walls)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fusion_center.tracking.base import SensorScan
from fusion_center.tracking.gmphd import GmPhdTracker
from fusion_center.tracking.walls import WallSightModel

#: One partition at x = 10 m from y = 0 to 8 m, and the outer wall x = 0.
WALLS = WallSightModel([[10.0, 0.0], [0.0, 0.0]], [[10.0, 8.0], [0.0, 8.0]], factor=0.1)


def test_crossings_count_walls_between_sensor_and_position() -> None:
    n = WALLS.crossings([6.0, 4.0], [[8.0, 4.0], [12.0, 4.0], [12.0, 12.0], [-1.0, 4.0]])
    # Same room; through the partition; past its end (y = 9.3 > 8 at x = 10); through the
    # outer wall.
    assert n.tolist() == [0, 1, 0, 1]
    # A sensor mounted on the outer wall does not look through it.
    assert WALLS.crossings([0.0, 4.0], [[5.0, 4.0]]).tolist() == [0]


def test_factor_is_the_per_wall_factor_to_the_number_of_walls() -> None:
    scan = SensorScan(
        sensor="a",
        t=0.0,
        positions=np.zeros((0, 2)),
        cov=np.zeros((0, 2, 2)),
        origin=np.array([-5.0, 4.0]),
    )
    f = WALLS(scan, np.array([[-2.0, 4.0], [5.0, 4.0], [15.0, 4.0]]))
    np.testing.assert_allclose(f, [1.0, 0.1, 0.01])


def test_bad_walls_are_rejected() -> None:
    with pytest.raises(ValueError, match="factor"):
        WallSightModel([[0, 0]], [[1, 0]], factor=1.5)
    with pytest.raises(ValueError, match="end points"):
        WallSightModel([[0, 0], [1, 1]], [[1, 0]])


def _run(sight: WallSightModel | None) -> GmPhdTracker:
    """A person at (8, 4) seen by sensor a (same room) every frame; sensor b, looking at the
    spot from behind the partition at x = 10, never reports it."""
    tracker = GmPhdTracker()
    tracker.sight = sight
    rng = np.random.default_rng(0)
    for k in range(60):
        t = 0.02 * k
        z = np.array([[8.0, 4.0]]) + rng.normal(0.0, 0.05, (1, 2))
        a = SensorScan(
            sensor="a",
            t=t,
            positions=z,
            cov=np.eye(2)[None] * 0.01,
            origin=np.array([6.0, 4.0]),
            boresight=0.0,
            beamwidth=2.0,
            max_range=15.0,
        )
        b = SensorScan(
            sensor="b",
            t=t + 0.01,
            positions=np.zeros((0, 2)),
            cov=np.zeros((0, 2, 2)),
            origin=np.array([13.0, 4.0]),
            boresight=math.pi,
            beamwidth=2.0,
            max_range=15.0,
        )
        out = tracker.step(t + 0.01, [a, b])
    assert len(out.tracks) == 1  # the person is tracked either way
    return tracker


def test_a_sensor_behind_a_wall_does_not_learn_that_it_misses_people() -> None:
    blind = _run(None).detection_profiles["b"]
    walled = _run(WALLS).detection_profiles["b"]
    # Without the walls, b's silence about the person behind the partition lowers its
    # learned detection probability; with them it is not evidence, and b keeps its prior.
    assert walled.min() > blind.min() + 0.1
    assert np.allclose(walled, walled.max())


def test_compiled_pairs_count_the_walls_of_the_numpy_reference() -> None:
    # a generated building's walls, and sight lines from random points, from points on the
    # walls (sensors mounted there), along walls (parallel lines) and through wall ends
    from uwbnet.scale_roles import building, wall_sight

    model = wall_sight(building({"nodes": 24, "people": 2, "seed": 1}))
    rng = np.random.default_rng(4)
    k = 3000
    o = np.column_stack([rng.uniform(-2.0, 62.0, k), rng.uniform(-1.0, 9.0, k)])
    p = o + rng.normal(0.0, 8.0, (k, 2))
    w = rng.integers(0, model.start.shape[0], k)
    a = rng.uniform(0.0, 1.0, k)[:, None]
    on_wall = model.start[w] + a * (model.end[w] - model.start[w])
    o[: k // 4] = on_wall[: k // 4]  # mounted on a wall
    along = model.start[w] + 2.0 * a * (model.end[w] - model.start[w])
    p[k // 4 : k // 2] = along[k // 4 : k // 2]  # in line with a wall
    p[k // 2 : 3 * k // 4] = model.end[w][k // 2 : 3 * k // 4]  # exactly at a wall's end
    fast = model.pairs(o, p)
    model.compiled = False
    want = model.pairs(o, p)
    np.testing.assert_array_equal(fast, want)
    assert (want < 1.0).sum() > k // 10 and (want == 1.0).sum() > k // 10
    # one origin for every sight line broadcasts in both (the compiled loop read past it)
    want_one = model.pairs(o[:1], p[:50])
    model.compiled = True
    np.testing.assert_array_equal(model.pairs(o[:1], p[:50]), want_one)
    np.testing.assert_array_equal(want_one, model.pairs(np.repeat(o[:1], 50, 0), p[:50]))
