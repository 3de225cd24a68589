"""Simulated channels against published statistics (uwbnet.nlos_published) and the
K-factor option of the stochastic channel model."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from sim_nodes.channel.stochastic import OFFICE_LOS, OFFICE_NLOS, RESIDENTIAL_LOS, draw_channel
from uwbnet import nlos_loeo, nlos_published
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
    assert nlos["published_k_factor_db"] is None  # 3GPP gives no NLOS K-factor
    # an NLOS channel spreads its energy later than a LOS one with a strong direct path
    assert nlos["lg_delay_spread"][0] > los["lg_delay_spread"][0]
    assert nlos["rx_minus_fp_db_median"] > los["rx_minus_fp_db_median"]
    # with the published K the direct path dominates: nearly every LOS row is on
    # Decawave's LOS side (0.98-1.00 in the docs' table)
    assert los["share_rx_minus_fp_as_published"] > 0.9


# draw_channel(RESIDENTIAL_LOS / OFFICE_NLOS, default_rng(3)) by the code before
# k_factor_db existed (commit 12cad0b): path count, sum of delays (ns), total power, and the
# generator's next random() after the draw
_BEFORE_K_FACTOR = {
    "residential LOS": (
        RESIDENTIAL_LOS,
        95,
        3066.1679067036384,
        8.294975861367341,
        0.5456422200054575,
    ),
    "office NLOS": (OFFICE_NLOS, 199, 10866.458087654619, 3.281309943391463, 0.29967306703498076),
}


@pytest.mark.parametrize("name", sorted(_BEFORE_K_FACTOR))
def test_draws_without_k_factor_are_those_of_before_the_field(name: str) -> None:
    env, n, sum_delay, power, after = _BEFORE_K_FACTOR[name]
    assert env.k_factor_db is None
    rng = np.random.default_rng(3)
    d, a = draw_channel(env, rng)
    assert d.size == n
    assert float(d.sum()) == sum_delay  # bit for bit, not approximately
    assert float((np.abs(a) ** 2).sum()) == power
    assert rng.random() == after  # and no extra draw from the shared generator


def test_negative_k_factor_std_is_refused() -> None:
    with pytest.raises(ValueError, match="standard deviation must be >= 0"):
        replace(OFFICE_LOS, k_factor_db=(7.0, -1.0))


class _StopError(Exception):
    pass


def test_published_k_flag_reaches_the_drawn_classes(monkeypatch: pytest.MonkeyPatch) -> None:
    seen = []

    def first_set_only(name, **kw):  # record what would be drawn, draw nothing
        seen.append((name, kw["pair"]))
        raise _StopError

    monkeypatch.setattr(nlos_loeo, "environment_sets", first_set_only)
    for argv, k in (([], None), (["--published-k"], PUBLISHED_K_FACTOR_DB)):
        with pytest.raises(_StopError):
            nlos_loeo.main(argv)
        name, pair = seen.pop()
        if k is None:
            assert pair is None  # the environment's own classes
        else:
            assert pair[0].k_factor_db == k[name] and pair[1].k_factor_db is None


@pytest.mark.parametrize("main", [nlos_loeo.main, nlos_published.main])
@pytest.mark.parametrize("seed", ["-1", "x"])
def test_a_bad_seed_is_a_usage_error(main, seed: str, capsys: pytest.CaptureFixture) -> None:
    with pytest.raises(SystemExit) as e:
        main(["--seed", seed])
    assert e.value.code != 0
    err = capsys.readouterr().err
    assert "--seed" in err and "Traceback" not in err
