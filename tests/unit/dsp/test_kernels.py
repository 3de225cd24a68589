"""The compiled DSP kernels (``node_agent.dsp.kernels``) against plain Python references,
and their fallback when numba has no writable cache directory."""

from __future__ import annotations

import numpy as np
import pytest

from node_agent.dsp import GaussianCfarDetector, RangeGmPhdFilter, kernels
from tests.numba_cache import run_without_numba_cache

from .test_reference_equivalence import ReferenceCfar, ReferenceRangePhd


def _random_mixture(rng, n_channels, span):
    """Kernel rows and the reference's per-channel dicts of one random mixture: weights up
    to 2.5 (estimates repeated), close neighbours (merged), sorted by channel-offset range."""
    rows, mix = [], [[] for _ in range(n_channels)]
    for ch in range(n_channels):
        r = np.sort(np.concatenate([rng.uniform(2.0, 12.0, 6), 5.0 + 0.02 * rng.random(3)]))
        for rk in r:
            w = rng.choice([rng.uniform(0.001, 0.6), rng.uniform(0.6, 2.5)])
            a = rng.normal(size=(2, 2))
            p = a @ a.T * 0.01 + np.diag([1e-3, 0.05])
            m = np.array([rk, rng.normal()])
            amp = rng.uniform(0.1, 2.0)
            rows.append([w, p[0, 0], p[0, 1], p[1, 1], rk + ch * span, m[1], amp, ch])
            mix[ch].append({"w": w, "m": m, "P": p, "amp": amp})
    return np.array(rows), mix


@pytest.mark.parametrize("max_components", [60, 12])
def test_range_phd_kernel_matches_reference_from_random_mixtures(max_components):
    rng = np.random.default_rng(5)
    span = 1.0e6
    n_repeated = n_merged = 0
    for trial in range(40):
        phd = RangeGmPhdFilter(
            n_channels=2,
            detection_probability=0.3,  # weights survive a missed frame above 1.5
            clutter_intensity=0.05,
            max_components=max_components,
        )
        x, mix = _random_mixture(rng, 2, span)
        ref = ReferenceRangePhd(phd)
        ref.mix, ref.t = mix, 1.0
        dt = rng.choice([0.0, 0.02, 0.05])
        k = int(rng.integers(0, 8))
        ch = np.sort(rng.integers(0, 2, k))
        r = rng.uniform(2.0, 12.0, k)
        order = np.lexsort((r, ch))
        r, ch = r[order], ch[order].astype(np.intp)
        a = rng.uniform(0.1, 2.0, k)
        transition = phd._prediction(dt) if dt else np.zeros(kernels.N_TRANSITION)
        x_new, est = kernels.range_phd_step(x, transition, r, a, ch, phd._par)
        want = ref.step(1.0 + dt, r.tolist(), a.tolist(), ch.tolist())
        np.testing.assert_allclose(est, want.reshape(-1, 5), rtol=1e-9, atol=1e-8, err_msg=trial)
        # the mixture itself, row by row in (channel, range) order
        got_mix = [
            [row[0], row[1], row[2], row[3], row[4] - row[7] * span, row[5], row[6]]
            for row in x_new.tolist()
        ]
        want_mix = [
            [c["w"], c["P"][0, 0], c["P"][0, 1], c["P"][1, 1], c["m"][0], c["m"][1], c["amp"]]
            for comps in ref.mix
            for c in comps
        ]
        np.testing.assert_allclose(got_mix, want_mix, rtol=1e-9, atol=1e-8, err_msg=trial)
        assert len(x_new) <= max_components
        n_repeated += len(est) > len({tuple(e) for e in est.tolist()})
        n_merged += len(x_new) < np.count_nonzero(x[:, 0] * (1 - 0.3) > 1e-3)
    assert n_repeated >= 5 and n_merged >= 5  # both paths were exercised


def test_range_phd_kernel_edge_cases():
    phd = RangeGmPhdFilter(n_channels=1)
    empty = np.empty(0)
    # nothing at all
    x, est = kernels.range_phd_step(
        np.empty((0, 8)), np.zeros(7), empty, empty, np.empty(0, np.intp), phd._par
    )
    assert x.shape == (0, 8) and est.shape == (0, 5)
    # a first detection is born with the birth weight, below the extraction threshold
    x, est = kernels.range_phd_step(
        x, np.zeros(7), np.array([4.0]), np.array([1.0]), np.zeros(1, np.intp), phd._par
    )
    assert x.tolist() == [[0.1, 0.05**2, 0.0, 4.0, 4.0, 0.0, 1.0, 0.0]]
    assert est.shape == (0, 5)
    # the public step converts other integer channel types to the kernel's signature
    out = phd.step_detections(0.02, np.array([4.0]), np.array([1.0]), np.zeros(1, np.int32))
    assert out.shape[1] == 5


