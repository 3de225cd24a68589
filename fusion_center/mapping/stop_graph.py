"""The robot's path from stop-to-stop scan registration: a pose graph over the stops.

Beyond the CoLOR chapter (whose Section 6 estimates the path with the particle filter): a
deterministic path estimator for stop-and-turn recordings (the robot drives, stops, turns a
full circle on the spot in small steps, drives on), in the manner of graph SLAM
(Lu and Milios, "Globally consistent range scan alignment for environment mapping",
Autonomous Robots 1997; Olson, "Real-time correlative scan matching", ICRA 2009, for the
grid search).

1. **Front end** (:func:`scan_front_end`): per acquisition the echo pairs ``(r1, r2)`` as
   :class:`~fusion_center.mapping.pipeline.EchoSlamMapper` makes them
   (:class:`~fusion_center.mapping.echoes.EnvelopePeakEchoExtractor`,
   :func:`~fusion_center.mapping.echoes.pair_echoes`,
   :class:`~fusion_center.mapping.grouping.KalmanEchoGrouper`) and the odometry; an
   odometry step longer than ``drive_reset`` starts a new stop (:func:`segment_stops`).
2. **Per stop** (:func:`stop_scan`): the in-stop headings corrected by the turn closure
   (:class:`~fusion_center.mapping.turn_closure.EchoBearingTurnCloser`) and the stop's
   reflectors: the echo tracks joined into reflectors fixed in the stop frame, each with its
   image point ``T'`` (eq. (11) and Fig. 19 of the chapter: the transmitter mirrored in a
   wall, point-reflected in a corner; a point scatterer's echoes invert to about twice its
   position, pushed out radially by about ``|rx|^2 cos^2(beta) / (4 d)``: 2-4 cm at 1.5-3 m
   for the recorder's receivers 0.5 m off the transmitter, which the point hypothesis
   models, :func:`predicted_images`' ``point_bias``).
3. **Registration** (:class:`ReflectorRegistration`): the pose of stop B in stop A's frame
   that best explains B's reflector images by A's reflectors, each of A's taken as a wall
   (the same line seen from B: ``T'_B = t + 2 (d - n . t) n``) or as a corner or point (the
   same point: ``T'_B = 2 c - t``), by a coarse-to-fine grid around the odometry's prior, a
   robust refinement, an explained fraction and an ambiguity test.
4. **Pose graph** (:class:`StopPoseGraph`): odometry edges (the turn's corrected end heading
   composed with the drive, with the slip model's noise), registration edges between
   consecutive stops and loop closures between stops close by the current estimate, solved
   by :func:`scipy.optimize.least_squares` (sparse Jacobian) with a Cauchy weight per
   registration edge; solve, look for loop closures around the new estimate, solve again.
5. **Joint refinement** (:func:`refine_turns`): the stop poses and every stop's in-stop
   heading drift (two coefficients over the turn, :func:`turn_basis`) over the reflector
   correspondences of the accepted registrations, the odometry edges and a prior on the
   drift: the turn closure's in-stop headings were the registrations' main error.
6. Output (:meth:`StopGraphPathEstimator.estimate`): ``[t, x, y, yaw]`` of every acquisition
   in the frame of the first pose (the stop's pose and its corrected in-stop heading), the
   layout of map.json's trajectory.

Assumes, as the turn closure does, that the transmitter is the turning centre (the origin
of the robot frame): the reflectors' images are then fixed in the stop frame.

Pure numpy / scipy; poses ``[x, y, yaw]`` (m, rad), ranges bistatic (m).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
import numpy.typing as npt
import scipy.sparse
from scipy.optimize import least_squares

from fusion_center.mapping.echoes import pair_echoes
from fusion_center.mapping.grouping import KalmanEchoGrouper
from fusion_center.mapping.models import invert_image, rotate
from fusion_center.mapping.pipeline import MapperConfig, echo_extractor
from fusion_center.mapping.relocalise import compose_poses
from fusion_center.mapping.stop_bundle import (
    StopBundleConfig,
    adjust_stop_bundle,
    block_pattern,
    drift_basis,
    drift_prior,
)
from fusion_center.mapping.stop_bundle import sqrt_information as _sqrt_info
from fusion_center.mapping.turn_closure import (
    EchoBearingTurnCloser,
    TurnClosureConfig,
    group_median,
)

FloatArray = npt.NDArray[np.float64]


def _wrap(a: npt.ArrayLike) -> FloatArray:
    return (np.asarray(a, float) + np.pi) % (2 * np.pi) - np.pi


def _rot(a: float) -> FloatArray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s], [s, c]])


def relative_pose(a: FloatArray, b: FloatArray) -> FloatArray:
    """Pose ``b`` (3,) in the frame of pose ``a`` (3,): ``a^{-1} (+) b`` (heading wrapped)."""
    d = _rot(-a[2]) @ (np.asarray(b[:2], float) - a[:2])
    return np.array([d[0], d[1], float(_wrap(b[2] - a[2]))])


# --------------------------------------------------------------------------- front end


@dataclass(frozen=True, slots=True, kw_only=True)
class ScanLog:
    """Front-end output of a recording, one entry per acquisition.

    Attributes
    ----------
    t : ndarray, shape (n,)
        Acquisition times, s.
    odometry : ndarray, shape (n, 3)
        ``(dx, dy, dyaw)`` since the previous acquisition (robot frame, m, rad; row 0 zero).
    pairs : list of ndarray, shape (m_k, 2)
        Echo pairs ``(r1, r2)``, m.
    groups : list of ndarray of int, shape (m_k,)
        Echo-track ids of the pairs (restarted at every drive).
    """

    t: FloatArray
    odometry: FloatArray
    pairs: list[FloatArray]
    groups: list[npt.NDArray[np.int64]]

    def __post_init__(self) -> None:
        n = np.asarray(self.t).shape[0]
        if np.asarray(self.odometry).shape != (n, 3):
            raise ValueError(f"ScanLog.odometry must have shape ({n}, 3)")
        if len(self.pairs) != n or len(self.groups) != n:
            raise ValueError(f"ScanLog needs {n} pair and group arrays, one per acquisition")
        if not np.all(np.isfinite(self.odometry)):
            raise ValueError("ScanLog.odometry must be finite")


def scan_front_end(
    frames: Iterable[tuple[float, npt.NDArray, npt.ArrayLike]],
    *,
    fs: float,
    t0: float,
    bandwidth: float,
    config: MapperConfig | None = None,
) -> ScanLog:
    """Echo pairs and echo-track ids of every acquisition, as EchoSlamMapper makes them.

    ``config`` holds the front end's settings (echo search, pairing, warm-up, drive reset),
    the mapper's own :class:`~fusion_center.mapping.pipeline.MapperConfig`. ``frames``
    yields ``(t, h, odometry)``: time (s), impulse responses (2, n) at rx1 and rx2, and
    ``(dx, dy, dyaw)`` since the previous acquisition (required: the path is built on it).
    """
    cfg = config or MapperConfig()
    ext = echo_extractor(cfg, fs=fs, t0=t0, bandwidth=bandwidth)
    pair_gate = cfg.pair_gate
    ts: list[float] = []
    odos: list[FloatArray] = []
    pairs: list[FloatArray] = []
    for t, h, odo in frames:
        if odo is None:
            raise ValueError(f"acquisition at t = {t} s has no odometry (the stop graph needs it)")
        o = np.asarray(odo, float).reshape(-1)
        if o.shape != (3,) or not np.all(np.isfinite(o)):
            raise ValueError(f"acquisition at t = {t} s: odometry must be 3 finite numbers")
        ts.append(float(t))
        odos.append(o if ts[1:] else np.zeros(3))
        pairs += [pair_echoes(e, pair_gate) for e in ext.push(np.asarray(h))]
    pairs += [pair_echoes(e, pair_gate) for e in ext.flush()]
    return scan_log_from_pairs(ts, np.array(odos).reshape(-1, 3), pairs, cfg.drive_reset)


def scan_log_from_pairs(
    t: npt.ArrayLike,
    odometry: npt.ArrayLike,
    pairs: Sequence[npt.ArrayLike],
    drive_reset: float = 0.1,
) -> ScanLog:
    """A :class:`ScanLog` from echo pairs: the Kalman echo tracks of
    :class:`~fusion_center.mapping.grouping.KalmanEchoGrouper` (restarted when the odometry
    steps more than ``drive_reset``, m, as the mapper does), one id per pair.

    Raises
    ------
    ValueError
        Lengths that differ, odometry not (n, 3) and finite, a pair array not (m, 2).
    """
    ts = np.asarray(t, float).reshape(-1)
    odo = np.asarray(odometry, float)
    if odo.shape != (ts.size, 3) or not np.all(np.isfinite(odo)):
        raise ValueError(f"odometry must be {ts.size} finite (dx, dy, dyaw) rows")
    if len(pairs) != ts.size:
        raise ValueError(f"{len(pairs)} pair arrays for {ts.size} acquisitions")
    grouper = KalmanEchoGrouper()
    zs: list[FloatArray] = []
    groups: list[npt.NDArray[np.int64]] = []
    for k, p in enumerate(pairs):  # one Kalman step per acquisition
        z = np.asarray(p, float)
        if z.size == 0:
            z = np.zeros((0, 2))
        if z.ndim != 2 or z.shape[1] != 2:
            raise ValueError(f"pairs of acquisition {k} must have shape (m, 2), got {z.shape}")
        if np.hypot(odo[k, 0], odo[k, 1]) > drive_reset:
            grouper.reset()
        zs.append(z)
        groups.append(np.asarray(grouper.step(z), np.int64))
    return ScanLog(t=ts, odometry=odo, pairs=zs, groups=groups)


def segment_stops(
    odometry: npt.ArrayLike, drive_reset: float = 0.1, move_step: float = 0.02
) -> list[tuple[int, int]]:
    """Index ranges ``[start, end)`` of the stops: an odometry step longer than
    ``drive_reset`` (m) starts a new stop (the acquisition after the drive is its first),
    and so does a step longer than ``move_step`` (m): a drive sampled in several shorter
    steps leaves one-acquisition segments (no turn, no reflectors) and the stop after it
    starts at the acquisition after its last step. A turn on the spot moves by millimetres
    per step (room_pillar, corridor_L: at most 9 mm)."""
    o = np.asarray(odometry, float).reshape(-1, 3)
    if o.shape[0] == 0:
        return []
    step = min(drive_reset, move_step)
    starts = np.r_[0, np.flatnonzero(np.hypot(o[1:, 0], o[1:, 1]) > step) + 1]
    ends = np.r_[starts[1:], o.shape[0]]
    return [(int(a), int(b)) for a, b in zip(starts, ends, strict=True)]


# --------------------------------------------------------------------------- per stop


@dataclass(frozen=True, slots=True, kw_only=True)
class StopScan:
    """One stop: its acquisitions, corrected in-stop poses and reflectors (stop frame).

    Attributes
    ----------
    start, end : int
        Acquisition index range ``[start, end)``.
    poses : ndarray, shape (n, 3)
        Pose of each acquisition in the stop frame (the first acquisition's pose): heading
        ``phi_k + e_k`` (odometry plus turn-closure correction); position 0 when the stop is
        a turn on the spot, else the odometry's.
    end_sigma : float
        Standard deviation of the last acquisition's heading relative to the first, rad
        (the closure's, or the odometry's summed slip noise when the stop was not closed).
    closed : bool
        Whether the turn closure corrected the stop.
    on_the_spot : bool
        Whether the stop is a turn on the spot (its reflectors are only formed then).
    images : ndarray, shape (R, 2)
        Reflector image points ``T'`` in the stop frame, m.
    weights : ndarray, shape (R,)
        Echo pairs behind each reflector.
    image_sigma : ndarray, shape (R,)
        Robust scatter of each reflector's pair images, m.
    turn_basis : ndarray, shape (R, 2)
        Mean over each reflector's pairs of :func:`turn_basis` at the pair's phase of the
        turn: the image rotates by ``turn_basis @ c`` when the in-stop headings are
        corrected by ``turn_basis(f_k) @ c`` (first order; used by the joint refinement).
    phase : ndarray, shape (n,)
        Phase ``f_k`` of each acquisition in the turn: the odometry's heading since the
        first acquisition over the whole turn's (0 .. 1; zeros when the stop does not turn).
    odometry_sigma : float
        Standard deviation of the odometry's own heading at the end of the turn (its summed
        slip noise), rad; NaN when unknown.
    closure_rms : float
        RMS over the turn of the closure's marginal standard deviation of the corrected
        headings (:attr:`~fusion_center.mapping.turn_closure.TurnClosure.rms_sigma`), rad;
        NaN when not closed or unknown.
    """

    start: int
    end: int
    poses: FloatArray
    end_sigma: float
    closed: bool
    on_the_spot: bool
    images: FloatArray
    weights: FloatArray
    image_sigma: FloatArray
    turn_basis: FloatArray = field(default_factory=lambda: np.zeros((0, 2)))
    phase: FloatArray = field(default_factory=lambda: np.zeros(0))
    odometry_sigma: float = float("nan")
    closure_rms: float = float("nan")

    @property
    def heading_rms(self) -> float:
        """RMS over the turn of the in-stop heading's standard deviation, rad: a random walk
        that reaches ``end_sigma`` at the end (``end_sigma / sqrt(2)``), or, when the
        closure corrected the stop, the closure's own marginal over the turn
        (``closure_rms``, with ``StopGraphConfig.closure_marginal``: the inverse of its
        normal matrix; without it the first round's ``end_sigma / sqrt(6)``, about 3 times
        too small, review M1). The
        closure's ``end_sigma`` is not the mid-turn error (room_pillar: 0.55 deg median,
        against 0.74 deg RMS against truth). A reflector is seen somewhere in the turn, so
        its image shares this error; the errors of one stop's reflectors are correlated,
        which the registration's covariance must keep."""
        if not self.closed:
            return float(self.end_sigma / np.sqrt(2.0))
        if np.isfinite(self.closure_rms):
            return float(self.closure_rms)
        return float(self.end_sigma / np.sqrt(6.0))


