"""ToA estimators: simulate a known first path in noise, recover it (Section 4.1)."""

from __future__ import annotations

import numpy as np
import pytest

from node_agent.dsp.toa import (
    ESTIMATORS,
    MIN_PADDING,
    AdaptiveThresholdToaEstimator,
    MpdToaEstimator,
    PeakToaEstimator,
    ThresholdToaEstimator,
    envelope,
    make_toa_estimator,
    measured,
    noise_sigma,
)

from .cir import DW1000, M_SEQUENCE, PASSBAND, synth_cir

RADARS = {
    "dw1000_c8": (DW1000, True),
    "passband_c8": (PASSBAND, True),
    "msequence_f4": (M_SEQUENCE, False),
}


def _first(radar, fraction: float = 0.6) -> float:
    """A first-path delay off the sample grid (0.37 sample past a sample), s."""
    return (round(fraction * radar.n) + 0.37) / radar.fs


@pytest.mark.parametrize("method", sorted(ESTIMATORS))
@pytest.mark.parametrize("radar_name", sorted(RADARS))
def test_single_path_recovered_to_a_fraction_of_a_sample(
    method: str, radar_name: str, rng: np.random.Generator
) -> None:
    radar, cplx = RADARS[radar_name]
    d0 = _first(radar)
    h = synth_cir(radar, [d0], [1.0], 35.0, rng, rows=64, complex_input=cplx)
    est = make_toa_estimator(method, radar).estimate(h)
    err = (est.toa - d0) * radar.fs  # in samples
    # 35 dB: every estimator finds the only path; the log-parabola refinement is exact for
    # the Gaussian pulse, so what is left is noise: well under a fifth of a sample (for real
    # signals the rectified carrier of a band-pass pulse is not Gaussian: half a sample)
    tol = 0.2 if cplx or radar.f_low == 0.0 else 0.5
    assert np.all(np.isfinite(err))
    assert np.median(np.abs(err)) < tol / 2
    assert np.mean(np.abs(err) < tol) >= 0.95
    # (off-grid sampling of the narrow real baseband pulse loses up to 3 dB of its peak)
    assert np.median(est.snr_db) > 35.0 - 4.0
    assert np.all((est.quality >= 0.0) & (est.quality <= 1.0))


@pytest.mark.parametrize("radar_name", sorted(RADARS))
def test_noise_sigma_from_the_impulse_response(radar_name: str, rng: np.random.Generator) -> None:
    radar, cplx = RADARS[radar_name]
    h = synth_cir(radar, [_first(radar)], [1.0], 30.0, rng, rows=32, complex_input=cplx)
    sigma = noise_sigma(envelope(h), complex_input=cplx)
    # synth_cir scales the noise to a per-component std of 10^(-30/20) of the peak
    assert np.median(sigma) == pytest.approx(10 ** (-30 / 20), rel=0.1)


def test_rows_are_independent(rng: np.random.Generator) -> None:
    delays = np.array([[300.2], [500.7], [812.5]]) / DW1000.fs
    h = synth_cir(DW1000, delays, np.ones((3, 1)), 35.0, rng, rows=3)
    est = MpdToaEstimator(DW1000).estimate(h)
    np.testing.assert_allclose(est.toa, delays[:, 0], atol=0.2 / DW1000.fs)


def test_peak_is_late_by_the_excess_delay_of_the_strongest_path(rng: np.random.Generator) -> None:
    d0 = _first(DW1000)
    h = synth_cir(DW1000, d0 + np.array([0.0, 6e-9]), [0.3, 1.0], 35.0, rng, rows=32)
    err = PeakToaEstimator(DW1000).estimate(h).toa - d0
    assert np.median(err) == pytest.approx(6e-9, abs=0.2e-9)


