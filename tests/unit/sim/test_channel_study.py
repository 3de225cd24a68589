"""The chapter's qualitative findings (Section 3, Fig. 12) on the simulated office."""

from __future__ import annotations

import pytest

from sim_nodes.scene import load_scenario
from sim_nodes.study import channel_study


@pytest.fixture(scope="module")
def table() -> dict[str, dict]:
    rows = channel_study(load_scenario("office"), seed=0, realizations=2, max_receivers=6)
    for r in rows:  # shown with -s, and in the failure report
        print(r)
    return {r["model"]: r for r in rows}


def ds(table: dict[str, dict], model: str) -> float:
    return table[model]["rms_delay_spread_ns"]


def test_hybrid_raises_received_power_and_delay_spread_over_ray_tracing(table: dict) -> None:
    rt, hy = table["ray tracing only"], table["hybrid (defaults)"]
    assert hy["power_db"] > rt["power_db"] + 0.5
    assert hy["rms_delay_spread_ns"] > 1.15 * rt["rms_delay_spread_ns"]
    assert hy["mean_delay_ns"] > rt["mean_delay_ns"]
    assert hy["azimuth_spread_deg"] > rt["azimuth_spread_deg"]


def test_delay_spread_grows_with_a_and_with_n(table: dict) -> None:
    assert ds(table, "a = 0.1") < ds(table, "hybrid (defaults)") < ds(table, "a = 0.4")
    assert ds(table, "N = 4") < ds(table, "hybrid (defaults)") < ds(table, "N = 64")


def test_scatterers_beyond_order_3_hardly_change_the_delay_spread(table: dict) -> None:
    by_order = [ds(table, "ray tracing only")] + [
        ds(table, f"scatterers to order {k}") for k in range(1, 6)
    ]
    up_to_3 = by_order[3] - by_order[0]
    beyond_3 = by_order[5] - by_order[3]
    assert up_to_3 > 2 * abs(beyond_3)
    # The increments shrink: order 5 adds less than order 3 did.
    assert by_order[5] - by_order[4] < by_order[3] - by_order[2]
    power = [table[f"scatterers to order {k}"]["power_db"] for k in (3, 5)]
    assert abs(power[1] - power[0]) < 0.1
