"""Measurement models of the bat-type robot's echoes (Fig. 19 of the CoLOR chapter).

A bat-type array has one transmitter and two receivers. An echo at receiver ``j`` is a
bistatic range ``r_j`` (path length Tx -> landmark -> Rx_j, m, PROTOCOL.md). Three landmark
kinds give three models, all with a 2-D landmark state:

* **wall** (single specular reflection), state ``(alpha, d)``: the line
  ``{x : n . x = d}`` with unit normal ``n = (cos alpha, sin alpha)``. The echo comes from the
  image of the transmitter in the wall, ``T' = tx + 2 (d - n . tx) n``, and
  ``r_j = |T' - rx_j|``.
* **corner** (double reflection in two perpendicular walls), state ``c``: the image is the
  point reflection ``T' = 2 c - tx`` and ``r_j = |T' - rx_j|``.
* **point** (edge, small object: a point scatterer), state ``p``:
  ``r_j = |p - tx| + |p - rx_j|``.

From one robot position a wall and a corner give the same echoes (the same image ``T'``); a
point differs by second-order terms only while the robot turns on the spot. The kind is
therefore decided from several views (:mod:`fusion_center.mapping.rbpf` keeps the three
hypotheses of each landmark side by side).

Everything is vectorised over leading axes (particles, landmarks); positions are world x, y
in metres, angles in radians.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]

#: Landmark kinds, in the order of the hypothesis axis.
WALL, CORNER, POINT = 0, 1, 2
KINDS = ("wall", "corner", "point")


def wall_image(state: FloatArray, tx: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Image of the transmitter in a wall and its Jacobian.

    Parameters
    ----------
    state : ndarray, shape (..., 2)
        Wall ``(alpha, d)``: normal angle (rad) and signed distance of the line from the origin
        along the normal (m).
    tx : ndarray, shape (..., 2)
        Transmitter position, m.

    Returns
    -------
    image : ndarray, shape (..., 2)
        ``T' = tx + 2 s n`` with ``s = d - n . tx`` (distance of tx to the wall, positive on the
        side the normal points away from).
    jac : ndarray, shape (..., 2, 2)
        ``dT' / d(alpha, d)``.
    s : ndarray, shape (...)
        Signed distance of the transmitter to the wall along ``-n``.
    """
    a = state[..., 0]
    n = np.stack([np.cos(a), np.sin(a)], axis=-1)
    nt = np.stack([-np.sin(a), np.cos(a)], axis=-1)
    s = state[..., 1] - np.sum(n * tx, axis=-1)
    image = tx + 2.0 * s[..., None] * n
    ds_da = -np.sum(nt * tx, axis=-1)
    d_alpha = 2.0 * s[..., None] * nt + 2.0 * ds_da[..., None] * n
    jac = np.stack([d_alpha, 2.0 * n], axis=-1)
    return image, jac, s


