"""``uwbnet map FILE.mcap --out map.json [--png map.png]``: UWB SLAM over a robot recording.

The I/O shell around :class:`fusion_center.mapping.EchoSlamMapper`: reads the robot's
``node_info`` and ``ir`` messages (``ir.odom`` when present), runs the SLAM as fast as the
machine allows and writes ``map.json``: ``walls`` ([[x1, y1, x2, y2], ...]), ``corners`` and
``points`` ([[x, y], ...]) and ``trajectory`` ([[t, x, y, yaw], ...]), all in the frame of
the robot's first pose (m, rad). The recorded true poses are never given to the filter.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from protocol import Ir, NodeInfo, Truth
from protocol.recording import decoded_messages

log = logging.getLogger(__name__)


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
    wall_s: float = 0.0
    acquisitions_per_s: float = 0.0
    smoothed: bool = False
    smooth_cpu_s: float = 0.0
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


def map_recording(
    path: str | os.PathLike[str],
    out: str | os.PathLike[str],
    *,
    method: str = "measurement",
    particles: int = 40,
    seed: int = 0,
    robot: str | None = None,
    png: str | os.PathLike[str] | None = None,
    scenario: Any = None,
    progress: Callable[[int], None] | None = None,
    smooth: bool = True,
) -> MapStats:
    """Map a robot recording; write ``out`` (map.json) and optionally ``png``.

    ``method`` is the data association (``measurement`` or ``state``, Section 6.3); ``seed``
    seeds the particle filter (a run's figures scatter with it). With
    ``scenario`` (a loaded scenario) and ``truth`` messages in the recording, ``stats.eval``
    holds the map's errors (:func:`uwbnet.map_eval.evaluate_map`). Outputs appear only when
    complete. Bad messages are counted in ``rejected`` and logged. With ``smooth`` (and
    odometry in the recording), the filter's path and map are re-estimated jointly by least
    squares (:meth:`fusion_center.mapping.EchoSlamMapper.smooth`) and map.json holds the
    smoothed ones; ``stats.eval_filter`` then scores the filter's own map and path.
    """
    import time

    if method not in ("measurement", "state"):
        raise MappingError(f"unknown association {method!r} (measurement, state)")
    if particles < 1:
        raise MappingError(f"--particles must be at least 1, got {particles}")
    stats = MapStats()
    infos: dict[str, NodeInfo] = {}
    mapper = None
    traj: list[list[float]] = []
    # the odometry integrated alone (the baseline of --eval), first-pose frame
    dead: list[list[float]] = []
    dr_pose = np.zeros(3)
    truth: list[tuple[float, tuple[float, ...]]] = []
    t_start = time.perf_counter()

    def emit(outputs: list[Any]) -> None:
        for o in outputs:
            x, y, yaw = o.estimate.pose
            traj.append([o.t, float(x), float(y), float(yaw)])
            stats.updates += 1

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
                mapper = _make_mapper(info, msg.rx, particles, method, seed, smooth)
            elif msg.src != stats.robot:
                continue
            if msg.h.shape[0] != 2 or not np.all(np.isfinite(msg.h)):
                stats.rejected += 1
                log.warning("ir of %s rejected: needs two finite rows", msg.src)
                continue
            stats.ir += 1
            if msg.odom is not None and dead:
                dr_pose = compose(dr_pose, np.asarray(msg.odom, float))
            dead.append([msg.t, *dr_pose.tolist()])
            emit(mapper.step(msg.t, msg.h, msg.odom))
    if mapper is None:
        raise MappingError(f"{path}: no ir of a mobile node (robot) with its node_info")
    emit(mapper.finish())
    the_map = filter_map = mapper.map()
    filter_traj = traj
    # the filter's own rate (what the live service must sustain); smoothing runs once after
    filter_s = time.perf_counter() - t_start
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
    stats.wall_s = round(time.perf_counter() - t_start, 2)
    stats.walls, stats.corners, stats.points = (
        len(the_map.walls),
        len(the_map.corners),
        len(the_map.points),
    )
    stats.pairs_seen, stats.pairs_used = mapper.pairs_seen, mapper.pairs_used
    doc = {
        "walls": np.round(the_map.walls, 4).tolist(),
        "corners": np.round(the_map.corners, 4).tolist(),
        "points": np.round(the_map.points, 4).tolist(),
        "trajectory": [[round(v, 5) for v in row] for row in traj],
        "robot": stats.robot,
        "frame": "first pose of the robot",
        "association": method,
        "particles": particles,
        "seed": seed,
    }
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
        if stats.smoothed:
            raw = {
                "walls": filter_map.walls.tolist(),
                "corners": filter_map.corners.tolist(),
                "points": filter_map.points.tolist(),
                "trajectory": filter_traj,
            }
            stats.eval_filter = evaluate_map(raw, scenario, truth_traj, first, None)
    return stats


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
