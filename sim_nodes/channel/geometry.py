"""Vectorised plane geometry for the channel: walls, mirrors, crossings, antenna patterns.

Walls are vertical: a 2-D segment in world x, y from the floor (z = 0) to ``height``.
Points are 3-D ``[x, y, z]`` world coordinates, m. All functions broadcast over leading
axes; nothing here loops over paths.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

_EPS = 1e-9


@dataclass(frozen=True, slots=True, kw_only=True)
class Walls:
    """A set of W vertical walls.

    Attributes
    ----------
    start, end : ndarray, float64, shape (W, 2)
        Segment end points in world x, y, m.
    height : ndarray, float64, shape (W,)
        Top edge above the floor, m.
    reflection : ndarray, float64, shape (W,)
        Amplitude reflection coefficient Gamma (signed, frequency- and angle-independent).
    transmission : ndarray, float64, shape (W,)
        One-way amplitude transmission factor ``10**(-loss_db / 20)``.
    excess : ndarray, float64, shape (W,), optional
        Extra path length of a crossing, m: ``thickness (sqrt(eps_r) - 1)`` at normal
        incidence (the wave is slower inside the wall). Zeros if omitted.
    """

    start: npt.NDArray[np.float64]
    end: npt.NDArray[np.float64]
    height: npt.NDArray[np.float64]
    reflection: npt.NDArray[np.float64]
    transmission: npt.NDArray[np.float64]
    excess: npt.NDArray[np.float64] | None = None

    @property
    def count(self) -> int:
        """Number of walls W."""
        return int(self.start.shape[0])

    def take(self, index: npt.ArrayLike) -> Walls:
        """The walls ``index`` (integer indices or a boolean mask), in their order."""
        i = np.asarray(index)
        return Walls(
            start=self.start[i],
            end=self.end[i],
            height=self.height[i],
            reflection=self.reflection[i],
            transmission=self.transmission[i],
            excess=None if self.excess is None else self.excess[i],
        )

    @classmethod
    def empty(cls) -> Walls:
        """No walls (free space)."""
        z2 = np.zeros((0, 2))
        z1 = np.zeros(0)
        return cls(start=z2, end=z2, height=z1, reflection=z1, transmission=z1)


def mirror(points: np.ndarray, start: np.ndarray, end: np.ndarray) -> np.ndarray:
    """Mirror 3-D points in the vertical planes through wall lines (z unchanged).

    .. math:: p' = p - 2 ((p - a) \\cdot \\hat n) \\hat n

    Parameters
    ----------
    points : ndarray, shape (..., 3)
    start, end : ndarray, shape (..., 2)
        Wall line end points, broadcast against ``points``.

    Returns
    -------
    ndarray, shape (..., 3)
    """
    d = end - start
    nrm = np.stack([-d[..., 1], d[..., 0]], axis=-1) / np.linalg.norm(d, axis=-1, keepdims=True)
    dist = np.sum((points[..., :2] - start) * nrm, axis=-1, keepdims=True)
    shape = (*np.broadcast_shapes(points.shape[:-1], dist.shape[:-1]), 3)
    out = np.broadcast_to(points, shape).copy()
    out[..., :2] = out[..., :2] - 2 * dist * nrm
    return out


def segment_intersection(
    p: np.ndarray, q: np.ndarray, a: np.ndarray, b: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Parameters of the intersection of lines ``p + u (q - p)`` and ``a + s (b - a)`` (x, y).

    Parameters
    ----------
    p, q : ndarray, shape (..., >=2)
        Ray/segment end points (only x, y used).
    a, b : ndarray, shape (..., 2)
        Wall end points.

    Returns
    -------
    u, s : ndarray, float64, broadcast shape
        ``nan`` where the lines are parallel.
    """
    r = q[..., :2] - p[..., :2]
    e = b - a
    den = r[..., 0] * e[..., 1] - r[..., 1] * e[..., 0]
    w = a - p[..., :2]
    with np.errstate(divide="ignore", invalid="ignore"):
        den = np.where(np.abs(den) < 1e-15, np.nan, den)
        u = (w[..., 0] * e[..., 1] - w[..., 1] * e[..., 0]) / den
        s = (w[..., 0] * r[..., 1] - w[..., 1] * r[..., 0]) / den
    return u, s


