"""Propagation paths between one transmitter and a node's receivers.

Two families, both returned as ``(delays, amplitudes)`` arrays of shape ``(n_rx, P)``
(padding paths have amplitude 0), ready for :meth:`sim_nodes.radar.MSequenceRadar.path_spectrum`:

* :func:`image_paths`: the static channel, the direct Tx -> Rx coupling and specular wall
  reflections up to order 2 by the image method, with visibility checks.
* :func:`scatter_paths`: single-bounce paths via point scatterers (people), with shadowing
  by other bodies, self-shadowing and through-wall loss.

Amplitudes are relative to a unit-gain free-space link of 1 m: ``1/d`` for the direct path
and images (d the unfolded length), ``sqrt(sigma / 4 pi) / (d1 d2)`` for a scatterer, times
antenna pattern factors at both ends, reflection coefficients and transmission factors.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from sim_nodes.channel.geometry import (
    Walls,
    antenna_gain,
    mirror,
    segment_intersection,
    wall_crossings,
    wall_side,
)
from sim_nodes.radar import C

_EPS = 1e-9


@dataclass(frozen=True, slots=True, kw_only=True)
class Antennas:
    """A set of A antennas in world coordinates.

    Attributes
    ----------
    position : ndarray, float64, shape (A, 3)
        World positions, m.
    boresight : ndarray, float64, shape (A,)
        World yaw of boresight, rad.
    beamwidth : ndarray, float64, shape (A,)
        3 dB beamwidth, rad (``2 pi``: omni).
    """

    position: npt.NDArray[np.float64]
    boresight: npt.NDArray[np.float64]
    beamwidth: npt.NDArray[np.float64]


def _wall_sequences(n_walls: int, order: int) -> np.ndarray:
    """All reflection sequences of ``order`` walls, no wall twice in a row, shape (S, order)."""
    if order == 0:
        return np.zeros((1, 0), int)
    seqs = np.arange(n_walls)[:, None]
    for _ in range(order - 1):
        nxt = np.arange(n_walls)
        a = np.repeat(seqs, n_walls, axis=0)
        b = np.tile(nxt, seqs.shape[0])[:, None]
        keep = a[:, -1] != b[:, 0]
        seqs = np.concatenate([a, b], axis=1)[keep]
    return seqs


def _image_paths_of_order(
    tx: Antennas, rx: Antennas, walls: Walls, order: int
) -> tuple[np.ndarray, np.ndarray]:
    seq = _wall_sequences(walls.count, order)  # (S, k)
    n_seq, n_rx = seq.shape[0], rx.position.shape[0]
    # Images of the transmitter: img[m] is the image after the first m reflections.
    images = [np.broadcast_to(tx.position[0], (n_seq, 3)).copy()]
    for m in range(order):
        images.append(mirror(images[-1], walls.start[seq[:, m]], walls.end[seq[:, m]]))
    # Back-trace from each receiver: the last reflection point lies on the segment from the
    # last image to the receiver, the one before on the segment from the previous image
    # to that point, and so on. A path exists only if every point lies on its wall.
    target = np.broadcast_to(rx.position[None, :, :], (n_seq, n_rx, 3))
    valid = np.ones((n_seq, n_rx), bool)
    points = [target]
    for m in range(order, 0, -1):
        w = seq[:, m - 1]
        src = np.broadcast_to(images[m][:, None, :], target.shape)
        u, s = segment_intersection(src, target, walls.start[w][:, None], walls.end[w][:, None])
        with np.errstate(invalid="ignore"):
            ok = (u > _EPS) & (u < 1 - _EPS) & (s >= 0) & (s <= 1)
        u = np.where(ok, u, 0.5)
        target = src + u[..., None] * (target - src)
        valid &= ok & (target[..., 2] >= 0) & (target[..., 2] <= walls.height[w][:, None])
        points.insert(0, target)
    points.insert(0, np.broadcast_to(tx.position[0], (n_seq, n_rx, 3)))
    length = np.linalg.norm(rx.position[None, :, :] - images[-1][:, None, :], axis=-1)

    # Walls crossed by each leg, excluding the walls the leg starts or ends on.
    trans = np.ones((n_seq, n_rx))
    excess = np.zeros((n_seq, n_rx))
    eye = np.eye(walls.count, dtype=bool)
    for j in range(order + 1 if walls.count else 0):
        exclude = np.zeros((n_seq, walls.count), bool)
        if j >= 1:
            exclude |= eye[seq[:, j - 1]]
        if j < order:
            exclude |= eye[seq[:, j]]
        ex = np.broadcast_to(exclude[:, None, :], (n_seq, n_rx, walls.count))
        t_leg, e_leg = wall_crossings(
            points[j].reshape(-1, 3),
            points[j + 1].reshape(-1, 3),
            walls,
            ex.reshape(-1, walls.count),
        )
        trans *= t_leg.reshape(n_seq, n_rx)
        excess += e_leg.reshape(n_seq, n_rx)

    gamma = np.prod(walls.reflection[seq], axis=1) if order else np.ones(n_seq)
    f_tx = antenna_gain(points[1] - points[0], tx.boresight[0], tx.beamwidth[0])
    f_rx = antenna_gain(points[-2] - points[-1], rx.boresight[None, :], rx.beamwidth[None, :])
    amp = gamma[:, None] * trans * f_tx * f_rx / np.maximum(length, 1e-3)
    amp = np.where(valid, amp, 0.0)
    delay = np.where(valid, (length + excess) / C, 0.0)
    return delay.T, amp.T


def image_paths(
    tx: Antennas, rx: Antennas, walls: Walls, max_order: int = 2
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Direct coupling and specular wall reflections by the image method.

    For a reflection sequence of walls ``w_1..w_k`` the transmitter is mirrored
    successively, ``T_m = M_{w_m} T_{m-1}``; the path length is the unfolded distance
    ``|R - T_k|`` and the amplitude

    .. math:: a = F_{tx}(\\phi_d) F_{rx}(\\phi_a) \\prod_m \\Gamma_{w_m}
              \\prod_{crossed} T_w / |R - T_k|

    The path is kept only if each reflection point lies on its wall segment (and below
    its top); legs that pass through other walls are attenuated by their one-way
    transmission factors ``T_w`` (not removed: a sensor behind a wall still sees through).

    Parameters
    ----------
    tx : Antennas
        One transmitting antenna (A = 1).
    rx : Antennas
        The receiving antennas (A = n_rx).
    walls : Walls
    max_order : int
        Highest reflection order, 0 (direct only) to 2.

    Returns
    -------
    delays : ndarray, float64, shape (n_rx, P)
        Path delays, s.
    amplitudes : ndarray, float64, shape (n_rx, P)
        Path amplitudes; 0 for reflection sequences without a valid path.
    """
    orders = range(0, max_order + 1 if walls.count else 1)
    parts = [_image_paths_of_order(tx, rx, walls, k) for k in orders]
    return np.concatenate([p[0] for p in parts], 1), np.concatenate([p[1] for p in parts], 1)


