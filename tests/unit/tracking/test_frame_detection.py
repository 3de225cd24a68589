"""The frame update's per-sensor detection probabilities, all sensors at once, against the
per-sensor loop they replaced (same tracks, same learned detection profiles)."""

from __future__ import annotations

import dataclasses
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
        angles = np.asarray(cfg.detection_angle_bins)
        n_a = angles.size + 1
        for i, scan in enumerate(scans):
            vis = in_field_of_view(scan, xy, cfg.fov_margin)
            if not vis.any():
                continue
            profile = self.detection_profiles.get(scan.sensor)
            if profile is None:
                profile = np.full((edges.size + 1) * n_a, cfg.detection_probability)
                self.detection_profiles[scan.sensor] = profile
            rel = xy - scan.origin
            off = np.abs(np.angle(np.exp(1j * (np.arctan2(rel[:, 1], rel[:, 0]) - scan.boresight))))
            abin = np.zeros(xy.shape[0], dtype=np.intp)
            if scan.beamwidth < 2 * math.pi:
                abin = np.searchsorted(angles, off / (scan.beamwidth / 2))
            rbin = np.searchsorted(edges, np.linalg.norm(rel, axis=1)) * n_a + abin
            sight = self._sight(scan, xy)
            pd_j = np.where(vis, profile[rbin], 0.0) * sight
            if cfg.occluded_factor < 1.0 and xy.shape[0] > 1:
                pd_j = pd_j * np.where(self._occluded(scan, mix), cfg.occluded_factor, 1.0)
            pd_js[:, i] = pd_j
            seen = (vis & (sight >= 1.0))[heavy]
            if cfg.adapt_detection and seen.any():
                mine = near if owner is None else near[:, owner == i]
                hit = mine.any(axis=1)[seen]
                hb = rbin[heavy][seen]
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


def _edge_walk(angle_bins: tuple[float, ...]) -> np.ndarray:
    """The learned profile of a sensor that sees one walker head-on and another at 0.9 of its
    half view (both 6 m away) and detects the second in one frame in ten."""
    from fusion_center.tracking.gmphd import GmPhdConfig

    tracker = GmPhdTracker(GmPhdConfig(detection_angle_bins=angle_bins))
    rng = np.random.default_rng(3)
    near = Sensor(
        name="s", origin=np.array([0.0, 0.0]), boresight=0.0, beamwidth=2.0, max_range=12.0
    )
    helper = Sensor(
        name="h", origin=np.array([6.0, 8.0]), boresight=-math.pi / 2, beamwidth=3.0,
        max_range=12.0,
    )  # fmt: skip
    edge = 0.9 * 1.0  # rad off the boresight: 0.9 of the half view
    people = np.array([[6.0, 0.0], [6.0 * math.cos(edge), 6.0 * math.sin(edge)]])
    for k in range(400):
        t = k * FRAME
        a = detect(rng, near, t, people[:1], pd=0.9, clutter=0.0)
        if rng.random() < 0.1:  # the person at the edge, now and then
            a = SensorScan(
                sensor="s", t=t, positions=np.vstack([a.positions, people[1:]]),
                cov=np.broadcast_to(np.eye(2) * 0.01, (a.positions.shape[0] + 1, 2, 2)),
                origin=near.origin, boresight=0.0, beamwidth=2.0, max_range=12.0,
            )  # fmt: skip
        b = detect(rng, helper, t + 0.001, people, pd=0.9, clutter=0.0)
        tracker.step(t + FRAME, [a, b])
    return tracker.detection_profiles["s"]


def test_the_detection_profile_learns_that_a_sensor_misses_people_at_its_beam_edge() -> None:
    split = _edge_walk((0.5, 0.8))
    # 6 distance bins x 3 bearing bins; 6 m is the third distance bin (5-7 m)
    assert split.shape == (18,)
    head_on, edge = split[2 * 3 + 0], split[2 * 3 + 2]
    assert head_on > 0.7
    assert edge < 0.35  # learned from about one detection in ten
    # Without bearing bins, the one distance bin mixes both people.
    (mixed,) = _edge_walk(())[2:3]
    assert edge + 0.2 < mixed < head_on - 0.1


def test_profile_bins_are_validated_and_a_profile_of_other_bins_is_rebuilt() -> None:
    from fusion_center.tracking.gmphd import GmPhdConfig

    with pytest.raises(ValueError, match="detection_angle_bins"):
        GmPhdConfig(detection_angle_bins=(0.8, 0.5))
    with pytest.raises(ValueError, match="detection_range_bins"):
        GmPhdConfig(detection_range_bins=(0.0, 3.0))
    # a profile learned per distance only (6 bins) on a tracker that now bins by bearing too
    tracker = GmPhdTracker(GmPhdConfig())
    learned = np.linspace(0.3, 0.8, 6)
    tracker.detection_profiles["s"] = learned.copy()
    for k in range(20):  # a person 6 m ahead on s's boresight, seen by h too
        scans = [
            SensorScan(
                sensor=name, t=k * FRAME + dt, positions=np.array([[6.0, 0.0]]),
                cov=np.eye(2)[None] * 0.01, origin=np.array(origin), boresight=boresight,
                beamwidth=2.0, max_range=12.0,
            )
            for name, dt, origin, boresight in (
                ("s", 0.0, (0.0, 0.0), 0.0), ("h", 0.001, (6.0, 8.0), -math.pi / 2)
            )
        ]  # fmt: skip
        tracker.step(k * FRAME + 0.002, scans)
    profile = tracker.detection_profiles["s"].reshape(6, 3)
    # every distance bin keeps what it learned in each bearing bin, except where the
    # person is (5-7 m, head-on) and may have moved it
    untouched = np.ones((6, 3), bool)
    untouched[2, 0] = False
    np.testing.assert_array_equal(profile[untouched], np.repeat(learned, 3)[untouched.ravel()])


