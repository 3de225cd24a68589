"""Joint least-squares smoothing of path and landmarks (graph SLAM) on synthetic echoes."""

from __future__ import annotations

import numpy as np
import pytest

from fusion_center.mapping.models import CORNER, POINT, WALL
from fusion_center.mapping.smoothing import (
    LeastSquaresPathMapSmoother,
    SmootherConfig,
    image_clusters,
    merge_duplicates,
    smoothed_landmark_set,
)
from fusion_center.mapping.synthetic import echo_pairs, rectangle_room, stop_and_turn_poses
from sim_nodes.robot_record import OdometrySlip, odometry_increments

ANTENNAS = np.array([[0.0, 0.0], [0.0, 0.5], [0.0, -0.5]])
STOPS = [[1.5, 1.5], [3.0, 1.2], [4.5, 1.5], [4.5, 3.5], [3.0, 3.8], [1.5, 3.5]]
TURN = 30


def _true_landmarks(room) -> tuple[np.ndarray, np.ndarray]:
    centre = room.corners.mean(0)
    walls = []
    for w in room.walls:
        a, b = w[:2], w[2:]
        e = (b - a) / np.linalg.norm(b - a)
        n = np.array([-e[1], e[0]])
        n = n if n @ (a - centre) > 0 else -n  # normal away from the robot's side
        walls.append([np.arctan2(n[1], n[0]), n @ a])
    kinds = np.r_[[WALL] * 4, [CORNER] * 4, [POINT] * 2]
    return kinds, np.vstack([walls, room.corners, room.points])


def _problem(seed: int = 1):
    room = rectangle_room()
    poses = stop_and_turn_poses(STOPS, TURN, np.radians(12.0))
    rng = np.random.default_rng(seed)
    odo = odometry_increments(poses, rng, OdometrySlip(translation=0.01, rotation=0.01))
    pairs = [echo_pairs(room, p, ANTENNAS, rng) for p in poses]
    # a filter-like initial guess: every stop after the first off by a few cm and degrees
    off = np.repeat(rng.normal(0.0, 1.0, (len(STOPS), 3)) * [0.1, 0.1, 0.03], TURN, 0)
    off[:TURN] = 0.0
    kinds, truth = _true_landmarks(room)
    scale = np.where(kinds[:, None] == WALL, [0.05, 1.0], 1.0)  # walls: rad, m
    init = truth + rng.normal(0.0, 0.1, truth.shape) * scale
    return poses, odo, pairs, kinds, truth, poses + off, init


def _wrapped(d: np.ndarray, kinds: np.ndarray) -> np.ndarray:
    d = d.copy()
    d[kinds == WALL, 0] = (d[kinds == WALL, 0] + np.pi) % (2 * np.pi) - np.pi
    return d


def test_smoothing_pulls_path_and_landmarks_onto_the_truth() -> None:
    poses, odo, pairs, kinds, truth, init_poses, init_lm = _problem()
    cfg = SmootherConfig(range_sigma=0.02, slip_translation=0.01, slip_rotation=0.01, max_nfev=200)
    res = LeastSquaresPathMapSmoother(ANTENNAS, cfg).smooth(
        init_poses, odo, pairs, None, kinds, init_lm
    )
    before = np.sqrt(np.mean(np.sum((init_poses[:, :2] - poses[:, :2]) ** 2, 1)))
    after = np.sqrt(np.mean(np.sum((res.poses[:, :2] - poses[:, :2]) ** 2, 1)))
    assert before > 0.08
    assert after < 0.02
    seen = res.pairs > 0
    assert seen.sum() >= 8  # a corner behind the robot at every stop may get no echo
    err = np.abs(_wrapped(res.states - truth, kinds))[seen]
    assert err.max() < 0.03
    assert np.all(res.stops[seen] >= 2)
    assert res.cost_after < 0.2 * res.cost_before
    # the wall extents come from the specular points: inside the room's 5-6 m faces
    ext = res.wall_extent[kinds == WALL]
    assert np.all(np.isfinite(ext)) and np.all(ext[:, 1] - ext[:, 0] > 1.0)


