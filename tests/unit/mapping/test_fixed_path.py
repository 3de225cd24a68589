"""Batch mapping at a known path (fixed_path.py) on the synthetic room's echoes."""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

from fusion_center.mapping.fixed_path import FixedPathConfig, _arc, _junctions, map_fixed_path
from fusion_center.mapping.grouping import KalmanEchoGrouper
from fusion_center.mapping.models import WALL
from fusion_center.mapping.synthetic import (
    SyntheticRoom,
    echo_pairs,
    rectangle_room,
    stop_and_turn_poses,
)

ANTENNAS = np.array([[0.0, 0.0], [0.0, 0.5], [0.0, -0.5]])
STOPS = [[1.5, 1.5], [3.0, 1.2], [4.5, 1.5], [4.5, 3.5], [3.0, 3.8], [1.5, 3.5]]
TURN = 60


def _echoes(seed: int = 1):
    """The room's echo pairs at every pose of a stop-and-turn path, grouped as the mapper
    groups them (Kalman tracks, reset at every drive)."""
    room = rectangle_room()
    return (room, *_stop_echoes(room, STOPS, seed))


def _track_ids(pairs) -> list:
    """Kalman track ids of ``pairs`` as the mapper groups them (reset at every drive)."""
    grouper = KalmanEchoGrouper()
    ids = []
    for i, z in enumerate(pairs):
        if i % TURN == 0:
            grouper.reset()
        ids.append(grouper.step(z))
    return ids


def _stop_echoes(room, stops, seed: int):
    """Poses of a stop-and-turn path through ``stops`` (TURN acquisitions, 6-degree steps),
    the room's echo pairs there and their Kalman track ids (reset at every drive)."""
    poses = stop_and_turn_poses(stops, TURN, np.radians(6.0))
    rng = np.random.default_rng(seed)
    pairs = [echo_pairs(room, p, ANTENNAS, rng) for p in poses]
    ids = _track_ids(pairs)
    return poses, pairs, ids


def _wrap_angle(a: np.ndarray) -> np.ndarray:
    return (a + np.pi) % (2 * np.pi) - np.pi


def _seg_dist(seg: np.ndarray, p: np.ndarray) -> np.ndarray:
    a, b = seg[:2], seg[2:]
    e = b - a
    t = np.clip((p - a) @ e / (e @ e), 0.0, 1.0)
    return np.linalg.norm(a + t[:, None] * e - p, axis=1)


def _wall_errors(room, walls: np.ndarray) -> np.ndarray:
    """For every true wall, the largest distance of the closest mapped wall's end points
    from its line (inf if no mapped wall runs along it)."""
    out = []
    for w in room.walls:
        e = (w[2:] - w[:2]) / np.linalg.norm(w[2:] - w[:2])
        n = np.array([-e[1], e[0]])
        best = np.inf
        for m in walls:
            d = np.abs((m.reshape(2, 2) - w[:2]) @ n)
            along = (m.reshape(2, 2) - w[:2]) @ e
            if abs((m[2:] - m[:2]) @ n) < 0.2 * np.linalg.norm(m[2:] - m[:2]) and np.any(
                (along > 0) & (along < np.linalg.norm(w[2:] - w[:2]))
            ):
                best = min(best, float(d.max()))
        out.append(best)
    return np.array(out)


def test_the_room_is_mapped_at_its_true_path() -> None:
    room, poses, pairs, ids = _echoes()
    res = map_fixed_path(pairs, ids, poses, ANTENNAS)
    m = res.map
    # every wall found, along its true line within 3 cm at both ends (1 cm echoes)
    err = _wall_errors(room, m.walls)
    assert np.all(err < 0.03), err
    assert len(m.walls) == 4
    # corners and the two point scatterers: each within 5 cm of a mapped corner / point
    found = np.vstack([m.corners, m.points])
    assert len(m.corners) == len(room.corners)
    d_c = np.linalg.norm(room.corners[:, None] - m.corners[None], axis=-1).min(1)
    d_p = np.linalg.norm(room.points[:, None] - m.points[None], axis=-1).min(1)
    assert np.all(d_c < 0.05), d_c
    assert np.all(d_p < 0.05), d_p
    # nothing mapped that is not in the room
    ghosts = [
        p
        for p in found
        if min(
            np.linalg.norm(room.corners - p, axis=1).min(),
            np.linalg.norm(room.points - p, axis=1).min(),
        )
        > 0.2
    ]
    assert not ghosts
    assert np.array_equal(res.poses[:, :2], poses[:, :2]) and not np.any(res.stop_corrections)
    assert np.allclose(_wrap_angle(res.poses[:, 2] - poses[:, 2]), 0.0, atol=1e-12)


