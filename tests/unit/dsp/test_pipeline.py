import numpy as np
import pytest

from node_agent.dsp import SPEED_OF_LIGHT, NodeDsp, NodeDspConfig, RadarParams, SensorGeometry

from .synth import M_SEQUENCE, bat_geometry, bistatic_ranges, body_offsets, scene_ir

WARMUP = 25  # 0.5 s: the ghost of the scene at start-up leaves the background (alpha 0.05)
# the synthetic bodies scatter strongest from their centre (synth.body_offsets), unlike
# a real body's front surface: no range offset
CENTRE_ECHO = NodeDspConfig(range_offset=0.0, pfa=1e-4)


def run_walk(radar, geometry, start, velocity, rng, frames=75, config=None, people=1):
    dsp = NodeDsp(geometry, radar, CENTRE_ECHO if config is None else config)
    bodies = [body_offsets(rng) for _ in range(people)]
    errors, results = [], []
    for k in range(frames):
        t = 100.0 + k / 50  # network time need not start at 0
        truth = [
            np.asarray(s) + np.asarray(v) * (k / 50) for s, v in zip(start, velocity, strict=True)
        ]
        h = scene_ir(radar, geometry, list(zip(truth, bodies, strict=True)), rng)
        res = dsp.process(t, h)
        results.append(res)
        assert res.positions.shape[1:] == (2,) and res.cov.shape[1:] == (2, 2)
        assert len(res.ranges) == geometry.n_rx
        if k >= WARMUP:
            for p in truth:
                d = np.linalg.norm(res.positions - p, axis=1)
                errors.append(d.min() if d.size else np.inf)
    return np.array(errors), results


def test_bat_tracks_walking_person(rng):
    g = bat_geometry()
    err, _ = run_walk(M_SEQUENCE, g, [(3.0, -1.0)], [(0.8, 1.0)], rng)
    # the torso dominates the echo: range errors ~1 cm, so a 1 m baseline at 3-5 m puts
    # the point within a few cm; 0.15 m allows for limbs and PHD lag
    assert np.mean(err < 0.15) > 0.7


def test_other_radar_cropped_window_and_rotated_sensor(rng):
    # 5 GHz sampling, 2.5 GHz band, window starting 10 ns after emission (3 m of path),
    # sensor at an arbitrary position with yaw 2.0 rad
    radar = RadarParams(fs=5e9, n=1500, t0=10e-9, f_low=0.0, f_high=2.5e9)
    g = bat_geometry(3.0, -2.0, 2.0)
    heading = np.array([np.cos(2.0), np.sin(2.0)])
    left = np.array([-heading[1], heading[0]])
    start = g.centre + 3.5 * heading - 0.8 * left
    velocity = 0.9 * heading + 0.9 * left
    err, results = run_walk(radar, g, [start], [velocity], rng)
    assert np.mean(err < 0.15) > 0.7
    # all ranges inside the window and beyond the coupling guard
    r_all = np.concatenate([r for res in results for r in res.ranges])
    assert r_all.size and r_all.min() >= radar.ranges()[0]


def test_two_people(rng):
    g = bat_geometry()
    err, _ = run_walk(
        M_SEQUENCE, g, [(3.0, -1.5), (5.0, 1.5)], [(0.5, 0.8), (-0.5, -0.6)], rng, people=2
    )
    assert np.mean(err < 0.2) > 0.6


def test_single_receiver_gives_ranges_only(rng):
    g2 = bat_geometry()
    g1 = SensorGeometry(tx=g2.tx, rx=g2.rx[:1], rx_names=("rx1",), beamwidth=g2.beamwidth)
    dsp = NodeDsp(g1, M_SEQUENCE)
    body = body_offsets(rng)
    found = 0
    for k in range(30):
        p = np.array([4.0, 0.5]) + np.array([1.0, 0.0]) * k / 50
        res = dsp.process(k / 50, scene_ir(M_SEQUENCE, g1, [(p, body)], rng))
        assert res.positions.shape == (0, 2) and res.rx_pair is None
        r_true = np.linalg.norm(p - g1.tx[:2]) + np.linalg.norm(p - g1.rx[0, :2])
        found += bool(res.ranges[0].size) and np.min(np.abs(res.ranges[0] - r_true)) < 0.1
    assert found > 15


