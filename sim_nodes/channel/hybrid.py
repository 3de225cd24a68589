"""The hybrid deterministic-stochastic channel of Section 3 of the CoLOR chapter (pure numpy).

Ray tracing (:mod:`sim_nodes.channel.raytrace`) underestimates received power, mean delay
and delay spread because real surfaces are rough and cluttered. The chapter adds, around
every specular reflection point of the paths up to order ``scatter_order`` (3), a cluster of
N point scatterers on the reflecting surface, uniformly within radius r of the point, each
with the scattering coefficient (eq. (1))

.. math:: S_n = (a + p\\,\\delta_n)\\, \\Gamma\\, e^{-j k_0 \\delta_n},

where ``delta_n`` is the scatterer's distance from the reflection point (m), ``Gamma`` the
(Fresnel, polarimetric) reflection coefficient of the surface and ``k_0 = 2 pi f_c / c``.
A scatterer replaces the specular interaction: its ray goes Tx -> (earlier bounces) ->
scatterer -> (later bounces) -> Rx, with the unfolded length (eq. (2))

.. math:: L_n = |Q_n - T_{m-1}| + |Q_n - R_{m+1}|,

``T_{m-1}`` the transmitter imaged through the earlier faces and ``R_{m+1}`` the receiver
imaged through the later ones, so its amplitude is the specular one scaled by
``(L_spec / L_n) S_n / Gamma``. The channel is the coherent sum of the specular paths and
all scatterer contributions (eq. (3)):

.. math:: H(f) = \\sum_i a_i e^{-j 2\\pi f \\tau_i}
          + \\sum_i \\sum_{n=1}^{N} a_i \\frac{L_i}{L_{i,n}} (a + p\\delta_n)
            e^{-j k_0 \\delta_n} e^{-j 2\\pi f L_{i,n} / c}.

Since the specular point minimises the unfolded length over the plane, ``L_n >= L_spec``
and every scatterer is at most ``(a + p r)`` times its specular path: the scattered energy
of a cluster of ``N_i`` scatterers is bounded by ``N_i (a + p r)^2 |a_i|^2`` (``N_i`` is
Poisson with mean N, below). Scatterers that fall off the face's polygon are dropped, so a
cluster near a face's edge has fewer.

**Realization.** The scatterers are fixed on the surfaces, in the world: each face carries a
homogeneous Poisson field of points of density ``N / (pi r^2)`` (so that a disc of radius r
around a reflection point holds N on average), and the cluster of a reflection point is the
set of its face's scatterers within r of it. The field is laid out on a square lattice of
cells of side r in the face's plane frame; each cell's points are a row of a seeded table of
``n_table`` cell patterns, selected by a hash of (face, cell). Every path that reflects near
the same spot of a face, whatever its order and wherever the Tx and Rx are, therefore sees
the same physical scatterers, as a rough wall does. (An earlier version drew one offset
pattern per reflection sequence and moved it with the specular point: on a moving robot the
clusters rode along and made echoes no static map explains.)

Simplifications (documented, not hidden): scatterer rays inherit the visibility, the
transmission factors, the polarization and the antenna gains of their specular path.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from sim_nodes.channel.raytrace import (
    SCATTERED,
    AntennaArray,
    PathSet,
    SpecularGeometry,
    face_visibility,
    trace,
)
from sim_nodes.channel.room import Room
from sim_nodes.radar import C

_HASH_PRIMES = np.array([73856093, 19349663, 83492791, 49979687, 67867967], np.int64)


@dataclass(frozen=True, slots=True, kw_only=True)
class HybridConfig:
    """Parameters of the hybrid channel.

    Attributes
    ----------
    max_order : int
        Highest specular reflection order, 0..5.
    scatter_order : int
        Scatterer clusters around reflection points of paths up to this order (chapter: 3);
        0 gives pure ray tracing.
    n_scatterers : int
        N, scatterers per reflection point (eq. (1)); 0 gives pure ray tracing.
    radius : float
        r, radius of a cluster on the surface, m.
    a : float
        Constant part of the scattering coefficient (eq. (1)).
    p : float
        Growth of the scattering coefficient with the distance from the reflection point, 1/m.
    center_frequency : float
        f_c of ``k_0 = 2 pi f_c / c``, Hz.
    diffraction : bool
        Add first-order wedge diffraction (edge-scattering model, see raytrace).
    diffraction_strength : float
        ``d_0`` of the edge-scattering model.
    knots : tuple of float
        Frequencies at which amplitudes are evaluated, Hz (one knot: frequency-flat).
    n_table : int
        Number of lattice-cell patterns of the surface scatterer field drawn per realization.
    """

    max_order: int = 3
    scatter_order: int = 3
    n_scatterers: int = 16
    radius: float = 1.0
    a: float = 0.2
    p: float = 0.03
    center_frequency: float = 9e9
    diffraction: bool = True
    diffraction_strength: float = 0.5
    knots: tuple[float, ...] = (9e9,)
    n_table: int = 4096


def draw_clusters(n_table: int, n: int, radius: float, rng: np.random.Generator) -> np.ndarray:
    """Table of cell patterns of the surface scatterer field, shape (n_table, M, 2), m.

    Row i holds the offsets of one lattice cell's scatterers from the cell's lower corner,
    uniform on ``[0, radius)^2``, their number Poisson with mean ``n / pi`` (density
    ``n / (pi radius^2)``); unused slots of the M columns are NaN.
    """
    mean = n / np.pi
    m_max = int(np.ceil(mean + 6.0 * np.sqrt(mean))) + 1 if n > 0 else 0
    count = np.minimum(rng.poisson(mean, n_table), m_max)
    offsets = radius * rng.random((n_table, m_max, 2))
    offsets[np.arange(m_max)[None, :] >= count[:, None]] = np.nan
    return offsets


def cluster_index(face: np.ndarray, cell: np.ndarray, n_table: int) -> npt.NDArray[np.int64]:
    """Table row of lattice cell ``cell`` (..., 2) of face ``face`` (...)."""
    h = (
        (face + 1) * _HASH_PRIMES[0]
        + cell[..., 0] * _HASH_PRIMES[1]
        + cell[..., 1] * _HASH_PRIMES[2]
    )
    return np.remainder(h, n_table).astype(np.int64)


def surface_scatterers(
    room: Room, face: np.ndarray, points: np.ndarray, clusters: np.ndarray, radius: float
) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """The world-fixed scatterers within ``radius`` of reflection points on their faces.

    Parameters
    ----------
    room : Room
    face : ndarray, int, shape (n,)
        Face of each reflection point.
    points : ndarray, float64, shape (n, 3)
        Reflection points (in their face's plane), world, m.
    clusters : ndarray, float64, shape (n_table, M, 2)
        Cell patterns from :func:`draw_clusters`, drawn with the same ``radius``.
    radius : float
        r, m (also the lattice's cell side).

    Returns
    -------
    row : ndarray, int, shape (S,)
        Index into ``points`` of each scatterer.
    position : ndarray, float64, shape (S, 3)
        Scatterer positions, world, m: on the face (off-polygon ones dropped).
    delta : ndarray, float64, shape (S,)
        Distance from the reflection point, m (``delta_n`` of eq. (1)).
    """
    axes = np.stack([room.axis_u[face], room.axis_v[face]], axis=1)  # (n, 2, 3)
    st = np.einsum("njk,nk->nj", axes, points - room.origin[face])  # plane coordinates
    base = np.floor(st / radius).astype(np.int64)
    # a disc of radius r around st lies within the 3 x 3 cells around st's cell (side r)
    shift = np.stack(np.meshgrid([-1, 0, 1], [-1, 0, 1], indexing="ij"), axis=-1).reshape(9, 2)
    cell = base[:, None, :] + shift[None, :, :]  # (n, 9, 2)
    pattern = clusters[cluster_index(face[:, None], cell, clusters.shape[0])]  # (n, 9, M, 2)
    at = cell[:, :, None, :] * radius + pattern  # scatterers' plane coordinates
    rel = (at - st[:, None, None, :]).reshape(len(face), -1, 2)  # (n, 9 M, 2)
    with np.errstate(invalid="ignore"):
        dist = np.linalg.norm(rel, axis=-1)
        near = dist < radius  # NaN (empty slots) compares False
    row, col = np.nonzero(near)
    o = rel[row, col]
    q = points[row] + o[:, :1] * axes[row, 0] + o[:, 1:] * axes[row, 1]
    # Scatterers that fall off the face are not on the surface: dropped.
    keep = room.contains(face[row], q)
    return row[keep], q[keep], dist[row, col][keep]


def scatterer_paths(
    room: Room,
    paths: PathSet,
    geometry: list[SpecularGeometry],
    clusters: np.ndarray,
    config: HybridConfig,
) -> PathSet:
    """The scatterer contributions (eq. (1)-(3)) around the specular paths' reflections.

    Parameters
    ----------
    room : Room
    paths : PathSet
        The deterministic paths (rows referenced by ``geometry``).
    geometry : list of SpecularGeometry
        Per order 1.., from :func:`sim_nodes.channel.raytrace.trace`.
    clusters : ndarray, float64, shape (n_table, M, 2)
        Cell patterns from :func:`draw_clusters`, m.
    config : HybridConfig

    Returns
    -------
    PathSet
        ``kind == SCATTERED``; other attributes those of the parent specular path.
    """
    k0 = 2 * np.pi * config.center_frequency / C
    parent_rows, delays, scales = [], [], []
    for g in geometry:
        k = g.sequence.shape[1]
        if k > config.scatter_order or g.index.size == 0 or clusters.shape[1] == 0:
            continue
        excess = paths.delay[g.index] - g.length / C  # through-wall excess of the parent
        for m in range(k):
            row, q, delta = surface_scatterers(
                room, g.sequence[:, m], g.points[:, m], clusters, config.radius
            )
            length = np.linalg.norm(q - g.tx_images[row, m], axis=-1) + np.linalg.norm(
                q - g.rx_images[row, m], axis=-1
            )
            parent_rows.append(g.index[row])
            delays.append(length / C + excess[row])
            # eq. (1) without Gamma (the parent's amplitude carries it), times L_spec / L_n
            scale = (config.a + config.p * delta) * np.exp(-1j * k0 * delta)
            scales.append(scale * (g.length[row] / length))
    if not parent_rows:
        return paths.select(np.zeros(paths.count, bool))
    rows = np.concatenate(parent_rows)
    return PathSet(
        rx=paths.rx[rows],
        delay=np.concatenate(delays),
        amplitude=paths.amplitude[rows] * np.concatenate(scales)[:, None],
        knots=paths.knots,
        kind=np.full(rows.size, SCATTERED, np.int64),
        order=paths.order[rows],
        faces=paths.faces[rows],
        aod=paths.aod[rows],
        aoa=paths.aoa[rows],
        n_transmissions=paths.n_transmissions[rows],
    )


class HybridChannel:
    """One realization of the hybrid channel in a room.

    Parameters
    ----------
    room : Room
    config : HybridConfig
    rng : numpy.random.Generator
        Draws the surface scatterer field once, at construction (the realization).
    """

    def __init__(self, room: Room, config: HybridConfig, rng: np.random.Generator) -> None:
        self.room = room
        self.config = config
        self.clusters = draw_clusters(config.n_table, config.n_scatterers, config.radius, rng)
        self._sees = face_visibility(room)

    @property
    def knots(self) -> npt.NDArray[np.float64]:
        """Amplitude knots, Hz, shape (B,)."""
        return np.asarray(self.config.knots, float)

    def paths(
        self,
        tx: AntennaArray,
        rx: AntennaArray,
        *,
        scatterers: bool = True,
        tx_yaw: np.ndarray | None = None,
    ) -> PathSet:
        """All paths Tx -> each Rx: specular, diffracted and (if enabled) scattered.

        Parameters
        ----------
        tx : AntennaArray
            One transmitter.
        rx : AntennaArray
            R receivers (``PathSet.rx`` indexes them).
        scatterers : bool
            Include the stochastic clusters (False: pure ray tracing).
        tx_yaw : ndarray, shape (R,), optional
            Transmitter boresight per receiver (see :func:`~sim_nodes.channel.raytrace.trace`).
        """
        cfg = self.config
        det, geom = trace(
            self.room,
            tx,
            rx,
            self.knots,
            max_order=cfg.max_order,
            diffraction=cfg.diffraction,
            diffraction_strength=cfg.diffraction_strength,
            sees=self._sees,
            tx_yaw=tx_yaw,
        )
        if not scatterers or cfg.n_scatterers == 0 or cfg.scatter_order == 0:
            return det
        sc = scatterer_paths(self.room, det, geom, self.clusters, cfg)
        return PathSet.concat([det, sc], self.knots)
