"""Trajectory scoring of ``uwbnet map --eval``: per-stop errors and the dead-reckoning baseline."""

from __future__ import annotations

import math

import numpy as np
import pytest

import uwbnet.map_eval as me
from uwbnet.map_cmd import compose
from uwbnet.map_eval import trajectory_errors


def test_per_stop_errors_follow_the_true_stops() -> None:
    # Two stops of 4 headings each; the estimate is 0.1 m off at the first stop and 0.3 m
    # and 2 degrees off at the second.
    t = np.arange(8.0)
    truth = np.zeros((8, 4))
    truth[:, 0] = t
    truth[4:, 1] = 2.0
    truth[:, 3] = np.radians(np.tile([0.0, 90.0, 180.0, -90.0], 2))
    est = truth.copy()
    est[:4, 2] += 0.1
    est[4:, 2] += 0.3
    est[4:, 3] += np.radians(2.0)
    out = trajectory_errors(est, truth)
    assert out["per_stop_m"] == [0.1, 0.3]
    assert out["per_stop_yaw_deg"] == [0.0, 2.0]
    assert math.isclose(out["rmse_m"], math.sqrt((0.01 + 0.09) / 2), abs_tol=1e-3)
    assert out["final_m"] == 0.3


def test_a_robot_that_never_stops_has_no_per_stop_list() -> None:
    truth = np.zeros((300, 4))
    truth[:, 0] = np.arange(300.0)
    truth[:, 1] = 0.05 * np.arange(300.0)
    out = trajectory_errors(truth, truth)
    assert out["rmse_m"] == 0.0 and "per_stop_m" not in out


def test_compose_integrates_odometry_in_the_robot_frame() -> None:
    pose = compose(np.zeros(3), np.array([1.0, 0.0, math.pi / 2]))
    pose = compose(pose, np.array([1.0, 0.0, 0.0]))
    np.testing.assert_allclose(pose, [1.0, 1.0, math.pi / 2], atol=1e-12)


def test_a_rotated_path_fits_the_truth_once_aligned_and_the_turn_drift_is_per_stop() -> None:
    # Three stops of 5 headings; the estimate is the truth rotated by 2 degrees about the
    # start, and at the middle stop its heading drifts by 1 degree per acquisition.
    truth = np.zeros((15, 4))
    truth[:, 0] = np.arange(15.0)
    truth[5:10, 1], truth[10:, 1:3] = 3.0, [3.0, 4.0]
    truth[:, 3] = np.radians(np.tile(np.arange(5) * 72.0, 3))
    rot = np.radians(2.0)
    c, s = math.cos(rot), math.sin(rot)
    est = truth.copy()
    est[:, 1:3] = truth[:, 1:3] @ np.array([[c, s], [-s, c]])
    est[:, 3] += rot
    est[5:10, 3] += np.radians(np.arange(5.0))
    out = trajectory_errors(est, truth)
    assert out["rmse_m"] > 0.1
    assert out["aligned_rmse_m"] < 1e-3
    assert math.isclose(out["aligned_rotation_deg"], 2.0, abs_tol=1e-2)  # the path's rotation
    assert out["per_stop_turn_drift_deg"] == [0.0, 4.0, 0.0]
    assert math.isclose(out["turn_drift_deg"], 4.0 / 3, abs_tol=0.01)


