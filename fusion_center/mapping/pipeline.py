"""From a robot's impulse responses to its map and pose: echoes -> pairs -> groups -> RBPF.

:class:`EchoSlamMapper` is the pure core the offline command (``uwbnet map``) and the fusion
center's runtime share: one call per ``ir`` acquisition, time as an argument, no I/O.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from fusion_center.mapping.echoes import EnvelopePeakEchoExtractor, pair_echoes
from fusion_center.mapping.features import SlamMap, build_map, corridor_end_walls
from fusion_center.mapping.grouping import KalmanEchoGrouper
from fusion_center.mapping.models import CORNER, POINT, WALL
from fusion_center.mapping.rbpf import PoseEstimate2D, RbpfSlam, SlamConfig
from fusion_center.mapping.relocalise import compose_poses
from fusion_center.mapping.smoothing import (
    LeastSquaresPathMapSmoother,
    SmoothedPathMap,
    SmootherConfig,
    smoothed_landmark_set,
)
from fusion_center.mapping.turn_closure import EchoBearingTurnCloser, TurnClosureConfig

FloatArray = npt.NDArray[np.float64]

#: how many of the last stops' turn corrections :attr:`EchoSlamMapper.turn_corrections` keeps
TURN_CORRECTIONS_KEPT = 1000
#: ``SmootherConfig.stop_gate`` of :meth:`EchoSlamMapper.smooth` with state-space association
#: (m; measurement space: 0, off). corridor_L_sparse seeds 1 / 3 (15-degree steps): the third
#: stop's side walls and the second leg's inner wall mapped, outline 60 -> 66 / 65 %;
#: room_pillar seed 0 with the filter (3-degree steps, measurement space): 18 m more wall
#: matching no face, 6 more false corners (docs/mapping.md, twelfth round).
STATE_STOP_GATE = 0.6
#: ``SmootherConfig.keyframe_turn`` (rad) and ``sigma_floor`` (m) of :meth:`EchoSlamMapper.smooth`
#: with state-space association (measurement space: 0, off). corridor_L_sparse and its
#: spread-stop and drive-start variants (15-degree steps, 36 runs): a key pose at every
#: acquisition and each landmark's own residual scale took the first stop's in-turn heading
#: drift out (seed 1: 2.7 -> 0.9 degrees); with the array's own mount (``smoother_mount``),
#: 40 recordings (seeds 1-8): mean path 0.253 -> 0.220 m, outline 68.9 -> 70.1 %; seed 3 is
#: worse (docs/mapping.md, "The sparse corridor's path").
STATE_KEYFRAME_TURN = float(np.radians(10.0))
STATE_SIGMA_FLOOR = 0.01


def array_geometry(antennas: Mapping[str, Any], rx: Sequence[str]) -> FloatArray:
    """tx, rx1, rx2 positions (x, y in the robot frame, m) from a ``node_info.antennas`` map.

    Parameters
    ----------
    antennas : mapping name -> antenna
        Objects with ``pos`` ([x, y, z], node frame) and ``tx`` (bool), as in
        :class:`protocol.messages.Antenna`.
    rx : sequence of str
        The receivers of the ``ir`` rows, in row order.

    Raises
    ------
    ValueError
        Not exactly one transmitter, or ``rx`` does not name two known receivers.
    """
    tx = [a for a in antennas.values() if a.tx]
    if len(tx) != 1:
        raise ValueError("needs exactly one transmitting antenna")
    if len(rx) != 2 or any(r not in antennas for r in rx):
        raise ValueError(f"ir needs two known receivers, got {list(rx)}")
    pos = [tx[0].pos] + [antennas[r].pos for r in rx]
    return np.array([[p[0], p[1]] for p in pos], float)


@dataclass(frozen=True, slots=True, kw_only=True)
class MapperConfig:
    """Parameters of :class:`EchoSlamMapper` besides the filter's (SI units).

    Attributes
    ----------
    min_range, max_range : float
        Bistatic ranges searched for echoes, m (the direct coupling and the floor lie below
        ``min_range``; far echoes are mostly higher-order multipath).
    threshold : float
        Echo threshold in noise sigmas.
    dynamic_db : float
        Echoes weaker than this below the strongest are ignored, dB.
    max_echoes : int
        Echoes kept per receiver and acquisition.
    pair_gate : float
        Largest ``|r1 - r2|`` of one landmark's pair, m.
    background_alpha : float
        Forgetting factor of the robot-frame background after the warm-up (0: fixed).
    warmup : int
        Acquisitions whose median is the robot-frame background.
    confirm : int
        Pairs an echo group needs before it reaches the filter (measurement space).
    lag : int
        Acquisitions the measurement-space association waits for a group to confirm.
    drive_reset : float
        Odometry translation, m, after which the echo tracks restart (the robot drove).
    provisional_poses : bool
        While the filter holds a stop back for a relocalisation (up to one stop, about 2.4 s
        on room_pillar), also output each held acquisition at once with the odometry's
        prediction, marked ``provisional`` (a live view then never goes without a pose); the
        revised estimates still follow after the replay. Off for offline use, where the
        trajectory holds only the revised estimates.
    turn_closure : bool
        Offline only (``uwbnet map`` and the live mapping service do not set it; the live
        service's pose stream would drop the corrected poses, see docs/mapping.md). Hold
        each stop's acquisitions until the robot drives on, estimate the turn's heading
        errors from the stop's own echoes (:mod:`fusion_center.mapping.turn_closure`: the
        reflectors seen at the start of a turn come back into view at its end; a stop is
        corrected only when at least ``turn_closure_min_links`` reflectors are seen in both
        its first and its last third) and give the filter the corrected odometry.
        The outputs of a stop then come out when it ends (with ``provisional_poses``, at
        once as the odometry's prediction too). An acquisition without odometry is not
        held: it ends the held stop and passes straight on (the turn after it is a new
        stop), so a stream without odometry has no added latency.
    turn_closure_max : int
        Acquisitions held at most for one stop (a robot that never drives on), >= 3. It
        counts acquisitions, not rotation: it must exceed the steps of one turn (room_pillar:
        121), or the turn is cut in parts that each fall short of ``min_turn`` and are left
        uncorrected (a 357-degree turn in 1-degree steps needs more than the default 240).
    turn_closure_translation : float
        Net displacement, m (>= 0), of a held stop by its odometry (from its first
        acquisition, composed through the turn) beyond which it is not a turn on the spot,
        on top of the odometry's own noise (3.5 ``SlamConfig.slip_floor[0]`` sqrt(steps),
        at most ``turn_closure_translation`` again, so that a wider slip model does not
        pass a slow creep as a turn): the stop is then passed on at once, its odometry left
        alone, and a new one begins.
    turn_closure_noise : bool
        With ``turn_closure``: the filter turns the particles through a corrected stop with
        the closure's own uncertainty of each step (``TurnClosure.step_sigma``) in place of
        the slip model's rotation noise, so that the particles keep the corrected heading
        (off: the slip model's, which lets the filter drift 1.8-2.4 degrees per turn on the
        corrected odometry). Off by default: better on one room_pillar recording, worse on
        the other (docs/mapping.md).
    turn_closure_min_links : int
        With ``turn_closure``: reflectors (>= 1) that must be seen in both the first and the
        last third of a stop for it to be corrected (``TurnClosureConfig.min_links``).
    """

    min_range: float = 1.2
    max_range: float = 10.0
    threshold: float = 8.0
    dynamic_db: float = 6.0
    max_echoes: int = 4
    pair_gate: float = 0.6
    background_alpha: float = 0.0
    warmup: int = 24
    confirm: int = 3
    lag: int = 2
    drive_reset: float = 0.1
    provisional_poses: bool = False
    keep_history: bool = False
    turn_closure: bool = False
    turn_closure_max: int = 240
    turn_closure_translation: float = 0.05
    turn_closure_noise: bool = False
    turn_closure_min_links: int = 2

    def __post_init__(self) -> None:
        m = self.turn_closure_max
        if isinstance(m, bool) or not isinstance(m, int | np.integer) or m < 3:
            raise ValueError(f"MapperConfig.turn_closure_max must be an integer >= 3, got {m!r}")
        d = self.turn_closure_translation
        if not (np.isfinite(d) and d >= 0.0):
            raise ValueError(f"MapperConfig.turn_closure_translation must be >= 0, got {d!r}")
        b = self.turn_closure_noise
        if not isinstance(b, bool | np.bool_):
            raise ValueError(f"MapperConfig.turn_closure_noise must be a bool, got {b!r}")
        k = self.turn_closure_min_links
        if isinstance(k, bool) or not isinstance(k, int | np.integer) or k < 1:
            raise ValueError(
                f"MapperConfig.turn_closure_min_links must be an integer >= 1, got {k!r}"
            )


#: An on-the-spot odometry step turning less than this (rad) is a dwell, another acquisition at
#: the same heading (a robot standing still reads its odometry's noise: the simulated floor is
#: 0.1 degree); no recording has one, their turning steps are 2.9-17 degrees.
DWELL_TURN = np.radians(0.5)


def turning_step(
    odometry: npt.ArrayLike, drive: float = 0.1, *, per_acquisition: bool = False
) -> float | None:
    """A stop-and-turn robot's turning step, rad, from its odometry increments.

    Of the steps that do not drive (moved at most ``drive``, m: the turns on the spot), those
    turning at least :data:`DWELL_TURN` are turning steps and the others dwells (more
    acquisitions at one heading). The step is the median ``|dyaw|`` of the turning steps: the
    change of heading between acquisitions, which decides whether echoes can be tracked from
    one to the next (``uwbnet map``'s automatic association and localiser). With
    ``per_acquisition`` it is the angle turned per acquisition on the spot instead, that step
    times the turning steps' share of the steps on the spot: a robot taking 3 acquisitions per
    15-degree heading hears each wall 3 times per heading, as often as a 5-degree robot
    (:func:`scaled_min_pairs`). Without dwells the two are the same. A heuristic of this
    implementation (beyond the chapter).

    Parameters
    ----------
    odometry : array_like, shape (n, 3)
        ``(dx, dy, dyaw)`` of every step, m, m, rad.
    drive : float
        m, >= 0.
    per_acquisition : bool
        The angle per acquisition (dwells included) rather than the step between headings.

    Returns
    -------
    float or None
        rad; None when no step turns on the spot.
    """
    if not drive >= 0.0:
        raise ValueError(f"drive must be >= 0, got {drive}")
    odo = np.asarray(odometry, float).reshape(-1, 3)
    spot = np.abs(odo[np.hypot(odo[:, 0], odo[:, 1]) <= drive, 2])
    turn = spot[spot >= DWELL_TURN]
    if turn.size == 0:
        return None
    step = float(np.median(turn))
    return step * turn.size / spot.size if per_acquisition else step


def scaled_min_pairs(
    min_pairs: int, odometry: npt.ArrayLike, reference_step: float, drive: float = 0.1
) -> int:
    """Echo pairs a smoothed landmark needs (:meth:`EchoSlamMapper.smooth`) for a robot
    turning in its own steps: ``ceil(min_pairs * reference_step / step)``, at most
    ``min_pairs``, at least 1.

    A wall is heard over a fixed span of headings at each stop (the horns' beam around the
    foot of the perpendicular, Fig. 19 of the CoLOR chapter), so the pairs it gives scale with
    the acquisitions in that span: ``min_pairs`` (8) was measured on room_pillar's 3-degree
    steps, where a wall gives 20-25 pairs a stop; at corridor_L_sparse's 15 degrees it gives
    4-6, and the second leg's inner wall, seen from two stops with 7 pairs, was left out
    (beyond the chapter: a support rule of this implementation). ``step`` is the angle turned
    per acquisition on the spot (:func:`turning_step` with ``per_acquisition``): dwells, more
    acquisitions at one heading, count as acquisitions.

    Parameters
    ----------
    min_pairs : int
        The count at ``reference_step``, >= 1.
    odometry : array_like, shape (n, 3)
        ``(dx, dy, dyaw)`` of every step (m, m, rad); the steps that move at most ``drive``
        (m) are the steps on the spot. A robot that never turns keeps ``min_pairs``.
    reference_step : float
        rad, > 0.
    """
    k = min_pairs
    if isinstance(k, bool) or not isinstance(k, int | np.integer) or k < 1:
        raise ValueError(f"min_pairs must be an integer >= 1, got {k!r}")
    if not reference_step > 0.0:
        raise ValueError(f"reference_step must be > 0, got {reference_step}")
    step = turning_step(odometry, drive, per_acquisition=True)
    if step is None:
        return int(min_pairs)
    return int(min(min_pairs, max(1, np.ceil(min_pairs * reference_step / step - 1e-9))))


def echo_extractor(
    config: MapperConfig, *, fs: float, t0: float, bandwidth: float
) -> EnvelopePeakEchoExtractor:
    """The mapper's echo extractor for impulse responses sampled at ``fs`` (Hz) from ``t0``
    (s) over ``bandwidth`` (Hz), with ``config``'s echo search and background settings."""
    return EnvelopePeakEchoExtractor(
        fs=fs,
        t0=t0,
        bandwidth=bandwidth,
        min_range=config.min_range,
        max_range=config.max_range,
        threshold=config.threshold,
        dynamic_db=config.dynamic_db,
        max_echoes=config.max_echoes,
        alpha=config.background_alpha,
        warmup=config.warmup,
    )


@dataclass(frozen=True, slots=True, kw_only=True)
class MapperOutput:
    """The filter's state after one acquisition: time ``t`` (s) and the pose estimate in the
    frame of the robot's first pose. ``provisional``: the odometry's prediction of an
    acquisition held back for a relocalisation; its revised estimate comes out later with the
    same ``t`` (see ``MapperConfig.provisional_poses``)."""

    t: float
    estimate: PoseEstimate2D
    pairs: int
    provisional: bool = False


class EchoSlamMapper:
    """UWB SLAM of a bat-type robot from its impulse responses (Section 6 of the CoLOR chapter).

    Parameters
    ----------
    antennas : array_like, shape (3, 2)
        tx, rx1, rx2 in the robot frame (x forward, y left), m.
    fs, t0, bandwidth : float
        Sampling of the impulse responses (``node_info.radar``): Hz, s, Hz.
    config : MapperConfig
    slam : SlamConfig
    """

    def __init__(
        self,
        antennas: npt.ArrayLike,
        *,
        fs: float,
        t0: float,
        bandwidth: float,
        config: MapperConfig | None = None,
        slam: SlamConfig | None = None,
    ) -> None:
        self.config = cfg = config or MapperConfig()
        self.filter = RbpfSlam(antennas, slam)
        self.measurement_space = self.filter.config.association == "measurement"
        self.extractor = echo_extractor(cfg, fs=fs, t0=t0, bandwidth=bandwidth)
        self.grouper = KalmanEchoGrouper()
        # acquisitions waiting for the extractor's warm-up: (t, odometry)
        self._meta: deque[tuple[float, FloatArray | None]] = deque()
        # acquisitions waiting for their groups to confirm: (t, odometry, pairs, ids)
        self._queue: deque[tuple[float, FloatArray | None, FloatArray, npt.NDArray]] = deque()
        self._last_t: float | None = None
        # processed acquisitions whose output waits for a relocalisation: (t, pairs)
        self._pending: list[tuple[float, int]] = []
        # how many of them already went out as provisional outputs
        self._provisional_sent = 0
        self.pairs_used = 0
        self.pairs_seen = 0
        # with keep_history: (t, odometry, pairs, group ids) of every processed acquisition
        # and its final (not provisional) pose estimate by time
        self._history: list[tuple[float, FloatArray | None, FloatArray, npt.NDArray]] = []
        self._final: dict[float, FloatArray] = {}
        fc = self.filter.config
        self.turn_closer = EchoBearingTurnCloser(
            self.filter._rx_body,
            TurnClosureConfig(
                slip_rotation=fc.slip_rotation,
                slip_floor=fc.slip_floor[1],
                min_links=int(cfg.turn_closure_min_links),
            ),
        )
        # acquisitions of the current stop held for its turn closure: t, odometry, all pairs
        # and their ids, the pairs for the filter and their ids, the echo groups still live
        self._stop: list[
            tuple[
                float, FloatArray | None, FloatArray, npt.NDArray, FloatArray, npt.NDArray, set[int]
            ]
        ] = []
        self._stop_provisional = 0
        # the last provisional pose of the held stop (the next ones continue from it)
        self._stop_pose = np.zeros(3)
        # odometry pose of the held stop's last acquisition in the frame of its first
        self._stop_shift = np.zeros(3)
        #: the end corrections (rad) of the last stops the turn closure corrected (bounded:
        #: a robot that runs for days must not grow it)
        self.turn_corrections: deque[float] = deque(maxlen=TURN_CORRECTIONS_KEPT)

    def step(
        self, t: float, h: npt.NDArray, odometry: npt.ArrayLike | None = None
    ) -> list[MapperOutput]:
        """Add one acquisition; return the outputs of the acquisitions now processed.

        Parameters
        ----------
        t : float
            Acquisition time, s.
        h : ndarray, float32 or complex64, shape (2, n)
            Impulse responses at rx1 and rx2.
        odometry : array_like, shape (3,), optional
            ``(dx, dy, dyaw)`` since the previous acquisition (PROTOCOL ``ir.odom``).
        """
        odo = None if odometry is None else np.asarray(odometry, float)
        self._meta.append((t, odo))
        out: list[MapperOutput] = []
        for echoes in self.extractor.push(h):
            out += self._pairs(pair_echoes(echoes, self.config.pair_gate))
        return out

    def finish(self) -> list[MapperOutput]:
        """Process everything still held back (end of the stream)."""
        out: list[MapperOutput] = []
        for echoes in self.extractor.flush():
            out += self._pairs(pair_echoes(echoes, self.config.pair_gate))
        while self._queue:
            out += self._filter(*self._queue.popleft())
        out += self._close_turn()
        self.filter.flush()
        return out + self._release()

    def _pairs(self, z: FloatArray) -> list[MapperOutput]:
        t, odo = self._meta.popleft()
        self.pairs_seen += z.shape[0]
        if odo is not None and np.hypot(odo[0], odo[1]) > self.config.drive_reset:
            self.grouper.reset()
        ids = self.grouper.step(z)
        if not self.measurement_space:
            return self._filter(t, odo, z, ids)
        self._queue.append((t, odo, z, ids))
        out = []
        while len(self._queue) > self.config.lag:
            out += self._filter(*self._queue.popleft())
        return out

    def _filter(
        self, t: float, odo: FloatArray | None, z: FloatArray, ids: npt.NDArray
    ) -> list[MapperOutput]:
        z_all, ids_all = z, ids
        if self.measurement_space:
            hits = self.grouper.hits
            keep = np.array([hits.get(int(g), 0) >= self.config.confirm for g in ids], bool)
            z, ids = z[keep], ids[keep]
        live: set[int] = set()
        if self.measurement_space:
            live = {int(g) for q in self._queue for g in q[3]} | set(ids.tolist())
            self.grouper.hits = {g: n for g, n in self.grouper.hits.items() if g in live}
        return self._route(t, odo, z_all, ids_all, z, ids, live)

    def _route(
        self,
        t: float,
        odo: FloatArray | None,
        z_all: FloatArray,
        ids_all: npt.NDArray,
        z: FloatArray,
        ids: npt.NDArray,
        live: set[int],
    ) -> list[MapperOutput]:
        """One acquisition after the front end (all its pairs and ids; those for the filter;
        the echo groups still live): to the filter, or held for its stop's turn closure."""
        if not self.config.turn_closure:
            return self._feed(t, odo, z, ids, live)
        if odo is None:
            # no odometry: nothing to correct and the turn's steps are no longer known
            # end to end, so end the held stop and pass this acquisition on unheld
            return self._close_turn() + self._feed(t, odo, z, ids, live)
        out: list[MapperOutput] = []
        shift = float(np.hypot(odo[0], odo[1]))
        drive = shift > self.config.drive_reset
        if self._stop and (drive or len(self._stop) >= self.config.turn_closure_max):
            out += self._close_turn()
        if self._stop:
            self._stop_shift = compose_poses(self._stop_shift[None], np.asarray(odo, float))[0]
        self._stop.append((t, odo, z_all, ids_all, z, ids, live))
        if not self._on_the_spot():
            # not a turn on the spot: it can no longer qualify, so stop holding it
            return out + self._close_turn()
        if self.config.provisional_poses:
            out += self._stop_provisionals()
        return out

    def _on_the_spot(self, n: int | None = None) -> bool:
        """Whether the held stop (``n`` acquisitions, default all) is still a turn on the
        spot: its net odometry displacement within ``turn_closure_translation`` plus 3.5
        standard deviations of the odometry's per-step noise summed over its steps (the
        noise term at most ``turn_closure_translation``: it comes from the filter's slip
        model, a tuning knob, and must not widen the bound to a slow drive)."""
        steps = max((len(self._stop) if n is None else n) - 1, 0)
        bound = self.config.turn_closure_translation
        noise = min(3.5 * self.filter.config.slip_floor[0] * np.sqrt(steps), bound)
        shift = float(np.hypot(self._stop_shift[0], self._stop_shift[1]))
        return shift <= bound + noise

    def _close_turn(self) -> list[MapperOutput]:
        """Correct the held stop's odometry by its turn closure and pass it to the filter."""
        stop, self._stop = self._stop, []
        self._stop_provisional = 0
        self._stop_pose = np.zeros(3)
        on_the_spot = self._on_the_spot(len(stop))
        self._stop_shift = np.zeros(3)
        if not stop:
            return []
        # every held acquisition has odometry (``_filter`` passes the others on unheld)
        odos = [np.asarray(s[1], float) for s in stop]
        step = np.zeros(len(stop))
        sigma: list[float | None] = [None] * len(stop)
        if len(stop) > 2 and on_the_spot:
            res = self.turn_closer.close(
                np.array([o[2] for o in odos]), [s[2] for s in stop], [s[3] for s in stop]
            )
            if np.isfinite(res.end_sigma):
                step = np.diff(res.correction, prepend=0.0)
                self.turn_corrections.append(float(res.correction[-1]))
                if self.config.turn_closure_noise:
                    # the first acquisition carries the drive to the stop: the slip model's
                    sigma = [None] + [float(v) for v in res.step_sigma[1:]]
        out: list[MapperOutput] = []
        for (t, odo, _, _, z, ids, live), d, sg in zip(stop, step, sigma, strict=True):
            if d != 0.0:
                odo = odo + np.array([0.0, 0.0, d])
            # their provisional poses went out while the stop was held
            out += [o for o in self._feed(t, odo, z, ids, live, sg) if not o.provisional]
        if self.filter.holding:
            self._provisional_sent = len(self._pending)
        return out

    def _stop_provisionals(self) -> list[MapperOutput]:
        """The held stop's acquisitions not yet output, as the odometry's prediction from
        the filter's estimate at the stop's start (marked ``provisional``). Each call
        composes only the new acquisitions onto the last provisional pose: the filter gets
        nothing while the stop is held, so its estimate does not change, and a recompute
        from the stop's start made the hold quadratic in the stop's length."""
        est = self.filter.estimate()
        pose = est.pose.copy() if self._stop_provisional == 0 else self._stop_pose
        out = []
        for t, odo, z_all, *_rest in self._stop[self._stop_provisional :]:
            if odo is not None:
                pose = compose_poses(pose[None], np.asarray(odo, float))[0]
            e = PoseEstimate2D(pose=pose.copy(), cov=est.cov)
            out.append(MapperOutput(t=t, estimate=e, pairs=len(z_all), provisional=True))
        self._stop_pose = pose
        self._stop_provisional = len(self._stop)
        return out

    def _feed(
        self,
        t: float,
        odo: FloatArray | None,
        z: FloatArray,
        ids: npt.NDArray,
        live: set[int],
        rotation_sigma: float | None = None,
    ) -> list[MapperOutput]:
        """One acquisition through the filter (``rotation_sigma``: see
        :meth:`RbpfSlam.predict`)."""
        f = self.filter
        if self._last_t is not None:
            f.predict(t - self._last_t, odo, rotation_sigma=rotation_sigma)
        self._last_t = t
        f.update(z, ids)
        self.pairs_used += z.shape[0]
        if self.config.keep_history:
            self._history.append((t, odo, z, ids))
        if self.measurement_space:
            f.forget_groups(live)
        self._pending.append((t, int(z.shape[0])))
        return self._release()

    def _release(self) -> list[MapperOutput]:
        """Outputs of the acquisitions the filter has processed: those it held back for a
        relocalisation come out together, with the estimates of their replay."""
        f = self.filter
        out = [
            MapperOutput(t=t, estimate=e, pairs=n)
            for (t, n), e in zip(self._pending, f.revised, strict=False)
        ]
        del self._pending[: len(f.revised)]
        self._provisional_sent = max(self._provisional_sent - len(f.revised), 0)
        f.revised.clear()
        if not f.holding:
            out += [MapperOutput(t=t, estimate=f.estimate(), pairs=n) for t, n in self._pending]
            self._pending.clear()
            self._provisional_sent = 0
        if self.config.keep_history:  # ``out`` holds final estimates only so far
            self._final.update((o.t, o.estimate.pose) for o in out)
        if (
            f.holding
            and self.config.provisional_poses
            and self._provisional_sent < len(self._pending)
        ):
            # the filter's estimate while it holds is the odometry's prediction
            est = f.estimate()
            out += [
                MapperOutput(t=t, estimate=est, pairs=n, provisional=True)
                for t, n in self._pending[self._provisional_sent :]
            ]
            self._provisional_sent = len(self._pending)
        return out

    def smooth(
        self,
        config: SmootherConfig | None = None,
        *,
        min_hits: int = 4,
        min_pairs: int = 8,
        min_stops: int = 2,
        overlap_dist: float = 0.3,
        overlap_angle: float = np.radians(12.0),
        extend: float = 1.0,
        min_pairs_step: float | None = np.radians(3.0),
        end_walls: bool | None = None,
        filter_mount: bool | None = None,
        reflectors: bool = True,
    ) -> tuple[SlamMap, FloatArray] | None:
        """Map and path after joint least-squares smoothing of the whole run (graph SLAM,
        :class:`~fusion_center.mapping.smoothing.LeastSquaresPathMapSmoother`; beyond the
        chapter). Call after :meth:`finish`; needs ``MapperConfig.keep_history`` and odometry.

        Parameters
        ----------
        config : SmootherConfig, optional
            Defaults to :meth:`smoother_config` (the filter's range and slip noise and field
            of view; the joint per-stop association with state space).
        min_hits : int
            Echoes a landmark of the heaviest particle needs to enter the smoothing.
        min_pairs, min_stops : int
            Support a smoothed landmark needs to be mapped (echo pairs associated with it, and
            distinct stops they come from; see
            :func:`~fusion_center.mapping.smoothing.smoothed_landmark_set`).
        overlap_dist, overlap_angle, extend : float
            :func:`~fusion_center.mapping.features.build_map`'s merging of overlapping walls
            (m, rad) and longest wall extension (m). Measured on room_pillar (3 filter seeds):
            with the support rule they cut the walls that match no true face from 72-81 to
            39-55 while finding 7-10 of 28 faces (the filter's map: 7-11).
        min_pairs_step : float or None
            The turning step (rad) at which ``min_pairs`` holds; a robot turning in coarser
            steps needs fewer (:func:`scaled_min_pairs`; None: ``min_pairs`` as given).
        end_walls : bool or None
            Map a landmark heard from one stop (with ``min_pairs``) straight down a mapped
            corridor as the corridor's end wall
            (:func:`~fusion_center.mapping.features.corridor_end_walls`; beyond the chapter).
            None: with state-space association only (coarse turning steps; on room_pillar
            seed 0 mapped by the filter in measurement space, 3-degree steps, 27 landmarks
            came from one stop and one became a wall matching no face).
        reflectors : bool
            With ``end_walls``, also offer the end-wall rule the reflectors heard from one
            stop by pairs no smoothed landmark explains, grouped by their image point
            (:meth:`~fusion_center.mapping.smoothing.LeastSquaresPathMapSmoother.stop_reflectors`,
            ``min_pairs`` each): the filter may have split a wall's echoes over young
            landmarks or merged them with a corner's, so that none enters the smoothing
            (docs/mapping.md). corridor_L_sparse spread over the corridor (span seeds 1-8):
            the far end wall on seeds 1, 2, 7, outline 85.2 -> 91.9 % mean, the same path;
            seed 1's far end is one more wall matching no face (placed from a last stop
            0.6 m off along the corridor, its corners 0.5 m off until the path's rigid fit).
        filter_mount : bool or None
            Smooth with the heaviest particle's array orientation (``RbpfSlam.mount``),
            else with the array geometry's own (0). None: the particle's with
            measurement-space association only. Each particle's orientation is a draw from
            the 1-degree prior (``SlamConfig.mount_sigma``) that the filter keeps by
            selection: with the state-space smoother's sharp bearings (``sigma_floor``) that
            draw turns every wall (corridor_L_sparse and its variants, 8 seeds: 0.253 m
            mean path with the draw, 0.214 m with 0).

        Returns
        -------
        (SlamMap, ndarray of shape (n, 4)) or None
            The map and ``[t, x, y, yaw]`` of every processed acquisition, in the frame of
            the robot's first pose; ``None`` without history, odometry or landmarks.
        """
        hist = self._history
        if not hist or any(h[1] is None for h in hist[1:]):
            return None
        f = self.filter
        ls = f.landmarks(min_hits=min_hits)
        kinds = np.r_[
            np.full(len(ls.walls), WALL), np.where(ls.point_is_corner, CORNER, POINT)
        ].astype(np.int64)
        if kinds.size == 0:
            return None
        states = np.vstack([ls.walls.reshape(-1, 2), ls.points.reshape(-1, 2)])
        cfg = config or self.smoother_config()
        b = int(np.argmax(f.logw))
        smoother = LeastSquaresPathMapSmoother(
            f.antennas, cfg, bias=float(f.bias[b]), mount=self.smoother_mount(filter_mount)
        )
        t = np.array([h[0] for h in hist])
        poses = np.array([self._final[h[0]] for h in hist])
        odo = np.array([np.zeros(3)] + [np.asarray(h[1], float) for h in hist[1:]])
        res = smoother.smooth(poses, odo, [h[2] for h in hist], [h[3] for h in hist], kinds, states)
        if min_pairs_step is not None:
            min_pairs = self.support_min_pairs(min_pairs, min_pairs_step)
        the_map = build_map(
            smoothed_landmark_set(res, min_pairs=min_pairs, min_stops=min_stops),
            overlap_dist=overlap_dist,
            overlap_angle=overlap_angle,
            extend=extend,
        )
        if self.maps_end_walls(end_walls):
            extra = None
            if reflectors:
                extra = smoother.stop_reflectors(res, [h[2] for h in hist], min_pairs=min_pairs)
            the_map = _with_end_walls(the_map, res, min_pairs, extra)
        return the_map, np.column_stack([t, res.poses])

    def support_min_pairs(self, min_pairs: int, min_pairs_step: float) -> int:
        """Echo pairs a smoothed landmark needs (:meth:`smooth`): :func:`scaled_min_pairs` of
        the recorded odometry increments, from the second acquisition on (the first has none;
        a zero row in its place would count as a dwell and ask for one pair more where
        ``min_pairs * min_pairs_step / step`` is whole: 5 instead of 4 at 6-degree steps)."""
        odo = [np.asarray(h[1], float) for h in self._history[1:] if h[1] is not None]
        return scaled_min_pairs(
            min_pairs, np.reshape(odo, (-1, 3)), min_pairs_step, self.config.drive_reset
        )

    def maps_end_walls(self, end_walls: bool | None = None) -> bool:
        """Whether :meth:`smooth` maps corridor end walls heard from one stop: ``end_walls``,
        or for None with state-space association only (see :meth:`smooth`)."""
        return bool(end_walls) if end_walls is not None else not self.measurement_space

    def smoother_mount(self, filter_mount: bool | None = None) -> float:
        """Array orientation against the heading (rad) that :meth:`smooth` uses: the heaviest
        particle's with ``filter_mount`` (None: with measurement-space association only),
        else 0, the array geometry's own (see :meth:`smooth`)."""
        use = self.measurement_space if filter_mount is None else filter_mount
        return float(self.filter.mount[int(np.argmax(self.filter.logw))]) if use else 0.0

    def smoother_config(self) -> SmootherConfig:
        """:meth:`smooth`'s default :class:`SmootherConfig`: the filter's range and slip noise
        and field of view; with state-space association only, the joint per-stop association
        (``stop_gate``, :data:`STATE_STOP_GATE`), a key pose every
        :data:`STATE_KEYFRAME_TURN` of turning and each landmark's own range noise
        (``sigma_floor``, :data:`STATE_SIGMA_FLOOR`)."""
        state = not self.measurement_space
        fc = self.filter.config
        return SmootherConfig(
            range_sigma=fc.range_sigma,
            slip_translation=fc.slip_translation,
            slip_rotation=fc.slip_rotation,
            slip_heading_per_metre=fc.slip_heading_per_metre,
            slip_floor=fc.slip_floor,
            fov=fc.fov,
            drive_distance=self.config.drive_reset,
            # on room_pillar's measurement-space echo tracks (filter seed 0, 3-degree steps)
            # the joint association added 18 m of wall matching no face and 6 false corners
            stop_gate=STATE_STOP_GATE if state else 0.0,
            # not measured on room_pillar's filter runs (measurement space): left off there
            keyframe_turn=STATE_KEYFRAME_TURN if state else 0.0,
            # never above the filter's own range noise (a valid SlamConfig with range_sigma
            # under 1 cm must not fail on a floor the user never set)
            sigma_floor=min(STATE_SIGMA_FLOOR, fc.range_sigma) if state else 0.0,
        )

    def map(self, min_hits: int = 8) -> SlamMap:
        """The current map of the best particle (:func:`~fusion_center.mapping.features.build_map`
        of :meth:`RbpfSlam.landmarks`)."""
        return build_map(self.filter.landmarks(min_hits=min_hits))


def _with_end_walls(
    the_map: SlamMap,
    res: SmoothedPathMap,
    min_pairs: int,
    extra: tuple[FloatArray, FloatArray, npt.NDArray[np.int64]] | None = None,
) -> SlamMap:
    """``the_map`` with the corridor end walls of ``res``'s landmarks heard from one stop
    (:func:`~fusion_center.mapping.features.corridor_end_walls`) appended and listed in
    ``end_walls``. A wall's reflection point is the foot of the perpendicular from the
    stop, a corner's or point's its position (the same image from one stop, Fig. 19).
    ``extra``: further reflection points, the positions they were heard from and their pairs
    (:meth:`~fusion_center.mapping.smoothing.LeastSquaresPathMapSmoother.stop_reflectors`),
    those with ``min_pairs`` taken as well."""
    one = np.flatnonzero((res.stops == 1) & (res.pairs >= min_pairs))
    if res.observer.shape[0] != res.kinds.size:
        one = one[:0]
    obs = res.observer[one]
    st = res.states[one]
    refl = st.copy()
    wall = res.kinds[one] == WALL
    if np.any(wall):
        nrm = np.stack([np.cos(st[wall, 0]), np.sin(st[wall, 0])], -1)
        refl[wall] = obs[wall] + (st[wall, 1] - np.sum(nrm * obs[wall], 1))[:, None] * nrm
    if extra is not None:
        more = np.asarray(extra[2]) >= min_pairs
        refl = np.vstack([refl, np.asarray(extra[0], float).reshape(-1, 2)[more]])
        obs = np.vstack([obs, np.asarray(extra[1], float).reshape(-1, 2)[more]])
    if refl.shape[0] == 0:
        return the_map
    ends = corridor_end_walls(the_map.walls, refl, obs)
    if len(ends) == 0:
        return the_map
    n = len(the_map.walls)
    return SlamMap(
        walls=np.vstack([the_map.walls, ends]),
        corners=the_map.corners,
        points=the_map.points,
        end_walls=np.r_[np.asarray(the_map.end_walls, np.intp), n + np.arange(len(ends))],
    )