def test_cfar_kernel_matches_reference_on_edges_and_flat_tops():
    """Echoes cut at either end of the window, flat tops (two equal maxima: one peak, the
    first), a receiver switched off by its minimum range; detections and the variance
    state against the bin-by-bin reference."""
    rng = np.random.default_rng(4)
    ranges = 2.0 + 0.05 * np.arange(300)
    min_range = np.array([0.0, 2.5, 100.0])  # the third receiver searches nothing
    det = GaussianCfarDetector(1e-3, ranges=ranges, pulse_width=0.15, min_range=min_range)
    ref = ReferenceCfar(det, ranges, min_range)
    n_flat = n_edge = 0
    for k in range(30):
        y = rng.standard_normal((3, 300)).astype(np.float32)
        y[:, 0] = 9.0  # cut echo at the window's first sample (receiver 0 searches there)
        y[0, 150 + k : 152 + k] = np.float32(8.0)  # flat top
        y[1, -2:] = np.float32([5.0, 10.0])  # rising into the window's end
        y[2, 100] = 20.0  # never reported: receiver 2 is switched off
        got = det.detect(y)
        want = ref.step(y)
        assert got[2].tolist() == want[2], k
        np.testing.assert_allclose(got[0], want[0], rtol=0, atol=1e-12)
        np.testing.assert_allclose(got[1], want[1], rtol=1e-12)
        np.testing.assert_array_equal(det._var[:, det._half : -det._half], ref.var)
        # a flat top's parabola peaks half-way between its two samples
        n_flat += int(np.any(np.abs(got[0] - ranges[150 + k] - 0.025) < 1e-9))
        n_edge += int(np.any(got[0] < ranges[0] + 0.03)) + int(got[0][-1] > ranges[-2])
    print(f"flat tops found {n_flat}/30, edge echoes {n_edge}/60")
    assert n_flat >= 20 and n_edge >= 40


def test_background_cfar_kernel_matches_subtractor_and_detector_bit_for_bit():
    """The fused background subtraction + CFAR (``detect_subtracting``) against the numpy
    subtractor followed by ``detect`` on twin states: the same detections, subtracted
    frames, backgrounds and noise variances, bit for bit, over frames of a strided window
    with moving echoes, writable or read-only (and the first frames, where the fused call
    declines)."""
    from node_agent.dsp import ExponentialBackgroundSubtractor

    rng = np.random.default_rng(11)
    ranges = 2.0 + 0.05 * np.arange(400)
    make = lambda: GaussianCfarDetector(1e-3, ranges=ranges, pulse_width=0.15, min_range=2.3)  # noqa: E731
    det_a, det_b = make(), make()
    bg_a, bg_b = ExponentialBackgroundSubtractor(0.05), ExponentialBackgroundSubtractor(0.05)
    static = rng.standard_normal((2, 420)).astype(np.float32) * 5
    y_a, y_b = np.empty((2, 400), np.float32), np.empty((2, 400), np.float32)
    fused = found = 0
    for k in range(60):
        frame = static + rng.standard_normal((2, 420)).astype(np.float32)
        frame[:, 60 + 3 * k] += np.float32(12.0)  # a walker
        frame[1, 300 - 2 * k : 302 - 2 * k] += np.float32(9.0)
        frame.flags.writeable = k % 2 == 0  # odd frames read-only, as decoded from a file
        window = frame[:, 10:410]  # strided, as NodeDsp's range window
        state = bg_a.state_for(window)
        got = None if state is None else det_a.detect_subtracting(window, state, 0.05, y_a)
        if got is None:
            got = det_a.detect(bg_a.step(window, out=y_a))
        else:
            fused += 1
        want = det_b.detect(bg_b.step(window, out=y_b))
        for g, w in zip(got, want, strict=True):
            np.testing.assert_array_equal(g, w)
        np.testing.assert_array_equal(y_a, y_b)
        np.testing.assert_array_equal(bg_a.state_for(window), bg_b.state_for(window))
        np.testing.assert_array_equal(det_a._var, det_b._var)
        found += got[0].size
    assert fused >= 58 and found >= 60  # fused from the third frame; the walker detected


def test_background_cfar_kernel_declines_complex_input():
    """Complex baseband keeps the numpy path: the fused call declines, changing nothing."""
    ranges = 2.0 + 0.05 * np.arange(50)
    det = GaussianCfarDetector(1e-3, ranges=ranges, pulse_width=0.15, complex_input=True)
    h = np.ones((2, 50), np.complex64)
    bg = np.zeros((2, 50), np.complex64)
    assert det.detect_subtracting(h, bg, 0.05, np.empty_like(h)) is None
    assert not bg.any()


def test_kernels_work_without_a_writable_numba_cache(tmp_path):
    """With no usable cache directory numba refuses ``cache=True``; the kernels then compile
    in memory (a warning per kernel) and give the same estimates."""
    code = (
        "import numpy as np\n"
        "from node_agent.dsp import RangeGmPhdFilter\n"
        "f = RangeGmPhdFilter()\n"
        "for k in range(5):\n"
        "    r, a = f.step(0.02 * k, [4.0 + 0.01 * k, 7.0], [1.0, 0.5])\n"
        "print(np.round(r, 9).tolist())\n"
    )
    res = run_without_numba_cache(code, tmp_path, timeout=240)
    assert res.returncode == 0, res.stderr
    assert "numba cache unavailable, compiling in memory" in res.stderr
    f = RangeGmPhdFilter()
    for k in range(5):
        r, _ = f.step(0.02 * k, [4.0 + 0.01 * k, 7.0], [1.0, 0.5])
    assert res.stdout.strip() == str(np.round(r, 9).tolist())
    assert len(r) == 2  # both echoes confirmed after five frames
