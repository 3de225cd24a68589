"""The fusion center's mapping runtime: robots' ``ir`` -> UWB SLAM -> ``poses`` and ``map``.

A thin zenoh shell around :class:`fusion_center.mapping.EchoSlamMapper`. It follows the nodes'
``node_info`` (published ones and, at start, the replies of their queryables); for every node
whose role is ``robot`` it subscribes to that node's ``ir`` through a
:class:`~protocol.transport.RingChannel` (drop oldest, counted: a slow SLAM never blocks the
robot) and runs one mapper per robot. Each processed acquisition publishes the robot's pose on
``uwbnet/{net}/fusion/poses`` (world frame: the map frame is the robot's first pose, anchored
at the ``pose`` of its first ``node_info``, or the ``pose`` of its first ``ir`` when present)
and every ``map_every`` acquisitions the map on ``uwbnet/{net}/fusion/map`` (kind ``map``).

While the filter holds a stop back for a relocalisation (after a long drive, up to one stop),
the pose of each held acquisition is published at once with the odometry's prediction
(``MapperConfig.provisional_poses``); the acquisition that ends the hold publishes the
relocalised pose. The revised poses of the acquisitions already published are not sent again,
so a robot's poses keep increasing ``t``.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import threading
from typing import Any

import numpy as np
import zenoh

from fusion_center.mapping import EchoSlamMapper, MapperOutput, SlamConfig, SlamMap
from fusion_center.mapping.pipeline import MapperConfig, array_geometry
from protocol import Ir, Map, NodeInfo, PoseEstimate, Poses, ProtocolError, decode, keys
from protocol.transport import FifoChannel, RingChannel, stop_worker

log = logging.getLogger(__name__)


@dataclasses.dataclass(frozen=True, slots=True, kw_only=True)
class MappingConfig:
    """Configuration of the mapping runtime.

    Parameters
    ----------
    net : network name.
    service_id : ``src`` of the published messages.
    particles : particles of each robot's filter.
    association : ``measurement`` or ``state`` (Section 6.3).
    map_every : acquisitions between two published maps.
    ring : capacity of the ``ir`` ring (drop oldest beyond it).
    """

    net: str = "demo"
    service_id: str = "fusion"
    particles: int = 40
    association: str = "measurement"
    map_every: int = 30
    ring: int = 256


@dataclasses.dataclass(slots=True)
class _Robot:
    info: NodeInfo
    mapper: EchoSlamMapper | None = None
    origin: tuple[float, float, float, float] | None = None
    processed: int = 0
    last_t: float = -math.inf


def _compose(origin: tuple[float, ...], pose: np.ndarray) -> tuple[float, float, float, float]:
    """World pose of a first-pose-frame ``[x, y, yaw]`` given the world ``origin``."""
    c, s = math.cos(origin[3]), math.sin(origin[3])
    x = origin[0] + c * pose[0] - s * pose[1]
    y = origin[1] + s * pose[0] + c * pose[1]
    yaw = (origin[3] + pose[2] + math.pi) % (2 * math.pi) - math.pi
    return (float(x), float(y), float(origin[2]), float(yaw))


class MappingService:
    """UWB SLAM of every robot on an open zenoh ``session``; ``start``/``stop`` are idempotent."""

    def __init__(self, session: zenoh.Session, config: MappingConfig | None = None) -> None:
        self.session = session
        self.config = config or MappingConfig()
        self._control: FifoChannel[tuple[str, bytes]] = FifoChannel(1024)
        self._ir: RingChannel[bytes] = RingChannel(self.config.ring)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._decl: list[Any] = []
        self._robots: dict[str, _Robot] = {}
        self._seq = {"poses": 0, "map": 0}
        self.rejected = 0
        self.maps_published = 0
        self.poses_published = 0

    @property
    def dropped(self) -> int:
        """``ir`` messages dropped because the SLAM fell behind."""
        return self._ir.dropped

    def start(self) -> None:
        if self._thread is not None:
            return
        net, s = self.config.net, self.session
        self._pub_poses = s.declare_publisher(keys.fusion_key(net, "poses"))
        self._pub_map = s.declare_publisher(
            keys.fusion_key(net, "map"), congestion_control=zenoh.CongestionControl.BLOCK
        )
        self._decl += [self._pub_poses, self._pub_map]
        put = self._control.put
        self._decl.append(
            s.declare_subscriber(
                keys.all_nodes_key(net, "info"), lambda sample: put(("info", _bytes(sample)))
            )
        )
        s.get(
            keys.all_nodes_key(net, "info"),
            lambda reply: put(("info", reply.ok.payload.to_bytes())) if reply.ok else None,
        )
        self._thread = threading.Thread(target=self._run, name="mapping", daemon=True)
        self._thread.start()
        log.info("mapping runtime started on net %s", net)

    def stop(self) -> None:
        stop_worker(self._stop, self._thread, self._decl)
        self._thread = None

    def maps(self) -> dict[str, SlamMap]:
        """The current map of every robot (first-pose frame)."""
        return {n: r.mapper.map() for n, r in self._robots.items() if r.mapper is not None}

    # -- worker --------------------------------------------------------------------------------

    def _run(self) -> None:
        while not self._stop.is_set():
            for kind, payload in self._control.drain():
                self._handle(kind, payload)
            payload = self._ir.get(timeout=0.05)
            if payload is not None:
                self._handle("ir", payload)

    def _handle(self, kind: str, payload: bytes) -> None:
        try:
            msg = decode(payload)
        except ProtocolError as exc:
            self.rejected += 1
            log.warning("mapping: rejected %s: %s", kind, exc)
            return
        if isinstance(msg, NodeInfo):
            self._add(msg)
        elif isinstance(msg, Ir):
            self._on_ir(msg)

    def _add(self, info: NodeInfo) -> None:
        if info.role != "robot" or info.src in self._robots:
            return
        self._robots[info.src] = _Robot(info=info)
        put = self._ir.put
        self._decl.append(
            self.session.declare_subscriber(
                keys.node_key(self.config.net, info.src, "ir"), lambda sample: put(_bytes(sample))
            )
        )
        log.info("mapping robot %s", info.src)

    def _on_ir(self, msg: Ir) -> None:
        robot = self._robots.get(msg.src)
        if robot is None:
            return
        if msg.h.shape[0] != 2 or not np.all(np.isfinite(msg.h)):
            self.rejected += 1
            log.warning("mapping: ir of %s rejected: needs two finite rows", msg.src)
            return
        if robot.mapper is None:
            try:
                ant = array_geometry(robot.info.antennas, msg.rx)
            except ValueError as exc:
                self.rejected += 1
                log.warning("mapping: robot %s: %s", msg.src, exc)
                return
            r = robot.info.radar
            robot.mapper = EchoSlamMapper(
                ant,
                fs=r.fs,
                t0=r.t0,
                bandwidth=r.f_high - r.f_low,
                config=MapperConfig(provisional_poses=True),
                slam=SlamConfig(
                    n_particles=self.config.particles, association=self.config.association
                ),
            )
            robot.origin = msg.pose if msg.pose is not None else robot.info.pose
        for out in robot.mapper.step(msg.t, msg.h, msg.odom):
            self._publish_pose(msg.src, robot, out)

    def _publish_pose(self, node: str, robot: _Robot, out: MapperOutput) -> None:
        assert robot.origin is not None and robot.mapper is not None
        if out.t <= robot.last_t:
            return  # the revision of a pose published provisionally during a hold
        robot.last_t = out.t
        pose = _compose(robot.origin, out.estimate.pose)
        est = PoseEstimate(pose=pose, cov=out.estimate.cov.tolist(), los={})
        msg = Poses(src=self.config.service_id, seq=self._next("poses"), t=out.t, poses={node: est})
        self._pub_poses.put(msg.to_wire())
        self.poses_published += 1
        robot.processed += 1
        if robot.processed % self.config.map_every == 0:
            self._publish_map(node, robot, out.t)

    def _publish_map(self, node: str, robot: _Robot, t: float) -> None:
        assert robot.origin is not None and robot.mapper is not None
        m = robot.mapper.map()
        o = robot.origin
        c, s = math.cos(o[3]), math.sin(o[3])
        rot = np.array([[c, -s], [s, c]])

        def world(p: np.ndarray) -> np.ndarray:
            return p @ rot.T + np.array(o[:2])

        walls = np.hstack([world(m.walls[:, :2]), world(m.walls[:, 2:])]).reshape(-1, 4)
        msg = Map(
            src=self.config.service_id,
            seq=self._next("map"),
            t=t,
            robot=node,
            origin=tuple(float(v) for v in o),
            walls=walls.astype(np.float64),
            corners=world(m.corners).reshape(-1, 2),
            points=world(m.points).reshape(-1, 2),
        )
        self._pub_map.put(msg.to_wire())
        self.maps_published += 1

    def _next(self, stream: str) -> int:
        seq = self._seq[stream]
        self._seq[stream] = seq + 1
        return seq


def _bytes(sample: zenoh.Sample) -> bytes:
    return sample.payload.to_bytes()
