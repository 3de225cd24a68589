"""The frame update's per-sensor detection probabilities, all sensors at once, against the
per-sensor loop they replaced (same tracks, same learned detection profiles)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fusion_center.tracking.base import SensorScan, in_field_of_view
from fusion_center.tracking.gmphd import GmPhdTracker
from fusion_center.tracking.walls import WallSightModel

from .sim import FRAME, Sensor, crossing_truth, detect, sensors_around


class LoopGmPhdTracker(GmPhdTracker):
    """The reference: one sensor after the other, as the frame update did it before."""

    def _frame_detection(self, scans, mix, xy, heavy, near, owner):  # type: ignore[no-untyped-def]
        cfg = self.config
        pd_js = np.zeros((xy.shape[0], len(scans)))
        edges = np.asarray(cfg.detection_range_bins)
        for i, scan in enumerate(scans):
            vis = in_field_of_view(scan, xy, cfg.fov_margin)
            if not vis.any():
                continue
            profile = self.detection_profiles.get(scan.sensor)
            if profile is None:
                profile = np.full(edges.size + 1, cfg.detection_probability)
                self.detection_profiles[scan.sensor] = profile
            rbin = np.searchsorted(edges, np.linalg.norm(xy - scan.origin, axis=1))
            sight = self._sight(scan, xy)
            pd_j = np.where(vis, profile[rbin], 0.0) * sight
            if cfg.occluded_factor < 1.0 and xy.shape[0] > 1:
                pd_j = pd_j * np.where(self._occluded(scan, mix), cfg.occluded_factor, 1.0)
            pd_js[:, i] = pd_j
            seen = (vis & (sight >= 1.0))[heavy]
            if cfg.adapt_detection and seen.any():
                mine = near if owner is None else near[:, owner == i]
                hit = mine.any(axis=1)[seen]
                hb = np.searchsorted(edges, np.linalg.norm(xy - scan.origin, axis=1))[heavy][seen]
                count = np.bincount(hb, minlength=profile.size)
                rate = np.bincount(hb, weights=hit, minlength=profile.size)
                upd = count > 0
                profile[upd] += cfg.adapt_rate * (rate[upd] / count[upd] - profile[upd])
                np.clip(
                    profile,
                    cfg.min_detection_probability,
                    cfg.max_detection_probability,
                    out=profile,
                )
        return pd_js


def _sensors() -> list[Sensor]:
    # Six sensors around the room, one omni in the middle, one looking away, one out of range.
    return [
        *sensors_around(10.0, 8.0),
        Sensor(
            name="omni",
            origin=np.array([5.0, 0.2]),
            boresight=0.0,
            beamwidth=2 * math.pi,
            max_range=12.0,
        ),
        Sensor(
            name="away",
            origin=np.array([0.0, 4.0]),
            boresight=math.pi,
            beamwidth=1.7,
            max_range=12.0,
        ),
        Sensor(
            name="far",
            origin=np.array([40.0, 4.0]),
            boresight=math.pi,
            beamwidth=1.7,
            max_range=10.0,
        ),
    ]


@pytest.mark.parametrize("walls", [False, True])
def test_frame_detection_of_all_sensors_at_once_equals_the_per_sensor_loop(walls: bool) -> None:
    sight = WallSightModel([[5.0, 0.0]], [[5.0, 3.0]], factor=0.1) if walls else None
    fast, loop = GmPhdTracker(), LoopGmPhdTracker()
    fast.sight = loop.sight = sight
    rng = np.random.default_rng(11)
    sensors = _sensors()
    t, truth = crossing_truth(3.0)
    for k in range(t.size):
        scans = [detect(rng, s, float(t[k]) + 1e-4 * i, truth[k]) for i, s in enumerate(sensors)]
        if k % 10 == 5:  # a frame with one sensor twice (its profile adapts scan by scan)
            scans.append(detect(rng, sensors[0], float(t[k]) + 0.015, truth[k]))
        a, b = fast.step(float(t[k]) + FRAME, scans), loop.step(float(t[k]) + FRAME, scans)
        assert a.ids().tolist() == b.ids().tolist()
        np.testing.assert_allclose(a.positions(), b.positions(), rtol=0, atol=1e-9)
    assert fast.detection_profiles.keys() == loop.detection_profiles.keys()
    for name, profile in loop.detection_profiles.items():
        np.testing.assert_allclose(fast.detection_profiles[name], profile, rtol=0, atol=1e-12)
    # The profiles did adapt away from their start, and a person was tracked.
    start = GmPhdTracker().config.detection_probability
    assert any(np.abs(p - start).max() > 0.01 for p in loop.detection_profiles.values())
    assert len(a.tracks) >= 2
    assert "far" not in loop.detection_profiles  # a sensor that sees nobody learns nothing


def test_wall_sight_of_pairs_equals_one_sensor_at_a_time() -> None:
    model = WallSightModel(
        [[10.0, 0.0], [0.0, 0.0], [3.0, 5.0]], [[10.0, 8.0], [0.0, 8.0], [9.0, 5.0]], factor=0.2
    )
    rng = np.random.default_rng(2)
    origins = rng.uniform([-2, -1], [14, 9], (7, 2))
    xy = rng.uniform([-2, -1], [14, 9], (30, 2))
    many = model.pairs(np.repeat(origins, len(xy), axis=0), np.tile(xy, (len(origins), 1)))
    many = many.reshape(len(origins), len(xy)).T
    for s, o in enumerate(origins):
        scan = SensorScan(
            sensor="x", t=0.0, positions=np.zeros((0, 2)), cov=np.zeros((0, 2, 2)), origin=o
        )
        np.testing.assert_array_equal(many[:, s], model(scan, xy))
    assert (many < 1).any() and (many == 1).any()
