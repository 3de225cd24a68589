"""The leave-one-environment-out check of the per-link classifier (uwbnet.nlos_loeo)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from node_agent.dsp.nlos import FEATURES
from sim_nodes.channel.stochastic import (
    INDUSTRIAL_LOS,
    OUTDOOR_LOS,
    OUTDOOR_NLOS,
    draw_channel,
)
from uwbnet.nlos_loeo import (
    ENVIRONMENTS,
    cache_tag,
    environment_sets,
    first_path_peak_rule,
    loeo_table,
)

COL = FEATURES.index("fp_to_peak_db")


def _env_set(rng: np.random.Generator, flip: bool, n: int = 200):
    """Features where NLOS means a first path more than 5 dB under the peak (or, with
    ``flip``, the reverse); the other columns are noise."""
    x = rng.normal(0.0, 1.0, (n, len(FEATURES)))
    x[:, COL] = rng.uniform(-15.0, 0.0, n)
    y = (x[:, COL] < -5.0) ^ flip
    return (x, y), (x.copy(), y.copy())


def test_held_out_environment_is_left_out_of_training() -> None:
    rng = np.random.default_rng(5)
    sets = {e: _env_set(rng, flip=(e == "odd")) for e in ("a", "b", "c", "odd")}
    table = loeo_table(sets, {"fit": ("fp_to_peak_db",), "rule": first_path_peak_rule(-5.0, 1e9)})
    # trained on a, b, c only, the model gets the inverted environment wrong; had it seen
    # the held-out set, it could not be below one half
    assert table["fit"]["odd"] < 0.1
    # the others are trained on two agreeing environments and the inverted one
    assert min(table["fit"][e] for e in "abc") > 0.75
    assert table["fit"]["min"] == table["fit"]["odd"]
    # a fixed rule is not trained: its rows are its plain accuracy
    x, y = sets["a"][1]
    assert table["rule"]["a"] == round(float(np.mean((x[:, COL] >= -5.0) == ~y)), 4)


def test_every_environment_draws_its_direct_path_as_entry_zero() -> None:
    # entry 0 is the direct path: unattenuated and the earliest path for LOS; attenuated
    # by the class's loss and delayed by at most its excess for NLOS (a first ray of the
    # multipath may then come before it)
    rng = np.random.default_rng(9)
    for name, (los, nlos) in ENVIRONMENTS.items():
        for env in (los, nlos):
            for _ in range(20):
                delays, amps = draw_channel(env, rng)
                assert len(delays) > 10 and np.all((delays >= 0.0) & (delays <= 200.0)), name
                loss_db = -20.0 * np.log10(abs(amps[0]))
                lo, hi = env.direct_loss_db
                assert lo - 1e-9 <= loss_db <= hi + 1e-9, name
                assert env.direct_excess[0] <= delays[0] <= env.direct_excess[1], name
                if env is los:
                    assert delays[0] == 0.0 == delays.min() and abs(loss_db) < 1e-9, name
                else:
                    assert loss_db > 5.0, name


def _mean_gap_rate(lambda_1: float, lambda_2: float, beta: float) -> float:
    """One Poisson ray rate with the mean ray gap of the report's two-rate mixture."""
    return 1.0 / (beta / lambda_1 + (1.0 - beta) / lambda_2)


def test_outdoor_and_industrial_parameters_follow_their_stated_derivation() -> None:
    # the 802.15.4a figures as the module's comment states them (unchecked against the
    # report) and the derivations into the module's one-rate, one-decay form
    assert OUTDOOR_LOS.cluster_rate == 0.0448  # CM5 Lambda (the typo was 0.0048)
    assert OUTDOOR_NLOS.cluster_rate == 0.0243
    assert OUTDOOR_LOS.ray_rate == pytest.approx(_mean_gap_rate(0.13, 2.41, 0.0078), abs=0.01)
    assert OUTDOOR_NLOS.ray_rate == pytest.approx(_mean_gap_rate(0.15, 1.13, 0.062), abs=0.01)
    # CM7: gamma = k_gamma T + gamma_0 at the clusters' mean start L / (2 Lambda)
    mean_start = INDUSTRIAL_LOS.n_clusters / (2.0 * INDUSTRIAL_LOS.cluster_rate)
    assert INDUSTRIAL_LOS.ray_decay == pytest.approx(0.926 * mean_start + 0.651, abs=0.1)


def test_mean_cluster_start_of_the_drawn_channels() -> None:
    # the L / (2 Lambda) above is the mean start of a cluster as draw_channel draws them
    env, lam, n_cl = INDUSTRIAL_LOS, INDUSTRIAL_LOS.cluster_rate, INDUSTRIAL_LOS.n_clusters
    rng = np.random.default_rng(4)
    starts = []
    for _ in range(4000):
        n = max(1, int(rng.poisson(n_cl)))
        starts.extend(np.concatenate([[0.0], np.cumsum(rng.exponential(1.0 / lam, n - 1))]))
    # at least one cluster (max(1, ...)) pulls the mean a little under L / (2 Lambda)
    assert np.mean(starts) == pytest.approx(n_cl / (2.0 * lam), rel=0.05)
    assert env.ray_decay > 30.0


def test_outdoor_los_clusters_arrive_within_the_channel() -> None:
    # CM5: about 1 + 200 ns * Lambda = 10 clusters start within max_delay 200 ns, each with
    # its rays; with the old typo (Lambda 0.0048, 208 ns gaps) most channels had one or two
    rng = np.random.default_rng(6)
    rays = max(4, int(np.ceil(5.0 * OUTDOOR_LOS.ray_decay * OUTDOOR_LOS.ray_rate)))
    counts = [len(draw_channel(OUTDOOR_LOS, rng)[0]) - 1 for _ in range(40)]
    assert np.mean(counts) > 5 * rays


def test_feature_cache_key_changes_with_what_shapes_the_features(tmp_path: Path) -> None:
    los, nlos = ENVIRONMENTS["outdoor"]
    classes = [(los, False), (nlos, True)]
    tag = cache_tag(classes, (0.6, 1.6))
    assert tag == cache_tag(list(classes), (0.6, 1.6))
    assert tag != cache_tag(classes, (0.5, 2.0))
    assert tag != cache_tag(classes, (0.6, 1.6), FEATURES[:-1])
    assert tag != cache_tag([(replace(los, cluster_rate=0.0048), False), (nlos, True)], (0.6, 1.6))
    # the sets' file names carry the tag: another decay randomisation draws new sets
    environment_sets("outdoor", seed=3, n_train=2, n_test=2, cache=tmp_path)
    first = {p.name for p in tmp_path.iterdir()}
    assert len(first) == 2 and all(tag in name for name in first)
    environment_sets("outdoor", seed=3, n_train=2, n_test=2, decay_factor=(1, 1), cache=tmp_path)
    assert len({p.name for p in tmp_path.iterdir()} - first) == 2