def test_a_ghost_landmark_gets_no_support_and_leaves_the_map() -> None:
    poses, odo, pairs, kinds, truth, _, _ = _problem(2)
    ghost_kinds = np.r_[kinds, WALL, POINT]
    ghost_states = np.vstack([truth, [np.pi / 4, 9.0], [20.0, 20.0]])
    res = LeastSquaresPathMapSmoother(ANTENNAS, SmootherConfig(range_sigma=0.02)).smooth(
        poses, odo, pairs, None, ghost_kinds, ghost_states
    )
    assert res.pairs[-2:].tolist() == [0, 0]
    ls = smoothed_landmark_set(res, min_pairs=8, min_stops=2)
    assert len(ls.walls) == 4
    assert len(ls.points) == int(np.sum((res.pairs[4:] >= 8) & (res.stops[4:] >= 2)))
    assert len(ls.points) >= 4


def test_bad_shapes_are_refused() -> None:
    s = LeastSquaresPathMapSmoother(ANTENNAS)
    with pytest.raises(ValueError, match="one row per acquisition"):
        s.smooth(np.zeros((3, 3)), np.zeros((2, 3)), [np.zeros((0, 2))] * 3, None, [0], [[0, 1]])
    with pytest.raises(ValueError, match="antennas"):
        LeastSquaresPathMapSmoother(np.zeros((2, 2)))


def test_overlapping_walls_a_little_apart_merge_and_separate_ones_stay() -> None:
    from fusion_center.mapping.features import merge_walls

    # x = 2 seen twice, 0.2 m apart and 8 degrees turned, overlapping along y; a third wall
    # 0.25 m off but 4 m further along (a different face) does not overlap
    walls = np.array([[0.0, 2.0], [np.radians(8.0), 2.2], [0.0, 2.25]])
    extent = np.array([[0.0, 3.0], [1.0, 4.0], [7.0, 9.0]])
    hits = np.array([30.0, 10.0, 12.0])
    w, e, h = merge_walls(walls, extent, hits, dist=0.1, angle=np.radians(6.0))
    assert len(w) == 3  # the plain rule keeps all three
    kw = {"overlap_dist": 0.3, "overlap_angle": np.radians(12.0)}
    w, e, h = merge_walls(walls, extent, hits, dist=0.1, angle=np.radians(6.0), **kw)
    assert len(w) == 2
    assert sorted(h.tolist()) == [12.0, 40.0]
    big = int(np.argmax(h))
    # the best supported wall's line stands: the copy 0.2 m off adds extent, not its line
    assert w[big, 1] == pytest.approx(2.0) and w[big, 0] == pytest.approx(0.0)
    assert e[big, 0] < 0.05 and e[big, 1] > 3.8  # the union of the extents


def test_overlap_merge_measures_the_gap_where_the_walls_overlap_not_at_the_origin() -> None:
    from fusion_center.mapping.features import merge_walls

    # two walls at 11 degrees whose line offsets differ by 0.2 m, but which overlap 5-8 m
    # along the line, where they are 0.8-1.4 m apart: two faces, not one seen twice
    walls = np.array([[0.0, 2.0], [np.radians(11.0), 2.2]])
    extent = np.array([[5.0, 8.0], [5.0, 8.0]])
    hits = np.array([30.0, 10.0])
    kw = {"overlap_dist": 0.3, "overlap_angle": np.radians(12.0)}
    w, _, _ = merge_walls(walls, extent, hits, dist=0.1, angle=np.radians(6.0), **kw)
    assert len(w) == 2
    # the same pair with extents next to the origin, where they are at most 0.26 m apart, merges
    extent = np.array([[-0.5, 1.0], [-0.5, 1.0]])
    w, _, _ = merge_walls(walls, extent, hits, dist=0.1, angle=np.radians(6.0), **kw)
    assert len(w) == 1


