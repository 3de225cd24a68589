"""Leave-one-environment-out check of per-link LOS/NLOS classifiers on simulated channels.

``python -m uwbnet.nlos_loeo`` draws seeded LOS and NLOS channels of four 802.15.4a-type
environments (residential CM1/CM2, office CM3/CM4, outdoor CM5/CM6, industrial CM7/CM8;
:mod:`sim_nodes.channel.stochastic`) with the environment's decay constants randomised per
channel (another building of the same kind), renders them through the training radars at
random SNRs and window positions, and runs the chain of ``uwbnet ranging``. For every
classifier variant it prints the accuracy on each environment when that environment was left
out of the training (train on the other three, test on the held-out one), rendered through
a DW1000-like front end (complex baseband, 1.0016 ns sampling, 1016-sample accumulator, first
path near sample 740, SNR 10-30 dB), a radar none of the training radars is. Fixed rules
are not trained; their rows show the same held-out sets. No measured data enters.

The outdoor and industrial parameters are unchecked against the 802.15.4a report (see the
comment in :mod:`sim_nodes.channel.stochastic`); the industrial column depends strongly on
them (docs/localization.md).

``--cache DIR`` keeps the feature sets between runs (they take minutes to draw); a set's
file name carries a hash of its channel classes, decay randomisation and feature names, so
a changed parameter draws new sets.
"""

from __future__ import annotations

import argparse
import hashlib
import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
import numpy.typing as npt

from node_agent.dsp.geometry import RadarParams
from node_agent.dsp.nlos import DEFAULT_CLASSIFIER, FEATURES
from sim_nodes.channel.stochastic import (
    INDUSTRIAL_LOS,
    INDUSTRIAL_NLOS,
    OFFICE_LOS,
    OFFICE_NLOS,
    OUTDOOR_LOS,
    OUTDOOR_NLOS,
    RESIDENTIAL_LOS,
    RESIDENTIAL_NLOS,
    ChannelClass,
)
from uwbnet.cli import _count
from uwbnet.nlos_training import SELECTED, fit_logistic, make_dataset

ENVIRONMENTS: dict[str, tuple[ChannelClass, ChannelClass]] = {
    "residential": (RESIDENTIAL_LOS, RESIDENTIAL_NLOS),
    "office": (OFFICE_LOS, OFFICE_NLOS),
    "outdoor": (OUTDOOR_LOS, OUTDOOR_NLOS),
    "industrial": (INDUSTRIAL_LOS, INDUSTRIAL_NLOS),
}
"""LOS and NLOS class of each environment."""

DW1000_HELD_OUT = RadarParams(
    fs=1 / 1.0016e-9, n=1016, t0=0.0, f_low=3.7436e9, f_high=4.2436e9, fc=3.9936e9
)
"""DW1000-like front end of the held-out sets: channel 2, 1.0016 ns sampling, 1016 taps."""

DW1000_FIRST = (735.0 / 1016, 745.0 / 1016)
"""First path near sample 740 of the accumulator (fractions of the window)."""

Features = tuple[npt.NDArray[np.float64], npt.NDArray[np.bool_]]


def environment_sets(
    name: str,
    *,
    seed: int,
    n_train: int,
    n_test: int,
    test_snr_db: tuple[float, float] = (10.0, 30.0),
    decay_factor: tuple[float, float] = (0.6, 1.6),
    cache: Path | None = None,
    pair: tuple[ChannelClass, ChannelClass] | None = None,
) -> tuple[Features, Features]:
    """Training features (training radars) and held-out features (DW1000-like, SNR uniform
    in ``test_snr_db``) of one environment; cached under ``cache`` when given. ``pair``
    replaces the environment's (LOS, NLOS) classes of :data:`ENVIRONMENTS`."""
    los, nlos = pair if pair is not None else ENVIRONMENTS[name]
    classes = [(los, False), (nlos, True)]
    # what else shapes the features: a cache drawn with other channel parameters, decay
    # randomisation or feature set must not be reused
    tag = cache_tag(classes, decay_factor)
    train = _cached(
        cache,
        f"{name}-train-{seed}-{n_train}-{tag}",
        lambda: make_dataset(seed, n_train, classes=classes, decay_factor=decay_factor),
    )
    lo, hi = test_snr_db
    test = _cached(
        cache,
        f"{name}-dw1000-{seed + 1000}-{n_test}-{lo:g}-{hi:g}-{tag}",
        lambda: make_dataset(
            seed + 1000,
            n_test,
            radars=(DW1000_HELD_OUT,),
            classes=classes,
            snr_db=test_snr_db,
            first_fraction=DW1000_FIRST,
            decay_factor=decay_factor,
        ),
    )
    return train, test


def cache_tag(
    classes: list[tuple[ChannelClass, bool]],
    decay_factor: tuple[float, float],
    features: tuple[str, ...] = FEATURES,
) -> str:
    """Short hash of the channel classes, the decay randomisation and the feature names:
    part of the cache key of a feature set."""
    text = repr((classes, tuple(decay_factor), tuple(features)))
    return hashlib.sha256(text.encode()).hexdigest()[:12]


def _cached(cache: Path | None, key: str, make: Callable[[], Features]) -> Features:
    if cache is None:
        return make()
    path = cache / f"{key}.npz"
    if path.exists():
        z = np.load(path)
        return z["x"], z["y"]
    x, y = make()
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp.npz")
    np.savez(tmp, x=x, y=y)
    tmp.replace(path)
    return x, y


