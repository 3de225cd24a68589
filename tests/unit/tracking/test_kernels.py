"""The compiled GM-PHD kernels (``fusion_center.tracking.kernels``) against the numpy
reference code of ``fusion_center.tracking.gmphd``, and their fallback without a cache."""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest

from fusion_center.tracking import kernels
from fusion_center.tracking.base import SensorScan
from fusion_center.tracking.gmphd import (
    GmPhdConfig,
    GmPhdTracker,
    _cap_label_weight,
    merge_components,
)
from tests.numba_cache import run_without_numba_cache

from .sim import FRAME, crossing_truth, detect, sensors_around


def _random_mixture(rng, n, n_labels):
    """``n`` components around a few centres (many within the merge gate), some weights
    tied, labels from ``n_labels``."""
    centres = rng.uniform(0.0, 8.0, (max(1, n // 4), 4))
    m = centres[rng.integers(0, centres.shape[0], n)] + rng.normal(0.0, 0.1, (n, 4))
    a = rng.normal(size=(n, 4, 4))
    P = a @ np.swapaxes(a, 1, 2) * 0.02 + np.diag([0.05, 0.3, 0.05, 0.3])
    w = rng.choice([rng.uniform(1e-4, 0.9), 0.25], n)  # ties: 0.25 is drawn repeatedly
    label = rng.integers(1, n_labels + 1, n).astype(np.int64)
    return w, m, P, label


def _same_mixture(got, want, msg):
    assert got[0].shape == want[0].shape, msg
    np.testing.assert_array_equal(got[3], want[3], err_msg=msg)
    for g, e in zip(got[:3], want[:3], strict=True):
        np.testing.assert_allclose(g, e, rtol=1e-11, atol=1e-13, err_msg=msg)


@pytest.mark.parametrize("cap", [math.inf, 1.0])
def test_merge_kernel_matches_reference(cap):
    rng = np.random.default_rng(11)
    n_merged = n_protected_kept = n_ties = 0
    for trial in range(150):
        n = int(rng.integers(0, 40))
        w, m, P, label = _random_mixture(rng, n, 6)
        confirmed = np.sort(rng.choice(np.arange(1, 7), int(rng.integers(0, 4)), replace=False))
        protected = np.isin(label, confirmed) if confirmed.size else None
        want = merge_components(w, m, P, label, 4.0, protected)
        if math.isfinite(cap):
            want = (_cap_label_weight(want[0], want[3], cap), *want[1:])
        got = kernels.merge_mixture(w, m, P, label, confirmed.astype(np.int64), 4.0, cap)
        _same_mixture(got, want, f"trial {trial}")
        n_merged += got[0].size < n
        n_ties += np.unique(w).size < n
        if protected is not None and got[0].size < n:
            # two confirmed labels are never merged into one
            n_protected_kept += np.isin(confirmed, got[3]).sum() == np.isin(confirmed, label).sum()
    assert n_merged >= 50 and n_ties >= 50 and n_protected_kept >= 20


def _tracker(compiled, **kw):
    tracker = GmPhdTracker(GmPhdConfig(clutter_rate=1.0, surveillance_area=80.0, **kw))
    tracker.compiled = compiled
    return tracker


def test_update_kernel_matches_numpy_update_from_random_mixtures():
    """One scan's correction from random mixtures (confirmed labels, components outside the
    sensor's view, read-only measurement arrays), sequential and frame fusion."""
    rng = np.random.default_rng(3)
    sensors = sensors_around(10.0, 8.0)
    n_births = n_detected = 0
    for trial in range(60):
        ref = _tracker(False, detection_probability=0.9)
        n = int(rng.integers(0, 30))
        w, m, P, label = _random_mixture(rng, n, 8)
        ref._mix.w, ref._mix.m, ref._mix.P, ref._mix.label = w, m, P, label
        ref._confirmed_arr = np.sort(rng.choice(np.arange(1, 9), 3, replace=False))
        ref._next_label = 100
        fast = copy.deepcopy(ref)
        fast.compiled = True
        xy = m[rng.integers(0, max(n, 1), 3), ::2] if n else rng.uniform(0, 8, (3, 2))
        scans = [detect(rng, s, 0.0, xy, clutter=2.0) for s in sensors[: int(rng.integers(1, 4))]]
        for s in scans:  # as decoded from the wire
            s.positions.flags.writeable = False
            s.cov.flags.writeable = False
            s.origin.flags.writeable = False
        if len(scans) == 1:
            births = [tr._update(scans[0]) for tr in (ref, fast)]
        else:
            births = [tr._frame_update(0.0, scans) for tr in (ref, fast)]
        a, b = ref._mix, fast._mix
        _same_mixture((b.w, b.m, b.P, b.label), (a.w, a.m, a.P, a.label), f"trial {trial}")
        _same_mixture(
            (births[1].w, births[1].m, births[1].P, births[1].label),
            (births[0].w, births[0].m, births[0].P, births[0].label),
            f"births, trial {trial}",
        )
        assert ref.detection_probabilities == pytest.approx(fast.detection_probabilities)
        n_births += births[0].w.size
        n_detected += births[0].w.size < sum(s.positions.shape[0] for s in scans)
    assert n_births >= 20 and n_detected >= 20


def test_small_kernels_match_numpy_methods_from_random_mixtures():
    """Prediction (manoeuvre copies), birth merging, label heads (splits), duplicate labels
    and occlusion, each from one random mixture through both paths of the tracker."""
    rng = np.random.default_rng(17)
    n_split = n_pairs = n_occluded = n_copies = n_birth_merged = 0
    for trial in range(80):
        ref = _tracker(False, duplicate_steps=2)
        n = int(rng.integers(0, 25))
        w, m, P, label = _random_mixture(rng, n, 6)
        w = w * rng.choice([1.0, 3.0], n)  # some above the split and extraction thresholds
        m[: n // 2] = np.round(m[: n // 2], 1)  # equal positions: exact duplicates
        ref._mix.w, ref._mix.m, ref._mix.P, ref._mix.label = w, m, P, label
        ref._next_label = 100
        ref._dup_count = {(1, 2): 1, (3, 5): 1}
        fast = copy.deepcopy(ref)
        fast.compiled = True
        msg = f"trial {trial}"
        origins = rng.uniform(-2.0, 10.0, (3, 2))
        want = ref._occluded_many(origins, ref._mix)
        np.testing.assert_array_equal(fast._occluded_many(origins, fast._mix), want, msg)
        mask = rng.random(want.shape) < 0.5
        got = fast._occluded_many(origins, fast._mix, mask)
        np.testing.assert_array_equal(got, want & mask, msg)
        n_occluded += want.sum()
        if n:
            births = ref._mix.take(rng.random(n) < 0.5)
            got = fast._merge_births(births)
            exp = ref._merge_births(births)
            _same_mixture((got.w, got.m, got.P, got.label), (exp.w, exp.m, exp.P, exp.label), msg)
            n_birth_merged += exp.w.size < births.w.size
        for tr in (ref, fast):
            tr._fold_duplicate_labels()
        assert fast._dup_count == ref._dup_count, msg
        n_pairs += len(ref._dup_count)
        for tr in (ref, fast):
            tr._predict(0.05)
        _same_mixture(_canonical(fast._mix), _canonical(ref._mix), msg)
        n_copies += ref._mix.w.size - n
        a, b = ref._extract(1.0), fast._extract(1.0)
        _same_mixture(_canonical(fast._mix), _canonical(ref._mix), msg)
        assert fast._next_label == ref._next_label and fast._hits == ref._hits, msg
        assert a.n_estimate == pytest.approx(b.n_estimate, rel=1e-12), msg
        n_split += ref._next_label - 100
    print(n_split, n_pairs, n_occluded, n_copies, n_birth_merged)
    assert min(n_split, n_pairs, n_occluded, n_copies, n_birth_merged) >= 20


def _canonical(mix):
    order = np.lexsort((np.round(mix.m[:, 2], 6), np.round(mix.m[:, 0], 6), mix.label))
    return mix.w[order], mix.m[order], mix.P[order], mix.label[order]


@pytest.mark.parametrize("max_components", [200, 12])
def test_tracker_steps_with_kernels_match_numpy_steps(max_components):
    """Every step of two runs (6 sensors, 3 walkers crossing; one sensor in heavy clutter),
    the component cap active in the second case, taken by both paths from the reference's
    state: the same tracks and mixture up to rounding. (Whole runs drift apart by rounding
    once a tie or a threshold flips, e.g. which of two nearly equal components the cap
    keeps.)"""
    times, truth = crossing_truth(3.0)
    for sensors, clutter in (
        (sensors_around(10.0, 8.0), 1.0),
        (sensors_around(10.0, 8.0)[:1], 5.0),
    ):
        rng = np.random.default_rng(7)
        ref = _tracker(False, max_components=max_components)
        n_tracks = n_capped = 0
        for k in range(times.size):
            t = k * FRAME
            scans = [
                detect(rng, s, t + FRAME * j / len(sensors), truth[k], clutter=clutter)
                for j, s in enumerate(sensors)
            ]
            fast = copy.deepcopy(ref)
            fast.compiled = True
            new = fast.step(t + FRAME, scans)
            old = ref.step(t + FRAME, scans)
            msg = f"step {k}"
            assert old.ids().tolist() == new.ids().tolist(), msg
            np.testing.assert_allclose(new.positions(), old.positions(), atol=1e-9, err_msg=msg)
            assert new.n_estimate == pytest.approx(old.n_estimate, rel=1e-9), msg
            # components in (label, position) order: equal weights may swap by rounding
            a, b = (_canonical(tr._mix) for tr in (ref, fast))
            _same_mixture(b, a, msg)
            assert fast._next_label == ref._next_label and fast._hits == ref._hits, msg
            n_tracks += len(new.tracks)
            n_capped += a[0].size == max_components
        assert n_tracks >= times.size  # people were tracked
        assert max_components == 200 or n_capped >= 20  # the cap was exercised


def test_tracking_kernels_work_without_a_writable_numba_cache(tmp_path):
    """With no usable cache directory the kernels compile in memory (a warning each) and
    give the same tracks."""
    code = (
        "import numpy as np\n"
        "from fusion_center.tracking.base import SensorScan\n"
        "from fusion_center.tracking.gmphd import GmPhdConfig, GmPhdTracker\n"
        "tr = GmPhdTracker(GmPhdConfig(surveillance_area=50.0))\n"
        "for k in range(40):\n"
        "    z = np.array([[1.0 + 0.02 * k, 2.0], [4.0, 3.0 - 0.01 * k]])\n"
        "    scan = SensorScan(sensor='a', t=0.02 * k, positions=z,\n"
        "                      cov=np.tile(0.01 * np.eye(2), (2, 1, 1)), origin=np.zeros(2))\n"
        "    out = tr.step(0.02 * k, [scan])\n"
        "print(np.round(out.positions(), 9).tolist())\n"
    )
    res = run_without_numba_cache(code, tmp_path, timeout=300)
    assert res.returncode == 0, res.stderr
    assert "numba cache unavailable, compiling in memory" in res.stderr
    tracker = GmPhdTracker(GmPhdConfig(surveillance_area=50.0))
    tracker.compiled = False
    for k in range(40):
        z = np.array([[1.0 + 0.02 * k, 2.0], [4.0, 3.0 - 0.01 * k]])
        scan = SensorScan(
            sensor="a",
            t=0.02 * k,
            positions=z,
            cov=np.tile(0.01 * np.eye(2), (2, 1, 1)),
            origin=np.zeros(2),
        )
        out = tracker.step(0.02 * k, [scan])
    assert len(out.tracks) == 2
    assert res.stdout.strip() == str(np.round(out.positions(), 9).tolist())


def test_range_pairs_kernel_matches_numpy():
    """``kernels.range_pairs`` keeps the pairs the dense numpy test keeps (``einsum``
    distances, the limits inclusive) in ``np.nonzero`` order, with the same differences."""
    rng = np.random.default_rng(8)
    for n_j, n_s in ((0, 5), (7, 0), (60, 48), (300, 13)):
        xy = np.round(rng.uniform(-3.0, 30.0, (n_j, 4)), 1)[:, ::2]  # a strided view
        origin = np.round(rng.uniform(0.0, 28.0, (n_s, 2)), 1)
        if n_j and n_s:
            origin[0] = xy[0]  # zero distance
            origin[1] = xy[1] + [3.0, 4.0]  # exactly at a limit (5 m)
        hi2 = rng.choice([25.0, 36.0, 81.0, 144.0], n_s)
        lo2 = rng.choice([0.0, 0.64, 25.0], n_s)
        d = xy[:, None, :] - origin[None, :, :]
        r2 = np.einsum("jsi,jsi->js", d, d)
        want_j, want_s = np.nonzero((r2 <= hi2) & (r2 >= lo2))
        j, s, dx, dy, got_r2 = kernels.range_pairs(xy, origin, hi2, lo2)
        np.testing.assert_array_equal(j, want_j)
        np.testing.assert_array_equal(s, want_s)
        np.testing.assert_array_equal(dx, d[j, s, 0])
        np.testing.assert_array_equal(dy, d[j, s, 1])
        np.testing.assert_array_equal(got_r2, r2[j, s])
        np.testing.assert_array_equal(np.sqrt(got_r2), np.linalg.norm(d, axis=2)[j, s])
        if n_j > 50:
            assert 0 < j.size < n_j * n_s
