"""``uwbnet bench localization``: position fixes per second per core, 4, 8 and 32 anchors.

One fix is one ranging round through the fusion center's localizer
(:class:`~fusion_center.localization.mobile.RangingLocalizer`, Taylor-series estimator): the
eq. (6) test of every anchor over its window, the snapshot fix and the Kalman update. Anchors
on a circle of 10 m around a node walking a circle, seeded Gaussian ranges; the snapshot
estimators alone are measured too.
"""

from __future__ import annotations

from typing import Any

import numpy as np


def bench_localization(seed: int = 0) -> dict[str, Any]:
    from fusion_center.localization import LOCATORS
    from fusion_center.localization.mobile import RangingLocalizer
    from uwbnet.bench import _machine, _rate

    rng = np.random.default_rng(seed)
    out: dict[str, Any] = {}
    for n in (4, 8, 32):
        ang = 2 * np.pi * np.arange(n) / n
        anchors = {f"a{i}": (10 * np.cos(a), 10 * np.sin(a), 1.5) for i, a in enumerate(ang)}
        pos = np.array(list(anchors.values()))
        loc = RangingLocalizer(anchors, height=1.0)
        # precomputed rounds: the bench measures localization, not the range simulation
        rounds = []
        for k in range(500):
            t = 0.1 * k
            p = np.array([3 * np.cos(0.1 * t), 3 * np.sin(0.1 * t), 1.0])
            r = np.linalg.norm(pos - p, axis=1) + rng.normal(0, 0.01, n)
            rounds.append((t, {a: (float(ri), 0.01) for a, ri in zip(anchors, r, strict=True)}))

        def one(i: int, loc=loc, rounds=rounds) -> None:
            t, links = rounds[i % len(rounds)]
            loc.step(t + 50.0 * (i // len(rounds)), links)

        calls, cpu, _ = _rate(one)
        out[f"fixes_per_s_per_core_{n}"] = round(calls / cpu, 1)
        r0 = np.array([v[0] for v in rounds[0][1].values()])
        xy = pos[:, :2]
        hr = np.sqrt(np.maximum(r0**2 - 0.25, 0))
        for name, cls in LOCATORS.items():
            est, args = cls(), (xy, hr, np.full(n, 0.01))
            c2, cpu2, _ = _rate(lambda i, est=est, args=args: est.locate(*args), 1.0)
            out[f"{name}_snapshots_per_s_per_core_{n}"] = round(c2 / cpu2, 1)
    return {**out, **_machine()}
