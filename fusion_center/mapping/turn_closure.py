"""Heading of a turn on the spot from its own echoes: the turn's loop closure.

At each stop the bat-type robot turns almost a full circle in small steps whose angle the
algorithm does not know (Section 6 of the CoLOR chapter: room_pillar turns 357 degrees in
120 steps); the wheels report each step with slip noise, so the heading at the end of the
turn is off by the sum of the steps' errors (room_pillar: 1.5 degrees mean absolute per
turn), and every pose and landmark after the stop inherits it.

While the robot turns on the spot its transmitter stays put (it is the turning centre, the
origin of the robot frame), so every echo comes from a point fixed in the stop's frame: the
image ``T'`` of the transmitter in a wall or a corner, or a point scatterer (Fig. 19 and
eq. (11) of the CoLOR chapter; higher-order specular paths are images too). The pair of
ranges at Rx1 and Rx2 gives that point's bearing ``beta`` in the array frame (the circles'
intersection, :func:`~fusion_center.mapping.models.invert_image`), and its world bearing is
``theta_k + beta`` with ``theta_k`` the robot's heading at acquisition ``k`` (eq. (7)-(10)):
constant over all the acquisitions that see it. A reflector seen at the start of the turn
comes back into view at its end (the horns see +-60 degrees, the turn leaves out 3), which
closes the loop.

:class:`EchoBearingTurnCloser` estimates the heading correction ``e_k`` of every
acquisition of one stop (``theta_k = phi_k + e_k``, ``phi_k`` the odometry's heading
relative to the stop's first acquisition, ``e_0 = 0``) by linear least squares over

* one equation per echo pair: ``e_k - psi_c = -(phi_k + beta)``, with ``psi_c`` the unknown
  world bearing of the reflector ``c`` the pair belongs to (echo tracks of
  :class:`~fusion_center.mapping.grouping.KalmanEchoGrouper`, joined into reflectors by their
  range and odometry bearing, across the turn's wrap too), Cauchy-reweighted against clutter;
* the odometry's random walk: ``e_k - e_{k-1} ~ N(0, sigma_k^2)`` with ``sigma_k`` the slip
  noise of step ``k`` (as in :class:`~fusion_center.mapping.rbpf.RbpfSlam`'s motion model).

Beyond the chapter (which estimates the unknown rotation inside the particle filter): a
rotation-only bundle adjustment of one stop, solved before the filter sees the stop.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from fusion_center.mapping.models import invert_image

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True, slots=True, kw_only=True)
class TurnClosureConfig:
    """Parameters of :class:`EchoBearingTurnCloser` (SI units).

    Attributes
    ----------
    range_sigma : float
        Noise of one echo range, m (sets the bearing noise of a pair: ``sqrt(2) sigma / (a
        cos beta)`` for a baseline ``a``).
    slip_rotation, slip_floor : float
        Odometry noise of one turning step: rad per rad turned, and rad per step.
    link_range, link_bearing : float
        Gates that join two echo tracks into one reflector: image distance (m) and world
        bearing from the odometry (rad; covers the odometry's drift over one turn).
    min_turn : float
        Smallest turn (sum of the odometry's steps), rad, for which the first and last
        acquisitions can see the same reflectors; shorter turns are left alone.
    min_links : int
        Reflectors seen both in the first and in the last third of the turn (with at least
        ``min_link_pairs`` pairs in each) the closure needs; otherwise no correction. The
        default, 2, means two distinct reflectors: one alone (often far clutter) is not
        trusted.
    min_link_pairs : int
        Pairs a reflector needs in each of the two thirds to count as a link.
    cauchy_scale : float
        Scale of the Cauchy reweighting, in bearing sigmas.
    iterations : int
        Reweighting rounds.
    max_correction : float
        Largest accepted correction at any acquisition of the turn, rad (a larger one, also
        an excursion mid-turn that returns near zero at its end, is a wrong link: no
        correction).
    cluster_noise : bool
        Scale each reflector's bearing noise by its robust residual scatter.
    link_scatter : float
        Largest robust scatter (1.4826 MAD, rad) of a link's world bearings (by the
        odometry) within each of the two thirds; a reflector scattering more on either side
        is no link (a heuristic beyond the chapter). A fixed image keeps its world bearing
        up to the slip over its span and the bearing noise, an echo track that sweeps with
        the robot (no fixed image) does not, and joined to a reflector seen at the other end
        it closes the turn wrongly. Measured on 8 recordings: right links 0.2-5 degrees (far
        images scatter by degrees), lab_skew seed 6's sweeping 4.07 m track 7.6, so the two
        overlap. Default inf (no test; see ``StopGraphConfig.closure_link_scatter``).

    Raises
    ------
    ValueError
        A non-positive noise, gate, scale or turn, a negative ``slip_rotation``, or
        ``min_links``, ``min_link_pairs`` or ``iterations`` below 1.
    """

    range_sigma: float = 0.01
    slip_rotation: float = 0.03
    slip_floor: float = np.radians(0.1)
    link_range: float = 0.1
    link_bearing: float = np.radians(8.0)
    min_turn: float = np.radians(300.0)
    min_links: int = 2
    min_link_pairs: int = 3
    cauchy_scale: float = 3.0
    iterations: int = 6
    max_correction: float = np.radians(8.0)
    cluster_noise: bool = True
    link_scatter: float = np.inf

    def __post_init__(self) -> None:
        # a zero floor makes a zero odometry step a zero-variance prior (1/0 in the solve)
        for name in (
            "range_sigma",
            "slip_floor",
            "link_range",
            "link_bearing",
            "min_turn",
            "cauchy_scale",
            "max_correction",
        ):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0.0):
                raise ValueError(f"TurnClosureConfig.{name} must be > 0, got {v!r}")
        if not self.link_scatter > 0.0:  # inf: no test
            raise ValueError(
                f"TurnClosureConfig.link_scatter must be > 0, got {self.link_scatter!r}"
            )
        if not (np.isfinite(self.slip_rotation) and self.slip_rotation >= 0.0):
            raise ValueError(
                f"TurnClosureConfig.slip_rotation must be >= 0, got {self.slip_rotation!r}"
            )
        for name in ("min_links", "min_link_pairs", "iterations"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int | np.integer) or v < 1:
                raise ValueError(f"TurnClosureConfig.{name} must be an integer >= 1, got {v!r}")


@dataclass(frozen=True, slots=True)
class TurnClosure:
    """Result of one stop: ``correction`` (rad, shape (n,), ``e_k``; ``e_0`` = 0), its standard
    deviation at the last acquisition (rad, inf when the stop was not corrected), the
    reflectors that close the loop and the RMS over the turn of every acquisition's
    marginal standard deviation (rad, from the same inverse normal matrix; inf when not
    corrected)."""

    correction: FloatArray
    end_sigma: float
    links: int
    rms_sigma: float = float("inf")

    @property
    def step_sigma(self) -> FloatArray:
        """The noise per turning step, rad, shape (n,): that of a random walk which
        accumulates to ``end_sigma`` over the turn's n - 1 steps, ``end_sigma / sqrt(n - 1)``
        (``step_sigma[0]`` = 0: the drive to the stop is not estimated; empty when the stop
        was not corrected). Not each step's own posterior: the echoes fix the heading over
        the turn, not its single steps, whose marginal deviations stay near the slip noise
        (room_pillar: 0.185 against 0.19 degrees) while their sum is known far better (the
        steps' errors are anti-correlated)."""
        n = self.correction.size
        if not np.isfinite(self.end_sigma) or n < 2:
            return np.zeros(0)
        return np.r_[0.0, np.full(n - 1, self.end_sigma / np.sqrt(n - 1))]


class EchoBearingTurnCloser:
    """Heading corrections of one turn on the spot from its echo bearings (see the module).

    Parameters
    ----------
    rx_body : array_like, shape (2, 2)
        Receivers in the array frame (transmitter at the origin), m.
    config : TurnClosureConfig
    """

    def __init__(self, rx_body: npt.ArrayLike, config: TurnClosureConfig | None = None) -> None:
        self.rx_body = np.asarray(rx_body, float).reshape(2, 2)
        self.baseline = float(np.linalg.norm(self.rx_body[1] - self.rx_body[0]))
        self.config = config or TurnClosureConfig()

    def close(
        self,
        dyaw: npt.ArrayLike,
        pairs: list[FloatArray],
        groups: list[npt.NDArray[np.int64]],
    ) -> TurnClosure:
        """Heading corrections of the acquisitions of one stop.

        Parameters
        ----------
        dyaw : array_like, shape (n,)
            Odometry rotation of each acquisition since the previous one, rad (the first
            entry, the drive to the stop, is ignored).
        pairs : list of ndarray, shape (m_k, 2)
            Echo pairs ``(r1, r2)`` of each acquisition, m.
        groups : list of ndarray of int, shape (m_k,)
            Echo-track ids of the pairs.
        """
        cfg = self.config
        dyaw = np.asarray(dyaw, float).copy()
        n = dyaw.size
        dyaw[0] = 0.0
        phi = np.cumsum(dyaw)
        none = TurnClosure(np.zeros(n), np.inf, 0)
        if n < 3 or abs(phi[-1]) < cfg.min_turn:
            return none
        k = np.concatenate([np.full(len(z), i) for i, z in enumerate(pairs)]).astype(np.intp)
        if k.size == 0:
            return none
        z = np.concatenate([np.reshape(z, (-1, 2)) for z in pairs])
        gid = np.concatenate([np.asarray(g, np.int64) for g in groups])
        u = invert_image(z, self.rx_body)
        ok = np.all(np.isfinite(u), 1)
        k, z, gid, u = k[ok], z[ok], gid[ok], u[ok]
        if k.size == 0:
            return none
        beta = np.arctan2(u[:, 1], u[:, 0])
        rho = np.hypot(u[:, 0], u[:, 1])
        world = phi[k] + beta
        sig_b = np.sqrt(2.0) * cfg.range_sigma / (self.baseline * np.maximum(np.cos(beta), 0.3))
        cluster = self.reflectors(gid, rho, world)
        # links across the wrap: a reflector seen in the first and in the last third of
        # the turn (by odometry heading), with enough pairs on each side
        third = abs(phi[-1]) / 3.0
        early = np.abs(phi[k]) < third
        late = np.abs(phi[k]) > 2.0 * third
        nc = int(cluster.max()) + 1
        n_early = np.bincount(cluster[early], minlength=nc)
        n_late = np.bincount(cluster[late], minlength=nc)
        is_link = (n_early >= cfg.min_link_pairs) & (n_late >= cfg.min_link_pairs)
        if np.isfinite(cfg.link_scatter):
            is_link &= self._side_scatter(world, cluster, nc, early, late) <= cfg.link_scatter
        links = int(np.sum(is_link))
        if links < cfg.min_links:
            return TurnClosure(np.zeros(n), np.inf, links)
        e, end_sigma, rms_sigma = self._solve(n, dyaw, k, world, sig_b, cluster, nc)
        # the whole turn, not only its end: a wrong link can bend the middle of the turn
        # by degrees and still return near zero at its end
        if not np.all(np.isfinite(e)) or np.max(np.abs(e)) > cfg.max_correction:
            return TurnClosure(np.zeros(n), np.inf, links)
        return TurnClosure(e, end_sigma, links, rms_sigma)

    @staticmethod
    def _side_scatter(
        world: FloatArray,
        cluster: npt.NDArray,
        nc: int,
        early: npt.NDArray[np.bool_],
        late: npt.NDArray[np.bool_],
    ) -> FloatArray:
        """Per reflector, the larger of its early and late pairs' robust world-bearing
        scatter (1.4826 MAD about each side's circular mean), rad, shape (nc,); 0 for a
        reflector without pairs on a side. ``world`` (rad), ``cluster`` (reflector index)
        and the side masks are per pair."""
        out = np.zeros(nc)
        for side in (early, late):  # two sides, vectorised over the reflectors
            c, w = cluster[side], world[side]
            mean = np.arctan2(np.bincount(c, np.sin(w), nc), np.bincount(c, np.cos(w), nc))
            dev = np.abs((w - mean[c] + np.pi) % (2 * np.pi) - np.pi)
            out = np.maximum(out, 1.4826 * group_median(dev, c, nc))
        return out

    def reflectors(self, gid: npt.NDArray, rho: FloatArray, world: FloatArray) -> npt.NDArray:
        """Reflector index (0 .. R-1) of every pair of one turn: its echo tracks joined when
        their mean image distances (m) lie within ``link_range`` and their mean world
        bearings (rad) within ``link_bearing``, by complete linkage (every two tracks of a
        reflector within both gates; the closest pairs first).

        Parameters
        ----------
        gid : ndarray of int, shape (m,)
            Echo-track id of every pair.
        rho : ndarray, shape (m,)
            Distance of every pair's image point ``T'`` from the transmitter, m.
        world : ndarray, shape (m,)
            World bearing of every pair's image (heading plus the bearing in the array), rad.
        """
        cfg = self.config
        tracks, inv = np.unique(gid, return_inverse=True)
        t = tracks.size
        cnt = np.bincount(inv, minlength=t).astype(float)
        r = np.bincount(inv, rho, t) / cnt
        c = np.bincount(inv, np.cos(world), t)
        s = np.bincount(inv, np.sin(world), t)
        ang = np.arctan2(s, c)
        dr = np.abs(r[:, None] - r[None, :])
        da = np.abs((ang[:, None] - ang[None, :] + np.pi) % (2 * np.pi) - np.pi)
        near = (dr < cfg.link_range) & (da < cfg.link_bearing)
        # complete linkage: every two tracks of a reflector within the gates (single linkage
        # chained the far clutter at one range all round the circle into one "reflector")
        label = np.arange(t)
        ii, jj = np.nonzero(np.triu(near, 1))
        order = np.argsort(dr[ii, jj] / cfg.link_range + da[ii, jj] / cfg.link_bearing)
        for i, j in zip(ii[order], jj[order], strict=True):
            a, b = label[i], label[j]
            if a == b:
                continue
            ma, mb = label == a, label == b
            if np.all(near[np.ix_(ma, mb)]):
                label[mb] = a
        return np.unique(label, return_inverse=True)[1][inv]

    def _solve(
        self,
        n: int,
        dyaw: FloatArray,
        k: npt.NDArray[np.intp],
        world: FloatArray,
        sig_b: FloatArray,
        cluster: npt.NDArray,
        nc: int,
    ) -> tuple[FloatArray, float, float]:
        """Weighted least squares over ``[e_1 .. e_{n-1}, psi_0 .. psi_{nc-1}]``: the
        corrections, the end's standard deviation and the RMS of all the corrections'
        standard deviations (``e_0`` = 0 included), from the inverse of the last round's
        normal matrix."""
        cfg = self.config
        # unwrap every pair's world bearing next to its reflector's mean
        cm = np.arctan2(
            np.bincount(cluster, np.sin(world), nc), np.bincount(cluster, np.cos(world), nc)
        )
        obs = cm[cluster] + (world - cm[cluster] + np.pi) % (2 * np.pi) - np.pi
        m = n - 1 + nc
        # odometry random walk: e_k - e_{k-1}
        s_step = cfg.slip_rotation * np.abs(dyaw[1:]) + cfg.slip_floor
        a_prior = np.zeros((m, m))
        w = 1.0 / s_step**2
        idx = np.arange(n - 1)
        a_prior[idx, idx] += w
        a_prior[idx[:-1], idx[:-1]] += w[1:]
        a_prior[idx[1:], idx[:-1]] -= w[1:]
        a_prior[idx[:-1], idx[1:]] -= w[1:]
        # pairs: e_k - psi_c = -obs (e_0 = 0 is fixed)
        col_e = k - 1
        col_c = n - 1 + cluster
        has_e = k > 0
        rw = np.ones(k.size)
        x = np.zeros(m)
        for _ in range(max(cfg.iterations, 1)):
            wt = rw / sig_b**2
            a = a_prior.copy()
            b = np.zeros(m)
            np.add.at(a, (col_c, col_c), wt)
            np.add.at(b, col_c, wt * obs)
            ce, we = col_e[has_e], wt[has_e]
            np.add.at(a, (ce, ce), we)
            np.add.at(a, (ce, col_c[has_e]), -we)
            np.add.at(a, (col_c[has_e], ce), -we)
            np.add.at(b, ce, -we * obs[has_e])
            # a reflector seen by no pair with weight keeps its row regular
            a[n - 1 :, n - 1 :] += 1e-9 * np.eye(nc)
            x = np.linalg.solve(a, b)
            e = np.r_[0.0, x[: n - 1]]
            res = e[k] - x[col_c] + obs
            if cfg.cluster_noise:
                # each reflector's own bearing scatter (far images from higher-order paths
                # scatter by degrees, a near wall's by a tenth): a robust std per reflector
                sig = np.maximum(sig_b, 1.4826 * group_median(np.abs(res), cluster, nc)[cluster])
            else:
                sig = sig_b
            rw = (sig_b / sig) ** 2 / (1.0 + (res / (cfg.cauchy_scale * sig)) ** 2)
        var = np.diag(np.linalg.inv(a))[: n - 1]
        end_sigma = float(np.sqrt(max(var[n - 2], 0.0)))
        rms_sigma = float(np.sqrt(np.sum(np.maximum(var, 0.0)) / n))
        return np.r_[0.0, x[: n - 1]], end_sigma, rms_sigma


def group_median(x: FloatArray, group: npt.NDArray, n: int) -> FloatArray:
    """Median of ``x`` per group index 0 .. n-1 (0 for an empty group)."""
    order = np.lexsort((x, group))
    xs, gs = x[order], group[order]
    start = np.searchsorted(gs, np.arange(n))
    cnt = np.bincount(gs, minlength=n)
    lo = np.minimum(start + np.maximum(cnt - 1, 0) // 2, max(xs.size - 1, 0))
    hi = np.minimum(start + cnt // 2, max(xs.size - 1, 0))
    if xs.size == 0:
        return np.zeros(n)
    return np.where(cnt > 0, 0.5 * (xs[lo] + xs[hi]), 0.0)
