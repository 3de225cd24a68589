"""``uwbnet map FILE.mcap --out map.json [--png map.png]``: UWB SLAM over a robot recording.

The I/O shell around the mapping of :mod:`fusion_center.mapping`: reads the robot's
``node_info`` and ``ir`` messages (``ir.odom`` when present) and writes ``map.json``:
``walls`` ([[x1, y1, x2, y2], ...]), ``corners`` and ``points`` ([[x, y], ...]) and
``trajectory`` ([[t, x, y, yaw], ...]), all in the frame of the robot's first pose (m, rad).
The recorded true poses are never given to the estimators.

Two ways to the path (``localise``):

* ``stops``: the stop graph (:mod:`fusion_center.mapping.stop_graph`, beyond the chapter): the
  turn of every stop is one 360-degree scan; scans are registered stop to stop and joined by a
  robust pose graph with the odometry; the map is then built along that path
  (:func:`fusion_center.mapping.fixed_path.map_fixed_path`). Deterministic; needs odometry
  and stops where the robot turns on the spot.
* ``filter``: the chapter's Rao-Blackwellized particle filter
  (:class:`fusion_center.mapping.EchoSlamMapper`, Section 6), then the joint least-squares
  smoothing (``smooth``). The live mapping service runs this one.
* ``auto`` (default): ``stops`` when the recording has odometry, the robot turns in steps
  under :data:`AUTO_STATE_STEP` and the stop graph's registrations join at least
  :data:`AUTO_MIN_REGISTERED` of its stops to another, else ``filter``.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import os
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from protocol import Ir, NodeInfo, Truth
from protocol.recording import decoded_messages

log = logging.getLogger(__name__)

#: ``auto`` takes the stop graph when its registrations (scan matches, the only thing besides
#: the odometry that places a stop) join at least this fraction of its stops to another stop:
#: a stop with none is placed by dead reckoning. Measured (stops joined): corridor_L_sparse
#: seeds 1-3 60 % (path 0.82 m by the stop graph against 0.07-0.36 m by the filter); room_pillar
#: seeds 0/1 97 / 99 %, corridor_L seed 1 100 %; held-out rooms 80-100 %. It replaced a test on the
#: turn closure (at least half the turns closed), which is not what places the stops and fails
#: where no wall faces the robot's heading at the start of its turn: a room at 25 degrees to
#: the robot's first heading closed 7 of 16 turns and a 6-degree-step hall 10 of 25, both then
#: mapped by the filter (0.130 and 0.485 m) where the stop graph gives 0.133 and 0.243 m.
AUTO_MIN_REGISTERED = 0.75
LOCALISERS = ("auto", "stops", "filter")
#: The map along the stop graph's path: walls split at 1 m gaps of their specular points and
#: walls the robot drove through left out (negative information). Along the stop graph's
#: path on room_pillar seeds 0 / 1 (docs/mapping.md): ghost walls 28 -> 19 / 28 -> 17, faces
#: found 10 -> 11 / 12 -> 12, mean position 0.081 -> 0.081 / 0.100 -> 0.088 m, outline
#: covered 97 -> 90 / 100 -> 95 %. (Not the fixed-path defaults: wall_gap cuts
#: corridor_L_sparse's few walls into unsupported pieces, but ``auto`` maps that by the filter.)
STOP_MAP_SETTINGS = {"wall_gap": 1.0, "drop_crossed": True}
#: ... and ``wall_gap`` at least this many times the median distance of a stop to its nearest
#: stop (the stop graph's own poses): a wall's specular points are the feet of the stops that
#: see it, so a gap under the stops' spacing cuts it at every foot (FixedPathConfig.wall_gap
#: must exceed the spacing of the stops). room_pillar's stops are 0.56 m apart (0.84 m: the
#: 1 m floor stays, its maps are unchanged). Along the same stop paths, 1 m against this:
#: corridor_L seed 1 (stops 1.0 m apart) faces 2 -> 4 of 6, outline 18 -> 55 %; held-out
#: rooms (docs/mapping.md) outline 46 -> 69 % and 40 -> 62 %, but 62 -> 51 % in a third, and
#: the merged walls' mean position 0.05 -> 0.05-0.08 m (0.07 -> 0.19 m where the path is
#: turned by 5 degrees, lab_skew).
STOP_WALL_GAP_SPACING = 1.5
#: ... and at most this (m): the gap also decides which collinear walls merge
#: (``build_map``'s ``merge_gap``), and a longer one would join two walls across a doorway
#: (unmeasured: no recorded room has one; lab_skew's stops 1.5 m apart give 2.3 m).
STOP_WALL_GAP_MAX = 2.5
#: ``--association auto`` for the filter: state space when the robot turns in steps of at
#: least this (rad; median over the first :data:`AUTO_LOOKAHEAD` acquisitions' turning steps),
#: measurement space otherwise. The measurement space's echo tracks need small steps (3
#: degrees); at 15 degrees they break (corridor_L_sparse seeds 1 / 2 / 3, state against
#: measurement: path 0.36 / 0.31 / 0.07 m against 0.40 / 0.47 / 0.22 m, 5 / 4 / 4 of 6 faces
#: against 2 / 2 / 2, outline 44-45 % against 36-40 %). ``--localise auto`` reuses it over
#: all acquisitions (the stop graph works at 6-degree steps and fails at 15; between them it
#: is not measured).
AUTO_STATE_STEP = math.radians(10.0)
AUTO_LOOKAHEAD = 12
ASSOCIATIONS = ("auto", "measurement", "state")


class MappingError(ValueError):
    """A recording cannot be mapped (one-line message)."""


@dataclasses.dataclass(slots=True)
class MapStats:
    """Counts of an offline mapping run."""

    messages: int = 0
    ir: int = 0
    rejected: int = 0
    updates: int = 0
    walls: int = 0
    corners: int = 0
    points: int = 0
    pairs_seen: int = 0
    pairs_used: int = 0
    robot: str = ""
    association: str = ""
    wall_s: float = 0.0
    acquisitions_per_s: float = 0.0
    smoothed: bool = False
    smooth_cpu_s: float = 0.0
    localise: str = ""
    stops: int = 0
    stops_closed: int = 0
    registrations: int = 0
    stops_registered: int = 0
    wall_gap: float | None = None
    bundle_adjust: bool | None = None
    bundle_unconverged: int | None = None
    bundle_shift: float | None = None
    bundle_dropped: bool | None = None
    drives_turn: bool | None = None
    eval: dict[str, Any] | None = None
    eval_filter: dict[str, Any] | None = None

    def as_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


def robot_geometry(info: NodeInfo, rx: tuple[str, ...]) -> np.ndarray:
    """tx, rx1, rx2 positions (x, y in the robot frame) of a robot's ``node_info``."""
    from fusion_center.mapping.pipeline import array_geometry

    try:
        return array_geometry(info.antennas, rx)
    except ValueError as exc:
        raise MappingError(f"robot {info.src}: {exc}") from None