def test_path_refinement_pulls_perturbed_stops_back() -> None:
    room, poses, pairs, ids = _echoes(2)
    rng = np.random.default_rng(5)
    off = rng.normal(0.0, 1.0, (len(STOPS), 3)) * [0.05, 0.05, np.radians(1.5)]
    off[0] = 0.0
    bad = poses + np.repeat(off, TURN, axis=0)
    cfg = FixedPathConfig(refine_path=True, path_sigma=(0.1, np.radians(3.0)))
    res = map_fixed_path(pairs, ids, bad, ANTENNAS, cfg)
    before = np.sqrt(np.mean(np.sum((bad[:, :2] - poses[:, :2]) ** 2, 1)))
    after = np.sqrt(np.mean(np.sum((res.poses[:, :2] - poses[:, :2]) ** 2, 1)))
    yaw_after = np.abs(_wrap_angle(res.poses[:, 2] - poses[:, 2])).max()
    assert before > 0.04
    assert after < 0.4 * before, (before, after)
    assert yaw_after < np.radians(0.5)
    assert np.all(_wall_errors(room, res.map.walls) < 0.04)
    # without the refinement the same path leaves the walls further off
    plain = map_fixed_path(pairs, ids, bad, ANTENNAS)
    assert _wall_errors(room, plain.map.walls).max() > _wall_errors(room, res.map.walls).max()


def test_no_echoes_give_an_empty_map() -> None:
    poses = stop_and_turn_poses(STOPS[:2], 5, 0.1)
    res = map_fixed_path([np.zeros((0, 2))] * len(poses), None, poses, ANTENNAS)
    assert len(res.map.walls) == len(res.map.corners) == len(res.map.points) == 0


def test_group_ids_need_only_be_unique_within_a_stop() -> None:
    _, poses, pairs, ids = _echoes()
    ref = map_fixed_path(pairs, ids, poses, ANTENNAS).map
    # the same tracks, numbered from 0 again at every stop
    restart = []
    for i, g in enumerate(ids):
        first = min(int(np.min(x)) for x in ids[i - i % TURN : i - i % TURN + TURN] if len(x))
        restart.append(np.asarray(g) - first)
    assert restart[TURN].size and restart[TURN].min() == 0
    res = map_fixed_path(pairs, restart, poses, ANTENNAS).map
    assert len(res.walls) == len(ref.walls) == 4
    assert len(res.corners) == len(ref.corners)
    assert len(res.points) == len(ref.points)
    np.testing.assert_allclose(res.walls, ref.walls, atol=1e-9)


def test_every_pair_its_own_group_keeps_memory_linear() -> None:
    """groups=None with min_group_pairs=1: the cross-stop consistency must not build dense
    arrays over all pairs of groups (9k pairs needed 6 GB so)."""
    room = rectangle_room()
    poses = stop_and_turn_poses(STOPS, 180, np.radians(2.0))
    rng = np.random.default_rng(3)
    pairs = [echo_pairs(room, p, ANTENNAS, rng) for p in poses]
    n_pairs = sum(len(p) for p in pairs)
    assert n_pairs > 1500
    tracemalloc.start()
    try:
        res = map_fixed_path(pairs, None, poses, ANTENNAS, FixedPathConfig(min_group_pairs=1))
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    # dense (G, G) float arrays alone would take 8 G^2 bytes each
    assert peak < 8 * n_pairs**2, (peak, n_pairs)
    assert len(res.map.walls) == 4


