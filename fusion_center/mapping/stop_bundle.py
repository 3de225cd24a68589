r"""Bundle adjustment of a stop-and-turn path over the individual echo pairs.

Beyond the CoLOR chapter (whose Section 6 estimates path and map with the particle filter),
and beyond :func:`~fusion_center.mapping.stop_graph.refine_turns`, which refines the stop
poses and a two-term in-stop heading drift over one averaged image point per reflector and
stop: here the stop poses, a richer in-stop heading drift per stop and the landmarks are
refined jointly over every echo pair ``(r_1, r_2)`` of every acquisition, through the
Fig. 19 / eq. (11) range models (:func:`~fusion_center.mapping.models.predict`). A bundle
adjustment in the sense of Triggs et al., "Bundle adjustment - a modern synthesis" (Vision
Algorithms 2000): robust (Cauchy, iteratively reweighted) and sparse
(:func:`scipy.optimize.least_squares` with a forward-difference Jacobian over groups of
columns that share no residual), the gauge fixed at the first stop's pose.

The landmarks and the association of every pair with one come from the map along the
current path (:func:`~fusion_center.mapping.fixed_path.map_fixed_path`), which is rebuilt
along the adjusted path between rounds.

Unknowns: the poses ``x_s = (x, y, psi)`` of stops 1..S-1 (stop 0 holds the frame), ``K``
coefficients ``c_s`` per stop of its in-stop heading correction ``b(f_k) . c_s``
(:func:`drift_basis`, ``f_k`` the acquisition's phase of the turn) and the landmark states
``l`` (a wall's ``(alpha, d)``, a corner's or point's ``(x, y)``). The cost is

.. math::

   J = \sum_i \sum_{j=1,2} \rho\Bigl(\frac{z_{ij} - h_j(l_{k(i)}, x_{s(i)} \oplus
       (p_i + b(f_i) \cdot c_{s(i)}))}{\sigma_r}\Bigr)
     + \tfrac12 \sum_s \lVert L_s^T (x_s^{-1} \oplus x_{s+1} - z_s(c_s)) \rVert^2
     + \tfrac12 \sum_s \lVert c_s / \sigma_c \rVert^2
     + \tfrac12 \Bigl(\frac{\overline{\psi_s - \psi_s^0}}{\sigma_\psi}\Bigr)^2

with ``rho`` the Cauchy loss (scale ``loss_scale``; ``sigma_r`` each landmark's robust
residual scale, at least ``range_sigma``), ``h`` the Fig. 19 model of the
landmark's kind, ``p_i`` the acquisition's in-stop pose of the turn closure, ``z_s`` the
odometry from stop s to s+1 (its drive turned by stop s's end correction) with covariance
``L_s L_s^T``, ``sigma_c`` a random walk's prior on the drift coefficients and the last
term the stops' mean heading change from the input stop poses ``psi^0`` (``rotation_sigma``:
the pose graph's rotation of the whole path, which the echo pairs alone hardly observe, held
to the input's in every round).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import scipy.sparse
from scipy.optimize import least_squares

from fusion_center.mapping.fixed_path import FixedPathConfig, map_fixed_path
from fusion_center.mapping.models import CORNER, POINT, WALL, predict
from fusion_center.mapping.turn_closure import group_median

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]


@dataclass(frozen=True, slots=True, kw_only=True)
class StopBundleConfig:
    """Parameters of :func:`adjust_stop_bundle` (SI units).

    Attributes
    ----------
    range_sigma : float
        Noise of one echo range, m.
    loss_scale : float
        Scale of the Cauchy loss, in ``range_sigma``.
    modes : int
        Terms of the in-stop heading drift (:func:`drift_basis`), at least 1. Two: at the
        true path of room_pillar seed 0 the pairs of one third of a turn ask for its heading
        within 0.4-0.5 degrees RMS, of a whole stop within 0.16 degrees; the third and
        fourth modes (0.42 -> 0.30 degrees of the turn-closed headings' in-stop error) are
        below what the echoes resolve, and measured no better (3 and 4: corners and
        outline worse on one of the two recordings).
    rounds : int
        Map along the path, adjust, repeat.
    reweight : int
        Solves with the Cauchy weights and landmark scales taken afresh, after the first
        (0 or more).
    rotation_sigma : float
        Standard deviation of the mean heading change of the stops 1..S-1 from the
        input stop poses (the pose graph's, in every round), rad (inf: free). The
        rotation of the whole path about the first stop is held by the pose graph's
        registrations with the first stop, which the adjustment does not see; alone it
        rests on the first stop's few echoes of strong landmarks (corridor_L seed 1: the
        path turned by 2.3 degrees, and its relative headings improved from 0.80 to 0.23
        degrees RMS between stops).
    hold_first_turn : bool
        Hold the first stop's in-stop drift at its initial coefficients with its pose
        (the pose alone is the gauge). Default False: held, the other stops' drifts took
        up the first turn's error (corridor_L seed 1, with ``rotation_sigma``: the path
        turned by 0.8 degrees, against -0.1 free).
    min_landmark_pairs, min_landmark_stops : int
        Pairs and distinct stops a landmark needs to enter the adjustment (a landmark seen
        from one stop cannot tell the stop's pose).
    max_nfev : int
        Function evaluations of one least-squares solve at most.

    Raises
    ------
    ValueError
        A non-positive noise or scale, an integer below 1 (``reweight``: below 0) or a
        ``hold_first_turn`` that is not a bool.
    """

    range_sigma: float = 0.01
    loss_scale: float = 3.0
    modes: int = 2
    rounds: int = 2
    reweight: int = 2
    hold_first_turn: bool = False
    rotation_sigma: float = np.radians(0.1)
    min_landmark_pairs: int = 20
    min_landmark_stops: int = 2
    max_nfev: int = 50

    def __post_init__(self) -> None:
        for name in ("range_sigma", "loss_scale", "rotation_sigma"):
            v = getattr(self, name)
            if not (v > 0.0 and (np.isfinite(v) or name == "rotation_sigma")):
                raise ValueError(f"StopBundleConfig.{name} must be > 0, got {v!r}")
        for name in ("modes", "rounds", "min_landmark_pairs", "min_landmark_stops", "max_nfev"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int | np.integer) or v < 1:
                raise ValueError(f"StopBundleConfig.{name} must be an integer >= 1, got {v!r}")
        r = self.reweight
        if isinstance(r, bool) or not isinstance(r, int | np.integer) or r < 0:
            raise ValueError(f"StopBundleConfig.reweight must be an integer >= 0, got {r!r}")
        if not isinstance(self.hold_first_turn, bool | np.bool_):
            raise ValueError(
                f"StopBundleConfig.hold_first_turn must be a bool, got {self.hold_first_turn!r}"
            )


def drift_basis(phase: npt.ArrayLike, modes: int) -> FloatArray:
    """Basis (n, modes) of the in-stop heading error at turn phases ``f`` (0 .. 1):
    ``[f, sin(pi f), sin(2 pi f), ...]``: the drift to the end of the turn, then the modes of
    a random walk's bridge (its Karhunen-Loeve expansion; the first two are
    :func:`~fusion_center.mapping.stop_graph.turn_basis`). Zero at ``f = 0``: the turn's
    first acquisition holds the stop's pose."""
    f = np.asarray(phase, float).reshape(-1)
    k = np.arange(1, modes)
    return np.column_stack([f, np.sin(np.pi * f[:, None] * k)]) if modes > 1 else f[:, None]