def _make_mapper(
    info: NodeInfo,
    rx: tuple[str, ...],
    particles: int,
    association: str,
    seed: int,
    keep_history: bool = False,
) -> Any:
    from fusion_center.mapping import EchoSlamMapper, MapperConfig, SlamConfig

    r = info.radar
    return EchoSlamMapper(
        robot_geometry(info, rx),
        fs=r.fs,
        t0=r.t0,
        bandwidth=r.f_high - r.f_low,
        config=MapperConfig(keep_history=keep_history),
        slam=SlamConfig(n_particles=particles, association=association, seed=seed),
    )


def _robot_ir(
    path: str | os.PathLike[str],
    robot: str | None,
    stats: MapStats,
    progress: Callable[[int], None] | None,
    truth: list[tuple[float, tuple[float, ...]]],
    dead: list[list[float]],
) -> Iterator[tuple[NodeInfo, Ir]]:
    """The mapped robot's valid ``ir`` messages with its ``node_info``; collects its
    ``truth`` and the dead-reckoning path (the odometry integrated alone, first-pose frame)
    on the way and counts rejected ones in ``stats``.

    ``ir.odom`` is the motion since the previous ``ir``: the odometry of a rejected ``ir`` is
    carried into the next one's (composed), so that a bad impulse response does not lose the
    robot's motion (one lost step during a drive merged two stops of the stop graph)."""
    infos: dict[str, NodeInfo] = {}
    dr_pose = np.zeros(3)
    carry: np.ndarray | None = None
    for msg in decoded_messages(path, ("node_info", "ir", "truth"), stats, progress):
        if isinstance(msg, NodeInfo):
            infos[msg.src] = msg
        elif isinstance(msg, Truth) and stats.robot and stats.robot in msg.nodes:
            truth.append((msg.t, msg.nodes[stats.robot]))
        elif isinstance(msg, Ir):
            info = infos.get(msg.src)
            if info is None or not info.mobile or (robot is not None and msg.src != robot):
                continue
            if not stats.robot:
                stats.robot = msg.src
            elif msg.src != stats.robot:
                continue
            if msg.h.shape[0] != 2 or not np.all(np.isfinite(msg.h)):
                stats.rejected += 1
                log.warning("ir of %s rejected: needs two finite rows", msg.src)
                if msg.odom is not None:
                    step = np.asarray(msg.odom, float)
                    carry = step if carry is None else compose(carry, step)
                continue
            if carry is not None and msg.odom is not None:
                odom = compose(carry, np.asarray(msg.odom, float))
                msg = dataclasses.replace(msg, odom=tuple(float(v) for v in odom))
            carry = None
            stats.ir += 1
            if msg.odom is not None and dead:
                dr_pose = compose(dr_pose, np.asarray(msg.odom, float))
            dead.append([msg.t, *dr_pose.tolist()])
            yield info, msg


