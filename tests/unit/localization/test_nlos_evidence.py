"""The combined NLOS test: eq. (6) plus first-path power and per-impulse-response flags."""

from __future__ import annotations

import numpy as np

from fusion_center.localization.mobile import LocalizerConfig, RangingLocalizer
from fusion_center.localization.nlos import EvidenceNlosTest, MseNlosTest

BUDGET = 48.0  # first-path SNR at 1 m, dB


def _window(rng, n, distance, loss_db, flag_p, range_std):
    """Times, ranges, SNRs and flags of one anchor over ``n`` rounds of a static node."""
    t = 0.1 * np.arange(n)
    r = distance + rng.normal(0.0, range_std, n)
    snr = BUDGET - 20.0 * np.log10(distance) - loss_db + rng.normal(0.0, 2.0, n)
    return t, r, snr, rng.random(n) < flag_p


def test_static_obstructed_link_is_caught_although_its_ranges_do_not_scatter(rng):
    # a frozen channel: the obstructed link's ranges are as steady as a LOS link's, so eq. (6)
    # cannot see it; its first path is 12 dB below the path loss and the shape flags it often
    ev = EvidenceNlosTest()
    t, r_los, s_los, f_los = _window(rng, 30, 3.0, 0.0, 0.06, 0.005)
    _, r_nl, s_nl, f_nl = _window(rng, 30, 5.0, 12.0, 0.6, 0.005)
    r = np.column_stack([r_los, r_nl])
    s = np.column_stack([s_los, s_nl])
    f = np.column_stack([f_los, f_nl])
    assert not np.any(MseNlosTest().decide(t, r))
    budget = ev.calibrate(list(s.T), list(r.T))
    assert abs(budget - BUDGET) < 1.5  # calibrated on the stronger (LOS) anchor
    np.testing.assert_array_equal(ev.decide(t, r, s, f, budget), [False, True])
    # each cue alone suffices: no SNR known (power term off), or no flags
    np.testing.assert_array_equal(ev.decide(t, r, s, f, float("nan")), [False, True])
    np.testing.assert_array_equal(ev.decide(t, r, s, np.zeros_like(f), budget), [False, True])


def test_one_gross_range_error_or_faded_round_does_not_flag_a_los_link(rng):
    ev = EvidenceNlosTest(link_budget_db=BUDGET)
    t, r, s, f = _window(rng, 30, 4.0, 0.0, 0.06, 0.003)
    r[12] -= 1.7  # a noise crossing taken for the first path
    s[20] -= 15.0  # a first path cancelled by an overlapping reflection
    assert MseNlosTest().is_nlos(t, r)  # eq. (6) alone: a false alarm
    assert not ev.decide(t, r[:, None], s[:, None], f[:, None], BUDGET)[0]


def test_combined_false_alarm_and_detection_over_many_windows(rng):
    ev = EvidenceNlosTest(link_budget_db=BUDGET)
    fa = [ev.decide(*_pack(_window(rng, 30, 4.0, 0.0, 0.06, 0.01)))[0] for _ in range(300)]
    det = [ev.decide(*_pack(_window(rng, 30, 4.0, 8.0, 0.4, 0.01)))[0] for _ in range(300)]
    assert np.mean(fa) < 0.01
    assert np.mean(det) > 0.99


def _pack(w):
    t, r, s, f = w
    return t, r[:, None], s[:, None], f[:, None], BUDGET


def test_localizer_takes_los_flags_and_snr_and_stays_compatible_with_range_only_links(rng):
    anchors = {"a": (0.0, 0.0, 1.0), "b": (6.0, 0.0, 1.0), "c": (6.0, 5.0, 1.0), "d": (0, 5, 1)}
    truth = np.array([2.0, 2.0, 1.0])
    loc = RangingLocalizer(anchors, height=1.0)
    plain = RangingLocalizer(anchors, height=1.0, config=LocalizerConfig(evidence=None))
    for k in range(40):
        links, bare = {}, {}
        for aid, pos in anchors.items():
            d = float(np.linalg.norm(np.subtract(pos, truth)))
            loss = 14.0 if aid == "d" else 0.0  # d obstructed, its ranges steady (frozen)
            snr = BUDGET - 20 * np.log10(d) - loss + rng.normal(0, 1.0)
            r = d + 0.25 * (aid == "d") + rng.normal(0, 0.003)
            links[aid] = (r, 0.01, aid != "d" or rng.random() > 0.6, snr)
            bare[aid] = (r, 0.01)
        res = loc.step(0.1 * k, links)
        res_plain = plain.step(0.1 * k, bare)
    assert res.los == {"a": True, "b": True, "c": True, "d": False}
    assert all(res_plain.los.values())  # eq. (6) alone misses the frozen NLOS link
    assert np.linalg.norm(np.subtract(res.pose[:2], truth[:2])) < 0.02
