"""Localization of one mobile node from its RTToA ranges to anchors, with NLOS mitigation.

Per ranging round (one ``detections`` message with ``links``): each anchor's recent ranges,
first-path SNRs and per-impulse-response decisions go through the NLOS test (eq. (6),
:class:`~fusion_center.localization.nlos.MseNlosTest`, combined with the links' own evidence
by :class:`~fusion_center.localization.nlos.EvidenceNlosTest`); LOS anchors
enter the snapshot estimator with their own range variance, NLOS anchors only with a large
one (``nlos_std``: they still resolve the mirror ambiguity of two LOS anchors, but no longer
pull the fix); the fix updates a position Kalman filter whose state is the published pose.
Mitigation also gates single ranges against the track's prediction (beyond the chapter):
the one range of a round further than ``gate`` standard deviations from the predicted distance
enters that round with ``nlos_std`` (a LOS multipath outlier), without changing the anchor's
LOS decision; with several such ranges the prediction is distrusted instead. And it resolves
the mirror ambiguity by the track (beyond the chapter): a fix outside the track's gate
(``branch_gate``, chi-square with 2 degrees of freedom) whose ranges fit hardly better than
the local solution from the predicted position (by less than ``branch_gate`` in weighted
cost) is the other branch of the same ranges (two LOS anchors plus de-weighted NLOS ones
leave two nearly equal minima); the solution near the prediction, the larger posterior,
replaces it.
Without mitigation every anchor enters with its LOS variance (the baseline).

Robust track (``robust``, the default with mitigation; beyond the chapter). The LOS range
error of the simulated 802.15.4a channels is a noise core at the CRLB plus a tail of
millimetre to centimetre errors, of either sign, from rays arriving within a pulse width of
the direct path; the channel is redrawn every round while the node moves (every
``coherence_time`` while it stands), so the tail is independent from round to round and a
track with a tight prediction sees it. The track runs with a small acceleration noise
(``robust_q``) and every LOS range enters with its own noise-core standard deviation (the
link's ``std``, floor ``min_range_std``), inflated by ``(z / robust_k) ** robust_power`` when
its innovation ``z`` against the prediction (range and prediction variances together) exceeds
``robust_k``: an M-estimator weight on the innovation, after Chang (J. Geodesy 88, 2014,
robust Kalman filtering with the Mahalanobis distance as outlier criterion). The published
covariance is the filter's, scaled by the LOS ranges' spread beyond their noise core and by
the fixes' mean normalised innovation (:meth:`RangingLocalizer._cov_factor`). The prediction
itself is checked first: when most LOS ranges are far off it (``manoeuvre_gate``), or with
two LOS anchors one is far off on the same side in two rounds running, the node changed its
motion and the round is predicted with ``q_manoeuvre``; when the LOS ranges agree with each
other on a fix outside the prediction's gate (``fading_gate``), the prediction's covariance is
scaled up to meet it (a fading memory). The mirror-branch check then asks whether the local
solution is reachable by a manoeuvre.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt
from scipy.stats import chi2

from .estimators import LOCATORS, PositionFix, TaylorSeriesLocator, horizontal_ranges
from .kalman import PositionKalmanTracker
from .nlos import EvidenceNlosTest, MseNlosTest

FloatArray = npt.NDArray[np.float64]

#: Estimators whose fixes the robust track takes (:attr:`LocalizerConfig.robust`).
ROBUST_METHODS = ("taylor", "aml")

#: Speed (m/s) above which the heading of motion is taken as the node's yaw.
MIN_SPEED_FOR_YAW = 0.1


@dataclass(frozen=True, slots=True, kw_only=True)
class LocalizerConfig:
    """Parameters of :class:`RangingLocalizer`.

    Parameters
    ----------
    method : ``lls``, ``taylor`` or ``aml`` (:data:`~.estimators.LOCATORS`).
    mitigate : run the NLOS test and de-weight the NLOS anchors.
    nlos_std : standard deviation given to an NLOS anchor's range, m.
    window : ranges per anchor kept for the test.
    test : the eq. (6) test.
    evidence : the eq. (6) test combined with the links' first-path power and per-impulse-
        response decisions (:class:`~.nlos.EvidenceNlosTest`, its ``mse`` replaced by
        ``test``); None: eq. (6) alone.
    q : acceleration noise density of the position filter, m²/s³.
    gate : innovation gate of a single range, standard deviations (0: off).
    branch_gate : chi-square (2 degrees of freedom) gate of a fix against the track's
        prediction, and the cost margin by which the ranges must prefer a fix outside it over
        the local solution near the prediction (13.8: 0.1 % of true fixes fall outside);
        0: off.
    robust : with ``mitigate`` and the ``taylor`` or ``aml`` method (:data:`ROBUST_METHODS`),
        weight every LOS range by its innovation against the track's prediction (see the
        module docstring) instead of the single-range ``gate``. The linear ``lls`` fix keeps
        the plain track (with two LOS anchors and the NLOS ones de-weighted it loses the
        circle intersection, and the robust track would hold on to that fix), but its LOS
        ranges enter with their own std (floor ``min_range_std``), not ``test.los_std``.
        False: the plain track with the ``test.los_std`` floor for every method (stop 18).
    robust_q : acceleration noise density of the robust track between manoeuvres, m²/s³.
    min_range_std : floor of a LOS range's standard deviation with ``robust`` and
        ``mitigate``, m (the links report the noise core's bound; otherwise the floor is
        ``test.los_std``).
    robust_k : innovation (standard deviations) beyond which a LOS range is down-weighted.
    robust_power : its standard deviation grows as ``(z / robust_k) ** robust_power``.
    manoeuvre_gate : squared innovation beyond which a range is far off the prediction; most
        LOS ranges far off (or, with two, one on the same side twice running) is a manoeuvre.
    fading_gate : chi-square gate of the LOS ranges' own consistent fix against the
        prediction; beyond it the prediction's covariance is scaled up to meet the fix.
    snoop_alpha : false-alarm rate of the fix's residual test (:meth:`RangingLocalizer._snoop`).
    persist : rounds running a LOS range may stay beyond ``robust_k`` on the same side before
        the prediction, not the range, is taken to be off (fading); 5 rounds outlast the
        channel of a standing node (``coherence_time`` 0.3 s at 10 rounds/s).
    cov_window : fixes behind the published covariance's factor (:meth:`RangingLocalizer.
        _cov_factor`).
    q_manoeuvre : acceleration noise density of a manoeuvre's prediction, m²/s³ (2.5: a
        0.5 m/s velocity change within one 0.1 s round).
    """

    method: str = "taylor"
    mitigate: bool = True
    nlos_std: float = 1.5
    window: int = 30
    test: MseNlosTest = field(default_factory=MseNlosTest)
    evidence: EvidenceNlosTest | None = field(default_factory=EvidenceNlosTest)
    q: float = 0.5
    gate: float = 4.0
    branch_gate: float = 13.8
    robust: bool = True
    robust_q: float = 1e-4
    min_range_std: float = 2e-4
    robust_k: float = 3.0
    robust_power: float = 2.0
    manoeuvre_gate: float = 200.0
    fading_gate: float = 13.8
    snoop_alpha: float = 0.01
    persist: int = 5
    cov_window: int = 100
    q_manoeuvre: float = 2.5


@dataclass(frozen=True, slots=True, kw_only=True, eq=False)
class PoseResult:
    """One localization update of a mobile node.

    Attributes
    ----------
    t : float
        Time of the ranging round, s.
    pose : tuple of 4 float
        Tracked ``[x, y, z, yaw]`` (z the node's known height).
    cov : ndarray, shape (3, 3)
        Covariance over x, y, yaw (yaw variance pi²/3 when the node is too slow to show its
        heading: uniform, nothing known).
    los : dict anchor id -> bool
        The NLOS decisions (True: LOS).
    fix : PositionFix
        The snapshot fix of this round.
    """

    t: float
    pose: tuple[float, float, float, float]
    cov: FloatArray
    los: dict[str, bool]
    fix: PositionFix


@functools.lru_cache(maxsize=256)
def _chi2_quantile(p: float, dof: int) -> float:
    """The chi-square quantile (cached: scipy's ppf costs as much as a fix)."""
    return float(chi2.ppf(p, dof))


def _mahalanobis(prior: tuple[FloatArray, FloatArray], x: FloatArray, c: FloatArray) -> float:
    """Squared distance of a fix ``x`` (cov ``c``) from a predicted ``(state, cov)``."""
    state, cov = prior
    d = x - state[[0, 2]]
    try:
        return float(d @ np.linalg.solve(cov[np.ix_([0, 2], [0, 2])] + c, d))
    except np.linalg.LinAlgError:
        return 0.0


def _innovations(
    prior: tuple[FloatArray, FloatArray], anchors: FloatArray, r: FloatArray, std: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Range innovations against a predicted ``(state, cov)`` (state ``[x, vx, y, vy]``), m,
    and their size in standard deviations of range and prediction together."""
    state, cov = prior
    xy = state[[0, 2]]
    p = cov[np.ix_([0, 2], [0, 2])]
    diff = xy - anchors
    d = np.maximum(np.linalg.norm(diff, axis=1), 1e-6)
    u = diff / d[:, None]
    var = std**2 + np.einsum("ki,ij,kj->k", u, p, u)
    innovation = r - d
    return innovation, np.abs(innovation) / np.sqrt(var)


class RangingLocalizer:
    """Localizes and tracks one mobile node (see the module docstring).

    Parameters
    ----------
    anchors : dict anchor id -> (x, y, z)
        Anchor positions, world frame, m.
    height : float
        The mobile node's known antenna height, m.
    config : LocalizerConfig
    """

    def __init__(
        self,
        anchors: dict[str, tuple[float, float, float]],
        height: float,
        config: LocalizerConfig | None = None,
    ) -> None:
        self.config = config or LocalizerConfig()
        if self.config.method not in LOCATORS:
            raise ValueError(f"unknown localization method {self.config.method!r}")
        self.anchors = dict(anchors)
        self.height = float(height)
        self.locator = LOCATORS[self.config.method]()
        self._local = TaylorSeriesLocator()
        # from the prediction, a millimetre off: two or three steps converge
        self._quick = TaylorSeriesLocator(max_iterations=3)
        cfg = self.config
        # the robust track needs a fix that converges to the ML solution from the prediction
        # (Gauss-Newton: Taylor, and approximate ML's refinement); the linear LS fix loses the
        # circle intersection of two LOS anchors once the NLOS ones are de-weighted, and the
        # robust track then holds on to it (lab_nlos 0.47 m, against 0.31 m on the plain track)
        self._robust_on = cfg.robust and cfg.mitigate and cfg.method in ROBUST_METHODS
        self.tracker = PositionKalmanTracker(cfg.robust_q if self._robust_on else cfg.q)
        # per anchor: (t, range, snr_db, per-impulse-response NLOS flag) of recent rounds
        self._history: dict[str, deque[tuple[float, float, float, bool]]] = {}
        ev = self.config.evidence
        self._evidence = None if ev is None else dataclasses.replace(ev, mse=self.config.test)
        self._yaw = 0.0
        # (anchor, range long) of the LOS ranges far off the last prediction
        self._far: set[tuple[str, bool]] = set()
        # anchor -> (sign, rounds running) of LOS innovations beyond robust_k
        self._streak: dict[str, tuple[float, int]] = {}
        # normalised innovations of the fixes against the prediction (cruise rounds)
        self._nis_fix: deque[float] = deque(maxlen=self.config.cov_window)
        # squared LOS innovations (standard deviations) of the recent rounds
        self._z2: deque[float] = deque(maxlen=4 * self.config.cov_window)
        #: plain track with the links' own std: the recent fixes' reduced chi-square
        self._chi2_fix: deque[float] = deque(maxlen=self.config.cov_window)

    def los_decisions(self) -> dict[str, bool]:
        """The current NLOS decision of every anchor with a history (True: LOS): eq. (6),
        or with ``evidence`` the combined test.

        Anchors ranged at the same times (the usual case: every anchor in every round) are
        tested together in one least-squares solve."""
        if not self.config.mitigate:
            return dict.fromkeys(self._history, True)
        hist = {a: np.array(h, float).reshape(-1, 4) for a, h in self._history.items()}
        budget = float("nan")
        if self._evidence is not None:
            budget = self._evidence.calibrate(
                [h[:, 2] for h in hist.values()], [h[:, 1] for h in hist.values()]
            )
        groups: dict[tuple[float, ...], list[str]] = {}
        for aid, h in hist.items():
            groups.setdefault(tuple(h[:, 0]), []).append(aid)
        out = {}
        for times, ids in groups.items():
            cols = np.stack([hist[a] for a in ids], axis=2)  # (N, 4, k)
            t = np.array(times)
            if self._evidence is None:
                nlos = self.config.test.decide(t, cols[:, 1])
            else:
                nlos = self._evidence.decide(t, cols[:, 1], cols[:, 2], cols[:, 3] > 0.5, budget)
            out.update(zip(ids, (not v for v in nlos), strict=True))
        return out

    def _outliers(
        self,
        prior: tuple[FloatArray, FloatArray],
        anchors: FloatArray,
        r: FloatArray,
        std: FloatArray,
    ) -> npt.NDArray[np.bool_]:
        """Ranges beyond the gate around the distance predicted by the track."""
        _, z = _innovations(prior, anchors, r, std)
        out = np.zeros(r.size, bool)
        # one outlier per round at most: when several ranges disagree with the prediction, the
        # prediction is the likelier culprit (a track started on NLOS ranges), so trust the ranges
        if np.sum(z > self.config.gate) == 1:
            out[np.argmax(z)] = True
        return out

    def _cov_factor(self) -> float:
        """Factor on the published position covariance. Plain track with the links' own std
        (linear LS): the recent fixes' mean reduced chi-square (the a-posteriori variance of
        unit weight of least squares), at least 1. Robust track: the mean normalised
        innovation of the recent fixes against the prediction over its expectation (2),
        at least 1 (covariance matching, after Mehra). The track's covariance is that of
        Gaussian errors; the fixes' errors have a tail (leaked multipath outliers, errors
        correlated over a standing node's rounds), and the mean, unlike a median, counts it,
        so that the published covariance matches the mean-square error."""
        if not self._robust_on:
            # plain track (linear LS with the links' own std): the fixes' mean reduced
            # chi-square, clipped per fix, at least 1 (the mean counts the tail)
            if len(self._chi2_fix) < (self._chi2_fix.maxlen or 1) // 4:
                return 1.0
            return max(float(np.mean(np.minimum(self._chi2_fix, 1e3))), 1.0)
        if not self._nis_fix or len(self._nis_fix) < self._nis_fix.maxlen // 4:
            return 1.0
        # the LOS ranges' spread beyond their reported noise core (median squared innovation
        # over that of a chi-square with one degree of freedom: the small multipath errors
        # the weights keep), times what the fixes' innovations say beyond that; no LOS range
        # yet (every anchor NLOS so far): no spread to measure, not a NaN covariance
        spread = max(float(np.median(self._z2)) / 0.455, 1.0) if self._z2 else 1.0
        return spread * max(float(np.mean(np.minimum(self._nis_fix, 1e3))) / 2.0, 1.0)

    def _robust(
        self,
        t: float,
        prior: tuple[FloatArray, FloatArray],
        anchors: FloatArray,
        r: FloatArray,
        std: FloatArray,
        los: npt.NDArray[np.bool_],
        ids: list[str],
    ) -> tuple[FloatArray, tuple[FloatArray, FloatArray], float | None, float]:
        """Robust weights of the LOS ranges against the track's prediction (module docstring).

        Returns
        -------
        std : ndarray, shape (k,)
            The ranges' standard deviations, LOS ones inflated, m.
        prior : (state, cov)
            The prediction the weights were taken against (widened on a manoeuvre or drift).
        q : float or None
            ``q_manoeuvre`` when the round is a manoeuvre, else None.
        fading : float
            Factor (>= 1) on the predicted covariance for this round.
        """
        cfg = self.config
        innovation, z = _innovations(prior, anchors, r, std)
        self._z2.extend((z[los] ** 2).tolist())
        far = los & (z > math.sqrt(cfg.manoeuvre_gate))
        far_now = {(ids[i], bool(innovation[i] > 0)) for i in np.flatnonzero(far)}
        repeated = bool(far_now & self._far)
        self._far = far_now
        # rounds running in which each LOS range was off the prediction on the same side
        off = los & (z > cfg.robust_k)
        streak = {}
        for i in np.flatnonzero(off):
            side, count = self._streak.get(ids[i], (0.0, 0))
            sign = float(np.sign(innovation[i]))
            streak[ids[i]] = (sign, count + 1 if sign == side else 1)
        self._streak = streak
        n_los = int(np.count_nonzero(los))
        manoeuvre, fading = False, 1.0
        if n_los >= 2 and (len(far_now) >= max(2, n_los - 1) or (repeated and n_los == 2)):
            # (nearly) every LOS range far off the prediction, or with two LOS anchors one far
            # off on the same side in two rounds running: the node changed its motion (the
            # multipath tail is independent per range and per round while the node moves,
            # and rarely that large)
            manoeuvre = True
        else:
            persistent = [i for i in np.flatnonzero(off) if streak[ids[i]][1] >= cfg.persist]
            if persistent:
                # a range off on the same side longer than a standing node's channel keeps an
                # outlier: the track drifted (a track that only trusts itself never recovers);
                # widen the prediction until that range is within the gate
                fading = float(np.max(z[persistent]) / cfg.robust_k) ** 2
            elif n_los >= 3 and np.any(off):
                # the LOS ranges alone, from the prediction: a fix outside the prediction's
                # gate whose ranges agree with each other says the prediction drifted (with
                # two LOS ranges nothing tells an outlier from a drift)
                xy = prior[0][[0, 2]]
                local = self._quick.from_start(anchors[los], r[los], std[los], xy)
                if local is not None and local[2] <= _chi2_quantile(0.999, n_los - 2):
                    fading = _mahalanobis(prior, local[0], local[1]) / cfg.fading_gate
            fading = min(max(fading, 1.0), cfg.manoeuvre_gate)
        if manoeuvre or fading > 1.0:
            wider = self.tracker.predict(t, cfg.q_manoeuvre if manoeuvre else None, fading)
            if wider is not None:
                prior = wider
                _, z = _innovations(prior, anchors, r, std)
        scale = np.where(los, np.maximum(1.0, z / cfg.robust_k) ** cfg.robust_power, 1.0)
        return std * scale, prior, (cfg.q_manoeuvre if manoeuvre else None), fading

    def _snoop(
        self,
        anchors: FloatArray,
        r: FloatArray,
        std: FloatArray,
        los: npt.NDArray[np.bool_],
        fix: PositionFix,
        initial: FloatArray | None,
    ) -> tuple[PositionFix, FloatArray]:
        """Data snooping of the fix's own LOS residuals (Baarda's iterated test): while the
        weighted residuals fail the chi-square test (``snoop_alpha``), the LOS range with the
        largest normalised residual is down-weighted like an innovation outlier and the fix
        recomputed, as long as a redundant LOS range is left. Catches what the prediction
        cannot: outliers right after a manoeuvre, when the prediction is loose."""
        cfg = self.config
        n_los = int(np.count_nonzero(los))
        for _ in range(max(n_los - 3, 0)):
            if not fix.ok:
                break
            res = np.abs(np.linalg.norm(fix.position - anchors, axis=1) - r) / std
            if float(np.sum(res[los] ** 2)) <= _chi2_quantile(1.0 - cfg.snoop_alpha, n_los - 2):
                break
            worst = int(np.argmax(np.where(los, res, -1.0)))
            std = std.copy()
            std[worst] *= max(1.0, res[worst] / cfg.robust_k) ** cfg.robust_power
            fix = self.locator.locate(anchors, r, std, initial=initial)
            n_los -= 1
        return fix, std

    def _branch(
        self,
        prior: tuple[FloatArray, FloatArray],
        anchors: FloatArray,
        r: FloatArray,
        std: FloatArray,
        fix: PositionFix,
        reach_t: float | None = None,
    ) -> PositionFix:
        """The fix, or the local solution near the prediction when the fix is the other
        branch of an ambiguous geometry (see the module docstring). With ``reach_t`` (the
        robust track) the gate is that of a manoeuvre's prediction at that time."""
        if not np.all(np.isfinite(fix.position)) or not np.all(np.isfinite(fix.cov)):
            return fix
        if reach_t is not None:
            # inside the tight prediction's gate is inside the manoeuvre's: no prediction
            if _mahalanobis(prior, fix.position, fix.cov) <= self.config.branch_gate:
                return fix
            prior = self.tracker.predict(reach_t, self.config.q_manoeuvre) or prior
        state, cov = prior
        xy = state[[0, 2]]
        p = cov[np.ix_([0, 2], [0, 2])]
        gate = self.config.branch_gate

        def mahalanobis(x: FloatArray, c: FloatArray) -> float:
            d = x - xy
            try:
                return float(d @ np.linalg.solve(p + c, d))
            except np.linalg.LinAlgError:
                return 0.0

        if mahalanobis(fix.position, fix.cov) <= gate:
            return fix
        local = self._local.from_start(anchors, r, std, xy)
        if local is None:
            return fix
        x, c, cost = local
        fix_cost = float(np.sum(((np.linalg.norm(fix.position - anchors, axis=1) - r) / std) ** 2))
        if mahalanobis(x, c) > gate or cost - fix_cost > gate:
            return fix  # the ranges insist: the track, not the fix, is off
        return dataclasses.replace(fix, position=x, cov=c)

    def step(self, t: float, links: dict[str, tuple[float, ...]]) -> PoseResult:
        """One ranging round.

        Parameters
        ----------
        t : float
            Time, s.
        links : dict anchor id -> (range, std[, los, snr_db])
            3-D first-path distance to each anchor, m, its standard deviation, m, and
            optionally the per-impulse-response LOS decision and the first-path SNR, dB
            (``detections.links``; without them: LOS and unknown). Anchors not in
            :attr:`anchors` are ignored.
        """
        ids = [a for a in links if a in self.anchors and math.isfinite(links[a][0])]
        for aid in ids:
            hist = self._history.setdefault(aid, deque(maxlen=self.config.window))
            link = links[aid]
            los = bool(link[2]) if len(link) > 2 else True
            snr = float(link[3]) if len(link) > 3 else float("nan")
            hist.append((t, float(link[0]), snr, float(not los)))
        los_all = self.los_decisions()
        los = {a: los_all.get(a, True) for a in ids}
        pos = np.array([self.anchors[a] for a in ids], float).reshape(-1, 3)
        r3 = np.array([links[a][0] for a in ids], float)
        robust = self._robust_on
        # the links' own std, floored, unless the stop-18 plain track is asked for (robust off):
        # a 3 cm floor made the fixes' covariance 100 times too large, and a track fed with it
        # lags a moving node by millimetres (LS and approximate ML were 7.5-8.4x the CRLB)
        tight = self.config.robust and self.config.mitigate
        floor = self.config.min_range_std if tight else self.config.test.los_std
        std = np.array([max(links[a][1], floor) for a in ids], float)
        nlos = np.array([not los[a] for a in ids], bool)
        std = np.where(nlos, max(self.config.nlos_std, 1e-3), std)
        r = horizontal_ranges(r3, pos[:, 2] - self.height)
        prior = self.tracker.predict(t)
        initial = prior[0][[0, 2]] if prior is not None else None
        q_step = None
        fading = 1.0
        if prior is not None and robust:
            std, prior, q_step, fading = self._robust(t, prior, pos[:, :2], r, std, ~nlos, ids)
        elif prior is not None and self.config.mitigate and self.config.gate > 0:
            std = np.where(self._outliers(prior, pos[:, :2], r, std), self.config.nlos_std, std)
        fix = self.locator.locate(pos[:, :2], r, std, initial=initial)
        if robust:
            fix, std = self._snoop(pos[:, :2], r, std, ~nlos, fix, initial)
        elif tight and fix.ok and r.size > 2:
            # the plain track fed with the links' own std (linear LS): the fix's weighted
            # residual over its degrees of freedom (the a-posteriori variance of unit weight),
            # for the published covariance's factor (:meth:`_cov_factor`); without it a
            # multipath tail left a mean NEES of 63 (review, stop 20)
            res = (r - np.linalg.norm(pos[:, :2] - fix.position, axis=1)) / std
            self._chi2_fix.append(float(np.sum(res**2)) / (r.size - 2))
        if prior is not None and self.config.mitigate and self.config.branch_gate > 0:
            # with the robust track's tight prediction, the branch test asks whether the
            # local solution is reachable by a manoeuvre, not whether it fits the cruise
            fix = self._branch(prior, pos[:, :2], r, std, fix, t if robust else None)
        usable = fix.ok or (initial is not None and np.all(np.isfinite(fix.position)))
        if robust and usable and prior is not None and q_step is None and fading == 1.0:
            # the fix against the (tight) prediction: its normalised innovation, for the
            # fix covariance's a-posteriori factor
            nis = _mahalanobis(prior, fix.position, fix.cov)
            if math.isfinite(nis):
                self._nis_fix.append(nis)
        if not self.tracker.initialised and not fix.ok:
            cov3 = np.diag([np.inf, np.inf, np.pi**2 / 3.0])
            pose = (float("nan"), float("nan"), self.height, float("nan"))
            return PoseResult(t=t, pose=pose, cov=cov3, los=los, fix=fix)
        state, p = self.tracker.step(
            t, fix.position if usable else None, fix.cov if usable else None, q_step, fading
        )
        speed = math.hypot(state[1], state[3])
        cov3 = np.zeros((3, 3))
        cov3[:2, :2] = p[np.ix_([0, 2], [0, 2])] * self._cov_factor()
        if speed > MIN_SPEED_FOR_YAW:
            self._yaw = math.atan2(state[3], state[1])
            # heading of the velocity: var(angle) ~ var(v_perp) / speed²
            cov3[2, 2] = min((p[1, 1] + p[3, 3]) / 2.0 / speed**2, np.pi**2 / 3.0)
        else:
            cov3[2, 2] = np.pi**2 / 3.0
        pose = (float(state[0]), float(state[2]), self.height, float(self._yaw))
        return PoseResult(t=t, pose=pose, cov=cov3, los=los, fix=fix)
