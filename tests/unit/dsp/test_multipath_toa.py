"""The joint multipath fit of the first path (method ``ml`` of FirstPathRanger)."""

import math

import numpy as np
import pytest

from fusion_center.localization import multipath_delay_bound
from node_agent.dsp.geometry import RadarParams
from node_agent.dsp.ranging import FirstPathRanger
from sim_nodes.channel.stochastic import render

BASEBAND = RadarParams(fs=7e9, n=256, t0=0.0, f_low=0.0, f_high=3.5e9)
DW1000 = RadarParams(fs=998.4e6, n=256, t0=0.0, f_low=6.2396e9, f_high=6.7396e9, fc=6.4896e9)
FIRST = 100.3


def channel(radar, delays_ns, amps, rng, count=40, snr_db=300.0, sigma=0.01):
    clean = render(
        np.asarray(delays_ns, float),
        np.asarray(amps, complex),
        fs=radar.fs,
        n=radar.n,
        f_low=radar.f_low,
        f_high=radar.f_high,
        fc=radar.fc,
        first_index=FIRST,
        snr_db=snr_db,
        rng=rng,
    )
    shape = (count, radar.n)
    if radar.fc > 0.0:
        noise = rng.standard_normal(shape) + 1j * rng.standard_normal(shape)
        return (clean + sigma * noise).astype(np.complex64)
    return (clean + sigma * rng.standard_normal(shape)).astype(np.float32)


def errors(radar, method, h):
    return FirstPathRanger(radar, method=method).process(h).toa * radar.fs - FIRST


def test_an_overlapping_reflection_no_longer_pulls_the_first_path():
    # a reflection 0.12 ns (1.7 pulse sigmas) after the direct path, opposite sign, 40 % as
    # strong: the single-pulse fit is pulled early, the joint fit reaches the multipath bound
    rng = np.random.default_rng(5)
    delays, amps = [0.0, 0.12, 3.0], [1.0, -0.4, 0.3]
    h = channel(BASEBAND, delays, amps, rng)
    _, bound = multipath_delay_bound(
        np.array(delays) * 1e-9,
        np.array(amps, complex),
        noise_sigma=0.01,
        fs=BASEBAND.fs,
        n=BASEBAND.n,
        first_index=FIRST,
        pulse_sigma=math.sqrt(math.log(10.0)) / (2 * math.pi * BASEBAND.f_high),
    )
    bound *= BASEBAND.fs  # samples
    adaptive = np.sqrt(np.mean(errors(BASEBAND, "adaptive", h) ** 2))
    ml = np.sqrt(np.mean(errors(BASEBAND, "ml", h) ** 2))
    assert adaptive > 2.5 * bound
    assert ml < 1.5 * bound


def test_a_lone_path_keeps_the_single_pulse_precision():
    rng = np.random.default_rng(6)
    h = channel(BASEBAND, [0.0], [1.0], rng)
    adaptive, ml = errors(BASEBAND, "adaptive", h), errors(BASEBAND, "ml", h)
    assert np.sqrt(np.mean(ml**2)) <= 1.3 * np.sqrt(np.mean(adaptive**2)) + 1e-3
    assert abs(np.mean(ml)) < 0.02


@pytest.mark.parametrize("delay", [0.0, 0.9])
def test_complex_baseband_first_path_with_a_later_stronger_one(delay):
    # DW1000-like: 500 MHz band, 1 ns sampling; an obstructed direct path (-8 dB) and a
    # reflection 2 ns later; the fit must still return the direct path
    rng = np.random.default_rng(7)
    h = channel(DW1000, [delay, delay + 2.0], [0.4, 1.0j], rng, sigma=0.005)
    ml = errors(DW1000, "ml", h) - delay * 1e-9 * DW1000.fs
    assert np.median(np.abs(ml)) < 0.05


def test_rows_without_a_path_stay_nan():
    rng = np.random.default_rng(8)
    h = (0.01 * rng.standard_normal((3, BASEBAND.n))).astype(np.float32)
    h[0] += channel(BASEBAND, [0.0], [1.0], rng, count=1, sigma=0.0)[0]
    res = FirstPathRanger(BASEBAND, method="ml").process(h)
    assert np.isfinite(res.toa[0])
    assert np.all(np.isnan(res.toa[1:])) or np.all(np.isfinite(res.toa[1:]))