@pytest.mark.parametrize("shift", [(-8.0, 0.0), (3.0, -6.0)])
def test_wall_merge_does_not_depend_on_the_map_origin(shift) -> None:
    from fusion_center.mapping.features import merge_walls

    # a face seen twice 4 degrees apart, a separate segment of the same line further on,
    # and a parallel face 1 m away; the same walls in a frame shifted by ``shift`` must give
    # the same merged walls, shifted (the same-line test used the offsets' difference,
    # which at an angle grows with the distance from the origin)
    walls = np.array([[0.0, 1.0], [np.radians(4.0), 1.02], [0.0, 1.03], [0.0, 2.0]])
    extent = np.array([[0.0, 3.0], [0.5, 3.5], [5.0, 6.0], [0.0, 3.0]])
    hits = np.array([30.0, 10.0, 12.0, 20.0])
    kw = {"dist": 0.1, "angle": np.radians(6.0), "overlap_dist": 0.3}
    kw["overlap_angle"] = np.radians(12.0)
    w0, e0, h0 = merge_walls(walls, extent, hits, **kw)
    v = np.array(shift)
    n = np.stack([np.cos(walls[:, 0]), np.sin(walls[:, 0])], -1)
    tang = np.stack([-n[:, 1], n[:, 0]], -1)
    moved = np.column_stack([walls[:, 0], walls[:, 1] + n @ v])
    w1, e1, h1 = merge_walls(moved, extent + (tang @ v)[:, None], hits, **kw)
    np.testing.assert_array_equal(h1, h0)
    n0 = np.stack([np.cos(w0[:, 0]), np.sin(w0[:, 0])], -1)
    np.testing.assert_allclose(w1[:, 0], w0[:, 0], atol=1e-9)
    np.testing.assert_allclose(w1[:, 1], w0[:, 1] + n0 @ v, atol=1e-9)
    t0 = np.stack([-n0[:, 1], n0[:, 0]], -1)
    np.testing.assert_allclose(e1, e0 + (t0 @ v)[:, None], atol=1e-9)
    assert len(w0) == 2  # the three copies of x = 1 are one face; x = 2 stays


def test_duplicate_landmarks_merge_into_one_and_distinct_ones_stay() -> None:
    kinds = np.array([WALL, WALL, WALL, POINT, CORNER, POINT])
    states = np.array(
        [[0.0, 3.0], [np.radians(3.0), 3.06], [0.0, 3.5], [1.0, 1.0], [1.1, 1.0], [2.0, 1.0]]
    )
    support = np.array([30.0, 10.0, 20.0, 5.0, 15.0, 9.0])
    k, s = merge_duplicates(
        kinds, states, support, wall_dist=0.15, wall_angle=np.radians(8.0), point_dist=0.15
    )
    assert k.tolist() == [WALL, WALL, CORNER, POINT]  # the best supported kind of a group
    assert s[0, 1] == pytest.approx(0.75 * 3.0 + 0.25 * 3.06)
    assert s[0, 0] == pytest.approx(np.radians(0.75), abs=1e-3)
    np.testing.assert_allclose(s[1], [0.0, 3.5])
    np.testing.assert_allclose(s[2], [0.25 * 1.0 + 0.75 * 1.1, 1.0])
    np.testing.assert_allclose(s[3], [2.0, 1.0])
    # off: nothing merges
    k0, s0 = merge_duplicates(kinds, states, support, wall_dist=0, wall_angle=0.1, point_dist=0)
    assert k0.tolist() == kinds.tolist() and np.array_equal(s0, states)


