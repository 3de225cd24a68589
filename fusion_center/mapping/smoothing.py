"""Joint least-squares smoothing of the robot's path and the landmarks (graph SLAM).

The Rao-Blackwellized particle filter of :mod:`fusion_center.mapping.rbpf` (Section 6 of the
CoLOR chapter) never revises a landmark together with the poses it was seen from: a landmark
placed from a pose that was 0.2 m off stays 0.2 m off, and later stops are matched against it.
This module goes beyond the chapter with the well-known batch alternative, graph SLAM /
bundle adjustment (Lu and Milios 1997; Thrun and Montemerlo 2006, "The GraphSLAM
algorithm"): after the filter, all robot poses and all landmarks are re-estimated at once
by robust non-linear least squares over

* the odometry between consecutive key poses (slip noise of the odometry's own model),
* every echo pair ``(r1, r2)`` associated with a landmark (the Fig. 19 models of
  :mod:`fusion_center.mapping.models`, range noise ``range_sigma``),

with ``scipy.optimize.least_squares`` (trust region, sparse Jacobian by grouped finite
differences, a Cauchy loss on the echoes against wrong associations). The filter gives the
initial guess (its trajectory and the heaviest particle's landmarks with their kinds). The
associations are re-made from the current estimate before each round: every echo group of
the measurement-space association (:mod:`fusion_center.mapping.grouping`) goes to the landmark
whose predicted echoes explain the group best (gated per pair), so a group stays one
landmark as in Section 6.3; the pairs left over are then tested per stop, together, against
each landmark with one common range offset (``SmootherConfig.stop_gate``: a stop placed off by
its odometry puts all its echoes of a wall off alike).

Poses: one key pose ``[x, y, yaw]`` per ``keyframe_step`` acquisitions and at every drive;
the acquisitions between key poses hang off their key pose through the recorded odometry.
The first key pose is held fixed (it defines the map frame). The number of distinct stops
from which a landmark's echoes come (``stops``) is the support used to prune the map
(:func:`smoothed_landmark_set`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt
import scipy.sparse as sp
from scipy.optimize import least_squares

from fusion_center.mapping.features import LandmarkSet
from fusion_center.mapping.models import (
    CORNER,
    POINT,
    WALL,
    invert_image,
    predict,
    rotate,
    wall_tangent,
)
from fusion_center.mapping.turn_closure import group_median

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]


@dataclass(frozen=True, slots=True, kw_only=True)
class SmootherConfig:
    """Parameters of :class:`LeastSquaresPathMapSmoother` (SI units).

    Attributes
    ----------
    keyframe_step : int
        Acquisitions per key pose (a drive always starts a new one).
    keyframe_turn : float
        A turn of at least this since the last key pose (the sum of the odometry's
        ``|dyaw|``) also starts a key pose, rad (0: off). The acquisitions between key poses
        hang off theirs through the odometry alone, so their echoes cannot correct the
        heading they drift by in between: at 15-degree steps 5 acquisitions are 75 degrees
        of turn (corridor_L_sparse).
    drive_distance : float
        Odometry translation of one step, m, that counts as a drive to a new stop.
    range_sigma : float
        Standard deviation of one bistatic range, m.
    gate : float
        A pair is associated with a landmark only if both its ranges are within this of the
        landmark's predicted echoes, m.
    loss_scale : float
        Echo residual, in standard deviations, beyond which the Cauchy loss discounts it
        (the odometry's residuals stay quadratic).
    rounds : int
        Association and optimisation rounds.
    max_nfev : int
        Function evaluations of one optimisation (scipy's ``max_nfev``).
    slip_translation, slip_rotation, slip_heading_per_metre : float
        Odometry noise per step: m per m driven, rad per rad turned, rad per m driven.
    slip_floor : tuple of float
        Odometry noise per step without motion: (m, rad).
    fov : float
        Half-angle around the array boresight within which landmarks echo, rad.
    landmark_prior : float
        Weak prior on every landmark around its initial value (m, or rad for a wall's
        normal), which keeps landmarks without any associated echo determined.
    extent_quantile : float
        A wall's extent spans these quantiles of its specular points.
    merge_dist, merge_angle : float
        Between rounds, walls whose lines are within ``merge_dist`` (m) and ``merge_angle``
        (rad) predict the same echoes and are merged into one (0: off).
    merge_point_dist : float
        Between rounds, corners and points closer than this are merged (m; 0: off).
    refit_kinds : bool
        Between rounds, every landmark with echoes from at least 2 stops is fitted alone, at
        the current poses, both as a wall and as a point-like landmark (its own kind, or the
        better of corner and point for a wall); it changes kind when the other fit's robust
        cost is below ``kind_switch_ratio`` times its own.
    stop_gate : float
        Pairs beyond ``gate`` but within this (m) of a landmark's prediction at both
        receivers are associated with it jointly per stop: when at least ``stop_min_pairs``
        of one stop's pairs lie within ``gate`` of one common range offset (with one
        receivers' difference) and no pair of that stop is associated with the landmark
        already
        (:meth:`LeastSquaresPathMapSmoother._associate_by_stop`; 0 or anything up to
        ``gate``: off, the default; :meth:`EchoSlamMapper.smooth
        <fusion_center.mapping.pipeline.EchoSlamMapper.smooth>` sets 0.6 m with state-space
        association). corridor_L_sparse seed 1: the third stop's 11 echoes of the two side
        walls were 0.4-0.5 m from their prediction (the walls turned by the first stop's
        heading drift, the stop placed by odometry) and never used.
    stop_min_pairs : int
        Pairs a stop's joint association needs (>= 1).
    sigma_floor : float
        With a value above 0, each landmark's range noise is the robust scale of its
        associated pairs' residuals (1.4826 times the median of each pair's mean absolute
        residual over the two receivers, taken afresh before each round: exact for one
        Gaussian, about 10 % high when the receivers' residuals are independent, so on the
        safe side), at least this and at most ``range_sigma``, m; 0: every
        landmark has ``range_sigma``. The same rule as the stop graph's bundle adjustment
        (:func:`~fusion_center.mapping.stop_bundle.adjust_stop_bundle`, which uses 1 cm):
        a wall echoes within millimetres (corridor_L_sparse at the true path: 2-3 mm robust
        residual scale), while ``range_sigma`` is sized for the filter's landmarks, which
        are themselves off; at 5 cm a pair's range difference (its bearing, eq. (7)-(10))
        weighs less than one step of the odometry's heading.
    """

    keyframe_step: int = 5
    drive_distance: float = 0.1
    range_sigma: float = 0.05
    gate: float = 0.25
    loss_scale: float = 3.0
    rounds: int = 3
    max_nfev: int = 40
    slip_translation: float = 0.02
    slip_rotation: float = 0.03
    slip_heading_per_metre: float = np.radians(1.0)
    slip_floor: tuple[float, float] = (0.002, np.radians(0.1))
    fov: float = np.radians(60.0)
    landmark_prior: float = 1.0
    extent_quantile: float = 0.05
    merge_dist: float = 0.0
    merge_angle: float = np.radians(8.0)
    merge_point_dist: float = 0.0
    refit_kinds: bool = False
    kind_switch_ratio: float = 0.7
    stop_gate: float = 0.0
    stop_min_pairs: int = 3
    keyframe_turn: float = 0.0
    sigma_floor: float = 0.0

    def __post_init__(self) -> None:
        if not 0.0 < self.kind_switch_ratio <= 1.0:
            # above 1 both kinds "fit clearly better" than each other: kinds flip every round
            raise ValueError(f"kind_switch_ratio must be in (0, 1], got {self.kind_switch_ratio}")
        if self.merge_dist < 0.0 or self.merge_point_dist < 0.0 or self.merge_angle < 0.0:
            raise ValueError("merge_dist, merge_point_dist and merge_angle must be >= 0")
        if not 0.0 <= self.stop_gate < np.inf:
            # inf would make every in-view pair a candidate of every landmark
            raise ValueError(f"stop_gate must be finite and >= 0, got {self.stop_gate}")
        if not self.keyframe_turn >= 0.0:
            raise ValueError(f"keyframe_turn must be >= 0, got {self.keyframe_turn}")
        if not 0.0 <= self.sigma_floor <= self.range_sigma:
            raise ValueError(f"sigma_floor must be in [0, range_sigma], got {self.sigma_floor}")
        k = self.stop_min_pairs
        if isinstance(k, bool) or not isinstance(k, int | np.integer) or k < 1:
            raise ValueError(f"stop_min_pairs must be an integer >= 1, got {k!r}")


@dataclass(frozen=True, slots=True, kw_only=True)
class SmoothedPathMap:
    """Result of :meth:`LeastSquaresPathMapSmoother.smooth`.

    Attributes
    ----------
    poses : ndarray, shape (n, 3)
        ``[x, y, yaw]`` of every acquisition, first-pose frame (m, rad).
    kinds : ndarray of int, shape (l,)
        Landmark kinds (:data:`~fusion_center.mapping.models.WALL`, ``CORNER``, ``POINT``).
    states : ndarray, shape (l, 2)
        Landmark states: ``(alpha, d)`` of a wall, ``(x, y)`` of a corner or point.
    pairs : ndarray of int, shape (l,)
        Echo pairs associated with each landmark.
    stops : ndarray of int, shape (l,)
        Distinct stops (runs of acquisitions between drives) those pairs come from.
    wall_extent : ndarray, shape (l, 2)
        ``(t_min, t_max)`` of the specular points along a wall (NaN for other kinds), m.
    cost_before, cost_after : float
        Robust cost of the first and the last optimisation round, at their start and end.
    observer : ndarray, shape (l, 2)
        Mean robot position ``(x, y)`` of the acquisitions whose pairs are associated with
        each landmark (NaN for none), m: for a landmark heard from one stop, that stop.
    association : ndarray of int, shape (m,)
        Landmark of every echo pair after the final association (-1: none), in the order of
        the acquisitions' pairs as given to :meth:`LeastSquaresPathMapSmoother.smooth`.
    pair_stop : ndarray of int, shape (m,)
        Stop (run of acquisitions between drives, counted from 0) of every echo pair.
    """

    poses: FloatArray
    kinds: IntArray
    states: FloatArray
    pairs: IntArray
    stops: IntArray
    wall_extent: FloatArray
    cost_before: float
    cost_after: float
    observer: FloatArray = field(default_factory=lambda: np.zeros((0, 2)))
    association: IntArray = field(default_factory=lambda: np.zeros(0, np.int64))
    pair_stop: IntArray = field(default_factory=lambda: np.zeros(0, np.int64))


def _compose(a: FloatArray, b: FloatArray) -> FloatArray:
    """Poses ``a`` (..., 3) followed by increments ``b`` (..., 3) in their frame."""
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    return np.stack(
        [
            a[..., 0] + c * b[..., 0] - s * b[..., 1],
            a[..., 1] + s * b[..., 0] + c * b[..., 1],
            a[..., 2] + b[..., 2],
        ],
        -1,
    )


def _wrap(a: FloatArray) -> FloatArray:
    return (a + np.pi) % (2 * np.pi) - np.pi


def merge_duplicates(
    kinds: IntArray,
    states: FloatArray,
    support: FloatArray,
    *,
    wall_dist: float,
    wall_angle: float,
    point_dist: float,
) -> tuple[IntArray, FloatArray]:
    """Merge landmarks that predict the same echoes: walls on nearly the same line, and
    corners or points close together (the filter places one face again from a pose that
    was off, and the copies then split its echoes between them).

    Parameters
    ----------
    kinds : ndarray of int, shape (l,)
    states : ndarray, shape (l, 2)
        ``(alpha, d)`` of walls, ``(x, y)`` of corners and points.
    support : ndarray, shape (l,)
        Echo pairs of each landmark: the best supported one of a group keeps its kind, and the
        merged state is the support-weighted mean.
    wall_dist, wall_angle, point_dist : float
        Merge thresholds, m and rad (0: no merging of that kind).

    Returns
    -------
    (ndarray of int, ndarray)
        The merged kinds and states; the landmarks keep their order (a merged group sits
        where its best supported member was).
    """
    n = kinds.size
    alive = np.ones(n, bool)
    # a merged group's survivor is finished: tested again with its moved state and summed
    # support, it could be absorbed into a weaker landmark it was never close to (review)
    done = np.zeros(n, bool)
    st = states.copy()
    w = np.maximum(support.astype(float), 1e-3)
    nrm = np.stack([np.cos(st[:, 0]), np.sin(st[:, 0])], -1)
    wall = kinds == WALL
    for i in np.argsort(-w):
        if not alive[i]:
            continue
        if wall[i]:
            if wall_dist <= 0.0:
                continue
            same = (
                alive
                & ~done
                & wall
                & (nrm @ nrm[i] >= np.cos(wall_angle))
                & (np.abs(st[:, 1] - st[i, 1]) <= wall_dist)
            )
            ww = w[same] / w[same].sum()
            m = ww @ nrm[same]
            st[i] = [np.arctan2(m[1], m[0]), ww @ st[same, 1]]
        else:
            if point_dist <= 0.0:
                continue
            same = alive & ~done & ~wall & (np.hypot(*(st[:, :2] - st[i, :2]).T) <= point_dist)
            ww = w[same] / w[same].sum()
            st[i] = ww @ st[same]
        w[i] = w[same].sum()
        same[i] = False
        alive &= ~same
        done[i] = True
    return kinds[alive], st[alive]


class LeastSquaresPathMapSmoother:
    """Graph-SLAM smoothing of a robot path and its echo landmarks (see the module docstring).

    Parameters
    ----------
    antennas : array_like, shape (3, 2)
        tx, rx1, rx2 in the robot frame (x forward, y left), m.
    config : SmootherConfig
    bias : float
        Range bias added to every predicted range, m (the filter's estimate).
    mount : float
        Array orientation relative to the robot's heading, rad (the filter's estimate).
    """

    def __init__(
        self,
        antennas: npt.ArrayLike,
        config: SmootherConfig | None = None,
        *,
        bias: float = 0.0,
        mount: float = 0.0,
    ) -> None:
        self.config = config or SmootherConfig()
        self.antennas = np.asarray(antennas, float)
        if self.antennas.shape != (3, 2):
            raise ValueError("antennas must be tx, rx1, rx2 positions, shape (3, 2)")
        self.bias = float(bias)
        self.mount = float(mount)

    # --- geometry -----------------------------------------------------------------------------

    def _array(self, poses: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """World tx (n, 2), rx (n, 2, 2) and boresight yaw (n,) at robot poses (n, 3)."""
        yaw = poses[:, 2] + self.mount
        c, s = np.cos(yaw), np.sin(yaw)
        rot = np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)
        ant = np.einsum("nij,aj->nai", rot, self.antennas) + poses[:, None, :2]
        return ant[:, 0], ant[:, 1:], yaw

    def _predict(
        self, kinds: IntArray, states: FloatArray, tx: FloatArray, rx: FloatArray
    ) -> tuple[FloatArray, npt.NDArray[np.bool_], FloatArray]:
        """Predicted ranges (..., 2), in-beam test and echo direction, per element's kind."""
        shape = np.broadcast_shapes(kinds.shape, tx.shape[:-1])
        ranges = np.zeros((*shape, 2))
        direction = np.zeros((*shape, 2))
        ok = np.ones(shape, bool)
        kinds_b = np.broadcast_to(kinds, shape)
        states_b = np.broadcast_to(states, (*shape, 2))
        tx_b = np.broadcast_to(tx, (*shape, 2))
        rx_b = np.broadcast_to(rx, (*shape, 2, 2))
        for kind in (WALL, CORNER, POINT):
            m = kinds_b == kind
            if not np.any(m):
                continue
            r, _, d = predict(kind, states_b[m], tx_b[m], rx_b[m])
            ranges[m] = r + self.bias
            direction[m] = d
            if kind == WALL:
                st = states_b[m]
                n = np.stack([np.cos(st[:, 0]), np.sin(st[:, 0])], -1)
                ok[m] = st[:, 1] - np.sum(n * tx_b[m], -1) > 0.05
        return ranges, ok, direction

    def fit_alone(
        self,
        kind: int,
        states: FloatArray,
        lm: IntArray,
        z: FloatArray,
        tx: FloatArray,
        rx: FloatArray,
        iterations: int = 6,
    ) -> tuple[FloatArray, FloatArray]:
        """Fit every landmark as ``kind`` to its own echoes, poses held fixed.

        Iteratively reweighted Gauss-Newton on the Fig. 19 model with the Cauchy loss,
        vectorised over landmarks (each has 2 unknowns).

        Parameters
        ----------
        kind : int
        states : ndarray, shape (l, 2)
            Initial states.
        lm : ndarray of int, shape (m,)
            Landmark of every echo pair.
        z : ndarray, shape (m, 2)
            The pairs' ranges, m.
        tx, rx : ndarray, shapes (m, 2) and (m, 2, 2)
            World antennas at each pair's pose, m.

        Returns
        -------
        (ndarray of shape (l, 2), ndarray of shape (l,))
            Fitted states and the robust cost ``sum 0.5 c^2 log(1 + res^2 / c^2)`` of each.
        """
        cfg = self.config
        st = np.array(states, float)
        n = st.shape[0]
        c2 = cfg.loss_scale**2
        for _ in range(iterations):
            r, jac, _ = predict(kind, st[lm], tx, rx)
            res = (z - r - self.bias) / cfg.range_sigma
            w = 1.0 / (1.0 + res**2 / c2)
            jn = jac / cfg.range_sigma
            a = np.einsum("mj,mjk,mjl->mkl", w, jn, jn).reshape(-1, 4)
            g = np.einsum("mj,mjk,mj->mk", w, jn, res)
            a_l = np.stack([np.bincount(lm, a[:, i], minlength=n) for i in range(4)], -1)
            g_l = np.stack([np.bincount(lm, g[:, i], minlength=n) for i in range(2)], -1)
            a_l = a_l.reshape(-1, 2, 2) + 1e-3 * np.eye(2)
            step = np.linalg.solve(a_l, g_l[..., None])[..., 0]
            # a step of more than 0.3 m (or rad) is a poor linearisation: shorten it
            norm = np.linalg.norm(step, axis=1, keepdims=True)
            st += step * np.minimum(1.0, 0.3 / np.maximum(norm, 1e-12))
        r, _, _ = predict(kind, st[lm], tx, rx)
        res = (z - r - self.bias) / cfg.range_sigma
        cost = np.bincount(lm, 0.5 * c2 * np.log1p(res**2 / c2).sum(1), minlength=n)
        return st, cost

    def refit_kinds(
        self,
        kinds: IntArray,
        states: FloatArray,
        lm: IntArray,
        z: FloatArray,
        poses: FloatArray,
        stops: IntArray,
    ) -> tuple[IntArray, FloatArray]:
        """Re-decide wall against point-like for every landmark seen from 2 stops or more
        (``SmootherConfig.refit_kinds``): each is fitted alone both ways at the current
        poses (a wall as a corner and as a point, the cheaper counting), and the kind changes
        when the other fit costs less than ``kind_switch_ratio`` times its own.

        Parameters
        ----------
        kinds, states : ndarray, shapes (l,) and (l, 2)
        lm : ndarray of int, shape (m,)
            Landmark of every associated pair.
        z : ndarray, shape (m, 2)
            The pairs' ranges, m.
        poses : ndarray, shape (m, 3)
            Robot pose of each pair, m and rad.
        stops : ndarray of int, shape (l,)
            Distinct stops each landmark's pairs come from.
        """
        n = kinds.size
        if n == 0 or lm.size == 0:
            return kinds, states
        tx, rx, _ = self._array(poses)
        cnt = np.maximum(np.bincount(lm, minlength=n), 1)
        mean_tx = np.stack([np.bincount(lm, tx[:, i], minlength=n) for i in range(2)], -1)
        mean_tx /= cnt[:, None]
        wall = kinds == WALL
        # initial wall of a point-like landmark: the line through it facing the robot
        to = states - mean_tx
        alpha = np.arctan2(to[:, 1], to[:, 0])
        as_wall = np.where(
            wall[:, None],
            states,
            np.column_stack(
                [alpha, np.sum(np.stack([np.cos(alpha), np.sin(alpha)], -1) * states, 1)]
            ),
        )
        # initial point of a wall: the mean of its specular points
        nrm = np.stack([np.cos(states[:, 0]), np.sin(states[:, 0])], -1)
        foot = tx + (states[lm, 1] - np.sum(nrm[lm] * tx, 1))[:, None] * nrm[lm]
        mean_foot = np.stack([np.bincount(lm, foot[:, i], minlength=n) for i in range(2)], -1)
        as_point = np.where(wall[:, None], mean_foot / cnt[:, None], states)
        st_w, cost_w = self.fit_alone(WALL, as_wall, lm, z, tx, rx)
        st_c, cost_c = self.fit_alone(CORNER, as_point, lm, z, tx, rx)
        st_q, cost_q = self.fit_alone(POINT, as_point, lm, z, tx, rx)
        # a point-like landmark keeps its own kind; a wall may become either (the cheaper)
        point_kind = np.where(wall, np.where(cost_c <= cost_q, CORNER, POINT), kinds)
        is_c = point_kind == CORNER
        st_p = np.where(is_c[:, None], st_c, st_q)
        cost_p = np.where(is_c, cost_c, cost_q)
        ratio = self.config.kind_switch_ratio
        eligible = stops >= 2
        to_point = eligible & wall & (cost_p < ratio * cost_w)
        to_wall = eligible & ~wall & (cost_w < ratio * cost_p)
        kinds = kinds.copy()
        states = states.copy()
        kinds[to_point] = point_kind[to_point]
        states[to_point] = st_p[to_point]
        kinds[to_wall] = WALL
        states[to_wall] = st_w[to_wall]
        return kinds, states

    def _associate_by_stop(
        self,
        lm: IntArray,
        pair_stop: IntArray,
        pair: IntArray,
        landmark: IntArray,
        err: FloatArray,
    ) -> IntArray:
        """Associate a stop's unassociated echo pairs with a landmark jointly, allowing one
        common range offset (``SmootherConfig.stop_gate``).

        The pairs of one stop share its pose error (and the landmark's own error there): a
        stop placed 0.2 m off a wall, or a wall turned by the first stop's heading drift, puts
        every echo of that wall from that stop 0.3-0.5 m from its prediction, beyond ``gate``,
        and the smoother never sees them. Here the candidates of a (stop, landmark) group,
        every unassociated pair within ``stop_gate`` of the landmark's prediction at both
        receivers, are tested together around the group's consensus candidate
        (:meth:`_consensus`): its mean (over the two receivers) range residual is the common
        offset, and a pair is an inlier when both its residuals lie within ``gate`` of it and
        the difference of its residuals (receiver 1 minus 2) within ``3 sqrt(2) range_sigma``
        of the consensus candidate's difference: the receivers'
        difference is ``b sin(angle)`` of the direction of arrival (``b`` the baseline), which
        another reflector's echo changes while the stop's pose error changes it for all its
        pairs nearly alike (a 0.3 m difference is about 17 degrees at 1 m baseline). The
        inliers are associated when at least ``stop_min_pairs`` are and the stop has no pair
        associated with that landmark already (then the landmark's echo from there is known
        and the rest are other echoes). A pair that qualifies for several
        landmarks takes the one with the smallest offset. This is the joint compatibility
        of a set of pairings (Neira and Tardos 2001, "Data association in stochastic mapping
        using the joint compatibility test") simplified to one shared offset per stop and
        landmark; beyond the chapter.

        Parameters
        ----------
        lm : ndarray of int, shape (m,)
            Landmark of every pair from the per-pair gate (-1: none).
        pair_stop : ndarray of int, shape (m,)
            Stop of every pair.
        pair, landmark : ndarray of int, shape (c,)
            Candidate (pair, landmark) entries within ``stop_gate``.
        err : ndarray, shape (c, 2)
            Their residuals ``z - predicted`` at the two receivers, m.

        Returns
        -------
        ndarray of int, shape (m,)
            ``lm`` with the jointly associated pairs set.
        """
        cfg = self.config
        n_lm = int(max(landmark.max(initial=-1), lm.max(initial=-1))) + 1
        free = lm[pair] < 0
        pair, landmark, err = pair[free], landmark[free], err[free]
        if pair.size == 0:
            return lm
        key = pair_stop[pair] * n_lm + landmark
        seen = lm >= 0
        known = np.unique(pair_stop[seen] * n_lm + lm[seen])
        keep = ~np.isin(key, known)
        pair, landmark, err, key = pair[keep], landmark[keep], err[keep], key[keep]
        if pair.size == 0:
            return lm
        groups, inv = np.unique(key, return_inverse=True)
        # one range offset for both receivers (a shifted pose or landmark moves both ranges
        # alike), each receiver within gate of it, and one direction of arrival: the
        # receivers' difference within 3 sigma (of a difference of two ranges: sqrt(2)
        # range_sigma) of the group's. The group's centre is the candidate with the most
        # candidates of its group so compatible (ties: the smaller offset), a consensus; the
        # median of the whole group (until stop 28) sat between a wall's echoes and a
        # corner's at the same stop and took neither (corridor_L_sparse seed 1, stop 3)
        mean = err.mean(1)
        diff = err[:, 0] - err[:, 1]
        diff_tol = 3.0 * np.sqrt(2.0) * cfg.range_sigma
        centre = self._consensus(inv, err, diff, diff_tol)  # one per group, in group order
        offset, d0 = mean[centre], diff[centre]
        inlier = np.all(np.abs(err - offset[inv, None]) <= cfg.gate, 1)
        inlier &= np.abs(diff - d0[inv]) <= diff_tol
        support = np.bincount(inv, inlier, minlength=groups.size)
        ok = inlier & (support[inv] >= cfg.stop_min_pairs)
        if not np.any(ok):
            return lm
        pair, landmark, inv = pair[ok], landmark[ok], inv[ok]
        # a pair with several qualifying landmarks: the smallest common offset
        size = np.abs(offset[inv])
        order = np.lexsort((size, pair))
        first = np.r_[True, pair[order][1:] != pair[order][:-1]]
        out = lm.copy()
        out[pair[order][first]] = landmark[order][first]
        return out

    def _consensus(
        self, group: IntArray, err: FloatArray, diff: FloatArray, diff_tol: float
    ) -> IntArray:
        """Index of each group's consensus candidate: the one whose mean residual and
        receivers' difference the most candidates of its group match (both residuals within
        ``gate`` of its mean residual, the difference within ``diff_tol`` of its), ties to
        the smaller ``|difference|`` (the direction of arrival the landmark predicts: a
        pose's offset moves both ranges alike, another reflector's echo turns it), then the
        smaller ``|mean residual|`` (one per group, in group order). The larger set wins even
        when its direction contradicts the landmark's (4 corner echoes against the wall's 3);
        ranking the direction first (review28b M1) was measured on 32 sparse-corridor
        recordings: mean path 0.218 -> 0.216 m, outline the same, but a 4.4 m ghost wall on
        one, so it was not kept. Pairwise within
        groups, in blocks of rows (the candidates of one recording: hundreds)."""
        gate = self.config.gate
        mean = err.mean(1)
        n = group.size
        support = np.zeros(n, np.int64)
        for a in range(0, n, 512):
            b = min(a + 512, n)
            same = group[a:b, None] == group[None, :]
            fit = np.all(np.abs(err[None, :, :] - mean[a:b, None, None]) <= gate, -1)
            fit &= np.abs(diff[None, :] - diff[a:b, None]) <= diff_tol
            support[a:b] = np.sum(same & fit, 1)
        order = np.lexsort((np.abs(mean), np.abs(diff), -support, group))
        first = np.r_[True, group[order][1:] != group[order][:-1]]
        return order[first]

    def stop_reflectors(
        self,
        result: SmoothedPathMap,
        pairs: list[npt.ArrayLike],
        *,
        min_pairs: int,
        radius: float | None = None,
    ) -> tuple[FloatArray, FloatArray, IntArray]:
        """Reflectors heard from one stop by echo pairs that no landmark explains.

        While the robot turns on the spot the image of the transmitter in a wall, ``2 f -
        tx`` with ``f`` the foot of the perpendicular, and in a corner, ``2 c - tx``, stays
        where it is (Fig. 19 of the CoLOR chapter), so a stop's echoes of one reflector
        invert (:func:`~fusion_center.mapping.models.invert_image`, at the smoothed poses)
        to one image point whatever the heading. The pairs the final association left
        unexplained (``result.association`` -1) are grouped per stop by their image point
        (:func:`image_clusters`, within ``radius``); a group of at least ``min_pairs`` is one
        reflector with reflection point ``f = (T' + tx) / 2`` (``T'`` the group's median
        image, ``tx`` the transmitter's mean position), a wall's foot of the perpendicular
        or a corner's position. The filter may have spread such pairs over several young
        landmarks, or merged them with another reflector's, so that no landmark of the
        smoothing holds them (corridor_L_sparse's far end wall heard from its last stop,
        docs/mapping.md); beyond the chapter.

        Parameters
        ----------
        result : SmoothedPathMap
            :meth:`smooth`'s result (its poses, ``association`` and ``pair_stop``).
        pairs : list of array_like, shape (m_i, 2)
            The echo pairs of every acquisition as given to :meth:`smooth`, m.
        min_pairs : int
            Pairs a reflector needs (>= 1), from at least ``max(2, min_pairs)``
            acquisitions.
        radius : float, optional
            Largest distance of a group's image points from the point it is grown from, m
            (default ``SmootherConfig.gate``).

        Returns
        -------
        (ndarray of shape (k, 2), ndarray of shape (k, 2), ndarray of int of shape (k,))
            Reflection points, the mean robot position ``(x, y)`` they were heard from, and
            their pairs, first-pose frame.
        """
        if min_pairs < 1:
            raise ValueError(f"stop_reflectors: min_pairs must be >= 1, got {min_pairs}")
        radius = self.config.gate if radius is None else float(radius)
        zs = [np.asarray(p, float).reshape(-1, 2) for p in pairs]
        z = np.concatenate([*zs, np.zeros((0, 2))])
        acq = np.repeat(np.arange(len(zs)), [x.shape[0] for x in zs])
        empty = (np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0, np.int64))
        if result.association.shape != (z.shape[0],) or len(zs) != result.poses.shape[0]:
            raise ValueError("stop_reflectors: pairs do not match the smoothing's result")
        free = np.flatnonzero(result.association < 0)
        if free.size == 0:
            return empty
        poses = result.poses[acq[free]]
        tx, _, yaw = self._array(poses)
        body = invert_image(z[free] - self.bias, self.antennas[1:] - self.antennas[0])
        image = tx + rotate(body, yaw)
        ok = np.all(np.isfinite(image), 1)
        free, image, tx, poses = free[ok], image[ok], tx[ok], poses[ok]
        label = image_clusters(image, result.pair_stop[free], radius=radius, min_size=min_pairs)
        n = int(label.max(initial=-1)) + 1
        if n == 0:
            return empty
        use = label >= 0
        li = label[use]
        count = np.bincount(li, minlength=n)
        centre = np.column_stack([group_median(image[use, i], li, n) for i in range(2)])
        mean_tx = np.column_stack([np.bincount(li, tx[use, i], minlength=n) for i in range(2)])
        where = np.column_stack([np.bincount(li, poses[use, i], minlength=n) for i in range(2)])
        refl = 0.5 * (centre + mean_tx / count[:, None])
        # heard in at least two acquisitions (and min_pairs): at coarse steps min_pairs scales
        # down to 1, and one stray pair is no reflector (review28b M2)
        seen = np.unique(li * len(zs) + acq[free][use]) // len(zs)
        good = np.bincount(seen, minlength=n) >= max(2, min_pairs)
        return refl[good], (where / count[:, None])[good], count[good].astype(np.int64)

    # --- the problem --------------------------------------------------------------------------

    def smooth(
        self,
        poses: npt.ArrayLike,
        odometry: npt.ArrayLike,
        pairs: list[npt.ArrayLike],
        groups: list[npt.ArrayLike] | None,
        kinds: npt.ArrayLike,
        states: npt.ArrayLike,
    ) -> SmoothedPathMap:
        """Re-estimate all poses and landmarks jointly.

        Parameters
        ----------
        poses : array_like, shape (n, 3)
            Initial ``[x, y, yaw]`` of every acquisition (the filter's estimates), m, rad.
        odometry : array_like, shape (n, 3)
            ``(dx, dy, dyaw)`` from acquisition ``i - 1`` to ``i`` in the frame of ``i - 1``
            (row 0 is ignored), m, rad.
        pairs : list of array_like, shape (m_i, 2)
            Echo pairs ``(r1, r2)`` of every acquisition, m.
        groups : list of array_like of int, shape (m_i,), optional
            Echo-group id of every pair (measurement-space association); ``None``: every
            pair is associated on its own.
        kinds : array_like of int, shape (l,)
            Landmark kinds.
        states : array_like, shape (l, 2)
            Initial landmark states.

        Returns
        -------
        SmoothedPathMap
        """
        cfg = self.config
        poses = np.asarray(poses, float).reshape(-1, 3)
        odo = np.asarray(odometry, float).reshape(-1, 3)
        n = poses.shape[0]
        if odo.shape[0] != n or len(pairs) != n:
            raise ValueError("poses, odometry and pairs need one row per acquisition")
        kinds = np.asarray(kinds, np.int64).reshape(-1)
        states0 = np.asarray(states, float).reshape(-1, 2)
        zs = [np.asarray(p, float).reshape(-1, 2) for p in pairs]
        z = np.concatenate([*zs, np.zeros((0, 2))])
        acq = np.repeat(np.arange(n), [x.shape[0] for x in zs])
        if groups is None:
            gid = np.arange(z.shape[0])
        else:
            g = np.concatenate([np.asarray(x, np.int64).reshape(-1) for x in groups] + [[]])
            gid = np.unique(g.astype(np.int64), return_inverse=True)[1]
        # key poses: the first acquisition, every drive, and every keyframe_step acquisitions
        drive = np.hypot(odo[:, 0], odo[:, 1]) > cfg.drive_distance
        drive[0] = False
        stop_of = np.cumsum(drive)
        key = np.zeros(n, bool)
        last = 0
        turned = 0.0
        turn_key = cfg.keyframe_turn if cfg.keyframe_turn > 0.0 else np.inf
        for i in range(n):  # n is a few thousand: cheap, and the rule is sequential
            turned += abs(odo[i, 2]) if i > 0 else 0.0
            if i == 0 or drive[i] or i - last >= cfg.keyframe_step or turned >= turn_key:
                key[i] = True
                last = i
                turned = 0.0
        key_idx = np.flatnonzero(key)
        key_of = np.cumsum(key) - 1
        # pose of every acquisition relative to its key pose, from the odometry
        rel = np.zeros((n, 3))
        for i in range(1, n):
            if not key[i]:
                rel[i] = _compose(rel[i - 1], odo[i])
        # odometry edges between consecutive key poses and their noise
        k_next = key_idx[1:]
        edge = _compose(rel[k_next - 1], odo[k_next])
        dist = np.hypot(odo[:, 0], odo[:, 1])
        s_tr = cfg.slip_translation * dist + cfg.slip_floor[0]
        s_rot = (
            cfg.slip_rotation * np.abs(odo[:, 2])
            + cfg.slip_heading_per_metre * dist
            + cfg.slip_floor[1]
        )
        seg = np.searchsorted(key_idx, np.arange(n), side="right") - 1  # key pose before i
        # step i (from acquisition i - 1 to i) lies on the edge from key pose seg[i - 1]
        edge_of_step = seg[:-1]
        var_tr = np.bincount(edge_of_step, s_tr[1:] ** 2, minlength=key_idx.size)[:-1]
        var_rot = np.bincount(edge_of_step, s_rot[1:] ** 2, minlength=key_idx.size)[:-1]
        sig_edge = np.column_stack([np.sqrt(var_tr), np.sqrt(var_tr), np.sqrt(var_rot)])
        sig_edge = np.maximum(sig_edge, 1e-6)

        n_key = key_idx.size
        n_lm = kinds.size
        n_pose_var = 3 * (n_key - 1)
        x0_key = poses[key_idx]
        fixed = x0_key[0].copy()

        def unpack(x: FloatArray) -> tuple[FloatArray, FloatArray]:
            kp = np.vstack([fixed, x[:n_pose_var].reshape(-1, 3)])
            return kp, x[n_pose_var:].reshape(-1, 2)

        def all_poses(kp: FloatArray) -> FloatArray:
            return _compose(kp[key_of], rel)

        def associate(x: FloatArray) -> IntArray:
            """Landmark of every pair (-1: none), whole echo groups at once."""
            kp, st = unpack(x)
            if n_lm == 0 or z.shape[0] == 0:
                return np.full(z.shape[0], -1)
            tx, rx, yaw = self._array(all_poses(kp)[acq])
            gate2 = (cfg.gate / cfg.range_sigma) ** 2
            d2 = np.empty((z.shape[0], n_lm))
            cos_fov = np.cos(cfg.fov)
            # pairs within stop_gate of a landmark's prediction: (pair, landmark, residuals)
            wide: list[tuple[IntArray, IntArray, FloatArray]] = []
            for a in range(0, z.shape[0], 1024):
                b = min(a + 1024, z.shape[0])
                r, ok, d = self._predict(
                    kinds[None, :], st[None, :, :], tx[a:b, None, :], rx[a:b, None, :, :]
                )
                bore = np.stack([np.cos(yaw[a:b]), np.sin(yaw[a:b])], -1)[:, None, :]
                ok &= np.sum(d * bore, -1) >= cos_fov
                err = z[a:b, None, :] - r
                res = np.abs(err) / cfg.range_sigma
                d2[a:b] = np.where(ok, np.sum(res**2, -1), np.inf)
                # a pair beyond the gate at either receiver cannot be that landmark's echo
                d2[a:b] = np.where(np.all(res <= np.sqrt(gate2), -1), d2[a:b], np.inf)
                if cfg.stop_gate > cfg.gate:
                    pi, li = np.nonzero(ok & np.all(np.abs(err) <= cfg.stop_gate, -1))
                    wide.append((pi + a, li, err[pi, li]))
            clipped = np.minimum(d2, gate2)
            m = z.shape[0]
            onehot = sp.csr_matrix((np.ones(m), (gid, np.arange(m))), shape=(gid.max() + 1, m))
            group_cost = onehot @ clipped  # (G, L)
            best = np.argmin(group_cost, 1)
            lm = best[gid]
            lm = np.where(np.isfinite(d2[np.arange(z.shape[0]), lm]), lm, -1)
            if wide:
                pi, li, err = (np.concatenate(v) for v in zip(*wide, strict=True))
                lm = self._associate_by_stop(lm, stop_of[acq], pi, li, err)
            return lm

        def landmark_sigma(x: FloatArray, assoc: IntArray) -> FloatArray:
            """Each landmark's range noise at ``x``, m (``SmootherConfig.sigma_floor``)."""
            sig = np.full(n_lm, cfg.range_sigma)
            use = np.flatnonzero(assoc >= 0)
            if cfg.sigma_floor <= 0.0 or use.size == 0:
                return sig
            kp, st = unpack(x)
            tx, rx, _ = self._array(all_poses(kp)[acq[use]])
            r, _, _ = self._predict(kinds[assoc[use]], st[assoc[use]], tx, rx)
            mad = group_median(np.abs(z[use] - r).mean(1), assoc[use], n_lm)
            seen = np.bincount(assoc[use], minlength=n_lm) > 0
            sig[seen] = np.clip(1.4826 * mad[seen], cfg.sigma_floor, cfg.range_sigma)
            return sig

        def build(assoc: IntArray, lm_sigma: FloatArray):
            use = np.flatnonzero(assoc >= 0)
            z_u, a_u, l_u = z[use], acq[use], assoc[use]
            k_u = key_of[a_u]
            n_meas = 2 * use.size
            n_odo = 3 * (n_key - 1)
            n_prior = 2 * n_lm
            rows, cols = [], []
            # measurement rows depend on their key pose (if free) and their landmark
            r_m = np.arange(n_meas).reshape(-1, 2)
            for j in range(3):
                free = k_u > 0
                for c in range(2):
                    rows.append(r_m[free, c])
                    cols.append(3 * (k_u[free] - 1) + j)
            for j in range(2):
                for c in range(2):
                    rows.append(r_m[:, c])
                    cols.append(n_pose_var + 2 * l_u + j)
            # odometry rows: key poses e and e + 1
            r_o = n_meas + np.arange(n_odo).reshape(-1, 3)
            e = np.arange(n_key - 1)
            for c in range(3):
                for j in range(3):
                    free = e > 0
                    rows.append(r_o[free, c])
                    cols.append(3 * (e[free] - 1) + j)
                    rows.append(r_o[:, c])
                    cols.append(3 * e + j)
            r_p = n_meas + n_odo + np.arange(n_prior)
            rows.append(r_p)
            cols.append(n_pose_var + np.arange(n_prior))
            rr = np.concatenate(rows)
            cc = np.concatenate(cols)
            shape = (n_meas + n_odo + n_prior, n_pose_var + 2 * n_lm)
            sparsity = sp.coo_matrix((np.ones(rr.size), (rr, cc)), shape=shape).tocsr()
            sparsity.data[:] = 1.0
            prior_sig = np.full(2 * n_lm, cfg.landmark_prior)
            st0 = states0.reshape(-1)

            def fun(x: FloatArray) -> FloatArray:
                kp, st = unpack(x)
                pa = _compose(kp[k_u], rel[a_u])
                tx, rx, _ = self._array(pa)
                r, _, _ = self._predict(kinds[l_u], st[l_u], tx, rx)
                res_m = ((z_u - r) / lm_sigma[l_u, None]).reshape(-1)
                # Cauchy loss on the echoes only (a wrong association must not pull), as a
                # residual transform: 0.5 * sum(res**2) is then the robust cost; the odometry
                # stays quadratic, so a stop the filter lost is pulled back by its drives
                c2 = cfg.loss_scale**2
                res_m = np.sign(res_m) * np.sqrt(c2 * np.log1p(res_m**2 / c2))
                a, b = kp[:-1], kp[1:]
                c, s = np.cos(a[:, 2]), np.sin(a[:, 2])
                dx, dy = b[:, 0] - a[:, 0], b[:, 1] - a[:, 1]
                rel_e = np.column_stack([c * dx + s * dy, -s * dx + c * dy, b[:, 2] - a[:, 2]])
                d = rel_e - edge
                d[:, 2] = _wrap(d[:, 2])
                res_o = (d / sig_edge).reshape(-1)
                dst = x[n_pose_var:] - st0
                res_p = dst / prior_sig
                return np.concatenate([res_m, res_o, res_p])

            return fun, sparsity

        x = np.concatenate([x0_key[1:].reshape(-1), states0.reshape(-1)])
        cost_before = cost_after = 0.0
        assoc = np.full(z.shape[0], -1)
        for rnd in range(max(cfg.rounds, 1)):
            assoc = associate(x)
            fun, sparsity = build(assoc, landmark_sigma(x, assoc))
            sol = least_squares(
                fun,
                x,
                jac_sparsity=sparsity,
                method="trf",
                x_scale="jac",
                tr_solver="lsmr",
                max_nfev=cfg.max_nfev,
            )
            if rnd == 0:
                cost_before = float(0.5 * np.sum(fun(x) ** 2))
            x = sol.x
            cost_after = float(sol.cost)
            if rnd + 1 < cfg.rounds and (cfg.merge_dist > 0.0 or cfg.merge_point_dist > 0.0):
                # the landmark set itself is re-made: copies of one face merge, and the next
                # round re-associates the echoes with the merged set
                kp, st = unpack(x)
                support = np.bincount(assoc[assoc >= 0], minlength=n_lm)
                kinds, states0 = merge_duplicates(
                    kinds,
                    st,
                    support,
                    wall_dist=cfg.merge_dist,
                    wall_angle=cfg.merge_angle,
                    point_dist=cfg.merge_point_dist,
                )
                n_lm = kinds.size
                x = np.concatenate([x[:n_pose_var], states0.reshape(-1)])
            if rnd + 1 < cfg.rounds and cfg.refit_kinds:
                assoc = associate(x)
                kp, st = unpack(x)
                used = assoc >= 0
                key_ls = np.unique(np.column_stack([assoc[used], stop_of[acq[used]]]), axis=0)
                n_stops = np.bincount(key_ls[:, 0], minlength=n_lm) if key_ls.size else 0
                kinds, states0 = self.refit_kinds(
                    kinds, st, assoc[used], z[used], all_poses(kp)[acq[used]], n_stops
                )
                x = np.concatenate([x[:n_pose_var], states0.reshape(-1)])
        assoc = associate(x)
        kp, st = unpack(x)
        out_poses = all_poses(kp)
        out_poses[:, 2] = _wrap(out_poses[:, 2])
        st = st.copy()
        wall = kinds == WALL
        st[wall, 0] = _wrap(st[wall, 0])
        used = assoc >= 0
        n_pairs = np.bincount(assoc[used], minlength=n_lm)
        key_ls = np.unique(np.column_stack([assoc[used], stop_of[acq[used]]]), axis=0)
        n_stops = np.bincount(key_ls[:, 0], minlength=n_lm) if key_ls.size else np.zeros(n_lm, int)
        extent = np.full((n_lm, 2), np.nan)
        on_wall = used & (kinds[np.maximum(assoc, 0)] == WALL)
        if np.any(on_wall):
            tx, _, _ = self._array(out_poses[acq[on_wall]])
            li = assoc[on_wall]
            w = st[li]
            nrm = np.stack([np.cos(w[:, 0]), np.sin(w[:, 0])], -1)
            foot = tx + (w[:, 1] - np.sum(nrm * tx, -1))[:, None] * nrm
            t = wall_tangent(w, foot)
            # robust extent: the outer specular points are the first to come from a wrong
            # association (min / max made walls of 8-11 m in a 10 m room)
            order = np.lexsort((t, li))
            li, t = li[order], t[order]
            start = np.searchsorted(li, np.arange(n_lm))
            count = np.bincount(li, minlength=n_lm)
            seen = count > 0
            q = cfg.extent_quantile
            lo_i = start + np.floor(q * (count - 1)).astype(int)
            hi_i = start + np.ceil((1.0 - q) * (count - 1)).astype(int)
            extent[seen] = np.column_stack([t[lo_i[seen]], t[hi_i[seen]]])
        observer = np.full((n_lm, 2), np.nan)
        if np.any(used):
            li = assoc[used]
            count = np.bincount(li, minlength=n_lm)
            seen = count > 0
            for c in range(2):
                observer[seen, c] = (
                    np.bincount(li, out_poses[acq[used], c], minlength=n_lm)[seen] / count[seen]
                )
        return SmoothedPathMap(
            poses=out_poses,
            kinds=kinds,
            states=st,
            pairs=n_pairs.astype(np.int64),
            stops=n_stops.astype(np.int64),
            wall_extent=extent,
            cost_before=cost_before,
            cost_after=cost_after,
            observer=observer,
            association=assoc.astype(np.int64),
            pair_stop=stop_of[acq].astype(np.int64),
        )


