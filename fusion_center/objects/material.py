"""Polarimetry and ellipsometry of short-range scans (Sections 7.6 and eq. (16)).

**Polarimetry.** With V/H antennas a smooth plate returns the transmitted polarization
(``S_VH = 0``), a rough bulk surface depolarizes (``S_VH != 0``): the depolarization ratio
``P_VH / P_VV`` (powers in the echo window) grows with roughness. With both antennas rotated
by 45 degrees, plates (``S_VV = S_HH``) vanish from the cross-polar channel while dihedrals
(``S_VV = -S_HH``) and wedges (``S_VV != S_HH``) remain: it shows only the corners.

**Ellipsometry.** At oblique incidence ``theta`` (bistatic antennas ``b`` apart) the ratio of
the two polarizations' reflection factors ``rho = Gamma_TM / Gamma_TE`` (``= -S_HH / S_VV`` in
the back-scatter alignment of the simulator) gives the permittivity of a non-magnetic half
space,

.. math::

    \\varepsilon_r = \\sin^2\\theta \\left[1 + \\tan^2\\theta
        \\left(\\frac{1 - \\rho}{1 + \\rho}\\right)^2\\right],

eq. (16) of the CoLOR chapter, and the (normal) emissivity ``e = 1 - |Gamma|^2`` with
``Gamma = (1 - sqrt(eps_r)) / (1 + sqrt(eps_r))``. Near a corner the face echo overlaps the
corner's diffraction, which has its own polarization ratio, and ``rho`` is biased (Fig. 37);
:class:`CornerCorrectionTable` stores the measured bias ``rho_measured / rho_true`` of a
reference target against the distance of the specular point from the nearest corner and
divides it out. Pure numpy.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]


def depolarization_ratio(co: npt.ArrayLike, cross: npt.ArrayLike) -> FloatArray:
    """``P_cross / P_co``: energy ratio of cross- and co-polar signals over the last axis."""
    co = np.asarray(co, float)
    cross = np.asarray(cross, float)
    return np.sum(cross**2, axis=-1) / np.maximum(np.sum(co**2, axis=-1), 1e-300)


def ellipsometry_permittivity(rho: npt.ArrayLike, theta: npt.ArrayLike) -> FloatArray:
    """Relative permittivity from the polarization ratio ``rho = Gamma_TM / Gamma_TE`` at
    incidence ``theta`` (rad), eq. (16) of the CoLOR chapter (NaN where ``rho = -1``)."""
    rho = np.asarray(rho, float)
    theta = np.asarray(theta, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        q = (1 - rho) / (1 + rho)
    return np.sin(theta) ** 2 * (1 + np.tan(theta) ** 2 * q**2)


def emissivity(permittivity: npt.ArrayLike) -> FloatArray:
    """Normal emissivity ``1 - |Gamma|^2`` of a lossless half space of permittivity eps_r."""
    n = np.sqrt(np.asarray(permittivity, float))
    return 1 - ((n - 1) / (n + 1)) ** 2


def incidence_angle(
    tx: npt.ArrayLike, rx: npt.ArrayLike, point: npt.ArrayLike, normal: npt.ArrayLike
) -> FloatArray:
    """Angle of incidence of the specular bistatic path on a plane (point, unit normal),
    from the image of the transmitter: ``cos theta = n . (R - T') / |R - T'|``, rad."""
    tx, rx = np.asarray(tx, float), np.asarray(rx, float)
    p, n = np.asarray(point, float), np.asarray(normal, float)
    dt = np.sum((tx - p) * n, axis=-1)
    img = tx - 2 * dt[..., None] * n
    d = rx - img
    return np.arccos(np.clip(np.sum(d * n, axis=-1) / np.linalg.norm(d, axis=-1), -1.0, 1.0))


def bistatic_incidence_angle(
    tx: npt.ArrayLike, rx: npt.ArrayLike, bistatic_range: npt.ArrayLike, normal: npt.ArrayLike
) -> FloatArray:
    """Angle of incidence of a specular reflection from the measured bistatic range, rad.

    A plane with unit normal ``n`` mirrors the transmitter ``T`` to ``T'``; the specular path
    has the length ``r = |R - T'|`` (image method) and meets the plane at ``theta`` from its
    normal. Mirroring keeps the components along the plane, so the part of ``R - T'`` along
    the plane is that of ``R - T`` and

    .. math::

        \\sin\\theta = \\frac{|n \\times (T - R)|}{r}
                    = \\frac{b\\,|n \\cdot f|}{r},

    with ``b`` the baseline and ``f`` the unit vector normal to it in the plane of incidence
    (the boresight of the scan's antennas). Equivalently ``cos theta = 2 u / r`` with
    ``u = sqrt(r^2 - b^2 (n . f)^2) / 2`` the distance of the plane from the antennas'
    midpoint. Needs neither the specular point nor the plane's distance, only the measured
    ``r`` and the face orientation, and is insensitive to the latter near ``n || f``
    (``d sin theta / d psi = 0`` there).

    Parameters
    ----------
    tx, rx : array_like, shape (..., 2)
        World x, y of transmitter and receiver, m.
    bistatic_range : array_like, shape (...)
        Measured path length Tx -> plane -> Rx, m.
    normal : array_like, shape (..., 2)
        Unit normal of the plane (either sign).

    Returns
    -------
    ndarray, float64, shape (...)
        NaN where the range is shorter than the baseline component along the plane.
    """
    d = np.asarray(tx, float) - np.asarray(rx, float)
    n = np.asarray(normal, float)
    along = np.abs(d[..., 0] * n[..., 1] - d[..., 1] * n[..., 0])
    with np.errstate(invalid="ignore", divide="ignore"):
        s = along / np.asarray(bistatic_range, float)
    return np.arcsin(np.where(s <= 1.0, s, np.nan))


@dataclass(frozen=True, slots=True, kw_only=True)
class CornerCorrectionTable:
    """Bias of the polarization ratio near corners (Fig. 37 of the CoLOR chapter).

    Attributes
    ----------
    distance : ndarray, float64, shape (K,)
        Distance of the specular point from the nearest corner, m (bin centres, ascending).
    factor : ndarray, float64, shape (K,)
        Median ``rho_measured / rho_true`` of the reference target in each bin.
    """

    distance: FloatArray
    factor: FloatArray

    @classmethod
    def calibrate(
        cls,
        distance: npt.ArrayLike,
        rho_measured: npt.ArrayLike,
        rho_true: npt.ArrayLike,
        bins: npt.ArrayLike,
    ) -> CornerCorrectionTable:
        """Table from a reference scan: per-position corner distance (m), measured and true
        ``rho``; ``bins`` are the bin edges (m). Empty bins are left out."""
        d = np.asarray(distance, float)
        ratio = np.asarray(rho_measured, float) / np.asarray(rho_true, float)
        edges = np.asarray(bins, float)
        which = np.digitize(d, edges) - 1
        centres, factors = [], []
        for k in range(len(edges) - 1):
            sel = (which == k) & np.isfinite(ratio)
            if sel.any():
                centres.append(0.5 * (edges[k] + edges[k + 1]))
                factors.append(float(np.median(ratio[sel])))
        if not centres:
            raise ValueError("no reference positions fall into the table's bins")
        return cls(distance=np.asarray(centres), factor=np.asarray(factors))

    def correct(self, rho: npt.ArrayLike, distance: npt.ArrayLike) -> FloatArray:
        """``rho / factor(distance)``, the factor interpolated (held beyond the table)."""
        f = np.interp(np.asarray(distance, float), self.distance, self.factor)
        return np.asarray(rho, float) / f
