"""RTToA ranging between unsynchronised nodes: drift, offsets, walls (simulated exchanges)."""

from __future__ import annotations

import numpy as np
import pytest

from node_agent.dsp.rttoa import RoundTripRanger, double_sided_tof, single_sided_tof
from sim_nodes.network import scenario_walls
from sim_nodes.ranging import RangingSimulator, track_position
from sim_nodes.scene import load_scenario, parse_scenario

C = 299792458.0


@pytest.mark.parametrize("drift_a, drift_b", [(20e-6, -20e-6), (-5e-6, 15e-6)])
def test_double_sided_cancels_drift_single_sided_does_not(drift_a, drift_b):
    # exact timestamps on drifting clocks: tof 10 ns, reply delays 1 ms and 0.3 ms
    tof, d_b, d_a = 10e-9, 1e-3, 0.3e-3
    round_a = (1 + drift_a) * (2 * tof + d_b / (1 + drift_b))
    reply_b = d_b
    round_b = (1 + drift_b) * (2 * tof + d_a / (1 + drift_a))
    ds = double_sided_tof(round_a, d_a, round_b, reply_b)
    ss = single_sided_tof(round_a, reply_b)
    assert abs(ds - tof) * C < 1e-4  # sub-0.1 mm
    # single-sided: the drift difference times half the reply delay (metres of error)
    assert abs(ss - tof) * C == pytest.approx(abs(0.5 * d_b * (drift_a - drift_b)) * C, rel=0.01)


def _scenario(walls: bool, scheme: str = "ds"):
    base = load_scenario("lab_nlos").model_dump()
    base["ranging"]["scheme"] = scheme
    if not walls:
        base["walls"] = []
    return parse_scenario(base)


@pytest.mark.parametrize("scheme, tol", [("ds", 0.01), ("ss", None)])
def test_simulated_los_ranges_are_centimetre_accurate_only_double_sided(scheme, tol):
    sc = _scenario(walls=False, scheme=scheme)
    sim = RangingSimulator(sc, scenario_walls(sc), seed=5)
    ranger = RoundTripRanger(sim.radar, method="adaptive")
    err = []
    for k in range(20):
        rnd = sim.round("tag", "rx2", 0.1 * k)
        assert rnd.link.los
        err.append(ranger.measure(rnd.exchange).range - rnd.link.distance)
    med = float(np.median(np.abs(err)))
    if tol is not None:
        assert med < tol  # one chip is 4.3 cm; the first path is interpolated well below it
    else:
        # 20 ppm clocks over a 1 ms reply: decimetres to metres of drift error
        d_a, d_b = sim.clocks["tag"][0], sim.clocks["rx2"][0]
        assert med == pytest.approx(abs(0.5 * 1e-3 * (d_a - d_b)) * C, abs=0.02)


def test_walls_delay_and_attenuate_the_direct_path_of_nlos_links():
    sc = _scenario(walls=True)
    sim = RangingSimulator(sc, scenario_walls(sc), seed=5)
    p, _, moving = track_position(sc.mobiles[0], 0.0)
    assert not moving and p.tolist() == [1.5, 1.5, 1.0]  # pausing at the first corner
    los = sim.link_state(p, "rx1")
    next_door = sim.link_state(p, "rx3")  # through 20 cm of concrete, eps_r 6
    corridor = sim.link_state(p, "rx4")  # through 24 cm of brick, eps_r 4
    assert los.los and not next_door.los and not corridor.los
    assert next_door.excess == pytest.approx(0.2 * (np.sqrt(6.0) - 1.0))
    assert corridor.transmission == pytest.approx(10 ** (-10.0 / 20.0))
    ranger = RoundTripRanger(sim.radar)
    err = [
        ranger.measure(sim.round("tag", "rx3", 0.1 * k).exchange).range - next_door.distance
        for k in range(10)
    ]
    # positively biased by at least most of the excess path through the wall
    assert np.median(err) > 0.7 * next_door.excess
