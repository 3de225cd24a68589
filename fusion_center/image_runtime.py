"""The fusion center's live imaging, I/O-free: ``node_info``, ``poses`` and ``ir`` in,
``image`` messages out (PROTOCOL.md). The service feeds it from its own thread.

Rows of arriving ``ir`` messages wait in a buffer; :meth:`ImagingRuntime.step` migrates them
into the running :class:`~fusion_center.imaging.incremental.IncrementalImager` and returns the
``image`` message. ``ir`` that cannot be placed (unknown node, no pose yet, other sampling)
are counted and logged, never raised.
"""

from __future__ import annotations

import dataclasses
import logging

import numpy as np

from fusion_center.image_input import ImagingError, ObservationAssembler, Rows, stack_rows
from fusion_center.imaging import Grid
from fusion_center.imaging.incremental import ImagingConfig, IncrementalImager
from protocol import Image, Ir, NodeInfo, Poses

log = logging.getLogger(__name__)


@dataclasses.dataclass(frozen=True, slots=True, kw_only=True)
class LiveImagingConfig:
    """Parameters of the live image.

    Parameters
    ----------
    rate : ``image`` messages per second; 0 turns live imaging off (the default: it competes
        with tracking for the CPU).
    bounds : image extent ``(x_min, x_max, y_min, y_max)``, m; None: the nodes known at the
        first step plus ``margin``.
    nx, ny : pixels.
    z : height of the image plane, m (None: the mean antenna height of the first batch).
    max_rows : rows migrated per step at most (the oldest beyond are dropped and counted), so
        a step's cost is bounded.
    imaging : method and pre-processing.
    """

    rate: float = 0.0
    bounds: tuple[float, float, float, float] | None = None
    margin: float = 2.0
    nx: int = 200
    ny: int = 200
    z: float | None = None
    max_rows: int = 4096
    imaging: ImagingConfig = dataclasses.field(default_factory=ImagingConfig)


@dataclasses.dataclass(slots=True)
class ImagingCounters:
    ir: int = 0
    rows: int = 0
    rejected: int = 0
    dropped_rows: int = 0
    steps: int = 0


class ImagingRuntime:
    """Assembles observations and keeps the running image."""

    def __init__(self, config: LiveImagingConfig, src: str = "fusion") -> None:
        self.config = config
        self.src = src
        self.assembler = ObservationAssembler()
        self.imager: IncrementalImager | None = None
        self.counters = ImagingCounters()
        self._pending: list[Rows] = []
        self._seq = 0

    def add_info(self, info: NodeInfo) -> None:
        try:
            self.assembler.add_info(info)
        except ImagingError as exc:
            self.counters.rejected += 1
            log.warning("imaging: %s", exc)

    def add_poses(self, msg: Poses) -> None:
        self.assembler.add_poses(msg)

    def add_ir(self, ir: Ir) -> bool:
        """Buffer the rows of ``ir``; False (counted, logged) if it cannot be imaged."""
        self.counters.ir += 1
        try:
            rows = self.assembler.rows(ir)
        except ImagingError as exc:
            self.counters.rejected += 1
            log.debug("imaging: rejected ir: %s", exc)
            return False
        self._pending.append(rows)
        return True

    def _grid(self, rows: list[Rows]) -> Grid:
        c = self.config
        p = np.concatenate([np.concatenate([r.tx, r.rx]) for r in rows])
        if c.bounds is not None:
            x0, x1, y0, y1 = c.bounds
        else:
            for info in self.assembler.infos.values():
                p = np.concatenate([p, np.array([info.pose[:3]])])
            (x0, y0), (x1, y1) = p[:, :2].min(axis=0) - c.margin, p[:, :2].max(axis=0) + c.margin
        z = c.z if c.z is not None else float(p[:, 2].mean())
        return Grid.covering(float(x0), float(x1), float(y0), float(y1), c.nx, c.ny, z)

    def step(self, t: float, map_fn=None) -> Image | None:
        """Migrate the buffered rows; the ``image`` message at time ``t`` (None before any)."""
        rows, self._pending = self._pending, []
        if rows and self.assembler.sampling is not None:
            n_rows = sum(len(r.tx) for r in rows)
            while n_rows > self.config.max_rows and len(rows) > 1:
                n_rows -= len(rows[0].tx)
                self.counters.dropped_rows += len(rows.pop(0).tx)
            if self.imager is None:
                self.imager = IncrementalImager(self._grid(rows), self.config.imaging)
            self.imager.add(stack_rows(rows, self.assembler.sampling), map_fn)
            self.counters.rows += n_rows
            self.counters.steps += 1
        if self.imager is None:
            return None
        g = self.imager.grid
        msg = Image(
            src=self.src,
            seq=self._seq,
            t=t,
            x0=g.x0,
            y0=g.y0,
            dx=g.dx,
            dy=g.dy,
            method=self.config.imaging.method,
            img=self.imager.image.copy(),
        )
        self._seq += 1
        return msg