def smoothed_landmark_set(
    result: SmoothedPathMap, *, min_pairs: int = 8, min_stops: int = 1
) -> LandmarkSet:
    """The smoothed landmarks with enough support, as a :class:`LandmarkSet` for
    :func:`~fusion_center.mapping.features.build_map`.

    Parameters
    ----------
    result : SmoothedPathMap
    min_pairs : int
        Echo pairs a landmark needs after the final association.
    min_stops : int
        Distinct stops its echoes must come from (landmarks seen from one stop only are
        mostly echoes no 2-D landmark explains: floor-wall bounces, scatter tails).
    """
    ok = (result.pairs >= min_pairs) & (result.stops >= min_stops)
    wall = ok & (result.kinds == WALL) & np.all(np.isfinite(result.wall_extent), 1)
    pt = ok & (result.kinds != WALL)
    return LandmarkSet(
        walls=result.states[wall],
        wall_extent=result.wall_extent[wall],
        wall_hits=result.pairs[wall].astype(float),
        points=result.states[pt],
        point_is_corner=result.kinds[pt] == CORNER,
        point_hits=result.pairs[pt].astype(float),
    )


def image_clusters(
    image: npt.ArrayLike, group: npt.ArrayLike, *, radius: float, min_size: int
) -> IntArray:
    """Greedy clusters of image points within each group (a stop).

    In each group, the point with the most points within ``radius`` (itself included; ties:
    the first) founds a cluster of those points, which leave the group; this repeats while
    the largest such count is at least ``min_size``. The count is a density (the leader
    clustering of Hartigan 1975, seeded at the densest point instead of the first); beyond
    the chapter.

    Parameters
    ----------
    image : array_like, shape (m, 2)
        Points, m.
    group : array_like of int, shape (m,)
        Group of every point; clusters never span groups.
    radius : float
        Largest distance of a member from the cluster's founding point, m (> 0).
    min_size : int
        Members a cluster needs (>= 1).

    Returns
    -------
    ndarray of int, shape (m,)
        Cluster of every point (0, 1, ... over all groups), -1 for none.
    """
    pts = np.asarray(image, float).reshape(-1, 2)
    grp = np.asarray(group, np.int64).reshape(-1)
    if grp.shape[0] != pts.shape[0]:
        raise ValueError("image_clusters: image and group need one row each")
    if not radius > 0.0 or min_size < 1:
        raise ValueError("image_clusters: radius must be > 0 and min_size >= 1")
    label = np.full(pts.shape[0], -1, np.int64)
    n = 0
    for g in np.unique(grp):  # stops: a handful
        idx = np.flatnonzero(grp == g)
        near = np.linalg.norm(pts[idx, None] - pts[None, idx], axis=-1) <= radius
        left = np.ones(idx.size, bool)
        while True:  # clusters of one stop: a handful
            count = (near & left[None, :]).sum(1) * left
            k = int(np.argmax(count))
            if count[k] < min_size:
                break
            members = near[k] & left
            label[idx[members]] = n
            left &= ~members
            n += 1
    return label
