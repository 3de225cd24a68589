"""EchoSlamMapper's output bookkeeping around a relocalisation hold."""

from __future__ import annotations

import numpy as np

from fusion_center.mapping import EchoSlamMapper, MapperConfig
from fusion_center.mapping.features import SlamMap
from fusion_center.mapping.models import CORNER, POINT, WALL
from fusion_center.mapping.pipeline import _with_end_walls
from fusion_center.mapping.rbpf import PoseEstimate2D
from fusion_center.mapping.smoothing import SmoothedPathMap

ANTENNAS = np.array([[0.0, 0.0], [0.0, 0.5], [0.0, -0.5]])


class _HoldingFilter:
    """Duck-typed RbpfSlam that holds acquisitions ``hold`` back and revises them when the
    last one arrives; its estimate is the acquisition count (x) and 1 once revised (y)."""

    def __init__(self, config: object, hold: range) -> None:
        self.config = config
        self.hold = hold
        self.k = 0
        self.revised: list[PoseEstimate2D] = []

    @property
    def holding(self) -> bool:
        return (self.k - 1) in self.hold[:-1]  # after the update of a held acquisition

    def predict(self, dt: float, odometry: object = None, rotation_sigma: object = None) -> None:
        pass

    def update(self, z: object, groups: object = None) -> None:
        if self.k == self.hold[-1]:
            self.revised += [self._est(k, 1.0) for k in self.hold]
        self.k += 1

    def forget_groups(self, keep: object) -> None:
        pass

    def flush(self) -> None:
        pass

    def estimate(self) -> PoseEstimate2D:
        return self._est(self.k - 1, 0.0)

    @staticmethod
    def _est(k: int, revised: float) -> PoseEstimate2D:
        return PoseEstimate2D(pose=np.array([float(k), revised, 0.0]), cov=np.eye(3))


def _outputs(provisional: bool) -> list:
    mapper = EchoSlamMapper(
        ANTENNAS,
        fs=32.4e9,
        t0=0.0,
        bandwidth=8.9e9,
        config=MapperConfig(warmup=0, lag=0, provisional_poses=provisional),
    )
    mapper.filter = _HoldingFilter(mapper.filter.config, range(3, 7))  # type: ignore[assignment]
    rng = np.random.default_rng(0)
    out = []
    for k in range(10):
        got = mapper.step(float(k), rng.normal(0.0, 1e-3, (2, 512)).astype(np.float32))
        out.append(got)
    return out


def test_issue_8_held_acquisitions_get_a_provisional_pose_at_once() -> None:
    per_step = _outputs(provisional=True)
    # every acquisition has an output at once: the held ones (3-6) provisional, with the
    # odometry's prediction (the filter's estimate while it holds)
    for k, got in enumerate(per_step):
        live = [o for o in got if o.t == float(k)]
        assert len(live) == 1, (k, got)
        assert live[0].provisional == (k in (3, 4, 5))
        assert live[0].estimate.pose[1] == (1.0 if k == 6 else 0.0)
    # the hold's end brings the revised estimates of all held acquisitions, not provisional
    revised = [o for o in per_step[6] if not o.provisional]
    assert [o.t for o in revised] == [3.0, 4.0, 5.0, 6.0]
    assert all(o.estimate.pose[1] == 1.0 for o in revised)


def test_offline_the_held_acquisitions_come_out_only_revised() -> None:
    per_step = _outputs(provisional=False)
    assert [len(g) for g in per_step] == [1, 1, 1, 0, 0, 0, 4, 1, 1, 1]
    assert not any(o.provisional for g in per_step for o in g)
    assert [o.t for g in per_step for o in g] == [float(k) for k in range(10)]


class _Publisher:
    def __init__(self) -> None:
        self.sent: list[bytes] = []

    def put(self, payload: bytes) -> None:
        self.sent.append(payload)


