"""Wiener deconvolution (eq. (15)) and pulse separation: DCM vs CLEAN vs matched filter."""

from __future__ import annotations

import numpy as np
import pytest

from fusion_center.objects.pulses import (
    CleanSeparator,
    DynamicCorrelationSeparator,
    MatchedFilterPeakPicker,
)
from node_agent.dsp.deconvolution import WienerDeconvolver
from sim_nodes.radar import MSequenceRadar, RadarConfig

FS = 7e9
N = 256


@pytest.fixture(scope="module")
def radar() -> MSequenceRadar:
    return MSequenceRadar(RadarConfig(noise=False))


def pulses(radar: MSequenceRadar, delays: list[float], amps: list[float]) -> np.ndarray:
    """Radar impulse response of point echoes at sample delays, first N samples."""
    spec = radar.path_spectrum(np.asarray(delays) / FS, amps)
    return radar.impulse_response(spec[None])[0].astype(float)[:N]


def reference(radar: MSequenceRadar) -> np.ndarray:
    spec = radar.path_spectrum(np.zeros(1), np.ones(1))
    return np.roll(radar.impulse_response(spec[None])[0].astype(float), 32)[:65]


def test_wiener_deconvolution_splits_a_merged_echo_pair() -> None:
    # A wide Gaussian pulse (sigma 3 samples) blurs echoes at samples 100 and 106 into one
    # peak; eq. (15) against that pulse restores two peaks at the right samples.
    t = np.arange(-16, 17)
    ref = np.exp(-0.5 * (t / 3.0) ** 2)
    x = np.zeros(N)
    x[100], x[106] = 1.0, 0.8
    y = np.real(np.fft.ifft(np.fft.fft(x) * np.fft.fft(np.roll(np.pad(ref, (0, N - 33)), -16))))
    y += np.random.default_rng(1).normal(0, 1e-4, N)
    peaks_in = np.flatnonzero((y > np.roll(y, 1)) & (y > np.roll(y, -1)) & (y > 0.3))
    assert len(peaks_in) == 1
    out = WienerDeconvolver(ref, N, snr_db=40.0, centre=16).apply(y)
    peaks = np.flatnonzero(
        (out > np.roll(out, 1)) & (out > np.roll(out, -1)) & (out > 0.3 * out.max())
    )
    assert peaks.tolist() == [100, 106]


def test_wiener_rejects_wrong_length() -> None:
    with pytest.raises(ValueError, match="samples"):
        WienerDeconvolver(np.ones(5), 64).apply(np.zeros(32))


def test_dcm_resolves_pulses_closer_than_the_resolution(radar: MSequenceRadar) -> None:
    # 1/B = 2 samples at B = 3.5 GHz; the echoes are 1 sample (half a resolution cell) apart.
    rng = np.random.default_rng(3)
    ref = reference(radar)
    dcm = DynamicCorrelationSeparator(ref, N, centre=32)
    mf = MatchedFilterPeakPicker(ref, N, centre=32)
    clean = CleanSeparator(ref, N, centre=32)
    hits = {"dcm": 0, "mf": 0, "clean": 0}
    for _ in range(10):
        d0 = 100 + rng.uniform()
        y = pulses(radar, [d0, d0 + 1.0], [1.0, 0.8]) + rng.normal(0, 0.01, N)
        for name, m in (("dcm", dcm), ("mf", mf), ("clean", clean)):
            p = m.separate(y, 0.01)
            if len(p.delays) >= 2:
                top = np.sort(p.delays[np.argsort(-np.abs(p.amplitudes))[:2]])
                if abs(top[0] - d0) < 0.25 and abs(top[1] - d0 - 1.0) < 0.25:
                    hits[name] += 1
    assert hits["dcm"] == 10
    assert hits["mf"] == 0


def test_dcm_single_pulse_terminates_with_one(radar: MSequenceRadar) -> None:
    rng = np.random.default_rng(4)
    y = pulses(radar, [120.3], [0.5]) + rng.normal(0, 0.01, N)
    p = DynamicCorrelationSeparator(reference(radar), N, centre=32).separate(y, 0.01)
    assert len(p.delays) == 1
    assert p.delays[0] == pytest.approx(120.3, abs=0.13)
    assert p.amplitudes[0] == pytest.approx(0.5, rel=0.05)


def test_clean_and_mf_separate_well_spaced_pulses(radar: MSequenceRadar) -> None:
    y = pulses(radar, [90.0, 110.0], [1.0, 0.5])
    for cls in (CleanSeparator, MatchedFilterPeakPicker):
        p = cls(reference(radar), N, centre=32).separate(y, 0.01)
        top = np.sort(p.delays[np.argsort(-np.abs(p.amplitudes))[:2]])
        assert np.allclose(top, [90.0, 110.0], atol=0.13)
