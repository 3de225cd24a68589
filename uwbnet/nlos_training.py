"""Train and check the per-link LOS/NLOS classifier on simulated channels.

``python -m uwbnet.nlos_training`` draws seeded LOS and NLOS channels from the stochastic
802.15.4a-type model (:mod:`sim_nodes.channel.stochastic`), renders them through several
radars (complex-baseband transceivers of 500 MHz and 900 MHz at about 1 ns sampling, a
1.3 GHz one, and the chapter's real 3.5 GHz M-sequence radar) at random SNRs, runs the same
chain as ``uwbnet ranging`` (:class:`node_agent.dsp.ranging.FirstPathRanger`) and fits a
logistic model by Newton's method (a small ridge keeps it tame). It prints the coefficients
for :data:`node_agent.dsp.nlos.DEFAULT_CLASSIFIER` and the accuracy on held-out channels
(another seed, another radar, perturbed environments). No measured data enters.
``python -m uwbnet.nlos_training --confusion`` prints the default classifier's confusion
matrix on each simulated check set instead.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from node_agent.dsp.geometry import RadarParams
from node_agent.dsp.nlos import FEATURES, LogisticNlosClassifier
from node_agent.dsp.ranging import FirstPathRanger
from sim_nodes.channel.stochastic import (
    OFFICE_LOS,
    OFFICE_NLOS,
    RESIDENTIAL_LOS,
    RESIDENTIAL_NLOS,
    ChannelClass,
    draw_channel,
    render,
)

TRAIN_RADARS = (
    # DW1000 channel 5 and channel 4 (wide band), 1016 taps at 998.4 MHz
    RadarParams(fs=998.4e6, n=1016, t0=0.0, f_low=6.2396e9, f_high=6.7396e9, fc=6.4896e9),
    RadarParams(fs=998.4e6, n=1016, t0=0.0, f_low=3.55e9, f_high=4.45e9, fc=3.9936e9),
    RadarParams(fs=2.0e9, n=1024, t0=0.0, f_low=6.85e9, f_high=8.15e9, fc=7.5e9),
    RadarParams(fs=7e9, n=4095, t0=0.0, f_low=0.0, f_high=3.5e9),
)
"""Radars of the training channels."""

HELD_OUT_RADARS = (
    # DW1000 channel 2 (3.9936 GHz, 500 MHz) and a 1.2 GHz-wide radar at 1.5 GHz sampling
    RadarParams(fs=998.4e6, n=1016, t0=0.0, f_low=3.7436e9, f_high=4.2436e9, fc=3.9936e9),
    RadarParams(fs=1.5e9, n=800, t0=0.0, f_low=5.4e9, f_high=6.6e9, fc=6.0e9),
)
"""Radars of the held-out check: none of them is in TRAIN_RADARS."""

TRAIN_CLASSES = (
    (RESIDENTIAL_LOS, False),
    (OFFICE_LOS, False),
    (RESIDENTIAL_NLOS, True),
    (OFFICE_NLOS, True),
)


def _perturbed(env: ChannelClass, factor: float) -> ChannelClass:
    """An environment with its decay constants and rates scaled (another building)."""
    return dataclasses.replace(
        env,
        cluster_decay=env.cluster_decay * factor,
        ray_decay=env.ray_decay * factor,
        ray_rate=env.ray_rate / factor,
    )


HELD_OUT_CLASSES = tuple(
    (_perturbed(env, f), nlos) for env, nlos in TRAIN_CLASSES for f in (0.7, 1.4)
)


def make_dataset(
    seed: int,
    n_per_class: int,
    radars: Sequence[RadarParams] = TRAIN_RADARS,
    classes: Sequence[tuple[ChannelClass, bool]] = TRAIN_CLASSES,
    snr_db: tuple[float, float] = (12.0, 40.0),
    first_fraction: tuple[float, float] = (0.2, 0.6),
    decay_factor: tuple[float, float] | None = None,
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.bool_]]:
    """Features (m, len(FEATURES)) and NLOS labels (m,) of seeded simulated channels.

    Each of ``n_per_class`` draws per (class, radar) gets its own SNR (uniform in dB) and
    first-path position (uniform over ``first_fraction`` of the window: the middle by
    default; a DW1000 accumulator of 1016 taps puts its first path near tap 745, 0.73).
    With ``decay_factor`` each channel's environment gets its decay constants and ray rate
    scaled by a factor drawn log-uniformly from that range (:func:`_perturbed`: another
    building of the same kind); without it the draws are those of earlier versions.
    """
    rng = np.random.default_rng(seed)
    xs, ys = [], []
    for radar in radars:
        ranger = FirstPathRanger(radar, method="adaptive")
        for env, nlos in classes:
            rows = []
            for _ in range(n_per_class):  # one channel realisation each: a few hundred paths
                e = env
                if decay_factor is not None:
                    lo, hi = np.log(decay_factor)
                    e = _perturbed(env, float(np.exp(rng.uniform(lo, hi))))
                delays, amps = draw_channel(e, rng)
                first = rng.uniform(*first_fraction) * radar.n
                rows.append(
                    render(
                        delays,
                        amps,
                        fs=radar.fs,
                        n=radar.n,
                        f_low=radar.f_low,
                        f_high=radar.f_high,
                        fc=radar.fc,
                        first_index=first,
                        snr_db=rng.uniform(*snr_db),
                        rng=rng,
                    )
                )
            xs.append(ranger.process(np.stack(rows)).features)
            ys.append(np.full(n_per_class, nlos))
    return np.concatenate(xs), np.concatenate(ys)


SELECTED = ("fp_to_peak_db", "rise_time", "mean_excess_delay", "kurtosis")
"""The features of the default classifier: the first path's weakness and lateness relative
to the strongest path, where the energy lies, and how peaky the profile is. The delay spread
and first-path energy ratio add nothing on the training channels (they are functions of
much the same profile) and a smaller model carries less of the simulator's peculiarities."""

