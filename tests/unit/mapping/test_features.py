"""features.merge_walls: walls on one line merge only across gaps up to max_gap."""

from __future__ import annotations

import numpy as np

from fusion_center.mapping.features import merge_walls


def _collinear():
    # three walls on the line y = 1 (alpha = pi / 2, d = 1), extents along its tangent;
    # gaps 0.5 m (first to second) and 2 m (second to third)
    walls = np.array([[np.pi / 2, 1.0], [np.pi / 2, 1.01], [np.pi / 2, 0.99]])
    extent = np.array([[0.0, 2.0], [2.5, 4.0], [6.0, 8.0]])
    hits = np.array([10.0, 5.0, 3.0])
    return walls, extent, hits


def test_collinear_walls_merge_only_across_small_gaps() -> None:
    w, e, h = merge_walls(*_collinear(), dist=0.05, angle=np.radians(5.0), max_gap=1.0)
    assert len(w) == 2
    order = np.argsort(e[:, 0])
    np.testing.assert_allclose(e[order], [[0.0, 4.0], [6.0, 8.0]], atol=1e-9)
    np.testing.assert_allclose(h[order], [15.0, 3.0])
    # the merged line is the hit-weighted mean of its walls
    np.testing.assert_allclose(w[order][0], [np.pi / 2, (10 * 1.0 + 5 * 1.01) / 15], atol=1e-12)
    np.testing.assert_allclose(w[order][1], [np.pi / 2, 0.99], atol=1e-12)


def test_without_max_gap_collinear_walls_make_one() -> None:
    w, e, h = merge_walls(*_collinear(), dist=0.05, angle=np.radians(5.0))
    assert len(w) == 1
    np.testing.assert_allclose(e[0], [0.0, 8.0], atol=1e-9)
    assert h[0] == 18.0


# close_outline: walls of an L-shaped room seen only near their specular points


def _closed(walls, path, corners=()):
    from fusion_center.mapping.features import SlamMap, close_outline

    m = SlamMap(
        walls=np.array(walls, float),
        corners=np.array(corners, float).reshape(-1, 2),
        points=np.zeros((0, 2)),
    )
    return m, close_outline(m, np.array(path, float))


def test_concave_corner_closes_both_walls_and_is_added() -> None:
    # y = 0 from x 1..4 seen from above, x = 5 from y 1..3 seen from the left: corner (5, 0)
    _, c = _closed([[1, 0, 4, 0], [5, 1, 5, 3]], [[2, 1], [4, 1], [4, 2]])
    np.testing.assert_allclose(c.walls, [[1, 0, 5, 0], [5, 0, 5, 3]], atol=1e-12)
    np.testing.assert_allclose(c.corners, [[5, 0]], atol=1e-12)


def test_a_mapped_corner_near_the_intersection_is_not_duplicated() -> None:
    _, c = _closed([[1, 0, 4, 0], [5, 1, 5, 3]], [[2, 1], [4, 1], [4, 2]], [[5.1, 0.05]])
    np.testing.assert_allclose(c.walls[0, 2:], [5, 0], atol=1e-12)
    np.testing.assert_allclose(c.corners, [[5.1, 0.05]])


def test_convex_corner_of_an_l_closes_without_a_corner() -> None:
    # y = 2 (x 0..3) seen from below, x = 5 (y 4..6) seen from the right: the inner corner
    # (5, 2) of an L whose corridor turns round it
    _, c = _closed([[0, 2, 3, 2], [5, 4, 5, 6]], [[1.5, 1], [6, 1], [6, 5]])
    np.testing.assert_allclose(c.walls, [[0, 2, 5, 2], [5, 2, 5, 6]], atol=1e-12)
    assert len(c.corners) == 0


def test_parallel_far_or_inconsistent_walls_stay_open() -> None:
    # parallel walls of a corridor
    m, c = _closed([[0, 0, 3, 0], [0, 2, 3, 2]], [[1, 1], [2, 1]])
    np.testing.assert_array_equal(c.walls, m.walls)
    # two faces at 19 degrees (a bend, no corner), their lines meeting 0.4 m beyond one end
    m, c = _closed([[0, 0, 3, 0], [4, 0.2, 6, 0.9]], [[1, 1], [5, 1.5]])
    np.testing.assert_array_equal(c.walls, m.walls)
    # perpendicular, but the intersection 3 m beyond both ends
    m, c = _closed([[1, 0, 2, 0], [5, 3, 5, 4]], [[1.5, 1], [4, 3.5]])
    np.testing.assert_array_equal(c.walls, m.walls)
    assert len(c.corners) == 0
    # x = 5 seen from the right, y = 0 from above: one wall would come from behind the other
    m, c = _closed([[1, 0, 4, 0], [5, 1, 5, 3]], [[2, 1], [6, 2]])
    np.testing.assert_array_equal(c.walls, m.walls)
    # the intersection inside a wall's observed extent (a corridor opening, not a corner)
    m, c = _closed([[1, 0, 4, 0], [6, -2, 6, 3]], [[2, 1], [5, 1.5]])
    np.testing.assert_array_equal(c.walls, m.walls)
    # a face ending 0.5 m short of a wall that goes on 0.6 m past their intersection (a
    # cabinet's side at a room wall): the room wall is not cut back
    m, c = _closed([[-0.6, 0, 4, 0], [0, 3, 0, 0.5]], [[2, 1], [1, 2]])
    np.testing.assert_array_equal(c.walls, m.walls)


def test_no_closure_across_the_robots_path() -> None:
    # the concave case, but the robot drove through the gap between the walls' ends
    m, c = _closed([[1, 0, 4, 0], [5, 1, 5, 3]], [[2, 1], [4, 2], [4.6, 0.8], [4.6, -0.6]])
    np.testing.assert_array_equal(c.walls, m.walls)
    assert len(c.corners) == 0


def test_no_corner_behind_a_mapped_wall() -> None:
    # two ghost faces below the wall y = 0 (multipath images beyond it) meeting at right
    # angles at (3.5, -2): the robot above the wall cannot see that corner
    walls = [[0, 0, 6, 0], [2, -0.5, 2.8, -1.3], [5, -0.5, 4.2, -1.3]]
    m, c = _closed(walls, [[2, 1], [3.5, 1], [5, 1]])
    np.testing.assert_array_equal(c.walls, m.walls)
    assert len(c.corners) == 0


def test_close_outline_rejects_bad_settings() -> None:
    import pytest

    from fusion_center.mapping.features import SlamMap, close_outline

    with pytest.raises(ValueError, match="reach"):
        close_outline(SlamMap(), np.zeros((1, 2)), reach=0.0)
