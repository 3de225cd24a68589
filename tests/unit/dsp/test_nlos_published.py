"""Simulated channels against published statistics (uwbnet.nlos_published) and the
K-factor option of the stochastic channel model."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from sim_nodes.channel.stochastic import OFFICE_LOS, RESIDENTIAL_LOS, draw_channel
from uwbnet.nlos_loeo import ENVIRONMENTS, cache_tag
from uwbnet.nlos_published import (
    PUBLISHED_K_FACTOR_DB,
    comparison,
    path_statistics,
    with_published_k_factor,
)


def test_k_factor_scales_only_the_multipath_of_the_same_draw() -> None:
    env = replace(RESIDENTIAL_LOS, k_factor_db=(7.0, 4.0))
    d0, a0 = draw_channel(RESIDENTIAL_LOS, np.random.default_rng(3))
    d1, a1 = draw_channel(env, np.random.default_rng(3))
    np.testing.assert_array_equal(d0, d1)  # same paths, same delays
    assert a1[0] == a0[0]  # the direct path is untouched
    ratio = a1[1:] / a0[1:]
    np.testing.assert_allclose(ratio, ratio[0], rtol=1e-9)  # one real gain for all rays
    assert abs(ratio[0].imag) < 1e-12


def test_k_factor_of_the_draws_follows_the_given_normal() -> None:
    env = replace(OFFICE_LOS, k_factor_db=(7.0, 4.0))
    k = path_statistics(env, np.random.default_rng(8), 300)["k_factor_db"]
    assert abs(k.mean() - 7.0) < 0.7
    assert abs(k.std() - 4.0) < 0.6
    # without it the class keeps its own multipath level: far below the published K
    # (the disagreement uwbnet.nlos_published reports)
    k0 = path_statistics(OFFICE_LOS, np.random.default_rng(8), 300)["k_factor_db"]
    assert k0.mean() < 0.0


def test_published_k_classes_and_their_cache_key() -> None:
    for name, (los, nlos) in ENVIRONMENTS.items():
        los_k, nlos_k = with_published_k_factor(name)
        assert los_k.k_factor_db == PUBLISHED_K_FACTOR_DB[name]
        assert nlos_k is nlos and los.k_factor_db is None
        # a feature set drawn without the K-factor is not reused for one with it
        assert cache_tag([(los, False), (nlos, True)], (0.6, 1.6)) != cache_tag(
            [(los_k, False), (nlos, True)], (0.6, 1.6)
        )


def test_comparison_table_rows() -> None:
    envs = {"office": with_published_k_factor("office")}
    t = comparison(envs, seed=2, n_paths=60, n_front_end=12)
    los, nlos = t["office LOS"], t["office NLOS"]
    assert abs(los["k_factor_db"][0] - 7.0) < 1.5
    assert los["published_k_factor_db"] == [7.0, 4.0] and nlos["published_k_factor_db"] is None
    # an NLOS channel spreads its energy later than a LOS one with a strong direct path
    assert nlos["lg_delay_spread"][0] > los["lg_delay_spread"][0]
    assert nlos["rx_minus_fp_db_median"] > los["rx_minus_fp_db_median"]
    assert 0.0 <= los["share_rx_minus_fp_as_published"] <= 1.0
