"""Materials of the hybrid channel: complex permittivity and Fresnel reflection (pure numpy).

Polarization convention (used by :mod:`sim_nodes.channel.raytrace`): at a reflection the
field is split along ``s = k_in x n / |k_in x n|`` (perpendicular to the plane of incidence,
TE) and ``p = s x k`` (in the plane, TM), and the reflected field is

.. math:: e' = \\Gamma_{TE} (e \\cdot s) s + \\Gamma_{TM} (e \\cdot p_{in}) p_{out},
          \\quad p_{in} = s \\times k_{in},\\; p_{out} = s \\times k_{out}.

With this convention a perfect conductor has ``Gamma_TE = -1`` and ``Gamma_TM = +1`` (the
tangential field reverses), and both coefficients tend to ``-+(sqrt(eps)-1)/(sqrt(eps)+1)``
at normal incidence on a dielectric.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

EPS0 = 8.8541878128e-12
"""Vacuum permittivity, F/m."""


@dataclass(frozen=True, slots=True, kw_only=True)
class Material:
    """Electromagnetic description of a surface material.

    Attributes
    ----------
    permittivity : float
        Real relative permittivity eps_r (>= 1).
    conductivity : float
        Conductivity sigma, S/m (gives the loss term of the complex permittivity).
    metal : bool
        Perfect electric conductor: ``Gamma_TE = -1``, ``Gamma_TM = +1``, opaque.
    transmission : float
        One-way amplitude transmission factor of a crossing (a wall slab, or one face of a
        solid), frequency-independent; 0 for metal.
    excess : float
        Extra path length of a crossing, m (``thickness (sqrt(eps_r) - 1)``).
    """

    permittivity: float = 1.0
    conductivity: float = 0.0
    metal: bool = False
    transmission: float = 1.0
    excess: float = 0.0


def complex_permittivity(
    permittivity: npt.ArrayLike, conductivity: npt.ArrayLike, f: npt.ArrayLike
) -> np.ndarray:
    """Complex relative permittivity of a lossy dielectric (time convention ``exp(+j w t)``).

    .. math:: \\varepsilon_c = \\varepsilon_r - j \\sigma / (2 \\pi f \\varepsilon_0)

    Parameters
    ----------
    permittivity, conductivity : array_like
        eps_r (relative) and sigma, S/m; broadcast against ``f``.
    f : array_like
        Frequency, Hz (> 0).

    Returns
    -------
    ndarray, complex128
    """
    f = np.asarray(f, float)
    return np.asarray(permittivity, float) - 1j * np.asarray(conductivity, float) / (
        2 * np.pi * f * EPS0
    )


def fresnel(eps_c: npt.ArrayLike, cos_theta: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """Fresnel amplitude reflection coefficients of a half-space, both polarizations.

    .. math::
        \\Gamma_{TE} = \\frac{\\cos\\theta - \\sqrt{\\varepsilon_c - \\sin^2\\theta}}
                             {\\cos\\theta + \\sqrt{\\varepsilon_c - \\sin^2\\theta}},\\quad
        \\Gamma_{TM} = \\frac{\\varepsilon_c\\cos\\theta - \\sqrt{\\varepsilon_c - \\sin^2\\theta}}
                             {\\varepsilon_c\\cos\\theta + \\sqrt{\\varepsilon_c - \\sin^2\\theta}}

    (the reflection model behind eq. (1) of the CoLOR chapter; sign convention in the
    module docstring).

    Parameters
    ----------
    eps_c : array_like, complex
        Complex relative permittivity; broadcast against ``cos_theta``.
    cos_theta : array_like, float
        Cosine of the angle of incidence from the surface normal, in [0, 1].

    Returns
    -------
    gamma_te, gamma_tm : ndarray, complex128
    """
    eps = np.asarray(eps_c, complex)
    c = np.clip(np.asarray(cos_theta, float), 0.0, 1.0)
    root = np.sqrt(eps - (1.0 - c * c))
    return (c - root) / (c + root), (eps * c - root) / (eps * c + root)


def reflection_coefficients(
    material: Material, cos_theta: np.ndarray, f: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """TE and TM reflection coefficients of ``material``, shape ``broadcast(cos_theta, f)``.

    A metal gives the perfect-conductor values (-1, +1) at every angle and frequency.
    """
    shape = np.broadcast_shapes(np.shape(cos_theta), np.shape(f))
    if material.metal:
        return np.full(shape, -1.0 + 0j), np.full(shape, 1.0 + 0j)
    eps = complex_permittivity(material.permittivity, material.conductivity, f)
    te, tm = fresnel(eps, cos_theta)
    return np.broadcast_to(te, shape), np.broadcast_to(tm, shape)


def normal_reflection(material: Material, f: float) -> float:
    """Real part of the normal-incidence TE coefficient at ``f`` (the 2-D model's Gamma)."""
    if material.metal:
        return -1.0
    te, _ = fresnel(complex_permittivity(material.permittivity, material.conductivity, f), 1.0)
    return float(np.real(te))