def test_three_receivers_use_longest_baseline(rng):
    g = SensorGeometry(
        tx=[0.0, 0.0, 1.0],
        rx=[[0.0, 0.3, 1.0], [0.0, -0.6, 1.0], [0.2, 0.6, 1.0]],
        rx_names=("a", "b", "c"),
        boresight=0.0,
        beamwidth=np.deg2rad(100),
    )
    err, results = run_walk(M_SEQUENCE, g, [(3.5, 0.5)], [(0.6, -0.8)], rng, frames=60)
    assert results[-1].rx_pair == (1, 2)
    assert np.mean(err < 0.2) > 0.6


def test_mobile_node_geometry_per_call(rng):
    g0 = bat_geometry(0.0, 0.0, 0.0)
    dsp = NodeDsp(g0, M_SEQUENCE, NodeDspConfig(max_range=20.0, range_offset=0.0))
    body = body_offsets(rng)
    g1 = bat_geometry(1.0, 2.0, 0.5)  # moved and turned: a new world geometry
    p = g1.centre + 4.0 * np.array([np.cos(0.5), np.sin(0.5)])
    errs = []
    for k in range(45):
        q = p + np.array([0.0, 1.0]) * k / 50
        res = dsp.process(k / 50, scene_ir(M_SEQUENCE, g1, [(q, body)], rng), geometry=g1)
        if k >= WARMUP and res.positions.size:
            errs.append(np.min(np.linalg.norm(res.positions - q, axis=1)))
    assert dsp.geometry is g1
    assert len(errs) > 8 and np.median(errs) < 0.15


def test_rejects_wrong_shape():
    dsp = NodeDsp(bat_geometry(), M_SEQUENCE)
    with pytest.raises(ValueError, match="shape"):
        dsp.process(0.0, np.zeros((2, 100), np.float32))
    with pytest.raises(ValueError, match="shape"):
        dsp.process(0.0, np.zeros((3, M_SEQUENCE.n), np.float32))


def test_complex_baseband_pipeline(rng):
    # a DW1000-class complex baseband radar: 2 GHz sampling, 3.5-5.5 GHz, carrier 4.5 GHz
    radar = RadarParams(fs=2e9, n=600, t0=0.0, f_low=3.5e9, f_high=5.5e9, fc=4.5e9)
    g = bat_geometry()
    dsp = NodeDsp(g, radar, CENTRE_ECHO)
    tk = radar.t0 + np.arange(radar.n) / radar.fs
    errs = []
    for k in range(50):
        p = np.array([4.0, 0.5]) + np.array([0.5, 0.8]) * k / 50
        r = np.column_stack((bistatic_ranges(p[None], g)[:, 0], g.direct_ranges(), [12.0, 12.0]))
        tau = r / SPEED_OF_LIGHT  # (n_rx, 3): person, coupling, wall
        amp = np.array([0.3, 3.0, 1.0])
        pulses = np.exp(-0.5 * ((tk[None, :, None] - tau[:, None, :]) * radar.bandwidth) ** 2)
        h = (amp * pulses * np.exp(-2j * np.pi * radar.fc * tau)[:, None, :]).sum(axis=2)
        h += 0.01 * (rng.standard_normal(h.shape) + 1j * rng.standard_normal(h.shape))
        res = dsp.process(k / 50, h.astype(np.complex64))
        if k >= WARMUP:
            d = np.linalg.norm(res.positions - p, axis=1)
            errs.append(d.min() if d.size else np.inf)
    # one sample is 15 cm of path here; a point target: within a fraction of a sample
    assert np.mean(np.array(errs) < 0.15) > 0.7


