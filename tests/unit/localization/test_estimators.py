"""Snapshot estimators, CRLB, eq. (6) test and Kalman filters on seeded simulated ranges."""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fusion_center.localization import (
    LOCATORS,
    MseNlosTest,
    PositionKalmanTracker,
    RangeKalmanTracker,
    position_error_bound,
    range_crlb,
)
from fusion_center.localization.estimators import TaylorSeriesLocator

ANCHORS = np.array([[0.0, 0.0], [8.0, 0.0], [8.0, 6.0], [0.0, 6.0]])


@pytest.mark.parametrize("method", sorted(LOCATORS))
def test_estimator_reaches_the_crlb_and_reports_it_as_covariance(method, rng):
    # unbiased Gaussian ranges: an efficient estimator's RMSE is the PEB (500 trials: +-7 %)
    x = np.array([3.0, 2.0])
    std = np.array([0.05, 0.02, 0.05, 0.1])
    loc = LOCATORS[method]()
    errs, covs = [], []
    for _ in range(500):
        r = np.linalg.norm(ANCHORS - x, axis=1) + rng.normal(0.0, std)
        fix = loc.locate(ANCHORS, r, std)
        assert fix.ok
        errs.append(fix.position - x)
        covs.append(np.trace(fix.cov))
    rmse = float(np.sqrt(np.mean(np.sum(np.square(errs), axis=1))))
    peb = position_error_bound(x, ANCHORS, std)
    tol = 1.5 if method == "lls" else 1.15  # linear LS is not efficient with unequal stds
    assert peb * 0.85 < rmse < peb * tol
    assert np.sqrt(np.mean(covs)) == pytest.approx(rmse, rel=0.5 if method == "lls" else 0.15)


def test_range_crlb_matches_the_formula_and_falls_with_snr_and_bandwidth():
    # c / (2 pi beta sqrt(2 SNR)): 30 dB, beta 1 GHz -> 1.067 mm
    assert range_crlb(30.0, 1e9) == pytest.approx(299792458.0 / (2 * np.pi * 1e9 * np.sqrt(2e3)))
    assert range_crlb(40.0, 1e9) < range_crlb(30.0, 1e9) < range_crlb(30.0, 5e8)


@pytest.mark.parametrize("method", sorted(LOCATORS))
def test_collinear_or_too_few_anchors_are_a_flagged_failure(method):
    loc = LOCATORS[method]()
    line = np.array([[0.0, 0.0], [2.0, 0.0], [5.0, 0.0]])
    r = np.linalg.norm(line - [1.0, 3.0], axis=1)
    for a, rr in ((line, r), (ANCHORS[:2], r[:2]), (ANCHORS[:0], r[:0])):
        fix = loc.locate(a, rr, np.full(len(rr), 0.05))
        assert not fix.ok and fix.reason
        assert np.all(np.isinf(np.diag(fix.cov)))


def test_taylor_with_a_prior_keeps_the_branch_and_flags_it():
    # two anchors and a prior: the local solution, honestly flagged as prior-dependent
    x = np.array([2.0, 3.0])
    r = np.linalg.norm(ANCHORS[:2] - x, axis=1)
    fix = TaylorSeriesLocator().locate(ANCHORS[:2], r, np.full(2, 0.05), initial=x + 0.3)
    assert not fix.ok and "2 anchors" in fix.reason
    np.testing.assert_allclose(fix.position, x, atol=1e-6)
    assert np.all(np.isfinite(fix.cov)) and np.all(np.linalg.eigvalsh(fix.cov) > 0)


@settings(max_examples=40, deadline=None)
@given(
    anchors=st.lists(st.tuples(st.floats(-20, 20), st.floats(-20, 20)), min_size=0, max_size=6),
    ranges=st.lists(st.floats(0.0, 50.0), min_size=6, max_size=6),
    method=st.sampled_from(sorted(LOCATORS)),
    collapse=st.booleans(),
)
def test_any_geometry_gives_a_fix_or_a_flag_never_an_exception(anchors, ranges, method, collapse):
    a = np.array(anchors, float).reshape(-1, 2)
    if collapse and len(a):
        a[:, 1] = 0.5 * a[:, 0]  # all on one line
    r = np.array(ranges[: len(a)])
    fix = LOCATORS[method]().locate(a, r, np.full(len(a), 0.1))
    assert fix.cov.shape == (2, 2)
    if fix.ok:
        assert np.all(np.isfinite(fix.position)) and np.all(np.isfinite(fix.cov))
        assert np.all(np.linalg.eigvalsh(0.5 * (fix.cov + fix.cov.T)) > 0)
    else:
        assert fix.reason