class _NotStopsError(Exception):
    """The recording does not suit the stop graph (``auto`` then runs the filter)."""


def _map_by_stops(
    path: str | os.PathLike[str],
    robot: str | None,
    stats: MapStats,
    progress: Callable[[int], None] | None,
    truth: list[tuple[float, tuple[float, ...]]],
    dead: list[list[float]],
    auto: bool,
    bundle_adjust: bool | None = None,
) -> tuple[Any, np.ndarray]:
    """Map and ``[t, x, y, yaw]`` path by the stop graph and the map along its path.

    Raises :class:`_NotStopsError` when the recording does not suit it (an ``ir`` without
    odometry), and with ``auto`` also when the robot turns in steps of
    :data:`AUTO_STATE_STEP` or more (the echo tracks the stop graph's reflectors are made of
    break), when registrations join fewer than :data:`AUTO_MIN_REGISTERED` of the stops (runs
    of at least ``StopGraphConfig.min_stop_acquisitions``: a drive sampled in several steps
    makes short runs that are no stops) to another stop (the rest would be dead reckoning),
    or when the stop graph or the map along it fails (``ValueError``); ``stops`` gives that
    failure as a :class:`MappingError`. ``bundle_adjust`` sets
    ``StopGraphConfig.bundle_adjust`` (None: its default)."""
    from fusion_center.mapping.fixed_path import FixedPathConfig, map_fixed_path
    from fusion_center.mapping.stop_graph import (
        StopGraphConfig,
        StopGraphPathEstimator,
        scan_front_end,
    )

    msgs = _robot_ir(path, robot, stats, progress, truth, dead)
    first = next(msgs, None)
    if first is None:
        raise MappingError(f"{path}: no ir of a mobile node (robot) with its node_info")
    info, msg0 = first
    antennas = robot_geometry(info, msg0.rx)
    r = info.radar
    missing: list[float] = []

    def frames() -> Iterator[tuple[float, np.ndarray, Any]]:
        yield msg0.t, msg0.h, (0.0, 0.0, 0.0)  # the first ir has no motion before it
        for _, m in msgs:
            if m.odom is None:
                missing.append(m.t)
                return
            yield m.t, m.h, m.odom

    try:
        scans = scan_front_end(frames(), fs=r.fs, t0=r.t0, bandwidth=r.f_high - r.f_low)
    except ValueError as exc:
        raise MappingError(f"{path}: {exc}") from None
    if missing:
        raise _NotStopsError(f"the ir at t = {missing[0]} s has no odometry")
    # the turning step needs only the odometry: a recording the stop graph does not suit is
    # refused before the stop graph is paid for
    step = turning_step(scans.odometry)
    if auto and (why := stops_unsuited(step, None, None)) is not None:
        raise _NotStopsError(why)
    config = StopGraphConfig()
    if bundle_adjust is not None:
        config = dataclasses.replace(config, bundle_adjust=bool(bundle_adjust))
    stats.bundle_adjust = config.bundle_adjust
    estimator = StopGraphPathEstimator(antennas, config)
    try:
        res = estimator.estimate(scans)
    except ValueError as exc:
        if auto:
            raise _NotStopsError(f"stop graph failed: {exc}") from None
        raise MappingError(f"{path}: {exc}") from None
    turns = [
        i
        for i, s in enumerate(res.stops)
        if s.end - s.start >= estimator.config.min_stop_acquisitions
    ]
    joined = {k for e in res.edges if e.kind != "odometry" for k in (e.i, e.j)}
    stats.stops = len(turns)
    stats.stops_closed = sum(res.stops[i].closed for i in turns)
    stats.registrations = res.n_registered
    stats.stops_registered = len(joined.intersection(turns))
    stats.bundle_unconverged = res.bundle_unconverged
    if res.bundle_shift is not None and np.isfinite(res.bundle_shift):
        stats.bundle_shift = round(float(res.bundle_shift), 3)
    stats.bundle_dropped = res.bundle_dropped if config.bundle_adjust else None
    stats.drives_turn = res.drives_turn
    if res.drives_turn:
        log.info(
            "%s: the robot turns with its drives: loop search deferred %s, gated at %.1f sigma",
            path,
            list(config.drive_loop_defer),
            config.drive_loop_gate,
        )
    if res.bundle_unconverged and not res.bundle_dropped:
        log.warning(
            "%s: %d solve(s) of the bundle adjustment stopped before converging",
            path,
            res.bundle_unconverged,
        )
    if res.bundle_dropped:
        shift = res.bundle_shift
        finite = shift is not None and np.isfinite(shift)
        moved = f"{shift:.1f} sigma (RMS)" if finite else "a non-finite shift"
        log.warning(
            "%s: the bundle adjustment moved the stops by %s; kept the refined poses", path, moved
        )
    why = stops_unsuited(step, stats.stops, stats.stops_registered)
    if why is not None and auto:
        raise _NotStopsError(why)
    if why is not None:  # forced: mapped all the same, the user is told what it rests on
        log.warning("%s: the stop graph maps it although %s", path, why)
    stats.wall_gap = stop_wall_gap(res.stop_poses[turns, :2])
    try:
        built = map_fixed_path(
            scans.pairs,
            scans.groups,
            res.trajectory[:, 1:],
            antennas,
            FixedPathConfig(**{**STOP_MAP_SETTINGS, "wall_gap": stats.wall_gap}),
        )
    except ValueError as exc:
        if auto:
            raise _NotStopsError(f"map along the stop graph failed: {exc}") from None
        raise MappingError(f"{path}: {exc}") from None
    stats.pairs_seen = sum(int(p.shape[0]) for p in scans.pairs)
    stats.pairs_used = int(built.pairs.sum())
    return built.map, res.trajectory


