"""``uwbnet map``'s automatic choices."""

from __future__ import annotations

import math

import numpy as np

from uwbnet.map_cmd import turning_step


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
