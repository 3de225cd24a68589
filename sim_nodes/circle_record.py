"""``uwbnet sim`` for ``[circle_scan]`` scenarios: one object, one polarimetric scan, to MCAP.

The recording holds the sensor's ``node_info`` (role ``bat``, mobile; antennas ``tx_v``,
``tx_h``, ``tx_p`` and ``rx_v``, ``rx_h``, ``rx_p``, ``rx_m``, each with the optional field
``pol``: the E-field's tilt from vertical in the antenna plane, rad: 0 V, pi/2 H, +-pi/4 the
45-degree pair), then per scan position three ``ir`` messages (frame = position index):

======  ===============  ===================  ===========================
slot    ``tx``           ``rx`` (rows)        channels
======  ===============  ===================  ===========================
0       ``{id}/tx_v``    ``rx_v, rx_h``       VV, HV (co, cross)
1       ``{id}/tx_h``    ``rx_h, rx_v``       HH, VH
2       ``{id}/tx_p``    ``rx_p, rx_m``       45-degree co- and cross-polar
======  ===============  ===================  ===========================

each with ``pose`` (the sensor pose ``[x, y, z, yaw]``, yaw toward the track centre), and one
``truth`` message per position whose optional field ``object`` describes the target
(``vertices`` [[x, y], ...], ``permittivity``, ``metal``, ``roughness``) for evaluation.
"""

from __future__ import annotations

import os
from collections.abc import Callable

import numpy as np

from protocol import Ir, NodeInfo, Target, Truth, keys
from protocol.recording import RecordingWriter
from sim_nodes.channel.prism import PrismTarget
from sim_nodes.circle_scan import CircleTrack, scan_echoes, scan_impulse_responses
from sim_nodes.radar import MSequenceRadar
from sim_nodes.scene import Scenario

#: (slot, tx antenna, rx antennas, channels) of each acquisition at a scan position.
ACQUISITIONS = (
    (0, "tx_v", ("rx_v", "rx_h"), ("vv", "hv")),
    (1, "tx_h", ("rx_h", "rx_v"), ("hh", "vh")),
    (2, "tx_p", ("rx_p", "rx_m"), ("pp", "pm")),
)
_POL = {"v": 0.0, "h": np.pi / 2, "p": np.pi / 4, "m": -np.pi / 4}


def scan_target(scenario: Scenario, seed: int) -> PrismTarget:
    """The scenario's object as a :class:`PrismTarget` (polygon without the closing vertex)."""
    cs = scenario.circle_scan
    if cs is None:
        raise ValueError(f"{scenario.name}: not a [circle_scan] scenario")
    mat = scenario.materials[cs.material]
    return PrismTarget(
        vertices=np.asarray(cs.target[:-1], float),
        permittivity=mat.permittivity,
        conductivity=mat.conductivity,
        metal=mat.metal,
        roughness=cs.roughness,
        seed=seed,
    )


def scan_track(scenario: Scenario) -> CircleTrack:
    """The scenario's sensor track."""
    cs = scenario.circle_scan
    if cs is None:
        raise ValueError(f"{scenario.name}: not a [circle_scan] scenario")
    return CircleTrack(
        centre=(cs.centre[0], cs.centre[1]),
        radius=cs.radius,
        start=cs.start,
        span=cs.span,
        step=cs.step,
        baseline=cs.baseline,
        height=cs.height,
    )


def scan_node_info(scenario: Scenario, pose: list[float]) -> NodeInfo:
    """``node_info`` of the scanning sensor (antenna positions in its frame: x forward)."""
    cs = scenario.circle_scan
    assert cs is not None
    b = cs.baseline / 2
    antennas = {}
    for name in ("tx_v", "tx_h", "tx_p", "rx_v", "rx_h", "rx_p", "rx_m"):
        is_tx = name.startswith("tx")
        # The transmitter is ahead on the counter-clockwise track: +y in the sensor frame
        # (x points to the centre), the receiver at -y.
        antennas[name] = {
            "pos": [0.0, -b if is_tx else b, 0.0],
            "tx": is_tx,
            "rx": not is_tx,
            "boresight": 0.0,
            "beamwidth": cs.beamwidth,
            "extra": {"pol": _POL[name[-1]]},
        }
    r = scenario.radar
    from protocol.messages import Antenna, RadarInfo

    return NodeInfo(
        src=cs.id,
        seq=0,
        t=0.0,
        role="bat",
        pose=tuple(pose),
        mobile=True,
        antennas={k: Antenna(**v) for k, v in antennas.items()},
        radar=RadarInfo(fs=r.fs, n=r.n, t0=r.t0, f_low=r.f_low, f_high=r.f_high, rate=r.rate),
    )


def simulate_circle_scan(
    scenario: Scenario,
    out: str | os.PathLike[str],
    *,
    seed: int,
    net: str = "demo",
    progress: Callable[[float], None] | None = None,
) -> int:
    """Simulate the scenario's circular scan into ``out`` (MCAP); returns messages written.

    One scan position per TDMA frame (``frame_period``); the recording's duration is the
    scan's. The file appears only when complete.
    """
    cs = scenario.circle_scan
    if cs is None:
        raise ValueError(f"{scenario.name}: not a [circle_scan] scenario")
    target = scan_target(scenario, seed)
    track = scan_track(scenario)
    radar = MSequenceRadar(scenario.radar.config())
    rng = np.random.default_rng(seed)
    poses = track.poses()
    echoes = scan_echoes(target, track, cs.beamwidth)
    channels = tuple(ch for _, _, _, chs in ACQUISITIONS for ch in chs)
    period = float(scenario.frame_period)
    obj = {
        "vertices": target.vertices.tolist(),
        "permittivity": target.permittivity,
        "metal": target.metal,
        "roughness": target.roughness,
    }
    centroid = target.vertices.mean(axis=0)
    batch = 30
    with RecordingWriter(out) as rec:
        info = scan_node_info(scenario, poses[0].tolist())
        rec.write_message(keys.node_key(net, cs.id, "info"), info)
        for lo in range(0, len(poses), batch):
            sl = slice(lo, lo + batch)
            sub = type(echoes)(
                length=echoes.length[sl],
                scattering=echoes.scattering[sl],
                point=echoes.point[sl],
                kind=echoes.kind,
            )
            h = scan_impulse_responses(sub, radar, channels, rng)  # (B, 6, n)
            for b, pose in enumerate(poses[sl]):
                k = lo + b
                t = k * period
                for slot, tx, rx, chs in ACQUISITIONS:
                    rows = [channels.index(c) for c in chs]
                    ir = Ir(
                        src=cs.id,
                        seq=3 * k + slot,
                        t=t + slot * period / 3,
                        tx=f"{cs.id}/{tx}",
                        rx=rx,
                        slot=slot,
                        frame=k,
                        h=np.ascontiguousarray(h[b, rows]),
                        pose=tuple(float(x) for x in pose),
                    )
                    rec.write_message(keys.node_key(net, cs.id, "ir"), ir)
                truth = Truth(
                    src="sim",
                    seq=k,
                    t=t,
                    targets=(
                        Target(id=0, x=float(centroid[0]), y=float(centroid[1]), vx=0.0, vy=0.0),
                    ),
                    nodes={cs.id: tuple(float(x) for x in pose)},
                    extra={"object": obj},
                )
                rec.write_message(keys.truth_key(net), truth)
                if progress is not None:
                    progress(period)
        return rec.count
