"""Polarimetry (Section 7.6) and ellipsometry (eq. (16)) on the prism echo model."""

from __future__ import annotations

import numpy as np
import pytest

from fusion_center.objects.material import (
    CornerCorrectionTable,
    depolarization_ratio,
    ellipsometry_permittivity,
    emissivity,
    incidence_angle,
)
from sim_nodes.channel.materials import fresnel
from sim_nodes.channel.prism import DIHEDRAL, FACE, WEDGE, PrismTarget, prism_echoes, rotate_basis
from sim_nodes.circle_scan import CircleTrack, channel_matrix, scan_echoes

L_SHAPE = np.array([[-0.2, -0.2], [0.2, -0.2], [0.2, 0.0], [0.0, 0.0], [0.0, 0.2], [-0.2, 0.2]])


@pytest.mark.parametrize("eps", [2.9, 4.5, 7.0])
@pytest.mark.parametrize("theta_deg", [20.0, 35.0, 50.0])
def test_ellipsometry_inverts_fresnel(eps: float, theta_deg: float) -> None:
    theta = np.deg2rad(theta_deg)
    te, tm = fresnel(eps, np.cos(theta))
    rho = np.real(tm / te)
    assert ellipsometry_permittivity(rho, theta) == pytest.approx(eps, rel=1e-9)


def test_emissivity_of_a_dielectric() -> None:
    assert emissivity(1.0) == pytest.approx(1.0)
    assert emissivity(4.0) == pytest.approx(1 - (1 / 3) ** 2)


def test_incidence_angle_of_a_bistatic_pair() -> None:
    # Antennas 0.8 m apart, 0.4 m above a plane: tan(theta) = 0.4 / 0.4.
    theta = incidence_angle([-0.4, 0.4], [0.4, 0.4], [0.0, 0.0], [0.0, 1.0])
    assert theta == pytest.approx(np.pi / 4)


def test_corner_correction_table_divides_out_the_bias() -> None:
    d = np.linspace(0.0, 0.5, 51)
    true = np.full_like(d, -0.6)
    measured = true * (1 - 0.1 * np.exp(-d / 0.05))
    table = CornerCorrectionTable.calibrate(d, measured, true, np.arange(0.0, 0.55, 0.025))
    corrected = table.correct(measured, d)
    assert np.abs(corrected / true - 1).max() < 0.02
    assert np.abs(measured / true - 1).max() > 0.09
    with pytest.raises(ValueError, match="bins"):
        CornerCorrectionTable.calibrate([9.0], [1.0], [1.0], [0.0, 1.0])


def test_plate_keeps_polarization_and_45_degree_cross_shows_only_corners() -> None:
    target = PrismTarget(vertices=L_SHAPE, metal=True)
    echoes = scan_echoes(target, CircleTrack(), np.deg2rad(70.0))
    s = echoes.scattering
    face = echoes.kind == FACE
    corner = (echoes.kind == WEDGE) | (echoes.kind == DIHEDRAL)
    assert np.abs(s[:, face, 0, 1]).max() == 0.0  # smooth plates: no V/H cross-polar echo
    cross45 = np.abs(rotate_basis(s, np.pi / 4)[..., 1, 0])
    co45 = np.abs(rotate_basis(s, np.pi / 4)[..., 0, 0])
    # Rotated 45 degrees: a plate (S = -I) has no cross-polar echo, corners do.
    assert cross45[:, face].max() < 1e-12
    assert cross45[:, corner].max() > 0.05 * co45[:, face].max()
    dihedral = echoes.kind == DIHEDRAL
    seen = np.isfinite(echoes.length[:, dihedral])
    # The metal dihedral is S = diag(1, -1): pure cross-polar in the rotated basis.
    assert np.allclose(co45[:, dihedral][seen], 0.0, atol=1e-12)


def test_rough_surface_depolarizes() -> None:
    track = CircleTrack(step=np.deg2rad(2.0))
    ratios = []
    for roughness in (0.0, 0.3):
        target = PrismTarget(vertices=L_SHAPE, metal=False, permittivity=4.5, roughness=roughness)
        echoes = scan_echoes(target, track, np.deg2rad(70.0))
        ratios.append(
            float(
                np.median(
                    depolarization_ratio(channel_matrix(echoes, "vv"), channel_matrix(echoes, "vh"))
                )
            )
        )
    assert ratios[0] == 0.0
    assert ratios[1] > 1e-3


def test_face_echo_geometry_at_normal_incidence() -> None:
    # A monostatic sensor 1 m from the centre facing a 0.3 m square: path 2 x 0.85 m.
    sq = np.array([[-0.15, -0.15], [0.15, -0.15], [0.15, 0.15], [-0.15, 0.15]])
    echoes = prism_echoes(PrismTarget(vertices=sq), [[1.0, 0.0]], [[1.0, 0.0]], [[-1.0, 0.0]])
    face = np.flatnonzero(echoes.kind == FACE)
    lengths = echoes.length[0, face]
    assert np.nanmin(lengths) == pytest.approx(1.7)
    assert np.isfinite(lengths).sum() == 1  # only the facing side is lit


def test_track_centre_of_a_partial_circle_and_band_limited_sampling() -> None:
    from fusion_center.objects.scan import sample_at, track_centre

    track = CircleTrack(centre=(0.3, -0.2), radius=0.7, start=0.7, span=np.deg2rad(100.0))
    assert np.allclose(track_centre(track.poses()), [0.3, -0.2], atol=1e-9)
    n = 64
    t = np.arange(n)
    tone = np.cos(2 * np.pi * 3 * t / n)
    got = sample_at(np.stack([tone, tone]), np.array([10.25, 40.5]))
    assert np.allclose(got, np.cos(2 * np.pi * 3 * np.array([10.25, 40.5]) / n), atol=1e-9)
