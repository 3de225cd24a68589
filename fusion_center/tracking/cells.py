"""Sharding the fusion center over cells of the area, and merging the cells' tracks.

A large area is cut into strips along x (:class:`StripCells`). Each cell's fusion worker fuses
the sensors of its cell plus a margin, so a person near a border is tracked by both
neighbouring workers, each with its own labels. :class:`HandoverMerger` (the gateway's core)
makes one track list with network-wide IDs:

* a cell *owns* the tracks of its worker whose position lies inside the cell; only owned tracks
  are output, so a person in the overlap appears once (a person on a border whose two
  workers' estimates lie crosswise, each in the other's cell, counts as owned by both);
* while a person is in the overlap, the neighbour's (not owned) track is *linked* to the owned
  track nearest to it within ``link_gate``: it takes the same global ID;
* when the person crosses the border, ownership passes to the neighbour, whose linked track
  already carries the global ID: the ID survives the hand-over;
* a newly owned track that is not linked inherits the global ID of a track that disappeared
  within ``lost_time`` less than ``link_gate`` away (a late hand-over); else it gets a new ID;
* links are checked at every update: when a worker swaps its labels (two people passing each
  other in the overlap), two owned tracks far apart can carry the same global ID. The one
  nearest to where that ID's last output predicts it (constant velocity) keeps it; the others
  and the neighbours' tracks far from it lose their links and are linked afresh, so nobody
  vanishes from the output behind another person's ID.

This is track-to-track association by nearest neighbour with gating (Bar-Shalom, Willett &
Tian 2011, ch. 9), the simplest scheme that keeps labels across a partition; the CoLOR chapter
fuses at one center and has no sharding. Pure: no I/O, time ``t`` is an argument.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from collections.abc import Mapping, Sequence

import numpy as np
import numpy.typing as npt

from fusion_center.tracking.base import TrackerOutput, TrackEstimate

__all__ = ["HandoverMerger", "StripCells", "border_crossings", "nodes_of_cells"]


@dataclasses.dataclass(frozen=True, slots=True)
class StripCells:
    """Cells that are strips of the area along x, split at ``borders``.

    Parameters
    ----------
    borders : sequence of float
        Increasing x (m) of the borders between cells; ``len(borders) + 1`` cells, cell 0
        west of ``borders[0]``.
    """

    borders: tuple[float, ...]

    @classmethod
    def even(cls, x_min: float, x_max: float, n_cells: int) -> StripCells:
        """``n_cells`` strips of equal width between ``x_min`` and ``x_max`` (m)."""
        if n_cells < 1:
            raise ValueError(f"need at least one cell, not {n_cells}")
        width = (x_max - x_min) / n_cells
        return cls(tuple(x_min + width * k for k in range(1, n_cells)))

    @property
    def count(self) -> int:
        """Number of cells."""
        return len(self.borders) + 1

    def cell_of(self, xy: npt.ArrayLike) -> npt.NDArray[np.int64]:
        """Cell index of each point, world x, y (m), shape (n, 2) -> (n,)."""
        x = np.asarray(xy, dtype=np.float64).reshape(-1, 2)[:, 0]
        return np.searchsorted(np.asarray(self.borders), x, side="right").astype(np.int64)

    def extent(self, cell: int) -> tuple[float, float]:
        """x interval ``[lo, hi)`` of ``cell`` (m; infinite at the ends)."""
        lo = self.borders[cell - 1] if cell > 0 else -math.inf
        hi = self.borders[cell] if cell < len(self.borders) else math.inf
        return lo, hi

    def members(self, cell: int, xy: npt.ArrayLike, margin: float) -> npt.NDArray[np.bool_]:
        """Which points (shape (n, 2), m) lie in ``cell`` widened by ``margin`` m each side."""
        lo, hi = self.extent(cell)
        x = np.asarray(xy, dtype=np.float64).reshape(-1, 2)[:, 0]
        return (x >= lo - margin) & (x < hi + margin)

    def crossings(self, x0: float, x1: float) -> int:
        """Borders crossed moving from x0 to x1 (m)."""
        lo, hi = min(x0, x1), max(x0, x1)
        return sum(1 for b in self.borders if lo < b <= hi)


@dataclasses.dataclass(slots=True)
class _Global:
    gid: int
    x: float
    y: float
    last_t: float
    vx: float = 0.0
    vy: float = 0.0

    def predict(self, t: float) -> tuple[float, float]:
        """Position (m) at ``t`` (s), constant velocity from the last output."""
        return self.x + self.vx * (t - self.last_t), self.y + self.vy * (t - self.last_t)


class HandoverMerger:
    """Merges the cell workers' tracker outputs into one labelled track list.

    Parameters
    ----------
    cells : StripCells
        The partition; worker ``k`` handles cell ``k``.
    link_gate : float
        Largest distance (m) between two workers' tracks of the same person.
    lost_time : float
        How long (s) a global track that vanished can still be taken over.
    stale : float
        A worker's output older than this (s) behind the newest is left out (a dead worker).
    """

    def __init__(
        self,
        cells: StripCells,
        *,
        link_gate: float = 1.0,
        lost_time: float = 1.0,
        stale: float = 0.5,
    ) -> None:
        self.cells = cells
        self.link_gate = link_gate
        self.lost_time = lost_time
        self.stale = stale
        self._latest: dict[int, TrackerOutput] = {}
        self._map: dict[tuple[int, int], int] = {}
        self._seen: dict[tuple[int, int], float] = {}
        self._globals: dict[int, _Global] = {}
        self._next_id = 1
        #: Hand-overs done: owned tracks that took a global ID from another worker's track.
        self.handovers = 0

    def update(self, cell: int, output: TrackerOutput) -> TrackerOutput:
        """Take worker ``cell``'s newest output; return the merged estimate.

        Returns
        -------
        TrackerOutput
            At the newest time of the workers' outputs; tracks sorted by global ID;
            ``acquired`` is that of ``output`` (the update that triggered this merge).
        """
        self._latest[cell] = output
        t = max(o.t for o in self._latest.values())
        live = {k: o for k, o in self._latest.items() if t - o.t <= self.stale}
        rows: list[tuple[int, TrackEstimate]] = [
            (k, tr) for k, o in sorted(live.items()) for tr in o.tracks
        ]
        if not rows:
            return TrackerOutput(t=t, tracks=(), n_estimate=0.0, acquired=output.acquired)
        xy = np.array([(tr.x, tr.y) for _, tr in rows], dtype=np.float64)
        owner = self.cells.cell_of(xy)
        owned = np.array([owner[i] == k for i, (k, _) in enumerate(rows)])
        keys = [(k, tr.id) for k, tr in rows]
        for key in keys:
            self._seen[key] = t
        d = np.hypot(xy[:, None, 0] - xy[None, :, 0], xy[:, None, 1] - xy[None, :, 1])
        worker = np.array([k for k, _ in rows], dtype=np.int64)
        same = self._same_person(worker, d)
        # A person on a border whose two estimates lie crosswise (each in the other worker's
        # cell) is owned by nobody: both take part as owned, and the merge outputs one.
        owned |= (
            same
            & ~owned[:, None]
            & ~owned[None, :]
            & (owner[:, None] == worker[None, :])
            & (owner[None, :] == worker[:, None])
        ).any(axis=1)
        holder = self._check_links(keys, owned, xy, same, t)
        # 1. Owned tracks without a global ID: the ID of another worker's track of the same
        #    person (within the gate: the estimates straddle the border), else that of a
        #    global track lost nearby moments ago (a late hand-over), else a new one.
        current = {
            self._map[key] for key, o in zip(keys, owned, strict=True) if o and key in self._map
        }
        for i in np.flatnonzero(owned):
            if keys[i] in self._map:
                continue
            # A neighbour's link counts only if its ID is free or held by this same person.
            near = [
                j
                for j in np.flatnonzero(same[i])
                if keys[j] in self._map
                and (holder.get(self._map[keys[j]]) is None or same[i, holder[self._map[keys[j]]]])
            ]
            if near:
                gid: int | None = self._map[keys[min(near, key=lambda j: d[i, j])]]
            else:
                gid = self._take_over(xy[i], t, current)
            if gid is None:
                gid = self._next_id
                self._next_id += 1
            else:
                self.handovers += 1
            self._map[keys[i]] = gid
            holder.setdefault(gid, int(i))
            current.add(gid)
        # 2. Link the not-owned tracks of other workers to the owned track nearest them.
        for j in np.flatnonzero(~owned):
            if keys[j] in self._map:
                continue
            cand = np.flatnonzero(owned & same[:, j]).tolist()
            if cand:
                i = min(cand, key=lambda i: d[i, j])
                self._map[keys[j]] = self._map[keys[i]]
        # 3. Output the owned tracks; one per global ID (two workers may both own the same
        #    person for a moment when their estimates straddle the border); the holder first.
        out: dict[int, TrackEstimate] = {}
        for i in sorted(np.flatnonzero(owned), key=lambda i: holder.get(self._map[keys[i]]) != i):
            gid = self._map[keys[i]]
            tr = rows[i][1]
            if gid in out:
                continue
            out[gid] = dataclasses.replace(tr, id=gid)
            self._globals[gid] = _Global(gid, tr.x, tr.y, t, tr.vx, tr.vy)
        self._forget(t)
        tracks = tuple(out[g] for g in sorted(out))
        # The workers' own n_estimate count the overlaps twice: the merged estimate is the
        # number of owned tracks.
        return TrackerOutput(
            t=t, tracks=tracks, n_estimate=float(len(tracks)), acquired=output.acquired
        )

    def _check_links(
        self,
        keys: list[tuple[int, int]],
        owned: npt.NDArray[np.bool_],
        xy: npt.NDArray[np.float64],
        same: npt.NDArray[np.bool_],
        t: float,
    ) -> dict[int, int]:
        """Drop the links that contradict the owned tracks; return each held global ID's
        holder (row index of the owned track that keeps it).

        Of the owned tracks sharing a global ID, the one nearest to the ID's predicted position
        keeps it; every other track with that ID that is not the holder's person (``same``) is
        unlinked (it belongs to somebody else: a worker swapped labels).
        """
        groups: dict[int, list[int]] = {}
        for i, key in enumerate(keys):
            if key in self._map:
                groups.setdefault(self._map[key], []).append(i)
        holder: dict[int, int] = {}
        for gid, members in groups.items():
            own = [i for i in members if owned[i]]
            if not own:
                continue
            g = self._globals.get(gid)
            if g is None:
                h = own[0]
            else:
                px, py = g.predict(t)
                h = min(own, key=lambda i: math.hypot(xy[i, 0] - px, xy[i, 1] - py))
            holder[gid] = h
            for i in members:
                if i != h and not same[i, h]:
                    self._map.pop(keys[i], None)  # a worker may repeat a label
        return holder

    def _same_person(
        self, worker: npt.NDArray[np.int64], d: npt.NDArray[np.float64]
    ) -> npt.NDArray[np.bool_]:
        """Which pairs of rows (tracks of ``worker``, distances ``d`` in m) may be one person:
        tracks of two different workers, closer than ``link_gate``, each the other worker's
        track nearest to the other (mutual nearest neighbours; one worker's two tracks are two
        people, however close)."""
        nearest_d = np.empty_like(d)
        for w in np.unique(worker):
            mine = worker == w
            nearest_d[mine] = d[mine].min(axis=0)
        nearest = d <= nearest_d
        return (worker[:, None] != worker[None, :]) & (d < self.link_gate) & nearest & nearest.T

    def _take_over(self, p: np.ndarray, t: float, taken: set[int]) -> int | None:
        best, best_d = None, self.link_gate
        for g in self._globals.values():
            if g.gid in taken or t - g.last_t > self.lost_time or g.last_t >= t:
                continue
            dist = math.hypot(p[0] - g.x, p[1] - g.y)
            if dist < best_d:
                best, best_d = g.gid, dist
        return best

    def _forget(self, t: float) -> None:
        horizon = max(5.0, 2 * self.lost_time)
        for key in [k for k, s in self._seen.items() if t - s > horizon]:
            del self._seen[key]
            self._map.pop(key, None)
        for gid in [g for g, v in self._globals.items() if t - v.last_t > horizon]:
            del self._globals[gid]

    def latest(self) -> Mapping[int, TrackerOutput]:
        """The newest output of each worker."""
        return dict(self._latest)


def nodes_of_cells(
    cells: StripCells, node_xy: Mapping[str, Sequence[float]], margin: float
) -> list[tuple[str, ...]]:
    """The nodes each cell's worker fuses: those within ``margin`` m of the cell (by x)."""
    ids = sorted(node_xy)
    xy = np.array([node_xy[n][:2] for n in ids], dtype=np.float64).reshape(-1, 2)
    return [
        tuple(n for n, m in zip(ids, cells.members(k, xy, margin), strict=True) if m)
        for k in range(cells.count)
    ]


def border_crossings(
    cells: StripCells, truth: Sequence[tuple[float, npt.ArrayLike, npt.ArrayLike]]
) -> int:
    """Cell borders crossed by the targets of a truth series ``(t, ids (m,), xy (m, 2))``
    (time-ordered), between consecutive samples in which a target is present."""
    total = 0
    for (_, ids0, xy0), (_, ids1, xy1) in itertools.pairwise(truth):
        _, a, b = np.intersect1d(np.asarray(ids0), np.asarray(ids1), return_indices=True)
        x0 = np.asarray(xy0, dtype=np.float64).reshape(-1, 2)[a, 0]
        x1 = np.asarray(xy1, dtype=np.float64).reshape(-1, 2)[b, 0]
        total += sum(cells.crossings(float(p), float(q)) for p, q in zip(x0, x1, strict=True))
    return total
