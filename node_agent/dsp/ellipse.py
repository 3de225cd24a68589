"""Bistatic ellipse intersection: a position from two ranges (Section 9.2.2)."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]
_EYE2 = np.eye(2)


def intersect_ellipses(
    tx: npt.ArrayLike,
    rx1: npt.ArrayLike,
    rx2: npt.ArrayLike,
    r1: npt.ArrayLike,
    r2: npt.ArrayLike,
) -> tuple[FloatArray, IntArray]:
    """Intersect pairs of bistatic ellipses with common transmitter, in closed form.

    Each range defines the ellipse :math:`\\|p - tx\\| + \\|p - rx_i\\| = r_i`
    (Section 9.2.2 of the CoLOR chapter). With :math:`tx` at the origin and
    :math:`d = \\|p\\|`, squaring :math:`\\|p - rx_i\\| = r_i - d` makes each ellipse linear
    in :math:`(p, d)`:

    .. math::

        2\\, rx_i \\cdot p - 2 r_i d = \\|rx_i\\|^2 - r_i^2, \\qquad i = 1, 2

    Two equations in three unknowns leave a line :math:`(p, d) = u_0 + \\lambda u_1`
    (:math:`u_1` spans the null space, a cross product), and :math:`d^2 = \\|p\\|^2`
    gives a quadratic in :math:`\\lambda`. This holds also when tx, rx1 and rx2 are
    collinear (a bat-type sensor), where the two roots are mirror images across the
    baseline. Roots need :math:`0 < d \\le r_i`. Pairs without a real intersection
    produce no point.

    Parameters
    ----------
    tx, rx1, rx2 : array_like, float64, shape (2,)
        Antenna positions, world x, y, m (targets are assumed at antenna height).
    r1, r2 : array_like, float64, shape (k,)
        Bistatic ranges at rx1 and rx2, m.

    Returns
    -------
    points : ndarray, float64, shape (m, 2)
        Intersections in world x, y, m (0 to 2 per pair).
    pair : ndarray, intp, shape (m,)
        Index of the range pair each point comes from, ascending.
    """
    tx = np.asarray(tx, dtype=np.float64)[:2]
    # Python floats for the antennas: scalar arithmetic on numpy scalars is slow
    tx_x, tx_y = float(tx[0]), float(tx[1])
    a1x, a1y = float(rx1[0]) - tx_x, float(rx1[1]) - tx_y
    a2x, a2y = float(rx2[0]) - tx_x, float(rx2[1]) - tx_y
    r1 = np.asarray(r1, dtype=np.float64).ravel()
    r2 = np.asarray(r2, dtype=np.float64).ravel()
    # the system M (p_x, p_y, d) = b with rows M_i = (a_i, -r_i) after dividing by 2,
    # b_i = (|a_i|^2 - r_i^2) / 2; written out per component on (k,) arrays
    n1, n2 = a1x * a1x + a1y * a1y, a2x * a2x + a2y * a2y
    r11, r22, r12 = r1 * r1, r2 * r2, r1 * r2
    b1 = 0.5 * (n1 - r11)
    b2 = 0.5 * (n2 - r22)
    # null direction u1 = M_1 x M_2 (its scale cancels in the roots)
    u1x = r1 * a2y - r2 * a1y
    u1y = r2 * a1x - r1 * a2x
    u1z = a1x * a2y - a1y * a2x
    # minimum-norm particular solution u0 = M^T c with (M M^T) c = b, the 2x2 Gram
    # system solved by Cramer's rule
    g11 = n1 + r11
    g22 = n2 + r22
    g12 = (a1x * a2x + a1y * a2y) + r12
    det = g11 * g22 - g12 * g12
    with np.errstate(divide="ignore", invalid="ignore"):
        c1 = (g22 * b1 - g12 * b2) / det
        c2 = (g11 * b2 - g12 * b1) / det
        u0x = c1 * a1x + c2 * a2x
        u0y = c1 * a1y + c2 * a2y
        u0z = -(c1 * r1 + c2 * r2)
        # d^2 = |p|^2 on the line (p, d) = u0 + lambda u1: a qa^2 + 2 qb l + qc = 0
        qa = u1x * u1x + u1y * u1y - u1z * u1z
        qb = u0x * u1x + u0y * u1y - u0z * u1z
        qc = u0x * u0x + u0y * u0y - u0z * u0z
        disc = qb * qb - qa * qc
        # tolerate rounding for tangent ellipses (exact ranges of a point on the baseline)
        tol = 1e-12 * (qb * qb + np.abs(qa * qc))
        disc[(disc < 0) & (disc > -tol)] = 0.0
        ok = (det > 1e-12 * (g11 * g22)) & (disc >= 0)
        sq = np.sqrt(np.abs(disc))
        # numerically stable roots: q = -(b + sign(b) sqrt(disc)), lambda = q/a and c/q
        qq = -(qb + np.copysign(sq, qb))
        lam = np.empty((2, r1.size))
        np.divide(qq, qa, out=lam[0])
        np.divide(qc, qq, out=lam[1])
        px = u0x + lam * u1x
        py = u0y + lam * u1y
        d = u0z + lam * u1z
        # d > 0 and |p - rx_i| = r_i - d >= 0; NaN from degenerate pairs compares False
        valid = ok & (d > 0) & (d <= np.minimum(r1, r2) * (1 + 1e-9))
    # a double root (tangent ellipses) yields the same point twice: keep it once
    valid[1] &= sq > 1e-9 * np.abs(qb)
    # nonzero of the transposed view lists the roots pair by pair
    pair, which = valid.T.nonzero()
    points = np.empty((pair.size, 2))
    points[:, 0] = px[which, pair] + tx_x
    points[:, 1] = py[which, pair] + tx_y
    return points, pair.astype(np.intp)


def position_covariance(
    points: npt.ArrayLike,
    tx: npt.ArrayLike,
    rx1: npt.ArrayLike,
    rx2: npt.ArrayLike,
    range_std: float,
) -> tuple[FloatArray, npt.NDArray[np.bool_]]:
    """Covariance of ellipse-intersection positions from the range standard deviation.

    With the Jacobian of the ranges :math:`r_i(p) = \\|p - tx\\| + \\|p - rx_i\\|`,
    :math:`J_i = (p - tx)^T/\\|p - tx\\| + (p - rx_i)^T/\\|p - rx_i\\|`, and
    :math:`R = \\sigma_r^2 I`, the linearised position covariance is

    .. math::

        C = (J^T R^{-1} J)^{-1}

    computed by solving :math:`(J^T R^{-1} J) C = I`.

    Parameters
    ----------
    points : array_like, float64, shape (k, 2)
        Positions, world x, y, m.
    tx, rx1, rx2 : array_like, float64, shape (2,)
        Antenna positions, m.
    range_std : float
        Standard deviation of each range, m.

    Returns
    -------
    cov : ndarray, float64, shape (k, 2, 2)
        Position covariances, m^2 (identity for singular geometry, see ``ok``).
    ok : ndarray, bool, shape (k,)
        False where the geometry is singular (point on the antennas' line, or on an antenna).
    """
    p = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    px, py = p[:, 0], p[:, 1]

    def unit(a: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
        dx, dy = px - float(a[0]), py - float(a[1])  # type: ignore[index]
        norm = np.hypot(dx, dy)
        return dx / norm, dy / norm

    with np.errstate(divide="ignore", invalid="ignore"):
        tx_x, tx_y = unit(tx)
        r1x, r1y = unit(rx1)
        r2x, r2y = unit(rx2)
    # rows of J: d r_i / d p = unit(p - tx) + unit(p - rx_i)
    j1x, j1y, j2x, j2y = tx_x + r1x, tx_y + r1y, tx_x + r2x, tx_y + r2y
    info = np.empty((p.shape[0], 2, 2))
    w = 1.0 / (range_std * range_std)
    info[:, 0, 0] = (j1x * j1x + j2x * j2x) * w
    info[:, 1, 1] = (j1y * j1y + j2y * j2y) * w
    info[:, 0, 1] = info[:, 1, 0] = (j1x * j1y + j2x * j2y) * w
    det = info[:, 0, 0] * info[:, 1, 1] - info[:, 0, 1] * info[:, 1, 0]
    tr = info[:, 0, 0] + info[:, 1, 1]
    ok = np.isfinite(det) & (det > 1e-12 * tr * tr)
    info[~ok] = _EYE2
    cov = np.linalg.solve(info, np.broadcast_to(_EYE2, info.shape))  # never inv
    return cov, ok
