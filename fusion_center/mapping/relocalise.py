"""Relocalisation of the robot after a long drive: scan matching against the mature map.

After a drive of several metres the odometry leaves degrees of heading spread (the wheels slip
about 1 degree per metre). The particles then predict the echoes of the known landmarks so
badly that the association of eq. (12) of the CoLOR chapter starts new landmarks instead, and
the first one or two echoes that do fit decide the pose. :class:`GridScanMatchRelocaliser`
therefore scores the first acquisitions of the new stop *jointly* (their poses relative to the
stop's first one come from the odometry of the turn on the spot, which is precise) against
the map of one particle, over a grid of poses around the odometry's prediction, coarse to
fine. The filter re-seeds its particles from the fine grid's posterior
(:meth:`~fusion_center.mapping.rbpf.RbpfSlam.predict`). This is correlative scan matching
(Olson, "Real-time correlative scan matching", ICRA 2009) with the chapter's echo models
(Fig. 19) as the scan model; it goes beyond the chapter, which relies on the particles alone.

Pure numpy; poses are ``[x, y, yaw]`` in the map frame (m, rad), ranges bistatic (m).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from fusion_center.mapping.models import CORNER, POINT, WALL

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True, slots=True, kw_only=True)
class MatchMap:
    """The landmarks a relocalisation matches against (one particle's mature landmarks).

    Each landmark enters with each of its kind hypotheses, weighted by the kind's posterior
    (a landmark seen from one stop may still be a wall or a corner).

    Attributes
    ----------
    kind : ndarray of int, shape (L,)
        :data:`~fusion_center.mapping.models.WALL`, ``CORNER`` or ``POINT``.
    state : ndarray, shape (L, 2)
        Landmark state in that kind's parametrisation (wall ``(alpha, d)``, else ``(x, y)``).
    log_weight : ndarray, shape (L,)
        Log-probability of the hypothesis (0 for a sure one).
    """

    kind: npt.NDArray[np.int64]
    state: FloatArray
    log_weight: FloatArray


def compose_poses(poses: FloatArray, rel: FloatArray) -> FloatArray:
    """Poses ``poses`` (n, 3) moved by the relative pose ``rel`` (3,) given in their frame."""
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    return np.column_stack(
        [
            poses[:, 0] + c * rel[0] - s * rel[1],
            poses[:, 1] + s * rel[0] + c * rel[1],
            poses[:, 2] + rel[2],
        ]
    )


def expected_ranges(
    lmap: MatchMap, tx: FloatArray, rx: FloatArray, yaw: FloatArray, cos_fov: float
) -> tuple[FloatArray, npt.NDArray[np.bool_]]:
    """Bistatic ranges (n, L, 2) of every landmark for n array poses, and their visibility.

    The models of Fig. 19 of the CoLOR chapter (:func:`fusion_center.mapping.models.predict`
    without the Jacobians): the image of the transmitter for walls and corners, the sum of
    two distances for points. A landmark is visible when its echo arrives within ``cos_fov``
    of the boresight ``yaw`` and, for a wall, the transmitter is in front of it.

    Parameters
    ----------
    tx : ndarray, shape (n, 2)
    rx : ndarray, shape (n, 2, 2)
    yaw : ndarray, shape (n,)
        World boresight of the array, rad.
    """
    n, lnum = tx.shape[0], lmap.kind.size
    ranges = np.empty((n, lnum, 2))
    vis = np.empty((n, lnum), bool)
    bore = np.stack([np.cos(yaw), np.sin(yaw)], -1)[:, None, :]
    t = tx[:, None, :]
    for kind in (WALL, CORNER, POINT):
        sel = np.flatnonzero(lmap.kind == kind)
        if sel.size == 0:
            continue
        st = lmap.state[sel][None]
        if kind == POINT:
            d0 = st - t
            n0 = np.linalg.norm(d0, axis=-1)
            r = n0[..., None] + np.linalg.norm(st[:, :, None, :] - rx[:, None], axis=-1)
            direction = d0
            ok = np.ones(n0.shape, bool)
        else:
            if kind == WALL:
                a = st[..., 0]
                nrm = np.stack([np.cos(a), np.sin(a)], -1)
                dist = st[..., 1] - np.sum(nrm * t, -1)
                image = t + 2.0 * dist[..., None] * nrm
                ok = dist > 0.05
            else:
                image = 2.0 * st - t
                ok = np.ones(image.shape[:2], bool)
            r = np.linalg.norm(image[:, :, None, :] - rx[:, None], axis=-1)
            direction = image - t
        norm = np.maximum(np.linalg.norm(direction, axis=-1), 1e-9)
        ranges[:, sel] = r
        vis[:, sel] = ok & (np.sum(direction * bore, -1) >= cos_fov * norm)
    return ranges, vis


class GridScanMatchRelocaliser:
    """Pose of a stop from its first acquisitions by a coarse-to-fine grid search.

    Score of a candidate pose ``q`` of the stop's first acquisition (log-likelihood plus
    the odometry's Gaussian prior):

    .. math::
        s(q) = \\sum_a \\sum_m \\ln\\Big(\\lambda + \\sum_{l\\,\\text{visible}}
        \\mathcal{N}(z_{am};\\, h_l(q \\oplus u_a) + b,\\, \\sigma^2 I)\\Big)
        - \\tfrac12 (q - \\hat q)^T P^{-1} (q - \\hat q)

    with ``z_am`` the pairs of acquisition ``a``, ``u_a`` its odometry relative to the first,
    ``h_l`` the echo model of landmark ``l`` (eq. of Fig. 19), ``lambda`` the clutter density
    (echoes no landmark explains cost the same for every pose) and ``b`` the range bias.

    Parameters
    ----------
    antennas : array_like, shape (3, 2)
        tx, rx1, rx2 in the robot frame, m.
    range_sigma : float
        Range noise at the fine level, m; the coarse level uses ``coarse_sigma``.
    clutter_log_density : float
        ``ln lambda`` (1/m^2).
    fov : float
        Half-angle of the beam, rad.
    coarse_step, fine_step : tuple of float
        Grid steps ``(m, rad)``.
    coarse_sigma : float
        Range noise at the coarse level, m (covers the coarse cells).
    refine : int
        Coarse candidates refined on the fine grid.
    coarse_stride : int
        The coarse level scores every ``coarse_stride``-th acquisition only (consecutive
        acquisitions of a turn see the same landmarks).
    """

    def __init__(
        self,
        antennas: npt.ArrayLike,
        *,
        range_sigma: float = 0.05,
        clutter_log_density: float = 0.0,
        fov: float = np.radians(60.0),
        coarse_step: tuple[float, float] = (0.08, np.radians(1.5)),
        fine_step: tuple[float, float] = (0.08 / 3, np.radians(0.5)),
        coarse_sigma: float = 0.1,
        refine: int = 2,
        coarse_stride: int = 3,
    ) -> None:
        self.antennas = np.asarray(antennas, float)
        self.range_sigma = range_sigma
        self.clutter = clutter_log_density
        self.cos_fov = float(np.cos(fov))
        self.coarse_step = coarse_step
        self.fine_step = fine_step
        self.coarse_sigma = coarse_sigma
        self.refine = refine
        self.coarse_stride = coarse_stride

    def _pair_scores(
        self,
        poses: FloatArray,
        rel: FloatArray,
        pairs: list[FloatArray],
        lmap: MatchMap,
        sigma: float,
        bias: float,
        mount: float,
    ) -> list[FloatArray]:
        """Per acquisition, ``ln(lambda + sum_l N(z; h_l, sigma^2 I))`` of each pair, (n, m)."""
        out = []
        log_norm = -np.log(2 * np.pi * sigma**2)
        for a, z in enumerate(pairs):
            if z.shape[0] == 0:
                continue
            q = compose_poses(poses, rel[a])
            yaw = q[:, 2] + mount
            c, s = np.cos(yaw), np.sin(yaw)
            rot = np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)
            ant = np.einsum("nij,aj->nai", rot, self.antennas) + q[:, None, :2]
            r, vis = expected_ranges(lmap, ant[:, 0], ant[:, 1:], yaw, self.cos_fov)
            d2 = np.sum((z[None, None] - (r + bias)[:, :, None, :]) ** 2, -1)  # (n, L, m)
            ll = log_norm - 0.5 * d2 / sigma**2 + lmap.log_weight[None, :, None]
            ll = np.where(vis[..., None], ll, -np.inf)
            top = np.maximum(ll.max(1), self.clutter)  # (n, m)
            with np.errstate(divide="ignore"):
                lse = top + np.log(np.exp(self.clutter - top) + np.exp(ll - top[:, None]).sum(1))
            out.append(lse)
        return out

    def log_likelihood(
        self,
        poses: FloatArray,
        rel: FloatArray,
        pairs: list[FloatArray],
        lmap: MatchMap,
        *,
        sigma: float,
        bias: float = 0.0,
        mount: float = 0.0,
    ) -> FloatArray:
        """Sum over the acquisitions' pairs of the clutter-robust log-likelihood, shape (n,).

        Parameters
        ----------
        poses : ndarray, shape (n, 3)
            Candidate robot poses of the first acquisition.
        rel : ndarray, shape (A, 3)
            Pose of each acquisition in the frame of the first (odometry), ``rel[0] = 0``.
        pairs : list of ndarray, shape (m_a, 2)
            Echo pairs of each acquisition, m.
        sigma : float
            Range noise, m.
        bias, mount : float
            Range bias (m) and array mounting yaw (rad).
        """
        total = np.zeros(poses.shape[0])
        for lse in self._pair_scores(poses, rel, pairs, lmap, sigma, bias, mount):
            total += lse.sum(1) - self.clutter * lse.shape[1]
        return total

    def explained(
        self,
        pose: FloatArray,
        rel: FloatArray,
        pairs: list[FloatArray],
        lmap: MatchMap,
        *,
        bias: float = 0.0,
        mount: float = 0.0,
    ) -> int:
        """Pairs a landmark explains from ``pose`` (3,): within about 2.4 ``range_sigma``
        (their likelihood exceeds the clutter level's by 1.5 nepers)."""
        scores = self._pair_scores(pose[None], rel, pairs, lmap, self.range_sigma, bias, mount)
        return int(sum(np.sum(s - self.clutter > 1.5) for s in scores))

    def search(
        self,
        center: FloatArray,
        cov: FloatArray,
        rel: FloatArray,
        pairs: list[FloatArray],
        lmap: MatchMap,
        *,
        bias: float = 0.0,
        mount: float = 0.0,
        window: tuple[float, float] = (0.8, np.radians(25.0)),
    ) -> tuple[FloatArray, FloatArray]:
        """Fine-grid candidates around the best coarse poses and their log-posterior.

        The coarse grid spans three standard deviations of the prior ``cov`` around
        ``center`` (at least two coarse steps, at most ``window``).

        Returns
        -------
        poses : ndarray, shape (k, 3)
        log_post : ndarray, shape (k,)
            Unnormalised log-posterior (fine likelihood plus prior).
        """
        cov = np.asarray(cov, float) + np.diag(
            [self.fine_step[0] ** 2, self.fine_step[0] ** 2, self.fine_step[1] ** 2]
        )
        info = np.linalg.inv(cov)
        sd = np.sqrt(np.diag(cov))
        half_xy = np.clip(3 * sd[:2], 2 * self.coarse_step[0], window[0])
        half_yaw = np.clip(3 * sd[2], 2 * self.coarse_step[1], window[1])

        def axis(half: float, step: float) -> FloatArray:
            k = int(np.ceil(half / step - 1e-9))
            return np.arange(-k, k + 1) * step

        def prior(q: FloatArray) -> FloatArray:
            d = q - center
            return -0.5 * np.einsum("ni,ij,nj->n", d, info, d)

        def grid(base: FloatArray, axes: list[FloatArray]) -> FloatArray:
            mesh = np.meshgrid(*axes, indexing="ij")
            return base + np.stack([m.ravel() for m in mesh], -1)

        cs, cy = self.coarse_step
        coarse = grid(center, [axis(half_xy[0], cs), axis(half_xy[1], cs), axis(half_yaw, cy)])
        kw = {"bias": bias, "mount": mount}
        k = self.coarse_stride
        score = self.log_likelihood(
            coarse, rel[::k], pairs[::k], lmap, sigma=self.coarse_sigma, **kw
        )
        score += prior(coarse)
        best = coarse[np.argsort(score)[::-1][: self.refine]]
        fs, fy = self.fine_step
        local = [axis(cs, fs), axis(cs, fs), axis(cy, fy)]
        fine = np.unique(np.round(np.concatenate([grid(b, local) for b in best]), 9), axis=0)
        post = self.log_likelihood(fine, rel, pairs, lmap, sigma=self.range_sigma, **kw)
        return fine, post + prior(fine)
