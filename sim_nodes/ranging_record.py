"""``uwbnet sim`` of a ranging scenario (``[[mobiles]]``, ``[[anchors]]``, ``[ranging]``).

Writes every node's ``node_info`` at t = 0, then per ranging round of each mobile node the
``detections`` its node agent publishes (``links``: one RTToA range per anchor, measured by
:class:`~node_agent.dsp.rttoa.RoundTripRanger` on the simulated exchange) and one ``truth``
message with the node's true pose and, as the optional field ``links``, the truth of every
link: LOS or not, true distance, and the direct path's E/N0 (dB) and RMS bandwidth (Hz) for
the Cramér-Rao bound (docs/localization.md).
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Iterator

from node_agent.dsp.rttoa import RoundTripRanger
from protocol import Antenna, Detections, LinkRange, Message, NodeInfo, RadarInfo, Truth, keys
from protocol.recording import RecordingWriter
from sim_nodes.network import scenario_walls
from sim_nodes.ranging import RangingSimulator, track_position
from sim_nodes.scene import Scenario

SIM_SRC = "sim"
ANTENNA = "ant"


def _info(sim: RangingSimulator, node: str, pose: list[float], mobile: bool) -> NodeInfo:
    cfg = sim.config
    return NodeInfo(
        src=node,
        seq=0,
        t=0.0,
        role="robot" if mobile else "anchor",
        pose=tuple(pose),
        mobile=mobile,
        antennas={
            ANTENNA: Antenna(
                pos=(0.0, 0.0, 0.0), tx=True, rx=True, boresight=0.0, beamwidth=2 * math.pi
            )
        },
        radar=RadarInfo(
            fs=cfg.fs,
            n=cfg.n,
            t0=0.0,
            f_low=cfg.f_low,
            f_high=cfg.f_high,
            rate=cfg.rate,
            fc=cfg.fc if cfg.fc > 0 else None,
        ),
    )


def ranging_messages(
    scenario: Scenario, *, duration: float, seed: int, net: str = "demo"
) -> Iterator[tuple[str, Message]]:
    """``(key expression, message)`` of a simulated ranging run, in time order."""
    sim = RangingSimulator(scenario, scenario_walls(scenario), seed)
    ranger = RoundTripRanger(sim.radar, method=sim.config.method)
    for aid, pos in sim.anchors.items():
        yield keys.node_key(net, aid, "info"), _info(sim, aid, [*pos.tolist(), 0.0], False)
    for mid, mob in sim.mobiles.items():
        p, yaw, _ = track_position(mob, 0.0)
        yield keys.node_key(net, mid, "info"), _info(sim, mid, [*p.tolist(), yaw], True)
    period = 1.0 / sim.config.rate
    for k in range(round(duration / period)):
        t = k * period
        for mid, mob in sim.mobiles.items():
            links, truth = {}, {}
            for aid in sim.anchors:
                rnd = sim.round(mid, aid, t)
                m = ranger.measure(rnd.exchange)
                if math.isfinite(m.range):
                    links[aid] = LinkRange(range=m.range, std=m.std, los=m.los, snr_db=m.snr_db)
                truth[aid] = {
                    "los": rnd.link.los,
                    "distance": rnd.link.distance,
                    "ebn0_db": rnd.ebn0_db,
                    "beta": rnd.beta,
                }
            det = Detections(
                src=mid,
                seq=k,
                t=t,
                tx=f"{mid}/{ANTENNA}",
                frame=k,
                ranges={},
                amplitudes={},
                links=links,
            )
            yield keys.node_key(net, mid, "det"), det
            p, yaw, _ = track_position(mob, t)
            yield (
                keys.truth_key(net),
                Truth(
                    src=SIM_SRC,
                    seq=k,
                    t=t,
                    targets=(),
                    nodes={mid: (*p.tolist(), yaw)},
                    extra={"links": {mid: truth}},
                ),
            )


def simulate_ranging_to_mcap(
    scenario: Scenario,
    out: str | os.PathLike[str],
    *,
    duration: float,
    seed: int,
    net: str = "demo",
    progress: Callable[[float], None] | None = None,
) -> int:
    """Simulate ``duration`` s of a ranging scenario into the MCAP file ``out`` (complete or
    absent). Returns the messages written."""
    with RecordingWriter(out) as rec:
        last = 0.0
        for key, msg in ranging_messages(scenario, duration=duration, seed=seed, net=net):
            rec.write_message(key, msg)
            if progress is not None and msg.t > last:
                progress(msg.t - last)
                last = msg.t
        return rec.count
