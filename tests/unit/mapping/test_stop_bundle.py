"""Bundle adjustment of the stop graph's path over the individual echo pairs (issue 8)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

import fusion_center.mapping.stop_bundle as sb
from fusion_center.mapping.models import POINT, WALL
from fusion_center.mapping.stop_bundle import (
    StopBundleConfig,
    adjust_stop_bundle,
    drift_basis,
    drift_prior,
)
from fusion_center.mapping.stop_graph import (
    relative_pose,
    scan_log_from_pairs,
    segment_stops,
    turn_basis,
)
from fusion_center.mapping.synthetic import echo_pairs, rectangle_room, stop_and_turn_poses
from sim_nodes.robot_record import odometry_increments

ANTENNAS = np.array([[0.0, 0.0], [0.0, 0.5], [0.0, -0.5]])
STOPS = np.array([[1.6, 1.4], [2.9, 1.7], [4.2, 2.6], [3.6, 3.7], [2.0, 3.3]])


def _compose(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    c, s = np.cos(a[2]), np.sin(a[2])
    return np.array([a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], a[2] + b[2]])


def _problem(seed: int, modes: int, point_sigma: float = 0.005) -> dict:
    """Five stops of 357-degree turns in a 6 x 5 m room (echo pairs with 5 mm of noise,
    the two point scatterers' with ``point_sigma``) and the stop graph's view of them: every
    stop's in-stop headings off by a drift ``drift_basis(f) @ c_true`` of about a degree (the
    turn closure's error), the stop poses off by 2-3 cm and 0.5-1 degree, the odometry edges
    from the erroneous turn ends."""
    rng = np.random.default_rng(seed)
    world = stop_and_turn_poses(STOPS, 120, np.radians(3.0))
    world[:, 2] += 0.3
    odo = odometry_increments(world, rng)
    room = rectangle_room()
    if point_sigma == 0.005:
        pairs = [
            echo_pairs(room, p, ANTENNAS, rng, sigma=0.005, beam=np.radians(50.0)) for p in world
        ]
    else:  # the points' pairs apart, with their own noise
        flat = replace(room, points=np.zeros((0, 2)))
        pts = replace(room, walls=np.zeros((0, 4)), corners=np.zeros((0, 2)))
        pairs = []
        for p in world:
            z = np.vstack(
                [
                    echo_pairs(flat, p, ANTENNAS, rng, sigma=0.005, beam=np.radians(50.0)),
                    echo_pairs(pts, p, ANTENNAS, rng, sigma=point_sigma, beam=np.radians(50.0)),
                ]
            )
            pairs.append(z[np.argsort(z.sum(1))])
    groups = scan_log_from_pairs(np.arange(len(world)) * 0.05, odo, pairs).groups
    truth = np.array([relative_pose(world[0], p) for p in world])
    ranges = segment_stops(odo)
    n = len(ranges)
    phase = [np.linspace(0.0, 1.0, b - a) for a, b in ranges]
    c_true = rng.normal(0.0, np.radians(1.0), (n, modes)) / np.arange(1, modes + 1)
    c_true[:, 0] = rng.normal(0.0, np.radians(1.0), n)
    in_stop, stop_true = [], np.array([truth[a] for a, _ in ranges])
    for (a, b), f, c in zip(ranges, phase, c_true, strict=True):
        rel = np.array([relative_pose(truth[a], truth[k]) for k in range(a, b)])
        rel[:, 2] -= drift_basis(f, modes) @ c
        in_stop.append(rel)
    odometry = []
    for s in range(n - 1):
        end_true = truth[ranges[s][1] - 1]
        drive = relative_pose(end_true, stop_true[s + 1])
        z = _compose(in_stop[s][-1], drive)
        odometry.append((z, np.diag([0.03**2, 0.03**2, np.radians(2.0) ** 2])))
    init = stop_true.copy()
    init[1:] += rng.normal(0.0, [0.03, 0.03, np.radians(1.0)], (n - 1, 3))
    prior = drift_prior(np.full(n, np.radians(1.5)), np.full(n, np.radians(2.0)), modes)
    return {
        "pairs": pairs,
        "groups": groups,
        "ranges": ranges,
        "in_stop": in_stop,
        "phase": phase,
        "init": init,
        "odometry": odometry,
        "prior": prior,
        "truth": truth,
        "c_true": c_true,
        "stop_true": stop_true,
    }


def _path(p: dict, poses: np.ndarray, coef: np.ndarray, modes: int) -> np.ndarray:
    out = []
    for rel, f, pose, c in zip(p["in_stop"], p["phase"], poses, coef, strict=True):
        r = rel.copy()
        r[:, 2] += drift_basis(f, modes) @ c
        out += [_compose(pose, q) for q in r]
    return np.array(out)


def _yaw_rms_deg(path: np.ndarray, truth: np.ndarray) -> float:
    d = (path[:, 2] - truth[:, 2] + np.pi) % (2 * np.pi) - np.pi
    return float(np.degrees(np.sqrt(np.mean(d**2))))


@pytest.mark.parametrize("modes", [2, 4])
def test_bundle_adjustment_recovers_stop_poses_and_in_stop_drift(modes: int) -> None:
    """The echo pairs of four walls, four corners and two point scatterers, seen from five
    stops, fix every acquisition's heading: from 1.1 degrees RMS (drift and stop poses off)
    the adjustment comes within 0.25 degrees (0.04 with two modes, 0.06 with four), and the
    stop positions within 1 cm (5 mm range noise over hundreds of pairs per stop)."""
    p = _problem(11, modes)
    start = _path(p, p["init"], np.zeros((len(p["ranges"]), modes)), modes)
    before = _yaw_rms_deg(start, p["truth"])
    res = adjust_stop_bundle(
        p["pairs"],
        p["groups"],
        p["ranges"],
        p["in_stop"],
        p["phase"],
        p["init"],
        p["odometry"],
        p["prior"],
        ANTENNAS,
        StopBundleConfig(modes=modes, range_sigma=0.005),
    )
    after = _yaw_rms_deg(_path(p, res.poses, res.coefficients, modes), p["truth"])
    assert before > 0.8
    assert after < 0.25, (before, after)
    stop_true = np.array([p["truth"][a] for a, _ in p["ranges"]])
    assert np.all(np.hypot(*(res.poses[:, :2] - stop_true[:, :2]).T) < 0.01)
    np.testing.assert_array_equal(res.poses[0], p["init"][0])  # the gauge
    assert res.n_pairs > 1000


def test_rotation_sigma_holds_the_paths_mean_heading() -> None:
    """A tight ``rotation_sigma`` keeps the stops' mean heading change from the starting
    path at zero (the pose graph's rotation of the whole path); free, the adjustment moves
    it back by the start's error (half a degree)."""
    p = _problem(11, 2)
    # the start turned by half a degree about the first stop (the origin)
    rot = np.radians(0.5)
    init = p["init"].copy()
    c, s = np.cos(rot), np.sin(rot)
    init[1:, :2] = init[1:, :2] @ np.array([[c, s], [-s, c]])
    init[1:, 2] += rot
    args = (
        p["pairs"],
        p["groups"],
        p["ranges"],
        p["in_stop"],
        p["phase"],
        init,
        p["odometry"],
        p["prior"],
        ANTENNAS,
    )
    held = adjust_stop_bundle(*args, StopBundleConfig(rotation_sigma=1e-6, range_sigma=0.005))
    free = adjust_stop_bundle(*args, StopBundleConfig(rotation_sigma=np.inf, range_sigma=0.005))
    mean_held = np.degrees(np.mean(held.poses[1:, 2] - init[1:, 2]))
    mean_free = np.degrees(np.mean(free.poses[1:, 2] - init[1:, 2]))
    assert abs(mean_held) < 0.01
    assert mean_free < -0.3


def test_drift_basis_starts_at_zero_and_extends_turn_basis() -> None:
    f = np.linspace(0.0, 1.0, 7)
    b = drift_basis(f, 4)
    np.testing.assert_allclose(b[:, :2], turn_basis(f))
    np.testing.assert_allclose(b[0], 0.0)
    np.testing.assert_allclose(b[-1], [1.0, 0.0, 0.0, 0.0], atol=1e-12)
    sd = drift_prior(np.array([0.01]), np.array([0.02]), 3)
    np.testing.assert_allclose(sd, [[0.01, np.sqrt(2) * 0.02 / np.pi, np.sqrt(2) * 0.01 / np.pi]])


def test_bad_input_gives_one_line_value_errors() -> None:
    with pytest.raises(ValueError, match="modes"):
        StopBundleConfig(modes=0)
    with pytest.raises(ValueError, match="range_sigma"):
        StopBundleConfig(range_sigma=-1.0)
    with pytest.raises(ValueError, match="rotation_sigma"):
        StopBundleConfig(rotation_sigma=float("nan"))
    with pytest.raises(ValueError, match="same stops"):
        adjust_stop_bundle(
            [np.zeros((0, 2))] * 3,
            [np.zeros(0)] * 3,
            [(0, 3)],
            [],
            [],
            np.zeros((1, 3)),
            [],
            np.ones((1, 2)),
            ANTENNAS,
        )


def test_fixed_path_map_reports_every_pairs_landmark() -> None:
    """``FixedPathMap.association`` holds one landmark index (or -1) per pair, in the order
    of the pairs over the acquisitions, and counts the landmarks' pairs as ``pairs`` does."""
    from fusion_center.mapping.fixed_path import map_fixed_path

    p = _problem(2, 2)
    path = _path(p, np.array([p["truth"][a] for a, _ in p["ranges"]]), np.zeros((5, 2)), 2)
    built = map_fixed_path(p["pairs"], p["groups"], path, ANTENNAS)
    lm = built.association
    assert lm.shape == (sum(len(z) for z in p["pairs"]),)
    assert lm.min() >= -1 and lm.max() < built.kinds.size
    np.testing.assert_array_equal(np.bincount(lm[lm >= 0], minlength=built.kinds.size), built.pairs)


def test_stop_graph_bundle_adjust_option() -> None:
    """``StopGraphConfig.bundle_adjust`` runs the adjustment (default ``StopBundleConfig``,
    two modes) after the refinement. On the synthetic five-stop run the headings' scatter
    about their mean error goes 0.28 -> 0.22 degrees and the positions 11.9 -> 9.1 mm RMS
    (bounds halfway, 0.25 degrees and 10.5 mm); their mean error (-0.16 -> -0.24 degrees)
    is the path's rotation, which the adjustment holds at the graph's, not its gain. Its
    coefficients come over ``modes`` terms."""
    from fusion_center.mapping.stop_graph import (
        StopGraphConfig,
        StopGraphPathEstimator,
    )

    rng = np.random.default_rng(3)
    world = stop_and_turn_poses(STOPS, 120, np.radians(3.0))
    world[:, 2] += 0.3
    odo = odometry_increments(world, rng)
    room = rectangle_room()
    pairs = [echo_pairs(room, p, ANTENNAS, rng, sigma=0.005, beam=np.radians(50.0)) for p in world]
    log = scan_log_from_pairs(np.arange(len(world)) * 0.05, odo, pairs)
    truth = np.array([relative_pose(world[0], p) for p in world])
    errors = []
    for on in (False, True):
        res = StopGraphPathEstimator(ANTENNAS, StopGraphConfig(bundle_adjust=on)).estimate(log)
        d = (res.trajectory[:, 3] - truth[:, 2] + np.pi) % (2 * np.pi) - np.pi
        pos = np.sqrt(np.mean(np.sum((res.trajectory[:, 1:3] - truth[:, :2]) ** 2, 1)))
        errors.append((np.degrees(np.std(d)), pos))
    assert res.turn_coefficients.shape == (5, StopBundleConfig().modes)
    (scatter_off, pos_off), (scatter_on, pos_on) = errors
    assert scatter_off > 0.25 and pos_off > 0.0105, errors  # the test can fail
    assert scatter_on < 0.25 and pos_on < 0.0105, errors


def test_sparse_differences_match_the_dense_jacobian() -> None:
    """The grouped forward differences with an exact dense row equal the dense Jacobian
    (a chain of products, as a pose chain couples neighbours, and a mean over all)."""
    from fusion_center.mapping.stop_bundle import _SparseDifferences

    def fun(x: np.ndarray) -> np.ndarray:
        return np.r_[x[:-1] * x[1:], np.sin(x), 0.5 * np.sum(x)]

    n = 9
    rows = np.r_[np.repeat(np.arange(n - 1), 2), n - 1 + np.arange(n)]
    cols = np.r_[np.column_stack([np.arange(n - 1), np.arange(1, n)]).ravel(), np.arange(n)]
    jac = _SparseDifferences(fun, rows, cols, (2 * n, n))
    jac.dense_row(2 * n - 1, np.arange(n), 0.5)
    assert jac.group.max() + 1 <= 3  # neighbours conflict, the dense row does not count
    x = np.random.default_rng(0).normal(size=n)
    dense = np.zeros((2 * n, n))
    for i in range(n - 1):
        dense[i, i], dense[i, i + 1] = x[i + 1], x[i]
    dense[n - 1 + np.arange(n), np.arange(n)] = np.cos(x)
    dense[-1] = 0.5
    np.testing.assert_allclose(jac(x).toarray(), dense, atol=1e-6)


def _args(p: dict, init: np.ndarray | None = None) -> tuple:
    return (
        p["pairs"],
        p["groups"],
        p["ranges"],
        p["in_stop"],
        p["phase"],
        p["init"] if init is None else init,
        p["odometry"],
        p["prior"],
        ANTENNAS,
    )


def _capture(monkeypatch: pytest.MonkeyPatch) -> list:
    """Every least-squares problem :func:`adjust_stop_bundle` builds, in order."""
    made: list = []

    class Spy(sb._Problem):
        def __init__(self, *a, **k) -> None:
            super().__init__(*a, **k)
            made.append(self)

    monkeypatch.setattr(sb, "_Problem", Spy)
    return made


@pytest.mark.parametrize("hold_first_turn", [False, True])
def test_the_solvers_jacobian_pattern_holds_every_derivative(
    monkeypatch: pytest.MonkeyPatch, hold_first_turn: bool
) -> None:
    """The grouped differences of the real residuals (echo pairs, odometry, drift prior,
    rotation hold) equal a dense column-by-column forward difference: no derivative falls
    outside the sparsity pattern (an odometry row without its stops' drift columns would)."""
    made = _capture(monkeypatch)
    p = _problem(11, 2)
    cfg = StopBundleConfig(
        range_sigma=0.005, rounds=1, reweight=0, max_nfev=1, hold_first_turn=hold_first_turn
    )
    adjust_stop_bundle(*_args(p), cfg)
    prob = made[0]
    # away from zero drift, where every coefficient's derivative is generic
    x = prob.x0 + np.random.default_rng(1).normal(0.0, 1e-3, prob.x0.size)
    jac = prob.jac(x).toarray()
    f0 = prob.fun(x)
    dense = np.zeros_like(jac)
    for j in range(x.size):  # a loop over the unknowns (tens)
        h = 1e-7 * max(1.0, abs(x[j]))
        step = np.zeros_like(x)
        step[j] = h
        dense[:, j] = (prob.fun(x + step) - f0) / h
    assert jac.shape == (f0.size, x.size) and np.any(dense[prob.rows["odometry"]] != 0.0)
    outside = (np.abs(dense) > 1e-6 * np.abs(dense).max()) & (jac == 0.0)
    assert not outside.any(), np.argwhere(outside)[:5]
    np.testing.assert_allclose(jac, dense, atol=1e-5 * np.abs(dense).max())


def test_the_odometry_leaves_from_the_turns_corrected_end(monkeypatch: pytest.MonkeyPatch) -> None:
    """At the true stop poses and drift coefficients the odometry residuals vanish: the
    drive leaves the last in-stop pose turned by the stop's end drift ``c_s[0]`` (the
    synthetic odometry is exact from the true end). Without the end drift they are
    ``c_s[0]`` over the odometry's heading sigma (half a sigma and more)."""
    made = _capture(monkeypatch)
    p = _problem(11, 2)
    adjust_stop_bundle(*_args(p), StopBundleConfig(range_sigma=0.005, rounds=1, max_nfev=1))
    prob = made[0]
    x = prob.x0.copy()
    x[: prob.n_pose] = p["stop_true"][1:].ravel()
    x[prob.n_pose : prob.n_pose + prob.n_coef] = p["c_true"].ravel()
    r_odo = prob.fun(x)[prob.rows["odometry"]]
    np.testing.assert_allclose(r_odo, 0.0, atol=1e-6)
    x[prob.n_pose : prob.n_pose + prob.n_coef] = 0.0
    assert np.max(np.abs(prob.fun(x)[prob.rows["odometry"]])) > 0.3  # the test can fail


def test_rotation_hold_is_anchored_to_the_input_poses_in_every_round(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The stops' mean heading change is held to the input stop poses (the graph's), not
    to each round's start: with a loose hold (0.05 degrees) against a start turned by half
    a degree, one round moves the mean by -0.085 degrees and three by -0.12 (the map and
    its association change between rounds); re-anchored at each round's start, three rounds
    walked to -0.26. The second round's hold starts where the first left it, off zero."""
    made = _capture(monkeypatch)
    p = _problem(11, 2)
    rot = np.radians(0.5)
    init = p["init"].copy()
    c, s = np.cos(rot), np.sin(rot)
    init[1:, :2] = init[1:, :2] @ np.array([[c, s], [-s, c]])
    init[1:, 2] += rot
    moved = []
    for rounds in (1, 3):
        cfg = StopBundleConfig(rotation_sigma=np.radians(0.05), range_sigma=0.005, rounds=rounds)
        res = adjust_stop_bundle(*_args(p, init), cfg)
        moved.append(np.degrees(np.mean(res.poses[1:, 2] - init[1:, 2])))
    assert moved[0] < -0.02  # the echo pairs pull against the hold
    assert abs(moved[1]) < 2.0 * abs(moved[0]), moved
    second = made[2]  # rounds=3's second problem
    r_rot = second.fun(second.x0)[second.rows["rotation"]]
    start = second.x0[: second.n_pose].reshape(-1, 3)[:, 2]
    np.testing.assert_allclose(r_rot, np.mean(start - init[1:, 2]) / np.radians(0.05))
    assert abs(r_rot[0]) > 0.1


def test_each_landmark_has_its_own_robust_scale() -> None:
    """A point scatterer whose pairs scatter by 3.5 cm gets a residual scale of centimetres,
    the walls keep about the range noise (5 mm), so a point's scatter does not widen the
    walls' weights (nor the walls' precision shrink the points')."""
    p = _problem(11, 2, point_sigma=0.035)
    res = adjust_stop_bundle(*_args(p), StopBundleConfig(range_sigma=0.005, rounds=1))
    walls, points = res.scales[res.kinds == WALL], res.scales[res.kinds == POINT]
    assert walls.size >= 3 and points.size >= 1, res.kinds
    # (corners the map takes for points keep millimetres too)
    assert np.all(walls < 0.01) and np.max(points) > 0.02, (walls, points)


def test_landmarks_need_min_landmark_stops() -> None:
    """No landmark is seen from more than the five stops: asking for six leaves nothing to
    adjust, and the input comes back."""
    p = _problem(11, 2)
    res = adjust_stop_bundle(*_args(p), StopBundleConfig(range_sigma=0.005, min_landmark_stops=6))
    assert res.n_pairs == 0 and res.kinds.size == 0
    np.testing.assert_array_equal(res.poses, p["init"])
    few = adjust_stop_bundle(*_args(p), StopBundleConfig(range_sigma=0.005, min_landmark_stops=4))
    assert 0 < few.n_pairs


def test_an_unconverged_solve_is_counted() -> None:
    p = _problem(11, 2)
    res = adjust_stop_bundle(*_args(p), StopBundleConfig(range_sigma=0.005, rounds=1, max_nfev=1))
    assert res.unconverged == 3  # the first solve and two reweighted ones
    res = adjust_stop_bundle(*_args(p), StopBundleConfig(range_sigma=0.005, rounds=1, reweight=0))
    assert res.unconverged == 0


def test_more_bad_input_gives_one_line_value_errors() -> None:
    p = _problem(11, 2)
    with pytest.raises(ValueError, match="reweight"):
        StopBundleConfig(reweight=-1)
    with pytest.raises(ValueError, match="hold_first_turn"):
        StopBundleConfig(hold_first_turn="no")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="at least one stop"):
        adjust_stop_bundle([], [], [], [], [], np.zeros((0, 3)), [], np.zeros((0, 2)), ANTENNAS)
    a = list(_args(p))
    with pytest.raises(ValueError, match="prior_sd"):
        adjust_stop_bundle(*a[:7], p["prior"][:, :1], ANTENNAS)
    with pytest.raises(ValueError, match="initial"):
        adjust_stop_bundle(*a, initial=np.zeros((5, 3)))
    with pytest.raises(ValueError, match="stop_poses"):
        adjust_stop_bundle(*a[:5], p["init"][:4], *a[6:])
    shifted = [(a_ + 1, b_ + 1) for a_, b_ in p["ranges"]]
    shifted[0] = (0, shifted[0][1])
    with pytest.raises(ValueError, match="stop 0"):
        adjust_stop_bundle(a[0], a[1], shifted, *a[3:])
