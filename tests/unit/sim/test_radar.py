"""M-sequence radar model: sequence, correlation, pulse position, noise."""

from __future__ import annotations

import numpy as np
import pytest

from sim_nodes.radar import ILMSENS_TAPS_12, C, MSequenceRadar, RadarConfig, mlbs

from .conftest import peak

HALF_CHIP_M = C / 7e9 / 2  # 2.14 cm of bistatic range


def test_lfsr_equals_golden_ilmsens_sequence(golden_mlbs: np.ndarray) -> None:
    s = mlbs()
    assert s.dtype == np.int8
    assert s.shape == (4095,)
    np.testing.assert_array_equal(s, golden_mlbs)


def test_other_seed_gives_a_cyclic_shift_of_the_golden_sequence(golden_mlbs: np.ndarray) -> None:
    s = mlbs(ILMSENS_TAPS_12, (1,) * 12)
    corr = np.fft.irfft(np.fft.rfft(golden_mlbs) * np.conj(np.fft.rfft(s)), n=4095)
    shift = int(np.argmax(corr))
    assert round(corr[shift]) == 4095
    np.testing.assert_array_equal(np.roll(s, shift), golden_mlbs)


def test_periodic_autocorrelation_is_4095_and_minus_one() -> None:
    s = mlbs().astype(float)
    acf = np.fft.irfft(np.abs(np.fft.rfft(s)) ** 2, n=4095)
    assert acf[0] == pytest.approx(4095)
    np.testing.assert_allclose(acf[1:], -1.0, atol=1e-8)
    assert int((s > 0).sum()) == 2048


def test_reference_spectrum_is_the_ilmsens_phase_only_reference(
    radar: MSequenceRadar, golden_reference: dict[str, np.ndarray]
) -> None:
    ref = golden_reference["ref_spec"]  # full FFT length, DC = 0
    ours = radar.reference_spectrum * np.sqrt(4096)
    np.testing.assert_allclose(ours, ref[: radar.n_bins], atol=1e-9)


@pytest.mark.parametrize("t0", [0.0, 3.3e-9, -1.234e-9])
@pytest.mark.parametrize("bistatic", [2.0, 7.3131, 18.4567])
def test_point_scatterer_peaks_at_its_bistatic_range(t0: float, bistatic: float) -> None:
    radar = MSequenceRadar(RadarConfig(t0=t0))
    h = radar.impulse_response(radar.path_spectrum([[bistatic / C]], [[0.01]]))
    k = int(np.argmax(np.abs(h[0])))
    assert abs(C * (t0 + k / 7e9) - bistatic) <= HALF_CHIP_M
    k_fine, _ = peak(h[0])
    assert abs(C * (t0 + k_fine / 7e9) - bistatic) < 0.002  # sub-sample delay is exact


def test_system_pulse_has_unit_peak_on_the_grid(radar: MSequenceRadar) -> None:
    h = radar.impulse_response(radar.path_spectrum([[100 / 7e9]], [[1.0]]))
    assert h[0, 100] == pytest.approx(1.0, rel=1e-5)
    assert np.argmax(h[0]) == 100


def test_fast_synthesis_equals_explicit_receive_and_correlate(radar: MSequenceRadar) -> None:
    spec = radar.path_spectrum([[3.1e-8, 5.77e-8]], [[0.2, -0.05]])
    h_fast = radar.impulse_response(spec)
    h_explicit = radar.correlate(radar.receive(spec))
    np.testing.assert_allclose(h_fast, h_explicit, atol=1e-6)


def test_noise_std_matches_the_snr_definition(radar: MSequenceRadar) -> None:
    zero = np.zeros((2, radar.n_bins), complex)
    h = radar.impulse_response(zero, np.random.default_rng(7))
    # Same noise generated the explicit way: white in the receive domain, then correlated.
    h_explicit = radar.correlate(radar.receive(zero, np.random.default_rng(8)))
    expected = radar.reference_amplitude * 10 ** (-radar.config.snr_db / 20)
    assert radar.noise_std == pytest.approx(expected)
    assert h.std() == pytest.approx(expected, rel=0.05)
    assert h_explicit.std() == pytest.approx(expected, rel=0.05)
    # Receive-domain noise is larger by the correlation gain sqrt(n) (band factor aside).
    assert radar.receive_noise_std / radar.noise_std > np.sqrt(4095)


