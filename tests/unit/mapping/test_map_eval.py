"""Trajectory scoring of ``uwbnet map --eval``: per-stop errors and the dead-reckoning baseline."""

from __future__ import annotations

import math

import numpy as np

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
