"""features.merge_walls: walls on one line merge only across gaps up to max_gap."""

from __future__ import annotations

import numpy as np
import pytest

from fusion_center.mapping.features import (
    SlamMap,
    close_outline,
    corridor_end_walls,
    free_side,
    merge_walls,
)


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


@pytest.mark.parametrize("max_gap", [np.inf, 1.0])
def test_zero_merge_distance_keeps_every_wall_as_it_is(max_gap) -> None:
    # dist = 0 merges nothing (a wall's own ends lie within rounding of its line, not on
    # it): each wall comes back unchanged, never empty or NaN
    walls, extent, hits = _collinear()
    walls = walls + np.array([[0.3, 0.0]])  # off the axes, where rounding shows
    w, e, h = merge_walls(walls, extent, hits, dist=0.0, angle=0.0, max_gap=max_gap)
    order = np.argsort(e[:, 0])
    np.testing.assert_allclose(w[order], walls, atol=1e-12)
    np.testing.assert_allclose(e[order], extent, atol=1e-9)
    np.testing.assert_allclose(h[order], hits)


# close_outline: walls of an L-shaped room seen only near their specular points


def _closed(walls, path, corners=(), **kw):
    m = SlamMap(
        walls=np.array(walls, float),
        corners=np.array(corners, float).reshape(-1, 2),
        points=np.zeros((0, 2)),
    )
    return m, close_outline(m, np.array(path, float), **kw)


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


def test_a_wall_running_past_a_convex_corner_is_trimmed_to_it() -> None:
    # the L of corridor_L_sparse: the first leg's inner wall y = 2 mapped x 0..2.2 (seen from
    # below), the second leg's inner wall x = 5 mapped down to y = 1.2 (seen from the right):
    # 0.8 m past the corner (5, 2) into the first leg, the echo of the corner's edge heard
    # from (6, 1); the corner lies 2.8 m beyond the first wall's end
    walls = [[0, 2, 2.2, 2], [5, 6, 5, 1.2]]
    path = [[1.5, 1], [6, 1], [6, 5]]
    _, c = _closed(walls, path)
    np.testing.assert_allclose(c.walls, [[0, 2, 5, 2], [5, 6, 5, 2]], atol=1e-12)
    assert len(c.corners) == 0
    # with the concave corners' reach and trim it stays open
    m, c = _closed(walls, path, convex_reach=2.5, convex_trim=0.3)
    np.testing.assert_array_equal(c.walls, m.walls)
    # a trim leaves at least 2 overshoot (0.6 m) of the wall: x = 5 mapped y 1.55..2.5 runs
    # 0.45 m past the corner, which would leave 0.5 m; mapped to y = 3.2 it leaves 1.2 m
    m, c = _closed([walls[0], [5, 2.5, 5, 1.55]], path)
    np.testing.assert_array_equal(c.walls, m.walls)
    _, c = _closed([walls[0], [5, 3.2, 5, 1.55]], path)
    np.testing.assert_allclose(c.walls, [[0, 2, 5, 2], [5, 3.2, 5, 2]], atol=1e-12)
    # (at overshoot 0.2 the 0.5 m left are enough)
    _, c = _closed([walls[0], [5, 2.5, 5, 1.55]], path, overshoot=0.2)
    np.testing.assert_allclose(c.walls, [[0, 2, 5, 2], [5, 2.5, 5, 2]], atol=1e-12)
    # a concave corner's wall running 0.8 m past it is not cut (a room wall going on past a
    # face; the convex trim does not apply)
    m, c = _closed([[-0.8, 0, 4, 0], [0, 3, 0, 0.5]], [[2, 1], [1, 2]])
    np.testing.assert_array_equal(c.walls, m.walls)


def test_parallel_far_or_inconsistent_walls_stay_open() -> None:
    # parallel walls of a corridor
    m, c = _closed([[0, 0, 3, 0], [0, 2, 3, 2]], [[1, 1], [2, 1]])
    np.testing.assert_array_equal(c.walls, m.walls)
    # two faces at 19 degrees (a bend, no corner), their lines meeting 0.4 m beyond one end
    m, c = _closed([[0, 0, 3, 0], [4, 0.2, 6, 0.9]], [[1, 1], [5, 1.5]])
    np.testing.assert_array_equal(c.walls, m.walls)
    # perpendicular, but the intersection 3 m beyond both ends
    # (no position test: the observers face both extensions)
    m, c = _closed([[1, 0, 2, 0], [5, 3, 5, 4]], [[1.5, 1], [4, 3.5]], witness_range=0.0)
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
    # the concave case, but the robot drove through the gap between the walls' ends (from
    # positions that face neither extension, more than clearance from both)
    path = [[2, 1], [4, 2], [4.2, 1.5], [4.9, -1.5]]
    m, c = _closed([[1, 0, 4, 0], [5, 1, 5, 3]], path)
    np.testing.assert_array_equal(c.walls, m.walls)
    assert len(c.corners) == 0


