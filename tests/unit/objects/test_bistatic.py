"""Bistatic geometry of the end-to-end scan chain: range ellipses, incidence angle, eq. (16)."""

from __future__ import annotations

import numpy as np
import pytest

from fusion_center.objects.fuzzy import ellipse_intersections
from fusion_center.objects.material import bistatic_incidence_angle, incidence_angle
from fusion_center.objects.scan import ScanData, process_scan
from sim_nodes.channel.prism import PrismTarget
from sim_nodes.circle_scan import CircleTrack, scan_echoes, scan_impulse_responses
from sim_nodes.radar import MSequenceRadar, RadarConfig

SLAB = np.array([[-0.5, -0.08], [0.5, -0.08], [0.5, 0.08], [-0.5, 0.08]])


def test_ellipse_intersection_finds_a_point_scatterer() -> None:
    p = np.array([0.05, 0.1])
    tx_i, rx_i = np.array([0.4, 0.7]), np.array([-0.4, 0.7])
    tx_j, rx_j = np.array([0.45, 0.68]), np.array([-0.35, 0.72])

    def rng(t: np.ndarray, r: np.ndarray) -> float:
        return float(np.linalg.norm(p - t) + np.linalg.norm(p - r))

    # Started 3 cm off (where the monostatic circles would meet), Newton lands on the point.
    got = ellipse_intersections(
        tx_i, rx_i, rng(tx_i, rx_i), tx_j, rx_j, rng(tx_j, rx_j), p + np.array([0.02, 0.02])
    )
    assert np.allclose(got, p, atol=1e-9)


@pytest.mark.parametrize("tilt_deg", [0.0, 25.0, 60.0])
def test_incidence_angle_from_the_measured_range_matches_the_image_method(
    tilt_deg: float,
) -> None:
    tilt = np.deg2rad(tilt_deg)
    normal = np.array([np.sin(tilt), np.cos(tilt)])
    tx, rx = np.array([0.4, 0.6]), np.array([-0.4, 0.6])
    image = tx - 2 * (tx @ normal) * normal  # plane through the origin
    r = np.linalg.norm(rx - image)
    want = incidence_angle(tx, rx, np.zeros(2), normal)
    assert bistatic_incidence_angle(tx, rx, r, normal) == pytest.approx(want, abs=1e-12)
    assert bistatic_incidence_angle(tx, rx, r, -normal) == pytest.approx(want, abs=1e-12)


@pytest.mark.parametrize("eps", [2.9, 4.5])
def test_wide_baseline_scan_estimates_permittivity_within_3_percent(eps: float) -> None:
    # The circle_slab scan (0.8 m baseline, incidence about 33 degrees, 0.5-degree grid):
    # impulse responses to permittivity with no knowledge of the slab. The boresight
    # conversion of bistatic ranges gave eps_r about 30 times too high here.
    track = CircleTrack(
        radius=0.7, start=np.deg2rad(40), span=np.deg2rad(100), step=np.deg2rad(0.5), baseline=0.8
    )
    radar = MSequenceRadar(RadarConfig(snr_db=40.0))
    target = PrismTarget(vertices=SLAB, permittivity=eps, metal=False)
    chans = ("vv", "hh", "vh", "hv", "pp", "pm")
    h = scan_impulse_responses(
        scan_echoes(target, track, np.deg2rad(70.0)), radar, chans, np.random.default_rng(4)
    )
    tx, rx, _ = track.antennas()
    scan = ScanData(
        h={c: h[:, i].astype(float) for i, c in enumerate(chans)},
        poses=track.poses(),
        tx=tx,
        rx=rx,
        fs=radar.config.fs,
        t0=radar.config.t0,
    )
    res = process_scan(scan)
    assert res.n_face_positions >= 30
    assert res.permittivity == pytest.approx(eps, rel=0.03)
    assert not res.metal_like
