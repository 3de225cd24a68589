"""``uwbnet map``'s automatic choices: the turning step and the wall gap along a stop path."""

from __future__ import annotations

import math

import numpy as np

from uwbnet.map_cmd import (
    AUTO_MIN_REGISTERED,
    AUTO_STATE_STEP,
    STOP_MAP_SETTINGS,
    STOP_WALL_GAP_MAX,
    STOP_WALL_GAP_SPACING,
    stop_wall_gap,
    stops_unsuited,
    turning_step,
)


def test_turning_step_is_the_median_of_the_steps_that_do_not_drive() -> None:
    rng = np.random.default_rng(4)
    step = math.radians(6.0)
    turns = np.column_stack(
        [rng.normal(0, 0.002, 60), rng.normal(0, 0.002, 60), rng.normal(step, 0.003, 60)]
    )
    drives = np.array([[2.5, 0.1, 0.4], [3.0, -0.2, -1.2]])  # large turns while driving
    odo = np.vstack([turns[:30], drives, turns[30:]])
    assert abs(turning_step(odo) - step) < math.radians(0.3)
    assert abs(turning_step(-odo) - step) < math.radians(0.3)  # turning the other way
    assert turning_step(drives) is None and turning_step(np.zeros((0, 3))) is None
    # a robot taking 3 acquisitions per heading (2 dwells reading the odometry's noise) turns
    # in the same steps: the dwells are left out (the median over all was 0: measurement
    # space and the stop graph for 15-degree steps)
    still = np.column_stack(
        [rng.normal(0, 0.001, 120), rng.normal(0, 0.001, 120), rng.normal(0, 0.002, 120)]
    )
    dwelling = np.concatenate([turns[:, None], still.reshape(60, 2, 3)], 1).reshape(-1, 3)
    assert abs(turning_step(dwelling) - step) < math.radians(0.3)


def test_the_wall_gap_exceeds_the_spacing_of_the_stops() -> None:
    floor = STOP_MAP_SETTINGS["wall_gap"]
    # room_pillar-like: stops about 0.5 m apart keep the 1 m floor
    dense = np.array([[x, y] for x in np.arange(0, 3, 0.5) for y in np.arange(0, 2, 0.5)])
    assert stop_wall_gap(dense) == floor
    # a tour with stops 1.5 m apart (and one far one): the gap follows the median spacing, so
    # a wall seen from neighbouring stops is not cut at every stop's foot
    rng = np.random.default_rng(1)
    sparse = np.array([[x, y] for x in np.arange(0, 6, 1.5) for y in (0.0, 1.5)])
    sparse = np.vstack([sparse + rng.normal(0, 0.01, sparse.shape), [[20.0, 20.0]]])
    gap = stop_wall_gap(sparse)
    assert abs(gap - STOP_WALL_GAP_SPACING * 1.5) < 0.05
    assert stop_wall_gap(sparse[:1]) == floor and stop_wall_gap(np.zeros((0, 2))) == floor
    # stops 3 m apart (a sparse corridor forced onto the stop graph) would give 4.5 m, enough
    # to merge two walls across a doorway: capped
    far = np.array([[0.0, 0.0], [3.0, 0.0], [6.0, 0.0], [9.0, 0.0]])
    assert stop_wall_gap(far) == STOP_WALL_GAP_MAX < STOP_WALL_GAP_SPACING * 3.0


def test_auto_refuses_the_stop_graph_for_coarse_turns_or_unjoined_stops() -> None:
    fine, coarse = math.radians(3.0), math.radians(15.0)
    assert stops_unsuited(fine, None, None) is None and stops_unsuited(None, None, None) is None
    # coarse steps are refused whatever the registrations (corridor_L_sparse's 15 degrees)
    assert stops_unsuited(coarse, None, None) == "turning steps of 15 degrees"
    assert stops_unsuited(coarse, 5, 5) == "turning steps of 15 degrees"
    assert stops_unsuited(AUTO_STATE_STEP, 5, 5) is not None
    # fine steps: the share of the stops joined to another by a registration decides
    need = math.ceil(AUTO_MIN_REGISTERED * 12)
    assert stops_unsuited(fine, 12, need) is None
    assert (
        stops_unsuited(fine, 12, need - 1)
        == f"registrations join {need - 1} of 12 stops to another"
    )
    assert stops_unsuited(fine, 0, 0) is not None  # a robot that never stops