def _single(corner=None, point=None, wall=None):
    z = np.zeros((0, 2))
    return SyntheticRoom(
        walls=np.zeros((0, 4)) if wall is None else np.array([wall], float),
        corners=z if corner is None else np.array([corner], float),
        points=z if point is None else np.array([point], float),
    )


def _map_from_stops(room, stops, seed: int, config: FixedPathConfig | None = None):
    poses, pairs, ids = _stop_echoes(room, stops, seed)
    return map_fixed_path(pairs, ids, poses, ANTENNAS, config)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_keep_ties_keeps_a_corner_seen_with_little_parallax(seed) -> None:
    # stops 0.2 m apart, 4 m from the corner (2.9 deg): its hypotheses agree as a wall
    # through it as well as at one position; a tie given to the wall (the default) loses it
    stops, corner = [[0.0, 0.0], [0.0, 0.2]], [4.0, 0.0]
    res = _map_from_stops(_single(corner=corner), stops, seed, FixedPathConfig(keep_ties=True))
    found = np.vstack([res.map.corners, res.map.points])
    assert len(found) and np.linalg.norm(found - corner, axis=1).min() < 0.05, found
    res = _map_from_stops(_single(corner=corner), stops, seed)
    assert len(res.map.corners) + len(res.map.points) == 0


THREE_STOPS = [[0.0, 0.0], [0.0, 1.0], [0.5, -0.8]]


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("kind", ["corner", "point"])
def test_a_point_like_landmark_near_the_stops_gets_its_kind(seed, kind) -> None:
    # 1.5 m from three stops the corner and point models differ by more than the noise
    other = "point" if kind == "corner" else "corner"
    res = _map_from_stops(_single(**{kind: [1.5, 0.0]}), THREE_STOPS, seed).map
    got = res.corners if kind == "corner" else res.points
    wrong = res.points if kind == "corner" else res.corners
    assert len(got) == 1 and np.linalg.norm(got[0] - [1.5, 0.0]) < 0.05, (kind, got)
    assert len(wrong) == 0, (other, wrong)


@pytest.mark.parametrize("seed", range(6))
def test_a_far_corner_is_not_called_a_point_on_noise(seed) -> None:
    # 4 m away the two models differ by less than the range noise: without a margin the
    # better cost labels at random; undecided keeps the corner
    res = _map_from_stops(_single(corner=[4.0, 0.0]), THREE_STOPS, seed).map
    assert len(res.points) == 0, res.points
    assert len(res.corners) == 1 and np.linalg.norm(res.corners[0] - [4.0, 0.0]) < 0.05


def test_output_angles_are_wrapped() -> None:
    _, poses, pairs, ids = _echoes()
    poses = poses.copy()
    poses[::2, 2] += 4 * np.pi  # the same headings, given unwrapped
    res = map_fixed_path(pairs, ids, poses, ANTENNAS, FixedPathConfig(refine_path=True))
    for a in (res.poses[:, 2], res.states[res.kinds == WALL, 0]):
        assert a.size and np.all((a >= -np.pi) & (a < np.pi)), a
    assert len(res.map.walls) == 4


def _is_empty(res) -> bool:
    return len(res.map.walls) == len(res.map.corners) == len(res.map.points) == 0


def test_echoes_without_a_confirmed_hypothesis_give_an_empty_map() -> None:
    _, poses, pairs, ids = _echoes()
    # every pair its own group: below the default min_group_pairs, no hypothesis at all
    assert _is_empty(map_fixed_path(pairs, None, poses, ANTENNAS))
    # one stop: no other stop can confirm a hypothesis, whatever min_stops
    one = slice(0, TURN)
    assert _is_empty(map_fixed_path(pairs[one], ids[one], poses[one], ANTENNAS))
    cfg = FixedPathConfig(min_stops=1)
    assert _is_empty(map_fixed_path(pairs[one], ids[one], poses[one], ANTENNAS, cfg))
    # one pose with one pair
    assert _is_empty(map_fixed_path([np.array([[4.0, 4.0]])], None, np.zeros((1, 3)), ANTENNAS))