@dataclass(frozen=True, slots=True, kw_only=True)
class StopGraphConfig:
    """Parameters of :class:`StopGraphPathEstimator` (SI units).

    Attributes
    ----------
    drive_reset : float
        Odometry step (m) that starts a new stop (``MapperConfig.drive_reset``).
    move_step : float
        Odometry step (m) that also starts a new segment (a drive sampled in several
        steps, :func:`segment_stops`).
    min_stop_acquisitions : int
        Acquisitions a stop needs for reflectors to be formed (and registrations tried):
        a segment of a drive or of a robot that never stops has none.
    spot_translation : float
        Net odometry displacement of a stop (m) up to which it is a turn on the spot (plus
        3.5 sigma of the per-step translation floor, as ``MapperConfig``).
    slip_translation, slip_rotation, slip_heading_per_metre : float
        Odometry noise (m/m, rad/rad, rad/m): ``SlamConfig``'s defaults, the recorder's
        ``OdometrySlip``.
    slip_floor : tuple of float
        Per-acquisition odometry noise floor (m, rad).
    min_reflector_pairs : int
        Pairs a reflector needs.
    max_reflector_scatter : float
        Largest robust scatter of a reflector's pair images, m (beyond: clutter chained).
    scatter_per_metre : float
        Added to ``max_reflector_scatter`` per metre of image distance (a far reflector's
        pair images scatter with the bearing noise times the distance).
    merge_distance : float
        Reflectors of one stop whose images lie closer than this are one (the closure's
        complete linkage splits a reflector whose bearing drifts over the turn), m.
    heading_sigma : float
        Heading noise of a stop's in-stop poses after the closure, rad: a reflector image at
        distance ``rho`` gets ``rho * heading_sigma`` added (in quadrature) to its scale.
    coarse_sigma, fine_sigma : float
        Image mismatch scale of the coarse grid and of the fine grid and refinement, m.
    coarse_step, fine_step : tuple of float
        Grid steps ``(m, rad)``.
    window : tuple of float
        Largest half-width of the search ``(m, rad)``; the prior's 3 sigma otherwise.
    min_window : tuple of float
        Smallest half-width of the search ``(m, rad)``.
    max_coarse_cells : int
        Coarse cells per axis on each side of the prior at most: a wider search coarsens
        the steps (and widens the coarse scale with them) instead.
    min_matched : int
        Distinct reflectors of B a registration must explain.
    min_explained : float
        Fraction of B's reflector pairs (weights) it must explain.
    ambiguity_gap : float
        A second mode of the coarse score (outside 3 sigma of the refined covariance) within
        this many nepers of the best makes the match ambiguous (refused).
    match_gate : float
        Image distance, in ``fine_sigma``, within which a reflector counts as explained.
    consistency : tuple of float
        Largest disagreement ``(m, rad)`` of the two directions of a registration (B in A,
        and A in B inverted); beyond it the match is refused.
    cauchy_scale : float
        Scale of the Cauchy weight of a registration edge in the graph, in sigmas of its
        Mahalanobis distance.
    edge_sigma_floor : tuple of float
        Floor of a registration edge's standard deviations ``(m, rad)`` (model errors the
        image scatter does not see: higher-order images, a point taken for a corner).
    loop_distance : float
        Stops closer than this by the current estimate are tried for a loop closure, m.
    loop_window : tuple of float
        Prior standard deviation ``(m, rad)`` of a loop closure's search around the current
        estimate.
    loop_rounds : int
        Solve / look for loop closures rounds (per level of ``loop_defer``).
    loop_defer : tuple of float
        Gate levels of the loop search, in sigmas: at level ``k`` a candidate whose prior
        (the graph's marginal of the relative pose plus ``loop_window``) reaches beyond
        ``window`` at ``k`` sigma in x, y or yaw is left for later; the search moves to the
        next level (the last one: no gate) when a round adds no closure or after
        ``loop_rounds`` rounds. A search capped
        inside its prior's support accepts whatever local match it holds, so the closures
        with narrow priors tighten the graph first (our addition, not from Lu and Milios).
        Empty (default): one level, no gate. Measured: docs/mapping.md.
    loop_gate : float
        A loop closure whose pose lies farther than this many sigmas (Mahalanobis
        distance under the prior's covariance plus the registration's) from its prior is
        refused: the coarse search and its ambiguity test span 3 sigma of the prior, so a
        match the refinement carried beyond them was never compared with the rest of the
        prior (an innovation gate, as a Kalman filter's; our addition). Default inf (no
        gate): with ``loop_defer=(1.0,)`` every closure beyond 3 sigma on room_pillar seed
        1 (world) and seeds 0 / 1 (drive starts) was wrong, and seed 1 (world) went 0.049 ->
        0.039 m, but the pair loses 0.010 m on seed 0 (world); without the deferral right
        closures around a bent graph lay beyond it (docs/mapping.md).
    drive_turn : float
        A recording whose drives turn the robot (the median net ``|yaw|`` of its drives
        between stops, :func:`median_drive_turn`) by more than this (rad; default 20 degrees)
        searches its loops with ``drive_loop_defer`` and ``drive_loop_gate`` in place of
        ``loop_defer`` and ``loop_gate``. A robot that turns to drive (differential drive)
        carries the turn's heading error into every drive: loop priors 2.4-3 m and 31-39
        degrees wide (1 sigma) on room_pillar with ``turn_start = "drive"``, against a search
        capped at ``window``. Robots that drive without turning (the shipped scenarios: the
        drive's own step, 3 degrees) keep the plain search. inf: never. Our addition.
    drive_loop_defer, drive_loop_gate
        ``loop_defer`` and ``loop_gate`` of a recording whose drives turn (default ``(1.0,)``
        and 3.0): room_pillar seed 0 / 1 with drive starts 0.727 / 0.134 -> 0.082 / 0.125 m;
        on the world-start recordings the pair costs seed 0 0.010 m (a 0.3 degree turn of
        the whole map), so they keep the plain search (docs/mapping.md, stop 27).
    search_shear : bool
        The registration's coarse grid follows the prior's regression of ``(x, y)`` on the
        yaw: at a yaw offset ``dy`` from the prior its xy centre moves by
        ``P_xy,yaw / P_yaw,yaw * dy`` and its xy half-width is 3 sigma of the conditional
        (Schur complement) spread, capped at ``window``. A loop across a drive whose heading
        is unsure has its xy on a ridge along the yaw (a far stop swings with the heading);
        a box capped at ``window`` cuts that ridge. Default False: on every search it let
        wrong 2-3-reflector matches into room_pillar seed 1 with drive starts (graph 0.125
        -> 0.923 m); ``loop_shear`` uses it only where the box was capped (our addition).
    loop_shear, drive_loop_shear : bool
        After the last loop level, search once more, with ``search_shear``, every loop
        candidate that is not yet a closure and whose prior still reaches beyond
        ``window`` at 3 sigma (the box search was capped): a stretch the closures could
        not tighten, hung on a drive whose heading is off. ``drive_loop_shear`` (default
        True) for a recording whose drives turn (``drive_turn``), ``loop_shear`` (default
        False) otherwise. The held-out L hall with drive starts: a 23 degree heading error
        on the drive to stop 25 left stops 25-29 2 m off; graph 0.836 -> 0.073 m
        (docs/mapping.md, stop 28).
    closure_min_links : int
        ``TurnClosureConfig.min_links`` of the stops' turn closures (reflectors seen at both
        ends of the turn).
    pair_count_weight : bool
        The registration's refinement weights each reflector by the square root of its
        pairs, with its whole scatter as its scale (review M2: the mismatch and heading
        noise do not average over the pairs). False: weight 1, scale with the scatter over
        the pairs' square root. Default True: False together with ``point_scatterers`` and
        ``closure_marginal`` was worse on room_pillar seed 0 (0.107 -> 0.144 m) and
        corridor_L (0.066 -> 0.091 m); not yet measured one at a time.
    point_scatterers : bool
        Predict point scatterers as a hypothesis of their own, with the bias of their
        images (:func:`predicted_images`' ``point_bias``; review M4). Default False (see
        ``pair_count_weight``).
    closure_marginal : bool
        A closed stop's :attr:`StopScan.heading_rms` is the closure's own marginal over the
        turn (review M1; ``end_sigma / sqrt(6)`` is about 3 times too small). Default False
        (see ``pair_count_weight``).
    refine_turns : bool
        After the pose graph, refine the stop poses and every stop's in-stop heading drift
        jointly over the registrations' reflector correspondences (:func:`refine_turns`).
    refine_min_matches : int
        Correspondences a stop needs for its in-stop heading drift to be refined (fewer:
        kept at the turn closure's).
    refine_distance : float
        Stops closer than this by the graph's estimate give the refinement their reflector
        correspondences at that estimate, registered or not, m (0: only the registrations).
    bundle_adjust : bool
        After the refinement, adjust the stop poses, every stop's in-stop heading drift and
        the landmarks jointly over the individual echo pairs
        (:func:`~fusion_center.mapping.stop_bundle.adjust_stop_bundle`, with the
        estimator's :class:`~fusion_center.mapping.stop_bundle.StopBundleConfig`). On by
        default: room_pillar seeds 0 / 1 path 0.107 / 0.055 -> 0.063 / 0.036 m, corners
        0.151 / 0.088 -> 0.092 / 0.096 m mean, corridor_L 0.066 -> 0.029 m (held-out rooms
        mixed, within 0.03 m either way: docs/mapping.md); 20-28 s more CPU on room_pillar.
    bundle_max_shift : float
        Largest RMS over the stops of the bundle adjustment's pose change, in Mahalanobis
        distance under the pose graph's marginal covariance of each stop; beyond it the
        bundle adjustment's poses and drifts are dropped for the refinement's (a solve that
        turns or moves the graph far outside what its input allows followed wrong
        correspondences; our guard, not from the cited methods). Default 5: room_pillar
        seeds 0 / 1 and the held-out L hall (world starts) shift 1.3-2.7, room_pillar seed 0
        with drive starts 29 (its adjustment turned a wrong graph by 21 degrees: path
        0.727 -> 1.549 m); docs/mapping.md.
    closure_link_scatter : float
        ``TurnClosureConfig.link_scatter`` of the stops' turn closures, rad: a reflector
        whose world bearings scatter more than this in the first or the last third of the
        turn (an echo track that sweeps, no fixed image) is no link. Default inf (no test):
        at 6 degrees it refused lab_skew seed 6's first closure (a sweeping 4.07 m track
        linked to a late reflector, 4.2 degrees off; path 0.342 -> 0.303 m) and the held-out
        L hall's stop 28 (0.101 -> 0.092 m), but also right closures on room_pillar: seed 0
        0.107 -> 0.119 m, seed 1 0.055 -> 0.053 m (corners 0.088 -> 0.097 m). Of the 8
        closures it refused over 8 recordings, 3 were off by 2.7-4.2 degrees (one of them
        better than its odometry) and 5 within 0.6 degrees.
    """

    drive_reset: float = 0.1
    move_step: float = 0.02
    min_stop_acquisitions: int = 10
    spot_translation: float = 0.05
    slip_translation: float = 0.02
    slip_rotation: float = 0.03
    slip_heading_per_metre: float = np.radians(1.0)
    slip_floor: tuple[float, float] = (0.002, np.radians(0.1))
    min_reflector_pairs: int = 4
    max_reflector_scatter: float = 0.3
    scatter_per_metre: float = 0.0
    merge_distance: float = 0.15
    heading_sigma: float = np.radians(0.5)
    coarse_sigma: float = 0.12
    fine_sigma: float = 0.03
    coarse_step: tuple[float, float] = (0.06, np.radians(1.5))
    fine_step: tuple[float, float] = (0.015, np.radians(0.25))
    window: tuple[float, float] = (0.8, np.radians(25.0))
    max_coarse_cells: int = 8
    min_window: tuple[float, float] = (0.12, np.radians(3.0))
    min_matched: int = 2
    min_explained: float = 0.3
    ambiguity_gap: float = 3.0
    match_gate: float = 3.0
    consistency: tuple[float, float] = (0.05, np.radians(1.0))
    cauchy_scale: float = 3.0
    edge_sigma_floor: tuple[float, float] = (0.01, np.radians(0.2))
    loop_distance: float = 3.0
    loop_window: tuple[float, float] = (0.15, np.radians(3.0))
    loop_rounds: int = 3
    loop_defer: tuple[float, ...] = ()
    loop_gate: float = np.inf
    drive_turn: float = float(np.radians(20.0))
    drive_loop_defer: tuple[float, ...] = (1.0,)
    drive_loop_gate: float = 3.0
    search_shear: bool = False
    loop_shear: bool = False
    drive_loop_shear: bool = True
    closure_min_links: int = 1
    refine_turns: bool = True
    pair_count_weight: bool = True
    point_scatterers: bool = False
    closure_marginal: bool = False
    refine_min_matches: int = 8
    refine_distance: float = 3.0
    bundle_adjust: bool = True
    bundle_max_shift: float = 5.0
    closure_link_scatter: float = np.inf

    def __post_init__(self) -> None:
        for name in (
            "drive_reset",
            "move_step",
            "coarse_sigma",
            "fine_sigma",
            "match_gate",
            "cauchy_scale",
            "max_reflector_scatter",
        ):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0.0):
                raise ValueError(f"StopGraphConfig.{name} must be > 0, got {v!r}")
        for name in (
            "coarse_step",
            "fine_step",
            "window",
            "min_window",
            "loop_window",
            "consistency",
        ):
            v = getattr(self, name)
            if len(v) != 2 or not all(np.isfinite(x) and x > 0 for x in v):
                raise ValueError(f"StopGraphConfig.{name} must be two numbers > 0, got {v!r}")
        for name in (
            "min_reflector_pairs",
            "min_matched",
            "loop_rounds",
            "closure_min_links",
            "max_coarse_cells",
            "refine_min_matches",
            "min_stop_acquisitions",
        ):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int | np.integer) or v < 1:
                raise ValueError(f"StopGraphConfig.{name} must be an integer >= 1, got {v!r}")
        if not self.bundle_max_shift > 0.0:  # inf: no guard (nan fails too)
            raise ValueError(
                f"StopGraphConfig.bundle_max_shift must be > 0, got {self.bundle_max_shift!r}"
            )
        if not self.loop_gate > 0.0:  # inf: no gate (nan fails too)
            raise ValueError(f"StopGraphConfig.loop_gate must be > 0, got {self.loop_gate!r}")
        if not self.drive_loop_gate > 0.0:
            raise ValueError(
                f"StopGraphConfig.drive_loop_gate must be > 0, got {self.drive_loop_gate!r}"
            )
        if not self.drive_turn >= 0.0:  # inf: never (nan fails)
            raise ValueError(f"StopGraphConfig.drive_turn must be >= 0, got {self.drive_turn!r}")
        for name in ("loop_defer", "drive_loop_defer"):
            levels = getattr(self, name)
            try:
                ok = isinstance(levels, tuple) and all(
                    np.isfinite(float(k)) and float(k) > 0.0 for k in levels
                )
            except (TypeError, ValueError):
                ok = False
            if not ok:
                raise ValueError(
                    f"StopGraphConfig.{name} must be a tuple of numbers > 0, got {levels!r}"
                )
        if not self.closure_link_scatter > 0.0:  # inf: no test
            raise ValueError(
                "StopGraphConfig.closure_link_scatter must be > 0, "
                f"got {self.closure_link_scatter!r}"
            )
        if not (np.isfinite(self.refine_distance) and self.refine_distance >= 0.0):
            raise ValueError(
                f"StopGraphConfig.refine_distance must be >= 0, got {self.refine_distance!r}"
            )
        if not 0.0 <= self.min_explained <= 1.0:
            raise ValueError(
                f"StopGraphConfig.min_explained must be in [0, 1], got {self.min_explained!r}"
            )


