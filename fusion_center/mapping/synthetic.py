"""Synthetic echo pairs of a bat-type robot in a 2-D room (for tests and the SLAM benchmark).

Walls are segments (the echo exists when the specular point lies on the segment), corners and
points are positions; an echo is produced when the landmark lies within ``beam`` of the array
boresight. Ranges follow :func:`fusion_center.mapping.models.predict` plus Gaussian noise, so
the SLAM can be checked against known truth without the channel simulation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from fusion_center.mapping.models import CORNER, POINT, WALL, predict

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True, slots=True, kw_only=True)
class SyntheticRoom:
    """Landmarks of a synthetic room (world frame, m).

    Attributes
    ----------
    walls : ndarray, shape (w, 4)
        Segments ``[x1, y1, x2, y2]``.
    corners, points : ndarray, shape (k, 2)
    """

    walls: FloatArray
    corners: FloatArray
    points: FloatArray


def rectangle_room(width: float = 6.0, depth: float = 5.0) -> SyntheticRoom:
    """A ``width`` x ``depth`` room with its four corners and two point scatterers."""
    c = np.array([[0, 0], [width, 0], [width, depth], [0, depth]], float)
    walls = np.hstack([c, np.roll(c, -1, 0)])
    points = np.array([[0.6 * width, 0.55 * depth], [0.3 * width, 0.35 * depth]])
    return SyntheticRoom(walls=walls, corners=c, points=points)


def stop_and_turn_poses(stops: npt.ArrayLike, n_headings: int, heading_step: float) -> FloatArray:
    """Poses ``[x, y, yaw]`` of a robot turning on the spot at each stop, stop-major."""
    s = np.asarray(stops, float)
    yaw = np.arange(n_headings) * heading_step
    xy = np.repeat(s, n_headings, axis=0)
    return np.column_stack([xy, np.tile(yaw, s.shape[0])])


def echo_pairs(
    room: SyntheticRoom,
    pose: FloatArray,
    antennas: FloatArray,
    rng: np.random.Generator,
    *,
    sigma: float = 0.01,
    beam: float = np.radians(35.0),
    max_range: float = 12.0,
) -> FloatArray:
    """Noisy range pairs ``(r1, r2)`` of every landmark visible from ``pose``.

    Parameters
    ----------
    pose : ndarray, shape (3,)
        ``[x, y, yaw]``.
    antennas : ndarray, shape (3, 2)
        tx, rx1, rx2 in the robot frame.

    Returns
    -------
    ndarray, shape (m, 2), m
    """
    c, s = np.cos(pose[2]), np.sin(pose[2])
    rot = np.array([[c, -s], [s, c]])
    ant = antennas @ rot.T + pose[:2]
    tx, rx = ant[0], ant[1:]
    bore = np.array([c, s])
    out = []
    w = room.walls
    a, b = w[:, :2], w[:, 2:]
    e = (b - a) / np.linalg.norm(b - a, axis=1)[:, None]
    n = np.column_stack([-e[:, 1], e[:, 0]])
    n = np.where((np.sum(n * (a - tx), 1) > 0)[:, None], n, -n)  # normal from tx to the wall
    d = np.sum(n * a, 1)
    state = np.column_stack([np.arctan2(n[:, 1], n[:, 0]), d])
    foot = tx + (d - n @ tx)[:, None] * n
    t = np.sum((foot - a) * e, 1)
    on = (t > 0) & (t < np.linalg.norm(b - a, axis=1))
    for kind, st, ok in (
        (WALL, state, on),
        (CORNER, room.corners, np.ones(len(room.corners), bool)),
        (POINT, room.points, np.ones(len(room.points), bool)),
    ):
        if len(st) == 0:
            continue
        r, _, direction = predict(kind, st, tx[None], rx[None])
        vis = ok & (direction @ bore >= np.cos(beam)) & (r.max(1) <= max_range)
        out.append(r[vis])
    z = np.vstack(out) if out else np.zeros((0, 2))
    z = z + rng.normal(0.0, sigma, z.shape)
    return z[np.argsort(z.sum(1))]