def _col(name: str) -> int:
    return FEATURES.index(name)


def first_path_energy_rule(threshold_db: float = -10.0) -> Callable[[npt.NDArray], npt.NDArray]:
    """LOS if the first path's energy (one pulse width) is at least ``threshold_db`` of the
    profile's energy: the rule of thumb of transceiver vendors (received power over first-path
    power above about 6-10 dB: likely NLOS)."""

    def is_los(x: npt.NDArray) -> npt.NDArray[np.bool_]:
        v = x[:, _col("fp_energy_db")]
        return np.isfinite(v) & (v >= threshold_db)

    return is_los


def early_energy_rule(threshold_db: float = -3.0) -> Callable[[npt.NDArray], npt.NDArray]:
    """LOS if at least half (``threshold_db`` -3 dB) of the profile's energy arrives within
    10 ns of the first path (the direct path and the nearest surfaces' reflections)."""

    def is_los(x: npt.NDArray) -> npt.NDArray[np.bool_]:
        v = x[:, _col("early_energy_db")]
        return np.isfinite(v) & (v >= threshold_db)

    return is_los


def first_path_peak_rule(
    peak_db: float = -6.0, rise_ns: float = 5.0
) -> Callable[[npt.NDArray], npt.NDArray]:
    """LOS unless the first path is ``peak_db`` under the strongest path or the strongest
    path comes ``rise_ns`` after it."""

    def is_los(x: npt.NDArray) -> npt.NDArray[np.bool_]:
        a, r = x[:, _col("fp_to_peak_db")], x[:, _col("rise_time")]
        return np.isfinite(a) & (a >= peak_db) & (r <= rise_ns)

    return is_los


def loeo_table(
    sets: dict[str, tuple[Features, Features]],
    variants: dict[str, tuple[str, ...] | Callable],
) -> dict[str, dict[str, float]]:
    """Held-out accuracy of each variant per left-out environment (plus mean and min).

    A variant is a feature tuple (a logistic model fitted on the other environments'
    training sets) or a fixed ``is_los`` function of the feature matrix."""
    out: dict[str, dict[str, float]] = {}
    for vname, spec in variants.items():
        row: dict[str, float] = {}
        for held in sets:
            xh, yh = sets[held][1]
            if callable(spec):
                pred = spec(xh)
            else:
                xt = np.concatenate([sets[e][0][0] for e in sets if e != held])
                yt = np.concatenate([sets[e][0][1] for e in sets if e != held])
                pred = fit_logistic(xt, yt, spec).is_los(xh)
            row[held] = round(float(np.mean(pred == ~yh)), 4)
        vals = list(row.values())
        row["mean"] = round(float(np.mean(vals)), 4)
        row["min"] = round(float(np.min(vals)), 4)
        out[vname] = row
    return out


#: argparse type of a seed: an integer >= 0 (numpy's generators refuse negative ones), so
#: that a bad one is a one-line usage error instead of a traceback: the CLI's count type.
seed_arg = _count


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seed", type=seed_arg, default=11)
    p.add_argument("--n-train", type=int, default=100, help="channels per class and radar")
    p.add_argument("--n-test", type=int, default=200, help="held-out channels per class")
    p.add_argument("--test-snr", type=float, nargs=2, default=(10.0, 30.0), metavar=("LO", "HI"))
    p.add_argument("--cache", type=Path, default=None)
    p.add_argument(
        "--published-k",
        action="store_true",
        help="LOS classes with the published K-factors (uwbnet.nlos_published)",
    )
    a = p.parse_args(argv)
    from uwbnet.nlos_published import with_published_k_factor  # it imports this module

    sets = {
        e: environment_sets(
            e,
            seed=a.seed + 10 * i,
            n_train=a.n_train,
            n_test=a.n_test,
            test_snr_db=tuple(a.test_snr),
            cache=a.cache,
            pair=with_published_k_factor(e) if a.published_k else None,
        )
        for i, e in enumerate(ENVIRONMENTS)
    }
    variants: dict[str, tuple[str, ...] | Callable] = {
        "default (frozen)": DEFAULT_CLASSIFIER.is_los,
        "rule fp_energy >= -10 dB": first_path_energy_rule(-10.0),
        "rule fp_energy >= -6 dB": first_path_energy_rule(-6.0),
        "rule fp_to_peak >= -6 dB and rise <= 5 ns": first_path_peak_rule(),
        "rule early_energy >= -3 dB": early_energy_rule(-3.0),
        "logistic SELECTED": SELECTED,
        "logistic SELECTED + early, median": (*SELECTED, "early_energy_db", "median_excess_delay"),
        "logistic fp_to_peak, rise, early, median": (
            "fp_to_peak_db",
            "rise_time",
            "early_energy_db",
            "median_excess_delay",
        ),
        "logistic all": FEATURES,
    }
    table = loeo_table(sets, variants)
    table["held-out rows without a first path"] = {
        e: round(float(np.mean(~np.isfinite(s[1][0][:, 0]))), 4) for e, s in sets.items()
    }
    print(json.dumps(table, indent=1))  # noqa: T201 (a script's output)


if __name__ == "__main__":
    main()