_one_pair = [np.array([[3.0, 3.1]]), np.zeros((0, 2)), np.zeros((0, 2))]


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"path": np.zeros((3, 2))}, "path must have shape"),
        ({"path": np.zeros((0, 3)), "pairs": []}, "path must have shape"),
        ({"path": np.full((3, 3), np.nan)}, "non-finite"),
        ({"antennas": np.zeros((2, 2))}, "antennas"),
        ({"antennas": np.zeros((3, 2))}, "receivers coincide"),
        ({"pairs": [np.zeros((0, 2))] * 2}, "one entry per pose"),
        ({"groups": [np.zeros(1)] * 3}, "one id per pair"),
        ({"pairs": [np.ones((2, 3))] + [np.zeros((0, 2))] * 2}, r"pairs\[0\] must have shape"),
        ({"pairs": [np.ones(3)] + [np.zeros((0, 2))] * 2}, r"pairs\[0\] must have shape"),
        ({"pairs": [np.array([["a", "b"]])] + [np.zeros((0, 2))] * 2}, "numeric echo pairs"),
        ({"pairs": None}, "pairs must be a list"),
        ({"groups": 3}, "groups must be None or a list"),
        ({"path": [[0, 0, 0], [1, 1], [2, 2, 2]]}, "path must be a numeric array"),
        ({"pairs": _one_pair, "groups": [np.array([np.nan]), [], []]}, "integer ids"),
        ({"pairs": _one_pair, "groups": [np.array([1.5]), [], []]}, "integer ids"),
        ({"pairs": _one_pair, "groups": [np.array(["a"]), [], []]}, "integer ids"),
        ({"pairs": [np.array([[np.inf, 2.0]])] + [np.zeros((0, 2))] * 2}, "non-finite ranges"),
    ],
)
def test_bad_input_is_refused_in_one_line(kwargs, match) -> None:
    args = {
        "pairs": [np.zeros((0, 2))] * 3,
        "groups": None,
        "path": np.zeros((3, 3)),
        "antennas": ANTENNAS,
    }
    args.update(kwargs)
    with pytest.raises(ValueError, match=match) as err:
        map_fixed_path(args["pairs"], args["groups"], args["path"], args["antennas"])
    assert "\n" not in str(err.value)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"range_sigma": 0.0},
        {"rounds": 0},
        {"min_stops": 1.5},
        {"path_sigma": (0.1,)},
        {"extent_quantile": 0.5},
        {"path_sigma": 0.05},
        {"min_wall_length": np.nan},
        {"merge_dist": np.nan},
        {"extend": -1.0},
        {"overlap_dist": np.inf},
        {"kind_margin": np.nan},
        {"assoc_gate_start": 0.05, "assoc_gate": 0.15},
        {"fitted_kinds": "no"},
        {"refine_path": 1},
        {"corner_span": 0.0},
        {"corner_span": np.nan},
        {"corner_rate": -0.1},
        {"corner_separation": np.inf},
        {"corner_junction": -0.1},
    ],
)
def test_bad_configuration_is_refused(kwargs) -> None:
    with pytest.raises(ValueError, match="FixedPathConfig"):
        FixedPathConfig(**kwargs)


def test_fitted_kinds_keep_an_edge_between_two_faces_a_point() -> None:
    from fusion_center.mapping.features import LandmarkSet, build_map

    # two faces of a box meeting at (2, 1) and a point-like landmark there, fitted as a point
    lm = LandmarkSet(
        walls=np.array([[0.0, 2.0], [np.pi / 2, 1.0]]),
        wall_extent=np.array([[1.0, 3.0], [2.0, 4.0]]),
        wall_hits=np.array([20.0, 20.0]),
        points=np.array([[2.0, 1.0]]),
        point_is_corner=np.array([False]),
        point_hits=np.array([20.0]),
    )
    assert len(build_map(lm).corners) == 1  # the geometric rule: a junction is a corner
    m = build_map(lm, fitted_kinds=True)
    assert len(m.corners) == 0 and np.allclose(m.points, [[2.0, 1.0]])


