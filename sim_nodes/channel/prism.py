"""Polarimetric echoes of a prism with a polygonal cross-section (Section 7 circular scans).

A fast geometric (ray) model of what a bat-type sensor sees when it circles one object at
short range, in the horizontal plane of the sensor (2-D: the object is a vertical prism much
taller than the first Fresnel zone, so spreading is that of the image source). Echo types:

* **face** (plate): bistatic specular reflection by the image method; the scattering matrix
  in the V/H basis (V vertical, parallel to the prism's edges = TE; H horizontal = TM) is
  ``diag(Gamma_TE, -Gamma_TM)`` (Fresnel, :func:`sim_nodes.channel.materials.fresnel`; the
  minus sign is the back-scatter alignment convention, so a metal plate gives ``-I``);
* **wedge** (convex corner): edge diffraction, amplitude
  ``c_d sqrt(lambda_0 / 2 pi) / sqrt(d_1 d_2 (d_1 + d_2))`` with different soft (V) and hard
  (H) coefficients, so a corner depolarizes in the 45-degree basis;
* **dihedral** (concave 90-degree corner of an L or T): double bounce, the transmitter mirrored
  through the vertex, ``diag(Gamma_TE1 Gamma_TE2, -Gamma_TM1 Gamma_TM2)`` (metal ``diag(1, -1)``:
  pure cross-polarization in the 45-degree basis, Section 7.6 of the CoLOR chapter);
* **facet** (rough bulk surface): seeded point facets on each face with random 2x2 scattering
  matrices (co and cross), scaled by ``roughness``: the depolarization of rough surfaces.

Occlusion by the prism itself is checked for every leg, so non-convex shapes shadow parts of
themselves. Everything is vectorised over sensor positions and echoes; pure numpy.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from sim_nodes.channel.materials import complex_permittivity, fresnel

C = 299792458.0

#: Echo kinds (index into :attr:`PrismEchoes.kind`).
FACE, WEDGE, DIHEDRAL, FACET = 0, 1, 2, 3


@dataclass(frozen=True, slots=True, kw_only=True)
class PrismTarget:
    """A vertical prism over a simple polygon.

    Attributes
    ----------
    vertices : ndarray, float64, shape (V, 2)
        Cross-section polygon in world x, y (m), counter-clockwise, not closed.
    permittivity, conductivity : float
        Relative permittivity and conductivity (S/m) of the bulk material.
    metal : bool
        Perfect conductor (overrides permittivity).
    roughness : float
        RMS amplitude of the facet scatterers relative to a smooth face (0: smooth).
    facets_per_metre : float
        Density of facet scatterers along the faces (only with ``roughness > 0``).
    diffraction : float
        Wedge diffraction strength ``c_d`` (dimensionless).
    seed : int
        Seed of the facet positions and scattering matrices (a surface is one realisation).
    """

    vertices: npt.NDArray[np.float64]
    permittivity: float = 1.0
    conductivity: float = 0.0
    metal: bool = True
    roughness: float = 0.0
    facets_per_metre: float = 60.0
    diffraction: float = 0.5
    seed: int = 0
    _facets: tuple[np.ndarray, np.ndarray, np.ndarray] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        v = np.asarray(self.vertices, float)
        if v.ndim != 2 or v.shape[1] != 2 or len(v) < 3:
            raise ValueError("vertices must be (V >= 3, 2)")
        area = 0.5 * np.sum(v[:, 0] * np.roll(v[:, 1], -1) - np.roll(v[:, 0], -1) * v[:, 1])
        if area < 0:
            v = v[::-1].copy()
        object.__setattr__(self, "vertices", v)
        rng = np.random.default_rng(self.seed)
        a, b = v, np.roll(v, -1, axis=0)
        lengths = np.linalg.norm(b - a, axis=1)
        n_per = np.ceil(lengths * self.facets_per_metre).astype(int) if self.roughness else 0
        edge = np.repeat(np.arange(len(v)), n_per)
        s = rng.uniform(0.02, 0.98, len(edge))
        pts = a[edge] + s[:, None] * (b - a)[edge]
        # Random facet scattering matrices: co-polar N(0,1), cross-polar N(0, 0.5^2).
        mats = rng.standard_normal((len(edge), 2, 2))
        mats[:, 0, 1] *= 0.5
        mats[:, 1, 0] = mats[:, 0, 1]  # reciprocity: S_VH = S_HV
        mats *= self.roughness / np.sqrt(max(self.facets_per_metre, 1.0) * 0.05)
        object.__setattr__(self, "_facets", (pts, edge, mats))

    def reflection(self, cos_theta: np.ndarray, f: float = 3e9) -> tuple[np.ndarray, np.ndarray]:
        """Real Fresnel ``Gamma_TE, Gamma_TM`` at the incidence cosines (metal: -1, +1)."""
        if self.metal:
            return -np.ones_like(cos_theta), np.ones_like(cos_theta)
        eps = complex_permittivity(self.permittivity, self.conductivity, f)
        te, tm = fresnel(eps, cos_theta)
        return np.real(te), np.real(tm)


@dataclass(frozen=True, slots=True, kw_only=True)
class PrismEchoes:
    """Echoes of a prism at a set of sensor positions.

    Attributes
    ----------
    length : ndarray, float64, shape (P, E)
        Bistatic path length Tx -> object -> Rx, m (NaN: no such echo at that position).
    scattering : ndarray, float64, shape (P, E, 2, 2)
        Amplitude scattering matrix in the V/H basis, ``[rx_pol, tx_pol]`` (0 = V, 1 = H),
        including spreading and antenna gains (zero where absent).
    point : ndarray, float64, shape (P, E, 2)
        Scattering point (specular point, vertex or facet), world x, y, m.
    kind : ndarray, int, shape (E,)
        FACE, WEDGE, DIHEDRAL or FACET.
    """

    length: npt.NDArray[np.float64]
    scattering: npt.NDArray[np.float64]
    point: npt.NDArray[np.float64]
    kind: npt.NDArray[np.int64]


def _cross2(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def _blocked(
    p: np.ndarray, q: np.ndarray, a: np.ndarray, b: np.ndarray, tol: float = 1e-6
) -> np.ndarray:
    """Whether segments p-q (..., 2) properly cross any polygon edge a-b (V, 2); (...) bool.

    Touching an edge at an end point (the scattering point itself) does not count.
    """
    d = (q - p)[..., None, :]
    e = b - a
    denom = _cross2(d, e)
    w = a - p[..., None, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = _cross2(w, e) / denom
        u = _cross2(w, d) / denom
    hit = (np.abs(denom) > 1e-12) & (t > tol) & (t < 1 - tol) & (u > tol) & (u < 1 - tol)
    return hit.any(axis=-1)


def horn_gain(direction: np.ndarray, boresight: np.ndarray, beamwidth: float) -> np.ndarray:
    """Gaussian horn amplitude pattern: 1 on boresight, -3 dB (power) at half the beamwidth.

    Parameters
    ----------
    direction, boresight : ndarray, shape (..., 2)
        World directions (need not be unit).
    beamwidth : float
        3 dB beamwidth, rad (2 pi: omni).
    """
    if beamwidth >= 2 * np.pi:
        return np.ones(direction.shape[:-1])
    cosang = np.sum(direction * boresight, axis=-1) / (
        np.linalg.norm(direction, axis=-1) * np.linalg.norm(boresight, axis=-1) + 1e-300
    )
    ang = np.arccos(np.clip(cosang, -1.0, 1.0))
    return np.exp(-0.5 * np.log(2.0) * (ang / (beamwidth / 2)) ** 2)


def prism_echoes(
    target: PrismTarget,
    tx: npt.ArrayLike,
    rx: npt.ArrayLike,
    boresight: npt.ArrayLike,
    *,
    beamwidth: float = np.deg2rad(70.0),
    wavelength: float = 0.15,
) -> PrismEchoes:
    """Face, wedge, dihedral and facet echoes of ``target`` for a quasi-monostatic sensor.

    Parameters
    ----------
    target : PrismTarget
    tx, rx : array_like, float, shape (P, 2)
        World x, y of the transmitting and receiving antenna at each sensor position, m.
    boresight : array_like, float, shape (P, 2)
        World boresight direction of both antennas.
    beamwidth : float
        3 dB beamwidth of the (horn) antennas, rad.
    wavelength : float
        Reference wavelength ``lambda_0`` of the diffraction amplitude, m.

    Returns
    -------
    PrismEchoes
        ``E = V faces + V vertices + facets`` echo slots per position.
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        return _prism_echoes(
            target,
            np.asarray(tx, float),
            np.asarray(rx, float),
            np.asarray(boresight, float),
            beamwidth,
            wavelength,
        )


