"""From ``node_info``, ``poses`` and ``ir`` messages to imaging observations (world frame).

Shared by the offline ``uwbnet image`` and the live fusion center. A transmitter named in an
``ir`` (``"{node}/{antenna}"``) may belong to another node (multistatic). Positions come from,
in order: the ``ir``'s own ``pose`` (the receiving node at acquisition), the latest ``poses``
estimate of a mobile node, the ``node_info`` pose of a static node.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from fusion_center.imaging.migration import Observations
from protocol import Ir, NodeInfo, Poses


class ImagingError(ValueError):
    """Impulse responses that cannot be imaged (one-line message)."""


@dataclass(frozen=True, slots=True)
class Rows:
    """The observations of one ``ir`` message (one row per receiver)."""

    h: npt.NDArray[np.float32] | npt.NDArray[np.complex64]
    tx: npt.NDArray[np.float64]
    rx: npt.NDArray[np.float64]
    tx_yaw: npt.NDArray[np.float64]
    rx_yaw: npt.NDArray[np.float64]
    tx_bw: npt.NDArray[np.float64]
    rx_bw: npt.NDArray[np.float64]
    emission: int


def antenna_world(pose: tuple[float, ...], pos: tuple[float, ...]) -> npt.NDArray[np.float64]:
    """World position of an antenna at ``pos`` (node frame) on a node at ``pose``."""
    x, y, z, yaw = pose
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([x + c * pos[0] - s * pos[1], y + s * pos[0] + c * pos[1], z + pos[2]])


class ObservationAssembler:
    """Turns ``ir`` messages into :class:`Rows`, checking that sampling is common."""

    def __init__(self) -> None:
        self.infos: dict[str, NodeInfo] = {}
        self.estimates: dict[str, tuple[float, float, float, float]] = {}
        self.sampling: tuple[float, int, float, float] | None = None
        self._emissions: dict[tuple[str, int], int] = {}

    def add_info(self, info: NodeInfo) -> None:
        r = info.radar
        s = (float(r.fs), int(r.n), float(r.t0), float(r.fc or 0.0))
        if self.sampling is None:
            self.sampling = s
        elif s != self.sampling:
            fs, n, t0, fc = self.sampling
            raise ImagingError(
                f"mismatched sampling between nodes: {info.src} has fs={r.fs:g} Hz, n={r.n}, "
                f"t0={r.t0:g} s, fc={r.fc or 0:g} Hz; others fs={fs:g} Hz, n={n}, t0={t0:g} s, "
                f"fc={fc:g} Hz"
            )
        self.infos[info.src] = info

    def add_poses(self, msg: Poses) -> None:
        for node, est in msg.poses.items():
            self.estimates[node] = tuple(float(v) for v in est.pose)

    def _pose(self, node: str, ir: Ir) -> tuple[float, ...]:
        if node == ir.src and ir.pose is not None:
            return ir.pose
        info = self.infos[node]
        if info.mobile:
            pose = self.estimates.get(node)
            if pose is None:
                raise ImagingError(
                    f"no pose for mobile node {node} (its ir carry no pose and no poses "
                    "message estimated it)"
                )
            return pose
        return info.pose

    def rows(self, ir: Ir) -> Rows:
        """The observations of ``ir``; :class:`ImagingError` if it cannot be placed."""
        info = self.infos.get(ir.src)
        if info is None:
            raise ImagingError(f"ir from {ir.src} before its node_info")
        tx_node, _, tx_ant = ir.tx.partition("/")
        tx_info = self.infos.get(tx_node)
        if tx_info is None or tx_ant not in tx_info.antennas:
            raise ImagingError(f"ir from {ir.src}: unknown transmitter {ir.tx}")
        if ir.h.shape[1] != info.radar.n:
            raise ImagingError(
                f"ir from {ir.src}: {ir.h.shape[1]} samples, node_info says n={info.radar.n}"
            )
        if not np.all(np.isfinite(ir.h)):
            raise ImagingError(f"ir from {ir.src}: NaN or Inf samples")
        rx_pose = self._pose(ir.src, ir)
        tx_pose = self._pose(tx_node, ir)
        ant_t = tx_info.antennas[tx_ant]
        tx = antenna_world(tx_pose, ant_t.pos)
        rx, rx_yaw, rx_bw = [], [], []
        for name in ir.rx:
            ant = info.antennas.get(name)
            if ant is None:
                raise ImagingError(f"ir from {ir.src}: unknown receiver {name}")
            rx.append(antenna_world(rx_pose, ant.pos))
            rx_yaw.append(rx_pose[3] + ant.boresight)
            rx_bw.append(ant.beamwidth)
        k = len(ir.rx)
        key = (ir.tx, ir.frame)
        em = self._emissions.setdefault(key, len(self._emissions))
        return Rows(
            h=ir.h,
            tx=np.tile(tx, (k, 1)),
            rx=np.array(rx),
            tx_yaw=np.full(k, tx_pose[3] + ant_t.boresight),
            rx_yaw=np.array(rx_yaw),
            tx_bw=np.full(k, ant_t.beamwidth),
            rx_bw=np.array(rx_bw),
            emission=em,
        )


def stack_rows(rows: list[Rows], sampling: tuple[float, int, float, float]) -> Observations:
    """One :class:`Observations` of many messages' rows."""
    fs, _, t0, fc = sampling
    return Observations(
        h=np.concatenate([r.h for r in rows]),
        tx=np.concatenate([r.tx for r in rows]),
        rx=np.concatenate([r.rx for r in rows]),
        fs=fs,
        t0=t0,
        fc=fc,
        tx_yaw=np.concatenate([r.tx_yaw for r in rows]),
        rx_yaw=np.concatenate([r.rx_yaw for r in rows]),
        tx_beamwidth=np.concatenate([r.tx_bw for r in rows]),
        rx_beamwidth=np.concatenate([r.rx_bw for r in rows]),
        emission=np.concatenate([np.full(len(r.tx), r.emission) for r in rows]),
    )