def stop_scan(
    log: ScanLog,
    start: int,
    end: int,
    closer: EchoBearingTurnCloser,
    config: StopGraphConfig,
) -> StopScan:
    """Corrected in-stop poses and reflectors of acquisitions ``[start, end)`` of ``log``.

    The headings are ``theta_k = phi_k + e_k`` with ``phi_k`` the odometry's heading since
    the stop's first acquisition and ``e_k`` the turn closure's correction
    (:mod:`fusion_center.mapping.turn_closure`). Each echo pair gives the image point
    ``T' = R(theta_k) u`` in the stop frame (``u``: the circles' intersection in the array
    frame, :func:`~fusion_center.mapping.models.invert_image`; eq. (11) of the chapter); the
    closure's reflectors (echo tracks joined by image distance and world bearing) give one
    image each: the per-coordinate median of their pairs' images.
    """
    cfg = config
    odo = log.odometry[start:end]
    n = end - start
    dyaw = odo[:, 2].copy()
    dyaw[0] = 0.0
    phi = np.cumsum(dyaw)
    # odometry positions in the stop frame (composed through the turn)
    pos = np.zeros((n, 3))
    for k in range(1, n):  # a loop over one stop's ~120 steps, once per stop
        pos[k] = compose_poses(pos[k - 1 : k], odo[k])[0]
    steps = max(n - 1, 0)
    bound = cfg.spot_translation + min(
        3.5 * cfg.slip_floor[0] * np.sqrt(steps), cfg.spot_translation
    )
    on_spot = bool(np.hypot(pos[-1, 0], pos[-1, 1]) <= bound)
    pairs = log.pairs[start:end]
    groups = log.groups[start:end]
    e = np.zeros(n)
    s_step = cfg.slip_rotation * np.abs(dyaw[1:]) + cfg.slip_floor[1]
    end_sigma = odo_sigma = float(np.sqrt(np.sum(s_step**2)))
    closed = False
    closure_rms = float("nan")
    if on_spot and n > 2:
        res = closer.close(dyaw, list(pairs), list(groups))
        if np.isfinite(res.end_sigma):
            e, end_sigma, closed = res.correction, float(res.end_sigma), True
            if cfg.closure_marginal:
                closure_rms = float(res.rms_sigma)
    theta = phi + e
    poses = np.column_stack([pos[:, :2] * (not on_spot), theta])
    # phase of the turn, for the in-stop heading's drift model (joint refinement)
    frac = phi / phi[-1] if n > 1 and abs(phi[-1]) > np.radians(10.0) else np.zeros(n)
    empty = StopScan(
        start=start,
        end=end,
        poses=poses,
        end_sigma=end_sigma,
        closed=closed,
        on_the_spot=on_spot,
        images=np.zeros((0, 2)),
        weights=np.zeros(0),
        image_sigma=np.zeros(0),
        phase=frac,
        odometry_sigma=odo_sigma,
        closure_rms=closure_rms,
    )
    k = np.concatenate([np.full(len(z), i) for i, z in enumerate(pairs)]).astype(np.intp)
    if not on_spot or k.size == 0 or n < cfg.min_stop_acquisitions:
        return empty
    z = np.concatenate([np.reshape(p, (-1, 2)) for p in pairs])
    gid = np.concatenate([np.asarray(g, np.int64) for g in groups])
    u = invert_image(z, closer.rx_body)
    ok = np.all(np.isfinite(u), 1)
    k, gid, u = k[ok], gid[ok], u[ok]
    if k.size == 0:
        return empty
    c, s = np.cos(theta[k]), np.sin(theta[k])
    img = np.column_stack([c * u[:, 0] - s * u[:, 1], s * u[:, 0] + c * u[:, 1]])
    rho = np.hypot(u[:, 0], u[:, 1])
    world = theta[k] + np.arctan2(u[:, 1], u[:, 0])
    label = closer.reflectors(gid, rho, world)  # the closure's own joining of echo tracks
    nr = int(label.max()) + 1
    cnt = np.bincount(label, minlength=nr).astype(float)
    med = np.column_stack([group_median(img[:, j], label, nr) for j in range(2)])
    dev = np.linalg.norm(img - med[label], axis=1)
    scatter = 1.4826 * group_median(dev, label, nr) / np.sqrt(2.0)
    limit = cfg.max_reflector_scatter + cfg.scatter_per_metre * np.hypot(med[:, 0], med[:, 1])
    keep = (cnt >= cfg.min_reflector_pairs) & (scatter <= limit)
    basis = turn_basis(frac[k])
    gb = np.column_stack([np.bincount(label, basis[:, j], nr) / cnt for j in range(2)])
    med, cnt, scatter, gb = _merge_reflectors(
        med[keep], cnt[keep], scatter[keep], cfg.merge_distance, gb[keep]
    )
    return replace(empty, images=med, weights=cnt, image_sigma=scatter, turn_basis=gb)