def test_window_shorter_than_guard_gives_nothing(rng):
    radar = RadarParams(fs=7e9, n=5, t0=0.0, f_low=0.0, f_high=3.5e9)
    dsp = NodeDsp(bat_geometry(), radar)
    for k in range(3):
        res = dsp.process(k / 50, rng.standard_normal((2, 5)).astype(np.float32))
        assert all(r.size == 0 for r in res.ranges) and res.positions.shape == (0, 2)


def test_moving_the_node_resets_the_background(rng):
    g0 = bat_geometry()
    dsp = NodeDsp(g0, M_SEQUENCE)
    body = body_offsets(rng)
    for k in range(5):
        dsp.process(k / 50, scene_ir(M_SEQUENCE, g0, [(np.array([4.0, 0.0]), body)], rng))
    g1 = bat_geometry(0.5, 0.0, 0.0)
    res = dsp.process(0.1, scene_ir(M_SEQUENCE, g1, [(np.array([4.0, 0.0]), body)], rng), g1)
    # the first acquisition after a move initialises a new background: nothing detected,
    # instead of every wall showing up at its old range
    assert all(r.size == 0 for r in res.ranges)
    same = bat_geometry(0.5, 0.0, 0.0)  # equal geometry, new object: no reset
    dsp.process(0.12, scene_ir(M_SEQUENCE, same, [(np.array([4.0, 0.0]), body)], rng), same)
    assert dsp.geometry is same


def ghost_fraction(config, rng):
    """Two people 4 m apart across the bat's axis crossing in range, one walking towards
    the sensor, one away: at the crossing receiver 1's range of one is receiver 2's
    range of the other, and the swapped pairing puts two ghosts near the axis."""
    g = bat_geometry()
    dsp = NodeDsp(g, M_SEQUENCE, config)
    bodies = [body_offsets(rng), body_offsets(rng)]
    ghosts = real = 0
    for k in range(80):
        s = k / 50
        people = [np.array([5.0 - 1.0 * s, 2.0]), np.array([3.5 + 1.0 * s, -2.0])]
        res = dsp.process(
            k / 50, scene_ir(M_SEQUENCE, g, list(zip(people, bodies, strict=True)), rng)
        )
        if k < WARMUP or not res.positions.size:
            continue
        d = np.min(np.linalg.norm(res.positions[:, None] - np.array(people)[None], axis=2), 1)
        ghosts += int(np.sum(d > 0.5))
        real += int(np.sum(d <= 0.3))
    return ghosts, real


def test_pairing_by_range_rate_avoids_axis_ghosts():
    ghosts, real = ghost_fraction(CENTRE_ECHO, np.random.default_rng(20240611))
    assert real > 45 and ghosts <= 0.1 * real
    # the same scene paired by range difference only (rates and amplitudes ignored) has
    # ghosts while the two cross in range: the scene is ambiguous, the test can fail
    blind = NodeDspConfig(
        range_offset=0.0, pfa=1e-4, pairing_rate_std=1e6, pairing_log_amplitude_std=1e6
    )
    ghosts_blind, _ = ghost_fraction(blind, np.random.default_rng(20240611))
    assert ghosts_blind >= max(2 * ghosts, 5)


def test_range_offset_moves_front_surface_echoes_to_body_centre(rng):
    # a body of radius 0.15 m that scatters from its half facing the sensor: ranges are
    # short by about twice the radius, which the default offset restores
    g = bat_geometry()
    errors = {}
    for offset in (0.0, NodeDspConfig().range_offset):
        dsp = NodeDsp(g, M_SEQUENCE, NodeDspConfig(range_offset=offset))
        local = np.random.default_rng(3)
        errs = []
        for k in range(60):
            centre = np.array([3.0, -1.0]) + np.array([0.8, 1.0]) * k / 50
            facing = np.arctan2(*(g.centre - centre)[::-1])
            ang = facing + local.uniform(-0.6, 0.6, 5)
            front = 0.15 * np.column_stack((np.cos(ang), np.sin(ang)))
            res = dsp.process(k / 50, scene_ir(M_SEQUENCE, g, [(centre, front)], local))
            if k >= WARMUP and res.positions.size:
                errs.append(np.min(np.linalg.norm(res.positions - centre, axis=1)))
        errors[offset] = np.median(errs)
    assert errors[0.3] < 0.1 < errors[0.0]