def test_no_corner_behind_a_mapped_wall() -> None:
    # two ghost faces below the wall y = 0 (multipath images beyond it) meeting at right
    # angles at (3.5, -2): the robot above the wall cannot see that corner
    walls = [[0, 0, 6, 0], [2, -0.5, 2.8, -1.3], [5, -0.5, 4.2, -1.3]]
    m, c = _closed(walls, [[2, 1], [3.5, 1], [5, 1]])
    np.testing.assert_array_equal(c.walls, m.walls)
    assert len(c.corners) == 0


def test_close_outline_rejects_bad_settings_and_shapes() -> None:
    with pytest.raises(ValueError, match=r"reach .*got 0\.0"):
        close_outline(SlamMap(), np.zeros((1, 2)), reach=0.0)
    # a NaN clearance would turn the clearance test off
    with pytest.raises(ValueError, match=r"clearance .*got nan"):
        close_outline(SlamMap(), np.zeros((1, 2)), clearance=float("nan"))
    with pytest.raises(ValueError, match=r"confirm .*got -1"):
        close_outline(SlamMap(), np.zeros((1, 2)), confirm=-1.0)
    with pytest.raises(ValueError, match=r"convex_reach .*got 0\.0"):
        close_outline(SlamMap(), np.zeros((1, 2)), convex_reach=0.0)
    with pytest.raises(ValueError, match=r"convex_trim .*got nan"):
        close_outline(SlamMap(), np.zeros((1, 2)), convex_trim=float("nan"))
    # map.json's trajectory rows are [t, x, y, yaw]: not positions
    walls = SlamMap(walls=np.array([[1.0, 0, 4, 0], [5, 1, 5, 3]]))
    with pytest.raises(ValueError, match=r"path must be \(k, 2\).*\(3, 4\)"):
        close_outline(walls, np.array([[0.0, 2, 1, 0], [1, 4, 1, 0], [2, 4, 2, 0]]))
    with pytest.raises(ValueError, match=r"walls must be \(w, 4\)"):
        close_outline(SlamMap(walls=np.zeros((2, 3))), np.zeros((1, 2)))


# review_8s H1: no wall where a robot position faced the gap and heard nothing


def test_no_wall_through_a_doorway_the_robot_faced() -> None:
    # y = 0 mapped x 0.5..4.5, a doorway 4.5..6, the right wall x = 6: the robot stood at
    # (5, 2), 2 m in front of the doorway, and had no echo from (5, 0)
    m, c = _closed([[0.5, 0, 4.5, 0], [6, 1, 6, 3]], [[3, 2], [5, 2]])
    np.testing.assert_array_equal(c.walls, m.walls)
    assert len(c.corners) == 0
    # the same walls seen from positions whose specular points miss the gap: closed
    _, c = _closed([[0.5, 0, 4.5, 0], [6, 1, 6, 3]], [[3, 2], [4.4, 2.5]])
    np.testing.assert_allclose(c.walls, [[0.5, 0, 6, 0], [6, 0, 6, 3]], atol=1e-12)
    # a wall mapped between that position and the gap (at 45 degrees: no corner with
    # either) hides the gap from it: no evidence, closed
    walls = [[0.5, 0, 4.5, 0], [6, 1, 6, 3], [4.8, 1.0, 5.2, 1.4]]
    _, c = _closed(walls, [[3, 2], [5, 2]])
    np.testing.assert_allclose(c.walls[:2], [[0.5, 0, 6, 0], [6, 0, 6, 3]], atol=1e-12)
    # so does a mapped point (an object's edge: a cabinet in front of the wall, its face not
    # mapped) within 0.3 m of the line of sight
    m = SlamMap(
        walls=np.array([[0.5, 0, 4.5, 0], [6, 1, 6, 3]], float), points=np.array([[5.2, 0.8]])
    )
    c = close_outline(m, np.array([[3.0, 2], [5, 2]]))
    np.testing.assert_allclose(c.walls, [[0.5, 0, 6, 0], [6, 0, 6, 3]], atol=1e-12)


