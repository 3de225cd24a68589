"""``uwbnet bench scale``: the per-acquisition CPU costs behind the capacity model.

For generated buildings (:func:`sim_nodes.building.building_scenario`, one person per ten
sensors) it measures, in CPU seconds of this single-threaded process (independent of what else
the machine runs):

* ``sim_us_per_ir``: simulating one acquisition (people beyond 20 m left out, as in
  ``uwbnet scale``); ``sim_batch8_us_per_ir``: the same acquisitions simulated 8 adjacent
  slots at a time (``SimNetwork.acquire_many``, as a ``uwbnet scale`` node process does);
* ``dsp_us_per_ir``: the node DSP chain on it, plus encoding the ``detections`` message;
* ``fusion_us_per_scan``: decoding a ``detections`` message and frame assembly + GM-PHD
  update, per scan, with one fusion center and with the scans split over 4 cell workers
  (each fusing its cell plus the 6 m margin, so overlapping sensors are fused twice);
* ``merge_us_per_update``: the gateway's hand-over merge per worker update;
* ``cells4_vs_one``: tracking figures of one fusion center and of 4 cell workers + gateway on
  the same detections, with ID switches per 100 cell-border crossings (:func:`handover`).

docs/capacity.md turns these into the number of nodes a given number of cores sustains.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np


def _cpu(fn: Any) -> float:
    c0 = time.process_time()
    fn()
    return time.process_time() - c0


#: Acquisitions per batch of ``sim_batch8_us_per_ir``: ``uwbnet scale``'s nodes per process.
BATCH = 8


def _one_size(n: int, frames: int, seed: int) -> dict[str, Any]:
    """The figures of one building of ``n`` nodes (``frames`` TDMA frames, 20 for warm-up)."""
    from fusion_center.core import FusionCore
    from fusion_center.offline import make_tracker
    from fusion_center.tracking.cells import HandoverMerger, StripCells, nodes_of_cells
    from node_agent.core import NodeCore, detections_message
    from protocol import Detections, Ir, NodeInfo
    from sim_nodes.building import building_length, building_scenario
    from sim_nodes.driver import SimulatedDriver
    from sim_nodes.network import SimNetwork
    from uwbnet.scale_roles import CELL_MARGIN, PEOPLE_RANGE

    warm = 20  # frames for the DSP's background and the trackers to settle
    people = max(1, n // 10)
    scen = building_scenario(n, people, seed)
    net = SimNetwork(scen, seed, people_range=PEOPLE_RANGE)
    ids = net.node_ids
    infos = {}
    for node in ids:
        with SimulatedDriver(net, node) as drv:
            infos[node] = NodeInfo(src=node, seq=0, t=0.0, **drv.describe())
    cores = {node: NodeCore(infos[node]) for node in ids}
    period = scen.frame_period
    raw: list[list[Ir]] = []
    # One untimed acquisition: the first call loads the compiled people-echo kernel from
    # numba's cache (about 0.5 s), a start-up cost, not a per-acquisition one.
    SimNetwork(scen, seed, people_range=PEOPLE_RANGE).acquire(ids[0], 1.0)

    def simulate() -> None:
        for f in range(frames):
            row = []
            for s, node in enumerate(ids):
                t = 2.0 + f * period + s * period / n
                tx, rx, h = net.acquire(node, t)
                row.append(Ir(src=node, seq=f, t=t, tx=tx, rx=rx, slot=s, frame=f, h=h))
            raw.append(row)

    sim_cpu = _cpu(simulate)
    batched = SimNetwork(scen, seed, people_range=PEOPLE_RANGE)

    def simulate_batched() -> None:
        # as a uwbnet scale node process serves them: 8 adjacent slots in one batch
        for f in range(frames):
            for s0 in range(0, n, BATCH):
                batched.acquire_many(
                    [
                        (node, 2.0 + f * period + (s0 + k) * period / n)
                        for k, node in enumerate(ids[s0 : s0 + BATCH])
                    ]
                )

    sim_batch_cpu = _cpu(simulate_batched)
    wires: list[list[bytes]] = []
    dsp_cpu = 0.0
    for f, row in enumerate(raw):
        c0 = time.process_time()
        wires.append(
            [
                detections_message(ir, cores[ir.src].process(ir), src=ir.src, seq=f).to_wire()
                for ir in row
            ]
        )
        if f >= warm:
            dsp_cpu += time.process_time() - c0
    measured = (frames - warm) * n

    def fuse(members: list[tuple[str, ...]]) -> tuple[float, list[list[Any]]]:
        fusions = [FusionCore(make_tracker("gmphd")) for _ in members]
        outs: list[list[Any]] = [[] for _ in members]
        for core, m in zip(fusions, members, strict=True):
            for node in m:
                core.add_node(infos[node])
            core.expected = frozenset(m)
        sets = [set(m) for m in members]
        cpu = 0.0
        for f, row in enumerate(wires):
            c0 = time.process_time()
            for payload in row:
                det = Detections.from_wire(payload)
                for k, core in enumerate(fusions):
                    if det.src in sets[k]:
                        outs[k] += core.add_detections(det)
            if f >= warm:
                cpu += time.process_time() - c0
        return cpu, outs

    one_cpu, _ = fuse([tuple(ids)])
    cells = StripCells.even(0.0, building_length(n), 4)
    xy = {nd.id: nd.pose[:2] for nd in scen.nodes}
    members = list(nodes_of_cells(cells, xy, CELL_MARGIN))
    four_cpu, outs = fuse(members)
    merger = HandoverMerger(cells)
    updates = sorted(((o.t, k, o) for k, os_ in enumerate(outs) for o in os_), key=lambda x: x[:2])
    merge_cpu = _cpu(lambda: [merger.update(k, o) for _, k, o in updates])
    return {
        "people": people,
        "sim_us_per_ir": round(1e6 * sim_cpu / (frames * n), 1),
        "sim_batch8_us_per_ir": round(1e6 * sim_batch_cpu / (frames * n), 1),
        "dsp_us_per_ir": round(1e6 * dsp_cpu / measured, 1),
        "fusion_us_per_scan": round(1e6 * one_cpu / measured, 1),
        "fusion4_us_per_scan": round(1e6 * four_cpu / measured, 1),
        "fusion4_scans_per_scan": round(sum(len(m) for m in members) / n, 2),
        "merge_us_per_update": round(1e6 * merge_cpu / max(len(updates), 1), 1),
    }


def run(
    sizes: tuple[int, ...] = (12, 48, 100),
    frames: int = 60,
    seed: int = 1,
    with_handover: bool = True,
) -> dict[str, Any]:
    """The figures of every size, and their means (sim, DSP) and maximum (fusion)."""
    out = {str(n): _one_size(n, frames, seed) for n in sizes}
    cells = handover(seed=seed) if with_handover else None
    costs = np.array(
        [[v["sim_us_per_ir"], v["dsp_us_per_ir"], v["fusion_us_per_scan"]] for v in out.values()]
    )
    return {
        "sizes": out,
        "sim_us_per_ir": round(float(costs[:, 0].mean()), 1),
        "dsp_us_per_ir": round(float(costs[:, 1].mean()), 1),
        "fusion_us_per_scan_max": round(float(costs[:, 2].max()), 1),
        "cells4_vs_one": cells,
    }


def handover(
    n: int = 24, people: int = 6, seconds: float = 40.0, seed: int = 1, walls: bool = True
) -> dict[str, Any]:
    """One fusion center vs 4 cell workers + gateway on identical detections.

    Simulates ``seconds`` of a building of ``n`` nodes (no network: the node DSP's messages go
    straight to both fusion set-ups), and scores both track outputs against the truth with
    :func:`fusion_center.tracking.metrics.evaluate`; ``border_crossings`` counts the people's
    crossings of the 3 cell borders, so ``id_switches_cells`` per 100 crossings is an upper
    bound of the hand-over's ID switches (it includes the switches a single center makes too).
    ``walls``: the trackers know the building's walls (:func:`uwbnet.scale_roles.wall_sight`),
    as in ``uwbnet scale``.
    """
    from fusion_center.core import FusionCore
    from fusion_center.offline import make_tracker
    from fusion_center.tracking.cells import (
        HandoverMerger,
        StripCells,
        border_crossings,
        nodes_of_cells,
    )
    from fusion_center.tracking.metrics import evaluate
    from node_agent.core import NodeCore, detections_message
    from protocol import Detections, Ir, NodeInfo
    from sim_nodes.building import building_length, building_scenario
    from sim_nodes.driver import SimulatedDriver
    from sim_nodes.network import SimNetwork
    from uwbnet.scale_roles import CELL_MARGIN, PEOPLE_RANGE, wall_sight

    scen = building_scenario(n, people, seed)
    net = SimNetwork(scen, seed, people_range=PEOPLE_RANGE)
    ids = net.node_ids
    infos = {}
    for node in ids:
        with SimulatedDriver(net, node) as drv:
            infos[node] = NodeInfo(src=node, seq=0, t=0.0, **drv.describe())
    cores = {node: NodeCore(infos[node]) for node in ids}
    cells = StripCells.even(0.0, building_length(n), 4)
    members = nodes_of_cells(cells, {nd.id: nd.pose[:2] for nd in scen.nodes}, CELL_MARGIN)
    one = FusionCore(make_tracker("gmphd"))
    workers = [FusionCore(make_tracker("gmphd")) for _ in members]
    for node in ids:
        one.add_node(infos[node])
    for core, m in zip(workers, members, strict=True):
        for node in m:
            core.add_node(infos[node])
        core.expected = frozenset(m)
    one.expected = frozenset(ids)
    if walls:
        for core in (one, *workers):
            core.tracker.sight = wall_sight(scen)  # type: ignore[attr-defined]
    merger = HandoverMerger(cells)
    tracks_one: list[Any] = []
    tracks_cells: list[Any] = []
    truth: list[Any] = []
    period = scen.frame_period
    for f in range(round(seconds / period)):
        for s, node in enumerate(ids):
            t = f * period + s * period / n
            tx, rx, h = net.acquire(node, t)
            ir = Ir(src=node, seq=f, t=t, tx=tx, rx=rx, slot=s, frame=f, h=h)
            det = Detections.from_wire(
                detections_message(ir, cores[node].process(ir), src=node, seq=f).to_wire()
            )
            for o in one.add_detections(det):
                tracks_one.append((o.t, o.ids(), o.positions()))
            for k, core in enumerate(workers):
                if node in members[k]:
                    for o in core.add_detections(det):
                        m = merger.update(k, o)
                        tracks_cells.append((m.t, m.ids(), m.positions()))
        people_now = net.truth(f * period)
        truth.append(
            (
                f * period,
                np.array([p["id"] for p in people_now], dtype=np.int64),
                np.array([(p["x"], p["y"]) for p in people_now]).reshape(-1, 2),
            )
        )
    crossings = border_crossings(cells, truth)
    e1 = evaluate(truth, tracks_one, c=1.0, skip=3.0)
    e4 = evaluate(truth, tracks_cells, c=1.0, skip=3.0)
    return {
        "nodes": n,
        "people": people,
        "seconds": seconds,
        "border_crossings": crossings,
        "ospa_one": round(float(e1["ospa_p2_mean"]), 4),
        "ospa_cells": round(float(e4["ospa_p2_mean"]), 4),
        "card_correct_one": round(float(e1["card_correct_fraction"]), 4),
        "card_correct_cells": round(float(e4["card_correct_fraction"]), 4),
        "rmse_one": round(float(e1["rmse_mean"]), 4),
        "rmse_cells": round(float(e4["rmse_mean"]), 4),
        "id_switches_one": e1["id_switches"],
        "id_switches_cells": e4["id_switches"],
        "id_switches_cells_per_100_crossings": round(
            100.0 * e4["id_switches"] / max(crossings, 1), 2
        ),
        "handovers": merger.handovers,
        "walls": walls,
    }