def drift_prior(end_sigma: FloatArray, odometry_sigma: FloatArray, modes: int) -> FloatArray:
    """Standard deviations (S, modes) of the drift coefficients, rad: ``end_sigma`` (the
    turn's end error after the closure) for the drift, and for the bridge mode ``k`` of a
    random walk that accumulates ``odometry_sigma`` over the turn ``sqrt(2) sigma / (k pi)``
    (its Karhunen-Loeve variances)."""
    k = np.arange(1, modes)
    bridge = np.sqrt(2.0) * np.asarray(odometry_sigma, float)[:, None] / (np.pi * k)
    return np.maximum(np.column_stack([np.asarray(end_sigma, float), bridge]), 1e-6)


def _compose(base: FloatArray, rel: FloatArray) -> FloatArray:
    """Poses ``rel`` (m, 3) in the frames ``base`` (m, 3), in the outer frame."""
    c, s = np.cos(base[:, 2]), np.sin(base[:, 2])
    return np.column_stack(
        [
            base[:, 0] + c * rel[:, 0] - s * rel[:, 1],
            base[:, 1] + s * rel[:, 0] + c * rel[:, 1],
            base[:, 2] + rel[:, 2],
        ]
    )


def _ranges(
    kinds: IntArray, states: FloatArray, poses: FloatArray, antennas: FloatArray
) -> FloatArray:
    """Predicted ranges (m, 2) of landmarks of ``kinds`` (m,) at robot ``poses`` (m, 3)
    (Fig. 19 models, :func:`~fusion_center.mapping.models.predict`)."""
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    rot = np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)
    ant = np.einsum("mij,aj->mai", rot, antennas) + poses[:, None, :2]
    out = np.zeros((poses.shape[0], 2))
    for kind in (WALL, CORNER, POINT):  # three models, each vectorised over its pairs
        sel = kinds == kind
        if np.any(sel):
            out[sel] = predict(kind, states[sel], ant[sel, 0], ant[sel, 1:])[0]
    return out


