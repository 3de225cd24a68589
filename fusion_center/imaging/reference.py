"""A straightforward numpy Kirchhoff migration: the reference for tests and ``bench imaging``.

One observation at a time over the whole grid, :func:`numpy.hypot` distances and
:func:`numpy.interp` sampling, float64: what one writes first. :func:`kirchhoff_image` must
agree with it and is measured against it.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from fusion_center.imaging.migration import Grid, Observations, prepare_signals
from protocol.units import C


def straightforward_kirchhoff(
    obs: Observations, grid: Grid, *, envelope: bool = True, gate: float = 0.3
) -> npt.NDArray[np.float64]:
    """Eq. (17) of the CoLOR chapter, one observation per step (real rows only)."""
    sig = prepare_signals(obs, envelope=envelope, gate=gate)
    xs, ys = grid.xy()
    X, Y = np.meshgrid(xs, ys)
    img = np.zeros(X.shape)
    k = np.arange(sig.shape[1])
    for m in range(len(obs)):
        t, r = obs.tx[m], obs.rx[m]
        d = np.sqrt((X - t[0]) ** 2 + (Y - t[1]) ** 2 + (grid.z - t[2]) ** 2) + np.sqrt(
            (X - r[0]) ** 2 + (Y - r[1]) ** 2 + (grid.z - r[2]) ** 2
        )
        img += np.interp((d / C - obs.t0) * obs.fs, k, sig[m], left=0.0, right=0.0)
    return img
