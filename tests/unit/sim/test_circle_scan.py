"""``[circle_scan]`` scenarios: validation, track geometry, impulse responses per channel."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sim_nodes.circle_record import scan_target, scan_track
from sim_nodes.circle_scan import (
    CircleTrack,
    geometric_wavefronts,
    scan_echoes,
    scan_impulse_responses,
)
from sim_nodes.radar import C, MSequenceRadar, RadarConfig
from sim_nodes.scene import ScenarioError, load_scenario, parse_scenario

SQUARE = [[-0.15, -0.15], [0.15, -0.15], [0.15, 0.15], [-0.15, 0.15], [-0.15, -0.15]]


def scan_scenario(**circle: object) -> dict:
    return {
        "name": "t",
        "materials": {"mdf": {"permittivity": 2.9}},
        "circle_scan": {"target": SQUARE, "material": "mdf", **circle},
    }


def test_shipped_circle_scenario_loads() -> None:
    sc = load_scenario("circle_L")
    assert sc.circle_scan is not None
    track = scan_track(sc)
    assert track.closed and len(track.angles) == 360
    assert scan_target(sc, 0).permittivity == 2.9


@pytest.mark.parametrize(
    ("circle", "fragment"),
    [
        ({"radius": 0.2}, "circle_scan.radius: the track must clear the target"),
        ({"material": "oak"}, "circle_scan.material: unknown material 'oak'"),
        ({"target": SQUARE[:-1]}, "circle_scan.target: target polygon is open"),
        ({"step": 1.0}, "circle_scan.step"),
        ({"span": 7.0}, "circle_scan.span"),
    ],
)
def test_bad_circle_scan_gives_one_line(circle: dict, fragment: str) -> None:
    with pytest.raises(ScenarioError, match=fragment.replace("(", r"\(")) as err:
        parse_scenario(scan_scenario(**circle))
    assert "\n" not in str(err.value)


def test_partial_track_and_poses() -> None:
    track = CircleTrack(start=0.5, span=math.radians(180.0), radius=0.8)
    a = track.angles
    assert not track.closed and len(a) == 181
    poses = track.poses()
    # Boresight (yaw) points at the centre from every position.
    look = np.column_stack([np.cos(poses[:, 3]), np.sin(poses[:, 3])])
    assert np.allclose(poses[:, :2] + 0.8 * look, 0.0, atol=1e-12)
    tx, rx, _ = track.antennas()
    assert np.allclose(np.linalg.norm(tx - rx, axis=1), track.baseline)


def test_impulse_responses_peak_at_the_face_echo() -> None:
    sc = parse_scenario(scan_scenario(step=math.radians(10.0)))
    target, track = scan_target(sc, 0), scan_track(sc)
    radar = MSequenceRadar(RadarConfig(noise=False))
    echoes = scan_echoes(target, track, math.radians(70.0))
    h = scan_impulse_responses(echoes, radar, ("vv", "hv", "hh", "pm"), None)
    assert h.shape == (36, 4, 4095)
    # Position 0 faces the square's +x side: the strongest VV echo is at 2 x 0.85 m (+baseline).
    expected = 2 * math.hypot(0.85, track.baseline / 2)
    k = int(np.argmax(np.abs(h[0, 0])))
    assert abs(k / radar.config.fs * C - expected) < C / radar.config.fs
    assert np.abs(h[:, 1]).max() < 1e-6 * np.abs(h[:, 0]).max()  # smooth: no cross-pol
    # Same sign in VV and HH for a dielectric face (back-scatter alignment).
    assert np.sign(h[0, 0, k]) == np.sign(h[0, 2, k])


def test_geometric_wavefronts_merge_and_sort() -> None:
    rng = np.random.default_rng(0)
    target = scan_target(parse_scenario(scan_scenario()), 0)
    echoes = scan_echoes(target, CircleTrack(), math.radians(70.0))
    r = geometric_wavefronts(echoes, rng, range_noise=0.0, resolution=0.02)
    fin = np.isfinite(r)
    assert fin[:, 0].all()
    gaps = np.diff(r, axis=1)
    assert (gaps[np.isfinite(gaps)] > 0.02).all()
    # Nearest echo per position equals the nearest true echo (no noise, no merging there).
    assert np.allclose(r[:, 0], np.nanmin(echoes.length, axis=1), atol=0.02)
