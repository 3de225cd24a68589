"""Walls in a sensor's line of sight: a detection-probability factor for the GM-PHD.

The GM-PHD of :mod:`fusion_center.tracking.gmphd` takes a sensor's detection probability
``p_D`` as constant over its field of view (sector and range): a sensor is assumed to see a
person in the next room through the partition. It then counts the sensor's silence as
evidence against the tracks there and lowers its learned ``p_D`` profile. In a building of
many rooms most sensors' views cross walls, and the count of tracks goes wrong.

:class:`WallSightModel` gives the factor

.. math:: F_s(x) = f^{\\,n_s(x)}

with ``n_s(x)`` the number of known walls the straight line from sensor ``s``'s array centre
to ``x`` crosses and ``f`` the factor per wall, which the tracker multiplies into
``p_D,s(x)`` (the state-dependent ``p_D(x)`` of the GM-PHD, Vo & Ma 2006, eq. (20)).
The walls come from the site description (a scenario's or floor plan's walls), never from
truth. This goes beyond the CoLOR chapter's tracker, which has no building model. Pure numpy,
and one compiled kernel (:func:`fusion_center.tracking.kernels.wall_crossings`) for the
tracker's many sight lines per frame.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from fusion_center.tracking import kernels
from fusion_center.tracking.base import SensorScan

FloatArray = npt.NDArray[np.float64]

#: A wall crossed at this fraction of the sight line or nearer its ends does not count (a
#: sensor mounted on a wall does not look through that wall).
_END_MARGIN = 1e-6


class WallSightModel:
    """Factor on a sensor's detection probability for the walls between it and a position.

    Parameters
    ----------
    start, end : array_like, shape (W, 2)
        Wall segments in world x, y, m.
    factor : float
        ``p_D`` factor per wall crossed (0: sensors never see through walls; 1: walls
        ignored). 0.1 by default: through a brick partition the node DSP rarely reports a
        person (the two-way wall loss puts the echo near its detection threshold).
    """

    def __init__(self, start: npt.ArrayLike, end: npt.ArrayLike, factor: float = 0.1) -> None:
        self.start = np.asarray(start, float).reshape(-1, 2)
        self.end = np.asarray(end, float).reshape(-1, 2)
        if self.start.shape != self.end.shape:
            raise ValueError("walls need as many end points as start points")
        if not 0.0 <= factor <= 1.0:
            raise ValueError(f"factor must be in [0, 1], got {factor}")
        self.factor = float(factor)
        #: ``pairs`` by the compiled kernel (False: the numpy reference, the same counts).
        self.compiled = True

    def crossings(self, origin: npt.ArrayLike, xy: npt.ArrayLike) -> npt.NDArray[np.int64]:
        """Number of walls the segment from ``origin`` (2,) to each of ``xy`` (J, 2) crosses."""
        o = np.asarray(origin, float).reshape(2)
        p = np.asarray(xy, float).reshape(-1, 2)
        r = p - o  # (J, 2) sight lines
        e = self.end - self.start  # (W, 2)
        w = self.start - o  # (W, 2)
        den = r[:, None, 0] * e[None, :, 1] - r[:, None, 1] * e[None, :, 0]  # (J, W)
        with np.errstate(divide="ignore", invalid="ignore"):
            u = (w[None, :, 0] * e[None, :, 1] - w[None, :, 1] * e[None, :, 0]) / den
            s = (w[None, :, 0] * r[:, None, 1] - w[None, :, 1] * r[:, None, 0]) / den
            hit = (u > _END_MARGIN) & (u < 1 - _END_MARGIN) & (s >= 0.0) & (s <= 1.0)
        return hit.sum(axis=1)

    def pairs(self, origins: npt.ArrayLike, xy: npt.ArrayLike) -> FloatArray:
        """``factor ** crossings`` of the sight lines ``origins[k]`` -> ``xy[k]`` (both (K, 2)),
        shape (K,): :meth:`__call__` for many (sensor, position) pairs at once (a frame's
        components in the views of all its sensors)."""
        p = np.asarray(xy, float).reshape(-1, 2)
        # one origin for all sight lines broadcasts (the compiled loop indexes it per line)
        o = np.asarray(origins, float).reshape(-1, 2)
        if o.shape[0] == 1 and p.shape[0] != 1:
            o = np.repeat(o, p.shape[0], axis=0)
        elif o.shape != p.shape:
            raise ValueError(f"origins {o.shape} and xy {p.shape} do not pair up")
        if p.shape[0] == 0 or self.start.shape[0] == 0:
            return np.ones(p.shape[0])
        if self.compiled:
            # one loop over the (sight line, wall) pairs instead of a dozen (K, W) temporaries:
            # at 48 sensors about 0.34 ms of the tracker's 2 ms per frame (issue 11, stop 21)
            n = kernels.wall_crossings(o, p, self.start, self.end, _END_MARGIN)
            return self.factor ** n.astype(float)
        r = p - o  # (K, 2) sight lines
        e = self.end - self.start  # (W, 2)
        w = self.start[None, :, :] - o[:, None, :]  # (K, W, 2)
        den = r[:, None, 0] * e[None, :, 1] - r[:, None, 1] * e[None, :, 0]  # (K, W)
        with np.errstate(divide="ignore", invalid="ignore"):
            u = (w[..., 0] * e[None, :, 1] - w[..., 1] * e[None, :, 0]) / den
            s = (w[..., 0] * r[:, None, 1] - w[..., 1] * r[:, None, 0]) / den
            hit = (u > _END_MARGIN) & (u < 1 - _END_MARGIN) & (s >= 0.0) & (s <= 1.0)
        return self.factor ** hit.sum(axis=1).astype(float)

    def __call__(self, scan: SensorScan, xy: FloatArray) -> FloatArray:
        """``factor ** crossings`` from the scan's array centre to each position, shape (J,)."""
        if xy.shape[0] == 0 or self.start.shape[0] == 0:
            return np.ones(xy.shape[0])
        return self.factor ** self.crossings(scan.origin, xy).astype(float)