@pytest.mark.parametrize("radar_name", sorted(RADARS))
def test_mpd_beats_fixed_threshold_on_nlos_channels(
    radar_name: str, rng: np.random.Generator
) -> None:
    """A weak first path (-14 dB) before stronger multipath: the fixed threshold (half the
    maximum) skips it and is late by the strongest path's excess delay; MPD, with its
    threshold set from the noise, finds it."""
    radar, cplx = RADARS[radar_name]
    d0 = _first(radar)
    delays = d0 + np.array([0.0, 6e-9, 9e-9, 15e-9])
    amps = np.array([0.2, 1.0, 0.6, 0.7])
    h = synth_cir(radar, delays, amps, 35.0, rng, rows=200, complex_input=cplx)
    errors = {
        name: np.abs(cls(radar).estimate(h).toa - d0)
        for name, cls in (("mpd", MpdToaEstimator), ("threshold", ThresholdToaEstimator))
    }
    within = {name: float(np.mean(e < 1e-9)) for name, e in errors.items()}
    assert within["mpd"] >= 0.9
    assert within["threshold"] <= 0.1
    assert np.median(errors["mpd"]) < 0.25 * np.median(errors["threshold"])


def test_adaptive_threshold_false_alarm_rate_is_as_configured(rng: np.random.Generator) -> None:
    """On strong single paths, the only way to err by more than a pulse is a noise sample
    crossing the threshold inside the searched window: about ``pfa`` of the rows."""
    d0 = _first(DW1000)
    h = synth_cir(DW1000, [d0], [1.0], 25.0, rng, rows=1000)
    pfa = 0.05
    est = AdaptiveThresholdToaEstimator(DW1000, pfa=pfa, dynamic_range_db=60.0).estimate(h)
    early = np.mean(est.toa < d0 - 2e-9)
    # binomial(1000, 0.05): 3 standard deviations are 0.02; the effective count of
    # independent samples (B / fs) is an approximation: allow a factor of two
    assert 0.5 * pfa - 0.02 < early < 2.0 * pfa + 0.02


def test_invalid_parameters_raise() -> None:
    with pytest.raises(ValueError, match="fraction"):
        ThresholdToaEstimator(DW1000, fraction=0.0)
    with pytest.raises(ValueError, match="pfa"):
        AdaptiveThresholdToaEstimator(DW1000, pfa=1.0)
    with pytest.raises(ValueError, match="search_back"):
        MpdToaEstimator(DW1000, search_back=0.0)
    with pytest.raises(ValueError, match="unknown ToA method"):
        make_toa_estimator("music", DW1000)


def test_a_stronger_reflection_within_the_pulse_lobe_does_not_take_the_first_path(rng):
    # M-sequence radar: a reflection 0.25 ns (3.6 pulse sigmas) after the direct path and
    # twice as strong; both lie within the 2/B lobe searched after the threshold crossing
    radar = M_SEQUENCE
    d0 = _first(radar)
    h = synth_cir(radar, [d0, d0 + 0.25e-9], [1.0, 2.0], 40.0, rng, rows=64, complex_input=False)
    err = (AdaptiveThresholdToaEstimator(radar).estimate(h).toa - d0) * radar.fs
    assert np.median(np.abs(err)) < 0.1  # samples: the direct path, not the reflection


def test_known_pulse_refinement_reaches_the_delay_bound_of_one_path(rng):
    # one path at random sampling phases, 30 dB: the delay's Cramér-Rao bound for the sampled
    # Gaussian pulse with unknown amplitude, averaged over the phase (as the simulator's
    # truth computes it), against the estimator's RMS error
    from node_agent.dsp.band_filter import pulse_sigma

    radar = M_SEQUENCE
    w = pulse_sigma(radar, complex_input=False) * radar.fs  # envelope sigma, samples
    d0 = (round(0.6 * radar.n) + rng.uniform(0, 1, 400)) / radar.fs
    h = synth_cir(radar, d0[:, None], np.ones((400, 1)), 30.0, rng, rows=400, complex_input=False)
    err = (AdaptiveThresholdToaEstimator(radar).estimate(h).toa - d0) * radar.fs
    var = []
    for phase in rng.uniform(0, 1, 64):
        k = np.arange(-6, 7) - phase
        g = np.exp(-0.5 * (k / w) ** 2)
        jac = np.column_stack([k / w**2 * g, g])  # d/d(delay) and d/d(amplitude), per sample
        var.append(np.linalg.inv(jac.T @ jac)[0, 0])
    sigma = 10 ** (-30 / 20)  # synth_cir: noise std relative to the peak
    bound = sigma * np.sqrt(np.mean(var))  # samples
    rms = float(np.sqrt(np.mean(err**2)))
    assert rms < 1.5 * bound, (rms, bound)