def test_issue_8_the_service_publishes_held_poses_live_and_keeps_time_order() -> None:
    from fusion_center.mapping_service import MappingConfig, MappingService, _Robot
    from protocol import Poses, decode

    service = MappingService(None, MappingConfig(map_every=1000))  # type: ignore[arg-type]
    pub = _Publisher()
    service._pub_poses = pub
    robot = _Robot(info=None, origin=(1.0, 2.0, 0.0, 0.0))  # type: ignore[arg-type]
    robot.mapper = EchoSlamMapper(
        ANTENNAS, fs=32.4e9, t0=0.0, bandwidth=8.9e9, config=MapperConfig(warmup=0, lag=0)
    )
    for got in _outputs(provisional=True):
        for out in got:
            service._publish_pose("robot", robot, out)
    poses = [decode(b) for b in pub.sent]
    assert all(isinstance(p, Poses) for p in poses)
    assert [p.t for p in poses] == [float(k) for k in range(10)]
    # world frame: the origin's offset; the hold's last acquisition carries the revision
    xs = [p.poses["robot"].pose[0] for p in poses]
    ys = [p.poses["robot"].pose[1] for p in poses]
    assert np.allclose(xs, 1.0 + np.arange(10))
    assert np.allclose(ys, [2.0] * 6 + [3.0] + [2.0] * 3)


def _turns(step_deg: float, stops: int = 3, headings: int = 24, dwells: int = 0) -> np.ndarray:
    """Odometry of a robot turning ``headings`` steps at each stop, 3 m drives between, with
    ``dwells`` more acquisitions at every heading (a little odometry noise, no turn)."""
    rng = np.random.default_rng(7)
    turn = np.tile([0.0, 0.0, np.radians(step_deg)], (headings, 1))
    if dwells:
        still = rng.normal(0.0, [0.001, 0.001, np.radians(0.1)], (headings, dwells, 3))
        turn = np.concatenate([turn[:, None, :], still], 1).reshape(-1, 3)
    drive = np.array([[3.0, 0.05, 0.01]])
    return np.vstack([np.vstack([drive, turn]) for _ in range(stops)])


def test_the_support_a_smoothed_landmark_needs_follows_the_turning_step() -> None:
    import pytest

    from fusion_center.mapping.pipeline import scaled_min_pairs

    ref = np.radians(3.0)
    # at the reference step the count stands; coarser steps see a wall in fewer headings
    assert scaled_min_pairs(8, _turns(3.0), ref) == 8
    assert scaled_min_pairs(8, _turns(15.0), ref) == int(np.ceil(8 * 3.0 / 15.0))
    assert scaled_min_pairs(8, _turns(6.0), ref) == 4
    # finer steps do not ask for more, and a robot that never turns keeps it
    assert scaled_min_pairs(8, _turns(1.0), ref) == 8
    assert scaled_min_pairs(8, _turns(0.0), ref) == 8
    assert scaled_min_pairs(8, _turns(90.0), ref) == 1
    # 3 acquisitions per 15-degree heading hear a wall as often as 5-degree steps do
    assert scaled_min_pairs(8, _turns(15.0, dwells=2), ref) == int(np.ceil(8 * 3.0 / 5.0))
    with pytest.raises(ValueError, match="reference_step"):
        scaled_min_pairs(8, _turns(3.0), 0.0)
    for bad in (0, -3, 2.5, True):
        with pytest.raises(ValueError, match="min_pairs must be an integer >= 1"):
            scaled_min_pairs(bad, _turns(3.0), ref)


def test_the_smoother_scales_the_support_by_the_recorded_increments_only() -> None:
    """6-degree steps on the spot against the 3-degree reference: 4 pairs of 8; the first
    acquisition has no increment and must not count as a dwell (review28 M2: it gave 5)."""
    mapper = EchoSlamMapper(
        ANTENNAS, fs=32.4e9, t0=0.0, bandwidth=8.9e9, config=MapperConfig(keep_history=True)
    )
    rng = np.random.default_rng(0)
    for k in range(60):
        odo = None if k == 0 else (0.0, 0.0, np.radians(6.0))
        mapper.step(0.02 * k, rng.normal(0.0, 1e-3, (2, 512)).astype(np.float32), odo)
    mapper.finish()
    assert mapper.support_min_pairs(8, np.radians(3.0)) == 4
    assert mapper.support_min_pairs(8, np.radians(1.5)) == 2