def map_recording(
    path: str | os.PathLike[str],
    out: str | os.PathLike[str],
    *,
    method: str = "auto",
    particles: int = 40,
    seed: int = 0,
    robot: str | None = None,
    png: str | os.PathLike[str] | None = None,
    scenario: Any = None,
    progress: Callable[[int], None] | None = None,
    smooth: bool = True,
    localise: str = "auto",
    close: bool = True,
    bundle_adjust: bool | None = None,
) -> MapStats:
    """Map a robot recording; write ``out`` (map.json) and optionally ``png``.

    ``localise`` picks the path estimator (``auto``, ``stops``, ``filter``: the module
    docstring). For the filter, ``method`` is the data association (``auto``: see
    :data:`AUTO_STATE_STEP`, ``measurement`` or
    ``state``, Section 6.3) and ``seed`` seeds it (a run's figures scatter with it); with
    ``smooth`` (and odometry in the recording), the filter's path and map are re-estimated
    jointly by least squares (:meth:`fusion_center.mapping.EchoSlamMapper.smooth`), map.json
    holds the smoothed ones and ``stats.eval_filter`` scores the filter's own. With
    ``scenario`` (a loaded scenario) and ``truth`` messages in the recording, ``stats.eval``
    holds the map's errors (:func:`uwbnet.map_eval.evaluate_map`). With ``close``, mapped
    walls that meet are extended to their corner and the concave corners added
    (:func:`fusion_center.mapping.features.close_outline`, both localisers; the filter's own
    map in ``eval_filter`` too). ``bundle_adjust`` turns the stop graph's bundle adjustment
    over the echo pairs on or off (``StopGraphConfig.bundle_adjust``; None: its default) and
    is recorded with the stop fields. Outputs appear only when complete. Bad messages are counted
    in ``rejected`` and logged.
    """
    import time

    from fusion_center.mapping.features import close_outline

    if method not in ASSOCIATIONS:
        raise MappingError(f"unknown association {method!r} ({', '.join(ASSOCIATIONS)})")
    if particles < 1:
        raise MappingError(f"--particles must be at least 1, got {particles}")
    if localise not in LOCALISERS:
        raise MappingError(f"unknown --localise {localise!r} ({', '.join(LOCALISERS)})")
    t_start = t_filter = time.perf_counter()
    filter_map = filter_traj = None
    stats = MapStats()
    truth: list[tuple[float, tuple[float, ...]]] = []
    dead: list[list[float]] = []
    traj: list[list[float]] = []
    the_map = None
    if localise != "filter":
        try:
            the_map, path_arr = _map_by_stops(
                path,
                robot,
                stats,
                progress,
                truth,
                dead,
                auto=localise == "auto",
                bundle_adjust=bundle_adjust,
            )
            traj = [[float(v) for v in row] for row in path_arr]
            stats.updates = len(traj)
            stats.localise = "stops"
            stats.acquisitions_per_s = round(stats.ir / max(time.perf_counter() - t_start, 1e-9), 1)
        except _NotStopsError as why:
            if localise == "stops":
                raise MappingError(f"{path}: no stop graph: {why}") from None
            log.warning("%s: the particle filter maps it (no stop graph: %s)", path, why)
            # a fresh count for the filter's pass; what the stop graph found stays reported
            stats = MapStats(
                stops=stats.stops,
                stops_closed=stats.stops_closed,
                registrations=stats.registrations,
                stops_registered=stats.stops_registered,
            )
            truth, dead = [], []
            # the file was read once already: the progress bar is not advanced again
            progress = None
            t_filter = time.perf_counter()
    if the_map is None:
        stats.localise = "filter"
        mapper = None

        def emit(outputs: list[Any]) -> None:
            for o in outputs:
                x, y, yaw = o.estimate.pose
                traj.append([o.t, float(x), float(y), float(yaw)])
                stats.updates += 1

        # the first acquisitions wait until the association is chosen from their turning steps
        ahead: list[tuple[NodeInfo, Ir]] = []

        def start() -> Any:
            stats.association = _association(method, [m for _, m in ahead])
            info, first = ahead[0]
            new = _make_mapper(info, first.rx, particles, stats.association, seed, smooth)
            for _, m in ahead:
                emit(new.step(m.t, m.h, m.odom))
            ahead.clear()
            return new

        for info, msg in _robot_ir(path, robot, stats, progress, truth, dead):
            if mapper is not None:
                emit(mapper.step(msg.t, msg.h, msg.odom))
                continue
            ahead.append((info, msg))
            if len(ahead) >= AUTO_LOOKAHEAD:
                mapper = start()
        if mapper is None and ahead:
            mapper = start()
        if mapper is None:
            raise MappingError(f"{path}: no ir of a mobile node (robot) with its node_info")
        emit(mapper.finish())
        the_map = filter_map = mapper.map()
        filter_traj = traj
        # the filter's own rate (what the live service must sustain); smoothing runs once after
        filter_s = time.perf_counter() - t_filter
        stats.acquisitions_per_s = round(stats.ir / max(filter_s, 1e-9), 1)
        if smooth:
            c0 = time.process_time()
            smoothed = mapper.smooth()
            stats.smooth_cpu_s = round(time.process_time() - c0, 2)
            if smoothed is not None:
                the_map, poses = smoothed
                traj = [[float(v) for v in row] for row in poses]
                stats.smoothed = True
            else:
                log.warning("%s: not smoothed (an ir without odometry): the filter's map", path)
        stats.pairs_seen, stats.pairs_used = mapper.pairs_seen, mapper.pairs_used
    if close and traj:
        # the walls' ends to the corners they imply, along the path that saw them
        unsmoothed = the_map is filter_map
        the_map = close_outline(the_map, np.array(traj, float)[:, 1:3])
        if unsmoothed:
            filter_map = the_map
        elif filter_map is not None and filter_traj:
            filter_map = close_outline(filter_map, np.array(filter_traj, float)[:, 1:3])
    stats.wall_s = round(time.perf_counter() - t_start, 2)
    stats.walls, stats.corners, stats.points = (
        len(the_map.walls),
        len(the_map.corners),
        len(the_map.points),
    )
    doc = {
        "walls": np.round(the_map.walls, 4).tolist(),
        "corners": np.round(the_map.corners, 4).tolist(),
        "points": np.round(the_map.points, 4).tolist(),
        # indices into walls of the corridor end walls heard from one stop (an inference:
        # features.corridor_end_walls), so a later close_outline can extend to them again
        "end_walls": np.asarray(the_map.end_walls, int).tolist(),
        "trajectory": [[round(v, 5) for v in row] for row in traj],
        "robot": stats.robot,
        "frame": "first pose of the robot",
        "localise": stats.localise,
    }
    if stats.localise == "filter":
        doc.update(association=stats.association, particles=particles, seed=seed)
    else:
        doc.update(
            stops=stats.stops,
            stops_closed=stats.stops_closed,
            registrations=stats.registrations,
            stops_registered=stats.stops_registered,
            wall_gap=stats.wall_gap,
            bundle_adjust=stats.bundle_adjust,
            bundle_unconverged=stats.bundle_unconverged,
            bundle_shift=stats.bundle_shift,
            bundle_dropped=stats.bundle_dropped,
            drives_turn=stats.drives_turn,
        )
    _write_atomic(Path(out), json.dumps(doc, separators=(",", ":")).encode())
    truth_traj = truth_first_frame(truth)
    if png is not None:
        plot_map(doc, Path(png), truth_traj)
    if scenario is not None:
        from uwbnet.map_eval import evaluate_map

        if not truth:
            raise MappingError(f"{path}: no truth of robot {stats.robot} to evaluate against")
        first = np.array([truth[0][1][0], truth[0][1][1], truth[0][1][-1]], float)
        has_odom = any(np.any(r[1:] != 0) for r in dead)
        dr = np.array(dead) if has_odom else None
        stats.eval = evaluate_map(doc, scenario, truth_traj, first, dr)
        if stats.smoothed and filter_map is not None:
            # rounded as map.json is, so it scores what --no-smooth writes, to the digit
            raw = {
                "walls": np.round(filter_map.walls, 4).tolist(),
                "corners": np.round(filter_map.corners, 4).tolist(),
                "points": np.round(filter_map.points, 4).tolist(),
                "trajectory": [[round(v, 5) for v in row] for row in filter_traj],
            }
            stats.eval_filter = evaluate_map(raw, scenario, truth_traj, first, None)
    return stats