@dataclass(frozen=True, slots=True)
class StopBundleResult:
    """Output of :func:`adjust_stop_bundle`: the stop poses (S, 3), the drift coefficients
    (S, modes; rad, over :func:`drift_basis`), the landmarks' kinds and states of the last
    round, the number of echo pairs it used, each landmark's robust residual scale of its
    last solve (m; at least ``range_sigma``) and the number of solves that stopped at
    ``max_nfev`` before converging (0: every solve converged)."""

    poses: FloatArray
    coefficients: FloatArray
    kinds: IntArray
    states: FloatArray
    n_pairs: int
    scales: FloatArray
    unconverged: int


def adjust_stop_bundle(
    pairs: Sequence[npt.ArrayLike],
    groups: Sequence[npt.ArrayLike],
    stop_ranges: Sequence[tuple[int, int]],
    in_stop: Sequence[FloatArray],
    phases: Sequence[FloatArray],
    stop_poses: FloatArray,
    odometry: Sequence[tuple[FloatArray, FloatArray]],
    prior_sd: FloatArray,
    antennas: npt.ArrayLike,
    config: StopBundleConfig | None = None,
    map_config: FixedPathConfig | None = None,
    initial: FloatArray | None = None,
) -> StopBundleResult:
    """Stop poses, in-stop heading drifts and landmarks over the echo pairs (see the module).

    Parameters
    ----------
    pairs, groups : sequence of ndarray, shape (m_k, 2) and (m_k,)
        Echo pairs ``(r1, r2)`` (m) and echo-track ids of every acquisition.
    stop_ranges : sequence of (int, int)
        Acquisition range ``[start, end)`` of every stop, covering all acquisitions in order.
    in_stop : sequence of ndarray, shape (n_s, 3)
        Every stop's in-stop poses (stop frame: the turn closure's), m and rad.
    phases : sequence of ndarray, shape (n_s,)
        Phase of every acquisition in its stop's turn (0 .. 1).
    stop_poses : ndarray, shape (S, 3)
        Initial stop poses; row 0 holds the frame, and the mean heading of rows 1..S-1 is
        held to these (``rotation_sigma``) in every round.
    odometry : sequence of (ndarray (3,), ndarray (3, 3))
        Relative pose of stop s + 1 in stop s by the odometry from stop s's last in-stop
        pose (without its end heading noise) and its covariance, s = 0 .. S-2.
    prior_sd : ndarray, shape (S, modes)
        Standard deviations of the drift coefficients (:func:`drift_prior`), rad.
    antennas : array_like, shape (3, 2)
        tx, rx1, rx2 in the robot frame, m.
    initial : ndarray, shape (S, modes), optional
        Initial drift coefficients (zeros).

    Returns
    -------
    StopBundleResult

    Raises
    ------
    ValueError
        No stops, or inputs whose shapes do not describe the same stops and acquisitions.
    """
    cfg = config or StopBundleConfig()
    mcfg = map_config or FixedPathConfig()
    ant = np.asarray(antennas, float).reshape(3, 2)
    n_stop = len(stop_ranges)
    modes = cfg.modes
    if n_stop == 0:
        raise ValueError("the bundle adjustment needs at least one stop")
    if len(in_stop) != n_stop or len(phases) != n_stop or len(odometry) != n_stop - 1:
        raise ValueError("stop_ranges, in_stop, phases and odometry must describe the same stops")
    n_acq = int(stop_ranges[-1][1])
    stop_of = np.zeros(n_acq, np.intp)
    prev = 0
    for s, (a, b) in enumerate(stop_ranges):  # a loop over the stops
        if a != prev or b <= a or len(in_stop[s]) != b - a or len(phases[s]) != b - a:
            raise ValueError(
                f"stop {s}: range ({a}, {b}) must follow the last one and match its "
                f"{len(in_stop[s])} in-stop poses and {len(phases[s])} phases"
            )
        stop_of[a:b], prev = s, b
    if len(pairs) != n_acq or len(groups) != n_acq:
        raise ValueError(f"pairs and groups must hold {n_acq} acquisitions")
    prior_sd = np.asarray(prior_sd, float)
    coef = np.zeros((n_stop, modes)) if initial is None else np.array(initial, float)
    for name, v in (("prior_sd", prior_sd), ("initial", coef)):
        if v.shape != (n_stop, modes):
            raise ValueError(f"{name} must have shape ({n_stop}, {modes}), got {v.shape}")
    anchor = np.asarray(stop_poses, float)
    if anchor.shape != (n_stop, 3):
        raise ValueError(f"stop_poses must have shape ({n_stop}, 3), got {anchor.shape}")
    pose = anchor.copy()
    rel = np.concatenate([np.asarray(p, float).reshape(-1, 3) for p in in_stop])
    basis = drift_basis(np.concatenate([np.asarray(f, float) for f in phases]), modes)
    zs = [np.asarray(p, float).reshape(-1, 2) for p in pairs]
    z_all = np.concatenate([*zs, np.zeros((0, 2))])
    acq_all = np.repeat(np.arange(n_acq), [z.shape[0] for z in zs])
    oz = np.array([z for z, _ in odometry]).reshape(-1, 3)
    osq = np.array([sqrt_information(c) for _, c in odometry]).reshape(-1, 3, 3)
    oend = np.array([np.asarray(p, float)[-1, :2] for p in in_stop[:-1]]).reshape(-1, 2)

    def acq_poses(p: FloatArray, c: FloatArray, acq: npt.NDArray[np.intp]) -> FloatArray:
        s = stop_of[acq]
        r = rel[acq].copy()
        r[:, 2] += np.sum(basis[acq] * c[s], 1)
        return _compose(p[s], r)

    kinds = np.zeros(0, np.int64)
    states = np.zeros((0, 2))
    scales = np.zeros(0)
    used = unconverged = 0
    for _ in range(cfg.rounds):
        path = acq_poses(pose, coef, np.arange(n_acq))
        built = map_fixed_path(list(pairs), list(groups), path, ant, mcfg)
        lm = built.association
        if built.kinds.size == 0:
            break
        if lm.size != z_all.shape[0]:  # an inconsistency of map_fixed_path, not of the input
            raise ValueError(f"the map associated {lm.size} of {z_all.shape[0]} echo pairs")
        key = np.unique(np.column_stack([lm[lm >= 0], stop_of[acq_all[lm >= 0]]]), axis=0)
        n_lm = built.kinds.size
        strong = (np.bincount(lm[lm >= 0], minlength=n_lm) >= cfg.min_landmark_pairs) & (
            np.bincount(key[:, 0], minlength=n_lm) >= cfg.min_landmark_stops
        )
        sel = np.flatnonzero((lm >= 0) & strong[np.maximum(lm, 0)])
        if sel.size == 0:
            break
        # renumber the landmarks the adjustment uses
        keep_lm, li = np.unique(lm[sel], return_inverse=True)
        kinds, states = built.kinds[keep_lm], built.states[keep_lm].copy()
        acq = acq_all[sel]
        used = sel.size
        problem = _Problem(
            cfg,
            ant,
            pose=pose,
            anchor=anchor,
            coef=coef,
            kinds=kinds,
            states=states,
            li=li,
            z=z_all[sel],
            acq=acq,
            pst=stop_of[acq],
            acq_poses=acq_poses,
            odo=(np.arange(n_stop - 1), oz, osq, oend),
            prior_sd=prior_sd,
        )
        pose, coef, states, scales, n_unconv = _solve(problem, cfg)
        unconverged += n_unconv
    return StopBundleResult(pose, coef, kinds, states, used, scales, unconverged)