def _random_frame(rng: np.random.Generator, n_s: int, n_j: int) -> tuple:
    """Sensors (sectors, all-round, blind zones, a few on a component) and a mixture of
    ``n_j`` components around them, with the estimates near the heavy ones."""
    from fusion_center.tracking.gmphd import _Mixture

    m = np.zeros((n_j, 4))
    m[:, ::2] = rng.uniform([-2.0, -2.0], [30.0, 10.0], (n_j, 2))
    m[:, 1::2] = rng.normal(0.0, 0.5, (n_j, 2))
    w = rng.choice([0.05, 0.4, 0.6, 0.9], n_j)
    mix = _Mixture(w, m, np.broadcast_to(np.eye(4), (n_j, 4, 4)).copy(), rng.integers(0, 6, n_j))
    xy = mix.m[:, ::2]
    origins = rng.uniform([0.0, 0.0], [28.0, 8.0], (n_s, 2))
    origins[: min(3, n_j)] = xy[:3]  # a sensor exactly on a component (zero distance)
    scans, counts = [], rng.integers(0, 4, n_s)
    for i in range(n_s):
        pos = origins[i] + rng.normal(0.0, 3.0, (counts[i], 2))
        scans.append(
            SensorScan(
                sensor=f"n{i:03d}", t=0.01 * i, positions=pos, cov=np.full((counts[i], 2, 2), 0.0),
                origin=origins[i], boresight=float(rng.uniform(-math.pi, math.pi)),
                beamwidth=float(rng.choice([2 * math.pi, 1.2, 2.0, 3.0])),
                max_range=float(rng.choice([6.0, 9.0, 12.0])),
                min_range=float(rng.choice([0.0, 0.8])),
            )
        )  # fmt: skip
    z = np.concatenate([s.positions for s in scans])
    owner = np.repeat(np.arange(n_s), counts)
    heavy = w > 0.5
    near = np.linalg.norm(xy[heavy, None, :] - z[None, :, :], axis=2) < 1.5
    return scans, mix, xy, heavy, near, owner


@pytest.mark.parametrize("walls", [False, True])
def test_frame_detection_on_pairs_equals_the_dense_form_bit_for_bit(walls: bool) -> None:
    """The compiled pairs' path (``kernels.range_pairs``) gives the dense reference's
    detection probabilities and learned profiles exactly, frame after frame."""
    sight = WallSightModel([[5.0, 0.0], [12.0, 3.0]], [[5.0, 3.0], [20.0, 3.0]]) if walls else None
    pairs, dense = GmPhdTracker(), GmPhdTracker()
    pairs.sight = dense.sight = sight
    rng = np.random.default_rng(5)
    some_hidden = False
    for k in range(40):
        scans, mix, xy, heavy, near, owner = _random_frame(rng, 48, int(rng.integers(1, 150)))
        got = pairs._frame_detection(scans, mix, xy, heavy, near, owner if k % 4 else None)
        dense.compiled = False
        want = dense._frame_detection(scans, mix, xy, heavy, near, owner if k % 4 else None)
        dense.compiled = True
        np.testing.assert_array_equal(got, want)
        some_hidden |= bool(((want > 0.0) & (want < 0.3)).any())
    assert pairs.detection_profiles.keys() == dense.detection_profiles.keys()
    for name, profile in dense.detection_profiles.items():
        np.testing.assert_array_equal(pairs.detection_profiles[name], profile)
    start = GmPhdTracker().config.detection_probability
    assert any(np.abs(p - start).max() > 0.01 for p in dense.detection_profiles.values())
    assert some_hidden  # occluded or behind a wall somewhere


@pytest.mark.parametrize("limit", [int, np.float32])
def test_frame_detection_on_pairs_takes_the_limits_any_real_type(limit: type) -> None:
    """Scans built by hand with integer (``min_range=0``) or float32 distance limits give
    the dense form's probabilities, not a type error from the compiled kernel."""
    rng = np.random.default_rng(11)
    scans, mix, xy, heavy, near, owner = _random_frame(rng, 12, 40)
    scans = [
        dataclasses.replace(s, max_range=limit(round(s.max_range)), min_range=limit(0))
        for s in scans
    ]
    pairs, dense = GmPhdTracker(), GmPhdTracker()
    dense.compiled = False
    got = pairs._frame_detection(scans, mix, xy, heavy, near, owner)
    want = dense._frame_detection(scans, mix, xy, heavy, near, owner)
    np.testing.assert_array_equal(got, want)
    assert (want > 0.0).any()