def test_no_wall_between_an_object_and_the_room_wall() -> None:
    # a box face x = 2 (y 1..2) 1 m off the room wall y = 0 (mapped to x 1.5); the robot at
    # (1, 0.5) faced the free gap under the box at normal incidence
    walls = [[0, 0, 1.5, 0], [2, 2, 2, 1]]
    m, c = _closed(walls, [[1, 2.5], [0.5, 1.5], [1, 0.5]])
    np.testing.assert_array_equal(c.walls, m.walls)
    assert len(c.corners) == 0
    # without that position nothing says the gap is open (the closure is a guess)
    _, c = _closed(walls, [[1, 2.5], [0.5, 1.5]])
    assert len(c.corners) == 1


# review_8s M2, M3: the side, and one case per gate


def test_free_side_ignores_poses_beyond_the_end_or_on_the_line() -> None:
    # y = 0 (x 0..3) seen from above; later the robot passes its end 5 cm below its line
    # (through a doorway), or crosses its line within its extent
    walls = np.array([[0.0, 0, 3, 0]])
    for passing in ([3.3, -0.05], [2.9, -0.05]):
        normals, seen = free_side(walls, np.array([[1.5, 1.5], [2.5, 1.0], passing]))
        np.testing.assert_allclose(normals, [[0, 1]], atol=1e-12)
        assert seen[0] == 1
    # only poses on the line: side undecided
    normals, _ = free_side(walls, np.array([[1.0, 0.05], [4.0, 0.0]]))
    np.testing.assert_array_equal(normals, [[0, 0]])


def test_no_closure_within_clearance_of_a_robot_position() -> None:
    # the concave case; the robot was at (4.3, -0.2), 0.2 m from the bottom wall's extension
    # (not in front of it: behind its line), and drove off inside the wall's extent
    walls, path = [[1, 0, 4, 0], [5, 1, 5, 3]], [[4.3, -0.2], [2, 1], [4, 1], [4, 2]]
    m, c = _closed(walls, path)
    np.testing.assert_array_equal(c.walls, m.walls)
    _, c = _closed(walls, path, clearance=0.1)
    np.testing.assert_allclose(c.walls, [[1, 0, 5, 0], [5, 0, 5, 3]], atol=1e-12)


def test_no_closure_across_a_third_wall() -> None:
    # a short wall across the gap at x = 4.5 (out of the observers' lines of sight to X)
    m, c = _closed([[1, 0, 4, 0], [5, 1, 5, 3], [4.5, -0.3, 4.5, 0.1]], [[2, 1], [4, 1], [4, 2]])
    np.testing.assert_array_equal(c.walls, m.walls)
    assert len(c.corners) == 0


def _two_partners():
    # y = 0 (x 1..4) can close with x = 4.6 (y 0.4..1, X at 4.6, 1.0 m of extension) or
    # with x = 5 (y 1..3, X at 5, 2.0 m); no position faces either gap
    walls = [[1, 0, 4, 0], [4.6, 1, 4.6, 0.4], [5, 1, 5, 3]]
    return walls, [[2, 1], [4, 1], [4, 2], [4.2, 2.5]]


def test_a_wall_end_takes_one_closure_the_shortest() -> None:
    walls, path = _two_partners()
    _, c = _closed(walls, path)
    np.testing.assert_allclose(c.walls[:2], [[1, 0, 4.6, 0], [4.6, 1, 4.6, 0]], atol=1e-12)
    np.testing.assert_array_equal(c.walls[2], walls[2])
    np.testing.assert_allclose(c.corners, [[4.6, 0]], atol=1e-12)


def test_a_confirmed_closure_goes_before_a_shorter_one() -> None:
    # a mapped corner (double reflection) near (5, 0) confirms the longer closure
    walls, path = _two_partners()
    _, c = _closed(walls, path, corners=[[5.15, 0.05]])
    np.testing.assert_allclose(c.walls[[0, 2]], [[1, 0, 5, 0], [5, 0, 5, 3]], atol=1e-12)
    np.testing.assert_array_equal(c.walls[1], walls[1])
    np.testing.assert_allclose(c.corners, [[5.15, 0.05]])


