"""The multipath-aware delay bound (equivalent Fisher information, Shen & Win)."""

import math

import numpy as np
import pytest

from fusion_center.localization import multipath_delay_bound

FS = 7e9
SIG_T = math.sqrt(math.log(10.0)) / (2 * math.pi * 3.5e9)  # the lab_los baseband pulse


def bounds(delays_ns, amps, *, real=True, f_off=0.0, sigma=1e-2):
    return multipath_delay_bound(
        np.asarray(delays_ns) * 1e-9,
        np.asarray(amps, complex),
        noise_sigma=sigma,
        fs=FS,
        n=256,
        first_index=100.3,
        pulse_sigma=SIG_T,
        offset_frequency=f_off,
        real_output=real,
    )


def test_single_path_bound_matches_a_monte_carlo_ml_fit():
    # the bound of one real Gaussian pulse against the spread of its least-squares delay
    rng = np.random.default_rng(3)
    single, multi = bounds([0.0], [1.0])
    assert multi == pytest.approx(single)
    k = np.arange(256)
    t0 = 100.3
    grid = t0 + np.linspace(-0.06, 0.06, 1201)
    g = np.exp(-0.5 * ((k[None, :] - grid[:, None]) / (SIG_T * FS)) ** 2)
    clean = np.exp(-0.5 * ((k - t0) / (SIG_T * FS)) ** 2)
    y = clean + 1e-2 * rng.standard_normal((400, 256))
    # ML with unknown amplitude: maximise the normalised correlation over the grid
    est = grid[np.argmax((y @ g.T) ** 2 / np.sum(g * g, axis=1), axis=1)]
    spread = np.std(np.array(est) - t0) / FS
    assert spread == pytest.approx(single, rel=0.15)


def test_far_paths_change_nothing_and_near_paths_raise_the_bound():
    single, alone = bounds([0.0], [1.0])
    _, far = bounds([0.0, 5.0], [1.0, 0.8])
    _, near = bounds([0.0, 0.08], [1.0, 0.5])
    _, closer = bounds([0.0, 0.02], [1.0, 0.5])
    assert far == pytest.approx(alone, rel=1e-6)
    assert near > 1.5 * single
    assert closer > 5.0 * near


def test_complex_baseband_amplitude_phase_is_a_nuisance():
    # complex samples carry twice the noise components and the signal's phase is unknown:
    # the single-path bound with a carrier offset of 0 equals the real-baseband one
    real_single, _ = bounds([0.0], [1.0])
    cplx_single, cplx_multi = bounds([0.0], [1.0 + 0.0j], real=False)
    assert cplx_single == pytest.approx(real_single, rel=1e-6)
    assert cplx_multi == pytest.approx(cplx_single)
    _, near = bounds([0.0, 0.08], [1.0, 0.5j], real=False)
    assert near > 1.5 * cplx_single


def test_lab_los_error_budget_puts_the_median_at_the_bound_and_the_tail_beyond():
    from uwbnet.toa_budget import budget

    out = budget("lab_los", duration=1.0, seed=3)
    assert out["rounds"] == 40 and out["missed"] == 0
    err, bound = out["range_error_mm"], out["range_bound_mm"]
    # the typical round is noise-limited: its error is at the single-path bound's scale
    assert 0.2 < bound["single_path_rms"] < 0.5
    assert err["p50_abs"] < 2.0 * bound["single_path_rms"]
    # the multipath bound is never below the single-path one
    assert bound["multipath_p50"] >= bound["single_path_p50"]
    shares = out["share_of_squared_error"]
    assert sum(shares.values()) == pytest.approx(1.0, abs=1e-3)