def test_refit_gives_a_mislabelled_landmark_its_kind_back() -> None:
    """A wall entered as a point and a corner entered as a wall, each with its own echoes
    from all six stops: the fit alone at the poses gives each its kind back."""
    room = rectangle_room()
    poses = stop_and_turn_poses(STOPS, TURN, np.radians(12.0))
    kinds, truth = _true_landmarks(room)
    sm = LeastSquaresPathMapSmoother(ANTENNAS, SmootherConfig(range_sigma=0.02))
    rng = np.random.default_rng(4)
    tx, rx, yaw = sm._array(poses)
    lm, z, at = [], [], []
    for j, i in enumerate((0, 4)):
        r, ok, d = sm._predict(np.full(len(poses), kinds[i]), truth[i][None, :], tx, rx)
        ok &= np.sum(d * np.stack([np.cos(yaw), np.sin(yaw)], -1), -1) >= np.cos(np.radians(60))
        lm += [j] * int(ok.sum())
        z.append(r[ok] + rng.normal(0.0, 0.01, r[ok].shape))
        at.append(poses[ok])
    lm, z, at = np.array(lm), np.vstack(z), np.vstack(at)
    n0 = np.array([np.cos(truth[0, 0]), np.sin(truth[0, 0])])
    a4 = np.arctan2(*(truth[4] - poses[:, :2].mean(0))[::-1])
    wrong_kinds = np.array([POINT, WALL])
    wrong = np.array(
        [
            n0 * truth[0, 1] + 0.5 * np.array([-n0[1], n0[0]]),
            [a4, np.array([np.cos(a4), np.sin(a4)]) @ truth[4]],
        ]
    )
    k, st = sm.refit_kinds(wrong_kinds, wrong, lm, z, at, np.array([6, 6]))
    assert k.tolist() == [WALL, CORNER]
    assert np.abs(_wrapped(st - truth[[0, 4]], kinds[[0, 4]])).max() < 0.03
    # seen from one stop only, nothing changes (one view cannot tell the kinds apart)
    k1, st1 = sm.refit_kinds(wrong_kinds, wrong, lm, z, at, np.array([1, 1]))
    assert k1.tolist() == wrong_kinds.tolist() and np.array_equal(st1, wrong)


def test_a_merged_group_is_not_absorbed_again_by_a_weaker_landmark() -> None:
    # a corner (30 pairs) absorbs the point 0.15 m away (29); the point 0.2 m from the
    # corner (5) is not within reach of it and must not take the merged group over (it did:
    # the survivor was tested again against it with its summed support)
    kinds = np.array([CORNER, POINT, POINT])
    states = np.array([[0.0, 0.0], [0.15, 0.0], [0.2, 0.0]])
    k, s = merge_duplicates(
        kinds,
        states,
        np.array([30.0, 29.0, 5.0]),
        wall_dist=0.0,
        wall_angle=0.1,
        point_dist=0.15,
    )
    assert k.tolist() == [CORNER, POINT]
    np.testing.assert_allclose(s[1], [0.2, 0.0])


@pytest.mark.parametrize(
    "kw",
    [
        {"kind_switch_ratio": 1.5},
        {"kind_switch_ratio": 0.0},
        {"merge_dist": -0.1},
        {"stop_gate": -0.1},
        {"stop_gate": float("nan")},
        {"stop_gate": float("inf")},
        {"stop_min_pairs": 0},
        {"stop_min_pairs": 2.5},
        {"keyframe_turn": -0.1},
        {"sigma_floor": -0.01},
        {"sigma_floor": 0.06},
    ],
)
def test_smoother_config_rejects_settings_that_cannot_work(kw) -> None:
    with pytest.raises(ValueError):
        SmootherConfig(**kw)


@pytest.mark.parametrize("k", [0, -1, 2.5, True])
def test_slam_config_rejects_a_bad_hypothesis_count(k) -> None:
    from fusion_center.mapping.rbpf import SlamConfig

    with pytest.raises(ValueError):
        SlamConfig(relocalise_hypotheses=k)