def test_collinear_faces_with_a_gap_stay_two_walls() -> None:
    from fusion_center.mapping.synthetic import SyntheticRoom

    base = rectangle_room()
    # the wall y = 0 has a 2 m doorway in its middle: two faces on one line
    walls = np.vstack([[[0.0, 0.0, 2.0, 0.0], [4.0, 0.0, 6.0, 0.0]], base.walls[1:]])
    room = SyntheticRoom(walls=walls, corners=base.corners, points=base.points)
    poses = stop_and_turn_poses(STOPS, TURN, np.radians(6.0))
    rng = np.random.default_rng(3)
    pairs = [echo_pairs(room, p, ANTENNAS, rng) for p in poses]

    def crosses_doorway(cfg: FixedPathConfig) -> bool:
        w = map_fixed_path(pairs, None, poses, ANTENNAS, cfg).map.walls
        on_line = np.abs(w[:, 1]) + np.abs(w[:, 3]) < 0.1
        lo, hi = np.minimum(w[:, 0], w[:, 2]), np.maximum(w[:, 0], w[:, 2])
        assert np.any(on_line)
        return bool(np.any(on_line & (lo < 2.5) & (hi > 3.5)))

    kw = {"min_group_pairs": 1, "min_wall_length": 0.0, "extend": 0.5}
    assert crosses_doorway(FixedPathConfig(**kw))  # default: one wall per line
    assert not crosses_doorway(FixedPathConfig(wall_gap=2.5, **kw))


def test_a_wall_the_robot_drives_through_is_dropped() -> None:
    from fusion_center.mapping.synthetic import SyntheticRoom

    _, poses, pairs, _ = _echoes()
    # a ghost: echoes of a wall across the middle of the room, x = 2.4 for y in 0.5..4.5, that
    # the drives between the stops cross
    rng = np.random.default_rng(7)
    line = SyntheticRoom(
        walls=np.array([[2.4, 0.5, 2.4, 4.5]]), corners=np.zeros((0, 2)), points=np.zeros((0, 2))
    )
    extra = [
        np.vstack([z, echo_pairs(line, p, ANTENNAS, rng)])
        for z, p in zip(pairs, poses, strict=True)
    ]

    def across(cfg: FixedPathConfig) -> int:
        w = map_fixed_path(extra, None, poses, ANTENNAS, cfg).map.walls
        return int(np.sum((np.abs(w[:, 0] - 2.4) < 0.1) & (np.abs(w[:, 2] - 2.4) < 0.1)))

    # seen from both sides: a wall facing each way; the drives from x = 1.5 to x = 3 cross
    # the one whose specular points (from the stops at x = 3 and 4.5) span y = 1.2 .. 3.8,
    # not the other (y = 1.5 .. 3.5, from the stops at x = 1.5 only)
    assert across(FixedPathConfig(min_group_pairs=1)) == 2
    assert across(FixedPathConfig(min_group_pairs=1, drop_crossed=True)) == 1


@pytest.mark.parametrize("seed", [0, 1])
def test_a_corner_heard_from_all_around_is_mapped_as_a_point(seed) -> None:
    # a concave corner echoes only into the quadrant between its walls: a point-like
    # landmark heard from stops around it (here over 240 degrees) is an edge or a scatterer
    stops, spot = [[0.0, 0.0], [3.0, 0.0], [1.5, 2.5]], [1.5, 0.9]
    room = _single(corner=spot)
    off = _map_from_stops(room, stops, seed, FixedPathConfig(corner_span=np.inf))
    assert len(off.map.corners) == 1 and len(off.map.points) == 0
    res = _map_from_stops(room, stops, seed)
    assert len(res.map.corners) == 0, res.map.corners
    assert len(res.map.points) == 1 and np.linalg.norm(res.map.points[0] - spot) < 0.05
    k = int(np.argmin(np.linalg.norm(res.states - spot, axis=1)))
    assert res.view_span[k] > np.radians(200.0)
    assert np.array_equal(res.kinds, off.kinds)  # the fitted kinds are not changed


