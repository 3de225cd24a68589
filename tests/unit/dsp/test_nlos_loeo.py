"""The leave-one-environment-out check of the per-link classifier (uwbnet.nlos_loeo)."""

from __future__ import annotations

import numpy as np

from node_agent.dsp.nlos import FEATURES
from sim_nodes.channel.stochastic import draw_channel
from uwbnet.nlos_loeo import ENVIRONMENTS, first_path_peak_rule, loeo_table

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


def test_every_environment_draws_a_direct_path_first() -> None:
    rng = np.random.default_rng(9)
    for name, (los, nlos) in ENVIRONMENTS.items():
        for env, obstructed in ((los, False), (nlos, True)):
            delays, amps = draw_channel(env, rng)
            assert delays[0] <= 1.0 and np.all(delays <= 200.0), name
            loss_db = -20.0 * np.log10(abs(amps[0]))
            assert (loss_db > 5.0) if obstructed else abs(loss_db) < 1e-9, name
            assert len(delays) > 10, name