def _stop_placed_off(shift: float, seed: int = 3):
    """The rectangle room's problem with the last stop placed ``shift`` m off in y by its
    odometry (the drive to it slipped sideways): its echoes come from the true poses, the
    odometry and the initial guess say it stands ``shift`` m higher."""
    room = rectangle_room()
    poses = stop_and_turn_poses(STOPS, TURN, np.radians(12.0))
    rng = np.random.default_rng(seed)
    pairs = [echo_pairs(room, p, ANTENNAS, rng) for p in poses]
    believed = poses.copy()
    believed[-TURN:, 1] += shift
    odo = odometry_increments(believed, rng, OdometrySlip(translation=0.0, rotation=0.0))
    kinds, truth = _true_landmarks(room)
    # the walls only: a corner or point in another direction would place the stop alone
    return poses, believed, odo, pairs, kinds[:4], truth[:4]


@pytest.mark.parametrize("stop_gate", [0.0, 0.6])
def test_a_stop_placed_off_by_its_odometry_keeps_its_wall_echoes_jointly(stop_gate) -> None:
    poses, believed, odo, pairs, kinds, truth = _stop_placed_off(0.22)
    cfg = SmootherConfig(range_sigma=0.02, stop_gate=stop_gate)
    res = LeastSquaresPathMapSmoother(ANTENNAS, cfg).smooth(
        believed, odo, pairs, None, kinds, truth
    )
    last = slice(-TURN, None)
    err = np.abs(res.poses[last, 1] - poses[last, 1]).mean()
    if stop_gate == 0.0:
        # each echo of the walls above and below is 0.4 m from its prediction, beyond the
        # 0.25 m gate: the stop stays where its odometry put it
        assert err > 0.15
    else:
        # together they share one offset: associated, they pull the stop onto the truth
        assert err < 0.03
        # (the drive to it is 0.22 m off: the stop before gives a little, within 0.06 m)
        assert np.abs(res.poses[:-TURN, :2] - poses[:-TURN, :2]).max() < 0.06


def test_the_joint_association_needs_a_common_offset() -> None:
    smoother = LeastSquaresPathMapSmoother(ANTENNAS, SmootherConfig(stop_gate=0.6))
    lm = np.array([-1, -1, -1, -1, -1, 0])
    stop = np.array([0, 0, 0, 1, 1, 1])
    pair = np.array([0, 1, 2, 3, 4, 5])
    landmark = np.zeros(6, np.int64)
    # stop 0: three pairs 0.4 m off alike; stop 1: pairs spread 0.3 to 0.55, and its pair 5
    # is associated already
    err = np.array([[0.4, 0.41], [0.39, 0.4], [0.42, 0.4], [0.3, 0.3], [0.55, 0.55], [0, 0]])
    out = smoother._associate_by_stop(lm, stop, pair, landmark, err)
    assert out.tolist() == [0, 0, 0, -1, -1, 0]
    # two pairs are too few (stop_min_pairs = 3)
    two = smoother._associate_by_stop(lm, stop, pair[1:], landmark[1:], err[1:])
    assert two.tolist() == lm.tolist()


def test_the_joint_association_needs_one_direction_of_arrival() -> None:
    smoother = LeastSquaresPathMapSmoother(ANTENNAS, SmootherConfig(stop_gate=0.6))
    # one stop: four pairs 0.4 m off at both receivers, and three whose mean residual is the
    # same 0.4 m, each receiver within gate (0.25 m) of it, but whose receivers differ by
    # 0.3-0.45 m (another direction of arrival: another reflector's echo)
    err = np.array(
        [
            [0.4, 0.41],
            [0.39, 0.4],
            [0.42, 0.4],
            [0.41, 0.39],
            [0.55, 0.25],
            [0.6, 0.2],
            [0.62, 0.18],
        ]
    )
    assert np.allclose(err.mean(1), 0.4, atol=0.01)
    lm = np.full(7, -1)
    stop = np.zeros(7, np.int64)
    pair = np.arange(7)
    out = smoother._associate_by_stop(lm, stop, pair, np.zeros(7, np.int64), err)
    assert out.tolist() == [0, 0, 0, 0, -1, -1, -1]
    # the rule follows range_sigma: at a 0.05 m noise a 0.3 m difference is 4 sigma off
    loose = LeastSquaresPathMapSmoother(
        ANTENNAS, SmootherConfig(stop_gate=0.6, range_sigma=0.12)
    )._associate_by_stop(lm, stop, pair, np.zeros(7, np.int64), err)
    assert loose.tolist() == [0] * 7