def _with_ghost(seed: int, looks: int):
    """A corner heard wherever it is in the beam, and a second one (a multipath image)
    heard from the first two stops only, in ``looks`` consecutive headings of each."""
    stops = [[0.0, 0.0], [0.0, 1.0], [0.5, -0.8], [1.0, 0.5]]
    true, ghost = [3.0, 0.2], [2.0, 2.5]
    poses = stop_and_turn_poses(stops, TURN, np.radians(6.0))
    rng = np.random.default_rng(seed)
    pairs = [echo_pairs(_single(corner=true), p, ANTENNAS, rng) for p in poses]
    for s in (0, 1):
        seen = [
            i
            for i in range(s * TURN, (s + 1) * TURN)
            if len(echo_pairs(_single(corner=ghost), poses[i], ANTENNAS, rng))
        ]
        for i in seen[:looks]:
            z = np.vstack([pairs[i], echo_pairs(_single(corner=ghost), poses[i], ANTENNAS, rng)])
            pairs[i] = z[np.argsort(z.sum(1))]
    ids = _track_ids(pairs)
    return poses, pairs, ids, np.array(true), np.array(ghost)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_corner_heard_at_a_low_rate_is_left_out(seed) -> None:
    poses, pairs, ids, true, ghost = _with_ghost(seed, looks=5)
    off = map_fixed_path(pairs, ids, poses, ANTENNAS, FixedPathConfig(corner_rate=0.0))
    d_off = np.linalg.norm(off.map.corners - ghost, axis=1)
    assert np.any(d_off < 0.1), off.map.corners  # mapped without the rate test
    res = map_fixed_path(pairs, ids, poses, ANTENNAS, FixedPathConfig(corner_rate=0.08))
    assert len(res.map.corners) == 1 and np.linalg.norm(res.map.corners[0] - true) < 0.05
    # the rate: pairs per acquisition at the stops within the farthest that heard it
    k_true = int(np.argmin(np.linalg.norm(res.states - true, axis=1)))
    k_ghost = int(np.argmin(np.linalg.norm(res.states - ghost, axis=1)))
    assert res.hearing_rate[k_ghost] < 0.08 < res.hearing_rate[k_true]
    assert res.screened[k_ghost] and not res.screened[k_true]


def test_of_two_corners_close_together_the_weaker_is_left_out() -> None:
    poses, pairs, ids, true, _ = _with_ghost(0, looks=5)
    near = true + np.array([0.25, 0.0])
    rng = np.random.default_rng(7)
    # the same corner fitted twice: a second one 0.25 m behind it, heard from two stops
    for i in range(2 * TURN):
        extra = echo_pairs(_single(corner=near), poses[i], ANTENNAS, rng)
        z = np.vstack([pairs[i], extra])
        pairs[i] = z[np.argsort(z.sum(1))]
    ids = _track_ids(pairs)
    cfg = FixedPathConfig(corner_rate=0.0, corner_separation=0.0)
    both = map_fixed_path(pairs, ids, poses, ANTENNAS, cfg).map.corners
    assert np.linalg.norm(both - near, axis=1).min() < 0.05, both
    assert np.linalg.norm(both - true, axis=1).min() < 0.05, both
    one = map_fixed_path(
        pairs, ids, poses, ANTENNAS, FixedPathConfig(corner_rate=0.0, corner_separation=0.3)
    ).map.corners
    assert np.linalg.norm(one - true, axis=1).min() < 0.05, one
    assert np.linalg.norm(one - near, axis=1).min() > 0.15, one


def test_junctions_are_where_two_mapped_walls_meet() -> None:
    walls = np.array(
        [
            [0.0, 0.0, 3.0, 0.0],  # meets the next one 0.5 m beyond both ends: a junction
            [3.5, 0.5, 3.5, 4.0],
            [0.0, 1.0, 2.0, 1.1],  # nearly parallel to the first: no junction with it
            [6.0, -3.0, 6.0, -2.0],  # its line crosses the first's 3 m beyond its end
        ]
    )
    x = _junctions(walls, 1.0)
    assert x.shape == (1, 2) and np.allclose(x[0], [3.5, 0.0]), x
    assert len(_junctions(walls, 0.4)) == 0