class _Problem:
    """The least-squares problem of one solve at a fixed association (see the module):
    the unknowns ``x`` (poses of stops 1..S-1, the drift coefficients, the landmark
    states), the residuals :meth:`fun` in the blocks ``rows`` (``pairs``, ``odometry``,
    ``prior``, ``rotation``) and their Jacobian ``jac`` over the sparsity pattern."""

    def __init__(
        self,
        cfg: StopBundleConfig,
        ant: FloatArray,
        *,
        pose: FloatArray,
        anchor: FloatArray,
        coef: FloatArray,
        kinds: IntArray,
        states: FloatArray,
        li: npt.NDArray[np.intp],
        z: FloatArray,
        acq: npt.NDArray[np.intp],
        pst: npt.NDArray[np.intp],
        acq_poses: Callable[[FloatArray, FloatArray, npt.NDArray[np.intp]], FloatArray],
        odo: tuple[npt.NDArray[np.intp], FloatArray, FloatArray, FloatArray],
        prior_sd: FloatArray,
    ) -> None:
        self.cfg, self.ant, self.kinds, self.li, self.z = cfg, ant, kinds, li, z
        self.acq, self.acq_poses, self.odo, self.prior_sd = acq, acq_poses, odo, prior_sd
        n_stop, modes = coef.shape
        self.n_stop, self.modes, self.n_lm = n_stop, modes, kinds.size
        self.n_pose = n_pose = 3 * (n_stop - 1)
        # the first stop's turn is held with its pose (see StopBundleConfig.hold_first_turn)
        self.first = first = int(cfg.hold_first_turn)
        self.hold = hold = bool(np.isfinite(cfg.rotation_sigma) and n_stop > 1)
        self.n_coef = n_coef = modes * (n_stop - first)
        self.p0, self.c0 = pose[:1].copy(), coef[:first].copy()
        # the rotation hold's anchor: the input stop poses' headings, in every round
        self.anchor = np.asarray(anchor, float)[1:, 2].copy()
        self.scale = np.full(li.size, cfg.range_sigma)
        self.weight = np.ones(li.size)
        self.x0 = np.concatenate([pose[1:].ravel(), coef[first:].ravel(), states.ravel()])
        m, n_odo = 2 * li.size, 3 * (n_stop - 1)
        self.rows = {
            "pairs": slice(0, m),
            "odometry": slice(m, m + n_odo),
            "prior": slice(m + n_odo, m + n_odo + n_coef),
            "rotation": slice(m + n_odo + n_coef, m + n_odo + n_coef + int(hold)),
        }

        # sparsity: a pair's two ranges touch its stop's pose and drift and its landmark; an
        # odometry edge both stops' poses and drifts; a prior its coefficient
        def stop_cols(s: npt.NDArray[np.intp]) -> npt.NDArray[np.intp]:
            pc = np.where(s[:, None] > 0, 3 * (s[:, None] - 1) + np.arange(3), -1)
            cc = np.where(s[:, None] >= first, n_pose + modes * (s[:, None] - first), -1)
            return np.hstack([pc, np.where(cc >= 0, cc + np.arange(modes), -1)])

        oi = odo[0]
        n_var = n_pose + n_coef + 2 * self.n_lm
        blocks = [
            (np.hstack([stop_cols(pst), n_pose + n_coef + 2 * li[:, None] + np.arange(2)]), 2),
            (np.hstack([stop_cols(oi), stop_cols(oi + 1)]), 3),
        ]
        rows_a, cols_a, r0 = block_pattern(blocks, n_pose + np.arange(n_coef))
        r0 += int(hold)
        self.jac = _SparseDifferences(self.fun, rows_a, cols_a, (r0, n_var))
        if hold:  # the rotation hold's dense row is differentiated exactly
            self.jac.dense_row(
                r0 - 1, 3 * np.arange(n_stop - 1) + 2, 1.0 / ((n_stop - 1) * cfg.rotation_sigma)
            )

    def unpack(self, x: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Stop poses (S, 3), drift coefficients (S, modes) and landmark states (L, 2)."""
        p = np.vstack([self.p0, x[: self.n_pose].reshape(-1, 3)])
        c = np.vstack([self.c0, x[self.n_pose : self.n_pose + self.n_coef].reshape(-1, self.modes)])
        return p, c, x[self.n_pose + self.n_coef :].reshape(self.n_lm, 2)

    def pair_residuals(self, x: FloatArray) -> FloatArray:
        """Measured minus predicted ranges (m, 2) of the echo pairs, m."""
        p, c, st = self.unpack(x)
        at = self.acq_poses(p, c, self.acq)
        return self.z - _ranges(self.kinds[self.li], st[self.li], at, self.ant)

    def fun(self, x: FloatArray) -> FloatArray:
        """Every weighted residual, in the order of ``rows``."""
        cfg, (oi, oz, osq, oend) = self.cfg, self.odo
        p, c, _ = self.unpack(x)
        r_pair = self.pair_residuals(x) * (np.sqrt(self.weight) / self.scale)[:, None]
        pi, pj = p[oi], p[oi + 1]
        cc, ss = np.cos(pi[:, 2]), np.sin(pi[:, 2])
        dx, dy = pj[:, 0] - pi[:, 0], pj[:, 1] - pi[:, 1]
        # the drive leaves from stop i's last in-stop pose, turned by its end correction
        d_end = c[oi, 0]
        ce, se = np.cos(d_end), np.sin(d_end)
        v = oz[:, :2] - oend
        zz = np.column_stack(
            [oend[:, 0] + ce * v[:, 0] - se * v[:, 1], oend[:, 1] + se * v[:, 0] + ce * v[:, 1]]
        )
        d = np.column_stack(
            [cc * dx + ss * dy - zz[:, 0], -ss * dx + cc * dy - zz[:, 1], pj[:, 2] - pi[:, 2]]
        )
        d[:, 2] = (d[:, 2] - oz[:, 2] - d_end + np.pi) % (2 * np.pi) - np.pi
        r_odo = np.einsum("mij,mj->mi", osq, d)
        r_prior = (c[self.first :] / self.prior_sd[self.first :]).ravel()
        # the path's mean heading change from the input stop poses: the graph's rotation of
        # the whole path is held (not from each round's start, where it could walk)
        r_rot = np.atleast_1d(np.mean(p[1:, 2] - self.anchor) / cfg.rotation_sigma)
        return np.concatenate([r_pair.ravel(), r_odo.ravel(), r_prior, r_rot[: int(self.hold)]])


def _solve(
    problem: _Problem, cfg: StopBundleConfig
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, int]:
    """Robust sparse least squares of ``problem``: stop poses, coefficients, landmark
    states, each landmark's robust residual scale (m) and the solves that stopped at
    ``max_nfev``."""
    x = problem.x0
    n_lm, li = problem.n_lm, problem.li
    lm_scale = np.full(n_lm, cfg.range_sigma)
    unconverged = 0
    # iteratively reweighted: Cauchy weights on the echo pairs only (a robust loss on the
    # odometry and the drift prior would let a large residual switch them off), and each
    # landmark's own robust residual scale (a point-like object edge scatters by
    # centimetres, a wall by millimetres: room_pillar at the true path, 3.7 against 0.6 cm)
    for _ in range(cfg.reweight + 1):
        r = problem.pair_residuals(x)
        mad = group_median(np.abs(r).mean(1), li, n_lm)
        lm_scale = np.maximum(cfg.range_sigma, 1.4826 * mad)
        problem.scale = lm_scale[li]
        chi2 = np.sum((r / problem.scale[:, None]) ** 2, 1)
        problem.weight = 1.0 / (1.0 + chi2 / (2.0 * cfg.loss_scale**2))
        sol = least_squares(
            problem.fun, x, jac=problem.jac, method="trf", x_scale="jac", max_nfev=cfg.max_nfev
        )
        unconverged += int(sol.status == 0)
        x = sol.x
    p, c, st = problem.unpack(x)
    p = p.copy()
    p[:, 2] = (p[:, 2] + np.pi) % (2 * np.pi) - np.pi
    return p, c.copy(), st.copy(), lm_scale, unconverged


class _SparseDifferences:
    """Forward-difference Jacobian of ``fun`` with a known sparsity (``rows``, ``cols``):
    columns that share no row are perturbed together (greedy colouring, Curtis, Powell and
    Reid 1974, as :func:`scipy.optimize.least_squares` does with ``jac_sparsity``), and a
    linear dense row is set exactly (:meth:`dense_row`): left to the differences, it would
    put every one of its columns into a group of its own."""

    def __init__(
        self,
        fun: Callable[[FloatArray], FloatArray],
        rows: npt.NDArray[np.intp],
        cols: npt.NDArray[np.intp],
        shape: tuple[int, int],
    ) -> None:
        self.fun, self.rows, self.cols, self.shape = fun, rows, cols, shape
        pattern = scipy.sparse.csr_matrix((np.ones(rows.size), (rows, cols)), shape=shape)
        conflict = (pattern.T @ pattern).tocsr()
        group = np.full(shape[1], -1)
        for j in range(shape[1]):  # a loop over the unknowns (hundreds), once per solve
            taken = group[conflict.indices[conflict.indptr[j] : conflict.indptr[j + 1]]]
            free = np.setdiff1d(np.arange(taken.size + 1), taken)
            group[j] = free[0]
        self.group = group
        self.extra: list[tuple[int, npt.NDArray[np.intp], float]] = []

    def dense_row(self, row: int, cols: npt.NDArray[np.intp], value: float) -> None:
        """Row ``row`` is ``value`` at ``cols`` (a residual linear in them) and 0 elsewhere."""
        self.extra.append((row, cols, value))

    def __call__(self, x: FloatArray) -> scipy.sparse.csr_matrix:
        f0 = self.fun(x)
        h = np.sqrt(np.finfo(float).eps) * np.maximum(1.0, np.abs(x))
        vals = np.zeros(self.rows.size)
        col_group = self.group[self.cols]
        for g in range(int(self.group.max()) + 1):  # one evaluation per colour group
            step = np.where(self.group == g, h, 0.0)
            f1 = self.fun(x + step)
            on = col_group == g
            vals[on] = (f1[self.rows[on]] - f0[self.rows[on]]) / h[self.cols[on]]
        rows, cols = [self.rows], [self.cols]
        for row, c, v in self.extra:
            rows.append(np.full(c.size, row))
            cols.append(c)
            vals = np.r_[vals, np.full(c.size, v)]
        return scipy.sparse.csr_matrix(
            (vals, (np.concatenate(rows), np.concatenate(cols))), shape=self.shape
        )


def block_pattern(
    blocks: Sequence[tuple[npt.NDArray[np.intp], int]], diagonal: npt.NDArray[np.intp]
) -> tuple[npt.NDArray[np.intp], npt.NDArray[np.intp], int]:
    """Nonzero pattern of a least-squares Jacobian made of residual blocks, then one row per
    entry of ``diagonal`` (a prior on that column).

    ``blocks``: ``(cols, k)`` pairs, one per kind of residual: ``cols`` (m, c) the columns
    each of m residual groups touches (-1: none), ``k`` the rows per group; the groups' rows
    follow each other in that order. Returns the rows and columns of the nonzeros and the
    number of rows."""
    rows_l, cols_l, r0 = [], [], 0
    for cb, k in blocks:
        rr = r0 + np.arange(cb.shape[0] * k).reshape(-1, k)
        rows_l.append(np.repeat(rr[:, :, None], cb.shape[1], 2).ravel())
        cols_l.append(np.repeat(cb[:, None, :], k, 1).ravel())
        r0 += cb.shape[0] * k
    rows_l.append(r0 + np.arange(diagonal.size))
    cols_l.append(np.asarray(diagonal, np.intp))
    rows_a, cols_a = np.concatenate(rows_l), np.concatenate(cols_l)
    keep = cols_a >= 0
    return rows_a[keep], cols_a[keep], r0 + diagonal.size


def sqrt_information(cov: FloatArray) -> FloatArray:
    """``W`` (3, 3) with ``W^T W = cov^{-1}`` (eigen-decomposition of the symmetrised
    covariance, eigenvalues floored at 1e-12 so a near-singular edge stays finite)."""
    lam, vec = np.linalg.eigh(0.5 * (cov + cov.T))
    return (vec / np.sqrt(np.maximum(lam, 1e-12))).T
