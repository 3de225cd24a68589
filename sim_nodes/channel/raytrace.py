"""Deterministic part of the hybrid channel: 3-D ray tracing in a :class:`Room` (pure numpy).

Section 3 of the CoLOR chapter, the ray-tracing half of the hybrid model:

* **specular reflections** by the image method up to order 5: the transmitter is mirrored
  through every admissible face sequence (an image tree, pruned by "the image is on the
  reflecting side of the next face" and "the next face is at least partly in front of the
  previous one"); each receiver back-traces the sequence, and a path exists only if every
  reflection point lies inside its polygon;
* **visibility and transmission**: every leg is tested against all faces; a crossed face
  multiplies the amplitude by its material's one-way transmission factor (0 for metal, so
  metal blocks) and adds its excess length (slower propagation inside the slab);
* **diffraction** at vertical wedges (convex corners of solids, free wall ends), first order
  only, by a documented *edge-scattering* model rather than full UTD: the diffraction point
  lies on Keller's cone (for a vertical edge: where the unfolded path is straight) and the
  amplitude is that of a UTD-like spherical-wave edge term with a constant, angle-independent
  diffraction coefficient,

  .. math:: a_d = D(f) / \\sqrt{s_1 s_2 (s_1 + s_2)},
            \\quad D(f) = d_0 \\sqrt{\\lambda / (2 \\pi)}

  (``d_0`` dimensionless, default 0.5: the order of the UTD cotangent terms away from the
  shadow and reflection boundaries, whose singularities this simpler model does not have);
* **Fresnel reflection** from the complex permittivity, both polarizations, with the field
  vector carried through every bounce (:mod:`sim_nodes.channel.materials`); antennas are
  vertically polarized, so a vertical wall reflects mostly TE and floor/ceiling mostly TM;
* **antenna patterns** at both ends of every ray (:mod:`sim_nodes.channel.antenna`).

Amplitudes are complex, relative to a unit-gain link scaled ``1/d`` (the radar's
convention, no ``lambda / 4 pi``), evaluated at a few frequency *knots* and linearly
interpolated between them by :mod:`sim_nodes.channel.synth`: the geometry is computed once
per Tx/Rx configuration and reused for every frequency.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from sim_nodes.channel.antenna import AntennaPattern, OmniPattern, direction_angles
from sim_nodes.channel.materials import EPS0, fresnel
from sim_nodes.channel.room import Room, mirror_points, plane_dot, segment_face_hits
from sim_nodes.radar import C

#: Path kinds.
LOS, REFLECTED, DIFFRACTED, SCATTERED = 0, 1, 2, 3

_EPS = 1e-9
_CHUNK = 200_000  # (sequence, receiver) pairs per back-tracing chunk: bounds memory


@dataclass(frozen=True, slots=True, kw_only=True)
class AntennaArray:
    """Antennas of one side of a link, in world coordinates.

    Attributes
    ----------
    position : ndarray, float64, shape (A, 3)
        World positions, m.
    yaw : ndarray, float64, shape (A,)
        World yaw of each boresight, rad (boresights are horizontal).
    pattern : AntennaPattern
        Amplitude pattern shared by the antennas.
    """

    position: npt.NDArray[np.float64]
    yaw: npt.NDArray[np.float64]
    pattern: AntennaPattern = field(default_factory=OmniPattern)


@dataclass(frozen=True, slots=True, kw_only=True)
class PathSet:
    """A list of P propagation paths from one transmitter to R receivers.

    Attributes
    ----------
    rx : ndarray, int, shape (P,)
        Receiver index of each path.
    delay : ndarray, float64, shape (P,)
        Propagation delay, s.
    amplitude : ndarray, complex128, shape (P, B)
        Complex amplitude at the frequency knots (``1/d`` scale, antennas included).
    knots : ndarray, float64, shape (B,)
        Frequencies of the amplitude columns, Hz.
    kind : ndarray, int, shape (P,)
        LOS, REFLECTED, DIFFRACTED or SCATTERED.
    order : ndarray, int, shape (P,)
        Number of reflections of the (underlying specular) path.
    faces : ndarray, int, shape (P, K)
        Faces of the reflections in order, -1 padded (K = max order, at least 1). For a
        diffracted path ``faces[:, 0]`` is the wedge index.
    aod, aoa : ndarray, float64, shape (P, 2)
        World azimuth and elevation of departure (from Tx) and of arrival (the direction
        from the receiver towards the incoming ray), rad.
    n_transmissions : ndarray, int, shape (P,)
        Number of faces crossed.
    """

    rx: npt.NDArray[np.int64]
    delay: npt.NDArray[np.float64]
    amplitude: npt.NDArray[np.complex128]
    knots: npt.NDArray[np.float64]
    kind: npt.NDArray[np.int64]
    order: npt.NDArray[np.int64]
    faces: npt.NDArray[np.int64]
    aod: npt.NDArray[np.float64]
    aoa: npt.NDArray[np.float64]
    n_transmissions: npt.NDArray[np.int64]

    @property
    def count(self) -> int:
        """Number of paths P."""
        return int(self.delay.shape[0])

    def select(self, mask: np.ndarray) -> PathSet:
        """The paths where ``mask`` is true."""
        return PathSet(
            rx=self.rx[mask],
            delay=self.delay[mask],
            amplitude=self.amplitude[mask],
            knots=self.knots,
            kind=self.kind[mask],
            order=self.order[mask],
            faces=self.faces[mask],
            aod=self.aod[mask],
            aoa=self.aoa[mask],
            n_transmissions=self.n_transmissions[mask],
        )

    @classmethod
    def concat(cls, parts: list[PathSet], knots: np.ndarray) -> PathSet:
        """Concatenate path sets with the same knots (faces padded to the widest)."""
        k = max([p.faces.shape[1] for p in parts] + [1])

        def pad(f: np.ndarray) -> np.ndarray:
            return np.pad(f, ((0, 0), (0, k - f.shape[1])), constant_values=-1)

        return cls(
            rx=np.concatenate([p.rx for p in parts]).astype(np.int64),
            delay=np.concatenate([p.delay for p in parts]),
            amplitude=np.concatenate([p.amplitude for p in parts]).reshape(-1, knots.size),
            knots=knots,
            kind=np.concatenate([p.kind for p in parts]).astype(np.int64),
            order=np.concatenate([p.order for p in parts]).astype(np.int64),
            faces=np.concatenate([pad(p.faces) for p in parts]).astype(np.int64),
            aod=np.concatenate([p.aod for p in parts]).reshape(-1, 2),
            aoa=np.concatenate([p.aoa for p in parts]).reshape(-1, 2),
            n_transmissions=np.concatenate([p.n_transmissions for p in parts]).astype(np.int64),
        )


@dataclass(frozen=True, slots=True, kw_only=True)
class SpecularGeometry:
    """Geometry of the specular paths of one order k, for the scatterer clusters.

    Attributes
    ----------
    index : ndarray, int, shape (n,)
        Row of each path in the returned :class:`PathSet`.
    sequence : ndarray, int, shape (n, k)
        Reflecting faces in order.
    points : ndarray, float64, shape (n, k, 3)
        Reflection points, world, m.
    tx_images : ndarray, float64, shape (n, k, 3)
        ``tx_images[:, m]``: the transmitter mirrored through the first ``m`` faces
        (``m = 0``: the transmitter itself).
    rx_images : ndarray, float64, shape (n, k, 3)
        ``rx_images[:, m]``: the receiver mirrored through faces ``k-1 .. m+1`` (``m = k-1``:
        the receiver itself).
    length : ndarray, float64, shape (n,)
        Geometric (unfolded) length, m.
    """

    index: npt.NDArray[np.int64]
    sequence: npt.NDArray[np.int64]
    points: npt.NDArray[np.float64]
    tx_images: npt.NDArray[np.float64]
    rx_images: npt.NDArray[np.float64]
    length: npt.NDArray[np.float64]


def face_visibility(room: Room) -> npt.NDArray[np.bool_]:
    """``sees[w, f]``: a ray reflected by face ``w`` can reach face ``f`` next.

    False on the diagonal, for coplanar faces, and when ``f`` lies wholly behind a
    one-sided ``w`` (or ``w`` wholly behind a one-sided ``f``). Shape (F, F).
    """
    # Signed distance of every vertex of f from the plane of w: (W, F, V).
    side = np.einsum("wk,fvk->wfv", room.normal, room.vertices) - room.offset[:, None, None]
    front = np.any(side > 1e-6, axis=-1)  # some vertex of f in front of w
    off_plane = np.any(np.abs(side) > 1e-6, axis=-1)
    ok = (room.two_sided[:, None] | front) & (room.two_sided[None, :] | front.T)
    ok &= off_plane & off_plane.T
    np.fill_diagonal(ok, False)
    return ok


def image_tree(
    room: Room, tx: np.ndarray, max_order: int, sees: np.ndarray | None = None
) -> list[tuple[np.ndarray, np.ndarray]]:
    """Admissible reflection sequences and transmitter images, per order 1..max_order.

    .. math:: T_m = T_{m-1} - 2 (n_{w_m} \\cdot T_{m-1} - d_{w_m}) n_{w_m}

    Parameters
    ----------
    room : Room
    tx : ndarray, float64, shape (3,)
        Transmitter position, world, m.
    max_order : int
    sees : ndarray, bool, shape (F, F), optional
        :func:`face_visibility` (computed if omitted).

    Returns
    -------
    list of (sequence, images)
        For order k: ``sequence`` int (S_k, k) and ``images`` float64 (S_k, k + 1, 3), with
        ``images[:, m]`` the transmitter mirrored through the first m faces.
    """
    if sees is None:
        sees = face_visibility(room)
    out = []
    seq = np.zeros((1, 0), np.int64)
    imgs = np.asarray(tx, float)[None, None, :]
    for _ in range(max_order):
        if seq.shape[0] == 0 or room.n_faces == 0:
            out.append(
                (np.zeros((0, seq.shape[1] + 1), np.int64), np.zeros((0, imgs.shape[1] + 1, 3)))
            )
            continue
        last = imgs[:, -1]
        side = plane_dot(last, room.normal) - room.offset  # (S, F)
        ok = np.where(room.two_sided, np.abs(side) > _EPS, side > _EPS)
        if seq.shape[1]:
            ok &= sees[seq[:, -1]]
        s_i, f_i = np.nonzero(ok)
        new = mirror_points(last[s_i], room.normal[f_i], room.offset[f_i])
        seq = np.concatenate([seq[s_i], f_i[:, None]], axis=1)
        imgs = np.concatenate([imgs[s_i], new[:, None]], axis=1)
        out.append((seq, imgs))
    return out


def _back_trace(
    room: Room, seq: np.ndarray, imgs: np.ndarray, rx: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Valid (sequence, receiver) pairs of one order and their reflection points.

    Returns ``s_idx`` (n,), ``r_idx`` (n,), ``points`` (n, k, 3).
    """
    n_seq, k = seq.shape
    n_rx = rx.shape[0]
    out_s, out_r, out_p = [np.zeros(0, np.int64)], [np.zeros(0, np.int64)], [np.zeros((0, k, 3))]
    # The last bounce is tested for every (sequence, receiver) pair, so it is done on scalar
    # projections: with n.x and E.x (edge planes) of images and receivers precomputed, a pair
    # costs a few products instead of 3-vector arithmetic. Most pairs fail here.
    n_rx_dot = plane_dot(rx, room.normal)  # (R, F)
    e_rx_dot = np.einsum("fvk,rk->fvr", room.edge_plane, rx)  # (F, V, R)
    n_v = room.edge_plane.shape[1]
    step = max(1, _CHUNK // max(n_rx * n_v, 1))
    for c0 in range(0, n_seq, step):
        sl = slice(c0, min(c0 + step, n_seq))
        f = seq[sl, k - 1]
        img = imgs[sl, k]
        n_img = np.sum(room.normal[f] * img, axis=1)  # (s,)
        den = n_rx_dot[:, f].T - n_img[:, None]  # (s, R)
        with np.errstate(divide="ignore", invalid="ignore"):
            u = (room.offset[f] - n_img)[:, None] / den
        ok = (np.abs(den) > 1e-12) & (u > _EPS) & (u < 1 - _EPS)
        u = np.where(ok, u, 0.0)
        e_img = np.einsum("svk,sk->sv", room.edge_plane[f], img)  # (s, V)
        lhs = e_img[:, :, None] + u[:, None, :] * (e_rx_dot[f] - e_img[:, :, None])
        ok &= np.all(lhs >= room.edge_level[f][:, :, None] - 1e-9, axis=1)
        s_loc, r_idx = np.nonzero(ok)
        s_idx = s_loc + c0
        src = imgs[s_idx, k]
        target = src + u[s_loc, r_idx][:, None] * (rx[r_idx] - src)
        pts = np.empty((s_idx.size, k, 3))
        pts[:, k - 1] = target
        # The bounce before lies on the segment image_{k-1} -> that point, and so on; pairs
        # are dropped as soon as a point misses its polygon.
        for m in range(k - 2, -1, -1):
            f = seq[s_idx, m]
            src = imgs[s_idx, m + 1]
            d = target - src
            nrm = room.normal[f]
            den = np.sum(d * nrm, axis=1)
            with np.errstate(divide="ignore", invalid="ignore"):
                u = (room.offset[f] - np.sum(src * nrm, axis=1)) / den
            ok = (np.abs(den) > 1e-12) & (u > _EPS) & (u < 1 - _EPS)
            x = src + np.where(ok, u, 0.0)[:, None] * d
            ok &= room.contains(f, x)
            s_idx, r_idx, target, pts = s_idx[ok], r_idx[ok], x[ok], pts[ok]
            pts[:, m] = target
        out_s.append(s_idx)
        out_r.append(r_idx)
        out_p.append(pts)
    return np.concatenate(out_s), np.concatenate(out_r), np.concatenate(out_p).reshape(-1, k, 3)


def _unit(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    n = np.linalg.norm(v, axis=-1)
    return v / np.maximum(n, 1e-300)[..., None], n


def vertical_polarization(k: np.ndarray) -> np.ndarray:
    """Unit polarization of a vertical antenna for propagation direction(s) ``k`` (..., 3).

    ``z`` projected perpendicular to ``k`` and normalised; zero along the vertical, where
    a vertical antenna does not radiate.
    """
    z = np.zeros_like(k)
    z[..., 2] = 1.0
    p = z - k[..., 2:3] * k
    n = np.linalg.norm(p, axis=-1, keepdims=True)
    return np.where(n > 1e-9, p / np.maximum(n, 1e-300), 0.0)


def _legs_transmission(
    room: Room, chain: np.ndarray, seq: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Transmission factor, excess length and crossings of every leg of paths (n, k+2, 3)."""
    n, k2 = chain.shape[:2]
    k = k2 - 2
    trans = np.ones(n)
    excess = np.zeros(n)
    count = np.zeros(n, np.int64)
    if room.n_faces == 0:
        return trans, excess, count
    t_face, e_face = room.transmission, room.excess
    alive = np.arange(n)
    for j in range(k + 1):
        if alive.size == 0:
            break
        hits = segment_face_hits(room, chain[alive, j], chain[alive, j + 1])
        # A leg starts/ends on its reflecting faces: those are not crossings (-1: none,
        # e.g. at a diffracting wedge).
        for col in (j - 1, j):
            if 0 <= col < k:
                f = seq[alive, col]
                rows = np.nonzero(f >= 0)[0]
                hits[rows, f[rows]] = False
        trans[alive] *= np.prod(np.where(hits, t_face, 1.0), axis=1)
        excess[alive] += np.where(hits, e_face, 0.0).sum(axis=1)
        count[alive] += hits.sum(axis=1)
        alive = alive[trans[alive] > 0]  # blocked paths (metal) need no further legs
    return trans, excess, count


def _reflection_factors(
    room: Room, faces: np.ndarray, cos_theta: np.ndarray, knots: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """TE and TM coefficients (n, B) of reflections on ``faces`` (n,) at ``cos_theta``."""
    perm = np.array([m.permittivity for m in room.materials])[room.material[faces]]
    cond = np.array([m.conductivity for m in room.materials])[room.material[faces]]
    metal = np.array([m.metal for m in room.materials], bool)[room.material[faces]]
    eps = perm[:, None] - 1j * cond[:, None] / (2 * np.pi * knots[None, :] * EPS0)
    te, tm = fresnel(eps, cos_theta[:, None])
    te = np.where(metal[:, None], -1.0 + 0j, te)
    tm = np.where(metal[:, None], 1.0 + 0j, tm)
    return te, tm


def _world_angles(vec: np.ndarray) -> np.ndarray:
    az, el = direction_angles(vec, 0.0)
    return np.stack([az, el], axis=-1)


def _specular_order(
    room: Room,
    tx: AntennaArray,
    rx: AntennaArray,
    seq: np.ndarray,
    imgs: np.ndarray,
    knots: np.ndarray,
    tx_yaw: np.ndarray,
) -> tuple[PathSet, SpecularGeometry]:
    k = seq.shape[1]
    if k == 0:
        s_idx = np.zeros(rx.position.shape[0], np.int64)
        r_idx = np.arange(rx.position.shape[0])
        pts = np.zeros((r_idx.size, 0, 3))
    else:
        s_idx, r_idx, pts = _back_trace(room, seq, imgs, rx.position)
    sq = seq[s_idx]
    n = r_idx.size
    chain = np.concatenate(
        [np.broadcast_to(tx.position[0], (n, 1, 3)), pts, rx.position[r_idx][:, None]], axis=1
    )
    trans, excess, n_trans = _legs_transmission(room, chain, sq)
    keep = trans > 0
    sq, s_idx, r_idx, pts, chain = sq[keep], s_idx[keep], r_idx[keep], pts[keep], chain[keep]
    trans, excess, n_trans = trans[keep], excess[keep], n_trans[keep]
    n = r_idx.size
    dirs, seg = _unit(np.diff(chain, axis=1))  # (n, k+1, 3), (n, k+1)
    length = seg.sum(axis=1)
    # Field vector carried through the bounces (module docstring), per knot.
    e = np.broadcast_to(vertical_polarization(dirs[:, 0])[:, None, :], (n, knots.size, 3))
    e = e.astype(complex)
    for m in range(k):
        k_in, k_out = dirs[:, m], dirs[:, m + 1]
        nrm = room.normal[sq[:, m]]
        s, s_norm = _unit(np.cross(k_in, nrm))
        # Normal incidence: any s perpendicular to k_in works (TE and TM then agree).
        alt, _ = _unit(
            np.cross(k_in, np.where(np.abs(k_in[:, 2:3]) < 0.9, [0, 0, 1.0], [1.0, 0, 0]))
        )
        s = np.where((s_norm > 1e-9)[:, None], s, alt)
        p_in, p_out = np.cross(s, k_in), np.cross(s, k_out)
        te, tm = _reflection_factors(room, sq[:, m], np.abs(np.sum(k_in * nrm, axis=1)), knots)
        e_s = np.einsum("nbk,nk->nb", e, s)
        e_p = np.einsum("nbk,nk->nb", e, p_in)
        e = (te * e_s)[..., None] * s[:, None, :] + (tm * e_p)[..., None] * p_out[:, None, :]
    pol = np.einsum("nbk,nk->nb", e, vertical_polarization(dirs[:, -1]))
    az_t, el_t = direction_angles(dirs[:, 0], tx_yaw[r_idx])
    az_r, el_r = direction_angles(-dirs[:, -1], rx.yaw[r_idx])
    gain = tx.pattern.amplitude(az_t[:, None], el_t[:, None], knots) * rx.pattern.amplitude(
        az_r[:, None], el_r[:, None], knots
    )
    amp = pol * gain * (trans / np.maximum(length, 1e-3))[:, None]
    paths = PathSet(
        rx=r_idx,
        delay=(length + excess) / C,
        amplitude=amp,
        knots=knots,
        kind=np.full(n, LOS if k == 0 else REFLECTED, np.int64),
        order=np.full(n, k, np.int64),
        faces=sq if k else np.full((n, 1), -1, np.int64),
        aod=_world_angles(dirs[:, 0]),
        aoa=_world_angles(-dirs[:, -1]),
        n_transmissions=n_trans,
    )
    # Receiver images through faces k-1 .. m+1 for the scatterer clusters.
    rx_img = np.empty((n, k, 3))
    if k:
        cur = rx.position[r_idx]
        for m in range(k - 1, -1, -1):
            rx_img[:, m] = cur
            f = sq[:, m]
            cur = mirror_points(cur, room.normal[f], room.offset[f])
    geom = SpecularGeometry(
        index=np.arange(n, dtype=np.int64),
        sequence=sq,
        points=pts,
        tx_images=imgs[s_idx, :k] if k else np.zeros((n, 0, 3)),
        rx_images=rx_img,
        length=length,
    )
    return paths, geom


def _diffraction(
    room: Room,
    tx: AntennaArray,
    rx: AntennaArray,
    knots: np.ndarray,
    strength: float,
    tx_yaw: np.ndarray,
) -> PathSet:
    n_w, n_rx = room.wedge_xy.shape[0], rx.position.shape[0]
    w_idx = np.repeat(np.arange(n_w), n_rx)
    r_idx = np.tile(np.arange(n_rx), n_w)
    t = tx.position[0]
    r = rx.position[r_idx]
    xy = room.wedge_xy[w_idx]
    h1 = np.linalg.norm(xy - t[:2], axis=1)
    h2 = np.linalg.norm(xy - r[:, :2], axis=1)
    ok = (h1 > 1e-6) & (h2 > 1e-6)
    # Keller's cone for a vertical edge: the unfolded path is straight in (h, z).
    z = t[2] + (r[:, 2] - t[2]) * h1 / np.maximum(h1 + h2, 1e-300)
    ok &= (z >= room.wedge_z[w_idx, 0]) & (z <= room.wedge_z[w_idx, 1])
    w_idx, r_idx, r, z, xy = w_idx[ok], r_idx[ok], r[ok], z[ok], xy[ok]
    d = np.concatenate([xy, z[:, None]], axis=1)
    n = w_idx.size
    chain = np.stack([np.broadcast_to(t, (n, 3)), d, r], axis=1)
    trans, excess, n_trans = _legs_transmission(room, chain, np.full((n, 1), -1, np.int64))
    keep = trans > 0
    chain, w_idx, r_idx = chain[keep], w_idx[keep], r_idx[keep]
    trans, excess, n_trans = trans[keep], excess[keep], n_trans[keep]
    dirs, seg = _unit(np.diff(chain, axis=1))
    s1, s2 = seg[:, 0], seg[:, 1]
    coef = strength * np.sqrt(C / knots / (2 * np.pi))  # D(f), sqrt(m)
    pol = np.sum(vertical_polarization(dirs[:, 0]) * vertical_polarization(dirs[:, 1]), axis=1)
    az_t, el_t = direction_angles(dirs[:, 0], tx_yaw[r_idx])
    az_r, el_r = direction_angles(-dirs[:, 1], rx.yaw[r_idx])
    gain = tx.pattern.amplitude(az_t[:, None], el_t[:, None], knots) * rx.pattern.amplitude(
        az_r[:, None], el_r[:, None], knots
    )
    amp = (pol * trans / np.sqrt(s1 * s2 * (s1 + s2)))[:, None] * coef[None, :] * gain
    return PathSet(
        rx=r_idx,
        delay=(s1 + s2 + excess) / C,
        amplitude=amp.astype(complex),
        knots=knots,
        kind=np.full(r_idx.size, DIFFRACTED, np.int64),
        order=np.zeros(r_idx.size, np.int64),
        faces=w_idx[:, None],
        aod=_world_angles(dirs[:, 0]),
        aoa=_world_angles(-dirs[:, 1]),
        n_transmissions=n_trans,
    )


def trace(
    room: Room,
    tx: AntennaArray,
    rx: AntennaArray,
    knots: npt.ArrayLike,
    *,
    max_order: int = 3,
    diffraction: bool = True,
    diffraction_strength: float = 0.5,
    sees: np.ndarray | None = None,
    tx_yaw: np.ndarray | None = None,
) -> tuple[PathSet, list[SpecularGeometry]]:
    """All deterministic paths from one transmitter to R receivers.

    Parameters
    ----------
    room : Room
    tx : AntennaArray
        One transmitting antenna (A = 1).
    rx : AntennaArray
        R receiving antennas.
    knots : array_like, float, shape (B,)
        Frequencies at which amplitudes are evaluated, Hz.
    max_order : int
        Highest reflection order, 0..5.
    diffraction : bool
        Add first-order wedge diffraction.
    diffraction_strength : float
        ``d_0`` of the edge-scattering model (module docstring).
    sees : ndarray, bool, shape (F, F), optional
        Precomputed :func:`face_visibility` of ``room``.
    tx_yaw : ndarray, float64, shape (R,), optional
        Transmitter boresight while receiver r records, rad (a robot turning on the spot
        about its Tx: one trace serves all headings). Default ``tx.yaw[0]`` for all.

    Returns
    -------
    paths : PathSet
    geometry : list of SpecularGeometry
        One per reflection order 1..max_order (``index`` refers to rows of ``paths``).
    """
    knots = np.atleast_1d(np.asarray(knots, float))
    n_rx = rx.position.shape[0]
    yaw_t = np.full(n_rx, tx.yaw[0]) if tx_yaw is None else np.asarray(tx_yaw, float)
    tree = image_tree(room, tx.position[0], max_order, sees)
    zero = (np.zeros((1, 0), np.int64), tx.position[0][None, None, :])
    parts, geoms, offset = [], [], 0
    for seq, imgs in [zero, *tree]:
        p, g = _specular_order(room, tx, rx, seq, imgs, knots, yaw_t)
        if seq.shape[1]:
            geoms.append(
                SpecularGeometry(
                    index=g.index + offset,
                    sequence=g.sequence,
                    points=g.points,
                    tx_images=g.tx_images,
                    rx_images=g.rx_images,
                    length=g.length,
                )
            )
        parts.append(p)
        offset += p.count
    if diffraction and room.wedge_xy.shape[0]:
        parts.append(_diffraction(room, tx, rx, knots, diffraction_strength, yaw_t))
    return PathSet.concat(parts, knots), geoms