def test_the_turn_drift_wraps_at_180_degrees_and_is_none_without_stops() -> None:
    # one stop turning through +-180 degrees, its heading 1 degree ahead at the end
    truth = np.zeros((5, 4))
    truth[:, 0] = np.arange(5.0)
    truth[:, 3] = np.radians([170.0, 175.0, 180.0, -175.0, -170.0])
    est = truth.copy()
    est[-1, 3] += np.radians(1.0)
    est[:, 3] = (est[:, 3] + np.pi) % (2 * np.pi) - np.pi
    out = trajectory_errors(est, truth)
    assert out["per_stop_turn_drift_deg"] == [1.0]
    assert math.isclose(out["turn_drift_deg"], 1.0, abs_tol=1e-9)
    # a heading error of 179.5 degrees at the start and 180.5 (-179.5) at the end: the stop
    # gained 1 degree, not -359
    est = truth.copy()
    est[0, 3] += np.radians(179.5)
    est[-1, 3] += np.radians(180.5)
    est[:, 3] = (est[:, 3] + np.pi) % (2 * np.pi) - np.pi
    assert trajectory_errors(est, truth)["per_stop_turn_drift_deg"] == [1.0]
    # a robot that drives all the time: every acquisition its own "stop", no turn drift
    drive = np.zeros((20, 4))
    drive[:, 0] = np.arange(20.0)
    drive[:, 1] = 0.05 * np.arange(20)
    moved = drive.copy()
    moved[:, 3] += np.radians(0.5 * np.arange(20))
    assert trajectory_errors(moved, drive)["turn_drift_deg"] is None


def test_unsupported_length_and_false_corners_with_and_without_the_path_fit() -> None:
    # truth: the wall y = 0 (x 0..10) and its corner (10, 0); the map and the path are the
    # truth rotated 3 degrees about the start, with a wall 1 m past the corner (invented)
    faces = np.array([[0.0, 0, 10, 0], [10, 0, 10, 5]])
    a = np.radians(3.0)
    rot = np.array([[np.cos(a), np.sin(a)], [-np.sin(a), np.cos(a)]])  # x @ rot turns by a
    walls = np.array([[0.0, 0, 11, 0]])
    mapped = np.hstack([walls[:, :2] @ rot, walls[:, 2:] @ rot])
    corner = np.array([[10.0, 0]]) @ rot  # 0.52 m off the true one
    # 0.2 m off y = 0 from 3.82 m along, but the 0.4 m crossing x = 10 lies on the other face
    assert abs(me._unsupported_length(mapped, faces) - (11 - 0.2 / np.sin(a) - 0.4)) < 0.05
    assert me._false_corners(corner, np.array([[10.0, 0]])) == 1
    t = np.linspace(0, 1, 50)
    truth = np.column_stack([t, 10 * t, np.zeros_like(t), np.zeros_like(t)])
    path = truth.copy()
    path[:, 1:3] = truth[:, 1:3] @ rot
    r, shift = me._rigid_fit(path, truth)
    np.testing.assert_allclose(path[:, 1:3] @ r + shift, truth[:, 1:3], atol=1e-9)
    fitted = np.hstack([mapped[:, :2] @ r + shift, mapped[:, 2:] @ r + shift])
    # once the rotation is removed only the invented metre past the corner is unsupported
    assert abs(me._unsupported_length(fitted, faces) - 0.8) < 0.05
    assert me._false_corners(corner @ r + shift, np.array([[10.0, 0]])) == 0
    # the corner's error, 0.52 m in the first-pose frame (not found within 0.5 m), is gone
    # once the path's rotation is removed
    true_corner = np.array([[10.0, 0], [0.0, 5.0]])
    assert me._corner_errors(corner, true_corner) == []
    aligned = me._corner_errors(corner @ r + shift, true_corner)
    assert len(aligned) == 1 and aligned[0] < 1e-6
    assert me._corner_errors(np.zeros((0, 2)), true_corner) == []


@pytest.mark.parametrize("clockwise", [False, True])
def test_an_l_rooms_inner_vertex_is_an_edge_not_a_corner(clockwise) -> None:
    # The L's reflex vertex (9.6, 2.4) faces the room as a convex edge (a diffraction point,
    # mapped as a point), not a corner reflector: the corners are the other five.
    from sim_nodes.scene import load_scenario

    sc = load_scenario("corridor_L")
    if clockwise:
        sc = sc.model_copy(
            update={"room": sc.room.model_copy(update={"outline": sc.room.outline[::-1]})}
        )
    g = me.truth_geometry(sc)
    corners = {tuple(np.round(c, 6)) for c in g["corners"]}
    assert corners == {(0.0, 0.0), (12.0, 0.0), (12.0, 10.0), (9.6, 10.0), (0.0, 2.4)}
    np.testing.assert_allclose(g["edges"], [[9.6, 2.4]])
