import numpy as np
import pytest

from node_agent.dsp import (
    ExponentialBackgroundSubtractor,
    GaussianCfarDetector,
    NodeDsp,
    NodeDspConfig,
    RadarParams,
    SensorGeometry,
)
from node_agent.dsp.integration import (
    NoncoherentIntegrator,
    integration_frames,
    merge_detections,
)

COMPLEX = RadarParams(fs=3e9, n=1500, t0=15e-9, f_low=3.3e9, f_high=4.7e9, fc=4.0e9, rate=40.0)


def test_frames_fit_one_pulse_width():
    # 1.4 GHz band: 0.214 m pulse; at 40 Hz and 2 m/s a walker moves 5 cm per frame
    assert integration_frames(COMPLEX.pulse_range_width, 40.0, 2.0, 8) == 4
    assert integration_frames(COMPLEX.pulse_range_width, 40.0, 2.0, 3) == 3
    # a 3.5 GHz band at 25 Hz: the echo crosses its 8.6 cm pulse in one frame
    assert integration_frames(299792458.0 / 3.5e9, 25.0, 2.0, 8) == 1
    assert integration_frames(0.2, 0.0, 2.0, 8) == 1  # rate unknown: off
    assert integration_frames(0.2, 40.0, 0.0, 8) == 1  # off by configuration
    # the default walker (2.5 m/s of bistatic range): 3 frames here, off for the 3.5 GHz
    # M-sequence radar at 50 frames/s
    rate = NodeDspConfig().integration_range_rate
    assert integration_frames(COMPLEX.pulse_range_width, 40.0, rate, 8) == 3
    assert integration_frames(299792458.0 / 3.5e9, 50.0, rate, 8) == 1


@pytest.mark.parametrize("complex_input", [False, True])
def test_threshold_crossings_on_noise_match_pfa(rng, complex_input):
    frames, pfa, m = 4, 1e-2, 20000
    ranges = np.arange(m) * 0.05
    integ = NoncoherentIntegrator(
        frames, pfa, ranges=ranges, pulse_width=0.05, complex_input=complex_input
    )
    power = np.full((2, m), 2.0 if complex_input else 1.0, dtype=np.float32)
    searched = np.ones((2, m), dtype=bool)
    sums = np.zeros((2, m))
    for _ in range(frames):
        y = rng.standard_normal((2, m))
        if complex_input:
            y = y + 1j * rng.standard_normal((2, m))
        y = y.astype(np.complex64 if complex_input else np.float32)
        integ.step(y, power, searched)
        sums += np.abs(y) ** 2 / power
    # the Gamma quantile of the sum without a target: crossings at the set Pfa per sample
    rate = float(np.mean(sums > integ.threshold))
    assert pfa * 0.8 < rate < pfa * 1.2


def _echo_frames(rng, radar, r_true, amp, n_frames, noise=1.0):
    tk = radar.t0 + np.arange(radar.n) / radar.fs
    out = []
    for k in range(n_frames):
        tau = (r_true + 0.04 * k) / 299792458.0  # 1.6 m/s of bistatic range at 40 Hz
        env = np.exp(-0.5 * ((tk - tau) * radar.bandwidth) ** 2)
        h = amp * env * np.exp(-2j * np.pi * radar.fc * tau)
        h = h * np.exp(1j * rng.uniform(0, 2 * np.pi))  # fluctuating phase: no coherence
        n = rng.standard_normal((2, radar.n)) + 1j * rng.standard_normal((2, radar.n))
        out.append((h[None] + noise * n / np.sqrt(2)).astype(np.complex64))
    return out


def test_integration_finds_an_echo_below_the_single_frame_threshold(rng):
    radar = COMPLEX
    pfa = 1e-3
    cfar = GaussianCfarDetector(
        pfa, ranges=radar.ranges(), pulse_width=radar.pulse_range_width, complex_input=True
    )
    integ = NoncoherentIntegrator(
        4, pfa, ranges=radar.ranges(), pulse_width=radar.pulse_range_width, complex_input=True
    )
    bg = ExponentialBackgroundSubtractor(0.05)
    r0 = 30.0
    frames = _echo_frames(rng, radar, r0, amp=2.6, n_frames=200)
    single = integrated = trials = 0
    false_integrated = 0
    for k, h in enumerate(frames):
        y = bg.step(h)
        det = cfar.detect(y)
        noise = cfar.noise_power()
        if noise is None:
            continue
        r, _, rows = integ.step(y, *noise)
        if k < 60:  # the background and the noise statistics settle
            continue
        truth = r0 + 0.04 * k
        trials += 2
        single += sum(np.any(np.abs(det[0][det[2] == c] - truth) < 0.2) for c in (0, 1))
        near = np.abs(r - truth) < 0.3
        integrated += sum(np.any(near[rows == c]) for c in (0, 1))
        false_integrated += int(np.sum(~near))
    # 8 dB per frame: the single-frame CFAR misses about a third of the frames
    assert single / trials < 0.75
    assert integrated / trials > 0.85
    # false alarms stay of the order of Pfa per sample (n samples, 2 receivers, 140 frames)
    assert false_integrated / (trials / 2) < 3 * pfa * radar.n * 2