def _heard_by(
    stops, hears, stray=None, seed: int = 0, config: FixedPathConfig | None = None, few=None
):
    """The corner at (3, 0.2) heard from the stops ``hears`` (indices into ``stops``) at every
    heading; the others hear nothing but, with ``stray`` a stop index, one acquisition of
    that stop hears it once (a stray association), and with ``few = (stop, n)`` that stop
    hears it in n acquisitions."""
    true = np.array([3.0, 0.2])
    poses = stop_and_turn_poses(stops, TURN, np.radians(6.0))
    rng = np.random.default_rng(seed)
    room = _single(corner=true)
    pairs = [
        echo_pairs(room, p, ANTENNAS, rng) if i // TURN in hears else np.zeros((0, 2))
        for i, p in enumerate(poses)
    ]
    if stray is not None:
        for i in range(stray * TURN, (stray + 1) * TURN):
            z = echo_pairs(room, poses[i], ANTENNAS, rng)
            if len(z):
                pairs[i] = z[:1]
                break
    if few is not None:
        looks = [
            (i, z)
            for i in range(few[0] * TURN, (few[0] + 1) * TURN)
            if len(z := echo_pairs(room, poses[i], ANTENNAS, rng))
        ]
        for i, z in looks[: few[1]]:
            pairs[i] = z
    ids = _track_ids(pairs)
    cfg = config or FixedPathConfig(min_group_pairs=1)
    res = map_fixed_path(pairs, ids, poses, ANTENNAS, cfg)
    k = int(np.argmin(np.linalg.norm(res.states - true, axis=1)))
    return res, k, true


NEAR4 = [[0.0, 0.0], [0.0, 1.0], [0.5, -0.8], [1.0, 0.5]]


@pytest.mark.parametrize("seed", [0, 1])
def test_one_stray_pair_from_a_far_stop_changes_neither_span_nor_rate(seed) -> None:
    # three stops behind the corner, about 5 m away, hear nothing; one look of one of them
    # associates one pair: it must not widen the span (a point) or push the hearing distance
    # out over every stop in between (a low rate)
    behind = [[7.5, 2.0], [7.8, -1.5], [6.5, 3.5]]
    clean, k0, true = _heard_by(NEAR4 + behind, {0, 1, 2, 3}, seed=seed)
    res, k, _ = _heard_by(NEAR4 + behind, {0, 1, 2, 3}, stray=5, seed=seed)
    assert res.pairs[k] == clean.pairs[k0] + 1  # the stray pair is associated
    assert len(res.map.corners) == 1 and np.linalg.norm(res.map.corners[0] - true) < 0.05
    assert res.view_span[k] == pytest.approx(clean.view_span[k0], abs=1e-3)
    assert res.view_span[k] < np.radians(60.0)
    assert res.hearing_rate[k] == pytest.approx(clean.hearing_rate[k0], rel=1e-6)


@pytest.mark.parametrize("seed", [0, 1])
def test_stops_that_cannot_hear_a_corner_do_not_dilute_its_rate(seed) -> None:
    # stops behind the corner (the other leg of an L, within its hearing distance) and stops
    # in its sector beyond its hearing distance, none hearing it: the rate is that of the
    # four stops that hear it
    alone, k0, _ = _heard_by(NEAR4, {0, 1, 2, 3}, seed=seed)
    leg = [[5.0, 2.0], [5.5, 1.0], [5.0, -1.5], [4.5, 2.5], [5.5, -0.5], [4.0, -2.0]]
    beyond = [[-3.0, 0.0], [-3.0, 1.5]]
    res, k, true = _heard_by(NEAR4 + leg + beyond, {0, 1, 2, 3}, seed=seed)
    assert res.hearing_rate[k] == pytest.approx(alone.hearing_rate[k0], abs=1e-9)
    assert alone.hearing_rate[k0] > 0.1
    assert len(res.map.corners) == 1 and np.linalg.norm(res.map.corners[0] - true) < 0.05
    # the beyond stops are in its sector: within the hearing distance they count
    near = [[1.5, 0.3], [1.8, -0.3]]
    res2, k2, _ = _heard_by(NEAR4 + near, {0, 1, 2, 3}, seed=seed)
    assert res2.hearing_rate[k2] < 0.8 * alone.hearing_rate[k0]


