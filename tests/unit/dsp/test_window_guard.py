"""The window guard: no range is reported where an echo is cut by the window's start."""

import numpy as np
import pytest

from node_agent.dsp import SPEED_OF_LIGHT, NodeDsp, NodeDspConfig, RadarParams

from .synth import bat_geometry, body_offsets, scene_ir

# 5 GHz sampling, 1 GHz band (pulse width 0.3 m), window starting 10 ns after emission
RADAR = RadarParams(fs=5e9, n=800, t0=10e-9, f_low=0.0, f_high=1e9)


def test_measurable_interval() -> None:
    start = SPEED_OF_LIGHT * RADAR.t0
    end = SPEED_OF_LIGHT * (RADAR.t0 + (RADAR.n - 1) / RADAR.fs)
    assert RADAR.measurable(0.0) == pytest.approx((start, end))
    lo, hi = RADAR.measurable(1.0)
    assert lo == pytest.approx(start + RADAR.pulse_range_width)
    assert hi == pytest.approx(end - RADAR.pulse_range_width)


def edge_ranges(guard: float, rng: np.random.Generator) -> np.ndarray:
    """Ranges reported for a person walking across the window start (bistatic 2.6-3.4 m)."""
    g = bat_geometry()
    dsp = NodeDsp(g, RADAR, NodeDspConfig(range_offset=0.0, pfa=1e-4, window_guard=guard))
    body = body_offsets(rng)
    out = []
    for k in range(100):
        centre = np.array([1.3 + 0.4 * k / 100, 0.2])
        res = dsp.process(k / 50, scene_ir(RADAR, g, [(centre, body)], rng))
        out.extend(np.concatenate(res.ranges).tolist())
    return np.array(out)


def test_guard_drops_echoes_cut_at_the_window_start() -> None:
    # the reported ranges are the range GM-PHD's estimates, which may lag a detection by a
    # few cm: the edge zone tested is the first half pulse width of the window
    edge = SPEED_OF_LIGHT * RADAR.t0 + 0.5 * RADAR.pulse_range_width
    unguarded = edge_ranges(0.0, np.random.default_rng(5))
    guarded = edge_ranges(1.0, np.random.default_rng(5))
    # without the guard, the cut echo's detections sit at the window's first pulse width
    assert np.sum(unguarded < edge) > 5
    assert guarded.size and guarded.min() >= edge