CLIP = {
    "fp_to_peak_db": (-30.0, 0.0),
    "rise_time": (0.0, 60.0),
    "mean_excess_delay": (0.0, 80.0),
    "rms_delay_spread": (0.0, 60.0),
    "fp_energy_db": (-30.0, 0.0),
    "kurtosis": (1.0, 60.0),
    "early_energy_db": (-30.0, 0.0),
    "median_excess_delay": (0.0, 80.0),
}
"""Physical ranges the features are clipped to (dB, ns, ns, ns, dB, -, dB, ns)."""


def fit_logistic(
    x: npt.NDArray[np.float64],
    y: npt.NDArray[np.bool_],
    features: Sequence[str],
    ridge: float = 1e-2,
) -> LogisticNlosClassifier:
    """Logistic regression of ``y`` on the named, clipped, standardised features (Newton)."""
    cols = [FEATURES.index(f) for f in features]
    lo, hi = np.array([CLIP[f] for f in features]).T
    keep = np.all(np.isfinite(x[:, cols]), axis=1)
    xc = np.clip(x[keep][:, cols], lo, hi)
    t = y[keep].astype(np.float64)
    mean, scale = xc.mean(axis=0), xc.std(axis=0) + 1e-12
    a = np.column_stack([np.ones(len(xc)), (xc - mean) / scale])
    w = np.zeros(a.shape[1])
    reg = ridge * np.eye(a.shape[1])
    reg[0, 0] = 0.0
    for _ in range(50):
        p = 1.0 / (1.0 + np.exp(-(a @ w)))
        grad = a.T @ (p - t) + reg @ w
        hess = (a * (p * (1 - p))[:, None]).T @ a + reg
        step = np.linalg.solve(hess, grad)
        w -= step
        if np.max(np.abs(step)) < 1e-8:
            break
    return LogisticNlosClassifier(
        features=tuple(features),
        mean=tuple(float(v) for v in mean),
        scale=tuple(float(v) for v in scale),
        weights=tuple(float(v) for v in w[1:]),
        bias=float(w[0]),
        clip=tuple((float(a_), float(b_)) for a_, b_ in zip(lo, hi, strict=True)),
    )


def accuracy(clf: LogisticNlosClassifier, x: npt.NDArray, y: npt.NDArray) -> float:
    """Fraction of rows whose LOS decision matches ``~y``."""
    return float(np.mean(clf.is_los(x) == ~y))


def confusion(is_los: npt.NDArray[np.bool_], y: npt.NDArray[np.bool_]) -> dict[str, int | float]:
    """Confusion counts of LOS decisions ``is_los`` against NLOS labels ``y`` (NLOS is the
    positive class), with the accuracy, the NLOS detection rate and the false-alarm rate."""
    tp = int(np.sum(~is_los & y))
    fn = int(np.sum(is_los & y))
    fp = int(np.sum(~is_los & ~y))
    tn = int(np.sum(is_los & ~y))
    return {
        "nlos_as_nlos": tp,
        "nlos_as_los": fn,
        "los_as_nlos": fp,
        "los_as_los": tn,
        "accuracy": round((tp + tn) / max(y.size, 1), 4),
        "nlos_detection": round(tp / max(tp + fn, 1), 4),
        "false_alarm": round(fp / max(fp + tn, 1), 4),
    }


def confusion_report(n_per_class: int = 150, seed: int = 2) -> dict[str, dict]:
    """Confusion matrices of :data:`DEFAULT_CLASSIFIER` per simulated data set: the
    held-out radars and environments, and a DW1000-like set (channel 2, first path near
    tap 745 of 1016 as in the chip's accumulator, SNR 10-30 dB) of the training
    environments and of the perturbed ones."""
    from node_agent.dsp.nlos import DEFAULT_CLASSIFIER

    sets = {
        "held_out": make_dataset(
            seed, n_per_class, radars=HELD_OUT_RADARS, classes=HELD_OUT_CLASSES
        ),
        "dw1000_train_envs": make_dataset(
            seed + 1,
            n_per_class,
            radars=HELD_OUT_RADARS[:1],
            snr_db=(10.0, 30.0),
            first_fraction=(0.72, 0.74),
        ),
        "dw1000_perturbed_envs": make_dataset(
            seed + 2,
            n_per_class,
            radars=HELD_OUT_RADARS[:1],
            classes=HELD_OUT_CLASSES,
            snr_db=(10.0, 30.0),
            first_fraction=(0.72, 0.74),
        ),
    }
    return {k: confusion(DEFAULT_CLASSIFIER.is_los(x), y) for k, (x, y) in sets.items()}


def main() -> None:
    import sys

    if "--confusion" in sys.argv[1:]:
        print(json.dumps(confusion_report(), indent=1))  # noqa: T201 (a script's output)
        return
    x, y = make_dataset(seed=1, n_per_class=250)
    xh, yh = make_dataset(seed=2, n_per_class=150, radars=HELD_OUT_RADARS, classes=HELD_OUT_CLASSES)
    report = {}
    for feats in (
        ("fp_to_peak_db",),
        ("rise_time",),
        ("kurtosis",),
        ("mean_excess_delay",),
        SELECTED,
        FEATURES,
    ):
        clf = fit_logistic(x, y, feats)
        report[",".join(feats)] = {
            "train": round(accuracy(clf, x, y), 4),
            "held_out": round(accuracy(clf, xh, yh), 4),
            "classifier": dataclasses.asdict(clf),
        }
    print(json.dumps(report, indent=1))  # noqa: T201 (a script's output)


if __name__ == "__main__":
    main()