def scatter_paths(
    tx: Antennas,
    rx: Antennas,
    points: np.ndarray,
    rcs: np.ndarray,
    walls: Walls,
    *,
    normals: np.ndarray | None = None,
    owner: np.ndarray | None = None,
    blockers: np.ndarray | None = None,
    blocker_radius: np.ndarray | None = None,
    shadow_db: float = 18.0,
    antenna_side: np.ndarray | None = None,
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Single-bounce paths Tx -> point scatterer -> Rx.

    .. math:: a = \\sqrt{\\sigma / 4\\pi}\\, F_{tx} F_{rx}\\, S_1 S_2\\, T_1 T_2 / (d_1 d_2),
              \\quad \\tau = (d_1 + d_2 + \\Delta_1 + \\Delta_2) / c

    ``S`` are shadowing factors of the two legs: ``10^{-shadow_db/20}`` for every other
    body (a disc of ``blocker_radius`` around its centre) the leg passes, and a smooth
    self-shadowing ``10^{-shadow_db (1 - cos\\alpha) / 40}`` with alpha the angle between
    the point's outward body normal and the leg (the far side of a body is dim). ``T``
    are the through-wall factors of the legs and ``Delta`` their excess lengths.

    Parameters
    ----------
    tx, rx : Antennas
        One transmitter; n_rx receivers.
    points : ndarray, float64, shape (Q, 3)
        Scatterer positions, world, m.
    rcs : ndarray, float64, shape (Q,)
        Mean radar cross-section of each point, m^2 (fluctuation and the sign of the
        reflection are applied by the caller).
    walls : Walls
    normals : ndarray, shape (Q, 2), optional
        Outward unit body normals in x, y (self-shadowing off if omitted).
    owner : ndarray, int, shape (Q,), optional
        Index of the blocker each point belongs to (its own body does not block it).
    blockers : ndarray, shape (M, 2), optional
        Body centres in x, y, m.
    blocker_radius : ndarray, shape (M,), optional
        Body radii, m.
    shadow_db : float
        Attenuation of a leg through a body, dB.
    antenna_side : ndarray, shape (1 + n_rx, W), optional
        ``wall_side`` of the Tx and Rx antennas, if the caller keeps it (static antennas:
        the simulator computes it once per node instead of once per acquisition).

    Returns
    -------
    delays, amplitudes : ndarray, float64, shape (n_rx, Q)
    """
    # Antenna-major layout: row 0 is the Tx leg, rows 1.. the Rx legs; every factor below
    # is computed once for all (1 + n_rx) x Q legs.
    ant = np.concatenate([tx.position, rx.position])  # (A, 3)
    vec = points[None, :, :] - ant[:, None, :]  # (A, Q, 3) antenna -> point
    dist = np.sqrt(np.einsum("aqi,aqi->aq", vec, vec))
    factor = antenna_gain(
        vec,
        np.concatenate([tx.boresight, rx.boresight])[:, None],
        np.concatenate([tx.beamwidth, rx.beamwidth])[:, None],
    )
    excess = np.zeros_like(dist)
    # A leg can only cross a wall whose line separates its two ends: test the sides of the
    # few antennas and points once, and trace the legs only if some wall separates them
    # (never, for a node in the same room as the people).
    if antenna_side is None and walls.count:
        antenna_side = wall_side(ant, walls)
    if walls.count and np.any(antenna_side[:, None, :] * wall_side(points, walls)[None, :, :] < 0):
        leg_p = np.broadcast_to(ant[:, None, :], vec.shape).reshape(-1, 3)
        leg_q = np.broadcast_to(points[None], vec.shape).reshape(-1, 3)
        t_leg, e_leg = wall_crossings(leg_p, leg_q, walls)
        factor *= t_leg.reshape(factor.shape)
        excess = e_leg.reshape(factor.shape)
    if blockers is not None and blockers.shape[0] and blocker_radius is not None:
        # Body m blocks the leg antenna -> point if its centre projects inside the leg
        # (0 < w.r < |r|^2) within its radius: |w|^2 - (w.r)^2 / |r|^2 < R^2 (in x, y).
        r_xy = vec[..., :2]  # (A, Q, 2)
        w_xy = blockers[None, :, :] - ant[:, None, :2]  # (A, M, 2)
        dot = r_xy @ np.swapaxes(w_xy, -1, -2)  # (A, Q, M)
        rr = np.maximum(np.sum(r_xy * r_xy, axis=-1), 1e-12)[..., None]
        ww = np.sum(w_xy * w_xy, axis=-1)[:, None, :]
        blocked = (dot > 0) & (dot < rr) & (ww - dot * dot / rr < blocker_radius**2)
        if owner is not None:
            blocked &= owner[None, :, None] != np.arange(blockers.shape[0])
        factor *= 10 ** (-shadow_db / 20 * blocked.sum(axis=-1))
    if normals is not None:
        # cos(alpha) between the outward normal and the direction point -> antenna.
        horiz = np.sqrt(vec[..., 0] ** 2 + vec[..., 1] ** 2)
        cos = -(normals[None, :, 0] * vec[..., 0] + normals[None, :, 1] * vec[..., 1]) / (
            np.maximum(horiz, 1e-9)
        )
        factor *= 10 ** (-shadow_db / 40 * (1 - cos))
    amp = np.sqrt(np.abs(rcs) / (4 * np.pi)) * factor[0] * factor[1:] / (dist[0] * dist[1:])
    return (dist[0] + dist[1:] + excess[0] + excess[1:]) / C, amp