def test_the_joint_association_takes_the_consistent_set_not_the_median() -> None:
    """A wall heard from a stop placed off it (three pairs 0.3 m short at both receivers),
    and a corner's double reflections at that stop within stop_gate of the same wall (three
    pairs, another direction of arrival: the receivers differ by 0.35 m). The median of all
    six lay between the sets and took neither (corridor_L_sparse seed 1, stop 3); the
    consensus takes the wall's set, whose receivers agree as the wall predicts."""
    smoother = LeastSquaresPathMapSmoother(ANTENNAS, SmootherConfig(stop_gate=0.6))
    wall = [[-0.30, -0.29], [-0.29, -0.30], [-0.31, -0.30]]
    corner = [[0.05, 0.40], [0.06, 0.41], [0.04, 0.40]]
    err = np.array(wall + corner)
    lm, stop, pair = np.full(6, -1), np.zeros(6, np.int64), np.arange(6)
    out = smoother._associate_by_stop(lm, stop, pair, np.zeros(6, np.int64), err)
    assert out.tolist() == [0, 0, 0, -1, -1, -1]


def test_the_joint_association_skips_a_landmark_the_stop_has_already() -> None:
    smoother = LeastSquaresPathMapSmoother(ANTENNAS, SmootherConfig(stop_gate=0.6))
    # three pairs 0.4 m off alike, and a fourth pair of the stop on landmark 0 already (its
    # echo from there is known: the three are other echoes)
    err = np.array([[0.4, 0.41], [0.39, 0.4], [0.42, 0.4]])
    stop = np.zeros(4, np.int64)
    landmark = np.zeros(3, np.int64)
    pair = np.arange(3)
    known = smoother._associate_by_stop(np.array([-1, -1, -1, 0]), stop, pair, landmark, err)
    assert known.tolist() == [-1, -1, -1, 0]
    free = smoother._associate_by_stop(np.array([-1, -1, -1, -1]), stop, pair, landmark, err)
    assert free.tolist() == [0, 0, 0, -1]
    # the fourth pair on another landmark does not block landmark 0
    other = smoother._associate_by_stop(np.array([-1, -1, -1, 1]), stop, pair, landmark, err)
    assert other.tolist() == [0, 0, 0, 1]
    # nor does a pair of another stop on landmark 0
    two = smoother._associate_by_stop(
        np.array([-1, -1, -1, 0]), np.r_[0, 0, 0, 1], pair, landmark, err
    )
    assert two.tolist() == [0, 0, 0, 0]


@pytest.mark.parametrize("near", [0, 1])
def test_a_pair_qualifying_for_two_landmarks_takes_the_smaller_offset(near: int) -> None:
    smoother = LeastSquaresPathMapSmoother(ANTENNAS, SmootherConfig(stop_gate=0.6))
    # three pairs of one stop, each a candidate of both landmarks: 0.30 m off one (``near``),
    # 0.45 m off the other; both groups pass on their own
    base = np.array([[0.0, 0.01], [-0.01, 0.0], [0.02, 0.0]])
    pair = np.r_[np.arange(3), np.arange(3)]
    landmark = np.r_[np.zeros(3, np.int64), np.ones(3, np.int64)]
    offset = np.where(landmark == near, 0.30, 0.45)
    err = base[pair] + offset[:, None]
    out = smoother._associate_by_stop(np.full(3, -1), np.zeros(3, np.int64), pair, landmark, err)
    assert out.tolist() == [near] * 3
    # alone, the farther landmark's group would be associated
    far = landmark != near
    alone = smoother._associate_by_stop(
        np.full(3, -1), np.zeros(3, np.int64), pair[far], landmark[far], err[far]
    )
    assert alone.tolist() == [1 - near] * 3