def test_a_wall_ending_on_the_extended_end_does_not_block() -> None:
    # build_map extends walls to their junctions: x = 4 (y -2..0) ends on the bottom wall's
    # end, 1e-4 past its line after map.json's rounding; it is not across the extension
    walls = [[1, 0, 4, 0], [5, 1, 5, 3], [4.0001, 0.0001, 4.0001, -2]]
    _, c = _closed(walls, [[2, 1], [4, 1], [4, 2]])
    np.testing.assert_allclose(c.walls[:2], [[1, 0, 5, 0], [5, 0, 5, 3]], atol=1e-12)


def test_a_short_wall_is_not_trimmed() -> None:
    # a face 0.55 m long (shorter than two trims of 0.3 m) whose ends both overshoot the
    # walls x = 0 and x = 0.45 by 0.05 m (review_8s L6: two trims of a short wall leave a few
    # centimetres); its closures with them would trim it, so it stays as mapped
    walls = [[-0.05, 0, 0.5, 0], [0, 1, 0, 3], [0.45, 1, 0.45, 3]]
    m, c = _closed(walls, [[0.225, 2]])
    np.testing.assert_array_equal(c.walls[0], m.walls[0])


# corridor end walls heard from one stop (a wall and a corner echo alike from one position)

_SIDES = [[0, 0, 4, 0], [4, 2.4, 0, 2.4]]  # a corridor along x, 2.4 m wide, mapped x 0..4


def _sorted_ends(seg):
    seg = np.asarray(seg).reshape(-1, 2, 2)
    return np.sort(seg.reshape(-1, 2), axis=0)


def test_a_single_stop_landmark_down_a_corridor_is_its_end_wall() -> None:
    ends = corridor_end_walls(_SIDES, [[8.0, 1.2]], [[3.0, 1.2]])
    assert ends.shape == (1, 4)
    np.testing.assert_allclose(_sorted_ends(ends), [[8, 0], [8, 2.4]], atol=1e-12)
    # a bearing 10 degrees off the corridor: the end line is perpendicular to the corridor,
    # or with across_corridor False to the bearing
    f = np.array([3.0, 1.2]) + 4.0 * np.array([np.cos(0.1745), np.sin(0.1745)])
    ends = corridor_end_walls(_SIDES, [f], [[3.0, 1.2]])
    np.testing.assert_allclose(_sorted_ends(ends), [[f[0], 0], [f[0], 2.4]], atol=1e-9)
    ends = corridor_end_walls(_SIDES, [f], [[3.0, 1.2]], across_corridor=False)
    b = (f - [3.0, 1.2]) / 4.0
    d = ends.reshape(2, 2) - f
    np.testing.assert_allclose(d @ b, 0.0, atol=1e-9)
    np.testing.assert_allclose(np.sort(ends.reshape(2, 2)[:, 1]), [0.0, 2.4], atol=1e-9)


def test_an_end_heard_at_its_corner_lies_across_the_corridor() -> None:
    # the end x = 8 of the corridor 0 < y < 2.4 heard from (3, 1.2) at its corner (8, 0),
    # 13.5 degrees off the axis: the end is x = 8 whichever of its points was heard, not the
    # line perpendicular to the corner's bearing (turned by 13.5 degrees)
    for corner in ([8.0, 0.0], [8.0, 2.4]):
        # the corner itself is on both walls' lines: pull it in a little (the side walls'
        # own echoes place them, not the corner's)
        f = np.add(corner, (0.0, 0.05 if corner[1] == 0.0 else -0.05))
        ends = corridor_end_walls(_SIDES, [f], [[3.0, 1.2]])
        np.testing.assert_allclose(_sorted_ends(ends), [[8, 0], [8, 2.4]], atol=1e-9)
        turned = corridor_end_walls(_SIDES, [f], [[3.0, 1.2]], across_corridor=False)
        assert np.ptp(turned.reshape(2, 2)[:, 0]) > 0.4


