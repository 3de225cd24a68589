"""Batched simulation (``SimNetwork.acquire_many``, ``MSequenceRadar.impulse_responses``,
``SimulatedDriver.acquire_ahead``): bit for bit the impulse responses of one call per slot."""

from __future__ import annotations

import numpy as np
import pytest

from node_agent.tdma import SlotTiming
from sim_nodes.building import building_scenario
from sim_nodes.driver import SimulatedDriver
from sim_nodes.network import SimNetwork
from sim_nodes.radar import MSequenceRadar, RadarConfig

PEOPLE_RANGE = 20.0  # as in uwbnet scale


@pytest.fixture(scope="module")
def building():  # type: ignore[no-untyped-def]
    return building_scenario(16, 2, seed=4)


def test_impulse_responses_equal_one_call_each() -> None:
    radar = MSequenceRadar(RadarConfig())
    rng = np.random.default_rng(0)
    spectra = rng.standard_normal((5, 2, radar.n_bins)) + 1j * rng.standard_normal(
        (5, 2, radar.n_bins)
    )
    one = [radar.impulse_response(s, np.random.default_rng(10 + i)) for i, s in enumerate(spectra)]
    many = radar.impulse_responses(spectra, [np.random.default_rng(10 + i) for i in range(5)])
    assert many.shape == (5, 2, radar.config.n) and many.dtype == np.float32
    for i in range(5):
        np.testing.assert_array_equal(many[i], one[i])
    # the noise is each generator's own: other generators give other responses
    other = radar.impulse_responses(spectra, [np.random.default_rng(20 + i) for i in range(5)])
    assert not np.array_equal(other[0], many[0])
    with pytest.raises(ValueError, match="5 spectra but 4 generators"):
        radar.impulse_responses(spectra, [rng] * 4)


def test_path_spectra_equal_one_call_each() -> None:
    """Paths of 1 to 40 echoes per acquisition (different counts side by side), 2 and 3
    receivers: each spectrum bit for bit :meth:`path_spectrum` of its own paths."""
    radar = MSequenceRadar(RadarConfig())
    rng = np.random.default_rng(5)
    for n_rx, counts in ((2, (1, 7, 40, 12)), (3, (5,)), (2, (3, 3, 3, 3, 3, 3, 3, 3))):
        paths = [
            (rng.uniform(5e-9, 80e-9, (n_rx, p)), rng.uniform(-0.2, 0.2, (n_rx, p))) for p in counts
        ]
        many = radar.path_spectra(paths)
        assert len(many) == len(paths)
        for (d, a), got in zip(paths, many, strict=True):
            want = radar.path_spectrum(d, a)
            assert got.shape == want.shape == (n_rx, radar.n_bins) and got.dtype == np.complex64
            np.testing.assert_array_equal(got, want)
    assert radar.path_spectra([]) == []


def test_acquire_many_is_bit_for_bit_acquire_in_order(building) -> None:  # type: ignore[no-untyped-def]
    one = SimNetwork(building, 4, people_range=PEOPLE_RANGE)
    many = SimNetwork(building, 4, people_range=PEOPLE_RANGE)
    probe = SimNetwork(building, 4, people_range=PEOPLE_RANGE)  # own streams: only looks
    nodes = one.node_ids[4:12]  # a node process's adjacent slots
    period = building.frame_period
    walked = 0
    for frame in range(0, 400, 7):  # 8 s of a walk: people come and go in these rooms
        requests = [(node, frame * period + (4 + s) * period / 16) for s, node in enumerate(nodes)]
        expected = [one.acquire(node, t) for node, t in requests]
        got = many.acquire_many(requests)
        for (tx, rx, h), (tx2, rx2, h2) in zip(expected, got, strict=True):
            assert (tx, rx) == (tx2, rx2)
            np.testing.assert_array_equal(h2, h)
        walked += sum(bool(np.any(probe.people_spectrum(n, t))) for n, t in requests)
    assert walked > 0  # people's echoes were in the batches, not only the static channel


def test_acquire_many_serves_a_repeated_node_one_by_one(building) -> None:  # type: ignore[no-untyped-def]
    one = SimNetwork(building, 2, people_range=PEOPLE_RANGE)
    many = SimNetwork(building, 2, people_range=PEOPLE_RANGE)
    requests = [("n001", 1.0), ("n002", 1.001), ("n001", 1.02)]
    expected = [one.acquire(node, t)[2] for node, t in requests]
    for h, (_, _, h2) in zip(expected, many.acquire_many(requests), strict=True):
        np.testing.assert_array_equal(h2, h)
    assert many.acquire_many([]) == []
    with pytest.raises(KeyError, match="nobody"):
        many.acquire_many([("nobody", 1.0)])


def _slot(t: float, k: int) -> SlotTiming:
    return SlotTiming(frame=0, slot=k, tx=f"n00{k}/tx", t=t, duration=0.001)


def test_drivers_acquired_ahead_give_what_they_simulate_themselves(building) -> None:  # type: ignore[no-untyped-def]
    one = SimNetwork(building, 5, people_range=PEOPLE_RANGE)
    many = SimNetwork(building, 5, people_range=PEOPLE_RANGE)
    nodes = ["n000", "n001", "n002"]
    solo = [SimulatedDriver(one, n, start=100.0) for n in nodes]
    batch = [SimulatedDriver(many, n, start=100.0) for n in nodes]
    try:
        for frame in range(3):
            slots = [_slot(102.0 + 0.02 * frame + 0.001 * k, k) for k in range(3)]
            SimulatedDriver.acquire_ahead(list(zip(batch, slots, strict=True)))
            for d1, d2, slot in zip(solo, batch, slots, strict=True):
                a, b = d1.acquire(slot), d2.acquire(slot)
                assert (b.t, b.tx, b.rx) == (a.t, a.tx, a.rx)
                np.testing.assert_array_equal(b.h, a.h)
        # an acquisition prepared for a slot that is then not served is not returned for
        # another slot: the driver simulates that one itself
        SimulatedDriver.acquire_ahead([(batch[0], _slot(103.0, 0))])
        late = batch[0].acquire(_slot(103.02, 0))
        assert late.t == 103.02
        assert not np.array_equal(late.h, batch[0].network.static_response("n000"))
    finally:
        for d in solo + batch:
            d.close()
