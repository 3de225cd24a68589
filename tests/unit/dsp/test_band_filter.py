import numpy as np
import pytest

from node_agent.dsp import NodeDsp, NodeDspConfig, RadarParams
from node_agent.dsp.band_filter import BandMatchedFilter, band_pulse, matched_gain

from .synth import M_SEQUENCE, bat_geometry

# an oversampled complex baseband: 3 GHz sampling of a 1.3 GHz band around a 4 GHz carrier
COMPLEX = RadarParams(fs=3e9, n=800, t0=10e-9, f_low=3.35e9, f_high=4.65e9, fc=4.0e9)


def test_filter_is_off_where_the_band_fills_the_sampling():
    # the chapter's M-sequence radar: 0-3.5 GHz sampled at 7 GHz, its output already the
    # correlation (matched) one
    assert 10 * np.log10(matched_gain(band_pulse(M_SEQUENCE, complex_input=False))) < 1.0
    dsp = NodeDsp(bat_geometry(), M_SEQUENCE)
    dsp.process(0.0, np.zeros((2, M_SEQUENCE.n), np.float32))
    assert dsp._filter is None


def test_oversampled_complex_baseband_gains_about_3_db():
    band = BandMatchedFilter(COMPLEX, complex_input=True)
    # Gaussian envelope, sigma_t = sqrt(ln 10) / (2 pi 0.65 GHz) = 0.37 ns = 1.11 samples:
    # sum |s|^2 / max |s|^2 = sqrt(pi) sigma = 1.97
    assert band.gain == pytest.approx(np.sqrt(np.pi) * 1.1145, rel=0.02)


def test_white_noise_keeps_its_variance(rng):
    band = BandMatchedFilter(COMPLEX, complex_input=True)
    noise = (rng.standard_normal((2, 20000)) + 1j * rng.standard_normal((2, 20000))).astype(
        np.complex64
    )
    out = band.apply(noise)
    assert out.dtype == np.complex64 and out.shape == noise.shape
    assert np.var(out[:, 100:-100]) == pytest.approx(np.var(noise), rel=0.03)


def test_echo_gains_the_predicted_snr_without_moving(rng):
    band = BandMatchedFilter(COMPLEX, complex_input=True)
    pulse = band_pulse(COMPLEX, complex_input=True)
    k = pulse.size // 2
    h = np.zeros((1, COMPLEX.n), np.complex64)
    h[0, 400 - k : 401 + k] = pulse  # peak 1 at sample 400
    out = band.apply(h)
    assert int(np.argmax(np.abs(out[0]))) == 400  # symmetric kernel: no range shift
    noise = (rng.standard_normal((1, 50000)) + 1j * rng.standard_normal((1, 50000))) / np.sqrt(2)
    noise_out = band.apply(noise.astype(np.complex64))
    snr_in = 1.0 / np.var(noise)
    snr_out = np.abs(out[0, 400]) ** 2 / np.var(noise_out[0, 100:-100])
    assert 10 * np.log10(snr_out / snr_in) == pytest.approx(band.gain_db, abs=0.3)


def _detection_rate(gain_db: float | None, amplitude: float, seed: int) -> float:
    """Fraction of frames where both receivers report a walking person's range."""
    rng = np.random.default_rng(seed)
    radar = COMPLEX
    config = NodeDspConfig(range_offset=0.0, band_filter_min_gain_db=gain_db)
    dsp = NodeDsp(bat_geometry(), radar, config)
    pulse = band_pulse(radar, complex_input=True)
    k = pulse.size // 2
    axis = radar.ranges()
    found = 0
    for f in range(150):
        # unit-power complex white noise
        h = (rng.standard_normal((2, radar.n)) + 1j * rng.standard_normal((2, radar.n))) * 0.7071
        r = 9.0 + 0.02 * f  # bistatic range, walking away at 1 m/s and 50 Hz
        for row in range(2):
            i = int(np.searchsorted(axis, r + 0.1 * row))
            h[row, i - k : i + k + 1] += amplitude * pulse
        res = dsp.process(f / 50, h.astype(np.complex64))
        if f >= 50:
            found += all(
                rr.size and np.abs(rr - (r + 0.1 * row)).min() < 0.3
                for row, rr in enumerate(res.ranges)
            )
    return found / 100


def test_filter_finds_weak_echoes_of_an_oversampled_complex_radar():
    # peak SNR 13 dB per sample: the filter's ~3 dB decide whether the echo is found
    with_filter = _detection_rate(1.0, 4.5, seed=3)
    without = _detection_rate(None, 4.5, seed=3)
    assert with_filter >= 0.75, (with_filter, without)
    assert with_filter - without >= 0.25, (with_filter, without)