@pytest.mark.parametrize("seed", [0, 1])
def test_a_stop_near_a_corner_does_not_make_it_a_point(seed) -> None:
    # a stop 0.6 m from the corner, on another side than the others: the directions span
    # 112 degrees, and a 0.1 m error of the corner could swing that stop's by 19
    stops = [*NEAR4, [3.0, 0.8]]
    strict, ks, true = _heard_by(
        stops,
        {0, 1, 2, 3, 4},
        seed=seed,
        config=FixedPathConfig(min_group_pairs=1, corner_position_error=0.0),
    )
    assert strict.view_span[ks] > np.radians(110.0)
    assert len(strict.map.corners) == 0
    res, k, _ = _heard_by(stops, {0, 1, 2, 3, 4}, seed=seed)
    assert res.view_span[k] < np.radians(100.0)
    assert len(res.map.corners) == 1 and np.linalg.norm(res.map.corners[0] - true) < 0.05


@pytest.mark.parametrize("seed", [0, 1])
def test_a_corner_heard_from_around_that_no_point_fits_is_left_out(seed) -> None:
    stops, spot = [[0.0, 0.0], [3.0, 0.0], [1.5, 2.5]], [1.5, 0.9]
    room = _single(corner=spot)
    res = _map_from_stops(room, stops, seed)
    k = int(np.argmin(np.linalg.norm(res.states - spot, axis=1)))
    # mapped as the point model's fit, not at the corner model's state
    assert len(res.map.points) == 1
    assert np.linalg.norm(res.map.points[0] - res.states[k]) > 1e-6
    assert not res.screened[k]
    out = _map_from_stops(room, stops, seed, FixedPathConfig(corner_point_cost=0.0))
    assert len(out.map.corners) == 0 and len(out.map.points) == 0
    assert out.screened[k]


def test_a_low_rate_corner_comes_back_only_where_two_mapped_walls_meet() -> None:
    room = rectangle_room()
    inner = [2.5, 2.0]  # a corner heard from around, away from every wall
    room = SyntheticRoom(
        walls=room.walls, corners=np.vstack([room.corners, [inner]]), points=room.points
    )
    poses, pairs, ids = _stop_echoes(room, STOPS, 1)
    # every corner under the rate; the mapped walls end 1.2-1.5 m short of the corners
    base = {"corner_rate": 0.9, "corner_span": np.inf, "extend": 1.6}
    low = map_fixed_path(pairs, ids, poses, ANTENNAS, FixedPathConfig(**base))
    assert len(low.map.corners) == 0 and len(low.map.walls) == 4
    back = map_fixed_path(
        pairs, ids, poses, ANTENNAS, FixedPathConfig(**base, corner_junction=0.15)
    ).map.corners
    d = np.linalg.norm(back[:, None] - room.corners[None, :4], axis=-1)
    assert len(back) == 4 and np.all(d.min(1) < 0.05), back
    assert np.linalg.norm(back - inner, axis=1).min() > 1.0


def test_the_span_wraps_around_minus_pi() -> None:
    start, width = _arc(np.radians([170.0, -170.0, 175.0]))
    assert width == pytest.approx(np.radians(20.0))
    assert start == pytest.approx(np.radians(170.0))
    assert _arc(np.radians([10.0, 100.0]))[1] == pytest.approx(np.radians(90.0))


@pytest.mark.parametrize("seed", [0, 1])
def test_a_far_stop_that_hears_a_corner_a_little_does_not_set_its_hearing_distance(seed) -> None:
    # a stop 5 m away hears the corner in 4 looks (a stop that counts, but under a fifth of
    # the pairs); two stops between it and the corner hear nothing: the hearing distance is
    # the 0.8 quantile of the pairs' stops, the rate that of the four near stops
    alone, k0, _ = _heard_by(NEAR4, {0, 1, 2, 3}, seed=seed)
    stops = [*NEAR4, [-1.0, 0.6], [-1.0, -0.2], [-2.0, 0.2]]
    res, k, true = _heard_by(stops, {0, 1, 2, 3}, seed=seed, few=(6, 4))
    assert res.stops[k] == 5
    assert res.hearing_rate[k] == pytest.approx(alone.hearing_rate[k0], rel=1e-6)
    assert len(res.map.corners) == 1 and np.linalg.norm(res.map.corners[0] - true) < 0.05
