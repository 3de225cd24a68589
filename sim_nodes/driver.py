"""A node agent radar driver backed by the simulation (``node_agent.drivers`` name ``sim``)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from node_agent.drivers.base import Acquisition, RadarDriver
from node_agent.tdma import SlotTiming
from protocol import Antenna, RadarInfo
from sim_nodes.network import SimNetwork


class SimulatedDriver(RadarDriver):
    """Acquires impulse responses of one simulated node.

    Parameters
    ----------
    network : the simulated scene, shared by every simulated node of a process (or rebuilt from
        the same scenario and seed in each process: people move deterministically in time).
    node : node id in the scenario.
    start : network time (s) of scenario time 0.
    """

    def __init__(self, network: SimNetwork, node: str, *, start: float = 0.0) -> None:
        infos = network.node_infos()
        if node not in infos:
            raise ValueError(f"node {node!r} is not in the scenario ({', '.join(sorted(infos))})")
        self.network, self.node, self.start = network, node, start
        self._info = infos[node]
        # the acquisition of the next slot, simulated ahead with others (acquire_ahead)
        self._ahead: Acquisition | None = None
        self.simulated_alone = 0  # acquisitions not prepared with a batch (acquire_ahead)
        n_rx = sum(1 for a in self._info["antennas"].values() if a["rx"])
        super().__init__(n_rx=n_rx, n=int(self._info["radar"]["n"]))

    def describe(self) -> dict[str, Any]:

        info = self._info
        return {
            "role": info["role"],
            "pose": tuple(info["pose"]),
            "mobile": bool(info["mobile"]),
            "antennas": {name: Antenna(**a) for name, a in info["antennas"].items()},
            "radar": RadarInfo(**info["radar"]),
        }

    @classmethod
    def acquire_ahead(cls, batch: Sequence[tuple[RadarDriver, SlotTiming]]) -> None:
        """Simulate the acquisitions of ``batch`` together (:meth:`SimNetwork.acquire_many`,
        per network, in the batch's order); each driver's next :meth:`acquire` of its slot
        returns its impulse responses, bit for bit what it would have simulated itself.

        A driver whose prepared acquisition is not taken (a new schedule moved its slot)
        discards it at its next acquisition: its generator has then drawn one acquisition's
        noise more than without the batch."""
        by_network: dict[int, list[tuple[SimulatedDriver, SlotTiming]]] = {}
        for driver, slot in batch:
            if isinstance(driver, SimulatedDriver):
                by_network.setdefault(id(driver.network), []).append((driver, slot))
        for items in by_network.values():
            network = items[0][0].network
            out = network.acquire_many([(d.node, slot.t - d.start) for d, slot in items])
            for (driver, slot), (tx, rx, h) in zip(items, out, strict=True):
                driver._ahead = Acquisition(t=slot.t, tx=tx, rx=tuple(rx), h=h)

    def _acquire_internal(self, slot: SlotTiming) -> Acquisition:
        ahead, self._ahead = self._ahead, None
        if ahead is not None and ahead.t == slot.t:
            return ahead
        self.simulated_alone += 1
        tx, rx, h = self.network.acquire(self.node, slot.t - self.start)
        return Acquisition(t=slot.t, tx=tx, rx=tuple(rx), h=h)
