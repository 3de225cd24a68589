"""Stationary-target detection along a track (Section 8.2): eq. (19), (21), (22)."""

from __future__ import annotations

import numpy as np
import pytest

from fusion_center.imaging.stationary import (
    bistatic_delays,
    detection_probability,
    detection_table,
    gaussian_pulse,
    matched_filter,
    np_threshold,
    system_pulse,
    time_shift_accumulate,
)

FS = 20e9


def test_time_shift_aligns_echoes_at_subsample_delays() -> None:
    pulse = system_pulse(FS)
    half = (pulse.size - 1) // 2
    n = 400
    delays = np.array([5.3e-9, 6.1e-9, 7.77e-9])
    t = np.arange(n) / FS
    h = gaussian_pulse(t[None, :] - delays[:, None])
    y = time_shift_accumulate(h, delays, FS, 0.0, half)
    assert y.shape == (pulse.size,)
    # Aligned; linear interpolation of a 6 GHz carrier at 20 GHz loses some peak amplitude.
    assert np.argmax(y) == half and y[half] > 0.8
    wrong = time_shift_accumulate(h, delays[::-1], FS, 0.0, half)
    assert matched_filter(wrong, pulse) < 0.7 * matched_filter(y, pulse)


def test_neyman_pearson_threshold_and_pd() -> None:
    assert np_threshold(2.0, 1e-3) == pytest.approx(2.0 * 3.0902, rel=1e-4)
    assert detection_probability(0.0, 1e-3) == pytest.approx(1e-3)
    pd = detection_probability(10 ** (np.array([0.0, 10.0, 15.0]) / 10), 1e-3)
    assert np.all(np.diff(pd) > 0) and pd[-1] > 0.9


def test_delays_are_bistatic_paths() -> None:
    d = bistatic_delays([[0, 0, 0]], [[2, 0, 0]], [1, 1, 0])
    assert d[0] * 299792458.0 == pytest.approx(2 * np.sqrt(2))


def test_detection_table_pd_rises_with_sinr_and_accumulation_gains() -> None:
    rows = detection_table([-12.0, -3.0], trials=3000, seed=1)
    low, high = rows
    assert low.pd_simulated < high.pd_simulated and high.pd_simulated > 0.8
    # 16 positions: the output SINR is well above the single-response SINR.
    assert high.output_sinr_db - high.sinr_db > 9.0
    assert abs(high.pd_theory - high.pd_simulated) < 0.1
    assert 0 < low.pf_simulated < 0.02
