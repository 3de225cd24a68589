"""OSPA / GOSPA against hand-computed values; evaluate() bookkeeping."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from fusion_center.tracking.metrics import evaluate, gospa, ospa


def test_ospa_hand_computed() -> None:
    X = [[0.0, 0.0]]
    Y = [[0.0, 0.5], [3.0, 0.0]]
    # One pair at 0.5 m, one unmatched estimate at c: (0.5 + 1) / 2.
    assert ospa(X, Y, c=1.0, p=1) == pytest.approx(0.75)
    assert ospa(X, Y, c=1.0, p=2) == pytest.approx(math.sqrt((0.25 + 1.0) / 2))
    # Cut-off caps a far pair at c.
    assert ospa([[0.0, 0.0]], [[10.0, 0.0]], c=2.0, p=1) == pytest.approx(2.0)


def test_ospa_symmetric_zero_and_empty() -> None:
    rng = np.random.default_rng(3)
    X, Y = rng.normal(size=(4, 2)), rng.normal(size=(6, 2))
    assert ospa(X, Y, 1.0, 2) == pytest.approx(ospa(Y, X, 1.0, 2))
    assert ospa(X, X, 1.0, 1) == pytest.approx(0.0)
    assert ospa(np.zeros((0, 2)), np.zeros((0, 2))) == 0.0
    assert ospa(np.zeros((0, 2)), X, c=1.5) == 1.5
    assert ospa(X, np.zeros((0, 2)), c=1.5) == 1.5


def test_gospa_hand_computed() -> None:
    total, loc, missed, false = gospa([[0.0, 0.0]], [[0.0, 0.5], [3.0, 0.0]], c=1.0, p=1)
    assert (total, loc, missed, false) == pytest.approx((1.0, 0.5, 0.0, 0.5))
    total2, loc2, _, false2 = gospa([[0.0, 0.0]], [[0.0, 0.5], [3.0, 0.0]], c=1.0, p=2)
    assert total2 == pytest.approx(math.sqrt(0.25 + 0.5))
    assert (loc2, false2) == pytest.approx((0.25, 0.5))
    # A pair farther than c is a miss plus a false track, not a localisation error.
    total3, loc3, missed3, false3 = gospa([[0.0, 0.0], [5.0, 5.0]], [[0.0, 2.0]], 1.0, 1)
    assert (total3, loc3, missed3, false3) == pytest.approx((1.5, 0.0, 1.0, 0.5))
    assert gospa(np.zeros((0, 2)), np.zeros((0, 2)))[0] == 0.0


def test_id_switches_counted_per_target_ignoring_gaps() -> None:
    truth = [(float(k), [7], [[float(k), 0.0]]) for k in range(8)]
    track_ids = [1, 1, 2, 2, None, 2, 3, 3]  # 1 -> 2, gap, 2 -> 3: two switches
    tracks = [
        (float(k), [] if i is None else [i], np.zeros((0, 2)) if i is None else [[k + 0.1, 0.0]])
        for k, i in enumerate(track_ids)
    ]
    res = evaluate(truth, tracks, c=1.0)
    assert res["id_switches"] == 2
    assert res["n_updates"] == 8
    assert res["card_correct_fraction"] == pytest.approx(7 / 8)
    assert res["rmse"] == {"7": pytest.approx(0.1)}
    json.dumps(res)


def test_evaluate_interpolates_truth_and_skips_warmup() -> None:
    truth = [
        (0.0, [1], [[0.0, 0.0]]),
        (1.0, [1], [[1.0, 0.0]]),
        (2.0, [1, 2], [[2.0, 0.0], [5.0, 5.0]]),
    ]
    # At t = 1.5 the truth is (1.5, 0) only: id 2 is missing at the left neighbour.
    tracks = [(0.25, [4], [[9.0, 9.0]]), (1.5, [4], [[1.5, 0.0]])]
    res = evaluate(truth, tracks, c=1.0, skip=1.0)
    assert res["n_updates"] == 1
    assert res["ospa_p1_mean"] == pytest.approx(0.0)
    assert res["card_correct_fraction"] == 1.0
