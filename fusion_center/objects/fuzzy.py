"""Fuzzy range-points-migration (RPM) imaging of a circular scan (Section 7.5).

A sensor on a (partial) circular track measures, at each position ``i``, the wavefronts
(range of each echo). A scatterer seen from two neighbouring positions lies on both circles
of radius ``rho`` (the monostatic distance) around them; their intersection follows from the
law of cosines in the triangle (position i, position j, scatterer):

.. math::

    \\cos\\alpha_{ij} = \\frac{\\rho_i^2 + c_{ij}^2 - \\rho_j^2}{2 \\rho_i c_{ij}},
    \\quad P_{ij} = s_i + \\rho_i (\\cos\\alpha_{ij}\\, e_{ij} + \\sin\\alpha_{ij}\\, n_i),

with ``c_ij`` the chord between the positions, ``e_ij`` its unit vector and ``n_i`` the normal
toward the object. Every wavefront gets one candidate point per neighbour ``j = i +- 1..K``.
Fuzzification: each candidate is a Gaussian membership function of width ``sigma`` around it,
weighted by the distance between the two positions (near neighbours see the same scattering
centre, far ones give a better-conditioned triangle; the weight is a Gaussian in the index
distance). The membership of a candidate is the weighted sum of all memberships of the
wavefront at that point; maximum defuzzification keeps the candidate of highest membership
as the wavefront's image point. The 2-D contour is the chain of image points of the first
wavefront of every position (the object's front surface as seen from the track).

The 3-D extension (stacked circular scans at several heights) intersects three spheres:
position ``i`` at height ``z_l``, its azimuth neighbour and its elevation neighbour at
``z_{l+1}`` (trilateration), with the same fuzzification over neighbour pairs.

**Bistatic antennas.** A bistatic range ``r`` (Tx -> object -> Rx, antennas ``b`` apart) puts
the scatterer on an ellipse with foci Tx and Rx, not on a circle. Its monostatic equivalent
``rho = sqrt((r/2)^2 - (b/2)^2)`` (:func:`monostatic_distance`) is exact only on the boresight;
with a wide baseline (0.8 m at 0.7 m range) the circle of that radius misses the ellipse by
centimetres off the boresight. Given the antenna positions, :meth:`FuzzyRpmImager.image`
therefore replaces the law-of-cosines step by the intersection of the two range *ellipses*
``|P - T_i| + |P - R_i| = r_i`` and ``|P - T_j| + |P - R_j| = r_j``
(:func:`ellipse_intersections`: Newton's method started at the circle intersection; the
bistatic generalisation of the Section 7.5 step, which it equals for ``b = 0``). For a point
scatterer the intersection is the point itself, for a face it converges to the bistatic
specular point as the neighbours close in, as the circle intersection does monostatically.
Pure numpy.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True, slots=True, kw_only=True)
class FuzzyImageConfig:
    """Parameters of the fuzzy RPM imager.

    Attributes
    ----------
    neighbours : int
        Largest index distance K of the neighbour positions used (both sides).
    weight_width : float
        Width (in positions) of the Gaussian distance weighting of neighbour pairs.
    weight_centre : float
        Index distance of the largest weight.
    sigma : float
        Width of the Gaussian membership functions, m.
    gate : float
        Largest difference of distances (beyond the chord) for two wavefronts to be paired, m.
    min_membership : float
        Image points with a lower normalised membership are dropped.
    """

    neighbours: int = 8
    weight_width: float = 3.0
    weight_centre: float = 4.0
    sigma: float = 0.01
    gate: float = 0.01
    min_membership: float = 0.25


@dataclass(frozen=True, slots=True, kw_only=True)
class FuzzyImage:
    """Result of :meth:`FuzzyRpmImager.image`.

    Attributes
    ----------
    points : ndarray, float64, shape (P, M, 2)
        Image point of every wavefront, world x, y, m (NaN: none).
    membership : ndarray, float64, shape (P, M)
        Normalised membership of the kept candidate (0..1).
    contour : ndarray, float64, shape (Q, 2)
        The 2-D contour: image points of the first wavefront, in track order.
    contour_index : ndarray, int, shape (Q,)
        Position index of each contour point.
    """

    points: FloatArray
    membership: FloatArray
    contour: FloatArray
    contour_index: npt.NDArray[np.int64]


def monostatic_distance(ranges: npt.ArrayLike, baseline: float) -> FloatArray:
    """Monostatic distance of bistatic ranges, ``sqrt((r/2)^2 - (b/2)^2)``, m (NaN kept)."""
    r = np.asarray(ranges, float)
    with np.errstate(invalid="ignore"):
        return np.sqrt(np.maximum((r / 2) ** 2 - (baseline / 2) ** 2, 0.0))


def circle_intersections(
    s_i: FloatArray, rho_i: FloatArray, s_j: FloatArray, rho_j: FloatArray, toward: FloatArray
) -> FloatArray:
    """Law-of-cosines intersection of circles (s_i, rho_i) and (s_j, rho_j), on the side of
    ``toward`` (a direction from s_i), broadcast; NaN where the circles do not meet.

    Parameters
    ----------
    s_i, s_j : ndarray, shape (..., 2)
    rho_i, rho_j : ndarray, shape (...)
    toward : ndarray, shape (..., 2)

    Returns
    -------
    ndarray, float64, shape (..., 2)
    """
    s_i, s_j, toward = (np.asarray(a, float) for a in (s_i, s_j, toward))
    rho_i, rho_j = np.asarray(rho_i, float), np.asarray(rho_j, float)
    d = s_j - s_i
    c = np.linalg.norm(d, axis=-1)
    e = d / np.maximum(c, 1e-12)[..., None]
    n = np.stack([-e[..., 1], e[..., 0]], axis=-1)
    n = n * np.sign(np.sum(n * toward, axis=-1, keepdims=True) + 1e-300)
    with np.errstate(invalid="ignore", divide="ignore"):
        cos_a = (rho_i**2 + c**2 - rho_j**2) / (2 * rho_i * c)
    cos_a = np.where(np.abs(cos_a) <= 1.0, cos_a, np.nan)
    sin_a = np.sqrt(1 - cos_a**2)
    return s_i + rho_i[..., None] * (cos_a[..., None] * e + sin_a[..., None] * n)


def ellipse_intersections(
    tx_i: FloatArray,
    rx_i: FloatArray,
    r_i: FloatArray,
    tx_j: FloatArray,
    rx_j: FloatArray,
    r_j: FloatArray,
    start: FloatArray,
    *,
    iterations: int = 8,
    tol: float = 1e-6,
) -> FloatArray:
    """Intersection of two bistatic range ellipses nearest ``start``, broadcast.

    Solves ``|P - T_i| + |P - R_i| = r_i``, ``|P - T_j| + |P - R_j| = r_j`` for ``P`` by
    Newton's method (2x2 Jacobian: the sums of the unit vectors from the foci) from ``start``
    (the monostatic circle intersection, a few mm to cm away). NaN where ``start`` is NaN,
    the ellipses are too close to tangent there, or the residual stays above ``tol`` (m).

    Parameters
    ----------
    tx_i, rx_i, tx_j, rx_j : ndarray, shape (..., 2)
        Transmitter and receiver of positions i and j, world x, y, m.
    r_i, r_j : ndarray, shape (...)
        Bistatic ranges, m.
    start : ndarray, shape (..., 2)

    Returns
    -------
    ndarray, float64, shape (..., 2)
    """
    start = np.asarray(start, float)
    shape = np.broadcast_shapes(
        start.shape, *(np.shape(a) for a in (tx_i, rx_i, tx_j, rx_j)),
        (*np.shape(r_i), 2), (*np.shape(r_j), 2),
    )  # fmt: skip
    out = np.full(shape, np.nan)
    live = np.isfinite(np.broadcast_to(start, shape)).all(axis=-1)
    # Only the finite starts (most candidates of a scan are NaN padding).
    ti, ri, tj, rj, p = (np.broadcast_to(a, shape)[live] for a in (tx_i, rx_i, tx_j, rx_j, start))
    p = p.copy()
    li, lj = np.broadcast_to(r_i, shape[:-1])[live], np.broadcast_to(r_j, shape[:-1])[live]

    def residual_and_grad(t: FloatArray, r: FloatArray, q: FloatArray) -> tuple[FloatArray, ...]:
        a, b = q - t, q - r
        na, nb = np.linalg.norm(a, axis=-1), np.linalg.norm(b, axis=-1)
        grad = a / np.maximum(na, 1e-12)[..., None] + b / np.maximum(nb, 1e-12)[..., None]
        return na + nb, grad

    good = np.zeros(len(p), bool)
    act = np.arange(len(p))  # candidates still iterating
    with np.errstate(invalid="ignore", divide="ignore"):
        for it in range(iterations + 1):
            q = p[act]
            s_i, g_i = residual_and_grad(ti[act], ri[act], q)
            s_j, g_j = residual_and_grad(tj[act], rj[act], q)
            f_i, f_j = s_i - li[act], s_j - lj[act]
            done = (np.abs(f_i) < tol) & (np.abs(f_j) < tol)
            good[act[done]] = True
            keep = ~done & np.isfinite(f_i + f_j)
            act, f_i, f_j, g_i, g_j = act[keep], f_i[keep], f_j[keep], g_i[keep], g_j[keep]
            if not len(act) or it == iterations:
                break
            det = g_i[:, 0] * g_j[:, 1] - g_i[:, 1] * g_j[:, 0]
            det = np.where(np.abs(det) > 1e-9, det, np.nan)
            step = np.stack(
                [
                    (f_i * g_j[:, 1] - f_j * g_i[:, 1]) / det,
                    (g_i[:, 0] * f_j - g_j[:, 0] * f_i) / det,
                ],
                axis=-1,
            )
            # Damped: a step longer than 5 cm means the start was on the wrong branch.
            size = np.linalg.norm(step, axis=-1, keepdims=True)
            p[act] -= step * np.minimum(1.0, 0.05 / np.maximum(size, 1e-300))
    out[live] = np.where(good[:, None], p, np.nan)
    return out


class FuzzyRpmImager:
    """Fuzzy RPM imaging of one circular (or partial circular) scan, eq. of Section 7.5.

    Parameters
    ----------
    config : FuzzyImageConfig
    """

    def __init__(self, config: FuzzyImageConfig | None = None) -> None:
        self.config = config or FuzzyImageConfig()

    def image(
        self,
        positions: npt.ArrayLike,
        distances: npt.ArrayLike,
        toward: npt.ArrayLike,
        *,
        closed: bool,
        antennas: tuple[npt.ArrayLike, npt.ArrayLike] | None = None,
    ) -> FuzzyImage:
        """Image points of every wavefront and the 2-D contour.

        Parameters
        ----------
        positions : array_like, float, shape (P, 2)
            Sensor positions along the track, in track order, world x, y, m.
        distances : array_like, float, shape (P, M)
            Monostatic distance of each wavefront, m, ascending per row (NaN: none); with
            ``antennas``, the bistatic range Tx -> object -> Rx instead.
        toward : array_like, float, shape (P, 2)
            Direction from each position toward the object (the boresight).
        closed : bool
            The track is a full circle (neighbours wrap around).
        antennas : (tx, rx), each array_like of shape (P, 2), optional
            World x, y of the transmitter and receiver at each position: the candidates are
            then the intersections of the range ellipses (see the module doc), and the
            antennas' midpoints take the place of ``positions``.

        Returns
        -------
        FuzzyImage
        """
        cfg = self.config
        pos = np.asarray(positions, float)
        rho = np.asarray(distances, float)
        bs = np.asarray(toward, float)
        n_pos, m_all = rho.shape
        # Only as many wavefront columns as some position has (the rest is NaN padding).
        m = max(int(np.isfinite(rho).sum(axis=1).max(initial=0)), 1)
        rho = np.sort(rho, axis=1)[:, :m]
        if antennas is not None:
            tx, rx = (np.asarray(a, float) for a in antennas)
            bistatic = rho
            # Pairing and the Newton start use the monostatic equivalent on each position.
            half_b = 0.5 * np.linalg.norm(tx - rx, axis=1)[:, None]
            with np.errstate(invalid="ignore"):
                rho = np.sqrt(np.maximum((bistatic / 2) ** 2 - half_b**2, 0.0))
            pos = 0.5 * (tx + rx)
        deltas = np.concatenate(
            [-np.arange(1, cfg.neighbours + 1), np.arange(1, cfg.neighbours + 1)]
        )
        idx = np.arange(n_pos)[:, None] + deltas  # (P, D)
        valid_j = np.ones(idx.shape, bool) if closed else (idx >= 0) & (idx < n_pos)
        idx = np.mod(idx, n_pos)
        rho_j = rho[idx]  # (P, D, M): all wavefronts of neighbour j
        # Pair each wavefront of i with the nearest-distance wavefront of each neighbour.
        diff = np.abs(rho[:, None, :, None] - rho_j[:, :, None, :])  # (P, D, M, M)
        diff = np.where(np.isnan(diff), np.inf, diff)
        best = np.argmin(diff, axis=-1)  # (P, D, M)
        rho_pair = np.take_along_axis(rho_j, best, axis=-1)
        chord = np.linalg.norm(pos[idx] - pos[:, None, :], axis=-1)  # (P, D)
        ok = valid_j[..., None] & (
            np.abs(rho_pair - rho[:, None, :]) <= chord[..., None] + cfg.gate
        )
        cand = circle_intersections(
            np.broadcast_to(pos[:, None, None, :], (*ok.shape, 2)),
            np.broadcast_to(rho[:, None, :], ok.shape),
            np.broadcast_to(pos[idx][:, :, None, :], (*ok.shape, 2)),
            rho_pair,
            np.broadcast_to(bs[:, None, None, :], (*ok.shape, 2)),
        )  # (P, D, M, 2)
        if antennas is not None:
            r_j = np.take_along_axis(bistatic[idx], best, axis=-1)
            shape = (*ok.shape, 2)
            cand = ellipse_intersections(
                np.broadcast_to(tx[:, None, None, :], shape),
                np.broadcast_to(rx[:, None, None, :], shape),
                np.broadcast_to(bistatic[:, None, :], ok.shape),
                np.broadcast_to(tx[idx][:, :, None, :], shape),
                np.broadcast_to(rx[idx][:, :, None, :], shape),
                r_j,
                cand,
            )
            # Keep the root in front of the sensor (the other lies behind the antennas).
            ahead = np.sum((cand - pos[:, None, None, :]) * bs[:, None, None, :], axis=-1)
            cand = np.where((ahead > 0)[..., None], cand, np.nan)
        ok &= np.isfinite(cand).all(axis=-1)
        weight = np.exp(-0.5 * ((np.abs(deltas) - cfg.weight_centre) / cfg.weight_width) ** 2)
        w = np.where(ok, weight[None, :, None], 0.0)  # (P, D, M)
        # Membership of candidate q: weighted sum of the Gaussian memberships of all
        # candidates of the same wavefront, evaluated at q.
        cq = np.where(ok[..., None], cand, 0.0).transpose(0, 2, 1, 3)  # (P, M, D, 2)
        wt = w.transpose(0, 2, 1)  # (P, M, D)
        live = wt.sum(axis=-1) > 0  # wavefronts with any candidate
        cl, wl = cq[live].astype(np.float32), wt[live].astype(np.float32)  # (L, D, 2), (L, D)
        dx = cl[:, :, None, 0] - cl[:, None, :, 0]
        dy = cl[:, :, None, 1] - cl[:, None, :, 1]
        gauss = np.exp((dx * dx + dy * dy) * np.float32(-0.5 / cfg.sigma**2))
        mu_l = np.einsum("lqr,lr->lq", gauss, wl) / wl.sum(axis=-1, keepdims=True)
        mu_l = np.where(wl > 0, mu_l, -1.0)
        win = np.argmax(mu_l, axis=-1)  # maximum defuzzification
        membership = np.zeros((n_pos, m_all))
        points = np.full((n_pos, m_all, 2), np.nan)
        mem_live = np.take_along_axis(mu_l, win[:, None], axis=-1)[:, 0].astype(float)
        pts_live = np.take_along_axis(cl, win[:, None, None], axis=1)[:, 0, :].astype(float)
        keep = mem_live >= cfg.min_membership
        pi, mi = np.nonzero(live)
        membership[pi[keep], mi[keep]] = mem_live[keep]
        points[pi[keep], mi[keep]] = pts_live[keep]
        first = np.isfinite(points[:, 0, 0])
        return FuzzyImage(
            points=points,
            membership=membership,
            contour=points[first, 0, :],
            contour_index=np.flatnonzero(first),
        )

    def image_3d(
        self,
        positions: npt.ArrayLike,
        distances: npt.ArrayLike,
        toward: npt.ArrayLike,
        *,
        closed: bool,
    ) -> tuple[FloatArray, FloatArray]:
        """3-D image points of stacked circular scans by three-sphere intersection.

        For each position ``i`` of layer ``l`` and each wavefront, the spheres around
        ``(i, l)``, ``(i + d, l)`` (azimuth neighbour, ``d = +-1..K``) and ``(i, l +- 1)``
        (elevation neighbour) are intersected (trilateration; the root toward the object);
        the candidates are fuzzified and defuzzified by maximum as in :meth:`image`.

        Parameters
        ----------
        positions : array_like, float, shape (L, P, 3)
            Sensor positions, layer by layer (same azimuth grid on every layer), m.
        distances : array_like, float, shape (L, P, M)
            Monostatic distances of the wavefronts, m (NaN: none).
        toward : array_like, float, shape (L, P, 3)
            Direction from each position toward the object.
        closed : bool
            Each layer's track is a full circle.

        Returns
        -------
        points : ndarray, float64, shape (L, P, M, 3)
            World x, y, z, m (NaN: none).
        membership : ndarray, float64, shape (L, P, M)
        """
        cfg = self.config
        pos = np.asarray(positions, float)
        rho = np.asarray(distances, float)
        bs = np.asarray(toward, float)
        n_l, n_p, m = rho.shape
        d_az = np.concatenate([-np.arange(1, cfg.neighbours + 1), np.arange(1, cfg.neighbours + 1)])
        d_el = np.array([-1, 1])
        ja = np.arange(n_p)[:, None] + d_az  # (P, A)
        va = np.ones(ja.shape, bool) if closed else (ja >= 0) & (ja < n_p)
        ja = np.mod(ja, n_p)
        le = np.arange(n_l)[:, None] + d_el  # (L, 2)
        ve = (le >= 0) & (le < n_l)
        le = np.clip(le, 0, n_l - 1)

        def nearest(other: FloatArray) -> FloatArray:
            # other (..., M): the neighbour's wavefront nearest in distance to each of ours.
            diff = np.abs(rho_b[..., :, None] - other[..., None, :])
            diff = np.where(np.isnan(diff), np.inf, diff)
            return np.take_along_axis(other, np.argmin(diff, axis=-1), axis=-1)

        shape = (n_l, n_p, len(d_az), 2, m)
        rho_b = np.broadcast_to(rho[:, :, None, None, :], shape)
        r_a = nearest(np.broadcast_to(rho[:, ja][:, :, :, None, :], shape))
        r_e = nearest(np.broadcast_to(rho[le].transpose(0, 2, 1, 3)[:, :, None, :, :], shape))
        p0 = np.broadcast_to(pos[:, :, None, None, None, :], (*shape, 3))
        pa = np.broadcast_to(pos[:, ja][:, :, :, None, None, :], (*shape, 3))
        pe = np.broadcast_to(pos[le].transpose(0, 2, 1, 3)[:, :, None, :, None, :], (*shape, 3))
        pts = _trilaterate(p0, rho_b, pa, r_a, pe, r_e, bs[:, :, None, None, None, :])
        ok = (
            va[None, :, :, None, None]
            & ve[:, None, None, :, None]
            & np.isfinite(pts).all(axis=-1)
            & (np.abs(r_a - rho_b) <= np.linalg.norm(pa - p0, axis=-1) + cfg.gate)
            & (np.abs(r_e - rho_b) <= np.linalg.norm(pe - p0, axis=-1) + cfg.gate)
        )
        weight = np.exp(-0.5 * ((np.abs(d_az) - cfg.weight_centre) / cfg.weight_width) ** 2)
        w = np.where(ok, weight[None, None, :, None, None], 0.0)
        cq = np.where(ok[..., None], pts, 0.0).reshape(n_l, n_p, -1, m, 3).transpose(0, 1, 3, 2, 4)
        wt = w.reshape(n_l, n_p, -1, m).transpose(0, 1, 3, 2)  # (L, P, M, Q)
        d2 = np.sum((cq[..., :, None, :] - cq[..., None, :, :]) ** 2, axis=-1)
        mu = np.einsum("lpmqr,lpmr->lpmq", np.exp(-0.5 * d2 / cfg.sigma**2), wt)
        mu = np.where(wt > 0, mu / np.maximum(wt.sum(-1), 1e-300)[..., None], -1.0)
        win = np.argmax(mu, axis=-1)
        membership = np.take_along_axis(mu, win[..., None], axis=-1)[..., 0]
        points = np.take_along_axis(cq, win[..., None, None], axis=-2)[..., 0, :]
        keep = (membership >= cfg.min_membership) & np.isfinite(rho)
        return np.where(keep[..., None], points, np.nan), np.where(keep, membership, 0.0)


def _trilaterate(
    p1: FloatArray,
    r1: FloatArray,
    p2: FloatArray,
    r2: FloatArray,
    p3: FloatArray,
    r3: FloatArray,
    toward: FloatArray,
) -> FloatArray:
    """Intersection of three spheres (centres (..., 3), radii (...)), the root on the side of
    ``toward`` from ``p1``; NaN where they do not meet."""
    ex = p2 - p1
    d = np.linalg.norm(ex, axis=-1)
    ex = ex / np.maximum(d, 1e-12)[..., None]
    w = p3 - p1
    i = np.sum(ex * w, axis=-1)
    ey = w - i[..., None] * ex
    ny = np.linalg.norm(ey, axis=-1)
    ey = ey / np.maximum(ny, 1e-12)[..., None]
    ez = np.cross(ex, ey)
    j = np.sum(ey * w, axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        x = (r1**2 - r2**2 + d**2) / (2 * d)
        y = (r1**2 - r3**2 + i**2 + j**2) / (2 * j) - i / j * x
        z2 = r1**2 - x**2 - y**2
    z = np.sqrt(np.where(z2 >= 0, z2, np.nan))
    sign = np.sign(np.sum(ez * toward, axis=-1) + 1e-300)
    return p1 + x[..., None] * ex + y[..., None] * ey + (sign * z)[..., None] * ez