@pytest.mark.parametrize("method", sorted(ESTIMATORS))
def test_zero_padding_is_not_taken_for_noise(method: str, rng: np.random.Generator) -> None:
    """A recording that pads the receiver's window with exact zeros (here the first 400 of
    1016 taps): the zeros are no noise samples. Counted in the noise median they pull the
    threshold under the noise, and noise 100 ns before the path passes for the first path."""
    d0 = _first(DW1000, 0.73)
    # a direct path with a reflection 12 ns later: a LOS channel with the path at tap 742
    h = synth_cir(DW1000, [d0, d0 + 12e-9], [1.0, 0.5], 30.0, rng, rows=64)
    h[:, :400] = 0
    sigma = noise_sigma(envelope(h), complex_input=True, valid=h != 0)
    assert np.median(sigma) == pytest.approx(10 ** (-30 / 20), rel=0.1)
    est = make_toa_estimator(method, DW1000).estimate(h)
    err = (est.toa - d0) * DW1000.fs
    # (unpadded, MPD's own threshold lets 3 of these 64 rows start on noise; without the
    # exclusion 38 of 64 start early with MPD and the adaptive threshold)
    assert np.mean(np.abs(err) < 0.5) >= 0.9


@pytest.mark.parametrize(("radar_name", "lsb"), [("dw1000_c8", 0.7), ("msequence_f4", 2.0)])
def test_quantised_noise_zeros_inside_the_window_are_noise_samples(
    radar_name: str, lsb: float, rng: np.random.Generator
) -> None:
    """An accumulator-like readout rounds to integers: at a noise std of 0.7 LSB (complex) or
    2 LSB (real) a fifth to a third of the samples are exactly 0. They are noise samples, not
    padding: only the zero runs before the first and after the last non-zero sample are."""
    radar, is_complex = RADARS[radar_name]
    h = synth_cir(radar, [_first(radar)], [1.0], 30.0, rng, rows=16)
    scale = lsb / 10 ** (-30 / 20)
    h = np.round(h.real * scale) + (1j * np.round(h.imag * scale) if is_complex else 0)
    h = h.astype(np.complex64 if is_complex else np.float32)
    assert np.mean(h == 0) > 0.1  # the premise: many exact zeros inside the window
    env = envelope(h)
    np.testing.assert_array_equal(
        noise_sigma(env, complex_input=is_complex, valid=measured(h)),
        noise_sigma(env, complex_input=is_complex),
    )
    # each row padded differently; runs shorter than MIN_PADDING (a chance run of quantised
    # noise) are kept as noise samples
    lead = np.array([0, 3, 16, 100] * 4)
    trail = np.array([50, 0, 15, 16] * 4)
    padded = h.copy()
    cols = np.arange(h.shape[1])
    padded[(cols[None, :] < lead[:, None]) | (cols[None, :] >= h.shape[1] - trail[:, None])] = 0
    rows = np.arange(h.shape[0])
    padded[rows, lead] = padded[rows, h.shape[1] - trail - 1] = 1  # the window's edges: not 0
    assert MIN_PADDING == 16  # the runs of 3 and 15 zeros below are noise, 16 and more padding
    start = np.where(lead >= 16, lead, 0)
    stop = np.where(trail >= 16, h.shape[1] - trail, h.shape[1])
    np.testing.assert_array_equal(
        measured(padded), (cols >= start[:, None]) & (cols < stop[:, None])
    )
    assert not np.any(measured(np.zeros((2, 8))))  # an all-zero row has no measured sample
    assert measured(np.zeros((2, 0))) is None