def _association(method: str, first: list[Ir]) -> str:
    """The filter's data association: ``method``, or for ``auto`` state space when the
    median turning step of the ``first`` acquisitions (``|odom dyaw|`` of the steps that
    turn without driving 0.1 m; :func:`turning_step`) reaches :data:`AUTO_STATE_STEP`, else
    measurement space."""
    if method != "auto":
        return method
    odo = np.array([m.odom for m in first[1:] if m.odom is not None], float).reshape(-1, 3)
    step = turning_step(odo)
    if step is not None and step >= AUTO_STATE_STEP:
        return "state"
    return "measurement"


def stops_unsuited(step: float | None, stops: int | None, joined: int | None) -> str | None:
    """Why ``--localise auto`` does not take the stop graph, or None (a heuristic rule, its
    thresholds measured on the recordings in :data:`AUTO_MIN_REGISTERED`'s comment).

    ``step``: the robot's median turning step (rad, :func:`turning_step`; None: it never
    turns on the spot); ``stops``: the stop graph's stops (None: not built yet, only the step
    is tested); ``joined``: how many of them a registration joins to another stop."""
    if step is not None and step >= AUTO_STATE_STEP:
        return f"turning steps of {math.degrees(step):.0f} degrees"
    if stops is not None and (joined or 0) < AUTO_MIN_REGISTERED * max(stops, 1):
        return f"registrations join {joined or 0} of {stops} stops to another"
    return None


