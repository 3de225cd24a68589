"""``uwbnet sim``: simulate a scenario into a recording, as fast as the machine allows."""

from __future__ import annotations

import os
from collections.abc import Callable

from node_agent.tdma import SlotTiming
from protocol import Ir, NodeInfo, Slot, Target, TdmaSchedule, Truth, keys
from protocol.recording import RecordingWriter
from sim_nodes.driver import SimulatedDriver
from sim_nodes.network import SimNetwork
from sim_nodes.scene import Scenario

SIM_SRC = "sim"


def truth_message(network: SimNetwork, t: float, seq: int) -> Truth:
    """The ``truth`` message of the scene at scenario time ``t``."""
    targets = tuple(
        Target(id=int(p["id"]), x=p["x"], y=p["y"], vx=p["vx"], vy=p["vy"])
        for p in network.truth(t)
    )
    return Truth(src=SIM_SRC, seq=seq, t=t, targets=targets, nodes={})


def schedule_message(network: SimNetwork, frame_period: float, seq: int = 0) -> TdmaSchedule:
    """The TDMA schedule of the scenario's nodes, epoch 0."""
    slots = tuple(Slot(**s) for s in network.schedule())
    return TdmaSchedule(
        src="fusion", seq=seq, t=0.0, frame_period=frame_period, epoch=0.0, slots=slots
    )


def simulate_to_mcap(
    scenario: Scenario,
    out: str | os.PathLike[str],
    *,
    duration: float,
    seed: int,
    net: str = "demo",
    progress: Callable[[float], None] | None = None,
) -> int:
    """Simulate ``duration`` s of ``scenario`` into the MCAP file ``out``.

    Writes every node's ``node_info`` and the TDMA schedule at t = 0, then per TDMA frame the
    ``ir`` of every node in its slot and one ``truth`` message. Returns the messages written.
    A ranging scenario (``[[mobiles]]`` only) goes to
    :func:`sim_nodes.ranging_record.simulate_ranging_to_mcap`.
    The file appears only when complete.
    """
    if scenario.mobiles and not scenario.nodes:
        from sim_nodes.ranging_record import simulate_ranging_to_mcap

        return simulate_ranging_to_mcap(
            scenario, out, duration=duration, seed=seed, net=net, progress=progress
        )
    if scenario.circle_scan is not None:
        from sim_nodes.circle_record import simulate_circle_scan

        return simulate_circle_scan(scenario, out, seed=seed, net=net, progress=progress)
    network = SimNetwork(scenario, seed)
    frame_period = float(scenario.frame_period)
    sched = schedule_message(network, frame_period)
    drivers = {node: SimulatedDriver(network, node) for node in network.node_infos()}
    slot_of = {s.tx.partition("/")[0]: s for s in sched.slots}
    with RecordingWriter(out) as rec:
        for node, drv in drivers.items():
            info = NodeInfo(src=node, seq=0, t=0.0, **drv.describe())
            rec.write_message(keys.node_key(net, node, "info"), info)
        rec.write_message(keys.schedule_key(net), sched)
        n_frames = round(duration / frame_period)
        seq = 0
        for frame in range(n_frames):
            t_frame = frame * frame_period
            for node, drv in drivers.items():
                slot = slot_of.get(node)
                if slot is None:
                    continue
                timing = SlotTiming(
                    frame=frame,
                    slot=slot.slot,
                    tx=slot.tx,
                    t=t_frame + slot.start,
                    duration=slot.duration,
                )
                acq = drv.acquire(timing)
                ir = Ir(
                    src=node,
                    seq=frame,
                    t=acq.t,
                    tx=acq.tx,
                    rx=acq.rx,
                    slot=slot.slot,
                    frame=frame,
                    h=acq.h,
                )
                rec.write_message(keys.node_key(net, node, "ir"), ir)
            rec.write_message(keys.truth_key(net), truth_message(network, t_frame, seq))
            seq += 1
            if progress is not None:
                progress(frame_period)
        for drv in drivers.values():
            drv.close()
        return rec.count