def test_merge_keeps_single_frame_detections_and_adds_distant_integrated_ones():
    single = (np.array([5.0, 9.0, 4.0]), np.array([1.0, 2.0, 3.0]), np.array([0, 0, 1]))
    integrated = (
        np.array([5.1, 12.0, 4.05, 20.0]),
        np.array([0.5, 0.6, 0.7, 0.8]),
        np.array([0, 0, 1, 1]),
    )
    r, a, c = merge_detections(single, integrated, pulse_width=0.2)
    assert r.tolist() == [5.0, 9.0, 12.0, 4.0, 20.0]
    assert a.tolist() == [1.0, 2.0, 0.6, 3.0, 0.8]
    assert c.tolist() == [0, 0, 0, 1, 1]
    # nothing single-frame: the integrated ones, sorted
    empty = (np.empty(0), np.empty(0), np.empty(0, dtype=np.intp))
    r, _, c = merge_detections(empty, integrated, pulse_width=0.2)
    assert r.tolist() == [5.1, 12.0, 4.05, 20.0] and c.tolist() == [0, 0, 1, 1]
    r, _, _ = merge_detections(single, empty, pulse_width=0.2)
    assert r.tolist() == [5.0, 9.0, 4.0]


def test_node_dsp_detects_a_weak_far_echo_more_often_with_integration(rng):
    radar = COMPLEX
    geom = SensorGeometry(
        tx=np.array([0.0, 0.0, 1.0]),
        rx=np.array([[0.0, 0.4, 1.0], [0.0, -0.4, 1.0]]),
        boresight=0.0,
        beamwidth=2.0,
    )
    frames = _echo_frames(rng, radar, 24.0, amp=1.9, n_frames=160)

    def hit_rate(cfg):
        dsp = NodeDsp(geom, radar, cfg)
        hits = 0
        for k, h in enumerate(frames):
            res = dsp.process(k / radar.rate, h)
            if k >= 60:
                truth = 24.0 + 0.04 * k
                hits += sum(np.any(np.abs(res.ranges[c] - truth) < 0.3) for c in (0, 1))
        return hits / (2 * (len(frames) - 60))

    off = hit_rate(NodeDspConfig(integration_range_rate=0.0))
    on = hit_rate(NodeDspConfig())  # the default: 3 frames for this band and rate
    assert on > off + 0.1


def test_peak_kernel_matches_numpy_reference():
    """Flat tops (one peak, the first), peaks at the window's ends, bins not searched."""
    from node_agent.dsp import kernels
    from node_agent.dsp.integration import integrated_peaks_reference

    rng = np.random.default_rng(7)
    half, m, frames = 3, 400, 4
    ranges = 5.0 + 0.07 * np.arange(m)
    found = 0
    for k in range(40):
        padded = np.zeros((2, m + 2 * half), dtype=np.float32)
        padded[:, half:-half] = rng.gamma(frames, size=(2, m)).astype(np.float32)
        padded[0, half + 100 + k : half + 102 + k] = 40.0  # flat top
        padded[1, half] = 50.0  # first bin of the window
        padded[1, -half - 1] = 45.0  # last bin
        searched = np.ones((2, m), dtype=bool)
        searched[0, :20] = False
        padded[0, half + 5] = 60.0  # not searched: never reported
        power = rng.uniform(0.5, 2.0, (2, m)).astype(np.float32)
        args = (searched, power, 11.0, half, frames, ranges, 0.07)
        got = kernels.integrated_peaks(padded, *args)
        want = integrated_peaks_reference(padded, *args)
        assert got[2].tolist() == want[2].tolist(), k
        np.testing.assert_allclose(got[0], want[0], rtol=0, atol=1e-12)
        np.testing.assert_allclose(got[1], want[1], rtol=1e-12)
        assert not np.any(np.abs(got[0][got[2] == 0] - ranges[5]) < 0.01)
        found += int(np.any(np.abs(got[0] - ranges[100 + k] - 0.035) < 1e-9))
    assert found == 40
