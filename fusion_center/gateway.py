"""The gateway of a sharded fusion center: cell workers' tracks in, one track list out.

Subscribes to ``uwbnet/{net}/fusion/cell/*/tracks`` (each cell worker is a
:class:`~fusion_center.service.FusionService` fusing the nodes of its cell plus a margin), merges
them with :class:`~fusion_center.tracking.cells.HandoverMerger` (global IDs kept across cell
borders) and publishes the result on ``uwbnet/{net}/fusion/tracks``, as a single fusion center
would, keeping the optional ``t_acq`` field (acquisition times) of the triggering update.
Callbacks only enqueue; one worker thread merges and publishes.
"""

from __future__ import annotations

import logging
import threading
from typing import Any

import numpy as np
import zenoh

from fusion_center.service import tracks_message
from fusion_center.tracking.base import TrackerOutput, TrackEstimate
from fusion_center.tracking.cells import HandoverMerger, StripCells
from protocol import ProtocolError, Tracks, keys
from protocol.transport import FifoChannel, stop_worker

log = logging.getLogger(__name__)


def tracks_output(msg: Tracks) -> TrackerOutput:
    """A ``tracks`` message as a :class:`TrackerOutput` (``acquired`` from ``t_acq``)."""
    acquired = msg.extra.get("t_acq", ())
    if not isinstance(acquired, list | tuple) or not all(
        isinstance(v, float | int) for v in acquired
    ):
        raise ProtocolError(f"tracks from {msg.src}: t_acq is not a list of numbers")
    return TrackerOutput(
        t=msg.t,
        tracks=tuple(
            TrackEstimate(
                id=tr.id, x=tr.x, vx=tr.vx, y=tr.y, vy=tr.vy, cov=np.asarray(tr.cov), w=tr.w
            )
            for tr in msg.tracks
        ),
        n_estimate=msg.n_estimate,
        acquired=tuple(float(v) for v in acquired),
    )


class CellGateway:
    """Merges the cell workers' tracks of network ``net`` on an open zenoh ``session``.

    ``start``/``stop`` are idempotent; counters: ``merged``, ``rejected``.
    """

    def __init__(
        self, session: zenoh.Session, net: str, cells: StripCells, *, service_id: str = "gateway"
    ) -> None:
        self.session, self.net, self.service_id = session, net, service_id
        self.merger = HandoverMerger(cells)
        self._inbox: FifoChannel[tuple[str, bytes]] = FifoChannel(8192)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._decl: list[Any] = []
        self._seq = 0
        self.merged = 0
        self.rejected = 0

    def start(self) -> None:
        if self._thread is not None:
            return
        s = self.session
        self._pub = s.declare_publisher(
            keys.fusion_key(self.net, "tracks"), congestion_control=zenoh.CongestionControl.BLOCK
        )
        self._decl.append(self._pub)
        put = self._inbox.put
        self._decl.append(
            s.declare_subscriber(
                keys.all_cell_tracks_key(self.net),
                lambda sample: put((str(sample.key_expr), sample.payload.to_bytes())),
            )
        )
        self._thread = threading.Thread(target=self._run, name="gateway", daemon=True)
        self._thread.start()
        log.info("fusion gateway on net %s: %d cells", self.net, self.merger.cells.count)

    def stop(self) -> None:
        stop_worker(self._stop, self._thread, self._decl)
        self._thread = None

    def _run(self) -> None:
        while not self._stop.is_set():
            item = self._inbox.get(timeout=0.1)
            if item is None:
                continue
            key, payload = item
            try:
                cell = int(key.split("/")[-2])
                out = tracks_output(Tracks.from_wire(payload))
            except (ProtocolError, ValueError) as exc:
                self.rejected += 1
                log.warning("rejected %s: %s", key, exc)
                continue
            merged = self.merger.update(cell, out)
            self._pub.put(tracks_message(merged, src=self.service_id, seq=self._seq).to_wire())
            self._seq += 1
            self.merged += 1