@pytest.mark.parametrize("clip", [2.0, 3.0])
def test_noise_clip_reaches_the_cfar(rng, clip):
    # the config's clip is the detector's (the CFAR is built at the first impulse response)
    g = bat_geometry()
    dsp = NodeDsp(g, M_SEQUENCE, NodeDspConfig(noise_clip_sigma=clip))
    dsp.process(0.0, scene_ir(M_SEQUENCE, g, [], rng))
    assert dsp._cfar is not None and dsp._cfar._clip2 == np.float32(clip**2)


def test_fused_background_cfar_gives_the_per_step_results(monkeypatch):
    """NodeDsp's single compiled call for background + CFAR (real samples, no band filter)
    against the separate subtractor and detector: every result of a two-person walk equal,
    bit for bit."""
    from node_agent.dsp import GaussianCfarDetector

    def walk():
        _, results = run_walk(
            M_SEQUENCE,
            bat_geometry(),
            [(3.0, -1.0), (5.0, 1.5)],
            [(0.8, 1.0), (-0.6, -0.5)],
            np.random.default_rng(3),
            frames=60,
            people=2,
        )
        return results

    calls = []
    fused_call = GaussianCfarDetector.detect_subtracting

    def counted(self, *args):
        out = fused_call(self, *args)
        calls.append(out is not None)
        return out

    monkeypatch.setattr(GaussianCfarDetector, "detect_subtracting", counted)
    fused = walk()
    assert sum(calls) >= 58  # every frame after the first two
    monkeypatch.setattr(GaussianCfarDetector, "detect_subtracting", lambda *a: None)
    separate = walk()
    n_pos = 0
    for a, b in zip(fused, separate, strict=True):
        for field in ("ranges", "amplitudes"):
            for x, y in zip(getattr(a, field), getattr(b, field), strict=True):
                np.testing.assert_array_equal(x, y)
        np.testing.assert_array_equal(a.positions, b.positions)
        np.testing.assert_array_equal(a.cov, b.cov)
        n_pos += a.positions.shape[0]
    assert n_pos >= 40  # the people were located: the comparison covers detections


@pytest.mark.parametrize("layout", ["fortran", "broadcast"])
def test_frames_in_any_memory_layout_give_the_c_ordered_results(layout):
    """A driver may hand over a transposed or broadcast frame: the fused background + CFAR
    call then falls back or takes a C-ordered background (it raised a numba TypeError from
    the third frame on, outside the agent's rejection handling); results are the C-ordered
    frames' results, bit for bit."""
    g = bat_geometry()
    rng = np.random.default_rng(4)
    body = body_offsets(rng)
    frames = [
        scene_ir(M_SEQUENCE, g, [(np.array([4.0, 0.5 + 0.02 * k]), body)], rng) for k in range(8)
    ]
    if layout == "broadcast":
        # both receivers the same row, as a broadcast view
        frames = [np.broadcast_to(f[:1], f.shape) for f in frames]
    plain = NodeDsp(g, M_SEQUENCE, NodeDspConfig(range_offset=0.0))
    other = NodeDsp(g, M_SEQUENCE, NodeDspConfig(range_offset=0.0))
    for k, f in enumerate(frames):
        a = plain.process(100 + k / 50, np.ascontiguousarray(f))
        view = np.asfortranarray(f) if layout == "fortran" else f
        b = other.process(100 + k / 50, view)
        for x, y in zip(a.ranges, b.ranges, strict=True):
            np.testing.assert_array_equal(x, y)
        np.testing.assert_array_equal(a.positions, b.positions)
