"""Bistatic ellipse intersection: a position from two ranges (Section 9.2.2)."""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]
_EYE2 = np.eye(2)
_ADJ_SIGN = np.array([[1.0, -1.0], [-1.0, 1.0]])


class EllipseIntersector:
    """Intersects pairs of bistatic ellipses of one transmitter and two receivers.

    Each range defines the ellipse :math:`\\|p - tx\\| + \\|p - rx_i\\| = r_i`
    (Section 9.2.2 of the CoLOR chapter). With :math:`tx` at the origin, :math:`a_i = rx_i`
    and :math:`d = \\|p\\|`, squaring :math:`\\|p - rx_i\\| = r_i - d` makes each ellipse
    linear in :math:`(p, d)`:

    .. math::

        a_i \\cdot p - r_i d = b_i = (\\|a_i\\|^2 - r_i^2) / 2, \\qquad i = 1, 2

    Which two of the three unknowns these fix depends on the antennas only, so the
    case is chosen once, here:

    * antennas not on one line (:math:`A = [a_1; a_2]` invertible): :math:`p = A^{-1}(b +
      r d)`, and :math:`\\|p\\|^2 = d^2` is a quadratic in :math:`d`;
    * collinear antennas (a bat-type sensor, :math:`a_2 = \\kappa a_1`): the two equations
      give :math:`d` and the coordinate :math:`s = \\hat a_1 \\cdot p` along the baseline,
      linearly, and the offset from the baseline is :math:`\\pm \\sqrt{d^2 - s^2}` (mirror
      images).

    Roots need :math:`0 < d \\le r_i`; pairs without a real intersection produce no point.
    A call costs a fixed couple of dozen array operations, whatever the number of pairs.

    Parameters
    ----------
    tx, rx1, rx2 : array_like, float64, shape (2,) or (3,)
        Antenna positions, world x, y (z ignored), m.
    """

    def __init__(self, tx: npt.ArrayLike, rx1: npt.ArrayLike, rx2: npt.ArrayLike) -> None:
        ant = np.array([np.asarray(v, dtype=np.float64).ravel()[:2] for v in (tx, rx1, rx2)])
        self.antennas = ant
        self.tx = ant[0]
        a = ant[1:] - ant[0]  # rows a_1, a_2
        self._norm2 = (a * a).sum(axis=1)[:, None]  # |a_i|^2, (2, 1)
        len1 = float(np.sqrt(self._norm2[0, 0]))
        cross = float(a[0, 0] * a[1, 1] - a[0, 1] * a[1, 0])
        # |sin| of the angle at tx below 1e-4: rx2 is within 1e-4 |a_2| of the line
        self.collinear = abs(cross) <= 1e-4 * len1 * float(np.sqrt(self._norm2[1, 0]))
        if self.collinear:
            axis = a[0] / len1
            self._kappa = float(a[1] @ axis) / len1  # a_2 = kappa a_1
            self._len1 = len1
            self._frame = np.array([axis, [-axis[1], axis[0]]])  # rows: along, across
        else:
            self._inverse = np.linalg.solve(a, np.eye(2))  # A^{-1}, once per geometry
        # the constants of locate() as Python floats, converted once
        self._scalars = (
            ant.ravel().tolist(),
            float(self._norm2[0, 0]),
            float(self._norm2[1, 0]),
            self._frame.ravel().tolist() if self.collinear else self._inverse.ravel().tolist(),
        )

    def intersect(self, ranges: npt.ArrayLike) -> tuple[FloatArray, IntArray]:
        """Intersection points of range pairs.

        Parameters
        ----------
        ranges : array_like, float64, shape (2, k)
            Bistatic ranges at rx1 (row 0) and rx2 (row 1), m.

        Returns
        -------
        points : ndarray, float64, shape (m, 2)
            Intersections in world x, y, m (0 to 2 per pair; none without a real one).
        pair : ndarray, intp, shape (m,)
            Index of the range pair each point comes from, ascending.
        """
        r = np.asarray(ranges, dtype=np.float64).reshape(2, -1)
        b = self._norm2 - r * r
        b *= 0.5
        r_min = np.minimum(r[0], r[1]) * (1.0 + 1e-9)
        if self.collinear:
            # |a1| s - r1 d = b1 and kappa |a1| s - r2 d = b2; the denominator vanishes only
            # for r2 = kappa r1, impossible with kappa < 0 (receivers on either side of tx)
            kappa = self._kappa
            den = kappa * r[0] - r[1]
            if kappa >= 0:
                den[den == 0.0] = np.nan  # no unique solution: no point
            d = (b[1] - kappa * b[0]) / den
            s = (b[0] + r[0] * d) / self._len1
            across2 = d * d - s * s  # negative: the ellipses do not meet
            local = np.empty((2, 2, r.shape[1]))  # (coordinate, root, pair)
            local[0] = s
            np.sqrt(np.maximum(across2, 0.0), out=local[1, 0])
            np.negative(local[1, 0], out=local[1, 1])
            valid = np.empty((2, r.shape[1]), dtype=bool)
            # rounding may leave exact ranges of a point on the baseline slightly negative
            valid[0] = (d > 0) & (d <= r_min) & (across2 >= -1e-12 * d * d)
            # a point on the baseline (tangent ellipses) once, not twice
            np.logical_and(valid[0], across2 > 0, out=valid[1])
            pair, which = valid.T.nonzero()
            return (local[:, which, pair].T @ self._frame) + self.tx, pair
        with np.errstate(divide="ignore", invalid="ignore"):  # degenerate pairs give NaN
            p0 = self._inverse @ b  # p = p0 + p1 d, (2, k)
            p1 = self._inverse @ r
            qa = np.add.reduce(p1 * p1, 0) - 1.0
            qb = np.add.reduce(p0 * p1, 0)
            qc = np.add.reduce(p0 * p0, 0)
            disc = qb * qb - qa * qc
            # tolerate rounding for tangent ellipses
            ok = disc >= -1e-12 * (qb * qb + np.abs(qa * qc))
            sq = np.sqrt(np.maximum(disc, 0.0))
            # numerically stable roots of qa d^2 + 2 qb d + qc: q / qa and qc / q
            qq = -(qb + np.copysign(sq, qb))
            d = np.array((qq / qa, qc / qq))
            valid = (d > 0) & (d <= r_min)
            valid &= ok
        # a double root (tangent ellipses) yields the same point twice: keep it once
        valid[1] &= sq > 1e-9 * np.abs(qb)
        # nonzero of the transposed view lists the roots pair by pair
        pair, which = valid.T.nonzero()
        points = (p0[:, pair] + p1[:, pair] * d[which, pair]).T + self.tx
        return points, pair

    def locate(
        self, r1: list[float], r2: list[float], range_std: float
    ) -> list[tuple[float, float, float, float, float]]:
        """:meth:`intersect` then :meth:`covariance` of a handful of range pairs.

        The same arithmetic in plain Python floats: a node pairs a few ranges per impulse
        response, where each numpy call would cost more than its whole scalar loop.

        Parameters
        ----------
        r1, r2 : list of float, length k
            Paired bistatic ranges at rx1 and rx2, m.
        range_std : float
            Standard deviation of each range, m.

        Returns
        -------
        list of tuple
            ``(x, y, c_xx, c_xy, c_yy)`` per intersection point (world x, y in m and its
            covariance in m^2), in :meth:`intersect` order; points of singular geometry
            (``ok`` False in :meth:`covariance`) are left out.
        """
        (x0, y0, x1, y1, x2, y2), n1, n2, mat = self._scalars
        tx, ty = x0, y0
        points: list[tuple[float, float]] = []
        if self.collinear:
            kappa, len1 = self._kappa, self._len1
            ax, ay, cx, cy = mat
            for a, c in zip(r1, r2, strict=True):
                b0, b1 = (n1 - a * a) * 0.5, (n2 - c * c) * 0.5
                den = kappa * a - c
                if den == 0.0:  # no unique solution (kappa >= 0 only): no point
                    continue
                d = (b1 - kappa * b0) / den
                s = (b0 + a * d) / len1
                across2 = d * d - s * s
                if not (0 < d <= min(a, c) * (1.0 + 1e-9) and across2 >= -1e-12 * d * d):
                    continue
                off = math.sqrt(max(across2, 0.0))
                points.append((s * ax + off * cx + tx, s * ay + off * cy + ty))
                if across2 > 0:  # a point on the baseline once, not twice
                    points.append((s * ax - off * cx + tx, s * ay - off * cy + ty))
        else:
            i00, i01, i10, i11 = mat
            for a, c in zip(r1, r2, strict=True):
                b0, b1 = (n1 - a * a) * 0.5, (n2 - c * c) * 0.5
                p0x, p0y = i00 * b0 + i01 * b1, i10 * b0 + i11 * b1
                p1x, p1y = i00 * a + i01 * c, i10 * a + i11 * c
                qa = p1x * p1x + p1y * p1y - 1.0
                qb = p0x * p1x + p0y * p1y
                qc = p0x * p0x + p0y * p0y
                disc = qb * qb - qa * qc
                if not disc >= -1e-12 * (qb * qb + abs(qa * qc)):
                    continue
                sq = math.sqrt(max(disc, 0.0))
                qq = -(qb + math.copysign(sq, qb))
                r_min = min(a, c) * (1.0 + 1e-9)
                # a zero denominator is a root at infinity (NaN/inf in intersect): no point
                roots = (qq / qa if qa != 0.0 else math.inf, qc / qq if qq != 0.0 else math.inf)
                for k, d in enumerate(roots):
                    if 0 < d <= r_min and (k == 0 or sq > 1e-9 * abs(qb)):
                        points.append((p0x + p1x * d + tx, p0y + p1y * d + ty))
        out = []
        var = range_std * range_std
        for px, py in points:
            ux, uy = px - x0, py - y0
            dist = max(math.hypot(ux, uy), 1e-12)
            ux, uy = ux / dist, uy / dist
            j00, j01 = px - x1, py - y1
            dist = max(math.hypot(j00, j01), 1e-12)
            j00, j01 = j00 / dist + ux, j01 / dist + uy
            j10, j11 = px - x2, py - y2
            dist = max(math.hypot(j10, j11), 1e-12)
            j10, j11 = j10 / dist + ux, j11 / dist + uy
            det = j00 * j11 - j01 * j10
            det2 = det * det
            if det2 > 1e-12:
                f = var / det2
                out.append(
                    (
                        px,
                        py,
                        (j11 * j11 + j01 * j01) * f,
                        (-j11 * j10 - j01 * j00) * f,
                        (j10 * j10 + j00 * j00) * f,
                    )
                )
        return out

    def covariance(
        self, points: npt.ArrayLike, range_std: float
    ) -> tuple[FloatArray, npt.NDArray[np.bool_]]:
        """Covariance of intersection positions from the range standard deviation.

        With the Jacobian :math:`J` of the two ranges, rows :math:`J_i = (p - tx)^T /
        \\|p - tx\\| + (p - rx_i)^T / \\|p - rx_i\\|`, and :math:`R = \\sigma_r^2 I`, the
        linearised covariance :math:`C = (J^T R^{-1} J)^{-1} = \\sigma_r^2 J^{-1} J^{-T}` is,
        for the square 2x2 :math:`J`, in closed form

        .. math::

            C = \\frac{\\sigma_r^2}{\\det(J)^2} \\operatorname{adj}(J)
            \\operatorname{adj}(J)^T

        Parameters
        ----------
        points : array_like, float64, shape (k, 2)
            Positions, world x, y, m.
        range_std : float
            Standard deviation of each range, m.

        Returns
        -------
        cov : ndarray, float64, shape (k, 2, 2)
            Position covariances, m^2 (identity for singular geometry, see ``ok``).
        ok : ndarray, bool, shape (k,)
            False where the geometry is singular (point on the antennas' line, or on an
            antenna).
        """
        p = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        diff = p[:, None, :] - self.antennas  # (k, 3, 2): from tx, rx1, rx2
        dist = np.hypot(diff[:, :, 0], diff[:, :, 1])
        unit = diff / np.maximum(dist, 1e-12)[:, :, None]
        jac = unit[:, 1:] + unit[:, :1]  # (k, 2, 2), rows d r_i / d p
        det = jac[:, 0, 0] * jac[:, 1, 1] - jac[:, 0, 1] * jac[:, 1, 0]
        # adj(J) = [[J11, -J01], [-J10, J00]]
        adj = jac[:, ::-1, ::-1].transpose(0, 2, 1) * _ADJ_SIGN
        cov = adj @ adj.transpose(0, 2, 1)
        det2 = det * det
        # rows of J have norms up to 2: |det J| tiny is a point on the antennas' line
        ok = det2 > 1e-12
        cov *= (range_std * range_std / np.maximum(det2, 1e-12))[:, None, None]
        if np.count_nonzero(ok) < ok.size:
            cov[~ok] = _EYE2
        return cov, ok


def intersect_ellipses(
    tx: npt.ArrayLike,
    rx1: npt.ArrayLike,
    rx2: npt.ArrayLike,
    r1: npt.ArrayLike,
    r2: npt.ArrayLike,
) -> tuple[FloatArray, IntArray]:
    """Intersect pairs of bistatic ellipses with common transmitter, in closed form.

    See :class:`EllipseIntersector`, of which this is a one-off call.

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
    r = np.array((np.ravel(r1), np.ravel(r2)), dtype=np.float64)
    return EllipseIntersector(tx, rx1, rx2).intersect(r)


def position_covariance(
    points: npt.ArrayLike,
    tx: npt.ArrayLike,
    rx1: npt.ArrayLike,
    rx2: npt.ArrayLike,
    range_std: float,
) -> tuple[FloatArray, npt.NDArray[np.bool_]]:
    """Covariance of ellipse-intersection positions, see :meth:`EllipseIntersector.covariance`.

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
        False where the geometry is singular.
    """
    return EllipseIntersector(tx, rx1, rx2).covariance(points, range_std)