def stop_wall_gap(stops: np.ndarray) -> float:
    """``wall_gap`` of the map along a stop path (m; a heuristic rule): ``STOP_MAP_SETTINGS``'
    floor, or :data:`STOP_WALL_GAP_SPACING` times the median distance of a stop (positions,
    shape (n, 2), m) to its nearest other stop when that is larger, at most
    :data:`STOP_WALL_GAP_MAX`."""
    xy = np.asarray(stops, float).reshape(-1, 2)
    floor = float(STOP_MAP_SETTINGS["wall_gap"])
    if xy.shape[0] < 2:
        return floor
    d = np.hypot(*(xy[:, None, :] - xy[None, :, :]).transpose(2, 0, 1))
    np.fill_diagonal(d, np.inf)
    gap = STOP_WALL_GAP_SPACING * float(np.median(d.min(1)))
    return min(max(floor, gap), STOP_WALL_GAP_MAX)


def turning_step(odometry: np.ndarray, drive: float = 0.1) -> float | None:
    """Median turning step of a robot, rad: ``|dyaw|`` of the odometry increments
    ``(dx, dy, dyaw)`` (shape (n, 3)) that do not drive (moved at most ``drive``, m), dwells
    (no turn) left out; None when none turns
    (:func:`fusion_center.mapping.pipeline.turning_step`)."""
    from fusion_center.mapping.pipeline import turning_step as step

    return step(odometry, drive)


