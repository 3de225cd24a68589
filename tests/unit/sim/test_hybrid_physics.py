"""Hybrid channel physics: Friis, metal reflections and their signs, Fresnel, transmission,
diffraction, antenna patterns, the NUFFT synthesis and the scatterer clusters of eq. (1)-(3)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from sim_nodes.channel.antenna import HornPattern, OmniPattern, TablePattern
from sim_nodes.channel.hybrid import (
    HybridChannel,
    HybridConfig,
    draw_clusters,
    surface_scatterers,
)
from sim_nodes.channel.materials import Material, complex_permittivity, fresnel
from sim_nodes.channel.params import delay_moments, path_loss_db, power_delay_profile
from sim_nodes.channel.raytrace import (
    DIFFRACTED,
    LOS,
    REFLECTED,
    SCATTERED,
    AntennaArray,
    PathSet,
    trace,
)
from sim_nodes.channel.room import WALL, FaceSpec, Room, vertical_face
from sim_nodes.channel.synth import frequency_response, friis_amplitude
from sim_nodes.radar import C

F0, DF, NF = 4.5e9, 6.25e6, 1425  # the chapter's grid: 4.5-13.4 GHz
FREQS = F0 + DF * np.arange(NF)
METAL = Material(metal=True)


def omni(*pos: tuple[float, float, float]) -> AntennaArray:
    return AntennaArray(position=np.array(pos, float), yaw=np.zeros(len(pos)))


def metal_wall_room(x: float = 5.0) -> Room:
    vert, n = vertical_face([x, -20.0], [x, 20.0], -10.0, 10.0, [-1.0, 0.0])
    face = FaceSpec(vertices=vert, normal=n, material=0, two_sided=False, kind=WALL, name="w")
    return Room.build([face], (METAL,))


def metal_floor_room() -> Room:
    vert = np.array([[-20.0, -20, 0], [20, -20, 0], [20, 20, 0], [-20, 20, 0]])
    face = FaceSpec(
        vertices=vert, normal=np.array([0, 0, 1.0]), material=0, two_sided=False, kind=1, name="f"
    )
    return Room.build([face], (METAL,))


def test_free_space_path_loss_matches_friis_within_0_1_db() -> None:
    tx, rx = omni((0.3, -0.2, 1.1)), omni((4.0, 2.5, 1.6))
    d = float(np.linalg.norm(tx.position[0] - rx.position[0]))
    paths, _ = trace(Room.build([], ()), tx, rx, FREQS[[0, -1]], max_order=3)
    assert paths.count == 1 and paths.kind[0] == LOS
    h = frequency_response(paths, 1, F0, DF, NF)[0]
    loss_db = -20 * np.log10(np.abs(h * friis_amplitude(FREQS)))
    friis_db = 20 * np.log10(4 * np.pi * d * FREQS / C)
    assert np.max(np.abs(loss_db - friis_db)) < 0.1
    # The band-averaged figure agrees too (power average of the Friis loss).
    friis_band = -10 * np.log10(np.mean(10 ** (-friis_db / 10)))
    assert path_loss_db(h[None], FREQS)[0] == pytest.approx(friis_band, abs=0.1)


def test_metal_wall_reflection_has_mirror_delay_and_negative_sign() -> None:
    tx, rx = omni((1.0, 2.0, 1.2)), omni((1.0, 1.0, 1.2))
    paths, _ = trace(metal_wall_room(5.0), tx, rx, [9e9], max_order=1, diffraction=False)
    refl = paths.select(paths.kind == REFLECTED)
    assert refl.count == 1
    length = np.linalg.norm(np.array([9.0, 2.0, 1.2]) - rx.position[0])  # image in x = 5
    assert refl.delay[0] == pytest.approx(length / C, rel=1e-12)
    # Vertical polarization on a vertical PEC wall is TE: Gamma = -1, amplitude -1/d.
    assert refl.amplitude[0, 0] == pytest.approx(-1.0 / length, rel=1e-9)
    # The reflection point is on the wall, half-way in y.
    assert refl.faces[0, 0] == 0


def test_metal_floor_reflection_of_vertical_polarization_is_positive() -> None:
    # A vertical dipole's image in a ground plane points the same way: amplitude +1/d.
    tx, rx = omni((0.0, 0.0, 1.0)), omni((4.0, 0.0, 1.0))
    paths, _ = trace(metal_floor_room(), tx, rx, [9e9], max_order=1)
    refl = paths.select(paths.kind == REFLECTED)
    length = np.hypot(4.0, 2.0)
    assert refl.count == 1
    assert refl.delay[0] == pytest.approx(length / C, rel=1e-12)
    assert refl.amplitude[0, 0].real == pytest.approx(1.0 / length, rel=1e-9)


def test_fresnel_limits_normal_incidence_brewster_and_conductivity() -> None:
    eps = 4.0
    te, tm = fresnel(eps, 1.0)
    assert te == pytest.approx(-(2 - 1) / (2 + 1))
    assert tm == pytest.approx((2 - 1) / (2 + 1))  # e' = -Gamma_TM e_par: same field reversal
    brewster = np.arctan(np.sqrt(eps))
    _, tm_b = fresnel(eps, np.cos(brewster))
    assert abs(tm_b) < 1e-12
    te_g, tm_g = fresnel(eps, 0.0)  # grazing: total reflection
    assert te_g == pytest.approx(-1.0) and tm_g == pytest.approx(-1.0)
    # Conductivity: |Gamma| grows towards 1 and decreases with frequency.
    lossy = complex_permittivity(5.0, 0.5, np.array([1e9, 10e9]))
    g = np.abs(fresnel(lossy, 1.0)[0])
    assert g[0] > g[1] > abs(fresnel(5.0, 1.0)[0])


def test_wall_transmission_loss_and_excess_delay_and_metal_blocks() -> None:
    tx, rx = omni((0.0, 0.0, 1.0)), omni((6.0, 0.0, 1.0))
    vert, n = vertical_face([3.0, -5.0], [3.0, 5.0], 0.0, 3.0, [1.0, 0.0])
    slab = Material(permittivity=4.0, transmission=10 ** (-8 / 20), excess=0.24)
    wall = FaceSpec(vertices=vert, normal=n, material=0, two_sided=True, kind=WALL, name="w")
    paths, _ = trace(Room.build([wall], (slab,)), tx, rx, [9e9], max_order=0)
    assert paths.count == 1 and paths.n_transmissions[0] == 1
    assert paths.amplitude[0, 0].real == pytest.approx(10 ** (-8 / 20) / 6.0, rel=1e-9)
    assert C * paths.delay[0] == pytest.approx(6.24, rel=1e-12)
    blocked, _ = trace(Room.build([wall], (METAL,)), tx, rx, [9e9], max_order=0)
    assert blocked.count == 0


def test_diffraction_fills_the_shadow_behind_a_metal_screen() -> None:
    # A metal screen x = 2, y in [-3, 0.5], floor to 3 m, with free (diffracting) ends.
    vert, n = vertical_face([2.0, -3.0], [2.0, 0.5], 0.0, 3.0, [1.0, 0.0])
    screen = FaceSpec(vertices=vert, normal=n, material=0, two_sided=True, kind=WALL, name="s")
    room = Room.build([screen], (METAL,), [(2.0, -3.0, 0.0, 3.0), (2.0, 0.5, 0.0, 3.0)])
    tx, rx = omni((0.0, 0.0, 1.0)), omni((4.0, 0.0, 1.0))
    paths, _ = trace(room, tx, rx, FREQS[[0, -1]], max_order=1)
    assert not np.any(paths.kind == LOS)  # the screen blocks the direct path
    dif = paths.select(paths.kind == DIFFRACTED)
    assert dif.count == 2  # round each free end
    np.testing.assert_allclose(
        np.sort(C * dif.delay), [2 * np.hypot(2.0, 0.5), 2 * np.hypot(2.0, 3.0)], rtol=1e-12
    )
    # Weaker than a free-space path of that length, and weaker at the top of the band
    # (D ~ sqrt(lambda)).
    amp = np.abs(dif.amplitude)
    assert np.all(amp[:, 0] < 1 / (C * dif.delay)) and np.all(amp[:, 1] < amp[:, 0])
    assert amp[0, 0] / amp[0, 1] == pytest.approx(np.sqrt(FREQS[-1] / FREQS[0]), rel=1e-9)


def test_horn_pattern_is_3db_at_half_beamwidth_and_narrows_with_frequency() -> None:
    horn = HornPattern()  # 60 degrees at 9 GHz
    half = np.radians(30.0)
    g = horn.amplitude(np.array([0.0, half, 0.0]), np.array([0.0, 0.0, half]), 9e9)
    assert 20 * np.log10(g[0]) == pytest.approx(0.0)
    assert 20 * np.log10(g[1]) == pytest.approx(-3.0, abs=1e-9)
    assert 20 * np.log10(g[2]) == pytest.approx(-3.0, abs=1e-9)
    assert horn.amplitude(half, 0.0, 13.4e9) < g[1] < horn.amplitude(half, 0.0, 4.5e9)
    assert 20 * np.log10(horn.amplitude(np.pi, 0.0, 9e9)) == pytest.approx(-25.0)
    assert np.all(OmniPattern().amplitude(np.linspace(-3, 3, 5), 0.0, 9e9) == 1.0)


def test_table_pattern_interpolates_and_wraps_azimuth() -> None:
    az = np.radians(np.arange(-180, 180, 90.0))  # -180, -90, 0, 90
    el = np.radians([-30.0, 30.0])
    gain = np.array([[-20.0, -10.0, 0.0, -10.0], [-20.0, -10.0, -6.0, -10.0]])
    tab = TablePattern(az, el, gain)
    db = 20 * np.log10(tab.amplitude(np.radians([0.0, 45.0, 135.0, 180.0]), 0.0, 9e9))
    # el = 0 is half-way between the two rows: azimuth 45 deg -> ((0 - 10) + (-6 - 10)) / 4.
    np.testing.assert_allclose(db, [-3.0, -6.5, -15.0, -20.0], atol=1e-9)


def test_direct_synthesis_agrees_with_the_nufft() -> None:
    rng = np.random.default_rng(4)
    n_p = 400
    knots = np.array([4.5e9, 13.4e9])
    amp = rng.normal(size=(n_p, 2)) + 1j * rng.normal(size=(n_p, 2))
    ps = PathSet(
        rx=rng.integers(0, 2, n_p),
        delay=rng.uniform(1e-9, 200e-9, n_p),
        amplitude=amp,
        knots=knots,
        kind=np.zeros(n_p, int),
        order=np.zeros(n_p, int),
        faces=np.zeros((n_p, 1), int),
        aod=np.zeros((n_p, 2)),
        aoa=np.zeros((n_p, 2)),
        n_transmissions=np.zeros(n_p, int),
    )
    h = frequency_response(ps, 2, F0, DF, NF, delay_offset=1e-9)
    t = (FREQS - knots[0]) / (knots[1] - knots[0])
    a_f = amp[:, :1] * (1 - t) + amp[:, 1:] * t  # (P, K)
    ref = np.stack(
        [
            np.sum(a_f[m] * np.exp(-2j * np.pi * FREQS * (ps.delay[m, None] - 1e-9)), axis=0)
            for m in (ps.rx == 0, ps.rx == 1)
        ]
    )
    assert np.max(np.abs(h - ref)) < 1e-5 * np.max(np.abs(ref))


def shoebox(material: Material) -> Room:
    faces = []
    sq = np.array([[0.0, 0.0], [6.0, 0.0], [6.0, 4.0], [0.0, 4.0]])
    for a, b in zip(sq, np.roll(sq, -1, axis=0), strict=True):
        e = b - a
        vert, n = vertical_face(a, b, 0.0, 3.0, [-e[1], e[0]])
        faces.append(
            FaceSpec(vertices=vert, normal=n, material=0, two_sided=False, kind=WALL, name="w")
        )
    for z, s in ((0.0, 1.0), (3.0, -1.0)):
        vert = np.concatenate([sq, np.full((4, 1), z)], axis=1)
        faces.append(
            FaceSpec(
                vertices=vert,
                normal=np.array([0, 0, s]),
                material=0,
                two_sided=False,
                kind=1 if s > 0 else 2,
                name="fc",
            )
        )
    return Room.build(faces, (material,))


def test_scatterer_energy_never_exceeds_the_a_p_n_bound() -> None:
    cfg = HybridConfig(max_order=3, scatter_order=3, n_scatterers=16, knots=(9e9,))
    room = shoebox(Material(permittivity=5.0, conductivity=0.05))
    channel = HybridChannel(room, cfg, np.random.default_rng(7))
    tx, rx = omni((1.0, 1.0, 1.5)), omni((4.5, 3.0, 1.2), (2.0, 2.5, 0.8))
    paths = channel.paths(tx, rx)
    det = paths.select(paths.kind != SCATTERED)
    sc = paths.select(paths.kind == SCATTERED)
    bound_amp = cfg.a + cfg.p * cfg.radius
    for r in range(2):
        parents = det.select((det.rx == r) & (det.order >= 1) & (det.order <= 3))
        # Each path of order k carries k clusters of about N scatterers (Poisson, mean N:
        # summed over dozens of clusters the count stays well under 1.5 N each), each at
        # most (a + p r) times its specular amplitude (L_n >= L_spec).
        bound = (
            1.5
            * cfg.n_scatterers
            * bound_amp**2
            * np.sum(parents.order * np.abs(parents.amplitude[:, 0]) ** 2)
        )
        energy = np.sum(np.abs(sc.amplitude[sc.rx == r, 0]) ** 2)
        assert 0 < energy <= bound
        # And it is not vanishingly small either: a few scatterers drop off the faces.
        assert energy > 0.2 * cfg.n_scatterers * cfg.a**2 * np.sum(
            np.abs(parents.amplitude[:, 0]) ** 2
        )
    assert np.max(np.abs(sc.amplitude[:, 0])) <= bound_amp * np.max(np.abs(det.amplitude[:, 0]))


def test_clusters_are_seeded_per_realization() -> None:
    cfg = HybridConfig(
        max_order=1, scatter_order=1, n_scatterers=8, knots=(9e9,), diffraction=False
    )
    room = shoebox(METAL)
    tx, rx = omni((1.0, 1.0, 1.5)), omni((4.0, 2.0, 1.5))
    pa, pb, pc = (
        HybridChannel(room, cfg, np.random.default_rng(s)).paths(tx, rx) for s in (3, 3, 4)
    )
    np.testing.assert_array_equal(pa.delay, pb.delay)
    assert not np.array_equal(np.sort(pa.delay), np.sort(pc.delay))


def test_issue_8_scatterers_stay_fixed_on_the_wall_when_the_robot_drives() -> None:
    # A robot (Tx and Rx 0.2 m apart) drives 2 m along a metal wall. Every first-order
    # scattered path must go through one of a fixed set of points on the wall: the field
    # that surface_scatterers returns around wall points, independently of any Tx/Rx. The
    # old model moved each cluster with its specular point, so its rays matched no
    # fixed point.
    cfg = HybridConfig(
        max_order=1, scatter_order=1, n_scatterers=16, knots=(9e9,), diffraction=False
    )
    room = metal_wall_room(5.0)
    channel = HybridChannel(room, cfg, np.random.default_rng(11))
    grid = np.array([[5.0, y, z] for y in np.arange(-2.0, 5.01, 0.25) for z in (0.5, 1.0, 1.5)])
    _, field, _ = surface_scatterers(
        room, np.zeros(len(grid), np.int64), grid, channel.clusters, cfg.radius
    )
    field = np.unique(np.round(field, 9), axis=0)
    assert len(field) > 50
    used = np.zeros(len(field), bool)
    for y in np.linspace(0.0, 2.0, 5):
        tx, rx = omni((1.0, y, 1.0)), omni((1.0, y + 0.2, 1.0))
        paths = channel.paths(tx, rx)
        sc = paths.select(paths.kind == SCATTERED)
        assert sc.count > 5
        length = np.linalg.norm(field - tx.position[0], axis=1) + np.linalg.norm(
            field - rx.position[0], axis=1
        )
        miss = np.abs(sc.delay[:, None] * C - length[None, :])
        assert np.max(np.min(miss, axis=1)) < 1e-6
        used |= np.any(miss < 1e-6, axis=0)
    # Driving sweeps the cluster over new scatterers of the same field.
    assert used.sum() > 2 * cfg.n_scatterers


def test_surface_scatterer_field_has_n_per_disc_and_is_shared_by_nearby_points() -> None:
    room = metal_wall_room(5.0)
    radius, n = 1.0, 16
    clusters = draw_clusters(4096, n, radius, np.random.default_rng(5))
    rng = np.random.default_rng(6)
    pts = np.column_stack([np.full(400, 5.0), rng.uniform(-15, 15, 400), rng.uniform(-8, 8, 400)])
    row, _, delta = surface_scatterers(room, np.zeros(400, np.int64), pts, clusters, radius)
    assert np.all(delta < radius)
    assert np.bincount(row, minlength=400).mean() == pytest.approx(n, rel=0.1)
    # Two reflection points 0.5 m apart share the scatterers within r of both.
    a, b = np.array([[5.0, 0.0, 1.0]]), np.array([[5.0, 0.5, 1.0]])
    _, qa, _ = surface_scatterers(room, np.zeros(1, np.int64), a, clusters, radius)
    _, qb, _ = surface_scatterers(room, np.zeros(1, np.int64), b, clusters, radius)
    both_a = qa[np.linalg.norm(qa - b, axis=1) < radius]
    both_b = qb[np.linalg.norm(qb - a, axis=1) < radius]
    assert len(both_a) > 3
    np.testing.assert_allclose(np.sort(both_a, axis=0), np.sort(both_b, axis=0), atol=1e-12)


def test_hybrid_raises_delay_spread_and_power_over_ray_tracing() -> None:
    cfg = HybridConfig(max_order=3, scatter_order=3, knots=(4.5e9, 13.4e9))
    room = shoebox(Material(permittivity=5.0, conductivity=0.05))
    channel = HybridChannel(room, cfg, np.random.default_rng(1))
    tx = omni((1.0, 1.0, 1.5))
    rx = omni(*[(x, y, 1.2) for x in (2.5, 4.0, 5.2) for y in (1.0, 2.5, 3.4)])
    figs = {}
    for scat in (False, True):
        h = frequency_response(channel.paths(tx, rx, scatterers=scat), 9, F0, DF, NF)
        pdp, tau = power_delay_profile(h, DF)
        figs[scat] = (np.mean(-path_loss_db(h, FREQS)), np.mean(delay_moments(pdp, tau)[1]))
    assert figs[True][0] > figs[False][0] + 0.3  # dB more received power
    assert figs[True][1] > 1.1 * figs[False][1]  # delay spread up by more than 10 %


def test_zero_scatterers_is_pure_ray_tracing() -> None:
    room = shoebox(METAL)
    tx, rx = omni((1.0, 1.0, 1.5)), omni((4.0, 2.0, 1.5))
    base = HybridConfig(max_order=2, knots=(9e9,))
    none = HybridChannel(room, dataclasses.replace(base, n_scatterers=0), np.random.default_rng(0))
    rt = HybridChannel(room, base, np.random.default_rng(0)).paths(tx, rx, scatterers=False)
    p = none.paths(tx, rx)
    np.testing.assert_array_equal(p.delay, rt.delay)
    assert not np.any(p.kind == SCATTERED)


def test_angular_pdp_of_a_rotating_horn_points_at_the_echo() -> None:
    from sim_nodes.channel.params import angular_pdp

    # Receiver 1 m south of the Tx, metal wall at x = 5: the echo arrives from the Tx image
    # (9, 1), at atan(1/8) = 7.1 degrees; the direct path from the north (+90 degrees).
    tx, rx = omni((1.0, 1.0, 1.2)), omni((1.0, 0.0, 1.2))
    paths, _ = trace(metal_wall_room(5.0), tx, rx, FREQS[[0, -1]], max_order=1)
    headings = np.radians(np.arange(-180, 180, 3.0))
    pdp, tau = angular_pdp(paths, 0, headings, HornPattern(), F0, DF, NF)
    echo = np.argmin(np.abs(tau - paths.delay[paths.kind == REFLECTED][0]))
    direct = np.argmin(np.abs(tau - paths.delay[paths.kind == LOS][0]))
    assert np.degrees(headings[np.argmax(pdp[:, echo])]) == pytest.approx(
        np.degrees(np.arctan2(1, 8)), abs=1.6
    )
    assert np.degrees(headings[np.argmax(pdp[:, direct])]) == pytest.approx(90.0, abs=1.6)


def test_robot_data_set_stops_are_independent_and_seeded() -> None:
    from sim_nodes.propagation import hybrid_channel, robot_dataset
    from sim_nodes.scene import load_scenario

    sc = load_scenario("room_pillar")
    a = robot_dataset(sc, hybrid_channel(sc, np.random.default_rng(5)), stops=[3])
    b = robot_dataset(sc, hybrid_channel(sc, np.random.default_rng(5)), stops=[60, 3])
    np.testing.assert_array_equal(a.response[0], b.response[1])
    assert a.response.shape == (1, 120, 2, 1425)
    # Turning the robot changes what its horns see.
    power = np.mean(np.abs(a.response[0, :, 0]) ** 2, axis=-1)
    assert power.max() > 3 * power.min()