def test_a_landmark_heard_from_one_stop_has_that_stop_as_its_observer() -> None:
    _, odo, pairs, kinds, _t, init_poses, init_lm = _problem()
    # echoes from the second stop only: every landmark heard is heard from there
    one = [p if TURN <= i < 2 * TURN else np.zeros((0, 2)) for i, p in enumerate(pairs)]
    cfg = SmootherConfig(range_sigma=0.02, slip_translation=0.01, slip_rotation=0.01, max_nfev=50)
    res = LeastSquaresPathMapSmoother(ANTENNAS, cfg).smooth(
        init_poses, odo, one, None, kinds, init_lm
    )
    seen = res.pairs > 0
    assert seen.sum() >= 4
    assert np.all(res.stops[seen] == 1)
    # the mean position of the acquisitions heard: within the stop's own spread (its poses
    # move by the turning slip) and near the true stop
    stop = res.poses[TURN : 2 * TURN, :2]
    spread = np.linalg.norm(stop - stop.mean(0), axis=1).max()
    assert np.all(np.linalg.norm(res.observer[seen] - stop.mean(0), axis=1) <= spread)
    np.testing.assert_allclose(
        res.observer[seen], np.broadcast_to(STOPS[1], (seen.sum(), 2)), atol=0.05
    )
    assert np.all(np.isnan(res.observer[~seen]))


def _coarse_turns(seed: int):
    """Three stops turning on the spot in 15-degree steps (corridor_L_sparse's), with the
    recorder's odometry noise and 3 mm echo noise; the initial guess is dead reckoning."""
    room = rectangle_room()
    poses = stop_and_turn_poses([[1.5, 1.5], [4.5, 1.5], [4.5, 3.5]], 24, np.radians(15.0))
    rng = np.random.default_rng(seed)
    odo = odometry_increments(poses, rng, OdometrySlip())
    pairs = [echo_pairs(room, p, ANTENNAS, rng, sigma=0.003) for p in poses]
    dead = poses.copy()
    for i in range(1, len(poses)):
        c, s = np.cos(dead[i - 1, 2]), np.sin(dead[i - 1, 2])
        step = [c * odo[i, 0] - s * odo[i, 1], s * odo[i, 0] + c * odo[i, 1], odo[i, 2]]
        dead[i] = dead[i - 1] + step
    kinds, truth = _true_landmarks(room)
    return poses, dead, odo, pairs, kinds, truth


@pytest.mark.parametrize("seed", [1, 3, 4])
def test_coarse_turns_get_their_in_turn_heading_from_the_echoes(seed) -> None:
    poses, dead, odo, pairs, kinds, truth = _coarse_turns(seed)

    def first_stop_heading_rms(**kw) -> float:
        res = LeastSquaresPathMapSmoother(ANTENNAS, SmootherConfig(**kw)).smooth(
            dead, odo, pairs, None, kinds, truth
        )
        err = (res.poses[:24, 2] - poses[:24, 2] + np.pi) % (2 * np.pi) - np.pi
        return float(np.degrees(np.sqrt(np.mean(err**2))))

    # 5 acquisitions (75 degrees of turn) per key pose and 5 cm per range: the first stop's
    # headings follow the odometry's drift (0.55 degrees a step)
    assert first_stop_heading_rms() > 0.6
    # a key pose every step and each wall's own (millimetre) residual scale: the echoes'
    # bearings carry the heading from one wall's window to the next
    assert first_stop_heading_rms(keyframe_turn=np.radians(10.0), sigma_floor=0.01) < 0.5


