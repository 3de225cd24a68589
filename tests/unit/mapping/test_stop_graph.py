"""Stop graph: the path from stop-to-stop reflector registration and a pose graph (issue 8)."""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np
import pytest

from fusion_center.mapping.stop_graph import (
    GraphEdge,
    ReflectorRegistration,
    Registration,
    ScanLog,
    StopGraphConfig,
    StopGraphPathEstimator,
    StopPoseGraph,
    StopScan,
    _innovation,
    images_seen_from,
    median_drive_turn,
    pose_shift,
    predicted_images,
    refine_turns,
    relative_pose,
    scan_front_end,
    scan_log_from_pairs,
    segment_stops,
    stop_scan,
    turn_basis,
)
from fusion_center.mapping.synthetic import echo_pairs, rectangle_room, stop_and_turn_poses
from sim_nodes.robot_record import odometry_increments

# the robot recorder's array: Tx at the turning centre, a 1 m baseline
ANTENNAS = np.array([[0.0, 0.0], [0.0, 0.5], [0.0, -0.5]])
STOPS = np.array([[1.6, 1.4], [2.9, 1.7], [4.2, 2.6], [3.6, 3.7], [2.0, 3.3]])


def _recording(seed: int) -> tuple[ScanLog, np.ndarray]:
    """A stop-and-turn run in a 6 x 5 m room (four walls, four corners, two point
    scatterers): 357-degree turns in 3-degree steps at five stops, echo pairs with 5 mm of
    noise, the recorder's odometry slip. Returns the scan log and the true poses (world)."""
    rng = np.random.default_rng(seed)
    poses = stop_and_turn_poses(STOPS, 120, np.radians(3.0))
    poses[:, 2] += 0.3
    odo = odometry_increments(poses, rng)
    room = rectangle_room()
    pairs = [echo_pairs(room, p, ANTENNAS, rng, sigma=0.005, beam=np.radians(50.0)) for p in poses]
    t = np.arange(len(poses)) * 0.05
    return scan_log_from_pairs(t, odo, pairs), poses


def _in_first_frame(poses: np.ndarray) -> np.ndarray:
    return np.array([relative_pose(poses[0], p) for p in poses])


def _dead_reckoning(odo: np.ndarray) -> np.ndarray:
    out = np.zeros((len(odo), 3))
    for k in range(1, len(odo)):
        c, s = np.cos(out[k - 1, 2]), np.sin(out[k - 1, 2])
        d = odo[k]
        out[k] = out[k - 1] + [c * d[0] - s * d[1], s * d[0] + c * d[1], d[2]]
    return out


@pytest.fixture(scope="module")
def run() -> tuple[ScanLog, np.ndarray]:
    return _recording(3)


def test_segment_stops_splits_at_drives(run: tuple[ScanLog, np.ndarray]) -> None:
    log, _ = run
    segs = segment_stops(log.odometry)
    assert segs == [(120 * i, 120 * (i + 1)) for i in range(len(STOPS))]


def test_registration_recovers_the_relative_pose(run: tuple[ScanLog, np.ndarray]) -> None:
    """Stop 1 in stop 0's frame from their reflectors, from the odometry's prior, within
    3 cm and 0.7 degrees (the echoes' 5 mm noise at 1-9 m of image distance); the prior
    itself is off by more."""
    log, poses = run
    est = StopGraphPathEstimator(ANTENNAS)
    segs = segment_stops(log.odometry)
    from fusion_center.mapping.stop_graph import stop_scan

    a, b = (stop_scan(log, s, e, est.closer, est.config) for s, e in segs[:2])
    assert len(a.images) >= 3 and len(b.images) >= 3
    prior, cov = est.odometry_edge(log, a, b)
    truth = relative_pose(poses[segs[0][0]], poses[segs[1][0]])
    # a prior far enough off that an identity registration would fail the tolerance
    prior = prior + np.array([0.15, -0.1, np.radians(3.0)])
    cov = cov + np.diag([0.1**2, 0.1**2, np.radians(3.0) ** 2])
    reg = est.registration.register_both(a, b, prior, cov)
    assert reg.accepted, reg.reason
    err = reg.pose - truth
    assert np.hypot(err[0], err[1]) < 0.03
    # the stops' own in-stop heading errors (0.3 and 0.7 deg RMS against truth here) bound
    # the relative heading: 0.49 deg before the point-scatterer bias was modelled, 0.55 after
    assert abs(np.degrees(err[2])) < 0.7
    assert reg.explained > 0.5
    assert np.all(np.linalg.eigvalsh(reg.cov) > 0)


def test_graph_recovers_the_path(run: tuple[ScanLog, np.ndarray]) -> None:
    """Every acquisition within 5 cm and 1 degree (RMSE), several times better than
    dead reckoning; registrations between consecutive stops and at least one loop closure."""
    log, poses = run
    res = StopGraphPathEstimator(ANTENNAS).estimate(log)
    truth = _in_first_frame(poses)
    traj = res.trajectory
    assert traj.shape == (len(poses), 4)
    np.testing.assert_array_equal(traj[:, 0], log.t)
    pos = np.hypot(*(traj[:, 1:3] - truth[:, :2]).T)
    yaw = np.degrees((traj[:, 3] - truth[:, 2] + np.pi) % (2 * np.pi) - np.pi)
    rmse, yaw_rmse = np.sqrt(np.mean(pos**2)), np.sqrt(np.mean(yaw**2))
    dr = _dead_reckoning(log.odometry)
    dr_rmse = np.sqrt(np.mean(np.sum((dr[:, :2] - truth[:, :2]) ** 2, 1)))
    assert rmse < 0.025, (rmse, dr_rmse)
    assert yaw_rmse < 0.5
    assert rmse < dr_rmse / 2
    kinds = [e.kind for e in res.edges]
    assert kinds.count("scan") >= 3
    assert kinds.count("loop") >= 1
    # the registrations carry the result: without them (the turn closure and the odometry
    # alone; no refinement and no bundle adjustment, which find correspondences of their
    # own) the same run is at least twice as far off
    alone = StopGraphPathEstimator(
        ANTENNAS, StopGraphConfig(min_matched=1000, refine_turns=False, bundle_adjust=False)
    ).estimate(log)
    # and the pose graph alone (before the joint refinement) is within the same bounds
    graph_only = StopGraphPathEstimator(
        ANTENNAS, StopGraphConfig(refine_turns=False, bundle_adjust=False)
    )
    pos_g = np.hypot(*(graph_only.estimate(log).trajectory[:, 1:3] - truth[:, :2]).T)
    assert np.sqrt(np.mean(pos_g**2)) < 0.025
    pos0 = np.hypot(*(alone.trajectory[:, 1:3] - truth[:, :2]).T)
    assert rmse < 0.5 * np.sqrt(np.mean(pos0**2)), (rmse, np.sqrt(np.mean(pos0**2)))


