"""Rao-Blackwellized particle filter SLAM for a bat-type robot (Section 6 of the CoLOR chapter).

The joint posterior of the robot path and the map factorises (FastSLAM, eq. (13)-(14) of the
CoLOR chapter): particles carry the robot state and the sensor parameters, and each particle
carries one small EKF per landmark, conditioned on its path:

.. math::
    p(x_{0:k}, m \\mid z_{1:k}, u_{1:k}) = p(x_{0:k} \\mid z_{1:k}, u_{1:k})
    \\prod_l p(m_l \\mid x_{0:k}, z_{1:k})

State of a particle (eq. (7)-(10)): robot ``[px, py, heading, speed]`` (m, rad, m/s), the
sensor's range bias ``b`` (m, common to both receivers: cable and pulse-shape delay) and the
array orientation ``delta`` (rad, mounting yaw of the array relative to the driving
direction). ``b`` and ``delta`` are drawn once per particle and selected by resampling.

Landmarks: each landmark keeps the three hypotheses of :mod:`fusion_center.mapping.models`
(wall, corner, point) side by side, each a 2-D Gaussian, with the accumulated log-likelihood
of the echoes under each hypothesis. A wall and a corner predict the same echoes from one
position and a point differs by second-order terms while the robot only turns; as the robot
drives between stops the likelihoods separate (landmark initialisation and classification from
several views). The association likelihood is the mixture over the hypotheses.

Data association, per pair of echo ranges ``z = (r1, r2)``:

* **state space** (``association="state"``): per particle, the association ``c`` is sampled
  from the importance distribution of eq. (12) of the CoLOR chapter (Rao-Blackwellized Monte
  Carlo data association),

  .. math:: q(c = l) \\propto p(z \\mid c = l, x, m_l)\\, p(c = l), \\qquad
            q(c = \\text{new}) \\propto \\lambda_\\text{new},

  and the particle weight is multiplied by the normaliser :math:`\\sum_c p(z, c)`;
* **measurement space** (``association="measurement"``): pairs arrive with the group id of
  their echo track (:class:`~fusion_center.mapping.grouping.KalmanEchoGrouper`); a group's
  association is sampled as above once per particle and kept for the whole group.

Motion (:meth:`RbpfSlam.predict`): odometry increments ``(dx, dy, dyaw)`` in the previous robot
frame with slip noise proportional to the motion, or, without odometry, the constant-speed
model of eq. (7) with a heading random walk. Resampling is systematic when the effective
sample size falls below half the particles.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from fusion_center.mapping.features import LandmarkSet
from fusion_center.mapping.models import (
    CORNER,
    POINT,
    WALL,
    invert_image,
    invert_point,
    predict,
    states_from_image,
    wall_tangent,
)
from fusion_center.mapping.relocalise import GridScanMatchRelocaliser, MatchMap, compose_poses

FloatArray = npt.NDArray[np.float64]
_LOG2PI = np.log(2 * np.pi)


@dataclass(frozen=True, slots=True, kw_only=True)
class SlamConfig:
    """Parameters of :class:`RbpfSlam` (SI units).

    Attributes
    ----------
    n_particles : int
        Particles.
    association : str
        ``"state"`` (eq. (12) per pair) or ``"measurement"`` (whole echo groups).
    range_sigma : float
        Standard deviation of one bistatic range in the filter, m (inflated over the echo
        extractor's centimetre to cover model errors and the particles' spacing).
    new_log_density : float
        ``ln lambda_new``, density of a new landmark in the 2-D measurement space (1/m^2).
        It is also the clutter level: a pair no mature landmark explains costs a particle
        this much. The hybrid channel's rooms are dense in echoes that no 2-D landmark
        explains (scatterers, floor and higher-order paths): a low density (-6) let every
        particle whose map happened to hold a ghost near such an echo take all the weight
        (measured on room_pillar, first 10 stops, 3 seeds: 0.6-1.5 m RMSE at -6).
    kind_prior : tuple of float
        Prior probabilities of wall, corner, point.
    fov : float
        Half-angle around the array boresight within which landmarks can echo, rad.
    slip_translation, slip_rotation : float
        Odometry noise: standard deviation per metre driven (m/m) and per radian turned
        (rad/rad). The defaults are the noise the odometry reports (a real robot's from its
        calibration); the filter must not trust the wheels less than they deserve.
    slip_floor : tuple of float
        Noise per step even without motion: (m, rad).
    slip_heading_per_metre : float
        Heading noise per metre driven, rad/m (wheel slip while driving).
    no_odometry_turn_sigma : float
        Heading random walk per acquisition when the robot reports no odometry, rad.
    bias_sigma, mount_sigma : float
        Spread of the initial range bias (m) and array orientation (rad) over the particles.
    min_hits : int
        Pairs a landmark needs within ``tentative_window`` acquisitions to be kept.
    tentative_window : int
        Acquisitions a new landmark has to collect ``min_hits``.
    weight_hits : int
        Echoes a landmark needs before it may weight the particles (landmark quality): a
        younger landmark is still associated and refined, but for the particle weight a pair
        explained by it counts as a new landmark, so ghosts born from clutter cannot pull
        the pose before several consistent views (0: every landmark weighs at once).
    capacity : int
        Initial landmark slots per particle (grows as needed).
    expand_distance : float
        Odometry translation, m, after which the particle set is expanded (the robot drove to
        a new stop: the pose spreads most there).
    expand_factor : int
        Copies of every particle drawn through the motion model at such a step.
    expand_steps : int
        Acquisitions after which the expanded set is resampled back to ``n_particles``.
    likelihood_power : float
        Tempering exponent of the measurement likelihood in the particle weights (1: plain
        Bayes; below 1 counts the many correlated echoes of one stop as fewer independent
        ones). Measured on room_pillar (20 stops, 3 seeds): 0.5 no better than 1.
    weight_spread : float
        Distance, m, over which the robot must have seen a landmark before it may weight the
        particles (landmark quality, with ``weight_hits``). Echoes no 2-D landmark explains
        (floor-wall bounces, scatter tails, horn flanks) found landmarks that are consistent
        from one stop only; a landmark seen again from another stop is most likely real.
        Beyond the chapter.
    resample_threshold : float
        Resample when the effective sample size falls below this fraction of the particles.
    relocalise_distance : float
        Odometry translation of one step, m, after which the filter relocalises against its
        map (:mod:`fusion_center.mapping.relocalise`): the pairs of the next
        ``relocalise_acquisitions`` acquisitions are held back, scan-matched jointly over a
        grid of poses around the odometry's prediction, the particles re-seeded from the
        match's posterior (all carrying the heaviest particle's map), and the held-back
        acquisitions replayed. ``inf`` turns it off. Beyond the chapter.
    relocalise_spread : float
        ... and leaves the particles' heading spread wider than this, rad (after short
        drives the particles still associate well; a relocalisation ties all of them to the
        heaviest particle's map and its errors: synthetic room, 1.5 m drives, 1-2 degrees
        of spread, trajectory error 0.06 -> 0.14 m).
    relocalise_reach : float
        Landmarks farther than this from the predicted position are left out of the match, m.
    relocalise_pairs : int
        Echo pairs held back for the match (the acquisitions of the new stop are matched
        jointly, their relative poses from the odometry of the turn)...
    relocalise_acquisitions : int
        ... or at most this many acquisitions.
    relocalise_explained : float
        Fraction of the held-back pairs the best match must explain (within about 2.4
        ``relocalise_sigma`` of a landmark's echo); a weaker match is not trusted (the new stop
        may see too little of the map) and the particles carry on from the odometry.
    relocalise_sigma : float
        Range noise of the relocalisation's fine match and of its ``relocalise_explained``
        test, m. Wider than ``range_sigma``: the map's landmarks are themselves off by
        centimetres to decimetres (placed from estimated poses), and a 5 cm match then snapped
        the pose onto a wrong alignment that explained a few more pairs than the true pose
        (room_pillar stop 28: 46 against 39 of 93 pairs, 0.47 m off). Full room_pillar run,
        seed-1 recording, filter seeds 0 / 1: 2.17 / 1.45 m at 0.05 m, 1.76 / 0.36 m at 0.1 m.
    relocalise_min_landmarks : int
        Mature landmarks (see ``weight_hits``, ``weight_spread``) the map needs for it.
    relocalise_hypotheses : int
        The relocalisation matches the held stop against the maps and poses of this many of
        the heaviest particles and keeps the match that explains the most pairs. 3 kept the
        robot on room_pillar filter seed 0 (1.76 -> 0.76 m), at about 2.2 times the CPU.
    relocalise_from_prediction : bool
        Centre the match (its grid and its Gaussian prior) on the odometry's noise-free
        prediction of the matched particle; off, on that particle's pose after the drive,
        which is one random draw of the motion model (up to a standard deviation of the
        drive's spread off, so the true pose could fall near or beyond the grid's 3 sigma).
        With ``relocalise_hypotheses`` > 1 the hypotheses are the heaviest particles of
        distinct origins (the drive's copies of one particle share its map and prediction,
        so they would repeat one search).
    seed : int
        Seed of the filter's random generator.
    """

    n_particles: int = 40
    association: str = "measurement"
    range_sigma: float = 0.05
    new_log_density: float = 0.0
    kind_prior: tuple[float, float, float] = (0.5, 0.2, 0.3)
    fov: float = np.radians(60.0)
    # the odometry's own noise (the robot recorder's OdometrySlip); 2.5x wider let the echoes
    # turn the heading by more than the wheels allow (room_pillar, 20 stops, 3 seeds:
    # 1.25-1.56 m -> 0.32-0.76 m)
    slip_translation: float = 0.02
    slip_rotation: float = 0.03
    slip_floor: tuple[float, float] = (0.002, np.radians(0.1))
    slip_heading_per_metre: float = np.radians(1.0)
    no_odometry_turn_sigma: float = np.radians(3.0)
    bias_sigma: float = 0.01
    mount_sigma: float = np.radians(1.0)
    min_hits: int = 4
    tentative_window: int = 15
    weight_hits: int = 4
    capacity: int = 64
    expand_distance: float = 0.1
    expand_factor: int = 8
    expand_steps: int = 10
    likelihood_power: float = 1.0
    weight_spread: float = 0.3
    resample_threshold: float = 0.5
    relocalise_distance: float = 1.0
    relocalise_pairs: int = 240
    relocalise_acquisitions: int = 119
    relocalise_explained: float = 0.25
    relocalise_spread: float = 0.0
    relocalise_reach: float = 6.0
    relocalise_sigma: float = 0.1
    relocalise_min_landmarks: int = 4
    relocalise_hypotheses: int = 1
    relocalise_from_prediction: bool = False
    seed: int = 0

    def __post_init__(self) -> None:
        k = self.relocalise_hypotheses
        if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 1:
            raise ValueError(f"relocalise_hypotheses must be an integer >= 1, got {k!r}")
        if not isinstance(self.relocalise_from_prediction, (bool, np.bool_)):
            got = self.relocalise_from_prediction
            raise ValueError(f"relocalise_from_prediction must be a bool, got {got!r}")


@dataclass(slots=True)
class _Landmarks:
    """Per-particle landmark arrays, shape (P, L, ...)."""

    mean: FloatArray  # (P, L, 3, 2)
    cov: FloatArray  # (P, L, 3, 2, 2)
    loglik: FloatArray  # (P, L, 3) accumulated, prior included
    active: npt.NDArray[np.bool_]  # (P, L)
    hits: npt.NDArray[np.int64]  # (P, L)
    born: npt.NDArray[np.int64]  # (P, L)
    origin: FloatArray  # (P, L, 2) robot position at the first echo
    spread: FloatArray  # (P, L) largest distance from origin of a viewing position
    t_min: FloatArray  # (P, L) wall extent along the tangent, m
    t_max: FloatArray  # (P, L)

    @classmethod
    def empty(cls, p: int, cap: int) -> _Landmarks:
        return cls(
            mean=np.zeros((p, cap, 3, 2)),
            cov=np.tile(np.eye(2), (p, cap, 3, 1, 1)),
            loglik=np.zeros((p, cap, 3)),
            active=np.zeros((p, cap), bool),
            hits=np.zeros((p, cap), np.int64),
            born=np.zeros((p, cap), np.int64),
            origin=np.zeros((p, cap, 2)),
            spread=np.zeros((p, cap)),
            t_min=np.zeros((p, cap)),
            t_max=np.zeros((p, cap)),
        )

    def fields(self) -> tuple[str, ...]:
        return self.__slots__  # type: ignore[return-value]

    def take(self, idx: npt.NDArray[np.intp]) -> None:
        for name in self.fields():
            setattr(self, name, getattr(self, name)[idx])

    def grow(self, extra: int) -> None:
        fresh = _Landmarks.empty(self.active.shape[0], extra)
        for name in self.fields():
            setattr(self, name, np.concatenate([getattr(self, name), getattr(fresh, name)], 1))


@dataclass(frozen=True, slots=True, kw_only=True)
class PoseEstimate2D:
    """Weighted mean of the particles: ``pose`` [x, y, yaw] (m, rad) and its 3x3 covariance."""

    pose: FloatArray
    cov: FloatArray


def _inv2(s: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Inverse and determinant of 2x2 matrices (..., 2, 2)."""
    a, b, c, d = s[..., 0, 0], s[..., 0, 1], s[..., 1, 0], s[..., 1, 1]
    det = a * d - b * c
    inv = np.stack([np.stack([d, -b], -1), np.stack([-c, a], -1)], -2) / det[..., None, None]
    return inv, det


