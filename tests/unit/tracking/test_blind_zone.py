"""A sensor's blind zone (``SensorScan.min_range``): a person inside it is not missed."""

from __future__ import annotations

import numpy as np

from fusion_center.tracking.base import SensorScan, in_field_of_view
from fusion_center.tracking.gmphd import GmPhdTracker


def scan(
    t: float, positions: list[tuple[float, float]], min_range: float, sensor: str = "a"
) -> SensorScan:
    return SensorScan(
        sensor=sensor,
        t=t,
        positions=np.array(positions, dtype=float).reshape(-1, 2),
        cov=np.broadcast_to(0.01 * np.eye(2), (len(positions), 2, 2)),
        origin=np.zeros(2),
        boresight=0.0,
        beamwidth=2.0,
        max_range=10.0,
        min_range=min_range,
    )


def test_field_of_view_excludes_the_blind_zone() -> None:
    xy = np.array([[1.0, 0.0], [2.5, 0.0], [20.0, 0.0]])
    assert in_field_of_view(scan(0.0, [], 0.0), xy).tolist() == [True, True, False]
    assert in_field_of_view(scan(0.0, [], 2.0), xy).tolist() == [False, True, False]
    # the margin widens the view outward, never into the blind zone
    assert in_field_of_view(scan(0.0, [], 2.0), xy, 0.5).tolist() == [False, True, False]


def tracks_after_silence(min_range: float) -> int:
    """A person seen for 1 s at 3 m walks into 1.5 m of the sensor, which then sees nothing."""
    tracker = GmPhdTracker()
    t, out = 0.0, None
    for k in range(50):
        t = k * 0.02
        out = tracker.step(t, [scan(t, [(3.0 - 1.5 * t, 0.0)], min_range)])
    assert out is not None and len(out.tracks) == 1
    for k in range(1, 26):
        out = tracker.step(t + 0.02 * k, [scan(t + 0.02 * k, [], min_range)])
    return len(out.tracks)


def test_a_person_in_the_blind_zone_keeps_the_track() -> None:
    assert tracks_after_silence(0.0) == 0  # seen, then 0.5 s of misses: lost
    assert tracks_after_silence(2.0) == 1  # in the blind zone: nothing was missed


def weight_after_a_miss(tracker: GmPhdTracker, dt: float) -> float:
    """Mixture weight after one empty frame that follows 1 s of detections, frames dt apart
    (two sensors: the frame update, where the tempering applies)."""
    n = round(1.0 / dt)
    for k in range(n):
        tracker.step(k * dt, [scan(k * dt, [(5.0, 0.0)], 0.0, s) for s in "ab"])
    return tracker.step(n * dt, [scan(n * dt, [], 0.0, s) for s in "ab"]).n_estimate


def test_miss_correlation_time_tempers_a_miss_by_the_frame_interval() -> None:
    from fusion_center.tracking.gmphd import GmPhdConfig

    plain, tempered = GmPhdConfig(), GmPhdConfig(miss_correlation_time=0.04)
    fast, slow = (weight_after_a_miss(GmPhdTracker(plain), dt) for dt in (0.02, 0.05))
    fast_t, slow_t = (weight_after_a_miss(GmPhdTracker(tempered), dt) for dt in (0.02, 0.05))
    assert slow_t == slow  # frames 0.05 s apart: the miss counts as one frame either way
    assert fast_t > fast + 0.1  # 0.02 s apart: it counts half a frame