def predict(
    kind: int, state: FloatArray, tx: FloatArray, rx: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Expected bistatic ranges of a landmark at both receivers, with the Jacobian.

    .. math::
        r_j = \\lVert T' - rx_j \\rVert \\ \\text{(wall, corner)}, \\qquad
        r_j = \\lVert p - tx \\rVert + \\lVert p - rx_j \\rVert \\ \\text{(point)}

    (Fig. 19 of the CoLOR chapter).

    Parameters
    ----------
    kind : int
        :data:`WALL`, :data:`CORNER` or :data:`POINT`.
    state : ndarray, shape (..., 2)
        Landmark state (see the module docstring).
    tx : ndarray, shape (..., 2)
        Transmitter position, m (broadcast against ``state``).
    rx : ndarray, shape (..., 2, 2)
        Receiver positions ``rx[..., j, :]``, m.

    Returns
    -------
    ranges : ndarray, shape (..., 2)
        Bistatic ranges, m.
    jac : ndarray, shape (..., 2, 2)
        ``d ranges / d state``.
    direction : ndarray, shape (..., 2)
        World direction from the transmitter towards where the echo comes from (unit vector;
        used for the beam test).
    """
    tx = np.broadcast_to(tx, np.broadcast_shapes(tx.shape, state.shape))
    if kind == POINT:
        d0 = state - tx
        n0 = np.maximum(np.linalg.norm(d0, axis=-1), 1e-9)
        dj = state[..., None, :] - rx
        nj = np.maximum(np.linalg.norm(dj, axis=-1), 1e-9)
        ranges = n0[..., None] + nj
        jac = (d0 / n0[..., None])[..., None, :] + dj / nj[..., None]
        return ranges, jac, d0 / n0[..., None]
    if kind == WALL:
        image, dimg, _ = wall_image(state, tx)
    else:
        image = 2.0 * state - tx
        dimg = np.broadcast_to(2.0 * np.eye(2), (*state.shape[:-1], 2, 2))
    dj = image[..., None, :] - rx
    nj = np.maximum(np.linalg.norm(dj, axis=-1), 1e-9)
    u = dj / nj[..., None]
    jac = np.einsum("...jk,...kl->...jl", u, dimg)
    d0 = image - tx
    return nj, jac, d0 / np.maximum(np.linalg.norm(d0, axis=-1), 1e-9)[..., None]


def rotate(v: FloatArray, angle: FloatArray) -> FloatArray:
    """Vectors ``v`` (m, 2) rotated by angles ``angle`` (m,) or one angle, rad (a body-frame
    offset to the world frame at heading ``angle``)."""
    c, s = np.cos(angle), np.sin(angle)
    return np.stack([c * v[:, 0] - s * v[:, 1], s * v[:, 0] + c * v[:, 1]], -1)


def invert_image(ranges: FloatArray, rx_body: FloatArray) -> FloatArray:
    """Image point ``T'`` in the array frame from one pair of ranges (wall or corner echo).

    Intersection of the circles ``|T' - rx_j| = r_j`` in front of the array (``x > 0``; the
    horns look forward). The array frame has the transmitter at the origin.

    Parameters
    ----------
    ranges : ndarray, shape (m, 2)
        Bistatic ranges at rx1 and rx2, m.
    rx_body : ndarray, shape (2, 2)
        Receiver positions in the array frame, m.

    Returns
    -------
    ndarray, shape (m, 2)
        ``T'`` in the array frame; NaN where the circles do not meet.
    """
    a, b = rx_body
    base = b - a
    dist = np.linalg.norm(base)
    e = base / dist
    en = np.array([-e[1], e[0]])
    r1, r2 = ranges[:, 0], ranges[:, 1]
    along = (r1**2 - r2**2 + dist**2) / (2 * dist)
    h2 = r1**2 - along**2
    h = np.sqrt(np.where(h2 >= 0, h2, np.nan))
    p1 = a + along[:, None] * e + h[:, None] * en
    p2 = a + along[:, None] * e - h[:, None] * en
    return np.where((p1[:, :1] >= p2[:, :1]), p1, p2)


def invert_point(ranges: FloatArray, rx_body: FloatArray, iterations: int = 8) -> FloatArray:
    """Point scatterer in the array frame from one pair of ranges (ellipse intersection).

    Solves ``|p| + |p - rx_j| = r_j`` (transmitter at the origin) by Gauss-Newton from the
    image solution halved, which is within a few centimetres for ranges of metres.

    Parameters
    ----------
    ranges : ndarray, shape (m, 2)
        Bistatic ranges, m.
    rx_body : ndarray, shape (2, 2)
        Receiver positions in the array frame, m.
    iterations : int
        Gauss-Newton steps.

    Returns
    -------
    ndarray, shape (m, 2)
        Point in the array frame, NaN where the ellipses do not meet in front.
    """
    p = 0.5 * invert_image(ranges, rx_body)
    origin = np.zeros((p.shape[0], 2))
    for _ in range(iterations):
        pred, jac, _ = predict(POINT, p, origin, np.broadcast_to(rx_body, (p.shape[0], 2, 2)))
        res = ranges - pred
        step = np.linalg.solve(jac + 1e-9 * np.eye(2), res[..., None])[..., 0]
        p = p + step
    pred, _, _ = predict(POINT, p, origin, np.broadcast_to(rx_body, (p.shape[0], 2, 2)))
    bad = (np.abs(pred - ranges).max(axis=-1) > 1e-3) | (p[:, 0] <= 0)
    p[bad] = np.nan
    return p


def states_from_image(kind: int, image: FloatArray, tx: FloatArray) -> FloatArray:
    """Landmark state of a wall or corner from the world image point ``T'`` of an echo.

    Wall: normal from ``tx`` towards ``T'``, the line halfway (perpendicular bisector);
    corner: ``c = (tx + T') / 2``.

    Parameters
    ----------
    kind : int
        :data:`WALL` or :data:`CORNER`.
    image, tx : ndarray, shape (..., 2)
        World positions, m.

    Returns
    -------
    ndarray, shape (..., 2)
    """
    mid = 0.5 * (image + tx)
    if kind == CORNER:
        return mid
    v = image - tx
    alpha = np.arctan2(v[..., 1], v[..., 0])
    n = np.stack([np.cos(alpha), np.sin(alpha)], axis=-1)
    return np.stack([alpha, np.sum(n * mid, axis=-1)], axis=-1)


def wall_tangent(state: FloatArray, point: FloatArray) -> FloatArray:
    """Coordinate of ``point`` along a wall (m): ``point . (-sin alpha, cos alpha)``."""
    a = state[..., 0]
    return -np.sin(a) * point[..., 0] + np.cos(a) * point[..., 1]


def wall_segment(state: FloatArray, t_min: FloatArray, t_max: FloatArray) -> FloatArray:
    """End points ``[x1, y1, x2, y2]`` of walls from their state and tangential extent."""
    a = state[..., 0]
    n = np.stack([np.cos(a), np.sin(a)], axis=-1)
    nt = np.stack([-np.sin(a), np.cos(a)], axis=-1)
    base = state[..., 1:2] * n
    p1 = base + t_min[..., None] * nt
    p2 = base + t_max[..., None] * nt
    return np.concatenate([p1, p2], axis=-1)