def _scatterers(points: np.ndarray, pose: np.ndarray) -> StopScan:
    """A stop at ``pose`` (world) whose reflectors are point scatterers at ``points``
    (world): their images ``2 (p - t)`` in the stop's axes, 20 pairs each, 5 mm scatter."""
    c, s = np.cos(pose[2]), np.sin(pose[2])
    d = 2.0 * (points - pose[:2])
    img = np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]])
    n = len(img)
    return StopScan(
        start=0,
        end=1,
        poses=np.zeros((1, 3)),
        end_sigma=0.0,
        closed=True,
        on_the_spot=True,
        images=img,
        weights=np.full(n, 20.0),
        image_sigma=np.full(n, 0.005),
    )


def test_a_symmetric_scene_is_refused_as_ambiguous() -> None:
    """Sixteen scatterers on a circle around both stops: B turned by one period (22.5
    degrees) explains them as well as B at the truth, and the prior lies between the two:
    refused as ambiguous. The same with the points at random bearings is accepted at the
    true pose."""
    reg = ReflectorRegistration()
    truth = np.array([0.3, -0.2, 0.0])
    prior = truth + np.array([0.02, 0.01, np.radians(11.25)])
    cov = np.diag([0.1**2, 0.1**2, np.radians(10.0) ** 2])
    ang = np.radians(22.5) * np.arange(16)
    ring = np.column_stack([2.5 * np.cos(ang), 2.5 * np.sin(ang)]) + truth[:2]
    amb = reg.register_both(_scatterers(ring, np.zeros(3)), _scatterers(ring, truth), prior, cov)
    assert not amb.accepted
    assert "ambiguous" in amb.reason
    rng = np.random.default_rng(5)
    ang = rng.uniform(0, 2 * np.pi, 16)
    pts = np.column_stack([2.5 * np.cos(ang), 2.5 * np.sin(ang)]) + truth[:2]
    ok = reg.register_both(_scatterers(pts, np.zeros(3)), _scatterers(pts, truth), prior, cov)
    assert ok.accepted, ok.reason
    assert np.hypot(*(ok.pose[:2] - truth[:2])) < 0.01
    assert abs(ok.pose[2] - truth[2]) < np.radians(0.1)


def test_predicted_images_follow_fig19() -> None:
    """A wall seen from A at 2 m along +x, from B 0.5 m closer and turned 90 degrees: its
    image is 3 m away along B's -y; a point at (2, 1) has the image 2 (p - t) in B's axes."""
    a_images = np.array([[4.0, 0.0], [4.0, 2.0]])
    b = np.array([0.5, 0.0, np.pi / 2])
    pred = predicted_images(a_images, b)[0]
    np.testing.assert_allclose(pred[0], [0.0, -3.0], atol=1e-12)
    p_rel = 2.0 * (np.array([2.0, 1.0]) - b[:2])
    np.testing.assert_allclose(pred[3], [p_rel[1], -p_rel[0]], atol=1e-12)


def test_pose_graph_keeps_the_path_against_a_wrong_match() -> None:
    """Four stops on a square; noisy odometry edges, exact registrations between
    consecutive stops, and one wrong loop closure 0.5 m off: the robust graph keeps every
    stop within 2 cm (a plain least-squares solve would be bent by decimetres)."""
    rng = np.random.default_rng(2)
    truth = np.array([[0, 0, 0], [2, 0, np.pi / 2], [2, 2, np.pi], [0, 2, -np.pi / 2]], float)
    graph = StopPoseGraph(4)
    odo_cov = np.diag([0.05**2, 0.05**2, np.radians(2.0) ** 2])
    reg_cov = np.diag([0.01**2, 0.01**2, np.radians(0.2) ** 2])
    for i in range(3):
        z = relative_pose(truth[i], truth[i + 1])
        noisy = z + rng.normal(0, np.sqrt(np.diag(odo_cov)))
        graph.add(GraphEdge(i=i, j=i + 1, z=noisy, cov=odo_cov, robust=False))
        graph.add(GraphEdge(i=i, j=i + 1, z=z, cov=reg_cov, robust=True, kind="scan"))
    wrong = relative_pose(truth[0], truth[3]) + np.array([0.5, 0.0, 0.0])
    graph.add(GraphEdge(i=0, j=3, z=wrong, cov=reg_cov, robust=True, kind="loop"))
    # the initial estimate: the chain of the consecutive matches plus noise
    init = truth + rng.normal(0.0, [0.02, 0.02, np.radians(0.5)], truth.shape)
    init[0] = truth[0]
    poses, weights = graph.solve(init)
    assert np.max(np.hypot(*(poses[:, :2] - truth[:, :2]).T)) < 0.02
    assert weights[-1] < 0.01


def test_pose_graph_across_pi_and_its_covariance() -> None:
    """Two stops joined by two edges whose headings lie 0.02 rad apart across +-pi: the
    solve wraps the heading residual (the answer is their mean, not a heading near 0), and
    the marginal covariance of stop 1 is half the edges' covariance; the relative covariance
    of the pair is the same."""
    from fusion_center.mapping.stop_graph import relative_covariance

    z = np.array([1.0, 0.5, np.pi - 0.01])
    cov = np.array([[4e-4, 1e-4, 0.0], [1e-4, 9e-4, 2e-5], [0.0, 2e-5, 1e-4]])
    graph = StopPoseGraph(2)
    graph.add(GraphEdge(i=0, j=1, z=z, cov=cov, robust=False))
    # the same heading 0.02 rad further, written across the cut
    graph.add(
        GraphEdge(i=0, j=1, z=z + np.array([0.0, 0.0, 0.02 - 2 * np.pi]), cov=cov, robust=False)
    )
    init = np.array([[0.0, 0.0, 0.0], [1.1, 0.4, -np.pi + 0.05]])
    poses, _ = graph.solve(init)
    d = relative_pose(poses[0], poses[1]) - (z + np.array([0.0, 0.0, 0.01]))
    d[2] = (d[2] + np.pi) % (2 * np.pi) - np.pi
    np.testing.assert_allclose(d, 0.0, atol=1e-6)
    joint = graph.covariance(poses, np.ones(2))
    np.testing.assert_allclose(joint, cov / 2, rtol=1e-4, atol=1e-10)
    rel = relative_covariance(poses, joint, 0, 1)
    np.testing.assert_allclose(rel, cov / 2, rtol=1e-4, atol=1e-10)