def test_the_turning_step_leaves_dwells_out_and_counts_them_per_acquisition() -> None:
    from fusion_center.mapping.pipeline import turning_step

    odo = _turns(15.0, dwells=2)
    # the step between headings (echo tracking breaks at it) whatever the dwells
    assert abs(turning_step(odo) - np.radians(15.0)) < 1e-9
    assert abs(turning_step(_turns(15.0)) - np.radians(15.0)) < 1e-9
    # the angle per acquisition on the spot: a third of it
    assert abs(turning_step(odo, per_acquisition=True) - np.radians(5.0)) < 1e-9
    assert turning_step(_turns(15.0), per_acquisition=True) == turning_step(_turns(15.0))
    # no turn on the spot (only dwells, or only drives): None
    assert turning_step(_turns(0.0)) is None
    assert turning_step(_turns(0.0, dwells=2), per_acquisition=True) is None
    import pytest

    with pytest.raises(ValueError, match="drive"):
        turning_step(odo, drive=float("nan"))


def test_the_joint_per_stop_association_is_for_state_space_only() -> None:
    from fusion_center.mapping import SlamConfig
    from fusion_center.mapping.pipeline import STATE_STOP_GATE

    def mapper(association: str) -> EchoSlamMapper:
        slam = SlamConfig(association=association)
        return EchoSlamMapper(ANTENNAS, fs=20e9, t0=0.0, bandwidth=8e9, slam=slam)

    # measured: with room_pillar's measurement-space tracks it added walls matching no face
    assert mapper("state").smoother_config().stop_gate == STATE_STOP_GATE > 0.25
    assert mapper("measurement").smoother_config().stop_gate == 0.0
    cfg = mapper("state").smoother_config()
    assert cfg.range_sigma == mapper("state").filter.config.range_sigma


def test_coarse_turn_settings_of_the_smoother_are_for_state_space_only() -> None:
    from fusion_center.mapping import SlamConfig
    from fusion_center.mapping.pipeline import STATE_KEYFRAME_TURN, STATE_SIGMA_FLOOR

    def config(association: str, **kw: float):
        slam = SlamConfig(association=association, **kw)
        m = EchoSlamMapper(ANTENNAS, fs=20e9, t0=0.0, bandwidth=8e9, slam=slam)
        return m.smoother_config()

    state, meas = config("state"), config("measurement")
    # a key pose at every 15-degree step, not at room_pillar's 3-degree ones
    assert np.radians(3.0) * 3 < state.keyframe_turn == STATE_KEYFRAME_TURN < np.radians(15.0)
    assert 0.0 < state.sigma_floor == STATE_SIGMA_FLOOR < state.range_sigma
    # not measured on room_pillar's filter runs (measurement space): unchanged there
    assert meas.keyframe_turn == 0.0 and meas.sigma_floor == 0.0
    # a filter whose range noise is under the floor: the floor follows it (review28 L3)
    assert config("state", range_sigma=0.008).sigma_floor == 0.008


def test_the_state_space_smoother_keeps_the_arrays_own_orientation() -> None:
    from fusion_center.mapping import SlamConfig

    def mapper(association: str) -> EchoSlamMapper:
        slam = SlamConfig(association=association, mount_sigma=np.radians(1.0), seed=4)
        m = EchoSlamMapper(ANTENNAS, fs=20e9, t0=0.0, bandwidth=8e9, slam=slam)
        m.filter.logw[:] = -np.arange(m.filter.logw.size, dtype=float)  # particle 0 heaviest
        return m

    state, meas = mapper("state"), mapper("measurement")
    drawn = float(state.filter.mount[0])
    assert abs(drawn) > 1e-4  # a particle's draw from the 1-degree prior
    # state space (sharp bearings, coarse turns): the draw would turn every wall
    assert state.smoother_mount() == 0.0
    assert state.smoother_mount(filter_mount=True) == drawn
    assert meas.smoother_mount() == float(meas.filter.mount[0]) != 0.0
    assert meas.smoother_mount(filter_mount=False) == 0.0


