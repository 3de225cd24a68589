"""Generated buildings of ``uwbnet scale`` (sim_nodes.building)."""

from __future__ import annotations

import numpy as np
import pytest

from sim_nodes.building import ROOM_DEPTH, building_length, building_scenario
from sim_nodes.network import SimNetwork


@pytest.mark.parametrize("n", [1, 5, 12, 101])
def test_building_has_the_requested_nodes_inside_it(n):
    s = building_scenario(n, 3, seed=2)
    assert len(s.nodes) == n and len(s.people) == 3
    xy = np.array([nd.pose[:2] for nd in s.nodes])
    assert (xy[:, 0] > 0).all() and (xy[:, 0] < building_length(n)).all()
    assert (xy[:, 1] > 0).all() and (xy[:, 1] < ROOM_DEPTH).all()


def test_people_cross_the_middle_of_their_route_soon_and_stay_inside():
    s = building_scenario(12, 2, seed=1)
    net = SimNetwork(s, 1)
    xs: dict[int, list[float]] = {}
    for t in np.arange(0.0, 12.0, 0.5):
        for p in net.truth(t):
            xs.setdefault(p["id"], []).append(p["x"])
    assert sorted(xs) == [1, 2]
    for x in xs.values():
        x = np.array(x)
        assert ((x > 0) & (x < building_length(12))).all()
        # Each person passes x = 15 (the centre of the 30 m building) within 12 s.
        assert ((x - 15.0)[:-1] * (x - 15.0)[1:] < 0).any()


def test_people_range_leaves_far_people_out_of_a_nodes_acquisition():
    s = building_scenario(40, 4, seed=3)
    full, culled = SimNetwork(s, 1), SimNetwork(s, 1, people_range=20.0)
    node = s.nodes[0].id  # at x = 2.5: every person of seed 3 is farther than 20 m
    far = all(abs(p["x"] - 2.5) > 20.0 for p in full.truth(1.0))
    a, b = full.people_spectrum(node, 1.0), culled.people_spectrum(node, 1.0)
    assert far and np.abs(a).max() > 0 and np.abs(b).max() == 0


def test_fast_synthesis_gives_the_full_synthesis_impulse_responses():
    # 40 nodes, 8 people in 10 rooms: people behind walls, in range and out of range.
    s = building_scenario(40, 8, seed=4)
    fast = SimNetwork(s, 7, people_range=20.0)
    full = SimNetwork(s, 7, people_range=20.0, reference=True)
    # The fast path really leaves people and walls out for nodes at the building's ends.
    local = fast._local[s.nodes[0].id]
    assert local is not None and local.walls.count < fast.walls.count
    assert local.walkers.size < len(fast.crowd.walkers)
    echo = 0.0
    for f in range(6):
        for k, node in enumerate(fast.node_ids):
            t = 1.0 + 0.7 * f + 0.02 * k / 40
            ha, hb = fast.acquire(node, t)[2], full.acquire(node, t)[2]
            # Same people, walls and draws in the same order: identical, noise included.
            np.testing.assert_array_equal(ha, hb)
            echo = max(echo, float(np.abs(full.people_spectrum(node, t)).max()))
            fast.people_spectrum(node, t)  # keep both fluctuation streams in step
    assert echo > 0.0  # some node saw a person, so the people's part was compared


def test_a_node_no_person_can_reach_keeps_its_noise_stream():
    # 40 nodes, 2 people over 3 rooms each: the first room's nodes never see anyone, and
    # skip the people's synthesis; their impulse responses (noise included) stay those of
    # the full synthesis, in a batch and alone, and so do the next acquisitions of every node.
    s = building_scenario(40, 2, seed=1)
    fast = SimNetwork(s, 5, people_range=20.0)
    full = SimNetwork(s, 5, people_range=20.0, reference=True)
    ids = fast.node_ids[:8]
    unreachable = [n for n in ids if fast._local[n].points.size == 0]
    assert len(unreachable) == 4
    for f in range(3):
        requests = [(n, 1.0 + 0.02 * f + 0.0002 * k) for k, n in enumerate(ids)]
        batch = fast.acquire_many(requests)
        for (node, t), (_, _, h) in zip(requests, batch, strict=True):
            np.testing.assert_array_equal(h, full.acquire(node, t)[2])
    node = unreachable[0]
    assert np.abs(fast.people_spectrum(node, 2.0)).max() == 0
    full.people_spectrum(node, 2.0)
    np.testing.assert_array_equal(fast.acquire(node, 2.1)[2], full.acquire(node, 2.1)[2])


def test_a_radar_window_delivers_the_first_samples_with_the_noise_of_the_window():
    s = building_scenario(40, 2, seed=1)
    quiet = s.model_copy(update={"radar": s.radar.model_copy(update={"noise": False})})
    probe = SimNetwork(s, 3, people_range=20.0)
    ids = probe.node_ids[:4] + probe.node_ids[12:16]
    # people in reach of some, never of others
    assert {probe._local[n].points.size > 0 for n in ids} == {True, False}
    requests = [(n, 10.0 + 0.0002 * k) for k, n in enumerate(ids)]
    # without noise: the whole period's first 1051 samples (static + people, float32 sums)
    cut = SimNetwork(quiet, 3, people_range=20.0, window=1051).acquire_many(requests)
    whole = SimNetwork(quiet, 3, people_range=20.0).acquire_many(requests)
    echo = 0.0
    for (_, _, a), (_, _, b), node in zip(cut, whole, ids, strict=True):
        assert a.shape == (2, 1051)
        np.testing.assert_allclose(a, b[:, :1051], atol=1e-6 * np.abs(b).max())
        static = SimNetwork(quiet, 3, window=1051).static_response(node)
        echo = max(echo, float(np.abs(a - static).max()))
    assert echo > 1e-4  # some node saw a person
    # with noise: a batch is bit for bit its acquisitions one by one, noise included
    net = SimNetwork(s, 3, people_range=20.0, window=1051)
    alone = SimNetwork(s, 3, people_range=20.0, window=1051)
    for f in range(2):
        batch = net.acquire_many([(n, t + 0.02 * f) for n, t in requests])
        for (node, t), (_, _, h) in zip(requests, batch, strict=True):
            np.testing.assert_array_equal(h, alone.acquire(node, t + 0.02 * f)[2])
    assert net.node_infos()[ids[0]]["radar"]["n"] == 1051
