"""Turn closure: a turn's heading errors from its own echo bearings (issue 8)."""

from __future__ import annotations

import numpy as np

from fusion_center.mapping import EchoSlamMapper, MapperConfig
from fusion_center.mapping.grouping import KalmanEchoGrouper
from fusion_center.mapping.synthetic import echo_pairs, rectangle_room
from fusion_center.mapping.turn_closure import EchoBearingTurnCloser, TurnClosure
from sim_nodes.robot_record import odometry_increments

ANTENNAS = np.array([[0.0, 0.0], [0.0, 0.5], [0.0, -0.5]])


def _turn(total_deg: float, seed: int) -> tuple[np.ndarray, np.ndarray, list, list]:
    """A robot turning on the spot in 3-degree steps in a 6 x 5 m room: the true headings
    (rad, relative to the first), the odometry's steps (the robot recorder's slip noise)
    and the echo pairs with their Kalman echo-track ids."""
    rng = np.random.default_rng(seed)
    n = round(total_deg / 3.0) + 1
    true = np.radians(3.0) * np.arange(n)
    start = np.array([2.4, 2.1, 0.4])
    poses = np.column_stack([np.full(n, start[0]), np.full(n, start[1]), start[2] + true])
    dyaw = odometry_increments(poses, rng)[:, 2]
    room = rectangle_room()
    grouper = KalmanEchoGrouper()
    pairs, ids = [], []
    for yaw in true:
        pose = start + np.array([0.0, 0.0, yaw])
        z = echo_pairs(room, pose, ANTENNAS, rng, sigma=0.005, beam=np.radians(50.0))
        pairs.append(z)
        ids.append(grouper.step(z))
    return true, dyaw, pairs, ids


def test_the_turn_closure_recovers_the_heading_error_at_the_end_of_a_turn() -> None:
    before, after = [], []
    for seed in range(1, 7):
        true, dyaw, pairs, ids = _turn(357.0, seed)
        odo_err = true - np.cumsum(np.r_[0.0, dyaw[1:]])
        res = EchoBearingTurnCloser(ANTENNAS[1:]).close(dyaw, pairs, ids)
        assert res.links >= 1 and res.end_sigma < np.radians(0.6)
        left = res.correction[-1] - odo_err[-1]
        assert abs(left) < 3.0 * res.end_sigma  # the estimate's own uncertainty holds
        before.append(abs(odo_err[-1]))
        after.append(abs(left))
    assert np.degrees(max(before)) > 5.0  # one turn drifted by several degrees
    assert np.mean(after) < 0.3 * np.mean(before)


def test_a_half_turn_does_not_close_and_is_left_alone() -> None:
    _, dyaw, pairs, ids = _turn(180.0, seed=3)
    res = EchoBearingTurnCloser(ANTENNAS[1:]).close(dyaw, pairs, ids)
    assert not np.isfinite(res.end_sigma)
    assert np.all(res.correction == 0.0)


class _OdometryLog:
    """Duck-typed RbpfSlam that logs the odometry it is given."""

    def __init__(self, config: object) -> None:
        self.config = config
        self.odometry: list = []
        self.revised: list = []
        self.holding = False
        self._rx_body = ANTENNAS[1:]

    def predict(self, dt: float, odometry: object = None) -> None:
        self.odometry.append(None if odometry is None else np.array(odometry))

    def update(self, z: object, groups: object = None) -> None:
        pass

    def forget_groups(self, keep: object) -> None:
        pass

    def flush(self) -> None:
        pass

    def estimate(self):
        from fusion_center.mapping.rbpf import PoseEstimate2D

        return PoseEstimate2D(pose=np.zeros(3), cov=np.eye(3))


class _FixedCloser:
    def close(self, dyaw, pairs, groups) -> TurnClosure:
        return TurnClosure(np.linspace(0.0, 0.03, len(dyaw)), 0.001, 2)


def test_the_mapper_holds_a_stop_until_the_drive_and_corrects_its_odometry() -> None:
    mapper = EchoSlamMapper(
        ANTENNAS,
        fs=32.4e9,
        t0=0.0,
        bandwidth=8.9e9,
        config=MapperConfig(warmup=0, lag=0, turn_closure=True, provisional_poses=True),
    )
    mapper.filter = _OdometryLog(mapper.filter.config)  # type: ignore[assignment]
    mapper.turn_closer = _FixedCloser()  # type: ignore[assignment]
    rng = np.random.default_rng(0)
    turn, drive = np.array([0.0, 0.0, 0.05]), np.array([1.5, 0.0, 0.0])
    odo = [None] + [turn] * 4 + [drive] + [turn] * 3
    out = []
    for k, o in enumerate(odo):
        got = mapper.step(float(k), rng.normal(0.0, 1e-3, (2, 512)).astype(np.float32), o)
        # every acquisition is published at once (provisional while its stop is held)
        assert [g.t for g in got if g.provisional] == [float(k)]
        out += [g for g in got if not g.provisional]
    assert [g.t for g in out] == [0.0, 1.0, 2.0, 3.0, 4.0]  # the first stop, at the drive
    out += mapper.finish()
    assert [g.t for g in out] == [float(k) for k in range(9)]
    got = mapper.filter.odometry
    # the stop's steps carry the closure's corrections (0.03 rad over the stop's 5
    # acquisitions), the drive passes unchanged
    assert np.allclose([g[2] for g in got[:4]], 0.05 + 0.03 / 4)
    assert np.allclose(got[4], drive)
    assert np.allclose([g[2] for g in got[5:]], 0.05 + 0.03 / 3)