def _one_stop_result(kinds, states, pairs, stops, observer) -> SmoothedPathMap:
    n = len(kinds)
    return SmoothedPathMap(
        poses=np.zeros((1, 3)),
        kinds=np.array(kinds, np.int64),
        states=np.array(states, float),
        pairs=np.array(pairs, np.int64),
        stops=np.array(stops, np.int64),
        wall_extent=np.full((n, 2), np.nan),
        cost_before=0.0,
        cost_after=0.0,
        observer=np.array(observer, float),
    )


def test_a_landmark_heard_from_one_stop_down_a_corridor_becomes_its_end_wall() -> None:
    # side walls y = 0 and y = 2.4 mapped x 0..4; heard from the stop (3, 1.2) only: a point
    # at (8, 1.2), or the wall x = 8 (alpha 0, d 8) whose foot from the stop is (8, 1.2)
    sides = SlamMap(walls=np.array([[0, 0, 4, 0], [4, 2.4, 0, 2.4]], float))
    for kind, state in ((POINT, [8.0, 1.2]), (CORNER, [8.0, 1.2]), (WALL, [0.0, 8.0])):
        res = _one_stop_result([kind], [state], [4], [1], [[3.0, 1.2]])
        m = _with_end_walls(sides, res, min_pairs=2)
        assert len(m.walls) == 3
        np.testing.assert_array_equal(m.end_walls, [2])
        np.testing.assert_allclose(np.sort(m.walls[2, [0, 2]]), [8.0, 8.0], atol=1e-9)
        np.testing.assert_allclose(np.sort(m.walls[2, [1, 3]]), [0.0, 2.4], atol=1e-9)
    # too few pairs, or heard from two stops (then it is in the map by the 2-stop rule)
    for pairs, stops in ((1, 1), (4, 2)):
        res = _one_stop_result([POINT], [[8.0, 1.2]], [pairs], [stops], [[3.0, 1.2]])
        assert _with_end_walls(sides, res, min_pairs=2) is sides


def test_a_reflector_no_landmark_holds_becomes_an_end_wall_too() -> None:
    # the end x = 8 heard from (3, 1.2) by pairs that no smoothed landmark holds
    # (SmoothedPathMap.association -1), grouped by their image point: stop_reflectors
    sides = SlamMap(walls=np.array([[0, 0, 4, 0], [4, 2.4, 0, 2.4]], float))
    res = _one_stop_result([WALL], [[np.pi / 2, 2.4]], [9], [3], [[2.0, 1.2]])
    extra = (np.array([[8.0, 1.3]]), np.array([[3.0, 1.2]]), np.array([3]))
    m = _with_end_walls(sides, res, min_pairs=2, extra=extra)
    np.testing.assert_array_equal(m.end_walls, [2])
    np.testing.assert_allclose(_sorted(m.walls[2]), [[8.0, 0.0], [8.0, 2.4]], atol=1e-9)
    # fewer pairs than min_pairs: not offered
    few = (extra[0], extra[1], np.array([1]))
    assert _with_end_walls(sides, res, min_pairs=2, extra=few) is sides


def _sorted(seg: np.ndarray) -> np.ndarray:
    return np.sort(np.asarray(seg).reshape(-1, 2), axis=0)


def test_end_walls_are_mapped_with_state_space_association_only_by_default() -> None:
    from fusion_center.mapping import SlamConfig

    def mapper(association: str) -> EchoSlamMapper:
        slam = SlamConfig(association=association)
        return EchoSlamMapper(ANTENNAS, fs=20e9, t0=0.0, bandwidth=8e9, slam=slam)

    # measured: on room_pillar's measurement-space run one became a wall matching no face
    assert mapper("state").maps_end_walls()
    assert not mapper("measurement").maps_end_walls()
    assert mapper("measurement").maps_end_walls(True)
    assert not mapper("state").maps_end_walls(False)
