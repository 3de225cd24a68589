"""SimNetwork: node descriptions, schedule, acquisition, truth, determinism, detectability."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sim_nodes.network import SimNetwork
from sim_nodes.radar import C
from sim_nodes.scene import load_scenario, parse_scenario

from .conftest import peak


@pytest.fixture(scope="module")
def foyer3():  # type: ignore[no-untyped-def]
    return load_scenario("foyer3")


def _one_person(noise: bool, **person: object) -> SimNetwork:
    data = {
        "name": "one",
        "radar": {"noise": noise},
        "nodes": [{"id": "a", "role": "bat", "pose": [0.0, 0.0, 1.2, 0.0]}],
        "people": [{"id": 7, "waypoints": [[4.0, 0.0], [4.0, 3.0]], "speed": 1.0, **person}],
    }
    return SimNetwork(parse_scenario(data), seed=3)


def test_node_infos_follow_the_protocol(foyer3) -> None:  # type: ignore[no-untyped-def]
    infos = SimNetwork(foyer3, seed=1).node_infos()
    assert list(infos) == [f"bat{i}" for i in range(1, 7)]
    info = infos["bat3"]
    assert info["role"] == "bat" and info["mobile"] is False
    assert info["pose"] == [9.5, 0.25, 1.2, 1.25]
    ant = info["antennas"]
    assert ant["tx"] == {
        "pos": [0, 0, 0],
        "tx": True,
        "rx": False,
        "boresight": 0.0,
        "beamwidth": 1.75,
    }
    assert ant["rx1"]["pos"] == [0, 0.5, 0] and ant["rx2"]["pos"] == [0, -0.5, 0]
    assert ant["rx1"]["rx"] and not ant["rx1"]["tx"]
    assert info["radar"] == {
        "fs": 7e9,
        "n": 4095,
        "t0": 0.0,
        "f_low": 0.0,
        "f_high": 3.5e9,
        "rate": 50.0,
    }


def test_schedule_fills_the_frame_with_one_slot_per_node(foyer3) -> None:  # type: ignore[no-untyped-def]
    slots = SimNetwork(foyer3, seed=1).schedule()
    assert [s["tx"] for s in slots] == [f"bat{i}/tx" for i in range(1, 7)]
    assert [s["slot"] for s in slots] == list(range(6))
    end = max(s["start"] + s["duration"] for s in slots)
    assert end == pytest.approx(0.02)
    starts = [s["start"] for s in slots]
    assert starts == sorted(starts)


def test_acquire_shape_dtype_and_names(foyer3) -> None:  # type: ignore[no-untyped-def]
    tx, rx, h = SimNetwork(foyer3, seed=1).acquire("bat2", 1.0)
    assert tx == "bat2/tx"
    assert rx == ("rx1", "rx2")
    assert h.dtype == np.float32 and h.shape == (2, 4095)
    assert np.all(np.isfinite(h))


def test_same_seed_same_responses_other_seed_differs(foyer3) -> None:  # type: ignore[no-untyped-def]
    times = [0.0, 0.02, 0.04, 3.0]
    a, b, c = (SimNetwork(foyer3, seed=s) for s in (5, 5, 6))
    for t in times:
        for node in ("bat1", "bat6"):
            np.testing.assert_array_equal(a.acquire(node, t)[2], b.acquire(node, t)[2])
    assert not np.array_equal(a.acquire("bat1", 4.0)[2], c.acquire("bat1", 4.0)[2])


def test_a_node_depends_only_on_its_own_acquisition_times(foyer3) -> None:  # type: ignore[no-untyped-def]
    a, b = SimNetwork(foyer3, seed=9), SimNetwork(foyer3, seed=9)
    b.acquire("bat2", 0.0)  # another node's activity must not change bat1's stream
    np.testing.assert_array_equal(a.acquire("bat1", 0.5)[2], b.acquire("bat1", 0.5)[2])


def test_truth_follows_the_waypoints(foyer3) -> None:  # type: ignore[no-untyped-def]
    net = SimNetwork(foyer3, seed=1)
    truth = {p["id"]: p for p in net.truth(2.0)}
    assert set(truth) == {1, 2}  # person 3 enters at 7 s
    p1 = truth[1]
    length = math.hypot(10.0, 6.0)
    assert p1["x"] == pytest.approx(1.0 + 2.6 * 10.0 / length)
    assert p1["y"] == pytest.approx(1.5 + 2.6 * 6.0 / length)
    assert math.hypot(p1["vx"], p1["vy"]) == pytest.approx(1.3)
    back = {p["id"]: p for p in net.truth(length / 1.3 + 1.0)}[1]  # walking back
    assert back["vx"] < 0 and back["vy"] < 0
    assert {p["id"] for p in net.truth(7.5)} == {1, 2, 3}
    assert {p["id"] for p in net.truth(0.5)} == {1}  # person 2 enters at 0.9 s


def test_people_never_walk_through_each_other_in_foyer3(foyer3) -> None:  # type: ignore[no-untyped-def]
    net = SimNetwork(foyer3, seed=1)
    closest = np.inf
    for t in np.arange(0.0, 60.0, 0.05):
        xy = np.array([(p["x"], p["y"]) for p in net.truth(float(t))])
        d = np.linalg.norm(xy[:, None] - xy[None], axis=-1) + np.eye(len(xy)) * 1e9
        closest = min(closest, float(d.min()))
    assert closest > 0.8


def test_people_1_and_2_cross_each_other_in_foyer3(foyer3) -> None:  # type: ignore[no-untyped-def]
    net = SimNetwork(foyer3, seed=1)
    gaps = []
    for t in np.arange(1.0, 20.0, 0.05):
        tr = {p["id"]: p for p in net.truth(float(t))}
        gaps.append(math.dist((tr[1]["x"], tr[1]["y"]), (tr[2]["x"], tr[2]["y"])))
    assert min(gaps) < 1.5


def test_person_echo_after_background_subtraction_is_at_its_bistatic_range() -> None:
    net = _one_person(noise=False, mode="once")
    t = 1.0
    _, _, h = net.acquire("a", t)
    diff = h - net.static_response("a")
    person = net.truth(t)[0]
    for row, rx_y in zip(diff, (0.5, -0.5), strict=True):
        k, _ = peak(row)
        d1 = math.hypot(person["x"], person["y"])
        d2 = math.hypot(person["x"], person["y"] - rx_y)
        # The echo comes from the body front (about 0.15-0.22 m nearer than the centre).
        assert -0.6 < C * k / 7e9 - (d1 + d2) < 0.1


def test_person_is_clearly_above_noise_after_background_subtraction() -> None:
    net = _one_person(noise=True, mode="once")
    static = net.static_response("a")
    _, _, h = net.acquire("a", 1.0)
    diff = (h - static)[0]
    sigma = net.radar.noise_std
    person = net.truth(1.0)[0]
    k_true = round(2 * math.hypot(person["x"], person["y"]) / C * 7e9)
    window = np.abs(diff[k_true - 20 : k_true + 4])  # the body front is nearer than its centre
    assert window.max() > 8 * sigma  # about 5 m: detectable
    far = np.abs(diff[2000:])  # nothing there but noise
    assert far.max() < 6 * sigma


def test_a_person_standing_behind_another_fades_when_the_front_one_is_there() -> None:
    # Frozen fluctuation (huge correlation time) so only the geometry changes between t.
    data = {
        "name": "shadow",
        "radar": {"noise": False},
        "channel": {"fluctuation_time": 1e9, "gait_amplitude": 0.0, "breathing_amplitude": 0.0},
        "nodes": [{"id": "a", "role": "bat", "pose": [0.0, 0.0, 1.2, 0.0]}],
        "people": [
            # Person 1 stands at 3 m on boresight until t = 1 s, then leaves.
            {"id": 1, "waypoints": [[3.0, 0.0], [3.0, 0.01]], "mode": "once", "leave": 1.0},
            {"id": 2, "waypoints": [[6.0, 0.0], [6.0, 0.01]], "mode": "once"},
        ],
    }
    net = SimNetwork(parse_scenario(data), seed=4)
    static = net.static_response("a")
    k = round(12.0 / C * 7e9)  # person 2 at about 12 m bistatic
    window = slice(k - 25, k + 5)
    behind = np.abs((net.acquire("a", 0.5)[2] - static)[:, window]).max()
    alone = np.abs((net.acquire("a", 1.5)[2] - static)[:, window]).max()
    assert 20 * np.log10(alone / behind) > 15.0


def test_a_standing_person_breathes() -> None:
    data = {
        "name": "breath",
        "radar": {"noise": False},
        "channel": {"fluctuation_time": 1e9, "breathing_amplitude": 0.01, "breathing_rate": 0.25},
        "nodes": [{"id": "a", "role": "bat", "pose": [0.0, 0.0, 1.2, 0.0]}],
        "people": [{"id": 1, "waypoints": [[4.0, 0.0], [4.0, 0.01]], "mode": "once"}],
    }
    net = SimNetwork(parse_scenario(data), seed=4)
    ranges = []
    for t in np.arange(1.0, 5.0, 0.25):  # one breathing period
        body = net.crowd.scatterers(float(t))
        ranges.append(np.linalg.norm(body.points[:, :2], axis=1))
    swing = np.ptp(np.array(ranges), axis=0)
    # 2 x 1 cm peak to peak along the body normal: full swing for the point facing the
    # radar, less for points whose normal is across the line of sight.
    assert swing.max() > 0.015
    assert np.all(swing < 0.021)


def test_only_bat6_looks_through_a_wall_into_the_foyer(foyer3) -> None:  # type: ignore[no-untyped-def]
    from sim_nodes.channel import wall_crossings

    net = SimNetwork(foyer3, seed=1)
    centre = np.array([[6.0, 4.5, 1.2]])
    for node in net.node_ids:
        tx = np.array([net.node_infos()[node]["pose"][:3]])
        trans, _ = wall_crossings(tx, centre, net.walls)
        expected = 10 ** (-7 / 20) if node == "bat6" else 1.0  # the brick partition
        assert trans[0] == pytest.approx(expected), node


def test_hybrid_and_image2d_models_agree_on_wall_echo_delays(foyer3) -> None:  # type: ignore[no-untyped-def]
    # Both are image methods on the same vertical walls: with scatterers and diffraction off
    # the hybrid model must find exactly the image2d paths (delays), only the reflection
    # coefficients differ (Fresnel vs scalar Gamma).
    import dataclasses

    from sim_nodes.channel import image_paths
    from sim_nodes.channel.antenna import OmniPattern
    from sim_nodes.channel.raytrace import AntennaArray
    from sim_nodes.propagation import hybrid_channel

    net = SimNetwork(foyer3, seed=1)
    channel = hybrid_channel(foyer3, np.random.default_rng(0))
    channel.config = dataclasses.replace(channel.config, diffraction=False)
    for node in net._nodes.values():
        delays, amps = image_paths(node.tx, node.rx, net.walls, 2)
        for r in range(2):
            expected = np.sort(delays[r][amps[r] != 0])
            paths = channel.paths(
                AntennaArray(
                    position=node.tx.position, yaw=node.tx.boresight, pattern=OmniPattern()
                ),
                AntennaArray(
                    position=node.rx.position[r : r + 1],
                    yaw=node.rx.boresight[r : r + 1],
                    pattern=OmniPattern(),
                ),
                scatterers=False,
            )
            np.testing.assert_allclose(np.sort(paths.delay), expected, rtol=0, atol=1e-15)


def test_hybrid_static_response_adds_scatterer_energy(foyer3) -> None:  # type: ignore[no-untyped-def]
    data = foyer3.model_dump()
    data["channel"]["n_scatterers"] = 0  # the same model as pure ray tracing
    traced = SimNetwork(parse_scenario(data), seed=2)
    hybrid = SimNetwork(foyer3, seed=2)
    for node in ("bat1", "bat6"):  # in the foyer, and behind the brick partition
        rt, hyb = traced.static_response(node), hybrid.static_response(node)
        # Same direct coupling (the strongest sample), more energy in the multipath tail.
        assert np.argmax(np.abs(hyb[0])) == np.argmax(np.abs(rt[0]))
        late = slice(200, 1200)  # 8.6 m to 51 m of bistatic range
        assert np.sum(hyb[:, late] ** 2) > 1.2 * np.sum(rt[:, late] ** 2)