def test_inverse_jacobian_and_relative_covariance_against_finite_differences() -> None:
    """``_inverse_jacobian`` is the derivative of the inverse pose; the relative covariance of
    two stops is the first-order propagation of their joint covariance."""
    from fusion_center.mapping.stop_graph import _inverse_jacobian, relative_covariance

    pose = np.array([1.3, -0.7, 2.2])
    jac = _inverse_jacobian(pose)
    num = np.empty((3, 3))
    for k in range(3):
        dq = np.zeros(3)
        dq[k] = 1e-6
        num[:, k] = (
            relative_pose(pose + dq, np.zeros(3)) - relative_pose(pose, np.zeros(3))
        ) / 1e-6
    np.testing.assert_allclose(jac, num, atol=1e-5)
    rng = np.random.default_rng(1)
    poses = np.array([[0.0, 0.0, 0.0], [1.0, 0.2, 0.3], [2.0, 1.0, 1.2]])
    a = rng.normal(size=(6, 6))
    joint = a @ a.T * 1e-4
    cov = relative_covariance(poses, joint, 1, 2)
    # Monte Carlo of the relative pose of stop 2 in stop 1
    draws = rng.multivariate_normal(np.zeros(6), joint, 40000)
    rel = np.array(
        [relative_pose(poses[1] + d[:3], poses[2] + d[3:]) for d in draws]
    ) - relative_pose(poses[1], poses[2])
    np.testing.assert_allclose(cov, np.cov(rel.T), rtol=0.05, atol=2e-6)


def test_predicted_wall_seen_from_behind_is_nan() -> None:
    """A wall 1 m ahead of A (image (2, 0)) is seen from behind by a stop 1.5 m ahead: its
    wall hypothesis is NaN, its point hypothesis is not."""
    pred = predicted_images(np.array([[2.0, 0.0]]), np.array([1.5, 0.0, 0.0]))[0]
    assert np.all(np.isnan(pred[0]))
    assert np.all(np.isfinite(pred[1]))


def _two_scatter_stops():
    """Two stops seeing the same 8 point scatterers (1 cm of image noise on the second), the
    true relative pose and a prior covariance of 5 cm / 2 deg."""
    rng = np.random.default_rng(4)
    points = rng.uniform([0.0, 0.0], [6.0, 5.0], (8, 2))
    pa, pb = np.array([2.0, 2.0, 0.3]), np.array([3.0, 2.4, 0.6])
    a, b = _scatterers(points, pa), _scatterers(points, pb)
    b = replace(b, images=b.images + rng.normal(0.0, 0.01, b.images.shape))
    cov = np.diag([0.05**2, 0.05**2, np.radians(2.0) ** 2])
    return a, b, relative_pose(pa, pb), cov


def test_register_both_refuses_an_inconsistent_pair() -> None:
    """With ``consistency`` tighter than the two directions can agree, a good pair is
    refused as inconsistent; at the default it is accepted."""
    a, b, z, cov = _two_scatter_stops()
    assert ReflectorRegistration().register_both(a, b, z, cov).accepted
    tight = ReflectorRegistration(StopGraphConfig(consistency=(1e-6, 1e-8)))
    reg = tight.register_both(a, b, z, cov)
    assert not reg.accepted and reg.reason == "inconsistent"


def test_bad_input_gives_one_line_value_errors() -> None:
    with pytest.raises(ValueError, match=r"^StopGraphConfig.fine_sigma must be > 0"):
        StopGraphConfig(fine_sigma=-1.0)
    with pytest.raises(ValueError, match=r"^StopGraphConfig.window must be two numbers"):
        StopGraphConfig(window=(0.5,))
    with pytest.raises(ValueError, match=r"^antennas must be 3 finite"):
        StopGraphPathEstimator(np.zeros((2, 2)))
    with pytest.raises(ValueError, match=r"^odometry must be 2 finite"):
        scan_log_from_pairs([0.0, 1.0], np.zeros((2, 2)), [np.zeros((0, 2))] * 2)
    with pytest.raises(ValueError, match=r"^pairs of acquisition 1 must have shape"):
        scan_log_from_pairs([0.0, 1.0], np.zeros((2, 3)), [np.zeros((0, 2)), np.zeros(3)])
    with pytest.raises(ValueError, match=r"^no acquisitions"):
        StopGraphPathEstimator(ANTENNAS).estimate(scan_log_from_pairs([], np.zeros((0, 3)), []))
    frames = [(0.0, np.zeros((2, 64), np.float32), None)]
    with pytest.raises(ValueError, match=r"has no odometry"):
        scan_front_end(frames, fs=1e9, t0=0.0, bandwidth=5e8)
    with pytest.raises(ValueError, match=r"^a pose graph needs at least one stop"):
        StopPoseGraph(0)
    with pytest.raises(ValueError, match=r"^StopGraphConfig.closure_link_scatter must be > 0"):
        StopGraphConfig(closure_link_scatter=float("nan"))
    with pytest.raises(ValueError, match=r"^StopGraphConfig.bundle_max_shift must be > 0"):
        StopGraphConfig(bundle_max_shift=0.0)
    # a float, a string or a list (unhashable in the frozen config) is refused in one line
    for bad in ((1.0, -1.0), 1.0, ("a",), [1.0]):
        with pytest.raises(ValueError, match=r"^StopGraphConfig.loop_defer must be a tuple"):
            StopGraphConfig(loop_defer=bad)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"^StopGraphConfig.drive_loop_defer must be a tuple"):
        StopGraphConfig(drive_loop_defer=(0.0,))
    with pytest.raises(ValueError, match=r"^StopGraphConfig.drive_loop_gate must be > 0"):
        StopGraphConfig(drive_loop_gate=0.0)
    with pytest.raises(ValueError, match=r"^StopGraphConfig.drive_turn must be >= 0"):
        StopGraphConfig(drive_turn=float("nan"))
    with pytest.raises(ValueError, match=r"^StopGraphConfig.loop_gate must be > 0"):
        StopGraphConfig(loop_gate=float("nan"))
    for msg in (
        str(_catch(lambda: StopGraphConfig(min_matched=0))),
        str(_catch(lambda: StopGraphConfig(min_explained=2.0))),
    ):
        assert "\n" not in msg and msg


def _catch(f: object) -> Exception:
    try:
        f()  # type: ignore[operator]
    except ValueError as exc:
        return exc
    raise AssertionError("no ValueError")


