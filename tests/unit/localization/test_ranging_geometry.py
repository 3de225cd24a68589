"""The ranging link's multipath from the scenario geometry: specular reflections of walls,
floor and ceiling, and the dense 802.15.4a multipath starting no earlier than them."""

from __future__ import annotations

import numpy as np
import pytest

from sim_nodes.channel.stochastic import RESIDENTIAL_LOS, draw_channel
from sim_nodes.network import scenario_walls
from sim_nodes.ranging import RangingSimulator, track_position
from sim_nodes.scene import ScenarioError, load_scenario, parse_scenario

C = 299792458.0


def _sim(name: str = "lab_los", seed: int = 3, **edit) -> RangingSimulator:
    data = load_scenario(name).model_dump(exclude_none=True)
    for key, value in edit.items():
        data[key] = value
    sc = parse_scenario(data)
    return RangingSimulator(sc, scenario_walls(sc), seed=seed)


def _floor_excess_ns(p: np.ndarray, a: np.ndarray, floor: float = 0.0) -> float:
    d = np.linalg.norm(a - p)
    horizontal = np.linalg.norm(a[:2] - p[:2])
    unfolded = np.hypot(horizontal, (p[2] - floor) + (a[2] - floor))
    return float((unfolded - d) / C * 1e9)


def test_no_path_arrives_before_the_first_geometric_reflection():
    sim = _sim()
    mobile = sim.scenario.mobiles[0]
    # moving and standing rounds (the multipath is redrawn or kept), every anchor
    for t in np.arange(0.0, 40.0, 0.7):
        p, _, _ = track_position(mobile, t)
        for aid, a in sim.anchors.items():
            rnd = sim.round("tag", aid, float(t))
            floor = _floor_excess_ns(p, a)
            assert rnd.delays[0] == 0.0  # the LOS direct path, undelayed
            # lab_los has no walls: the floor is the earliest surface, and nothing
            # (specular or dense) arrives before it
            assert np.min(rnd.delays[1:]) == pytest.approx(floor, abs=1e-9)
            assert floor > 1.4  # the 1.6-6.6 m links at 1.0 and 1.5 m height


def test_the_old_channel_had_rays_within_the_first_fresnel_zone():
    # why the onset matters: from the direct path, 15 % of draws have a ray within 0.1 ns
    rng = np.random.default_rng(0)
    first = [draw_channel(RESIDENTIAL_LOS, rng)[0][1] for _ in range(2000)]
    assert np.mean(np.asarray(first) < 0.1) > 0.1


def test_onset_shifts_the_dense_multipath_and_nothing_else():
    a_d, a_a = draw_channel(RESIDENTIAL_LOS, np.random.default_rng(4), max_delay=1e4)
    b_d, b_a = draw_channel(RESIDENTIAL_LOS, np.random.default_rng(4), max_delay=1e4, onset=2.5)
    assert b_d[0] == a_d[0] == 0.0 and b_a[0] == a_a[0]
    np.testing.assert_allclose(b_d[1:], a_d[1:] + 2.5)
    np.testing.assert_array_equal(b_a, a_a)
    with pytest.raises(ValueError, match="onset"):
        draw_channel(RESIDENTIAL_LOS, np.random.default_rng(4), onset=-1.0)


def test_wall_and_floor_reflections_follow_the_image_method():
    wall = {"start": [6.0, -1.0], "end": [6.0, 8.0], "thickness": 0.2, "material": "concrete"}
    sim = _sim(walls=[wall])
    gamma = -(np.sqrt(6.0) - 1) / (np.sqrt(6.0) + 1)  # concrete eps_r 6, the default floor too
    p = np.array([4.5, 1.5, 1.0])
    for aid in ("rx1", "rx2", "rx4"):  # same side of the wall as the node
        a = sim.anchors[aid]
        d = np.linalg.norm(a - p)
        refl = sim.reflections(p, aid)
        image = np.array([12.0 - p[0], p[1], p[2]])  # mirrored in x = 6
        wall_len = np.linalg.norm(a - image)
        floor_len = np.linalg.norm(a - np.array([p[0], p[1], -p[2]]))
        expect = sorted([(wall_len - d) / C * 1e9, (floor_len - d) / C * 1e9])
        np.testing.assert_allclose(np.sort(refl.delays), expect, rtol=1e-9)
        np.testing.assert_allclose(
            np.sort(refl.amplitudes), np.sort([gamma * d / wall_len, gamma * d / floor_len])
        )
        assert refl.onset == pytest.approx(min(expect))
    # the wall ends at y = 8: no specular point on it for a short wall below the link
    short = {**wall, "start": [6.0, 6.5], "end": [6.0, 8.0]}
    sim_short = _sim(walls=[short])
    assert sim_short.reflections(p, "rx1").delays.size == 1  # the floor only