def compose(pose: np.ndarray, increment: np.ndarray) -> np.ndarray:
    """Pose ``[x, y, yaw]`` after an odometry increment ``(dx, dy, dyaw)`` given in its frame."""
    c, s = math.cos(pose[2]), math.sin(pose[2])
    dx, dy, da = increment
    return np.array([pose[0] + c * dx - s * dy, pose[1] + s * dx + c * dy, pose[2] + da])


def truth_first_frame(truth: list[tuple[float, tuple[float, ...]]]) -> np.ndarray | None:
    """True ``[t, x, y, yaw]`` in the frame of the first true pose (for plots and scoring)."""
    if not truth:
        return None
    arr = np.array([[t, p[0], p[1], p[-1]] for t, p in truth], float)
    x0, y0, a0 = arr[0, 1], arr[0, 2], arr[0, 3]
    c, s = math.cos(a0), math.sin(a0)
    dx, dy = arr[:, 1] - x0, arr[:, 2] - y0
    return np.column_stack(
        [
            arr[:, 0],
            c * dx + s * dy,
            -s * dx + c * dy,
            (arr[:, 3] - a0 + np.pi) % (2 * np.pi) - np.pi,
        ]
    )


def _write_atomic(out: Path, data: bytes) -> None:
    part = out.with_name(out.name + ".partial")
    try:
        part.write_bytes(data)
        os.replace(part, out)
    except BaseException:
        part.unlink(missing_ok=True)
        raise


def plot_map(doc: dict[str, Any], out: Path, truth: np.ndarray | None = None) -> None:
    """Draw walls, corners, points and the trajectory (and the true trajectory if known)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 7))
    for x1, y1, x2, y2 in doc["walls"]:
        ax.plot([x1, x2], [y1, y2], "k-", lw=2)
    if doc["corners"]:
        c = np.array(doc["corners"])
        ax.plot(c[:, 0], c[:, 1], "rs", ms=6, label="corners")
    if doc["points"]:
        p = np.array(doc["points"])
        ax.plot(p[:, 0], p[:, 1], "bo", ms=5, label="points")
    if doc["trajectory"]:
        t = np.array(doc["trajectory"])
        ax.plot(t[:, 1], t[:, 2], "g.", ms=2, label="robot (SLAM)")
    if truth is not None:
        ax.plot(truth[:, 1], truth[:, 2], "mx", ms=4, label="robot (truth)")
    ax.set_aspect("equal")
    ax.set(xlabel="x (m), first robot pose frame", ylabel="y (m)")
    ax.legend(loc="best", fontsize=8)
    ax.grid(alpha=0.3)
    part = out.with_name(out.stem + ".partial" + out.suffix)
    try:
        fig.savefig(part, dpi=110)
        os.replace(part, out)
    except BaseException:
        part.unlink(missing_ok=True)
        raise
    finally:
        plt.close(fig)