def test_refine_turns_recovers_the_in_stop_heading_drift() -> None:
    """Four stops see twelve scatterers, each at its own phase of the turn; every stop's
    in-stop headings carry a drift ``turn_basis(f) @ c`` (about a degree) that rotates its
    images and its odometry edge's end heading. The joint refinement over the
    correspondences recovers each drift within 0.3 degrees (the images' 5 mm noise) and the
    stop headings within 0.2 degrees, where the uncorrected errors are several times larger."""
    rng = np.random.default_rng(5)
    points = rng.uniform([0.5, 0.5], [5.5, 4.5], (12, 2))
    world = np.array([[1.5, 1.5, 0.2], [3.5, 1.8, 0.5], [4.0, 3.2, 1.4], [2.0, 3.0, 2.8]])
    c_true = np.radians([[0.0, 0.0], [1.2, -0.6], [-1.0, 0.8], [0.7, 0.5]])
    turn = np.column_stack([np.zeros((120, 2)), np.linspace(0.0, np.radians(357.0), 120)])
    stops = []
    for k, pose in enumerate(world):
        st = _scatterers(points, pose)
        phase = rng.uniform(0.0, 1.0, len(points))
        basis = turn_basis(phase)
        # the images as the drifting headings put them: rotated by -drift (the correction
        # +drift restores them), with the echoes' noise
        ang = -(basis @ c_true[k])
        c, s = np.cos(ang), np.sin(ang)
        img = np.column_stack(
            [c * st.images[:, 0] - s * st.images[:, 1], s * st.images[:, 0] + c * st.images[:, 1]]
        )
        img += rng.normal(0.0, 0.005, img.shape)
        stops.append(
            replace(
                st,
                images=img,
                poses=turn,
                end_sigma=np.radians(2.0),
                closed=False,
                turn_basis=basis,
                phase=np.linspace(0.0, 1.0, 120),
            )
        )
    edges, odo = [], []
    for i in range(len(world)):
        for j in range(i + 1, len(world)):
            z = relative_pose(world[i], world[j])
            cov = np.diag([0.02**2, 0.02**2, np.radians(1.0) ** 2])
            edges.append(GraphEdge(i=i, j=j, z=z, cov=cov, robust=True, kind="scan"))
    for i in range(len(world) - 1):
        z = relative_pose(world[i], world[i + 1])
        d = -c_true[i, 0]  # the turn's end heading error turns the drive
        cz, sz = np.cos(d), np.sin(d)
        z_obs = np.array([cz * z[0] - sz * z[1], sz * z[0] + cz * z[1], z[2] + d])
        odo.append((z_obs, np.diag([0.05**2, 0.05**2, np.radians(0.3) ** 2])))
    # the graph's estimate: the true poses off by a degree and a few cm
    init = np.array([relative_pose(world[0], p) for p in world])
    init[1:] += rng.normal(0.0, [0.03, 0.03, np.radians(1.0)], (len(world) - 1, 3))
    truth = np.array([relative_pose(world[0], p) for p in world])
    # the registrations' correspondences only, then, without registrations, those of every
    # stop pair within 3 m found at the (erroneous) initial estimate
    # (fewer correspondences fall within the gate at the estimate: wider tolerances)
    for dist, reg, tol in ((0.0, edges, (0.3, 0.4, 0.2)), (3.0, [], (0.45, 0.5, 0.35))):
        cfg = StopGraphConfig(refine_min_matches=4, refine_distance=dist)
        poses, coef, cw = refine_turns(stops, reg, np.ones(len(reg)), init, odo, cfg)
        err_c = np.degrees(np.abs(coef - c_true))
        assert np.all(err_c[:, 0] < tol[0]), (dist, np.degrees(coef))
        assert np.all(err_c[:, 1] < tol[1]), (dist, np.degrees(coef))
        yaw = np.degrees(np.abs((poses[:, 2] - truth[:, 2] + np.pi) % (2 * np.pi) - np.pi))
        assert np.all(yaw < tol[2]), (dist, yaw)
        assert np.all(np.hypot(*(poses[:, :2] - truth[:, :2]).T) < 0.02)
        assert np.all(cw > 0.5)
        if dist == 0.0:
            assert cw.shape == (len(edges) * len(points),)


def test_refine_turns_leaves_stops_with_few_correspondences() -> None:
    """A stop with fewer correspondences than ``refine_min_matches`` keeps its turn (zero
    coefficients); with none anywhere the poses come back unchanged."""
    st = _scatterers(np.array([[1.0, 1.0], [2.0, 0.5]]), np.zeros(3))
    st = replace(st, turn_basis=turn_basis([0.2, 0.7]))
    b = _scatterers(np.array([[1.0, 1.0], [2.0, 0.5]]), np.array([0.3, 0.0, 0.1]))
    b = replace(b, turn_basis=turn_basis([0.4, 0.9]))
    z = np.array([0.3, 0.0, 0.1])
    edge = GraphEdge(i=0, j=1, z=z, cov=np.eye(3) * 1e-4, robust=True, kind="scan")
    init = np.array([[0.0, 0.0, 0.0], [0.31, 0.01, 0.1]])
    odo = [(z, np.eye(3) * 1e-2)]
    poses, coef, _ = refine_turns([st, b], [edge], np.ones(1), init, odo, StopGraphConfig())
    np.testing.assert_array_equal(coef, 0.0)
    np.testing.assert_array_equal(poses, init)


def test_a_drive_sampled_in_several_steps_still_separates_the_stops() -> None:
    """The stop-and-turn run with every drive sampled in four steps (each shorter than
    ``drive_reset``): the three intermediate acquisitions become segments of their own,
    the stops keep their 120 acquisitions, get reflectors and registrations, and the path
    is as good as with one-step drives."""
    rng = np.random.default_rng(3)
    turns = stop_and_turn_poses(STOPS, 120, np.radians(3.0))
    turns[:, 2] += 0.3
    rows = [turns[:120]]
    for k in range(1, len(STOPS)):
        last, nxt = turns[120 * k - 1], turns[120 * k]
        f = np.array([0.25, 0.5, 0.75])[:, None]
        drive = np.column_stack([last[:2] + f * (nxt[:2] - last[:2]), np.full(3, last[2])])
        rows += [drive, turns[120 * k : 120 * (k + 1)]]
    poses = np.vstack(rows)
    odo = odometry_increments(poses, rng)
    room = rectangle_room()
    pairs = [echo_pairs(room, p, ANTENNAS, rng, sigma=0.005, beam=np.radians(50.0)) for p in poses]
    log = scan_log_from_pairs(np.arange(len(poses)) * 0.05, odo, pairs)
    assert np.all(np.hypot(odo[:, 0], odo[:, 1]) < 0.5)  # no single step is the whole drive
    segs = segment_stops(log.odometry)
    long = [(a, b) for a, b in segs if b - a > 1]
    assert [b - a for a, b in long] == [120] * len(STOPS)
    res = StopGraphPathEstimator(ANTENNAS).estimate(log)
    assert res.n_registered >= 3
    truth = _in_first_frame(poses)
    pos = np.hypot(*(res.trajectory[:, 1:3] - truth[:, :2]).T)
    assert np.sqrt(np.mean(pos**2)) < 0.025


