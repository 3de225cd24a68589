"""Cell partition and the gateway's hand-over merge (fusion_center.tracking.cells)."""

from __future__ import annotations

import numpy as np

from fusion_center.tracking.base import TrackerOutput, TrackEstimate
from fusion_center.tracking.cells import HandoverMerger, StripCells, nodes_of_cells


def _out(t: float, tracks: list[tuple[int, float, float]], vx: float = 1.0) -> TrackerOutput:
    return TrackerOutput(
        t=t,
        tracks=tuple(
            TrackEstimate(id=i, x=x, vx=vx if i % 2 else -vx, y=y, vy=0.0) for i, x, y in tracks
        ),
        n_estimate=float(len(tracks)),
        acquired=(t,),
    )


def test_strip_cells_assign_points_and_count_crossings():
    cells = StripCells.even(0.0, 40.0, 4)
    assert cells.borders == (10.0, 20.0, 30.0)
    points = [[0.0, 1.0], [10.0, 1.0], [29.9, 0.0], [99.0, 0.0]]
    assert cells.cell_of(points).tolist() == [0, 1, 2, 3]
    assert cells.crossings(5.0, 25.0) == 2 and cells.crossings(25.0, 5.0) == 2
    assert cells.crossings(11.0, 19.0) == 0
    members = nodes_of_cells(cells, {"a": (9.0, 0.0), "b": (15.0, 0.0), "c": (35.0, 0.0)}, 2.0)
    assert members == [("a",), ("a", "b"), (), ("c",)]


def test_a_person_walking_across_a_border_keeps_one_global_id():
    """Two workers with their own labels (7 west, 3 east) see a person in the overlap; the
    merged output has one track whose ID does not change when ownership passes east."""
    merger = HandoverMerger(StripCells((15.0,)), link_gate=1.0)
    ids, xs = [], []
    rng = np.random.default_rng(1)
    for k, x in enumerate(np.arange(8.0, 22.0, 0.1)):
        t = 0.02 * k
        west = [(7, x + rng.normal(0, 0.05), 4.0)] if x < 21.0 else []
        east = [(3, x + rng.normal(0, 0.05), 4.0)] if x > 9.0 else []
        merger.update(0, _out(t, west))
        merged = merger.update(1, _out(t, east))
        assert len(merged.tracks) == 1, (x, merged.tracks)
        ids.append(merged.tracks[0].id)
        xs.append(merged.tracks[0].x)
    assert min(xs) < 14.0 and max(xs) > 16.0
    assert len(set(ids)) == 1
    assert merged.acquired == (merged.t,)


def test_a_late_hand_over_takes_the_lost_id_and_distinct_people_keep_distinct_ids():
    merger = HandoverMerger(StripCells((15.0,)), link_gate=1.0, lost_time=1.0)
    a = merger.update(0, _out(0.0, [(1, 14.8, 2.0), (2, 5.0, 6.0)]))
    gid = {round(tr.x, 1): tr.id for tr in a.tracks}
    assert gid[14.8] != gid[5.0]
    # The west worker loses the person at the border; the east one picks them up 0.2 s later.
    merger.update(0, _out(0.2, [(2, 5.2, 6.0)]))
    b = merger.update(1, _out(0.2, [(9, 15.1, 2.0)]))
    got = {round(tr.x, 1): tr.id for tr in b.tracks}
    assert got[15.1] == gid[14.8] and got[5.2] == gid[5.0]
    # Somebody new far from any lost track gets a new ID.
    c = merger.update(1, _out(0.3, [(9, 15.2, 2.0), (4, 25.0, 4.0)]))
    got = {round(tr.x, 1): tr.id for tr in c.tracks}
    assert got[15.2] == gid[14.8] and got[5.2] == gid[5.0]
    assert got[25.0] not in gid.values()


def test_two_people_passing_at_a_border_stay_two_when_a_worker_swaps_its_labels():
    """A walks east, B west; they pass each other at the border and the east worker swaps its
    labels as they do (the west one does not). The merged output keeps two tracks and their
    IDs (before the fix, both owned tracks carried B's ID and A vanished for good)."""
    merger = HandoverMerger(StripCells((15.0,)), link_gate=1.0)
    rng = np.random.default_rng(3)
    seen: dict[str, set[int]] = {"A": set(), "B": set()}
    for k in range(300):
        t = 0.02 * k
        xa, xb = 12.0 + 1.0 * t, 18.0 - 1.0 * t  # pass at x = 15 at t = 3 s
        ya, yb = 4.0, 4.4

        def noisy(x: float) -> float:
            return x + rng.normal(0.0, 0.03)

        west = [(1, noisy(xa), ya), (2, noisy(xb), yb)]
        swapped = t > 3.0
        east_a, east_b = (6, 5) if swapped else (5, 6)
        east = [(east_a, noisy(xa), ya), (east_b, noisy(xb), yb)]
        merger.update(0, _out(t, west))
        merged = merger.update(1, _out(t, east))
        assert len(merged.tracks) == 2, (t, merged.tracks)
        for tr in merged.tracks:
            seen["A" if abs(tr.y - ya) < 0.2 else "B"].add(tr.id)
    assert len(seen["A"]) == 1 and len(seen["B"]) == 1 and seen["A"] != seen["B"]


def test_a_person_on_a_border_with_crosswise_estimates_is_output_once():
    """Each worker's estimate of a person standing on the border lies in the other's cell:
    neither owns it, yet the person is there (before the fix the output was empty)."""
    merger = HandoverMerger(StripCells((15.0,)), link_gate=1.0)
    for k in range(50):
        t = 0.02 * k
        merger.update(0, _out(t, [(1, 15.03, 4.0), (3, 5.0, 2.0)], vx=0.0))
        merged = merger.update(1, _out(t, [(2, 14.98, 4.02)], vx=0.0))
        assert sorted(round(tr.x) for tr in merged.tracks) == [5, 15], merged.tracks
