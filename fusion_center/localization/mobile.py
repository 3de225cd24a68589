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
"""

from __future__ import annotations

import dataclasses
import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from .estimators import LOCATORS, PositionFix, TaylorSeriesLocator, horizontal_ranges
from .kalman import PositionKalmanTracker
from .nlos import EvidenceNlosTest, MseNlosTest

FloatArray = npt.NDArray[np.float64]

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
        self.tracker = PositionKalmanTracker(self.config.q)
        # per anchor: (t, range, snr_db, per-impulse-response NLOS flag) of recent rounds
        self._history: dict[str, deque[tuple[float, float, float, bool]]] = {}
        ev = self.config.evidence
        self._evidence = None if ev is None else dataclasses.replace(ev, mse=self.config.test)
        self._yaw = 0.0

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
        state, cov = prior
        xy = state[[0, 2]]
        p = cov[np.ix_([0, 2], [0, 2])]
        diff = xy - anchors
        d = np.maximum(np.linalg.norm(diff, axis=1), 1e-6)
        u = diff / d[:, None]
        var = std**2 + np.einsum("ki,ij,kj->k", u, p, u)
        z = np.abs(r - d) / np.sqrt(var)
        out = np.zeros(r.size, bool)
        # one outlier per round at most: when several ranges disagree with the prediction, the
        # prediction is the likelier culprit (a track started on NLOS ranges), so trust the ranges
        if np.sum(z > self.config.gate) == 1:
            out[np.argmax(z)] = True
        return out

    def _branch(
        self,
        prior: tuple[FloatArray, FloatArray],
        anchors: FloatArray,
        r: FloatArray,
        std: FloatArray,
        fix: PositionFix,
    ) -> PositionFix:
        """The fix, or the local solution near the prediction when the fix is the other
        branch of an ambiguous geometry (see the module docstring)."""
        if not np.all(np.isfinite(fix.position)) or not np.all(np.isfinite(fix.cov)):
            return fix
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
        std = np.array([max(links[a][1], self.config.test.los_std) for a in ids], float)
        nlos = np.array([not los[a] for a in ids], bool)
        std = np.where(nlos, max(self.config.nlos_std, 1e-3), std)
        r = horizontal_ranges(r3, pos[:, 2] - self.height)
        prior = self.tracker.predict(t)
        initial = prior[0][[0, 2]] if prior is not None else None
        if prior is not None and self.config.mitigate and self.config.gate > 0:
            std = np.where(self._outliers(prior, pos[:, :2], r, std), self.config.nlos_std, std)
        fix = self.locator.locate(pos[:, :2], r, std, initial=initial)
        if prior is not None and self.config.mitigate and self.config.branch_gate > 0:
            fix = self._branch(prior, pos[:, :2], r, std, fix)
        usable = fix.ok or (initial is not None and np.all(np.isfinite(fix.position)))
        if not self.tracker.initialised and not fix.ok:
            cov3 = np.diag([np.inf, np.inf, np.pi**2 / 3.0])
            pose = (float("nan"), float("nan"), self.height, float("nan"))
            return PoseResult(t=t, pose=pose, cov=cov3, los=los, fix=fix)
        state, p = self.tracker.step(
            t, fix.position if usable else None, fix.cov if usable else None
        )
        speed = math.hypot(state[1], state[3])
        cov3 = np.zeros((3, 3))
        cov3[:2, :2] = p[np.ix_([0, 2], [0, 2])]
        if speed > MIN_SPEED_FOR_YAW:
            self._yaw = math.atan2(state[3], state[1])
            # heading of the velocity: var(angle) ~ var(v_perp) / speed²
            cov3[2, 2] = min((p[1, 1] + p[3, 3]) / 2.0 / speed**2, np.pi**2 / 3.0)
        else:
            cov3[2, 2] = np.pi**2 / 3.0
        pose = (float(state[0]), float(state[2]), self.height, float(self._yaw))
        return PoseResult(t=t, pose=pose, cov=cov3, los=los, fix=fix)
