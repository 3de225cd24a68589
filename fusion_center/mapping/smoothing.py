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
landmark as in Section 6.3.

Poses: one key pose ``[x, y, yaw]`` per ``keyframe_step`` acquisitions and at every drive;
the acquisitions between key poses hang off their key pose through the recorded odometry.
The first key pose is held fixed (it defines the map frame). The number of distinct stops
from which a landmark's echoes come (``stops``) is the support used to prune the map
(:func:`smoothed_landmark_set`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import scipy.sparse as sp
from scipy.optimize import least_squares

from fusion_center.mapping.features import LandmarkSet
from fusion_center.mapping.models import CORNER, POINT, WALL, predict, wall_tangent

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]


@dataclass(frozen=True, slots=True, kw_only=True)
class SmootherConfig:
    """Parameters of :class:`LeastSquaresPathMapSmoother` (SI units).

    Attributes
    ----------
    keyframe_step : int
        Acquisitions per key pose (a drive always starts a new one).
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
    """

    poses: FloatArray
    kinds: IntArray
    states: FloatArray
    pairs: IntArray
    stops: IntArray
    wall_extent: FloatArray
    cost_before: float
    cost_after: float


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
        for i in range(n):  # n is a few thousand: cheap, and the rule is sequential
            if i == 0 or drive[i] or i - last >= cfg.keyframe_step:
                key[i] = True
                last = i
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
            for a in range(0, z.shape[0], 1024):
                b = min(a + 1024, z.shape[0])
                r, ok, d = self._predict(
                    kinds[None, :], st[None, :, :], tx[a:b, None, :], rx[a:b, None, :, :]
                )
                bore = np.stack([np.cos(yaw[a:b]), np.sin(yaw[a:b])], -1)[:, None, :]
                ok &= np.sum(d * bore, -1) >= cos_fov
                res = np.abs(z[a:b, None, :] - r) / cfg.range_sigma
                d2[a:b] = np.where(ok, np.sum(res**2, -1), np.inf)
                # a pair beyond the gate at either receiver cannot be that landmark's echo
                d2[a:b] = np.where(np.all(res <= np.sqrt(gate2), -1), d2[a:b], np.inf)
            clipped = np.minimum(d2, gate2)
            m = z.shape[0]
            onehot = sp.csr_matrix((np.ones(m), (gid, np.arange(m))), shape=(gid.max() + 1, m))
            group_cost = onehot @ clipped  # (G, L)
            best = np.argmin(group_cost, 1)
            lm = best[gid]
            return np.where(np.isfinite(d2[np.arange(z.shape[0]), lm]), lm, -1)

        def build(assoc: IntArray):
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
                res_m = ((z_u - r) / cfg.range_sigma).reshape(-1)
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
            fun, sparsity = build(assoc)
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
        return SmoothedPathMap(
            poses=out_poses,
            kinds=kinds,
            states=st,
            pairs=n_pairs.astype(np.int64),
            stops=n_stops.astype(np.int64),
            wall_extent=extent,
            cost_before=cost_before,
            cost_after=cost_after,
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
