"""Measure the link-level NLOS evidence of :class:`~fusion_center.localization.nlos.
EvidenceNlosTest`.

``python -m uwbnet.nlos_link_training [--seeds 101 102 103] [--duration 60]`` simulates
``lab_nlos`` and ``lab_los`` (in memory, the same chain as ``uwbnet sim``) with seeds that the
evaluation (seeds 1-5) does not use, and prints, as JSON, the distributions the combined test
assumes:

* ``power_los_std``, ``power_nlos_mean``, ``power_nlos_std``: of the first-path power
  residual :math:`\\Delta = \\mathrm{SNR} + 20 \\log_{10} r - \\mathrm{SNR}_{1m}` (dB), the
  link budget being the median level of the LOS links (what the test's calibration finds);
* ``flag_detection``, ``flag_false_alarm``: of the per-impulse-response classifier's flags;
* ``kappa``: the median, over windows of NLOS links, of the eq. (6) statistic per degree of
  freedom (NLOS over LOS range variance).

No evaluation seed enters; the figures are rounded before they go into the defaults.
"""

from __future__ import annotations

import argparse
import json
from collections import defaultdict

import numpy as np

from fusion_center.localization.nlos import MseNlosTest
from protocol import Detections, Truth
from sim_nodes.ranging_record import ranging_messages
from sim_nodes.scene import load_scenario

TRAINING_SEEDS = (101, 102, 103)


def link_rows(scenario: str, seed: int, duration: float) -> dict[str, np.ndarray]:
    """Per anchor, rows ``(t, range, snr_db, flag, true_nlos)`` of one simulated run."""
    sc = load_scenario(scenario)
    rows: dict[str, list[tuple[float, ...]]] = defaultdict(list)
    pending: dict[float, Detections] = {}
    for _, msg in ranging_messages(sc, duration=duration, seed=seed):
        if isinstance(msg, Detections) and msg.links is not None:
            pending[msg.t] = msg
        elif isinstance(msg, Truth) and msg.t in pending:
            det = pending.pop(msg.t)
            truth = next(iter(msg.extra["links"].values()))
            for aid, lk in det.links.items():
                nlos = not truth[aid]["los"]
                rows[aid].append((msg.t, lk.range, lk.snr_db, float(not lk.los), float(nlos)))
    return {a: np.array(v) for a, v in rows.items()}


def measure(seeds: tuple[int, ...], duration: float) -> dict[str, float]:
    """The evidence distributions over ``lab_nlos`` and ``lab_los`` runs of ``seeds``."""
    test = MseNlosTest()
    los_d, nlos_d, los_f, nlos_f, ratio = [], [], [], [], []
    for scenario in ("lab_nlos", "lab_los"):
        for seed in seeds:
            runs = link_rows(scenario, seed, duration)
            level = {a: x[:, 2] + 20.0 * np.log10(x[:, 1]) for a, x in runs.items()}
            budget = np.median(np.concatenate([level[a] for a, x in runs.items() if x[0, 4] == 0]))
            for a, x in runs.items():
                nlos = x[:, 4] > 0.5
                d = level[a] - budget
                (nlos_d if nlos[0] else los_d).append(d)
                (nlos_f if nlos[0] else los_f).append(x[:, 3])
                if nlos[0]:
                    for k in range(30, len(x)):
                        stat, dof = test.statistic(x[k - 30 : k, 0], x[k - 30 : k, 1])
                        ratio.append(stat / dof)
    ld, nd = np.concatenate(los_d), np.concatenate(nlos_d)
    return {
        "power_los_std": round(float(np.std(ld)), 2),
        "power_nlos_mean": round(float(np.mean(nd)), 2),
        "power_nlos_std": round(float(np.std(nd)), 2),
        "flag_detection": round(float(np.mean(np.concatenate(nlos_f))), 3),
        "flag_false_alarm": round(float(np.mean(np.concatenate(los_f))), 3),
        "kappa": round(float(np.median(ratio)), 1),
    }


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=list(TRAINING_SEEDS))
    ap.add_argument("--duration", type=float, default=60.0)
    args = ap.parse_args(argv)
    print(json.dumps(measure(tuple(args.seeds), args.duration)))  # noqa: T201


if __name__ == "__main__":
    main()