def test_mse_test_false_alarm_rate_is_alpha_and_nlos_variance_is_caught(rng):
    test = MseNlosTest(los_std=0.02, false_alarm=0.05, order=2)
    t = np.arange(30) * 0.1
    trend = 3.0 + 0.4 * t - 0.05 * t**2  # a moving node: the polynomial absorbs the motion
    los = [test.is_nlos(t, trend + rng.normal(0, 0.02, t.size)) for _ in range(2000)]
    nlos = [test.is_nlos(t, trend + 0.3 + rng.normal(0, 0.06, t.size)) for _ in range(500)]
    assert np.mean(los) == pytest.approx(0.05, abs=0.015)
    assert np.mean(nlos) > 0.99
    assert not test.is_nlos(t[:3], trend[:3] + 5.0 * np.arange(3))  # too few: not tested


def test_kalman_filters_follow_a_constant_velocity_node(rng):
    pos, rng_kf = PositionKalmanTracker(q=0.1), RangeKalmanTracker(q=0.1)
    errs = []
    for k in range(100):
        t = 0.1 * k
        truth = np.array([1.0 + 0.5 * t, 2.0 - 0.2 * t])
        state, _ = pos.step(t, truth + rng.normal(0, 0.05, 2), np.eye(2) * 0.05**2)
        r, s = rng_kf.step(t, 3.0 + 0.3 * t + rng.normal(0, 0.05), 0.05)
        if k > 20:
            errs.append(state[[0, 2]] - truth)
            assert abs(r - (3.0 + 0.3 * t)) < 4 * s
    assert np.sqrt(np.mean(np.sum(np.square(errs), axis=1))) < 0.05  # below the fix noise
    np.testing.assert_allclose(state[[1, 3]], [0.5, -0.2], atol=0.1)
    assert pos.predict(20.0) is not None


def test_localization_core_imports_nothing_impure():
    root = Path(__file__).resolve().parents[3]
    forbidden = {"zenoh", "msgpack", "mcap", "serial", "time", "datetime", "socket", "threading"}
    files = [*(root / "fusion_center" / "localization").glob("*.py")]
    files += [root / "node_agent" / "dsp" / "rttoa.py", root / "sim_nodes" / "ranging.py"]
    for path in files:
        imported = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                imported |= {a.name.split(".")[0] for a in node.names}
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                imported.add(node.module.split(".")[0])
        assert not imported & forbidden, f"{path.name} imports {sorted(imported & forbidden)}"


def test_clipped_mse_ignores_one_outlier_the_plain_one_does_not(rng):
    t = np.arange(30) * 0.1
    r = 4.0 + 0.3 * t + rng.normal(0, 0.005, t.size)
    r[12] += 0.3  # one multipath outlier of a LOS link: 10 sigma
    assert MseNlosTest(los_std=0.03).is_nlos(t, r)
    assert not MseNlosTest(los_std=0.03, clip=3.0).is_nlos(t, r)


def test_equilibrated_weighted_solve_is_the_plain_one():
    from fusion_center.localization.estimators import _solve_weighted

    rng = np.random.default_rng(3)
    design = np.column_stack([rng.normal(size=(6, 2)) * [10.0, 0.01], np.ones(6)])
    rhs, w = rng.normal(size=6), rng.uniform(0.1, 10.0, 6)
    x0, c0 = _solve_weighted(design, rhs, w)
    x1, c1 = _solve_weighted(design, rhs, w, equilibrate=True)
    np.testing.assert_allclose(x1, x0, rtol=1e-9)
    np.testing.assert_allclose(c1, c0, rtol=1e-9)
    # a rank-deficient design stays singular after scaling
    assert _solve_weighted(np.ones((4, 2)), rhs[:4], w[:4], equilibrate=True) is None