def test_a_robot_that_never_stops_is_cheap_and_flagged() -> None:
    """400 acquisitions 0.2 m apart round a 2 x 2 m loop (no turn on the spot): no stop
    gets reflectors, no registration is tried, ``n_registered`` is 0 and the path is the
    odometry's; in well under a second of work per hundred acquisitions."""
    import time

    rng = np.random.default_rng(0)
    s = np.arange(400) * 0.2 % 8.0
    side = (s // 2.0).astype(int)
    u = s % 2.0
    corners = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0]])
    dirs = np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]])
    xy = corners[side] + u[:, None] * dirs[side] + 1.5
    poses = np.column_stack([xy, np.arctan2(dirs[side, 1], dirs[side, 0])])
    odo = odometry_increments(poses, rng)
    room = rectangle_room()
    pairs = [echo_pairs(room, p, ANTENNAS, rng, sigma=0.005) for p in poses]
    log = scan_log_from_pairs(np.arange(len(poses)) * 0.05, odo, pairs)
    c0 = time.process_time()
    res = StopGraphPathEstimator(ANTENNAS).estimate(log)
    assert time.process_time() - c0 < 4.0
    assert res.registrations == [] and res.n_registered == 0
    dr = _dead_reckoning(log.odometry)
    np.testing.assert_allclose(res.trajectory[:, 1:3], dr[:, :2], atol=1e-6)
    dyaw = (res.trajectory[:, 3] - dr[:, 2] + np.pi) % (2 * np.pi) - np.pi
    np.testing.assert_allclose(dyaw, 0.0, atol=1e-6)


def test_heading_rms_of_closed_stops_matches_their_in_stop_heading_error(
    run: tuple[ScanLog, np.ndarray],
) -> None:
    """Review M1: over the closed stops of the synthetic run, the claimed in-stop heading
    noise (:attr:`StopScan.heading_rms`, the closure's own marginal) is within a factor of
    1.5 of the RMS in-stop heading error against truth (``end_sigma / sqrt(6)`` was 3 times
    too small)."""
    log, poses = run
    est = StopGraphPathEstimator(ANTENNAS, StopGraphConfig(closure_marginal=True))
    err, claimed = [], []
    for s, e in segment_stops(log.odometry):
        st = stop_scan(log, s, e, est.closer, est.config)
        assert st.closed
        err.append(st.poses[:, 2] - (poses[s:e, 2] - poses[s, 2]))
        claimed.append(st.heading_rms)
    actual = np.sqrt(np.mean(np.concatenate(err) ** 2))
    rms = np.sqrt(np.mean(np.square(claimed)))
    assert actual / 1.5 < rms < actual * 1.5, (np.degrees(actual), np.degrees(rms))


def test_registration_covariance_does_not_shrink_with_the_pair_count() -> None:
    """Review M2: a reflector's model mismatch and heading noise are common to its pairs, so
    a hundred times more pairs behind the same reflectors (same 5 mm scatter) must not make
    the registration a hundred or ten times more certain."""
    a, b, z, cov = _two_scatter_stops()
    cfg = StopGraphConfig(edge_sigma_floor=(1e-6, 1e-8), pair_count_weight=False)
    reg = ReflectorRegistration(cfg)
    few = reg.register(a, b, z, cov)
    many = reg.register(
        replace(a, weights=a.weights * 100), replace(b, weights=b.weights * 100), z, cov
    )
    assert few.accepted and many.accepted
    ratio = np.trace(few.cov[:2, :2]) / np.trace(many.cov[:2, :2])
    assert ratio < 1.5, ratio


def test_point_bias_predicts_a_point_scatterers_image() -> None:
    """Review M4: a point scatterer's image from the exact ellipse ranges
    (:func:`~fusion_center.mapping.models.invert_image`) at two stops, each facing it on
    its array's axis: with ``point_bias = |rx|^2`` the predicted image is within 3 mm of
    B's; without it off by more than 1 cm."""
    from fusion_center.mapping.models import invert_image

    rx = ANTENNAS[1:] - ANTENNAS[0]
    p = np.array([4.0, 1.0])

    def image(pose: np.ndarray) -> np.ndarray:
        c, s = np.cos(pose[2]), np.sin(pose[2])
        rot = np.array([[c, -s], [s, c]])
        rng_ = [np.linalg.norm(p - pose[:2]) + np.linalg.norm(p - pose[:2] - rot @ r) for r in rx]
        return rot @ invert_image(np.array([rng_]), rx)[0]  # stop frame = pose's axes

    pa = np.array([2.5, 1.0, 0.0])
    pb = np.array([1.0, 1.0 + 3.0 * np.tan(0.0), 0.0])
    ia, ib = image(pa), image(pb)
    z = relative_pose(pa, pb)
    kappa = float(np.mean(np.sum(rx**2, 1)))
    exact = predicted_images(ia[None], z, kappa)[0]
    plain = predicted_images(ia[None], z)[0]
    assert exact.shape == (3, 2) and plain.shape == (2, 2)
    assert np.linalg.norm(exact[2] - ib) < 0.003, exact[2] - ib
    assert np.linalg.norm(plain[1] - ib) > 0.01, plain[1] - ib


def test_images_seen_from_is_predicted_images_one_hypothesis_at_a_time() -> None:
    """One image prediction for the registration and the refinement: ``images_seen_from``
    per reflector and pose gives ``predicted_images``' blocks (rotated into B's frame), with
    a wall seen from behind NaN in both."""
    rng = np.random.default_rng(4)
    images = rng.normal(0.0, 2.0, (6, 2))
    pose = np.array([0.4, -0.3, 0.7])
    pred = predicted_images(images, pose, 0.18)[0]
    wall, point, scat = images_seen_from(images, np.broadcast_to(pose[:2], (6, 2)), 0.18)
    c, s = np.cos(pose[2]), np.sin(pose[2])
    rot = np.array([[c, s], [-s, c]])
    np.testing.assert_allclose(pred, np.vstack([wall, point, scat]) @ rot.T)
    behind = images_seen_from(np.array([[2.0, 0.0]]), np.array([[1.5, 0.0]]))[0]
    assert np.all(np.isnan(behind))
    assert images_seen_from(images, np.zeros((6, 2)))[2] is None


def test_the_link_scatter_reaches_the_turn_closer() -> None:
    """``closure_link_scatter`` is the stops' closer's ``link_scatter`` (off by default)."""
    assert not np.isfinite(StopGraphPathEstimator(ANTENNAS).closer.config.link_scatter)
    est = StopGraphPathEstimator(ANTENNAS, StopGraphConfig(closure_link_scatter=0.1))
    assert est.closer.config.link_scatter == 0.1


