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


def _collinear_case() -> tuple[SiteCandidates, NetworkGeometry]:
    # A robot track whose own receivers lie on its line (y = 2): the whole network is
    # mirror-symmetric about that line, so every reference point has a 0 dB mirror ghost.
    # The naive (evenly spaced) pick of 2 of these 6 sites is sites 0 and 3, both on the
    # line too; any site off the line breaks the symmetry.
    tx = np.column_stack([np.linspace(1.0, 5.0, 9), np.full(9, 2.0)])
    fixed = NetworkGeometry(
        transmitters=tx, receivers=tx + np.array([0.3, 0.0]), links=[[i, i] for i in range(9)]
    )
    pos = np.array([[0.3, 2.0], [1.5, 0.3], [4.5, 0.3], [5.7, 2.0], [3.0, 3.7], [0.3, 0.8]])
    cands = SiteCandidates(
        positions=pos, transmitters=np.zeros((6, 0, 2)), receivers=pos[:, None, :]
    )
    return cands, fixed


def test_reranked_result_beats_naive_on_the_final_objective():
    cands, fixed = _collinear_case()
    final_area = AREA.with_grid(60, 40)
    opt = GreedyPlacementOptimizer(
        BAND,
        AREA.with_grid(20, 14),  # a cheap proxy grid for the search
        (3, 2),
        final_area=final_area,
        final_references=(3, 2),
        rerank=2,
        neighbours=2,
        sweeps=1,
    )
    naive = even_selection(len(cands), 2)
    assert naive == (0, 3)
    result = opt.optimize(cands, 2, fixed, starts=[naive])

    # The final objective, recomputed independently at the final settings.
    def final(sel: tuple[int, ...]) -> float:
        return placement_cost(
            evaluate_area(compose_network(cands, sel, fixed), BAND, final_area, (3, 2))
        )

    j_naive, j_opt = final(naive), final(result.selection)
    assert j_naive == pytest.approx(result.start_final_costs[0], abs=1e-6)
    assert j_opt == pytest.approx(result.final_cost, abs=1e-6)
    assert result.start_final_evaluations[0].worst_ghost_db > -1.0  # the mirror ghost
    # A clear improvement exists (an off-line receiver): it must be found, by > 6 dB.
    assert j_opt < j_naive - 6.0
    assert result.improved
    assert not set(result.selection) & {0, 3}
    # The winner is the best of the re-ranked pool on the final objective, naive included.
    assert result.selection == result.ranking[0][0]
    assert [r[2] for r in result.ranking] == sorted(r[2] for r in result.ranking)
    assert naive in [r[0] for r in result.ranking]


def test_naive_is_kept_when_nothing_beats_it():
    # Budget = every candidate: the only selection is the naive one, and the result says so.
    cands, fixed = _collinear_case()
    opt = GreedyPlacementOptimizer(
        BAND, AREA.with_grid(20, 14), (1, 1), final_area=AREA.with_grid(30, 20), rerank=3
    )
    naive = even_selection(len(cands), len(cands))
    result = opt.optimize(cands, len(cands), fixed, starts=[naive])
    assert result.selection == naive
    assert result.final_cost == pytest.approx(result.start_final_costs[0])
    assert not result.improved


def test_bad_budget_is_rejected():
    opt = GreedyPlacementOptimizer(BAND, AREA, (1, 1))
    with pytest.raises(ValueError, match="k = 11"):
        opt.optimize(_receiver_sites(), 11, _track())
    with pytest.raises(ValueError, match="need 1 <= k"):
        even_selection(3, 0)
    with pytest.raises(ValueError, match="rerank"):
        GreedyPlacementOptimizer(BAND, AREA, rerank=0)