def test_image_clusters_grow_from_the_densest_point_within_each_stop() -> None:
    rng = np.random.default_rng(5)
    a = np.add([2.0, 5.0], rng.normal(0.0, 0.03, (4, 2)))  # 4 images of one reflector
    b = np.add([3.0, 5.0], rng.normal(0.0, 0.03, (2, 2)))  # 2 of another, 1 m away
    lone = [[2.0, 4.6]]  # 0.4 m from the first: not within 0.25 m
    other = np.add([2.0, 5.0], rng.normal(0.0, 0.03, (3, 2)))  # the first's place, another stop
    pts = np.vstack([a, b, lone, other])
    grp = np.r_[[0] * 7, [1] * 3]
    lab = image_clusters(pts, grp, radius=0.25, min_size=2)
    assert len(set(lab[:4])) == 1 and lab[0] >= 0
    assert len(set(lab[4:6])) == 1 and lab[4] >= 0 and lab[4] != lab[0]
    assert lab[6] == -1
    assert len(set(lab[7:])) == 1 and lab[7] not in (lab[0], lab[4])
    # min_size 3: the pair of the second reflector is no cluster
    lab = image_clusters(pts, grp, radius=0.25, min_size=3)
    assert np.all(lab[4:7] == -1) and lab[0] >= 0 and lab[7] >= 0
    with pytest.raises(ValueError, match="radius"):
        image_clusters(pts, grp, radius=0.0, min_size=2)
    with pytest.raises(ValueError, match="one row each"):
        image_clusters(pts, grp[:3], radius=0.25, min_size=2)


def test_echoes_no_landmark_explains_are_one_reflector_per_stop() -> None:
    _, odo, pairs, kinds, truth, init_poses, init_lm = _problem()
    # the wall y = 0 (the first) is not among the landmarks: its echoes stay unexplained
    cfg = SmootherConfig(range_sigma=0.02, slip_translation=0.01, slip_rotation=0.01, max_nfev=50)
    sm = LeastSquaresPathMapSmoother(ANTENNAS, cfg)
    res = sm.smooth(init_poses, odo, pairs, None, kinds[1:], init_lm[1:])
    refl, obs, count = sm.stop_reflectors(res, pairs, min_pairs=3)
    # the three stops along y = 0 hear it at the foot of their perpendicular, (x_stop, 0)
    for stop in STOPS[:3]:
        k = np.flatnonzero(np.linalg.norm(obs - stop, axis=1) < 0.1)
        near = k[np.abs(refl[k, 1]) < 0.1]
        assert near.size == 1
        np.testing.assert_allclose(refl[near[0]], [stop[0], 0.0], atol=0.1)
        assert count[near[0]] >= 3
    # with every landmark there, only the echoes of the corner whose initial guess lies
    # beyond the gate stay unexplained (no pair associated): it is found from every stop
    res = sm.smooth(init_poses, odo, pairs, None, kinds, init_lm)
    lost = np.flatnonzero(res.pairs == 0)
    refl, obs, count = sm.stop_reflectors(res, pairs, min_pairs=3)
    assert lost.size == 1 and kinds[lost[0]] == CORNER
    assert len(refl) == len(STOPS) and np.all(count >= 3)
    np.testing.assert_allclose(refl, np.broadcast_to(truth[lost[0]], refl.shape), atol=0.1)
    # one stray pair (an image no other pair shares) is no reflector, even at min_pairs 1
    # (coarse turning steps scale min_pairs down to 1; review28b M2)
    stray = [np.asarray(p, float).reshape(-1, 2) for p in pairs]
    stray[10] = np.vstack([stray[10], [7.31, 7.52]])
    res_s = sm.smooth(init_poses, odo, stray, None, kinds, init_lm)
    assert res_s.association[sum(len(p) for p in stray[:11]) - 1] == -1
    refl_s, _, count_s = sm.stop_reflectors(res_s, stray, min_pairs=1)
    assert np.all(count_s >= 2) and len(refl_s) == len(STOPS)
    with pytest.raises(ValueError, match="do not match"):
        sm.stop_reflectors(res, pairs[1:], min_pairs=3)
    with pytest.raises(ValueError, match="min_pairs"):
        sm.stop_reflectors(res, pairs, min_pairs=0)