def _walls(lines: np.ndarray, pose: np.ndarray, phase: np.ndarray) -> StopScan:
    """A stop at ``pose`` (world) whose reflectors are the walls ``n . x = d`` of ``lines``
    (normal angle, d; world): their images ``2 (d - n . t) n`` in the stop's axes."""
    n = np.column_stack([np.cos(lines[:, 0]), np.sin(lines[:, 0])])
    img = 2.0 * (lines[:, 1] - n @ pose[:2])[:, None] * n
    c, s = np.cos(pose[2]), np.sin(pose[2])
    img = np.column_stack([c * img[:, 0] + s * img[:, 1], -s * img[:, 0] + c * img[:, 1]])
    k = len(img)
    return StopScan(
        start=0,
        end=1,
        poses=np.zeros((1, 3)),
        end_sigma=np.radians(1.0),
        closed=True,
        on_the_spot=True,
        images=img,
        weights=np.full(k, 20.0),
        image_sigma=np.full(k, 0.005),
        turn_basis=turn_basis(phase),
    )


def test_refine_turns_residual_is_smooth_where_a_wall_passes_behind_b(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """B stands 7 cm before a wall of A (its correspondence is formed: in front by more than
    the 5 cm guard). The refinement's residuals are linear in B's position along the wall's
    normal (walls' images ``2 (d - n . t) n``, heading fixed), also where the wall passes
    within 5 cm and behind B: no residual jumps to 0 there (the cost stays continuous for
    the forward differences), none turns NaN."""
    import fusion_center.mapping.stop_graph as sg

    angles = np.radians(np.arange(0.0, 360.0, 40.0))
    lines = np.column_stack([angles, 2.0 + 0.1 * np.arange(angles.size)])
    lines[0, 1] = 1.0  # the wall x = 1
    pb = np.array([0.93, 0.3, 0.0])
    a = _walls(lines, np.zeros(3), np.linspace(0.1, 0.9, len(lines)))
    b = _walls(lines, pb, np.linspace(0.9, 0.1, len(lines)))
    seen = []
    solve = sg.least_squares

    def spy(fun, x0, **kw):  # type: ignore[no-untyped-def]
        seen.append((fun, x0.copy()))
        return solve(fun, x0, **kw)

    monkeypatch.setattr(sg, "least_squares", spy)
    odo = [(pb, np.eye(3) * 1e-4)]
    refine_turns([a, b], [], np.zeros(0), np.vstack([np.zeros(3), pb]), odo, StopGraphConfig())
    fun, x0 = seen[0]
    assert x0.size == 3 + 4  # B's pose, two coefficients per stop
    r = []
    for x in np.linspace(0.93, 0.98, 11):  # the wall's distance from B: 7 -> 2 cm
        xx = x0.copy()
        xx[0] = x
        r.append(fun(xx))
    r = np.array(r)
    assert np.all(np.isfinite(r))
    moved = np.abs(r[-1] - r[0]) > 1e-3
    assert moved[: 2 * 2 * len(lines)].any()  # the correspondences see B move
    np.testing.assert_allclose(np.diff(r, 2, axis=0), 0.0, atol=1e-8 * np.abs(r).max())


def test_refine_turns_does_not_hide_a_nan() -> None:
    """A NaN in a matched reflector's scatter reaches the residuals and stops the solve with
    a ValueError (least_squares': residuals not finite), not a residual silently set to 0."""
    angles = np.radians(np.arange(0.0, 360.0, 40.0))
    lines = np.column_stack([angles, 2.0 + 0.1 * np.arange(angles.size)])
    pb = np.array([0.5, 0.3, 0.0])
    a = _walls(lines, np.zeros(3), np.linspace(0.1, 0.9, len(lines)))
    a = replace(a, image_sigma=np.r_[np.nan, a.image_sigma[1:]])
    b = _walls(lines, pb, np.linspace(0.9, 0.1, len(lines)))
    odo = [(pb, np.eye(3) * 1e-4)]
    with pytest.raises(ValueError, match="finite"):
        refine_turns([a, b], [], np.zeros(0), np.vstack([np.zeros(3), pb]), odo, StopGraphConfig())


def test_pose_shift_is_the_rms_mahalanobis_distance_of_the_stops() -> None:
    """Stop 1 moved by 2 sigma in x, stop 2 by 1 sigma in yaw (across +-pi), stop 0 (the
    gauge) ignored: RMS of 2 and 1."""
    before = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, np.pi - 0.01]])
    sd = np.array([0.1, 0.2, 0.05, 0.3, 0.3, 0.02])
    cov = np.diag(sd**2)
    cov[0, 1] = cov[1, 0] = 0.5 * sd[0] * sd[1]  # a correlation within a stop's block
    cov[0, 3] = cov[3, 0] = 0.9 * sd[0] * sd[3]  # and across stops: not used
    after = before.copy()
    after[0] += [5.0, 5.0, 1.0]
    # 2 sigma along x of a correlated block: d' C^-1 d = 4 / (1 - 0.5^2) for d = (0.2, 0, 0)
    after[1, 0] += 0.2
    after[2, 2] = -np.pi + 0.01  # 0.02 rad = 1 sigma, wrapped
    m2 = np.array([4.0 / (1 - 0.25), 1.0])
    assert pose_shift(before, after, cov) == pytest.approx(np.sqrt(m2.mean()))
    assert pose_shift(before[:1], after[:1], np.zeros((0, 0))) == 0.0


def test_bundle_max_shift_drops_a_bundle_adjustment_that_moves_the_graph(
    run: tuple[ScanLog, np.ndarray],
) -> None:
    """The bundle adjustment's shift is reported; a guard below it keeps the refinement's
    poses (the result of ``bundle_adjust=False``), one above it the bundle adjustment's."""
    log, _ = run
    kept = StopGraphPathEstimator(ANTENNAS, StopGraphConfig(bundle_max_shift=np.inf)).estimate(log)
    assert kept.bundle_shift is not None and 0.0 < kept.bundle_shift < np.inf
    # the default guard leaves this clean run's adjustment alone
    assert kept.bundle_shift < StopGraphConfig().bundle_max_shift
    assert not kept.bundle_dropped
    no_ba = StopGraphPathEstimator(ANTENNAS, StopGraphConfig(bundle_adjust=False)).estimate(log)
    assert no_ba.bundle_shift is None
    assert not np.allclose(kept.trajectory, no_ba.trajectory)
    low = StopGraphConfig(bundle_max_shift=0.5 * kept.bundle_shift)
    dropped = StopGraphPathEstimator(ANTENNAS, low).estimate(log)
    assert dropped.bundle_dropped
    assert dropped.bundle_shift == pytest.approx(kept.bundle_shift)
    np.testing.assert_allclose(dropped.trajectory, no_ba.trajectory)
    high = StopGraphConfig(bundle_max_shift=2.0 * kept.bundle_shift)
    np.testing.assert_allclose(
        StopGraphPathEstimator(ANTENNAS, high).estimate(log).trajectory, kept.trajectory
    )