def _logsumexp(x: FloatArray, axis: int) -> FloatArray:
    m = np.max(x, axis=axis, keepdims=True)
    m = np.where(np.isfinite(m), m, 0.0)
    with np.errstate(divide="ignore"):
        return np.squeeze(m, axis) + np.log(np.sum(np.exp(x - m), axis=axis))


class RbpfSlam:
    """FastSLAM-style Rao-Blackwellized particle filter with per-landmark EKFs.

    Parameters
    ----------
    antennas : ndarray, shape (3, 2)
        Positions of tx, rx1, rx2 in the robot frame (x forward, y left), m.
    config : SlamConfig
    """

    def __init__(self, antennas: npt.ArrayLike, config: SlamConfig | None = None) -> None:
        self.config = cfg = config or SlamConfig()
        if cfg.association not in ("state", "measurement"):
            raise ValueError(
                f"association must be 'state' or 'measurement', not {cfg.association!r}"
            )
        ant = np.asarray(antennas, float)
        if ant.shape != (3, 2):
            raise ValueError("antennas must be tx, rx1, rx2 positions, shape (3, 2)")
        self.antennas = ant
        # array frame: transmitter at the origin (the inverse models expect it)
        self._rx_body = ant[1:] - ant[0]
        self.rng = np.random.default_rng(cfg.seed)
        p = cfg.n_particles
        self.pose = np.zeros((p, 3))
        self.speed = np.zeros(p)
        self.bias = self.rng.normal(0.0, cfg.bias_sigma, p)
        self.mount = self.rng.normal(0.0, cfg.mount_sigma, p)
        self.logw = np.zeros(p)
        self.lm = _Landmarks.empty(p, cfg.capacity)
        self._log_prior = np.log(np.asarray(cfg.kind_prior, float))
        self._groups: dict[int, npt.NDArray[np.intp]] = {}
        self._shrink_at: int | None = None
        self.k = 0
        self.resamples = 0
        self.relocalisations = 0
        self.relocaliser = GridScanMatchRelocaliser(
            ant,
            range_sigma=cfg.relocalise_sigma,
            clutter_log_density=cfg.new_log_density,
            fov=cfg.fov,
        )
        # calls held back after a long drive, and the particles' poses at its end
        self._held: list[tuple] | None = None
        self._held_start: tuple[FloatArray, FloatArray] | None = None
        self._held_centre: FloatArray | None = None
        #: the particle before the drive's expansion each held particle was copied from
        self._held_origin: npt.NDArray[np.int64] | None = None
        self._held_pairs = 0
        self._held_spread = 0.0
        # estimates of the held-back acquisitions after their replay (see holding)
        self.revised: list[PoseEstimate2D] = []
        self.relocalise_log: list[tuple[int, int, int, bool, float]] = []

    # --- geometry -----------------------------------------------------------------------------

    def _array_world(self) -> tuple[FloatArray, FloatArray, FloatArray]:
        """World tx (P, 2), rx (P, 2, 2) and boresight yaw (P,) of every particle."""
        yaw = self.pose[:, 2] + self.mount
        c, s = np.cos(yaw), np.sin(yaw)
        rot = np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)  # (P, 2, 2)
        ant = np.einsum("pij,aj->pai", rot, self.antennas) + self.pose[:, None, :2]
        return ant[:, 0], ant[:, 1:], yaw

    # --- motion -------------------------------------------------------------------------------

    def predict(
        self,
        dt: float,
        odometry: npt.ArrayLike | None = None,
        rotation_sigma: float | None = None,
    ) -> None:
        """Move every particle (eq. (7)-(8) of the CoLOR chapter) with slip noise.

        Parameters
        ----------
        dt : float
            Time since the previous acquisition, s.
        odometry : array_like, shape (3,), optional
            ``(dx, dy, dyaw)`` since the previous acquisition in the previous robot frame
            (m, m, rad). Without it the robot keeps its estimated speed and heading with a
            heading random walk.
        rotation_sigma : float, optional
            Standard deviation of this step's rotation, rad, in place of the slip model's
            (with odometry only): a step whose rotation was estimated elsewhere, e.g. by the
            turn closure (:mod:`fusion_center.mapping.turn_closure`), with that estimate's
            own uncertainty.
        """
        cfg = self.config
        if rotation_sigma is not None and not rotation_sigma >= 0.0:
            raise ValueError(
                f"RbpfSlam.predict: rotation_sigma must be >= 0, got {rotation_sigma!r}"
            )
        if (
            self._held is not None
            and odometry is not None
            and np.hypot(*np.asarray(odometry, float)[:2]) > cfg.expand_distance
        ):
            self._relocalise()  # the robot drove on before the match had its pairs
        if self._held is not None:
            # the particles keep moving so that estimate() stays the odometry's prediction
            self._held.append(("p", dt, odometry, rotation_sigma))
            self._move(dt, odometry, rotation_sigma)
            return
        before = self.pose.copy()
        self._move(dt, odometry, rotation_sigma)
        if (
            odometry is not None
            and np.hypot(*np.asarray(odometry, float)[:2]) > cfg.relocalise_distance
            and self._heading_spread() > cfg.relocalise_spread
            and self._mature(int(np.argmax(self.logw))).size >= cfg.relocalise_min_landmarks
        ):
            self._held = []
            self._held_pairs = 0
            self._held_spread = self._heading_spread()
            self._held_start = (self.pose.copy(), self.speed.copy())
            # the odometry's noise-free prediction of every particle (the expansion made
            # ``factor`` consecutive copies of each): the match is centred there, not on one
            # random draw of the motion model
            origin = np.arange(self.pose.shape[0]) // (self.pose.shape[0] // before.shape[0])
            self._held_centre = compose_poses(before, np.asarray(odometry, float))[origin]
            self._held_origin = origin

    def _move(
        self, dt: float, odometry: npt.ArrayLike | None, rotation_sigma: float | None = None
    ) -> None:
        """The motion model of :meth:`predict` (with the particle expansion)."""
        cfg = self.config
        p = self.pose.shape[0]
        if (
            odometry is not None
            and np.hypot(*np.asarray(odometry, float)[:2]) > cfg.expand_distance
            and cfg.expand_factor > 1
        ):
            self._expand(cfg.expand_factor)
            p = self.pose.shape[0]
        if odometry is None:
            dist = self.speed * dt
            dyaw = np.zeros(p)
            step = np.stack([dist, np.zeros(p)], -1)
            s_rot = np.full(p, cfg.no_odometry_turn_sigma)
            s_tr = cfg.slip_translation * np.abs(dist) + cfg.slip_floor[0]
        else:
            odo = np.asarray(odometry, float)
            dist = np.full(p, np.hypot(odo[0], odo[1]))
            dyaw = np.full(p, odo[2])
            step = np.broadcast_to(odo[:2], (p, 2))
            s_tr = cfg.slip_translation * dist + cfg.slip_floor[0]
            s_rot = (
                cfg.slip_rotation * np.abs(dyaw)
                + cfg.slip_heading_per_metre * dist
                + cfg.slip_floor[1]
            )
            if rotation_sigma is not None:
                s_rot = np.full(p, float(rotation_sigma))
            if dt > 0:
                self.speed = dist / dt
        noisy = step + self.rng.normal(size=(p, 2)) * s_tr[:, None]
        c, s = np.cos(self.pose[:, 2]), np.sin(self.pose[:, 2])
        self.pose[:, 0] += c * noisy[:, 0] - s * noisy[:, 1]
        self.pose[:, 1] += s * noisy[:, 0] + c * noisy[:, 1]
        self.pose[:, 2] = self.pose[:, 2] + dyaw + self.rng.normal(size=p) * s_rot

    def _expand(self, factor: int) -> None:
        """Copy every particle ``factor`` times before a large motion; the copies are drawn
        separately through the motion model, so the proposal covers the spread of a drive
        (a sampled stand-in for FastSLAM 2.0's measurement-informed proposal). Resampled back
        to ``n_particles`` after ``expand_steps`` acquisitions."""
        if self._shrink_at is None:
            idx = np.repeat(np.arange(self.pose.shape[0]), factor)
            self._take(idx)
            self.logw = self.logw - np.log(factor)
        self._shrink_at = self.k + self.config.expand_steps

    def _take(self, idx: npt.NDArray[np.intp]) -> None:
        self.pose = self.pose[idx]
        self.speed = self.speed[idx]
        self.bias = self.bias[idx]
        self.mount = self.mount[idx]
        self.logw = self.logw[idx]
        self.lm.take(idx)
        self._groups = {g: c[idx] for g, c in self._groups.items()}

    # --- measurement --------------------------------------------------------------------------

    def _predict_all(
        self, idx: npt.NDArray[np.intp] | None, tx: FloatArray, rx: FloatArray, yaw: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray, npt.NDArray[np.bool_]]:
        """Predicted ranges (P, L, 3, 2), Jacobians (P, L, 3, 2, 2), innovation covariances
        and visibility (P, L) of all landmarks (``idx`` None) or one per particle (L = 1)."""
        if idx is None:
            mean, cov, active = self.lm.mean, self.lm.cov, self.lm.active
        else:
            rows = np.arange(self.pose.shape[0])[:, None]
            mean = self.lm.mean[rows, idx[:, None]]
            cov = self.lm.cov[rows, idx[:, None]]
            active = self.lm.active[rows, idx[:, None]]
        txb = tx[:, None, :]
        rxb = rx[:, None, :, :]
        preds, jacs, vis = [], [], []
        boresight = np.stack([np.cos(yaw), np.sin(yaw)], -1)[:, None, :]
        cos_fov = np.cos(self.config.fov)
        for kind in (WALL, CORNER, POINT):
            r, j, direction = predict(kind, mean[:, :, kind], txb, rxb)
            preds.append(r + self.bias[:, None, None])
            jacs.append(j)
            v = np.sum(direction * boresight, -1) >= cos_fov
            if kind == WALL:
                a = mean[:, :, kind, 0]
                n = np.stack([np.cos(a), np.sin(a)], -1)
                v &= mean[:, :, kind, 1] - np.sum(n * txb, -1) > 0.05
            vis.append(v)
        pred = np.stack(preds, 2)
        jac = np.stack(jacs, 2)
        r_cov = self.config.range_sigma**2 * np.eye(2)
        s = jac @ cov @ np.swapaxes(jac, -1, -2) + r_cov
        visible = active & np.any(np.stack(vis, -1), -1)
        return pred, jac, s, visible

    def _kind_loglik(self, z: FloatArray, pred: FloatArray, s: FloatArray) -> FloatArray:
        """``ln N(z; pred, S)`` per hypothesis, shape (P, L, 3)."""
        inv, det = _inv2(s)
        nu = z - pred
        d2 = np.einsum("...i,...ij,...j->...", nu, inv, nu)
        return -0.5 * d2 - 0.5 * np.log(np.maximum(det, 1e-300)) - _LOG2PI

    def _mixture(self, kind_ll: FloatArray, rows: npt.NDArray[np.intp] | None = None) -> FloatArray:
        """Association log-likelihood: mixture over the hypotheses with their posteriors."""
        acc = self.lm.loglik if rows is None else rows
        logpi = acc - _logsumexp(acc, -1)[..., None]
        return _logsumexp(logpi + kind_ll, -1)

    def update(self, z: npt.ArrayLike, groups: npt.ArrayLike | None = None) -> None:
        """Process the pairs of one acquisition (after :meth:`predict`).

        Parameters
        ----------
        z : array_like, shape (m, 2)
            Pairs of bistatic ranges ``(r1, r2)``, m.
        groups : array_like of int, shape (m,), optional
            Echo-group ids (measurement-space association); ignored in state-space mode.
        """
        z = np.atleast_2d(np.asarray(z, float)).reshape(-1, 2)
        if self._held is not None:
            self._held.append(("u", z, groups))
            self._held_pairs += z.shape[0]
            if (
                self._held_pairs >= self.config.relocalise_pairs
                or sum(c[0] == "u" for c in self._held) >= self.config.relocalise_acquisitions
            ):
                self._relocalise()
            return
        use_groups = self.config.association == "measurement" and groups is not None
        gids = np.asarray(groups, np.int64) if use_groups else None
        tx, rx, yaw = self._array_world()
        # Inverse models in the array frame, once per pair (the same for every particle; the
        # per-particle bias is small against the 2-sigma initial covariance).
        image_body = invert_image(z, self._rx_body)
        point_body = invert_point(z, self._rx_body)
        for m in range(z.shape[0]):
            if not np.all(np.isfinite(image_body[m])):
                continue
            g = int(gids[m]) if gids is not None else None
            self._update_one(z[m], image_body[m], point_body[m], tx, rx, yaw, g)
        self._prune()
        if self._shrink_at is not None and self.k >= self._shrink_at:
            self._shrink_at = None
            self._resample(self.config.n_particles)
        else:
            self._maybe_resample()
        self.k += 1

    def _update_one(
        self,
        z: FloatArray,
        image_body: FloatArray,
        point_body: FloatArray,
        tx: FloatArray,
        rx: FloatArray,
        yaw: FloatArray,
        group: int | None,
    ) -> None:
        cfg = self.config
        p, cap = self.lm.active.shape
        rows = np.arange(p)
        known = self._groups.get(group) if group is not None else None
        if known is not None:
            known_ok = self.lm.active[rows, np.minimum(known, cap - 1)] & (known < cap)
        else:
            known_ok = np.zeros(p, bool)
        if np.all(known_ok):
            # measurement space: the group's landmark, no sampling
            choice = known
            pred, jac, s, _ = self._predict_all(choice, tx, rx, yaw)
            kind_ll = self._kind_loglik(z, pred, s)  # (P, 1, 3)
            acc = self.lm.loglik[rows, choice][:, None]
            ll = self._mixture(kind_ll, acc)[:, 0]
            mature = (self.lm.hits[rows, choice] >= cfg.weight_hits) & (
                self.lm.spread[rows, choice] >= cfg.weight_spread
            )
            self.logw += cfg.likelihood_power * np.where(
                mature, np.maximum(ll, cfg.new_log_density - 10.0), cfg.new_log_density
            )
            self._apply(choice, z, pred[:, 0], jac[:, 0], s[:, 0], kind_ll[:, 0], tx)
            return
        pred, jac, s, vis = self._predict_all(None, tx, rx, yaw)
        kind_ll = self._kind_loglik(z, pred, s)  # (P, L, 3)
        ll = np.where(vis, self._mixture(kind_ll), -np.inf)
        options = np.concatenate([ll, np.full((p, 1), cfg.new_log_density)], 1)
        # eq. (12): sample the association from its posterior (Gumbel-max per particle)
        choice = np.argmax(options + self.rng.gumbel(size=options.shape), 1)
        if cfg.weight_hits > 0 or cfg.weight_spread > 0:
            # landmark quality: young landmarks weigh like a new one (see SlamConfig)
            young = (self.lm.hits < cfg.weight_hits) | (self.lm.spread < cfg.weight_spread)
            options[:, :-1] = np.where(young, -np.inf, options[:, :-1])
        norm = _logsumexp(options, 1)
        if known is not None:
            choice = np.where(known_ok, known, choice)
        self.logw += cfg.likelihood_power * norm
        new = choice == cap
        if np.any(new):
            slots = self._free_slots(new)
            choice = np.where(new, slots, choice)
            cap = self.lm.active.shape[1]
            self._initialise(rows[new], slots[new], image_body, point_body, tx, yaw, z)
        old = ~new
        if np.any(old):
            sel = rows[old]
            c = choice[old]
            self._apply_rows(
                sel, c, z, pred[sel, c], jac[sel, c], s[sel, c], kind_ll[sel, c], tx[sel]
            )
        if group is not None:
            self._groups[group] = choice

    def _free_slots(self, need: npt.NDArray[np.bool_]) -> npt.NDArray[np.intp]:
        """First inactive slot of every particle (grows the arrays when one is full)."""
        full = self.lm.active.all(1)
        if np.any(full & need):
            self.lm.grow(self.lm.active.shape[1])
        return np.argmin(self.lm.active, 1)

    def _initialise(
        self,
        sel: npt.NDArray[np.intp],
        slot: npt.NDArray[np.intp],
        image_body: FloatArray,
        point_body: FloatArray,
        tx: FloatArray,
        yaw: FloatArray,
        z: FloatArray,
    ) -> None:
        """New landmarks from one pair: the three hypotheses from the inverse models."""
        c, s = np.cos(yaw[sel]), np.sin(yaw[sel])
        rot = np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)
        t = tx[sel]
        image = t + rot @ image_body
        mean = np.zeros((sel.size, 3, 2))
        mean[:, WALL] = states_from_image(WALL, image, t)
        mean[:, CORNER] = states_from_image(CORNER, image, t)
        point_ok = np.all(np.isfinite(point_body))
        mean[:, POINT] = t + rot @ (point_body if point_ok else 0.5 * image_body)
        lm = self.lm
        lm.mean[sel, slot] = mean
        # covariance through the inverse of the measurement Jacobian, inflated for the pose
        _, rx, _ = self._array_world()
        r_cov = (2.0 * self.config.range_sigma) ** 2 * np.eye(2)
        for kind in (WALL, CORNER, POINT):
            _, jac, _ = predict(kind, mean[:, kind], t, rx[sel])
            ginv = np.linalg.pinv(jac)
            lm.cov[sel, slot, kind] = ginv @ r_cov @ np.swapaxes(ginv, -1, -2) + 1e-4 * np.eye(2)
        lm.loglik[sel, slot] = self._log_prior
        if not point_ok:
            lm.loglik[sel, slot, POINT] = -50.0
        lm.active[sel, slot] = True
        lm.hits[sel, slot] = 1
        lm.born[sel, slot] = self.k
        lm.origin[sel, slot] = self.pose[sel, :2]
        lm.spread[sel, slot] = 0.0
        foot = 0.5 * (image + t)
        tw = wall_tangent(mean[:, WALL], foot)
        lm.t_min[sel, slot] = tw
        lm.t_max[sel, slot] = tw

    def _apply(self, choice, z, pred, jac, s, kind_ll, tx) -> None:
        rows = np.arange(self.pose.shape[0])
        self._apply_rows(rows, choice, z, pred, jac, s, kind_ll, tx)

    def _apply_rows(
        self,
        rows: npt.NDArray[np.intp],
        idx: npt.NDArray[np.intp],
        z: FloatArray,
        pred: FloatArray,
        jac: FloatArray,
        s: FloatArray,
        kind_ll: FloatArray,
        tx: FloatArray,
    ) -> None:
        """EKF update of landmark ``idx`` of particles ``rows`` under all three hypotheses."""
        lm = self.lm
        cov = lm.cov[rows, idx]  # (n, 3, 2, 2)
        inv, _ = _inv2(s)
        gain = cov @ np.swapaxes(jac, -1, -2) @ inv
        nu = z - pred
        mean = lm.mean[rows, idx] + np.einsum("nkij,nkj->nki", gain, nu)
        cov = (np.eye(2) - gain @ jac) @ cov
        lm.mean[rows, idx] = mean
        lm.cov[rows, idx] = 0.5 * (cov + np.swapaxes(cov, -1, -2))
        lm.loglik[rows, idx] += np.maximum(kind_ll, -50.0)
        lm.hits[rows, idx] += 1
        pos = self.pose[rows, :2]
        lm.spread[rows, idx] = np.maximum(
            lm.spread[rows, idx], np.linalg.norm(pos - lm.origin[rows, idx], axis=-1)
        )
        # wall extent: the specular point is the foot of the perpendicular from tx
        w = mean[:, WALL]
        a = w[:, 0]
        n = np.stack([np.cos(a), np.sin(a)], -1)
        t = tx if tx.shape[0] == rows.size else tx[rows]
        foot = t + (w[:, 1] - np.sum(n * t, -1))[:, None] * n
        tw = wall_tangent(w, foot)
        lm.t_min[rows, idx] = np.minimum(lm.t_min[rows, idx], tw)
        lm.t_max[rows, idx] = np.maximum(lm.t_max[rows, idx], tw)

    # --- relocalisation after long drives -----------------------------------------------------

    def _mature(self, b: int) -> npt.NDArray[np.intp]:
        """Landmarks of particle ``b`` that may weigh the particles (see ``weight_hits``)."""
        cfg = self.config
        lm = self.lm
        ok = lm.active[b] & (lm.hits[b] >= cfg.weight_hits) & (lm.spread[b] >= cfg.weight_spread)
        return np.flatnonzero(ok)

    def _heading_spread(self) -> float:
        """Weighted standard deviation of the particles' heading, rad."""
        w = np.exp(self.logw - self.logw.max())
        w /= w.sum()
        z = w @ np.exp(1j * self.pose[:, 2])
        return float(np.sqrt(max(-2.0 * np.log(max(abs(z), 1e-12)), 0.0)))

    def _match_map(self, b: int) -> MatchMap:
        """Mature landmarks of particle ``b``, every kind hypothesis with its posterior."""
        lm = self.lm
        idx = self._mature(b)
        acc = lm.loglik[b, idx]
        logp = acc - _logsumexp(acc, -1)[:, None]  # (L, 3)
        # hypotheses below 20 % and landmarks out of echo range (the extractor's 10 m of
        # bistatic range, plus the search window) cost time and explain nothing
        li, kind = np.nonzero(logp > np.log(0.2))
        state = lm.mean[b, idx[li], kind]
        c = self.pose[b, :2]
        n = np.stack([np.cos(state[:, 0]), np.sin(state[:, 0])], -1)
        dist = np.where(
            kind == WALL,
            np.abs(state[:, 1] - n @ c),
            np.linalg.norm(state - c, axis=-1),
        )
        near = dist < self.config.relocalise_reach
        return MatchMap(kind=kind[near], state=state[near], log_weight=logp[li, kind][near])

    @property
    def holding(self) -> bool:
        """True while acquisitions are held back for a relocalisation: :meth:`estimate` is
        then the odometry's prediction, and once they are replayed :attr:`revised` holds their
        estimates (the caller takes them out)."""
        return self._held is not None

    def flush(self) -> None:
        """Process acquisitions still held back for a relocalisation (end of the stream)."""
        if self._held is not None:
            self._relocalise()

    def _relocalise(self) -> None:
        """Scan-match the held-back acquisitions against the heaviest particle's map, re-seed
        the particles from the match's posterior and replay the acquisitions."""
        cfg = self.config
        calls, self._held = self._held or [], None
        assert self._held_start is not None
        self.pose, self.speed = self._held_start
        cur = np.zeros((1, 3))
        rel, pairs = [], []
        for c in calls:
            if c[0] == "u":
                rel.append(cur[0].copy())
                pairs.append(c[1])
            elif c[0] == "p" and c[2] is not None:
                cur = compose_poses(cur, np.asarray(c[2], float))
        b = int(np.argmax(self.logw))
        lmap = self._match_map(b)
        n_pairs = sum(z.shape[0] for z in pairs)
        # no mature landmark within reach of the new stop (a drive into a new area): nothing
        # to match, the held acquisitions are replayed on the odometry alone
        if n_pairs and lmap.kind.size:
            w = np.exp(self.logw - self.logw.max())
            w /= w.sum()
            d = self.pose - self.pose[b]
            d[:, 2] = (d[:, 2] + np.pi) % (2 * np.pi) - np.pi
            d -= w @ d
            cov = (w[:, None] * d).T @ d
            relp = np.array(rel)
            # several hypotheses (the heaviest particles' maps and poses): the match that
            # explains the most pairs wins, so one unlucky heaviest particle does not decide
            explained = -1
            order = np.argsort(-self.logw)
            origin = self._held_origin
            if cfg.relocalise_from_prediction and origin is not None and origin.size == order.size:
                # copies of one particle share its map and its centre: one search each
                _, first = np.unique(origin[order], return_index=True)
                order = order[np.sort(first)]
            for h in order[: max(cfg.relocalise_hypotheses, 1)]:
                h_map = lmap if h == b else self._match_map(int(h))
                if not h_map.kind.size:
                    continue
                kw = {"bias": float(self.bias[h]), "mount": float(self.mount[h])}
                centre = self.pose[h]
                if cfg.relocalise_from_prediction and self._held_centre is not None:
                    centre = self._held_centre[h]
                c_h, l_h = self.relocaliser.search(centre, cov, relp, pairs, h_map, **kw)
                e_h = self.relocaliser.explained(c_h[np.argmax(l_h)], relp, pairs, h_map, **kw)
                if e_h > explained:
                    explained, cand, logp, b = e_h, c_h, l_h, int(h)
            ok = explained >= cfg.relocalise_explained * n_pairs
            self.relocalise_log.append((self.k, n_pairs, explained, ok, self._held_spread))
            if ok:
                n = cfg.n_particles
                self._take(np.full(n, b))
                self._shrink_at = None
                prob = np.exp(logp - logp.max())
                pick = self.rng.choice(cand.shape[0], n, p=prob / prob.sum())
                fs, fy = self.relocaliser.fine_step
                jitter = self.rng.uniform(-0.5, 0.5, (n, 3)) * np.array([fs, fs, fy])
                self.pose = cand[pick] + jitter
                self.logw = np.full(n, -np.log(n))
                self.relocalisations += 1
        for c in calls:
            if c[0] == "p":
                self._move(c[1], c[2], c[3])
            elif c[0] == "u":
                self.update(c[1], c[2])
                self.revised.append(self.estimate())
            else:
                self.forget_groups(c[1])

    # --- bookkeeping --------------------------------------------------------------------------

    def _prune(self) -> None:
        """Drop tentative landmarks that did not collect ``min_hits`` echoes in time."""
        cfg = self.config
        lm = self.lm
        stale = lm.active & (lm.hits < cfg.min_hits) & (self.k - lm.born > cfg.tentative_window)
        lm.active &= ~stale

    def _maybe_resample(self) -> None:
        w = np.exp(self.logw - self.logw.max())
        w /= w.sum()
        ess = 1.0 / np.sum(w * w)
        self.logw = np.log(np.maximum(w, 1e-300))
        if ess < self.config.resample_threshold * w.size:
            self._resample(w.size)

    def _resample(self, n: int) -> None:
        """Systematic resampling to ``n`` particles."""
        w = np.exp(self.logw - self.logw.max())
        w /= w.sum()
        pos = (self.rng.random() + np.arange(n)) / n
        idx = np.minimum(np.searchsorted(np.cumsum(w), pos), w.size - 1)
        self._take(idx)
        self.logw = np.full(n, -np.log(n))
        self.resamples += 1

    def forget_groups(self, keep: set[int]) -> None:
        """Drop the associations of echo groups that ended (all but ``keep``)."""
        if self._held is not None:
            self._held.append(("f", set(keep)))
            return
        self._groups = {g: c for g, c in self._groups.items() if g in keep}

    # --- outputs ------------------------------------------------------------------------------

    def estimate(self) -> PoseEstimate2D:
        """Weighted mean pose [x, y, yaw] and covariance over x, y, yaw."""
        w = np.exp(self.logw - self.logw.max())
        w /= w.sum()
        xy = w @ self.pose[:, :2]
        yaw = np.arctan2(w @ np.sin(self.pose[:, 2]), w @ np.cos(self.pose[:, 2]))
        d = self.pose - np.array([xy[0], xy[1], yaw])
        d[:, 2] = (d[:, 2] + np.pi) % (2 * np.pi) - np.pi
        cov = (w[:, None] * d).T @ d
        return PoseEstimate2D(pose=np.array([xy[0], xy[1], yaw]), cov=cov)

    def landmarks(self, min_hits: int = 8, min_spread: float = 0.0) -> LandmarkSet:
        """Confirmed landmarks of the heaviest particle, each as its likeliest kind.

        Parameters
        ----------
        min_hits : int
            Echoes a landmark needs to be reported.
        min_spread : float
            Distance, m, over which the robot must have seen it (several views).
        """
        b = int(np.argmax(self.logw))
        lm = self.lm
        ok = lm.active[b] & (lm.hits[b] >= min_hits) & (lm.spread[b] >= min_spread)
        ll = lm.loglik[b]
        is_wall = ll[:, WALL] >= np.maximum(ll[:, CORNER], ll[:, POINT])
        wi = np.flatnonzero(ok & is_wall)
        pi = np.flatnonzero(ok & ~is_wall)
        corner = ll[pi, CORNER] >= ll[pi, POINT]
        pos = np.where(corner[:, None], lm.mean[b, pi, CORNER], lm.mean[b, pi, POINT])
        return LandmarkSet(
            walls=lm.mean[b, wi, WALL],
            wall_extent=np.column_stack([lm.t_min[b, wi], lm.t_max[b, wi]]),
            wall_hits=lm.hits[b, wi].astype(float),
            points=pos,
            point_is_corner=corner,
            point_hits=lm.hits[b, pi].astype(float),
        )
