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
of a cluster is bounded by ``N (a + p r)^2 |a_i|^2``. Scatterers are not clipped to the
face's polygon by rejection-resampling: those falling off the face are dropped, so a
cluster on a small face has fewer than N.

**Realization.** The offsets of the scatterers (in the face's plane frame) are drawn once per
realization, seeded, in a table of ``n_table`` clusters; a cluster is selected by a hash of
the reflection sequence and the bounce index. The same specular path therefore keeps the
same cluster (moving with its reflection point) for every Tx/Rx position of the
realization, as the chapter reuses one draw for all positions.

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
        Number of scatterer clusters drawn per realization.
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
    """Scatterer offsets uniform on a disc of ``radius``, shape (n_table, n, 2), m.

    Uniform in area: ``rho = r sqrt(U_1)``, ``phi = 2 pi U_2``.
    """
    rho = radius * np.sqrt(rng.random((n_table, n)))
    phi = 2 * np.pi * rng.random((n_table, n))
    return np.stack([rho * np.cos(phi), rho * np.sin(phi)], axis=-1)


def cluster_index(sequence: np.ndarray, bounce: int, n_table: int) -> npt.NDArray[np.int64]:
    """Table row of the cluster at bounce ``bounce`` of each reflection sequence (n, k)."""
    k = sequence.shape[1]
    h = (sequence + 1) @ _HASH_PRIMES[:k] + (bounce + 1) * 2654435761 + k * 97
    return np.remainder(h, n_table).astype(np.int64)


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
    clusters : ndarray, float64, shape (n_table, N, 2)
        Offsets from :func:`draw_clusters`, m.
    config : HybridConfig

    Returns
    -------
    PathSet
        ``kind == SCATTERED``; other attributes those of the parent specular path.
    """
    k0 = 2 * np.pi * config.center_frequency / C
    # Eq. (1) without Gamma depends only on the offsets: evaluate it once on the table.
    delta = np.linalg.norm(clusters, axis=-1)  # (n_table, N)
    table_scale = (config.a + config.p * delta) * np.exp(-1j * k0 * delta)
    parent_rows, delays, scales = [], [], []
    for g in geometry:
        k = g.sequence.shape[1]
        if k > config.scatter_order or g.index.size == 0 or clusters.shape[1] == 0:
            continue
        excess = paths.delay[g.index] - g.length / C  # through-wall excess of the parent
        for m in range(k):
            face = g.sequence[:, m]
            cluster = cluster_index(g.sequence, m, clusters.shape[0])
            offs = clusters[cluster]  # (n, N, 2)
            # Scatterers that fall off the face are not on the surface: dropped. In the
            # face's plane the edge test is linear: E.(X + o) = E.X + E.o.
            axes = np.stack([room.axis_u[face], room.axis_v[face]], axis=1)  # (n, 2, 3)
            plane = room.edge_plane[face]  # (n, V, 3)
            at_point = np.einsum("nvk,nk->nv", plane, g.points[:, m])
            along = np.einsum("nvk,njk->nvj", plane, axes)  # (n, V, 2)
            lhs = at_point[:, None, :] + np.einsum("nvj,nsj->nsv", along, offs)
            on_face = np.all(lhs >= room.edge_level[face][:, None, :] - 1e-9, axis=-1)
            row, col = np.nonzero(on_face)
            o = offs[row, col]
            q = g.points[row, m] + o[:, :1] * axes[row, 0] + o[:, 1:] * axes[row, 1]
            length = np.linalg.norm(q - g.tx_images[row, m], axis=-1) + np.linalg.norm(
                q - g.rx_images[row, m], axis=-1
            )
            parent_rows.append(g.index[row])
            delays.append(length / C + excess[row])
            scales.append(table_scale[cluster[row], col] * (g.length[row] / length))
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
        Draws the scatterer clusters once, at construction (the realization).
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
