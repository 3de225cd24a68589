"""The node's processing, I/O-free: ``ir`` messages in, ``detections`` out.

Shared by the live agent and offline ``uwbnet track``: every geometric and radar parameter
comes from the ``node_info`` messages (the receiving node's and, for multistatic links, the
transmitting node's), never from assumptions about our own simulator.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from node_agent.dsp.geometry import RadarParams, SensorGeometry
from node_agent.dsp.pipeline import DspResult, NodeDsp, NodeDspConfig
from protocol import Detections, Ir, NodeInfo


class NodeConfigError(ValueError):
    """The node's description does not allow processing an acquisition (one-line message)."""


def radar_params(info: NodeInfo) -> RadarParams:
    """The DSP's radar parameters from ``node_info.radar``."""
    r = info.radar
    try:
        return RadarParams(
            fs=r.fs,
            n=r.n,
            t0=r.t0,
            f_low=r.f_low,
            f_high=r.f_high,
            fc=float(r.fc or 0.0),
            rate=float(r.rate),
        )
    except ValueError as exc:
        raise NodeConfigError(f"node {info.src}: {exc}") from None


def _world(pose: tuple[float, ...], pos: tuple[float, ...]) -> np.ndarray:
    """A node-frame position (x forward, y left, z up) in the world frame."""
    x, y, z, yaw = pose
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([x + c * pos[0] - s * pos[1], y + s * pos[0] + c * pos[1], z + pos[2]])


def sensor_geometry(
    info: NodeInfo,
    tx: str,
    rx: tuple[str, ...],
    peers: Mapping[str, NodeInfo],
    pose: tuple[float, float, float, float] | None = None,
) -> SensorGeometry:
    """World geometry of one acquisition: transmitter ``tx`` ("{node}/{antenna}", this node's
    or a peer's), receivers ``rx`` of this node in row order, field of view of the receivers.

    ``pose`` overrides the node's published pose (mobile nodes carry it in ``ir.pose``).
    """
    node_pose = pose if pose is not None else info.pose
    tx_node, _, tx_ant = tx.partition("/")
    if tx_node == info.src:
        tx_info, tx_pose = info, node_pose
    elif tx_node in peers:
        tx_info = peers[tx_node]
        tx_pose = tx_info.pose
    else:
        raise NodeConfigError(f"transmitter {tx!r}: no node_info for node {tx_node!r}")
    ant = tx_info.antennas.get(tx_ant)
    if ant is None or not ant.tx:
        raise NodeConfigError(f"transmitter {tx!r}: node {tx_node!r} has no such tx antenna")
    rx_ants = []
    for name in rx:
        a = info.antennas.get(name)
        if a is None or not a.rx:
            raise NodeConfigError(f"node {info.src}: no receiving antenna {name!r}")
        rx_ants.append(a)
    # The field of view is the receivers' beam: mean boresight (on the circle), narrowest width.
    bs = np.array([a.boresight for a in rx_ants])
    boresight = float(node_pose[3] + np.arctan2(np.sin(bs).mean(), np.cos(bs).mean()))
    return SensorGeometry(
        tx=_world(tx_pose, ant.pos),
        rx=np.stack([_world(node_pose, a.pos) for a in rx_ants]),
        rx_names=tuple(rx),
        boresight=boresight,
        beamwidth=float(min(a.beamwidth for a in rx_ants)),
    )


class NodeCore:
    """Runs the DSP chain for one receiving node, one :class:`NodeDsp` per (tx, rx set).

    Parameters
    ----------
    info : this node's description.
    config : DSP configuration (defaults if None).
    peers : other nodes' descriptions, for multistatic transmitters.
    """

    def __init__(
        self,
        info: NodeInfo,
        config: NodeDspConfig | None = None,
        peers: Mapping[str, NodeInfo] | None = None,
    ) -> None:
        self.info = info
        self.config = config or NodeDspConfig()
        self.peers: dict[str, NodeInfo] = dict(peers or {})
        self.radar = radar_params(info)
        self._dsp: dict[tuple[str, tuple[str, ...]], NodeDsp] = {}
        # compile the DSP's numba kernels (or load them from numba's cache) now, not in the
        # time slot of the first acquisition
        from node_agent.dsp import kernels  # noqa: F401

    def update_info(self, info: NodeInfo) -> None:
        """Take a changed description of this node (new pose, antennas): DSP state restarts."""
        self.info = info
        self.radar = radar_params(info)
        self._dsp.clear()

    def process(self, ir: Ir) -> DspResult:
        """Run background subtraction, CFAR, range PHD, association and ellipse intersection.

        Raises
        ------
        NodeConfigError
            When the acquisition does not fit the node's description.
        """
        if ir.h.shape[1] != self.radar.n:
            raise NodeConfigError(
                f"node {self.info.src}: ir has {ir.h.shape[1]} samples, node_info says "
                f"{self.radar.n}"
            )
        key = (ir.tx, ir.rx)
        dsp = self._dsp.get(key)
        moving = self.info.mobile and ir.pose is not None
        if dsp is None:
            geometry = sensor_geometry(self.info, ir.tx, ir.rx, self.peers, ir.pose)
            dsp = NodeDsp(geometry, self.radar, self.config)
            self._dsp[key] = dsp
            return dsp.process(ir.t, ir.h)
        if moving:
            geometry = sensor_geometry(self.info, ir.tx, ir.rx, self.peers, ir.pose)
            return dsp.process(ir.t, ir.h, geometry=geometry)
        return dsp.process(ir.t, ir.h)

    def geometry(self, ir: Ir) -> SensorGeometry:
        """The geometry used for ``ir``'s link."""
        return sensor_geometry(self.info, ir.tx, ir.rx, self.peers, ir.pose)


def detections_message(ir: Ir, result: DspResult, *, src: str, seq: int) -> Detections:
    """The ``detections`` message of one processed acquisition."""
    ranges = {name: tuple(map(float, r)) for name, r in zip(ir.rx, result.ranges, strict=True)}
    amps = {name: tuple(map(float, a)) for name, a in zip(ir.rx, result.amplitudes, strict=True)}
    positions = np.asarray(result.positions, dtype=np.float64).reshape(-1, 2)
    cov = np.asarray(result.cov, dtype=np.float64).reshape(-1, 2, 2)
    return Detections(
        src=src,
        seq=seq,
        t=ir.t,
        tx=ir.tx,
        frame=ir.frame,
        ranges=ranges,
        amplitudes=amps,
        positions=positions,
        cov=cov,
    )
