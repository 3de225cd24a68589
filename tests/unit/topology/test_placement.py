"""Area maps, the placement objective and the greedy + swap site search."""

from __future__ import annotations

import numpy as np
import pytest

from fusion_center.topology import (
    Area,
    Band,
    GreedyPlacementOptimizer,
    NetworkGeometry,
    SiteCandidates,
    compose_network,
    evaluate_area,
    even_selection,
    placement_cost,
)

BAND = Band(f_low=0.5e9, f_high=3.5e9)
AREA = Area(x_min=0.0, y_min=0.0, x_max=6.0, y_max=4.0, nx=30, ny=20)


def _receiver_sites() -> SiteCandidates:
    # Receivers along the south wall only (y = 0.3) and along the west wall (x = 0.3).
    south = np.column_stack([np.linspace(0.5, 5.5, 6), np.full(6, 0.3)])
    west = np.column_stack([np.full(4, 0.3), np.linspace(0.8, 3.5, 4)])
    pos = np.vstack([south, west])
    return SiteCandidates(
        positions=pos, transmitters=np.zeros((len(pos), 0, 2)), receivers=pos[:, None, :]
    )


def _track() -> NetworkGeometry:
    # A transmitter driven along a straight line y = 2 (the robot's track), hearing only its
    # own receiver: the fixed part of the network.
    tx = np.column_stack([np.linspace(1.0, 5.0, 9), np.full(9, 2.0)])
    return NetworkGeometry(
        transmitters=tx, receivers=tx + np.array([0.0, 0.3]), links=[[i, i] for i in range(9)]
    )


def test_area_maps_have_one_value_per_reference_point():
    ev = evaluate_area(_track(), BAND, AREA, (3, 2))
    assert ev.widths.shape == (2, 3, 2) and ev.ghost_db.shape == (2, 3)
    assert np.all(ev.widths > 0) and np.all(ev.ghost_db <= 0)
    s = ev.summary()
    assert s["resolution_m"] == pytest.approx(ev.widths.mean(), abs=1e-4)
    assert s["ghost_db"] == pytest.approx(ev.ghost_db.max(), abs=0.01)
    assert placement_cost(ev) == pytest.approx(
        ev.worst_ghost_db + 20 * np.log10(ev.mean_resolution)
    )


def test_compose_network_links_sites_to_everything_and_keeps_fixed_links():
    fixed = _track()
    cands = _receiver_sites()
    net = compose_network(cands, [0, 7], fixed)
    assert len(net.receivers) == 9 + 2
    # 9 own links + every transmitter to each of the 2 new receivers.
    assert net.n_links == 9 + 9 * 2
    pairs = {tuple(p) for p in net.links}
    assert (3, 9) in pairs and (8, 10) in pairs and (3, 4) not in pairs


def test_greedy_search_beats_or_equals_the_even_placement():
    cands = _receiver_sites()
    opt = GreedyPlacementOptimizer(BAND, AREA, (3, 2), neighbours=3, sweeps=1)
    result = opt.optimize(cands, 2, _track())
    assert len(set(result.selection)) == 2
    naive, _ = opt.evaluate(cands, even_selection(len(cands), 2), _track())
    assert result.cost <= naive + 1e-9
    # The receiver off the track's line (the west wall) breaks the mirror ghost of the line.
    assert any(i >= 6 for i in result.selection)
    assert result.evaluations > len(cands)
    assert result.history[0][0] == "add 1"


def test_bad_budget_is_rejected():
    opt = GreedyPlacementOptimizer(BAND, AREA, (1, 1))
    with pytest.raises(ValueError, match="k = 11"):
        opt.optimize(_receiver_sites(), 11, _track())
    with pytest.raises(ValueError, match="need 1 <= k"):
        even_selection(3, 0)