def test_a_bundle_adjustment_that_returns_nan_poses_is_dropped(
    run: tuple[ScanLog, np.ndarray],
) -> None:
    """A non-finite adjustment has a NaN shift, which no limit admits: the refined poses
    stand (NaN > limit is False, so a plain comparison kept NaN poses)."""
    log, _ = run
    no_ba = StopGraphPathEstimator(ANTENNAS, StopGraphConfig(bundle_adjust=False)).estimate(log)
    est = StopGraphPathEstimator(ANTENNAS, StopGraphConfig(bundle_max_shift=np.inf))
    real = est._bundle_adjust

    def broken(*args: object) -> tuple[np.ndarray, np.ndarray, int]:
        poses, coef, unconverged = real(*args)
        return np.full_like(poses, np.nan), coef, unconverged

    est._bundle_adjust = broken  # type: ignore[method-assign]
    res = est.estimate(log)
    assert res.bundle_dropped and np.isnan(res.bundle_shift)
    assert np.isfinite(res.trajectory).all()
    np.testing.assert_allclose(res.trajectory, no_ba.trajectory)


def test_loop_defer_searches_the_narrow_priors_first(run: tuple[ScanLog, np.ndarray]) -> None:
    """A registration whose prior reaches beyond its search window at 1 sigma returns a
    wrong match (0.3 m off; a capped search holds some local match), otherwise the truth.
    With stops 1-2 and 2-3 joined by odometry alone, every loop prior crosses a drive; the
    default search takes the wide ones at once and bends the graph by centimetres, the
    deferred one closes 0-2 first and then finds every other loop within the window."""
    log, poses = run
    segs = segment_stops(log.odometry)
    truth = np.array([poses[s] for s, _ in segs])
    index = {s: k for k, (s, _) in enumerate(segs)}
    window = (0.05, np.radians(3.0))

    def solve(defer: tuple[float, ...], **kw: Any) -> tuple[np.ndarray, list[float]]:
        cfg = StopGraphConfig(
            refine_turns=False,
            bundle_adjust=False,
            loop_window=(0.005, np.radians(0.1)),
            window=window,
            loop_defer=defer,
            **{"drive_turn": np.inf, **kw},
        )
        est = StopGraphPathEstimator(ANTENNAS, cfg)
        widths: list[float] = []

        def fake(a: StopScan, b: StopScan, prior: np.ndarray, cov: np.ndarray) -> Registration:
            i, j = index[a.start], index[b.start]
            z = relative_pose(truth[i], truth[j])
            sd = np.sqrt(np.diag(cov))
            if j == i + 1 and i in (1, 2):
                return Registration(
                    pose=prior, cov=cov, explained=0.0, matched=0, accepted=False, reason="x"
                )
            if j > i + 1:
                widths.append(float(max(sd[0] / window[0], sd[1] / window[0], sd[2] / window[1])))
            if max(sd[:2]) > window[0] or sd[2] > window[1]:
                z = z + np.array([0.3, 0.0, 0.0])
            tight = np.diag([1e-4, 1e-4, 1e-6])
            return Registration(pose=z, cov=tight, explained=1.0, matched=5, accepted=True)

        est.registration.register_both = fake  # type: ignore[method-assign]
        res = est.estimate(log)
        err = np.hypot(*(res.stop_poses[:, :2] - _in_first_frame(truth)[:, :2]).T)
        return err, widths

    err0, widths0 = solve(())
    err1, widths1 = solve((1.0,))
    assert max(widths0) > 1.0 and err0.max() > 0.05
    assert len(widths1) == len(widths0)  # the same candidates, tried later
    assert max(widths1) <= 1.0 and err1.max() < 0.01
    # a robot that turns with its drives takes drive_loop_defer in place of loop_defer
    turn = median_drive_turn(log.odometry)
    assert turn > 0.0
    on = {"drive_loop_defer": (1.0,), "drive_loop_gate": np.inf}
    err2, widths2 = solve((), drive_turn=0.5 * turn, **on)
    np.testing.assert_allclose(err2, err1, atol=1e-9)
    assert widths2 == widths1
    err3, _ = solve((), drive_turn=2.0 * turn, **on)
    np.testing.assert_allclose(err3, err0, atol=1e-9)


def test_the_drive_turn_is_the_median_net_turn_between_stops(
    run: tuple[ScanLog, np.ndarray],
) -> None:
    """Each drive's yaw between two stops (segments of more than one acquisition) is summed
    over its steps and wrapped; turns on the spot do not count."""
    spot = np.array([[0.0, 0.0, 0.05]] * 3)  # three turning steps on the spot
    drives = [
        [[1.0, 0.0, np.radians(80.0)]],
        [[0.0, -0.5, -np.radians(90.0)]],
        [[0.3, 0.3, 2 * np.pi - np.radians(10.0)]],  # wraps to -10 degrees
    ]
    odo = np.vstack([spot] + [np.vstack([d, spot]) for d in drives])
    assert median_drive_turn(odo) == pytest.approx(np.radians(80.0))
    # the same drives logged in 4 steps each, the turn in the first (review28 M1: a median
    # over the steps gave 0)
    split = [
        np.vstack(
            [[np.r_[np.asarray(d[0][:2]) / 4, d[0][2]]], [[*(np.asarray(d[0][:2]) / 4), 0.0]] * 3]
        )
        for d in drives
    ]
    odo4 = np.vstack([spot] + [np.vstack([d, spot]) for d in split])
    assert len([1 for a, b in segment_stops(odo4) if b - a > 1]) == 4
    assert median_drive_turn(odo4) == pytest.approx(np.radians(80.0))
    # one stop, or no stop at all (every step drives): no drive between stops
    assert median_drive_turn(spot) == 0.0 and median_drive_turn(np.zeros((0, 3))) == 0.0
    assert median_drive_turn(np.vstack([d[0] for d in drives])) == 0.0
    res = StopGraphPathEstimator(ANTENNAS, StopGraphConfig(drive_turn=np.inf)).estimate(run[0])
    assert not res.drives_turn


def test_innovation_is_the_mahalanobis_distance_under_both_covariances() -> None:
    """Prior and registration covariances add; the yaw difference is wrapped."""
    cov = np.diag([0.03**2, 0.04**2, 0.02**2])
    reg = Registration(
        pose=np.array([0.1, 0.0, -np.pi + 0.01]), cov=cov, explained=1.0, matched=3, accepted=True
    )
    prior = np.array([0.0, 0.2, np.pi - 0.01])
    d = np.array([0.1, -0.2, 0.02])
    expect = np.sqrt(np.sum(d**2 / (2 * np.diag(cov))))
    assert _innovation(reg, prior, cov) == pytest.approx(expect, rel=1e-9)