def test_noise_bins_are_independent_standard_circular_gaussians(radar: MSequenceRadar) -> None:
    # The Box-Muller draws must give what two standard_normal draws per bin gave.
    rng = np.random.default_rng(5)
    v = np.stack([radar.noise_spectrum(rng, 2) for _ in range(200)])  # (200, 2, n_bins)
    scale = radar._noise_scale
    band = scale > 0.5 * scale.max()
    z = v[..., band] / scale[band]
    re, im = z.real.ravel().astype(float), z.imag.ravel().astype(float)
    assert re.var() == pytest.approx(1.0, rel=0.02) and im.var() == pytest.approx(1.0, rel=0.02)
    assert abs(np.mean(re * im)) < 0.01 and abs(re.mean()) < 0.01
    # Gaussian shape: kurtosis 3 and the two-sided 3-sigma tail of 0.27 %.
    assert np.mean(re**4) / re.var() ** 2 == pytest.approx(3.0, abs=0.05)
    assert np.mean(np.abs(np.concatenate([re, im])) > 3.0) == pytest.approx(0.0027, rel=0.15)
    # Bins and receivers are uncorrelated.
    assert abs(np.mean(z[:, 0, 1:].real * z[:, 0, :-1].real)) < 0.01
    assert abs(np.mean(z[:, 0].real * z[:, 1].real)) < 0.01


def test_reference_target_reaches_the_configured_snr() -> None:
    radar = MSequenceRadar(RadarConfig(snr_db=20.0))
    d = radar.config.snr_reference_distance
    spec = radar.path_spectrum([[2 * d / C]], [[radar.reference_amplitude]])
    h = radar.impulse_response(spec)
    _, value = peak(h[0])
    assert value / radar.noise_std == pytest.approx(10.0, rel=0.01)


def test_blocked_path_spectrum_equals_the_direct_sum(radar: MSequenceRadar) -> None:
    rng = np.random.default_rng(11)
    delays = rng.uniform(0.0, 2 * 4095 / 7e9, size=(2, 9))  # beyond one period too: wraps
    amps = rng.normal(size=(2, 9))
    f = radar.frequencies
    direct = np.sum(amps[..., None] * np.exp(-2j * np.pi * f * delays[..., None]), axis=1)
    np.testing.assert_allclose(radar.path_spectrum(delays, amps), direct, atol=2e-5)


def test_window_noise_has_the_std_and_correlation_of_the_full_period_noise():
    radar = MSequenceRadar()
    m, scale = radar.window_grid(1051)
    assert 1051 + 128 <= m < radar.config.n and scale.shape == (m // 2 + 1,)
    rngs = [np.random.default_rng(i) for i in range(300)]
    w = radar.window_noise(rngs, 2, 1051)
    assert w.shape == (300, 2, 1051) and w.dtype == np.float32
    full = np.fft.irfft(radar.noise_spectrum(np.random.default_rng(7), 600), n=radar.config.n)
    assert abs(w.std() / radar.noise_std - 1) < 0.01
    assert abs(full.std() / radar.noise_std - 1) < 0.01

    def corr(x, lag):
        return float(np.mean(x[..., :-lag] * x[..., lag:]) / np.mean(x * x))

    # the band's correlation (0.08, -0.20, 0.05 at lags 1-3), within the draws' error
    for lag in (1, 2, 3, 4, 8, 20):
        assert abs(corr(w, lag) - corr(full, lag)) < 0.01, lag
    # the same generator draws the same noise; a window as long as the period is the radar's grid
    again = radar.window_noise([np.random.default_rng(0)], 2, 1051)
    np.testing.assert_array_equal(again[0], w[0])
    assert radar.window_grid(4095)[0] == 4095
    with pytest.raises(ValueError, match="window"):
        radar.window_grid(0)