def test_ceiling_and_floor_of_a_room():
    room = {
        "outline": [[-1.0, -1.0], [11.0, -1.0], [11.0, 8.0], [-1.0, 8.0], [-1.0, -1.0]],
        "material": "concrete",
        "floor": 0.0,
        "ceiling": 2.6,
        "floor_material": "brick",
    }
    ranging = load_scenario("lab_los").ranging.model_dump(exclude_none=True)
    ranging.pop("floor_material")  # [ranging]'s would override the room's
    sim = _sim(room=room, ranging=ranging)
    p = np.array([1.5, 1.5, 1.0])
    a = sim.anchors["rx1"]
    d = np.linalg.norm(a - p)
    refl = sim.reflections(p, "rx1")
    assert refl.delays.size == 4 + 2  # the outline's four walls, floor, ceiling
    ceiling_len = np.linalg.norm(a - np.array([p[0], p[1], 2 * 2.6 - p[2]]))
    floor_len = np.linalg.norm(a - np.array([p[0], p[1], -p[2]]))
    np.testing.assert_allclose(
        refl.delays[-2:], np.array([floor_len, ceiling_len]) / C * 1e9 - d / C * 1e9
    )
    gamma_brick = -(2.0 - 1) / (2.0 + 1)
    assert refl.amplitudes[-2] == pytest.approx(gamma_brick * d / floor_len)
    # the west outline wall (x = -1): image at x = -2 - 1.5
    west = np.linalg.norm(a - np.array([-2.0 - p[0], p[1], p[2]]))
    assert np.min(np.abs(refl.delays - (west - d) / C * 1e9)) < 1e-9
    # the ceiling (1.6 m above the anchor) is the earliest surface here
    assert refl.onset == pytest.approx(min(refl.delays))


def test_no_floor_reflection_for_an_anchor_below_the_floor():
    sim = _sim()
    sim.anchors["low"] = np.array([2.0, 2.0, -0.5])  # a basement anchor: no floor between
    refl = sim.reflections(np.array([1.5, 1.5, 1.0]), "low")
    assert refl.delays.size == 0 and refl.onset == 0.0


def test_nlos_links_stay_obstructed():
    sim = _sim("lab_nlos", seed=5)
    p, _, _ = track_position(sim.scenario.mobiles[0], 0.0)
    for aid, loss_db, eps in (("rx3", 18.0, 6.0), ("rx4", 10.0, 4.0)):
        link = sim.link_state(p, aid)
        assert not link.los
        rnd = sim.round("tag", aid, 0.0)
        spread = 1.0 / link.distance
        # the direct path: attenuated by the wall and late by its excess path
        assert abs(rnd.amplitudes[0]) == pytest.approx(10 ** (-loss_db / 20) * spread)
        thickness = 0.2 if aid == "rx3" else 0.24
        assert rnd.delays[0] == pytest.approx(thickness * (np.sqrt(eps) - 1) / C * 1e9)
        assert np.all(rnd.delays[1:] > rnd.delays[0])
        # the reflections cross the same wall (attenuated too): none outshines free space
        refl = sim.reflections(p, aid)
        assert np.all(np.abs(refl.amplitudes) < 10 ** (-loss_db / 20) + 1e-12)


def test_unknown_floor_material_is_rejected():
    data = load_scenario("lab_los").model_dump(exclude_none=True)
    data["ranging"]["floor_material"] = "marble"
    with pytest.raises(ScenarioError, match="floor_material"):
        parse_scenario(data)


def test_a_wall_ending_beside_the_line_of_sight_bounds_the_onset_by_its_free_edge():
    # a partition whose line separates the tag from rx1 but which ends 10 cm beside the
    # link: the link stays LOS, and energy scattered by its free edge can arrive 0.04 ns
    # after the direct path, so the dense multipath may not wait for the floor
    wall = {"start": [1.07, 0.93], "end": [2.0, 0.0], "thickness": 0.1, "material": "concrete"}
    sim = _sim(walls=[wall])
    p = np.array([1.5, 1.5, 1.0])
    a = sim.anchors["rx1"]
    assert sim.link_state(p, "rx1").los
    zs = np.linspace(0.0, 3.0, 3001)
    edge = np.stack([np.full_like(zs, 1.07), np.full_like(zs, 0.93), zs], 1)
    d = np.linalg.norm(a - p)
    via_edge = (np.linalg.norm(edge - p, axis=1) + np.linalg.norm(a - edge, axis=1) - d) / C
    onset = sim.reflections(p, "rx1").onset
    assert onset == pytest.approx(via_edge.min() * 1e9, abs=2e-3)
    assert onset < 0.1 < _floor_excess_ns(p, a)


def test_objects_in_a_ranging_scenario_are_rejected_not_ignored():
    cabinet = {
        "id": "cabinet",
        "footprint": [[0.8, 0.8], [1.1, 0.8], [1.1, 1.1], [0.8, 1.1], [0.8, 0.8]],
        "z": [0.0, 2.0],
        "material": "concrete",
    }
    with pytest.raises(ScenarioError, match=r"objects.*\[ranging\] link does not model"):
        _sim(objects=[cabinet])