def turn_basis(phase: npt.ArrayLike) -> FloatArray:
    """Basis (n, 2) of the in-stop heading error over a turn at phases ``f`` (0 .. 1):
    ``[f, sin(pi f)]``, a drift that grows to the end of the turn and a bridge that returns
    to zero at its end. On room_pillar they leave 0.45-0.48 deg RMS of the turn-closed
    headings' 1.0-1.7 deg (beyond the chapter; a random walk's first two modes)."""
    return drift_basis(phase, 2)


def _merge_reflectors(
    images: FloatArray,
    weights: FloatArray,
    scatter: FloatArray,
    distance: float,
    basis: FloatArray,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Join reflectors whose images lie within ``distance`` (heaviest first, greedy): the
    weighted mean image, the summed weight, the weighted scatter plus the images' spread,
    the weighted mean turn basis."""
    order = np.argsort(-weights)
    images, weights, scatter, basis = images[order], weights[order], scatter[order], basis[order]
    free = np.ones(len(weights), bool)
    out_i, out_w, out_s, out_b = [], [], [], []
    for r in range(len(weights)):  # a handful of reflectors per stop
        if not free[r]:
            continue
        near = free & (np.linalg.norm(images - images[r], axis=1) < distance)
        free &= ~near
        w = weights[near]
        m = (w[:, None] * images[near]).sum(0) / w.sum()
        spread = np.sqrt((w * np.sum((images[near] - m) ** 2, 1)).sum() / w.sum() / 2)
        out_i.append(m)
        out_w.append(w.sum())
        out_s.append(float(np.hypot((w * scatter[near]).sum() / w.sum(), spread)))
        out_b.append((w[:, None] * basis[near]).sum(0) / w.sum())
    return (
        np.array(out_i).reshape(-1, 2),
        np.array(out_w),
        np.array(out_s),
        np.array(out_b).reshape(-1, 2),
    )


# --------------------------------------------------------------------------- registration


@dataclass(frozen=True, slots=True, kw_only=True)
class Registration:
    """Result of registering stop B to stop A.

    Attributes
    ----------
    pose : ndarray, shape (3,)
        Pose of B's frame in A's frame ``[x, y, yaw]`` (m, rad).
    cov : ndarray, shape (3, 3)
        Its covariance.
    explained : float
        Fraction of B's reflector pairs explained by A's reflectors at ``pose``.
    matched : int
        Distinct B reflectors explained.
    accepted : bool
        Whether the match passed the tests (explained fraction, matched reflectors,
        ambiguity, a regular covariance).
    reason : str
        Why it was refused ("" when accepted).
    """

    pose: FloatArray
    cov: FloatArray
    explained: float
    matched: int
    accepted: bool
    reason: str = ""


def predicted_images(images_a: FloatArray, pose: FloatArray, point_bias: float = 0.0) -> FloatArray:
    """Images of A's reflectors (R, 2; A frame) as stop B at ``pose`` (n, 3) would see them,
    in B's frame, under each hypothesis: shape (n, 2R, 2), walls first, then corners or points
    (and point scatterers with ``point_bias``, below).

    With A's transmitter at its origin, reflector ``I`` is the wall ``n . x = d`` with
    ``n = I / |I|``, ``d = |I| / 2`` (the perpendicular bisector, :func:`~fusion_center.
    mapping.models.states_from_image`), or the corner or point ``c = I / 2``. From B's
    transmitter ``t`` the images are (Fig. 19 / eq. (11) of the CoLOR chapter)

    .. math::
        T'_{wall} = t + 2 (d - n \\cdot t) n, \\qquad T'_{point} = 2 c - t = I - t,

    both rotated into B's frame: ``R(-yaw) (T' - t)``. A wall B sees from behind
    (``d - n . t <= 0.05``) is NaN.

    ``point_bias`` (``kappa``, m^2): the circles' intersection of a point scatterer's two
    ellipse ranges (:func:`~fusion_center.mapping.models.invert_image`) lies about
    ``kappa / (2 |I|)`` beyond ``2 c`` (``kappa = |rx|^2 cos^2(beta)``, receivers ``|rx|``
    off the transmitter, bearing ``beta``: a second-order expansion, checked against the
    exact inversion); a corner's image is exact. When it is not 0 a third hypothesis, the
    point scatterer, removes A's bias and adds B's: shape (n, 3R, 2).
    """
    q = np.asarray(pose, float).reshape(-1, 3)
    wall, point, scat = images_seen_from(images_a[None], q[:, None, :2], point_bias)
    # a point scatterer (not a corner, whose image is exact): a third hypothesis
    blocks = [wall, point] if scat is None else [wall, point, scat]
    rel = np.concatenate(blocks, axis=1)  # (n, 2R, 2), A-frame axes
    c, sn = np.cos(q[:, 2])[:, None], np.sin(q[:, 2])[:, None]
    return np.stack([c * rel[..., 0] + sn * rel[..., 1], -sn * rel[..., 0] + c * rel[..., 1]], -1)


def images_seen_from(
    images_a: FloatArray, t: FloatArray, point_bias: float = 0.0, guard: bool = True
) -> tuple[FloatArray, FloatArray, FloatArray | None]:
    """``T' - t`` (..., 2; A-frame axes, m) of A's reflector images ``images_a`` (..., 2; A
    frame, A's transmitter at the origin) seen from B's transmitter at ``t`` (..., 2; A
    frame), broadcast, under each hypothesis (Fig. 19 / eq. (11) of the CoLOR chapter; see
    :func:`predicted_images`): the wall ``2 (d - n . t) n`` (with ``guard`` NaN where B sees
    it from behind, ``d - n . t <= 0.05``: no correspondence is formed there; without it the
    smooth model, for a residual over formed correspondences), the corner or point
    ``I - 2 t``, and the point scatterer with ``point_bias`` (None when it is 0)."""
    norm = np.maximum(np.linalg.norm(images_a, axis=-1, keepdims=True), 1e-9)
    nrm = images_a / norm
    s = 0.5 * norm - np.sum(nrm * t, -1, keepdims=True)
    wall = 2.0 * s * nrm
    if guard:
        wall = np.where(s > 0.05, wall, np.nan)
    point = images_a - 2.0 * t
    if point_bias == 0.0:
        return wall, point, None
    return wall, point, _point_bias(_point_bias(images_a, -point_bias) - 2.0 * t, point_bias)


def _point_bias(images: FloatArray, kappa: float) -> FloatArray:
    """Images (m, 2) pushed out radially by ``kappa / (2 |I|)`` (in by a negative one)."""
    if kappa == 0.0:
        return images
    r = np.maximum(np.linalg.norm(images, axis=-1, keepdims=True), 1e-9)
    return images * (1.0 + kappa / (2.0 * r**2))


class ReflectorRegistration:
    """Pose of stop B in stop A's frame from their reflector sets (see the module).

    Score of a candidate pose ``q`` (log-likelihood of B's reflector images plus the prior):

    .. math::
        s(q) = \\sum_j w_j \\ln\\Big(\\lambda + \\sum_h
        \\exp\\big(-\\lVert I^B_j - P_h(q) \\rVert^2 / 2\\sigma^2\\big)\\Big)
        - \\tfrac12 (q - \\hat q)^T P^{-1} (q - \\hat q)

    with ``P_h(q)`` A's reflectors' predicted images (:func:`predicted_images`, each as a
    wall and as a point), ``w_j`` the square root of B's pairs behind reflector ``j`` (the
    pairs of one reflector are not independent: one image each), ``lambda = exp(-2)`` (a
    reflector more than 2 sigma from every prediction is clutter). Coarse grid (``sigma =
    coarse_sigma``) over 3 sigma of the prior, fine grid (``fine_sigma``) around its best,
    then Gauss-Newton with Cauchy weights on the explained reflectors' image residuals,
    whose inverse normal matrix (floored by ``edge_sigma_floor``) is the covariance.
    Correlative scan matching (Olson 2009) on reflectors; beyond the chapter.
    """

    def __init__(self, config: StopGraphConfig | None = None, point_bias: float = 0.0) -> None:
        self.config = config or StopGraphConfig()
        self.point_bias = float(point_bias)

    def _scores(
        self, poses: FloatArray, a: StopScan, b: StopScan, sigma: float, heading: float = 0.0
    ) -> tuple[FloatArray, FloatArray]:
        """Log-likelihood (n,) and the best hypothesis' squared distance (n, Rb)."""
        pred = predicted_images(a.images, poses, self.point_bias)  # (n, H, 2)
        d2 = np.sum((b.images[None, :, None, :] - pred[:, None]) ** 2, -1)  # (n, Rb, H)
        d2 = np.where(np.isnan(d2), np.inf, d2)
        best = d2.min(-1)
        sig2 = self._sigma(b, sigma, a, heading) ** 2
        lik = np.exp(-0.5 * d2 / sig2[None, :, None]).sum(-1)
        w = np.sqrt(b.weights)
        ll = np.log(np.exp(-2.0) + lik) @ w
        return ll, best

    def _sigma(
        self, b: StopScan, base: float, a: StopScan | None = None, heading: float = 0.0
    ) -> FloatArray:
        """Image mismatch scale of each of B's reflectors, m: ``base``, its own scatter and
        its distance times the heading noise (``heading_sigma``, both stops'
        :attr:`StopScan.heading_rms` and ``heading``, rad), in quadrature."""
        rho = np.linalg.norm(b.images, axis=1)
        hs2 = self.config.heading_sigma**2 + b.heading_rms**2 + heading**2
        if a is not None:
            hs2 += a.heading_rms**2
        return np.sqrt(base**2 + b.image_sigma**2 + rho**2 * hs2)

    def register(
        self, a: StopScan, b: StopScan, prior: npt.ArrayLike, prior_cov: npt.ArrayLike
    ) -> Registration:
        """Register stop ``b`` to stop ``a`` around ``prior`` (pose of B in A, (3,)) with
        covariance ``prior_cov`` (3, 3)."""
        cfg = self.config
        prior = np.asarray(prior, float).reshape(3)
        prior_cov = np.asarray(prior_cov, float).reshape(3, 3)
        refused = Registration(pose=prior, cov=prior_cov, explained=0.0, matched=0, accepted=False)
        if len(a.images) < cfg.min_matched or len(b.images) < cfg.min_matched:
            return _replace_reason(refused, "too few reflectors")
        # the prior's information matrix (its quadratic form over the grid, and the
        # refinement's normal equations)
        info = np.linalg.solve(prior_cov + np.diag([1e-6, 1e-6, 1e-8]), np.eye(3))
        sd = np.sqrt(np.diag(prior_cov))
        # the grid's xy follows the prior's regression on the yaw (its conditional mean
        # given the yaw) and spans the conditional spread: where the yaw is uncertain the
        # xy of a far stop moves with it, and a box capped at ``window`` cuts that ridge
        shear = np.zeros(2)
        if cfg.search_shear and sd[2] > 0.0:
            shear = prior_cov[:2, 2] / prior_cov[2, 2]
            sd = np.sqrt(
                np.r_[np.clip(np.diag(prior_cov)[:2] - shear * prior_cov[:2, 2], 0.0, None), sd[2]]
            )
        half_xy = np.clip(3 * sd[:2], cfg.min_window[0], cfg.window[0])
        half_yaw = float(np.clip(3 * sd[2], cfg.min_window[1], cfg.window[1]))

        def axis(half: float, step: float) -> FloatArray:
            k = int(np.ceil(half / step - 1e-9))
            return np.arange(-k, k + 1) * step

        def grid(base: FloatArray, axes: list[FloatArray]) -> FloatArray:
            mesh = np.meshgrid(*axes, indexing="ij")
            return base + np.stack([m.ravel() for m in mesh], -1)

        def log_prior(q: FloatArray) -> FloatArray:
            d = q - prior
            d[:, 2] = _wrap(d[:, 2])
            return -0.5 * np.einsum("ni,ij,nj->n", d, info, d)

        # a wide prior (a loop closure across a stretch held by odometry) coarsens the grid
        # rather than growing it: at most 2 max_coarse_cells + 1 cells per axis, the
        # match's scale widened to the cells
        m_c = cfg.max_coarse_cells
        cs = max(cfg.coarse_step[0], float(half_xy.max()) / m_c)
        cy = max(cfg.coarse_step[1], half_yaw / m_c)
        c_sigma = float(np.hypot(cfg.coarse_sigma, cs - cfg.coarse_step[0]))
        c_heading = max(cy - cfg.coarse_step[1], 0.0)
        coarse = grid(prior, [axis(half_xy[0], cs), axis(half_xy[1], cs), axis(half_yaw, cy)])
        coarse[:, :2] += (coarse[:, 2:] - prior[2]) * shear
        score = np.concatenate(
            [
                self._scores(chunk, a, b, c_sigma, c_heading)[0]
                for chunk in np.array_split(coarse, max(1, coarse.shape[0] // 4000))
            ]
        ) + log_prior(coarse)
        top = coarse[int(np.argmax(score))]
        fs, fy = cfg.fine_step
        fine = grid(top, [axis(cs, fs), axis(cs, fs), axis(cy, fy)])
        fscore = self._scores(fine, a, b, cfg.fine_sigma)[0] + log_prior(fine)
        pose = fine[int(np.argmax(fscore))]
        pose, cov, explained_mask = self._refine(pose, a, b, prior, info)
        if pose is None:
            return _replace_reason(refused, "refinement failed")
        wsum = float(b.weights.sum())
        explained = float(b.weights[explained_mask].sum() / max(wsum, 1e-12))
        matched = int(explained_mask.sum())
        reg = Registration(pose=pose, cov=cov, explained=explained, matched=matched, accepted=True)
        if matched < cfg.min_matched:
            return _replace_reason(reg, f"{matched} reflectors matched")
        if explained < cfg.min_explained:
            return _replace_reason(reg, f"explained {explained:.2f}")
        # ambiguity: another coarse mode, not within 3 sigma of the refined pose, nearly as good
        d = coarse - pose
        d[:, 2] = _wrap(d[:, 2])
        cov_s = cov + np.diag([cs**2, cs**2, cy**2])
        m2 = np.einsum("ni,ni->n", d, np.linalg.solve(cov_s, d.T).T)
        far = m2 > 9.0
        if np.any(far):
            # the coarse score at the refined pose's own cell
            own = float(score[~far].max()) if np.any(~far) else float(score.max())
            if float(score[far].max()) > own - cfg.ambiguity_gap:
                return _replace_reason(reg, "ambiguous")
        return reg

    def register_both(
        self, a: StopScan, b: StopScan, prior: npt.ArrayLike, prior_cov: npt.ArrayLike
    ) -> Registration:
        """:meth:`register` in both directions (B in A, and A in B inverted), accepted only
        when both are and they agree within ``consistency``; the result is the forward
        match with the larger of the two covariances (a wrong correspondence seldom wins
        both ways: the two directions explain different reflector sets)."""
        cfg = self.config
        prior = np.asarray(prior, float).reshape(3)
        prior_cov = np.asarray(prior_cov, float).reshape(3, 3)
        fwd = self.register(a, b, prior, prior_cov)
        if not fwd.accepted:
            return fwd
        inv_prior = relative_pose(prior, np.zeros(3))
        jac = _inverse_jacobian(prior)
        back = self.register(b, a, inv_prior, jac @ prior_cov @ jac.T)
        if not back.accepted:
            return _replace_reason(fwd, f"reverse {back.reason}")
        other = relative_pose(back.pose, np.zeros(3))
        d = other - fwd.pose
        d[2] = float(_wrap(d[2]))
        if np.hypot(d[0], d[1]) > cfg.consistency[0] or abs(d[2]) > cfg.consistency[1]:
            return _replace_reason(fwd, "inconsistent")
        jb = _inverse_jacobian(back.pose)
        cov_b = jb @ back.cov @ jb.T
        # the larger of the two in every direction, and their disagreement
        lam_f, vec = np.linalg.eigh(fwd.cov)
        lam_b = np.einsum("ij,jk,ki->i", vec.T, cov_b, vec)
        cov = vec @ np.diag(np.maximum(lam_f, lam_b)) @ vec.T + np.diag(d**2) / 4.0
        return Registration(
            pose=fwd.pose,
            cov=cov,
            explained=min(fwd.explained, back.explained),
            matched=min(fwd.matched, back.matched),
            accepted=True,
        )

    def _refine(
        self,
        pose: FloatArray,
        a: StopScan,
        b: StopScan,
        prior: FloatArray,
        prior_info: FloatArray,
    ) -> tuple[FloatArray | None, FloatArray, npt.NDArray[np.bool_]]:
        """Gauss-Newton with Cauchy weights on the image residuals of the explained
        reflectors (nearest hypothesis within ``match_gate`` fine sigmas); numerical
        Jacobian (3 parameters). Returns the pose, its covariance (without the prior, with
        the floor) and the explained mask over B's reflectors."""
        cfg = self.config
        gate = cfg.match_gate * self._sigma(b, cfg.fine_sigma, a)
        # information of a reflector: its model mismatch and heading error are common to
        # all its pairs; only its pairs' scatter averages over them (no sqrt(N) weight)
        if cfg.pair_count_weight:
            sig = self._sigma(b, cfg.fine_sigma, a)
            w = np.sqrt(b.weights)
        else:
            sig = self._sigma(
                replace(b, image_sigma=b.image_sigma / np.sqrt(b.weights)), cfg.fine_sigma, a
            )
            w = np.ones(len(b.weights))
        q = pose.copy()
        mask = np.zeros(len(b.images), bool)
        cov = np.diag(np.array([cfg.window[0], cfg.window[0], cfg.window[1]]) ** 2)
        for _ in range(8):
            pred = predicted_images(a.images, q, self.point_bias)[0]  # (H, 2)
            d2 = np.sum((b.images[:, None] - pred[None]) ** 2, -1)
            d2 = np.where(np.isnan(d2), np.inf, d2)
            h = np.argmin(d2, 1)
            mask = np.sqrt(d2[np.arange(len(h)), h]) < gate
            if mask.sum() < 2:
                return None, cov, mask
            jm, hm = np.flatnonzero(mask), h[mask]

            def resid(p: FloatArray, jm: npt.NDArray = jm, hm: npt.NDArray = hm) -> FloatArray:
                pr = predicted_images(a.images, p, self.point_bias)[0][hm]
                return ((b.images[jm] - pr) / sig[jm, None]).ravel()

            r = resid(q)
            jac = np.empty((r.size, 3))
            for i, eps in enumerate((1e-4, 1e-4, 1e-5)):
                dq = np.zeros(3)
                dq[i] = eps
                jac[:, i] = (resid(q + dq) - r) / eps
            rr = r.reshape(-1, 2)
            cw = 1.0 / (1.0 + np.sum(rr**2, 1) / (2 * cfg.match_gate**2))  # Cauchy on the 2-D
            wt = np.repeat(w[jm] * cw, 2)
            if not np.all(np.isfinite(jac)):
                return None, cov, mask
            a_mat = jac.T @ (wt[:, None] * jac)
            dp = q - prior
            dp[2] = _wrap(dp[2])
            lhs = a_mat + prior_info
            rhs = -(jac.T @ (wt * r)) - prior_info @ dp
            try:
                step = np.linalg.solve(lhs, rhs)
            except np.linalg.LinAlgError:
                return None, cov, mask
            q = q + step
            if np.all(np.abs(step) < [1e-5, 1e-5, 1e-6]):
                break
        # the normal matrix at the final pose (the loop's is from before its last step)
        r = resid(q)
        for i, eps in enumerate((1e-4, 1e-4, 1e-5)):
            dq = np.zeros(3)
            dq[i] = eps
            jac[:, i] = (resid(q + dq) - r) / eps
        cw = 1.0 / (1.0 + np.sum(r.reshape(-1, 2) ** 2, 1) / (2 * cfg.match_gate**2))
        a_mat = jac.T @ (np.repeat(w[jm] * cw, 2)[:, None] * jac)
        if not np.all(np.isfinite(a_mat)):
            return None, cov, mask
        try:
            cov = np.linalg.solve(a_mat + np.diag([1e-6, 1e-6, 1e-6]), np.eye(3))
        except np.linalg.LinAlgError:
            return None, cov, mask
        floor = np.array(
            [cfg.edge_sigma_floor[0], cfg.edge_sigma_floor[0], cfg.edge_sigma_floor[1]]
        )
        # the stops' in-stop heading errors are common to all their reflectors: they do not
        # average out over the reflectors as the normal matrix assumes
        hs = a.heading_rms**2 + b.heading_rms**2
        cov = cov + np.diag(floor**2) + np.diag([0.0, 0.0, hs])
        q[2] = float(_wrap(q[2]))
        return q, cov, mask


def _inverse_jacobian(pose: FloatArray) -> FloatArray:
    """Jacobian of the inverse pose ``(-R^T t, -yaw)`` with respect to ``pose``."""
    c, s = np.cos(pose[2]), np.sin(pose[2])
    x, y = pose[0], pose[1]
    return np.array(
        [
            [-c, -s, s * x - c * y],
            [s, -c, c * x + s * y],
            [0.0, 0.0, -1.0],
        ]
    )


def _replace_reason(r: Registration, reason: str) -> Registration:
    return Registration(
        pose=r.pose,
        cov=r.cov,
        explained=r.explained,
        matched=r.matched,
        accepted=False,
        reason=reason,
    )


# --------------------------------------------------------------------------- pose graph


@dataclass(frozen=True, slots=True, kw_only=True)
class GraphEdge:
    """A relative-pose measurement ``z`` (3,) of stop ``j`` in stop ``i``'s frame with
    covariance ``cov``; ``robust`` edges (registrations) get a Cauchy weight."""

    i: int
    j: int
    z: FloatArray
    cov: FloatArray
    robust: bool
    kind: str = "odometry"


class StopPoseGraph:
    """Least-squares pose graph over the stops (Lu and Milios 1997; beyond the chapter).

    Residual of edge ``(i, j, z, C)``: ``L^T (x_i^{-1} (+) x_j - z)`` (heading wrapped) with
    ``L L^T = C^{-1}``; stop 0 is fixed at the origin. Registration edges are weighted by
    ``1 / (1 + chi^2 / c^2)`` of their Mahalanobis distance ``chi`` (Cauchy, iteratively
    reweighted), so a wrong match does not bend the graph; odometry edges keep weight 1.
    Solved by :func:`scipy.optimize.least_squares` with a sparse Jacobian.
    """

    def __init__(self, n_stops: int, cauchy_scale: float = 3.0) -> None:
        if n_stops < 1:
            raise ValueError(f"a pose graph needs at least one stop, got {n_stops}")
        self.n = int(n_stops)
        self.cauchy_scale = float(cauchy_scale)
        self.edges: list[GraphEdge] = []

    def add(self, edge: GraphEdge) -> None:
        if not (0 <= edge.i < self.n and 0 <= edge.j < self.n) or edge.i == edge.j:
            raise ValueError(f"edge ({edge.i}, {edge.j}) outside stops 0..{self.n - 1}")
        self.edges.append(edge)

    def solve(self, initial: FloatArray, reweight: int = 4) -> tuple[FloatArray, FloatArray]:
        """Stop poses (n, 3) from ``initial`` (n, 3; row 0 is kept), and the final Cauchy
        weight of every edge (1 for odometry edges). The first weights come from
        ``initial``, which should be consistent with the trusted edges (the estimator's
        chain of consecutive registrations, or the previous solve)."""
        x0 = np.asarray(initial, float).reshape(self.n, 3)
        if self.n == 1 or not self.edges:
            return x0.copy(), np.ones(len(self.edges))
        ei = np.array([e.i for e in self.edges])
        ej = np.array([e.j for e in self.edges])
        z = np.array([e.z for e in self.edges])
        sqi = np.array([_sqrt_info(e.cov) for e in self.edges])
        robust = np.array([e.robust for e in self.edges])
        m = len(self.edges)
        # sparsity: each edge's 3 residuals depend on the 3 + 3 variables of its stops
        rows = np.repeat(np.arange(3 * m), 6)
        k3 = np.arange(3)
        cols_e = np.hstack([3 * (ei - 1)[:, None] + k3, 3 * (ej - 1)[:, None] + k3])
        cols = np.repeat(cols_e[:, None, :], 3, axis=1).reshape(-1)
        ok = cols >= 0
        sparsity = scipy.sparse.coo_matrix(
            (np.ones(ok.sum()), (rows[ok], cols[ok])), shape=(3 * m, 3 * (self.n - 1))
        ).tocsr()
        wt = np.ones(m)

        def errors(x: FloatArray) -> FloatArray:
            p = np.vstack([x0[:1], x.reshape(-1, 3)])
            pi, pj = p[ei], p[ej]
            c, s = np.cos(pi[:, 2]), np.sin(pi[:, 2])
            dx, dy = pj[:, 0] - pi[:, 0], pj[:, 1] - pi[:, 1]
            rel = np.column_stack([c * dx + s * dy, -s * dx + c * dy, pj[:, 2] - pi[:, 2]])
            d = rel - z
            d[:, 2] = _wrap(d[:, 2])
            return np.einsum("mij,mj->mi", sqi, d)

        def fun(x: FloatArray) -> FloatArray:
            return (np.sqrt(wt)[:, None] * errors(x)).ravel()

        x = x0[1:].ravel()
        # the first weights from the initial estimate (the chain of consecutive matches):
        # starting from weight 1 would let a wrong loop closure bend the first solve, and
        # then every edge it bent looks as wrong as the loop closure itself
        chi2 = np.sum(errors(x) ** 2, 1)
        wt = np.where(robust, 1.0 / (1.0 + chi2 / self.cauchy_scale**2), 1.0)
        for _ in range(max(reweight, 1)):
            sol = least_squares(fun, x, jac_sparsity=sparsity, method="trf", x_scale="jac")
            x = sol.x
            chi2 = np.sum(errors(x) ** 2, 1)
            wt = np.where(robust, 1.0 / (1.0 + chi2 / self.cauchy_scale**2), 1.0)
        poses = np.vstack([x0[:1], x.reshape(-1, 3)])
        poses[:, 2] = _wrap(poses[:, 2])
        return poses, wt

    def covariance(self, poses: FloatArray, weights: FloatArray) -> FloatArray:
        """Covariance (3(n-1), 3(n-1)) of stops 1..n-1 at the solution ``poses`` with the
        edge ``weights`` of :meth:`solve`: the inverse of the Gauss-Newton normal matrix
        (Jacobian by finite differences; stop 0 fixed). Dense: meant for tens to a few
        hundred stops."""
        p = np.asarray(poses, float).reshape(self.n, 3)
        if self.n == 1 or not self.edges:
            return np.eye(3 * (self.n - 1))
        ei = np.array([e.i for e in self.edges])
        ej = np.array([e.j for e in self.edges])
        z = np.array([e.z for e in self.edges])
        sw = np.sqrt(np.asarray(weights, float))[:, None, None]
        sqi = sw * np.array([_sqrt_info(e.cov) for e in self.edges])

        def res(q: FloatArray) -> FloatArray:
            pi, pj = q[ei], q[ej]
            c, s = np.cos(pi[:, 2]), np.sin(pi[:, 2])
            dx, dy = pj[:, 0] - pi[:, 0], pj[:, 1] - pi[:, 1]
            d = np.column_stack([c * dx + s * dy, -s * dx + c * dy, pj[:, 2] - pi[:, 2]]) - z
            d[:, 2] = _wrap(d[:, 2])
            return np.einsum("mij,mj->mi", sqi, d).ravel()

        r0 = res(p)
        jac = np.empty((r0.size, 3 * (self.n - 1)))
        for k in range(3 * (self.n - 1)):  # one column per variable
            q = p.copy()
            q[1 + k // 3, k % 3] += 1e-6
            jac[:, k] = (res(q) - r0) / 1e-6
        info = jac.T @ jac
        return np.linalg.solve(info + 1e-12 * np.eye(info.shape[0]), np.eye(info.shape[0]))


def relative_covariance(poses: FloatArray, cov: FloatArray, i: int, j: int) -> FloatArray:
    """Covariance (3, 3) of stop ``j``'s pose in stop ``i``'s frame from the joint
    covariance ``cov`` of stops 1..n-1 (:meth:`StopPoseGraph.covariance`; stop 0 fixed),
    propagated to first order (numerical Jacobian of :func:`relative_pose`)."""
    idx = [k for k in (i, j) if k > 0]
    sel = np.concatenate([3 * (k - 1) + np.arange(3) for k in idx]) if idx else np.zeros(0, int)
    if sel.size == 0:
        return np.zeros((3, 3))
    base = relative_pose(poses[i], poses[j])
    cols = []
    for k in idx:
        for c in range(3):
            q = poses.copy()
            q[k, c] += 1e-6
            d = relative_pose(q[i], q[j]) - base
            d[2] = float(_wrap(d[2]))
            cols.append(d / 1e-6)
    jac = np.array(cols).T
    return jac @ cov[np.ix_(sel, sel)] @ jac.T


# --------------------------------------------------------------------------- refinement


def refine_turns(
    stops: Sequence[StopScan],
    edges: Sequence[GraphEdge],
    weights: FloatArray,
    poses: FloatArray,
    odometry: Sequence[tuple[FloatArray, FloatArray]],
    config: StopGraphConfig,
    rounds: int = 3,
    point_bias: float = 0.0,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Joint refinement of the stop poses and every stop's in-stop heading error over the
    reflector correspondences of the accepted registrations (a small bundle adjustment;
    beyond the chapter, after Triggs et al., "Bundle adjustment - a modern synthesis", 2000).

    Unknowns: the poses of stops 1..n-1 and two coefficients ``c_s`` per stop of the
    in-stop heading correction ``turn_basis(f_k) @ c_s`` (:func:`turn_basis`). Residuals:

    * every reflector correspondence of a stop pair ``(i, j)``: each pair closer than
      ``refine_distance`` by ``poses`` at that relative pose, and each other registration
      edge at its own pose and with its graph weight (B's reflector and A's wall or point
      hypothesis nearest at that pose, within ``match_gate``): B's image
      rotated by ``turn_basis_j @ c_j`` against A's image rotated by ``turn_basis_i @ c_i``
      and predicted at ``x_i^{-1} (+) x_j`` (:func:`predicted_images`' models), over the
      image scale (``fine_sigma``, both reflectors' scatter, the distance times
      ``heading_sigma``), times the pair's weight and a Cauchy weight per
      correspondence (iteratively reweighted, ``rounds`` times);
    * the odometry edges ``odometry[i]`` = ``(z, C)`` of stop i to i + 1 built without the
      turn's end heading noise, the drive rotated by stop i's end correction ``c_i[0]``;
    * the prior ``c_s ~ N(0, diag(end_sigma^2, (s_odo / 2)^2))``: the turn's end error (the
      closure's or the odometry's) and the bridge of the odometry's random walk.

    Returns the stop poses (n, 3; stop 0 kept), the coefficients (n, 2), rad, and the final
    Cauchy weight of every correspondence.
    """
    cfg = config
    n = len(stops)
    p0 = np.asarray(poses, float).reshape(n, 3)
    # correspondences of every registration edge at its own pose
    # the stop pairs: every pair closer than ``refine_distance`` by the graph's estimate,
    # at that estimate (weight 1), and the registration edges of the other pairs, at their
    # own pose with their graph weight
    near: dict[tuple[int, int], tuple[FloatArray, float]] = {}
    has = np.flatnonzero([len(st.images) > 0 for st in stops])
    if cfg.refine_distance > 0.0 and has.size > 1:
        q = p0[has]
        dist = np.hypot(*(q[None, :, :2] - q[:, None, :2]).transpose(2, 0, 1))
        for i, j in zip(*np.nonzero(np.triu(dist < cfg.refine_distance, 1)), strict=True):
            a_, b_ = int(has[i]), int(has[j])
            near[(a_, b_)] = (relative_pose(p0[a_], p0[b_]), 1.0)
    for e, w in zip(edges, weights, strict=True):
        if e.kind != "odometry" and w > 0.0 and (e.i, e.j) not in near:
            near[(e.i, e.j)] = (e.z, float(w))
    ei, ej, ra, rb, wall, sig, ew, kind = [], [], [], [], [], [], [], []
    for (i, j), (z, w) in near.items():  # a few hundred stop pairs
        a, b = stops[i], stops[j]
        if len(a.images) == 0 or len(b.images) == 0:
            continue
        s_b = np.sqrt(
            cfg.fine_sigma**2 + b.image_sigma**2 + np.sum(b.images**2, 1) * cfg.heading_sigma**2
        )
        pred = predicted_images(a.images, z, point_bias)[0]
        d2 = np.sum((b.images[:, None] - pred[None]) ** 2, -1)
        d2 = np.where(np.isnan(d2), np.inf, d2)
        h = np.argmin(d2, 1)
        ok = np.sqrt(d2[np.arange(len(h)), h]) < cfg.match_gate * s_b
        jm, hm = np.flatnonzero(ok), h[ok]
        r_a = hm % len(a.images)
        kind.append(hm // len(a.images))
        ei.append(np.full(jm.size, i))
        ej.append(np.full(jm.size, j))
        ra.append(r_a)
        rb.append(jm)
        wall.append(hm < len(a.images))
        s_a = np.hypot(
            a.image_sigma[r_a], np.linalg.norm(a.images[r_a], axis=1) * cfg.heading_sigma
        )
        sig.append(np.hypot(s_b[jm], s_a))
        ew.append(np.full(jm.size, float(w)))

    def cat(v: list, d: type) -> npt.NDArray:
        return np.concatenate(v).astype(d) if v else np.zeros(0, d)

    ei, ej, ra, rb = (cat(v, np.intp) for v in (ei, ej, ra, rb))
    wall, sig, ew = cat(wall, bool), cat(sig, float), cat(ew, float)
    scat = cat(kind, np.intp) == 2
    img_a = np.array([stops[i].images[r] for i, r in zip(ei, ra, strict=True)]).reshape(-1, 2)
    img_b = np.array([stops[j].images[r] for j, r in zip(ej, rb, strict=True)]).reshape(-1, 2)
    g_a = np.array([stops[i].turn_basis[r] for i, r in zip(ei, ra, strict=True)]).reshape(-1, 2)
    g_b = np.array([stops[j].turn_basis[r] for j, r in zip(ej, rb, strict=True)]).reshape(-1, 2)
    m = ei.size
    # odometry edges and coefficient priors
    oz = np.array([z for z, _ in odometry]).reshape(-1, 3)
    osq = np.array([_sqrt_info(c) for _, c in odometry]).reshape(-1, 3, 3)
    oend = np.array([s.poses[-1, :2] for s in stops[:-1]]).reshape(-1, 2)
    oi = np.arange(n - 1)
    s_odo = np.array(
        [
            np.sqrt(
                np.sum(
                    (cfg.slip_rotation * np.abs(np.diff(s.poses[:, 2])) + cfg.slip_floor[1]) ** 2
                )
            )
            for s in stops
        ]
    )
    prior_sd = np.column_stack(
        [[max(s.end_sigma, 1e-4) for s in stops], np.maximum(s_odo / 2, 1e-4)]
    )
    # a stop's turn is refined only over enough correspondences (corridor_L_sparse: one
    # wrong registration of 2 correspondences would turn its stops by degrees)
    touch = np.bincount(np.r_[ei, ej], minlength=n)
    prior_sd[touch < cfg.refine_min_matches] = 1e-6
    if not np.any(touch >= cfg.refine_min_matches):
        return p0.copy(), np.zeros((n, 2)), np.ones(m)
    cw = np.ones(m)

    def unpack(x: FloatArray) -> tuple[FloatArray, FloatArray]:
        p = np.vstack([p0[:1], x[: 3 * (n - 1)].reshape(-1, 3)])
        return p, x[3 * (n - 1) :].reshape(n, 2)

    def image_residuals(p: FloatArray, c: FloatArray) -> FloatArray:
        ia = rotate(img_a, np.sum(g_a * c[ei], 1))
        ib = rotate(img_b, np.sum(g_b * c[ej], 1))
        pi, pj = p[ei], p[ej]
        t = rotate(pj[:, :2] - pi[:, :2], -pi[:, 2])
        # the wall's guard acted when the correspondence was formed (predicted_images at the
        # stop pair's pose); here the model stays smooth (a residual zeroed behind B would
        # make the cost jump, and hide a NaN)
        w_rel, p_rel, s_rel = images_seen_from(ia, t, point_bias, guard=False)
        pt = p_rel if s_rel is None else np.where(scat[:, None], s_rel, p_rel)
        rel = np.where(wall[:, None], w_rel, pt)
        pred = rotate(rel, -(pj[:, 2] - pi[:, 2]))
        return (ib - pred) / sig[:, None]

    def fun(x: FloatArray) -> FloatArray:
        p, c = unpack(x)
        r_img = image_residuals(p, c) * np.sqrt(ew * cw)[:, None]
        pi, pj = p[oi], p[oi + 1]
        rel = np.column_stack([rotate(pj[:, :2] - pi[:, :2], -pi[:, 2]), pj[:, 2] - pi[:, 2]])
        d_end = c[oi, 0]
        z = np.column_stack([oend + rotate(oz[:, :2] - oend, d_end), oz[:, 2] + d_end])
        d = rel - z
        d[:, 2] = _wrap(d[:, 2])
        r_odo = np.einsum("mij,mj->mi", osq, d)
        return np.concatenate([r_img.ravel(), r_odo.ravel(), (c / prior_sd).ravel()])

    nv = 3 * (n - 1) + 2 * n

    # sparsity: each residual block touches its stops' pose and coefficient columns
    def cols(stop: npt.NDArray) -> FloatArray:
        pc = 3 * (stop - 1)[:, None] + np.arange(3)
        pc = np.where(pc >= 0, pc, -1)
        cc = 3 * (n - 1) + 2 * stop[:, None] + np.arange(2)
        return np.hstack([pc, cc])

    blocks = [(np.hstack([cols(ei), cols(ej)]), 2), (np.hstack([cols(oi), cols(oi + 1)]), 3)]
    rows_a, cols_a, n_rows = block_pattern(blocks, 3 * (n - 1) + np.arange(2 * n))
    sparsity = scipy.sparse.coo_matrix(
        (np.ones(rows_a.size), (rows_a, cols_a)), shape=(n_rows, nv)
    ).tocsr()
    x = np.concatenate([p0[1:].ravel(), np.zeros(2 * n)])
    for _ in range(max(rounds, 1)):
        sol = least_squares(fun, x, jac_sparsity=sparsity, method="trf", x_scale="jac")
        x = sol.x
        p, c = unpack(x)
        chi2 = np.sum(image_residuals(p, c) ** 2, 1)
        cw = 1.0 / (1.0 + chi2 / (2.0 * cfg.cauchy_scale**2))
    p, c = unpack(x)
    p = p.copy()
    p[:, 2] = _wrap(p[:, 2])
    return p, c, cw


# --------------------------------------------------------------------------- estimator


@dataclass(frozen=True, slots=True, kw_only=True)
class StopGraphResult:
    """Output of :meth:`StopGraphPathEstimator.estimate`.

    Attributes
    ----------
    trajectory : ndarray, shape (n, 4)
        ``[t, x, y, yaw]`` of every acquisition, frame of the first pose (map.json's layout).
    stop_poses : ndarray, shape (S, 3)
        Pose of each stop's first acquisition, same frame.
    stops : list of StopScan
    edges : list of GraphEdge
        The graph's edges (odometry and accepted registrations).
    edge_weights : ndarray
        Final Cauchy weight of each edge.
    registrations : list of tuple (int, int, Registration)
        Every registration tried (accepted or not), with the stops it joined.
    turn_coefficients : ndarray, shape (S, 2) or (S, modes)
        Each stop's in-stop heading correction of the joint refinement (rad, over
        :func:`turn_basis`; zeros without it), or with ``bundle_adjust`` of the bundle
        adjustment (over :func:`~fusion_center.mapping.stop_bundle.drift_basis`, whose first
        two terms are :func:`turn_basis`), already in ``stops``' poses and ``trajectory``.
    n_registered : int
        Accepted registrations in the graph. 0: the path is the odometry with the turn
        closure alone (no stop had reflectors to register, e.g. no turns on the spot).
    bundle_unconverged : int or None
        Solves of the bundle adjustment that stopped at their evaluation limit before
        converging (0: all converged; None: no bundle adjustment ran).
    bundle_shift : float or None
        RMS over the stops of the bundle adjustment's pose change in Mahalanobis distance
        (``StopGraphConfig.bundle_max_shift``; None: no bundle adjustment ran).
    bundle_dropped : bool
        The bundle adjustment's result was dropped by ``bundle_max_shift``.
    drives_turn : bool
        The drives turned the robot (``StopGraphConfig.drive_turn``): the loop search ran
        with ``drive_loop_defer`` and ``drive_loop_gate``.
    """

    trajectory: FloatArray
    stop_poses: FloatArray
    stops: list[StopScan]
    edges: list[GraphEdge]
    edge_weights: FloatArray
    registrations: list[tuple[int, int, Registration]] = field(default_factory=list)
    turn_coefficients: FloatArray = field(default_factory=lambda: np.zeros((0, 2)))
    n_registered: int = 0
    bundle_unconverged: int | None = None
    bundle_shift: float | None = None
    bundle_dropped: bool = False
    drives_turn: bool = False


class StopGraphPathEstimator:
    """The path of a stop-and-turn robot from its echoes and odometry (see the module).

    Parameters
    ----------
    antennas : array_like, shape (3, 2)
        tx, rx1, rx2 in the robot frame (x forward, y left), m; tx is the turning centre.
    config : StopGraphConfig
    closure : TurnClosureConfig, optional
        Turn closure settings; default: its own with the config's slip noise.
    bundle : StopBundleConfig, optional
        Settings of the bundle adjustment (``StopGraphConfig.bundle_adjust``).
    """

    def __init__(
        self,
        antennas: npt.ArrayLike,
        config: StopGraphConfig | None = None,
        closure: TurnClosureConfig | None = None,
        bundle: StopBundleConfig | None = None,
    ) -> None:
        ant = np.asarray(antennas, float)
        if ant.shape != (3, 2) or not np.all(np.isfinite(ant)):
            raise ValueError(f"antennas must be 3 finite (x, y) rows, got shape {ant.shape}")
        self.antennas = ant
        self.config = cfg = config or StopGraphConfig()
        self.closer = EchoBearingTurnCloser(
            ant[1:] - ant[0],
            closure
            or TurnClosureConfig(
                slip_rotation=cfg.slip_rotation,
                slip_floor=cfg.slip_floor[1],
                min_links=cfg.closure_min_links,
                link_scatter=cfg.closure_link_scatter,
            ),
        )
        # the point images' bias, averaged over the horns' +-60 degrees (mean cos^2 0.71)
        self.point_bias = 0.71 * float(np.mean(np.sum((ant[1:] - ant[0]) ** 2, 1)))
        self.point_bias *= float(cfg.point_scatterers)
        self.registration = ReflectorRegistration(cfg, self.point_bias)
        self.bundle = bundle or StopBundleConfig()

    def odometry_edge(
        self, log: ScanLog, a: StopScan, b: StopScan
    ) -> tuple[FloatArray, FloatArray]:
        """Relative pose of stop ``b``'s frame in stop ``a``'s (the next stop) by the
        odometry, and its covariance: ``a``'s last in-stop pose (corrected heading, its
        ``end_sigma``) composed with the drive's increments (``b.start``'s and those of
        acquisitions between the stops), each with the recorder's slip model
        (``s_t = slip_translation |d| + floor``, ``s_r = slip_rotation |dyaw| +
        slip_heading_per_metre |d| + floor``), propagated to first order."""
        cfg = self.config
        pose = a.poses[-1].copy()
        cov = np.diag([1e-8, 1e-8, a.end_sigma**2])
        if not a.on_the_spot:
            # the odometry's own in-stop translation noise
            steps = a.end - a.start - 1
            cov[:2, :2] += cfg.slip_floor[0] ** 2 * max(steps, 0) * np.eye(2)
        for k in range(a.end, b.start + 1):
            inc = log.odometry[k]
            dist = float(np.hypot(inc[0], inc[1]))
            s_t = cfg.slip_translation * dist + cfg.slip_floor[0]
            s_r = (
                cfg.slip_rotation * abs(inc[2])
                + cfg.slip_heading_per_metre * dist
                + cfg.slip_floor[1]
            )
            c, s = np.cos(pose[2]), np.sin(pose[2])
            jx = np.array(
                [[1, 0, -s * inc[0] - c * inc[1]], [0, 1, c * inc[0] - s * inc[1]], [0, 0, 1]]
            )
            ju = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
            cov = jx @ cov @ jx.T + ju @ np.diag([s_t**2, s_t**2, s_r**2]) @ ju.T
            pose = compose_poses(pose[None], inc)[0]
        pose[2] = float(_wrap(pose[2]))
        return pose, cov

    def _bundle_adjust(
        self,
        log: ScanLog,
        stops: list[StopScan],
        poses: FloatArray,
        coef: FloatArray,
        odo: list[tuple[FloatArray, FloatArray]],
    ) -> tuple[FloatArray, FloatArray, int]:
        """Stop poses, in-stop drift coefficients (S, modes) and unconverged solves of the
        bundle adjustment over the echo pairs
        (:func:`~fusion_center.mapping.stop_bundle.adjust_stop_bundle`),
        started from the refinement's (its two coefficients are the first two modes). The
        drift prior: each turn's end error (``end_sigma``) and the bridge of its odometry's
        random walk (``odometry_sigma``; ``end_sigma`` when unknown)."""
        modes = self.bundle.modes
        init = np.zeros((len(stops), modes))
        k = min(modes, coef.shape[1])
        init[:, :k] = coef[:, :k]
        end = np.array([st.end_sigma for st in stops])
        walk = np.array([st.odometry_sigma for st in stops])
        walk = np.where(np.isfinite(walk), walk, end)
        res = adjust_stop_bundle(
            log.pairs,
            log.groups,
            [(st.start, st.end) for st in stops],
            [st.poses for st in stops],
            [st.phase for st in stops],
            poses,
            odo,
            drift_prior(end, walk, modes),
            self.antennas,
            self.bundle,
            initial=init,
        )
        return res.poses, res.coefficients, res.unconverged

    def estimate(self, log: ScanLog) -> StopGraphResult:
        """Stop poses and the path of every acquisition of ``log`` (see the module)."""
        cfg = self.config
        if log.t.size == 0:
            raise ValueError("no acquisitions to estimate a path from")
        segs = segment_stops(log.odometry, cfg.drive_reset, cfg.move_step)
        stops = [stop_scan(log, s, e, self.closer, cfg) for s, e in segs]
        n = len(stops)
        # stops with too few reflectors are never registered (a drive's segments, a robot
        # that never stops): no call, no record, no loop candidates
        usable = np.array([len(st.images) >= cfg.min_matched for st in stops])
        graph = StopPoseGraph(n, cfg.cauchy_scale)
        init = np.zeros((n, 3))
        regs: list[tuple[int, int, Registration]] = []
        tried: set[tuple[int, int]] = set()
        tried_sheared: set[tuple[int, int]] = set()
        accepted: set[tuple[int, int]] = set()
        for i in range(n - 1):
            z, cov = self.odometry_edge(log, stops[i], stops[i + 1])
            graph.add(GraphEdge(i=i, j=i + 1, z=z, cov=cov, robust=False))
            step = z
            if not (usable[i] and usable[i + 1]):
                init[i + 1] = compose_poses(init[i : i + 1], step)[0]
                continue
            reg = self.registration.register_both(stops[i], stops[i + 1], z, cov)
            regs.append((i, i + 1, reg))
            tried.add((i, i + 1))
            if reg.accepted:
                graph.add(
                    GraphEdge(i=i, j=i + 1, z=reg.pose, cov=reg.cov, robust=True, kind="scan")
                )
                step = reg.pose
            init[i + 1] = compose_poses(init[i : i + 1], step)[0]
        poses, wt = graph.solve(init)
        loop_cov = np.diag(
            [cfg.loop_window[0] ** 2, cfg.loop_window[0] ** 2, cfg.loop_window[1] ** 2]
        )
        cand = np.flatnonzero(usable)
        drives_turn = (
            median_drive_turn(log.odometry, cfg.drive_reset, cfg.move_step) > cfg.drive_turn
        )
        defer, loop_gate, shear = (
            (cfg.drive_loop_defer, cfg.drive_loop_gate, cfg.drive_loop_shear)
            if drives_turn
            else (cfg.loop_defer, cfg.loop_gate, cfg.loop_shear)
        )
        # the last level (-1) searches again, along the prior's yaw ridge, the candidates
        # whose prior the box search had to cap at ``window``
        levels = [*defer, 0.0, *((-1.0,) if shear else ())]
        sheared = ReflectorRegistration(replace(cfg, search_shear=True), self.point_bias)
        level, rounds = 0, 0
        while cand.size > 2 and level < len(levels):
            added = 0
            gate = levels[level]
            # the search spans the current estimate's own uncertainty (the graph's marginal
            # of the relative pose), at least ``loop_window``: a fixed narrow window around
            # a stretch the graph holds only by odometry found wrong local matches
            joint = graph.covariance(poses, wt)
            for i in cand.tolist():
                later = cand[cand >= i + 2]
                d = np.hypot(*(poses[later, :2] - poses[i, :2]).T)
                for j in later[d < cfg.loop_distance].tolist():
                    if (i, j) in tried and (gate >= 0.0 or (i, j) in tried_sheared):
                        continue
                    prior = relative_pose(poses[i], poses[j])
                    cov = loop_cov + relative_covariance(poses, joint, i, j)
                    if gate > 0.0 and _beyond_window(cov, cfg.window, gate):
                        continue
                    search = self.registration
                    if gate < 0.0:
                        if (i, j) in accepted or not _beyond_window(cov, cfg.window, 3.0):
                            if (i, j) in tried:
                                continue
                        else:
                            search = sheared
                            tried_sheared.add((i, j))
                    tried.add((i, j))
                    reg = search.register_both(stops[i], stops[j], prior, cov)
                    if reg.accepted and _innovation(reg, prior, cov) > loop_gate:
                        reg = _replace_reason(reg, "outside the prior")
                    regs.append((i, j, reg))
                    if reg.accepted:
                        graph.add(
                            GraphEdge(i=i, j=j, z=reg.pose, cov=reg.cov, robust=True, kind="loop")
                        )
                        accepted.add((i, j))
                        added += 1
            rounds += 1
            if added > 0:
                poses, wt = graph.solve(poses)
            if added == 0 or rounds >= cfg.loop_rounds:
                level, rounds = level + 1, 0
        coef = np.zeros((n, 2))
        # the odometry edges from each turn's end without its end heading noise (the
        # refinements estimate that end)
        odo = [
            self.odometry_edge(log, replace(stops[i], end_sigma=0.0), stops[i + 1])
            for i in range(n - 1)
            if (cfg.refine_turns or cfg.bundle_adjust) and n > 1
        ]
        if cfg.refine_turns and n > 1:
            poses, coef, _ = refine_turns(
                stops, graph.edges, wt, poses, odo, cfg, point_bias=self.point_bias
            )
        unconverged, shift, dropped = None, None, False
        if cfg.bundle_adjust and n > 1:
            ba_poses, ba_coef, unconverged = self._bundle_adjust(log, stops, poses, coef, odo)
            shift = pose_shift(poses, ba_poses, graph.covariance(poses, wt))
            dropped = not shift <= cfg.bundle_max_shift  # a NaN shift is dropped too
            if not dropped:
                poses, coef = ba_poses, ba_coef
        modes = coef.shape[1]
        stops = [
            replace(
                st,
                poses=st.poses + np.c_[0.0, 0.0, 1.0] * (drift_basis(st.phase, modes) @ c)[:, None],
            )
            for st, c in zip(stops, coef, strict=True)
        ]
        traj = np.zeros((log.t.size, 4))
        traj[:, 0] = log.t
        for st, p in zip(stops, poses, strict=True):
            traj[st.start : st.end, 1:] = _compose_many(p, st.poses)
        traj[:, 3] = _wrap(traj[:, 3])
        return StopGraphResult(
            trajectory=traj,
            stop_poses=poses,
            stops=stops,
            edges=list(graph.edges),
            edge_weights=wt,
            registrations=regs,
            turn_coefficients=coef,
            n_registered=sum(1 for e in graph.edges if e.kind != "odometry"),
            bundle_unconverged=unconverged,
            bundle_shift=shift,
            bundle_dropped=dropped,
            drives_turn=drives_turn,
        )


def pose_shift(before: FloatArray, after: FloatArray, cov: FloatArray) -> float:
    """RMS over stops 1..n-1 of the Mahalanobis distance of the pose change
    ``after - before`` ((n, 3) each, m and rad, yaw wrapped) under each stop's marginal
    (3, 3) block of the joint covariance ``cov`` (3(n-1), 3(n-1); stop 0 fixed, as
    :meth:`StopPoseGraph.covariance`). 0 for a single stop."""
    d = np.asarray(after, float)[1:] - np.asarray(before, float)[1:]
    if d.size == 0:
        return 0.0
    d[:, 2] = _wrap(d[:, 2])
    m = d.shape[0]
    blocks = np.asarray(cov, float).reshape(m, 3, m, 3)[np.arange(m), :, np.arange(m), :]
    m2 = np.einsum("ni,ni->n", d, np.linalg.solve(blocks, d[:, :, None])[:, :, 0])
    return float(np.sqrt(np.mean(m2)))


def median_drive_turn(
    odometry: npt.ArrayLike, drive_reset: float = 0.1, move_step: float = 0.02
) -> float:
    """Median ``|yaw|`` (rad, wrapped) the robot turns over its drives: for each drive
    between two stops (:func:`segment_stops` with ``drive_reset`` and ``move_step``, m; a
    stop is a segment of more than one acquisition) the net yaw of the odometry increments
    ``(dx, dy, dyaw)`` (n, 3; m, rad) from the stop's last acquisition to the next stop's
    first, however many steps the drive was logged in. 0 with fewer than two stops.

    A heuristic of this implementation (beyond the chapter) that tells a robot turning with
    its drives (drive starts: room_pillar 162 degrees) from one that keeps its heading
    (2.5-3 degrees). Being a median, it stays low for a robot whose drives are mostly
    straight with a few large turns (a corridor with one corner)."""
    o = np.asarray(odometry, float).reshape(-1, 3)
    stops = [(a, b) for a, b in segment_stops(o, drive_reset, move_step) if b - a > 1]
    if len(stops) < 2:
        return 0.0
    cum = np.r_[0.0, np.cumsum(o[:, 2])]
    # rows b .. c (inclusive) take the last acquisition of a stop [a, b) to the first of the
    # next stop [c, d); their yaw sum is the drive's net turn
    b = np.array([s[1] for s in stops[:-1]])
    c = np.array([s[0] for s in stops[1:]])
    return float(np.median(np.abs(_wrap(cum[c + 1] - cum[b]))))


def _beyond_window(cov: FloatArray, window: tuple[float, float], k: float) -> bool:
    """Whether a prior of covariance ``cov`` (3, 3; m, rad) reaches beyond the search's
    largest half-width ``window`` ``(m, rad)`` at ``k`` sigma in x, y or yaw."""
    sd = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    return bool(k * max(sd[0], sd[1]) > window[0] or k * sd[2] > window[1])


def _innovation(reg: Registration, prior: FloatArray, cov: FloatArray) -> float:
    """Mahalanobis distance (sigmas) of a registration's pose from its ``prior`` (3,)
    under the prior's covariance ``cov`` plus the registration's (m, rad; yaw wrapped).
    The registration's pose is its refinement's, which already weighs the prior in, so this
    is the innovation shrunk by ``P (P + R)^-1``: about 2 % small for loop priors (``P`` at
    least ``loop_window`` squared, ``R`` centimetres), which the gate's 3 sigma absorbs."""
    d = np.asarray(reg.pose, float) - np.asarray(prior, float)
    d[2] = float(_wrap(d[2]))
    return float(np.sqrt(d @ np.linalg.solve(np.asarray(cov) + reg.cov, d)))


def _compose_many(base: FloatArray, rel: FloatArray) -> FloatArray:
    """Poses ``rel`` (n, 3) given in the frame of pose ``base`` (3,), in the outer frame."""
    c, s = np.cos(base[2]), np.sin(base[2])
    return np.column_stack(
        [
            base[0] + c * rel[:, 0] - s * rel[:, 1],
            base[1] + s * rel[:, 0] + c * rel[:, 1],
            base[2] + rel[:, 2],
        ]
    )


def stop_graph_path(
    log: ScanLog, antennas: npt.ArrayLike, config: StopGraphConfig | None = None
) -> FloatArray:
    """``[t, x, y, yaw]`` of every acquisition (first-pose frame): shorthand for
    :meth:`StopGraphPathEstimator.estimate`'s trajectory."""
    return StopGraphPathEstimator(antennas, config).estimate(log).trajectory


__all__: Sequence[str] = (
    "GraphEdge",
    "ReflectorRegistration",
    "Registration",
    "ScanLog",
    "StopGraphConfig",
    "StopGraphPathEstimator",
    "StopGraphResult",
    "StopPoseGraph",
    "StopScan",
    "images_seen_from",
    "median_drive_turn",
    "pose_shift",
    "predicted_images",
    "refine_turns",
    "relative_covariance",
    "relative_pose",
    "scan_front_end",
    "scan_log_from_pairs",
    "segment_stops",
    "stop_graph_path",
    "stop_scan",
    "turn_basis",
)