def test_loop_gate_refuses_a_match_outside_its_prior(run: tuple[ScanLog, np.ndarray]) -> None:
    """Stops 1-2-3 are joined by odometry alone and the only loop, stop 3 in stop 1, comes
    back 0.4 m off (several sigmas of its prior), with a covariance as wide as the prior's;
    the other registrations are exact. Without the gate the wrong loop enters the graph and
    moves stop 3 by centimetres; with ``loop_gate=3`` it is refused as outside the prior and
    the stops are those of the graph without the loop."""
    log, poses = run
    segs = segment_stops(log.odometry)
    truth = np.array([poses[s] for s, _ in segs])
    index = {s: k for k, (s, _) in enumerate(segs)}

    def solve(gate: float, loop: bool = True) -> tuple[np.ndarray, list[Registration]]:
        cfg = StopGraphConfig(
            refine_turns=False,
            bundle_adjust=False,
            loop_window=(0.005, np.radians(0.1)),
            loop_gate=gate,
            drive_turn=np.inf,  # loop_gate itself, never drive_loop_gate
        )
        est = StopGraphPathEstimator(ANTENNAS, cfg)

        def fake(a: StopScan, b: StopScan, prior: np.ndarray, cov: np.ndarray) -> Registration:
            i, j = index[a.start], index[b.start]
            refused = Registration(
                pose=prior, cov=cov, explained=0.0, matched=0, accepted=False, reason="x"
            )
            if (j == i + 1 and i in (1, 2)) or (j > i + 1 and ((i, j) != (1, 3) or not loop)):
                return refused
            z = relative_pose(truth[i], truth[j])
            tight = np.diag([1e-4, 1e-4, 1e-6])
            if (i, j) == (1, 3):
                z, tight = z + np.array([0.4, 0.0, 0.0]), cov
            return Registration(pose=z, cov=tight, explained=1.0, matched=5, accepted=True)

        est.registration.register_both = fake  # type: ignore[method-assign]
        res = est.estimate(log)
        return res.stop_poses, [r for i, j, r in res.registrations if (i, j) == (1, 3)]

    without, _ = solve(np.inf, loop=False)
    poses0, reg0 = solve(np.inf)
    poses1, reg1 = solve(3.0)
    assert reg0[0].accepted and np.hypot(*(poses0[3, :2] - without[3, :2])) > 0.03
    assert not reg1[0].accepted and reg1[0].reason == "outside the prior"
    np.testing.assert_allclose(poses1, without, atol=1e-9)


def test_search_shear_follows_the_prior_along_its_yaw() -> None:
    """A prior whose yaw is 20 degrees off, with the y of the far stop moving 3 m per radian
    of it (a loop across a drive whose heading is unsure): the truth lies 1.05 m off in y,
    beyond ``window``'s 0.8 m, but on the prior's ridge (1.7 sigma). The box search misses
    it; the grid sheared along the prior's regression of xy on the yaw finds it."""
    rng = np.random.default_rng(4)
    points = rng.uniform([0.0, 0.0], [6.0, 5.0], (8, 2))
    pa, pb = np.array([2.0, 2.0, 0.3]), np.array([4.5, 2.6, 0.6])
    a, b = _scatterers(points, pa), _scatterers(points, pb)
    b = replace(b, images=b.images + rng.normal(0.0, 0.01, b.images.shape))
    truth = relative_pose(pa, pb)
    ridge = np.array([0.0, 3.0, 1.0])  # (m/rad, m/rad, 1)
    jac = np.eye(3)
    jac[:2, 2] = ridge[:2]
    cov = jac @ np.diag([0.08**2, 0.08**2, np.radians(12.0) ** 2]) @ jac.T
    prior = truth - ridge * np.radians(20.0)
    box = ReflectorRegistration(StopGraphConfig()).register_both(a, b, prior, cov)
    assert not box.accepted or np.hypot(*(box.pose - truth)[:2]) > 0.3
    reg = ReflectorRegistration(StopGraphConfig(search_shear=True)).register_both(a, b, prior, cov)
    assert reg.accepted, reg.reason
    err = reg.pose - truth
    assert np.hypot(err[0], err[1]) < 0.02 and abs(np.degrees(err[2])) < 0.3


def test_loop_shear_searches_the_capped_candidates_again(
    run: tuple[ScanLog, np.ndarray], monkeypatch: pytest.MonkeyPatch
) -> None:
    """Every registration refused, so the graph is held by odometry alone. With
    ``loop_shear`` the last level searches each loop candidate again with the sheared grid
    when its prior reaches beyond ``window`` at 3 sigma (a 0.5 m / 15 degree
    ``loop_window``), once; never when its prior is narrow (5 mm / 0.1 degree over exact
    consecutive matches), nor without ``loop_shear``."""
    log, poses = run
    segs = segment_stops(log.odometry)
    truth = np.array([poses[s] for s, _ in segs])
    index = {s: k for k, (s, _) in enumerate(segs)}

    def calls(loop_window: tuple[float, float], shear: bool) -> list[tuple[int, int, bool]]:
        seen: list[tuple[int, int, bool]] = []

        def fake(
            self: ReflectorRegistration, a: StopScan, b: StopScan, prior: Any, cov: Any
        ) -> Registration:
            i, j = index[a.start], index[b.start]
            seen.append((i, j, self.config.search_shear))
            if j == i + 1 and loop_window[0] < 0.1:
                z = relative_pose(truth[i], truth[j])
                tight = np.diag([1e-6, 1e-6, 1e-8])
                return Registration(pose=z, cov=tight, explained=1.0, matched=5, accepted=True)
            return Registration(
                pose=prior, cov=cov, explained=0.0, matched=0, accepted=False, reason="x"
            )

        monkeypatch.setattr(ReflectorRegistration, "register_both", fake)
        cfg = StopGraphConfig(
            refine_turns=False,
            bundle_adjust=False,
            loop_window=(loop_window[0], np.radians(loop_window[1])),
            drive_turn=np.inf,
            loop_shear=shear,
        )
        StopGraphPathEstimator(ANTENNAS, cfg).estimate(log)
        return [c for c in seen if c[1] > c[0] + 1]

    wide = calls((0.5, 15.0), True)
    box = [(i, j) for i, j, s in wide if not s]
    assert box and sorted((i, j) for i, j, s in wide if s) == sorted(box)
    assert not any(s for _, _, s in calls((0.5, 15.0), False))
    narrow = calls((0.005, 0.1), True)
    assert narrow and not any(s for _, _, s in narrow)