def wall_hits(p: np.ndarray, q: np.ndarray, walls: Walls) -> np.ndarray:
    """Which walls each segment passes through: strictly between its ends (``0 < u < 1``),
    within the wall (``0 <= s <= 1``) and below its top edge.

    Parameters
    ----------
    p, q : ndarray, shape (L, 3)
        Segment end points.
    walls : Walls

    Returns
    -------
    ndarray, bool, shape (L, W)
    """
    u, s = segment_intersection(p[:, None, :], q[:, None, :], walls.start, walls.end)
    z = p[:, None, 2] + u * (q[:, None, 2] - p[:, None, 2])
    with np.errstate(invalid="ignore"):
        return (u > _EPS) & (u < 1 - _EPS) & (s >= 0) & (s <= 1) & (z <= walls.height)


def wall_crossings(
    p: np.ndarray, q: np.ndarray, walls: Walls, exclude: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Transmission factor and excess length of the walls a segment passes through.

    A wall counts when the segment crosses it strictly between its ends (``0 < u < 1``),
    within the wall (``0 <= s <= 1``) and below its top edge.

    .. math:: T = \\prod_{w\\ crossed} T_w, \\quad \\Delta = \\sum_{w\\ crossed} \\Delta_w

    Parameters
    ----------
    p, q : ndarray, shape (L, 3)
        Segment end points.
    walls : Walls
    exclude : ndarray of bool, shape (L, W), optional
        Walls not to count per segment (the walls a path reflects on at its ends).

    Returns
    -------
    transmission : ndarray, float64, shape (L,)
        Product of the one-way amplitude transmission factors.
    excess : ndarray, float64, shape (L,)
        Sum of the crossed walls' excess path lengths, m.
    """
    if walls.count == 0:
        return np.ones(p.shape[0]), np.zeros(p.shape[0])
    hit = wall_hits(p, q, walls)
    if exclude is not None:
        hit &= ~exclude
    trans = np.prod(np.where(hit, walls.transmission, 1.0), axis=-1)
    if walls.excess is None:
        return trans, np.zeros(p.shape[0])
    return trans, hit @ walls.excess


def wall_side(points: np.ndarray, walls: Walls) -> np.ndarray:
    """Signed distance of points from the wall lines (positive on the left of start->end).

    Parameters
    ----------
    points : ndarray, shape (N, >=2)
    walls : Walls

    Returns
    -------
    ndarray, float64, shape (N, W), m
    """
    e = walls.end - walls.start
    e = e / np.linalg.norm(e, axis=-1, keepdims=True)
    w = points[:, None, :2] - walls.start
    return e[:, 0] * w[..., 1] - e[:, 1] * w[..., 0]


def segment_point_distance(
    p: np.ndarray, q: np.ndarray, c: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Distance in x, y from points ``c`` to segments ``p q``, and the projection parameter.

    Parameters
    ----------
    p, q : ndarray, shape (L, >=2)
    c : ndarray, shape (M, 2)

    Returns
    -------
    dist, u : ndarray, float64, shape (L, M)
        ``u`` is the unclipped position of the foot point along the segment (0 at p, 1 at q).
    """
    r = (q[:, :2] - p[:, :2])[:, None, :]
    w = c[None, :, :] - p[:, None, :2]
    rr = np.maximum(np.sum(r * r, axis=-1), 1e-30)
    u = np.sum(w * r, axis=-1) / rr
    foot = p[:, None, :2] + np.clip(u, 0.0, 1.0)[..., None] * r
    return np.linalg.norm(c[None, :, :] - foot, axis=-1), u


def antenna_gain(
    direction: np.ndarray,
    boresight: npt.ArrayLike,
    beamwidth: npt.ArrayLike,
    floor_db: float = -25.0,
) -> np.ndarray:
    """Smooth horn amplitude pattern in azimuth (elevation ignored in this version).

    Gaussian beam in dB with the given 3 dB width, clipped at a back-lobe floor:

    .. math:: G_{dB}(\\theta) = \\max(-3 (2 \\theta / \\theta_{3dB})^2, G_{floor}),
              \\quad F = 10^{G_{dB} / 20}

    Parameters
    ----------
    direction : ndarray, shape (..., >=2)
        World vectors from the antenna towards the path's first/last interaction.
    boresight : array_like
        World yaw of the antenna's boresight, rad.
    beamwidth : array_like
        3 dB beamwidth, rad; ``>= 2 pi`` means omnidirectional.
    floor_db : float
        Back-lobe level, dB.

    Returns
    -------
    ndarray, float64, amplitude factor (1 on boresight)
    """
    yaw = np.arctan2(direction[..., 1], direction[..., 0])
    off = np.remainder(yaw - boresight + np.pi, 2 * np.pi) - np.pi
    bw = np.asarray(beamwidth, float)
    gain_db = np.maximum(-3.0 * (2 * off / bw) ** 2, floor_db)
    return np.where(bw >= 2 * np.pi, 1.0, np.exp(gain_db * (np.log(10) / 20)))