def test_of_two_landmarks_down_one_corridor_the_nearest_is_the_end() -> None:
    ends = corridor_end_walls(_SIDES, [[9.0, 1.0], [7.0, 1.3]], [[3.0, 1.2], [3.0, 1.2]])
    np.testing.assert_allclose(_sorted_ends(ends)[:, 0], [7.0, 7.0], atol=0.05)
    # the other way down the corridor is another end
    ends = corridor_end_walls(_SIDES, [[9.0, 1.2], [-1.0, 1.2]], [[3.0, 1.2], [1.0, 1.2]])
    assert len(ends) == 2
    # nearest along the corridor, not to the stop that heard it: the end at x = 8 heard from
    # x = 1 (7 m) stands, the image at x = 12 heard from x = 6 (6 m) does not
    for order in ([0, 1], [1, 0]):
        refl = np.array([[8.0, 1.2], [12.0, 1.2]])[order]
        obs = np.array([[1.0, 1.2], [6.0, 1.2]])[order]
        ends = corridor_end_walls(_SIDES, refl, obs)
        np.testing.assert_allclose(_sorted_ends(ends)[:, 0], [8.0, 8.0], atol=1e-9)
    # and the other way: the end at x = -3 (from x = 3.5) before the image at x = -6 (from -1)
    ends = corridor_end_walls(_SIDES, [[-6.0, 1.2], [-3.0, 1.2]], [[-1.0, 1.2], [3.5, 1.2]])
    np.testing.assert_allclose(_sorted_ends(ends)[:, 0], [-3.0, -3.0], atol=1e-9)


def test_no_end_wall_off_the_corridor_or_where_a_wall_is_seen() -> None:
    obs = [[3.0, 0.4]]
    # 38 degrees off the corridor's direction: a corner or a point, not an end wall
    assert len(corridor_end_walls(_SIDES, [[5.0, 2.0]], obs)) == 0
    # one wall only: no corridor
    assert len(corridor_end_walls(_SIDES[:1], [[8.0, 1.2]], [[3.0, 1.2]])) == 0
    # a side wall mapped past the landmark: an object in the corridor, not its end
    long_sides = [[0, 0, 9, 0], [9, 2.4, 0, 2.4]]
    assert len(corridor_end_walls(long_sides, [[8.0, 1.2]], [[3.0, 1.2]])) == 0
    # a mapped wall across the line of sight, or at the point (the end is mapped already)
    across = [*_SIDES, [6, 0.5, 6, 2.0]]
    assert len(corridor_end_walls(across, [[8.0, 1.2]], [[3.0, 1.2]])) == 0
    at = [*_SIDES, [8.0, 0.8, 8.0, 1.6]]
    assert len(corridor_end_walls(at, [[8.0, 1.2]], [[3.0, 1.2]])) == 0
    # beyond a side wall (the landmark is not between the corridor's walls)
    assert len(corridor_end_walls(_SIDES, [[8.0, 3.0]], [[3.0, 1.2]])) == 0
    with pytest.raises(ValueError, match="one row each"):
        corridor_end_walls(_SIDES, [[8.0, 1.2]], np.zeros((2, 2)))
    with pytest.raises(ValueError, match="out of range"):
        corridor_end_walls(_SIDES, [[8.0, 1.2]], [[3.0, 1.2]], max_angle=0.0)


def test_side_walls_close_with_a_confirmed_end_wall_from_farther() -> None:
    # the end wall x = 8 lies 4 m beyond the side walls' mapped ends (x = 4): beyond reach
    # (2.5 m) for two walls, within end_reach for a confirmed end wall
    walls = [*_SIDES, [8, 0, 8, 2.4]]
    path = [[1.0, 1.2], [3.0, 1.2]]
    m = SlamMap(walls=np.array(walls, float), end_walls=np.array([2]))
    c = close_outline(m, np.array(path))
    np.testing.assert_allclose(c.walls[:2], [[0, 0, 8, 0], [8, 2.4, 0, 2.4]], atol=1e-12)
    np.testing.assert_allclose(_sorted_ends(c.corners), [[8, 0], [8, 2.4]], atol=1e-12)
    np.testing.assert_array_equal(c.end_walls, [2])
    # the same wall not marked as an end wall: the side walls stay where they were heard
    plain = close_outline(SlamMap(walls=np.array(walls, float)), np.array(path))
    np.testing.assert_array_equal(plain.walls[:2], np.array(_SIDES, float))
    # nor with end_reach below the gap
    short = close_outline(m, np.array(path), end_reach=3.0)
    np.testing.assert_array_equal(short.walls[:2], np.array(_SIDES, float))
    with pytest.raises(ValueError, match=r"end_reach .*got 0\.0"):
        close_outline(m, np.array(path), end_reach=0.0)
    # end_walls index the walls: out of range, negative or not integers is an error
    for bad in ([3], [-1], [2.0]):
        with pytest.raises(ValueError, match=r"end_walls must index the 3 walls"):
            close_outline(SlamMap(walls=m.walls, end_walls=np.array(bad)), np.array(path))