def _prism_echoes(
    target: PrismTarget,
    tx: np.ndarray,
    rx: np.ndarray,
    bs: np.ndarray,
    beamwidth: float,
    wavelength: float,
) -> PrismEchoes:
    v = target.vertices
    nv = len(v)
    a, b = v, np.roll(v, -1, axis=0)
    e = b - a
    seg_len = np.linalg.norm(e, axis=1)
    u = e / seg_len[:, None]
    normal = np.column_stack([u[:, 1], -u[:, 0]])  # outward for a CCW polygon

    # --- faces: image method ---
    dt = np.einsum("pk,vk->pv", tx, normal) - np.sum(a * normal, axis=1)
    dr = np.einsum("pk,vk->pv", rx, normal) - np.sum(a * normal, axis=1)
    tx_img = tx[:, None, :] - 2 * dt[..., None] * normal
    lam = dt / np.where(dt + dr > 0, dt + dr, np.inf)
    spec = tx_img + lam[..., None] * (rx[:, None, :] - tx_img)
    along = np.einsum("pvk,vk->pv", spec - a, u)
    face_len = np.linalg.norm(rx[:, None, :] - tx_img, axis=-1)
    face_ok = (dt > 0) & (dr > 0) & (along > 0) & (along < seg_len)
    cos_face = (dt + dr) / face_len
    te, tm = target.reflection(np.clip(cos_face, 0.0, 1.0))
    face_s = np.zeros((*dt.shape, 2, 2))
    face_s[..., 0, 0] = te
    face_s[..., 1, 1] = -tm
    face_s /= face_len[..., None, None]

    # --- vertices: wedge diffraction (convex) or dihedral double bounce (concave) ---
    prev_n = np.roll(normal, 1, axis=0)  # normal of the edge ending at each vertex
    convex = _cross2(np.roll(e, 1, axis=0), e) > 0
    d_t = tx[:, None, :] - v
    d_r = rx[:, None, :] - v
    dist_t = np.linalg.norm(d_t, axis=-1)
    dist_r = np.linalg.norm(d_r, axis=-1)
    side_prev = np.einsum("pvk,vk->pv", d_t, prev_n) > 0
    side_next = np.einsum("pvk,vk->pv", d_t, normal) > 0
    wedge_ok = convex & (side_prev | side_next)
    g_normal = np.abs(target.reflection(np.ones(1))[0][0])
    amp = (
        target.diffraction
        * g_normal
        * np.sqrt(wavelength / (2 * np.pi))
        / np.sqrt(dist_t * dist_r * (dist_t + dist_r))
    )
    vert_s = np.zeros((*dist_t.shape, 2, 2))
    # Soft (E parallel to the edge) and hard diffraction differ: the corner depolarizes.
    vert_s[..., 0, 0] = -amp
    vert_s[..., 1, 1] = -0.55 * amp
    # Concave 90-degree corner: the sensor must see into the dihedral (both faces lit).
    dihedral_ok = ~convex & side_prev & side_next
    tx_dbl = 2 * v - tx[:, None, :]
    dbl_len = np.linalg.norm(rx[:, None, :] - tx_dbl, axis=-1)
    cos1 = np.einsum("pvk,vk->pv", d_t, prev_n) / dist_t
    cos2 = np.einsum("pvk,vk->pv", d_t, normal) / dist_t
    te1, tm1 = target.reflection(np.clip(cos1, 0.0, 1.0))
    te2, tm2 = target.reflection(np.clip(cos2, 0.0, 1.0))
    # Aperture of the dihedral seen from the sensor: largest at 45 degrees, none along a face.
    aperture = np.clip(2 * cos1 * cos2, 0.0, 1.0)
    dbl_s = np.zeros_like(vert_s)
    dbl_s[..., 0, 0] = te1 * te2 * aperture / dbl_len
    dbl_s[..., 1, 1] = -tm1 * tm2 * aperture / dbl_len
    vert_s = np.where(convex[None, :, None, None], vert_s, dbl_s)
    vert_len = np.where(convex, dist_t + dist_r, dbl_len)
    vert_ok = wedge_ok | dihedral_ok

    # --- facets of rough faces ---
    fpts, fedge, fmat = target._facets
    f_t = tx[:, None, :] - fpts
    f_r = rx[:, None, :] - fpts
    ft_d = np.linalg.norm(f_t, axis=-1)
    fr_d = np.linalg.norm(f_r, axis=-1)
    fcos = np.einsum("pfk,fk->pf", f_t, normal[fedge]) / np.maximum(ft_d, 1e-12)
    facet_ok = fcos > 0.05
    lobe = np.clip(fcos, 0.0, 1.0) ** 1.5 * np.sqrt(wavelength / (2 * np.pi))
    facet_s = fmat[None] * (g_normal * lobe / np.sqrt(ft_d * fr_d * (ft_d + fr_d)))[..., None, None]

    length = np.concatenate([face_len, vert_len, ft_d + fr_d], axis=1)
    point = np.concatenate(
        [spec, np.broadcast_to(v, (len(tx), nv, 2)), np.broadcast_to(fpts, (len(tx), *fpts.shape))],
        axis=1,
    )
    s = np.concatenate([face_s, vert_s, facet_s], axis=1)
    ok = np.concatenate([face_ok, vert_ok, facet_ok], axis=1)
    # Shadowing by the prism itself: both legs (for the dihedral, legs to the vertex).
    legs_ok = ~_blocked(np.broadcast_to(tx[:, None, :], point.shape), point, a, b) & ~_blocked(
        point, np.broadcast_to(rx[:, None, :], point.shape), a, b
    )
    ok &= legs_ok
    gain = horn_gain(point - tx[:, None, :], bs[:, None, :], beamwidth) * horn_gain(
        point - rx[:, None, :], bs[:, None, :], beamwidth
    )
    # Absent echoes may carry 0/0 from degenerate geometry (a sensor on an edge's line).
    s = np.where(ok[..., None, None], s * gain[..., None, None], 0.0)
    kind = np.concatenate(
        [
            np.full(nv, FACE),
            np.where(convex, WEDGE, DIHEDRAL),
            np.full(len(fpts), FACET),
        ]
    ).astype(np.int64)
    return PrismEchoes(length=np.where(ok, length, np.nan), scattering=s, point=point, kind=kind)


def rotate_basis(scattering: np.ndarray, angle: float) -> np.ndarray:
    """Scattering matrices in antennas rotated by ``angle`` about the line of sight.

    .. math:: S' = R(\\alpha)^T S R(\\alpha)

    With ``angle = pi / 4`` the co- and cross-polar channels of the rotated pair are
    ``(S_VV + S_HH)/2 +- S_VH`` and ``(S_HH - S_VV)/2``: a plate (``S_VV = S_HH``) leaves no
    cross-polar echo, a dihedral (``S_VV = -S_HH``) only a cross-polar one (Section 7.6).

    Parameters
    ----------
    scattering : ndarray, shape (..., 2, 2)
    angle : float, rad
    """
    c, s = np.cos(angle), np.sin(angle)
    r = np.array([[c, -s], [s, c]])
    return np.einsum("ji,...jk,kl->...il", r, scattering, r)
